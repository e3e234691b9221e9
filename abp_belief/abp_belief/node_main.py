"""The `main()` every abp node shares: init, build, spin, shut down cleanly.

ROS wiring (no science): a node whose construction fails on a bad parameter or
file prints `[name] configuration error: ...` and exits with code 2 instead of a
traceback; Ctrl-C ends the spin quietly, also when it shuts the context down
under a running callback; `on_exit(node)` runs before the node is destroyed.
"""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor


def run_node(name, make_node, args=None, config_errors=(), make_executor=SingleThreadedExecutor,
             on_exit=None):
    """Run the node `make_node()` builds until shutdown; returns the process exit code.

    `make_executor` is called after rclpy.init (an executor needs the context)."""
    rclpy.init(args=args)
    try:
        node = make_node()
    except (ValueError, rclpy.exceptions.InvalidParameterValueException,
            *config_errors) as error:
        print(f'[{name}] configuration error: {error}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = make_executor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # Ctrl-C shuts the context down under a running callback; only a
        # failure while the context is still valid is a real error.
        if rclpy.ok():
            raise
    finally:
        if on_exit is not None:
            on_exit(node)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
