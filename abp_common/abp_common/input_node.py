"""A managed node's high-rate subscriptions on a small hidden node of their own, spun by
a single-threaded executor on a thread of its own.

rclpy's executors rebuild their wait set from every entity of a node at each wake-up,
and a multi-threaded executor wakes several times per message while a worker takes it.
A node with action servers and clients, services and parameters has ~40-60 entities:
at sensor rates (/joint_states and /odom at 25 Hz in the sim, 100 Hz or more from a
robot's joint_state_broadcaster, ten times that at a 10x speed-up) that overhead was
most of the node's CPU. On a node of three subscriptions with one thread it is small,
and one thread also keeps each topic's messages in order.

`InputNode(owner)`: the hidden node `_<owner name>_inputs`, in the owner's namespace and
context. Its subscriptions are made through the owner's `NodeHealth.subscribe(...,
node=input_node.node)`: the topic is resolved by the owner (its namespace and
remappings), and inputs are counted and rejected in the owner's /diagnostics. Global
arguments are not applied to it, so a remapping of the owner's name does not rename it.
Its subscriptions drop messages rclpy cannot convert (TolerantNode). `close()` ends the
thread and destroys the node (the owner's deactivate)."""

import threading

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from .tolerant_subscriptions import TolerantNode

CLOSE_TIMEOUT_S = 2.0


class InputNode:
    def __init__(self, owner, suffix='inputs'):
        """The hidden node `_<owner name>_<suffix>` and its thread `<owner name>-<suffix>`."""
        self.node = TolerantNode(
            f'_{owner.get_name()}_{suffix}', namespace=owner.get_namespace(),
            context=owner.context, use_global_arguments=False,
            start_parameter_services=False)
        self._executor = SingleThreadedExecutor(context=owner.context)
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True,
                                        name=f'{owner.get_name()}-{suffix}')
        self._thread.start()

    def _spin(self):
        try:
            self._executor.spin()
        except ExternalShutdownException:
            pass
        except Exception:
            # Ctrl-C shuts the context down under the executor: between its check and the
            # wait, rclpy raises its RCLError ("context is not valid"), not the above.
            if self.node.context.ok():
                raise

    @property
    def subscriptions(self):
        return list(self.node.subscriptions)

    @property
    def spinning(self):
        return self._thread.is_alive()

    def close(self):
        self._executor.shutdown(timeout_sec=CLOSE_TIMEOUT_S)
        self._thread.join(timeout=CLOSE_TIMEOUT_S)
        self.node.destroy_node()


__all__ = ['InputNode']
