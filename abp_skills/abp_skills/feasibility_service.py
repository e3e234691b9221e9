"""ROS wiring of /abp/skills/check_feasibility (abp_msgs/srv/CheckFeasibility).

For each asked ATG action (all of `plans.ACTIONS` when none is asked), whether the skill
could run at the current cube pose estimate, and why not: the motion planner's
`feasibility` from the current joints (or the home posture the robot will hold when idle,
if no recent /joint_states). No estimate, or a stale one, makes every action infeasible
with that reason.
"""

from abp_common import names
from abp_msgs.srv import CheckFeasibility

from .plans import ACTIONS
from .skill_checks import Refused


class FeasibilityService:
    """The feasibility service of a skills node (`context`: a SkillsContext)."""

    def __init__(self, context):
        self.ctx = context
        self.service = context.ros.create_service(CheckFeasibility, names.CHECK_FEASIBILITY,
                                                  self._on_request,
                                                  callback_group=context.callback_group)

    def _current_joints(self):
        """The recent joint positions without waiting for them, or None."""
        ctx = self.ctx
        if ctx.state.latest_joints() is None:
            return None
        try:
            return ctx.state.joints(ctx.param('max_state_age'), wait=False)
        except Refused:
            return None

    def _on_request(self, request, response):
        ctx = self.ctx
        actions = list(request.actions) or list(ACTIONS)
        try:
            cube_base, _ = ctx.cube()
            why = None
        except Refused as refusal:
            cube_base, why = None, str(refusal).replace('refused: ', '', 1)
        q = self._current_joints()
        response.actions = actions
        with ctx.plan_lock:
            if q is None:
                q = ctx.motion_planner.home(ctx.kin.neutral())  # as it will be when idle
            for action in actions:
                if why is not None:
                    ok, reason = False, why
                else:
                    ok, reason = ctx.motion_planner.feasibility(action, q, cube_base)
                response.feasible.append(bool(ok))
                response.reasons.append('' if ok else reason)
        return response


__all__ = ['FeasibilityService']
