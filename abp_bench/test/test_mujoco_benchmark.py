"""The MuJoCo world benchmark runs (tiny sizes) and its numbers are sane."""

import json
import os

import numpy as np
import pytest

# Headless rendering: MuJoCo picks its GL backend when first imported in this process
# (another test module may import it first).
os.environ.setdefault('MUJOCO_GL', 'egl')
pytest.importorskip('mujoco')

from abp_bench import mujoco_benchmark as mb  # noqa: E402


@pytest.fixture(scope='module')
def kin():
    from abp_description.kinematics import RobotKinematics
    return RobotKinematics()


@pytest.fixture(scope='module')
def named(kin):
    return mb.postures(kin)


@pytest.fixture(scope='module')
def gl_ok():
    from abp_sim_bridge.worlds import check_rendering
    try:
        check_rendering()
    except ValueError as error:
        pytest.skip(str(error))


def test_scaled_intrinsics_match_the_calibration_at_640x480():
    from abp_description import camera_intrinsics
    np.testing.assert_allclose(mb.scaled_intrinsics(640, 480), camera_intrinsics().K,
                               atol=1e-3)
    k = mb.scaled_intrinsics(320, 240)
    assert k[0, 0] == pytest.approx(camera_intrinsics().fy / 2)
    assert k[0, 2] == pytest.approx(159.5)


def test_physics_runs_faster_than_nothing(kin, named):
    postures, plan = named
    phys = mb.physics_benchmark(kin, postures['home'], plan, sim_seconds=0.2, repeats=1)
    assert set(phys) == {'idle', 'drive', 'lift', 'raw'}
    for r in phys.values():
        assert r['rtf_wall_median'] > 0 and r['rtf_cpu_median'] > 0
    assert phys['idle']['physics_rate_hz'] >= 500
    assert phys['lift']['sim_s'] > 5.0        # the whole LIFT plan ran
    assert any(a.startswith('LIFT') for a in phys['lift']['actions'])


def test_camera_cost_gives_frames_per_second(kin, named, gl_ok):
    postures, _ = named
    rows = mb.camera_benchmark(kin, postures['pre-grasp'], frames=2, resolutions=((320, 240),),
                               shadows=(False,), offsamples=(0,), min_frames=1)
    assert len(rows) == 1 and rows[0]['frames'] == 2 and rows[0]['fps'] > 0


def test_pre_grasp_posture_has_the_arms_in_view(kin, named, gl_ok):
    postures, _ = named
    world = mb.make_world(kin, postures['pre-grasp'])
    try:
        view = mb.arms_in_view(world, postures['pre-grasp'])
    finally:
        world.close()
    assert view['arms'] > 0.02 and view['cube'] > 0.01


def test_recall_counts_visible_tags_and_finds_them(kin, named, gl_ok, tmp_path, capsys):
    postures, _ = named
    result = mb.recall_benchmark(kin, postures, scenes=6, seed=1)
    assert result['frames'] == 6 and result['wrong_ids'] == 0
    recs = result['records']
    assert len(recs) == 6 * 6
    # At most three faces of a cube turn towards a camera.
    for scene in range(6):
        assert sum(r['view_angle_deg'] < 90 for r in recs if r['scene'] == scene) <= 3
    summary = mb.summarise_recall(result)
    everything = summary['unhidden'][-1]
    assert everything['bucket'] == 'all' and everything['tags'] >= 6
    assert everything['recall'] >= 0.9
    assert everything['pos_err_mm_median'] < 20
    mb.print_recall(result, summary)
    assert 'recall' in capsys.readouterr().out
    path = tmp_path / 'out.json'
    assert mb.main(['--skip', 'physics', 'camera', '--scenes', '3', '--json', str(path)]) == 0
    data = json.loads(path.read_text())
    assert data['recall']['frames'] == 3 and len(data['load_average_end']) == 3


def test_a_hand_across_the_view_hides_tags(kin, named):
    postures, _ = named
    maker = mb.SceneMaker(kin, postures, seed=3)
    try:
        hidden = []
        for _ in range(12):
            scene = maker.random_scene(0.9)
            qpos, info = scene
            if info['posture'] != mb.HAND_ACROSS:
                continue
            _, faces = maker.ground_truth(qpos)
            hidden += [f['hidden'] for f in faces if f['visible']]
    finally:
        maker.close()
    assert hidden and max(hidden) > 0
