"""Real-photo suite of ``perception_benchmark`` (issue 34): our detector against plain OpenCV
on real photographs of ArUco and AprilTag 36h11 tags from public repositories.

    perception_benchmark --suite real [--real-repeats 3] [--real-photos NAME ...]
                         [--json /tmp/real.json] [--update-doc /tmp/perception.md]

Photos and truth: ``real_photos/manifest.json`` (each photo pinned by repository, commit,
path and licence; truth by ``real_photo_truth``). Both detectors see the committed file in
grey, in the photo's dictionary. **Ours**: ``TagDetector`` with its defaults (rigid cube
fit and face search on) and a nominal camera (focal = the image's larger side, centred
principal point). **Plain OpenCV**: ``realistic_suite.PlainOpenCV`` (default
``DetectorParameters`` + ``SOLVEPNP_IPPE_SQUARE`` per marker, as in the realistic suite).

Per photo: tags in the truth, found by each, **wrong** reports (no truth tag of that id
within max(3 px, 0.3 side)), reports on tags the truth rejected (their bits did not
re-read) counted apart, **duplicates** (two reports of one id within the tag's side),
corner error against the truth corners and against an **edge-fit reference**
(``real_photo_truth.edge_fit_corners`` on the truth corners), the same for our detector
with ``refine_corners=False`` (the refinement goal compares the two), and CPU: median over
``--real-repeats`` of ``time.process_time`` of the detection call (poses included), OpenCV
on one thread. Tags we miss are listed with the drop reason the detector gave at that
place, if any.
"""

from __future__ import annotations

import json
import time

import cv2
import numpy as np

from .real_photo_truth import (
    abp_detector,
    corner_distance,
    dictionary,
    edge_fit_corners,
    load_gray,
    load_manifest,
    nominal_camera,
    side_px,
)

GOALS = {'recall': 0.95, 'wrong': 0, 'duplicates': 0, 'refine_px': 0.2, 'cpu_total': 1.5,
         'cpu_worst': 3.0}


class PlainOpenCVDict:
    """realistic_suite.PlainOpenCV in another dictionary."""

    def __init__(self, K, dict_name):
        from .realistic_suite import PlainOpenCV
        self.inner = PlainOpenCV(K)
        self.inner.detector = cv2.aruco.ArucoDetector(dictionary(dict_name),
                                                      cv2.aruco.DetectorParameters())

    def detect(self, gray):
        return [(i, q) for i, q, _ in self.inner.detect(gray)]


def _match(tags, tag_id, corners):
    c = np.asarray(corners).reshape(4, 2).mean(axis=0)
    for k, t in enumerate(tags):
        q = np.asarray(t['corners'])
        if t['id'] == tag_id and np.linalg.norm(q.mean(axis=0) - c) < max(3.0, 0.3 * side_px(q)):
            return k
    return None


def duplicates(reports) -> int:
    """Pairs of reports of one id whose centres are closer than the smaller one's side."""
    n = 0
    for a in range(len(reports)):
        for b in range(a + 1, len(reports)):
            (ia, qa), (ib, qb) = reports[a], reports[b]
            if ia == ib and np.linalg.norm(qa.mean(axis=0) - qb.mean(axis=0)) < min(
                    side_px(qa), side_px(qb)):
                n += 1
    return n


def score(entry, refs, reports):
    """Found truth indices, wrong, on-rejected, duplicates, corner errors vs truth / ref."""
    found, wrong, rejected, err_truth, err_ref = set(), 0, 0, [], []
    for tag_id, q in reports:
        k = _match(entry['tags'], tag_id, q)
        if k is None:
            if _match(entry.get('rejected', []), tag_id, q) is not None:
                rejected += 1
            else:
                wrong += 1
            continue
        found.add(k)
        err_truth.append(corner_distance(q, entry['tags'][k]['corners']))
        if refs[k] is not None:
            err_ref.append(corner_distance(q, refs[k]))
    return found, wrong, rejected, duplicates(reports), err_truth, err_ref


def _cpu(fn, repeats):
    times = []
    out = None
    for _ in range(repeats):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return out, float(np.median(times))


def _drop_reason(result, tag_id, q):
    c = q.mean(axis=0)
    for d in result.dropped:
        if d.corners is not None and np.linalg.norm(
                np.asarray(d.corners).reshape(4, 2).mean(axis=0) - c) < 0.3 * side_px(q):
            return f'dropped ({d.tag_id}): {d.reason}'
    return 'not reported'


def run_photo(entry, repeats):
    gray = load_gray(entry)
    name = entry['dictionary']
    ours = abp_detector(name, gray.shape)
    unrefined = abp_detector(name, gray.shape, refine_corners=False)
    plain = PlainOpenCVDict(nominal_camera(gray.shape), name)
    result, cpu_ours = _cpu(lambda: ours.detect(gray), repeats)
    theirs, cpu_cv = _cpu(lambda: plain.detect(gray), repeats)
    mine = [(int(d.tag_id), np.asarray(d.corners, dtype=np.float64).reshape(4, 2))
            for d in result.detections]
    raw = [(int(d.tag_id), np.asarray(d.corners, dtype=np.float64).reshape(4, 2))
           for d in unrefined.detect(gray).detections]
    refs = [edge_fit_corners(gray, t['corners'], dictionary(name).markerSize)[0]
            for t in entry['tags']]
    f_ours, w_ours, r_ours, dup_ours, et_ours, er_ours = score(entry, refs, mine)
    f_cv, w_cv, r_cv, dup_cv, et_cv, er_cv = score(entry, refs, theirs)
    # Refinement: per tag both runs found, refined minus unrefined distance to the reference.
    worse = []
    for tag_id, q in mine:
        k = _match(entry['tags'], tag_id, q)
        if k is None or refs[k] is None:
            continue
        raw_q = [r for i, r in raw if _match(entry['tags'], i, r) == k]
        if raw_q:
            worse.append(corner_distance(q, refs[k]) - corner_distance(raw_q[0], refs[k]))
    missed = [f"{t['id']} ({side_px(t['corners']):.0f} px): "
              f"{_drop_reason(result, t['id'], np.asarray(t['corners']))}"
              for k, t in enumerate(entry['tags']) if k not in f_ours]
    cv_only = sorted(entry['tags'][k]['id'] for k in f_cv - f_ours)
    return {
        'photo': entry['name'], 'dictionary': name, 'size': list(gray.shape[::-1]),
        'truth': len(entry['tags']), 'found_ours': len(f_ours), 'found_opencv': len(f_cv),
        'wrong_ours': w_ours, 'wrong_opencv': w_cv,
        'on_rejected_ours': r_ours, 'on_rejected_opencv': r_cv,
        'duplicates_ours': dup_ours, 'duplicates_opencv': dup_cv,
        'corner_vs_truth_ours': _med(et_ours), 'corner_vs_truth_opencv': _med(et_cv),
        'corner_vs_edge_fit_ours': _med(er_ours), 'corner_vs_edge_fit_opencv': _med(er_cv),
        'refined_minus_unrefined_max': max(worse) if worse else None,
        'refined_worse_than_02': int(sum(w > GOALS['refine_px'] for w in worse)),
        'cpu_ms_ours': 1e3 * cpu_ours, 'cpu_ms_opencv': 1e3 * cpu_cv,
        'cpu_ratio': cpu_ours / max(cpu_cv, 1e-6),
        'face_search': result.face_search, 'missed_ours': missed,
        'opencv_found_ours_missed': cv_only,
    }


def _med(values):
    return float(np.median(values)) if values else None


def totals(rows):
    truth = sum(r['truth'] for r in rows)
    cpu_ours = sum(r['cpu_ms_ours'] for r in rows)
    cpu_cv = sum(r['cpu_ms_opencv'] for r in rows)
    worst = max(rows, key=lambda r: r['cpu_ratio'])
    deltas = [r['refined_minus_unrefined_max'] for r in rows
              if r['refined_minus_unrefined_max'] is not None]
    return {
        'photos': len(rows), 'truth': truth,
        'recall_ours': sum(r['found_ours'] for r in rows) / max(truth, 1),
        'recall_opencv': sum(r['found_opencv'] for r in rows) / max(truth, 1),
        'photos_fewer_than_opencv': [r['photo'] for r in rows
                                     if r['found_ours'] < r['found_opencv']],
        'wrong_ours': sum(r['wrong_ours'] for r in rows),
        'wrong_opencv': sum(r['wrong_opencv'] for r in rows),
        'duplicates_ours': sum(r['duplicates_ours'] for r in rows),
        'duplicates_opencv': sum(r['duplicates_opencv'] for r in rows),
        'refined_worse_than_02': sum(r['refined_worse_than_02'] for r in rows),
        'refined_minus_unrefined_max': max(deltas) if deltas else None,
        'cpu_ms_ours': cpu_ours, 'cpu_ms_opencv': cpu_cv,
        'cpu_ratio_total': cpu_ours / max(cpu_cv, 1e-9),
        'cpu_ratio_median': float(np.median([r['cpu_ratio'] for r in rows])),
        'cpu_ratio_worst': worst['cpu_ratio'], 'cpu_worst_photo': worst['photo'],
    }


def _f(v, fmt='.2f'):
    return '–' if v is None else format(v, fmt)


def photo_table(rows):
    out = ['| photo | dictionary | size | truth | ours / OpenCV found | wrong ours / OpenCV '
           '| duplicates ours / OpenCV | corner vs truth ours / OpenCV (px) '
           '| corner vs edge fit ours / OpenCV (px) | CPU ours / OpenCV (ms) | ratio '
           '| missed by ours |', '|' + '---|' * 12]
    for r in rows:
        flag = ' **(fewer)**' if r['found_ours'] < r['found_opencv'] else ''
        out.append(
            f"| {r['photo']} | {r['dictionary'][5:]} | {r['size'][0]}x{r['size'][1]} "
            f"| {r['truth']} | {r['found_ours']} / {r['found_opencv']}{flag} "
            f"| {r['wrong_ours']} / {r['wrong_opencv']} "
            f"| {r['duplicates_ours']} / {r['duplicates_opencv']} "
            f"| {_f(r['corner_vs_truth_ours'])} / {_f(r['corner_vs_truth_opencv'])} "
            f"| {_f(r['corner_vs_edge_fit_ours'])} / {_f(r['corner_vs_edge_fit_opencv'])} "
            f"| {r['cpu_ms_ours']:.1f} / {r['cpu_ms_opencv']:.1f} | {r['cpu_ratio']:.1f} "
            f"| {'; '.join(r['missed_ours']) or '–'} |")
    return out


def goals_table(t):
    def row(name, goal, value, ok):
        return f"| {name} | {goal} | {value} | {'met' if ok else '**not met**'} |"
    return [
        '| goal (issue 34) | target | today | |', '|---|---|---|---|',
        row('recall over all truth tags', '≥ 95 %',
            f"{100 * t['recall_ours']:.1f} % (OpenCV {100 * t['recall_opencv']:.1f} %)",
            t['recall_ours'] >= GOALS['recall']),
        row('photos with fewer tags than OpenCV', '0',
            f"{len(t['photos_fewer_than_opencv'])}", not t['photos_fewer_than_opencv']),
        row('wrong ids', '0', f"{t['wrong_ours']} (OpenCV {t['wrong_opencv']})",
            t['wrong_ours'] == 0),
        row('duplicate reports', '0', f"{t['duplicates_ours']} (OpenCV "
            f"{t['duplicates_opencv']})", t['duplicates_ours'] == 0),
        row('tags whose refined corners are > 0.2 px farther from the edge fit than the '
            'unrefined', '0', f"{t['refined_worse_than_02']} (max "
            f"{_f(t['refined_minus_unrefined_max'])} px)", t['refined_worse_than_02'] == 0),
        row('CPU total, ours / OpenCV', '≤ 1.5×', f"{t['cpu_ratio_total']:.2f}× "
            f"({t['cpu_ms_ours']:.0f} / {t['cpu_ms_opencv']:.0f} ms; median per photo "
            f"{t['cpu_ratio_median']:.2f}×)", t['cpu_ratio_total'] <= GOALS['cpu_total']),
        row('CPU worst photo', '≤ 3×', f"{t['cpu_ratio_worst']:.1f}× ({t['cpu_worst_photo']})",
            t['cpu_ratio_worst'] <= GOALS['cpu_worst']),
    ]


def run(names=None, repeats=3):
    cv2.setNumThreads(1)
    photos = load_manifest()['photos']
    if names:
        photos = [p for p in photos if any(n in p['name'] for n in names)]
        if not photos:
            raise SystemExit(f'no photo matches {names}')
    rows = [run_photo(p, repeats) for p in photos]
    return rows, totals(rows)


def main(args):
    if args.real_repeats < 1:
        raise SystemExit('--real-repeats must be >= 1')
    rows, tot = run(args.real_photos, args.real_repeats)
    lines = ['## Perception on real photographs (issue 34)', '',
             f"`perception_benchmark --suite real --real-repeats {args.real_repeats}`: "
             f"{tot['photos']} photos, {tot['truth']} tags in the truth "
             '(docs/PERCEPTION_REAL.md).', ''] + goals_table(tot) + [''] + photo_table(rows)
    print('\n'.join(lines))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'photos': rows, 'totals': tot}, f, indent=1)
    if args.update_doc:
        from .perception_scenes import update_doc
        update_doc(args.update_doc, '\n'.join(lines[2:]),
                   heading='Perception on real photographs (issue 34)')
    return 0
