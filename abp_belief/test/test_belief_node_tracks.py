"""The `belief` node's object tracks over real DDS (issue 37): one belief per track.

- With one object (the empty track id) /abp/beliefs holds that object's belief, and it
  is the very message /abp/belief carries, with the single-object filter's numbers.
- An observation or an action of track A leaves track B's published belief as it was;
  A's equals A's sequence through the plain filter.
- SceneBelief content: tracks in the order they were made, poses in the observation's
  frame, `visible` for the latest image, actions per object, the model set.
- Reset of one track, of an unknown track (refused, the tracks named), of all; the bound
  on the number of tracks; a clock that went back (a restarted simulation) starts every
  object again.
"""

import os

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

from abp_belief.cube import STATES_PER_MODEL  # noqa: E402
from abp_belief.filter import BeliefFilter  # noqa: E402
from abp_belief.model_file import fingerprint  # noqa: E402
from abp_belief.population import robot_set  # noqa: E402
from abp_common import names  # noqa: E402
from abp_common.qos import LATCHED, RELIABLE  # noqa: E402
from abp_msgs.msg import (  # noqa: E402
    AspectHypothesis,
    AspectObservation,
    Belief,
    ExecutedAction,
    SceneBelief,
)
from abp_msgs.srv import ResetBelief  # noqa: E402

SEED = 3
BASE = 'base_link'   # the uBot-6 profile's base frame


def belief_executable():
    prefix = ament_index.get_package_prefix('abp_belief')
    return os.path.join(prefix, 'lib', 'abp_belief', 'belief')


def observation(z, track='', sec=0, position=None, frame=''):
    hyp = AspectHypothesis(aspect_type=z[0], slots=list(z[1:]), support=3.0, score=1.0)
    msg = AspectObservation(hypotheses=[hyp], track_id=track)
    msg.header.stamp.sec = sec
    msg.header.frame_id = frame
    if position is not None:
        p = msg.cube_pose.position
        p.x, p.y, p.z = position
    return msg


def action(name, track='', sec=0, success=True):
    msg = ExecutedAction(action=name, success=success, track_id=track)
    msg.header.stamp.sec = sec
    return msg


def dense(belief_msg, num_nodes):
    out = np.zeros(num_nodes)
    out[np.asarray(belief_msg.node_indices, dtype=np.int64)] = belief_msg.node_probabilities
    return out


class Graph:
    """The belief node and this test's publishers, subscribers and reset client."""

    def __init__(self, ros_processes, context, spin, *params):
        self.proc = ros_processes.start([
            belief_executable(), '--ros-args', '-p', 'model_set:=robot', '-p', f'seed:={SEED}',
            '-p', 'top_k:=30', '-p', 'node_floor:=0.0', *params])
        self.node = rclpy.create_node('tracks_tester', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._spin = spin
        self.beliefs, self.scenes = [], []
        self.node.create_subscription(Belief, names.BELIEF, self.beliefs.append, LATCHED)
        self.node.create_subscription(SceneBelief, names.BELIEFS, self.scenes.append, LATCHED)
        self.obs_pub = self.node.create_publisher(AspectObservation, names.ASPECT_OBSERVATION,
                                                  RELIABLE)
        self.act_pub = self.node.create_publisher(ExecutedAction, names.EXECUTED_ACTION,
                                                  RELIABLE)
        self.reset_client = self.node.create_client(ResetBelief, names.RESET_BELIEF)
        assert self.spin(lambda: self.beliefs and self.scenes
                         and self.obs_pub.get_subscription_count() > 0
                         and self.act_pub.get_subscription_count() > 0
                         and self.reset_client.service_is_ready(), 30), 'belief node not up'

    def spin(self, predicate, timeout=15):
        return self._spin(self.executor, predicate, timeout)

    def scene_where(self, predicate, timeout=15):
        """The latest SceneBelief once it satisfies `predicate` (by object steps)."""
        assert self.spin(lambda: predicate(self.steps()), timeout), \
            f'scene steps {self.steps()}'
        return self.scenes[-1]

    def steps(self):
        return {o.track_id: o.belief.step for o in self.scenes[-1].objects}

    def reset(self, track_id='', prior=()):
        call = self.reset_client.call_async(ResetBelief.Request(track_id=track_id,
                                                                model_prior=list(prior)))
        assert self.spin(call.done, 15), 'no reply from abp/reset_belief'
        return call.result()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def models():
    return robot_set(seed=SEED)


def aspect(models, model, state):
    return models.aspect_key(models.node_aspect[model * STATES_PER_MODEL + state])


def test_one_object_scene_is_the_single_object_belief(ros_processes, rclpy_context, spin,
                                                      models):
    graph = Graph(ros_processes, rclpy_context, spin)
    try:
        # Before any observation: the prior on /abp/belief, no object on /abp/beliefs.
        assert graph.beliefs[-1].step == 0 and graph.scenes[-1].objects == []
        assert graph.scenes[-1].model_set_id == fingerprint(models)
        reference = BeliefFilter(models)
        assert np.array_equal(dense(graph.beliefs[-1], models.num_nodes), reference.belief)

        z1, z2 = aspect(models, 7, 1), aspect(models, 7, 3)
        graph.obs_pub.publish(observation(z1, sec=10, position=(0.6, 0.1, 0.05)))
        scene = graph.scene_where(lambda steps: steps.get('') == 1)
        graph.act_pub.publish(action('ORBIT_P90', sec=20))
        scene = graph.scene_where(lambda steps: steps.get('') == 2)
        graph.obs_pub.publish(observation(z2, sec=21))
        scene = graph.scene_where(lambda steps: steps.get('') == 3)
        reference.correct(z1)
        reference.predict('ORBIT_P90')
        reference.correct(z2)
        assert graph.spin(lambda: graph.beliefs[-1].step == 3)

        [only] = scene.objects
        # The very message /abp/belief carries, field for field (not byte for byte: CDR
        # leaves its alignment padding unset, so equal messages may serialize apart).
        assert only.belief == graph.beliefs[-1]
        assert np.array_equal(dense(only.belief, models.num_nodes), reference.belief)
        marginal = dict(zip(only.belief.object_ids, only.belief.probabilities))
        np.testing.assert_array_equal([marginal[n] for n in models.names],
                                      reference.object_marginal())
        assert only.belief.entropy == reference.entropy()
        assert (only.track_id, only.actions_taken, only.visible) == ('', 1, True)
        # The pose of the last fit (the second view had none), in the base frame.
        assert only.pose.header.frame_id == BASE and only.pose.header.stamp.sec == 10
        assert (only.pose.pose.position.x, only.pose.pose.position.y) == (0.6, 0.1)
        assert (scene.header.stamp.sec, only.belief.header.stamp.sec) == (21, 21)
    finally:
        graph.close()


def test_tracks_are_independent_bounded_and_reset_one_by_one(ros_processes, rclpy_context,
                                                             spin, models):
    graph = Graph(ros_processes, rclpy_context, spin, '-p', 'max_tracks:=2')
    try:
        za = [aspect(models, 4, 0), aspect(models, 4, 10)]
        zb = [aspect(models, 21, 5), aspect(models, 21, 17)]
        graph.obs_pub.publish(observation(za[0], 'a', 10, (1.0, 0.0, 0.05)))
        graph.obs_pub.publish(observation(zb[0], 'b', 10, (0.5, -0.5, 0.05), frame=BASE))
        scene = graph.scene_where(lambda steps: steps == {'a': 1, 'b': 1})
        assert [o.track_id for o in scene.objects] == ['a', 'b']
        assert all(o.visible for o in scene.objects)
        b_before = scene.objects[1].belief
        a_alone = BeliefFilter(models)
        a_alone.correct(za[0])
        assert np.array_equal(dense(scene.objects[0].belief, models.num_nodes), a_alone.belief)

        # A is acted on and seen again: B is untouched, A is A's sequence alone.
        graph.act_pub.publish(action('PUSH', 'a', 20))
        graph.obs_pub.publish(observation(za[1], 'a', 21, (1.1, 0.0, 0.05)))
        scene = graph.scene_where(lambda steps: steps == {'a': 3, 'b': 1})
        a_alone.predict('PUSH')
        a_alone.correct(za[1])
        obj_a, obj_b = scene.objects
        assert np.array_equal(dense(obj_a.belief, models.num_nodes), a_alone.belief)
        assert obj_b.belief == b_before
        assert (obj_a.actions_taken, obj_b.actions_taken) == (1, 0)
        assert obj_a.visible and not obj_b.visible   # only A is in the latest image
        assert obj_a.pose.pose.position.x == 1.1 and obj_a.pose.header.stamp.sec == 21
        assert obj_b.pose.pose.position.y == -0.5 and obj_b.pose.header.frame_id == BASE
        assert obj_a.pose.header.frame_id == BASE
        assert graph.beliefs[-1] == obj_a.belief

        # A third track is refused (max_tracks 2); the node goes on. The observations come
        # on one topic, in order: once B's later frame is applied, C's was refused.
        graph.act_pub.publish(action('ORBIT_M45', 'b', 30))
        scene = graph.scene_where(lambda steps: steps == {'a': 3, 'b': 2})
        graph.obs_pub.publish(observation(za[0], 'c', 31))
        graph.obs_pub.publish(observation(zb[1], 'b', 32))
        scene = graph.scene_where(lambda steps: steps == {'a': 3, 'b': 3})
        assert [o.track_id for o in scene.objects] == ['a', 'b']
        assert graph.proc.poll() is None

        # Reset of one track: back to the prior, the other kept.
        b_now = scene.objects[1].belief
        reply = graph.reset('a')
        assert reply.success, reply.message
        scene = graph.scene_where(lambda steps: steps == {'a': 0, 'b': 3})
        assert np.array_equal(dense(scene.objects[0].belief, models.num_nodes),
                              BeliefFilter(models).belief)
        assert scene.objects[0].actions_taken == 0
        assert scene.objects[1].belief == b_now
        assert graph.spin(lambda: graph.beliefs[-1].step == 0)   # /abp/belief: A, reset

        # An unknown track: refused, and the reply names the tracks there are.
        reply = graph.reset('zz')
        assert not reply.success
        assert "no object track 'zz'" in reply.message and "'a', 'b'" in reply.message
        bad = graph.reset('b', prior=[1.0, 2.0])
        assert not bad.success and 'prior' in bad.message

        # Reset of all forgets the tracks, which makes room for C.
        reply = graph.reset()
        assert reply.success, reply.message
        assert graph.spin(lambda: graph.scenes[-1].objects == [])
        graph.obs_pub.publish(observation(za[0], 'c', 40))
        scene = graph.scene_where(lambda steps: steps == {'c': 1})
    finally:
        graph.close()
    # The refused track was logged, saying why and what to do (read once it has ended).
    ros_processes.stop_all()
    assert graph.proc.returncode == 0
    log = ros_processes.transcript(graph.proc)
    assert "(too_many_tracks): new object track 'c' refused: already 2 tracks (max_tracks " \
           "2); reset the belief" in log, log


def test_a_clock_that_went_back_starts_every_objects_belief_again(ros_processes,
                                                                  rclpy_context, spin, models):
    """A frame of track A stamped well before the end of A's last action, on a clock that
    went back (a restarted simulation): the world the tracks described is gone, so every
    track is forgotten and A's frame starts A again from the prior."""
    graph = Graph(ros_processes, rclpy_context, spin, '-p', 'use_sim_time:=true')
    try:
        clock_pub = graph.node.create_publisher(Clock, '/clock', RELIABLE)
        assert graph.spin(lambda: clock_pub.get_subscription_count() > 0, 20)

        def publish_clock(sec):
            clock_pub.publish(Clock(clock=rclpy.time.Time(seconds=sec).to_msg()))

        za, zb = aspect(models, 4, 0), aspect(models, 21, 5)
        publish_clock(100)
        graph.obs_pub.publish(observation(za, 'a', 100))
        graph.obs_pub.publish(observation(zb, 'b', 100))
        graph.act_pub.publish(action('ORBIT_P45', 'a', 101))
        graph.scene_where(lambda steps: steps == {'a': 2, 'b': 1})

        def restarted_and_corrected():
            # The node takes the restarted clock when its /clock message arrives: send the
            # clock and the new world's frame again until it has.
            publish_clock(2)
            graph.obs_pub.publish(observation(za, 'a', 2))
            return graph.spin(lambda: graph.steps() == {'a': 1}, 1.0)

        assert graph.spin(restarted_and_corrected, 20), \
            f'no restart after the clock went back (steps {graph.steps()})'
        alone = BeliefFilter(models)
        alone.correct(za)
        [obj_a] = graph.scenes[-1].objects
        assert np.array_equal(dense(obj_a.belief, models.num_nodes), alone.belief)
        assert obj_a.actions_taken == 0
    finally:
        graph.close()


@pytest.mark.parametrize('value', ['0', '101', 'many'])
def test_a_bad_track_bound_is_refused_clearly(value, main_in_process):
    from abp_belief.belief_node import main
    code, stderr = main_in_process(main, '-p', f'max_tracks:={value}')
    assert code == 2, stderr
    assert 'configuration error' in stderr and 'max_tracks' in stderr
    assert 'Traceback' not in stderr
