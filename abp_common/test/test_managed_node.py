"""ManagedNode on a real rclpy context: each transition undoes exactly what its counterpart
made, with the node's own registry (rclpy's public API only), and its state is the one
rclpy's lifecycle services report.

The sample node makes one of every kind of entity: in configure parameters (one
read-only), a parameter callback and a client; in activate a publisher, a subscription, a
service, a timer, a guard condition, an action server it keeps no reference to and an
action client, and an input node (its own node and thread) with a subscription. The
node's public entity iterators (`publishers`, `waitables`, ...) are compared with what
they held before each transition."""

import gc

import pytest

rclpy = pytest.importorskip('rclpy')

from lifecycle_msgs.srv import GetState  # noqa: E402
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult  # noqa: E402
from rclpy.action import ActionClient, ActionServer  # noqa: E402
from rclpy.action.server import ServerGoalHandle  # noqa: E402, F401 -- its module loads
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from abp_common.lifecycle import ManagedNode  # noqa: E402
from abp_msgs.action import Lift  # noqa: E402

SUCCESS = TransitionCallbackReturn.SUCCESS
KINDS = ('publishers', 'subscriptions', 'services', 'clients', 'timers', 'guards',
         'waitables')


class Sample(ManagedNode):
    def __init__(self, context, fail_in=None):
        self.fail_in = fail_in
        self.hooks = []
        super().__init__('sample', context=context, parameter_overrides=[
            rclpy.parameter.Parameter('autostart', value=False),
            rclpy.parameter.Parameter('mode', value='given')])

    def configure(self):
        self.declare_parameter('gain', 1.5)
        self.declare_parameter('mode', 'default', ParameterDescriptor(read_only=True))
        self.add_on_set_parameters_callback(self.check)
        self.create_client(Trigger, '~/peer')
        if self.fail_in == 'configure':
            raise ValueError('bad gain')

    def activate(self):
        self.create_publisher(String, '~/out', 10)
        self.create_subscription(String, '~/in', lambda msg: None, 10)
        self.create_service(Trigger, '~/do', lambda request, response: response)
        self.create_timer(10.0, lambda: None)
        self.create_guard_condition(lambda: None)
        ActionServer(self, Lift, '~/lift', lambda goal: Lift.Result())   # no reference kept
        self.lift_client = ActionClient(self, Lift, '~/other_lift')
        self.inputs = self.create_input_node()
        self.inputs.node.create_subscription(String, self.resolve_topic_name('~/fast_in'),
                                             lambda msg: None, 10)
        if self.fail_in == 'activate':
            raise RuntimeError('activate broke')

    def deactivate(self):
        self.hooks.append('deactivate')

    def cleanup(self):
        self.hooks.append('cleanup')

    def check(self, parameters):
        return SetParametersResult(successful=True)


def entities(node):
    return {kind: {id(x) for x in getattr(node, kind)} for kind in KINDS}


def added(before, after):
    return {kind: len(after[kind] - before[kind]) for kind in KINDS}


def removed(before, after):
    return {kind: len(before[kind] - after[kind]) for kind in KINDS}


NONE = dict.fromkeys(KINDS, 0)
# An action server or client is one waitable; a publisher or subscription adds two
# (rclpy's default handlers of incompatible QoS and incompatible type events).
CONFIGURE_MAKES = dict(NONE, clients=1)
ACTIVATE_MAKES = dict(NONE, publishers=1, subscriptions=1, services=1, timers=1, guards=1,
                      waitables=2 + 2 + 2)


@pytest.fixture
def sample_node(rclpy_context, tester):
    made = []

    def make(**kwargs):
        node = Sample(rclpy_context, **kwargs)
        tester[1].add_node(node)
        made.append(node)
        return node
    yield make
    for node in made:
        tester[1].remove_node(node)
        node.destroy_node()


def rclpy_state(tester, call_service):
    node, executor = tester
    client = node.create_client(GetState, '/sample/get_state')
    try:
        return call_service(executor, client, GetState.Request(), 30.0).current_state.label
    finally:
        node.destroy_client(client)


def test_each_transition_undoes_what_its_counterpart_made(sample_node, tester, call_service):
    node = sample_node()
    built = entities(node)
    service_names = {s.srv_name for s in node.services}
    assert '~/endpoint_status' in service_names and '/sample/get_state' in service_names
    assert node.state_label() == rclpy_state(tester, call_service) == 'unconfigured'

    assert node.trigger_configure() == SUCCESS
    configured = entities(node)
    assert added(built, configured) == CONFIGURE_MAKES
    assert node.get_parameter('mode').value == 'given'
    assert node.state_label() == rclpy_state(tester, call_service) == 'inactive'

    assert node.trigger_activate() == SUCCESS
    gc.collect()   # the action server nobody else refers to is still served
    active = entities(node)
    assert added(configured, active) == ACTIVATE_MAKES
    assert any(isinstance(w, ActionServer) for w in node.waitables)
    assert node.state_label() == rclpy_state(tester, call_service) == 'active'
    # The input node's subscription is the node's own input in the manager's report.
    inputs = node.inputs
    assert inputs.spinning and '/sample/fast_in' in node.endpoint_report()['inputs']

    assert node.trigger_deactivate() == SUCCESS
    assert entities(node) == configured
    assert not inputs.spinning and '/sample/fast_in' not in node.endpoint_report()['inputs']
    assert not any(isinstance(w, (ActionServer, ActionClient)) for w in node.waitables)
    assert node.has_parameter('gain')
    assert node.state_label() == rclpy_state(tester, call_service) == 'inactive'

    assert node.trigger_cleanup() == SUCCESS
    assert entities(node) == built
    assert {s.srv_name for s in node.services} == service_names
    assert not node.has_parameter('gain')
    # rclpy cannot undeclare a read-only parameter: it stays, with the value given at
    # start, and the next configure gets it back as it is.
    assert node.get_parameter('mode').value == 'given'
    assert node.hooks == ['deactivate', 'cleanup']
    assert node.state_label() == rclpy_state(tester, call_service) == 'unconfigured'

    # Configure and activate again (the lifecycle manager does so after a cleanup).
    assert node.trigger_configure() == SUCCESS
    assert node.get_parameter('mode').value == 'given'
    assert node.get_parameter('gain').value == 1.5
    assert node.trigger_activate() == SUCCESS
    assert added(built, entities(node)) == {k: CONFIGURE_MAKES[k] + ACTIVATE_MAKES[k]
                                            for k in KINDS}

    # Shutdown from active runs the deactivate hook and undoes both phases.
    assert node.trigger_shutdown() == SUCCESS
    assert entities(node) == built
    assert node.hooks[-1] == 'deactivate'
    assert node.state_label() == rclpy_state(tester, call_service) == 'finalized'


@pytest.mark.parametrize('phase', ['configure', 'activate'])
def test_a_failed_transition_undoes_what_it_made(sample_node, tester, call_service, phase):
    node = sample_node(fail_in=phase)
    built = entities(node)
    if phase == 'configure':
        assert node.trigger_configure() != SUCCESS
        assert isinstance(node.configuration_error, ValueError)
        assert entities(node) == built and not node.has_parameter('gain')
        assert node.state_label() == rclpy_state(tester, call_service) == 'unconfigured'
        # The failure is reported, not fatal: configure can be asked again.
        assert node.trigger_configure() != SUCCESS
    else:
        assert node.trigger_configure() == SUCCESS
        configured = entities(node)
        assert node.trigger_activate() != SUCCESS
        assert entities(node) == configured and not node.inputs.spinning
        assert node.state_label() == rclpy_state(tester, call_service) == 'inactive'
        assert node.trigger_cleanup() == SUCCESS
        assert entities(node) == built
