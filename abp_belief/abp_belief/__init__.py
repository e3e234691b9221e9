"""ARcube model populations, Aspect Transition Graphs, observation model and Bayes filter.

Plain NumPy/SciPy science modules, no rclpy (conventions in ``docs/MODEL.md``,
API in ``docs/BELIEF_API.md``): ``cube`` (geometry and physics of one cube),
``population`` (model sets), ``modelset`` (the ATG tables), ``observation``
(p(z|x)), ``filter`` (Bayes filter), ``factored_belief`` (one belief per object of a
scene), ``model_file`` (model-set files),
``model_set_config`` (the model-set parameter table), ``atg_learning`` (transition tables
learned from experience, with ``learn_atg_cli``), ``transition_tables`` (the tables' dense
and sparse forms and the state neighbourhoods, shared by ``modelset`` and
``atg_learning``), ``evidence_gate`` (which observation corrects the belief, and when),
``belief_config`` (the belief node's parameter table) and ``models_cli`` (command-line
tool). ``belief_node`` is the ROS wiring.
"""
