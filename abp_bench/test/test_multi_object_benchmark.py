"""planner_benchmark --objects K (issue 37): model-sampled scenes of K cubes, seeded, with
eccentric twins on request; K = 1 stays the single-object benchmark."""

import json

import numpy as np
import pytest

from abp_bench import multi_object_benchmark, planner_benchmark
from abp_bench.model_sets import build_model_set, object_families


def test_three_cube_scenes_with_twins_run_and_report(capsys, tmp_path):
    out = tmp_path / 'multi.json'
    assert planner_benchmark.main(['--models', 'robot', '--objects', '3', '--twins',
                                   '--trials', '2', '--planners', 'abp', '--seed', '1',
                                   '--json', str(out)]) == 0
    text = capsys.readouterr().out
    for task in multi_object_benchmark.SCENE_TASKS:
        assert f'| robot | abp | {task} | 2 |' in text
    assert 'load average' in text
    data = json.loads(out.read_text())
    summary = data['summaries'][0]
    # Each cube is worked on as it would be alone (own noise stream, own belief).
    assert summary['identify_all_vs_single'] == pytest.approx(1.0)
    assert summary['identify_all']['wrong_decidable'] == 0
    assert data['update_timing']['robot']['k'] == 3
    robot = build_model_set('robot', 1)
    families = object_families(robot)
    for scene in data['scenes']:
        cubes = scene['cubes']
        models = [c['true_model'] for c in cubes]
        assert len(set(models)) == 3
        eccentric = [m for m in models if families[m] == 'twin family, eccentric']
        assert len(eccentric) >= 2
        assert len({robot.visual_id[m] for m in eccentric}) < len(eccentric)  # twins
        xy = np.array([c['position'] for c in cubes])
        assert min(np.linalg.norm(xy[i] - xy[j]) for i in range(3) for j in range(i)) >= 0.3
        assert scene['target_present'] in models and scene['target_absent'] not in models
        assert scene['find_present']['task'] == f"find {scene['target_present']}"


def test_scenes_are_seeded():
    robot = build_model_set('robot', 0)
    first = multi_object_benchmark.draw_scene(robot, 5, 3, 3, twins=True)
    again = multi_object_benchmark.draw_scene(robot, 5, 3, 3, twins=True)
    other = multi_object_benchmark.draw_scene(robot, 5, 4, 3, twins=True)
    assert first == again and first != other


@pytest.mark.parametrize('argv, message', [
    (['--objects', '2', '--planners', 'random'], 'no expected gains'),
    (['--objects', '1', '--twins'], '--twins needs --objects >= 2'),
    (['--objects', '2', '--twins', '--models', '30'], 'no eccentric mass twins'),
    (['--objects', '0'], '--objects must be >= 1'),
    (['--objects', '2', '--travel-speed', '0'], 'speed_mps'),
])
def test_bad_multi_object_options_are_refused(argv, message, capsys):
    with pytest.raises(SystemExit):
        planner_benchmark.parse_args(argv)
    assert message in capsys.readouterr().err


def test_one_object_keeps_the_single_object_defaults():
    args = planner_benchmark.parse_args([])
    assert args.objects == 1 and args.planners == ['random', 'abp']
    assert planner_benchmark.parse_args(['--objects', '3']).planners == ['cost']
