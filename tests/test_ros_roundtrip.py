"""Real ROS round trips across two processes over DDS (no mocks).

(a) every abp_msgs message, filled in every field, goes to a separate echo
process and comes back equal; both services answer across processes;
(b) an Orbit action goal gets feedback and a result, and a second goal is
cancelled mid-motion, across processes.
"""

import pathlib

import pytest

rclpy = pytest.importorskip('rclpy')

from action_msgs.msg import GoalStatus  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from abp_common import qos  # noqa: E402
from abp_msgs.action import Orbit  # noqa: E402
from abp_msgs.srv import CheckFeasibility, ResetBelief  # noqa: E402
from tests.helpers.echo_node import message_types  # noqa: E402
from tests.helpers.populate import populate  # noqa: E402

ECHO_NODE = pathlib.Path(__file__).parent / 'helpers' / 'echo_node.py'


@pytest.fixture
def echo_process(ros_processes):
    repo = pathlib.Path(__file__).resolve().parent.parent
    proc = ros_processes.start_python(ECHO_NODE, cwd=repo)
    ros_processes.wait_for_line(proc, 'READY', timeout=30)
    return proc


@pytest.fixture
def node(rclpy_context):
    test_node = rclpy.create_node('roundtrip_tester', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(test_node)
    test_node.executor_for_test = executor
    yield test_node
    executor.shutdown()
    test_node.destroy_node()


def test_every_message_round_trips(echo_process, node, spin):
    types = message_types()
    assert len(types) >= 9, f'expected the full abp_msgs set, found {sorted(types)}'
    executor = node.executor_for_test
    received = {}
    publishers = {}
    sent = {}
    for name, msg_type in types.items():
        node.create_subscription(
            msg_type, f'/roundtrip/out/{name}',
            lambda msg, name=name: received.setdefault(name, msg), qos.RELIABLE)
        publishers[name] = node.create_publisher(msg_type, f'/roundtrip/in/{name}', qos.RELIABLE)
        sent[name] = populate(msg_type(), seed=len(name))
    # Wait for discovery both ways before publishing, then resend until echoed.
    assert spin(executor, lambda: all(p.get_subscription_count() > 0
                                      for p in publishers.values()), 20), 'echo node not matched'
    for _ in range(50):
        for name, publisher in publishers.items():
            if name not in received:
                publisher.publish(sent[name])
        if spin(executor, lambda: len(received) == len(types), 0.5):
            break
    missing = sorted(set(types) - set(received))
    assert not missing, f'no echo for {missing}'
    for name in types:
        assert received[name] == sent[name], f'{name} changed on the round trip'
        assert received[name] != types[name](), f'{name} was not populated'


def test_services_answer_across_processes(echo_process, node, call_service):
    executor = node.executor_for_test
    feasibility = node.create_client(CheckFeasibility, '/roundtrip/check_feasibility')
    reset = node.create_client(ResetBelief, '/roundtrip/reset_belief')

    request = CheckFeasibility.Request(actions=['PUSH', 'LIFT', 'FLIP'])
    answer = call_service(executor, feasibility, request, 10, ready_timeout=20)
    assert list(answer.actions) == ['PUSH', 'LIFT', 'FLIP']
    assert list(answer.feasible) == [True, False, True]
    assert answer.reasons[1] == 'unreachable: LIFT'

    answer = call_service(executor, reset, ResetBelief.Request(model_prior=[0.5, 0.25, 0.25]),
                          10, ready_timeout=20)
    assert answer.success
    assert answer.message == 'reset with 3 prior entries'


def test_action_goal_feedback_result_and_cancel(echo_process, node, spin, answering):
    executor = node.executor_for_test
    client = ActionClient(node, Orbit, '/roundtrip/orbit')
    assert answering(executor, client, 20), 'orbit server not found'

    # A goal outside the allowed angles is rejected by the server.
    rejected = client.send_goal_async(Orbit.Goal(angle_deg=33.0))
    assert spin(executor, rejected.done, 10)
    assert not rejected.result().accepted

    feedback = []
    send = client.send_goal_async(Orbit.Goal(angle_deg=90.0),
                                  feedback_callback=lambda msg: feedback.append(msg.feedback))
    assert spin(executor, send.done, 10)
    handle = send.result()
    assert handle.accepted
    result_future = handle.get_result_async()
    assert spin(executor, result_future.done, 20)
    response = result_future.result()
    assert response.status == GoalStatus.STATUS_SUCCEEDED
    assert response.result.success and response.result.reason == 'orbited 90 deg'
    assert response.result.duration.sec >= 1
    phases = [f.phase for f in feedback]
    assert {'approach', 'contact', 'stroke', 'retreat'} <= set(phases)
    progress = [f.progress for f in feedback]
    assert progress == sorted(progress) and progress[-1] == pytest.approx(1.0)

    feedback.clear()
    send = client.send_goal_async(Orbit.Goal(angle_deg=-45.0),
                                  feedback_callback=lambda msg: feedback.append(msg.feedback))
    assert spin(executor, send.done, 10)
    handle = send.result()
    assert spin(executor, lambda: len(feedback) >= 3, 10), 'no feedback before cancel'
    cancel = handle.cancel_goal_async()
    assert spin(executor, cancel.done, 10)
    assert len(cancel.result().goals_canceling) == 1
    result_future = handle.get_result_async()
    assert spin(executor, result_future.done, 10)
    response = result_future.result()
    assert response.status == GoalStatus.STATUS_CANCELED
    assert not response.result.success
    assert response.result.reason.startswith('cancelled at step')
    assert feedback[-1].progress < 1.0
    client.destroy()
