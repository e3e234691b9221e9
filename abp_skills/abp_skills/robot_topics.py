"""ROS wiring of the robot's topics for the skills: sensors in, commands out.

`RobotInputs` subscribes /joint_states, /odom and /abp/aspect_observation (the cube pose
estimate: hypotheses[0].object_pose, in the base frame or any URDF frame) and feeds the node's
`RobotState`; malformed messages (abp_common.input_checks: non-finite values, sizes that
disagree, frames not in the URDF, stamps from the past or the future) are rejected and
counted in the node's /diagnostics (`SkillsContext.health`, abp_common.health). `RobotCommands`
commands the base (TwistStamped or Twist) and every controller of the robot profile
(FollowJointTrajectory goals on <controller>/follow_joint_trajectory, or JointTrajectory
on <controller>/joint_trajectory, the only way for a controller whose profile interface is
`topic`), as Jazzy's ros2_control controllers take them. Names are relative (abp_common.names).
"""

import queue
import threading
import time

import numpy as np
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration as DurationMsg
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from nav_msgs.msg import Odometry
from rclpy.action import ActionClient
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.duration import Duration as RclpyDuration
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from abp_common import base_command, input_checks, names
from abp_common.input_checks import Rejected
from abp_common.qos import RELIABLE
from abp_common.server_handshake import ask_action_server
from abp_description.frames import yaw_of_quaternion
from abp_description.kinematics import look_at
from abp_msgs.msg import AspectObservation

from .skill_checks import Refused

HEAD_MOVE_S = 0.2   # time_from_start of a head aiming point
FOLLOW_JOINT_TRAJECTORY = '{controller}/follow_joint_trajectory'
HANDSHAKE_TIMEOUT_S = 2.0
STATUS_NAMES = {GoalStatus.STATUS_ABORTED: 'aborted', GoalStatus.STATUS_CANCELED: 'canceled',
                GoalStatus.STATUS_SUCCEEDED: 'succeeded'}


def duration_msg(seconds):
    sec = int(seconds)
    return DurationMsg(sec=sec, nanosec=int(round((seconds - sec) * 1e9)))


class RobotInputs:
    """The robot's sensor topics and the cube estimate into `context.state` (a RobotState;
    `context`: a SkillsContext), subscribed on `input_node`, the node of the skills node's
    InputNode (abp_common.input_node: at sensor rates, the skills node's ~60 entities made
    its executor's wake-ups most of its CPU)."""

    def __init__(self, context, input_node):
        self.ctx = context
        health = context.health
        self._observation_stamps = health.stamp_check()
        node = input_node
        health.subscribe(JointState, names.JOINT_STATES, self._on_joint_states, RELIABLE,
                         node=node)
        health.subscribe(Odometry, names.ODOM, self._on_odom, RELIABLE, node=node)
        health.subscribe(AspectObservation, names.ASPECT_OBSERVATION, self._on_observation,
                         RELIABLE, node=node)

    def _on_joint_states(self, msg):
        input_checks.joint_state(msg)
        positions = dict(zip(msg.name, msg.position))
        if not any(self.ctx.kin.has_joint(n) for n in positions):
            raise Rejected('unknown_id', 'joint_states names no joint of the robot')
        self.ctx.state.set_joint_positions(positions)
        self.ctx.clock_rate.feed(time.monotonic(), self.ctx.now())

    def _on_odom(self, msg):
        input_checks.odometry(msg)
        p = msg.pose.pose
        o = p.orientation
        self.ctx.state.set_odom((p.position.x, p.position.y,
                                  yaw_of_quaternion(o.x, o.y, o.z, o.w)))

    def _on_observation(self, msg):
        input_checks.aspect_observation(msg)
        stamps = self._observation_stamps
        stamps.check(msg.header.stamp, self.ctx.health.now_ns())
        stamps.taken(msg.header.stamp)
        if not msg.hypotheses:
            return
        pose = msg.hypotheses[0].object_pose.pose
        point = np.array([pose.position.x, pose.position.y, pose.position.z])
        frame = msg.header.frame_id.lstrip('/')
        if frame not in ('', self.ctx.kin.profile.frames.base):
            ctx = self.ctx
            if not ctx.kin.has_frame(frame):
                raise Rejected('frame', f'cube estimate in frame {frame[:40]!r}, which is not '
                                        'in the URDF')
            q = ctx.state.latest_joints()
            if q is None:
                raise Rejected('no_joint_states', f'cube estimate in frame {frame!r} cannot '
                                                  'be put in the base frame before '
                                                  '/joint_states')
            with ctx.fk_lock:
                tf = ctx.kin.frame_pose(q, frame)
            point = tf[:3, :3] @ point + tf[:3, 3]
        self.ctx.state.set_cube_estimate(point)


class RobotCommands:
    """The base command and the controllers' trajectories, as Jazzy's controllers take
    them; `moved` tells whether anything was sent since the last `reset_moved()` (a failed
    goal that moved nothing needs no stop).

    The base: geometry_msgs/TwistStamped (diff_drive_controller) or Twist on
    `base_command_topic` (abp_common.base_command). Trajectories: one
    control_msgs/FollowJointTrajectory goal per controller (`trajectory_interface` action,
    or auto where the controller offers the action), so that goal tolerances and aborts
    reach the skill (`trajectory_outcome`), else trajectory_msgs/JointTrajectory on the
    controller's topic. A stop is a one-point hold at the measured position on every
    controller (what the controller itself does after a cancel): a trajectory without
    points is refused by Jazzy's joint_trajectory_controller and never sent."""

    def __init__(self, context):
        self.ctx = context
        node = context.ros
        self.moved = False
        self._base_kind = context.param('base_command_type')
        self._base_topic = context.param('base_command_topic')
        self._cmd_pub = node.create_publisher(base_command.message_type(self._base_kind),
                                              self._base_topic, RELIABLE)
        profile = context.kin.profile
        self._controllers = profile.controller_joints   # name -> joints, message order
        self._head = profile.head.controller
        self._traj_pubs = {
            name: node.create_publisher(JointTrajectory, names.trajectory_topic(name), RELIABLE)
            for name in self._controllers
        }
        self._interface = context.param('trajectory_interface')
        self._calls = None if self._interface == 'topic' else ClientCalls(node)
        self._clients = {} if self._interface == 'topic' else {
            c.name: ActionClient(node, FollowJointTrajectory,
                                 FOLLOW_JOINT_TRAJECTORY.format(controller=c.name),
                                 callback_group=self._calls.group)
            for c in profile.controllers if c.interface == 'action'}
        self._answering = set()     # controllers whose action server answered a handshake
        self._goals = {}            # controller -> _Goal of the last trajectory sent by action

    def reset_moved(self):
        self.moved = False

    # -- the base ----------------------------------------------------------------------
    def _publish_base(self, v, w):
        self._cmd_pub.publish(base_command.command(
            self._base_kind, v, w, self.ctx.ros.get_clock().now().to_msg(),
            self.ctx.kin.profile.frames.base))

    def velocity(self, v, w):
        """Drive the base at v (m/s), ω (rad/s)."""
        self.moved = True
        self._publish_base(v, w)

    def stop_base(self):
        self._publish_base(0.0, 0.0)

    def base_listener_problem(self):
        """Why the base command reaches nobody (a sentence), or None: no subscriber on the
        topic, or subscribers of the other message type (DDS would carry nothing and say
        nothing)."""
        node = self.ctx.ros
        topic = node.resolve_topic_name(self._base_topic)
        endpoints = node.get_subscriptions_info_by_topic(topic)
        mismatch = base_command.type_mismatch(self._base_kind, topic, endpoints)
        if mismatch and self._cmd_pub.get_subscription_count() == 0:
            return mismatch
        if not endpoints:
            return f'nothing subscribes to {topic}, the base command topic'
        return None

    # -- the controllers ---------------------------------------------------------------
    def stop_motion(self):
        """Zero base velocity and hold every controller where its joints are. A controller
        running a goal of ours gets a cancel: Jazzy's controller then holds the position
        it measures itself. Every other controller gets a one-point hold at the position
        measured here: a hold sent by topic to a running goal's controller would pull
        the joints back to where /joint_states last showed them (seen: 0.6 s of motion
        when the joint states reached this node late)."""
        for _ in range(3):
            self.stop_base()
        cancelled = {name for name, goal in self._goals.items() if goal.cancel()}
        q = self.ctx.state.latest_joints()
        if q is None:       # no joint state ever: nothing to hold at (and nothing moved)
            return
        for name, joints in self._controllers.items():
            if name in cancelled:
                continue
            idx = [self.ctx.kin.joint_index(j) for j in joints]
            msg = JointTrajectory(joint_names=list(joints))
            msg.points.append(JointTrajectoryPoint(
                positions=q[idx].tolist(), velocities=[0.0] * len(idx),
                time_from_start=duration_msg(0.0)))
            self._traj_pubs[name].publish(msg)

    def send_trajectory(self, trajectory, start_delay_s, tolerance=None, settle_s=None):
        """Send a SampledTrajectory over BODY_JOINTS to the four controllers at once, with
        one common start stamp `start_delay_s` of wall time ahead, in clock time at the
        clock's measured rate (docs/INTERFACES.md: the controllers then start together;
        0 = zero stamp, start on receipt). By action, each goal asks the joints to end
        within `tolerance` (rad) of the end, at most `settle_s` after it. Returns the start
        time (node clock, s)."""
        self.moved = True
        start_delay_s *= self.ctx.clock_rate.rate()
        now = self.ctx.ros.get_clock().now()
        start = now.nanoseconds * 1e-9 + start_delay_s
        stamp = (now + RclpyDuration(seconds=start_delay_s)).to_msg() if start_delay_s > 0 \
            else None
        for name, joints in self._controllers.items():
            part = trajectory.select(joints)
            msg = JointTrajectory(joint_names=list(joints))
            if stamp is not None:
                msg.header.stamp = stamp
            for t, p, v, a in zip(part.times, part.positions, part.velocities,
                                  part.accelerations):
                msg.points.append(JointTrajectoryPoint(
                    positions=p.tolist(), velocities=v.tolist(), accelerations=a.tolist(),
                    time_from_start=duration_msg(t)))
            self._send(name, msg, tolerance, settle_s)
        return start

    def aim_head(self, q, cube_base):
        """Point the camera at `cube_base` (base_link) from the joints `q` (on the topic:
        a stream of short aiming moves, each replacing the last, needs no result)."""
        ctx = self.ctx
        with ctx.fk_lock:
            q_look, _ = look_at(ctx.kin, q, cube_base)
        joints = self._controllers[self._head]
        idx = [ctx.kin.joint_index(n) for n in joints]
        msg = JointTrajectory(joint_names=list(joints))
        msg.points.append(JointTrajectoryPoint(
            positions=q_look[idx].tolist(), velocities=[0.0] * len(idx),
            time_from_start=duration_msg(HEAD_MOVE_S)))
        self._traj_pubs[self._head].publish(msg)
        self._goals.pop(self._head, None)

    def trajectory_outcome(self):
        """The controllers' verdict on the last trajectory sent by action: None while any
        goal runs (or when the last trajectory went by topic: see `by_action`), else
        (True, '') when every goal succeeded, or (False, reason)."""
        goals = self._goals.values()
        if not goals or any(g.outcome is None for g in goals):
            return None
        failed = [f'{g.controller}: {g.outcome[1]}' for g in goals if not g.outcome[0]]
        return (False, '; '.join(failed)) if failed else (True, '')

    @property
    def by_action(self):
        """Whether the last trajectory went to every controller by action."""
        return len(self._goals) == len(self._controllers)

    def _uses_action(self, name):
        if self._interface == 'topic' or name not in self._clients:
            return False   # topic only (parameter, or the controller's profile interface)
        client = self._clients[name]
        if name not in self._answering:
            action = self.ctx.ros.resolve_topic_name(
                FOLLOW_JOINT_TRAJECTORY.format(controller=name))
            if not client.server_is_ready():
                if self._interface == 'action':
                    raise Refused(f'{action} has no action server (trajectory_interface: '
                                  'action)')
                return False
            # A goal sent before the server has discovered this client can be lost
            # (abp_common.server_handshake): ask once, then trust it.
            answered = threading.Event()
            self._calls.run(lambda: ask_action_server(client).add_done_callback(
                lambda _f: answered.set()))
            if not answered.wait(HANDSHAKE_TIMEOUT_S):
                if self._interface == 'action':
                    raise Refused(f'{action} did not answer within {HANDSHAKE_TIMEOUT_S:g} s')
                return False
            self._answering.add(name)
        return True

    def _send(self, name, msg, tolerance=None, settle_s=None):
        if not self._uses_action(name):
            self._goals.pop(name, None)
            self._traj_pubs[name].publish(msg)
            return
        goal = FollowJointTrajectory.Goal(trajectory=msg)
        if tolerance is not None:
            # Positions only: a joint pressed against the cube may keep a small tremor, and
            # the topic path judges arrival by position alone too (-1 erases velocity).
            goal.goal_tolerance = [JointTolerance(name=j, position=float(tolerance),
                                                  velocity=-1.0) for j in msg.joint_names]
        if settle_s is not None:
            goal.goal_time_tolerance = duration_msg(max(float(settle_s), 1e-3))
        client = self._clients[name]
        tracked = _Goal(name, self._calls)
        self._goals[name] = tracked
        self._calls.run(lambda: client.send_goal_async(goal).add_done_callback(
            tracked.on_response))


class ClientCalls:
    """Runs action-client requests inside the clients' own mutually exclusive callback
    group. Jazzy's rclpy ActionClient files a request's future under its sequence number
    only after sending it: sent from another thread while the executor runs, a quick
    response can be taken first and is then dropped ("Ignoring unexpected goal response"),
    and the goal's future never completes. In the clients' group, no response of theirs
    is handled while a request is being filed."""

    def __init__(self, node):
        self.group = MutuallyExclusiveCallbackGroup()
        self._pending = queue.SimpleQueue()
        self._logger = node.get_logger()
        self._guard = node.create_guard_condition(self._run_pending, callback_group=self.group)

    def run(self, call):
        self._pending.put(call)
        self._guard.trigger()

    def _run_pending(self):
        while True:
            try:
                call = self._pending.get_nowait()
            except queue.Empty:
                return
            try:
                call()
            except Exception as error:  # noqa: BLE001 -- one failed request is reported
                self._logger.error(f'action client request failed: {error!r}')


class _Goal:
    """One FollowJointTrajectory goal and, once known, its outcome (ok, reason)."""

    def __init__(self, controller, calls):
        self.controller = controller
        self.outcome = None
        self._calls = calls
        self._lock = threading.Lock()
        self._handle = None
        self._cancel = False

    def cancel(self):
        """Cancel the goal, now or as soon as the controller has accepted it. True when
        the goal runs or may still run (its controller stops on the cancel), False when
        it has ended (its controller holds already)."""
        with self._lock:
            self._cancel = True
            handle = self._handle
        if self.outcome is not None:
            return False
        if handle is not None:
            self._calls.run(handle.cancel_goal_async)
        return True

    def on_response(self, future):
        handle = future.result()
        if handle is None or not handle.accepted:
            self.outcome = (False, 'goal rejected by the controller (see its log)')
            return
        with self._lock:
            self._handle = handle
            cancel = self._cancel
        if cancel:
            self._calls.run(handle.cancel_goal_async)
        self._calls.run(lambda: handle.get_result_async().add_done_callback(self._on_result))

    def _on_result(self, future):
        response = future.result()
        result = response.result
        if response.status == GoalStatus.STATUS_SUCCEEDED and \
                result.error_code == FollowJointTrajectory.Result.SUCCESSFUL:
            self.outcome = (True, '')
        else:
            status = STATUS_NAMES.get(response.status, str(response.status))
            self.outcome = (False, f'{status}: {result.error_string or result.error_code}')


__all__ = ['RobotCommands', 'RobotInputs']
