"""The `sim_bridge` node over real DDS in the rules world (world:=rules; the MuJoCo world's
DDS test is test_sim_bridge_mujoco.py): base and joint integration, /clock ticks, camera
images that ArUco reads as the ground truth says, and — for each manual action on a mass
variant it turns — the cube state after real hand trajectories, checked against MODEL.md's
physics table (every action on every mass variant: test_rules_world.py, in process); bad
parameters are refused."""

import os
import subprocess
import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from action_msgs.msg import GoalStatus  # noqa: E402
from builtin_interfaces.msg import Duration, Time  # noqa: E402
from control_msgs.action import FollowJointTrajectory  # noqa: E402
from control_msgs.msg import JointTolerance  # noqa: E402
from geometry_msgs.msg import TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState  # noqa: E402
from sim_hand_paths import (  # noqa: E402
    CONTROLLER_JOINTS,
    DlsIK,
    expected_state,
    hand_path,
    view_rotation,
)
from std_srvs.srv import Trigger  # noqa: E402
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402

from abp_common import qos  # noqa: E402
from abp_common.server_handshake import wait_until_answering  # noqa: E402
from abp_description import camera_intrinsics  # noqa: E402
from abp_description.controllers import CONTROLLERS  # noqa: E402
from abp_description.frames import (  # noqa: E402
    base_to_world,
    rotation_from_quaternion,
    wrap_rad,
    yaw_of_quaternion,
)
from abp_description.kinematics import RobotKinematics  # noqa: E402
from abp_msgs.msg import SimGroundTruth  # noqa: E402
from abp_sim_bridge.flat_renderer import visible_faces  # noqa: E402

RELIABLE = qos.reliable(200)  # the tests read whole streams of 50 Hz state
TAGS = [0, 1, 2, 3, 4, 5]


def bridge_executable():
    prefix = ament_index.get_package_prefix('abp_sim_bridge')
    return os.path.join(prefix, 'lib', 'abp_sim_bridge', 'sim_bridge')


def ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def to_time(t_ns):
    return Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def to_duration(seconds):
    t_ns = int(round(seconds * 1e9))
    return Duration(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def pose_matrix(pose):
    out = np.eye(4)
    q = pose.orientation
    out[:3, :3] = rotation_from_quaternion(q.x, q.y, q.z, q.w)
    out[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return out


def yaw_of(q):
    return yaw_of_quaternion(q.x, q.y, q.z, q.w)


class Tester:  # noqa: D101
    __test__ = False

    """A test node on the bridge's topics; messages are collected in lists."""

    def __init__(self, context, topics):
        self.node = rclpy.create_node('sim_bridge_tester', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.msgs = {name: [] for name in topics}
        self.wall = {name: [] for name in topics}
        # The state topics come at up to ~300 a wall second at speed-up 10: a reader of
        # depth 10 (40 ms of them) that this process takes late on a loaded machine
        # loses some, and the tests read every one (a run lost three joint states).
        every_one = qos.reliable(1000)
        spec = {
            'clock': (Clock, '/clock', every_one),
            'joint_states': (JointState, '/joint_states', every_one),
            'odom': (Odometry, '/odom', every_one),
            # Reliable: the bridge publishes its camera reliable (qos.CAMERA_PUBLISHER), and
            # a best-effort reader loses most 921 KB frames on a loaded machine.
            'image': (Image, '/camera/image_raw', qos.reliable(10)),
            'camera_info': (CameraInfo, '/camera/camera_info', qos.reliable(10)),
            'compressed': (CompressedImage, '/camera/image_raw/compressed',
                           qos.reliable(10)),
            'ground_truth': (SimGroundTruth, '/abp/sim/ground_truth', qos.LATCHED),
        }
        for name in topics:
            msg_type, topic, profile = spec[name]
            self.node.create_subscription(msg_type, topic, self._collector(name), profile)

    def _collector(self, name):
        def collect(msg):
            self.msgs[name].append(msg)
            self.wall[name].append(time.monotonic())
        return collect

    def spin_until(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return predicate()

    def spin_for(self, seconds):
        self.spin_until(lambda: False, seconds)

    def last(self, name):
        return self.msgs[name][-1] if self.msgs[name] else None

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def tester_factory(rclpy_context):
    made = []

    def make(*topics):
        tester = Tester(rclpy_context, topics)
        made.append(tester)
        return tester
    yield make
    for tester in made:
        tester.close()


def start_bridge(ros_processes, world, **params):
    """Start the node in `world` (rules or mujoco: each test names its world)."""
    # Every tick's joint state (state_rate = rate): these tests read the state at given
    # simulation times. The default (25 Hz and every image) has its own test.
    params = {'world': world, 'state_rate': 50.0, **params}
    argv = [bridge_executable(), '--ros-args']
    for name, value in params.items():
        argv += ['-p', f'{name}:={value}']
    return ros_processes.start(argv)


def publish_when_matched(tester, publisher, msg, timeout=10):
    assert tester.spin_until(lambda: publisher.get_subscription_count() > 0, timeout), \
        f'nobody subscribes to {publisher.topic_name}'
    publisher.publish(msg)


# -- base, joints and clock ------------------------------------------------------------------

def moving_runs(odom):
    """The runs of consecutive moving odometry messages received, as lists."""
    runs, run = [], []
    for m in odom:
        if m.twist.twist.linear.x != 0.0 or m.twist.twist.angular.z != 0.0:
            run.append(m)
        elif run:
            runs.append(run)
            run = []
    return runs + ([run] if run else [])


def test_base_follows_cmd_vel_and_clock_ticks(ros_processes, tester_factory):
    speedup, tick, cmd_vel_timeout = 4.0, 1 / 50.0, 0.5
    tick_ns = round(tick * 1e9)
    # Every tick's /clock and state (the defaults thin them out: test_state_clock_and_
    # frames_are_thinned_but_each_image_has_its_joint_state), so that the pacing is seen.
    # command_wait 0: the robot's rule alone (the base stops cmd_vel_timeout after the
    # last command); this test commands every 0.2 s, later than the skills' 20 Hz.
    proc = start_bridge(ros_processes, world='rules', speedup=speedup, camera_rate=0.0,
                        clock_max_wall_rate=0.0, state_rate=50.0, command_wait=0.0)
    # A node on /clock alone: the Python executor of a node that also takes /odom and
    # /joint_states falls behind on a loaded machine, and its receipt times with it.
    # How fast simulation time runs against wall time is the pacer's (test_sim_timing.py)
    # and the benchmarks' business: on a loaded machine it is not the node's to assert.
    c = tester_factory('clock')
    assert c.spin_until(lambda: len(c.msgs['clock']) > 20, 30), 'no /clock'
    c.msgs['clock'].clear()
    assert c.spin_until(lambda: len(c.msgs['clock']) > 100, 60), '/clock stopped'
    clocks = np.array([ns(m.clock) for m in c.msgs['clock']])
    # One /clock per 50 Hz tick. The bridge's publishers keep the last 10 messages: a
    # reader starved for longer loses some (a gap of whole ticks), never gets others.
    steps = np.diff(clocks)
    assert np.all(steps > 0), 'simulation time must increase'
    assert np.all(steps % tick_ns == 0), 'one /clock per 50 Hz tick'
    assert np.mean(steps == tick_ns) > 0.5, 'most /clock ticks must arrive'

    t = tester_factory('clock', 'odom', 'joint_states')
    assert t.spin_until(lambda: t.msgs['joint_states'] and t.msgs['odom'], 30)
    joints = t.last('joint_states')
    assert len(joints.name) == len(joints.position) == len(joints.velocity) == 13
    assert set(joints.name) == set(RobotKinematics().joint_names)

    def sim_now():
        return ns(t.last('clock').clock) * 1e-9

    def still_since(sim_s, heading_from=None):
        """The base stands still in the latest odometry, stamped >= `sim_s` (simulation
        time); with `heading_from`, the heading has changed from it (the command arrived).
        Poses, not message counts: a starved reader loses some odometry messages."""
        if not t.msgs['odom']:
            return False
        last = t.msgs['odom'][-1]
        if last.twist.twist.linear.x != 0.0 or last.twist.twist.angular.z != 0.0:
            return False
        if heading_from is not None and abs(yaw_of(last.pose.pose.orientation)
                                            - heading_from) < 1e-9:
            return False
        return ns(last.header.stamp) * 1e-9 >= sim_s

    def describe(sent):
        """What the odometry shows, for a failure message."""
        runs = [(ns(r[0].header.stamp) * 1e-9, ns(r[-1].header.stamp) * 1e-9, len(r))
                for r in moving_runs(t.msgs['odom'])]
        last = ns(t.msgs['odom'][-1].header.stamp) * 1e-9 if t.msgs['odom'] else None
        return (f'last command sent at {sent:.2f} s, moving (from, to, messages): {runs}, '
                f'last odometry at {last} s, /clock at {sim_now():.2f} s')

    def on_the_arc(m, v, w):
        """The odometry pose of `m` is on the arc of (v, w) from the origin, at the
        heading it reached (yaw < pi here): the base followed the command exactly."""
        p = m.pose.pose
        yaw = yaw_of(p.orientation)
        return (p.position.x == pytest.approx(v / w * np.sin(yaw), abs=1e-6)
                and p.position.y == pytest.approx(v / w * (1 - np.cos(yaw)), abs=1e-6))

    # Drive an arc: v = 0.2 m/s, w = 0.3 rad/s, a command every 0.2 s of simulation time
    # (paced on /clock) for 6 s of it. On a loaded machine this node may publish late and
    # the base stop between two commands: what is checked holds whatever the gaps.
    v, w = 0.2, 0.3
    pub = t.node.create_publisher(TwistStamped, '/cmd_vel', 10)
    cmd = TwistStamped()
    cmd.twist.linear.x, cmd.twist.angular.z = v, w
    assert t.spin_until(lambda: pub.get_subscription_count() > 0, 10)
    t.msgs['odom'].clear()
    t.msgs['joint_states'].clear()
    first_sent = next_cmd = sim_now()
    deadline = time.monotonic() + 60
    while sim_now() < first_sent + 6.0:
        assert time.monotonic() < deadline, '/clock stopped'
        if sim_now() >= next_cmd:
            pub.publish(cmd)
            last_sent, next_cmd = sim_now(), sim_now() + 0.2
        t.executor.spin_once(timeout_sec=0.01)
    # The last command arrived at or after `last_sent` (simulation time) and drives the
    # base for cmd_vel_timeout from its receipt; then the base stops by itself.
    assert t.spin_until(lambda: still_since(last_sent + cmd_vel_timeout + 2.0), 60), \
        f'the base did not stop after cmd_vel_timeout: {describe(last_sent)}'
    drive = moving_runs(t.msgs['odom'])
    assert drive, 'the base never moved'
    assert ns(drive[0][0].header.stamp) * 1e-9 >= first_sent + tick - 1e-6
    heading = yaw_of(t.msgs['odom'][-1].pose.pose.orientation)

    # One single command, a turn in place (w_p): the base turns for exactly
    # cmd_vel_timeout of simulation time from its receipt, whenever that is, then stops
    # by itself. The arc's position tells how far the drive turned (even if a late drive
    # command arrives after the wait above), the rest of the heading is the pulse's.
    w_p = 0.6
    pulse = TwistStamped()
    pulse.twist.angular.z = w_p
    pulse_sent = sim_now()
    n_before = len(t.msgs['odom'])

    def turned():
        """The first odometry after the pulse whose heading has changed, or None."""
        return next((m for m in t.msgs['odom'][n_before:]
                     if abs(yaw_of(m.pose.pose.orientation) - heading) > 1e-9), None)
    pub.publish(pulse)
    assert t.spin_until(lambda: turned() is not None, 60), \
        f'the base did not move on a command: {describe(pulse_sent)}'
    moved = ns(turned().header.stamp) * 1e-9   # at most cmd_vel_timeout after it started
    assert t.spin_until(lambda: still_since(moved + cmd_vel_timeout + 1.0), 60), \
        f'the base did not stop after cmd_vel_timeout: {describe(pulse_sent)}'
    final = t.msgs['odom'][-1]
    assert final.twist.twist.linear.x == 0.0 and final.twist.twist.angular.z == 0.0
    assert final.header.frame_id == 'odom' and final.child_frame_id == 'base_link'
    fx, fy = final.pose.pose.position.x, final.pose.pose.position.y
    radius = v / w
    drive_heading = np.arctan2(fx / radius, 1 - fy / radius)   # on the arc: wrapped
    pulse_turn = wrap_rad(yaw_of(final.pose.pose.orientation) - drive_heading)
    assert pulse_turn == pytest.approx(w_p * cmd_vel_timeout, abs=1e-6), \
        'a command drives the base for cmd_vel_timeout'

    odom = t.msgs['odom']
    stamps = np.array([ns(m.header.stamp) for m in odom])
    assert np.all(np.diff(stamps) > 0) and np.all(np.diff(stamps) % tick_ns == 0)
    moving = [m for run in moving_runs(odom) for m in run]
    driving = [m for m in moving if m.twist.twist.linear.x != 0.0]
    turning = [m for m in moving if m.twist.twist.linear.x == 0.0]
    assert all(m.twist.twist.linear.x == pytest.approx(v)
               and m.twist.twist.angular.z == pytest.approx(w) for m in driving)
    assert all(m.twist.twist.angular.z == pytest.approx(w_p) for m in turning)
    # Constant (v, w): whatever the gaps, every pose of the drive is on one arc from the
    # origin (the turn in place comes after it).
    assert all(on_the_arc(m, v, w) for m in driving)
    # The drive's moving time: its heading over w (unwrapped: no fewer than the moving
    # messages received; lost messages only hide some).
    received = len(driving) * tick
    turns = np.ceil((w * received - drive_heading - 1e-6) / (2 * np.pi))
    duration = (drive_heading + 2 * np.pi * turns) / w
    assert received - 1e-6 <= duration
    # The wheels turned as a diff drive: radius 0.1 m, track 0.34 m.
    # `joints` is from before the first command, the last joint state from after the stop.
    js = t.msgs['joint_states'][-1]
    assert ns(js.header.stamp) > ns(final.header.stamp) - 1_000_000_000
    left, right = (js.position[js.name.index(n)] - joints.position[joints.name.index(n)]
                   for n in ('left_wheel_joint', 'right_wheel_joint'))
    spin = w_p * cmd_vel_timeout * 0.17 / 0.1
    assert left == pytest.approx((v - w * 0.17) / 0.1 * duration - spin, abs=1e-6)
    assert right == pytest.approx((v + w * 0.17) / 0.1 * duration + spin, abs=1e-6)
    assert proc.poll() is None


def test_state_clock_and_frames_are_thinned_but_each_image_has_its_joint_state(
        ros_processes, tester_factory):
    """At speed-up 10 (500 ticks per wall second): /clock at most clock_max_wall_rate per
    wall second, joint states and odometry at state_rate of simulation time plus one at
    every image, images at most camera_max_wall_rate per wall second, and every image
    stamp is also the stamp of a joint state (the detector's camera pose at the stamp).

    Frames are read from camera_info, published with each image and its stamp (this
    reader need not take the 921 KB frames). Beside two busy loops, 3 runs in 10 lost a
    joint state or a camera_info while the bridge's writers kept the last 10 (at a 10x
    speed-up ~30 ms of joint states); with STATE_WRITER's 100 for the joint states (and
    camera_info, for that experiment), 10 in 10 lost none. A stall
    longer than that still loses samples (DDS's keep-last contract), so a few may be
    missing; a bridge that left out the image ticks' joint states misses half the frames
    (every other frame is off the 25 Hz grid)."""
    tick_ns, state_ns = 20_000_000, 40_000_000
    start_bridge(ros_processes, world='rules', speedup=10.0, camera_rate=10.0,
                 state_rate=25.0, clock_max_wall_rate=50.0, camera_max_wall_rate=20.0)
    t = tester_factory('clock', 'joint_states', 'odom', 'camera_info')
    assert t.spin_until(lambda: len(t.msgs['camera_info']) >= 2 and t.msgs['joint_states'], 60), \
        'no images or joint states'
    for name in t.msgs:
        t.msgs[name].clear()
        t.wall[name].clear()
    assert t.spin_until(lambda: len(t.msgs['camera_info']) >= 20, 60), 'too few images'
    images = [ns(m.header.stamp) for m in t.msgs['camera_info']]
    joints = [ns(m.header.stamp) for m in t.msgs['joint_states']]
    odom = [ns(m.header.stamp) for m in t.msgs['odom']]
    clocks = np.array([ns(m.clock) for m in t.msgs['clock']])
    # Frames on the camera grid (0.1 s), each with the joint state of its own tick.
    assert all(stamp % 100_000_000 == 0 for stamp in images), images
    # (An image is published after its joint state: the first one may have come before the
    # lists were cleared.)
    missing = sorted(s for s in set(images[:-1]) - set(joints) if s > joints[0])
    assert len(missing) <= len(images) // 5, \
        f'images without the joint state at their stamp: {missing} of {len(images)}'
    assert joints == odom or set(joints[:-2]) <= set(odom), 'odometry with the joint states'
    # Joint states: the 25 Hz grid, plus the image ticks (every 5th 50 Hz tick, on the
    # camera's 0.1 s grid whether or not that frame's camera_info was received).
    off_grid = [s for s in joints if s % state_ns and s % 100_000_000]
    assert not off_grid, f'joint states off the 25 Hz and camera grids: {off_grid}'
    steps = np.diff(joints)
    assert np.all(steps > 0) and np.all(steps % tick_ns == 0)
    # /clock and images: their wall-clock caps (a slack for bursts of late delivery: the
    # sim thread publishes them, this reader may take them in bunches).
    # The sender's wall time is at least the simulated span over the speed-up (the pacer
    # never runs faster); this reader's receipt times can be bunched shorter than that
    # when it took a backlog at once (a clean-clone run: 61 /clock "in 0.8 s" of 1.1 s).
    def sender_wall_s(name, stamps):
        received = t.wall[name][-1] - t.wall[name][0]
        return max(received, (stamps[-1] - stamps[0]) * 1e-9 / 10.0, 1e-9)

    wall_s = sender_wall_s('clock', clocks)
    assert len(clocks) <= 50.0 * wall_s * 1.3 + 5, f'{len(clocks)} /clock in {wall_s:.1f} s'
    assert np.all(np.diff(clocks) > 0) and np.all(np.diff(clocks) % tick_ns == 0)
    image_wall_s = sender_wall_s('camera_info', images)
    assert len(images) <= 20.0 * image_wall_s * 1.3 + 3, \
        f'{len(images)} images in {image_wall_s:.1f} s of wall time'


def test_a_simulation_waiting_for_a_late_base_command_sends_the_time_it_waits_at(
        ros_processes, tester_factory):
    """command_wait: while the base drives, the simulation stops command_wait after the
    last /cmd_vel and waits for the next (up to 0.5 s of wall time). The skills send that
    command when their clock reaches the next control period, so the time the simulation
    stopped at must reach them at once: here /clock is capped at one a wall second (10 s
    of simulation time apart), and the only /clock near the stop is the one sent for it."""
    tick_s, state_s, wait_s = 0.02, 0.04, 0.15
    start_bridge(ros_processes, world='rules', speedup=10.0, camera_rate=0.0,
                 state_rate=1 / state_s, clock_max_wall_rate=1.0, command_wait=wait_s)
    t = tester_factory('clock', 'odom')
    assert t.spin_until(lambda: t.msgs['clock'] and t.msgs['odom'], 60), 'no /clock or /odom'
    pub = t.node.create_publisher(TwistStamped, '/cmd_vel', 10)
    cmd = TwistStamped()
    cmd.twist.angular.z = 0.3
    publish_when_matched(t, pub, cmd)
    assert t.spin_until(lambda: moving_runs(t.msgs['odom']), 30), 'the base never moved'
    moved_s = ns(moving_runs(t.msgs['odom'])[0][0].header.stamp) * 1e-9
    # The command arrived at most one state period before the first moving odometry; the
    # simulation stops at the first tick command_wait after it.
    earliest, latest = moved_s - state_s + wait_s, moved_s + wait_s + tick_s
    assert t.spin_until(lambda: ns(t.last('clock').clock) * 1e-9 > latest, 30), \
        '/clock stopped'
    clocks = [ns(m.clock) * 1e-9 for m in t.msgs['clock']]
    held = [c for c in clocks if earliest - 1e-6 <= c <= latest + 1e-6]
    assert held, (f'no /clock in [{earliest:.2f}, {latest:.2f}] s, where the simulation '
                  f'waited for a base command; /clock stamps: {clocks}')


def test_joint_trajectories_are_tracked(ros_processes, tester_factory):
    start_bridge(ros_processes, world='rules', speedup=4.0, camera_rate=0.0,
                 look_at_cube=False)
    t = tester_factory('joint_states')
    kin = RobotKinematics()
    assert t.spin_until(lambda: len(t.msgs['joint_states']) > 5, 30), 'no /joint_states'
    head = t.node.create_publisher(JointTrajectory, '/head_controller/joint_trajectory', 10)
    arm = t.node.create_publisher(JointTrajectory, '/left_arm_controller/joint_trajectory', 10)
    assert t.spin_until(lambda: head.get_subscription_count() > 0
                        and arm.get_subscription_count() > 0, 10)

    def pos(msg, name):
        return msg.position[msg.name.index(name)]

    def at(time_s, name):
        """Position of `name` in the joint state stamped time_s (within half a tick)."""
        for m in t.msgs['joint_states']:
            if abs(ns(m.header.stamp) * 1e-9 - time_s) < 0.005:
                return pos(m, name)
        raise AssertionError(f'no joint state at t={time_s:.3f}')

    now = ns(t.last('joint_states').header.stamp)
    # 8 s of simulation time ahead (2 s of wall time): the last joint state received
    # may lag the simulation on a busy machine, and the trajectory must arrive before it
    # starts (the bridge's simulation thread holds the GIL most of the time).
    start = now + 8_000_000_000
    traj = JointTrajectory()
    traj.header.stamp = to_time(start)
    traj.joint_names = ['head_tilt_joint', 'head_pan_joint']  # not the controller's order
    traj.points = [JointTrajectoryPoint(positions=[0.6, -0.4], time_from_start=to_duration(1.0)),
                   JointTrajectoryPoint(positions=[5.0, 0.2], time_from_start=to_duration(2.0))]
    head.publish(traj)
    arm_joints = list(CONTROLLERS['left_arm_controller'])
    arm_now = [pos(t.last('joint_states'), j) for j in arm_joints]

    def arm_at(elbow):
        return [elbow if j == 'left_elbow_joint' else q for j, q in zip(arm_joints, arm_now)]
    # As Jazzy's controller: a trajectory naming only some of its joints is refused.
    partial = JointTrajectory(joint_names=['left_elbow_joint'])
    partial.points = [JointTrajectoryPoint(positions=[0.5], time_from_start=to_duration(0.5))]
    arm.publish(partial)
    elbow = JointTrajectory(joint_names=arm_joints)
    elbow.points = [JointTrajectoryPoint(positions=arm_at(-1.0),
                                         time_from_start=to_duration(2.0)),
                    JointTrajectoryPoint(positions=arm_at(-0.2),
                                         time_from_start=to_duration(10.0))]
    arm.publish(elbow)
    s = start * 1e-9
    assert t.spin_until(lambda: ns(t.last('joint_states').header.stamp) * 1e-9 > s + 3.0, 30)
    tilt_hi = kin.upper_limits[kin.joint_index('head_tilt_joint')]
    # Holds until the stamp, then linear interpolation from the state at receipt.
    assert at(s - 0.1, 'head_tilt_joint') == pytest.approx(0.0, abs=1e-9)
    assert at(s + 0.5, 'head_tilt_joint') == pytest.approx(0.3, abs=1e-3)
    assert at(s + 0.5, 'head_pan_joint') == pytest.approx(-0.2, abs=1e-3)
    assert at(s + 1.0, 'head_tilt_joint') == pytest.approx(0.6, abs=1e-3)
    assert at(s + 1.0, 'head_pan_joint') == pytest.approx(-0.4, abs=1e-3)
    # The second point is clamped to the URDF limit (1.2 rad) before interpolating.
    assert at(s + 1.5, 'head_tilt_joint') == pytest.approx((0.6 + tilt_hi) / 2, abs=1e-3)
    assert at(s + 2.0, 'head_tilt_joint') == pytest.approx(tilt_hi, abs=1e-3)
    assert at(s + 3.0, 'head_pan_joint') == pytest.approx(0.2, abs=1e-3)
    assert max(m.position[m.name.index('head_tilt_joint')]
               for m in t.msgs['joint_states']) <= tilt_hi + 1e-9
    # The elbow (zero stamp: from receipt) is on its way to -1.0; the shoulder holds 0.
    last = t.last('joint_states')
    assert pos(last, 'left_shoulder_pitch_joint') == 0.0
    assert -1.0 < pos(last, 'left_elbow_joint') < 0.0
    # A trajectory without points is refused (Jazzy's "Empty trajectory received."): the
    # elbow goes on. A stop is a one-point hold at the current position: it replaces the
    # running trajectory when it reaches the bridge (under load, more than a fixed sim
    # time after the last state received here): from the first state with the elbow at
    # rest, it holds.
    def elbow_below(limit):
        return pos(t.last('joint_states'), 'left_elbow_joint') < limit
    # A new trajectory replaces the running (or finished) one: a slow move to -1.2.
    slow = JointTrajectory(joint_names=arm_joints)
    slow.points = [JointTrajectoryPoint(positions=arm_at(-1.2), time_from_start=to_duration(40.0))]
    from_here = pos(t.last('joint_states'), 'left_elbow_joint')
    arm.publish(slow)
    assert t.spin_until(lambda: elbow_below(from_here - 0.02), 30), 'not replaced'
    arm.publish(JointTrajectory(joint_names=arm_joints))
    moving_from = pos(t.last('joint_states'), 'left_elbow_joint')
    assert t.spin_until(lambda: elbow_below(moving_from - 0.05), 30), \
        'an empty trajectory stopped the elbow'
    n_before = len(t.msgs['joint_states'])
    here = t.last('joint_states')
    hold = JointTrajectory(joint_names=arm_joints)
    hold.points = [JointTrajectoryPoint(positions=[pos(here, j) for j in arm_joints],
                                        velocities=[0.0] * len(arm_joints),
                                        time_from_start=to_duration(0.0))]
    arm.publish(hold)

    def stopped():
        return next((m for m in t.msgs['joint_states'][n_before:]
                     if m.velocity[m.name.index('left_elbow_joint')] == 0.0), None)
    assert t.spin_until(lambda: stopped() is not None, 30), 'the elbow did not stop'
    t0 = ns(stopped().header.stamp)
    assert t.spin_until(lambda: ns(t.last('joint_states').header.stamp) > t0 + 2e9, 30)
    held = [pos(m, 'left_elbow_joint') for m in t.msgs['joint_states']
            if ns(m.header.stamp) >= t0]
    assert np.ptp(held) < 1e-9, 'the elbow did not hold after a one-point hold'
    assert held[0] > -1.2 + 1e-3  # it stopped before the end of the slow move



def test_follow_joint_trajectory_goals_end_as_jazzys_controller_ends_them(ros_processes,
                                                                           tester_factory):
    """The head controller's action: a goal without points is rejected; one that the
    joints follow ends SUCCESSFUL; a path tolerance the velocity-limited joint cannot keep
    aborts PATH_TOLERANCE_VIOLATED and the joint holds; a cancel holds the joint where it
    is and ends the goal canceled."""
    start_bridge(ros_processes, world='rules', speedup=2.0, camera_rate=0.0,
                 look_at_cube=False)
    t = tester_factory('joint_states')
    client = ActionClient(t.node, FollowJointTrajectory, '/head_controller/follow_joint_trajectory')
    assert wait_until_answering(client, lambda done, s: t.spin_until(done, s), 30)
    joints = list(CONTROLLERS['head_controller'])

    def goal(points, path_tolerance=None):
        g = FollowJointTrajectory.Goal()
        g.trajectory = JointTrajectory(joint_names=joints, points=[
            JointTrajectoryPoint(positions=[pan, 0.0], velocities=[0.0, 0.0],
                                 time_from_start=to_duration(at)) for at, pan in points])
        if path_tolerance is not None:
            g.path_tolerance = [JointTolerance(name='head_pan_joint', position=path_tolerance)]
        g.goal_tolerance = [JointTolerance(name=j, position=0.01) for j in joints]
        return g

    def send(g):
        sent = client.send_goal_async(g)
        assert t.spin_until(sent.done, 30)
        return sent.result()

    def result(handle, timeout=60):
        future = handle.get_result_async()
        assert t.spin_until(future.done, timeout)
        return future.result()

    def pan():
        return t.last('joint_states').position[t.last('joint_states').name.index('head_pan_joint')]

    assert not send(goal([])).accepted, 'a goal without points was accepted'
    done = result(send(goal([(1.0, 0.3)])))
    assert done.status == GoalStatus.STATUS_SUCCEEDED
    assert done.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    assert t.spin_until(lambda: abs(pan() - 0.3) < 1e-6, 30)
    # 2 rad in 0.1 s is far beyond the pan's 3 rad/s: the joint lags the desired path.
    aborted = result(send(goal([(0.1, -1.7)], path_tolerance=0.05)))
    assert aborted.status == GoalStatus.STATUS_ABORTED
    assert aborted.result.error_code == FollowJointTrajectory.Result.PATH_TOLERANCE_VIOLATED
    assert 'head_pan_joint' in aborted.result.error_string
    n = len(t.msgs['joint_states'])
    assert t.spin_until(lambda: len(t.msgs['joint_states']) > n + 20, 30)
    held = [m.position[m.name.index('head_pan_joint')] for m in t.msgs['joint_states'][n:]]
    assert np.ptp(held) < 1e-9 and held[0] > -1.7 + 0.1, 'no hold after the abort'
    # A slow move, cancelled on its way: canceled, and the joint holds where it was.
    slow = send(goal([(20.0, 1.0)]))
    start = pan()
    assert t.spin_until(lambda: pan() > start + 0.05, 30), 'the slow move did not start'
    cancel = slow.cancel_goal_async()
    assert t.spin_until(cancel.done, 30)
    assert result(slow).status == GoalStatus.STATUS_CANCELED
    n = len(t.msgs['joint_states'])
    assert t.spin_until(lambda: len(t.msgs['joint_states']) > n + 20, 30)
    held = [m.position[m.name.index('head_pan_joint')] for m in t.msgs['joint_states'][n:]]
    assert np.ptp(held) < 1e-9 and held[0] < 0.9, 'no hold after the cancel'
    client.destroy()


# -- camera -------------------------------------------------------------------------------

def test_camera_images_show_the_tags_the_ground_truth_says(ros_processes, tester_factory):
    start_bridge(ros_processes, world='rules', speedup=1.0, camera_encoding='bgr8',
                 distractors=3,
                 cube_x=0.9, cube_y=0.15, cube_yaw=0.35, camera_noise_std=1.5,
                 face_tags=str(TAGS).replace(' ', ''))
    t = tester_factory('image', 'camera_info', 'joint_states', 'ground_truth')

    def image_and_joints():
        """The latest image whose joint state (same stamp) has arrived too, and that state:
        the two travel on different topics, and either can come first."""
        joints = {ns(m.header.stamp): m for m in t.msgs['joint_states']}
        return next(((m, joints[ns(m.header.stamp)]) for m in reversed(t.msgs['image'])
                     if ns(m.header.stamp) in joints), None)
    assert t.spin_until(lambda: len(t.msgs['image']) >= 6 and t.msgs['camera_info']
                        and t.msgs['ground_truth'], 30), 'no camera images'
    assert t.spin_until(lambda: image_and_joints() is not None, 30), \
        'no joint state with the stamp of an image'
    info = t.last('camera_info')
    intr = camera_intrinsics()
    assert (info.width, info.height) == (intr.width, intr.height) == (640, 480)
    assert np.allclose(np.reshape(info.k, (3, 3)), intr.K)
    assert info.header.frame_id == 'camera_optical_frame'
    # Frames every 0.1 s of sim time (a reliable reader can still miss frames its keep-last
    # history dropped while this process was starved).
    stamps = np.array([ns(m.header.stamp) for m in t.msgs['image']]) / 1e8
    assert np.allclose(stamps, np.round(stamps), atol=1e-6), 'camera_rate 10 Hz of sim time'
    assert np.all(np.diff(stamps) >= 1 - 1e-6)
    assert {ns(m.header.stamp) for m in t.msgs['image']} & \
        {ns(m.header.stamp) for m in t.msgs['camera_info']}, 'image and info share stamps'

    img_msg, js = image_and_joints()
    assert img_msg.encoding == 'bgr8' and img_msg.step == 640 * 3
    assert len(img_msg.data) == 640 * 480 * 3
    img = np.frombuffer(bytes(img_msg.data), np.uint8).reshape(480, 640, 3)
    # Where was the camera? FK over the joint state of the same stamp + the true base.
    kin = RobotKinematics()
    q = kin.q_from_mapping(dict(zip(js.name, js.position)))
    gt = t.last('ground_truth')
    base = gt.base_pose
    cam = base_to_world((base.position.x, base.position.y, yaw_of(base.orientation))) \
        @ kin.camera_pose(q)
    cube = pose_matrix(gt.cube_pose)
    assert list(gt.face_tags) == TAGS
    truth = visible_faces(intr.K, 640, 480, cam, cube, TAGS)
    expected = {f.tag_id for f in truth if f.in_image and f.area_px > 400 and f.cos_view > 0.25}
    assert len(expected) >= 2, 'the head should look at the cube (look_at_cube)'
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
                                       cv2.aruco.DetectorParameters())
    _, ids, _ = detector.detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    found = set() if ids is None else set(ids.ravel().tolist())
    cube_found = found & set(TAGS)
    possible = {f.tag_id for f in truth if f.in_image}
    assert expected <= cube_found <= possible, (expected, found)
    # Distractors carry ids outside the cube's tags (n_tags..49).
    assert all(i >= 7 for i in found - set(TAGS))


def test_compressed_frames_are_the_raw_frames_in_jpeg(ros_processes, tester_factory):
    """publish_compressed: each frame also as image_transport's compressed transport sends
    it (format '<encoding>; jpeg compressed <encoding>'), with the raw frame's header, a
    fraction of its size, and the same picture up to JPEG's loss at jpeg_quality."""
    start_bridge(ros_processes, world='rules', speedup=1.0, publish_compressed=True,
                 jpeg_quality=80, face_tags=str(TAGS).replace(' ', ''))
    t = tester_factory('image', 'compressed')

    def pair():
        raw = {ns(m.header.stamp): m for m in t.msgs['image']}
        return next(((raw[ns(c.header.stamp)], c) for c in reversed(t.msgs['compressed'])
                     if ns(c.header.stamp) in raw), None)
    assert t.spin_until(lambda: len(t.msgs['compressed']) >= 3 and pair() is not None, 30), \
        f"{len(t.msgs['image'])} raw and {len(t.msgs['compressed'])} compressed frames"
    raw, jpeg = pair()
    assert jpeg.format == 'mono8; jpeg compressed mono8'
    assert jpeg.header.frame_id == raw.header.frame_id == 'camera_optical_frame'
    assert bytes(jpeg.data[:2]) == b'\xff\xd8', 'a JPEG stream'
    assert len(jpeg.data) < len(raw.data) / 4, (len(jpeg.data), len(raw.data))
    decoded = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_GRAYSCALE)
    image = np.frombuffer(bytes(raw.data), np.uint8).reshape(raw.height, raw.width)
    assert decoded.shape == image.shape
    assert np.mean(np.abs(decoded.astype(float) - image)) < 3.0


# -- manual actions: every mass variant, real hand trajectories -----------------------------

def _set_and_reset(t, params_client, reset_client, **values):
    future = params_client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
    assert t.spin_until(future.done, 10), 'set_parameters timed out'
    assert all(r.successful for r in future.result().results), future.result()
    future = reset_client.call_async(Trigger.Request())
    assert t.spin_until(future.done, 10), 'reset timed out'
    assert future.result().success, future.result().message


def _trajectories(plan):
    out = {}
    for controller, (names, points) in plan.controller_points().items():
        msg = JointTrajectory(joint_names=list(names))
        msg.points = [JointTrajectoryPoint(positions=list(p), time_from_start=to_duration(tt))
                      for tt, p in points if tt > 0]
        out[controller] = msg
    return out


# One case per action over DDS, each on a mass variant that turns the cube (MODEL.md);
# every action on every mass variant is checked in process with the same hand paths
# (test_rules_world.py::test_real_hand_trajectories_give_model_md_outcomes).
MASS_PER_ACTION = {'PUSH': 4, 'LIFT': 5, 'FLIP': 3}   # heavy body -y, +z, +y


def test_manual_actions_follow_model_physics_over_dds(ros_processes, tester_factory):
    """The cube stands with body +z up and body +x away from the robot. For each action,
    the mass variant is set as a parameter and the world reset over the node's service,
    then the real hand trajectories go to the controllers' topics."""
    # max_stamp_future above the 40 s lead of the trajectories' start stamp (below).
    proc = start_bridge(ros_processes, world='rules', speedup=20.0, camera_rate=0.0,
                        ground_truth_rate=10.0, max_stamp_future=60.0,
                        face_tags=str(TAGS).replace(' ', ''), mass_index=0)
    t = tester_factory('ground_truth')
    pubs = {c: t.node.create_publisher(JointTrajectory, f'/{c}/joint_trajectory', 10)
            for c in CONTROLLER_JOINTS}
    params = AsyncParameterClient(t.node, 'sim_bridge')
    reset = t.node.create_client(Trigger, '/sim_bridge/reset_world')
    assert t.spin_until(lambda: t.msgs['ground_truth'], 30), 'no ground truth'
    assert params.wait_for_services(timeout_sec=10) and reset.wait_for_service(timeout_sec=10)
    assert t.spin_until(lambda: all(p.get_subscription_count() > 0 for p in pubs.values()), 10)
    # A bad value is refused when set, with the parameter's name.
    refused = params.set_parameters([Parameter('camera_encoding', value='rgb8')])
    assert t.spin_until(refused.done, 10)
    assert not refused.result().results[0].successful
    assert 'camera_encoding' in refused.result().results[0].reason
    rel = view_rotation(np.eye(3), (0.40, 0.0))
    ik = DlsIK()
    results = {}
    for action, mass in MASS_PER_ACTION.items():
        plan = hand_path(action, cube_xy=(0.40, 0.0), ik=ik)
        msgs = _trajectories(plan)
        _set_and_reset(t, params, reset, mass_index=mass)
        assert t.spin_until(lambda: t.last('ground_truth').mass_index == mass
                            and t.last('ground_truth').manual_actions == 0, 10)
        start = t.last('ground_truth')
        assert start.state == expected_state('PUSH', 0, rel)  # slide = the initial state
        # One common start stamp for the three controllers (zero stamps would start each
        # on its own receipt, ticks apart at this speed-up, and the hands would not meet).
        # All three must arrive before it: a late one starts part-way along its path (the
        # follower's first segment catches up from the state at receipt) and the hand
        # misses the cube. 40 s of simulation time ahead = 2 s of wall time; 0.2 s was not
        # always enough for the bridge, whose simulation thread holds the GIL at 20x,
        # on 2 cores shared with two busy loops (fresh-clone run 1 of 73a2934: no contact).
        begin = ns(start.header.stamp) + 40_000_000_000
        for controller, msg in msgs.items():
            msg.header.stamp = to_time(begin)
            pubs[controller].publish(msg)
        done = begin * 1e-9 + plan.duration + 1.0
        assert t.spin_until(lambda: ns(t.last('ground_truth').header.stamp) * 1e-9 > done, 60)
        gt = t.last('ground_truth')
        results[action] = (mass, gt.state, expected_state(action, mass, rel),
                           gt.manual_actions, gt.last_outcome)
    assert proc.poll() is None
    ros_processes.stop_all()
    log = ros_processes.output(proc)
    for action, (mass, state, want, count, outcome) in results.items():
        assert want != expected_state('PUSH', 0, rel), 'a case that does not turn the cube'
        assert count == 1, f'{action}, mass {mass}: {count} manual actions ({outcome})\n{log}'
        assert outcome.startswith(action), f'{action}, mass {mass}: {outcome}\n{log}'
        assert state == want, f'{action}, mass {mass}: state {state}, MODEL.md says {want} ' \
                              f'({outcome})\n{log}'


# -- configuration errors -------------------------------------------------------------------

def test_a_bad_parameter_ends_the_executable_with_code_2():
    """The one process start-up: the executable's exit code and its message (the other
    bad values go through the same main() in process, below)."""
    result = subprocess.run([bridge_executable(), '--ros-args', '-p', 'world:=rules',
                             '-p', 'speedup:=0.0'],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert 'configuration error' in result.stderr and 'speedup' in result.stderr
    assert 'Traceback' not in result.stderr


@pytest.mark.parametrize('override, expected', [
    ('speedup:=0.0', 'speedup'),
    ('camera_encoding:=rgb8', 'camera_encoding'),
    ('face_tags:=[1,1,2,3,4,5]', 'face_tags'),
    ('camera_rate:=100.0', 'camera_rate'),
])
def test_bad_parameters_are_refused_clearly(override, expected, main_in_process):
    from abp_sim_bridge.sim_bridge_node import main
    code, stderr = main_in_process(main, '-p', 'world:=rules', '-p', override)
    assert code == 2, stderr
    assert 'configuration error' in stderr and expected in stderr
    assert 'Traceback' not in stderr
