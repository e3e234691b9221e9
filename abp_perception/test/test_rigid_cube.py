"""Rigid-cube pose (abp_perception.rigid_cube) on synthetic images of a cube's tags
(tag_scene.render_tags: each tag drawn at the pose its face gives it). Flip removal on
the renderer's ARcube scenes: abp_bench/test/test_detector_on_scenes.py."""

from dataclasses import replace

import cv2
import numpy as np
import pytest
from tag_scene import render_tags

from abp_perception.detector import TagDetector
from abp_perception.rigid_cube import (
    CUBE_GROUP,
    face_placements,
    fit_cubes,
    group_tags,
)

H = 0.10          # cube edge
S = 0.08          # tag edge
# Tag axes on each body face (x right, y up, z out): the sim bridge's convention, but any
# placement with edges parallel to the cube's would do.
_UP = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1], [-1, 0, 0], [1, 0, 0]], float)
_N = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
FACE_AXES = np.stack([np.column_stack([np.cross(u, n), u, n]) for u, n in zip(_UP, _N)])


def rot_deg(a, b):
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))))


@pytest.fixture(scope='module')
def camera():
    from abp_description import camera_intrinsics
    return camera_intrinsics()


def cube_in_camera(distance, yaw_deg, elevation_deg=35.0, offset=(0.0, 0.0)):
    """Body -> camera pose of a cube `distance` ahead, seen from `elevation_deg` above,
    turned by `yaw_deg` about its vertical axis."""
    e = np.radians(elevation_deg)
    # Camera optical frame: z forward; world z up is -y_cam rotated by the elevation.
    cam_from_world = np.array([[0, -1, 0], [-np.sin(e), 0, -np.cos(e)],
                               [np.cos(e), 0, -np.sin(e)]]).T.T
    # World: x forward from the camera, z up; the cube faces the camera with body +x.
    yaw = np.radians(yaw_deg)
    body_to_world = cv2.Rodrigues(np.array([0.0, 0.0, np.pi + yaw]))[0]
    pose = np.eye(4)
    pose[:3, :3] = cam_from_world @ body_to_world
    pose[:3, 3] = [offset[0], offset[1], distance]
    return pose


def cube_tags(cube_pose, faces, ids):
    """[(tag_id, tag -> camera pose)] of the tags on `faces`."""
    out = []
    for face, tag_id in zip(faces, ids):
        tag = np.eye(4)
        tag[:3, :3] = FACE_AXES[face]
        tag[:3, 3] = _N[face] * H / 2
        out.append((tag_id, cube_pose @ tag))
    return out


def visible(cube_pose):
    """Faces whose normal points towards the camera by more than 15 deg."""
    centres = cube_pose[:3, :3] @ (_N.T * H / 2) + cube_pose[:3, 3:4]
    normals = cube_pose[:3, :3] @ _N.T
    cos = -np.sum(normals * centres, axis=0) / np.linalg.norm(centres, axis=0)
    return [f for f in range(6) if cos[f] > np.sin(np.radians(15.0))]


@pytest.mark.parametrize('distance, yaw', [(0.6, 20.0), (1.0, 45.0), (1.5, -30.0)])
def test_cube_pose_from_all_corners_matches_the_truth(camera, distance, yaw):
    cube = cube_in_camera(distance, yaw)
    faces = visible(cube)
    assert len(faces) >= 2
    tags = cube_tags(cube, faces, [10 + f for f in faces])
    image = render_tags(camera.K, camera.width, camera.height, tags, S)
    result = TagDetector(camera.K, cube_size=H).detect(image)
    assert len(result.detections) == len(faces)
    assert len(result.cubes) == 1
    fit = result.cubes[0]
    assert sorted(fit.detections) == list(range(len(faces)))
    np.testing.assert_allclose(fit.position, cube[:3, 3], atol=4e-3 * distance)
    truth = dict(tags)
    for k, det in enumerate(result.detections):
        assert det.solver == 'rigid_cube' and det.cube == 0
        assert rot_deg(det.pose[:3, :3], truth[det.tag_id][:3, :3]) < 0.5
        np.testing.assert_allclose(det.position, truth[det.tag_id][:3, 3], atol=4e-3 * distance)
        # The tag's own pose is still there, and differs from the rigid one.
        assert det.single_pose is not None and det.single_covariance is not None
        assert not np.array_equal(det.single_pose, det.pose)
        # The cube's placements reproduce each tag pose from the cube pose.
        np.testing.assert_allclose(fit.tag_poses()[fit.detections.index(k)], det.pose,
                                   atol=1e-9)
    # The cube frame has the first tag's axes: its z is that tag's normal.
    first = result.detections[fit.detections[0]]
    np.testing.assert_allclose(fit.pose[:3, :3], first.pose[:3, :3], atol=1e-9)
    # Covariances: positive definite, and the cube's is tighter than a single tag's.
    for det in result.detections:
        assert np.all(np.linalg.eigvalsh(det.covariance) > 0)
        assert np.trace(det.covariance[3:, 3:]) < np.trace(det.single_covariance[3:, 3:])


def _mirrored(det):
    """The detection with its IPPE candidates swapped: its own pose is the mirror one."""
    cands = det.candidates[::-1].copy()
    return replace(det, pose=cands[0], candidates=cands)


def test_a_mirrored_single_tag_pose_is_corrected_by_the_other_tags(camera):
    cube = cube_in_camera(1.2, 30.0)
    faces = visible(cube)
    tags = cube_tags(cube, faces, [20 + f for f in faces])
    image = render_tags(camera.K, camera.width, camera.height, tags, S)
    det = TagDetector(camera.K, cube_size=0)              # single-tag poses only
    dets = det.detect(image).detections
    assert all(d.candidates.shape[0] == 2 for d in dets)
    truth = dict(tags)
    # Every tag's pose replaced by its mirrored IPPE solution: tilted far from the truth.
    flipped = [_mirrored(d) for d in dets]
    for d in flipped:
        assert rot_deg(d.pose[:3, :3], truth[d.tag_id][:3, :3]) > 5.0
    cubes, rigid = fit_cubes(flipped, [d.candidates for d in flipped], camera.K, None, H,
                             det.object_points)
    assert len(cubes) == 1 and sorted(rigid) == list(range(len(dets)))
    for i, (pose, cov, rms, k) in rigid.items():
        assert rot_deg(pose[:3, :3], truth[flipped[i].tag_id][:3, :3]) < 0.5
        assert rms < 0.3 and k == 0


def test_tags_that_are_not_on_one_cube_keep_their_own_poses(camera):
    # Two tags at right angles, 7.07 cm apart (the adjacent-face distance, so linked), but
    # forming an inside corner (each normal turned towards the other tag): no placement on
    # a convex cube fits them, and the fit is refused.
    from tag_scene import tag_pose
    tags = [(30, tag_pose([-H / np.sqrt(8), 0.0, 0.8], -45.0)),
            (31, tag_pose([H / np.sqrt(8), 0.0, 0.8], 45.0))]
    image = render_tags(camera.K, camera.width, camera.height, tags, S)
    result = TagDetector(camera.K, cube_size=H).detect(image)
    assert len(result.detections) == 2
    dets = result.detections
    assert group_tags([d.position for d in dets], [d.covariance[:3, :3] for d in dets],
                      [S, S], H) == [[0, 1]]                 # linked: the fit was tried
    assert result.cubes == []
    for d in result.detections:
        assert d.solver != 'rigid_cube' and d.cube == -1 and d.single_pose is None
        np.testing.assert_array_equal(d.single_tag_pose, d.pose)


def test_two_cubes_are_fitted_separately(camera):
    a = cube_in_camera(1.0, 25.0, offset=(-0.25, 0.0))
    b = cube_in_camera(1.1, -40.0, offset=(0.25, 0.02))
    tags = cube_tags(a, visible(a), [1, 2, 3, 4, 5, 6]) \
        + cube_tags(b, visible(b), [11, 12, 13, 14, 15, 16])
    image = render_tags(camera.K, camera.width, camera.height, tags, S)
    result = TagDetector(camera.K, cube_size=H).detect(image)
    assert len(result.cubes) == 2
    centres = sorted((c.position for c in result.cubes), key=lambda p: p[0])
    np.testing.assert_allclose(centres[0], a[:3, 3], atol=3e-3)
    np.testing.assert_allclose(centres[1], b[:3, 3], atol=3e-3)
    for c in result.cubes:
        ids = {result.detections[i].tag_id for i in c.detections}
        assert ids <= set(range(1, 7)) or ids <= set(range(11, 17))


def test_in_frame_moves_cubes_and_single_poses_with_the_tags(camera):
    cube = cube_in_camera(0.9, 10.0)
    tags = cube_tags(cube, visible(cube), [40, 41, 42, 43, 44, 45])
    image = render_tags(camera.K, camera.width, camera.height, tags, S)
    result = TagDetector(camera.K, cube_size=H).detect(image)
    move = np.eye(4)
    move[:3, :3] = cv2.Rodrigues(np.array([0.1, -0.4, 0.7]))[0]
    move[:3, 3] = [0.3, -0.2, 1.1]
    moved = result.in_frame(move, 'base_link')
    assert moved.cubes[0].frame == 'base_link'
    np.testing.assert_allclose(moved.cubes[0].pose, move @ result.cubes[0].pose)
    np.testing.assert_allclose(moved.cubes[0].tag_poses(),
                               [moved.detections[i].pose for i in moved.cubes[0].detections],
                               atol=1e-9)
    for d0, d1 in zip(result.detections, moved.detections):
        np.testing.assert_allclose(d1.single_pose, move @ d0.single_pose)


def test_grouping_links_adjacent_face_distances_only():
    cov = np.tile(1e-6 * np.eye(3), (4, 1, 1))
    d = H / np.sqrt(2)
    pos = [[0, 0, 1], [d, 0, 1], [d, d, 1], [1, 1, 1]]
    assert group_tags(pos, cov, [S] * 4, H) == [[0, 1, 2]]
    assert group_tags(pos, cov, [S, 0.05, S, S], H) == []          # other marker size
    assert group_tags(pos[:1], cov[:1], [S], H) == []


def test_placements_are_the_24_cube_rotations_with_the_face_offset():
    p = face_placements(H)
    assert p.shape == (24, 4, 4)
    np.testing.assert_allclose(p[:, :3, :3] @ np.transpose(p[:, :3, :3], (0, 2, 1)),
                               np.tile(np.eye(3), (24, 1, 1)), atol=1e-12)
    assert np.allclose(np.linalg.det(CUBE_GROUP), 1.0)
    assert len({tuple(q.ravel()) for q in CUBE_GROUP}) == 24
    np.testing.assert_allclose(np.linalg.norm(p[:, :3, 3], axis=1), H / 2)
    np.testing.assert_allclose(p[:, :3, 3], p[:, :3, 2] * H / 2)


@pytest.mark.parametrize('kwargs, message', [
    ({'cube_size': -0.1}, 'cube_size must be >= 0'),
    ({'cube_size': 0.05}, 'must exceed marker_size'),
])
def test_bad_cube_size_is_refused(camera, kwargs, message):
    with pytest.raises(ValueError, match=message):
        TagDetector(camera.K, **kwargs)


def test_cube_size_zero_turns_the_rigid_fit_off(camera):
    cube = cube_in_camera(1.0, 30.0)
    tags = cube_tags(cube, visible(cube), [1, 2, 3, 4, 5, 6])
    image = render_tags(camera.K, camera.width, camera.height, tags, S)
    result = TagDetector(camera.K, cube_size=0).detect(image)
    assert len(result.detections) >= 2 and result.cubes == []
    assert all(d.solver == 'ippe_square' for d in result.detections)


def test_a_flat_sheet_of_linked_tags_is_not_refitted_tag_by_tag(camera, monkeypatch):
    # Six coplanar tags on a grid of the adjacent-face distance: all linked into one group,
    # which no cube fits. A cube shows at most three tags, so the worst three go at once:
    # fits of 6, 3 and 2 tags (not 6, 5, 4, 3, 2: a real ChArUco board of 11 tags cost 10).
    from tag_scene import tag_pose

    from abp_perception import rigid_cube
    step = H / np.sqrt(2.0)
    tags = [(40 + k, tag_pose([(k % 3 - 1) * step, (k // 3 - 0.5) * step, 0.8], 0.0))
            for k in range(6)]
    image = render_tags(camera.K, camera.width, camera.height, tags, 0.05)
    sizes = []
    real_fit = rigid_cube._Problem.fit

    def counted(problem):
        sizes.append(len(problem.candidates))
        return real_fit(problem)

    monkeypatch.setattr(rigid_cube._Problem, 'fit', counted)
    result = TagDetector(camera.K, marker_size=0.05, cube_size=H).detect(image)
    assert sorted(d.tag_id for d in result.detections) == list(range(40, 46))
    assert result.cubes == []
    assert sizes == [6, 3, 2]
