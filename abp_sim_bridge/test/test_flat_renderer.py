import cv2
import numpy as np
import pytest

from abp_description.frames import rot_z_deg
from abp_sim_bridge.flat_renderer import (
    FACE_NORMALS,
    FACE_TAG_AXES,
    ArcubeRenderer,
    Distractor,
    ImageEffects,
    Lighting,
    face_tag_pose,
    look_at,
    tag_object_points,
    visible_faces,
)

K = np.array([[554.256, 0.0, 319.5], [0.0, 554.256, 239.5], [0.0, 0.0, 1.0]])
W, H = 640, 480
TAGS = [0, 1, 2, 3, 4, 5]
MILD = ImageEffects(gain=1.0, blur_sigma=0.6, noise_std=2.0)


def cube_pose(yaw_deg, centre=(0.3, -0.2, 0.05)):
    pose = np.eye(4)
    pose[:3, :3] = rot_z_deg(yaw_deg)
    pose[:3, 3] = centre
    return pose


def camera_looking_at(target, distance, elevation_deg, azimuth_deg=0.0):
    e, a = np.radians(elevation_deg), np.radians(azimuth_deg)
    eye = np.asarray(target) + distance * np.array(
        [np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    return look_at(eye, target)


def detector(refinement=cv2.aruco.CORNER_REFINE_SUBPIX):
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = refinement
    return cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), params)


def detect(det, img):
    corners, ids, _ = det.detectMarkers(img)
    if ids is None:
        return {}
    return {int(i): c.reshape(4, 2).astype(np.float64) for c, i in zip(corners, ids.ravel())}


def test_face_tag_axes_are_right_handed_with_normal_out():
    for face in range(6):
        axes = FACE_TAG_AXES[face]
        np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-12)
        assert np.linalg.det(axes) == pytest.approx(1.0)
        np.testing.assert_allclose(axes[:, 2], FACE_NORMALS[face])
        np.testing.assert_allclose(face_tag_pose(face, 0.1)[:3, 3], FACE_NORMALS[face] * 0.05)


def test_look_at_optical_convention():
    pose = look_at([1.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(pose[:3, 2], np.array([-1, 0, -1]) / np.sqrt(2), atol=1e-12)
    assert pose[2, 1] < 0  # image y (down) has a downward world component
    np.testing.assert_allclose(pose[:3, 0], [0, 1, 0], atol=1e-12)  # looking along -x: right is +y
    np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-12)


@pytest.mark.parametrize('yaw, expected', [(0, {0, 4}), (45, {0, 3, 4}), (90, {3, 4}),
                                           (180, {1, 4}), (-45, {0, 2, 4})])
def test_visible_faces_ground_truth(yaw, expected):
    cube = cube_pose(yaw)
    cam = camera_looking_at(cube[:3, 3], 1.0, 35)
    faces = visible_faces(K, W, H, cam, cube, TAGS)
    assert {f.face for f in faces} == expected
    assert all(f.in_image and f.cos_view > 0.3 for f in faces)


@pytest.fixture(scope='module')
def renderer():
    return ArcubeRenderer(K, W, H, effects=MILD, seed=1)


POSES = [(d, yaw, el) for d in (0.5, 1.0, 1.5) for yaw in (0, 45, 90, 225) for el in (30, 40)]


@pytest.mark.parametrize('tags', [TAGS, [6, 2, 9, 4, 1, 3]])
def test_detects_exactly_the_visible_tags(renderer, tags):
    det = detector()
    for dist, yaw, el in POSES:
        cube = cube_pose(yaw)
        cam = camera_looking_at(cube[:3, 3], dist, el)
        img = renderer.render(cam, cube, tags)
        expected = {f.tag_id for f in renderer.visible_faces(cam, cube, tags)}
        assert set(detect(det, img)) == expected, (dist, yaw, el)
        assert len(expected) == (2 if yaw % 90 == 0 else 3)


def test_far_views_never_report_hidden_tags(renderer):
    # At 2 m the tags are ~20 px wide: some are missed, none is invented.
    det = detector()
    found = 0
    for yaw in (0, 45, 135, 270):
        for el in (30, 40):
            cube = cube_pose(yaw)
            cam = camera_looking_at(cube[:3, 3], 2.0, el)
            got = set(detect(det, renderer.render(cam, cube, TAGS)))
            assert got <= {f.tag_id for f in renderer.visible_faces(cam, cube, TAGS)}
            found += len(got)
    assert found >= 8


def pose_errors(renderer, det, distance):
    """Lateral and 3-D errors (m) of IPPE_SQUARE tag centres over the test poses."""
    lateral, total = [], []
    for yaw in (0, 45, 90, 225):
        for el in (30, 35, 40):
            cube = cube_pose(yaw)
            cam = camera_looking_at(cube[:3, 3], distance, el)
            truth = {f.tag_id: f for f in renderer.visible_faces(cam, cube, TAGS)}
            for tag, corners in detect(det, renderer.render(cam, cube, TAGS)).items():
                ok, _, tvec = cv2.solvePnP(tag_object_points(renderer.tag_edge), corners, K, None,
                                           flags=cv2.SOLVEPNP_IPPE_SQUARE)
                assert ok
                centre = truth[tag].centre_camera
                err = tvec.ravel() - centre
                ray = centre / np.linalg.norm(centre)
                lateral.append(np.linalg.norm(err - (err @ ray) * ray))
                total.append(np.linalg.norm(err))
    return np.array(lateral), np.array(total)


def test_pnp_recovers_face_centres(renderer):
    # Rendered geometry is exact (lateral error well under a mm on clean images); the depth
    # error comes from ArUco's sub-pixel corners sitting ~0.2 px inside a ~45 px tag.
    clean = ArcubeRenderer(K, W, H)
    lat, tot = pose_errors(clean, detector(), 1.0)
    assert len(tot) >= 25
    assert np.max(lat) < 0.6e-3
    assert np.median(tot) < 12e-3
    lat, tot = pose_errors(clean, detector(), 0.5)
    assert np.median(tot) < 3e-3
    # AprilTag-style edge refinement removes most of the depth bias.
    lat, tot = pose_errors(clean, detector(cv2.aruco.CORNER_REFINE_APRILTAG), 1.0)
    assert np.median(tot) < 5e-3
    # Mild blur and noise: corners jitter, a few refine badly.
    lat, tot = pose_errors(renderer, detector(), 1.0)
    assert np.median(lat) < 0.5e-3 and np.percentile(lat, 75) < 1e-3
    assert np.median(tot) < 15e-3


def test_face_area_matches_projection():
    # Blank white faces on black: the integrated intensity is the projected area of the
    # visible faces, which checks the warp geometry and its anti-aliasing without a detector.
    level = 200.0
    r = ArcubeRenderer(K, W, H, floor_level=0, background_level=0, face_level=level,
                       lighting=Lighting(ambient=1.0, diffuse=0.0))
    for yaw, dist in ((0, 0.6), (30, 1.0), (45, 1.7)):
        cube = cube_pose(yaw)
        cam = camera_looking_at(cube[:3, 3], dist, 35, azimuth_deg=10)
        img = r.render(cam, cube, [-1] * 6)
        area = 0.0
        for f in r.visible_faces(cam, cube, [-1] * 6):
            # scale the tag corners about their centre up to the full face
            c = f.corners_px
            world_to_cam = np.linalg.inv(cam)
            pose = cube @ face_tag_pose(f.face, r.edge)
            h = r.edge / 2
            local = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0], ])
            pts = local @ pose[:3, :3].T + pose[:3, 3]
            pts = pts @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
            c = (pts[:, :2] / pts[:, 2:]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
            area += cv2.contourArea(c.astype(np.float32))
        rendered = img.astype(np.float64).sum() / level
        assert rendered == pytest.approx(area, rel=0.01), (yaw, dist)


def test_distractors_and_occlusion():
    r = ArcubeRenderer(K, W, H, effects=MILD, seed=2)
    det = detector()
    cube = cube_pose(0, centre=(0.0, 0.0, 0.05))
    cam = camera_looking_at(cube[:3, 3], 1.0, 35)
    floor_tag = np.eye(4)
    floor_tag[:3, 3] = [0.0, 0.25, 0.0005]  # flat on the floor beside the cube, z up
    wall_tag = np.eye(4)
    wall_tag[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # vertical, facing +x, right = +y
    wall_tag[:3, 3] = [-0.6, -0.25, 0.15]
    hidden = np.eye(4)
    hidden[:3, :3] = wall_tag[:3, :3]
    hidden[:3, 3] = [-0.06, 0.0, 0.05]  # just behind the cube, facing the camera
    distractors = [(10, floor_tag, 0.08), Distractor(11, wall_tag, 0.10), (12, hidden, 0.06)]
    got = set(detect(det, r.render(cam, cube, TAGS, distractors=distractors)))
    assert got == {0, 4, 10, 11}
    # A tag held in front of the cube hides the cube's front tag.
    front = np.eye(4)
    front[:3, :3] = wall_tag[:3, :3]
    front[:3, 3] = [0.15, 0.0, 0.07]
    got = set(detect(det, r.render(cam, cube, TAGS, distractors=[(13, front, 0.09)])))
    assert 13 in got and 0 not in got
    # A mirrored (left-handed) tag pose is refused rather than rendered unreadable.
    mirrored = wall_tag.copy()
    mirrored[:3, 0] *= -1
    with pytest.raises(ValueError):
        r.render(cam, cube, TAGS, distractors=[(14, mirrored, 0.08)])
    # Without a cube only the distractors show.
    assert set(detect(det, r.render(cam, None, distractors=distractors))) == {10, 11, 12}


def test_encoding_and_effects():
    cube = cube_pose(45)
    cam = camera_looking_at(cube[:3, 3], 1.0, 35)
    clean = ArcubeRenderer(K, W, H).render(cam, cube, TAGS)
    assert clean.shape == (H, W) and clean.dtype == np.uint8
    bgr = ArcubeRenderer(K, W, H, encoding='bgr8').render(cam, cube, TAGS)
    assert bgr.shape == (H, W, 3)
    np.testing.assert_array_equal(bgr[..., 0], clean)
    bright = ArcubeRenderer(K, W, H, effects=ImageEffects(gain=1.3)).render(cam, cube, TAGS)
    assert bright.mean() > 1.2 * clean.mean()
    blurred = ArcubeRenderer(K, W, H, effects=ImageEffects(blur_sigma=2.0)).render(cam, cube, TAGS)
    assert np.abs(np.diff(blurred.astype(float), axis=1)).sum() < \
        0.7 * np.abs(np.diff(clean.astype(float), axis=1)).sum()
    noisy_a = ArcubeRenderer(K, W, H, effects=ImageEffects(noise_std=5.0), seed=3)
    noisy_b = ArcubeRenderer(K, W, H, effects=ImageEffects(noise_std=5.0), seed=3)
    a, b = noisy_a.render(cam, cube, TAGS), noisy_b.render(cam, cube, TAGS)
    np.testing.assert_array_equal(a, b)  # seeded
    assert 3.5 < np.std(a.astype(float) - clean) < 6.5
    with pytest.raises(ValueError):
        ArcubeRenderer(K, W, H, encoding='rgb16')
    with pytest.raises(ValueError):
        ArcubeRenderer(K, W, H).render(cam, cube, [0, 1, 2])


def test_camera_behind_or_inside_cube_does_not_crash():
    r = ArcubeRenderer(K, W, H)
    cube = cube_pose(0, centre=(0.0, 0.0, 0.05))
    for eye in ([0.052, 0.0, 0.05], [0.0, 0.0, 0.3], [3.0, 0.0, 0.02]):
        r.render(look_at(eye, [0.0, 0.0, 0.05]), cube, TAGS)
    r.render(look_at([1.0, 0.0, 0.5], [2.0, 0.0, 0.5]), cube, TAGS)  # cube behind the camera
