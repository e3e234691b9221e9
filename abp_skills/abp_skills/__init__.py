"""ORBIT, PUSH, LIFT and FLIP skills of the uBot-6-like robot.

Plain modules (no rclpy): `ik` (damped least-squares hand IK on Pinocchio), `collision`
(arm self-collision), `motion_profiles` (Ruckig joint and path profiles), `base_motion`
(the ORBIT and approach base plans and their odometry tracker), `plans` (the skills'
waypoints and phases, feasibility: `SkillPlanner`, built on `arm_plans` and `plan_types`),
`skill_params` (the parameter table), `skill_claim` (one skill at a time across
processes), `skill_checks` and `robot_state` (goal, timeout, arrival and state-age rules).
ROS wiring: `skills_node` (the node and its executables),
`skill_action_servers`, `feasibility_service`, `robot_topics`. Robot facts (joint tables,
head aiming, frames) come from abp_description.
"""
