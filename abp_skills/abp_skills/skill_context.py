"""What the skills' ROS helpers (robot_topics, skill_action_servers, feasibility_service)
use of their node, in one object: they depend on this, not on `skills_node.SkillsNode`.

`ros` is the rclpy node, used only through rclpy's public Node API: rclpy's action
servers and clients take a node, and entities made on it are the managed node's to
destroy (abp_common.lifecycle). The rest is the node's state the helpers share: the
health accounting, the parameters, the robot state, the kinematics and the motion planner
with their locks, and, once active, the robot commands and the skill claim. Plain Python:
no rclpy import.
"""

import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable


@dataclass
class SkillsContext:
    ros: Any                       # rclpy.node.Node (entities, names, clock, logger)
    health: Any                    # abp_common.health.NodeHealth: guarded subscriptions
    callback_group: Any            # the servers' (reentrant) callback group
    param: Callable[[str], Any]    # the current value of a parameter
    kin: Any                       # RobotKinematics of the helpers' own FK (under fk_lock)
    state: Any                     # robot_state.RobotState, fed by robot_topics.RobotInputs
    clock_rate: Any                # clock_rate.ClockRate, fed by /joint_states
    # plans.SkillPlanner; replaced (under plan_lock) when a parameter changes, so read it
    # under plan_lock and keep no reference across a lock release.
    motion_planner: Any
    plan_lock: threading.Lock = field(default_factory=threading.Lock)
    fk_lock: threading.Lock = field(default_factory=threading.Lock)
    # Sleeps up to t wall seconds, waking early when the clock moves (clock_ticks).
    clock_sleep: Callable[[float], None] = time.sleep
    commands: Any = None           # robot_topics.RobotCommands, once active
    claim: Any = None              # skill_claim.SkillClaim, once active

    def now(self):
        """The node's clock (sim time under use_sim_time), s."""
        return self.ros.get_clock().now().nanoseconds * 1e-9

    def logger(self):
        return self.ros.get_logger()

    def joints(self):
        return self.state.joints(self.param('max_state_age'),
                                 first_wait_s=self.param('state_wait_timeout'))

    def base_pose(self):
        return self.state.base_pose(self.param('max_state_age'),
                                    first_wait_s=self.param('state_wait_timeout'))

    def cube(self):
        """(cube centre in base_link now, in odom) from the latest estimate."""
        return self.state.cube(self.param('max_estimate_age'))


__all__ = ['SkillsContext']
