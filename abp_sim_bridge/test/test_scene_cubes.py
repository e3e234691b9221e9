"""Scenes of several cubes (num_cubes > 1): seeded placement, models without repeats,
forced eccentric twins, impossible scenes refused at configure, and both worlds drawing
every cube so that the real tag detector finds each one in the start view."""

import time

import numpy as np
import pytest

from abp_description import camera_intrinsics
from abp_description.kinematics import RobotKinematics
from abp_perception.detector import TagDetector
from abp_sim_bridge import config as cfg
from abp_sim_bridge.scenario import eccentric_twins, load_model_set, place_cubes, scene_models
from abp_sim_bridge.worlds import make_world

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope='module')
def kin():
    return RobotKinematics()


@pytest.mark.parametrize('seed', range(20))
def test_placement_is_seeded_spaced_and_in_the_sector(seed):
    xy = place_cubes(4, seed, spacing=0.3, radius=(0.45, 0.85), half_angle_deg=20.0)
    np.testing.assert_array_equal(xy, place_cubes(4, seed, 0.3, (0.45, 0.85), 20.0))
    gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2)[np.triu_indices(4, 1)]
    assert gaps.min() >= 0.3
    r, bearing = np.hypot(xy[:, 0], xy[:, 1]), np.degrees(np.arctan2(xy[:, 1], xy[:, 0]))
    assert np.all((r >= 0.45) & (r <= 0.85)) and np.all(np.abs(bearing) <= 20.0)


def test_an_impossible_scene_is_a_clear_error_at_configure_not_a_hang():
    started = time.monotonic()
    with pytest.raises(ValueError, match='num_cubes: cannot place 8 cubes at least 0.3 m'):
        cfg.build({'world': 'rules', 'num_cubes': 8})
    with pytest.raises(ValueError, match='cannot place 5 cubes'):   # area bound passes
        cfg.build({'world': 'rules', 'num_cubes': 5})
    assert time.monotonic() - started < 10.0
    assert cfg.refusal(cfg.defaults(), {'num_cubes': 8}).startswith('num_cubes: cannot place')


def test_one_cube_is_the_scene_of_before():
    config = cfg.build({'world': 'rules', 'cube_seed': 3})
    assert len(config.cubes) == len(config.hiddens) == 1
    assert config.hiddens[0] is config.hidden and config.cubes[0] is config.cube
    np.testing.assert_array_equal(config.cube.position, [0.40, 0.0, 0.05])
    np.testing.assert_array_equal(config.look_at_point, config.cube.position)
    with pytest.raises(ValueError, match='twin_cubes needs num_cubes >= 2'):
        cfg.build({'twin_cubes': True})


@pytest.mark.parametrize('seed', range(8))
def test_scene_models_are_distinct_and_twins_are_forced(seed):
    models = load_model_set()
    config = cfg.build({'world': 'rules', 'num_cubes': 3, 'cube_seed': seed})
    indices = [h.model_index for h in config.hiddens]
    assert len(set(indices)) == 3
    assert config.hiddens[0] == cfg.build({'world': 'rules', 'cube_seed': seed}).hidden
    twins = cfg.build({'world': 'rules', 'num_cubes': 3, 'cube_seed': seed, 'twin_cubes': True})
    a, b, c = twins.hiddens
    assert a.face_tags == b.face_tags and a.mass_index != b.mass_index
    assert (a.model_index, b.model_index) in eccentric_twins(models) or \
        (b.model_index, a.model_index) in eccentric_twins(models)
    assert len({a.model_index, b.model_index, c.model_index}) == 3


def test_scenes_the_set_cannot_make_are_refused():
    with pytest.raises(ValueError, match='leave face_tags empty'):
        cfg.build({'num_cubes': 2, 'face_tags': [0, 1, 2, 3, 4, 5]})
    with pytest.raises(ValueError, match='no eccentric mass twins of model 0'):
        cfg.build({'num_cubes': 2, 'model_index': 0, 'twin_cubes': True})   # a uniform cube
    with pytest.raises(ValueError, match='exceeds the 30 models'):
        scene_models(0, 31, load_model_set())


def tags_seen_per_cube(world, camera, config, intrinsics):
    """Tags the real detector finds in the start frame, counted per cube (by the cube
    centre nearest the centre each tag implies)."""
    tags = tuple(h.face_tags for h in config.hiddens)
    image = camera.render(camera.capture(world, tags))
    if image.ndim == 3:
        image = image[..., 0]
    result = TagDetector(intrinsics.K, None, marker_size=config.camera.tag_size,
                         cube_size=config.camera.cube_size).detect(image)
    centres = np.array([world.display_cube(i).pose()[:3, 3] for i in range(len(tags))])
    counts, worst = np.zeros(len(tags), int), 0.0
    for det in result.detections:
        pose = world.camera_pose() @ det.pose
        implied = pose[:3, 3] - pose[:3, 2] * config.camera.cube_size / 2
        distance = np.linalg.norm(centres - implied, axis=1)
        counts[int(np.argmin(distance))] += 1
        worst = max(worst, float(distance.min()))
    return counts, worst


@pytest.mark.parametrize('seed', range(4))
def test_rules_world_shows_every_cube_to_the_detector(kin, seed):
    config = cfg.build({'world': 'rules', 'num_cubes': 3, 'cube_seed': seed,
                        'twin_cubes': seed % 2 == 1})
    intrinsics = camera_intrinsics()
    world, camera = make_world(config, kin, intrinsics)
    counts, worst = tags_seen_per_cube(world, camera, config, intrinsics)
    assert np.all(counts >= 2), counts   # every cube shows at least two faces
    assert worst < 0.02
    for i, cube in enumerate(config.cubes):
        np.testing.assert_array_equal(world.display_cube(i).position, cube.position)
        assert world.discrete_state(i) == world.discrete_state(i)


def test_rules_contacts_act_on_the_cube_the_hands_reach(kin):
    config = cfg.build({'world': 'rules', 'num_cubes': 3, 'cube_seed': 0})
    world, _ = make_world(config, kin, camera_intrinsics())
    assert world.world.cube is world.cubes[0]
    world.hands = {side: config.cubes[2].position + [-0.08, 0.0, 0.0] for side in world.hands}
    world._choose_active_cube()
    assert world.active == 2 and world.world.cube is world.cubes[2]
    np.testing.assert_array_equal(world.display_cube(2).position, config.cubes[2].position)
    np.testing.assert_array_equal(world.display_cube(0).position, config.cubes[0].position)


def test_mujoco_world_has_a_free_body_per_cube_and_renders_them(kin):
    config = cfg.build({'world': 'mujoco', 'num_cubes': 3, 'cube_seed': 1,
                        'twin_cubes': True})
    intrinsics = camera_intrinsics()
    world, camera = make_world(config, kin, intrinsics)
    try:
        for _ in range(25):   # 0.5 s: the cubes settle on the floor where they were put
            world.step()
        for i, cube in enumerate(config.cubes):
            np.testing.assert_allclose(world.display_cube(i).position, cube.position,
                                       atol=0.005)
            assert world.display_cube(i).heavy_face == cube.heavy_face
        counts, worst = tags_seen_per_cube(world, camera, config, intrinsics)
        assert np.all(counts >= 2), counts
        assert worst < 0.02
    finally:
        camera.close()


def test_mujoco_contact_episode_is_with_the_cube_a_hand_touches(kin):
    """A hand on the second cube opens the contact episode with that cube (the active
    cube); the first cube's ground truth is left alone."""
    import mujoco

    config = cfg.build({'world': 'mujoco', 'num_cubes': 2, 'cube_seed': 0, 'camera_rate': 0.0})
    world, camera = make_world(config, kin, camera_intrinsics())
    try:
        hand = next(iter(world.hand_positions().values()))
        joint = world.model.body_jntadr[world._cube_bodies[1]]
        adr = world.model.jnt_qposadr[joint]
        world.data.qpos[adr:adr + 3] = hand + [0.06, 0.0, 0.0]   # ball radius 3.5 cm
        mujoco.mj_forward(world.model, world.data)
        assert world.hands_touching(1) and not world.hands_touching(0)
        world._track_contacts()
        assert world._active == 1 and world._episode is not None
        np.testing.assert_allclose(world.cube_pose()[:3, 3], hand + [0.06, 0.0, 0.0])
        np.testing.assert_allclose(world.display_cube(0).position, config.cubes[0].position)
    finally:
        camera.close()
