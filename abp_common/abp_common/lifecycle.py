"""Managed (lifecycle) abp nodes: the shared plumbing, like nav2_util's LifecycleNode.

Every long-running node is a `ManagedNode` (an `rclpy.lifecycle.LifecycleNode`) and
implements two methods:

- `configure()`: declare the parameters, load the model set, build the science objects
  (raise ValueError, or one of the node's configuration error types, on a bad value);
- `activate()`: open the publishers, subscriptions, services, action servers and timers.

The base class records what each of them created (endpoints, timers, waitables,
parameters, parameter callbacks) and undoes it on the way back: deactivate destroys what
activate opened (so an inactive node publishes and serves nothing), cleanup what
configure made (so configure can run again). Optional hooks `deactivate()` and
`cleanup()` run first.

The boolean parameter `autostart` (default true) makes the node configure and activate
itself as soon as it is built (`start()`, called by `node_runner.run_node`): a plain
`ros2 run` behaves as before, and a configuration error still ends the process with code
2. With `autostart:=false` the node waits unconfigured for a lifecycle manager
(`abp_bringup lifecycle_manager`); a configuration error then makes configure return
FAILURE with the reason logged, and the node stays unconfigured.

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
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_srvs.srv import Trigger

from .lifecycle_report import endpoint_report

AUTOSTART = 'autostart'
ENDPOINT_STATUS = '~/endpoint_status'
BASE_CONFIG_ERRORS = (ValueError, rclpy.exceptions.InvalidParameterValueException,
                      rclpy.exceptions.InvalidParameterTypeException)

_ENTITY_LISTS = ('_publishers', '_subscriptions', '_services', '_clients', '_timers',
                 '_guards')
_CALLBACK_LISTS = ('_pre_set_parameters_callbacks', '_on_set_parameters_callbacks',
                   '_post_set_parameters_callbacks')


class ManagedNode(LifecycleNode):
    """A lifecycle node whose subclasses implement configure() and activate()."""

    def __init__(self, node_name, **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_parameter(AUTOSTART, True, ParameterDescriptor(
            description='Configure and activate this node as soon as it starts (true), or '
                        'wait unconfigured for a lifecycle manager (false).', read_only=True))
        self.config_errors = BASE_CONFIG_ERRORS
        self.configuration_error = None    # the last configure failure (an exception)
        self.instance = f'{os.getpid()}-{uuid.uuid4().hex[:8]}'
        self._made = {'configure': None, 'activate': None}
        self.create_service(Trigger, ENDPOINT_STATUS, self._on_endpoint_status)

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
        return self._state_machine.current_state[1]

    # -- transitions -----------------------------------------------------------------
    def on_configure(self, state):
        self.configuration_error = None
        before = self._snapshot()
        try:
            self.configure()
        except Exception as error:  # noqa: BLE001 -- reported, then the node is undone
            made = self._diff(before)
            self._run_hook(lambda: self._undo(made), 'destroying')
            self.configuration_error = error
            if isinstance(error, self.config_errors):
                self.get_logger().error(f'configure failed: configuration error: {error}')
                return TransitionCallbackReturn.FAILURE
            self.get_logger().error(f'configure failed: {type(error).__name__}: {error}\n'
                                    f'{traceback.format_exc()}')
            return TransitionCallbackReturn.FAILURE
        self._made['configure'] = self._diff(before)
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        before = self._snapshot()
        try:
            self.activate()
        except Exception as error:  # noqa: BLE001
            made = self._diff(before)
            self._run_hook(lambda: self._undo(made), 'destroying')
            self.get_logger().error(f'activate failed: {type(error).__name__}: {error}\n'
                                    f'{traceback.format_exc()}')
            return TransitionCallbackReturn.FAILURE
        self._made['activate'] = self._diff(before)
        # Lifecycle publishers (create_lifecycle_publisher), if a node has any.
        result = super().on_activate(state)
        if result == TransitionCallbackReturn.SUCCESS:
            self.get_logger().info('active')
        return result

    def on_deactivate(self, state):
        super().on_deactivate(state)
        self._run_hook(self.deactivate)
        self._run_hook(lambda: self._undo(self._made['activate']), 'destroying')
        self._made['activate'] = None
        self.get_logger().info('inactive')
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state):
        self._run_hook(self.cleanup)
        self._run_hook(lambda: self._undo(self._made['configure']), 'destroying')
        self._made['configure'] = None
        self.get_logger().info('unconfigured (cleaned up)')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        if self._made['activate'] is not None:
            self._run_hook(self.deactivate)
        self._undo(self._made['activate'])
        self._undo(self._made['configure'])
        self._made = {'configure': None, 'activate': None}
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        self.on_shutdown(state)
        return TransitionCallbackReturn.SUCCESS

    def _run_hook(self, hook, what=None):
        try:
            hook()
        except Exception as error:  # noqa: BLE001 -- the transition must still complete
            self.get_logger().error(f'{what or hook.__name__} failed: '
                                    f'{type(error).__name__}: {error}')

    # -- bookkeeping of what a transition made ---------------------------------------
    def _snapshot(self):
        snap = {name: list(getattr(self, name)) for name in _ENTITY_LISTS + _CALLBACK_LISTS}
        snap['waitables'] = list(self.waitables)
        snap['parameters'] = set(self._parameters)
        return snap

    def _diff(self, before):
        now = self._snapshot()
        made = {}
        for name, items in now.items():
            if name == 'parameters':
                made[name] = [p for p in items if p not in before[name]]
            else:
                old = {id(x) for x in before[name]}
                made[name] = [x for x in items if id(x) not in old]
        return made

    def _undo(self, made):
        if not made:
            return
        # Endpoints first: destroying one also removes its QoS event handlers (waitables).
        destroyers = {'_publishers': self.destroy_publisher,
                      '_subscriptions': self.destroy_subscription,
                      '_services': self.destroy_service, '_clients': self.destroy_client,
                      '_timers': self.destroy_timer, '_guards': self.destroy_guard_condition}
        for name, destroy in destroyers.items():
            for entity in made[name]:
                destroy(entity)
        for waitable in made['waitables']:
            if any(w is waitable for w in self.waitables):
                destroy = getattr(waitable, 'destroy', None)
                if destroy is not None:
                    destroy()       # an action server or client removes itself
                if any(w is waitable for w in self.waitables):
                    self.remove_waitable(waitable)
        for name in _CALLBACK_LISTS:
            callbacks = getattr(self, name)
            for callback in made[name]:
                if callback in callbacks:
                    callbacks.remove(callback)
        for parameter in made['parameters']:
            # undeclare_parameter refuses read-only ones; configure declares them again
            # (with the values given at start) after a cleanup.
            self._parameters.pop(parameter, None)
            self._descriptors.pop(parameter, None)

    # -- status for the lifecycle manager --------------------------------------------
    def endpoint_report(self):
        return endpoint_report(
            self.state_label(), self.instance,
            ((s.topic_name, s.get_publisher_count()) for s in self.subscriptions),
            ((p.topic_name, p.get_subscription_count()) for p in self.publishers))

    def _on_endpoint_status(self, request, response):
        report = self.endpoint_report()
        response.success = report['state'] == 'active'
        response.message = json.dumps(report, sort_keys=True)
        return response


__all__ = ['AUTOSTART', 'BASE_CONFIG_ERRORS', 'ENDPOINT_STATUS', 'ManagedNode']
