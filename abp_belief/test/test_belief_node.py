"""The `belief` node over real DDS: observations and executed actions go in, the
published belief equals the plain filter's, reset works, bad parameters are refused."""

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
from abp_common.qos import LATCHED, LATCHED_READER, RELIABLE  # noqa: E402
from abp_msgs.msg import (  # noqa: E402
    AspectHypothesis,
    AspectObservation,
    Belief,
    ExecutedAction,
)
from abp_msgs.srv import ResetBelief  # noqa: E402

SEED = 3


def belief_executable():
    prefix = ament_index.get_package_prefix('abp_belief')
    return os.path.join(prefix, 'lib', 'abp_belief', 'belief')


def observation_msg(z):
    hyp = AspectHypothesis(aspect_type=z[0], slots=list(z[1:]), support=3.0, score=1.0)
    return AspectObservation(hypotheses=[hyp])


@pytest.fixture
def graph(ros_processes, rclpy_context):
    proc = ros_processes.start([belief_executable(), '--ros-args', '-p', 'model_set:=robot',
                                '-p', f'seed:={SEED}', '-p', 'top_k:=30'])
    node = rclpy.create_node('belief_tester', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    beliefs = []
    node.create_subscription(Belief, '/abp/belief', beliefs.append, LATCHED)
    yield proc, node, executor, beliefs
    executor.shutdown()
    node.destroy_node()


def marginal_of(msg, names):
    by_id = dict(zip(msg.object_ids, msg.probabilities))
    return np.array([by_id[name] for name in names])


def test_observation_and_action_update_the_published_belief(graph, spin):
    proc, node, executor, beliefs = graph
    assert spin(executor, lambda: beliefs, 30), 'no initial (latched) belief'
    models = robot_set(seed=SEED)
    reference = BeliefFilter(models)
    initial = beliefs[-1]
    assert initial.step == 0 and initial.total_models == models.num_models == 30
    assert initial.entropy == pytest.approx(np.log2(30))

    obs_pub = node.create_publisher(AspectObservation, '/abp/aspect_observation', RELIABLE)
    act_pub = node.create_publisher(ExecutedAction, '/abp/executed_action', RELIABLE)
    assert spin(executor, lambda: obs_pub.get_subscription_count() > 0
                and act_pub.get_subscription_count() > 0, 20)

    true_model = 7
    z1 = models.aspect_key(models.node_aspect[true_model * STATES_PER_MODEL + 1])
    obs_pub.publish(observation_msg(z1))
    assert spin(executor, lambda: beliefs[-1].step == 1, 10), 'observation not applied'
    reference.correct(z1)
    np.testing.assert_allclose(marginal_of(beliefs[-1], models.names),
                               reference.object_marginal(), atol=1e-12)
    assert beliefs[-1].entropy < initial.entropy
    # The sparse node belief carries everything above the floor, for the planner.
    sparse = np.zeros(models.num_nodes)
    sparse[np.asarray(beliefs[-1].node_indices)] = beliefs[-1].node_probabilities
    live = reference.belief >= beliefs[-1].node_floor * reference.belief.max()
    np.testing.assert_allclose(sparse[live], reference.belief[live], atol=1e-15)
    assert not sparse[~live].any()
    assert beliefs[-1].model_set_id == fingerprint(models)
    assert beliefs[-1].top_nodes[0].probability > 0

    # A second frame of the same view is not new evidence: ignored until an action.
    obs_pub.publish(observation_msg(z1))
    spin(executor, lambda: False, 0.5)
    assert beliefs[-1].step == 1

    orbit = ExecutedAction(action=ExecutedAction.ORBIT_P90, success=True, sequence=1)
    orbit.header.stamp.sec = 100
    act_pub.publish(orbit)
    assert spin(executor, lambda: beliefs[-1].step == 2, 10), 'action not applied'
    reference.predict('ORBIT_P90')
    np.testing.assert_allclose(marginal_of(beliefs[-1], models.names),
                               reference.object_marginal(), atol=1e-12)

    # A frame taken before the action ended shows the old view: ignored.
    stale = observation_msg(z1)
    stale.header.stamp.sec = 99
    obs_pub.publish(stale)
    spin(executor, lambda: False, 0.5)
    assert beliefs[-1].step == 2
    z2 = models.aspect_key(models.node_aspect[true_model * STATES_PER_MODEL + 3])
    fresh = observation_msg(z2)
    fresh.header.stamp.sec = 101
    obs_pub.publish(fresh)
    assert spin(executor, lambda: beliefs[-1].step == 3, 10)
    reference.correct(z2)
    np.testing.assert_allclose(marginal_of(beliefs[-1], models.names),
                               reference.object_marginal(), atol=1e-12)

    # The two topics keep no common order: a frame of the new view that arrives before
    # its action's message is applied right after the action's prediction.
    z3 = models.aspect_key(models.node_aspect[true_model * STATES_PER_MODEL + 5])
    overtaking = observation_msg(z3)
    overtaking.header.stamp.sec = 201
    obs_pub.publish(overtaking)
    spin(executor, lambda: False, 0.5)
    assert beliefs[-1].step == 3
    late_orbit = ExecutedAction(action=ExecutedAction.ORBIT_P90, success=True, sequence=2)
    late_orbit.header.stamp.sec = 200
    act_pub.publish(late_orbit)
    assert spin(executor, lambda: beliefs[-1].step == 5, 10), 'overtaking frame not applied'
    reference.predict('ORBIT_P90')
    reference.correct(z3)
    np.testing.assert_allclose(marginal_of(beliefs[-1], models.names),
                               reference.object_marginal(), atol=1e-12)

    # Bad input is logged and ignored, and the node keeps running.
    act_pub.publish(ExecutedAction(action='DANCE', success=True))
    obs_pub.publish(observation_msg((3, 42, 1, 2)))
    spin(executor, lambda: False, 0.5)
    assert beliefs[-1].step == 5 and proc.poll() is None

    reset = node.create_client(ResetBelief, '/abp/reset_belief')
    assert spin(executor, reset.service_is_ready, 10)
    bad = reset.call_async(ResetBelief.Request(model_prior=[1.0, 2.0]))
    assert spin(executor, bad.done, 10)
    assert not bad.result().success and 'prior' in bad.result().message
    good = reset.call_async(ResetBelief.Request())
    assert spin(executor, good.done, 10) and good.result().success
    assert spin(executor, lambda: beliefs[-1].step == 0, 10)
    assert beliefs[-1].entropy == pytest.approx(np.log2(30))
    # Stamped with the newest input taken (the overtaking frame), not the clock: the next
    # correction carries its frame's stamp, and the topic must not go back in time.
    assert (beliefs[-1].header.stamp.sec, beliefs[-1].header.stamp.nanosec) == (201, 0)


def test_a_restarted_simulation_starts_the_belief_again_and_its_reset_is_not_in_the_future(
        ros_processes, rclpy_context, spin):
    """A clock that goes back before the last action's end starts the belief again (a
    crash-test finding: a respawned sim bridge's frames were dropped as stale and the
    planner waited out its observation timeout). On sim time, the reset belief carries
    the newest input's stamp, but never one after the clock: a restarted simulation's
    clock starts again near 0, and the planner refuses a belief stamped in its future
    (another crash-test finding)."""
    ros_processes.start([belief_executable(), '--ros-args', '-p', 'model_set:=robot',
                         '-p', f'seed:={SEED}', '-p', 'use_sim_time:=true'])
    node = rclpy.create_node('belief_sim_time_tester', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    try:
        beliefs = []
        # A deep reader: the restart's step-0 belief and the correction's step 1 are
        # published back to back, and a depth-1 reader keeps only the second.
        node.create_subscription(Belief, '/abp/belief', beliefs.append, LATCHED_READER)
        clock_pub = node.create_publisher(Clock, '/clock', RELIABLE)
        obs_pub = node.create_publisher(AspectObservation, '/abp/aspect_observation',
                                        RELIABLE)
        action_pub = node.create_publisher(ExecutedAction, '/abp/executed_action', RELIABLE)
        reset = node.create_client(ResetBelief, '/abp/reset_belief')
        assert spin(executor, lambda: beliefs and reset.service_is_ready()
                    and obs_pub.get_subscription_count() > 0
                    and action_pub.get_subscription_count() > 0
                    and clock_pub.get_subscription_count() > 0, 30)

        def publish_clock(sec):
            clock_pub.publish(Clock(clock=rclpy.time.Time(seconds=sec).to_msg()))

        models = robot_set(seed=SEED)
        z = models.aspect_key(models.node_aspect[1])
        publish_clock(100)
        frame = observation_msg(z)
        frame.header.stamp.sec = 100
        obs_pub.publish(frame)
        assert spin(executor, lambda: beliefs[-1].step == 1, 10), 'observation not applied'
        action = ExecutedAction(action='ORBIT_P45', sequence=1, success=True)
        action.header.stamp.sec = 101
        action_pub.publish(action)
        assert spin(executor, lambda: beliefs[-1].step == 2, 10), 'action not applied'

        # The simulation restarts: its clock starts again at 2 s. Frames from the new
        # world are stamped before the last action's end; rather than drop them all as
        # stale until the clock is back at 101 s, the node starts the belief again (as
        # tf2 clears its buffer on a jump back in time) and corrects with them.
        seen = len(beliefs)

        def restarted_and_corrected():
            publish_clock(2)
            new_frame = observation_msg(z)
            new_frame.header.stamp.sec = 2
            obs_pub.publish(new_frame)
            return spin(executor, lambda: beliefs[-1].step == 1, 1.0)

        assert spin(executor, restarted_and_corrected, 20), \
            f'no correction after the clock went back (steps {[b.step for b in beliefs]})'
        assert 0 in [b.step for b in beliefs[seen:]], 'the belief was not started again'

        def reset_stamp():
            # The node takes the restarted clock when its /clock message arrives: ask
            # again (with the clock again) until it has.
            publish_clock(3)
            call = reset.call_async(ResetBelief.Request())
            assert spin(executor, call.done, 10) and call.result().success
            assert spin(executor, lambda: beliefs[-1].step == 0, 10)
            return beliefs[-1].header.stamp.sec

        assert spin(executor, lambda: reset_stamp() <= 3, 20), \
            f'reset belief stamped {beliefs[-1].header.stamp.sec} s on a clock at 3 s'
    finally:
        executor.shutdown()
        node.destroy_node()


@pytest.mark.parametrize('override, expected', [
    ('n_tags:=3', 'n_tags'),
    ('model_set:=bogus', 'model_set'),
    ('p_miss:=0.0', 'p_miss'),
])
def test_bad_parameters_are_refused_clearly(override, expected, main_in_process):
    """The executable's main() in this process (the exit code of a process start-up is
    checked once, in test_sim_bridge_node.py)."""
    from abp_belief.belief_node import main
    code, stderr = main_in_process(main, '-p', override)
    assert code == 2, stderr
    assert 'configuration error' in stderr and expected in stderr
    assert 'Traceback' not in stderr
