"""Aspect matching (Alg. 2) on rendered ARcube states: right aspect, missed tags,
distractors, unknown ids, empty input, the lookup table, and speed on the 1470 set."""

import time

import numpy as np
import pytest

from abp_belief import cube
from abp_belief.population import robot_set
from abp_perception.matcher import AspectMatcher, Feature, features_from_detections
from abp_sim_bridge.renderer import Distractor


def observe(scenes, detector, faces, state, distance=1.0, elevation=35.0, yaw_error=0.0,
            distractors=(), look_offset=(0.0, 0.0)):
    scene = scenes.render(faces, state, distance=distance, elevation_deg=elevation,
                          yaw_error_deg=yaw_error, distractors=distractors,
                          look_offset=look_offset)
    result = detector.detect(scene.image).in_frame(scene.camera_pose, "base_link")
    return scene, features_from_detections(result.detections)


def floor_tag(tag_id, x, y, yaw=0.3):
    pose = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = [x, y, 0.0005]
    return Distractor(tag_id, pose, 0.08)


def upright_tag(tag_id, x, y):
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([[0, -1, 0], [0, 0, 1], [-1, 0, 0]])  # facing the robot
    pose[:3, 3] = [x, y, 0.06]
    return Distractor(tag_id, pose, 0.08)


@pytest.mark.parametrize("model, state", [(0, 32), (0, 33), (17, 5), (300, 14), (911, 46),
                                          (1469, 23), (640, 7)])
def test_rendered_states_give_their_aspect(full_models, full_matcher, scenes, detector,
                                           model, state):
    faces = full_models.faces[model]
    scene, feats = observe(scenes, detector, faces, state, yaw_error=4.0)
    result = full_matcher.match(feats)
    assert result.best is not None
    assert result.best.key == cube.aspect_of(faces, state)
    assert np.linalg.norm(result.best.position - scene.cube_pose[:3, 3]) < 0.02
    # Orientation: the aspect's V frame (x towards the robot, turned by the yaw error).
    c = scene.cube_pose[:3, 3]
    yaw = np.arctan2(-c[1], -c[0]) + np.radians(4.0)
    expected = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0],
                         [0, 0, 1]])
    angle = np.degrees(np.arccos(np.clip((np.trace(expected.T @ result.best.rotation) - 1) / 2,
                                         -1, 1)))
    assert angle < 8.0
    assert 0 < result.best.score <= 1 and abs(sum(h.score for h in result.hypotheses) - 1) < 1e-9
    assert all(h.support <= result.best.support for h in result.hypotheses)


def test_plus_y_and_minus_y_follow_the_view_frame(full_models, full_matcher, scenes,
                                                  detector):
    faces = full_models.faces[42]
    for state in (1, 3, 5, 7):
        scene, feats = observe(scenes, detector, faces, state)
        best = full_matcher.match(feats).best
        assert best.aspect_type == 3
        assert best.slots == cube.aspect_of(faces, state)[1:]
        by_id = {f.tag_id: f for f in feats}
        to_robot = -scene.cube_pose[:3, 3]
        right = np.cross([0.0, 0.0, 1.0], to_robot)         # +y_V
        assert by_id[best.slots[1]].normal @ right > 0      # plus_y on the robot's right
        assert by_id[best.slots[2]].normal @ right < 0


def test_missed_tag_is_reported_as_minus_one(full_models, full_matcher, scenes, detector):
    faces = full_models.faces[123]
    state = 9                                                 # odd yaw: 3 features
    _, feats = observe(scenes, detector, faces, state)
    true = cube.aspect_of(faces, state)
    assert full_matcher.match(feats).best.key == true
    for missing_slot in (1, 2, 3):
        kept = [f for f in feats if f.tag_id != true[missing_slot]]
        best = full_matcher.match(kept).best
        expected = list(true)
        expected[missing_slot] = -1
        assert best.key == tuple(expected)


def test_two_distractors_do_not_change_the_answer(full_models, full_matcher, scenes,
                                                  detector):
    faces = full_models.faces[500]
    for state in (8, 11, 26, 45):
        true = cube.aspect_of(faces, state)
        # An in-range id that is also on the cube, and one outside 0..n_tags-1.
        distractors = [floor_tag(int(faces[0]), 0.75, 0.35), upright_tag(33, 0.9, -0.4)]
        scene, feats = observe(scenes, detector, faces, state, distractors=distractors)
        ids = [f.tag_id for f in feats]
        assert 33 in ids and ids.count(int(faces[0])) >= 1
        result = full_matcher.match(feats)
        assert result.best.key == true
        assert result.ignored_features == 1 and result.ignored_ids == [33]
        # The distractor features are not part of the winning hypothesis.
        winners = {ids[i] for i in result.best.feature_indices}
        assert 33 not in winners
        assert len(result.best.feature_indices) == true[0]


def test_stray_pair_of_in_range_tags_gets_no_consistent_votes(full_matcher):
    # Two in-range tags 0.3 m apart on the floor: wrong distance, wrong geometry.
    cov = np.eye(3) * 1e-6
    feats = [Feature(1, np.array([1.0, 0.2, 0.0]), cov, np.array([0.0, 0.0, 1.0])),
             Feature(2, np.array([1.0, -0.1, 0.0]), cov, np.array([0.0, 0.0, 1.0]))]
    assert full_matcher.match(feats).hypotheses == []


def test_zero_one_and_unknown_features(full_matcher):
    empty = full_matcher.match([])
    assert empty.hypotheses == [] and empty.best is None and empty.ignored_features == 0
    cov = np.eye(3) * 1e-6
    one = full_matcher.match([Feature(3, np.array([1.0, 0.0, 0.1]), cov,
                                      np.array([0.0, 0.0, 1.0]))])
    assert one.hypotheses == []
    unknown = [Feature(40, np.array([1.0, 0.0, 0.1]), cov, np.array([0.0, 0.0, 1.0])),
               Feature(-1, np.array([1.0, 0.05, 0.05]), cov, np.array([1.0, 0.0, 0.0])),
               Feature(2, np.array([np.nan, 0.0, 0.0]), cov, np.array([1.0, 0.0, 0.0]))]
    res = full_matcher.match(unknown)
    assert res.hypotheses == [] and res.ignored_features == 3 and res.ignored_ids == [-1, 40]


def test_ideal_features_of_every_robot_set_aspect():
    models = robot_set(seed=0)
    matcher = AspectMatcher(models)
    h = models.cube_size
    cov = np.eye(3) * 1e-6
    centre = np.array([1.2, -0.3, h / 2])
    # V frame at that centre: x towards the base origin.
    x = -centre.copy()
    x[2] = 0
    x /= np.linalg.norm(x)
    rv = np.column_stack([x, np.cross([0, 0, 1.0], x), [0, 0, 1.0]])
    for row in range(len(models.aspects)):
        tags = models.aspect_feature_tags(row)
        pos = models.aspect_feature_positions(row)
        feats = [Feature(int(t), centre + rv @ p, cov, rv @ (p / np.linalg.norm(p)))
                 for t, p in zip(tags, pos)]
        best = matcher.match(feats).best
        assert best.key == models.aspect_key(row)
        np.testing.assert_allclose(best.position, centre, atol=1e-6)
        np.testing.assert_allclose(best.rotation, rv, atol=1e-6)


def test_lookup_table_lists_every_slot_pair_of_every_aspect(full_models, full_matcher):
    m = full_matcher
    n = full_models.n_tags
    counts = np.zeros(n * n, dtype=int)
    for row in full_models.aspects:
        tags = row[1:1 + row[0]]
        for a in range(len(tags)):
            for b in range(len(tags)):
                if a != b:
                    counts[tags[a] * n + tags[b]] += 1
    np.testing.assert_array_equal((m._table >= 0).sum(axis=1), counts)
    entries = m._table[m._table >= 0]
    rows, sa, sb = m._entry_row[entries], m._entry_sa[entries], m._entry_sb[entries]
    keys = np.repeat(np.arange(n * n), (m._table >= 0).sum(axis=1))
    np.testing.assert_array_equal(m.aspect_tags[rows, sa] * n + m.aspect_tags[rows, sb], keys)


def test_sampled_distances_agree_with_propagation(full_models, scenes, detector):
    faces = full_models.faces[77]
    _, feats = observe(scenes, detector, faces, 19)
    sampled = AspectMatcher(full_models, distance_samples=200, seed=3).match(feats)
    assert sampled.best.key == cube.aspect_of(faces, 19)


def test_bad_matcher_settings_are_refused(full_models):
    for kwargs in ({"voxel_size": 0.0}, {"orientation_sigma_deg": 0.0},
                   {"max_hypotheses": 0}, {"distance_samples": -1}):
        with pytest.raises(ValueError):
            AspectMatcher(full_models, **kwargs)


def test_matching_is_fast_on_the_full_set(full_models, full_matcher, scenes, detector):
    rng = np.random.default_rng(4)
    observations = []
    for _ in range(12):
        model, state = int(rng.integers(full_models.num_models)), int(rng.integers(48))
        distractors = [floor_tag(int(rng.integers(7)), 0.8, 0.4), upright_tag(41, 0.9, -0.45)]
        _, feats = observe(scenes, detector, full_models.faces[model], state,
                           distractors=distractors)
        observations.append(feats)
    times = []
    for feats in observations * 3:
        t0 = time.perf_counter()
        full_matcher.match(feats)
        times.append(time.perf_counter() - t0)
    # Goal: 5 ms; generous here for loaded CI machines.
    assert np.median(times) < 0.02


def test_robot_working_pose_grazing_side_faces(full_models, full_matcher, detector):
    # The sim bridge's default: cube 0.40 m in front of base_link, the head tilted ~60 deg
    # down to it, so a 45 deg aspect's side faces are seen at 70-80 deg from their normal.
    from abp_description.kinematics import RobotKinematics
    from abp_perception.scenes import SceneGenerator
    from abp_sim_bridge.renderer import ImageEffects

    kin = RobotKinematics()
    gen = SceneGenerator(seed=11, effects=ImageEffects(blur_sigma=0.5, noise_std=1.0))
    faces = full_models.faces[1000]
    for state in (1, 3, 5, 7, 10, 19, 28, 45):
        scene, _ = gen.render_robot(kin, faces, state, [0.40, 0.03, 0.05], yaw_error_deg=-3.0)
        assert 55 < scene.elevation_deg < 70
        result = detector.detect(scene.image).in_frame(scene.camera_pose, "base_link")
        best = full_matcher.match(features_from_detections(result.detections)).best
        assert best is not None and best.key == cube.aspect_of(faces, state), state
