"""The skills' ROS helpers depend on a SkillsContext, not on SkillsNode: built here on a
plain rclpy node (no SkillsNode anywhere), they open their topics and the feasibility
service answers from the context's robot state and motion planner."""

import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup

from abp_common.health import NodeHealth
from abp_common.input_node import InputNode
from abp_common.parameters import declare_all
from abp_description.kinematics import RobotKinematics
from abp_msgs.srv import CheckFeasibility
from abp_skills.clock_rate import ClockRate
from abp_skills.feasibility_service import FeasibilityService
from abp_skills.plans import ACTIONS, SkillPlanner
from abp_skills.robot_state import RobotState
from abp_skills.robot_topics import RobotCommands, RobotInputs
from abp_skills.skill_context import SkillsContext
from abp_skills.skill_params import config_from_values, skills_parameter_specs


def test_the_helpers_run_on_a_context_of_a_plain_rclpy_node():
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('skills_context_probe', context=context)
        values = declare_all(node, skills_parameter_specs(True))
        kin = RobotKinematics()
        ctx = SkillsContext(
            ros=node, health=NodeHealth(node), callback_group=ReentrantCallbackGroup(),
            param=lambda name: node.get_parameter(name).value, kin=kin,
            state=RobotState(lambda: 0.0, kin.q_from_mapping), clock_rate=ClockRate(),
            motion_planner=SkillPlanner(RobotKinematics(), config_from_values(values)))
        inputs = InputNode(node)
        RobotInputs(ctx, inputs.node)
        ctx.commands = RobotCommands(ctx)
        service = FeasibilityService(ctx)
        topics = {name for name, _ in node.get_topic_names_and_types()}
        assert {s.topic_name for s in inputs.subscriptions} == \
            {'/joint_states', '/odom', '/abp/aspect_observation'}
        assert {'/joint_states', '/odom', '/cmd_vel'} <= topics, topics

        # No cube estimate yet: every action infeasible, saying why.
        answer = service._on_request(CheckFeasibility.Request(), CheckFeasibility.Response())
        assert list(answer.actions) == list(ACTIONS) and not any(answer.feasible)
        assert all('estimate' in reason for reason in answer.reasons), answer.reasons

        # With an estimate: the planner's own verdict, from the home posture (no joints).
        ctx.state.set_odom((0.0, 0.0, 0.0))
        cube = [0.45, 0.0, 0.05]
        ctx.state.set_cube_estimate(cube)
        answer = service._on_request(CheckFeasibility.Request(), CheckFeasibility.Response())
        planner = ctx.motion_planner
        home = planner.home(kin.neutral())
        expected = [bool(planner.feasibility(a, home, ctx.cube()[0])[0]) for a in ACTIONS]
        assert list(answer.feasible) == expected
        assert any(expected), 'a cube 45 cm ahead: some skill must be feasible'
        inputs.close()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
