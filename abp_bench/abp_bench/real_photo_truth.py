"""Ground truth of the real-photo suite (``real_photos/manifest.json``) and the geometry the
suite shares with it: reading a tag's bits at given corners and an edge-fit corner reference.

    python -m abp_bench.real_photo_truth [--write] [--draw /tmp/truth_png] [--only NAME ...]

Truth per photo = the union of three detectors on the committed file (grey):

- plain OpenCV: ``cv2.aruco.ArucoDetector`` with default ``DetectorParameters``;
- relaxed OpenCV: threshold windows 3-53 px in steps of 4, minimum marker perimeter rate
  0.01, ``CORNER_REFINE_SUBPIX``; on the image and on the image scaled 2x (tiny tags);
- abp: ``abp_perception.detector.TagDetector`` with its defaults (as the suite runs it);
- where the source repository ships the detections of its own detector with the photo
  (AprilRobotics/apriltag's test data), those too (``reference_lines``), first.

Reports of one id whose centres are closer than 0.3 of the tag's side are one tag. Its
corners are the relaxed OpenCV ones where it found the tag (sub-pixel), else plain OpenCV's,
else abp's. Every union tag is then checked by re-reading its bits at those corners
(``read_bits``: perspective warp, Otsu threshold, the centre of each cell): the black
border and the id's code in the dictionary's canonical rotation must match with at most
``MAX_TRUTH_BIT_ERRORS`` wrong cells. Tags that fail are listed as doubtful and stay out of
the truth unless a person looked at them (``--draw`` writes the photos with the tags drawn;
``EYE_CHECKED`` lists what was accepted or rejected by eye, with the reason).
"""

from __future__ import annotations

import argparse
import json
import os

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
PHOTO_DIR = os.path.join(HERE, 'real_photos')
MANIFEST = os.path.join(PHOTO_DIR, 'manifest.json')
# A union tag becomes truth when its re-read code differs from its id's in at most this
# many cells (JPEG and blur flip a cell now and then); see bits_agree for the border.
MAX_TRUTH_BIT_ERRORS = 1
# Photos x tags settled by eye: (photo, id) -> (accepted, why).
EYE_CHECKED: dict = {}


def accepted_by_eye_rule(photo, found_by) -> bool:
    """The doubtful tags of the swatbotics photos (printed 36h11 sheets, 320x240 webcam and
    dim phone photos) that plain OpenCV and at least two other detectors report: looked at
    (crops with the quad drawn), each quad sits on a clear tag whose id fits its
    neighbours; our bit reader misreads them (3-px cells, blur, lens distortion)."""
    return photo.startswith('swat_') and 'opencv' in found_by and len(found_by) >= 3


def load_manifest(path=MANIFEST) -> dict:
    with open(path) as f:
        return json.load(f)


def load_gray(entry, photo_dir=PHOTO_DIR) -> np.ndarray:
    img = cv2.imread(os.path.join(photo_dir, entry['file']), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"cannot read {entry['file']} in {photo_dir}")
    return img


def dictionary(name):
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


# -- geometry shared with the suite ------------------------------------------------------------

def side_px(corners) -> float:
    """Apparent side: square root of the quad's area (px)."""
    q = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    x, y = q[:, 0], q[:, 1]
    return float(np.sqrt(abs(0.5 * (x @ np.roll(y, -1) - y @ np.roll(x, -1)))))


def read_bits(gray, corners, marker_size, cell_px=12):
    """(cells, border_errors) at `corners` (ArUco order): the (marker_size x marker_size)
    inner cells (1 = white) and how many of the border cells are not black."""
    n = marker_size + 2
    size = n * cell_px
    dst = np.float32([[0, 0], [size, 0], [size, size], [0, size]])
    h = cv2.getPerspectiveTransform(np.float32(np.asarray(corners).reshape(4, 2)), dst)
    patch = cv2.warpPerspective(gray, h, (size, size), flags=cv2.INTER_LINEAR)
    lo, hi = cell_px // 4, cell_px - cell_px // 4
    means = patch.reshape(n, cell_px, n, cell_px)[:, lo:hi, :, lo:hi].mean(axis=(1, 3))
    thr, _ = cv2.threshold(means.astype(np.uint8), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    cells = (means > thr).astype(np.uint8)
    border = np.ones_like(cells, dtype=bool)
    border[1:-1, 1:-1] = False
    return cells[1:-1, 1:-1], int(cells[border].sum())


def bit_errors(gray, corners, dict_obj, tag_id):
    """(code, border): wrong cells of `tag_id`'s code in its canonical rotation and border
    cells that are not black, read at `corners`."""
    bits, border = read_bits(gray, corners, dict_obj.markerSize)
    return int(dict_obj.getDistanceToId(bits, int(tag_id), False)), border


def bits_agree(errors, marker_size) -> bool:
    """A tag's re-read cells confirm it: code within MAX_TRUTH_BIT_ERRORS and at most 15 %
    of the border cells read white (blur of the white quiet zone on tags of a few px per
    cell greys the outer border cells)."""
    code, border = errors
    return code <= MAX_TRUTH_BIT_ERRORS and border <= 0.15 * 4 * (marker_size + 1)


def _edge_points(gray_f, a, b, cell, samples=24):
    """Sub-pixel points of the dark-to-bright edge along side a->b (inside on the right of
    a->b in image coordinates for ArUco's clockwise order): the mid-level crossing of the
    intensity profile along the normal, within 0.6 cell of the side."""
    d = b - a
    length = np.linalg.norm(d)
    if length < 4:
        return np.empty((0, 2))
    t = d / length
    normal = np.array([-t[1], t[0]])              # points to the inside for clockwise quads
    reach = max(1.5, 0.6 * cell)
    offsets = np.arange(-reach, reach + 1e-9, 0.25)
    s = np.linspace(0.15, 0.85, samples)
    base = a[None, :] + s[:, None] * d[None, :]
    pts = base[:, None, :] + offsets[None, :, None] * normal[None, None, :]
    prof = cv2.remap(gray_f, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = []
    half = len(offsets) // 2
    for k in range(samples):
        p = prof[k]
        outside, inside = p[:half].max(), p[half + 1:].min()
        if outside - inside < 20:                 # no edge here (occluded, glare)
            continue
        mid = 0.5 * (outside + inside)
        above = p > mid
        flips = np.nonzero(above[:-1] & ~above[1:])[0]
        if len(flips) == 0:
            continue
        j = flips[np.argmin(np.abs(flips - half))]
        frac = (p[j] - mid) / (p[j] - p[j + 1])
        out.append(base[k] + (offsets[j] + frac * 0.25) * normal)
    return np.array(out).reshape(-1, 2)


def turn(a, b):
    """z of the cross product of two image vectors (np.cross of 2-vectors is deprecated)."""
    return a[0] * b[1] - a[1] * b[0]


def edge_fit_corners(gray, corners, marker_size):
    """(corners, rms_px) of the tag's outer edge: each side's sub-pixel edge points fitted
    by a line (total least squares), adjacent lines intersected; None where a side has too
    few points. An estimate independent of either detector's corner method."""
    q = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    if turn(q[1] - q[0], q[2] - q[1]) < 0:    # keep the inside on the normal's side
        return None, None
    gray_f = gray.astype(np.float32)
    cell = side_px(q) / (marker_size + 2)
    lines, resid = [], []
    for i in range(4):
        pts = _edge_points(gray_f, q[i], q[(i + 1) % 4], cell)
        if len(pts) < 6:
            return None, None
        c = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c)
        n = vt[1]
        lines.append((n, float(n @ c)))
        resid.append((pts - c) @ n)
    out = np.zeros((4, 2))
    for i in range(4):
        (n1, c1), (n2, c2) = lines[i - 1], lines[i]
        m = np.array([n1, n2])
        if abs(np.linalg.det(m)) < 1e-6:
            return None, None
        out[i] = np.linalg.solve(m, [c1, c2])
    if np.abs(out - q).max() > max(3.0, 0.5 * cell):
        return None, None                         # the fit locked onto another edge
    return out, float(np.sqrt(np.mean(np.concatenate(resid) ** 2)))


def corner_distance(a, b) -> float:
    """Mean distance (px) between corresponding corners."""
    return float(np.linalg.norm(np.asarray(a).reshape(4, 2) - np.asarray(b).reshape(4, 2),
                                axis=1).mean())


# -- the union of detectors --------------------------------------------------------------------

def relaxed_parameters():
    p = cv2.aruco.DetectorParameters()
    p.adaptiveThreshWinSizeMin, p.adaptiveThreshWinSizeMax = 3, 53
    p.adaptiveThreshWinSizeStep = 4
    p.minMarkerPerimeterRate = 0.01
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return p


def opencv_reports(gray, dict_name, params=None, scale=1.0):
    """[(id, corners (4, 2))] of cv2.aruco.ArucoDetector (on the image scaled by `scale`)."""
    det = cv2.aruco.ArucoDetector(dictionary(dict_name), params or cv2.aruco.DetectorParameters())
    img = gray if scale == 1.0 else cv2.resize(gray, None, fx=scale, fy=scale,
                                               interpolation=cv2.INTER_CUBIC)
    corners, ids, _ = det.detectMarkers(img)
    if ids is None:
        return []
    return [(int(i), (np.asarray(c).reshape(4, 2) + 0.5) / scale - 0.5)
            for c, i in zip(corners, ids.ravel())]


def nominal_camera(shape) -> np.ndarray:
    """Camera matrix for a photo of unknown calibration: focal = the larger side (a ~53 deg
    field of view), principal point at the centre."""
    h, w = shape
    f = float(max(w, h))
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])


def abp_detector(dict_name, shape, **options):
    """abp's TagDetector for a photo (defaults unless `options` say otherwise)."""
    from abp_perception.detector import TagDetector
    h, w = shape
    return TagDetector(nominal_camera(shape), dictionary=dict_name, image_size=(w, h),
                       **options)


def abp_reports(gray, dict_name, detector=None):
    det = detector or abp_detector(dict_name, gray.shape)
    return [(int(d.tag_id), np.asarray(d.corners, dtype=np.float64).reshape(4, 2))
            for d in det.detect(gray).detections]


def union_tags(sources):
    """{source: [(id, corners)]} -> [{'id', 'corners', 'found_by'}], corners from the first
    source (in dict order) that found the tag."""
    tags = []
    for src, reports in sources.items():
        for tag_id, q in reports:
            c = q.mean(axis=0)
            hit = [t for t in tags if t['id'] == tag_id and np.linalg.norm(
                np.asarray(t['corners']).mean(axis=0) - c) < 0.3 * side_px(t['corners'])]
            if hit:
                if src not in hit[0]['found_by']:
                    hit[0]['found_by'].append(src)
                continue
            tags.append({'id': tag_id, 'corners': q, 'found_by': [src]})
    return tags


def reference_reports(gray, entry, dict_obj):
    """The detections a photo's source repository ships with it (``entry['reference']``:
    'apriltag_txt' = AprilRobotics/apriltag's test/data/*.txt, `id, (x y) x4` per line, in
    AprilTag's corner order), each put in the corner order whose bits read best."""
    out = []
    for line in entry.get('reference_lines', []):
        tag_id, rest = line.split(',', 1)
        q = np.array([float(v) for v in rest.replace('(', ' ').replace(')', ' ')
                      .replace(',', ' ').split()]).reshape(4, 2)
        orders = [np.roll(q, k, axis=0) for k in range(4)]
        orders += [np.roll(q[::-1], k, axis=0) for k in range(4)]
        best = min(orders, key=lambda o: sum(bit_errors(gray, o, dict_obj, int(tag_id))))
        out.append((int(tag_id), best))
    return out


def build_truth(entry):
    gray = load_gray(entry)
    name = entry['dictionary']
    relaxed = relaxed_parameters()
    sources = {
        'source_reference': reference_reports(gray, entry, dictionary(name)),
        'opencv_relaxed': opencv_reports(gray, name, relaxed),
        'opencv_relaxed_2x': opencv_reports(gray, name, relaxed, scale=2.0),
        'opencv': opencv_reports(gray, name),
        'abp': abp_reports(gray, name),
    }
    d = dictionary(name)
    accepted, doubtful = [], []
    for t in union_tags(sources):
        errors = bit_errors(gray, t['corners'], d, t['id'])
        t['bit_errors'] = list(errors)
        eye = EYE_CHECKED.get((entry['name'], t['id']))
        # The source's own detector (AprilTag's, with its own Hamming check) is trusted.
        # A tag three detectors report is kept when its code reads within half the
        # dictionary's correction bits, whatever the border (oblique faces, 3-px cells).
        ok = eye[0] if eye else (accepted_by_eye_rule(entry['name'], t['found_by'])
                                 or 'source_reference' in t['found_by']
                                 or bits_agree(errors, d.markerSize)
                                 or (len(t['found_by']) >= 3
                                     and errors[0] <= max(1, d.maxCorrectionBits // 2)))
        (accepted if ok else doubtful).append(t)
    return gray, accepted, doubtful


def draw(gray, accepted, doubtful, path):
    img = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    for tags, colour in ((accepted, (0, 200, 0)), (doubtful, (0, 0, 255))):
        for t in tags:
            q = np.asarray(t['corners']).reshape(4, 2)
            cv2.polylines(img, [np.round(q).astype(np.int32)], True, colour, 1)
            cv2.circle(img, tuple(int(v) for v in np.round(q[0])), 3, colour, -1)
            cv2.putText(img, str(t['id']), tuple(int(v) for v in q.mean(axis=0)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1)
    cv2.imwrite(path, img)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--write', action='store_true', help='store the truth in the manifest')
    parser.add_argument('--draw', default=None, help='directory for PNGs with the tags drawn')
    parser.add_argument('--only', nargs='+', metavar='NAME',
                        help='redo only the photos whose name contains one of these')
    args = parser.parse_args(argv)
    manifest = load_manifest()
    for entry in manifest['photos']:
        if args.only and not any(n in entry['name'] for n in args.only):
            continue
        gray, accepted, doubtful = build_truth(entry)
        print(f"{entry['name']:40s} {entry['dictionary']:22s} truth {len(accepted):3d} "
              f"doubtful {[(t['id'], t['bit_errors'], t['found_by']) for t in doubtful]}")
        entry['tags'] = [{'id': t['id'], 'corners': np.round(t['corners'], 3).tolist(),
                          'found_by': t['found_by'], 'bit_errors': t['bit_errors']}
                         for t in sorted(accepted, key=lambda t: t['id'])]
        entry['rejected'] = [{'id': t['id'], 'corners': np.round(t['corners'], 3).tolist(),
                              'found_by': t['found_by'], 'bit_errors': t['bit_errors']}
                             for t in doubtful]
        if args.draw:
            os.makedirs(args.draw, exist_ok=True)
            draw(gray, accepted, doubtful, os.path.join(args.draw, entry['name'] + '.png'))
    if args.write:
        with open(MANIFEST, 'w') as f:
            json.dump(manifest, f, indent=1)
            f.write('\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
