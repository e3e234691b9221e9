"""The lifecycle manager's ChangeState request, sent twice to a real rclpy LifecycleNode
over DDS: the second, arriving after the first did its work (as a request the manager
sends again when the first answer was lost), is refused and the node lives on. An id-only
request in the same place makes rclpy raise in the node's executor (the belief node died
of it once, with "Transition is not registered")."""

import pytest

rclpy = pytest.importorskip('rclpy')

from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rclpy.lifecycle import LifecycleNode  # noqa: E402

from abp_bringup.lifecycle_manager import transition_request  # noqa: E402

TIMEOUT = 30.0


def test_a_transition_asked_again_is_refused_and_the_node_lives_on(tester, call_service,
                                                                    rclpy_context):
    node, executor = tester
    managed = LifecycleNode('managed_once', context=rclpy_context)
    executor.add_node(managed)
    change = node.create_client(ChangeState, '/managed_once/change_state')
    state = node.create_client(GetState, '/managed_once/get_state')
    try:
        for transition, label in (('configure', 'inactive'), ('activate', 'active')):
            assert call_service(executor, change, transition_request(transition), TIMEOUT).success
            assert call_service(executor, state, GetState.Request(),
                                TIMEOUT).current_state.label == label
        # Asked again: refused, and the node still answers (its executor did not raise).
        assert not call_service(executor, change, transition_request('activate'),
                                TIMEOUT).success
        assert not call_service(executor, change, transition_request('configure'),
                                TIMEOUT).success
        assert call_service(executor, state, GetState.Request(),
                            TIMEOUT).current_state.label == 'active'
    finally:
        executor.remove_node(managed)
        managed.destroy_node()
