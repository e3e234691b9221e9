"""Decoding a blurred marker by correlation with blurred renderings of every code.

Plain NumPy + OpenCV, no rclpy.

Under motion blur of 3-8 px on cells of 4-6 px the cell means of a marker are mixed with
their neighbours', so thresholding them (``corners.decode_quads``) reads wrong bits even
where the quad is right. ``decode_blurred`` instead predicts what each marker of the
dictionary, in each of its four rotations, would look like at the quad after a blur, and
takes the one that correlates best with the image.

Model: the sharp marker is 0 on black cells and 1 on white cells and in the quiet zone
around it; the image is ``a + b * (kernel * sharp)`` with an unknown gain and offset. For
a kernel given as taps (offsets ``u_j`` px, weights ``w_j``) the image value at a sample
point ``s`` is ``sum_j w_j sharp(H^-1(s - u_j))`` (``H``: the quad's homography), i.e.
linear in the 36 cell values plus the quiet zone: ``A_k`` (samples x 37) per kernel, and
a code ``x`` (37) predicts ``A_k x``. The normalised correlation of the samples ``v`` with
``A_k x`` needs only ``A_k^T v`` and the Gram matrix ``A_k^T A_k`` (both centred over the
samples), so every code and every kernel is scored with small matrix products.

Kernels: no blur, discs of radius 1.5 and 3 px (defocus, JPEG smoothing) and linear
motion of 3-9 px in 8 directions. ``darkness`` screens quads first (a marker, however
blurred, is darker inside than its quiet zone), so quads where no marker is cost ~0.2 ms,
the others ~4 ms. A quad is accepted only when its best code correlates
at least ``min_corr`` and the best code of any *other* id leaves at least
``margin`` times its residual (1 - corr), and the fitted contrast ``b`` is at least
``min_contrast`` grey levels: a blurred non-marker rarely fits one code much better than
all the others.
"""

from __future__ import annotations

import time
from functools import lru_cache

import cv2
import numpy as np

from .corners import square_homographies

__all__ = ['DecodeBudget', 'quad_seconds', 'decode_blurred', 'blur_kernels', 'code_matrix',
           'darkness', 'marker_contrast']

# Canonical sample grid (marker spans [0, cells]); a little of the quiet zone included.
_SAMPLES_PER_AXIS = 14
_SAMPLE_PAD = 0.3          # cells outside the marker
MIN_CORR = 0.85
MARGIN = 2.0
MIN_CONTRAST = 20.0
# Pre-screen: a marker, however blurred, is darker inside (mean) than its quiet zone
# (the lower quartile of a ring 0.4 cells outside) by at least this many grey levels;
# most quads predicted where no marker is fail it, and cost no correlation.
MIN_DARKNESS = 10.0


@lru_cache(maxsize=4)
def blur_kernels(lengths=(3, 5, 7, 9), angles=8, discs=(1.5, 3.0)):
    """All kernels' taps, flat: offsets (T, 2) px, weights (T,) (each kernel's sum to 1)
    and kernel index (T,), and the number of kernels K: the identity, discs of the given
    radii and linear motion of each length in `angles` directions over 180 deg."""
    kernels = [np.zeros((1, 2))]
    for r in discs:
        g = np.arange(-np.ceil(r), np.ceil(r) + 1)
        xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
        kernels.append(xy[(xy ** 2).sum(axis=1) <= r * r + 1e-9])
    for length in lengths:
        t = np.linspace(-(length - 1) / 2.0, (length - 1) / 2.0, int(length))
        for k in range(int(angles)):
            a = np.pi * k / angles
            kernels.append(t[:, None] * np.array([np.cos(a), np.sin(a)])[None])
    off = np.concatenate(kernels)
    w = np.concatenate([np.full(k.shape[0], 1.0 / k.shape[0]) for k in kernels])
    kid = np.concatenate([np.full(k.shape[0], i) for i, k in enumerate(kernels)])
    for arr in (off, w, kid):
        arr.flags.writeable = False
    return off, w, kid, len(kernels)


_CODE_MATRICES = {}


def code_matrix(dictionary):
    """(M, 37) cell values (black 0, white 1; 6 x 6 cells row-major, then the quiet zone,
    1) of every marker in each of its 4 rotations, and the (M,) ids and rotations, in the
    same rotation convention as ``corners.code_table``. Cached per dictionary."""
    codes = np.asarray(dictionary.bytesList)
    key = (int(dictionary.markerSize), codes.tobytes())
    out = _CODE_MATRICES.get(key)
    if out is None:
        n = int(dictionary.markerSize)
        rows, ids, rots = [], [], []
        for marker in range(codes.shape[0]):
            image = dictionary.generateImageMarker(marker, n + 2) > 127   # 1 px a cell
            for turns in range(4):
                rows.append(np.append(np.rot90(image, turns).ravel(), 1.0))
                ids.append(marker)
                rots.append(turns)
        out = (np.array(rows, dtype=np.float64), np.array(ids), np.array(rots))
        for a in out:
            a.flags.writeable = False
        _CODE_MATRICES[key] = out
    return out


def _design(h_inv, samples, kernels, cells):
    """(K, N, cells^2 + 1) blurred cell indicators at image `samples` (N, 2)."""
    off, w, kid, k = kernels
    n = samples.shape[0]
    px = samples[:, None, 0] - off[None, :, 0]                            # (N, T)
    py = samples[:, None, 1] - off[None, :, 1]
    with np.errstate(divide='ignore', invalid='ignore'):
        den = 1.0 / (h_inv[2, 0] * px + h_inv[2, 1] * py + h_inv[2, 2])
        cx = (h_inv[0, 0] * px + h_inv[0, 1] * py + h_inv[0, 2]) * den
        cy = (h_inv[1, 0] * px + h_inv[1, 1] * py + h_inv[1, 2]) * den
    inside = (cx >= 0) & (cx < cells) & (cy >= 0) & (cy < cells)       # NaN: outside
    idx = np.where(inside, np.floor(np.where(inside, cy, 0)).astype(np.int64) * cells
                   + np.floor(np.where(inside, cx, 0)).astype(np.int64), cells * cells)
    c1 = cells * cells + 1
    flat = (kid[None, :] * n + np.arange(n)[:, None]) * c1 + idx
    weights = np.broadcast_to(w[None, :], idx.shape)
    return np.bincount(flat.ravel(), weights.ravel(), minlength=k * n * c1).reshape(k, n, c1)


@lru_cache(maxsize=4)
def _screen_points(cells: int):
    """Canonical points: cell centres (cells^2, 2, row-major), then a ring 0.4 cells
    outside; and a mask of the border cells among the centres."""
    g = np.arange(cells) + 0.5
    inner = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    lo, hi = np.full(cells, -0.4), np.full(cells, cells + 0.4)
    ring = np.concatenate([np.stack(p, axis=1) for p in ((g, lo), (g, hi), (lo, g), (hi, g))])
    pts = np.concatenate([inner, ring])
    ij = np.floor(inner).astype(int)
    border = (ij == 0).any(axis=1) | (ij == cells - 1).any(axis=1)
    for a in (pts, border):
        a.flags.writeable = False
    return pts, inner.shape[0], border


def _cell_samples(gray, quads, cells: int) -> np.ndarray:
    """(Q, cells^2 + 4 cells) grey values at ``_screen_points`` of each quad."""
    pts, _, _ = _screen_points(cells)
    h = square_homographies(quads, cells)
    w = h[:, None, :, 2] + pts @ h[:, :, :2].transpose(0, 2, 1)       # (Q, P, 3)
    with np.errstate(divide='ignore', invalid='ignore'):
        xy = w[..., :2] / w[..., 2:]
    xy = np.where(np.isfinite(xy), xy, -1e4).astype(np.float32)
    return cv2.remap(gray, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


def darkness(gray, quads, cells: int) -> np.ndarray:
    """(Q,) lower quartile of the quiet-zone ring minus the mean inside, grey levels."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 2)
    if q.shape[0] == 0:
        return np.zeros(0)
    v = _cell_samples(gray, q, cells)
    n_in = cells * cells
    return np.quantile(v[:, n_in:], 0.25, axis=1) - v[:, :n_in].mean(axis=1)


def marker_contrast(gray, quads, cells: int):
    """Per quad (Q, 4, 2): (border, bits) contrasts, grey levels, at the cell centres.
    `border`: the lower quartile of the quiet-zone ring (0.4 cells outside) minus the
    median of the border cells (a marker's black frame: high); `bits`: the 90th minus
    the 10th percentile of the inner cells (a code has black and white cells: high; a
    dark blob or a square of texture is mostly uniform inside)."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 2)
    if q.shape[0] == 0:
        return np.zeros(0), np.zeros(0)
    _, n_in, border = _screen_points(cells)
    v = _cell_samples(gray, q, cells)
    inner = v[:, :n_in]
    ring = np.quantile(v[:, n_in:], 0.25, axis=1)
    frame = ring - np.median(inner[:, border], axis=1)
    bits = np.quantile(inner[:, ~border], [0.9, 0.1], axis=1)
    return frame, bits[0] - bits[1]


class DecodeBudget:
    """The CPU time (``time.thread_time``) one frame's blurred-code decoding may take, s.
    ``decode_blurred`` decodes a quad only when its expected cost (``quad_seconds``) fits
    in what is left, and charges what it took; `skipped` counts the quads it left out.
    The cost grows with the dictionary: ~4 ms a quad for DICT_4X4_50, ~34 ms for
    DICT_APRILTAG_36h11 (2,348 codes and rotations of 8 x 8 cells)."""

    def __init__(self, seconds: float):
        if not (np.isfinite(seconds) and seconds >= 0):
            raise ValueError(f'a decode budget must be >= 0 s, got {seconds}')
        self.left = float(seconds)
        self.skipped = 0

    def affords(self, cost: float) -> bool:
        return cost <= self.left

    def charge(self, seconds: float):
        self.left -= float(seconds)


# Measured CPU seconds of one quad's correlation per dictionary (moving average), and the
# prior used before any measurement: overhead + a share of the code x kernel x cell^2 work.
_QUAD_SECONDS = {}
_PRIOR_OVERHEAD_S, _PRIOR_PER_UNIT_S = 3e-3, 1e-10


def quad_seconds(dictionary) -> float:
    """Expected CPU seconds of ``decode_blurred`` on one quad of `dictionary` (after the
    darkness screen): the moving average of the measured ones, or a prior from the
    dictionary's size before the first."""
    codes = np.asarray(dictionary.bytesList)
    key = (int(dictionary.markerSize), codes.shape[0])
    if key not in _QUAD_SECONDS:
        cells = key[0] + 2
        units = 4 * codes.shape[0] * blur_kernels()[3] * (cells * cells + 1) ** 2
        return _PRIOR_OVERHEAD_S + _PRIOR_PER_UNIT_S * units
    return _QUAD_SECONDS[key]


def _measured(dictionary, seconds):
    codes = np.asarray(dictionary.bytesList)
    key = (int(dictionary.markerSize), codes.shape[0])
    old = _QUAD_SECONDS.get(key)
    _QUAD_SECONDS[key] = seconds if old is None else 0.8 * old + 0.2 * seconds


def decode_blurred(gray, quads, dictionary, min_corr=MIN_CORR, margin=MARGIN,
                   min_contrast=MIN_CONTRAST, min_darkness=MIN_DARKNESS, kernels=None,
                   budget=None):
    """Per quad (Q, 4, 2), clockwise on screen: (id, rotation, corr) or None.

    `rotation` as ``corners.decode_quads``: ``np.roll(quad, rotation, axis=0)`` is in
    ArUco order. See the module docstring for the model and the acceptance test.
    `budget` (``DecodeBudget`` or None: unlimited): quads it cannot afford are None."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 2)
    if q.shape[0] == 0:
        return []
    cells = int(dictionary.markerSize) + 2
    codes = code_matrix(dictionary)
    kernels = blur_kernels() if kernels is None else kernels
    g = np.linspace(-_SAMPLE_PAD, cells + _SAMPLE_PAD, _SAMPLES_PER_AXIS)
    canon = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    img = gray.astype(np.float32) if gray.dtype != np.float32 else gray
    dark = darkness(gray, q, cells) if min_darkness is not None else np.zeros(q.shape[0])
    out = []
    for h, dk in zip(square_homographies(q, cells), dark):
        if (min_darkness is not None and not dk >= min_darkness) or not np.isfinite(h).all():
            out.append(None)
            continue
        if budget is not None and not budget.affords(quad_seconds(dictionary)):
            budget.skipped += 1
            out.append(None)
            continue
        start = time.thread_time()
        out.append(_correlate(img, h, canon, kernels, cells, codes, min_corr, margin,
                              min_contrast))
        took = time.thread_time() - start
        _measured(dictionary, took)
        if budget is not None:
            budget.charge(took)
    return out


def _correlate(img, h, canon, kernels, cells, codes, min_corr, margin, min_contrast):
    """(id, rotation, corr) of the code that best explains the image at homography `h`
    under some kernel, or None (``decode_blurred``'s test)."""
    x, ids, rots = codes
    try:
        h_inv = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return None
    s = cv2.perspectiveTransform(canon[None].astype(np.float64), h)[0]
    v = cv2.remap(img, s[:, 0].astype(np.float32)[None], s[:, 1].astype(np.float32)[None],
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0].astype(np.float64)
    a = _design(h_inv, s, kernels, cells)                                    # (K, N, C)
    a = a - a.mean(axis=1, keepdims=True)
    vc = v - v.mean()
    vn = float(np.sqrt(vc @ vc))
    if vn < 1e-9:
        return None
    atv = (vc @ a)                                                           # (K, C)
    gram = a.transpose(0, 2, 1) @ a                                          # (K, C, C)
    num = atv @ x.T                                                          # (K, M)
    var = ((x @ gram) * x).sum(axis=2)                                       # (K, M)
    with np.errstate(divide='ignore', invalid='ignore'):
        corr = np.where(var > 1e-12, num / (np.sqrt(np.maximum(var, 1e-300)) * vn), -1.0)
    best_k = np.argmax(corr, axis=0)                                         # per code
    per_code = corr[best_k, np.arange(corr.shape[1])]
    m1 = int(np.argmax(per_code))
    c1 = float(per_code[m1])
    other = per_code[ids != ids[m1]]
    c2 = float(other.max()) if other.size else -1.0
    k1 = int(best_k[m1])
    gain = num[k1, m1] / max(var[k1, m1], 1e-12)                            # b of the fit
    ok = (c1 >= min_corr and (1.0 - c2) >= margin * (1.0 - c1) and gain >= min_contrast)
    return (int(ids[m1]), int(rots[m1]), c1) if ok else None
