"""ROS 2 wiring of the simulated robot and ARcube world: the `sim_bridge` node.

It stands in for the uBot-6 drivers through the robot's own topics (docs/INTERFACES.md):

Subscribes:  /cmd_vel (geometry_msgs/TwistStamped, as Jazzy's diff_drive_controller;
             `base_command_type: twist` for geometry_msgs/Twist; topic
             `base_command_topic`)
             /torso_controller/joint_trajectory, /left_arm_controller/joint_trajectory,
             /right_arm_controller/joint_trajectory, /head_controller/joint_trajectory
             (trajectory_msgs/JointTrajectory)
Actions:     /<controller>/follow_joint_trajectory (control_msgs/FollowJointTrajectory)
             for the same four controllers
Publishes:   /clock (rosgraph_msgs/Clock; when publish_clock)
             /joint_states (sensor_msgs/JointState, 13 joints), /odom (nav_msgs/Odometry)
             /camera/image_raw (sensor_msgs/Image; JPEG on .../compressed with
             publish_compressed), /camera/camera_info (reliable: a subscriber chooses
             sensor data QoS or reliable; abp_common.qos)
             /abp/sim/ground_truth (abp_msgs/SimGroundTruth: the first cube), /abp/sim/
             scene_truth (SimSceneTruth: every cube), transient local; TESTS, BENCHMARKS
Services:    ~/reset_world (std_srvs/Trigger): rebuild the world (cube, base at the origin,
             initial joints) from the current parameters; simulation time goes on.

The world is `world:=rules` (rules_world + flat_renderer) or `world:=mujoco` (MuJoCo
physics and rendering), chosen in `worlds`.

Threads: the executor (main thread) takes commands and services; a simulation thread
steps the world at `rate` Hz of simulation time, paced to `speedup` x wall time
(`sim_timing.Pacer`), and publishes clock, joint states, odometry (keep-last 100:
`STATE_WRITER`) and ground truth; a render thread draws camera
frames (scene snapshots taken by the simulation thread at `camera_rate`). The simulation
never waits for the renderer: a frame that falls due while the previous one is still
being rendered, or sooner than `camera_max_wall_rate` allows in wall time, is skipped (not
queued, not drawn; counted in /diagnostics), since the detector could not take it
either. Joint states and odometry go out at `state_rate` and at every tick that takes a
frame (an image always has the joint state at its stamp), /clock at most
`clock_max_wall_rate` times per wall second and at every frame (docs/SPEED.md).
Rendering stays in the render thread (MuJoCo's GL context belongs to the thread that
rendered first): a reset's new camera is first used, and the old one closed, there.

The four controllers behave as Jazzy's joint_trajectory_controller (topic and action):
a trajectory without points, or one that leaves out some of the controller's joints, is
refused with the controller's own error; a new trajectory replaces the running one; a
goal ends SUCCESSFUL once its trajectory ended with the joints within its goal tolerance,
aborts on a path or goal tolerance violation or a preemption, and a cancel holds the
joints where they are (`joint_trajectory_follower`, `controller_goals`).

Commands are checked before they reach the world: non-finite numbers, unknown joints,
sizes that disagree, oversized trajectories and start stamps from the past or the far
future are rejected, counted in /diagnostics and logged at most once per few seconds per
kind (abp_common.health); the world keeps the last good command.

Topic names are relative (abp_common.names), so the node runs under a namespace; /clock
stays absolute. The science lives in the package's other modules (`worlds` first).
"""

import queue
import sys
import threading
import time
import traceback
from dataclasses import dataclass

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import MultiThreadedExecutor
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from abp_common import base_command, input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all, read_all
from abp_description import camera_intrinsics
from abp_description.kinematics import RobotKinematics
from abp_description.robot_profile import PROFILE_SPEC, load_profile, with_profile_defaults
from abp_msgs.msg import SimGroundTruth, SimSceneTruth

from . import config as cfg
from . import sim_messages
from .controller_servers import (
    EXECUTOR_THREADS,
    ControllerActions,
    check_trajectory,
    trajectory_points,
)
from .joint_trajectory_follower import TrajectoryError
from .scenario import drawn_tags
from .sim_timing import (
    BaseCommandWait,
    CameraSchedule,
    GroundTruthSchedule,
    Pacer,
    StateSchedule,
    WallRateLimit,
    sim_seconds,
)
from .worlds import check_rendering, make_world

ODOM_FRAME = 'odom'
COMMAND_POLL_S = 0.002   # wall s between looks for a late base command (BaseCommandWait)
# A keep-last writer drops unacknowledged samples: 10 (~30 ms at 10x) lost some under load.
STATE_WRITER = qos.reliable(100)


@dataclass
class _Frame:
    """What the render thread needs to draw one camera frame."""
    stamp: object       # builtin_interfaces/Time
    camera: object      # worlds.FlatCamera or worlds.MujocoCamera
    snapshot: tuple     # camera.capture(...)


class SimBridgeNode(ManagedNode):
    """Configure builds the world; activate opens the topics and starts the simulation
    and render threads; deactivate stops them (abp_common.lifecycle)."""

    def __init__(self):
        super().__init__('sim_bridge')
        self._stop = threading.Event()
        self._render_idle = threading.Event()   # set: the render thread can take a frame
        self.frames_skipped = 0
        self._failed = False
        self._threads = []

    def configure(self):
        # The robot profile first: it sets the defaults of the base command parameters.
        profile = load_profile(declare_all(self, (PROFILE_SPEC,))['robot_profile'])
        try:
            values = declare_all(self, with_profile_defaults(cfg.PARAMETERS[1:], profile),
                                 note=cfg.description_note)
            values['robot_profile'] = profile.path
        except rclpy.exceptions.InvalidParameterTypeException as error:
            raise ValueError(f'{error} (write a double with a decimal point, e.g. '
                             'speedup:=10.0, and integer arrays as [1,2,3])') from error
        self.config = cfg.build(values)
        if self.config.world == 'mujoco' and self.config.camera.rate > 0:
            check_rendering()  # no EGL: a configuration error with the fix, not a traceback
        self.kin, frames = RobotKinematics(profile=profile), profile.frames
        self.intrinsics = camera_intrinsics(profile.camera_calibration, frames.camera_optical)
        self.lock = threading.Lock()
        self._epoch_ns = 0  # publish_clock false: wall-clock time at the start (below)
        self._build(self.config, start_time_ns=0)
        self.health = NodeHealth(self)
        self.health.add_values(lambda: [
            ('camera frames skipped (renderer busy or above camera_max_wall_rate)',
             self.frames_skipped),
            ('late base commands waited for (command_wait)', self._command_wait.waits)])
        # The simulation is the clock the commands are stamped in: it is trusted.
        self._trajectory_stamps = {c: self.health.stamp_check(zero_is_now=True,
                                                              trust_clock=True)
                                   for c in profile.controller_joints}
        self._controller_actions = ControllerActions(
            self, self.config.values['stopped_velocity_tolerance'])
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._camera_info = sim_messages.camera_info(self.intrinsics)
        self._joint_msg = JointState(name=list(self.kin.joint_names))
        self._odom = Odometry()
        self._odom.header.frame_id = ODOM_FRAME
        self._odom.child_frame_id = profile.frames.base
        self._clock_msg = Clock()
        self.get_logger().info(
            f'sim_bridge: {self.config.world} world, {cfg.scene_summary(self.config)}, '
            f'{self.config.settings.rate:g} Hz, camera {self.config.camera.rate:g} Hz, '
            f'speedup {self.config.speedup:g}, publish_clock {self.config.publish_clock}')
        if not self.config.publish_clock:
            self._epoch_ns = time.time_ns()
        self._pacer = Pacer(self.config.speedup, self.sim.time_ns)

    def activate(self):
        self._pacer = Pacer(self.config.speedup, self.sim.time_ns)   # wall time starts now
        self._clock_pub = (self.create_publisher(Clock, names.CLOCK, qos.RELIABLE)
                           if self.config.publish_clock else None)
        self._joint_pub = self.create_publisher(JointState, names.JOINT_STATES, STATE_WRITER)
        self._odom_pub = self.create_publisher(Odometry, names.ODOM, STATE_WRITER)
        self._image_pub = self.create_publisher(Image, names.IMAGE, qos.CAMERA_PUBLISHER)
        self._compressed_pub = (self.create_publisher(
            CompressedImage, sim_messages.COMPRESSED_IMAGE, qos.CAMERA_PUBLISHER)
            if self.config.values['publish_compressed'] else None)
        self._info_pub = self.create_publisher(CameraInfo, names.CAMERA_INFO,
                                               qos.CAMERA_PUBLISHER)
        self._gt_pub = self.create_publisher(SimGroundTruth, names.GROUND_TRUTH, qos.LATCHED)
        self._scene_pub = self.create_publisher(SimSceneTruth, names.SCENE_TRUTH, qos.LATCHED)
        values = self.config.values
        self.health.subscribe(base_command.message_type(values['base_command_type']),
                              values['base_command_topic'], self._on_cmd_vel, qos.RELIABLE)
        for controller in self.kin.profile.controller_joints:
            self.health.subscribe(
                JointTrajectory, names.trajectory_topic(controller),
                lambda msg, c=controller: self._on_trajectory(c, msg), qos.RELIABLE)
        self._controller_actions.serve()
        # ~/reset_world: names.RESET_WORLD for the node named sim_bridge.
        self.create_service(Trigger, '~/reset_world', self._on_reset)
        self._frames = queue.Queue(maxsize=1)
        self._render_idle.set()
        self._stop.clear()
        self._threads = [threading.Thread(target=self._sim_loop, name='sim', daemon=True),
                         threading.Thread(target=self._render_loop, name='render',
                                          daemon=True)]
        for thread in self._threads:
            thread.start()

    def deactivate(self):
        self.stop()

    # -- parameters and the world -----------------------------------------------------
    def _on_set_parameters(self, params):
        reason = cfg.refusal(read_all(self, cfg.PARAMETERS), {p.name: p.value for p in params})
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        for p in params:
            if p.name == 'speedup':
                self._pacer.set_speedup(cfg.check_speedup(p.value))
        return SetParametersResult(successful=True)

    def _build(self, config, start_time_ns):
        """(Re)build the world from `config`. Call with the lock held (or before threads)."""
        self.sim, self.camera = make_world(config, self.kin, self.intrinsics, start_time_ns)
        cam = config.camera
        self.hidden, self.hiddens = config.hidden, config.hiddens
        self._tag_miss_rng = np.random.default_rng(config.failure_seed + 1)
        self.config = config
        tick_ns = self.sim.period_ns
        self._camera_schedule = CameraSchedule(cam.rate, start_time_ns, tick_ns)
        self._gt_schedule = GroundTruthSchedule(config.ground_truth_rate, start_time_ns,
                                                tick_ns)
        values = config.values
        self._state_schedule = StateSchedule(values['state_rate'], start_time_ns, tick_ns)
        self._clock_limit = WallRateLimit(values['clock_max_wall_rate'])
        self._clock_sent_ns = None   # the simulation time last sent on /clock
        self._camera_limit = WallRateLimit(values['camera_max_wall_rate'])
        self._command_wait = BaseCommandWait(values['command_wait'])
        self._event_index = 0

    def _on_reset(self, request, response):
        try:
            config = cfg.build(read_all(self, cfg.PARAMETERS))
            with self.lock:
                self._build(config, self.sim.time_ns)
        except ValueError as err:
            response.success = False
            response.message = f'reset refused: {err}'
            return response
        self._pacer.set_speedup(config.speedup)
        response.success = True
        response.message = (f'world reset at t={self.sim.time:.3f} s: '
                            f'{cfg.scene_summary(config)}')
        self.get_logger().info(response.message)
        return response

    # -- commands ---------------------------------------------------------------------
    def _on_cmd_vel(self, msg):
        """Raises input_checks.Rejected for a bad command (NodeHealth counts it)."""
        twist = base_command.twist_of(msg)
        input_checks.point('cmd_vel linear', twist.linear)
        input_checks.point('cmd_vel angular', twist.angular)
        try:
            with self.lock:
                self.sim.set_cmd_vel(twist.linear.x, twist.angular.z)
        except ValueError as err:
            raise Rejected('out_of_range', str(err)) from None

    def _sim_now_ns(self):
        """The simulation's time as the stamps of the commands count it."""
        return self.sim.time_ns + self._epoch_ns

    def trajectory_start_s(self, controller, stamp):
        """A trajectory's header.stamp in the simulation's seconds (0: on receipt);
        raises Rejected for a stamp from the past or the far future."""
        stamp_ns = self._trajectory_stamps[controller].check(stamp, self._sim_now_ns())
        return sim_seconds(stamp_ns, self._epoch_ns)

    def stopping(self):
        return self._stop.is_set() or not self.context.ok()

    def _on_trajectory(self, controller, msg):
        """Raises input_checks.Rejected for a trajectory the controller refuses."""
        check_trajectory(msg, self.kin.profile.controller_joints[controller])
        stamps = self._trajectory_stamps[controller]
        now_ns = self._sim_now_ns()
        stamp_ns = stamps.check(msg.header.stamp, now_ns)
        late_s = (now_ns - stamp_ns) * 1e-9
        if (msg.header.stamp.sec or msg.header.stamp.nanosec) and late_s > 0 and msg.points:
            # Accepted (ros2_control's convention) but it starts part-way along its path:
            # a hand that skips its approach can miss the cube. Say so, at most every 5 s.
            self.get_logger().warning(
                f'a {controller} trajectory arrived {late_s:.2f} s of simulation time after '
                'its start stamp: it starts part-way along its path (stamp it further ahead '
                'at this speed-up)', throttle_duration_sec=5.0)
        try:
            with self.lock:
                self.sim.set_trajectory(controller, list(msg.joint_names),
                                        trajectory_points(msg),
                                        sim_seconds(stamp_ns, self._epoch_ns))
        except TrajectoryError as err:
            raise Rejected('malformed', str(err)) from None
        stamps.taken(msg.header.stamp)

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
        pacer = self._pacer
        while not self._stop.is_set():
            sim = self.sim
            wait_s = pacer.wait_s(sim.time_ns, sim.time_ns + sim.period_ns)
            if wait_s == 0 and self._command_wait.hold(sim.time_ns, sim.cmd, sim.cmd_time_ns,
                                                       time.monotonic()):
                self._publish_held_clock(sim.time_ns)
                wait_s = COMMAND_POLL_S
            if wait_s > 0:
                self._stop.wait(wait_s)
                continue
            self._tick()
            factor = pacer.ticked(self.sim.time_ns)
            if factor is not None:
                self.get_logger().warning(
                    f'simulation runs at {factor:.2f}x wall time (speedup {pacer.speedup:g} '
                    'asked for): the machine cannot keep up')

    def _publish_clock(self, t_ns, stamp):
        if self._clock_pub is not None:
            self._clock_msg.clock = stamp
            self._clock_pub.publish(self._clock_msg)
        self._clock_sent_ns = t_ns

    def _publish_held_clock(self, t_ns):
        """Waiting for a late base command: the skills must see the time waited at (a
        loop sleeping on an older, rate-capped /clock would wait out its 0.5 s wall cap)."""
        if self._clock_sent_ns != t_ns:
            self._publish_clock(t_ns, sim_messages.stamp(t_ns + self._epoch_ns))

    def _take_frame(self, t_ns, wall_now):
        """Whether this tick takes a camera frame: one is due, the renderer is free and
        the wall-clock rate allows it. Otherwise a due frame is skipped, never queued."""
        if not self._camera_schedule.due(t_ns):
            return False
        if not (self._render_idle.is_set() and self._camera_limit.ready(wall_now)):
            self.frames_skipped += 1
            return False
        self._camera_limit.taken(wall_now)
        self._render_idle.clear()
        return True

    def _tick(self):
        frame = gt = joints = odom = None
        started = time.perf_counter()
        wall_now = time.monotonic()
        with self.lock:
            sim = self.sim
            sim.step()
            t_ns = sim.time_ns
            stamp = sim_messages.stamp(t_ns + self._epoch_ns)
            if self._take_frame(t_ns, wall_now):
                tags = tuple(drawn_tags(h.face_tags, self.config.camera.p_missed_tag,
                                        self._tag_miss_rng) for h in self.hiddens)
                frame = _Frame(stamp, self.camera, self.camera.capture(sim, tags))
            if self._state_schedule.due(t_ns, forced=frame is not None):
                joints = self._joint_msg
                joints.header.stamp = stamp
                joints.position = sim.q.tolist()
                joints.velocity = sim.qd.tolist()
                odom = sim_messages.fill_odometry(self._odom, stamp, self.sim)
            send_clock = frame is not None or self._clock_limit.ready(wall_now)
            if send_clock:
                self._clock_limit.taken(wall_now)
            goal_ends = self._controller_actions.judge()
            new_events = sim.events[self._event_index:]
            self._event_index = len(sim.events)
            if self._gt_schedule.due(t_ns, events=bool(new_events)):
                scene = sim_messages.scene_truth(self.sim, self.hiddens, stamp, ODOM_FRAME)
                gt = scene.cubes[0]
        self.health.latency(time.perf_counter() - started)
        self._controller_actions.report(goal_ends)
        if send_clock:
            self._publish_clock(t_ns, stamp)
        if joints is not None:
            self._joint_pub.publish(joints)
            self._odom_pub.publish(odom)
        if gt is not None:
            self._gt_pub.publish(gt)
            self._scene_pub.publish(scene)
        for t_event, event in new_events:
            self.get_logger().info(f'[t={t_event * 1e-9:.2f} s] {event}')
        if frame is not None:
            self._frames.put_nowait(frame)   # the slot is free: the renderer was idle

    # -- the render thread ------------------------------------------------------------
    def _render_loop(self):
        camera = None
        try:
            while not self._stop.is_set():
                try:
                    frame = self._frames.get(timeout=0.1)
                except queue.Empty:
                    continue
                if frame.camera is not camera:  # a reset's new world: free the old one here
                    if camera is not None:
                        camera.close()
                    camera = frame.camera
                img = camera.render(frame.snapshot)
                msg = sim_messages.image(img, camera.encoding, frame.stamp,
                                         self.intrinsics.frame_id)
                self._camera_info.header.stamp = frame.stamp
                self._image_pub.publish(msg)
                sim_messages.publish_compressed(self._compressed_pub, img, camera.encoding,
                                                self.config.values['jpeg_quality'], msg.header)
                self._info_pub.publish(self._camera_info)
                self._render_idle.set()
        except Exception:  # noqa: BLE001
            if self._stop.is_set() or not self.context.ok():
                return
            self._failed = True
            self.get_logger().error('render thread failed:\n' + traceback.format_exc())
            rclpy.try_shutdown(context=self.context)
        finally:
            if camera is not None:
                camera.close()

    def stop(self):
        """Stop the threads; returns True when one of them failed."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        return self._failed


def main(args=None):
    failed = []  # a simulation or render thread failed: exit code 1
    code = run_node('sim_bridge', SimBridgeNode, args,
                    make_executor=lambda: MultiThreadedExecutor(num_threads=EXECUTOR_THREADS),
                    on_exit=lambda node: failed.append(node.stop()))
    return 1 if any(failed) else code


if __name__ == '__main__':
    sys.exit(main())
