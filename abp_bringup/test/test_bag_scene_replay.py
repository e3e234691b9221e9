"""A three-cube scene recorded to a rosbag2 bag and replayed, over real DDS (issue 37).

The real belief node is driven with real AspectObservation and ExecutedAction messages
for three object tracks, sampled from three models' ATGs (one failed action among
them). The real bag recorder (abp_bringup.bag_recorder_node, run in this process so that
the test can wait until it has written each message: a recorder process gives no event
for that) writes the inputs, /abp/belief and /abp/beliefs to an MCAP bag. Then:

- every object's belief rebuilt from the bag (abp_bringup.scene_bag) equals the live
  one, and the plain factored filter's on the same evidence;
- the recorded inputs replayed by bag_player into a fresh belief node rebuild the same
  scene, object by object.
"""

import collections
import os
import subprocess

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402

from abp_belief import cube  # noqa: E402
from abp_belief.factored_belief import FactoredBelief  # noqa: E402
from abp_belief.population import robot_set  # noqa: E402
from abp_bringup.bag import bag_topics, offered_qos, outdated_types  # noqa: E402
from abp_bringup.bag_recorder_node import BagRecorder  # noqa: E402
from abp_bringup.scene_bag import dense_belief, object_beliefs, scene_beliefs  # noqa: E402
from abp_common import names, qos  # noqa: E402
from abp_msgs.msg import (  # noqa: E402
    AspectHypothesis,
    AspectObservation,
    ExecutedAction,
    SceneBelief,
)

SEED = 5
# Track -> (true model, actions on it; a False marks a failed action).
SCENE = {
    'cube_a': (3, [('ORBIT_P90', True), ('PUSH', True), ('FLIP', True)]),
    'cube_b': (12, [('LIFT', False), ('ORBIT_M45', True), ('LIFT', True)]),
    'cube_c': (25, [('FLIP', True), ('ORBIT_180', True), ('PUSH', True)]),
}
INPUTS = (names.ASPECT_OBSERVATION, names.EXECUTED_ACTION)
RECORDED = (*INPUTS, names.BELIEF, names.BELIEFS)


def executable(package, name):
    return os.path.join(ament_index.get_package_prefix(package), 'lib', package, name)


def model_params():
    return ['--ros-args', '-p', 'model_set:=robot', '-p', f'seed:={SEED}']


def episode(models, rng):
    """The scene's inputs in sending order: (track, 'observe', z) and (track, 'act',
    (action, success)). Each cube is seen once, then takes its actions in turn with the
    others', each action followed by a view of that cube."""
    state = {t: model * cube.STATES_PER_MODEL + int(rng.integers(cube.STATES_PER_MODEL))
             for t, (model, _) in SCENE.items()}

    def view(track):
        return (track, 'observe', models.observation.sample(models.node_aspect[state[track]],
                                                            rng))

    inputs = [view(track) for track in SCENE]
    for i in range(max(len(script) for _, script in SCENE.values())):
        for track, (_, script) in SCENE.items():
            name, success = script[i]
            if success:
                nxt, probs = models.successors(cube.ACTIONS.index(name), [state[track]])
                state[track] = int(rng.choice(nxt[0], p=probs[0]))
            inputs += [(track, 'act', (name, success)), view(track)]
    return inputs


def message(track, kind, value, sec):
    if kind == 'observe':
        hyp = AspectHypothesis(aspect_type=value[0], slots=list(value[1:]), support=3.0,
                               score=1.0)
        msg = AspectObservation(hypotheses=[hyp], track_id=track)
        msg.cube_pose.position.x = 0.5 + 0.5 * sorted(SCENE).index(track)
        msg.cube_pose.position.y = sec * 0.01
    else:
        msg = ExecutedAction(action=value[0], success=value[1], track_id=track,
                             reason='' if value[1] else 'grasp lost')
    msg.header.stamp.sec = sec
    return msg


def reference_beliefs(models, inputs):
    """The plain factored filter through the same evidence (each track's gate lets every
    input through: one view after each action, stamped after it)."""
    factored = FactoredBelief(models, SCENE)
    for track, kind, value in inputs:
        if kind == 'observe':
            factored.correct(track, value)
        elif value[1]:
            factored.predict(track, value[0])
    return factored


def test_a_three_cube_scene_recorded_and_replayed_rebuilds_every_objects_belief(
        ros_processes, rclpy_context, spin, tmp_path):
    models = robot_set(seed=SEED)
    inputs = episode(models, np.random.default_rng(SEED))
    bag = tmp_path / 'scene'
    ros_processes.start([executable('abp_belief', 'belief'), *model_params()])
    node = rclpy.create_node('scene_tester', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    recorder = BagRecorder(context=rclpy_context, parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('topics', value=list(RECORDED))])
    executor.add_node(recorder)
    # Every message the recorder writes, per topic, as it writes it (then to the bag).
    written = collections.defaultdict(list)
    write = recorder.writer.write

    def write_and_note(topic, timestamp_ns, data):
        write(topic, timestamp_ns, data)
        written[topic].append(bytes(data))

    recorder.writer.write = write_and_note
    try:
        scenes = []
        node.create_subscription(SceneBelief, names.BELIEFS, scenes.append, qos.LATCHED)
        pubs = {names.ASPECT_OBSERVATION: node.create_publisher(
                    AspectObservation, names.ASPECT_OBSERVATION, qos.RELIABLE),
                names.EXECUTED_ACTION: node.create_publisher(
                    ExecutedAction, names.EXECUTED_ACTION, qos.RELIABLE)}
        # The recorder has subscribed to all four topics and holds the latched prior scene;
        # the belief node and the recorder both take the inputs.
        assert spin(executor, lambda: scenes and written['/abp/beliefs']
                    and all(recorder.writer.added('/' + t) for t in RECORDED)
                    and all(p.get_subscription_count() == 2 for p in pubs.values()), 60), \
            'recorder or belief node not ready'

        steps = dict.fromkeys(SCENE, 0)
        for sec, (track, kind, value) in enumerate(inputs, start=1):
            topic = names.ASPECT_OBSERVATION if kind == 'observe' else names.EXECUTED_ACTION
            count = len(written['/' + topic])
            pubs[topic].publish(message(track, kind, value, sec))
            if kind == 'observe' or value[1]:   # a failed action predicts nothing
                steps[track] += 1

            def applied(track=track):
                last = {o.track_id: o.belief.step for o in scenes[-1].objects}
                return last.get(track) == steps[track]
            # One input at a time, recorded before the next is sent: the bag keeps the
            # order of the two topics.
            assert spin(executor, lambda: applied() and len(written['/' + topic]) > count,
                        20), f'input {sec} ({track} {kind} {value}) not applied and recorded'
        live = scenes[-1]
        assert [o.track_id for o in live.objects] == list(SCENE)
        assert spin(executor, lambda: deserialize_message(
            written['/abp/beliefs'][-1], SceneBelief) == live, 20), 'last scene not recorded'
    finally:
        recorder.close()
        executor.remove_node(recorder)
        recorder.destroy_node()

    # The bag: its topics with their publishers' QoS, and every object's belief in it.
    assert bag_topics(bag) == {'/abp/aspect_observation': 'abp_msgs/msg/AspectObservation',
                               '/abp/executed_action': 'abp_msgs/msg/ExecutedAction',
                               '/abp/belief': 'abp_msgs/msg/Belief',
                               '/abp/beliefs': 'abp_msgs/msg/SceneBelief'}
    assert offered_qos(bag)['/abp/beliefs'][0].durability.name == 'TRANSIENT_LOCAL'
    assert outdated_types(bag) == {}   # recorded with today's definitions
    recorded = object_beliefs(bag)
    reference = reference_beliefs(models, inputs)
    assert list(recorded) == list(SCENE)
    for entry in live.objects:
        rebuilt = recorded[entry.track_id]
        assert np.array_equal(rebuilt.belief, dense_belief(entry.belief))
        # Above the default node floor (1e-12 of the best) the belief is the plain filter's.
        full = reference.belief(entry.track_id)
        kept = full >= 1e-12 * full.max()
        np.testing.assert_allclose(rebuilt.belief[kept], full[kept], rtol=1e-12, atol=0)
        assert not rebuilt.belief[~kept].any()
        assert (rebuilt.step, rebuilt.actions_taken) == (entry.belief.step, entry.actions_taken)
        assert rebuilt.position == (entry.pose.pose.position.x, entry.pose.pose.position.y, 0.0)
        assert rebuilt.visible == entry.visible == (entry.track_id == 'cube_c')
    assert recorded['cube_b'].actions_taken == 2 and recorded['cube_a'].actions_taken == 3
    assert len(list(scene_beliefs(bag))) == len(written['/abp/beliefs'])

    # Replay the recorded inputs into a fresh belief node: the same scene, object by object.
    ros_processes.stop_all()
    ros_processes.start([executable('abp_belief', 'belief'), *model_params()])
    scenes.clear()
    assert spin(executor, lambda: scenes and scenes[-1].objects == [], 30), \
        'fresh belief node not up'
    player = subprocess.run(
        [executable('abp_bringup', 'bag_player'), str(bag), '--rate', '1', '--topics',
         *('/' + t for t in INPUTS), '--wait-for', *('/' + t for t in INPUTS)],
        capture_output=True, text=True, timeout=120)
    assert player.returncode == 0, player.stderr
    assert spin(executor, lambda: scenes[-1] == live, 30), \
        ('replayed scene differs: steps ' +
         str({o.track_id: o.belief.step for o in scenes[-1].objects}) + ' live ' +
         str({o.track_id: o.belief.step for o in live.objects}))
    for entry in scenes[-1].objects:
        assert np.array_equal(dense_belief(entry.belief), recorded[entry.track_id].belief)
    executor.shutdown()
    node.destroy_node()
