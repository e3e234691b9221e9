"""The transition tables' two forms and the start states' neighbourhoods (plain NumPy, no
rclpy): what the runtime model set (``modelset``) and the offline learner
(``atg_learning``) both need, so that neither imports the other's module.

- ``dense_table`` / ``sparse_tables``: p(next | action, mass, state) as a dense
  (8, 7, 48, 48) array and as the model files' sparse (8, 7, 48, K) outcome tables;
- ``neighbourhood``: the manual-action neighbourhood of each start state (``near`` = no
  change, +-45 deg yaw, the four quarter rolls about the horizontal body axes; ``wide`` =
  {no change, the 4 quarter rolls, the 2 half rolls} x {yaw 0, +-45 deg}; ``none``), the
  learner's prior support and the hand table's unmodelled outcomes;
- ``states_of_rotations``: the state index (docs/MODEL.md: ``8 * up + yaw``) of a rotation.
"""

from __future__ import annotations

import functools

import numpy as np

from .cube import FACE_NORMALS, NUM_YAWS, R_UP, STATE_ROTATIONS, STATES_PER_MODEL

__all__ = ['DEFAULT_NEIGHBOURHOOD', 'NEIGHBOURHOODS', 'LearningError', 'axis_rotation',
           'dense_table', 'neighbourhood', 'sparse_tables', 'states_of_rotations']

NEIGHBOURHOODS = ('none', 'near', 'wide')
DEFAULT_NEIGHBOURHOOD = 'near'
_NS = STATES_PER_MODEL


class LearningError(ValueError):
    """Experience that cannot be learned from (unreadable, out of range, inconsistent)."""


def states_of_rotations(rot: np.ndarray) -> np.ndarray:
    """State index of each (..., 3, 3) rotation, -1 where it is not one of the 48."""
    up_normal = rot[..., 2, :]                                   # body vector mapped to +z
    hit = np.abs(up_normal[..., None, :] - FACE_NORMALS).max(axis=-1) < 1e-6
    up = np.where(hit.any(axis=-1), hit.argmax(axis=-1), -1)
    rz = rot @ np.swapaxes(R_UP[np.maximum(up, 0)], -1, -2)      # Rz(yaw) if a state
    yaw_f = np.degrees(np.arctan2(rz[..., 1, 0], rz[..., 0, 0])) / 45.0
    yaw = np.rint(yaw_f).astype(np.int64) % NUM_YAWS
    ok = (up >= 0) & (np.abs(yaw_f - np.rint(yaw_f)) < 1e-6) & (np.abs(rz[..., 2, 2] - 1) < 1e-6)
    return np.where(ok, NUM_YAWS * up + yaw, -1)


def dense_table(outcome_states, outcome_probs) -> np.ndarray:
    """(8, 7, 48, 48) p(next | action, mass, state) from the sparse (.., K) tables."""
    states = np.asarray(outcome_states).astype(np.int64)
    dense = np.zeros(states.shape[:3] + (_NS,))
    a, m, s, _ = np.indices(states.shape)
    np.add.at(dense, (a, m, s, states), np.asarray(outcome_probs, dtype=np.float64))
    return dense


def sparse_tables(probs, counts, min_prob: float = 0.0):
    """Sparse (outcome_states int16, outcome_probs, outcome_counts), each (8, 7, 48, K), of
    dense (8, 7, 48, 48) `probs` and `counts`: per cell its successors with p > min_prob
    (renormalised), most likely first; K the largest support; padding repeats the start
    state with probability and count 0."""
    probs = np.where(probs > min_prob, probs, 0.0)
    probs = probs / probs.sum(axis=3, keepdims=True)
    k = max(1, int((probs > 0).sum(axis=3).max()))
    order = np.argsort(-probs, axis=3, kind='stable')[..., :k]
    p = np.take_along_axis(probs, order, axis=3)
    c = np.take_along_axis(counts, order, axis=3)
    start = np.arange(_NS)[None, None, :, None]
    states = np.where(p > 0, order, start).astype(np.int16)
    return states, p, np.where(p > 0, c, 0.0)


def _neighbourhood_motions(kind: str) -> list[tuple[int, np.ndarray]]:
    """(yaw steps, roll axis index or -1, roll degrees) combos of a neighbourhood."""
    if kind == 'none':
        return []
    rolls = [(None, 0.0)] + [(axis, deg) for axis in (0, 1) for deg in (90.0, -90.0)]
    yaws = (0, 1, -1)
    if kind == 'near':
        return [(k, None, 0.0) for k in yaws] + [(0, ax, deg) for ax, deg in rolls[1:]]
    return [(k, ax, deg) for k in yaws for ax, deg in rolls + [(0, 180.0), (1, 180.0)]]


def neighbourhood(kind: str = DEFAULT_NEIGHBOURHOOD) -> np.ndarray:
    """(48, 48) bool: the manual-action neighbourhood of each start state (module doc).

    Rolls are about the cube's horizontal body axes (the two body-face normals lying in the
    horizontal plane, whatever the yaw), so the result is always one of the 48 states."""
    if kind not in NEIGHBOURHOODS:
        raise LearningError(f"neighbourhood must be one of {', '.join(NEIGHBOURHOODS)}")
    return _neighbourhood(kind).copy()


@functools.lru_cache(maxsize=None)
def _neighbourhood(kind: str) -> np.ndarray:
    out = np.zeros((_NS, _NS), dtype=bool)
    for s in range(_NS):
        rot = STATE_ROTATIONS[s]
        horizontal = [rot @ n for n in FACE_NORMALS if abs((rot @ n)[2]) < 1e-6][::2]
        for yaw_steps, axis, deg in _neighbourhood_motions(kind):
            q = np.eye(3)
            if axis is not None:
                q = axis_rotation(horizontal[axis], deg)
            q = axis_rotation(np.array([0.0, 0.0, 1.0]), 45.0 * yaw_steps) @ q
            nxt = int(states_of_rotations(q @ rot))
            if nxt >= 0:
                out[s, nxt] = True
    return out


def axis_rotation(axis, deg) -> np.ndarray:
    """The rotation by `deg` about `axis` (Rodrigues), rounded so that state rotations
    compare exactly."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    t = np.radians(deg)
    r = np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)
    return np.round(r, 12)
