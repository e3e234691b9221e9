"""ROS 2 wiring of the simulated robot and ARcube world: the `sim_bridge` node.

It stands in for the uBot-6 drivers through the robot's own topics (docs/INTERFACES.md):

Subscribes:  /cmd_vel (geometry_msgs/Twist)
             /torso_controller/joint_trajectory, /left_arm_controller/joint_trajectory,
             /right_arm_controller/joint_trajectory, /head_controller/joint_trajectory
             (trajectory_msgs/JointTrajectory)
Publishes:   /clock (rosgraph_msgs/Clock; when publish_clock)
             /joint_states (sensor_msgs/JointState, 13 joints), /odom (nav_msgs/Odometry)
             /camera/image_raw (sensor_msgs/Image), /camera/camera_info (sensor data QoS)
             /abp/sim/ground_truth (abp_msgs/SimGroundTruth, transient local;
             TESTS AND BENCHMARKS ONLY)
Services:    ~/reset_world (std_srvs/Trigger): rebuild the world (cube, base at the origin,
             initial joints) from the current parameters; simulation time goes on.

Threads: the executor (main thread) takes commands and services; a simulation thread
steps `SimWorld` at `rate` Hz of simulation time, paced to `speedup` x wall time, and
publishes clock, joint states, odometry and ground truth; a render thread draws camera
frames (scene snapshots taken by the simulation thread at `camera_rate`). When the
renderer is still busy with the previous frame, the simulation waits: every frame is
drawn, simulation time just runs slower than asked for.

The science lives in `sim_world`, `contact`, `world`, `renderer`, `scenario`, `config`.
"""

import queue
import sys
import threading
import time
import traceback
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion, Twist
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    QoSDurabilityPolicy,
    QoSProfile,
    QoSReliabilityPolicy,
    qos_profile_sensor_data,
)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from abp_belief.node_main import run_node
from abp_description import camera_intrinsics
from abp_description.kinematics import RobotKinematics
from abp_msgs.msg import SimGroundTruth

from . import config as cfg
from .renderer import ArcubeRenderer
from .sim_world import CONTROLLERS, SimWorld, look_at
from .trajectory import TrajectoryError, TrajectoryPoint
from .world import Physics, World

LATCHED = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                     durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)
ODOM_FRAME, BASE_FRAME = 'odom', 'base_link'
START_ONLY = frozenset({'publish_clock'})
MAX_LAG_WALL_S = 0.1   # further behind than this: stop trying to catch up (re-anchor)

_TYPES = {
    cfg.BOOL: Parameter.Type.BOOL, cfg.INT: Parameter.Type.INTEGER,
    cfg.DOUBLE: Parameter.Type.DOUBLE, cfg.STRING: Parameter.Type.STRING,
    cfg.INT_ARRAY: Parameter.Type.INTEGER_ARRAY, cfg.DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY,
}


def _stamp(ns):
    ns = int(ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _pose_msg(position, rotation):
    x, y, z, w = pin.Quaternion(np.asarray(rotation, dtype=float)).coeffs()
    return Pose(position=Point(x=float(position[0]), y=float(position[1]),
                               z=float(position[2])),
                orientation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))


def _yaw_rotation(yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class _Frame:
    """What the render thread needs to draw one camera frame."""
    stamp: Time
    camera_pose: np.ndarray
    cube_pose: np.ndarray
    tags: tuple
    renderer: ArcubeRenderer
    distractors: list


class SimBridgeNode(Node):
    def __init__(self):
        super().__init__('sim_bridge')
        try:
            self._declare_parameters()
        except rclpy.exceptions.InvalidParameterTypeException as error:
            raise ValueError(f'{error} (write a double with a decimal point, e.g. '
                             'speedup:=10.0, and integer arrays as [1,2,3])') from error
        self.config = cfg.build(self._values())
        self.kin = RobotKinematics()
        self.intrinsics = camera_intrinsics()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._failed = False
        self._speedup = self.config.speedup
        self._epoch_ns = 0  # publish_clock false: wall-clock time at the start (below)
        self._build(self.config, start_time_ns=0)

        self._clock_pub = (self.create_publisher(Clock, '/clock', RELIABLE)
                           if self.config.publish_clock else None)
        self._joint_pub = self.create_publisher(JointState, '/joint_states', RELIABLE)
        self._odom_pub = self.create_publisher(Odometry, '/odom', RELIABLE)
        self._image_pub = self.create_publisher(Image, '/camera/image_raw',
                                                qos_profile_sensor_data)
        self._info_pub = self.create_publisher(CameraInfo, '/camera/camera_info',
                                               qos_profile_sensor_data)
        self._gt_pub = self.create_publisher(SimGroundTruth, '/abp/sim/ground_truth', LATCHED)
        self.create_subscription(Twist, '/cmd_vel', self._on_cmd_vel, RELIABLE)
        for controller in CONTROLLERS:
            self.create_subscription(
                JointTrajectory, f'/{controller}/joint_trajectory',
                lambda msg, c=controller: self._on_trajectory(c, msg), RELIABLE)
        self.create_service(Trigger, '~/reset_world', self._on_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._camera_info = self._camera_info_msg()
        self._joint_msg = JointState(name=list(self.kin.joint_names))
        self._odom = Odometry()
        self._odom.header.frame_id, self._odom.child_frame_id = ODOM_FRAME, BASE_FRAME
        self._clock_msg = Clock()

        h = self.config.hidden
        self.get_logger().info(
            f'sim_bridge: hidden cube {h.object_id} (model_index {h.model_index}), '
            f'{self.config.settings.rate:g} Hz, camera {self.config.camera.rate:g} Hz, '
            f'speedup {self._speedup:g}, publish_clock {self.config.publish_clock}')
        self._frames = queue.Queue(maxsize=1)
        if not self.config.publish_clock:
            self._epoch_ns = time.time_ns()
        self._threads = [threading.Thread(target=self._sim_loop, name='sim', daemon=True),
                         threading.Thread(target=self._render_loop, name='render',
                                          daemon=True)]
        for thread in self._threads:
            thread.start()

    # -- parameters -------------------------------------------------------------------
    def _declare_parameters(self):
        # `-p speedup:=10` arrives as an integer; accept it for a double parameter (as the
        # start script and launch files write numbers) rather than refusing the type.
        overrides = getattr(self, '_parameter_overrides', None)
        if isinstance(overrides, dict):
            for p in cfg.PARAMETERS:
                given = overrides.get(p.name)
                if given is None:
                    continue
                if p.kind == cfg.DOUBLE and given.type_ == Parameter.Type.INTEGER:
                    overrides[p.name] = Parameter(p.name, value=float(given.value))
                elif p.kind == cfg.DOUBLE_ARRAY and given.type_ == Parameter.Type.INTEGER_ARRAY:
                    overrides[p.name] = Parameter(p.name, value=[float(v) for v in given.value])
        for p in cfg.PARAMETERS:
            kw = {}
            if p.range is not None and p.kind == cfg.INT:
                kw['integer_range'] = [IntegerRange(from_value=int(p.range[0]),
                                                    to_value=int(p.range[1]), step=1)]
            elif p.range is not None and p.kind == cfg.DOUBLE:
                kw['floating_point_range'] = [FloatingPointRange(
                    from_value=float(p.range[0]), to_value=float(p.range[1]), step=0.0)]
            note = (' (read at start only)' if p.name in START_ONLY else
                    '' if p.name in cfg.LIVE_PARAMETERS else
                    ' (changes take effect at ~/reset_world)')
            descriptor = ParameterDescriptor(description=p.description + note, **kw)
            default = _TYPES[p.kind] if p.default is None else p.default
            self.declare_parameter(p.name, default, descriptor)

    def _values(self, overrides=()):
        out = {}
        for name in cfg.PARAMETER_NAMES:
            try:
                out[name] = self.get_parameter(name).value
            except rclpy.exceptions.ParameterUninitializedException:
                out[name] = None
        for param in overrides:
            out[param.name] = param.value
        return out

    def _on_set_parameters(self, params):
        params = [p for p in params if p.name in cfg.PARAMETER_NAMES]  # not use_sim_time
        if not params:
            return SetParametersResult(successful=True)
        for p in params:
            if p.name in START_ONLY:
                return SetParametersResult(successful=False,
                                           reason=f'{p.name} is read at start only: restart')
        try:
            cfg.build(self._values(params))
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        for p in params:
            if p.name == 'speedup':
                self._speedup = cfg.check_speedup(p.value)
        return SetParametersResult(successful=True)

    # -- world ------------------------------------------------------------------------
    def _build(self, config, start_time_ns):
        """(Re)build the world from `config`. Call with the lock held (or before threads)."""
        settings = config.settings
        if not settings.initial_positions and config.look_at_cube:
            q0 = look_at(self.kin, self.kin.neutral(), (0.0, 0.0, 0.0), config.cube.position)
            settings = replace(settings, initial_positions=tuple(q0))
        world = World(config.cube, np.zeros(3), config.failures, Physics(),
                      seed=config.failure_seed)
        self.sim = SimWorld(world, settings, self.kin, start_time_ns)
        cam = config.camera
        intr = self.intrinsics
        self.renderer = ArcubeRenderer(intr.K, intr.width, intr.height, edge=cam.cube_size,
                                       tag_edge=cam.tag_size, encoding=cam.encoding,
                                       effects=cam.effects, supersample=cam.supersample,
                                       seed=config.failure_seed, noise_bank=cam.noise_bank)
        self.distractors = config.distractors
        self.hidden = config.hidden
        self._tag_miss_rng = np.random.default_rng(config.failure_seed + 1)
        self.config = config
        period = settings.period_ns
        self._camera_period_ns = (int(round(1e9 / cam.rate)) if cam.rate > 0 else 0)
        self._gt_period_ns = (int(round(1e9 / config.ground_truth_rate))
                              if config.ground_truth_rate > 0 else 0)
        # Frames at whole multiples of the camera period (t = 0.1, 0.2, ... s at 10 Hz).
        self._next_camera_ns = None
        if cam.rate > 0:
            cp = self._camera_period_ns
            self._next_camera_ns = ((start_time_ns + period + cp - 1) // cp) * cp
        self._next_gt_ns = start_time_ns + period
        self._gt_now = True
        self._event_index = 0

    def _on_reset(self, request, response):
        try:
            config = cfg.build(self._values())
        except ValueError as err:
            response.success = False
            response.message = f'reset refused: {err}'
            return response
        with self._lock:
            self._build(config, self.sim.time_ns)
        self._speedup = config.speedup
        h = config.hidden
        response.success = True
        response.message = (f'world reset at t={self.sim.time:.3f} s: hidden cube '
                            f'{h.object_id} (model_index {h.model_index})')
        self.get_logger().info(response.message)
        return response

    # -- commands ---------------------------------------------------------------------
    def _on_cmd_vel(self, msg):
        try:
            with self._lock:
                self.sim.set_cmd_vel(msg.linear.x, msg.angular.z)
        except ValueError as err:
            self.get_logger().warning(f'/cmd_vel ignored: {err}')

    def _sim_seconds(self, stamp):
        ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        return 0.0 if ns == 0 else (ns - self._epoch_ns) * 1e-9

    def _on_trajectory(self, controller, msg):
        points = [TrajectoryPoint(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9,
                                  np.asarray(p.positions, dtype=float),
                                  np.asarray(p.velocities, dtype=float)
                                  if len(p.velocities) else None)
                  for p in msg.points]
        try:
            with self._lock:
                self.sim.set_trajectory(controller, list(msg.joint_names), points,
                                        self._sim_seconds(msg.header.stamp))
        except TrajectoryError as err:
            self.get_logger().warning(f'/{controller}/joint_trajectory refused: {err}')

    # -- the simulation thread --------------------------------------------------------
    def _sim_loop(self):
        try:
            self._run()
        except Exception:  # noqa: BLE001 -- report any bug loudly, then stop the node
            if self._stop.is_set() or not self.context.ok():
                return
            self._failed = True
            self.get_logger().error('simulation thread failed:\n' + traceback.format_exc())
            rclpy.try_shutdown(context=self.context)

    def _run(self):
        wall0, sim0, speedup = time.monotonic(), self.sim.time_ns, self._speedup
        report_wall, report_sim = wall0, sim0
        while not self._stop.is_set():
            if self._speedup != speedup:
                wall0, sim0, speedup = time.monotonic(), self.sim.time_ns, self._speedup
            now = time.monotonic()
            target = sim0 + (now - wall0) * speedup * 1e9
            next_ns = self.sim.time_ns + self.sim.period_ns
            if next_ns > target:
                self._stop.wait(min((next_ns - target) / (speedup * 1e9), 0.05))
                continue
            if (target - next_ns) / (speedup * 1e9) > MAX_LAG_WALL_S:
                # Too far behind to catch up smoothly: let simulation time run slower.
                wall0, sim0 = now, self.sim.time_ns
            self._tick()
            if now - report_wall > 10.0:
                factor = (self.sim.time_ns - report_sim) * 1e-9 / (now - report_wall)
                if factor < 0.9 * speedup:
                    self.get_logger().warning(
                        f'simulation runs at {factor:.2f}x wall time (speedup {speedup:g} '
                        'asked for): the machine cannot keep up')
                report_wall, report_sim = now, self.sim.time_ns

    def _tick(self):
        frame = gt = None
        with self._lock:
            sim = self.sim
            sim.step()
            t_ns = sim.time_ns
            stamp = _stamp(t_ns + self._epoch_ns)
            joints = self._joint_msg
            joints.header.stamp = stamp
            joints.position = sim.q.tolist()
            joints.velocity = sim.qd.tolist()
            odom = self._odom_msg(stamp)
            if self._next_camera_ns is not None and t_ns >= self._next_camera_ns:
                self._next_camera_ns += self._camera_period_ns
                if self._next_camera_ns <= t_ns:
                    self._next_camera_ns = t_ns + self._camera_period_ns
                frame = _Frame(stamp, sim.camera_pose(), sim.display_cube().pose(),
                               self._drawn_tags(), self.renderer, self.distractors)
            new_events = sim.events[self._event_index:]
            self._event_index = len(sim.events)
            if new_events or self._gt_now or (self._gt_period_ns and t_ns >= self._next_gt_ns):
                if self._gt_period_ns:
                    while self._next_gt_ns <= t_ns:
                        self._next_gt_ns += self._gt_period_ns
                self._gt_now = False
                gt = self._ground_truth_msg(stamp)
        if self._clock_pub is not None:
            self._clock_msg.clock = stamp
            self._clock_pub.publish(self._clock_msg)
        self._joint_pub.publish(joints)
        self._odom_pub.publish(odom)
        if gt is not None:
            self._gt_pub.publish(gt)
        for t_event, event in new_events:
            self.get_logger().info(f'[t={t_event * 1e-9:.2f} s] {event}')
        if frame is not None:
            while not self._stop.is_set():
                try:
                    self._frames.put(frame, timeout=0.1)
                    break
                except queue.Full:
                    continue

    def _odom_msg(self, stamp):
        """The (reused) odometry message: only the sim thread touches it."""
        x, y, yaw = self.sim.world.odometry_pose
        v, w = self.sim.twist
        msg = self._odom
        msg.header.stamp = stamp
        pose, twist = msg.pose.pose, msg.twist.twist
        pose.position.x, pose.position.y = float(x), float(y)
        pose.orientation.z, pose.orientation.w = float(np.sin(yaw / 2)), float(np.cos(yaw / 2))
        twist.linear.x, twist.angular.z = float(v), float(w)
        return msg

    def _ground_truth_msg(self, stamp):
        sim, h = self.sim, self.hidden
        cube = sim.display_cube()
        up, yaw = sim.discrete_state()
        base = sim.world.robot_pose
        msg = SimGroundTruth()
        msg.header.stamp = stamp
        msg.header.frame_id = ODOM_FRAME
        msg.object_id = h.object_id
        msg.model_index = int(h.model_index)
        msg.face_tags = [int(t) for t in h.face_tags]
        msg.mass_index = int(h.mass_index)
        msg.cube_pose = _pose_msg(cube.position, cube.rotation)
        msg.base_pose = _pose_msg([base[0], base[1], 0.0], _yaw_rotation(base[2]))
        msg.state, msg.up_face, msg.yaw_step = 8 * up + yaw, up, yaw
        msg.manual_actions = sim.manual_actions
        msg.last_outcome = sim.last_outcome
        return msg

    def _drawn_tags(self):
        """The face tags drawn in this frame: each is left blank (a missed tag) with
        probability p_missed_tag, the fault injection for perception."""
        tags = np.asarray(self.hidden.face_tags)
        p_missed = self.config.camera.p_missed_tag
        if p_missed <= 0:
            return tuple(int(t) for t in tags)
        missed = self._tag_miss_rng.random(tags.size) < p_missed
        return tuple(int(t) for t in np.where(missed, -1, tags))

    # -- the render thread ------------------------------------------------------------
    def _camera_info_msg(self):
        intr = self.intrinsics
        K = intr.K
        msg = CameraInfo()
        msg.header.frame_id = intr.frame_id
        msg.width, msg.height = intr.width, intr.height
        msg.distortion_model = intr.distortion_model
        msg.d = [float(v) for v in intr.distortion]
        msg.k = K.ravel().tolist()
        msg.r = np.eye(3).ravel().tolist()
        msg.p = np.hstack([K, np.zeros((3, 1))]).ravel().tolist()
        return msg

    def _render_loop(self):
        try:
            while not self._stop.is_set():
                try:
                    frame = self._frames.get(timeout=0.1)
                except queue.Empty:
                    continue
                img = frame.renderer.render(frame.camera_pose, frame.cube_pose, frame.tags,
                                            distractors=frame.distractors)
                msg = Image()
                msg.header.stamp = frame.stamp
                msg.header.frame_id = self.intrinsics.frame_id
                msg.height, msg.width = img.shape[:2]
                msg.encoding = frame.renderer.encoding
                msg.step = int(img.strides[0])
                msg.data = img.tobytes()
                info = self._camera_info
                info.header.stamp = frame.stamp
                self._image_pub.publish(msg)
                self._info_pub.publish(info)
        except Exception:  # noqa: BLE001
            if self._stop.is_set() or not self.context.ok():
                return
            self._failed = True
            self.get_logger().error('render thread failed:\n' + traceback.format_exc())
            rclpy.try_shutdown(context=self.context)

    def stop(self):
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)

    @property
    def failed(self):
        return self._failed


def main(args=None):
    failed = []

    def stop_simulation(node):
        node.stop()
        failed.append(node.failed)

    code = run_node('sim_bridge', SimBridgeNode, args, on_exit=stop_simulation)
    return 1 if any(failed) else code

if __name__ == '__main__':
    sys.exit(main())
