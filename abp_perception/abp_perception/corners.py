"""Sub-pixel marker corners by edge-line fitting, and ArUco bit decoding of a quad.

Plain NumPy + OpenCV, no rclpy.

Why not ``CORNER_REFINE_SUBPIX``: ``cv2.cornerSubPix`` is made for X-shaped
(chessboard) corners. On the L-shaped outer corners of a blurred marker it
settles ~0.25 px inside the square, which shrinks every marker by ~0.5 px and
biases the IPPE depth by ~1 % (10 mm at 1 m, 55 mm at 2 m on the sim bridge's
renders). ``refine_quads`` instead locates each of the four black-to-white
edges: it samples intensity profiles across the edge at 16 points along it (one
``cv2.remap`` for all quads), finds in each the first strong dark -> bright rise out
of the black border and takes the centroid of its gradient, fits a line to those
edge points (weighted least squares with one outlier pass), and intersects adjacent
lines. A first pass with profiles 0.6 cell long on either side recovers contour
corners that are several pixels off (ArUco's polygon often cuts a corner where a dim,
shaded quiet zone meets the floor); a second, narrow pass polishes. A symmetric blur
does not move a straight edge, so the corners are unbiased (median 0.06 px at
0.7-1 m, 0.1 px at 1.5 m, 0.2 px at 2 m on the renders, against 0.3-1 px for SUBPIX).

``decode_quads`` reads the 6 x 6 cell grid of a quad (1-cell black border and
the inner bits) through its homography and identifies it in an ArUco
dictionary without error correction. The detector uses it for a second pass
over the candidates ArUco rejected: small, blurred tags are often rejected
only because their integer-pixel contour corners sample the bits badly.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

__all__ = ['refine_quads', 'keep_better_corners', 'corner_edge_residuals', 'decode_quads',
           'quad_areas', 'inside_any_quad', 'code_table',
           'square_homographies']

# Edge-profile sampling: fractions of each edge, samples across it (wide first pass to
# recover contour corners that are several pixels off, then a narrow pass).
_ALONG = np.linspace(0.15, 0.85, 16)
_ACROSS_WIDE = np.linspace(0.0, 1.0, 33)
_ACROSS_NARROW = np.linspace(0.0, 1.0, 17)
_GRADIENT_FLOOR = 0.25   # fraction of the edge's gradient peak ignored (noise, other edges)
# Profile half-lengths in cells: wide first pass, narrow later passes.
WIDE_INNER, WIDE_OUTER, NARROW = 0.6, 0.6, 0.4
# A rise ends where the gradient falls under this fraction of its peak: separates the
# black -> dim quiet zone rise from a following dim -> bright (neighbouring face) one.
END_FLOOR = 0.5
_NEXT = np.array([1, 2, 3, 0])
_PREV = np.array([3, 0, 1, 2])
_OPPOSITE = np.array([2, 3, 0, 1])


def quad_areas(quads) -> np.ndarray:
    """Signed areas (shoelace, image coordinates: > 0 for clockwise on screen) of (Q, 4, 2)."""
    q = np.asarray(quads, dtype=np.float64)
    nxt = q[:, _NEXT]
    return 0.5 * np.sum(q[..., 0] * nxt[..., 1] - nxt[..., 0] * q[..., 1], axis=1)


def inside_any_quad(points, quads) -> np.ndarray:
    """Whether each point (P, 2) lies inside any convex quad (Q, 4, 2) (either winding)."""
    a = quads[None, :, :, :]                                   # (1, Q, 4, 2)
    b = quads[None, :, [1, 2, 3, 0], :]
    p = points[:, None, None, :]                               # (P, 1, 1, 2)
    cross = (b[..., 0] - a[..., 0]) * (p[..., 1] - a[..., 1]) \
        - (b[..., 1] - a[..., 1]) * (p[..., 0] - a[..., 0])    # (P, Q, 4)
    inside = (cross >= 0).all(axis=2) | (cross <= 0).all(axis=2)
    return inside.any(axis=1)


def _edge_offsets(prof, s):
    """Sub-pixel offset of the marker edge along each profile (inside -> outside).

    The marker edge is the first strong dark -> bright rise after the darkest point of
    the profile (the black border): shaded faces put a second rise further out (a dim
    quiet zone meeting a bright neighbouring face) which must not win. The offset is
    the centroid of the rise's positive gradient above a floor. Returns the offsets and
    the rises' peak gradients (0 where there is none).
    """
    grad = prof[..., 1:] - prof[..., :-1]
    k = np.arange(grad.shape[-1])
    after = k >= np.argmin(prof[..., :-1], axis=-1)[..., None]
    g_after = np.where(after, grad, 0.0)
    gmax = g_after.max(axis=-1, keepdims=True)
    first = np.argmax(g_after >= 0.3 * gmax, axis=-1)[..., None]
    flat = grad.reshape(-1, grad.shape[-1])
    peak = flat[np.arange(flat.shape[0]), first.ravel()].reshape(first.shape)
    # ... and where that rise ends (gradient back under END_FLOOR of its peak).
    below = (k > first) & (grad < END_FLOOR * peak)
    end = np.where(below.any(axis=-1, keepdims=True), np.argmax(below, axis=-1)[..., None],
                   grad.shape[-1])
    gpos = np.where(after & (k < end), np.maximum(grad - _GRADIENT_FLOOR * peak, 0.0), 0.0)
    mass = gpos.sum(axis=-1)
    offset = (gpos @ (0.5 * (s[1:] + s[:-1]))) / np.maximum(mass, 1e-12)
    peak = np.where((mass > 0) & (gmax[..., 0] > 0), peak[..., 0], 0.0)
    return offset, peak


def _line_fit(t, y, w):
    """Weighted least-squares y = a + b t per row of (E, M) arrays."""
    s0 = w.sum(axis=1)
    s1 = w @ t
    s2 = w @ (t * t)
    sy = (w * y).sum(axis=1)
    sty = (w * y) @ t
    den = s0 * s2 - s1 * s1
    ok = den > 1e-12 * np.maximum(s0 * s0, 1e-300)
    b = np.where(ok, s0 * sty - s1 * sy, 0.0) / np.where(ok, den, 1.0)
    a = np.where(ok, sy - b * s1, np.nan) / np.where(ok, s0, 1.0)
    return a, b


def _fit_edges(img, q, sign, first_pass):
    """One refinement pass: new corners (Q, 4, 2) and per-quad validity.

    Each edge is parametrised from its current estimate: points p0 + t d + y n (t along
    the edge, y across it, n outward); the measured edge offsets y(t) are fitted by a
    weighted line y = a + b t (one outlier pass), and adjacent lines are intersected.
    """
    nq = q.shape[0]
    p0 = q.reshape(-1, 2)                                        # (E, 2), E = 4 Q
    d = q[:, _NEXT].reshape(-1, 2) - p0                          # edge k runs c[k] -> c[k+1]
    length = np.sqrt((d * d).sum(axis=1))
    u = d / np.maximum(length, 1e-9)[:, None]
    n = np.repeat(sign, 4)[:, None] * np.stack([u[:, 1], -u[:, 0]], axis=1)   # outward
    # Cell size across this edge (the marker spans 6 cells between opposite edges): the
    # profile reaches into the black border but not past it into the bits.
    mid = (p0 + 0.5 * d).reshape(nq, 4, 2)
    cell = np.abs(((mid - mid[:, _OPPOSITE]).reshape(-1, 2) * n).sum(axis=1)) / 6.0
    if first_pass:
        inner = np.clip(WIDE_INNER * cell, 1.0, 8.0)
        outer = np.clip(WIDE_OUTER * cell, 1.0, 8.0)
        across = _ACROSS_WIDE
    else:
        inner = outer = np.clip(NARROW * cell, 0.8, 2.5)
        across = _ACROSS_NARROW
    ns, m = across.size, _ALONG.size
    span = inner + outer                                         # (E,)
    s_unit = across * 1.0                                        # profile in [0, 1]
    base = p0[:, None, :] + _ALONG[None, :, None] * d[:, None, :]             # (E, M, 2)
    offs = (s_unit[None, :] * span[:, None] - inner[:, None])                  # (E, S)
    map_x = (base[:, :, None, 0] + offs[:, None, :] * n[:, None, None, 0]).astype(np.float32)
    map_y = (base[:, :, None, 1] + offs[:, None, :] * n[:, None, None, 1]).astype(np.float32)
    prof = cv2.remap(img, map_x.reshape(-1, ns), map_y.reshape(-1, ns), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(-1, m, ns)
    unit_offset, peak = _edge_offsets(prof, s_unit)                           # (E, M)
    y = unit_offset * span[:, None] - inner[:, None]
    contrast = prof.max(axis=2) - prof.min(axis=2)
    good = (peak > 2.0) & (peak > 0.3 * peak.mean(axis=1, keepdims=True)) & (contrast > 10.0)
    w = np.where(good, peak, 0.0)
    a, b = _line_fit(_ALONG, y, w)
    resid = np.abs(y - a[:, None] - b[:, None] * _ALONG[None, :])
    rms = np.sqrt((w * resid * resid).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-12))
    keep = good & (resid < np.maximum(0.5, 2.5 * rms)[:, None])
    a, b = _line_fit(_ALONG, y, np.where(keep, peak, 0.0))
    enough = (keep.sum(axis=1) >= 4).reshape(nq, 4).all(axis=1)
    # Line k: origin p0 + a n, direction d + b n. Corner k is where line k-1 meets line k.
    origin = (p0 + a[:, None] * n).reshape(nq, 4, 2)
    direction = (d + b[:, None] * n).reshape(nq, 4, 2)
    ca, da = origin[:, _PREV], direction[:, _PREV]
    cb, db = origin, direction
    det = da[..., 1] * db[..., 0] - da[..., 0] * db[..., 1]
    sin_angle = np.abs(det) / np.maximum(
        np.sqrt((da * da).sum(axis=2) * (db * db).sum(axis=2)), 1e-12)
    crossing = np.isfinite(det) & (sin_angle > 1e-3)
    rhs = cb - ca
    ta = np.where(crossing, rhs[..., 1] * db[..., 0] - rhs[..., 0] * db[..., 1], 0.0) \
        / np.where(crossing, det, 1.0)
    corners = ca + ta[..., None] * da
    finite = np.isfinite(corners).all(axis=(1, 2)) & crossing.all(axis=1)
    corners = np.where(finite[:, None, None], corners, q)
    shift = np.sqrt(((corners - q) ** 2).sum(axis=2)).max(axis=1)
    valid = enough & finite & (shift < np.maximum(2.5, 0.5 * length.reshape(nq, 4).min(axis=1)))
    return corners, valid, shift


def refine_quads(gray, quads, passes: int = 2):
    """Refine marker corners (Q, 4, 2) on a grey image; returns (corners, ok (Q,) bool).

    `passes` >= 2: one wide pass, then narrow ones. A quad whose corners still move by
    more than 2 px after the wide pass (its contour cut a corner badly, as on grazing,
    shaded faces) gets a second wide pass, and one still moving by more than 0.3 px
    after the narrow pass a second narrow one; so ``passes + 2`` at most, the extra
    ones for those quads only. Quads where a fit fails (too few edge points, a corner
    moving more than max(2.5 px, half the shortest edge), parallel edges) keep their
    input corners and ok = False. Corner order is kept; either winding is accepted.
    """
    q = np.array(quads, dtype=np.float64).reshape(-1, 4, 2)
    ok = np.ones(q.shape[0], dtype=bool)
    if q.shape[0] == 0:
        return q, ok
    img = gray if gray.dtype == np.float32 else gray.astype(np.float32)
    sign = np.where(quad_areas(q) >= 0.0, 1.0, -1.0)
    # (wide profiles?, only quads whose corners moved more than this in the last pass)
    schedule = [(True, -1.0), (True, 2.0)]
    schedule += [(False, -1.0)] * max(0, int(passes) - 1) + [(False, 0.3)]
    moved = np.full(q.shape[0], np.inf)
    for wide, retry_above in schedule:
        idx = np.flatnonzero(ok & (moved > retry_above))
        if idx.size == 0:
            continue
        corners, valid, shift = _fit_edges(img, q[idx], sign[idx], first_pass=wide)
        q[idx[valid]] = corners[valid]
        moved[idx] = np.where(valid, shift, 0.0)
        ok[idx[~valid]] = False
    return q, ok


# Edge residual at the corners (``corner_edge_residuals``): profiles across each edge at
# _NEAR_STEPS fractions of it from either end (the first no nearer to the corner than
# 1.5 profile half-lengths), half-length in cells (px bounds).
_NEAR_STEPS = np.arange(4) * 0.04
RESIDUAL_HALF_CELLS, RESIDUAL_HALF_PX = 0.3, (1.5, 6.0)
_ACROSS_RESIDUAL = np.linspace(0.0, 1.0, 25)
# A refined quad is kept unless its residual exceeds the unrefined one's by this, px,
# plus half the unrefined one's (blurred edges measure noisily).
REFINE_TOLERANCE_PX = 0.1
# Only quads at least this large (sqrt of the area, px) are checked: a curved edge's
# offset at the corners grows with the side squared (1-3.4 px at 300-400 px on the
# renders, under 0.1 px at 64 px), and on small tags the contour corners are the worse
# ones (checking them cost recall and accuracy at 1.5-2.5 m on the realistic suite).
CHECK_MIN_SIDE_PX = 64.0


def corner_edge_residuals(gray, quads) -> np.ndarray:
    """(Q,) RMS distance (px) of each quad's corners from the marker's edges measured next
    to them: on each edge, the dark -> bright rise (as the edge fit finds it) at four
    points near each end, fitted by a line and extrapolated to the corner; the offsets
    there from both edges of the four corners. inf where a corner's edge is not found.
    Curved edges (lens distortion, a bent print) leave the lines the edge fit puts
    through the edges' middles off the corners; this measure sees that."""
    q = np.array(quads, dtype=np.float64).reshape(-1, 4, 2)
    if q.shape[0] == 0:
        return np.zeros(0)
    img = gray if gray.dtype == np.float32 else gray.astype(np.float32)
    nq = q.shape[0]
    sign = np.where(quad_areas(q) >= 0.0, 1.0, -1.0)
    p0 = q.reshape(-1, 2)
    d = q[:, _NEXT].reshape(-1, 2) - p0
    length = np.sqrt((d * d).sum(axis=1))
    u = d / np.maximum(length, 1e-9)[:, None]
    n = np.repeat(sign, 4)[:, None] * np.stack([u[:, 1], -u[:, 0]], axis=1)   # outward
    mid = (p0 + 0.5 * d).reshape(nq, 4, 2)
    cell = np.abs(((mid - mid[:, _OPPOSITE]).reshape(-1, 2) * n).sum(axis=1)) / 6.0
    half = np.clip(RESIDUAL_HALF_CELLS * cell, *RESIDUAL_HALF_PX)               # (E,)
    first = np.clip(np.maximum(0.04, 1.5 * half / np.maximum(length, 1e-9)), 0.0, 0.3)
    t_start = first[:, None] + _NEAR_STEPS[None]                                # (E, 4)
    t = np.concatenate([t_start, 1.0 - t_start], axis=1)                        # (E, 8)
    s = _ACROSS_RESIDUAL
    base = p0[:, None, :] + t[:, :, None] * d[:, None, :]                       # (E, 8, 2)
    offs = (2.0 * s[None, :] - 1.0) * half[:, None]                            # (E, S)
    map_x = (base[:, :, None, 0] + offs[:, None, :] * n[:, None, None, 0]).astype(np.float32)
    map_y = (base[:, :, None, 1] + offs[:, None, :] * n[:, None, None, 1]).astype(np.float32)
    m, ns = t.shape[1], s.size
    prof = cv2.remap(img, map_x.reshape(-1, ns), map_y.reshape(-1, ns), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(-1, m, ns)
    unit, peak = _edge_offsets(prof, s)
    y = (2.0 * unit - 1.0) * half[:, None]                                     # px, (E, 8)
    w = np.where(peak > 2.0, 1.0, 0.0)
    # Per edge end: a line y(t) over its four points, at the corner (t = 0 or 1).
    ends = []
    for cols, at in ((slice(0, 4), 0.0), (slice(4, 8), 1.0)):
        tt, yy, ww = t[:, cols] - at, y[:, cols], w[:, cols]
        s0, s1, s2 = ww.sum(axis=1), (ww * tt).sum(axis=1), (ww * tt * tt).sum(axis=1)
        sy, sty = (ww * yy).sum(axis=1), (ww * tt * yy).sum(axis=1)
        den = s0 * s2 - s1 * s1
        good = (s0 >= 3) & (den > 1e-12)
        slope = np.where(good, s0 * sty - s1 * sy, 0.0) / np.where(good, den, 1.0)
        ends.append(np.where(good, (sy - slope * s1) / np.maximum(s0, 1e-12), np.nan))
    off = np.stack(ends, axis=1).reshape(nq, 8)                                # (Q, 8)
    rms = np.sqrt(np.mean(off * off, axis=1))
    return np.where(np.isfinite(rms), rms, np.inf)


def keep_better_corners(gray, refined, unrefined, tolerance=REFINE_TOLERANCE_PX,
                        min_side_px=CHECK_MIN_SIDE_PX):
    """Per quad, the refined corners unless they sit worse on the marker's edges near the
    corners than the unrefined ones (``corner_edge_residuals`` larger by `tolerance` px
    plus half the unrefined one's): the edge fit's straight lines through curved edges
    (a 16-MP phone photo's lens) moved large tags' corners 5-6 px into the black square.
    Quads under `min_side_px` keep their refined corners unchecked. Returns (quads,
    refined kept (Q,) bool)."""
    refined = np.asarray(refined, dtype=np.float64).reshape(-1, 4, 2)
    unrefined = np.asarray(unrefined, dtype=np.float64).reshape(-1, 4, 2)
    if refined.shape[0] == 0:
        return refined.copy(), np.zeros(0, dtype=bool)
    keep = np.ones(refined.shape[0], dtype=bool)
    large = np.flatnonzero(np.sqrt(np.abs(quad_areas(unrefined))) >= min_side_px)
    if large.size:
        res = corner_edge_residuals(gray, np.concatenate([refined[large], unrefined[large]]))
        after, before = res[:large.size], res[large.size:]
        keep[large] = ~(after > before * 1.5 + tolerance)
    return np.where(keep[:, None, None], refined, unrefined), keep


# -- bit decoding --------------------------------------------------------------------------

@lru_cache(maxsize=8)
def _grid_points(cells: int):
    """Sample points in canonical marker coordinates (marker spans [0, cells]^2), in
    homogeneous coordinates (P, 3): the cell samples, then the quiet-zone ring; the
    number of cell samples and of samples per cell. Cached (read-only arrays)."""
    sub = np.array([-0.2, 0.0, 0.2])
    centres = np.stack(np.meshgrid(np.arange(cells) + 0.5, np.arange(cells) + 0.5,
                                   indexing='xy'), axis=-1).reshape(-1, 2)   # row-major (y, x)
    offsets = np.stack(np.meshgrid(sub, sub, indexing='xy'), axis=-1).reshape(-1, 2)
    samples = (centres[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
    ring = []
    for v in np.linspace(0.5, cells - 0.5, cells):
        ring += [[v, -0.4], [v, cells + 0.4], [-0.4, v], [cells + 0.4, v]]
    pts = np.concatenate([samples, np.array(ring)])
    pts = np.concatenate([pts, np.ones((pts.shape[0], 1))], axis=1)
    pts.flags.writeable = False
    return pts, samples.shape[0], offsets.shape[0]


# Packed bits -> (id, rotation) of every marker of a dictionary in its four rotations,
# per dictionary (marker size and codes).
_CODE_TABLES = {}


def _pack_bits(bits) -> np.ndarray:
    """(..., n, n) 0/1 bits as one integer each (row-major, first bit lowest)."""
    flat = np.asarray(bits).reshape(*np.shape(bits)[:-2], -1).astype(np.int64)
    return flat @ (np.int64(1) << np.arange(flat.shape[-1], dtype=np.int64))


def code_table(dictionary) -> dict:
    """{packed bits: (id, rotation)} for every marker of `dictionary` in each of its four
    rotations, so that looking a bit pattern up answers as ``identify(bits, 0.0)`` (no
    error correction; not found: not in the table) without identify's cost (~80 us for a
    pattern it does not find, the common case for rejected candidates). Rotation k is the
    marker's bits turned by ``np.rot90`` k times, in identify's search order (markers,
    then rotations, first match kept); test_corners checks it against identify. Cached
    per dictionary."""
    codes = np.asarray(dictionary.bytesList)
    key = (int(dictionary.markerSize), codes.tobytes())
    table = _CODE_TABLES.get(key)
    if table is None:
        n = int(dictionary.markerSize)
        table = {}
        for marker in range(codes.shape[0]):
            image = dictionary.generateImageMarker(marker, n + 2)      # 1 px per cell
            bits = image[1:-1, 1:-1] > 127
            for turns in range(4):
                table.setdefault(int(_pack_bits(np.rot90(bits, turns))), (marker, turns))
        _CODE_TABLES[key] = table
    return table


def square_homographies(quads, cells: int) -> np.ndarray:
    """(Q, 3, 3) homographies from the canonical square [0, cells]^2 (corners (0, 0),
    (cells, 0), (cells, cells), (0, cells)) to each quad (Q, 4, 2), in one batched solve
    (cv2.getPerspectiveTransform's system). Degenerate quads give non-finite rows."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 2)
    src = np.array([[0, 0], [cells, 0], [cells, cells], [0, cells]], dtype=np.float64)
    n = q.shape[0]
    a = np.zeros((n, 8, 8))
    x, y = src[:, 0], src[:, 1]
    u, v = q[..., 0], q[..., 1]
    a[:, 0::2, 0], a[:, 0::2, 1], a[:, 0::2, 2] = x, y, 1.0
    a[:, 1::2, 3], a[:, 1::2, 4], a[:, 1::2, 5] = x, y, 1.0
    a[:, 0::2, 6], a[:, 0::2, 7] = -x * u, -y * u
    a[:, 1::2, 6], a[:, 1::2, 7] = -x * v, -y * v
    b = q.reshape(n, 8)
    h = np.full((n, 9), np.nan)
    ok = np.abs(np.linalg.det(a)) > 1e-12
    if ok.any():
        h[ok, :8] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
        h[ok, 8] = 1.0
    return h.reshape(n, 3, 3)


def decode_quads(gray, quads, dictionary, border_bits: int = 1, max_border_errors: int = 2,
                 min_contrast: float = 15.0):
    """Identify quads (Q, 4, 2) in `dictionary`; per quad (id, rotation) or None.

    The cell values are means of 3 x 3 samples near each cell centre. The black level is
    the median of the border cells, the white level the median of a ring sampled just
    outside the marker (the white quiet zone); the threshold is their midpoint. A quad
    is refused when the contrast is below `min_contrast` grey levels, more than
    `max_border_errors` border cells are white, or more than a quarter of the quiet zone
    is dark. Bits are identified without error correction. `rotation` is as returned by
    ``Dictionary.identify``: the marker's top-left corner is input corner ``-rotation``
    (i.e. ``np.roll(quad, rotation, axis=0)`` is in ArUco order).
    """
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 2)
    if q.shape[0] == 0:
        return []
    size = int(dictionary.markerSize)
    cells = size + 2 * int(border_bits)
    pts, n_s, per_cell = _grid_points(cells)
    homog = square_homographies(q, cells)
    proj = pts @ homog.transpose(0, 2, 1)                                   # (Q, P, 3)
    with np.errstate(divide='ignore', invalid='ignore'):
        xy = (proj[..., :2] / proj[..., 2:3]).astype(np.float32)
    xy = np.nan_to_num(xy, nan=-1e4, posinf=-1e4, neginf=-1e4)
    vals = cv2.remap(gray, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(np.float64)
    cell_vals = vals[:, :n_s].reshape(q.shape[0], cells * cells, per_cell).mean(axis=2)
    cell_vals = cell_vals.reshape(q.shape[0], cells, cells)
    ring_vals = vals[:, n_s:]
    border = np.ones((cells, cells), dtype=bool)
    b = int(border_bits)
    border[b:cells - b, b:cells - b] = False
    # Every quad's levels and checks at once; only the survivors are identified.
    black = np.median(cell_vals[:, border], axis=1)
    white = np.median(ring_vals, axis=1)
    thr = 0.5 * (black + white)
    ok = (white - black >= min_contrast) \
        & ((cell_vals[:, border] > thr[:, None]).sum(axis=1) <= max_border_errors) \
        & ((ring_vals < thr[:, None]).sum(axis=1) <= ring_vals.shape[1] // 4)
    bits = cell_vals[:, b:cells - b, b:cells - b] > thr[:, None, None]
    table = code_table(dictionary)
    packed = _pack_bits(bits)
    return [table.get(int(packed[k])) if ok[k] else None for k in range(q.shape[0])]
