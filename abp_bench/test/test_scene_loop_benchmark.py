"""scene_loop_benchmark's scoring of a Recognize result against the scene's truth (the DDS
loop itself is run by hand: docs/MULTI_OBJECT.md)."""

import pytest

pytest.importorskip('rclpy')

from abp_bench.scene_loop_benchmark import score, summarise  # noqa: E402
from abp_msgs.action import Recognize  # noqa: E402
from abp_msgs.msg import ObjectResult  # noqa: E402

NAMES = ['m0', 'm1', 'm2', 'm3']
TRUTH = {'cube1': 0, 'cube2': 1, 'cube3': 2}


def result(named, found='', success=True, actions=6):
    return Recognize.Result(success=success, actions_taken=actions, found_track_id=found,
                            objects=[ObjectResult(track_id=t, object_id=m, decided=True,
                                                  actions_taken=2) for t, m in named.items()])


def test_identify_all_is_correct_only_when_every_cube_is_named_right():
    right = result({'cube1': 'm0', 'cube2': 'm1', 'cube3': 'm2'})
    assert score('identify_all', right, TRUTH, NAMES, None)['correct']
    one_wrong = score('identify_all', result({'cube1': 'm0', 'cube2': 'm3', 'cube3': 'm2'}),
                      TRUTH, NAMES, None)
    assert not one_wrong['correct'] and one_wrong['wrong'] == 1
    missing = score('identify_all', result({'cube1': 'm0', 'cube2': 'm1'}), TRUTH, NAMES, None)
    assert not missing['correct']
    extra = score('identify_all', result({'cube1': 'm0', 'cube2': 'm1', 'cube3': 'm2',
                                          'ghost': 'm3'}), TRUTH, NAMES, None)
    assert extra['correct'] and extra['wrong'] == 1


def test_find_scores_the_found_track_against_the_truth():
    named = {'cube1': 'm0', 'cube2': 'm1', 'cube3': 'm2'}
    assert score('find_present', result(named, found='cube2'), TRUTH, NAMES, 1)['correct']
    wrong = score('find_present', result(named, found='cube3'), TRUTH, NAMES, 1)
    assert not wrong['correct'] and wrong['wrong'] == 1
    assert score('find_absent', result(named), TRUTH, NAMES, 3)['correct']
    assert not score('find_absent', result(named, success=False), TRUTH, NAMES, 3)['correct']
    assert score('find_absent', result(named, found='cube1'), TRUTH, NAMES, 3)['wrong'] == 1


def test_summary_ratios():
    row = {'actions': 6, 'correct': True, 'wrong': 0, 'wall_s': 1.0}
    records = [{'identify_all': {**row, 'actions': 10}, 'find_present': {**row, 'actions': 4},
                'find_absent': row, 'single': [{'actions': 4, 'correct': True}] * 3}]
    summary = summarise(records)
    assert summary['identify_all_over_single'] == pytest.approx(10 / 12)
    assert summary['find_present_fewer_than_identify_all'] == pytest.approx(0.6)
    assert summary['single_sum']['correct_cubes'] == 3
