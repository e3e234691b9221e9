"""The skill servers against the real sim bridge and perception, over DDS.

Each skill runs on cubes with different hidden masses; the sim bridge's physics
(from the hands' real motion) decides the outcome, and its ground truth (read
here by the test only) must change as docs/MODEL.md says: PUSH slides a
uniform cube and pivots a laterally weighted one, LIFT turns a top-heavy cube
over, FLIP rolls a uniform cube, and ORBIT(theta) changes the relative yaw by
theta. The cube pose estimate the skills act on comes from the real
artag_detector and aspect_matcher on the rendered camera images.
"""

import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from action_msgs.msg import GoalStatus, GoalStatusArray  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import qos_profile_action_status_default  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from trajectory_msgs.msg import JointTrajectory  # noqa: E402

from abp_common.qos import LATCHED, RELIABLE  # noqa: E402
from abp_common.server_handshake import wait_until_answering  # noqa: E402
from abp_description.controllers import BODY_JOINTS, CONTROLLERS  # noqa: E402
from abp_description.kinematics import RobotKinematics  # noqa: E402
from abp_msgs.action import Flip, Lift, Orbit, Push  # noqa: E402
from abp_msgs.msg import AspectObservation, SimGroundTruth  # noqa: E402
from abp_msgs.srv import CheckFeasibility  # noqa: E402

FACE_TAGS = '[0, 1, 2, 3, 4, 5]'  # body faces +x -x +y -y +z -z
# mass index: 0 uniform, 1 + body face (docs/MODEL.md)
UNIFORM, HEAVY_PLUS_Y, HEAVY_TOP = 0, 3, 5


def executable(package, name):
    return os.path.join(ament_index.get_package_prefix(package), 'lib', package, name)


@pytest.fixture
def sim_graph(ros_processes, rclpy_context):
    """Start the sim bridge (given hidden mass), perception and the skill servers."""
    node = rclpy.create_node('skills_in_sim_tester', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    truth = []
    estimates = []
    node.create_subscription(SimGroundTruth, '/abp/sim/ground_truth', truth.append, LATCHED)
    node.create_subscription(AspectObservation, '/abp/aspect_observation',
                             lambda m: m.hypotheses and estimates.append(m), RELIABLE)

    def start(mass_index, speedup=5.0):
        sim_time = ['-p', 'use_sim_time:=true']
        ros_processes.start([executable('abp_sim_bridge', 'sim_bridge'), '--ros-args',
                             '-p', 'world:=rules', '-p', f'face_tags:={FACE_TAGS}',
                             '-p', f'mass_index:={mass_index}',
                             '-p', f'speedup:={speedup}',
                             # Body +x towards the robot: the initial state is (up 4, yaw 0).
                             '-p', 'cube_yaw:=3.141592653589793'])
        ros_processes.start([executable('abp_perception', 'artag_detector'), '--ros-args',
                             *sim_time])
        ros_processes.start([executable('abp_perception', 'aspect_matcher'), '--ros-args',
                             *sim_time])
        # These tests check what the cube and the views do (45 deg steps); the ORBIT's
        # end precision is the node tests' business. On a starved machine the base can
        # settle 2.1 deg off, just outside the 2 deg default, so allow 5 deg here.
        # A trajectory is stamped 0.25 s of wall time ahead; a skill server starved for
        # 1.8 s (seen with load 7 on 2 cores) has it arrive 9 s of simulation time late
        # at speed-up 5, after its end: the joints then catch up from where they are,
        # which the default 2 s settle_timeout (simulation time) does not leave room for.
        ros_processes.start([executable('abp_skills', 'skill_servers'), '--ros-args',
                             *sim_time, '-p', 'orbit_yaw_tolerance_deg:=5.0',
                             '-p', 'state_wait_timeout:=30.0', '-p', 'settle_timeout:=15.0'])
        return node, executor, truth, estimates

    yield start
    executor.shutdown()
    node.destroy_node()


def run_skill(node, executor, spin, action_type, name, goal):
    client = ActionClient(node, action_type, f'/abp/skills/{name}')
    assert wait_until_answering(client, lambda done, s: spin(executor, done, s), 60), \
        f'no /abp/skills/{name} server'
    send = client.send_goal_async(goal)
    assert spin(executor, send.done, 30)
    handle = send.result()
    assert handle.accepted
    result = handle.get_result_async()
    assert spin(executor, result.done, 180), f'{name} did not finish'
    client.destroy()
    return result.result().result


def server_sees_the_cube(node, executor, spin, timeout=60.0):
    """Ask the feasibility service until the skill server has a recent cube estimate: its
    subscription can match the matcher's publisher later than this node's does."""
    client = node.create_client(CheckFeasibility, '/abp/skills/check_feasibility')
    assert spin(executor, client.service_is_ready, 60), 'no feasibility service'
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            future = client.call_async(CheckFeasibility.Request(actions=['ORBIT_P90']))
            if not spin(executor, future.done, 3.0):   # a lost answer: ask again
                client.remove_pending_request(future)
                continue
            reason = future.result().reasons[0]
            if 'cube pose estimate' not in reason:
                return
            spin(executor, lambda: False, 0.2)
        raise AssertionError(f'the skill server has no recent cube estimate: {reason}')
    finally:
        node.destroy_client(client)


def settled_truth(node, executor, spin, truth, estimates):
    """Latest ground truth once a fresh cube estimate exists (skills need one)."""
    count = len(estimates)
    assert spin(executor, lambda: len(estimates) > count + 2, 60), 'no aspect observations'
    server_sees_the_cube(node, executor, spin)
    assert spin(executor, lambda: truth, 30), 'no ground truth from the sim bridge'
    return truth[-1]


def truth_after(executor, spin, truth, sim_seconds=2.0):
    """The ground truth `sim_seconds` of simulation time on (it comes at 5 Hz of sim time):
    the cube has settled after a skill, whatever the machine's load."""
    count = len(truth)
    assert spin(executor, lambda: len(truth) >= count + round(5 * sim_seconds), 60), \
        'the ground truth stopped'
    return truth[-1]


@pytest.mark.parametrize('mass, expected_yaw_change', [
    (UNIFORM, 0),        # slides: no aspect change
    (HEAVY_PLUS_Y, -1),  # the heavy +y side drags: yaw -= 1 (MODEL.md)
])
def test_push_slides_or_pivots_as_the_mass_dictates(sim_graph, spin, mass,
                                                    expected_yaw_change):
    node, executor, truth, estimates = sim_graph(mass)
    before = settled_truth(node, executor, spin, truth, estimates)
    assert (before.up_face, before.yaw_step) == (4, 0)
    result = run_skill(node, executor, spin, Push, 'push', Push.Goal(face='front'))
    assert result.success, result.reason
    after = truth_after(executor, spin, truth)
    assert after.up_face == before.up_face
    assert after.yaw_step == (before.yaw_step + expected_yaw_change) % 8
    assert after.manual_actions == before.manual_actions + 1


def test_lift_turns_a_top_heavy_cube_over(sim_graph, spin):
    node, executor, truth, estimates = sim_graph(HEAVY_TOP)
    before = settled_truth(node, executor, spin, truth, estimates)
    assert before.up_face == 4
    result = run_skill(node, executor, spin, Lift, 'lift', Lift.Goal())
    assert result.success, result.reason
    # 180 degrees about the hand axis: the mass ends down.
    assert truth_after(executor, spin, truth).up_face == 5


def test_flip_rolls_a_uniform_cube_and_orbit_turns_the_view(sim_graph, spin):
    node, executor, truth, estimates = sim_graph(UNIFORM)
    before = settled_truth(node, executor, spin, truth, estimates)
    result = run_skill(node, executor, spin, Flip, 'flip', Flip.Goal())
    assert result.success, result.reason
    # The front face (+x) goes to the top.
    assert truth_after(executor, spin, truth).up_face == 0

    before = settled_truth(node, executor, spin, truth, estimates)
    result = run_skill(node, executor, spin, Orbit, 'orbit', Orbit.Goal(angle_deg=90.0))
    assert result.success, result.reason
    after = truth_after(executor, spin, truth)
    assert after.up_face == before.up_face
    assert after.yaw_step == (before.yaw_step + 2) % 8


def test_a_cancelled_skill_holds_every_joint_within_0_3_s_of_sim_time(sim_graph, spin):
    """A LIFT cancelled while its arms move: every joint the controllers drive comes to
    rest for good soon after the cancel was sent (how soon is printed; the goal is 0.3 s
    of sim time). The sim bridge's controllers behave as Jazzy's (a trajectory without
    points is refused; a cancelled goal holds where the joints are); the skills reach
    them by FollowJointTrajectory and stop them by cancelling their goals. Real time
    (speed-up 1), as on a robot."""
    node, executor, truth, estimates = sim_graph(UNIFORM, speedup=1.0)
    states, sizes, statuses = [], [], []
    node.create_subscription(JointState, '/joint_states', states.append, RELIABLE)
    for controller in CONTROLLERS:
        node.create_subscription(JointTrajectory, f'/{controller}/joint_trajectory',
                                 lambda m: sizes.append(len(m.points)), RELIABLE)
        node.create_subscription(
            GoalStatusArray, f'/{controller}/follow_joint_trajectory/_action/status',
            lambda m: statuses.extend(m.status_list), qos_profile_action_status_default)
    settled_truth(node, executor, spin, truth, estimates)
    client = ActionClient(node, Lift, '/abp/skills/lift')
    assert wait_until_answering(client, lambda done, s: spin(executor, done, s), 60)
    feedback = []
    send = client.send_goal_async(Lift.Goal(), feedback_callback=lambda f: feedback.append(
        f.feedback))
    assert spin(executor, send.done, 30) and send.result().accepted
    body = [RobotKinematics().joint_index(j) for j in BODY_JOINTS]

    def moving():
        return states and np.max(np.abs(np.asarray(states[-1].velocity)[body])) > 0.05
    assert spin(executor, lambda: any(f.phase != 'approach' for f in feedback) and moving(),
                60), 'the arms never moved'
    cancel_sent = stamp_s(states[-1])   # what this node has seen: the sim is not earlier
    handle = send.result()
    cancel = handle.cancel_goal_async()
    result = handle.get_result_async()
    assert spin(executor, lambda: cancel.done() and result.done(), 30)
    assert result.result().status == GoalStatus.STATUS_CANCELED
    # Still for good from some time after the cancel. How soon is a latency, measured
    # here and printed (docs/BENCHMARKS.md: the goal is 0.3 s of sim time), not asserted
    # tightly: on a starved machine the processes' reaction takes longer in wall time,
    # which at speed-up 1 is sim time too. The bound only rules out a stop that never
    # comes (the old empty trajectory, which the controller refuses).
    assert spin(executor, lambda: stamp_s(states[-1]) > cancel_sent + HOLD_BOUND_S + 1.5, 30)
    stamps = np.array([stamp_s(m) for m in states])
    positions = np.array([np.asarray(m.position)[body] for m in states])
    changed = np.flatnonzero(np.any(np.abs(positions - positions[-1]) > 1e-6, axis=1))
    held_at = stamps[changed[-1] + 1] if len(changed) else stamps[0]
    print(f'joints held {held_at - cancel_sent:.3f} s of sim time after the cancel was sent')
    assert held_at - cancel_sent <= HOLD_BOUND_S, \
        f'joints still moving {held_at - cancel_sent:.2f} s after the cancel'
    assert statuses, 'the skills did not use FollowJointTrajectory'
    # The stop went by cancel (the goals ran); nothing without points on the topics.
    assert 0 not in sizes, f'a trajectory without points was sent: {sizes}'


HOLD_BOUND_S = 2.0


def stamp_s(msg):
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
