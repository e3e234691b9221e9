"""TEST FIXTURE (not part of the package): a minimal stand-in for the robot drivers.

Run as a process by the node tests until the sim bridge exists. It implements the
command/sensor contract of docs/INTERFACES.md and nothing else (no cube, no physics):

- /cmd_vel (TwistStamped, as Jazzy's diff_drive_controller) is integrated into /odom as a
  unicycle; the base stops when no command arrives for `--cmd-timeout` s (default 0.5; a
  long one means only a zero command stops it).
- /{torso,left_arm,right_arm,head}_controller/joint_trajectory are followed by linear
  interpolation of the points (time_from_start counts from header.stamp, a zero stamp
  meaning on receipt; the joints hold until then);
  a new trajectory replaces the running one; as Jazzy's joint_trajectory_controller, one
  without points or without every joint of the controller is refused (logged as an error
  and counted in the line "refused trajectories: N"), so a stop must be a one-point hold;
  positions are clamped to the URDF limits. It offers no FollowJointTrajectory action: the
  skills fall back to the topics here (the sim bridge offers both).
- /joint_states (all 13 joints, position and velocity) and /odom are published at 50 Hz.
- `--block-arms`: the first trajectory of each arm controller stops halfway through its
  time (as if the arm hit something) and the arm holds there; once both arms hold, the
  robot prints "arms blocked". Later trajectories are followed in full.

    python fake_robot.py [--posture home|neutral] [--cmd-timeout S] [--block-arms]
"""

import argparse
import sys
import threading
import time

import numpy as np
import rclpy
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from abp_common.qos import RELIABLE
from abp_description.controllers import CONTROLLERS
from abp_description.kinematics import RobotKinematics

HOME = {'left_shoulder_pitch_joint': 0.5, 'left_shoulder_roll_joint': 0.2,
        'left_elbow_joint': -2.0, 'right_shoulder_pitch_joint': 0.5,
        'right_shoulder_roll_joint': -0.2, 'right_elbow_joint': -2.0, 'head_tilt_joint': 1.0}


ARM_CONTROLLERS = ('left_arm_controller', 'right_arm_controller')


def cut_at(times, pos, t_cut):
    """The trajectory (times, positions) up to `t_cut`, ending there (interpolated)."""
    keep = times < t_cut
    end = [np.interp(t_cut, times, pos[:, k]) for k in range(pos.shape[1])]
    return np.append(times[keep], t_cut), np.vstack([pos[keep], end])


class FakeRobot(Node):
    def __init__(self, posture, cmd_timeout=0.5, block_arms=False):
        super().__init__('fake_robot')
        self.cmd_timeout = float(cmd_timeout)
        # Arm controllers whose next trajectory is cut halfway, and those running a cut one.
        self.to_block = set(ARM_CONTROLLERS) if block_arms else set()
        self.blocking = set()
        self.kin = RobotKinematics()
        self.lock = threading.Lock()
        self.q = self.kin.neutral()
        if posture == 'home':
            self.q = self.kin.q_from_mapping(HOME)
        self.qd = np.zeros_like(self.q)
        self.pose = np.zeros(3)
        self.cmd = (0.0, 0.0)
        self.cmd_time = -1e9
        self.active = {}   # controller -> (t0, joint indices, times, positions)
        self.refused = 0
        self.create_subscription(TwistStamped, '/cmd_vel', self.on_cmd, RELIABLE)
        for name in CONTROLLERS:
            self.create_subscription(JointTrajectory, f'/{name}/joint_trajectory',
                                     lambda msg, n=name: self.on_traj(n, msg), RELIABLE)
        self.js_pub = self.create_publisher(JointState, '/joint_states', RELIABLE)
        self.odom_pub = self.create_publisher(Odometry, '/odom', RELIABLE)
        self.last = time.monotonic()
        self.create_timer(0.02, self.step)
        self.get_logger().info('fake robot ready')

    def on_cmd(self, msg):
        with self.lock:
            self.cmd = (msg.twist.linear.x, msg.twist.angular.z)
            self.cmd_time = time.monotonic()

    def ros_now(self):
        return self.get_clock().now().nanoseconds * 1e-9

    def on_traj(self, name, msg):
        now = self.ros_now()
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        start = stamp if stamp > 0 else now   # zero stamp: start on receipt
        if not msg.points or sorted(msg.joint_names) != sorted(CONTROLLERS[name]):
            self.refused += 1
            self.get_logger().error(
                f'{name}: ' + ('Empty trajectory received.' if not msg.points else
                               "Joints on incoming trajectory don't match the controller "
                               'joints.') + f' refused trajectories: {self.refused}')
            return
        with self.lock:
            idx = [self.kin.joint_index(j) for j in msg.joint_names]
            times = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                              for p in msg.points])
            pos = np.array([p.positions for p in msg.points], dtype=float)
            # Hold until `start`, then the first segment runs from the state at receipt.
            q_now = self.q[idx][None, :]
            if times[0] > 0:
                times = np.concatenate([[0.0], times])
                pos = np.vstack([q_now, pos])
            if now < start:
                times = np.concatenate([[now - start], times])
                pos = np.vstack([q_now, pos])
            if name in self.to_block:
                self.to_block.discard(name)
                self.blocking.add(name)
                times, pos = cut_at(times, pos, times[-1] / 2)
            self.active[name] = (start, idx, times, pos)

    def step(self):
        now = time.monotonic()
        ros_now = self.ros_now()
        with self.lock:
            dt, self.last = now - self.last, now
            prev = self.q.copy()
            for name, (t0, idx, times, pos) in list(self.active.items()):
                t = ros_now - t0
                self.q[idx] = [np.interp(t, times, pos[:, k]) for k in range(len(idx))]
                if t > times[-1]:
                    del self.active[name]
                    if name in self.blocking:
                        self.blocking.discard(name)
                        if not self.blocking and not self.to_block:
                            self.get_logger().info('arms blocked')
            self.q = self.kin.clip(self.q)
            self.qd = (self.q - prev) / max(dt, 1e-6)
            v, w = self.cmd if now - self.cmd_time <= self.cmd_timeout else (0.0, 0.0)
            x, y, yaw = self.pose
            self.pose = np.array([x + v * dt * np.cos(yaw), y + v * dt * np.sin(yaw),
                                  yaw + w * dt])
            q, qd, pose = self.q.copy(), self.qd.copy(), self.pose.copy()
        stamp = self.get_clock().now().to_msg()
        js = JointState(name=list(self.kin.joint_names), position=q.tolist(),
                        velocity=qd.tolist())
        js.header.stamp = stamp
        self.js_pub.publish(js)
        odom = Odometry()
        odom.header.stamp = stamp
        odom.header.frame_id = 'odom'
        odom.child_frame_id = 'base_link'
        odom.pose.pose.position.x, odom.pose.pose.position.y = float(pose[0]), float(pose[1])
        odom.pose.pose.orientation.z = float(np.sin(pose[2] / 2))
        odom.pose.pose.orientation.w = float(np.cos(pose[2] / 2))
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = float(v), float(w)
        self.odom_pub.publish(odom)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--posture', choices=('home', 'neutral'), default='home')
    parser.add_argument('--cmd-timeout', type=float, default=0.5)
    parser.add_argument('--block-arms', action='store_true')
    args, ros_args = parser.parse_known_args()
    rclpy.init(args=[sys.argv[0], *ros_args])
    node = FakeRobot(args.posture, args.cmd_timeout, args.block_arms)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
