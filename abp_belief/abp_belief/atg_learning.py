"""Learned Aspect Transition Graphs: p(next state | action, mass variant, state) from experience.

The science of `learn_atg` (issue 13), plain NumPy, no rclpy.

**Experience** is a list of weighted transitions (action, mass index, state, next state,
weight) in the models' state indexing (docs/MODEL.md: ``8 * up + yaw``, relative to the
robot). `experience_from_survey` reads them from the MuJoCo ``outcome_survey`` JSON (one
transition per trial that ran, at its class representative; ``--trials-per-class`` keeps
the first n of each class). A weight below 1 is a partial observation (e.g. a transition
inferred with that posterior from a bag).

**Pooling** (`CLASS_OF`, `pooled_counts`). The world is a box whose only asymmetry is the
heavy slab, so the physics of a start cell depends only on the box's orientation in the
view frame V, fixed by the yaw parity, and on the mass direction d in V. Cells with the
same (action, yaw parity, d) are one class; d is `uniform` or one of the 6 axis directions
(even yaw: +-x_V, +-y_V, +-z_V) or +-z_V and the 4 horizontal diagonals (odd yaw): 7 classes
per parity, 14 per manual action for the 336 cells. ORBIT never touches the cube: its
classes are the 2 parities for every mass (the survey's classes exactly,
`abp_bench.outcome_survey.cell_key`). No mirror symmetry is used (the robot's arms are not
mirror images). A transition s -> s' of a class member is the motion Q = R(s') R(s)^T in V;
it is counted at the class representative as `apply_rotation(Q, rep)` and every member
receives the class's counts mapped back the same way (`map_outcome`, the survey's
comparison step). So every member of a class shows the same (pooled) counts and the same
learned row, in its own state indexing.

**Estimate** (`learn`). Per cell, the posterior mean of a Dirichlet:
``p = (n + alpha * mu) / (N + alpha)``, n the pooled counts, N their sum, alpha the prior
concentration (in pseudo-trials) and mu the prior mean. Default prior (``'table'``): mu =
(1 - epsilon) * the hand-written table of docs/MODEL.md + epsilon * uniform over a small
neighbourhood of the start state. Why: the table is the paper's physics and its failure
model, an informed guess that a few trials should correct, not discard; with little data
the learned model stays near it (a cell never tried is the table plus a sliver), with much
data the counts dominate. The neighbourhood term makes outcomes that neither the table nor
the data contain still possible: one surprising outcome then lowers the true object's
belief instead of killing it. ``'uniform'``: mu uniform over the neighbourhood and the
table's support (no preference for the table's nominal outcome). Neighbourhoods
(manual actions): ``near`` = no change, +-45 deg yaw, the four quarter rolls about the
horizontal body axes (7 states); ``wide`` = {no change, the 4 quarter rolls, the 2 half
rolls} x {yaw 0, +-45 deg} (21 states); ``none``. ORBIT's neighbourhood is the table's
support (nominal and one step off each way). Transitions in none of these, seen zero times,
stay impossible; they are also physically implausible for one skill.

Each cell keeps its counts (`LearnedTables.counts`; per outcome: how often the edge was
seen, and their sum: how many trials back the row), stored in the model file's
``outcome_counts`` (format version 2).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from abp_description.frames import axis_angle_deg

from . import cube
from .cube import (
    ACTIONS,
    NUM_MASS_VARIANTS,
    ORBIT_STEPS,
    STATE_ROTATIONS,
    STATES_PER_MODEL,
)
from .modelset import ModelSet, TransitionParams, build_outcome_tables
from .transition_tables import (
    DEFAULT_NEIGHBOURHOOD,
    NEIGHBOURHOODS,
    LearningError,
    axis_rotation,
    dense_table,
    neighbourhood,
    sparse_tables,
    states_of_rotations,
)

PRIORS = ('table', 'uniform')
DEFAULT_ALPHA = 2.0
DEFAULT_EPSILON = 0.1
TV_HIGHLIGHT = 0.1
_NA, _NM, _NS = len(ACTIONS), NUM_MASS_VARIANTS, STATES_PER_MODEL


# -- state geometry ---------------------------------------------------------------------
def _map_table() -> np.ndarray:
    """MAP[s, s2, t]: the state t goes to under the motion Q = R(s2) R(s)^T (-1: no state)."""
    q = STATE_ROTATIONS[None, :] @ np.swapaxes(STATE_ROTATIONS, 1, 2)[:, None]   # (48, 48)
    moved = q[:, :, None] @ STATE_ROTATIONS[None, None]                          # (48,48,48)
    return states_of_rotations(moved).astype(np.int16)


MAP = _map_table()


def map_outcome(from_state, next_state, to_state):
    """The next state of `to_state` under the motion `from_state` -> `next_state` (-1: none).

    Vectorised; the same motion in V as `abp_bench.outcome_survey.map_outcome`."""
    return MAP[from_state, next_state, to_state]


def _direction_key(d) -> str:
    if d is None:
        return 'uniform'
    d = np.round(d, 6)
    return ''.join(('+' if v > 0 else '-') + axis for v, axis in zip(d, 'xyz')
                   if abs(v) > 1e-6) + '_V'


def _classes():
    """CLASS_OF (8, 7, 48) class index per action, CLASS_LABELS [action][class] and
    CLASS_REP [action][class] = (mass, state) of the first member (mass-major order, as
    the survey's build_classes)."""
    class_of = np.empty((_NA, _NM, _NS), dtype=np.int64)
    labels, reps = [], []
    for a, action in enumerate(ACTIONS):
        index: dict[str, int] = {}
        rep = []
        for m in range(_NM):
            for s in range(_NS):
                parity = 'even' if s % 2 == 0 else 'odd'
                if action in ORBIT_STEPS:
                    key = f'any mass, {parity} yaw'
                else:
                    d = _direction_key(cube.mass_direction(m, s))
                    key = f'uniform, {parity} yaw' if d == 'uniform' else f'mass {d}, {parity} yaw'
                if key not in index:
                    index[key] = len(index)
                    rep.append((m, s))
                class_of[a, m, s] = index[key]
        labels.append(list(index))
        reps.append(rep)
    return class_of, labels, reps


CLASS_OF, CLASS_LABELS, CLASS_REP = _classes()
_MAX_CLASSES = max(len(r) for r in CLASS_REP)
_REP_STATE = np.full((_NA, _MAX_CLASSES), -1, dtype=np.int64)
for _a, _reps in enumerate(CLASS_REP):
    _REP_STATE[_a, :len(_reps)] = [s for _, s in _reps]


# -- experience --------------------------------------------------------------------------
@dataclass
class Experience:
    """Weighted transitions in the models' state indexing."""

    action: np.ndarray        # (E,) action index
    mass: np.ndarray          # (E,) mass index
    state: np.ndarray         # (E,) start state
    next_state: np.ndarray    # (E,) next state
    weight: np.ndarray        # (E,) > 0, 1 = one fully observed trial
    source: dict = field(default_factory=dict)

    def __post_init__(self):
        arrays = [np.asarray(x).reshape(-1) for x in (self.action, self.mass, self.state,
                                                       self.next_state)]
        n = arrays[0].size
        if any(a.size != n for a in arrays) or np.asarray(self.weight).size != n:
            raise LearningError('experience arrays must have the same length')
        self.action, self.mass, self.state, self.next_state = (a.astype(np.int64)
                                                                for a in arrays)
        self.weight = np.asarray(self.weight, dtype=np.float64).reshape(-1)
        for name, values, hi in (('action', self.action, _NA), ('mass', self.mass, _NM),
                                 ('state', self.state, _NS), ('next_state', self.next_state, _NS)):
            if n and (values.min() < 0 or values.max() >= hi):
                raise LearningError(f'experience {name} out of range 0..{hi - 1}')
        if n and not (np.isfinite(self.weight).all() and self.weight.min() > 0):
            raise LearningError('experience weights must be finite and > 0')

    def __len__(self) -> int:
        return int(self.action.size)

    @classmethod
    def concatenate(cls, parts: list[Experience]) -> Experience:
        """One experience of all `parts`' transitions (e.g. two surveys of the same world
        with different seeds); `source` lists the parts' sources."""
        if not parts:
            raise LearningError('no experience to concatenate')
        if len(parts) == 1:
            return parts[0]
        return cls(*(np.concatenate([getattr(e, name) for e in parts])
                     for name in ('action', 'mass', 'state', 'next_state', 'weight')),
                   source=dict(kind='concatenated', parts=[e.source for e in parts],
                               transitions=sum(len(e) for e in parts)))


def experience_from_survey(survey, trials_per_class: int | None = None,
                           subsample_seed: int | None = None) -> Experience:
    """Transitions of an `outcome_survey` JSON (path or parsed dict): one per trial that ran,
    at its class representative (mass, state) -> final_state.

    trials_per_class: keep n trials of each (action, class): the first n by trial index, or
    n drawn at random with `subsample_seed`. None keeps all."""
    path = None
    if isinstance(survey, (str, os.PathLike)):
        path = os.fspath(survey)
        try:
            with open(path) as stream:
                survey = json.load(stream)
        except FileNotFoundError:
            raise LearningError(f'{path}: no such file') from None
        except (OSError, ValueError) as exc:
            raise LearningError(f'{path}: not a readable survey JSON ({exc})') from None
    where = path or 'survey'
    if not isinstance(survey, dict) or not isinstance(survey.get('trials'), list):
        raise LearningError(f"{where}: no 'trials' list (not an outcome_survey JSON)")
    if trials_per_class is not None and trials_per_class < 1:
        raise LearningError('trials_per_class must be >= 1')
    groups: dict[tuple, list] = {}
    try:
        for record in survey['trials']:
            if not record.get('ran', True) or record.get('final_state') is None:
                continue
            key = (record['action'], record.get('klass', ''))
            groups.setdefault(key, []).append(
                (int(record.get('trial', 0)), cube.action_index(record['action']),
                 int(record['mass']), int(record['state']), int(record['final_state'])))
    except (KeyError, TypeError, ValueError) as exc:
        raise LearningError(f'{where}: bad trial record ({exc!r})') from None
    rng = np.random.default_rng(subsample_seed) if subsample_seed is not None else None
    rows = []
    for key in sorted(groups):
        trials = sorted(groups[key])
        if trials_per_class is not None and len(trials) > trials_per_class:
            if rng is None:
                trials = trials[:trials_per_class]
            else:
                pick = np.sort(rng.choice(len(trials), trials_per_class, replace=False))
                trials = [trials[i] for i in pick]
        rows += [t[1:] for t in trials]
    data = np.array(rows, dtype=np.int64).reshape(-1, 4)
    settings = survey.get('settings', {})
    return Experience(data[:, 0], data[:, 1], data[:, 2], data[:, 3], np.ones(len(data)),
                      source=dict(kind='outcome_survey', path=path,
                                  trials=settings.get('trials'), seed=settings.get('seed'),
                                  trials_per_class=trials_per_class,
                                  subsample_seed=subsample_seed, transitions=len(data)))


def survey_cell_counts(survey) -> np.ndarray:
    """(8, 7, 48, 48) counts exactly as the survey's comparison step stored them (its
    ``cells``), for checking `pooled_counts` against it."""
    if isinstance(survey, (str, os.PathLike)):
        with open(survey) as stream:
            survey = json.load(stream)
    counts = np.zeros((_NA, _NM, _NS, _NS))
    for cell in survey['cells']:
        a = cube.action_index(cell['action'])
        for nxt, c in cell['counts'].items():
            counts[a, int(cell['mass_index']), int(cell['state']), int(nxt)] = c
    return counts


# -- counting, prior, estimate -------------------------------------------------------------
def pooled_counts(experience: Experience, pool: bool = True) -> np.ndarray:
    """(8, 7, 48, 48) weighted counts per start cell. pool=True: every cell gets its class's
    counts (module doc); pool=False: each transition counts at its own cell only."""
    counts = np.zeros((_NA, _NM, _NS, _NS))
    e = experience
    if not pool:
        np.add.at(counts, (e.action, e.mass, e.state, e.next_state), e.weight)
        return counts
    klass = CLASS_OF[e.action, e.mass, e.state]
    rep = _REP_STATE[e.action, klass]
    at_rep = MAP[e.state, e.next_state, rep].astype(np.int64)
    if (at_rep < 0).any():                      # cannot happen for states of one class
        raise LearningError('a transition does not map onto its class representative')
    class_counts = np.zeros((_NA, _MAX_CLASSES, _NS))
    np.add.at(class_counts, (e.action, klass, at_rep), e.weight)
    # Broadcast: cell (a, m, s) of class c gets class_counts[a, c, n] at MAP[rep, n, s].
    a, m, s, n = np.indices((_NA, _NM, _NS, _NS)).reshape(4, -1)
    c = CLASS_OF[a, m, s]
    values = class_counts[a, c, n]
    keep = values > 0
    target = MAP[_REP_STATE[a, c], n, s].astype(np.int64)
    np.add.at(counts, (a[keep], m[keep], s[keep], target[keep]), values[keep])
    return counts


def hand_table(params: TransitionParams | None = None) -> np.ndarray:
    """The hand-written table of docs/MODEL.md, dense (8, 7, 48, 48) (a fresh copy)."""
    return _hand_table(params or TransitionParams()).copy()


@functools.lru_cache(maxsize=4)
def _hand_table(params: TransitionParams) -> np.ndarray:
    return dense_table(*build_outcome_tables(params))


def prior_mean(prior: str = 'table', epsilon: float = DEFAULT_EPSILON,
               neighbourhood_kind: str = DEFAULT_NEIGHBOURHOOD,
               params: TransitionParams | None = None) -> np.ndarray:
    """(8, 7, 48, 48) prior mean mu of every cell (module doc)."""
    if prior not in PRIORS:
        raise LearningError(f"prior must be one of {', '.join(PRIORS)}, got {prior!r}")
    if not 0.0 <= epsilon <= 1.0:
        raise LearningError(f'epsilon must be in [0, 1], got {epsilon}')
    # epsilon is the prior's share of unmodelled outcomes: not on top of the table's own.
    table = hand_table(dataclasses.replace(params or TransitionParams(), p_unmodelled=0.0))
    near = np.broadcast_to(neighbourhood(neighbourhood_kind), (_NA, _NM, _NS, _NS)).copy()
    for a, action in enumerate(ACTIONS):
        if action in ORBIT_STEPS:
            near[a] = table[a] > 0                  # ORBIT: nominal and one step off
    if prior == 'uniform':
        support = near | (table > 0)
        return support / support.sum(axis=3, keepdims=True)
    spread = near / np.maximum(near.sum(axis=3, keepdims=True), 1)
    spread = np.where(near.any(axis=3, keepdims=True), spread, table)
    return (1.0 - epsilon) * table + epsilon * spread


@dataclass
class LearnedTables:
    """Learned p(next | action, mass, state), dense, with the counts behind each row."""

    probs: np.ndarray         # (8, 7, 48, 48), rows sum to 1
    counts: np.ndarray        # (8, 7, 48, 48) pooled weighted counts
    info: dict                # provenance: source, alpha, prior, epsilon, pooling, timing

    @property
    def trials(self) -> np.ndarray:
        """(8, 7, 48) experience behind each row (the Dirichlet's N)."""
        return self.counts.sum(axis=3)

    def outcome_tables(self, min_prob: float = 0.0):
        """Sparse (outcome_states int16, outcome_probs, outcome_counts), each (8, 7, 48, K):
        per cell its successors with p > min_prob (renormalised), most likely first; K the
        largest support; padding repeats the start state with probability and count 0."""
        return sparse_tables(self.probs, self.counts, min_prob)


def with_contact_faults(probs: np.ndarray, fault_rates: dict) -> np.ndarray:
    """(8, 7, 48, 48) rows with each manual action's `fault_rates[action]` of 'no change'
    mixed in: p' = (1 - f) p + f * [next == state].

    Why: the MuJoCo survey runs the skills without robot faults, so it measures how the
    *object* responds when the hands make the planned contact. On the robot a push can
    miss and a grasp slip while the skill reports success (`--faults` in the sim): then
    nothing moves whatever the object. Without this term a learned row gives 'no change'
    the prior's sliver only (about 1 % after 20 trials), and one slipped FLIP of a uniform
    cube reads as strong evidence for a twin that rolls less."""
    unknown = set(fault_rates) - set(ACTIONS)
    if unknown:
        raise LearningError(f'fault rates for unknown actions: {sorted(unknown)}')
    out = np.array(probs, dtype=np.float64, copy=True)
    eye = np.eye(_NS)
    for action, rate in fault_rates.items():
        if not 0.0 <= rate < 1.0:
            raise LearningError(f'fault rate of {action} must be in [0, 1), got {rate}')
        if action in ORBIT_STEPS:
            raise LearningError(f'{action}: ORBIT does not touch the cube; no contact fault')
        a = ACTIONS.index(action)
        out[a] = (1.0 - rate) * out[a] + rate * eye[None, :, :]
    return out


def learn(experience: Experience, alpha: float = DEFAULT_ALPHA, prior: str = 'table',
          epsilon: float = DEFAULT_EPSILON, neighbourhood_kind: str = DEFAULT_NEIGHBOURHOOD,
          pool: bool = True, params: TransitionParams | None = None,
          fault_rates: dict | None = None) -> LearnedTables:
    """Dirichlet posterior-mean tables from `experience` (module doc).

    alpha = 0 gives the empirical frequencies where a cell has data (and the prior mean
    where it has none): the 'survey table' a world can be drawn from. `fault_rates`
    (action name -> rate, e.g. `TransitionParams().fail_rates()`): the robot's contact faults mixed
    into the learned rows (`with_contact_faults`); None or {} for experience that already
    holds them (the robot's own bags)."""
    if not (np.isfinite(alpha) and alpha >= 0):
        raise LearningError(f'alpha must be >= 0, got {alpha}')
    t0 = time.perf_counter()
    counts = pooled_counts(experience, pool=pool)
    mu = prior_mean(prior, epsilon, neighbourhood_kind, params)
    n = counts.sum(axis=3, keepdims=True)
    denom = n + alpha
    probs = np.where(denom > 0, (counts + alpha * mu) / np.where(denom > 0, denom, 1.0), mu)
    probs /= probs.sum(axis=3, keepdims=True)
    if fault_rates:
        probs = with_contact_faults(probs, fault_rates)
    info = dict(method='dirichlet posterior mean', alpha=float(alpha), prior=prior,
                epsilon=float(epsilon), neighbourhood=neighbourhood_kind, pooled=bool(pool),
                contact_fault_rates={k: float(v) for k, v in (fault_rates or {}).items()},
                transitions=len(experience), weight=float(experience.weight.sum()),
                source=experience.source, learn_s=round(time.perf_counter() - t0, 4))
    return LearnedTables(probs, counts, info)


# -- model sets --------------------------------------------------------------------------
def with_tables(model_set: ModelSet, tables_from) -> ModelSet:
    """`model_set`'s models with the transition tables of `tables_from` (a ModelSet, a
    LearnedTables, or a (states, probs[, counts]) tuple); everything else is kept."""
    counts, learning = None, None
    if isinstance(tables_from, ModelSet):
        states, probs = tables_from.outcome_states, tables_from.outcome_probs
        counts, learning = tables_from.outcome_counts, tables_from.learning
    elif isinstance(tables_from, LearnedTables):
        states, probs, counts = tables_from.outcome_tables()
        learning = tables_from.info
    else:
        states, probs, *rest = tables_from
        counts = rest[0] if rest else None
    return ModelSet(model_set.faces, model_set.mass, model_set.n_tags, names=model_set.names,
                    cube_size=model_set.cube_size, feature_sigma=model_set.feature_sigma,
                    transition_params=model_set.transition_params,
                    observation_params=model_set.observation_params,
                    outcome_tables=(states, probs), outcome_counts=counts, learning=learning)


# -- comparison ----------------------------------------------------------------------------
def total_variation(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Per cell 0.5 * sum |p - q| over next states."""
    return 0.5 * np.abs(np.asarray(p) - np.asarray(q)).sum(axis=-1)


def relative_outcomes(dist: np.ndarray, state: int, min_prob: float = 0.005) -> dict:
    """{motion name: p} of a (48,) next-state distribution from `state`."""
    out: dict[str, float] = {}
    for nxt in np.flatnonzero(dist > min_prob):
        name = motion_name(STATE_ROTATIONS[nxt] @ STATE_ROTATIONS[state].T)
        out[name] = out.get(name, 0.0) + float(dist[nxt])
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def motion_name(q) -> str:
    """'none', 'Rz+45', 'Ry-90', 'Rx180', 'R(+x+y)+90 Rz-45', ... (a roll, then a yaw)."""
    q = np.asarray(q, dtype=np.float64)
    for k in (0, 1, -1, 2, -2, 3, -3, 4):
        rest = axis_rotation(np.array([0.0, 0.0, 1.0]), -45.0 * k) @ q
        name = _roll_name(rest)
        if name is not None:
            if k == 0:
                return name
            yaw = 'Rz180' if k == 4 else f'Rz{45 * k:+d}'
            return yaw if name == 'none' else f'{name} {yaw}'
    return 'other'


def _roll_name(q) -> str | None:
    angle, axis = axis_angle_deg(q)
    if angle < 1.0:
        return 'none'
    if abs(axis[2]) > 1e-6 or abs(angle - 90) > 1 and angle < 179.0:
        return None                                     # not a roll about a horizontal axis
    nonzero = [i for i in range(2) if abs(axis[i]) > 1e-6]
    if len(nonzero) == 1:                               # about x_V or y_V: sign on the angle
        i = nonzero[0]
        if angle > 179.0:
            return f'R{"xy"[i]}180'
        return f'R{"xy"[i]}{round(np.sign(axis[i]) * angle):+d}'
    if angle > 179.0:
        axis *= np.sign(axis[nonzero[0]])
    parts = ''.join(('+' if axis[i] > 0 else '-') + 'xy'[i] for i in nonzero)
    return f'R({parts})180' if angle > 179.0 else f'R({parts}){round(angle):+d}'


def comparison_rows(learned: LearnedTables, hand: np.ndarray | None = None,
                    masses=range(_NM)) -> list[dict]:
    """One row per (action, class): pooled trials, learned and hand-written outcomes of the
    representative, and the largest per-cell total-variation distance in the class."""
    hand = hand_table() if hand is None else hand
    tv = total_variation(learned.probs, hand)
    rows = []
    for a, action in enumerate(ACTIONS):
        for c, label in enumerate(CLASS_LABELS[a]):
            members = [(m, s) for m, s in zip(*np.nonzero(CLASS_OF[a] == c)) if m in masses]
            if not members:
                continue
            m, s = members[0]
            rows.append(dict(
                action=action, klass=label, cells=len(members), rep=(int(m), int(s)),
                trials=float(learned.trials[a, m, s]),
                learned=relative_outcomes(learned.probs[a, m, s], s),
                hand=relative_outcomes(hand[a, m, s], s),
                tv_max=float(max(tv[a, mm, ss] for mm, ss in members)),
                tv_mean=float(np.mean([tv[a, mm, ss] for mm, ss in members]))))
    return rows


def comparison_markdown(learned: LearnedTables, hand: np.ndarray | None = None,
                        title: str = 'Learned vs hand-written ATG tables') -> str:
    """Side-by-side Markdown table; TV > 0.1 in bold with a mark."""
    hand = hand_table() if hand is None else hand
    rows = comparison_rows(learned, hand)
    tv = total_variation(learned.probs, hand)
    info = learned.info
    fmt = lambda d: ', '.join(f'{k} {100 * v:.0f}%' for k, v in d.items()) or '-'  # noqa: E731
    parts = info['source'].get('parts') or [info['source']]
    sources = ', '.join(f"{p.get('kind', '?')} {p.get('path') or ''}".strip() for p in parts)
    lines = [
        f'# {title}', '',
        f"Dirichlet posterior mean, alpha = {info['alpha']:g} pseudo-trials, prior "
        f"'{info['prior']}' (epsilon {info['epsilon']:g}, neighbourhood "
        f"'{info['neighbourhood']}'), pooled over the symmetry classes: "
        f"{info['pooled']}; {info['transitions']} transitions "
        f'(source: {sources}).',
        '',
        f'Cells with total-variation distance > {TV_HIGHLIGHT:g} between the learned and the '
        f'hand-written row: {int((tv > TV_HIGHLIGHT).sum())} of {tv.size}; mean TV '
        f'{tv.mean():.3f}. Per action: ' + ', '.join(
            f'{a} {int((tv[i] > TV_HIGHLIGHT).sum())}' for i, a in enumerate(ACTIONS)) + '.',
        '',
        'Outcomes are motions of the cube in the view frame V (`Rz-45`: 45 deg clockwise '
        'seen from above; `Ry-90`: front face rolled to the top; a roll then a yaw). '
        'Rows: one per (action, class); trials = pooled experience behind each of its cells.',
        '',
        '| action | class | cells | trials | learned | hand-written | TV max | TV mean |',
        '|---|---|---:|---:|---|---|---:|---:|',
    ]
    for r in rows:
        hi = r['tv_max'] > TV_HIGHLIGHT
        tv_cell = f"**{r['tv_max']:.2f}** X" if hi else f"{r['tv_max']:.2f}"
        lines.append(f"| {r['action']} | {r['klass']} | {r['cells']} | {r['trials']:g} | "
                     f"{fmt(r['learned'])} | {fmt(r['hand'])} | {tv_cell} | "
                     f"{r['tv_mean']:.2f} |")
    return '\n'.join(lines) + '\n'


__all__ = ['CLASS_LABELS', 'CLASS_OF', 'CLASS_REP', 'DEFAULT_ALPHA', 'DEFAULT_EPSILON',
           'DEFAULT_NEIGHBOURHOOD', 'Experience', 'LearnedTables', 'LearningError', 'MAP',
           'NEIGHBOURHOODS', 'PRIORS', 'comparison_markdown', 'comparison_rows', 'dense_table',
           'experience_from_survey', 'hand_table', 'learn', 'map_outcome', 'motion_name',
           'neighbourhood', 'pooled_counts', 'prior_mean', 'relative_outcomes',
           'survey_cell_counts', 'total_variation', 'with_tables']
