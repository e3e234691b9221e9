"""Record a recognition episode to a rosbag2 MCAP bag and replay it, over real DDS.

The episode runs the real belief and planner nodes against the model-sampled
world (tests/helpers/model_world_node.py), driven by the `recognize` client;
the `bag_recorder` writes it. Replaying the recorded observations and executed
actions into a fresh belief node reproduces the recorded identification.
"""

import json
import os
import pathlib
import signal
import subprocess
import sys

import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from abp_belief.population import robot_set  # noqa: E402
from abp_bringup.bag import (  # noqa: E402
    BagError,
    BagWriter,
    bag_topics,
    deserialize,
    offered_qos,
    read_bag,
    typestore,
)
from abp_common import names, qos  # noqa: E402
from abp_msgs.msg import Belief  # noqa: E402

REPO = pathlib.Path(__file__).resolve().parents[2]
WORLD = REPO / 'tests' / 'helpers' / 'model_world_node.py'
SEED = 5
TRUE_MODEL = 9


def executable(package, name):
    return os.path.join(ament_index.get_package_prefix(package), 'lib', package, name)


def model_params():
    return ['--ros-args', '-p', 'model_set:=robot', '-p', f'seed:={SEED}']


def stamp_ns(message):
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def write_episode_after_reset(recorded, path, profiles):
    """Write to a new bag at `path` the recorded episode from the belief's reset on: the
    aspect observations stamped after the last step-0 belief before the first executed
    action, and every executed action, with their recorded QoS `profiles`. Returns the
    message count per topic."""
    store = typestore()
    first_action = next(t for topic, _, t, _ in recorded if topic == '/abp/executed_action')
    resets = [deserialize(store, data, msgtype) for topic, msgtype, t, data in recorded
              if topic == '/abp/belief' and t < first_action]
    reset_ns = stamp_ns([b for b in resets if b.step == 0][-1])
    topics = {'/abp/aspect_observation': 'abp_msgs/msg/AspectObservation',
              '/abp/executed_action': 'abp_msgs/msg/ExecutedAction'}
    writer = BagWriter(path, topics, store=store,
                       offered_qos={t: profiles[t] for t in topics})
    counts = dict.fromkeys(topics, 0)
    for topic, msgtype, timestamp, data in recorded:
        if topic not in topics or (topic == '/abp/aspect_observation' and stamp_ns(
                deserialize(store, data, msgtype)) <= reset_ns):
            continue
        writer.write(topic, timestamp, data)
        counts[topic] += 1
    writer.close()
    return counts


def test_record_then_replay_reproduces_the_identification(ros_processes, rclpy_context, spin,
                                                          tmp_path):
    bag = tmp_path / 'episode'
    ros_processes.start([executable('abp_belief', 'belief'), *model_params()])
    ros_processes.start([executable('abp_planner', 'planner'), *model_params()])
    world = ros_processes.start([sys.executable, str(WORLD), 'robot', str(SEED),
                                 str(TRUE_MODEL)])
    recorder = ros_processes.start([executable('abp_bringup', 'bag_recorder'), '--ros-args',
                                    '-p', f'output:={bag}'])
    ros_processes.wait_for_line(world, 'READY', timeout=30)
    # Start the episode only once the recorder hears both inputs the replay needs and has
    # matched the planner's publishers of the volatile topics it writes during the
    # episode (messages published before the match are not recorded).
    ros_processes.wait_for_lines(recorder, [
        'first message on /abp/aspect_observation', 'first message on /abp/belief',
        'publisher matched on /abp/executed_action', 'publisher matched on /abp/plan'], 60)

    result_file = tmp_path / 'result.json'
    client = subprocess.run([executable('abp_bringup', 'recognize'), '--threshold', '0.99',
                             '--result-json', str(result_file)],
                            capture_output=True, text=True, timeout=180)
    assert client.returncode == 0, client.stdout + client.stderr
    assert 'plan ' in client.stdout and 'belief ' in client.stdout  # the readable trace
    result = json.loads(result_file.read_text())
    truth = robot_set(seed=SEED).names[TRUE_MODEL]
    assert result['object_id'] == truth and result['posterior'] >= 0.99

    os.killpg(recorder.pid, signal.SIGINT)
    assert recorder.wait(timeout=20) == 0
    topics = bag_topics(bag)
    assert topics['/abp/belief'] == 'abp_msgs/msg/Belief'
    assert (bag / 'metadata.yaml').read_text().count('storage_identifier: mcap') == 1
    recorded = list(read_bag(bag))
    counts = {t: sum(1 for m in recorded if m[0] == t) for t in topics}
    assert counts['/abp/executed_action'] == result['actions']
    assert counts['/abp/plan'] == result['actions']
    store = typestore()
    last_belief = deserialize(store, [m for m in recorded if m[0] == '/abp/belief'][-1][3],
                              'abp_msgs/msg/Belief')
    assert last_belief.object_ids[0] == truth

    # The bag begins before the episode: the planner reset the belief after the first
    # frames were recorded, and a reset is a service call, not a recorded topic. The world
    # samples each frame's observation afresh, so a replay that corrected with a frame of
    # before the reset would use other evidence than the live run did. Replay the episode
    # only: the frames stamped after the reset belief (stamped with the newest input the
    # belief node had taken) and the executed actions.
    episode = tmp_path / 'episode-after-reset'
    profiles = offered_qos(bag)
    assert all(profiles[t] for t in topics), profiles  # every recorded topic has its QoS
    replayed = write_episode_after_reset(recorded, episode, profiles)
    assert offered_qos(episode)['/abp/executed_action'] == profiles['/abp/executed_action']
    assert replayed['/abp/executed_action'] == result['actions']

    # Replay observations and actions into a fresh belief node at the recorded pace.
    # With --fast, a belief node that falls behind holds both topics in its queues and
    # takes them alternately, out of their recorded order (DDS orders within a topic
    # only): an action can then overtake the frames that preceded it.
    ros_processes.stop_all()
    replay_belief = ros_processes.start([executable('abp_belief', 'belief'), *model_params()])
    node = rclpy.create_node('replay_checker', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    beliefs = []
    node.create_subscription(Belief, names.BELIEF, beliefs.append, qos.LATCHED)
    assert spin(executor, lambda: beliefs, 30)
    player = subprocess.run(
        [executable('abp_bringup', 'bag_player'), str(episode), '--rate', '1', '--topics',
         '/abp/aspect_observation', '/abp/executed_action', '--wait-for',
         '/abp/aspect_observation', '/abp/executed_action'],
        capture_output=True, text=True, timeout=120)
    assert player.returncode == 0, player.stderr
    assert spin(executor, lambda: beliefs[-1].step >= last_belief.step, 20), \
        (beliefs[-1].step, last_belief.step)
    spin(executor, lambda: False, 0.5)
    assert beliefs[-1].object_ids[0] == truth
    assert beliefs[-1].probabilities[0] == pytest.approx(last_belief.probabilities[0], abs=0.02)
    assert replay_belief.poll() is None
    executor.shutdown()
    node.destroy_node()


def test_bad_bags_are_refused_clearly(tmp_path):
    with pytest.raises(BagError, match='does not exist'):
        bag_topics(tmp_path / 'missing')
    broken = tmp_path / 'broken'
    broken.mkdir()
    (broken / 'metadata.yaml').write_text('rosbag2_bagfile_information: {version: 9')
    with pytest.raises(BagError, match='cannot read bag'):
        bag_topics(broken)
    player = subprocess.run([executable('abp_bringup', 'bag_player'), str(tmp_path / 'missing')],
                            capture_output=True, text=True, timeout=60)
    assert player.returncode == 2 and 'does not exist' in player.stderr
    existing = tmp_path / 'exists'
    existing.mkdir()
    recorder = subprocess.run([executable('abp_bringup', 'bag_recorder'), '--ros-args', '-p',
                               f'output:={existing}'], capture_output=True, text=True, timeout=60)
    assert recorder.returncode == 2 and 'already exists' in recorder.stderr


def test_recorder_under_a_namespace_records_its_absolute_topics(ros_processes, rclpy_context,
                                                                 spin, tmp_path):
    bag = tmp_path / 'ns'
    node = rclpy.create_node('namespace_checker', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    # A belief under /robot1 and one at the root: the recorder records only its own.
    node.create_publisher(Belief, '/robot1/abp/belief', qos.LATCHED).publish(Belief(step=4))
    node.create_publisher(Belief, '/abp/belief', qos.LATCHED).publish(Belief(step=5))
    recorder = ros_processes.start([executable('abp_bringup', 'bag_recorder'), '--ros-args',
                                    '-r', '__ns:=/robot1', '-p', f'output:={bag}'])
    ros_processes.wait_for_lines(recorder, ['recording 12 topics',
                                            'first message on /robot1/abp/belief'], 30)
    assert spin(executor, lambda: node.count_subscribers('/robot1/abp/belief') > 0, 30)
    assert node.count_subscribers('/abp/belief') == 0
    os.killpg(recorder.pid, signal.SIGINT)
    assert recorder.wait(timeout=20) == 0
    # Topics no publisher offered are not in the bag (they would have no QoS).
    assert bag_topics(bag) == {'/robot1/abp/belief': 'abp_msgs/msg/Belief'}
    assert offered_qos(bag)['/robot1/abp/belief'][0].durability.name == 'TRANSIENT_LOCAL'
    store = typestore()
    assert [deserialize(store, m[3], m[1]).step for m in read_bag(bag)] == [4]
    executor.shutdown()
    node.destroy_node()
