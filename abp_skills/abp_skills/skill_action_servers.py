"""ROS wiring of the skills' action servers: /abp/skills/{orbit,push,lift,flip}.

A goal is accepted, then claimed (`SkillClaim`: one skill at a time across processes; a
busy goal aborts with reason "rejected: busy: ..."), planned by the node's motion planner
(`plans.SkillPlanner`, refused with a reason when it cannot be done) and run phase by
phase: base motions closed-loop on /odom (`base_motion.OrbitTracker`), arm phases sent as
one trajectory to every controller and waited for until the joints arrive: by
FollowJointTrajectory, the controllers' results (goal tolerance within settle_timeout);
by topic, `skill_checks.ArrivalCheck` on /joint_states. Cancelling stops the robot (a
one-point hold on every controller, robot_topics) and ends the goal canceled; a timeout,
lost odometry, a controller's abort or joints that do not arrive abort it (and stop the
robot). Odometry
that is late (older than `max_state_age` of node time, which at a high sim speed-up is a
short wall time) first stops the base and pauses the drive until it is recent again;
only when it stays late for `state_wait_timeout` wall seconds does the drive abort
(`skill_checks.OdometryGap`).
"""

import numpy as np
import rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse

from abp_common import names

from .base_motion import OrbitTracker, plan_base_approach
from .plans import PlanError
from .robot_state import point_odom_to_base
from .skill_checks import (
    ArrivalCheck,
    FeedbackThrottle,
    OdometryGap,
    Refused,
    manual_goal_overrides,
    sleep_on_clock,
    timeout_reason,
)
from .skill_goals import SKILL_TYPES, end_goal


class SkillActionServers:
    """The action servers of `skills` of a skills node (`context`: a SkillsContext)."""

    def __init__(self, context, skills):
        self.ctx = context
        self.servers = [
            ActionServer(context.ros, SKILL_TYPES[skill], names.skill_action(skill),
                         execute_callback=lambda handle, s=skill: self._execute(s, handle),
                         goal_callback=lambda _goal: GoalResponse.ACCEPT,
                         cancel_callback=lambda _handle: CancelResponse.ACCEPT,
                         callback_group=context.callback_group)
            for skill in skills]

    # -- a goal, start to end --------------------------------------------------------------
    def _execute(self, skill, goal_handle):
        ctx = self.ctx
        started = ctx.now()
        why = ctx.claim.claim(skill, ctx.param('claim_settle_time'))
        if why is not None:
            ctx.logger().info(f'{skill}: {why}')
            return self._finish(skill, goal_handle, 'abort', why, started)
        ctx.commands.reset_moved()
        try:
            outcome, reason = self._run(skill, goal_handle, started)
        except Refused as refusal:
            outcome, reason = 'abort', str(refusal)
        except Exception as error:  # never leave the robot moving
            ctx.logger().error(f'{skill}: internal error: {error!r}')
            outcome, reason = 'abort', f'internal error: {error}'
        if outcome != 'succeed' and ctx.commands.moved:
            ctx.commands.stop_motion()
        ctx.claim.release()
        return self._finish(skill, goal_handle, outcome, reason, started)

    def _finish(self, skill, goal_handle, outcome, reason, started):
        return end_goal(goal_handle, skill, outcome, reason, self.ctx.now() - started,
                        self.ctx.logger())

    def _run(self, skill, goal_handle, started):
        if skill == 'orbit':
            return self._run_orbit(goal_handle, goal_handle.request, started)
        overrides = manual_goal_overrides(skill, goal_handle.request)
        return self._run_manual(skill, goal_handle, overrides, started)

    def _check_goal(self, goal_handle, started, limit_s=None):
        """None to go on, or (outcome, reason) to stop now. `limit_s`: the time allowed
        since `started` (default: the `timeout` parameter)."""
        if goal_handle.is_cancel_requested:
            return 'cancel', 'canceled'
        if not goal_handle.is_active:
            return 'abort', 'goal no longer active'
        late = timeout_reason(self.ctx.now() - started,
                              self.ctx.param('timeout') if limit_s is None else limit_s)
        if late:
            return 'abort', late
        if not rclpy.ok(context=self.ctx.ros.context):
            return 'abort', 'shutting down'
        return None

    def _feedback(self, skill, goal_handle, phase, progress):
        fb = SKILL_TYPES[skill].Feedback()
        fb.phase = phase
        fb.progress = float(np.clip(progress, 0.0, 1.0))
        goal_handle.publish_feedback(fb)

    def _sleep_period(self):
        sleep_on_clock(1.0 / self.ctx.param('control_rate'), self.ctx.now,
                       sleep=self.ctx.clock_sleep)

    # -- the two kinds of motion -----------------------------------------------------------
    def _drive(self, skill, goal_handle, started, plan, progress_of, head_q=None):
        """Track a base plan (OrbitPlan) on /odom. Returns None or (outcome, reason).
        `head_q`: (joints, cube height) to keep the camera on the cube while driving."""
        ctx = self.ctx
        tracker = OrbitTracker(
            plan, ctx.motion_planner.config.base,
            yaw_tolerance=np.radians(ctx.param('orbit_yaw_tolerance_deg')),
            position_tolerance=ctx.param('orbit_position_tolerance'),
            settle_time=max(ctx.param('settle_timeout'), 0.5))
        problem = ctx.commands.base_listener_problem()
        if problem:
            return 'abort', f'the base cannot be driven: {problem}'
        t0 = ctx.now()
        feedback = FeedbackThrottle()
        gap = OdometryGap(ctx.param('state_wait_timeout'))
        held_at = None
        while True:
            stop = self._check_goal(goal_handle, started)
            if stop:
                return stop
            pose = ctx.state.base_pose(ctx.param('max_state_age'), required=False)
            step = gap.update(pose is not None)
            if step == 'abort':
                ctx.commands.stop_base()
                return 'abort', gap.reason()
            if step == 'stop':   # late odometry: stand still, the plan paused, and wait
                ctx.commands.stop_base()
                held_at = ctx.now()
                ctx.logger().warning(
                    f'{skill}: /odom is late; the base waits for it '
                    f'(up to {gap.max_wait_s:.1f} s)', throttle_duration_sec=5.0)
            if gap.holding:
                self._sleep_period()
                continue
            if step == 'resume':
                t0 += ctx.now() - held_at
            t = ctx.now() - t0
            v, w, phase, done, ok = tracker.command(t, pose)
            if done:
                ctx.commands.stop_base()
                if ok:
                    return None
                b, h, r = tracker.final_errors(pose)
                return 'abort', (f'the base did not settle: bearing {np.degrees(b):.1f} deg, '
                                 f'heading {np.degrees(h):.1f} deg, radius {100 * r:.1f} cm off')
            ctx.commands.velocity(v, w)
            if head_q is not None:
                cube_base = point_odom_to_base(pose, np.array([*plan.cube_xy, head_q[1]]))
                q = ctx.state.latest_joints()
                ctx.commands.aim_head(q if q is not None else head_q[0], cube_base)
            if feedback.due(t):
                done_s = min(tracker.plan_time, plan.duration)
                self._feedback(skill, goal_handle, phase,
                               progress_of(done_s / max(plan.duration, 1e-6)))
            self._sleep_period()

    def _move(self, skill, goal_handle, started, name, trajectory, progress_of, limit_s=None,
              pressing=False):
        """Send one phase trajectory and wait for it to end and the joints to arrive
        (`pressing`: a phase whose hands press into the cube, contact_goal_tolerance)."""
        ctx = self.ctx
        tolerance = ctx.param('contact_goal_tolerance' if pressing else 'goal_tolerance')
        t0 = ctx.commands.send_trajectory(trajectory, ctx.param('trajectory_start_delay'),
                                           tolerance, ctx.param('settle_timeout'))
        feedback = FeedbackThrottle()
        by_action = ctx.commands.by_action
        arrival = ArrivalCheck(name, trajectory.joint_names, trajectory.end, trajectory.duration,
                               tolerance, ctx.param('settle_timeout'))
        idx = [ctx.kin.joint_index(n) for n in trajectory.joint_names]
        while True:
            stop = self._check_goal(goal_handle, started, limit_s)
            if stop:
                return stop
            t = ctx.now() - t0
            if feedback.due(t):
                frac = min(max(t, 0.0), trajectory.duration) / max(trajectory.duration, 1e-6)
                self._feedback(skill, goal_handle, name, progress_of(frac))
            if by_action:
                # The controllers judge arrival (goal tolerance, goal_time_tolerance).
                outcome = ctx.commands.trajectory_outcome()
                if outcome is not None:
                    ok, reason = outcome
                    return None if ok else ('abort', f'{name}: {reason}')
            elif arrival.ended(t):
                done, reason = arrival.check(t, ctx.joints()[idx])
                if done:
                    return ('abort', reason) if reason else None
            self._sleep_period()

    # -- the skills ------------------------------------------------------------------------
    def _run_orbit(self, goal_handle, goal, started):
        ctx = self.ctx
        angle = float(goal.angle_deg)
        cube_base, cube_odom = ctx.cube()
        q = ctx.joints()
        pose = ctx.base_pose()
        radius = goal.radius if goal.radius > 0 else ctx.param('orbit_radius')
        with ctx.plan_lock:
            try:
                plan = ctx.motion_planner.orbit_plan(angle, pose, cube_base, radius)
            except (PlanError, ValueError) as error:
                raise Refused(f'refused: {error}') from error
            home = ctx.motion_planner.go_home(q, look=cube_base)
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
                           head_q=(ctx.joints(), cube_odom[2]))
        if stop:
            return stop
        self._feedback('orbit', goal_handle, 'stroke', 1.0)
        return 'succeed', ''

    def _run_manual(self, skill, goal_handle, overrides, started):
        ctx = self.ctx
        cube_base, cube_odom = ctx.cube()
        q = ctx.joints()
        with ctx.plan_lock:
            needed, ok, reason, cube_after = ctx.motion_planner.base_approach(cube_base)
            if not ok:
                raise Refused(f'refused: {reason}')
            # Check the arm plan where the arms will work before moving anything.
            plan = ctx.motion_planner.plan(skill, q, cube_after, **overrides)
            config = ctx.motion_planner.config
        if not plan.ok:
            raise Refused(f'refused: {plan.reason}')
        base_plan = None
        if needed:
            base_plan = plan_base_approach(ctx.base_pose(), cube_odom[:2],
                                           config.manipulation_distance, config.base)
        total = plan.duration + (base_plan.duration if base_plan is not None else 0.0)
        done = 0.0
        if base_plan is not None and base_plan.segments:
            stop = self._drive(skill, goal_handle, started, base_plan,
                               lambda f: f * base_plan.duration / total)
            if stop:
                return self._retreat(skill, goal_handle, cube_base, stop)
            done = base_plan.duration
            cube_base = point_odom_to_base(ctx.base_pose(), cube_odom)
            q = ctx.joints()
            with ctx.plan_lock:
                plan = ctx.motion_planner.plan(skill, q, cube_base, **overrides)
            if not plan.ok:
                return 'abort', f'after the base approach: {plan.reason}'
            total = done + plan.duration
        for phase in plan.phases:
            start = done
            stop = self._move(skill, goal_handle, started, phase.name, phase.trajectory,
                              lambda f, s=start, d=phase.duration: (s + f * d) / total,
                              pressing=phase.pressing)
            if stop:
                return self._retreat(skill, goal_handle, cube_base, stop)
            done += phase.duration
        self._feedback(skill, goal_handle, plan.phases[-1].name, 1.0)
        return 'succeed', ''

    def _retreat(self, skill, goal_handle, cube_base, stop):
        """After a manual skill aborted with the arms out (a joint that did not arrive, a
        timeout): bring them home, looking at the cube, so that they neither hold the cube
        nor hide it from the camera (else every later action is refused for a stale cube
        estimate). Not after a cancel: the caller wants the robot stopped. Returns `stop`,
        its reason saying whether the arms came home."""
        outcome, reason = stop
        if outcome != 'abort' or not goal_handle.is_active:
            return stop
        ctx = self.ctx
        q = ctx.state.latest_joints()
        if q is None:
            return stop
        with ctx.plan_lock:
            home = ctx.motion_planner.go_home(q, look=cube_base)
        if home is None:  # the arms are home already
            return outcome, f'{reason}; arms back home'
        # Its own time limit: `stop` may itself be the skill timeout, which can be shorter.
        limit = 2.0 * home.duration + ctx.param('settle_timeout') + 5.0
        failed = self._move(skill, goal_handle, ctx.now(), 'recover', home, lambda f: 1.0,
                            limit_s=limit)
        return outcome, f'{reason}; arms {"not " if failed else ""}back home'


__all__ = ['SKILL_TYPES', 'SkillActionServers']
