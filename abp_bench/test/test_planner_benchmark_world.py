"""planner_benchmark --world-models / --belief-models (issue 13): model error in the
model-sampled protocol."""

import json

import numpy as np
import pytest

from abp_belief import atg_learning, model_file, population
from abp_belief.cube import ACTIONS
from abp_belief.modelset import TransitionParams
from abp_bench import planner_benchmark


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('tables')
    robot = population.robot_set(seed=0, transition_params=TransitionParams(rules='paper'))
    hand = tmp / 'hand.npz'                       # the benchmark's default (paper) tables
    model_file.save(robot, hand)
    # A world where LIFT never does anything and FLIP of a uniform cube rolls it 180 deg.
    lift, flip = ACTIONS.index('LIFT'), ACTIONS.index('FLIP')
    rows = [[lift, m, s, s] for m in range(7) for s in range(48)]
    rows += [[flip, 0, 0, 8 * 5 + 4]] * 5                     # Ry180 of state 0 (+z up)
    exp = atg_learning.Experience(*np.array(rows).T, np.ones(len(rows)))
    world = tmp / 'world.npz'
    model_file.save(atg_learning.with_tables(robot, atg_learning.learn(exp, alpha=0.0)), world)
    return hand, world


def _run(tmp_path, *extra):
    out = tmp_path / 'out.json'
    planner_benchmark._WORKER.clear()
    assert planner_benchmark.main(['--models', 'robot', '--trials', '6', '--planners', 'abp',
                                   '--json', str(out), *extra]) == 0
    return json.loads(out.read_text())['trials']


def test_world_with_the_beliefs_own_tables_changes_nothing(files, tmp_path, capsys):
    hand, _ = files
    plain = _run(tmp_path)
    same = _run(tmp_path, '--world-models', str(hand), '--belief-models', str(hand))
    keys = ('true_model', 'initial_state', 'actions', 'correct', 'final_true_posterior')
    assert [{k: t[k] for k in keys} for t in plain] == [{k: t[k] for k in keys} for t in same]
    assert f'world {hand}' in capsys.readouterr().out


def test_tables_choose_the_hand_written_table(tmp_path, capsys):
    corrected = tmp_path / 'corrected.npz'
    model_file.save(population.robot_set(seed=0), corrected)
    by_option = _run(tmp_path, '--tables', 'corrected')
    assert 'belief hand-written corrected' in capsys.readouterr().out
    by_file = _run(tmp_path, '--world-models', str(corrected), '--belief-models', str(corrected))
    keys = ('true_model', 'initial_state', 'actions', 'correct', 'final_true_posterior')
    assert [{k: t[k] for k in keys} for t in by_option] == \
        [{k: t[k] for k in keys} for t in by_file]
    assert [t['actions'] for t in by_option] != [t['actions'] for t in _run(tmp_path)]


def test_world_tables_drive_the_outcomes(files, tmp_path):
    hand, world = files
    plain = _run(tmp_path)
    moved = _run(tmp_path, '--world-models', str(world))
    assert [t['true_model'] for t in plain] == [t['true_model'] for t in moved]  # same seeds
    assert [t['actions'] for t in plain] != [t['actions'] for t in moved]


def test_world_model_set_keeps_the_models(files):
    _, world = files
    robot = population.robot_set(seed=0)
    w = planner_benchmark.with_model_tables(robot, str(world))
    assert w.names == robot.names and w.outcome_counts is not None
    assert planner_benchmark.with_model_tables(robot, None) is robot


def test_bad_world_file_is_a_usage_error(tmp_path, capsys):
    bad = tmp_path / 'bad.npz'
    bad.write_text('not a model file')
    with pytest.raises(SystemExit) as info:
        planner_benchmark.main(['--models', 'robot', '--trials', '1', '--world-models',
                                str(bad)])
    assert info.value.code == 2 and 'not a model-set file' in capsys.readouterr().err


def test_learning_curve_runs(tmp_path):
    from abp_belief.atg_learning import CLASS_LABELS, CLASS_REP
    from abp_bench import atg_learning_curve

    lift = ACTIONS.index('LIFT')
    trials = [dict(action='LIFT', klass=CLASS_LABELS[lift][c], trial=t, mass=m, state=s,
                   final_state=s, ran=True)
              for c, (m, s) in enumerate(CLASS_REP[lift]) for t in range(2)]
    survey = tmp_path / 'survey.json'
    survey.write_text(json.dumps(dict(settings=dict(trials=2, seed=0), trials=trials)))
    result = atg_learning_curve.run(survey, tmp_path / 'out', counts=(1, 2), draws=1,
                                    models=('robot',), trials=2, progress=False)
    assert [p['n'] for p in result['points']] == [1, 2]
    assert (tmp_path / 'out' / 'learning_curve.png').stat().st_size > 0
    assert 'LIFT' in (tmp_path / 'out' / 'learned_vs_hand.md').read_text()


def test_results_split_by_object_family_on_the_robot_set(tmp_path, capsys):
    robot = population.robot_set(seed=0)
    families = planner_benchmark.object_families(robot)
    # 18 visual cubes, two of them with their 6 eccentric twins.
    assert families.count('visual only') == 16
    assert families.count('twin family, uniform') == 2
    assert families.count('twin family, eccentric') == 12
    trials = _run(tmp_path)
    out = capsys.readouterr().out
    assert 'By object family' in out
    for family in set(families[t['true_model']] for t in trials):
        n = sum(families[t['true_model']] == family for t in trials)
        assert f'| robot | abp | {family} | {n} |' in out
    uniform_only = population.random_visual_subset(30, seed=0)
    assert set(planner_benchmark.object_families(uniform_only)) == {'visual only'}
    assert planner_benchmark.family_table({('30', 'abp'): trials}, ['30'], ['abp'], 0) is None


def test_family_draws_the_true_object_from_that_family_only(tmp_path, capsys):
    families = planner_benchmark.object_families(population.robot_set(seed=0))
    trials = _run(tmp_path, '--family', 'twin family, uniform')
    assert {families[t['true_model']] for t in trials} == {'twin family, uniform'}
    assert 'true objects: twin family, uniform only' in capsys.readouterr().out
    # Both uniform cubes with twins are drawn, not one fixed model.
    assert len({t['true_model'] for t in _run(tmp_path, '--trials', '12', '--family',
                                                 'twin family, uniform')}) == 2


def test_family_the_set_does_not_have_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        planner_benchmark.parse_args(['--models', '30', '--family', 'twin family, uniform'])
    assert 'model set 30 has no such object' in capsys.readouterr().err
