"""Replaying stopping rules on full trajectories (planner_benchmark --stop-curve)."""

import numpy as np

from abp_bench import planner_benchmark


def test_replay_stop_takes_first_step_that_stops():
    trial = {'top_posterior': [0.5, 0.96, 0.9990, 0.99999], 'answer_posterior': [0.5] * 4,
             'top_is_true': [False, False, True, True], 'decidable': True}
    assert planner_benchmark.replay_stop(trial, lambda top, ans: top > 0.95) == (1, False)
    assert planner_benchmark.replay_stop(trial, lambda top, ans: 1 - top <= 0.003) == (2, True)
    # Never stops: the last step decides.
    assert planner_benchmark.replay_stop(trial, lambda top, ans: top > 1.0) == (3, True)
    # The twin class (answer) can stop the error rules on its own.
    twins = dict(trial, answer_posterior=[0.5, 0.9995, 0.9995, 0.9995])
    curves = planner_benchmark.stop_curves([twins], fault_ratio=1.0)
    point = curves['error rule: 1 - posterior <= e'][4]            # e = 0.003
    assert point['parameter'] == 0.003 and point['actions_mean'] == 1.0


def test_stop_curve_cli(capsys, tmp_path):
    plot = tmp_path / 'curve.png'
    assert planner_benchmark.main(['--models', '30', '--trials', '2', '--planners', 'abp',
                                   '--stop', 'fixed', '--max-actions', '6',
                                   '--stop-curve', str(plot)]) == 0
    out = capsys.readouterr().out
    assert '|M|=30 abp posterior > t (old rule)' in out and plot.stat().st_size > 0
    assert np.isfinite(planner_benchmark.fault_likelihood_ratio())
