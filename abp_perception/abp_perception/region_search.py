"""Where to look for tags in the next frame, and the last frame's tags found again (plain
NumPy + OpenCV, no rclpy): the detector's region search and tracking.

Region search (``RegionSearch``): ArUco searches the whole image every few frames and,
between those, only ``search_region`` of the last frame's tags (``clip_regions``: boxes
clipped to the image, overlapping ones merged).

Tracking (``TagDetector.track``; ``RegionSearch`` between full-frame passes): the last
frame's tags are followed instead of searched for: corners moved by Lucas-Kanade optical
flow (``flow_quads``), refined by the edge fit, decoded again under their own id (bits,
or the face search's blurred-code correlation: ``reread_quads``), then the detector's
face search and rigid-cube fit. No ArUco pass; ``RegionSearch`` falls back to ArUco in
the region when a tag ArUco had found is lost (``Detection.source``, ``lost_tags``).
"""

from __future__ import annotations

import collections

import cv2
import numpy as np

from .blur_decode import decode_blurred
from .corners import decode_quads, quad_areas, refine_quads
from .tag_pose import DetectionResult

__all__ = ['SEARCH_KINDS', 'RegionSearch', 'clip_regions', 'flow_quads', 'lost_tags',
           'reread_quads', 'search_region']


def clip_regions(roi, shape):
    """`roi` (one (x0, y0, x1, y1) px box or a sequence of them) as a list of int boxes
    clipped to an image of `shape` (rows, cols), overlapping boxes merged into their
    bounding box (so no pixel is searched twice); None for None or when a box covers the
    whole image. Raises ValueError for boxes that are not four finite numbers or when no
    box has a pixel in the image."""
    if roi is None:
        return None
    h, w = int(shape[0]), int(shape[1])
    try:
        arr = np.asarray(roi, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or not (arr.shape == (4,) or (arr.ndim == 2 and arr.shape[1] == 4)):
        raise ValueError(f'roi must be (x0, y0, x1, y1) px or a list of them, got {roi!r}')
    if not np.isfinite(arr).all():
        raise ValueError(f'roi must be finite, got {roi!r}')
    lo = np.clip(np.floor(arr.reshape(-1, 4)[:, :2]), 0, (w, h)).astype(int)
    hi = np.clip(np.ceil(arr.reshape(-1, 4)[:, 2:]), 0, (w, h)).astype(int)
    boxes = [(int(a[0]), int(a[1]), int(b[0]), int(b[1])) for a, b in zip(lo, hi)
             if b[0] > a[0] and b[1] > a[1]]
    if not boxes:
        raise ValueError(f'roi {roi!r} has no pixel in the {w}x{h} image')
    merged = True
    while merged:                        # union of overlapping boxes until none overlap
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]),
                                max(a[3], b[3]))
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    if any(box == (0, 0, w, h) for box in boxes):
        return None
    return sorted(boxes)


def search_region(detections, shape, margin=1.5, min_margin_px=24.0):
    """The regions (list of (x0, y0, x1, y1) px) to search next frame for the tags of
    `detections`: each tag's corner bounding box grown by `margin` times its larger side
    plus `min_margin_px` on each side (room for its cube's other faces, ~1.25 tag sides
    away, and for motion), clipped to an image of `shape`, overlapping ones merged
    (``clip_regions``); None when there is no detection (search it all)."""
    boxes = []
    for det in detections:
        pts = np.asarray(det.corners, dtype=np.float64).reshape(-1, 2)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        grow = float(margin) * float((hi - lo).max()) + float(min_margin_px)
        boxes.append((lo[0] - grow, lo[1] - grow, hi[0] + grow, hi[1] + grow))
    return clip_regions(boxes, shape) if boxes else None


# How RegionSearch searched a frame: ArUco on the whole image, ArUco in the region around
# the last tags, or the last tags followed (TagDetector.track).
SEARCH_KINDS = ('whole image', 'region', 'tracked')


class RegionSearch:
    """Search where the tags were. Every `full_frame_every`-th frame (the first one
    included), after a frame with no detection and after the detector changed (a new
    camera), ArUco searches the whole image. On the frames between, with `track` on,
    the last frame's tags are first looked for where they were (``TagDetector.track``:
    no ArUco pass, a fraction of its cost on a still or slowly moving camera); when
    every one of them is found again (those the face search found last frame: or lost
    to it again) that is the frame's result, otherwise (or with `track` off) ArUco
    searches ``search_region`` of the last frame's detections.
    `full_frame_every` 1: always the whole image. A tag that comes into view away from
    the found tags' cubes waits for the next full-frame pass.

    >>> search = RegionSearch(full_frame_every=5)
    >>> result = search.detect(detector, gray)     # DetectionResult; result.roi: searched
    """

    def __init__(self, full_frame_every: int = 5, margin: float = 1.5,
                 min_margin_px: float = 24.0, track: bool = True):
        if int(full_frame_every) < 1:
            raise ValueError(f'full_frame_every must be >= 1, got {full_frame_every}')
        if not (np.isfinite(margin) and margin >= 0 and np.isfinite(min_margin_px)
                and min_margin_px >= 0):
            raise ValueError(f'margin and min_margin_px must be >= 0, got {margin}, '
                             f'{min_margin_px}')
        self.full_frame_every = int(full_frame_every)
        self.margin, self.min_margin_px = float(margin), float(min_margin_px)
        self.track = bool(track)
        # Frames since construction by how they were searched (SEARCH_KINDS).
        self.frames = dict.fromkeys(SEARCH_KINDS, 0)
        self.reset()

    def reset(self):
        """Search the whole image next frame."""
        self._region, self._since_full, self._detector = None, 0, None
        self._previous, self._gray = [], None

    def detect(self, detector, gray) -> DetectionResult:
        """``detector.detect`` of `gray` in the region (or the whole image) due, or the
        last frame's tags found again (``detector.track``)."""
        if detector is not self._detector or (
                self._gray is not None and np.shape(gray) != self._gray.shape):
            self.reset()                 # a new camera, or a new image size
            self._detector = detector
        due = self._region is None or self._since_full >= self.full_frame_every - 1
        result = None
        if not due and self.track and self._previous:
            tracked, lost = detector.track(gray, self._previous, roi=self._region,
                                           previous_gray=self._gray)
            # A lost face-search tag was looked for again by track's own face search,
            # as ArUco's pass in the region would; a lost ArUco tag needs that pass.
            if all(det.source == 'face_search' for det in lost):
                result = tracked
        if result is None:
            result = detector.detect(gray, roi=None if due else self._region)
            kind = 'whole image' if result.roi is None else 'region'
        else:
            kind = 'tracked'
        self.frames[kind] += 1
        self._since_full = 0 if result.roi is None else self._since_full + 1
        self._previous = list(result.detections)
        # A copy: the caller may reuse its image buffer.
        self._gray = np.array(gray, dtype=np.uint8) if self.track else None
        self._region = search_region(result.detections, np.shape(gray), self.margin,
                                     self.min_margin_px)
        return result


def flow_quads(before, after, quads):
    """`quads` (Q, 4, 2) of image `before` moved to image `after` by pyramidal
    Lucas-Kanade flow of their corners; a quad keeps its corners where the flow of
    one of them failed or moved them apart (by over a third of the quad's side)."""
    pts = quads.reshape(-1, 1, 2).astype(np.float32)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        before, after, pts, None, winSize=(15, 15), maxLevel=2,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
    if moved is None:
        return quads
    moved = moved.reshape(-1, 4, 2).astype(np.float64)
    shift = moved - quads
    spread = np.linalg.norm(shift - shift.mean(axis=1, keepdims=True), axis=2).max(axis=1)
    good = status.reshape(-1, 4).all(axis=1) & np.isfinite(moved).all(axis=(1, 2)) \
        & (spread < np.sqrt(np.abs(quad_areas(quads))) / 3.0)
    out = quads.copy()
    out[good] = moved[good]
    return out


def reread_quads(gray, quads, ids, dictionary, blur_decode=True, budget=None) -> dict:
    """{k: quad (4, 2) in ArUco order} of the tags `ids[k]` read again at `quads` (Q, 4, 2)
    of `gray`: refined by the edge fit and decoded by bits or else (`blur_decode`) by
    blurred-code correlation (within `budget`, a ``blur_decode.DecodeBudget`` or None);
    a quad counts only when it reads as its own id."""
    refined, ok = refine_quads(gray, quads)
    found = {}
    for k, res in enumerate(decode_quads(gray, refined, dictionary)):
        if ok[k] and res is not None and res[0] == ids[k]:
            found[k] = np.roll(refined[k], res[1], axis=0)
    unread = [k for k in range(len(ids)) if k not in found]
    if blur_decode and unread:
        # ArUco order is clockwise on screen, as decode_blurred wants it.
        for k, res in zip(unread, decode_blurred(gray, refined[unread], dictionary,
                                                 budget=budget)):
            if res is not None and res[0] == ids[k]:
                found[k] = np.roll(refined[k], res[1], axis=0)
    return found


def lost_tags(previous, detections) -> list:
    """The detections of `previous` whose id none of `detections` claims (one each)."""
    unclaimed = collections.Counter(d.tag_id for d in detections)
    lost = []
    for det in previous:
        if unclaimed[det.tag_id] > 0:
            unclaimed[det.tag_id] -= 1
        else:
            lost.append(det)
    return lost
