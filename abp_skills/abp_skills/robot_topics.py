"""ROS wiring of the robot's topics for the skills: sensors in, commands out.

`RobotInputs` subscribes /joint_states, /odom and /abp/aspect_observation (the cube pose
estimate: hypotheses[0].object_pose, in base_link or any URDF frame) and feeds the node's
`RobotState`; malformed messages (abp_common.input_checks: non-finite values, sizes that
disagree, frames not in the URDF, stamps from the past or the future) are rejected and
counted in the node's /diagnostics (`node.health`, abp_common.health). `RobotCommands`
publishes /cmd_vel and the JointTrajectory of every controller of
`abp_description.controllers.CONTROLLERS` (/<controller>/joint_trajectory). Names are
relative (abp_common.names).
"""

import time

import numpy as np
from builtin_interfaces.msg import Duration as DurationMsg
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.duration import Duration as RclpyDuration
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from abp_common import input_checks, names
from abp_common.input_checks import Rejected
from abp_common.qos import RELIABLE
from abp_description.controllers import CONTROLLERS
from abp_description.frames import yaw_of_quaternion
from abp_description.kinematics import look_at
from abp_msgs.msg import AspectObservation

HEAD_CONTROLLER = 'head_controller'
HEAD_MOVE_S = 0.2   # time_from_start of a head aiming point


def duration_msg(seconds):
    sec = int(seconds)
    return DurationMsg(sec=sec, nanosec=int(round((seconds - sec) * 1e9)))


class RobotInputs:
    """The robot's sensor topics and the cube estimate into `node.state` (a RobotState)."""

    def __init__(self, node):
        self.node = node
        health = node.health
        self._observation_stamps = health.stamp_check()
        # Each topic on its own exclusive group: in the node's reentrant group two threads
        # could take two messages of one topic and store the older one last.
        health.subscribe(JointState, names.JOINT_STATES, self._on_joint_states,
                         RELIABLE, callback_group=MutuallyExclusiveCallbackGroup())
        health.subscribe(Odometry, names.ODOM, self._on_odom, RELIABLE,
                         callback_group=MutuallyExclusiveCallbackGroup())
        health.subscribe(AspectObservation, names.ASPECT_OBSERVATION, self._on_observation,
                         RELIABLE, callback_group=MutuallyExclusiveCallbackGroup())

    def _on_joint_states(self, msg):
        input_checks.joint_state(msg)
        positions = dict(zip(msg.name, msg.position))
        if not any(self.node.kin.has_joint(n) for n in positions):
            raise Rejected('unknown_id', 'joint_states names no joint of the robot')
        self.node.state.set_joint_positions(positions)
        self.node.clock_rate.feed(time.monotonic(), self.node.now())

    def _on_odom(self, msg):
        input_checks.odometry(msg)
        p = msg.pose.pose
        o = p.orientation
        self.node.state.set_odom((p.position.x, p.position.y,
                                  yaw_of_quaternion(o.x, o.y, o.z, o.w)))

    def _on_observation(self, msg):
        input_checks.aspect_observation(msg)
        stamps = self._observation_stamps
        stamps.check(msg.header.stamp, self.node.health.now_ns())
        stamps.taken(msg.header.stamp)
        if not msg.hypotheses:
            return
        pose = msg.hypotheses[0].object_pose.pose
        point = np.array([pose.position.x, pose.position.y, pose.position.z])
        frame = msg.header.frame_id.lstrip('/')
        if frame not in ('', 'base_link'):
            node = self.node
            if not node.kin.has_frame(frame):
                raise Rejected('frame', f'cube estimate in frame {frame[:40]!r}, which is not '
                                        'in the URDF')
            q = node.state.latest_joints()
            if q is None:
                raise Rejected('no_joint_states', f'cube estimate in frame {frame!r} cannot '
                                                  'be put in base_link before /joint_states')
            with node.fk_lock:
                tf = node.kin.frame_pose(q, frame)
            point = tf[:3, :3] @ point + tf[:3, 3]
        self.node.state.set_cube_estimate(point)


class RobotCommands:
    """/cmd_vel and the controllers' trajectories; `moved` tells whether anything was sent
    since the last `reset_moved()` (a failed goal that moved nothing needs no stop)."""

    def __init__(self, node):
        self.node = node
        self.moved = False
        self._cmd_pub = node.create_publisher(Twist, names.CMD_VEL, RELIABLE)
        self._traj_pubs = {
            name: node.create_publisher(JointTrajectory, names.trajectory_topic(name), RELIABLE)
            for name in CONTROLLERS
        }

    def reset_moved(self):
        self.moved = False

    def velocity(self, v, w):
        """Drive the base at v (m/s), ω (rad/s)."""
        cmd = Twist()
        cmd.linear.x, cmd.angular.z = float(v), float(w)
        self.moved = True
        self._cmd_pub.publish(cmd)

    def stop_base(self):
        self._cmd_pub.publish(Twist())

    def stop_motion(self):
        """Zero base velocity and hold every controller (an empty trajectory)."""
        for _ in range(3):
            self._cmd_pub.publish(Twist())
        for name, joints in CONTROLLERS.items():
            self._traj_pubs[name].publish(JointTrajectory(joint_names=list(joints)))

    def send_trajectory(self, trajectory, start_delay_s):
        """Send a SampledTrajectory over BODY_JOINTS to the four controllers at once, with
        one common start stamp `start_delay_s` of wall time ahead, in clock time at the
        clock's measured rate (docs/INTERFACES.md: the controllers then start together;
        0 = zero stamp, start on receipt). Returns the start time (node clock, s)."""
        self.moved = True
        start_delay_s *= self.node.clock_rate.rate()
        now = self.node.get_clock().now()
        start = now.nanoseconds * 1e-9 + start_delay_s
        stamp = (now + RclpyDuration(seconds=start_delay_s)).to_msg() if start_delay_s > 0 \
            else None
        for name, joints in CONTROLLERS.items():
            part = trajectory.select(joints)
            msg = JointTrajectory(joint_names=list(joints))
            if stamp is not None:
                msg.header.stamp = stamp
            for t, p, v, a in zip(part.times, part.positions, part.velocities,
                                  part.accelerations):
                msg.points.append(JointTrajectoryPoint(
                    positions=p.tolist(), velocities=v.tolist(), accelerations=a.tolist(),
                    time_from_start=duration_msg(t)))
            self._traj_pubs[name].publish(msg)
        return start

    def aim_head(self, q, cube_base):
        """Point the camera at `cube_base` (base_link) from the joints `q`."""
        node = self.node
        with node.fk_lock:
            q_look, _ = look_at(node.kin, q, cube_base)
        joints = CONTROLLERS[HEAD_CONTROLLER]
        idx = [node.kin.joint_index(n) for n in joints]
        msg = JointTrajectory(joint_names=list(joints))
        msg.points.append(JointTrajectoryPoint(
            positions=q_look[idx].tolist(), velocities=[0.0] * len(idx),
            time_from_start=duration_msg(HEAD_MOVE_S)))
        self._traj_pubs[HEAD_CONTROLLER].publish(msg)


__all__ = ['RobotCommands', 'RobotInputs']
