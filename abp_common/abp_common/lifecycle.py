"""Managed (lifecycle) abp nodes: the shared plumbing, like nav2_util's LifecycleNode.

Every long-running node is a `ManagedNode` (an `rclpy.lifecycle.LifecycleNode`) and
implements two methods:

- `configure()`: declare the parameters, load the model set, build the science objects
  (raise ValueError, or one of the node's configuration error types, on a bad value);
- `activate()`: open the publishers, subscriptions, services, action servers and timers.

The base class records what each of them created (endpoints, timers, action servers and
clients, parameters, parameter callbacks) and undoes it on the way back: deactivate
destroys what activate opened (so an inactive node publishes and serves nothing),
cleanup what configure made (so configure can run again); an input node
(`create_input_node()`: high-rate subscriptions on a thread of their own) is closed the
same way. Optional hooks `deactivate()` and `cleanup()` run first. The node keeps that
record itself, through rclpy's public factory and destroy methods
(`entity_registry.EntityRegistry`), and tracks its lifecycle state itself
(`state_label()`): rclpy's private lists and state machine are not read. Its
subscriptions drop a message rclpy cannot convert instead of ending the node
(`tolerant_subscriptions`).

The boolean parameter `autostart` (default true) makes the node configure and activate
itself as soon as it is built (`start()`, called by `node_runner.run_node`): a plain
`ros2 run` behaves as before, and a configuration error still ends the process with code
2. With `autostart:=false` the node waits unconfigured for a lifecycle manager
(`abp_bringup lifecycle_manager`); a configuration error then makes configure return
FAILURE with the reason logged, and the node stays unconfigured.

Run by `node_runner.run_node`, a managed node under use_sim_time has its clock driven from
/clock on a hidden node with a thread of its own (`take_clock_on_own_thread()`,
`clock_input.ClockInput`), so /clock does not wake the node's executor; that subscription
is in the endpoint report like the node's own.

Each managed node also serves `~/endpoint_status` (std_srvs/Trigger): success when the
node is active; the message is JSON with its lifecycle state, a per-process instance id
(a respawned node has a new one), and, per topic, how many publishers each of its
subscriptions has matched and how many subscriptions each of its publishers has
matched (`endpoint_report`). The lifecycle manager reads it to declare the graph ready.
"""

import json
import os
import traceback
import uuid

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_srvs.srv import Trigger

from .clock_input import ClockInput
from .entity_registry import EntityRegistry
from .input_node import InputNode
from .lifecycle_report import endpoint_report
from .tolerant_subscriptions import TolerantSubscriptions

AUTOSTART = 'autostart'
ENDPOINT_STATUS = '~/endpoint_status'
BASE_CONFIG_ERRORS = (ValueError, rclpy.exceptions.InvalidParameterValueException,
                      rclpy.exceptions.InvalidParameterTypeException)


class ManagedNode(EntityRegistry, TolerantSubscriptions, LifecycleNode):
    """A lifecycle node whose subclasses implement configure() and activate()."""

    def __init__(self, node_name, **kwargs):
        self.registry_init()
        # rclpy has no public getter for the state; each transition callback below sets
        # the state its result leads to.
        self._lifecycle_state = 'unconfigured'
        self._activated = False   # activate() succeeded and its entities are not undone
        super().__init__(node_name, **kwargs)
        self.declare_parameter(AUTOSTART, True, ParameterDescriptor(
            description='Configure and activate this node as soon as it starts (true), or '
                        'wait unconfigured for a lifecycle manager (false).', read_only=True))
        self.config_errors = BASE_CONFIG_ERRORS
        self.configuration_error = None    # the last configure failure (an exception)
        self.instance = f'{os.getpid()}-{uuid.uuid4().hex[:8]}'
        # Its own callback group: on a multi-threaded executor shared with other nodes
        # (abp_bringup graph_container) a busy node's stream of messages in the default
        # group would otherwise keep the manager's question waiting.
        self.create_service(Trigger, ENDPOINT_STATUS, self._on_endpoint_status,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self.clock_input = None   # take_clock_on_own_thread()

    def take_clock_on_own_thread(self):
        """Under use_sim_time, take /clock on a thread of its own, not on this node's
        executor (clock_input.ClockInput). node_runner does it for a node in a process of
        its own; the one-process graph container (abp_bringup) does not."""
        if self.clock_input is None:
            self.clock_input = ClockInput(self)

    def destroy_node(self):
        if self.clock_input is not None:
            self.clock_input.close()
        return super().destroy_node()

    # -- what subclasses implement ---------------------------------------------------
    def configure(self):
        """Declare parameters, load models; raise a configuration error on bad values."""

    def activate(self):
        """Open the publishers, subscriptions, services, action servers and timers."""

    def deactivate(self):
        """Before activate's entities are destroyed (optional)."""

    def cleanup(self):
        """Before configure's entities and parameters are removed (optional)."""

    # -- autostart -------------------------------------------------------------------
    @property
    def autostart(self):
        return bool(self.get_parameter(AUTOSTART).value)

    def start(self, config_errors=()):
        """Autostart: configure and activate now. Raises the configuration error (or the
        unexpected exception) that made configure fail, so that run_node reports it."""
        self.config_errors = (*BASE_CONFIG_ERRORS, *config_errors)
        if not self.autostart:
            self.get_logger().info('unconfigured: waiting for a lifecycle manager '
                                   '(autostart is false)')
            return
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise self.configuration_error or RuntimeError('configure failed')
        if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
            raise RuntimeError('activate failed (see the log above)')

    def state_label(self):
        """The lifecycle state: unconfigured, inactive, active or finalized (or the
        transition running: configuring, activating, ...)."""
        return self._lifecycle_state

    # -- transitions -----------------------------------------------------------------
    def on_configure(self, state):
        self._lifecycle_state = 'configuring'
        self.configuration_error = None
        try:
            with self.recording('configure'):
                self.configure()
        except Exception as error:  # noqa: BLE001 -- reported, then the node is undone
            self._undo('configure')
            self.configuration_error = error
            if isinstance(error, self.config_errors):
                self.get_logger().error(f'configure failed: configuration error: {error}')
            else:
                self.get_logger().error(f'configure failed: {type(error).__name__}: '
                                        f'{error}\n{traceback.format_exc()}')
            return self._ends_in('unconfigured', TransitionCallbackReturn.FAILURE)
        return self._ends_in('inactive', TransitionCallbackReturn.SUCCESS)

    def on_activate(self, state):
        self._lifecycle_state = 'activating'
        try:
            with self.recording('activate'):
                self.activate()
        except Exception as error:  # noqa: BLE001
            self._undo('activate')
            self.get_logger().error(f'activate failed: {type(error).__name__}: {error}\n'
                                    f'{traceback.format_exc()}')
            return self._ends_in('inactive', TransitionCallbackReturn.FAILURE)
        self._activated = True
        # Lifecycle publishers (create_lifecycle_publisher), if a node has any.
        result = super().on_activate(state)
        if result == TransitionCallbackReturn.SUCCESS:
            self.get_logger().info('active')
            return self._ends_in('active', result)
        # FAILURE leaves the node inactive; ERROR goes on to on_error.
        return self._ends_in('inactive', result)

    def on_deactivate(self, state):
        self._lifecycle_state = 'deactivating'
        super().on_deactivate(state)
        self._run_hook(self.deactivate)
        self._undo('activate')
        self._activated = False
        self.get_logger().info('inactive')
        return self._ends_in('inactive', TransitionCallbackReturn.SUCCESS)

    def on_cleanup(self, state):
        self._lifecycle_state = 'cleaningup'
        self._run_hook(self.cleanup)
        self._undo('configure')
        self.get_logger().info('unconfigured (cleaned up)')
        return self._ends_in('unconfigured', TransitionCallbackReturn.SUCCESS)

    def on_shutdown(self, state):
        self._lifecycle_state = 'shuttingdown'
        self._undo_all()
        return self._ends_in('finalized', TransitionCallbackReturn.SUCCESS)

    def on_error(self, state):
        self._lifecycle_state = 'errorprocessing'
        self._undo_all()
        return self._ends_in('unconfigured', TransitionCallbackReturn.SUCCESS)

    def _ends_in(self, label, result):
        self._lifecycle_state = label
        return result

    def _undo_all(self):
        if self._activated:
            self._run_hook(self.deactivate)
        self._undo('activate')
        self._activated = False
        self._undo('configure')

    def _undo(self, phase):
        def report(entity, error):
            self.get_logger().error(f'destroying {entity!r} failed: '
                                    f'{type(error).__name__}: {error}')
        self.undo(phase, report)

    def _run_hook(self, hook, what=None):
        try:
            hook()
        except Exception as error:  # noqa: BLE001 -- the transition must still complete
            self.get_logger().error(f'{what or hook.__name__} failed: '
                                    f'{type(error).__name__}: {error}')

    # -- input nodes -------------------------------------------------------------------
    def create_input_node(self):
        """An `input_node.InputNode` for high-rate subscriptions, with its own thread. Like
        any entity it is undone with the phase that made it (activate's is closed at
        deactivate), and its subscriptions are in this node's endpoint report."""
        return self._note(InputNode.close, InputNode(self))

    def _input_node_subscriptions(self):
        return [subscription for phase in ('configure', 'activate')
                for entity in self.made_in(phase) if isinstance(entity, InputNode)
                for subscription in entity.subscriptions]

    # -- status for the lifecycle manager --------------------------------------------
    def endpoint_report(self):
        return endpoint_report(
            self.state_label(), self.instance,
            ((s.topic_name, s.get_publisher_count())
             for s in (*self.subscriptions, *self._input_node_subscriptions(),
                       *(self.clock_input.subscriptions if self.clock_input else ()))),
            ((p.topic_name, p.get_subscription_count()) for p in self.publishers))

    def _on_endpoint_status(self, request, response):
        try:
            report = self.endpoint_report()
        except Exception:  # noqa: BLE001 -- an endpoint destroyed by a transition meanwhile
            report = endpoint_report('busy', self.instance, (), ())  # ask again later
        response.success = report['state'] == 'active'
        response.message = json.dumps(report, sort_keys=True)
        return response


__all__ = ['AUTOSTART', 'BASE_CONFIG_ERRORS', 'ENDPOINT_STATUS', 'ManagedNode']
