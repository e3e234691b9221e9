"""Perception benchmark: tag detection and aspect matching on rendered ARcube scenes.

    perception_benchmark [--frames 120] [--noise-frames 60] [--match-trials 600]
                         [--distance-trials 200] [--robot-trials 300] [--seed 0]
                         [--threads 1]
                         [--update-doc /tmp/perception.md]   # tables as a Markdown section

Scenes come from the sim bridge's renderer (``abp_bench.scenes``): a random model
of the full 1470-model set (n_tags = 7) in a random one of its 48 states, turned by a
yaw error of up to +-8 deg, seen from 0.5-2.5 m at 25-45 deg elevation, anywhere in the
image (look offset up to 40 % of the half image), with 2 distractor tags beside it (one
with an id in 0..6, one outside), default image noise = the sim bridge's (Gaussian blur
sigma 0.6 px, noise sigma 2 grey levels).

Detection: recall over the tags in the image (3 px clear of the border) viewed within
60 deg of their normal (and, separately, 60-70 deg); precision over all detections (a
detection is right when a tag with its id is in the scene within 3 px / 30 % of its
size); face-centre error = 3-D distance of a cube tag's estimated centre to the true
face centre. Matching: top-1 = the best hypothesis equals the rendered state's aspect
(type and all slots). Times are medians of per-frame CPU time of this thread (OpenCV
limited to --threads), which stays meaningful on a shared machine; wall times are given
too.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import cv2
import numpy as np

from abp_description.robot_profile import load_profile
from abp_perception.detector import TagDetector
from abp_perception.matcher import AspectMatcher, features_from_detections

# Shared with realistic_suite (perception_scenes), so that it need not import this module.
from .perception_scenes import random_scene, rotation_deg, update_doc

BASE_FRAME = load_profile().frames.base   # the scenes' world: the default robot's base

DISTANCES = (0.5, 1.0, 1.5, 2.0, 2.5)
NOISE_LEVELS = {'clean': (0.0, 0.0), 'default': (0.6, 2.0), 'noisy': (1.0, 5.0),
                'very noisy': (1.5, 8.0)}
GOALS = {'recall': 0.99, 'precision': 0.999, 'detect_ms': 10.0, 'centre_mm': 5.0,
         'top1': 0.99, 'match_ms': 5.0}


def _sim_bridge_effects():
    from abp_sim_bridge.flat_renderer import ImageEffects
    return ImageEffects(blur_sigma=0.5, noise_std=1.0)


def _effects(level):
    from abp_sim_bridge.flat_renderer import ImageEffects
    blur, noise = NOISE_LEVELS[level]
    return ImageEffects(blur_sigma=blur, noise_std=noise)


def score_detections(scene, detections):
    """(expected <= 60 deg, found, expected 60-70 deg, found, correct, wrong, centre errors)."""
    used = set()
    wrong = 0
    centre_err = []
    for det in detections:
        c = det.corners.mean(axis=0)
        hit = [k for k, t in enumerate(scene.tags) if t.tag_id == det.tag_id
               and np.linalg.norm(t.corners_px.mean(axis=0) - c) < max(3.0, 0.3 * det.side_px)]
        if not hit:
            wrong += 1
            continue
        used.add(hit[0])
        if scene.tags[hit[0]].on_cube:
            centre_err.append(float(np.linalg.norm(det.position - scene.tags[hit[0]].centre)))
    exp60 = found60 = exp70 = found70 = 0
    cos60, cos70 = np.cos(np.deg2rad(60.0)), np.cos(np.deg2rad(70.0))
    for k, t in enumerate(scene.tags):
        if not t.in_image:
            continue
        if t.cos_view >= cos60:
            exp60 += 1
            found60 += k in used
        elif t.cos_view >= cos70:
            exp70 += 1
            found70 += k in used
    return exp60, found60, exp70, found70, len(detections) - wrong, wrong, centre_err


def cube_tag_hits(scene, detections):
    """[(detection, TruthTag)] of the detections of the cube's tags (matched by id and
    image position, as in score_detections)."""
    hits = []
    for det in detections:
        c = det.corners.mean(axis=0)
        hit = [t for t in scene.tags if t.on_cube and t.tag_id == det.tag_id
               and np.linalg.norm(t.corners_px.mean(axis=0) - c) < max(3.0, 0.3 * det.side_px)]
        if hit:
            hits.append((det, hit[0]))
    return hits


def cube_tag_errors(scene, detections):
    """Errors of the cube's tags in a frame where >= 2 of them were detected (world-frame
    detections; empty lists otherwise): rotation (deg) of the single-tag pose and of the
    pose used (the rigid cube's when fitted), and their centre errors (m)."""
    hits = cube_tag_hits(scene, detections)
    if len(hits) < 2:
        return [], [], [], []
    return ([rotation_deg(d.single_tag_pose[:3, :3], t.rotation) for d, t in hits],
            [rotation_deg(d.pose[:3, :3], t.rotation) for d, t in hits],
            [float(np.linalg.norm(d.single_tag_pose[:3, 3] - t.centre)) for d, t in hits],
            [float(np.linalg.norm(d.pose[:3, 3] - t.centre)) for d, t in hits])


def run_rigid(gen, models, detector, rng, distances, frames, effects=None):
    """Per distance: rotation and position errors of the cube's tags (frames with >= 2 of
    them detected), single-tag IPPE pose against the rigid cube pose."""
    rows = []
    effects = _effects('default') if effects is None else effects
    for distance in distances:
        acc = [[], [], [], []]
        fitted = 0
        for _ in range(frames):
            scene = random_scene(gen, models, rng, distance, effects=effects)
            world = detector.detect(scene.image).in_frame(scene.camera_pose, BASE_FRAME)
            errs = cube_tag_errors(scene, world.detections)
            for k in range(4):
                acc[k] += errs[k]
            fitted += bool(errs[0]) and bool(world.cubes)
        rows.append({'distance': distance, 'frames': frames, 'tags': len(acc[0]),
                     'fitted': fitted, 'single': np.array(acc[0]), 'rigid': np.array(acc[1]),
                     'pos_single': np.array(acc[2]), 'pos_rigid': np.array(acc[3])})
    return rows


def rigid_table(rows):
    out = ['| distance (m) | frames | tags (frames with ≥ 2 cube tags detected) '
           '| frames with a rigid fit '
           '| rotation error single-tag median / p95 / max (°) '
           '| rotation error rigid cube median / p95 / max (°) '
           '| face-centre error single / rigid median (mm) |',
           '|---|---|---|---|---|---|---|']

    def stats(a):
        if not a.size:
            return 'n/a'
        return f'{np.median(a):.2f} / {np.percentile(a, 95):.2f} / {a.max():.1f}'

    def med_mm(a):
        return f'{1e3 * np.median(a):.1f}' if a.size else 'n/a'

    total = {k: np.concatenate([r[k] for r in rows]) for k in
             ('single', 'rigid', 'pos_single', 'pos_rigid')}
    for r in rows + [dict(total, distance=None, frames=sum(r['frames'] for r in rows),
                          tags=sum(r['tags'] for r in rows),
                          fitted=sum(r['fitted'] for r in rows))]:
        name = 'all' if r['distance'] is None else f"{r['distance']:.1f}"
        out.append(f"| {name} | {r['frames']} | {r['tags']} | {r['fitted']} "
                   f"| {stats(r['single'])} | {stats(r['rigid'])} "
                   f"| {med_mm(r['pos_single'])} / {med_mm(r['pos_rigid'])} |")
    return '\n'.join(out)


def run_detection(gen, models, detector, rng, distances, frames, level):
    rows = []
    gen_effects = _effects(level)
    for distance in distances:
        acc = np.zeros(6, dtype=np.int64)
        errs, cpu, wall = [], [], []
        for _ in range(frames):
            scene = random_scene(gen, models, rng, distance, effects=gen_effects)
            t0, w0 = time.thread_time(), time.perf_counter()
            result = detector.detect(scene.image)
            cpu.append(time.thread_time() - t0)
            wall.append(time.perf_counter() - w0)
            world = result.in_frame(scene.camera_pose, BASE_FRAME)
            *counts, e = score_detections(scene, world.detections)
            acc += np.array(counts)
            errs += e
        rows.append({'distance': distance, 'level': level, 'frames': frames,
                     'exp60': int(acc[0]), 'found60': int(acc[1]), 'exp70': int(acc[2]),
                     'found70': int(acc[3]), 'correct': int(acc[4]), 'wrong': int(acc[5]),
                     'err_median': float(np.median(errs)) if errs else float('nan'),
                     'err_p90': float(np.percentile(errs, 90)) if errs else float('nan'),
                     'cpu_ms': 1e3 * float(np.median(cpu)),
                     'wall_ms': 1e3 * float(np.median(wall))})
    return rows


def run_matching(gen, models, detector, matcher, rng, trials, distance_range):
    rows = []
    for _ in range(trials):
        distance = float(rng.uniform(*distance_range))
        scene = random_scene(gen, models, rng, distance)
        result = detector.detect(scene.image).in_frame(scene.camera_pose, BASE_FRAME)
        feats = features_from_detections(result.detections)
        t0, w0 = time.thread_time(), time.perf_counter()
        match = matcher.match(feats)
        cpu, wall = time.thread_time() - t0, time.perf_counter() - w0
        best = match.best
        ok = best is not None and best.key == scene.aspect
        partial = best is not None and not ok and all(
            s in (-1, t) for s, t in zip(best.slots, scene.aspect[1:])) \
            and best.aspect_type == scene.aspect[0]
        pos_err = float(np.linalg.norm(best.position - scene.cube_pose[:3, 3])) \
            if best is not None else float('nan')
        rows.append({'distance': distance, 'type': scene.aspect[0], 'ok': ok,
                     'partial': partial, 'none': best is None, 'cpu_ms': 1e3 * cpu,
                     'wall_ms': 1e3 * wall, 'pos_err': pos_err,
                     'features': len(feats)})
    return rows


def run_robot_matching(gen, models, detector, matcher, rng, trials, kinematics):
    """Matching as the robot sees the cube: base_link at the origin, the cube 0.35-0.45 m
    in front (the sim bridge's default 0.40 m, also the ORBIT radius), head turned to it."""
    rows = []
    for _ in range(trials):
        centre = np.array([rng.uniform(0.35, 0.45), rng.uniform(-0.1, 0.1), models.cube_size / 2])
        model = int(rng.integers(models.num_models))
        state = int(rng.integers(48))
        distance = float(np.linalg.norm(centre - [0.0, 0.0, 0.7]))
        distractors = gen.random_distractors(2, models.n_tags, distance, 60.0, in_range=1)
        scene, _ = gen.render_robot(kinematics, models.faces[model], state, centre,
                                    yaw_error_deg=float(rng.uniform(-8.0, 8.0)),
                                    distractors=distractors)
        result = detector.detect(scene.image).in_frame(scene.camera_pose, BASE_FRAME)
        match = matcher.match(features_from_detections(result.detections))
        best = match.best
        ok = best is not None and best.key == scene.aspect
        partial = best is not None and not ok and best.aspect_type == scene.aspect[0] and all(
            s in (-1, t) for s, t in zip(best.slots, scene.aspect[1:]))
        rows.append({'distance': scene.distance, 'type': scene.aspect[0], 'ok': ok,
                     'partial': partial, 'none': best is None, 'pos_err': float(
                         np.linalg.norm(best.position - scene.cube_pose[:3, 3]))
                     if best is not None else float('nan'),
                     'elevation': scene.elevation_deg})
    return rows


def _pct(num, den):
    return f'{100.0 * num / den:.2f} %' if den else 'n/a'


def detection_table(rows):
    out = ['| distance (m) | noise | frames | recall ≤60° | recall 60-70° | precision '
           '| face-centre error median / p90 (mm) | detect CPU / wall median (ms) |',
           '|---|---|---|---|---|---|---|---|']
    for r in rows:
        out.append(
            f"| {r['distance']:.1f} | {r['level']} | {r['frames']} "
            f"| {_pct(r['found60'], r['exp60'])} ({r['found60']}/{r['exp60']}) "
            f"| {_pct(r['found70'], r['exp70'])} ({r['found70']}/{r['exp70']}) "
            f"| {_pct(r['correct'], r['correct'] + r['wrong'])} "
            f"({r['correct']}/{r['correct'] + r['wrong']}) "
            f"| {1e3 * r['err_median']:.1f} / {1e3 * r['err_p90']:.1f} "
            f"| {r['cpu_ms']:.2f} / {r['wall_ms']:.2f} |")
    return '\n'.join(out)


def matching_table(rows, bins):
    out = ['| distance (m) | trials | top-1 | top-1 type 2 | top-1 type 3 '
           '| partial (missed tag) | no hypothesis | cube-centre error median (mm) |',
           '|---|---|---|---|---|---|---|---|']
    for lo, hi in bins:
        sel = [r for r in rows if lo <= r['distance'] < hi]
        if not sel:
            continue
        t2 = [r for r in sel if r['type'] == 2]
        t3 = [r for r in sel if r['type'] == 3]
        errs = [r['pos_err'] for r in sel if r['ok']]
        out.append(
            f"| {lo:.1f}-{hi:.1f} | {len(sel)} | {_pct(sum(r['ok'] for r in sel), len(sel))} "
            f"| {_pct(sum(r['ok'] for r in t2), len(t2))} "
            f"| {_pct(sum(r['ok'] for r in t3), len(t3))} "
            f"| {sum(r['partial'] for r in sel)} | {sum(r['none'] for r in sel)} "
            f"| {1e3 * float(np.median(errs)) if errs else float('nan'):.1f} |")
    return '\n'.join(out)


def goals_table(det_rows, match_rows, match_range):
    default = [r for r in det_rows if r['level'] == 'default']
    upto2 = [r for r in default if r['distance'] <= 2.0]
    exp = sum(r['exp60'] for r in upto2)
    rec = sum(r['found60'] for r in upto2) / max(exp, 1)
    cor = sum(r['correct'] for r in upto2)
    prec = cor / max(cor + sum(r['wrong'] for r in upto2), 1)
    det_ms = float(np.median([r['cpu_ms'] for r in default]))
    at1 = [r for r in default if abs(r['distance'] - 1.0) < 1e-9]
    centre = 1e3 * at1[0]['err_median'] if at1 else float('nan')
    sel = [r for r in match_rows if match_range[0] <= r['distance'] < match_range[1]]
    top1 = sum(r['ok'] for r in sel) / max(len(sel), 1)
    match_ms = float(np.median([r['cpu_ms'] for r in match_rows]))

    def row(name, goal, value, ok):
        return f"| {name} | {goal} | {value} | {'met' if ok else 'MISSED'} |"

    return '\n'.join([
        '| goal | target | measured | |', '|---|---|---|---|',
        row('detection recall, 8 cm tags ≤ 2 m, default noise (view ≤ 60°)', '≥ 99 %',
            f'{100 * rec:.2f} %', rec >= GOALS['recall']),
        row('detection precision, ≤ 2 m, default noise', '≥ 99.9 %', f'{100 * prec:.3f} %',
            prec >= GOALS['precision']),
        row('detection time per 640x480 frame (median, CPU)', '≤ 10 ms', f'{det_ms:.2f} ms',
            det_ms <= GOALS['detect_ms']),
        row('face-centre error at 1 m (median)', '≤ 5 mm', f'{centre:.2f} mm',
            centre <= GOALS['centre_mm']),
        row(f'aspect top-1 with 2 distractors ({match_range[0]:.1f}-{match_range[1]:.1f} m)',
            '≥ 99 %', f'{100 * top1:.2f} %', top1 >= GOALS['top1']),
        row('matching time vs the 1470-model set (median, CPU)', '≤ 5 ms',
            f'{match_ms:.3f} ms', match_ms <= GOALS['match_ms']),
    ])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--frames', type=int, default=120,
                        help='frames per distance at default noise (default 120)')
    parser.add_argument('--noise-frames', type=int, default=60,
                        help='frames per (distance, noise level) of the noise table')
    parser.add_argument('--match-trials', type=int, default=600)
    parser.add_argument('--distance-trials', type=int, default=200,
                        help='matching trials over 0.5-2.5 m for the by-distance table')
    parser.add_argument('--robot-trials', type=int, default=300,
                        help="matching trials at the robot's working pose (0: skip)")
    parser.add_argument('--match-min', type=float, default=0.6, help='matching distances, m')
    parser.add_argument('--match-max', type=float, default=1.6)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--threads', type=int, default=1, help='OpenCV threads')
    parser.add_argument('--rigid-frames', type=int, default=120,
                        help='frames per distance for the rigid-cube pose table (0: skip)')
    parser.add_argument('--cube-size', type=float, default=0.10,
                        help="TagDetector's cube_size: rigid cube fit for tags on one cube "
                        '(0: per-tag poses only, as before issue 16)')
    parser.add_argument('--realistic-frames', type=int, default=150,
                        help='frames per condition of the realistic suite')
    parser.add_argument('--suite', choices=('standard', 'rigid', 'realistic', 'real'),
                        default='standard',
                        help="standard: every table of the '## Perception' section; rigid: "
                        "only the rigid-cube pose table; realistic: the realistic-conditions "
                        "suite against plain OpenCV (issue 16); real: committed real "
                        "photographs against plain OpenCV (issue 34, real_photo_suite)")
    parser.add_argument('--real-repeats', type=int, default=3,
                        help='real suite: timed runs per photo and detector (median)')
    parser.add_argument('--real-photos', nargs='+', metavar='NAME',
                        help='real suite: only photos whose name contains one of these')
    parser.add_argument('--json', metavar='PATH', help='real suite: results as JSON')
    parser.add_argument('--update-doc', metavar='PATH',
                        help="write the tables as the '## Perception' section of PATH")
    args = parser.parse_args(argv)
    if args.frames < 1 or args.noise_frames < 0 or args.match_trials < 1:
        parser.error('--frames and --match-trials must be >= 1, --noise-frames >= 0')
    if not 0 < args.match_min < args.match_max:
        parser.error('need 0 < --match-min < --match-max')
    if args.suite == 'real':
        from abp_bench import real_photo_suite
        return real_photo_suite.main(args)

    from abp_belief.population import full_set
    from abp_bench.scenes import SceneGenerator

    cv2.setNumThreads(args.threads)
    models = full_set(7)
    rng = np.random.default_rng(args.seed)
    gen = SceneGenerator(seed=args.seed)
    detector = TagDetector(gen.K, cube_size=args.cube_size)
    t0 = time.perf_counter()
    matcher = AspectMatcher(models)
    build_s = time.perf_counter() - t0

    if args.suite == 'rigid':
        rows = run_rigid(gen, models, detector, rng, DISTANCES, max(args.rigid_frames, 1))
        print(rigid_table(rows))
        return 0
    if args.suite == 'realistic':
        from abp_bench import realistic_suite
        return realistic_suite.main(args, models, gen, argv)
    det_rows = run_detection(gen, models, detector, rng, DISTANCES, args.frames, 'default')
    noise_rows = []
    if args.noise_frames:
        for level in NOISE_LEVELS:
            if level != 'default':
                noise_rows += run_detection(gen, models, detector, rng, (1.0, 2.0),
                                            args.noise_frames, level)
    match_range = (args.match_min, args.match_max)
    match_rows = run_matching(gen, models, detector, matcher, rng, args.match_trials,
                              match_range)
    by_distance = run_matching(gen, models, detector, matcher, rng, args.distance_trials,
                               (0.5, 2.5)) if args.distance_trials > 0 else []
    rigid_rows = run_rigid(gen, models, detector, rng, DISTANCES, args.rigid_frames) \
        if args.rigid_frames > 0 else []
    robot_rows = []
    if args.robot_trials > 0:
        from abp_description.kinematics import RobotKinematics
        robot_gen = SceneGenerator(seed=args.seed + 1, effects=_sim_bridge_effects())
        robot_rows = run_robot_matching(robot_gen, models, detector, matcher, rng,
                                        args.robot_trials, RobotKinematics())
    cpu = np.array([r['cpu_ms'] for r in match_rows])
    wall = np.array([r['wall_ms'] for r in match_rows])

    command = 'perception_benchmark ' + ' '.join(argv if argv is not None else sys.argv[1:])
    try:
        load = 'load average {:.1f} / {:.1f} / {:.1f}'.format(*os.getloadavg())
    except OSError:
        load = 'load average unknown'
    machine = f'{os.cpu_count()} CPU cores, {load} (1/5/15 min) at the end of the run'
    lines = [
        '## Perception',
        '',
        "ArUco tag detection (`abp_perception.detector`) and aspect matching "
        "(`abp_perception.matcher`, paper Alg. 2) on scenes rendered by the sim bridge's "
        "renderer: a random model of the full 1470-model set in a random state (yaw error "
        "±8°), 25-45° elevation, anywhere in the 640x480 image, 2 distractor tags (one id in "
        "0..6, one outside), 8 cm tags on 10 cm cubes. Default noise = blur σ 0.6 px + noise "
        "σ 2 grey levels. Times: median CPU time of one thread, OpenCV on "
        f"{args.threads} thread(s); wall-clock medians beside them. Machine: {machine}.",
        '',
        'Reproduce (after `scripts/bootstrap.sh && source scripts/env.sh`; on a robot '
        '`ros2 run abp_bench perception_benchmark ...`):',
        '',
        '```',
        f'install/abp_bench/lib/abp_bench/{command.strip()}',
        '```',
        '',
        '### Goals',
        '',
        goals_table(det_rows, match_rows, match_range),
        '',
        '### Detection by distance (default noise)',
        '',
        detection_table(det_rows),
        '',
    ]
    if noise_rows:
        lines += ['### Detection under other noise levels',
                  '',
                  'Noise levels: ' + ', '.join(f'{k} = blur {v[0]} px / noise {v[1]}'
                                               for k, v in NOISE_LEVELS.items()) + '.',
                  '',
                  detection_table(noise_rows), '']
    lines += [
        f'### Aspect matching, 2 distractors, {args.match_trials} trials at '
        f'{match_range[0]:.1f}-{match_range[1]:.1f} m',
        '',
        matching_table(match_rows, [match_range]),
        '',
        f'Matching time: median {np.median(cpu):.3f} ms CPU ({np.median(wall):.3f} ms wall), '
        f'p95 {np.percentile(cpu, 95):.3f} ms; lookup tables for {len(models.aspects)} '
        f'aspects of {models.num_models} models built in {1e3 * build_s:.0f} ms.',
        '',
    ]
    if robot_rows:
        elev = np.array([r['elevation'] for r in robot_rows])
        dist = np.array([r['distance'] for r in robot_rows])
        lines += [f"### Aspect matching at the robot's working pose, {len(robot_rows)} trials",
                  '',
                  "The robot's head camera (`abp_description` kinematics, head panned and "
                  "tilted to the cube) with the cube 0.35-0.45 m in front of the base frame "
                  "(the sim bridge's default 0.40 m, also the ORBIT radius): camera "
                  f"{dist.min():.2f}-{dist.max():.2f} m from the cube, "
                  f"{elev.min():.0f}-{elev.max():.0f}° elevation, so the side faces of a "
                  "45° aspect are seen at 65-80° from their normal. Sim-bridge camera noise "
                  "(blur 0.5 px, noise σ 1), 2 distractors. A missed, grazing side tag gives "
                  "a partial hypothesis (-1 in its slot), which the belief's p_miss covers.",
                  '',
                  matching_table(robot_rows, [(0.0, 10.0)]).replace('| 0.0-10.0 |', '| robot |'),
                  '']
    if args.rigid_frames > 0:
        lines += ['### Rigid-cube pose (issue 16, item 3)', '',
                  'Tags of the cube in frames where at least 2 of them were detected: the '
                  "tag's own IPPE_SQUARE pose (`Detection.single_tag_pose`) against the pose "
                  'its cube implies (`Detection.pose`, one pose fitted to all the corners of '
                  "the cube's tags, `abp_perception.rigid_cube`); default noise, "
                  f'{args.rigid_frames} frames per distance.', '',
                  rigid_table(rigid_rows), '']
    if by_distance:
        lines += ['### Aspect matching by distance (0.5-2.5 m)',
                  '',
                  matching_table(by_distance, [(0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5)]),
                  '']
    section = '\n'.join(lines)
    print(section)
    if args.update_doc:
        update_doc(args.update_doc, section)
    return 0


if __name__ == '__main__':
    sys.exit(main())
