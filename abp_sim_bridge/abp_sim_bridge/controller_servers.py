"""The sim bridge's trajectory controllers as ROS sees them: what their topics accept
(`check_trajectory`) and their control_msgs/FollowJointTrajectory action servers
(`ControllerActions`), with the semantics of Jazzy's joint_trajectory_controller. The
decisions are plain Python (`joint_trajectory_follower`, `controller_goals`); this module
wires them to rclpy for the sim_bridge node.
"""

import threading

import numpy as np
from control_msgs.action import FollowJointTrajectory
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from abp_common import input_checks
from abp_common.input_checks import Rejected

from .controller_goals import INVALID_GOAL, GoalEnd, GoalMonitor
from .joint_trajectory_follower import TrajectoryError, TrajectoryPoint

FOLLOW_JOINT_TRAJECTORY = '{controller}/follow_joint_trajectory'
# Executor threads of the sim bridge: each running FollowJointTrajectory goal keeps one
# (four controllers), and the topics and services need the rest.
EXECUTOR_THREADS = 8


class ControllerActions:
    """One FollowJointTrajectory action server per controller of the `node` (a
    SimBridgeNode: its world `sim` under `lock`, `trajectory_start_s`, `stopping`). The
    simulation thread calls `judge` each tick (lock held) and `report` after it."""

    def __init__(self, node, stopped_velocity_tolerance):
        self.node = node
        self._controllers = node.kin.profile.controller_joints   # the robot profile's
        self._monitors = {c: GoalMonitor(joints, stopped_velocity_tolerance)
                          for c, joints in self._controllers.items()}
        self._ends = {}    # goal id -> (threading.Event, [GoalEnd]) of running goals

    def serve(self):
        """Create the action servers (at activation)."""
        node = self.node
        group = ReentrantCallbackGroup()
        for controller in self._controllers:
            ActionServer(
                node, FollowJointTrajectory, FOLLOW_JOINT_TRAJECTORY.format(controller=controller),
                execute_callback=self._execute_goal,
                goal_callback=lambda goal, c=controller: self._on_goal_request(c, goal),
                handle_accepted_callback=lambda handle, c=controller:
                    self._on_goal_accepted(c, handle),
                cancel_callback=lambda handle, c=controller: self._on_goal_cancel(c, handle),
                callback_group=group)

    def _on_goal_request(self, controller, goal):
        """Accept a goal the controller can follow; refuse the rest with its error."""
        follower = self.node.sim.controllers[controller][0]
        try:
            check_trajectory(goal.trajectory, self._controllers[controller])
            follower.check(goal.trajectory.joint_names, trajectory_points(goal.trajectory))
            for tolerance in (*goal.path_tolerance, *goal.goal_tolerance):
                input_checks.finite('tolerance', [tolerance.position, tolerance.velocity])
        except (Rejected, TrajectoryError) as err:
            self.node.get_logger().error(f'{controller}: goal refused: {err}')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_goal_accepted(self, controller, handle):
        goal = handle.request
        traj = goal.trajectory
        goal_id = bytes(handle.goal_id.uuid)
        done = (threading.Event(), [])
        self._ends[goal_id] = done
        node = self.node
        try:
            start_s = node.trajectory_start_s(controller, traj.header.stamp)
            with node.lock:
                node.sim.set_trajectory(controller, list(traj.joint_names),
                                        trajectory_points(traj), start_s)
                follower = node.sim.controllers[controller][0]
                preempted = self._monitors[controller].start(
                    goal_id, follower.end_time,
                    path_tolerance=[(t.name, t.position) for t in goal.path_tolerance],
                    goal_tolerance=[(t.name, t.position) for t in goal.goal_tolerance],
                    velocity_tolerance=[(t.name, t.velocity) for t in goal.goal_tolerance],
                    goal_time_tolerance=goal.goal_time_tolerance.sec
                    + goal.goal_time_tolerance.nanosec * 1e-9)
        except (Rejected, TrajectoryError, ValueError) as err:
            preempted = None
            done[1].append(GoalEnd(goal_id, 'aborted', INVALID_GOAL, str(err)))
            done[0].set()
        if preempted is not None:
            self._end_goal(preempted)
        handle.execute()

    def _on_goal_cancel(self, controller, handle):
        """As the controller: the goal ends canceled and the joints hold where they are."""
        goal_id = bytes(handle.goal_id.uuid)
        with self.node.lock:
            end = self._monitors[controller].cancel(goal_id)
            if end is not None:
                follower, idx = self.node.sim.controllers[controller]
                follower.hold(self.node.sim.q[idx])
        if end is not None:
            self._end_goal(end)
        return CancelResponse.ACCEPT

    def report(self, ends):
        """Tell the waiting goals how they ended (after the tick, lock released)."""
        for end in ends:
            self._end_goal(end)

    def _end_goal(self, end):
        done = self._ends.get(end.goal_id)
        if done is not None:
            done[1].append(end)
            done[0].set()

    def _execute_goal(self, handle):
        """Wait (an executor thread of its own) until the simulation ends the goal."""
        goal_id = bytes(handle.goal_id.uuid)
        event, ends = self._ends[goal_id]
        while not event.wait(0.5):
            if self.node.stopping():
                break
        self._ends.pop(goal_id, None)
        result = FollowJointTrajectory.Result()
        if not ends:
            result.error_code, result.error_string = INVALID_GOAL, 'the simulation stopped'
            handle.abort()
            return result
        end = ends[0]
        result.error_code, result.error_string = end.error_code, end.error_string
        if end.status == 'succeeded':
            handle.succeed()
        elif end.status == 'canceled':
            handle.canceled()
        else:
            handle.abort()
        return result

    def judge(self):
        """Each tick: the verdict on every running goal (call with the lock held). An
        aborted goal leaves its controller holding, as the controller does."""
        sim = self.node.sim
        ended = []
        for controller, monitor in self._monitors.items():
            if monitor.active_goal is None:
                continue
            follower, idx = sim.controllers[controller]
            q = sim.q[idx]
            end = monitor.update(sim.time, q, sim.qd[idx], follower.sample(sim.time, q),
                                 follower.end_time)
            if end is not None:
                if end.status == 'aborted':
                    follower.hold(q)
                ended.append(end)
        return ended


MAX_TRAJECTORY_POINTS = 100_000


def trajectory_points(msg):
    """The points of a trajectory_msgs/JointTrajectory for the followers."""
    return [TrajectoryPoint(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9,
                            np.asarray(p.positions, dtype=float),
                            np.asarray(p.velocities, dtype=float) if len(p.velocities) else None)
            for p in msg.points]


def check_trajectory(msg, controller_joints):
    """Raise input_checks.Rejected for a JointTrajectory no controller should follow:
    oversized, joints the controller does not have, point sizes that disagree with the
    joint names, non-finite numbers. (joint_trajectory_follower checks the rest.)"""
    input_checks.at_most('trajectory points', len(msg.points), MAX_TRAJECTORY_POINTS)
    input_checks.at_most('trajectory joint names', len(msg.joint_names), len(controller_joints))
    unknown = [n for n in msg.joint_names if n not in controller_joints]
    if unknown:
        raise Rejected('unknown_id', f'joints {[n[:40] for n in unknown[:3]]} are not '
                                     f'controlled here ({", ".join(controller_joints)})')
    if not msg.points:
        # Jazzy's joint_trajectory_controller: "Empty trajectory received." It does not
        # stop: a stop is a one-point hold at the current position.
        raise Rejected('empty', 'Empty trajectory received. (a stop is a one-point hold at '
                                'the current position)')
    if not msg.joint_names:
        raise Rejected('empty', 'trajectory points without joint names')
    n = len(msg.joint_names)
    for i, p in enumerate(msg.points):
        if len(p.positions) != n or len(p.velocities) not in (0, n) \
                or len(p.accelerations) not in (0, n):
            raise Rejected('size_mismatch', f'point {i} has {len(p.positions)} positions, '
                                            f'{len(p.velocities)} velocities and '
                                            f'{len(p.accelerations)} accelerations for {n} '
                                            'joints')
        input_checks.finite(f'point {i}', [*p.positions, *p.velocities, *p.accelerations])


