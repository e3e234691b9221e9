"""InputNode on a real rclpy context: the owner's subscriptions on a hidden node of their
own, in the owner's namespace, on topics the owner resolves (its remappings), counted and
guarded by the owner's NodeHealth, taken by the input node's own thread; close() ends it."""

import threading

import pytest

rclpy = pytest.importorskip('rclpy')

from std_msgs.msg import String  # noqa: E402

from abp_common.health import NodeHealth  # noqa: E402
from abp_common.input_checks import Rejected  # noqa: E402
from abp_common.input_node import InputNode  # noqa: E402

WAIT_S = 30.0


@pytest.fixture
def owner(rclpy_context):
    node = rclpy.create_node('owner', namespace='/input_node_test', context=rclpy_context,
                             cli_args=['--ros-args', '-r', 'chatter:=remapped'])
    yield node
    node.destroy_node()


def test_the_owners_topics_reach_its_callback_on_the_input_nodes_thread(owner, tester,
                                                                         spin):
    health = NodeHealth(owner)
    inputs = InputNode(owner)
    assert inputs.spinning
    got, threads, arrived = [], set(), threading.Event()

    def on_message(msg):
        if msg.data == 'bad':
            raise Rejected('malformed', 'a bad message')
        got.append(msg.data)
        threads.add(threading.current_thread().name)
        arrived.set()
    subscription = health.subscribe(String, 'chatter', on_message, 10, node=inputs.node)
    assert subscription.topic_name == '/input_node_test/remapped'
    assert inputs.subscriptions == [subscription]
    names = {(name, ns) for name, ns in inputs.node.get_node_names_and_namespaces()}
    assert ('_owner_inputs', '/input_node_test') in names

    node, executor = tester
    pub = node.create_publisher(String, '/input_node_test/remapped', 10)
    assert spin(executor, lambda: pub.get_subscription_count() > 0, WAIT_S)
    pub.publish(String(data='bad'))
    pub.publish(String(data='hello'))
    assert arrived.wait(WAIT_S), 'no message reached the callback'
    assert got == ['hello'] and threads == {'owner-inputs'}
    assert health.stats.rejected[('chatter', 'malformed')] == 1

    inputs.close()
    assert not inputs.spinning
