"""Active Belief Planner (Ruiken et al., Alg. 3), its variants and benchmarks.

Plain Python science modules, no rclpy: ``planner`` (action selection),
``simulator`` (the paper's model-sampled simulation protocol) and
``benchmark`` (the CLI that reproduces Tables II/IV and Fig. 3).
"""
