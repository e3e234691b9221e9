"""ROS 2 wiring of the skills: ORBIT/PUSH/LIFT/FLIP action servers and the feasibility service.

One node class hosts any subset of the four action servers; the executables differ only
in which ones (and in whether they host the feasibility service):

| executable      | node name       | hosts                                              |
|-----------------|-----------------|----------------------------------------------------|
| `orbit_server`  | `orbit_server`  | /abp/skills/orbit + /abp/skills/check_feasibility  |
| `push_server`   | `push_server`   | /abp/skills/push                                   |
| `lift_server`   | `lift_server`   | /abp/skills/lift                                   |
| `flip_server`   | `flip_server`   | /abp/skills/flip                                   |
| `skill_servers` | `skill_servers` | all four + /abp/skills/check_feasibility (one process) |

Run either the four single-skill executables (as abp_bringup does) or `skill_servers`,
not both: the feasibility service must have one host (parameter `feasibility_service`
switches it on or off in any of them).

One skill at a time, across processes: the servers of one process share a lock, and
every node publishes its state on the latched topic /abp/skills/active (std_msgs/String,
JSON `{"node", "skill", "since", "goal"}`, `skill` empty when idle) and reads the others'.
A goal arriving while any skill runs (here or in another process) is accepted and
immediately aborted with `reason` "rejected: busy: ..." (a rejected goal could carry no
reason). Two goals claimed at the same moment in two processes are settled after
`claim_settle_time`: the earlier claim wins, the other aborts.

Subscribes:  /joint_states, /odom, /abp/aspect_observation (the cube pose estimate:
             hypotheses[0].object_pose, in base_link or any URDF frame), /abp/skills/active
Publishes:   /cmd_vel, /{torso,left_arm,right_arm,head}_controller/joint_trajectory,
             /abp/skills/active
Actions:     /abp/skills/{orbit,push,lift,flip} (abp_msgs/action/*)
Service:     /abp/skills/check_feasibility (abp_msgs/srv/CheckFeasibility)

Cancelling a goal stops the robot (zero /cmd_vel, an empty trajectory = hold on every
controller) and ends it canceled. The science is in `plans`, `ik`, `trajectories`.
"""

import json
import sys
import threading
import time
import uuid
from dataclasses import fields

import numpy as np
import rclpy
from builtin_interfaces.msg import Duration as DurationMsg
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.duration import Duration as RclpyDuration
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from abp_description.kinematics import RobotKinematics
from abp_msgs.action import Flip, Lift, Orbit, Push
from abp_msgs.msg import AspectObservation
from abp_msgs.srv import CheckFeasibility

from .ik import CONTROLLERS, look_at
from .plans import ACTIONS, PlanError, SkillConfig, SkillPlanner
from .trajectories import BaseLimits, OrbitTracker, plan_base_approach

LATCHED = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                     durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
LATCHED_READER = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE,
                            durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)

SKILL_TYPES = {'orbit': Orbit, 'push': Push, 'lift': Lift, 'flip': Flip}
ACTIVE_TOPIC = '/abp/skills/active'
FEASIBILITY_SERVICE = '/abp/skills/check_feasibility'

# Node-only parameters: (default, description, (low, high) or None).
NODE_PARAMETERS = {
    'max_estimate_age': (5.0, 'Seconds after which a cube pose estimate is too old to act on.',
                         (0.1, 3600.0)),
    'max_state_age': (1.0, 'Seconds after which /joint_states or /odom count as lost.',
                      (0.05, 60.0)),
    'timeout': (120.0, 'Seconds a skill may run before it stops and aborts.', (1.0, 3600.0)),
    'control_rate': (20.0, 'Hz of the base control loop and of progress checks.',
                     (1.0, 200.0)),
    'goal_tolerance': (0.05, 'rad: joints within this of a phase end count as arrived.',
                       (0.001, 1.0)),
    'settle_timeout': (2.0, 'Seconds to wait for the joints (or the base) to arrive after '
                       'a phase.', (0.0, 60.0)),
    'claim_settle_time': (0.2, 'Seconds a new goal waits to detect a simultaneous goal in '
                          'another skills process.', (0.0, 5.0)),
    'trajectory_start_delay': (0.1, 'Seconds ahead of now of the common header.stamp of '
                               'the controllers\' trajectories; 0 = zero stamp (start on '
                               'receipt).', (0.0, 5.0)),
    'orbit_radius': (0.0, 'Default ORBIT radius (m) when the goal gives none; 0 = keep the '
                     'current distance (clamped to orbit_min_radius..orbit_max_radius).',
                     (0.0, 5.0)),
    'orbit_yaw_tolerance_deg': (2.0, 'ORBIT ends when bearing and heading are within this.',
                                (0.1, 45.0)),
    'orbit_position_tolerance': (0.02, 'm, radius tolerance at the end of ORBIT.',
                                 (0.001, 0.5)),
}
# Descriptions of the SkillConfig fields exposed as parameters.
CONFIG_DESCRIPTIONS = {
    'cube_size': 'm, ARcube edge.',
    'support_height': 'm, height of the surface the cube rests on, in base_link.',
    'use_estimated_height': 'Take the cube centre height from the estimate (else '
                            'support_height + cube_size / 2).',
    'hand_radius': 'm, radius of the hands\' contact balls (sim bridge: 0.03).',
    'grasp_squeeze': 'm, how far a grasp presses into the faces.',
    'approach_gap': 'm, free space between hand and face before contact and after release.',
    'hover_height': 'm, via point above the pre-contact posture.',
    'push_hand': 'Hand that pushes: left or right.',
    'push_stroke': 'm, hand travel beyond first contact (the sim slides the cube after 2 cm).',
    'lift_height': 'm, default lift height.',
    'flip_grasp_offset': 'm, FLIP contacts this far from the face centres towards the robot.',
    'flip_up': 'm, FLIP roll: hands up.',
    'flip_back': 'm, FLIP roll: hands back towards the robot.',
    'flip_roll_deg': 'Default FLIP roll angle (shape of the hands\' roll path).',
    'joint_velocity_scale': 'Fraction of the URDF velocity limits used by trajectories.',
    'joint_acceleration': 'rad/s^2, joint acceleration limit.',
    'joint_jerk': 'rad/s^3, joint jerk limit.',
    'cartesian_velocity': 'm/s, hand speed on contact, stroke and release paths.',
    'cartesian_acceleration': 'm/s^2 on hand paths.',
    'cartesian_jerk': 'm/s^3 on hand paths.',
    'sample_dt': 's between trajectory points.',
    'ik_tolerance': 'm, IK position tolerance.',
    'collision_margin': 'm, clearance required between arm parts and the body.',
    'check_stride': 'Collision-check every n-th trajectory sample of a skill to run.',
    'feasibility_check_stride': 'The same for /abp/skills/check_feasibility answers.',
    'base_approach': 'PUSH/LIFT/FLIP first drive the base to manipulation_distance.',
    'manipulation_distance': 'm, cube centre distance for PUSH/LIFT/FLIP.',
    'max_base_approach': 'm, the furthest the base approach may drive.',
    'approach_tolerance': 'm, no base approach when the cube is this close to '
                          'manipulation_distance (and within 5 deg of straight ahead).',
    'orbit_min_radius': 'm, smallest ORBIT radius (turning in place clears the cube).',
    'orbit_max_radius': 'm, largest ORBIT radius.',
}
BASE_DESCRIPTIONS = {
    'linear_velocity': 'm/s', 'linear_acceleration': 'm/s^2', 'linear_jerk': 'm/s^3',
    'angular_velocity': 'rad/s', 'angular_acceleration': 'rad/s^2', 'angular_jerk': 'rad/s^3',
}


class Refused(Exception):
    """The skill cannot start (or continue); the message is the result's reason."""


def _range(low, high):
    return [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]


def yaw_of(q):
    """Yaw of a geometry_msgs Quaternion."""
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


def quaternion_matrix(q):
    x, y, z, w = q.x, q.y, q.z, q.w
    n = x * x + y * y + z * z + w * w
    if n < 1e-12:
        return np.eye(3)
    s = 2.0 / n
    return np.array([
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)]])


def base_to_odom(pose, point):
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([x + c * point[0] - s * point[1], y + s * point[0] + c * point[1],
                     point[2]])


def odom_to_base(pose, point):
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = point[0] - x, point[1] - y
    return np.array([c * dx + s * dy, -s * dx + c * dy, point[2]])


class SkillsNode(Node):
    def __init__(self, node_name='skill_servers', skills=tuple(SKILL_TYPES),
                 feasibility=True):
        super().__init__(node_name)
        self._declare_parameters(feasibility)
        # The planner owns one Pinocchio model/data (used under _plan_lock); the node's
        # own forward kinematics (head aiming, estimate frames) use another (_fk_lock).
        self.kin = RobotKinematics()
        self.planner = SkillPlanner(RobotKinematics(), self._config())  # raises on bad params
        self._plan_lock = threading.Lock()
        self._fk_lock = threading.Lock()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._group = ReentrantCallbackGroup()
        self._state_lock = threading.Lock()
        self._run_lock = threading.Lock()
        self._q = None              # (13,) latest joint positions
        self._q_time = None
        self._odom = None           # (x, y, yaw)
        self._odom_time = None
        self._estimate = None       # (cube centre in odom (3,), receipt time, frame note)
        self._active = None         # dict of the running skill, or None
        self._peers = {}            # node -> dict from /abp/skills/active
        self._fqn = self.get_fully_qualified_name()
        self._moved = False         # the running goal has sent motion commands

        self._cmd_pub = self.create_publisher(Twist, '/cmd_vel', RELIABLE)
        self._traj_pubs = {
            name: self.create_publisher(JointTrajectory, f'/{name}_controller/joint_trajectory',
                                        RELIABLE)
            for name in CONTROLLERS
        }
        self._active_pub = self.create_publisher(String, ACTIVE_TOPIC, LATCHED)
        self.create_subscription(JointState, '/joint_states', self._on_joint_states, RELIABLE,
                                 callback_group=self._group)
        self.create_subscription(Odometry, '/odom', self._on_odom, RELIABLE,
                                 callback_group=self._group)
        self.create_subscription(AspectObservation, '/abp/aspect_observation',
                                 self._on_observation, RELIABLE, callback_group=self._group)
        self.create_subscription(String, ACTIVE_TOPIC, self._on_active, LATCHED_READER,
                                 callback_group=self._group)
        self._servers = []
        for skill in skills:
            self._servers.append(ActionServer(
                self, SKILL_TYPES[skill], f'/abp/skills/{skill}',
                execute_callback=lambda handle, s=skill: self._execute(s, handle),
                goal_callback=lambda _goal: GoalResponse.ACCEPT,
                cancel_callback=lambda _handle: CancelResponse.ACCEPT,
                callback_group=self._group))
        self._service = None
        if self.get_parameter('feasibility_service').value:
            self._service = self.create_service(CheckFeasibility, FEASIBILITY_SERVICE,
                                                self._on_feasibility,
                                                callback_group=self._group)
        self._publish_active()
        hosted = ', '.join(f'/abp/skills/{s}' for s in skills) or 'no action servers'
        self.get_logger().info(
            f'skills ready: {hosted}' + (f'; {FEASIBILITY_SERVICE}' if self._service else ''))

    # -- parameters -----------------------------------------------------------------------
    def _declare_parameters(self, feasibility):
        def declare(name, default, description, bounds=None):
            kwargs = {}
            if bounds is not None and isinstance(default, float):
                kwargs['floating_point_range'] = _range(*bounds)
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, **kwargs))

        declare('feasibility_service', bool(feasibility),
                f'Host {FEASIBILITY_SERVICE} in this process.')
        for name, (default, description, bounds) in NODE_PARAMETERS.items():
            declare(name, default, description, bounds)
        defaults = SkillConfig()
        for f in fields(SkillConfig):
            if f.name == 'base':
                continue
            value = getattr(defaults, f.name)
            bounds = (-1.0, 10.0) if f.name == 'support_height' else (0.0, 1000.0)
            declare(f.name, value, CONFIG_DESCRIPTIONS.get(f.name, f.name), bounds)
        for f in fields(BaseLimits):
            declare(f'base_{f.name}', getattr(defaults.base, f.name),
                    f'Base {f.name.replace("_", " ")} limit, {BASE_DESCRIPTIONS[f.name]}.',
                    (0.0, 100.0))

    def _config(self, overrides=None):
        names = [f.name for f in fields(SkillConfig) if f.name != 'base']
        names += [f'base_{f.name}' for f in fields(BaseLimits)]
        values = {n: self.get_parameter(n).value for n in names}
        values.update(overrides or {})
        base = BaseLimits(**{f.name: float(values[f'base_{f.name}']) for f in fields(BaseLimits)})
        kwargs = {f.name: values[f.name] for f in fields(SkillConfig) if f.name != 'base'}
        config = SkillConfig(**kwargs, base=base).validate()
        for f in fields(BaseLimits):
            if not getattr(base, f.name) > 0:
                raise ValueError(f'base_{f.name} must be > 0')
        return config

    def _on_set_parameters(self, params):
        overrides = {p.name: p.value for p in params}
        if 'feasibility_service' in overrides:
            return SetParametersResult(successful=False,
                                       reason='feasibility_service needs a restart')
        try:
            config = self._config(overrides)
        except (ValueError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        with self._plan_lock:
            self.planner = SkillPlanner(self.planner.kin, config)
        return SetParametersResult(successful=True)

    def _param(self, name):
        return self.get_parameter(name).value

    # -- inputs ---------------------------------------------------------------------------
    def _now(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_joint_states(self, msg):
        positions = dict(zip(msg.name, msg.position))
        with self._state_lock:
            self._q = self.kin.q_from_mapping(positions, default=self._q)
            self._q_time = self._now()

    def _on_odom(self, msg):
        p = msg.pose.pose
        with self._state_lock:
            self._odom = np.array([p.position.x, p.position.y, yaw_of(p.orientation)])
            self._odom_time = self._now()

    def _on_observation(self, msg):
        if not msg.hypotheses:
            return
        pose = msg.hypotheses[0].object_pose.pose
        point = np.array([pose.position.x, pose.position.y, pose.position.z])
        if not np.all(np.isfinite(point)):
            return
        frame = msg.header.frame_id.lstrip('/')
        with self._state_lock:
            q, odom = self._q, self._odom
        if frame not in ('', 'base_link'):
            if not self.kin.has_frame(frame) or q is None:
                self.get_logger().warning(
                    f'cube estimate in frame {frame!r} cannot be put in base_link '
                    '(unknown frame or no /joint_states yet); ignored',
                    throttle_duration_sec=10.0)
                return
            with self._fk_lock:
                tf = self.kin.frame_pose(q, frame)
            point = tf[:3, :3] @ point + tf[:3, 3]
        in_odom = base_to_odom(odom if odom is not None else np.zeros(3), point)
        with self._state_lock:
            self._estimate = (in_odom, self._now())

    def _on_active(self, msg):
        try:
            state = json.loads(msg.data)
            node = str(state['node'])
        except (ValueError, KeyError, TypeError):
            return
        if node == self._fqn:
            return
        with self._state_lock:
            self._peers[node] = state

    def _wait_first(self, attribute):
        """Just after start-up, give a sensor topic up to max_state_age to arrive."""
        deadline = time.monotonic() + self._param('max_state_age')
        while getattr(self, attribute) is None and time.monotonic() < deadline:
            time.sleep(0.02)

    def _joints(self):
        self._wait_first('_q')
        with self._state_lock:
            q, stamp = self._q, self._q_time
        if q is None:
            raise Refused('refused: no /joint_states received')
        age = self._now() - stamp
        if age > self._param('max_state_age'):
            raise Refused(f'refused: /joint_states is {age:.1f} s old')
        return q.copy()

    def _base_pose(self, required=True):
        if required:
            self._wait_first('_odom')
        with self._state_lock:
            pose, stamp = self._odom, self._odom_time
        if pose is None or self._now() - stamp > self._param('max_state_age'):
            if required:
                raise Refused('refused: no recent /odom' if pose is None else
                              f'refused: /odom is {self._now() - stamp:.1f} s old')
            return None
        return pose.copy()

    def _cube(self):
        """The cube centre in base_link now, from the latest estimate (moved by odometry
        since it arrived)."""
        with self._state_lock:
            estimate, odom = self._estimate, self._odom
        if estimate is None:
            raise Refused('refused: no cube pose estimate (nothing on /abp/aspect_observation '
                          'with a hypothesis)')
        in_odom, stamp = estimate
        age = self._now() - stamp
        limit = self._param('max_estimate_age')
        if age > limit:
            raise Refused(f'refused: the cube pose estimate is {age:.1f} s old '
                          f'(max_estimate_age {limit:.1f} s)')
        return odom_to_base(odom if odom is not None else np.zeros(3), in_odom), in_odom

    # -- the one-skill-at-a-time claim ------------------------------------------------------
    def _publish_active(self):
        state = self._active or {}
        self._active_pub.publish(String(data=json.dumps({
            'node': self._fqn, 'skill': state.get('skill', ''),
            'since': state.get('since', 0.0), 'goal': state.get('goal', '')})))

    def _busy_peers(self):
        live = {f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                for i in self.get_publishers_info_by_topic(ACTIVE_TOPIC)}
        with self._state_lock:
            for node in [n for n in self._peers if n not in live]:
                del self._peers[node]  # that process is gone
            return [dict(p) for p in self._peers.values() if p.get('skill')]

    def _claim(self, skill):
        """None when this goal may run (the claim is held), else why not."""
        if not self._run_lock.acquire(blocking=False):
            running = (self._active or {}).get('skill', 'another skill')
            return f'rejected: busy: {running} is running'
        busy = self._busy_peers()
        if busy:
            self._run_lock.release()
            return f'rejected: busy: {busy[0]["skill"]} is running ({busy[0]["node"]})'
        self._active = {'skill': skill, 'since': time.time(), 'goal': uuid.uuid4().hex}
        self._publish_active()
        if self.count_publishers(ACTIVE_TOPIC) > 1:
            time.sleep(self._param('claim_settle_time'))
            mine = (self._active['since'], self._fqn)
            for peer in self._busy_peers():
                if (float(peer.get('since', 0.0)), str(peer['node'])) < mine:
                    self._release()
                    return (f'rejected: busy: {peer["skill"]} started at the same time '
                            f'({peer["node"]})')
        return None

    def _release(self):
        self._active = None
        self._publish_active()
        self._run_lock.release()

    # -- outputs --------------------------------------------------------------------------
    def stop_motion(self):
        """Zero base velocity and hold every controller (an empty trajectory)."""
        for _ in range(3):
            self._cmd_pub.publish(Twist())
        for name, joints in CONTROLLERS.items():
            self._traj_pubs[name].publish(JointTrajectory(joint_names=list(joints)))

    def _send_trajectory(self, trajectory):
        """Send a SampledTrajectory over BODY_JOINTS to the four controllers at once, with
        one common start stamp `trajectory_start_delay` ahead (docs/INTERFACES.md: the
        controllers then start together). Returns the start time (node clock, s)."""
        self._moved = True
        delay = self._param('trajectory_start_delay')
        now = self.get_clock().now()
        start = now.nanoseconds * 1e-9 + delay
        stamp = (now + RclpyDuration(seconds=delay)).to_msg() if delay > 0 else None
        for name, joints in CONTROLLERS.items():
            part = trajectory.select(joints)
            msg = JointTrajectory(joint_names=list(joints))
            if stamp is not None:
                msg.header.stamp = stamp
            for t, p, v, a in zip(part.times, part.positions, part.velocities,
                                  part.accelerations):
                sec = int(t)
                msg.points.append(JointTrajectoryPoint(
                    positions=p.tolist(), velocities=v.tolist(), accelerations=a.tolist(),
                    time_from_start=DurationMsg(sec=sec, nanosec=int(round((t - sec) * 1e9)))))
            self._traj_pubs[name].publish(msg)
        return start

    def _send_head(self, q, cube_base):
        with self._fk_lock:
            q_look, _ = look_at(self.kin, q, cube_base)
        joints = CONTROLLERS['head']
        idx = [self.kin.joint_index(n) for n in joints]
        msg = JointTrajectory(joint_names=list(joints))
        msg.points.append(JointTrajectoryPoint(
            positions=q_look[idx].tolist(), velocities=[0.0] * len(idx),
            time_from_start=DurationMsg(sec=0, nanosec=200_000_000)))
        self._traj_pubs['head'].publish(msg)

    # -- execution ------------------------------------------------------------------------
    def _execute(self, skill, goal_handle):
        started = self._now()
        why = self._claim(skill)
        if why is not None:
            self.get_logger().info(f'{skill}: {why}')
            return self._finish(skill, goal_handle, 'abort', why, started)
        self._moved = False
        try:
            outcome, reason = self._run(skill, goal_handle, started)
        except Refused as refusal:
            outcome, reason = 'abort', str(refusal)
        except Exception as error:  # never leave the robot moving
            self.get_logger().error(f'{skill}: internal error: {error!r}')
            outcome, reason = 'abort', f'internal error: {error}'
        if outcome != 'succeed' and self._moved:
            self.stop_motion()
        self._release()
        return self._finish(skill, goal_handle, outcome, reason, started)

    def _finish(self, skill, goal_handle, outcome, reason, started):
        result = SKILL_TYPES[skill].Result()
        result.success = outcome == 'succeed'
        result.reason = reason
        elapsed = max(0.0, self._now() - started)
        result.duration = DurationMsg(sec=int(elapsed),
                                      nanosec=int((elapsed - int(elapsed)) * 1e9))
        if outcome == 'succeed':
            goal_handle.succeed()
        elif outcome == 'cancel' and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        text = f'{skill}: {outcome} after {elapsed:.1f} s' + (f' ({reason})' if reason else '')
        if result.success:
            self.get_logger().info(text)
        else:
            self.get_logger().warning(text)
        return result

    def _run(self, skill, goal_handle, started):
        goal = goal_handle.request
        if skill == 'orbit':
            return self._run_orbit(goal_handle, goal, started)
        if skill == 'push':
            face = (goal.face or 'front').strip().lower()
            if face != 'front':
                raise Refused(f'refused: PUSH supports only the front face, not {goal.face!r}')
            overrides = {'push_stroke': goal.stroke_length}
        elif skill == 'lift':
            overrides = {'lift_height': goal.lift_height}
        else:
            overrides = {'flip_roll_deg': goal.roll_deg}
        for name, value in overrides.items():
            if not np.isfinite(value) or value < 0:
                raise Refused(f'refused: {name} must be >= 0, got {value}')
        return self._run_manual(skill, goal_handle, overrides, started)

    def _check_goal(self, goal_handle, started):
        """None to go on, or (outcome, reason) to stop now."""
        if goal_handle.is_cancel_requested:
            return 'cancel', 'canceled'
        if not goal_handle.is_active:
            return 'abort', 'goal no longer active'
        limit = self._param('timeout')
        if self._now() - started > limit:
            return 'abort', f'timeout: the skill took more than {limit:.0f} s'
        if not rclpy.ok(context=self.context):
            return 'abort', 'shutting down'
        return None

    def _feedback(self, skill, goal_handle, phase, progress):
        fb = SKILL_TYPES[skill].Feedback()
        fb.phase = phase
        fb.progress = float(np.clip(progress, 0.0, 1.0))
        goal_handle.publish_feedback(fb)

    def _sleep(self, seconds):
        """Sleep on the node's clock (sim time when use_sim_time is set), at most a few
        wall seconds so that a stopped /clock cannot block cancel and timeout checks."""
        end = self._now() + seconds
        wall_end = time.monotonic() + max(0.5, 5.0 * seconds)
        while self._now() < end and time.monotonic() < wall_end:
            time.sleep(min(0.01, max(0.0, end - self._now())))

    def _drive(self, skill, goal_handle, started, plan, progress_of, head_q=None):
        """Track a base plan (OrbitPlan) on /odom. Returns None or (outcome, reason)."""
        cfg = self.planner.config
        tracker = OrbitTracker(plan, cfg.base,
                               yaw_tolerance=np.radians(self._param('orbit_yaw_tolerance_deg')),
                               position_tolerance=self._param('orbit_position_tolerance'),
                               settle_time=max(self._param('settle_timeout'), 0.5))
        period = 1.0 / self._param('control_rate')
        t0 = self._now()
        last_feedback = -1.0
        while True:
            stop = self._check_goal(goal_handle, started)
            if stop:
                return stop
            pose = self._base_pose(required=False)
            if pose is None:
                return 'abort', 'odometry lost: no recent /odom'
            t = self._now() - t0
            v, w, phase, done, ok = tracker.command(t, pose)
            if done:
                self._cmd_pub.publish(Twist())
                if ok:
                    return None
                b, h, r = tracker.final_errors(pose)
                return 'abort', (f'the base did not settle: bearing {np.degrees(b):.1f} deg, '
                                 f'heading {np.degrees(h):.1f} deg, radius {100 * r:.1f} cm off')
            cmd = Twist()
            cmd.linear.x, cmd.angular.z = v, w
            self._moved = True
            self._cmd_pub.publish(cmd)
            if head_q is not None:
                cube_base = odom_to_base(pose, np.array([*plan.cube_xy, head_q[1]]))
                with self._state_lock:
                    q = self._q.copy() if self._q is not None else head_q[0]
                self._send_head(q, cube_base)
            if t - last_feedback >= 0.25:
                self._feedback(skill, goal_handle, phase,
                               progress_of(min(t, plan.duration) / max(plan.duration, 1e-6)))
                last_feedback = t
            self._sleep(period)

    def _move(self, skill, goal_handle, started, name, trajectory, progress_of):
        """Send one phase trajectory and wait for it to end and the joints to arrive."""
        t0 = self._send_trajectory(trajectory)
        period = 1.0 / self._param('control_rate')
        last_feedback = -1.0
        settle = self._param('settle_timeout')
        tol = self._param('goal_tolerance')
        idx = [self.kin.joint_index(n) for n in trajectory.joint_names]
        ended_wall = None
        while True:
            stop = self._check_goal(goal_handle, started)
            if stop:
                return stop
            t = self._now() - t0
            if t - last_feedback >= 0.25:
                frac = min(max(t, 0.0), trajectory.duration) / max(trajectory.duration, 1e-6)
                self._feedback(skill, goal_handle, name, progress_of(frac))
                last_feedback = t
            if t >= trajectory.duration:
                q = self._joints()
                err = np.abs(q[idx] - trajectory.end)
                if np.max(err) <= tol:
                    return None
                # Settle in sim time *and* wall time: at a high sim speed-up on a busy
                # machine the joint states can lag the sim clock by more than `settle`.
                if ended_wall is None:
                    ended_wall = time.monotonic()
                if (t >= trajectory.duration + settle
                        and time.monotonic() - ended_wall >= settle):
                    worst = trajectory.joint_names[int(np.argmax(err))]
                    return 'abort', (f'the joints did not reach the end of the {name} phase '
                                     f'({worst} {np.max(err):.3f} rad off)')
            self._sleep(period)

    def _run_orbit(self, goal_handle, goal, started):
        angle = float(goal.angle_deg)
        cube_base, cube_odom = self._cube()
        q = self._joints()
        pose = self._base_pose()
        radius = goal.radius if goal.radius > 0 else self._param('orbit_radius')
        with self._plan_lock:
            try:
                plan = self.planner.orbit_plan(angle, pose, cube_base, radius)
            except (PlanError, ValueError) as error:
                raise Refused(f'refused: {error}') from error
            home = self.planner.go_home(q, look=cube_base)
        total = plan.duration + (home.duration if home is not None else 0.0)
        done = 0.0
        if home is not None:
            stop = self._move('orbit', goal_handle, started, 'approach', home,
                              lambda f: f * home.duration / total)
            if stop:
                return stop
            done = home.duration
        stop = self._drive('orbit', goal_handle, started, plan,
                           lambda f: (done + f * plan.duration) / total,
                           head_q=(self._joints(), cube_odom[2]))
        if stop:
            return stop
        self._feedback('orbit', goal_handle, 'stroke', 1.0)
        return 'succeed', ''

    def _run_manual(self, skill, goal_handle, overrides, started):
        cube_base, cube_odom = self._cube()
        q = self._joints()
        with self._plan_lock:
            needed, ok, reason, cube_after = self.planner.base_approach(cube_base)
            if not ok:
                raise Refused(f'refused: {reason}')
            # Check the arm plan where the arms will work before moving anything.
            plan = self.planner.plan(skill, q, cube_after, **overrides)
        if not plan.ok:
            raise Refused(f'refused: {plan.reason}')
        base_plan = None
        if needed:
            pose = self._base_pose()
            base_plan = plan_base_approach(pose, cube_odom[:2],
                                           self.planner.config.manipulation_distance,
                                           self.planner.config.base)
        total = plan.duration + (base_plan.duration if base_plan is not None else 0.0)
        done = 0.0
        if base_plan is not None and base_plan.segments:
            stop = self._drive(skill, goal_handle, started, base_plan,
                               lambda f: f * base_plan.duration / total)
            if stop:
                return stop
            done = base_plan.duration
            pose = self._base_pose()
            cube_base = odom_to_base(pose, cube_odom)
            q = self._joints()
            with self._plan_lock:
                plan = self.planner.plan(skill, q, cube_base, **overrides)
            if not plan.ok:
                return 'abort', f'after the base approach: {plan.reason}'
            total = done + plan.duration
        for phase in plan.phases:
            start = done
            stop = self._move(skill, goal_handle, started, phase.name, phase.trajectory,
                              lambda f, s=start, d=phase.duration: (s + f * d) / total)
            if stop:
                return stop
            done += phase.duration
        self._feedback(skill, goal_handle, plan.phases[-1].name, 1.0)
        return 'succeed', ''

    # -- feasibility ----------------------------------------------------------------------
    def _on_feasibility(self, request, response):
        actions = list(request.actions) or list(ACTIONS)
        try:
            cube_base, _ = self._cube()
            why = None
        except Refused as refusal:
            cube_base, why = None, str(refusal).replace('refused: ', '', 1)
        q = None
        if self._q is not None:
            try:
                q = self._joints()
            except Refused:
                q = None
        response.actions = actions
        with self._plan_lock:
            if q is None:
                q = self.planner.home(self.kin.neutral())  # as it will be when idle
            for action in actions:
                if why is not None:
                    ok, reason = False, why
                else:
                    ok, reason = self.planner.feasibility(action, q, cube_base)
                response.feasible.append(bool(ok))
                response.reasons.append('' if ok else reason)
        return response


def _main(node_name, skills, feasibility, args=None):
    rclpy.init(args=args)
    try:
        node = SkillsNode(node_name, skills, feasibility)
    except (ValueError, TypeError, rclpy.exceptions.ParameterException) as error:
        print(f'[{node_name}] configuration error: {error}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=8)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # Ctrl-C shuts the context down under a running callback; only a
        # failure while the context is still valid is a real error.
        if rclpy.ok():
            raise
    finally:
        try:
            node.stop_motion()
        except Exception:  # the context may already be gone
            pass
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(args=None):
    """All four action servers and the feasibility service in one process."""
    return _main('skill_servers', tuple(SKILL_TYPES), True, args)


def orbit_main(args=None):
    """ORBIT, and (parameter feasibility_service, default true) the feasibility service."""
    return _main('orbit_server', ('orbit',), True, args)


def push_main(args=None):
    return _main('push_server', ('push',), False, args)


def lift_main(args=None):
    return _main('lift_server', ('lift',), False, args)


def flip_main(args=None):
    return _main('flip_server', ('flip',), False, args)


if __name__ == '__main__':
    sys.exit(main())
