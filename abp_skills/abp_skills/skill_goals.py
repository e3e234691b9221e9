"""The skill actions' types, and how a skill goal ends, shared by the robot's skill servers
(skill_action_servers) and the person's (operator_node)."""

from builtin_interfaces.msg import Duration as DurationMsg

from abp_msgs.action import Flip, Lift, Orbit, Push

SKILL_TYPES = {'orbit': Orbit, 'push': Push, 'lift': Lift, 'flip': Flip}


def end_goal(goal_handle, skill, outcome, reason, elapsed_s, logger):
    """End `goal_handle` as `outcome` ('succeed', 'cancel' when a cancel was asked for,
    else aborted), log it, and return the skill's Result."""
    result = SKILL_TYPES[skill].Result()
    result.success = outcome == 'succeed'
    result.reason = reason
    elapsed_s = max(0.0, elapsed_s)
    result.duration = DurationMsg(sec=int(elapsed_s),
                                  nanosec=int((elapsed_s - int(elapsed_s)) * 1e9))
    if outcome == 'succeed':
        goal_handle.succeed()
    elif outcome == 'cancel' and goal_handle.is_cancel_requested:
        goal_handle.canceled()
    else:
        goal_handle.abort()
    text = f'{skill}: {outcome} after {elapsed_s:.1f} s' + (f' ({reason})' if reason else '')
    # Two call sites: rclpy refuses one call site that logs at two severities.
    if result.success:
        logger.info(text)
    else:
        logger.warning(text)
    return result
