"""Active Belief Planner (Ruiken et al., Alg. 3) and its variants.

Plain Python science modules, no rclpy: ``planner`` (action selection),
``simulator`` (the paper's model-sampled simulation protocol), ``stopping``
(when to stop), ``episode`` (one Recognize episode: stop, re-plan, retry, wait
for evidence) and ``planner_config`` (the planner node's parameter table).
``planner_node`` is the ROS wiring, ``skill_clients`` its clients of the skill
servers, ``markers`` builds its RViz markers. The benchmarks live in ``abp_bench``.
"""
