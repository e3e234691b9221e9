"""Benchmark of the ARcube renderer: median time per 640x480 frame on one core, and
optionally the ArUco + IPPE_SQUARE pose errors of the rendered tags.

    render_benchmark [--frames 300] [--encoding bgr8] [--pose-errors]
"""

import argparse
import sys
import time

import cv2
import numpy as np

from abp_sim_bridge.flat_renderer import (
    ArcubeRenderer,
    Distractor,
    ImageEffects,
    look_at,
    tag_object_points,
)

DEFAULT_K = np.array([[554.256, 0.0, 319.5], [0.0, 554.256, 239.5], [0.0, 0.0, 1.0]])
TAGS = [0, 1, 2, 3, 4, 5]


def _intrinsics():
    try:
        from abp_description import camera_intrinsics
    except ImportError:
        return DEFAULT_K, 640, 480
    cam = camera_intrinsics()
    return cam.K, cam.width, cam.height


def _cube(yaw_deg):
    a = np.radians(yaw_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    pose[:3, 3] = [0.0, 0.0, 0.05]
    return pose


def _camera(target, distance, elevation_deg):
    e = np.radians(elevation_deg)
    return look_at(np.asarray(target) + distance * np.array([np.cos(e), 0.0, np.sin(e)]), target)


def bench_time(renderer, frames, distance, n_distractors):
    distractors = []
    for i in range(n_distractors):
        pose = np.eye(4)
        pose[:3, 3] = [-0.3 - 0.2 * i, 0.3 * (-1) ** i, 0.0005]  # flat on the floor
        distractors.append(Distractor(10 + i, pose, 0.08))
    times = []
    for k in range(frames):
        cube = _cube(7.0 * k)  # turn the cube so every face size and mip level gets used
        cam = _camera(cube[:3, 3], distance, 35.0)
        t0 = time.perf_counter()
        renderer.render(cam, cube, TAGS, distractors=distractors)
        times.append(time.perf_counter() - t0)
    return np.array(times[1:] if frames > 1 else times)


def pose_error_table(renderer, refinement):
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = refinement
    det = cv2.aruco.ArucoDetector(renderer.dictionary, params)
    rows = []
    for distance in (0.5, 1.0, 1.5, 2.0):
        lateral, total, missed, n_expected = [], [], 0, 0
        for yaw in (0, 45, 90, 225):
            for el in (30, 35, 40):
                cube = _cube(yaw)
                cam = _camera(cube[:3, 3], distance, el)
                truth = {f.tag_id: f for f in renderer.visible_faces(cam, cube, TAGS)}
                corners, ids, _ = det.detectMarkers(renderer.render(cam, cube, TAGS))
                found = {} if ids is None else {
                    int(i): c.reshape(4, 2).astype(np.float64)
                    for c, i in zip(corners, ids.ravel())}
                n_expected += len(truth)
                missed += len(set(truth) - set(found))
                for tag, c in found.items():
                    if tag not in truth:
                        continue
                    _, _, tvec = cv2.solvePnP(tag_object_points(renderer.tag_edge), c,
                                              renderer.K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
                    centre = truth[tag].centre_camera
                    err = tvec.ravel() - centre
                    ray = centre / np.linalg.norm(centre)
                    lateral.append(np.linalg.norm(err - (err @ ray) * ray))
                    total.append(np.linalg.norm(err))
        rows.append((distance, n_expected, missed, np.array(lateral), np.array(total)))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=300)
    parser.add_argument('--encoding', choices=('mono8', 'bgr8'), default='mono8')
    parser.add_argument('--distance', type=float, default=0.8, help='camera to cube, m')
    parser.add_argument('--distractors', type=int, default=2)
    parser.add_argument('--supersample', type=int, default=4)
    parser.add_argument('--blur', type=float, default=0.6)
    parser.add_argument('--noise', type=float, default=2.0)
    parser.add_argument('--threads', type=int, default=1, help='OpenCV threads (1 = one core)')
    parser.add_argument('--pose-errors', action='store_true',
                        help='also print ArUco/IPPE_SQUARE tag-centre errors by distance')
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error('--frames must be at least 1')

    cv2.setNumThreads(args.threads)
    K, width, height = _intrinsics()
    effects = ImageEffects(gain=1.0, blur_sigma=args.blur, noise_std=args.noise)
    renderer = ArcubeRenderer(K, width, height, encoding=args.encoding, effects=effects,
                              supersample=args.supersample)
    times = bench_time(renderer, args.frames, args.distance, args.distractors)
    median_ms = 1e3 * float(np.median(times))
    print(f'render {width}x{height} {args.encoding}, supersample {args.supersample}, '
          f'{args.threads} OpenCV thread(s), {len(times)} frames: median {median_ms:.2f} ms '
          f'(p95 {1e3 * float(np.percentile(times, 95)):.2f} ms) = {1e3 / median_ms:.0f} Hz')

    if args.pose_errors:
        for name, method in (('SUBPIX', cv2.aruco.CORNER_REFINE_SUBPIX),
                             ('APRILTAG', cv2.aruco.CORNER_REFINE_APRILTAG)):
            print(f'tag-centre error, {name} corners + SOLVEPNP_IPPE_SQUARE '
                  f'(blur {args.blur}, noise {args.noise}):')
            for distance, n, missed, lat, tot in pose_error_table(renderer, method):
                if len(tot) == 0:
                    print(f'  {distance:.1f} m: no detections of {n}')
                    continue
                tot_mm, lat_mm = 1e3 * tot, 1e3 * lat
                print(f'  {distance:.1f} m: detected {n - missed}/{n}; '
                      f'3-D median {np.median(tot_mm):.1f} mm, '
                      f'p90 {np.percentile(tot_mm, 90):.1f} mm; '
                      f'lateral median {np.median(lat_mm):.2f} mm, '
                      f'p90 {np.percentile(lat_mm, 90):.2f} mm')
    return 0


if __name__ == '__main__':
    sys.exit(main())
