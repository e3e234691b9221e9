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
`claim_settle_time`: the earlier claim wins, the other aborts (`skill_claim`). Each change
of a peer's state is logged when it arrives ("skills peer /orbit_server: orbit running",
"... idle"): the topic takes its time, and a goal sent to this process before that line
may still find the peer idle.

Subscribes:  /joint_states, /odom, /abp/aspect_observation (the cube pose estimate:
             hypotheses[0].object_pose, in base_link or any URDF frame), /abp/skills/active
Publishes:   /cmd_vel, /{torso,left_arm,right_arm,head}_controller/joint_trajectory,
             /abp/skills/active
Actions:     /abp/skills/{orbit,push,lift,flip} (abp_msgs/action/*)
Service:     /abp/skills/check_feasibility (abp_msgs/srv/CheckFeasibility)
(All names relative: under a namespace they move with it.)

Cancelling a goal stops the robot (zero /cmd_vel, an empty trajectory = hold on every
controller) and ends it canceled. The parts: `skill_params` (the parameter table),
`robot_topics` + `robot_state` (sensors in, commands out), `skill_action_servers` +
`skill_checks` (running a goal), `feasibility_service`, `skill_claim`, which use the node
only through a `skill_context.SkillsContext`; the science is in
`plans`, `ik`, `collision`, `motion_profiles` and `base_motion`.
"""

import sys
from functools import partial

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from std_msgs.msg import String

from abp_common import input_checks, names
from abp_common.health import NodeHealth
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.param_spec import check_all
from abp_common.parameters import declare_all, read_all
from abp_common.qos import LATCHED, LATCHED_READER
from abp_description.kinematics import RobotKinematics
from abp_description.robot_profile import PROFILE_SPEC, load_profile

from .clock_rate import ClockRate
from .clock_ticks import ClockTicks
from .feasibility_service import FeasibilityService
from .plans import SkillPlanner
from .robot_state import RobotState
from .robot_topics import RobotCommands, RobotInputs
from .skill_action_servers import SkillActionServers
from .skill_claim import SkillClaim
from .skill_context import SkillsContext
from .skill_params import config_from_values, skills_parameter_specs

EXECUTOR_THREADS = 8   # concurrent goals, feasibility answers and sensor callbacks


class SkillsNode(ManagedNode):
    """Configure reads the parameters and builds the motion planner; activate opens the
    robot's topics and the action (and feasibility) servers (abp_common.lifecycle)."""

    def __init__(self, node_name='skill_servers', skills=names.SKILLS, feasibility=True):
        super().__init__(node_name)
        self._skills = skills
        self._feasibility = feasibility
        self._clock_ticks = ClockTicks(self.get_clock())   # one per node: a jump callback
        self.inputs = None   # robot_topics.RobotInputs while active

    def configure(self):
        # The robot profile first: it sets the robot's defaults of the other parameters.
        profile = load_profile(declare_all(self, (PROFILE_SPEC,))['robot_profile'])
        self._specs = skills_parameter_specs(self._feasibility, profile)
        values = self._values = {**declare_all(self, self._specs[1:]),
                                 'robot_profile': profile.path}
        self.health = NodeHealth(self)   # declares its parameters: before the callback below
        # The motion planner owns one Pinocchio model/data (used under plan_lock); the
        # node's own forward kinematics (head aiming, estimate frames) use another (fk_lock).
        kin = RobotKinematics(profile=profile)
        # All the helpers below use of this node (skill_context).
        self.ctx = SkillsContext(
            ros=self, health=self.health, callback_group=ReentrantCallbackGroup(),
            param=self.param, kin=kin, state=RobotState(self.now, kin.q_from_mapping),
            clock_rate=ClockRate(),   # fed by /joint_states (robot_topics)
            clock_sleep=self._clock_ticks.sleep,
            motion_planner=SkillPlanner(RobotKinematics(profile=profile),
                                        config_from_values(values, profile)))
        self.add_on_set_parameters_callback(self._on_set_parameters)

    def activate(self):
        skills = self._skills
        ctx = self.ctx
        ctx.commands = RobotCommands(ctx)

        self._active_pub = self.create_publisher(String, names.SKILLS_ACTIVE, LATCHED)
        ctx.claim = SkillClaim(self.get_fully_qualified_name(),
                               lambda text: self._active_pub.publish(String(data=text)),
                               self._active_publishers)
        # In order (an exclusive group): a peer's claim and its release must not swap.
        self.health.subscribe(String, names.SKILLS_ACTIVE, self._on_skills_state,
                              LATCHED_READER, callback_group=MutuallyExclusiveCallbackGroup())
        self.actions = SkillActionServers(ctx, skills)
        self.feasibility = (FeasibilityService(ctx) if self._values['feasibility_service']
                            else None)
        ctx.claim.announce()
        # Last: nothing after it can fail and leave its thread running (close: deactivate).
        # Made in activate, so closed at deactivate (ManagedNode.create_input_node).
        self.inputs = RobotInputs(ctx, self.create_input_node().node)
        hosted = [self.resolve_topic_name(names.skill_action(s)) for s in skills]
        if self.feasibility is not None:
            hosted.append(self.resolve_service_name(names.CHECK_FEASIBILITY))
        self.get_logger().info(f'skills ready: {", ".join(hosted) or "nothing hosted"}')

    def deactivate(self):
        _stop_robot(self)

    def _on_skills_state(self, msg):
        input_checks.skills_state(msg.data)     # Rejected: not a skills state
        changed = self.ctx.claim.on_message(msg.data)
        if changed is not None:
            # A peer's claim or release has reached this process (tests wait for this line).
            running = f'{changed["skill"]} running' if changed['skill'] else 'idle'
            self.get_logger().info(f'skills peer {changed["node"]}: {running}')

    def _active_publishers(self):
        """Fully qualified names of the nodes publishing the skills' state (one per
        publisher)."""
        return [f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                for i in self.get_publishers_info_by_topic(names.SKILLS_ACTIVE)]

    def _on_set_parameters(self, params):
        changes = {p.name: p.value for p in params}
        try:
            check_all(self._specs, changes)
            config = config_from_values({**read_all(self, self._specs), **changes},
                                        self.ctx.kin.profile)
        except (ValueError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        with self.ctx.plan_lock:
            self.ctx.motion_planner = SkillPlanner(self.ctx.motion_planner.kin, config)
        return SetParametersResult(successful=True)

    # -- what the node itself reads --------------------------------------------------------
    def now(self):
        """The node's clock (sim time under use_sim_time), s."""
        return self.get_clock().now().nanoseconds * 1e-9

    def param(self, name):
        return self.get_parameter(name).value

    def stop_motion(self):
        self.ctx.commands.stop_motion()


def _stop_robot(node):
    try:
        node.stop_motion()
    except Exception:  # the context may already be gone
        pass


def _run(node_name, skills, feasibility, args):
    return run_node(node_name, partial(SkillsNode, node_name, skills, feasibility), args,
                    config_errors=(TypeError, rclpy.exceptions.ParameterException),
                    make_executor=partial(MultiThreadedExecutor, num_threads=EXECUTOR_THREADS),
                    on_exit=_stop_robot)


def main(args=None):
    """All four action servers and the feasibility service in one process."""
    return _run('skill_servers', names.SKILLS, True, args)


def orbit_main(args=None):
    """ORBIT, and (parameter feasibility_service, default true) the feasibility service."""
    return _run('orbit_server', ('orbit',), True, args)


def push_main(args=None):
    return _run('push_server', ('push',), False, args)


def lift_main(args=None):
    return _run('lift_server', ('lift',), False, args)


def flip_main(args=None):
    return _run('flip_server', ('flip',), False, args)


if __name__ == '__main__':
    sys.exit(main())
