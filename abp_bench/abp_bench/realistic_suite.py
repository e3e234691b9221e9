"""Realistic-conditions suite of ``perception_benchmark`` (issue 16): our detector against
plain OpenCV on the same frames.

    perception_benchmark --suite realistic [--realistic-frames 150] [--seed 0]
                         [--update-doc /tmp/perception.md]   # tables as a Markdown section

Frames: the benchmark's random ARcube scenes (``perception_benchmark.random_scene``: a
random model of the full set in a random state, 25-45 deg elevation, anywhere in the
image, 2 distractor tags), at a distance drawn uniformly from 0.5-2.5 m, then degraded by
one **condition**:

- ``plain``: the renderer's own frame (plain floor and wall), sensor blur 0.6 px and
  noise sigma 2, as the standard benchmark;
- ``textured``: the floor and wall replaced by a textured background (multi-scale noise
  and wood-like stripes);
- ``clutter``: a cluttered background: rectangles, discs, lines, checkerboards, printed
  text and *fake tags* (black-bordered 4x4 bit patterns at Hamming distance >= 4 from
  every DICT_4X4_50 code);
- ``gradient``: clutter + a lighting gradient across the whole frame (gain 0.35-1.3,
  linear or radial) and a shadow band;
- ``motion blur``: clutter + a linear motion blur of 3-8 px at a random angle;
- ``jpeg``: clutter + JPEG compression at quality 30-60;
- ``occlusion``: clutter + an arm-like bar (shaded, 25-60 px wide) across the cube;
- ``all``: clutter, gradient, motion blur in half the frames, JPEG 40-90 and the bar in
  half the frames.

Every condition also gets the sensor blur and noise. The background replacement is exact
compositing: the scene is rendered twice with the floor and wall at 0 and at 255 and no
effects, which gives each pixel's coverage by the cube and the tags (rendering is linear
in the background level).

Both detectors see the same grey frame. **Ours**: ``TagDetector`` (defaults, rigid cube
fit on). **Plain OpenCV**: ``cv2.aruco.ArucoDetector`` with default
``DetectorParameters`` and ``cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)`` per marker. A
tag counts as expected when it is in the image (3 px clear of the border), viewed within
75 deg of its normal and not hidden by the bar (less than 5 % of its quad covered); a
detection is right when an unhidden or hidden tag with its id is within 3 px / 30 % of its
size (hidden tags found do not count as wrong). Errors: the face-centre position error and
the rotation error of the tag's pose (ours: ``Detection.pose``, the rigid cube's when it
was fitted; ``single`` also given). CPU: per-frame ``time.thread_time`` of the detection
call (pose included), OpenCV on one thread.
"""

from __future__ import annotations

import os
import time

import cv2
import numpy as np

from abp_description.robot_profile import load_profile
from abp_perception.detector import (
    RegionSearch,
    TagDetector,
    marker_object_points,
    search_region,
)
from abp_perception.matcher import AspectMatcher, features_from_detections

from .perception_scenes import random_scene, rotation_deg

BASE_FRAME = load_profile().frames.base   # the scenes' world: the default robot's base

CONDITIONS = ('plain', 'textured', 'clutter', 'gradient', 'motion blur', 'jpeg',
              'occlusion', 'all')
DISTANCE_BINS = ((0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5))
ANGLE_BINS = ((0.0, 30.0), (30.0, 60.0), (60.0, 75.0))
HIDDEN_FRACTION = 0.05
SENSOR_BLUR, SENSOR_NOISE = 0.6, 2.0


# -- backgrounds and degradations ------------------------------------------------------------

def _fake_tags(rng, dictionary, count=48):
    """Black-bordered 4x4 bit patterns (6x6 cells) that are no DICT_4X4_50 tag (Hamming
    distance >= 4 to every code in every rotation)."""
    out = []
    n_ids = dictionary.bytesList.shape[0]
    while len(out) < count:
        bits = rng.integers(0, 2, (4, 4)).astype(np.uint8)
        if min(dictionary.getDistanceToId(bits, k, True) for k in range(n_ids)) < 4:
            continue
        cells = np.zeros((6, 6), np.uint8)
        cells[1:5, 1:5] = bits * 255
        out.append(cells)
    return out


class Degrader:
    """Backgrounds, lighting, blur, JPEG and the arm bar, from one seeded generator."""

    def __init__(self, width, height, seed=0):
        self.width, self.height = int(width), int(height)
        self.rng = np.random.default_rng(seed)
        self.fakes = _fake_tags(self.rng, cv2.aruco.getPredefinedDictionary(
            cv2.aruco.DICT_4X4_50))

    def textured(self):
        h, w, rng = self.height, self.width, self.rng
        img = np.zeros((h, w), np.float32)
        for scale, amp in ((4, 50.0), (16, 35.0), (64, 25.0)):
            small = rng.standard_normal((h // scale + 2, w // scale + 2)).astype(np.float32)
            img += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        angle = rng.uniform(0, np.pi)
        phase = np.cos(angle) * xx + np.sin(angle) * yy
        img += 30.0 * np.sin(phase / rng.uniform(3.0, 12.0) + 2.0 * np.sin(phase / 60.0))
        img += rng.uniform(90, 170)
        return np.clip(img, 0, 255)

    def clutter(self):
        """A cluttered background: textured base, shapes, checkerboards, text, fake tags."""
        rng = self.rng
        img = self.textured() * 0.5 + rng.uniform(40, 110)
        img = img.astype(np.uint8)
        h, w = self.height, self.width
        for _ in range(int(rng.integers(10, 20))):                     # rectangles, discs
            c = int(rng.integers(0, 256))
            x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
            if rng.random() < 0.5:
                cv2.rectangle(img, (x, y), (x + int(rng.integers(10, 120)),
                                            y + int(rng.integers(10, 120))), c, -1)
            else:
                cv2.circle(img, (x, y), int(rng.integers(5, 60)), c, -1, cv2.LINE_AA)
        for _ in range(int(rng.integers(5, 12))):                      # lines
            p = rng.integers(0, (w, h), size=(2, 2))
            cv2.line(img, tuple(int(v) for v in p[0]), tuple(int(v) for v in p[1]),
                     int(rng.integers(0, 256)), int(rng.integers(1, 6)), cv2.LINE_AA)
        for _ in range(int(rng.integers(1, 4))):                       # checkerboards
            n, cell = int(rng.integers(4, 9)), int(rng.integers(6, 20))
            board = ((np.indices((n, n)).sum(axis=0) % 2) * 255).astype(np.uint8)
            self._paste_warped(img, cv2.resize(board, (n * cell, n * cell),
                                               interpolation=cv2.INTER_NEAREST))
        for _ in range(int(rng.integers(2, 6))):                       # text
            text = ''.join(rng.choice(list('ABCDEFGHKLMNPRSTUVXYZ0123456789 '), 10))
            cv2.putText(img, text, (int(rng.integers(0, w - 100)), int(rng.integers(20, h))),
                        cv2.FONT_HERSHEY_SIMPLEX, float(rng.uniform(0.4, 1.5)),
                        int(rng.choice([0, 255])), int(rng.integers(1, 4)), cv2.LINE_AA)
        for _ in range(int(rng.integers(3, 8))):                       # fake tags
            cells = self.fakes[int(rng.integers(len(self.fakes)))]
            side = int(rng.integers(18, 80))
            pad = side // 6
            tag = cv2.resize(cells, (side, side), interpolation=cv2.INTER_NEAREST)
            self._paste_warped(img, cv2.copyMakeBorder(tag, pad, pad, pad, pad,
                                                       cv2.BORDER_CONSTANT, value=255))
        return img.astype(np.float32)

    def _paste_warped(self, img, patch):
        """Paste `patch` under a random perspective warp somewhere in `img` (in place)."""
        rng = self.rng
        ph, pw = patch.shape
        src = np.float32([[0, 0], [pw, 0], [pw, ph], [0, ph]])
        centre = rng.uniform((0, 0), (self.width, self.height))
        scale = rng.uniform(0.6, 1.4)
        angle = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        dst = (src - src.mean(axis=0)) * scale @ rot.T
        dst = dst * (1 + rng.uniform(-0.25, 0.25, size=(4, 1))) + centre
        warp = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
        size = (self.width, self.height)
        drawn = cv2.warpPerspective(patch, warp, size, flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.full_like(patch, 255), warp, size,
                                   flags=cv2.INTER_LINEAR).astype(np.float32) / 255.0
        img[:] = (mask * drawn + (1 - mask) * img).astype(img.dtype)

    def gradient(self, img):
        """A lighting gain field (linear or radial, 0.35-1.3) and a soft shadow band."""
        rng, h, w = self.rng, self.height, self.width
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        lo, hi = rng.uniform(0.35, 0.6), rng.uniform(0.95, 1.3)
        if rng.random() < 0.5:
            a = rng.uniform(0, 2 * np.pi)
            t = (np.cos(a) * (xx - w / 2) + np.sin(a) * (yy - h / 2)) / (0.5 * np.hypot(w, h))
            gain = lo + (hi - lo) * 0.5 * (1 + np.clip(t, -1, 1))
        else:
            cx, cy = rng.uniform(0, w), rng.uniform(0, h)
            r = np.hypot(xx - cx, yy - cy) / np.hypot(w, h)
            gain = hi - (hi - lo) * np.clip(r / 0.8, 0, 1)
        a = rng.uniform(0, np.pi)
        d = np.cos(a) * (xx - rng.uniform(0, w)) + np.sin(a) * (yy - rng.uniform(0, h))
        gain *= 1.0 - 0.35 * np.exp(-0.5 * (d / rng.uniform(15, 60)) ** 2)
        return img * gain

    def motion_blur(self, img, length=None):
        rng = self.rng
        length = int(rng.integers(3, 9)) if length is None else int(length)
        k = np.zeros((length, length), np.float32)
        k[length // 2, :] = 1.0
        rot = cv2.getRotationMatrix2D(((length - 1) / 2, (length - 1) / 2),
                                      float(rng.uniform(0, 180)), 1.0)
        k = cv2.warpAffine(k, rot, (length, length))
        return cv2.filter2D(img, -1, k / k.sum())

    def jpeg(self, gray, quality):
        ok, buf = cv2.imencode('.jpg', gray, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)

    def bar(self, img, centre_px, cube_px):
        """An arm-like bar (shaded cylinder) from an image border across the cube; returns
        its polygon (4, 2) px."""
        rng = self.rng
        width = float(rng.uniform(25, 60))
        angle = rng.uniform(0, np.pi)
        direction = np.array([np.cos(angle), np.sin(angle)])
        normal = np.array([-direction[1], direction[0]])
        through = np.asarray(centre_px, float) + normal * rng.uniform(-0.4, 0.4) * cube_px
        # From outside the image to a point past the cube (the arm reaches in from a side).
        start = through - direction * 2 * max(self.width, self.height)
        end = through + direction * rng.uniform(0.0, 0.6) * cube_px
        poly = np.array([start + normal * width / 2, end + normal * width / 2,
                         end - normal * width / 2, start - normal * width / 2])
        mask = np.zeros(img.shape, np.uint8)
        cv2.fillConvexPoly(mask, np.round(poly * 16).astype(np.int32), 255, cv2.LINE_AA, 4)
        yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]].astype(np.float32)
        across = ((xx - through[0]) * normal[0] + (yy - through[1]) * normal[1]) / (width / 2)
        shade = float(rng.uniform(60, 150)) * (1.0 - 0.45 * np.clip(across, -1, 1) ** 2) \
            + 60.0 * np.exp(-0.5 * ((across + 0.4) / 0.15) ** 2)
        alpha = mask.astype(np.float32) / 255.0
        img[:] = alpha * shade + (1 - alpha) * img
        return poly

    def sensor(self, img):
        img = cv2.GaussianBlur(img, (0, 0), SENSOR_BLUR)
        img = img + self.rng.standard_normal(img.shape).astype(np.float32) * SENSOR_NOISE
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _covered_fraction(quad, poly, shape):
    if poly is None:
        return 0.0
    a = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(a, np.round(quad).astype(np.int32), 1)
    area = int(a.sum())
    if area == 0:
        return 1.0
    b = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(b, np.round(poly).astype(np.int32), 1)
    return float((a & b).sum()) / area


def render_frame(gen, models, rng, degrader, condition, distance):
    """(grey frame, scene, bar polygon or None) for one condition."""
    renderer = gen.renderer
    from abp_sim_bridge.flat_renderer import ImageEffects
    if condition == 'plain':
        scene = random_scene(gen, models, rng, distance,
                             effects=ImageEffects(blur_sigma=SENSOR_BLUR, noise_std=SENSOR_NOISE))
        return scene.image, scene, None
    states = rng.bit_generator.state, gen.rng.bit_generator.state
    levels = renderer.floor_level, renderer.background_level
    try:
        renderer.floor_level = renderer.background_level = 0.0
        scene = random_scene(gen, models, rng, distance, effects=ImageEffects())
        dark = scene.image.astype(np.float32)
        # The same scene again (same draws) on white: the difference is the coverage.
        rng.bit_generator.state, gen.rng.bit_generator.state = states
        renderer.floor_level = renderer.background_level = 255.0
        light = random_scene(gen, models, rng, distance, effects=ImageEffects()).image
    finally:
        renderer.floor_level, renderer.background_level = levels
    coverage = 1.0 - (light.astype(np.float32) - dark) / 255.0       # 1 = cube / tag
    background = degrader.textured() if condition == 'textured' else degrader.clutter()
    img = dark + (1.0 - coverage) * background
    poly = None
    if condition in ('gradient', 'all'):
        img = degrader.gradient(img)
    if condition in ('occlusion',) or (condition == 'all' and degrader.rng.random() < 0.5):
        centre = scene.cube_pose[:3, 3]
        cam = np.linalg.inv(scene.camera_pose)
        pc = cam[:3, :3] @ centre + cam[:3, 3]
        px = gen.K[:2, :2] @ (pc[:2] / pc[2]) + gen.K[:2, 2]
        poly = degrader.bar(img, px, gen.K[0, 0] * gen.cube_size / pc[2])
    if condition == 'motion blur' or (condition == 'all' and degrader.rng.random() < 0.5):
        img = degrader.motion_blur(img)
    gray = degrader.sensor(img)
    if condition == 'jpeg':
        gray = degrader.jpeg(gray, degrader.rng.integers(30, 61))
    elif condition == 'all':
        gray = degrader.jpeg(gray, degrader.rng.integers(40, 91))
    return gray, scene, poly


# -- plain OpenCV ------------------------------------------------------------------------------

class PlainOpenCV:
    """``cv2.aruco.ArucoDetector`` defaults + ``solvePnP(SOLVEPNP_IPPE_SQUARE)``."""

    def __init__(self, K, marker_size=0.08):
        self.K = np.asarray(K, dtype=np.float64)
        self.detector = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
            cv2.aruco.DetectorParameters())
        self.obj = marker_object_points(marker_size)

    def detect(self, gray):
        """[(tag_id, corners (4, 2), pose (4, 4) tag -> camera or None)]."""
        corners, ids, _ = self.detector.detectMarkers(gray)
        out = []
        for c, i in zip(corners, [] if ids is None else ids.ravel()):
            quad = c.reshape(4, 2).astype(np.float64)
            ok, rvec, tvec = cv2.solvePnP(self.obj, quad, self.K, None,
                                          flags=cv2.SOLVEPNP_IPPE_SQUARE)
            pose = None
            if ok:
                pose = np.eye(4)
                pose[:3, :3], _ = cv2.Rodrigues(rvec)
                pose[:3, 3] = tvec.reshape(3)
            out.append((int(i), quad, pose))
        return out


# -- scoring -----------------------------------------------------------------------------------

def score(scene, found, hidden):
    """Match detections [(tag_id, corners, pose in world or None, single pose or None)] to
    the scene's tags. Returns (per expected tag: (distance, angle, found, pos err, rot err,
    single rot err, cube tags detected >= 2)), wrong detections."""
    used, wrong, hits = {}, 0, []
    for k, (tag_id, corners, pose, single) in enumerate(found):
        c = corners.mean(axis=0)
        side = float(np.sqrt(abs(cv2.contourArea(corners.astype(np.float32)))))
        hit = [j for j, t in enumerate(scene.tags) if t.tag_id == tag_id
               and np.linalg.norm(t.corners_px.mean(axis=0) - c) < max(3.0, 0.3 * side)]
        if not hit:
            wrong += 1
            continue
        used[hit[0]] = (pose, single)
        hits.append(hit[0])
    cube_found = sum(1 for j in hits if scene.tags[j].on_cube)
    cam = scene.camera_pose[:3, 3]
    rows = []
    for j, t in enumerate(scene.tags):
        angle = float(np.degrees(np.arccos(np.clip(t.cos_view, -1, 1))))
        if not t.in_image or angle > 75.0 or hidden[j]:
            continue
        dist = float(np.linalg.norm(t.centre - cam))
        pose, single = used.get(j, (None, None))
        pos = rot = rot1 = np.nan
        if pose is not None:
            pos = float(np.linalg.norm(pose[:3, 3] - t.centre))
            rot = rotation_deg(pose[:3, :3], t.rotation)
            rot1 = rotation_deg(single[:3, :3], t.rotation) if single is not None else rot
        rows.append((dist, angle, j in used, pos, rot, rot1, t.on_cube and cube_found >= 2))
    return rows, wrong


def aspect_verdict(key, truth):
    """How a best hypothesis `key` (or None) compares with the true aspect `truth`:
    'top-1' (type and every slot), 'partial' (right type, every reported slot right, a
    tag missed: what the observation model's p_miss covers), 'wrong' (wrong type or a
    wrong tag in a slot: p_false / p_type) or 'none'."""
    if key is None:
        return 'none'
    if tuple(key) == tuple(truth):
        return 'top-1'
    if key[0] == truth[0] and all(k in (-1, t) for k, t in zip(key[1:], truth[1:])):
        return 'partial'
    return 'wrong'


def unhidden_aspect_tags(scene, hidden):
    """How many of the true aspect's tags are in the image and not hidden by the bar."""
    slots = {int(t) for t in scene.aspect[1:] if t >= 0}
    return sum(1 for t, h in zip(scene.tags, hidden)
               if t.on_cube and t.tag_id in slots and t.in_image and not h)


# A still robot's head camera between two frames: a small image motion (ego-motion,
# vibration), bounds of the tracking benchmark below.
MOVE_SHIFT_PX = 2.0
MOVE_ROTATION_DEG = 0.3


def moved_frame(gray, rng, shift_px=MOVE_SHIFT_PX, rotation_deg=MOVE_ROTATION_DEG):
    """`gray` moved in the image by a random shift (up to `shift_px` each axis) and rotation
    (up to `rotation_deg`) about its centre, bilinear; returns (moved, 2 x 3 affine map
    from `gray`'s pixels to the moved one's)."""
    h, w = gray.shape
    a = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0),
                                float(rng.uniform(-rotation_deg, rotation_deg)), 1.0)
    a[:, 2] += rng.uniform(-shift_px, shift_px, size=2)
    return cv2.warpAffine(gray, a, (w, h), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE), a


def unmoved(corners, affine):
    """Corners (4, 2) found in a ``moved_frame`` mapped back to the original frame."""
    back = cv2.invertAffineTransform(affine)
    return np.asarray(corners, dtype=np.float64) @ back[:, :2].T + back[:, 2]


def run(gen, models, rng, frames, seed=0, conditions=CONDITIONS):
    ours = TagDetector(gen.K)
    plain = PlainOpenCV(gen.K, ours.marker_size)
    matcher = AspectMatcher(models)
    degrader = Degrader(gen.width, gen.height, seed=seed + 16)
    motion = np.random.default_rng(seed + 32)    # apart, so the scenes stay as they were
    search = RegionSearch(full_frame_every=5)
    untracked = RegionSearch(full_frame_every=5, track=False)
    rows, frames_out = [], []
    for condition in conditions:
        for _ in range(frames):
            distance = float(rng.uniform(0.5, 2.5))
            gray, scene, poly = render_frame(gen, models, rng, degrader, condition, distance)
            hidden = [_covered_fraction(t.corners_px, poly, gray.shape) > HIDDEN_FRACTION
                      for t in scene.tags]
            t0 = time.thread_time()
            result = ours.detect(gray)
            cpu_ours = time.thread_time() - t0
            t0 = time.thread_time()
            theirs = plain.detect(gray)
            cpu_cv = time.thread_time() - t0
            # The region search between full-frame passes (RegionSearch) on a still
            # camera: the same frame searched around the tags the full frame found.
            region = search_region(result.detections, gray.shape)
            cpu_region, in_region = cpu_ours, result
            if region is not None:
                t0 = time.thread_time()
                in_region = ours.detect(gray, roi=region)
                cpu_region = time.thread_time() - t0
            # The next frame of RegionSearch (full_frame_every 5) after this full-frame
            # pass, the camera moved a little: the tags tracked, or the region searched.
            search.reset()
            search.detect(ours, gray)
            moved, affine = moved_frame(gray, motion)
            t0 = time.thread_time()
            next_frame = search.detect(ours, moved)
            cpu_next = time.thread_time() - t0
            untracked.reset()
            untracked.detect(ours, gray)
            t0 = time.thread_time()
            next_untracked = untracked.detect(ours, moved)
            cpu_untracked = time.thread_time() - t0
            world = result.in_frame(scene.camera_pose, BASE_FRAME)
            a, wrong_a = score(scene, [(d.tag_id, d.corners, d.pose, d.single_tag_pose)
                                       for d in world.detections], hidden)
            b, wrong_b = score(scene, [(i, c, None if p is None else scene.camera_pose @ p,
                                        None) for i, c, p in theirs], hidden)
            c, _ = score(scene, [(d.tag_id, d.corners, None, None)
                                 for d in in_region.detections], hidden)
            n, _ = score(scene, [(d.tag_id, unmoved(d.corners, affine), None, None)
                                 for d in next_frame.detections], hidden)
            u, _ = score(scene, [(d.tag_id, unmoved(d.corners, affine), None, None)
                                 for d in next_untracked.detections], hidden)
            for (ra, rb, rc, rn, ru) in zip(a, b, c, n, u):
                rows.append({'condition': condition, 'distance': ra[0], 'angle': ra[1],
                             'ours': ra[2], 'cv': rb[2], 'pos_ours': ra[3], 'pos_cv': rb[3],
                             'rot_ours': ra[4], 'rot_single': ra[5], 'rot_cv': rb[4],
                             'multi': ra[6], 'multi_cv': rb[6], 'region': rc[2],
                             'next': rn[2], 'next_untracked': ru[2]})
            # The aspect matcher on our detections, as the graph runs it (issue 16 goal).
            best = matcher.match(features_from_detections(world.detections)).best
            verdict = aspect_verdict(None if best is None else best.key, scene.aspect)
            frames_out.append({'condition': condition, 'cpu_ours': cpu_ours,
                               'distance': distance, 'aspect_verdict': verdict,
                               'aspect_ok': verdict == 'top-1',
                               'aspect_unhidden': unhidden_aspect_tags(scene, hidden),
                               'cpu_cv': cpu_cv, 'wrong_ours': wrong_a, 'wrong_cv': wrong_b,
                               'det_ours': len(result.detections), 'det_cv': len(theirs),
                               'cpu_region': cpu_region, 'image_px': gray.size,
                               'cpu_next': cpu_next, 'next_tracked': next_frame.tracked > 0,
                               'cpu_untracked': cpu_untracked,
                               'region_px': 0 if region is None else sum(
                                   (x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in region)})
    return rows, frames_out


# -- tables ------------------------------------------------------------------------------------

def _pct(sel, key):
    n = len(sel)
    return f'{100.0 * sum(r[key] for r in sel) / n:.1f} %' if n else 'n/a'


def _q(values, q, scale=1.0, fmt='.1f'):
    v = np.array([x for x in values if np.isfinite(x)])
    return format(scale * float(np.percentile(v, q)), fmt) if v.size else 'n/a'


def condition_bucket_lines(rows, key, bins, unit):
    """Markdown lines of a condition x `key`-bucket table of recall, ours / OpenCV."""
    head = '| condition | ' + ' | '.join(f'{lo:g}-{hi:g}{unit}' for lo, hi in bins) + ' |'
    lines = [head, '|---|' + '---|' * len(bins)]
    for cond in CONDITIONS:
        cells = []
        for lo, hi in bins:
            sel = [r for r in rows if r['condition'] == cond and lo <= r[key] < hi]
            worse = sum(r['ours'] for r in sel) < sum(r['cv'] for r in sel)
            mark = ' **(worse)**' if worse else ''
            cells.append(f"{_pct(sel, 'ours')} / {_pct(sel, 'cv')}{mark}")
        lines.append(f'| {cond} | ' + ' | '.join(cells) + ' |')
    return lines


def bucket_table(rows, key, bins, label):
    out = [f'| {label} | tags | recall ours | recall OpenCV '
           '| position error median ours / OpenCV (mm) | rotation error p95 ours / OpenCV (°) |',
           '|---|---|---|---|---|---|']
    for lo, hi in bins:
        sel = [r for r in rows if lo <= r[key] < hi]
        out.append(_bucket_row(f'{lo:g}-{hi:g}', sel))
    return '\n'.join(out)


def _bucket_row(name, sel):
    flag = ''
    if sel:
        a, b = sum(r['ours'] for r in sel), sum(r['cv'] for r in sel)
        flag = ' **(worse)**' if a < b else ''
    return (f"| {name} | {len(sel)} | {_pct(sel, 'ours')}{flag} | {_pct(sel, 'cv')} "
            f"| {_q([r['pos_ours'] for r in sel], 50, 1e3)} / "
            f"{_q([r['pos_cv'] for r in sel], 50, 1e3)} "
            f"| {_q([r['rot_ours'] for r in sel], 95)} / {_q([r['rot_cv'] for r in sel], 95)} |")


def _by_condition(rows, frames):
    """(condition, its tag rows, its frames) for each condition with frames, then for
    'every condition'."""
    for cond in CONDITIONS + ('every condition',):
        sel = [r for r in rows if cond == 'every condition' or r['condition'] == cond]
        fr = [f for f in frames if cond == 'every condition' or f['condition'] == cond]
        if fr:
            yield cond, sel, fr


def condition_table(rows, frames):
    out = ['| condition | frames | tags | recall ours | recall OpenCV '
           '| recall ≤ 1.5 m ours / OpenCV | wrong detections ours / OpenCV '
           '| position error median ours / OpenCV (mm) '
           '| rotation p95 ours / OpenCV (°) | CPU median ours / OpenCV (ms) | ratio |',
           '|---|---|---|---|---|---|---|---|---|---|---|']
    for cond, sel, fr in _by_condition(rows, frames):
        near = [r for r in sel if r['distance'] < 1.5]
        worse = sum(r['ours'] for r in sel) < sum(r['cv'] for r in sel)
        co, cc = (1e3 * float(np.median([f[k] for f in fr])) for k in ('cpu_ours', 'cpu_cv'))
        out.append(
            f"| {cond} | {len(fr)} | {len(sel)} | {_pct(sel, 'ours')}"
            f"{' **(worse)**' if worse else ''} | {_pct(sel, 'cv')} "
            f"| {_pct(near, 'ours')} / {_pct(near, 'cv')} "
            f"| {sum(f['wrong_ours'] for f in fr)} / {sum(f['wrong_cv'] for f in fr)} "
            f"| {_q([r['pos_ours'] for r in sel], 50, 1e3)} / "
            f"{_q([r['pos_cv'] for r in sel], 50, 1e3)} "
            f"| {_q([r['rot_ours'] for r in sel], 95)} / {_q([r['rot_cv'] for r in sel], 95)} "
            f"| {co:.2f} / {cc:.2f} | {co / cc:.2f} |")
    return '\n'.join(out)


def region_table(rows, frames, full_frame_every=5):
    """CPU and recall of the region search (RegionSearch) against the full frame."""
    out = ['| condition | recall full frame / region | CPU median full frame / region / '
           f'OpenCV (ms) | RegionSearch(full_frame_every={full_frame_every}): mean CPU '
           '(ms), ratio to OpenCV | area searched (median, % of the image) |',
           '|---|---|---|---|---|']
    for cond, sel, fr in _by_condition(rows, frames):
        full, region, cv = (1e3 * np.array([f[k] for f in fr])
                            for k in ('cpu_ours', 'cpu_region', 'cpu_cv'))
        mix = (full + (full_frame_every - 1) * region) / full_frame_every
        area = [100.0 * (f['region_px'] or f['image_px']) / f['image_px'] for f in fr]
        out.append(f"| {cond} | {_pct(sel, 'ours')} / {_pct(sel, 'region')} "
                   f'| {np.median(full):.2f} / {np.median(region):.2f} / {np.median(cv):.2f} '
                   f'| {mix.mean():.2f}, {mix.mean() / cv.mean():.2f} '
                   f'| {np.median(area):.0f} % |')
    return '\n'.join(out)


def tracking_table(rows, frames, full_frame_every=5):
    """CPU and recall of RegionSearch's frames between full-frame passes, on the moved
    frame: with tracking (or the region searched where a tag was lost) and without it
    (the region searched), against the full frame."""
    out = ['| condition | next frames tracked (no ArUco pass) | recall full frame / '
           'next frame tracked / next frame region only | CPU median full frame / next '
           'frame tracked / region only / OpenCV (ms) | '
           f'RegionSearch(full_frame_every={full_frame_every}) per frame, tracked: median, '
           'mean (ms), mean ratio to OpenCV |', '|---|---|---|---|---|']
    for cond, sel, fr in _by_condition(rows, frames):
        full, nxt, region, cv = (1e3 * np.array([f[k] for f in fr])
                                 for k in ('cpu_ours', 'cpu_next', 'cpu_untracked', 'cpu_cv'))
        seq = np.concatenate([full, np.repeat(nxt, full_frame_every - 1)])
        tracked = sum(f['next_tracked'] for f in fr)
        out.append(f"| {cond} | {tracked} of {len(fr)} | {_pct(sel, 'ours')} / "
                   f"{_pct(sel, 'next')} / {_pct(sel, 'next_untracked')} | "
                   f'{np.median(full):.2f} / {np.median(nxt):.2f} / {np.median(region):.2f} / '
                   f'{np.median(cv):.2f} | {np.median(seq):.2f}, {seq.mean():.2f}, '
                   f'{seq.mean() / cv.mean():.2f} |')
    return '\n'.join(out)


def aspect_table(frames, max_distance=1.5):
    """Aspect verdicts per condition over the frames with the cube within `max_distance`.

    The matcher votes with pairs of tags, so a frame where the bar leaves fewer than two
    of the aspect's tags unhidden has no answer to find; those frames are counted apart
    and the last column is top-1 over the others."""
    lines = [f'| condition | frames (cube ≤ {max_distance:g} m) | top-1 | partial (a tag '
             'missed, the rest right) | wrong | no hypothesis | frames with < 2 of the '
             "aspect's tags unhidden | top-1 over the other frames |",
             '|---|---:|---:|---:|---:|---:|---:|---:|']

    def count(sel, verdict):
        return sum(f['aspect_verdict'] == verdict for f in sel)

    def row(name, sel):
        clear = [f for f in sel if f['aspect_unhidden'] >= 2]
        return (f"| {name} | {len(sel)} | {_pct(sel, 'aspect_ok')} | {count(sel, 'partial')} | "
                f"{count(sel, 'wrong')} | {count(sel, 'none')} | {len(sel) - len(clear)} | "
                f"{_pct(clear, 'aspect_ok')} |")
    for condition, _, fr in _by_condition([], frames):
        lines.append(row(condition, [f for f in fr if f['distance'] <= max_distance]))
    return '\n'.join(lines)


def rigid_rows_table(rows):
    """Rotation errors of the cube's tags in frames with >= 2 of them found by us."""
    out = ['| condition | tags | ours (rigid cube) median / p95 / max (°) '
           '| ours single-tag median / p95 / max (°) | OpenCV (its tags on cubes with ≥ 2 '
           'found) median / p95 / max (°) |', '|---|---|---|---|---|']

    def stats(v):
        v = np.array([x for x in v if np.isfinite(x)])
        if not v.size:
            return 'n/a'
        return f'{np.median(v):.2f} / {np.percentile(v, 95):.2f} / {v.max():.1f}'

    for cond in CONDITIONS + ('every condition',):
        sel = [r for r in rows if (cond == 'every condition' or r['condition'] == cond)
               and r['multi'] and r['ours']]
        cv = [r['rot_cv'] for r in rows if (cond == 'every condition' or r['condition'] == cond)
              and r['multi_cv'] and r['cv']]
        out.append(f"| {cond} | {len(sel)} | {stats([r['rot_ours'] for r in sel])} "
                   f"| {stats([r['rot_single'] for r in sel])} | {stats(cv)} |")
    return '\n'.join(out)


def section(rows, frames, command, per_condition):
    try:
        load = 'load average {:.1f} / {:.1f} / {:.1f}'.format(*os.getloadavg())
    except OSError:
        load = 'load average unknown'
    lines = [
        '## Perception under realistic conditions (issue 16)', '',
        'The realistic-conditions suite of `perception_benchmark` (`abp_bench.realistic_suite`'
        ", conditions in its docstring): the standard benchmark's random ARcube scenes at "
        f'0.5-2.5 m, {per_condition} frames per condition, each degraded by one condition, '
        'and both detectors on the same grey frame: ours (`TagDetector` defaults, rigid '
        'cube fit on) and plain OpenCV (`cv2.aruco.ArucoDetector` defaults + '
        '`solvePnP(SOLVEPNP_IPPE_SQUARE)`). Recall over the tags in the image viewed within '
        '75° and not hidden by the arm bar; errors over the tags both found or each found; '
        'CPU = median per-frame `time.thread_time` of the detection call, OpenCV on 1 thread. '
        f'Machine: {os.cpu_count()} cores, shared, {load} at the end of the run. '
        "**(worse)** marks a bucket where our recall is below OpenCV's.", '',
        '```', command, '```', '',
        '### By condition', '', condition_table(rows, frames), '',
        '### By distance (camera to tag), every condition', '',
        bucket_table(rows, 'distance', DISTANCE_BINS, 'distance (m)'), '',
        '### By viewing angle (from the tag normal), every condition', '',
        bucket_table(rows, 'angle', ANGLE_BINS, 'angle (°)'), '',
        '### By distance and condition (recall ours / OpenCV)', '',
        *condition_bucket_lines(rows, 'distance', DISTANCE_BINS, ' m'),
        '', '### By viewing angle and condition (recall ours / OpenCV)', '',
        *condition_bucket_lines(rows, 'angle', ANGLE_BINS, '°'),
        '', '### Region search: only around the tags of the last frame', '',
        'Each frame searched again around the tags its full-frame pass found '
        '(`search_region`, as `RegionSearch` does between full-frame passes on a still '
        'camera); frames without a detection count at their full-frame cost. The mean over '
        "frames of (full + 4 region) / 5 is the cost at `full_frame_every` 5 (the node's "
        'default).', '',
        region_table(rows, frames),
        '', '### Between full-frame passes: tracking on a moving camera', '',
        'The frame after each full-frame pass as `RegionSearch` (`full_frame_every` 5, '
        '`track` on) gets it, moved in the image by up to '
        f'{MOVE_SHIFT_PX:g} px and {MOVE_ROTATION_DEG:g}° (`moved_frame`): the last '
        "frame's tags found again where they were (`TagDetector.track`, no ArUco pass), "
        'or, where one is lost, ArUco in `search_region`; and, on the same moved frame, '
        '`RegionSearch` with `track` off (ArUco in `search_region`). The per-frame '
        'figures of `RegionSearch` count 1 full frame and 4 tracked frames.', '',
        tracking_table(rows, frames),
    ]
    lines += ['', '### Aspect top-1 (the aspect matcher on our detections)', '',
              "Top-1: the matcher's best hypothesis is the rendered state's aspect (type "
              'and every slot); partial: the right type and every reported slot right, a '
              "missed tag's slot empty (the observation model's p_miss); wrong: a wrong "
              'type or tag (p_type, p_false). A tag hidden by the arm bar leaves its slot '
              'unknowable, so frames with fewer than two unhidden aspect tags are also '
              'shown apart.', '', aspect_table(frames)]
    lines += ['', '### Rotation error of tags on cubes with ≥ 2 tags found (issue 16, item 3)',
              '', rigid_rows_table(rows), '']
    return '\n'.join(lines)


def main(args, models, gen, argv):
    import sys

    from .perception_scenes import update_doc
    rng = np.random.default_rng(args.seed)
    rows, frames = run(gen, models, rng, args.realistic_frames, seed=args.seed)
    command = ('install/abp_bench/lib/abp_bench/perception_benchmark '
               + ' '.join(argv if argv is not None else sys.argv[1:]))
    text = section(rows, frames, command, args.realistic_frames)
    print(text)
    if args.update_doc:
        update_doc(args.update_doc, text, heading='Perception under realistic conditions')
    return 0
