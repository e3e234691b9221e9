"""QoS in abp's bags, over real DDS and real rosbag2 files: the recorder stores each topic's
offered QoS profiles as rosbag2 Jazzy does (checked against a metadata.yaml rosbag2 wrote,
test/resources), and the player replays a latched topic latched, so that a subscriber that
joins after the replay still gets its message."""

import os
import pathlib
import signal

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from geometry_msgs.msg import TransformStamped  # noqa: E402
from rclpy.event_handler import SubscriptionEventCallbacks  # noqa: E402
from rclpy.qos import QoSPolicyKind  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.interfaces import QosDurability, QosReliability  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from abp_bringup import bag_qos  # noqa: E402
from abp_bringup.bag import BagWriter, offered_qos, read_bag  # noqa: E402
from abp_common import names, qos  # noqa: E402
from abp_msgs.msg import Belief, ExecutedAction  # noqa: E402

RESOURCES = pathlib.Path(__file__).resolve().parent / 'resources'
ROSBAG2_METADATA = RESOURCES / 'rosbag2_bag_with_topics_and_service_events.metadata.yaml'
RECORDED = ['abp/belief', '/tf_static', 'abp/executed_action', 'camera/camera_info']

# rmw's policy values (rmw/types.h) and the names rosbag2 Jazzy writes for them in a
# version 9 metadata.yaml (rmw_qos_*_policy_to_str; 'unknown' for UNKNOWN).
RMW_NAMES = {
    'history': ['system_default', 'keep_last', 'keep_all', 'unknown'],
    'reliability': ['system_default', 'reliable', 'best_effort', 'unknown', 'best_available'],
    'durability': ['system_default', 'transient_local', 'volatile', 'unknown',
                   'best_available'],
    'liveliness': ['system_default', 'automatic', None, 'manual_by_topic', 'unknown',
                   'best_available'],
}


def executable(package, name):
    return os.path.join(ament_index.get_package_prefix(package), 'lib', package, name)


def static_transform():
    transform = TransformStamped()
    transform.header.frame_id, transform.child_frame_id = 'base_link', 'camera_link'
    transform.transform.translation.z = 1.25
    transform.transform.rotation.w = 1.0
    return TFMessage(transforms=[transform])


def record_short_graph(ros_processes, node, bag, late_volatile_belief=False):
    """Record a latched /abp/belief and /tf_static (published before the recorder starts),
    a volatile reliable /abp/executed_action and a best-effort /camera/camera_info, from
    this test's node; the publishers are gone when this returns. With
    `late_volatile_belief`, a volatile /abp/belief publisher joins once the recorder
    subscribed transient local: the recorder must say it cannot record it."""
    publishers = [
        node.create_publisher(Belief, names.BELIEF, qos.LATCHED),
        node.create_publisher(TFMessage, '/tf_static', qos.LATCHED),
        node.create_publisher(ExecutedAction, names.EXECUTED_ACTION, qos.RELIABLE),
        node.create_publisher(CameraInfo, names.CAMERA_INFO, qos.SENSOR_DATA),
    ]
    publishers[0].publish(Belief(step=7, object_ids=['cube-a'], probabilities=[0.9]))
    publishers[1].publish(static_transform())
    recorder = ros_processes.start([
        executable('abp_bringup', 'bag_recorder'), '--ros-args', '-p', f'output:={bag}',
        '-p', f"topics:=[{', '.join(RECORDED)}]"])
    # The latched messages reach the bag although they were sent before the recorder
    # existed: it subscribed transient local because their publishers offer it.
    ros_processes.wait_for_lines(recorder, [
        'first message on /abp/belief', 'first message on /tf_static',
        'publisher matched on /abp/executed_action',
        'publisher matched on /camera/camera_info'], 60)
    publishers[2].publish(ExecutedAction(action='PUSH', sequence=1, success=True))
    ros_processes.wait_for_line(recorder, 'first message on /abp/executed_action', 30)
    if late_volatile_belief:
        publishers.append(node.create_publisher(Belief, names.BELIEF, qos.RELIABLE))
        ros_processes.wait_for_line(
            recorder, 'a publisher on /abp/belief offers a QoS the recording subscription '
            'cannot match (DURABILITY)', 30)
    os.killpg(recorder.pid, signal.SIGINT)
    assert recorder.wait(timeout=20) == 0
    for publisher in publishers:
        node.destroy_publisher(publisher)


def qos_by_topic(metadata):
    return {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
            for t in metadata['rosbag2_bagfile_information']['topics_with_message_count']}


def as_version_9(profile_v8):
    """A version-8 profile (rmw's integers) with the policies spelled as version 9 does."""
    return {key: RMW_NAMES[key][value] if key in RMW_NAMES else value
            for key, value in profile_v8.items()}


def test_recorded_bag_carries_the_offered_qos_as_rosbag2_jazzy_writes_it(
        ros_processes, tester, tmp_path):
    node, _ = tester
    bag = tmp_path / 'graph'
    record_short_graph(ros_processes, node, bag, late_volatile_belief=True)

    # (a) every topic has its publisher's profile; latched ones are transient local.
    metadata = yaml.safe_load((bag / 'metadata.yaml').read_text())
    recorded = qos_by_topic(metadata)
    assert set(recorded) == {'/abp/belief', '/tf_static', '/abp/executed_action',
                             '/camera/camera_info'}
    assert all(len(profiles) == 1 for profiles in recorded.values()), recorded
    policies = {topic: (p[0]['reliability'], p[0]['durability'])
                for topic, p in recorded.items()}
    assert policies == {'/abp/belief': ('reliable', 'transient_local'),
                        '/tf_static': ('reliable', 'transient_local'),
                        '/abp/executed_action': ('reliable', 'volatile'),
                        '/camera/camera_info': ('best_effort', 'volatile')}
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in metadata['rosbag2_bagfile_information']['topics_with_message_count']}
    assert counts['/abp/belief'] == counts['/tf_static'] == counts['/abp/executed_action'] == 1
    # The MCAP channels (what `ros2 bag play` of an MCAP bag reads) carry the same.
    in_storage = offered_qos(bag)
    assert in_storage['/tf_static'][0].durability == QosDurability.TRANSIENT_LOCAL
    assert in_storage['/camera/camera_info'][0].reliability == QosReliability.BEST_EFFORT

    # (b) the layout and spellings of a metadata.yaml rosbag2 wrote (version 8 there:
    # resources/README.md), taken to version 9 by rosbag2 Jazzy's two rules.
    reference = yaml.safe_load(ROSBAG2_METADATA.read_text())['rosbag2_bagfile_information']
    ours = metadata['rosbag2_bagfile_information']
    assert ours['version'] == 9 and reference['version'] == 8
    assert set(ours) == set(reference)
    assert set(ours['topics_with_message_count'][0]) == \
        set(reference['topics_with_message_count'][0])
    reference_topics = {t['topic_metadata']['name']: t['topic_metadata']
                        for t in reference['topics_with_message_count']}
    for topic in ours['topics_with_message_count']:
        assert set(topic['topic_metadata']) == set(reference_topics['/test_topic1'])
    rosbag2_profiles = {name: [as_version_9(p) for p in yaml.safe_load(t['offered_qos_profiles'])]
                        for name, t in reference_topics.items()}
    # A default publisher (reliable, volatile) and a transient-local one, as DDS reported
    # them to rosbag2 and to abp's recorder: the same keys, nesting, values and spellings.
    assert recorded['/abp/executed_action'] == rosbag2_profiles['/test_topic1']
    assert recorded['/abp/belief'] == rosbag2_profiles['/test_service1/_service_event']
    assert recorded['/tf_static'] == rosbag2_profiles['/test_service1/_service_event']
    best_effort = dict(rosbag2_profiles['/test_topic1'][0], reliability='best_effort')
    assert recorded['/camera/camera_info'] == [best_effort]


def test_player_replays_a_latched_topic_to_a_late_subscriber(ros_processes, tester, spin,
                                                             tmp_path):
    node, executor = tester
    bag = tmp_path / 'graph'
    record_short_graph(ros_processes, node, bag)

    player = ros_processes.start([executable('abp_bringup', 'bag_player'), str(bag), '--hold'])
    lines = ''.join(ros_processes.wait_for_line(player, 'holding the publishers', 60))
    assert '/abp/belief: recorded QoS (reliable, transient_local)' in lines
    assert '/tf_static: recorded QoS (reliable, transient_local)' in lines
    # The player has published everything; only now subscribe, once the recording's own
    # publishers are gone, so that only the player can answer.
    assert spin(executor, lambda: [p.node_name for p in node.get_publishers_info_by_topic(
        '/abp/belief')] == ['bag_player'], 30)
    beliefs, transforms = [], []
    node.create_subscription(Belief, names.BELIEF, beliefs.append, qos.LATCHED)
    node.create_subscription(TFMessage, '/tf_static', transforms.append, qos.LATCHED)
    assert spin(executor, lambda: beliefs and transforms, 30), (beliefs, transforms)
    assert beliefs[-1].step == 7 and list(beliefs[-1].object_ids) == ['cube-a']
    assert transforms[-1].transforms[0].child_frame_id == 'camera_link'
    assert transforms[-1].transforms[0].transform.translation.z == pytest.approx(1.25)


def test_a_bag_without_qos_is_replayed_with_the_graphs_qos_and_says_so(
        ros_processes, tester, spin, tmp_path):
    """A bag of before QoS was stored: the player falls back to the graph's QoS (latched
    for /abp/belief) and says so; /tf_static, latched for no graph rule, is replayed
    volatile, which a transient-local subscriber cannot match: the failure stored QoS
    prevents."""
    bag = tmp_path / 'old'
    writer = BagWriter(bag, {'/abp/belief': 'abp_msgs/msg/Belief',
                             '/tf_static': 'tf2_msgs/msg/TFMessage'}, add_all=True)
    writer.write('/abp/belief', 1, serialize_message(Belief(step=3)))
    writer.write('/tf_static', 2, serialize_message(static_transform()))
    writer.close()
    assert offered_qos(bag) == {'/abp/belief': [], '/tf_static': []}
    assert [m[0] for m in read_bag(bag)] == ['/abp/belief', '/tf_static']

    player = ros_processes.start([executable('abp_bringup', 'bag_player'), str(bag), '--hold'])
    lines = ''.join(ros_processes.wait_for_line(player, 'holding the publishers', 60))
    assert ('/abp/belief: the bag stores no QoS for it (recorded before abp stored QoS); '
            "replaying with the graph's QoS (reliable, transient_local)") in lines
    assert "/tf_static: the bag stores no QoS for it (recorded before abp stored QoS); " \
        "replaying with the graph's QoS (reliable, volatile)" in lines
    node, executor = tester
    beliefs, transforms, incompatible = [], [], []
    node.create_subscription(Belief, names.BELIEF, beliefs.append, qos.LATCHED)
    node.create_subscription(
        TFMessage, '/tf_static', transforms.append, qos.LATCHED,
        event_callbacks=SubscriptionEventCallbacks(incompatible_qos=incompatible.append))
    assert spin(executor, lambda: beliefs and incompatible, 30), (beliefs, incompatible)
    assert beliefs[-1].step == 3
    assert incompatible[0].last_policy_kind == QoSPolicyKind.DURABILITY
    assert transforms == []


# The adaptive QoS rules, without DDS.

def offer(reliability, durability):
    return bag_qos.profile('unknown', 0, reliability, durability, bag_qos.INFINITE_NS,
                           bag_qos.INFINITE_NS, 'automatic', bag_qos.INFINITE_NS)


def test_recording_matches_every_publisher():
    latched = offer('reliable', 'transient_local')
    assert bag_qos.recording_request('/t', [latched, latched])[:2] == (True, True)
    reliable, transient_local, warnings = bag_qos.recording_request(
        '/t', [latched, offer('best_effort', 'volatile')])
    assert (reliable, transient_local) == (False, False)
    assert len(warnings) == 2 and 'not all, publishers on /t are transient local' in warnings[1]


def test_replay_offers_the_recorded_profile_only_when_the_publishers_agree():
    latched, volatile = offer('reliable', 'transient_local'), offer('reliable', 'volatile')
    assert bag_qos.playback_offer([latched, latched]) == latched
    assert bag_qos.playback_offer([latched, volatile]) is None
    assert bag_qos.playback_offer([]) is None
    # Durations as bags of older distros stored "infinite".
    assert bag_qos.nanoseconds(bag_qos.QosTime(0x7FFFFFFF, 0xFFFFFFFF)) == bag_qos.INFINITE_NS
    assert bag_qos.qos_time(bag_qos.INFINITE_NS) == (9223372036, 854775807)
