"""outcome_survey: its symmetry classes and outcome mapping (no physics), and a tiny survey
end to end (1 trial, 2 classes, real MuJoCo physics, < 30 s)."""

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from abp_belief.cube import ACTIONS, MANUAL_ACTIONS, ORBIT_STEPS, rot_x, rot_y
from abp_belief.modelset import TransitionParams
from abp_bench import outcome_survey as survey
from abp_description.frames import rot_z_deg


def test_classes_partition_the_cells_by_parity_and_mass_direction():
    classes = survey.build_classes()
    for action, cls_list in classes.items():
        cells = [ms for c in cls_list for ms in c.members]
        assert sorted(cells) == [(m, s) for m in range(7) for s in range(48)]
        if action in ORBIT_STEPS:
            assert [len(c.members) for c in cls_list] == [168, 168]
        else:
            assert len(cls_list) == 14 and all(len(c.members) == 24 for c in cls_list)
        for c in cls_list:
            assert len({s % 2 for _, s in c.members}) == 1


def test_mapping_agrees_with_the_tables_own_symmetry():
    # The hand-written tables are written in V (MODEL.md), so they respect the classes:
    # mapping the representative's table distribution must give each member's.
    table = survey.table_distributions()
    for action, cls_list in survey.build_classes(MANUAL_ACTIONS).items():
        a = ACTIONS.index(action)
        for c in cls_list:
            rm, rs = c.rep
            for m, s in c.members:
                mapped = np.zeros(48)
                for nxt in np.nonzero(table[a, rm, rs])[0]:
                    mapped[survey.map_outcome(rs, nxt, s)] += table[a, rm, rs, nxt]
                np.testing.assert_allclose(mapped, table[a, m, s], atol=1e-12)


@pytest.mark.parametrize('q, name', [
    (np.eye(3), 'none'), (rot_z_deg(-45), 'Rz-45'), (rot_y(-90), 'Ry-90'),
    (rot_x(180), 'Rx180'), (rot_z_deg(45) @ rot_y(90) @ rot_z_deg(-45), 'R(-x+y)+90')])
def test_rotation_names(q, name):
    assert survey.rotation_name(q) == name


def test_the_simulation_side_never_imports_the_tables():
    code = ('import sys\n'
            'from abp_bench.outcome_survey import simulate, Randomisation\n'
            "r = simulate(dict(action='ORBIT_P45', mass=3, state=36, seed=1,\n"
            '                  rand=Randomisation().__dict__))\n'
            "assert r['final_state'] == 37, r\n"
            "assert 'abp_belief.modelset' not in sys.modules\n")
    subprocess.run([sys.executable, '-c', code], check=True, timeout=120)


@pytest.mark.timeout(120)   # ~15 s on an idle 2-core machine
def test_tiny_survey_writes_json_markdown_and_heat_map(tmp_path):
    # PUSH on a heavy-+y cube, even yaws: the classes 'mass +x_V' and 'mass +y_V', against
    # the paper's table (which pivots the side-heavy cube; the corrected one slides it).
    assert survey.main(['--trials', '1', '--actions', 'PUSH', '--masses', 'm+y',
                        '--parity', 'even', '--max-classes', '2', '--jobs', '2',
                        '--tables', 'paper', '--no-symmetry-check', '--no-progress',
                        '--out', str(tmp_path)]) == 0
    doc = json.loads((tmp_path / 'survey.json').read_text())
    assert doc['settings']['trials'] == 1 and doc['versions']['mujoco']
    assert [c['label'] for c in doc['classes']] == ['mass +x_V, even yaw',
                                                     'mass +y_V, even yaw']
    assert len(doc['cells']) == 8 and all(c['trials'] == 1 for c in doc['cells'])
    assert len(doc['trials']) == 2 and all(t['start_ok'] and t['ran'] for t in doc['trials'])
    # The table's nominal for a +y_V mass is a -45 deg pivot; the flag says whether physics
    # agrees (one trial: either 0 or >= 88 points apart).
    pivot = doc['classes'][1]
    assert pivot['table']['Rz-45'] == pytest.approx(0.88)
    assert pivot['flagged_cells'] in (0, 4)
    assert '| PUSH | mass +y_V, even yaw | 4 |' in (tmp_path / 'survey.md').read_text()
    assert 'hand-written one, paper rules' in (tmp_path / 'survey.md').read_text()
    # The same trials against the corrected table, which slides it: 98 % of the rules'
    # share, plus its part of the unmodelled share (no change is one of 7 neighbours).
    assert survey.main(['--report-only', '--out', str(tmp_path)]) == 0
    slide = json.loads((tmp_path / 'survey.json').read_text())['classes'][1]
    unmodelled = TransitionParams().p_unmodelled
    assert slide['table']['none'] == pytest.approx(0.98 * (1 - unmodelled) + unmodelled / 7)
    assert slide['flagged_cells'] == 4 - pivot['flagged_cells']
    assert (tmp_path / 'survey.png').stat().st_size > 10_000


def test_a_drawn_missed_push_leaves_the_cube_alone():
    # The fault is physical: the hands pass 10 cm outside the cube, so nothing touches it.
    rand = survey.Randomisation(p_missed_push=1.0)
    record = survey.simulate(dict(action='PUSH', mass=0, state=4, seed=3, rand=rand.__dict__))
    assert record['fault'] == 'missed push'
    assert record['ran'] and record['start_ok']
    assert record['final_state'] == 4 and record['moved_cm'] < 0.5, record
    nominal = survey.simulate(dict(action='PUSH', mass=0, state=4, seed=3,
                                   rand=survey.Randomisation().__dict__))
    assert nominal['fault'] == '' and nominal['moved_cm'] > 1.0, nominal


@pytest.mark.timeout(120)
def test_the_survey_pushes_with_the_one_arm_of_the_robot_its_profile_names(tmp_path):
    # rover5 (abp_description/profiles/rover5.yaml): one arm, its ball the only hand.
    from abp_description.robot_profile import default_profile_path
    rover = str(pathlib.Path(default_profile_path()).with_name('rover5.yaml'))
    try:
        assert survey.main(['--robot-profile', rover, '--trials', '1', '--actions', 'PUSH',
                            '--masses', 'u', '--parity', 'even', '--max-classes', '1',
                            '--jobs', '1', '--no-symmetry-check', '--no-progress',
                            '--out', str(tmp_path)]) == 0
        doc = json.loads((tmp_path / 'survey.json').read_text())
        assert doc['settings']['robot'] == 'rover5'
        assert doc['settings']['robot_profile'] == rover
        (trial,) = doc['trials']
        assert trial['ran'] and trial['effects'] == ['slid'], trial
        assert 'arm hand' in trial['events'][0] and trial['moved_cm'] > 3.0, trial
        # Its missed push turns the arm's base aside (the profile's grasp_opening_joints).
        missed = survey.simulate(dict(action='PUSH', mass=0, state=4, seed=3, rand=survey
                                      .Randomisation(p_missed_push=1.0).__dict__))
        assert missed['fault'] == 'missed push' and missed['moved_cm'] < 0.5, missed
    finally:
        survey._WORKER.clear()   # later tests simulate the default robot
