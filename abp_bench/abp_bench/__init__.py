"""Every abp benchmark and the rendered perception scenes; never needed on a robot.

Runtime packages depend only on what they run: the simulator, matplotlib and tqdm are
needed here, not there. One module per benchmark, each a command-line tool
(``ros2 run abp_bench <executable>``; figures and commands in docs/BENCHMARKS.md):

- ``filter_benchmark`` (``bench_filter``): one Bayes-filter step (abp_belief).
- ``planner_benchmark``: the planners against the paper's Tables II/IV and Fig. 3.
- ``perception_benchmark``: tag detection and aspect matching on rendered scenes
  (``realistic_suite``: under realistic conditions; ``perception_scenes``: what the two share).
- ``skills_benchmark``: IK, Ruckig trajectories and skill plans (abp_skills).
- ``render_benchmark``: the sim bridge's ARcube renderer, time per frame and pose errors.
- ``sim_bridge_benchmark``: the sim bridge's render and tick times and its publish rates.
- ``graph_benchmark``: latencies and episodes through the whole running graph.
- ``scenes``: rendered ARcube scenes with ground truth (perception tests and benchmark).
"""
