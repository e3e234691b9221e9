"""The `robot_state` node over real DDS (issue 32's tf goal).

A test node publishes /joint_states (the head panning and tilting, every other joint set,
stamps advancing) and /odom to the real robot_state process. A second node, started
after the node has published its static transforms (a late joiner), listens to /tf and
/tf_static only and keeps its own small buffer as tf2 does: per parent -> child edge the
stamped transforms, interpolated between the two nearest stamps (linear translation,
slerp rotation), composed along the tree. From that alone it recovers base_link ->
camera_optical_frame at stamps between two joint states; the camera pose the detector
uses is abp_description's forward kinematics of the joint state at the image stamp
(linear in the joint values between two joint-state messages). Required: within 1 mm and
0.1 degree. odom -> base_link is checked the same way against the odometry.

The node runs under a namespace of its own with /tf and /tf_static remapped into it, as
robots sharing a network do: a graph of another test session that happens to share the
DDS domain publishes /odom and /joint_states too, and must not reach this one.
"""

import os
import uuid

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.qos import QoSDurabilityPolicy, QoSProfile  # noqa: E402
from scipy.spatial.transform import Rotation, Slerp  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from abp_common.qos import LATCHED, RELIABLE  # noqa: E402
from abp_description import urdf_path  # noqa: E402
from abp_description.frames import base_to_world, quaternion_from_yaw  # noqa: E402
from abp_description.kinematics import RobotKinematics  # noqa: E402
from abp_msgs.msg import AspectHypothesis, AspectObservation  # noqa: E402

NS = 1_000_000_000
T0_NS = 1_000 * NS              # the joint states' first stamp
STEP_NS = 20_000_000            # 50 Hz, the sim bridge's rate
STEPS = 12
MAX_POSITION_ERROR_M = 1e-3
MAX_ANGLE_ERROR_DEG = 0.1
# tf2_ros's listener QoS: /tf reliable depth 100, /tf_static also transient local.
TF_LISTENER = QoSProfile(depth=100)
TF_STATIC_LISTENER = QoSProfile(depth=100, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)


# The node runs under a namespace of this test, with /tf and /tf_static remapped into it
# (the multi-robot way): another graph on the same DDS domain cannot reach it.
NAMESPACE = f'tf_test_{uuid.uuid4().hex[:8]}'


def command(*args):
    prefix = ament_index.get_package_prefix('abp_description')
    return [os.path.join(prefix, 'lib', 'abp_description', 'robot_state'), '--ros-args',
            '-r', f'__ns:=/{NAMESPACE}', '-r', f'/tf:=/{NAMESPACE}/tf',
            '-r', f'/tf_static:=/{NAMESPACE}/tf_static', *args]


def topic(name):
    return f'/{NAMESPACE}/{name}'


def stamp(t_ns):
    return Time(sec=t_ns // NS, nanosec=t_ns % NS)


def stamp_ns(msg_stamp):
    return msg_stamp.sec * NS + msg_stamp.nanosec


# -- the test's own tf buffer (independent of the node's code) ---------------------------
class SmallTfBuffer:
    """Edges child -> (parent, [(stamp_ns, translation, quaternion)]); static edges have
    stamp None and hold at every time."""

    def __init__(self):
        self.edges = {}

    def add(self, msg, static):
        for tf in msg.transforms:
            t, r = tf.transform.translation, tf.transform.rotation
            entry = (None if static else stamp_ns(tf.header.stamp),
                     np.array([t.x, t.y, t.z]), np.array([r.x, r.y, r.z, r.w]))
            parent, samples = self.edges.setdefault(tf.child_frame_id,
                                                    (tf.header.frame_id, []))
            assert parent == tf.header.frame_id, f'{tf.child_frame_id} has two parents'
            samples.append(entry)

    def has(self, child, t_ns):
        return any(s[0] == t_ns for s in self.edges.get(child, (None, []))[1])

    def edge_at(self, child, t_ns):
        """4x4 of `child` in its parent at t, interpolated between the nearest stamps."""
        parent, samples = self.edges[child]
        if samples[-1][0] is None:
            return parent, matrix(samples[-1][1], samples[-1][2])
        samples = sorted(samples, key=lambda s: s[0])
        times = [s[0] for s in samples]
        i = int(np.searchsorted(times, t_ns))
        assert times[0] <= t_ns <= times[-1], f'{child}: {t_ns} outside the buffer'
        if times[i] == t_ns:
            return parent, matrix(samples[i][1], samples[i][2])
        (ta, pa, qa), (tb, pb, qb) = samples[i - 1], samples[i]
        fraction = (t_ns - ta) / (tb - ta)
        rotation = Slerp([0, 1], Rotation.from_quat([qa, qb]))(fraction)
        return parent, matrix((1 - fraction) * pa + fraction * pb, rotation.as_quat())

    def lookup(self, target, source, t_ns):
        """Pose of `source` in `target` (an ancestor of it) at t."""
        pose = np.eye(4)
        frame = source
        while frame != target:
            frame, edge = self.edge_at(frame, t_ns)
            pose = edge @ pose
        return pose


def matrix(translation, quaternion):
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat(quaternion).as_matrix()
    out[:3, 3] = translation
    return out


def pose_errors(a, b):
    """(translation error in m, rotation error in degrees) between two 4x4 poses."""
    angle = Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).magnitude()
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), float(np.degrees(angle))


# -- the motion published ------------------------------------------------------------------
def joint_positions(kin, k):
    """Joint state k: the head pans and tilts (not at a constant rate), the wheels turn,
    every other joint is held at a non-zero value."""
    t = k * STEP_NS / NS
    q = kin.clip(np.linspace(-0.4, 0.5, kin.nq))
    q[kin.joint_index('head_pan_joint')] = 0.8 * np.sin(2.0 * t) - 0.2
    q[kin.joint_index('head_tilt_joint')] = 0.3 + 0.4 * t * t
    for wheel in ('left_wheel_joint', 'right_wheel_joint'):
        q[kin.joint_index(wheel)] = 3.0 + 5.0 * t    # crosses pi: a continuous joint
    return kin.clip(q)


def base_pose(k):
    t = k * STEP_NS / NS
    return np.array([0.5 + 0.3 * t, -0.2 + 0.1 * t * t, 0.4 + 0.6 * t])


def odometry_msg(k, frame='odom', child='base_link'):
    x, y, yaw = base_pose(k)
    msg = Odometry()
    msg.header.stamp = stamp(T0_NS + k * STEP_NS)
    msg.header.frame_id, msg.child_frame_id = frame, child
    msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = quaternion_from_yaw(yaw)
    return msg


@pytest.fixture
def nodes(rclpy_context):
    from rclpy.executors import SingleThreadedExecutor
    made = []

    def make(name):
        node = rclpy.create_node(name, context=rclpy_context)
        made.append(node)
        return node

    executor = SingleThreadedExecutor(context=rclpy_context)
    yield make, executor
    executor.shutdown()
    for node in made:
        node.destroy_node()


def late_tf_listener(make, executor):
    """The second node: /tf and /tf_static only, into a SmallTfBuffer."""
    listener = make('tf_only_listener')
    executor.add_node(listener)
    buffer, counts = SmallTfBuffer(), {'tf': 0, 'static': 0}

    def on(static):
        def take(msg):
            buffer.add(msg, static)
            counts['static' if static else 'tf'] += 1
        return take
    tf_sub = listener.create_subscription(TFMessage, topic('tf'), on(False), TF_LISTENER)
    listener.create_subscription(TFMessage, topic('tf_static'), on(True), TF_STATIC_LISTENER)
    return buffer, counts, tf_sub


def test_tf_alone_recovers_the_detector_camera_pose(ros_processes, nodes, spin):
    make, executor = nodes
    proc = ros_processes.start(command())
    kin = RobotKinematics()
    sender = make('joint_state_sender')
    executor.add_node(sender)
    # The node publishes /tf_static when it activates: seen here first, then by a node
    # created afterwards, which only transient local durability can serve.
    first_static = []
    sender.create_subscription(TFMessage, topic('tf_static'), first_static.append,
                               TF_STATIC_LISTENER)
    description = []
    sender.create_subscription(String, topic('robot_description'), description.append,
                               LATCHED)
    assert spin(executor, lambda: first_static and description, 30), \
        'no /tf_static or robot_description from robot_state'
    with open(urdf_path()) as stream:
        assert description[-1].data == stream.read()
    infos = sender.get_publishers_info_by_topic(topic('tf_static'))
    assert [i.qos_profile.durability for i in infos] == [QoSDurabilityPolicy.TRANSIENT_LOCAL]

    buffer, counts, tf_sub = late_tf_listener(make, executor)
    assert spin(executor, lambda: counts['static'] >= 1, 20), 'late joiner got no /tf_static'
    assert {c for c, (_, s) in buffer.edges.items() if s[0][0] is None} == \
        {'camera_link', 'camera_optical_frame', 'left_hand_link', 'right_hand_link'}

    joints_pub = sender.create_publisher(JointState, topic('joint_states'), RELIABLE)
    odom_pub = sender.create_publisher(Odometry, topic('odom'), RELIABLE)
    assert spin(executor, lambda: joints_pub.get_subscription_count() > 0
                and odom_pub.get_subscription_count() > 0
                and tf_sub.get_publisher_count() > 0, 20), 'robot_state topics not matched'
    published = []
    for k in range(STEPS):
        t_ns = T0_NS + k * STEP_NS
        q = joint_positions(kin, k)
        msg = JointState(name=list(kin.joint_names), position=q.tolist())
        msg.header.stamp = stamp(t_ns)
        published.append((t_ns, q))
        # joint_states is taken best effort, as robot_state_publisher does: a message lost
        # under load is sent again (same stamp) until its transforms are on /tf.
        for _ in range(5):
            joints_pub.publish(msg)
            odom_pub.publish(odometry_msg(k))
            if spin(executor, lambda: buffer.has('head_link', t_ns)
                    and buffer.has('base_link', t_ns), 3):
                break
        assert buffer.has('head_link', t_ns) and buffer.has('base_link', t_ns), \
            f'no /tf at joint state {k}'
        # One transform per moving joint of the message, parent link -> child link.
        assert all(buffer.has(e, t_ns) for e in ('left_wheel_link', 'torso_link',
                                                 'head_pan_link', 'right_forearm_link'))

    worst = (0.0, 0.0)
    for k in range(STEPS - 1):
        (ta, qa), (tb, qb) = published[k], published[k + 1]
        for fraction in (0.25, 0.5, 0.8):
            t_ns = ta + int(fraction * (tb - ta))
            exact = (t_ns - ta) / (tb - ta)
            # The detector's camera pose: FK of the joint state at the image stamp.
            expected = kin.camera_pose((1 - exact) * qa + exact * qb)
            got = buffer.lookup('base_link', 'camera_optical_frame', t_ns)
            position_err, angle_err = pose_errors(got, expected)
            worst = (max(worst[0], position_err), max(worst[1], angle_err))
            # odom -> base_link from /odom, and the whole chain odom -> camera.
            odom_a, odom_b = base_to_world(base_pose(k)), base_to_world(base_pose(k + 1))
            rotation = Slerp([0, 1], Rotation.from_matrix([odom_a[:3, :3], odom_b[:3, :3]]))
            base = np.eye(4)
            base[:3, :3] = rotation(exact).as_matrix()
            base[:3, 3] = (1 - exact) * odom_a[:3, 3] + exact * odom_b[:3, 3]
            for a, b in ((buffer.lookup('odom', 'base_link', t_ns), base),
                         (buffer.lookup('odom', 'camera_optical_frame', t_ns),
                          base @ expected)):
                p_err, a_err = pose_errors(a, b)
                assert p_err <= MAX_POSITION_ERROR_M and a_err <= MAX_ANGLE_ERROR_DEG
    assert worst[0] <= MAX_POSITION_ERROR_M and worst[1] <= MAX_ANGLE_ERROR_DEG, worst
    print(f'camera pose from /tf: worst error {worst[0] * 1e3:.2g} mm, {worst[1]:.2g} deg')
    assert proc.poll() is None


def test_urdf_from_topic_and_the_cube_frame(ros_processes, nodes, spin):
    """urdf_source topic: the tree comes from robot_description published by another node;
    enable_odom_tf false publishes no odom -> base_link; the cube estimate, seen in
    base_link at a stamp between two odometry messages, is published as odom -> cube;
    malformed inputs are counted in /diagnostics, not published."""
    make, executor = nodes
    proc = ros_processes.start(command('-p', 'urdf_source:=topic',
                                       '-p', 'enable_odom_tf:=false'))
    sender = make('description_sender')
    executor.add_node(sender)
    description_pub = sender.create_publisher(String, topic('robot_description'), LATCHED)
    with open(urdf_path()) as stream:
        description_pub.publish(String(data=stream.read()))
    buffer, counts, tf_sub = late_tf_listener(make, executor)
    assert spin(executor, lambda: counts['static'] >= 1, 30), \
        'no /tf_static from a robot_description given on the topic'
    assert 'camera_optical_frame' in buffer.edges

    odom_pub = sender.create_publisher(Odometry, topic('odom'), RELIABLE)
    observation_pub = sender.create_publisher(AspectObservation, topic('abp/aspect_observation'),
                                              RELIABLE)
    assert spin(executor, lambda: odom_pub.get_subscription_count() > 0
                and observation_pub.get_subscription_count() > 0
                and tf_sub.get_publisher_count() > 0, 20), 'robot_state topics not matched'
    for k in (0, 1):
        odom_pub.publish(odometry_msg(k))
    cube_in_base = np.eye(4)
    cube_in_base[:3, :3] = Rotation.from_euler('z', 0.7).as_matrix()
    cube_in_base[:3, 3] = (0.6, 0.1, 0.05)
    observation = AspectObservation()
    t_ns = T0_NS + STEP_NS // 2
    observation.header.stamp, observation.header.frame_id = stamp(t_ns), 'base_link'
    hypothesis = AspectHypothesis(aspect_type=0, slots=[0, 1, -1], support=3.0, score=1.0)
    p, o = hypothesis.object_pose.pose.position, hypothesis.object_pose.pose.orientation
    p.x, p.y, p.z = cube_in_base[:3, 3]
    o.x, o.y, o.z, o.w = Rotation.from_matrix(cube_in_base[:3, :3]).as_quat()
    observation.hypotheses = [hypothesis]
    # The cube goes out with the next odometry. Odometry is taken best effort: the
    # observation is sent again until the cube is placed (a lost odometry message makes
    # the node refuse it; then the odometry is sent again too).
    t2 = T0_NS + 2 * STEP_NS
    for _ in range(10):
        observation_pub.publish(observation)
        odom_pub.publish(odometry_msg(2))
        if spin(executor, lambda: buffer.has('cube', t2), 2):
            break
        for k in (0, 1):
            odom_pub.publish(odometry_msg(k))
    assert buffer.has('cube', t2), 'no odom -> cube on /tf'
    odom_a, odom_b = base_to_world(base_pose(0)), base_to_world(base_pose(1))
    rotation = Slerp([0, 1], Rotation.from_matrix([odom_a[:3, :3], odom_b[:3, :3]]))
    base = np.eye(4)
    base[:3, :3] = rotation(0.5).as_matrix()
    base[:3, 3] = 0.5 * (odom_a[:3, 3] + odom_b[:3, 3])
    parent, cube = buffer.edge_at('cube', t2)
    assert parent == 'odom'
    p_err, a_err = pose_errors(cube, base @ cube_in_base)
    assert p_err <= 1e-6 and a_err <= 1e-4
    # Held in odom: sent again at each later odometry stamp.
    t4 = T0_NS + 4 * STEP_NS
    for _ in range(5):
        odom_pub.publish(odometry_msg(4))
        if spin(executor, lambda: buffer.has('cube', t4), 3):
            break
    assert buffer.has('cube', t4), 'cube not held at a later odometry stamp'
    p_err, a_err = pose_errors(buffer.edge_at('cube', t4)[1], base @ cube_in_base)
    assert p_err <= 1e-6 and a_err <= 1e-4
    assert 'base_link' not in buffer.edges, 'odom -> base_link published with it off'

    # Bad inputs are refused and counted in /diagnostics; the node goes on.
    statuses = []
    sender.create_subscription(DiagnosticArray, '/diagnostics', lambda m: statuses.extend(
        s for s in m.status if s.name == f'{NAMESPACE}/robot_state: health'), 10)
    joints_pub = sender.create_publisher(JointState, topic('joint_states'), RELIABLE)
    assert spin(executor, lambda: joints_pub.get_subscription_count() > 0, 20)
    wrong_child = odometry_msg(3, child='base_footprint')
    nan_joint = JointState(name=['head_pan_joint'], position=[float('nan')])

    def counted():
        keys = {kv.key for kv in statuses[-1].values} if statuses else set()
        return {'rejected odom frame', 'rejected joint_states non_finite'} <= keys
    for _ in range(10):
        odom_pub.publish(wrong_child)
        joints_pub.publish(nan_joint)
        if spin(executor, counted, 3):
            break
    assert counted(), statuses[-1].values if statuses else 'no /diagnostics'
    assert not buffer.has('base_footprint', T0_NS + 3 * STEP_NS)
    assert proc.poll() is None
