"""ORBIT, PUSH, LIFT and FLIP skills of the uBot-6-like robot.

Plain modules (no rclpy): `ik` (damped least-squares hand IK on Pinocchio),
`collision` (arm self-collision), `trajectories` (Ruckig joint and path profiles,
the ORBIT base profile and controller), `plans` (the skills' waypoints and phases,
feasibility). ROS wiring: `skills_node` (the action servers and the feasibility
service). `benchmark` times IK and trajectory generation.
"""
