import json

import numpy as np
import pytest

from abp_belief import model_file, models_cli
from abp_belief.modelset import TransitionParams, build_outcome_tables


def _run(capsys, *argv):
    code = models_cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_json_summary_full(capsys):
    code, out, err = _run(capsys, '--set', 'full', '--json')
    assert code == 0, err
    summary = json.loads(out)
    assert summary['models'] == 1470
    assert summary['visual_cubes'] == 210
    assert summary['aspect_nodes'] == 1470 * 48
    assert summary['distinct_aspects'] == 252
    # (top, front) pairs: 840 models each; corner triples: 168 models each.
    assert summary['models_per_aspect_histogram'] == {'168': 210, '840': 42}
    assert '\n' not in out.strip()                      # compact: one line


def test_json_summary_robot_and_random(capsys):
    code, out, _ = _run(capsys, '--set', 'robot', '--seed', '3', '--json')
    summary = json.loads(out)
    assert code == 0 and summary['models'] == 30 and summary['visual_cubes'] == 18
    assert summary['eccentric_models'] == 12
    assert sum(summary['models_per_aspect_histogram'].values()) == summary['distinct_aspects']
    code, out, _ = _run(capsys, '--set', 'random', '--size', '60', '--tags', '8', '--json')
    summary = json.loads(out)
    assert code == 0 and summary['models'] == 60 and summary['n_tags'] == 8


def test_readable_summary_and_save_load(capsys, tmp_path):
    path = tmp_path / 'm.npz'
    code, out, _ = _run(capsys, '--set', 'visual', '--out', str(path))
    assert code == 0
    assert 'models           : 210' in out and 'distinct aspects : 252' in out
    assert path.exists()
    code, out, _ = _run(capsys, '--load', str(path), '--json')
    assert code == 0 and json.loads(out)['models'] == 210


def test_tables_choose_the_saved_hand_written_table(capsys, tmp_path):
    for tables in ('paper', 'corrected'):
        path = tmp_path / f'{tables}.npz'
        code, _, err = _run(capsys, '--set', 'robot', '--tables', tables, '--out', str(path))
        assert code == 0, err
        saved = model_file.load(path)
        states, probs = build_outcome_tables(TransitionParams(rules=tables))
        assert saved.transition_params.rules == tables
        assert np.array_equal(saved.outcome_states, states)
        assert np.array_equal(saved.outcome_probs, probs)


@pytest.mark.parametrize('argv,fragment', [
    (['--tags', '5'], '6..50'),
    (['--tags', 'many'], 'invalid int value'),
    (['--set', 'huge'], 'invalid choice'),
    (['--set', 'random', '--size', '500'], '1..210'),
    (['--size', '5'], '--size only applies'),
    (['--load', '/nonexistent/file.npz'], 'no such file'),
    (['--load', 'x.npz', '--set', 'full'], 'mutually exclusive'),
    (['--set', 'full', '--tags', '50'], 'too many'),
    (['--tables', 'survey'], 'invalid choice'),
])
def test_bad_arguments_exit_2_without_traceback(capsys, argv, fragment):
    code, out, err = _run(capsys, *argv)
    assert code == 2
    assert fragment in err
    assert 'Traceback' not in err + out


def test_corrupt_load_file_exit_2(capsys, tmp_path):
    path = tmp_path / 'bad.npz'
    path.write_bytes(b'PK\x03\x04 garbage')
    code, _, err = _run(capsys, '--load', str(path))
    assert code == 2 and 'bad.npz' in err
