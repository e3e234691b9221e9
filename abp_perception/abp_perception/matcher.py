"""Aspect-based generalised Hough transform (paper section III-B, Algorithm 2).

Plain NumPy, no rclpy. Conventions: docs/MODEL.md.

Features are tag face centres: type = tag id, 3-D position with covariance, outward
normal = the tag's z axis (a tag is centred on its face, so the tag centre is the
face centre). For every pair of observed features (i, j) (Alg. 2 lines 2-3):

- line 4, inter-feature distance Gaussian: mean ``|p_j - p_i|`` and variance
  ``u^T (Sigma_i + Sigma_j) u`` (``u`` the unit pair direction), i.e. first-order
  propagation of the detection covariances, which is what sampling converges to and
  is deterministic and cheap. ``distance_samples > 0`` samples it instead, as in the
  paper (seeded; mean and standard deviation of sampled distances).
- lines 5-6, the aspects that contain both feature types: a lookup table built once
  from the model set maps an ordered tag pair to every (aspect, slot_a, slot_b) with
  those tags (both slot orders), so there is no loop over aspects or models.
- line 7, score: Gaussian correlation of the observed distance distribution with the
  aspect's stored pair Gaussian (``ModelSet.aspect_pair_gaussians``), normalised to
  [0, 1]: ``rho = sqrt(2 s1 s2 / (s1^2 + s2^2)) exp(-(m1 - m2)^2 / (2 (s1^2 + s2^2)))``
  (the correlation coefficient of the two densities; 1 only for identical ones).
- line 8, Hough votes: each candidate (pair, aspect, slot_a, slot_b) fixes a pair frame
  on both sides (axis 1 along the pair, axis 2 the normals' mean perpendicular to it);
  the vote for the object (cube centre) frame is the model centre carried by the
  observed pair frame, and the same frames give the rotation model -> observation.
  Votes are weighted by the score, by an orientation term, and by the detection
  confidences, and summed into a sparse 3-D Cartesian accumulator (voxels of
  ``voxel_size``), one per aspect.

Beyond the paper, for far tags (whose range, from the apparent size, is far less
certain than their image position, see ``detector``): before voting, a pair is moved
to the model distance by weighted least squares under its covariances; the roll of
the pair frame about its axis is the inverse-variance weighted mean of the two normals'
estimates (so a tag with an ambiguous IPPE pose barely counts), and their disagreement
multiplies the vote weight; the orientation tolerance widens by the vote's own rotation
uncertainty, and a peak gathers votes within ``max(peak_radius, 2.5 x`` the votes'
position spread ``)``.

Orientation term: the model aspects live in the view frame V (docs/MODEL.md): origin
at the cube centre, z up, x horizontal from the cube towards the robot base (the
``viewpoint``: base_link's origin when the features are in base_link). At each
vote, V is built from the voted centre; the vote's rotation is compared to it and
weighted by ``exp(-angle^2 / (2 (orientation_sigma^2 + the vote's rotation variance)))``.
That is what tells a (top, front) aspect at an aligned yaw from a (top, plus_y,
minus_y) aspect at a 45 deg yaw, and plus_y from minus_y, and what silences pairs of
stray tags whose distance happens to fit.

Peaks: per aspect, the accumulator voxel with the largest tally; the votes of that
aspect near the voxel's mean (above) are its support. A hypothesis
reports the aspect's slots that its supporting votes filled with their tag id and
-1 for slots that no observed feature supports (a missed tag), so model aspects that
differ only in unseen slots collapse into one reported hypothesis (the best one is
kept). Object pose: position = weighted mean of the supporting votes; orientation =
weighted Kabsch fit of the aspect's model face directions and normals (in V) to
the observed ones; the rotation maps the aspect's V frame to the observation frame.

Features whose type is not a tag id of the model set (outside 0..n_tags-1) are
ignored and counted; in-range tags elsewhere in the scene (distractors) get no
consistent votes (wrong distance, wrong orientation, scattered centres).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['Feature', 'Hypothesis', 'MatchResult', 'AspectMatcher',
           'features_from_detections', 'normal_sigma_of']

_EPS = 1e-12
_NORMAL_SIGMA_FLOOR = np.deg2rad(3.0)   # normals are never better than this (tags bend)


@dataclass
class Feature:
    """A typed 3-D feature: the centre of one tagged face."""

    tag_id: int
    position: np.ndarray                 # (3,)
    covariance: np.ndarray               # (3, 3) m^2
    normal: np.ndarray                   # (3,) outward unit normal
    confidence: float = 1.0
    normal_sigma: float = 0.05           # rad, standard deviation of the normal's direction


def normal_sigma_of(covariance6) -> float:
    """Normal-direction uncertainty (rad) from a 6 x 6 pose covariance: its largest
    rotation standard deviation (the tilt, which moves the normal)."""
    rot = np.asarray(covariance6, dtype=np.float64).reshape(6, 6)[3:, 3:]
    return float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (rot + rot.T))[-1], 0.0)))


def features_from_detections(detections) -> list:
    """Features from detector.Detection objects (their frame is the features' frame)."""
    return [Feature(int(d.tag_id), np.asarray(d.pose[:3, 3], float).copy(),
                    np.asarray(d.covariance[:3, :3], float).copy(),
                    np.asarray(d.pose[:3, 2], float).copy(), float(d.confidence),
                    normal_sigma_of(d.covariance))
            for d in detections]


@dataclass
class Hypothesis:
    aspect_type: int
    slots: tuple                         # 3 tag ids, -1 = empty slot or missed tag
    support: float                       # sum of vote weights at the peak
    score: float                         # support / sum of supports of all hypotheses
    position: np.ndarray                 # (3,) cube centre
    rotation: np.ndarray                 # (3, 3) aspect's V frame -> observation frame
    covariance: np.ndarray               # (6, 6) x y z rx ry rz
    feature_indices: tuple               # indices into MatchResult.features
    aspect_rows: tuple = ()              # model-set aspect rows reported as this key
    votes: int = 0

    @property
    def key(self) -> tuple:
        return (int(self.aspect_type), *(int(s) for s in self.slots))


@dataclass
class MatchResult:
    features: list
    hypotheses: list
    ignored_features: int = 0            # features whose tag id is not in the model set
    pairs: int = 0
    votes: int = 0
    ignored_ids: list = field(default_factory=list)

    @property
    def best(self):
        return self.hypotheses[0] if self.hypotheses else None


def _normalise(v, axis=-1):
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / np.maximum(n, _EPS), n[..., 0]


def _pair_frames(pa, pb, na, nb):
    """Pair frames (..., 3, 3) (columns e1, e2, e3) and a validity mask."""
    e1, length = _normalise(pb - pa)
    w = na + nb
    w = w - np.sum(w * e1, axis=-1, keepdims=True) * e1
    e2, wn = _normalise(w)
    e3 = np.cross(e1, e2)
    return np.stack([e1, e2, e3], axis=-1), (length > 1e-6) & (wn > 0.2)


class AspectMatcher:
    """Matches observed features to the aspects of a ``abp_belief.modelset.ModelSet``."""

    def __init__(self, model_set, voxel_size: float | None = None,
                 peak_radius: float | None = None, orientation_sigma_deg: float = 15.0,
                 min_pair_score: float = 0.05, min_support: float = 0.05,
                 max_hypotheses: int = 10, distance_samples: int = 0,
                 viewpoint=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), seed: int = 0):
        h = float(model_set.cube_size)
        self.model_set = model_set
        self.n_tags = int(model_set.n_tags)
        self.cube_size = h
        self.voxel_size = float(voxel_size) if voxel_size is not None else h / 4.0
        self.peak_radius = float(peak_radius) if peak_radius is not None else h / 2.0
        if not (self.voxel_size > 0 and self.peak_radius > 0):
            raise ValueError('voxel_size and peak_radius must be > 0 m')
        if not 0 < orientation_sigma_deg <= 180:
            raise ValueError(f'orientation_sigma_deg must be in (0, 180], got '
                             f'{orientation_sigma_deg}')
        if int(max_hypotheses) < 1:
            raise ValueError('max_hypotheses must be >= 1')
        if int(distance_samples) < 0:
            raise ValueError('distance_samples must be >= 0')
        self.orientation_sigma = np.deg2rad(float(orientation_sigma_deg))
        self.min_pair_score = float(min_pair_score)
        self.min_support = float(min_support)
        self.max_hypotheses = int(max_hypotheses)
        self.distance_samples = int(distance_samples)
        self.viewpoint = np.asarray(viewpoint, dtype=np.float64).reshape(3)
        up = np.asarray(up, dtype=np.float64).reshape(3)
        self.up = up / np.linalg.norm(up)
        self._rng = np.random.default_rng(seed)
        self._build_tables()

    # -- model side: built once ---------------------------------------------------------
    def _build_tables(self):
        ms = self.model_set
        aspects = np.asarray(ms.aspects, dtype=np.int64)
        self.aspects = aspects
        self.aspect_types = aspects[:, 0]
        self.aspect_tags = aspects[:, 1:4]
        rows, sa, sb, mean, sigma, pos_a, pos_b = [], [], [], [], [], [], []
        for row in range(aspects.shape[0]):
            pg = ms.aspect_pair_gaussians(row)
            pos = np.asarray(ms.aspect_feature_positions(row), dtype=np.float64)
            for (i, j), mu, sd in zip(np.asarray(pg.slots), np.asarray(pg.mean),
                                      np.asarray(pg.sigma)):
                for a, b in ((i, j), (j, i)):           # both slot orders
                    rows.append(row)
                    sa.append(a)
                    sb.append(b)
                    mean.append(mu)
                    sigma.append(sd)
                    pos_a.append(pos[a])
                    pos_b.append(pos[b])
        rows, sa, sb = (np.asarray(x, dtype=np.int64) for x in (rows, sa, sb))
        pos_a, pos_b = np.asarray(pos_a), np.asarray(pos_b)
        frames, ok = _pair_frames(pos_a, pos_b, _normalise(pos_a)[0], _normalise(pos_b)[0])
        if not ok.all():
            raise ValueError('model aspect with a degenerate feature pair')
        mid = 0.5 * (pos_a + pos_b)
        # Model normals about the pair axis: roll angle and size of the perpendicular part.
        self._entry_roll, self._entry_perp = [], []
        for p in (pos_a, pos_b):
            nu = _normalise(p)[0]
            c2 = np.einsum('ei,ei->e', nu, frames[:, :, 1])
            c3 = np.einsum('ei,ei->e', nu, frames[:, :, 2])
            self._entry_roll.append(np.arctan2(c3, c2))
            self._entry_perp.append(np.hypot(c2, c3))
        self._entry_row, self._entry_sa, self._entry_sb = rows, sa, sb
        self._entry_mean = np.asarray(mean, dtype=np.float64)
        self._entry_sigma = np.asarray(sigma, dtype=np.float64)
        self._entry_frame_t = np.transpose(frames, (0, 2, 1))            # model -> pair
        self._entry_offset = np.einsum('eij,ej->ei', self._entry_frame_t, -mid)  # centre
        # Lookup: ordered tag pair -> padded entry list.
        keys = self.aspect_tags[rows, sa] * self.n_tags + self.aspect_tags[rows, sb]
        order = np.argsort(keys, kind='stable')
        counts = np.bincount(keys, minlength=self.n_tags ** 2)
        width = max(1, int(counts.max(initial=0)))
        table = np.full((self.n_tags ** 2, width), -1, dtype=np.int64)
        starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
        sorted_keys = keys[order]
        rank = np.arange(order.size) - starts[sorted_keys]
        table[sorted_keys, rank] = order
        self._table = table
        # Model face directions (unit) per aspect type (index) and slot, zero-padded.
        self._slot_dir_table = np.zeros((4, 3, 3))
        for row in range(aspects.shape[0]):
            k = int(self.aspect_types[row])
            dirs = _normalise(np.asarray(ms.aspect_feature_positions(row), dtype=np.float64))[0]
            self._slot_dir_table[k, :dirs.shape[0]] = dirs

    # -- observation side -----------------------------------------------------------------
    def _distance_gaussians(self, pos, cov, i, j):
        if self.distance_samples > 0:
            s = self.distance_samples
            chol = np.linalg.cholesky(cov + 1e-12 * np.eye(3))
            za = self._rng.standard_normal((i.size, s, 3))
            zb = self._rng.standard_normal((i.size, s, 3))
            xa = pos[i][:, None, :] + np.einsum('pij,psj->psi', chol[i], za)
            xb = pos[j][:, None, :] + np.einsum('pij,psj->psi', chol[j], zb)
            dist = np.linalg.norm(xb - xa, axis=2)
            return dist.mean(axis=1), dist.std(axis=1, ddof=1)
        d = pos[j] - pos[i]
        u, mu = _normalise(d)
        var = np.einsum('pi,pij,pj->p', u, cov[i] + cov[j], u)
        return mu, np.sqrt(np.maximum(var, 1e-12))

    def _view_frames(self, centres, viewpoint):
        """V frames (n, 3, 3) (columns x, y, z in the observation frame) at cube centres."""
        z = np.broadcast_to(self.up, centres.shape)
        x = viewpoint - centres
        x = x - np.sum(x * z, axis=1, keepdims=True) * z
        x, _ = _normalise(x)
        y = np.cross(z, x)
        return np.stack([x, y, z], axis=-1)

    def match(self, features, viewpoint=None) -> MatchResult:
        """Aspect hypotheses (best first) for a list of Feature (frame of the features)."""
        features = list(features)
        view = self.viewpoint if viewpoint is None else np.asarray(viewpoint, float).reshape(3)
        ids = np.array([int(f.tag_id) for f in features], dtype=np.int64)
        usable = (ids >= 0) & (ids < self.n_tags)
        if features:
            pos_all = np.array([np.asarray(f.position, float) for f in features])
            nrm_all = np.array([np.asarray(f.normal, float) for f in features])
            cov_all = np.array([np.asarray(f.covariance, float).reshape(3, 3)
                                for f in features])
            conf_all = np.array([float(f.confidence) for f in features])
            usable &= np.isfinite(pos_all).all(axis=1) & np.isfinite(nrm_all).all(axis=1) \
                & np.isfinite(cov_all).all(axis=(1, 2)) & np.isfinite(conf_all)
        ignored_ids = sorted(int(t) for t in ids[(ids < 0) | (ids >= self.n_tags)])
        result = MatchResult(features, [], int(np.sum(~usable)), 0, 0, ignored_ids)
        idx = np.flatnonzero(usable)
        if idx.size < 2:
            return result
        pos, cov = pos_all[idx], cov_all[idx]
        nrm, _ = _normalise(nrm_all[idx])
        conf = np.clip(conf_all[idx], 0.0, 1.0)
        nsd = np.array([float(features[k].normal_sigma) for k in idx])
        tags = ids[idx]

        # Alg. 2 lines 2-4: all pairs, their distance Gaussians.
        pi, pj = np.triu_indices(idx.size, k=1)
        result.pairs = int(pi.size)
        mu_o, sd_o = self._distance_gaussians(pos, cov, pi, pj)
        # Lines 5-6: aspects containing both types, from the lookup table.
        cand = self._table[tags[pi] * self.n_tags + tags[pj]]             # (P, W)
        vp, vk = np.nonzero((cand >= 0) & (mu_o > 1e-6)[:, None])
        if vp.size == 0:
            return result
        entry = cand[vp, vk]
        # Line 7: Gaussian correlation score.
        s1, s2 = sd_o[vp], self._entry_sigma[entry]
        var = s1 ** 2 + s2 ** 2
        rho = np.sqrt(2.0 * s1 * s2 / var) * np.exp(-(mu_o[vp] - self._entry_mean[entry]) ** 2
                                                     / (2.0 * var))
        keep = rho >= self.min_pair_score
        vp, entry, rho = vp[keep], entry[keep], rho[keep]
        if vp.size == 0:
            return result
        # Line 8: votes for the object frame and its rotation.
        centres, rot, agree, spread, rot_var = self._votes(pos, cov, nrm, nsd, pi[vp], pj[vp],
                                                           entry)
        view_frames = self._view_frames(centres, view)
        cos_angle = 0.5 * (np.einsum('vij,vij->v', view_frames, rot) - 1.0)
        angle = np.arccos(np.clip(cos_angle, -1.0, 1.0))
        weight = rho * agree * np.exp(-0.5 * angle ** 2 / (self.orientation_sigma ** 2 + rot_var)) \
            * np.sqrt(conf[pi[vp]] * conf[pj[vp]])
        keep = weight > 1e-4
        vp, entry, centres, weight, spread = vp[keep], entry[keep], centres[keep], \
            weight[keep], spread[keep]
        result.votes = int(vp.size)
        if vp.size == 0:
            return result
        aspect = self._entry_row[entry]
        hyps = self._peaks(aspect, centres, weight)
        if hyps is None:
            return result
        peak_aspect, peak_centre = hyps
        # Supporting votes: same aspect, within peak_radius of its peak (peak_aspect is
        # sorted, every voted aspect has a peak).
        vote_h = np.searchsorted(peak_aspect, aspect)
        near = np.linalg.norm(centres - peak_centre[vote_h], axis=1) \
            <= np.maximum(self.peak_radius, 2.5 * spread)
        return self._hypotheses(result, idx, pos, nrm, cov, pi, pj, vp, entry, centres,
                                weight, near, vote_h, peak_aspect)

    def _votes(self, pos, cov, nrm, nsd, i, j, entry):
        """Object-frame votes of feature pairs (i, j) matched to model pair entries.

        The pair is first moved, by weighted least squares under the detection
        covariances, to the model's inter-feature distance (the range of a far tag is
        uncertain; its image position is not). Its axis then fixes the pair frame up to a
        roll about it, which each observed normal estimates against the model's normal;
        the two estimates are averaged with weights 1 / (normal variance) (a tag whose
        IPPE pose is ambiguous has a large normal variance and barely counts), and their
        disagreement scores the pair (``agree``). Returns the voted centres, rotations
        (model V -> observation), ``agree``, the votes' position spread (m) and their
        rotation variance (rad^2).
        """
        d = pos[j] - pos[i]
        u, mu = _normalise(d)
        cu_i = np.einsum('vab,vb->va', cov[i], u)
        cu_j = np.einsum('vab,vb->va', cov[j], u)
        var = np.maximum(np.einsum('va,va->v', u, cu_i + cu_j), 1e-12)
        lam = (self._entry_mean[entry] - mu) / var
        pa = pos[i] - lam[:, None] * cu_i
        pb = pos[j] + lam[:, None] * cu_j
        e1, _ = _normalise(pb - pa)
        # Reference axes about e1: f2 = "up" made perpendicular (any perpendicular if e1 is
        # vertical), f3 = e1 x f2.
        up = np.broadcast_to(self.up, e1.shape)
        f2 = up - np.sum(up * e1, axis=1, keepdims=True) * e1
        vertical = np.linalg.norm(f2, axis=1) < 1e-6
        if vertical.any():
            alt = np.cross(e1[vertical], [1.0, 0.0, 0.0])
            f2[vertical] = alt
        f2, _ = _normalise(f2)
        f3 = np.cross(e1, f2)
        rolls, weights = [], []
        for k, (f, roll_m, perp_m) in enumerate(((i, self._entry_roll[0], self._entry_perp[0]),
                                                  (j, self._entry_roll[1], self._entry_perp[1]))):
            c2 = np.sum(nrm[f] * f2, axis=1)
            c3 = np.sum(nrm[f] * f3, axis=1)
            rolls.append(np.arctan2(c3, c2) - roll_m[entry])
            weights.append((c2 ** 2 + c3 ** 2) * perp_m[entry] ** 2
                           / (nsd[f] ** 2 + _NORMAL_SIGMA_FLOOR ** 2))
        wa, wb = weights
        psi = np.arctan2(wa * np.sin(rolls[0]) + wb * np.sin(rolls[1]),
                         wa * np.cos(rolls[0]) + wb * np.cos(rolls[1]))
        gap = np.angle(np.exp(1j * (rolls[0] - rolls[1])))
        gap_var = nsd[i] ** 2 + nsd[j] ** 2 + 2 * _NORMAL_SIGMA_FLOOR ** 2
        agree = np.exp(-0.5 * gap ** 2 / gap_var)
        # Rotation uncertainty of the vote: the roll from the normals, plus the pair axis'
        # direction from the positions (perpendicular spread over the pair length).
        roll_var = np.minimum(1.0 / np.maximum(wa + wb, _EPS), (0.5 * np.pi) ** 2)
        tr = np.trace(cov[i] + cov[j], axis1=1, axis2=2)
        axis_var = np.maximum(tr - var, 0.0) / np.maximum(self._entry_mean[entry], _EPS) ** 2
        rot_var = roll_var + np.minimum(axis_var, (0.5 * np.pi) ** 2)
        e2 = np.cos(psi)[:, None] * f2 + np.sin(psi)[:, None] * f3
        e3 = np.cross(e1, e2)
        frames = np.stack([e1, e2, e3], axis=-1)
        mid = 0.5 * (pa + pb)
        centres = mid + np.einsum('vij,vj->vi', frames, self._entry_offset[entry])
        rot = np.einsum('vij,vjk->vik', frames, self._entry_frame_t[entry])
        spread = np.sqrt(tr / 4.0)
        return centres, rot, agree, spread, rot_var

    def _peaks(self, aspect, centres, weight):
        """Per aspect: the accumulator voxel with the largest tally and its mean vote."""
        cell = np.floor(centres / self.voxel_size).astype(np.int64)
        cell -= cell.min(axis=0)
        dims = cell.max(axis=0) + 1
        flat = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        key = aspect * int(np.prod(dims)) + flat
        ukey, inv = np.unique(key, return_inverse=True)
        tally = np.bincount(inv, weights=weight)
        key_aspect = ukey // int(np.prod(dims))
        order = np.lexsort((-tally, key_aspect))                          # best voxel first
        peak_aspect, first = np.unique(key_aspect[order], return_index=True)
        peak_key = order[first]                                           # index into ukey
        # Mean of the votes in each peak voxel.
        is_peak = np.full(ukey.size, -1, dtype=np.int64)
        is_peak[peak_key] = np.arange(peak_key.size)
        h = is_peak[inv]
        sel = h >= 0
        wsum = np.bincount(h[sel], weights=weight[sel], minlength=peak_key.size)
        csum = np.stack([np.bincount(h[sel], weights=weight[sel] * centres[sel, d],
                                     minlength=peak_key.size) for d in range(3)], axis=1)
        return peak_aspect, csum / np.maximum(wsum, _EPS)[:, None]

    def _hypotheses(self, result, idx, pos, nrm, cov, pi, pj, vp, entry, centres, weight,
                    near, vote_h, peak_aspect):
        n_h = peak_aspect.size
        w = np.where(near, weight, 0.0)
        support = np.bincount(vote_h, weights=w, minlength=n_h)
        count = np.bincount(vote_h[near], minlength=n_h)
        centre = np.stack([np.bincount(vote_h, weights=w * centres[:, d], minlength=n_h)
                           for d in range(3)], axis=1) / np.maximum(support, _EPS)[:, None]
        types = self.aspect_types[peak_aspect]
        # Feature of each (hypothesis, slot): from the strongest supporting vote filling it.
        sv = np.flatnonzero(near)
        ends_h = np.concatenate([vote_h[sv], vote_h[sv]])
        ends_s = np.concatenate([self._entry_sa[entry[sv]], self._entry_sb[entry[sv]]])
        ends_f = np.concatenate([pi[vp[sv]], pj[vp[sv]]])
        ends_w = np.concatenate([weight[sv], weight[sv]])
        order = np.argsort(-ends_w, kind='stable')
        key = ends_h[order] * 3 + ends_s[order]
        ukey, first = np.unique(key, return_index=True)
        slot_feature = np.full((n_h, 3), -1, dtype=np.int64)
        slot_feature[ukey // 3, ukey % 3] = ends_f[order][first]
        filled = slot_feature >= 0
        reported = np.where(filled, self.aspect_tags[peak_aspect], -1)
        good = (support >= self.min_support) & (filled.sum(axis=1) >= 2)
        if not good.any():
            return result
        # Merge aspects with the same reported key, keeping the best support.
        base = self.n_tags + 1
        code = ((types * base + reported[:, 0] + 1) * base + reported[:, 1] + 1) * base \
            + reported[:, 2] + 1
        cand = np.flatnonzero(good)
        order = cand[np.lexsort((-support[cand], code[cand]))]
        _, first = np.unique(code[order], return_index=True)
        best = order[first]
        best = best[np.argsort(-support[best], kind='stable')][:self.max_hypotheses]
        # Orientation: batched weighted Kabsch of model face directions and normals.
        sf = slot_feature[best]
        mask = (sf >= 0).astype(np.float64)                                  # (B, 3)
        fidx = np.where(sf >= 0, sf, 0)
        model = self._slot_dir_table[types[best]]                            # (B, 3, 3)
        obs_dir = (pos[fidx] - centre[best][:, None, :]) / (0.5 * self.cube_size)
        obs_nrm = nrm[fidx]
        hmat = np.einsum('bs,bsi,bsj->bij', mask, model, obs_dir + obs_nrm)
        u, _, vt = np.linalg.svd(hmat)
        v = np.transpose(vt, (0, 2, 1))
        ut = np.transpose(u, (0, 2, 1))
        d = np.sign(np.linalg.det(v @ ut))
        d[d == 0] = 1.0
        rotation = v @ (np.array([1.0, 1.0, 0.0])[None, :, None] * ut
                        + np.array([0.0, 0.0, 1.0])[None, :, None] * d[:, None, None] * ut)
        pred = np.einsum('bij,bsj->bsi', rotation, model)
        resid = (np.sum((obs_dir - pred) ** 2, axis=2) + np.sum((obs_nrm - pred) ** 2, axis=2))
        n_used = mask.sum(axis=1)
        rot_var = np.maximum(np.sum(mask * resid, axis=1) / np.maximum(2 * n_used - 1, 1), 1e-6)
        # Position: mean feature covariance / n, plus the votes' weighted scatter / n_votes.
        feat_cov = np.einsum('bs,bsij->bij', mask, cov[fidx]) / (n_used ** 2)[:, None, None]
        spread = centres[sv] - centre[vote_h[sv]]
        outer = (weight[sv, None] * (spread[:, :, None] * spread[:, None, :]).reshape(-1, 9))
        scatter = np.stack([np.bincount(vote_h[sv], weights=outer[:, k], minlength=n_h)
                            for k in range(9)], axis=1).reshape(n_h, 3, 3)
        scatter = scatter[best] / (np.maximum(support[best], _EPS)
                                   * np.maximum(count[best], 1))[:, None, None]
        pos_cov = feat_cov + scatter
        total = float(support[best].sum())
        for k, h in enumerate(best):
            covariance = np.zeros((6, 6))
            covariance[:3, :3] = pos_cov[k]
            covariance[3:, 3:] = rot_var[k] * np.eye(3)
            merged = cand[code[cand] == code[h]]
            result.hypotheses.append(Hypothesis(
                aspect_type=int(types[h]),
                slots=tuple(int(x) for x in reported[h]),
                support=float(support[h]),
                score=float(support[h] / total) if total > 0 else 0.0,
                position=centre[h].copy(),
                rotation=rotation[k],
                covariance=covariance,
                feature_indices=tuple(sorted(int(idx[f]) for f in sf[k] if f >= 0)),
                aspect_rows=tuple(int(peak_aspect[m]) for m in merged),
                votes=int(count[h])))
        return result
