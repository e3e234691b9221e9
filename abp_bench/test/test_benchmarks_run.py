"""Every benchmark CLI runs end to end at tiny sizes (no ROS graph) and prints its table."""

import json
import signal

import cv2
import numpy as np
import pytest
import yaml

from abp_bench import (
    filter_benchmark,
    graph_benchmark,
    planner_benchmark,
    sim_bridge_benchmark,
    skills_benchmark,
)


@pytest.fixture
def one_cv_thread():
    threads = cv2.getNumThreads()
    yield
    cv2.setNumThreads(threads)


def test_filter_benchmark(capsys):
    assert filter_benchmark.main(['--repeats', '2']) == 0
    assert '| full n=7 | 1470 |' in capsys.readouterr().out


def test_planner_benchmark_with_json_and_plot(capsys, tmp_path):
    out_json, plot = tmp_path / 'out.json', tmp_path / 'fig.png'
    assert planner_benchmark.main(['--models', '30', '--trials', '1', '--planners', 'random',
                                   'abp', '--json', str(out_json), '--plot', str(plot)]) == 0
    assert '| 30 | abp | 1 |' in capsys.readouterr().out
    assert json.loads(out_json.read_text()) and plot.stat().st_size > 0


def test_skills_benchmark(capsys):
    assert skills_benchmark.main(['--repeats', '1']) == 0
    assert 'Feasibility of all 8 actions' in capsys.readouterr().out


def test_sim_bridge_benchmark_in_process(capsys, one_cv_thread):
    assert sim_bridge_benchmark.main(['--no-node']) == 0
    assert 'simulation tick' in capsys.readouterr().out


def test_graph_benchmark_records_into_a_new_or_empty_directory_only(tmp_path):
    assert graph_benchmark.record_dir(tmp_path / 'new' / 'bags') == (tmp_path / 'new' / 'bags')
    assert graph_benchmark.record_dir(tmp_path / 'new' / 'bags').is_dir()  # empty: fine
    (tmp_path / 'new' / 'bags' / 'labels.yaml').write_text('old: c0-1-2-3-4-5/u\n')
    with pytest.raises(SystemExit, match='must be a new or empty directory'):
        graph_benchmark.record_dir(tmp_path / 'new' / 'bags')


def test_graph_benchmark_runs_listed_cubes_from_starts_of_their_own():
    args = graph_benchmark.parse_args(['--objects', '3', '7', '--repeats', '2', '--vary-start',
                                       '--faults'])
    assert args.episodes == 4
    assert graph_benchmark.episode_objects(args, 30) == [3, 7, 3, 7]
    with pytest.raises(SystemExit, match=r'--objects \[30\] not in the model set'):
        graph_benchmark.episode_objects(graph_benchmark.parse_args(['--objects', '30']), 30)
    starts = [yaml.safe_load(graph_benchmark.episode_params(args, n))['/**/sim_bridge']
              ['ros__parameters'] for n in (1, 2, 3, 4)]
    assert all(s['p_slip_grasp'] == 0.1 for s in starts)          # the faults stay
    assert len({s['failure_seed'] for s in starts}) == 4
    assert len({(s['cube_up_face'], s['cube_yaw']) for s in starts}) == 4
    for s in starts:
        assert s['cube_up_face'] in range(6)
        step = np.rad2deg(s['cube_yaw']) / 45.0
        assert abs(step - round(step)) <= 5.0 / 45.0 + 1e-9    # a 45 deg step +-5 deg
    assert graph_benchmark.episode_params(args, 2) == graph_benchmark.episode_params(args, 2)
    assert graph_benchmark.episode_params(graph_benchmark.parse_args([]), 1) == ''


@pytest.mark.parametrize('argv, message', [
    (['--repeats', '2'], '--repeats needs --objects'),
    (['--objects', '1', '--episodes', '3'], '--episodes and --objects exclude each other'),
    (['--objects', '1', '--repeats', '0'], '--repeats must be >= 1'),
    (['--episodes', '0'], '--episodes must be >= 1'),
    (['--wrong-action-fraction', '0.1'], '--wrong-action-fraction goes with --operator'),
    (['--operator', 'scripted', '--faults'], '--operator scripted has no sim bridge'),
])
def test_graph_benchmark_refuses_conflicting_episode_options(argv, message, capsys):
    with pytest.raises(SystemExit):
        graph_benchmark.parse_args(argv)
    assert message in capsys.readouterr().err


def test_graph_benchmark_counts_the_scripted_operators_wrong_actions(tmp_path):
    log = tmp_path / 'scripted_operator.log'
    log.write_text('[INFO] [1.0] [scripted_operator]: did LIFT 10 cm as asked: state 32 -> 32\n'
                   '[INFO] [2.0] [scripted_operator]: did PUSH instead of FLIP 90 deg (wrong '
                   'action): state 32 -> 32\n[INFO] [3.0] [scripted_operator]: active\n')
    assert graph_benchmark.operator_actions(log) == {'operator_actions': 2, 'wrong_actions': 1}
    assert graph_benchmark.operator_actions(tmp_path / 'none.log') == \
        {'operator_actions': 0, 'wrong_actions': 0}


def test_an_interrupted_graph_benchmark_keeps_its_finished_episodes(tmp_path, monkeypatch,
                                                                    capsys):
    # The episodes themselves are the graph's (tests/test_end_to_end.py); here the second
    # episode is interrupted as Ctrl-C or SIGTERM would interrupt it.
    finished = []

    def one_episode_then_ctrl_c(args, index, workdir, params_file, bag=None):
        if finished:
            raise KeyboardInterrupt
        finished.append(index)
        return dict(object=index, hung=False, correct=True, success=True, actions=3,
                    elapsed_s=30.0, wall_s=5.0)

    monkeypatch.setattr(graph_benchmark, 'run_episode', one_episode_then_ctrl_c)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    out = tmp_path / 'run.json'
    try:
        assert graph_benchmark.main(['--objects', '1', '2', '--json', str(out)]) == 130
    finally:
        for sig, handler in handlers.items():      # main() installs its own
            signal.signal(sig, handler)
    data = json.loads(out.read_text())
    assert data['interrupted'] is True and [r['object'] for r in data['results']] == [1]
    captured = capsys.readouterr()
    assert '| correct | 1/1 (100.0 %) |' in captured.out
    assert 'the summary covers the 1 finished episodes' in captured.err


def test_graph_benchmark_summary_table():
    args = graph_benchmark.parse_args(['--episodes', '2'])
    results = [dict(correct=True, success=True, hung=False, actions=2, elapsed_s=40.0,
                    wall_s=9.0),
               dict(correct=False, success=True, hung=False, actions=4, elapsed_s=60.0,
                    wall_s=12.0),
               dict(correct=False, success=False, hung=False, actions=6, elapsed_s=80.0,
                    wall_s=15.0),
               dict(correct=False, hung=True, wall_s=30.0),
               # Aborted at the action limit with the right most likely object.
               dict(correct=False, most_likely_correct=True, success=False, hung=False,
                    actions=30, elapsed_s=300.0, wall_s=90.0),
               # start_graph gave up on a graph that never came up: no result JSON.
               dict(correct=False, hung=False, wall_s=602.0,
                    no_result='[start_graph] the graph is not ready after 600 s')]
    table = graph_benchmark.summarise(results, [12.0, 14.0], [5.0], args)
    assert '| correct | 1/6 (16.7 %) |' in table
    assert '| wrong (succeeded on the wrong object) | 1 |' in table
    assert ('| not identified (aborted with a reason) | 2 (1 with the right most likely '
            'object) |') in table
    assert '| hung (no result within the timeout) | 1 |' in table
    assert '| no result (the graph did not come up, or the goal timed out) | 1 |' in table
    assert graph_benchmark.verdict(results[-1]) == 'no result'
    # (40 + 60 + 80 + 300) s of sim over (9 + 12 + 15 + 90) s of wall, where a goal ended.
    assert '| sim s / wall s, start-up included (all episodes) | 3.81 |' in table
    assert '| mean actions | 10.50 |' in table
    assert ('mujoco world, robot models (corrected tables), planner cost, without fault '
            'injection') in table
    # The rules world's tables are the paper's, unless --tables says otherwise.
    rules = graph_benchmark.parse_args(['--world', 'rules'])
    assert graph_benchmark.tables_of(rules) == 'paper'
    assert graph_benchmark.tables_of(graph_benchmark.parse_args(
        ['--world', 'rules', '--tables', 'corrected'])) == 'corrected'


def test_transport_benchmark(capsys):
    from abp_bench import transport_benchmark
    assert transport_benchmark.main(['--frames', '2']) == 0
    out = capsys.readouterr().out
    assert '| JPEG q80 CompressedImage |' in out and 'Tags found on the raw frames' in out
    assert '| PNG CompressedImage of `mono8` |' in out and 'for PNG of mono8' in out
    with pytest.raises(SystemExit):
        transport_benchmark.main(['--quality', '0'])
