"""calibrate_camera (issue 35): intrinsics recovered from rendered views of the ChArUco
board with known K and mild distortion; refusals; the calibration YAML round trip.

Views are rendered exactly: a pinhole homography of the board plane (2x supersampled,
averaged down), then the lens distortion by remapping every pixel through
cv2.undistortPoints. No rclpy; the CLI runs in-process on files.
"""

import cv2
import numpy as np
import pytest
import yaml

from abp_perception import calibrate_camera_cli, camera_calibration_file
from abp_perception.charuco_calibration import BoardSpec, CalibrationError, calibrate, iter_pictures

SIZE = (640, 480)
K_TRUE = np.array([[610.0, 0.0, 318.5], [0.0, 604.0, 243.2], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.08, 0.03, 0.0005, -0.0003, 0.0])
BOARD_PX_PER_MM = 4.0


def _rotation(ax_deg, ay_deg, az_deg):
    r, _ = cv2.Rodrigues(np.radians([ax_deg, 0, 0]))
    q, _ = cv2.Rodrigues(np.radians([0, ay_deg, 0]))
    s, _ = cv2.Rodrigues(np.radians([0, 0, az_deg]))
    return r @ q @ s


def render_view(board_image, spec, K, D, rotation, target, size=SIZE, crease_deg=0.0):
    """The board seen by a camera (K, D): board frame x right, y down (as printed), its
    centre at `target` (camera frame, m), turned by `rotation`; `crease_deg` folds its
    lower half about the middle line (a board that is not flat)."""
    centre = np.array([spec.size_mm[0], spec.size_mm[1], 0.0]) / 2000
    t = np.asarray(target) - rotation @ centre
    scale = 1.0 / (BOARD_PX_PER_MM * 1000)
    pixel_to_board = np.array([[scale, 0, 0.5 * scale], [0, scale, 0.5 * scale], [0, 0, 1]])
    K2 = np.diag([2.0, 2.0, 1.0]) @ K + np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
    r1, r2, r3 = rotation.T
    fold_y = centre[1]
    c, s = np.cos(np.radians(crease_deg)), np.sin(np.radians(crease_deg))
    # The lower half's plane: y runs along (c r2 + s r3) from the fold line.
    planes = [(np.column_stack([r1, r2, t]), slice(None, board_image.shape[0] // 2)),
              (np.column_stack([r1, c * r2 + s * r3,
                                t + fold_y * ((1 - c) * r2 - s * r3)]),
               slice(board_image.shape[0] // 2, None))]
    ideal = np.full((2 * size[1], 2 * size[0]), 90, np.uint8)
    for plane, rows in planes:
        H = K2 @ plane @ pixel_to_board
        mask = np.zeros_like(board_image)
        mask[rows] = 255
        warped = cv2.warpPerspective(board_image, H, ideal.shape[::-1], flags=cv2.INTER_LINEAR)
        inside = cv2.warpPerspective(mask, H, ideal.shape[::-1], flags=cv2.INTER_NEAREST)
        ideal[inside > 0] = warped[inside > 0]
    ideal = cv2.resize(ideal, size, interpolation=cv2.INTER_AREA)
    # Distortion: each output pixel shows the ideal pixel its ray goes through.
    u, v = np.meshgrid(np.arange(size[0], dtype=np.float64), np.arange(size[1], dtype=float))
    points = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    ideal_points = cv2.undistortPoints(points, K, D, P=K).reshape(size[1], size[0], 2)
    return cv2.remap(ideal, ideal_points[..., 0].astype(np.float32),
                     ideal_points[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                     borderValue=90)


def views(count, K=K_TRUE, D=D_TRUE, seed=3, crease_deg=0.0):
    spec = BoardSpec()
    board_image = spec.image(BOARD_PX_PER_MM)
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        rotation = _rotation(rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-30, 30))
        distance = rng.uniform(0.3, 0.5)
        # Spread over the whole image, corners included: what pins the distortion down.
        target = [rng.uniform(-0.1, 0.1), rng.uniform(-0.07, 0.07), distance]
        out.append((f'view{k:02d}.png', render_view(board_image, spec, K, D, rotation, target,
                                                  crease_deg=crease_deg)))
    return out


@pytest.fixture(scope='module')
def rendered():
    return views(18)


def test_recovers_the_intrinsics_from_rendered_views(rendered):
    result = calibrate(rendered, min_views=15)
    K = result.camera_matrix
    assert len(result.views_used) == 18, result.views_skipped
    assert result.rms_px < 0.5
    for (i, j) in ((0, 0), (1, 1), (0, 2), (1, 2)):
        assert abs(K[i, j] - K_TRUE[i, j]) < 0.01 * K_TRUE[i, j], (i, j, K[i, j])
    # The distortion as a whole (its terms trade off): each pixel undistorts to within
    # about a pixel of where the true lens sends it.
    u, v = np.meshgrid(np.arange(0, SIZE[0], 16.0), np.arange(0, SIZE[1], 16.0))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    error = np.linalg.norm(cv2.undistortPoints(pixels, K_TRUE, D_TRUE, P=K_TRUE)
                           - cv2.undistortPoints(pixels, K, result.distortion, P=K_TRUE), axis=2)
    assert error.max() < 1.5 and np.median(error) < 0.5
    assert result.image_size == SIZE


def test_cli_writes_a_camera_calibration_yaml(rendered, tmp_path, capsys):
    folder = tmp_path / 'pictures'
    folder.mkdir()
    for name, image in rendered:
        cv2.imwrite(str(folder / name), image)
    (folder / 'notes.txt').write_text('not a picture')
    out = tmp_path / 'camera.yaml'
    assert calibrate_camera_cli.main([str(folder), '--out', str(out), '--camera-name',
                                      'webcam']) == 0
    printed = capsys.readouterr().out
    assert 'views used: 18 of 18' in printed and 'RMS reprojection error' in printed
    doc = yaml.safe_load(out.read_text())
    assert doc['image_width'] == 640 and doc['image_height'] == 480
    assert doc['camera_name'] == 'webcam' and doc['distortion_model'] == 'plumb_bob'
    assert doc['camera_matrix']['rows'] == 3 and len(doc['camera_matrix']['data']) == 9
    assert doc['distortion_coefficients'] == {'rows': 1, 'cols': 5,
                                              'data': doc['distortion_coefficients']['data']}
    assert doc['rectification_matrix']['data'] == [1, 0, 0, 0, 1, 0, 0, 0, 1]
    assert doc['projection_matrix']['rows'] == 3 and doc['projection_matrix']['cols'] == 4
    loaded = camera_calibration_file.load(str(out))
    assert np.allclose(loaded.K, K_TRUE, rtol=0.01)
    assert loaded.size == SIZE
    info = loaded.camera_info_fields()
    assert len(info['k']) == 9 and len(info['p']) == 12 and len(info['d']) == 5


def test_refuses_too_few_views(rendered, tmp_path, capsys):
    folder = tmp_path / 'few'
    folder.mkdir()
    for name, image in rendered[:5]:
        cv2.imwrite(str(folder / name), image)
    cv2.imwrite(str(folder / 'blank.png'), np.full((480, 640), 200, np.uint8))
    out = tmp_path / 'camera.yaml'
    assert calibrate_camera_cli.main([str(folder), '--out', str(out)]) == 1
    err = capsys.readouterr().err
    assert 'only 5 of 6 pictures' in err and 'nothing written' in err
    assert not out.exists()


def test_refuses_a_high_reprojection_error(rendered, tmp_path, capsys):
    # A board creased by 20 degrees across its middle is no plane: no camera fits it.
    with pytest.raises(CalibrationError, match='RMS reprojection error .* above the limit 1'):
        calibrate(views(12, crease_deg=20.0), max_error_px=1.0)
    folder = tmp_path / 'pictures'
    folder.mkdir()
    for name, image in rendered[:12]:
        cv2.imwrite(str(folder / name), image)
    out = tmp_path / 'camera.yaml'
    assert calibrate_camera_cli.main([str(folder), '--out', str(out), '--max-error',
                                      '0.01']) == 1
    assert 'above the limit 0.01 px' in capsys.readouterr().err
    assert not out.exists()


def test_video_input_and_bad_sources(rendered, tmp_path):
    video = str(tmp_path / 'board.avi')
    writer = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*'MJPG'), 10, SIZE)
    assert writer.isOpened()
    for _, image in rendered[:4]:
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    frames = list(iter_pictures(video, every=2))
    assert [name for name, _ in frames] == ['frame 0', 'frame 2']
    assert frames[0][1].shape[:2] == (480, 640)
    with pytest.raises(CalibrationError, match='no such file'):
        list(iter_pictures(str(tmp_path / 'missing')))
    (tmp_path / 'bad.mp4').write_bytes(b'not a video')
    with pytest.raises(CalibrationError):
        list(iter_pictures(str(tmp_path / 'bad.mp4')))


def test_calibration_file_round_trip_and_errors(tmp_path):
    D = np.array([0.1, -0.2, 0.001, 0.002, 0.05])
    saved = camera_calibration_file.make(K_TRUE, D, (640, 480), 'cam')
    path = str(tmp_path / 'c.yaml')
    camera_calibration_file.save(path, saved)
    loaded = camera_calibration_file.load(path)
    assert loaded.camera_name == 'cam' and loaded.size == (640, 480)
    for name in ('K', 'D', 'R', 'P'):
        assert np.array_equal(getattr(loaded, name), getattr(saved, name)), name
    bad = {'missing.yaml': None, 'list.yaml': '[1, 2]', 'nosize.yaml': 'camera_matrix: {}',
           'short.yaml': 'image_width: 640\nimage_height: 480\ncamera_matrix: '
                         '{rows: 3, cols: 3, data: [1, 2]}\n'}
    for name, text in bad.items():
        if text is not None:
            (tmp_path / name).write_text(text)
        with pytest.raises(camera_calibration_file.CalibrationFileError, match=name):
            camera_calibration_file.load(str(tmp_path / name))
