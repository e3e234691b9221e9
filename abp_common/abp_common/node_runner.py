"""The `main()` every abp node shares: init, build, spin, shut down cleanly.

A node whose construction fails on a bad parameter or file prints
`[name] configuration error: ...` and exits with code 2 instead of a traceback (so a
respawning launcher does not loop on a configuration that can never work); Ctrl-C ends
the spin quietly, also when it shuts the context down under a running callback;
`on_exit(node)` runs before the node is destroyed.

A message that rclpy fails to convert to a Python message (which it does now and then
under heavy load: ros2/rclpy#848, ros/joint_state_publisher#117) is logged, throttled,
and dropped; the spin goes on. That is the node's subscriptions' doing, not the
executor's (`tolerant_subscriptions`: every abp node class has them), so any executor
works and no rclpy internals are replaced. An exception from the node's own callback
still ends it.

Before rclpy.init, the shared-memory ports of DDS participants that were killed are
marked not ok (`shm_ports.retire_zombie_ports`): a node respawned after a SIGKILL takes
the dead one's port numbers, and without this the processes that had sent to the dead
one may never reach the new one (docs/RECOVERY.md).

A managed node (`lifecycle.ManagedNode`) is started here: with `autostart` true (the
default) it configures and activates before the spin, and a configuration error in its
configure() is reported the same way (code 2); with `autostart:=false` it spins
unconfigured until a lifecycle manager drives it.
"""

import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from .lifecycle import BASE_CONFIG_ERRORS, ManagedNode
from .shm_ports import retire_zombie_ports

CONFIGURATION_ERROR_EXIT_CODE = 2


def retire_ports_of_killed_participants(name):
    """Before this process's rclpy.init: mark the shared-memory ports of killed DDS
    participants not ok (shm_ports), saying which on stderr."""
    retired = retire_zombie_ports()
    if retired:
        print(f'[{name}] marked the shared-memory ports {", ".join(map(str, retired))} of '
              'killed DDS participants not ok, so that their writers open them afresh',
              file=sys.stderr)


def run_node(name, make_node, args=None, config_errors=(), make_executor=SingleThreadedExecutor,
             on_exit=None):
    """Run the node `make_node()` builds until shutdown; returns the process exit code.

    `config_errors`: extra exception types that mean a bad configuration (besides
    ValueError and rclpy's InvalidParameterValueException). `make_executor` is called
    after rclpy.init (an executor needs the context)."""
    retire_ports_of_killed_participants(name)
    init_rclpy_with_quiet_interrupt(args)
    node = None
    try:
        node = make_node()
        if isinstance(node, ManagedNode):
            node.take_clock_on_own_thread()   # /clock off the node's executor (clock_input)
            node.start(config_errors)
    except (*BASE_CONFIG_ERRORS, *config_errors) as error:
        print(f'[{name}] configuration error: {error}', file=sys.stderr)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        return CONFIGURATION_ERROR_EXIT_CODE
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


_rclpy_handles_interrupts = False  # set once rclpy.init has installed rclpy's SIGINT handler


def init_rclpy_with_quiet_interrupt(args):
    """rclpy.init(args), with a Python SIGINT handler under rclpy's: Ctrl-C ends the spin
    without a KeyboardInterrupt.

    rclpy's own handler (installed by rclpy.init, chaining to Python's) shuts the context
    down, which ends the spin. Python's default handler would also raise KeyboardInterrupt
    wherever the main thread is, even inside a finalizer (`Exception ignored in:
    Future.__del__`), where nothing can catch it. So Python's handler does nothing once
    rclpy handles the signal, and above all takes no lock: Python runs it between two
    bytecodes of the main thread, which may hold the context's lock at that moment
    (inside `Context.ok()`); a handler that called rclpy.try_shutdown() waited on that
    lock for ever (a bag recorder that never closed its bag). Before rclpy.init has
    returned, Ctrl-C interrupts as usual."""
    global _rclpy_handles_interrupts
    _rclpy_handles_interrupts = False
    signal.signal(signal.SIGINT, _interrupt)
    rclpy.init(args=args)
    _rclpy_handles_interrupts = True


def _interrupt(signum, frame):
    if not _rclpy_handles_interrupts:
        signal.default_int_handler(signum, frame)


__all__ = ['CONFIGURATION_ERROR_EXIT_CODE', 'init_rclpy_with_quiet_interrupt', 'run_node']
