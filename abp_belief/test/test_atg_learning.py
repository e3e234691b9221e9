"""The ATG learner (issue 13): Dirichlet estimate, pooling, counts, model files, CLI."""

import json
from pathlib import Path

import numpy as np
import pytest

from abp_belief import atg_learning as L
from abp_belief import cube, model_file, population
from abp_belief.cube import ACTIONS, STATES_PER_MODEL, apply_rotation
from abp_belief.learn_atg_cli import main as learn_atg
from abp_belief.modelset import TransitionParams

PUSH, LIFT, FLIP = (ACTIONS.index(a) for a in ('PUSH', 'LIFT', 'FLIP'))


def _experience(rows, weight=None):
    rows = np.array(rows, dtype=np.int64).reshape(-1, 4)
    w = np.ones(len(rows)) if weight is None else weight
    return L.Experience(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], w)


def _survey(per_class=3):
    """A small outcome_survey-like document: LIFT, every class, `per_class` trials at the
    representative; uniform even-yaw class: 1 of 3 trials rolls front-to-top (Ry-90)."""
    trials = []
    roll = cube.rot_y(-90.0)
    for c, (m, s) in enumerate(L.CLASS_REP[LIFT]):
        for t in range(per_class):
            nxt = apply_rotation(roll, s) if (c == 0 and t == 0) else s
            trials.append(dict(action='LIFT', klass=L.CLASS_LABELS[LIFT][c], trial=t, mass=m,
                               state=s, final_state=int(nxt), ran=True))
    trials.append(dict(action='LIFT', klass='x', trial=9, mass=0, state=0, final_state=None,
                       ran=False))
    return dict(settings=dict(trials=per_class, seed=0), trials=trials)


def test_map_is_the_motion_in_the_view_frame():
    rng = np.random.default_rng(0)
    for s, s2 in rng.integers(0, STATES_PER_MODEL, (20, 2)):
        q = cube.STATE_ROTATIONS[s2] @ cube.STATE_ROTATIONS[s].T
        for t in range(STATES_PER_MODEL):
            try:
                expected = apply_rotation(q, t)
            except ValueError:
                expected = -1
            assert L.MAP[s, s2, t] == expected


def test_motion_names():
    assert L.motion_name(cube.rot_y(-90.0)) == 'Ry-90'              # uniform FLIP (MODEL.md)
    assert L.motion_name(cube.rot_x(90.0)) == 'Rx+90'
    assert L.motion_name(cube.rot_y(180.0)) == 'Ry180'
    assert L.motion_name(np.eye(3)) == 'none'
    rz = cube.STATE_ROTATIONS[1] @ cube.STATE_ROTATIONS[0].T          # +45 deg yaw
    assert L.motion_name(rz) == 'Rz+45'
    assert L.motion_name(rz @ cube.rot_y(-90.0)) == 'Ry-90 Rz+45'


def test_classes_are_the_surveys():
    # 14 classes per manual action, 2 per ORBIT; every member's mass direction agrees.
    assert [len(c) for c in L.CLASS_LABELS] == [2] * 5 + [14] * 3
    for a in range(len(ACTIONS)):
        for c, (m0, s0) in enumerate(L.CLASS_REP[a]):
            assert L.CLASS_OF[a, m0, s0] == c


def test_unseen_transitions_stay_possible_and_rows_sum_to_one():
    # Mass +x, state 16: LIFT's table nominal is Ry+90 (90 %); we only ever see 'none'.
    m, s = 1, 16
    learned = L.learn(_experience([[LIFT, m, s, s]] * 20), alpha=2.0)
    hand = L.hand_table()
    nominal = int(np.argmax(hand[LIFT, m, s]))
    assert nominal != s
    row = learned.probs[LIFT, m, s]
    assert row[s] > 0.9 and row[nominal] > 0                     # prior keeps the table edge
    near = L.neighbourhood('near')[s]
    assert (row[near] > 0).all() and near.sum() == 7             # and the neighbourhood
    assert np.allclose(learned.probs.sum(axis=3), 1.0)
    states, probs, counts = learned.outcome_tables()
    assert np.allclose(probs.sum(axis=3), 1.0) and states.dtype == np.int16
    assert (probs[LIFT, m, s] > 0).sum() == (row > 0).sum()
    assert counts[LIFT, m, s].sum() == 20


def test_alpha_zero_is_empirical_and_no_data_is_the_prior():
    learned = L.learn(_experience([[PUSH, 3, 18, 18]] * 3 + [[PUSH, 3, 18, 17]]), alpha=0.0)
    assert learned.probs[PUSH, 3, 18, 18] == pytest.approx(0.75)
    assert learned.probs[PUSH, 3, 18, 17] == pytest.approx(0.25)
    empty = L.learn(_experience(np.zeros((0, 4))), alpha=2.0)
    assert np.allclose(empty.probs, L.prior_mean())
    uniform = L.prior_mean('uniform')
    assert np.allclose(uniform.sum(axis=3), 1.0)
    with pytest.raises(ValueError, match='alpha'):
        L.learn(_experience([[PUSH, 0, 0, 0]]), alpha=-1)


def test_pooling_gives_every_class_member_the_mapped_counts():
    m, s, nxt = 1, 16, apply_rotation(cube.rot_y(90.0), 16)      # heavy +x_V, even yaw
    counts = L.pooled_counts(_experience([[LIFT, m, s, nxt]] * 4 + [[LIFT, m, s, s]]))
    c = L.CLASS_OF[LIFT, m, s]
    members = np.argwhere(L.CLASS_OF[LIFT] == c)
    assert len(members) == 24
    for mm, ss in members:
        row = counts[LIFT, mm, ss]
        assert row.sum() == 5 and row[ss] == 1
        # The same motion in V: the member's heavy face ends down as well.
        assert row[apply_rotation(cube.rot_y(90.0), ss)] == 4
    assert counts.sum() == 24 * 5
    unpooled = L.pooled_counts(_experience([[LIFT, m, s, nxt]]), pool=False)
    assert unpooled.sum() == 1 and unpooled[LIFT, m, s, nxt] == 1


def test_weighted_experience_and_bad_experience():
    counts = L.pooled_counts(_experience([[PUSH, 0, 0, 0]], weight=np.array([0.25])), pool=False)
    assert counts[PUSH, 0, 0, 0] == 0.25
    with pytest.raises(L.LearningError, match='state'):
        _experience([[PUSH, 0, 48, 0]])
    with pytest.raises(L.LearningError, match='weights'):
        _experience([[PUSH, 0, 0, 0]], weight=np.array([0.0]))


def test_survey_experience_and_subsampling(tmp_path):
    doc = _survey(per_class=3)
    exp = L.experience_from_survey(doc)
    assert len(exp) == 14 * 3                                     # the not-run trial is skipped
    assert len(L.experience_from_survey(doc, trials_per_class=1)) == 14
    assert len(L.experience_from_survey(doc, 2, subsample_seed=1)) == 28
    learned = L.learn(exp)
    m, s = L.CLASS_REP[LIFT][0]
    assert learned.trials[LIFT, m, s] == 3
    path = tmp_path / 'survey.json'
    path.write_text(json.dumps(doc))
    assert len(L.experience_from_survey(path)) == 42
    with pytest.raises(L.LearningError, match='no such file'):
        L.experience_from_survey(tmp_path / 'missing.json')
    path.write_text('{"cells": []}')
    with pytest.raises(L.LearningError, match='trials'):
        L.experience_from_survey(path)


def test_model_file_round_trip_keeps_tables_counts_and_provenance(tmp_path, robot):
    learned = L.learn(L.experience_from_survey(_survey()))
    models = L.with_tables(robot, learned)
    assert models.names == robot.names and models.outcome_counts is not None
    path = tmp_path / 'learned.npz'
    model_file.save(models, path)
    loaded = model_file.load(path)
    for name in ('outcome_states', 'outcome_probs', 'outcome_counts', 'faces', 'mass'):
        assert np.array_equal(getattr(loaded, name), getattr(models, name)), name
    assert loaded.learning['alpha'] == learned.info['alpha']
    assert loaded.learning['prior'] == 'table'
    for name, matrix in models.transitions.items():
        assert (matrix != loaded.transitions[name]).nnz == 0
    # The model-set id covers the tables, not the counts.
    assert model_file.fingerprint(loaded) == model_file.fingerprint(models)
    assert model_file.fingerprint(loaded) != model_file.fingerprint(robot)
    # A subset keeps the learned tables and counts.
    assert np.array_equal(loaded.subset([0, 1]).outcome_counts, models.outcome_counts)


def _members(path):
    with np.load(path, allow_pickle=False) as npz:
        members = {k: npz[k] for k in npz.files}
    return json.loads(members.pop('header').tobytes()), members


def test_corrupt_learned_file_is_refused(tmp_path, robot):
    path = tmp_path / 'learned.npz'
    model_file.save(L.with_tables(robot, L.learn(L.experience_from_survey(_survey()))), path)
    header, arrays = _members(path)
    arrays['outcome_counts'] = arrays['outcome_counts'] + 1.0
    model_file.write_npz(path, header, arrays)                    # no rehash
    with pytest.raises(model_file.ModelFileError, match='checksum mismatch'):
        model_file.load(path)
    arrays['outcome_counts'][0, 0, 0, 0] = -1.0
    header['sha256'] = model_file.arrays_sha256(arrays)
    model_file.write_npz(path, header, arrays)
    with pytest.raises(model_file.ModelFileError, match='outcome_counts'):
        model_file.load(path)
    del arrays['outcome_counts']                                  # listed but missing
    header['sha256'] = model_file.arrays_sha256(arrays)
    model_file.write_npz(path, header, arrays)
    with pytest.raises(model_file.ModelFileError, match="missing array 'outcome_counts'"):
        model_file.load(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(model_file.ModelFileError, match='truncated or corrupt'):
        model_file.load(path)


def test_version_1_files_are_still_read(tmp_path, robot):
    path = tmp_path / 'v1.npz'
    model_file.save(robot, path)
    header, arrays = _members(path)
    assert header['version'] == 2 and 'outcome_counts' not in arrays
    header['version'] = 1
    del header['learning']
    model_file.write_npz(path, header, arrays)
    loaded = model_file.load(path)
    assert loaded.outcome_counts is None and loaded.learning is None
    assert model_file.fingerprint(loaded) == header['sha256']


def test_contact_faults_mix_no_change_into_manual_rows_only():
    # A +x-heavy cube at state 16 that LIFT rolls as the table says, 20 times of 20.
    m, s = 1, 16
    rolled = int(np.argmax(L.hand_table()[LIFT, m, s]))
    assert rolled != s
    experience = _experience([[LIFT, m, s, rolled]] * 20)
    plain = L.learn(experience, alpha=2.0)
    faulty = L.learn(experience, alpha=2.0, fault_rates=TransitionParams().fail_rates())
    assert plain.probs[LIFT, m, s, s] < 0.02                     # the prior's sliver only
    assert faulty.probs[LIFT, m, s, s] == pytest.approx(0.1 + 0.9 * plain.probs[LIFT, m, s, s])
    assert faulty.probs[LIFT, m, s, rolled] == pytest.approx(0.9 * plain.probs[LIFT, m, s, rolled])
    orbit = [ACTIONS.index(a) for a in ACTIONS if a.startswith('ORBIT')]
    assert np.array_equal(faulty.probs[orbit], plain.probs[orbit])
    assert np.allclose(faulty.probs.sum(axis=3), 1.0)
    assert np.array_equal(faulty.counts, plain.counts)           # experience is unchanged
    assert faulty.info['contact_fault_rates'] == {'PUSH': 0.1, 'LIFT': 0.1, 'FLIP': 0.1}
    with pytest.raises(ValueError, match='ORBIT'):
        L.with_contact_faults(plain.probs, {'ORBIT_P45': 0.1})
    with pytest.raises(ValueError, match=r'\[0, 1\)'):
        L.with_contact_faults(plain.probs, {'LIFT': 1.0})
    with pytest.raises(ValueError, match='unknown'):
        L.with_contact_faults(plain.probs, {'JUMP': 0.1})


def test_learn_atg_cli(tmp_path, capsys):
    survey = tmp_path / 'survey.json'
    survey.write_text(json.dumps(_survey()))
    out, report = tmp_path / 'learned.npz', tmp_path / 'report.md'
    assert learn_atg(['--survey', str(survey), '--out', str(out), '--report', str(report),
                      '--json']) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary['transitions'] == 42 and summary['models'] == 30
    loaded = population.model_set_from_config(model_file=str(out))   # as every node loads it
    assert loaded.learning['source']['kind'] == 'outcome_survey'
    assert loaded.learning['contact_fault_rates'] == {}
    faulty = tmp_path / 'faulty.npz'
    assert learn_atg(['--survey', str(survey), '--contact-fault-rate', '0.1',
                      '--out', str(faulty)]) == 0
    assert population.model_set_from_config(model_file=str(faulty)).learning[
        'contact_fault_rates'] == {'PUSH': 0.1, 'LIFT': 0.1, 'FLIP': 0.1}
    assert learn_atg(['--survey', str(survey), '--contact-fault-rate', '1.5']) == 2
    assert '--contact-fault-rate must be in [0, 1)' in capsys.readouterr().err
    text = report.read_text()
    assert '| LIFT | uniform, even yaw | 24 | 3 |' in text and 'TV' in text
    assert learn_atg(['--survey', str(tmp_path / 'none.json')]) == 2
    assert 'no such file' in capsys.readouterr().err


def test_several_surveys_pool_their_trials(tmp_path, capsys):
    first, second = tmp_path / 'seed0.json', tmp_path / 'seed1.json'
    first.write_text(json.dumps(_survey(per_class=3)))
    second.write_text(json.dumps(_survey(per_class=2)))
    out = tmp_path / 'pooled.npz'
    report = tmp_path / 'report.md'
    assert learn_atg(['--survey', str(first), str(second), '--out', str(out), '--json',
                      '--report', str(report)]) == 0
    assert json.loads(capsys.readouterr().out)['transitions'] == 14 * 5
    assert f'outcome_survey {first}, outcome_survey {second}' in report.read_text()
    learned = population.model_set_from_config(model_file=str(out)).learning
    assert [p['trials'] for p in learned['source']['parts']] == [3, 2]
    # The counts behind a row are both surveys' trials: 3 + 2 at each class representative,
    # and the rolls of both (one per survey) in the uniform even-yaw row.
    both = L.Experience.concatenate([L.experience_from_survey(json.loads(p.read_text()))
                                     for p in (first, second)])
    counts = L.pooled_counts(both)
    m, s = L.CLASS_REP[LIFT][0]
    assert counts[LIFT, m, s].sum() == 5
    assert counts[LIFT, m, s, apply_rotation(cube.rot_y(-90.0), s)] == 2
    assert learn_atg(['--survey', str(first), str(second), '--trials-per-class', '1']) == 2
    assert 'needs a single --survey' in capsys.readouterr().err
    with pytest.raises(L.LearningError, match='no experience'):
        L.Experience.concatenate([])


def test_learner_takes_a_survey_sized_experience():
    # 1040 transitions (the N = 20 survey's size), pooled and estimated. Its speed is a
    # benchmark figure (`learn_atg` prints it; docs/BENCHMARKS.md), not a timed test.
    rng = np.random.default_rng(0)
    a = rng.integers(0, len(ACTIONS), 1040)
    m = rng.integers(0, 7, 1040)
    s = rng.integers(0, 48, 1040)
    exp = L.Experience(a, m, s, s, np.ones(1040))
    learned = L.learn(exp)
    assert learned.info['transitions'] == 1040 and learned.info['learn_s'] >= 0.0
    np.testing.assert_allclose(learned.probs.sum(axis=3), 1.0)
    # Every transition went to its own start: where a row has 3 or more trials (more than
    # the prior's alpha = 2 pseudo-trials), its most likely next state is its start.
    rows = np.argwhere(learned.trials >= 3)
    assert rows.size
    assert all(learned.probs[i, j, k].argmax() == k for i, j, k in rows)


def test_shipped_model_files_load_as_the_nodes_load_them():
    models = Path(__file__).resolve().parents[1] / 'models'
    shipped = sorted(models.glob('*.npz'))
    assert {p.name for p in shipped} >= {'learned_robot_mujoco.npz',
                                         'learned_robot_mujoco_70trials.npz'}
    for path in shipped:
        loaded = population.model_set_from_config(model_file=str(path))
        assert loaded.num_models == 30 and loaded.learning['alpha'] == 2.0
    pooled = population.model_set_from_config(
        model_file=str(models / 'learned_robot_mujoco_70trials.npz')).learning['source']
    assert [p['trials'] for p in pooled['parts']] == [20, 50, 50]
