"""A population of ARcube models and their Aspect Transition Graphs (paper III-A).

Node n = 48 * model + state. Transitions depend only on (mass index, state), so
they live in small outcome tables (8, 7, 48, K); the per-action N x N CSR
matrices are built from them with array operations.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from abp_description.frames import rot_z_deg

from . import cube
from .cube import ACTIONS, NUM_MASS_VARIANTS, STATES_PER_MODEL
from .observation import ObservationModel, ObservationParams
from .transition_tables import dense_table, neighbourhood, sparse_tables

__all__ = ['TransitionParams', 'ObservationParams', 'ModelSet', 'PairGaussians',
           'build_outcome_tables', 'MAX_NODES']

MAX_OUTCOMES = 3            # K before the unmodelled outcomes: nominal + two neighbours
MAX_NODES = 4_000_000       # ~1 GB of transition matrices; larger sets need pruning first


@dataclass(frozen=True)
class TransitionParams:
    p_orbit_slip: float = 0.05       # ORBIT lands one 45 deg step off (half each way)
    p_fail_push: float = 0.1         # manual action fails: no change
    p_fail_lift: float = 0.1
    p_fail_flip: float = 0.1
    p_push_neighbour: float = 0.02   # PUSH pivots the other way round (sliding: +-45 half each)
    # Corrected rules only: a manual action ends in a neighbouring state that no rule names.
    p_unmodelled: float = 0.05
    rules: str = 'corrected'         # nominal outcomes: cube.TRANSITION_RULES (MODEL.md)

    def __post_init__(self):
        cube.check_transition_rules(self.rules)
        for name in self.noise_names():
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= float(value) < 1.0):
                raise ValueError(f'TransitionParams.{name} must be in [0, 1), got {value!r}')
        if self.p_fail_push + self.p_push_neighbour >= 1.0:
            raise ValueError('TransitionParams: p_fail_push + p_push_neighbour must be < 1')

    @classmethod
    def noise_names(cls) -> tuple[str, ...]:
        """The probability fields (all but `rules`)."""
        return tuple(f.name for f in fields(cls) if f.name != 'rules')

    def fail_rates(self) -> dict:
        """Manual action name -> probability that it fails and nothing changes."""
        return {'PUSH': self.p_fail_push, 'LIFT': self.p_fail_lift, 'FLIP': self.p_fail_flip}


class PairGaussians(NamedTuple):
    """Inter-feature distance Gaussians of one aspect (all feature pairs i < j)."""
    slots: np.ndarray    # (P, 2) slot indices into the aspect's features
    tags: np.ndarray     # (P, 2) tag ids of the two features
    mean: np.ndarray     # (P,) expected distance (m)
    sigma: np.ndarray    # (P,) its standard deviation (m)


def _state_distribution(outcomes) -> tuple[list[int], list[float]]:
    """Merge (rotation, prob) outcomes into distinct successor states."""
    merged: dict[int, float] = {}
    for rotation, prob, state in outcomes:
        if prob > 0.0:
            nxt = cube.apply_rotation(rotation, state)
            merged[nxt] = merged.get(nxt, 0.0) + prob
    return list(merged), list(merged.values())


def build_outcome_tables(params: TransitionParams | None = None):
    """outcome_states / outcome_probs (len(ACTIONS), 7, 48, K) from the physics in MODEL.md.

    The nominal motions come from ``cube.nominal_outcomes`` under ``params.rules``
    (geometry of R and the mass direction); the failure model adds the no-change /
    neighbour outcomes.
    Unused slots hold the state itself with probability 0.
    """
    p = params if params is not None else TransitionParams()
    shape = (len(ACTIONS), NUM_MASS_VARIANTS, STATES_PER_MODEL, MAX_OUTCOMES)
    states = np.empty(shape, dtype=np.int16)
    probs = np.zeros(shape, dtype=np.float64)
    states[:] = np.arange(STATES_PER_MODEL, dtype=np.int16)[None, None, :, None]
    fail = p.fail_rates()
    eye = np.eye(3)
    for a, name in enumerate(ACTIONS):
        for m in range(NUM_MASS_VARIANTS):
            if name in cube.ORBIT_STEPS and m > 0:
                states[a, m], probs[a, m] = states[a, 0], probs[a, 0]   # mass-independent
                continue
            for s in range(STATES_PER_MODEL):
                nominal = cube.nominal_outcomes(a, m, s, p.rules)
                q = nominal[0][0]
                if name in cube.ORBIT_STEPS:
                    k = cube.ORBIT_STEPS[name]
                    outcomes = [(q, 1.0 - p.p_orbit_slip),
                                (rot_z_deg(45.0 * (k + 1)), p.p_orbit_slip / 2),
                                (rot_z_deg(45.0 * (k - 1)), p.p_orbit_slip / 2)]
                elif cube.STATE_YAW[s] % 2 == 1 and len(nominal) == 1 and np.allclose(q, eye):
                    outcomes = [(eye, 1.0)]                            # no face contact
                elif name == 'PUSH':
                    nb = p.p_push_neighbour
                    if np.allclose(q, eye):                            # slides
                        outcomes = [(eye, 1.0 - nb), (rot_z_deg(45.0), nb / 2),
                                    (rot_z_deg(-45.0), nb / 2)]
                    else:                                              # pivots; neighbour = reverse
                        outcomes = [(q, 1.0 - fail[name] - nb), (eye, fail[name]), (q.T, nb)]
                else:
                    outcomes = [(rot, (1.0 - fail[name]) * weight) for rot, weight in nominal]
                    outcomes.append((eye, fail[name]))
                nxt, pr = _state_distribution((rot, prob, s) for rot, prob in outcomes)
                states[a, m, s, :len(nxt)] = nxt
                probs[a, m, s, :len(pr)] = pr
    if p.rules == 'corrected' and p.p_unmodelled > 0.0:
        return _with_unmodelled_outcomes(states, probs, p.p_unmodelled)
    return states, probs


def _with_unmodelled_outcomes(states, probs, share: float):
    """The tables with `share` of every manual-action row spread evenly over the start
    state's neighbourhood (no change, +-45 deg yaw, the four quarter rolls about the
    horizontal axes: `transition_tables.neighbourhood('near')`, the learner's too).

    Why: the MuJoCo survey sees 5-15 % of outcomes no rule names (a cube turned while
    handled, a roll over an edge); a table that makes them impossible stops confidently
    wrong when one happens. ORBIT rows are unchanged (their slip is modelled)."""
    dense = dense_table(states, probs)
    near = neighbourhood('near').astype(np.float64)
    near /= near.sum(axis=1, keepdims=True)
    manual = [ACTIONS.index(name) for name in cube.MANUAL_ACTIONS]
    dense[manual] = (1.0 - share) * dense[manual] + share * near
    sparse_states, sparse_probs, _ = sparse_tables(dense, np.zeros_like(dense))
    return sparse_states, sparse_probs


_DEFAULT_TABLES: dict = {}


def _default_outcome_tables(params: TransitionParams):
    # Tables are a pure function of the params; cache them (read-only) across model sets.
    if params not in _DEFAULT_TABLES:
        states, probs = build_outcome_tables(params)
        states.flags.writeable = False
        probs.flags.writeable = False
        _DEFAULT_TABLES[params] = (states, probs)
    return _DEFAULT_TABLES[params]


def model_name(faces_row, mass_index) -> str:
    return 'c' + '-'.join(str(int(t)) for t in faces_row) + '/' + cube.MASS_NAMES[int(mass_index)]


class ModelSet:
    """Models (visual cube x mass variant), their ATG tables and the observation model.

    visual_id is computed from the faces: rows that are rotations of each other are
    the same visual cube; ids are dense, in order of first appearance.
    """

    def __init__(self, faces, mass, n_tags: int, names=None, cube_size: float = 0.10,
                 feature_sigma: float = 0.005,
                 transition_params: TransitionParams | None = None,
                 observation_params: ObservationParams | None = None,
                 outcome_tables=None, outcome_counts=None, learning: dict | None = None):
        self.n_tags = cube.check_n_tags(n_tags)
        faces = np.array(faces, dtype=np.int64, copy=True)
        mass = np.array(mass, dtype=np.int64, copy=True).reshape(-1)
        if faces.ndim != 2 or faces.shape[1] != 6 or faces.shape[0] < 1:
            raise ValueError(f'faces must have shape (M >= 1, 6), got {faces.shape}')
        if mass.shape != (faces.shape[0],):
            raise ValueError(f'mass must have shape ({faces.shape[0]},), got {mass.shape}')
        if faces.min() < 0 or faces.max() >= self.n_tags:
            raise ValueError(f'tag ids must be in 0..{self.n_tags - 1}')
        if (np.sort(faces, axis=1)[:, 1:] == np.sort(faces, axis=1)[:, :-1]).any():
            raise ValueError('each cube needs 6 distinct tags')
        if mass.min() < 0 or mass.max() >= NUM_MASS_VARIANTS:
            raise ValueError(f'mass indices must be in 0..{NUM_MASS_VARIANTS - 1}')
        if faces.shape[0] * STATES_PER_MODEL > MAX_NODES:
            raise ValueError(f'{faces.shape[0]} models = {faces.shape[0] * STATES_PER_MODEL} '
                             f'nodes exceeds MAX_NODES = {MAX_NODES}; use a subset')
        if not (np.isfinite(cube_size) and cube_size > 0):
            raise ValueError(f'cube_size must be > 0 m, got {cube_size}')
        if not (np.isfinite(feature_sigma) and feature_sigma > 0):
            raise ValueError(f'feature_sigma must be > 0 m, got {feature_sigma}')
        self.cube_size = float(cube_size)
        self.feature_sigma = float(feature_sigma)
        self.transition_params = transition_params or TransitionParams()
        self.observation_params = observation_params or ObservationParams()

        self.faces = faces.astype(np.int16)
        self.mass = mass.astype(np.int8)
        self.num_models = faces.shape[0]
        self.num_nodes = self.num_models * STATES_PER_MODEL

        # Visual identity from the canonical (rotation-free) face tuple.
        canon = cube.canonical_faces(faces)
        codes = (canon * (self.n_tags ** np.arange(5, -1, -1, dtype=np.int64))).sum(axis=1)
        _, first, inverse = np.unique(codes, return_index=True, return_inverse=True)
        rank = np.empty(first.size, dtype=np.int32)
        rank[np.argsort(first, kind='stable')] = np.arange(first.size, dtype=np.int32)
        self.visual_id = rank[inverse.reshape(-1)]
        self.num_visual_cubes = int(first.size)
        model_codes = codes * NUM_MASS_VARIANTS + mass
        if np.unique(model_codes).size != self.num_models:
            raise ValueError('duplicate models (same visual cube and mass variant)')

        if names is None:
            names = [model_name(f, m) for f, m in zip(self.faces, self.mass)]
        self.names = [str(n) for n in names]
        if len(self.names) != self.num_models or len(set(self.names)) != self.num_models:
            raise ValueError('names must be unique, one per model')

        self._build_aspects()
        self.observation = ObservationModel(self.aspects, self.n_tags, self.observation_params)
        self._set_outcome_tables(outcome_tables)
        self._set_outcome_counts(outcome_counts)
        self.learning = dict(learning) if learning else None
        self._build_transitions()

    # -- construction -----------------------------------------------------------------------
    def _build_aspects(self):
        f = self.faces.astype(np.int64)
        even = cube.STATE_ASPECT_TYPE == 2
        keys = np.empty((self.num_models, STATES_PER_MODEL, 4), dtype=np.int64)
        keys[:, :, 0] = cube.STATE_ASPECT_TYPE
        keys[:, :, 1] = f[:, cube.STATE_TOP_FACE]
        keys[:, :, 2] = np.where(even, f[:, cube.STATE_FRONT_FACE], f[:, cube.STATE_PLUS_Y_FACE])
        keys[:, :, 3] = np.where(even, -1, f[:, cube.STATE_MINUS_Y_FACE])
        base = self.n_tags + 1
        code = ((keys[..., 0] * base + keys[..., 1] + 1) * base + keys[..., 2] + 1) * base \
            + keys[..., 3] + 1
        unique_codes, inverse = np.unique(code.reshape(-1), return_inverse=True)
        self.node_aspect = inverse.reshape(-1).astype(np.int32)
        # Decode the sorted unique codes back to (type, s0, s1, s2).
        aspects = np.empty((unique_codes.size, 4), dtype=np.int64)
        rest = unique_codes
        for col in (3, 2, 1):
            aspects[:, col] = rest % base - 1
            rest = rest // base
        aspects[:, 0] = rest
        self.aspects = aspects.astype(np.int16)
        self.num_aspects = self.aspects.shape[0]

    def _set_outcome_tables(self, outcome_tables):
        if outcome_tables is None:
            states, probs = _default_outcome_tables(self.transition_params)
        else:
            states, probs = (np.asarray(t) for t in outcome_tables)
            if states.ndim != 4 or states.shape[:3] != (len(ACTIONS), NUM_MASS_VARIANTS,
                                                        STATES_PER_MODEL) \
                    or probs.shape != states.shape:
                raise ValueError('outcome tables must both have shape '
                                 f'({len(ACTIONS)}, {NUM_MASS_VARIANTS}, {STATES_PER_MODEL}, K), '
                                 f'got {states.shape} and {probs.shape}')
            if states.min() < 0 or states.max() >= STATES_PER_MODEL:
                raise ValueError('outcome_states must be in 0..47')
            if not np.isfinite(probs).all() or probs.min() < 0 \
                    or not np.allclose(probs.sum(axis=3), 1.0, atol=1e-9):
                raise ValueError('outcome_probs must be >= 0 and sum to 1 per '
                                 '(action, mass, state)')
            states = states.astype(np.int16)
            probs = probs.astype(np.float64)
        self.outcome_states = states
        self.outcome_probs = probs

    def _set_outcome_counts(self, outcome_counts):
        # Learned tables: the (weighted) experience behind each edge; None = hand-written.
        if outcome_counts is None:
            self.outcome_counts = None
            return
        counts = np.asarray(outcome_counts, dtype=np.float64)
        if counts.shape != self.outcome_states.shape:
            raise ValueError(f'outcome_counts must have the shape of outcome_states '
                             f'{self.outcome_states.shape}, got {counts.shape}')
        if not np.isfinite(counts).all() or counts.min() < 0:
            raise ValueError('outcome_counts must be finite and >= 0')
        self.outcome_counts = counts

    def _build_transitions(self):
        node_model = np.repeat(np.arange(self.num_models, dtype=np.int64), STATES_PER_MODEL)
        node_state = np.tile(np.arange(STATES_PER_MODEL, dtype=np.int64), self.num_models)
        node_mass = self.mass.astype(np.int64)[node_model]
        base = node_model * STATES_PER_MODEL
        self.transitions: dict[str, sp.csr_matrix] = {}
        self._transposes: dict[int, sp.csr_matrix] = {}
        for a, name in enumerate(ACTIONS):
            nxt = self.outcome_states[a][node_mass, node_state].astype(np.int64) + base[:, None]
            pr = self.outcome_probs[a][node_mass, node_state]
            keep = pr > 0.0
            indptr = np.concatenate(([0], np.cumsum(keep.sum(axis=1))))
            matrix = sp.csr_matrix((pr[keep], nxt[keep].astype(np.int32), indptr),
                                   shape=(self.num_nodes, self.num_nodes))
            matrix.sum_duplicates()                                    # also sorts indices
            self.transitions[name] = matrix

    # -- queries ----------------------------------------------------------------------------
    def transition_transpose(self, action) -> sp.csr_matrix:
        """T^T as CSR (row = to-node), cached: predict is then one CSR mat-vec."""
        a = cube.action_index(action)
        if a not in self._transposes:
            self._transposes[a] = self.transitions[ACTIONS[a]].T.tocsr()
        return self._transposes[a]

    def successors(self, action_index, nodes):
        """Successor nodes (len, K) and their probabilities (len, K) of `nodes` under an action.

        Padding entries have probability 0 (and repeat the node itself).
        """
        a = cube.action_index(action_index)
        nodes = np.asarray(nodes, dtype=np.int64)
        model, state = np.divmod(nodes, STATES_PER_MODEL)
        m = self.mass.astype(np.int64)[model]
        nxt = (self.outcome_states[a][m, state].astype(np.int64)
               + (model * STATES_PER_MODEL)[..., None])
        return nxt, self.outcome_probs[a][m, state].copy()

    def aspect_key(self, aspect_row) -> tuple:
        return tuple(int(v) for v in self.aspects[int(aspect_row)])

    def aspect_row(self, key) -> int | None:
        """Row of aspect key (type, s0, s1, s2), or None if no node of this set shows it."""
        return self.observation.aspect_row(key)

    def node_of(self, model_index, state) -> int:
        return int(model_index) * STATES_PER_MODEL + int(state)

    def model_index(self, name: str) -> int:
        return self.names.index(name)

    def aspect_feature_tags(self, aspect_row) -> np.ndarray:
        """Tag ids of the features of an aspect, in slot order (2 or 3)."""
        row = self.aspects[int(aspect_row)]
        return row[1:1 + int(row[0])].astype(np.int64)

    def aspect_feature_positions(self, aspect_row) -> np.ndarray:
        """(k, 3) face-centre positions in V (cube centre at the origin), in slot order."""
        k = int(self.aspects[int(aspect_row), 0])
        return cube.FEATURE_UNIT_POSITIONS[k] * self.cube_size

    def aspect_pair_gaussians(self, aspect_row) -> PairGaussians:
        """Pairwise feature-distance Gaussians (mean, sigma) of an aspect for the Hough matcher."""
        pos = self.aspect_feature_positions(aspect_row)
        tags = self.aspect_feature_tags(aspect_row)
        i, j = np.triu_indices(len(pos), k=1)
        mean = np.linalg.norm(pos[i] - pos[j], axis=1)
        return PairGaussians(np.stack([i, j], axis=1), np.stack([tags[i], tags[j]], axis=1),
                             mean, np.full(mean.shape, self.feature_sigma))

    def models_per_aspect(self) -> np.ndarray:
        """(A,) number of models that show each aspect in at least one state."""
        pairs = np.unique(self.node_aspect.astype(np.int64)
                          + self.num_aspects * np.repeat(np.arange(self.num_models),
                                                         STATES_PER_MODEL))
        return np.bincount(pairs % self.num_aspects, minlength=self.num_aspects)

    def subset(self, model_indices) -> "ModelSet":
        idx = np.asarray(model_indices, dtype=np.int64).reshape(-1)
        if idx.size == 0 or idx.min() < -self.num_models or idx.max() >= self.num_models:
            raise ValueError('model_indices must be a non-empty list of valid model indices')
        return ModelSet(self.faces[idx], self.mass[idx], self.n_tags,
                        names=[self.names[i] for i in idx], cube_size=self.cube_size,
                        feature_sigma=self.feature_sigma,
                        transition_params=self.transition_params,
                        observation_params=self.observation_params,
                        outcome_tables=(self.outcome_states, self.outcome_probs),
                        outcome_counts=self.outcome_counts, learning=self.learning)

    def __repr__(self) -> str:
        return (f'ModelSet(n_tags={self.n_tags}, models={self.num_models}, '
                f'visual_cubes={self.num_visual_cubes}, nodes={self.num_nodes}, '
                f'aspects={self.num_aspects})')
