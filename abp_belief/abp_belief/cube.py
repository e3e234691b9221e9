"""Geometry and physics of one ARcube (conventions: docs/MODEL.md).

Everything here is a small constant table or a function of one state; the
per-model-set tables are built from these in ``modelset``.
"""

from __future__ import annotations

import itertools

import numpy as np

from abp_description.frames import rot_z_deg

# The action vocabulary (abp_msgs/ExecutedAction carries the same names as constants).
ACTIONS = ('ORBIT_P45', 'ORBIT_M45', 'ORBIT_P90', 'ORBIT_M90', 'ORBIT_180', 'PUSH', 'LIFT', 'FLIP')
ACTION_INDEX = {name: i for i, name in enumerate(ACTIONS)}
NOMINAL_DURATION_S = {'ORBIT_P45': 20.0, 'ORBIT_M45': 20.0, 'ORBIT_P90': 30.0, 'ORBIT_M90': 30.0,
                      'ORBIT_180': 50.0, 'PUSH': 30.0, 'LIFT': 45.0, 'FLIP': 60.0}
# Yaw change (in 45 deg steps) of each ORBIT action.
ORBIT_STEPS = {'ORBIT_P45': 1, 'ORBIT_M45': -1, 'ORBIT_P90': 2, 'ORBIT_M90': -2, 'ORBIT_180': 4}
MANUAL_ACTIONS = ('PUSH', 'LIFT', 'FLIP')

STATES_PER_MODEL = 48            # state = 8 * up_face + yaw
NUM_YAWS = 8
NUM_FACES = 6
NUM_MASS_VARIANTS = 7            # mass index 0 = uniform, 1 + f = heavy body face f
MIN_TAGS, MAX_TAGS = 6, 50       # ArUco DICT_4X4_50 holds 50 ids

FACE_NAMES = ('+x', '-x', '+y', '-y', '+z', '-z')
FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                        dtype=np.float64)
OPPOSITE_FACE = np.array([1, 0, 3, 2, 5, 4], dtype=np.int64)
MASS_NAMES = ('u',) + tuple('m' + name for name in FACE_NAMES)

_SQRT_HALF = float(np.sqrt(0.5))
_TOL = 1e-6


def action_index(action) -> int:
    """Index into ACTIONS of an action given by name or index (ValueError otherwise)."""
    if isinstance(action, (int, np.integer)) and not isinstance(action, bool):
        if 0 <= int(action) < len(ACTIONS):
            return int(action)
        raise ValueError(f'action index {action} out of range 0..{len(ACTIONS) - 1}')
    if isinstance(action, str) and action in ACTION_INDEX:
        return ACTION_INDEX[action]
    raise ValueError(f"unknown action {action!r}; expected one of {', '.join(ACTIONS)}")


def check_n_tags(n_tags) -> int:
    """The tag-set size as int, or ValueError naming the supported range."""
    if isinstance(n_tags, bool) or not isinstance(n_tags, (int, np.integer)):
        raise ValueError(f'n_tags must be an integer in {MIN_TAGS}..{MAX_TAGS}, got {n_tags!r}')
    if not MIN_TAGS <= int(n_tags) <= MAX_TAGS:
        raise ValueError(f'n_tags must be in {MIN_TAGS}..{MAX_TAGS} (a cube needs 6 distinct tags; '
                         f'DICT_4X4_50 has 50), got {n_tags}')
    return int(n_tags)


def rot_x(deg: float) -> np.ndarray:
    c, s = _cos_sin(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(deg: float) -> np.ndarray:
    c, s = _cos_sin(deg)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _cos_sin(deg: float) -> tuple[float, float]:
    # Exact zeros/ones for multiples of 90 deg so that state matching stays crisp.
    rad = np.deg2rad(deg)
    return float(np.round(np.cos(rad), 15)), float(np.round(np.sin(rad), 15))


def _cube_group() -> np.ndarray:
    """The 24 proper rotations of the cube in canonical order (see MODEL.md).

    Signed permutation matrices Q[i, perm[i]] = sign[i] with det +1, in the
    order of itertools.permutations((0, 1, 2)) and then
    itertools.product((1, -1), repeat=3); the identity comes first.
    """
    group = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            q = np.zeros((3, 3))
            q[np.arange(3), perm] = signs
            if np.linalg.det(q) > 0:
                group.append(q)
    return np.array(group)


CUBE_ROTATIONS = _cube_group()                                        # (24, 3, 3)
# R_UP[f]: first group element taking body face f to +z.
R_UP = np.array([next(q for q in CUBE_ROTATIONS if np.allclose(q @ n, [0, 0, 1]))
                 for n in FACE_NORMALS])                              # (6, 3, 3)
STATE_ROTATIONS = np.array([rot_z_deg(45.0 * (s % NUM_YAWS)) @ R_UP[s // NUM_YAWS]
                            for s in range(STATES_PER_MODEL)])        # (48, 3, 3) body -> V


def _face_towards(rotations: np.ndarray, direction) -> np.ndarray:
    """Per rotation, the body face whose normal maps onto `direction` (-1 if none)."""
    normals_v = np.einsum('rij,fj->rfi', rotations, FACE_NORMALS)     # (R, 6, 3)
    hit = np.linalg.norm(normals_v - np.asarray(direction, float), axis=2) < _TOL
    return np.where(hit.any(axis=1), hit.argmax(axis=1), -1)


# Visible faces per state: top, front (even yaw), right = plus_y and left = minus_y (odd yaw).
STATE_UP_FACE = np.repeat(np.arange(NUM_FACES), NUM_YAWS)
STATE_YAW = np.tile(np.arange(NUM_YAWS), NUM_FACES)
STATE_TOP_FACE = _face_towards(STATE_ROTATIONS, [0, 0, 1])
STATE_FRONT_FACE = _face_towards(STATE_ROTATIONS, [1, 0, 0])
STATE_PLUS_Y_FACE = _face_towards(STATE_ROTATIONS, [_SQRT_HALF, _SQRT_HALF, 0])
STATE_MINUS_Y_FACE = _face_towards(STATE_ROTATIONS, [_SQRT_HALF, -_SQRT_HALF, 0])
STATE_ASPECT_TYPE = np.where(STATE_YAW % 2 == 0, 2, 3)

# Face permutation of each group rotation: a cube turned by CUBE_ROTATIONS[r] carries, on
# body face g, the tag that was on face ROTATION_FACE_SOURCE[r, g].
ROTATION_FACE_SOURCE = np.array(
    [[int(np.argmax(np.linalg.norm((q @ FACE_NORMALS.T).T - FACE_NORMALS[g], axis=1) < _TOL))
      for g in range(NUM_FACES)] for q in CUBE_ROTATIONS])

# Feature (face-centre) positions in V in units of the cube edge, per aspect type, slot order.
FEATURE_UNIT_POSITIONS = {
    2: np.array([[0.0, 0.0, 0.5], [0.5, 0.0, 0.0]]),
    3: np.array([[0.0, 0.0, 0.5], [0.5 * _SQRT_HALF, 0.5 * _SQRT_HALF, 0.0],
                 [0.5 * _SQRT_HALF, -0.5 * _SQRT_HALF, 0.0]]),
}


def state_of(up_face: int, yaw: int) -> int:
    return NUM_YAWS * int(up_face) + int(yaw) % NUM_YAWS


def _check_state(state) -> int:
    if not 0 <= int(state) < STATES_PER_MODEL:
        raise ValueError(f'state {state} out of range 0..{STATES_PER_MODEL - 1}')
    return int(state)


def state_rotation(state) -> np.ndarray:
    """Body -> view frame rotation R(up, yaw) of a state (a copy)."""
    return STATE_ROTATIONS[_check_state(state)].copy()


def state_from_rotation(rotation) -> int:
    """The state whose rotation equals `rotation` (ValueError if it is none of the 48)."""
    err = np.linalg.norm(STATE_ROTATIONS - np.asarray(rotation, float), axis=(1, 2))
    best = int(np.argmin(err))
    if err[best] > 1e-6:
        raise ValueError('rotation is not one of the 48 discrete cube states')
    return best


def aspect_of(faces_tags, state) -> tuple[int, int, int, int]:
    """Aspect key (type, s0, s1, s2) of a cube with tags `faces_tags` (by body face) in `state`."""
    tags = np.asarray(faces_tags)
    s = _check_state(state)
    if STATE_ASPECT_TYPE[s] == 2:
        return (2, int(tags[STATE_TOP_FACE[s]]), int(tags[STATE_FRONT_FACE[s]]), -1)
    return (3, int(tags[STATE_TOP_FACE[s]]), int(tags[STATE_PLUS_Y_FACE[s]]),
            int(tags[STATE_MINUS_Y_FACE[s]]))


def mass_direction(mass_index, state) -> np.ndarray | None:
    """Direction in V of the heavy face (None for uniform mass)."""
    m = int(mass_index)
    if not 0 <= m < NUM_MASS_VARIANTS:
        raise ValueError(f'mass index {m} out of range 0..{NUM_MASS_VARIANTS - 1}')
    if m == 0:
        return None
    return STATE_ROTATIONS[_check_state(state)] @ FACE_NORMALS[m - 1]


def _is(d: np.ndarray | None, direction) -> bool:
    return d is not None and float(np.abs(d - direction).max()) < _TOL


def nominal_rotation(action, mass_index, state) -> np.ndarray:
    """The nominal (success, no noise) rotation Q in V of an action: R' = Q R.

    Physics of MODEL.md; manual actions at an odd yaw make no contact -> identity.
    """
    name = ACTIONS[action_index(action)]
    s = _check_state(state)
    if name in ORBIT_STEPS:
        return rot_z_deg(45.0 * ORBIT_STEPS[name])
    if STATE_YAW[s] % 2 == 1:
        return np.eye(3)
    d = mass_direction(mass_index, s)
    if name == 'PUSH':
        # The heavy side drags, the light side advances.
        if _is(d, [0, 1, 0]):
            return rot_z_deg(-45.0)
        if _is(d, [0, -1, 0]):
            return rot_z_deg(45.0)
        return np.eye(3)
    if name == 'LIFT':
        if _is(d, [0, 0, 1]):
            return rot_y(180.0)
        if _is(d, [1, 0, 0]):
            return rot_y(90.0)
        if _is(d, [-1, 0, 0]):
            return rot_y(-90.0)
        return np.eye(3)
    # FLIP: uniform tips front-to-top; eccentric comes to rest with the mass at the base.
    if d is None or _is(d, [-1, 0, 0]):
        return rot_y(-90.0)
    if _is(d, [1, 0, 0]):
        return rot_y(90.0)
    if _is(d, [0, 0, 1]):
        return rot_y(180.0)
    if _is(d, [0, 1, 0]):
        return rot_x(-90.0)
    if _is(d, [0, -1, 0]):
        return rot_x(90.0)
    return np.eye(3)                                                  # d = -z: already at rest


# The two hand-written transition tables (docs/MODEL.md, "Actions and their physics"):
# `paper` is the table as the paper wrote it (Table II is reproduced with it); `corrected`
# is that table with the cells the MuJoCo outcome survey showed wrong (issue 12) rewritten
# from the physics.
TRANSITION_RULES = ('corrected', 'paper')


def check_transition_rules(rules) -> str:
    if rules not in TRANSITION_RULES:
        raise ValueError(f"transition rules must be one of {', '.join(TRANSITION_RULES)}, "
                         f'got {rules!r}')
    return rules


def nominal_outcomes(action, mass_index, state,
                     rules='corrected') -> list[tuple[np.ndarray, float]]:
    """The successful outcomes of an action as (rotation Q in V, weight) pairs, weights
    summing to 1, under the `paper` or the `corrected` rules of MODEL.md."""
    if check_transition_rules(rules) == 'paper':
        return [(nominal_rotation(action, mass_index, state), 1.0)]
    name = ACTIONS[action_index(action)]
    s = _check_state(state)
    if name in ORBIT_STEPS:
        return [(rot_z_deg(45.0 * ORBIT_STEPS[name]), 1.0)]
    d = mass_direction(mass_index, s)
    if name == 'PUSH':
        # The skill's 5 cm stroke turns even a side-heavy cube only ~12 deg: it slides.
        return [(np.eye(3), 1.0)]
    if STATE_YAW[s] % 2 == 1:
        if name == 'LIFT' and d is not None and abs(d[2]) < _TOL:
            # The pads squeeze two vertical edges; the heavy side swings down about the
            # hand axis (y) and the cube, set down on an edge, falls either way: heavy face
            # down, or heavy face towards the robot's side it was on.
            swing = rot_y(90.0 * np.sign(d[0]))
            side = np.sign(d[1])
            return [(rot_x(-45.0 * side) @ swing, 0.5), (rot_x(45.0 * side) @ swing, 0.5)]
        return [(np.eye(3), 1.0)]                                    # no face contact
    if name == 'LIFT':
        # A firm grip holds a top-heavy cube level; only a front/back-heavy one swings.
        if _is(d, [1, 0, 0]):
            return [(rot_y(90.0), 1.0)]
        if _is(d, [-1, 0, 0]):
            return [(rot_y(-90.0), 1.0)]
        return [(np.eye(3), 1.0)]
    # FLIP: the hands hold the ±y faces, so the roll is about y whatever the side mass.
    if _is(d, [0, 0, 1]):
        # The quarter roll leaves the heavy face towards the robot: it stays or tips on.
        return [(rot_y(180.0), 0.5), (rot_y(-90.0), 0.5)]
    if _is(d, [0, 0, -1]):
        return [(np.eye(3), 1.0)]
    if _is(d, [1, 0, 0]):
        # The roll lifts the heavy face first: the grip slips, rolls it, or it rolls back.
        return [(np.eye(3), 1 / 3), (rot_y(-90.0), 1 / 3), (rot_y(90.0), 1 / 3)]
    return [(rot_y(-90.0), 1.0)]                                     # uniform, -x, +-y


def apply_rotation(rotation, state) -> int:
    """Successor state after rotating the cube by `rotation` (in V) from `state`."""
    return state_from_rotation(np.asarray(rotation) @ STATE_ROTATIONS[_check_state(state)])


def canonical_faces(faces) -> np.ndarray:
    """Lexicographically smallest face tuple over the 24 rotations, for (..., 6) tag arrays."""
    faces = np.asarray(faces)
    variants = faces[..., ROTATION_FACE_SOURCE]                        # (..., 24, 6)
    best = lexmin_index(variants.reshape(-1, 24, NUM_FACES))
    flat = variants.reshape(-1, 24, NUM_FACES)
    return flat[np.arange(flat.shape[0]), best].reshape(faces.shape)


def lexmin_index(rows: np.ndarray) -> np.ndarray:
    """Index along axis 1 of the lexicographically smallest row, for a (B, R, L) int array."""
    rows = np.asarray(rows, dtype=np.int64)
    base = int(rows.max(initial=0)) + 2
    code = np.zeros(rows.shape[:2], dtype=np.int64)
    for j in range(rows.shape[2]):                                    # L <= 6: no overflow
        code = code * base + (rows[:, :, j] + 1)
    return code.argmin(axis=1)
