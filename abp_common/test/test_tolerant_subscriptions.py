"""TolerantNode's subscriptions on a real rclpy context: the node's callback gets the
message as rclpy would have given it (typed; with the message info when it takes two
arguments; awaited when it is a coroutine), a caller asking for raw bytes gets them, and
malformed bytes are dropped before the callback. (The dropped message's log line and the
process that spins on are checked over DDS in test_node_runner.py.)"""

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from abp_common.tolerant_subscriptions import TolerantNode, takes_message_info  # noqa: E402

TOPIC = '/tolerant_subscriptions_test'


@pytest.fixture
def listener(rclpy_context, tester):
    node = TolerantNode('listener', context=rclpy_context)
    tester[1].add_node(node)
    yield node
    tester[1].remove_node(node)
    node.destroy_node()


def test_callbacks_get_what_rclpy_would_give_them(listener, tester, spin):
    node, executor = tester
    got = {'plain': [], 'info': [], 'async': [], 'raw': [], 'bound': []}

    async def on_async(msg):
        got['async'].append(msg)

    class Holder:
        def on_message(self, msg):
            got['bound'].append(msg)

    listener.create_subscription(String, TOPIC, got['plain'].append, 10)
    listener.create_subscription(String, TOPIC, lambda msg, info: got['info'].append(
        (msg, info)), 10)
    listener.create_subscription(String, TOPIC, on_async, 10)
    listener.create_subscription(String, TOPIC, got['raw'].append, 10, raw=True)
    listener.create_subscription(String, TOPIC, Holder().on_message, 10)
    publisher = node.create_publisher(String, TOPIC, 10)
    assert spin(executor, lambda: publisher.get_subscription_count() == 5, 30)

    malformed = bytearray(serialize_message(String(data='x')))
    malformed[4:8] = (10 ** 9).to_bytes(4, 'little')     # the string's length field
    publisher.publish(bytes(malformed))
    publisher.publish(String(data='hello'))
    assert spin(executor, lambda: all(len(v) >= 1 for v in got.values()) and
                len(got['raw']) == 2, 30), got

    for kind in ('plain', 'async', 'bound'):
        assert got[kind] == [String(data='hello')], kind
    (msg, info), = got['info']
    assert msg == String(data='hello') and info['source_timestamp'] > 0
    # The raw subscriber gets both, as bytes; the malformed one never reached a typed one.
    assert got['raw'][0] == bytes(malformed)
    assert got['raw'][1] == serialize_message(String(data='hello'))


def test_the_arity_rule_is_rclpys():
    assert not takes_message_info(lambda msg: None)
    assert not takes_message_info(lambda msg, topic='t': None)    # default: one argument
    assert takes_message_info(lambda msg, info: None)
    with pytest.raises(TypeError):
        takes_message_info(lambda: None)
