"""Aspect matching (Alg. 2) on rendered ARcube states (abp_bench.scenes): right aspect,
view frame, missed tags, distractors, sampled distances and the robot's working pose (its
speed: perception_benchmark). The matcher on ideal features:
abp_perception/test/test_matcher.py."""

import numpy as np
import pytest

from abp_belief import cube
from abp_perception.matcher import AspectMatcher, features_from_detections
from abp_sim_bridge.flat_renderer import Distractor


def observe(scenes, detector, faces, state, distance=1.0, elevation=35.0, yaw_error=0.0,
            distractors=(), look_offset=(0.0, 0.0)):
    scene = scenes.render(faces, state, distance=distance, elevation_deg=elevation,
                          yaw_error_deg=yaw_error, distractors=distractors,
                          look_offset=look_offset)
    result = detector.detect(scene.image).in_frame(scene.camera_pose, 'base_link')
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


@pytest.mark.parametrize('model, state', [(0, 32), (0, 33), (17, 5), (300, 14), (911, 46),
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


def test_sampled_distances_agree_with_propagation(full_models, scenes, detector):
    faces = full_models.faces[77]
    _, feats = observe(scenes, detector, faces, 19)
    sampled = AspectMatcher(full_models, distance_samples=200, seed=3).match(feats)
    assert sampled.best.key == cube.aspect_of(faces, 19)


def test_robot_working_pose_grazing_side_faces(full_models, full_matcher, detector):
    # The sim bridge's default: cube 0.40 m in front of base_link, the head tilted ~60 deg
    # down to it, so a 45 deg aspect's side faces are seen at 70-80 deg from their normal.
    from abp_bench.scenes import SceneGenerator
    from abp_description.kinematics import RobotKinematics
    from abp_sim_bridge.flat_renderer import ImageEffects

    kin = RobotKinematics()
    gen = SceneGenerator(seed=11, effects=ImageEffects(blur_sigma=0.5, noise_std=1.0))
    faces = full_models.faces[1000]
    for state in (1, 3, 5, 7, 10, 19, 28, 45):
        scene, _ = gen.render_robot(kin, faces, state, [0.40, 0.03, 0.05], yaw_error_deg=-3.0)
        assert 55 < scene.elevation_deg < 70
        result = detector.detect(scene.image).in_frame(scene.camera_pose, 'base_link')
        best = full_matcher.match(features_from_detections(result.detections)).best
        assert best is not None and best.key == cube.aspect_of(faces, state), state
