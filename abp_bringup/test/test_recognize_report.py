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
