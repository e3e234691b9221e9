"""recognize_client's report (no DDS): real action-result and ground-truth messages, the
summary JSON, the verdict line and the exit code; an aborted goal is not an identification
even when its most likely object is the true one."""

import json
from types import SimpleNamespace

import pytest
from action_msgs.msg import GoalStatus

from abp_bringup.recognize_client import report
from abp_msgs.action import Recognize
from abp_msgs.msg import SimGroundTruth


def _response(status, success, object_id):
    result = Recognize.Result(success=success, object_id=object_id, posterior=0.996,
                              actions_taken=30, reason='stop reason here',
                              top_object_ids=[object_id, 'other'],
                              top_posteriors=[0.996, 0.004])
    return SimpleNamespace(status=status, result=result)


@pytest.mark.parametrize('status, success, named, code, correct, likely, line', [
    (GoalStatus.STATUS_SUCCEEDED, True, 'cube_a', 0, True, True, '-> correct'),
    (GoalStatus.STATUS_SUCCEEDED, True, 'cube_b', 1, False, False, '-> WRONG'),
    (GoalStatus.STATUS_ABORTED, False, 'cube_a', 1, False, True,
     '-> not identified (most likely object right)'),
    (GoalStatus.STATUS_ABORTED, False, 'cube_b', 1, False, False,
     '-> not identified (most likely object wrong)'),
])
def test_report_counts_only_an_identification_as_correct(tmp_path, capsys, status, success,
                                                        named, code, correct, likely, line):
    tracer = SimpleNamespace(belief=None, ground_truth=SimGroundTruth(object_id='cube_a'))
    out = tmp_path / 'result.json'
    assert report(_response(status, success, named), tracer, str(out)) == code
    summary = json.loads(out.read_text())
    assert summary['correct'] is correct and summary['most_likely_correct'] is likely
    assert summary['ground_truth'] == 'cube_a' and summary['object_id'] == named
    assert f'ground truth: cube_a {line}' in capsys.readouterr().out


def test_report_without_ground_truth_has_no_verdict(tmp_path, capsys):
    tracer = SimpleNamespace(belief=None, ground_truth=None)
    out = tmp_path / 'result.json'
    assert report(_response(GoalStatus.STATUS_SUCCEEDED, True, 'cube_a'), tracer,
                  str(out)) == 0
    assert 'correct' not in json.loads(out.read_text())
    assert 'ground truth' not in capsys.readouterr().out


def test_a_task_result_lists_every_object_track(tmp_path, capsys):
    from abp_msgs.msg import ObjectResult
    result = Recognize.Result(success=True, object_id='cube_a', posterior=0.99,
                              actions_taken=7, reason='found', found_track_id='2',
                              objects=[ObjectResult(track_id='1', object_id='cube_b',
                                                    posterior=0.4, actions_taken=3,
                                                    decided=False, reason='not the target'),
                                       ObjectResult(track_id='2', object_id='cube_a',
                                                    posterior=0.99, actions_taken=4,
                                                    decided=True, reason='found')])
    out = tmp_path / 'result.json'
    response = SimpleNamespace(status=GoalStatus.STATUS_SUCCEEDED, result=result)
    assert report(response, SimpleNamespace(belief=None, ground_truth=None), str(out)) == 0
    summary = json.loads(out.read_text())
    assert summary['found_track_id'] == '2'
    assert [o['track_id'] for o in summary['objects']] == ['1', '2']
    assert summary['objects'][1] == {'track_id': '2', 'object_id': 'cube_a', 'posterior': 0.99,
                                     'actions': 4, 'decided': True, 'reason': 'found'}
    assert 'track 1: cube_b 0.400, 3 actions, not named (not the target)' in \
        capsys.readouterr().out


@pytest.mark.parametrize('argv', [
    ['--task', 'find'],                              # find needs the model it seeks
    ['--task', 'identify'],                          # identify needs the track
    ['--task', 'identify_all', '--track-id', '3'],   # a track without identify
    ['--task', 'bogus'],
])
def test_task_arguments_that_do_not_fit_are_refused(argv):
    from abp_bringup.recognize_client import parse_args
    with pytest.raises(SystemExit) as exited:
        parse_args(argv)
    assert exited.value.code == 2
