"""ARcube model populations, Aspect Transition Graphs, observation model and Bayes filter.

Plain NumPy/SciPy science modules, no rclpy (conventions in ``docs/MODEL.md``,
API in ``docs/BELIEF_API.md``): ``cube`` (geometry and physics of one cube),
``population`` (model sets), ``modelset`` (the ATG tables), ``observation``
(p(z|x)), ``filter`` (Bayes filter), ``io`` (model-set files), ``models_cli``
and ``bench_filter`` (command-line tools).
"""
