"""Active Belief Planner (Ruiken et al., Alg. 3) and its variants.

Plain NumPy, no rclpy. Every planner exposes
``choose(belief, feasible=None) -> Decision`` where ``belief`` is the (N,)
node belief (or anything with a ``.belief`` array, e.g. a
``abp_belief.filter.BeliefFilter``; it is read, never changed) and
``feasible(action_name) -> bool`` is the motion planner's verdict (``None``:
everything is feasible). Build one with ``make_planner(name, ...)``.

Conventions (docs/MODEL.md, docs/BELIEF_API.md): node = model * 48 + state,
``node_aspect`` maps a node to its aspect row, the observation likelihood
``p(z | x)`` depends on the aspect only and is precomputed
(``ObservationModel.aspect_likelihood[z_row, x_row]``). Entropies are of the
object marginal, in bits.

How Algorithm 3 is evaluated without loops over nodes or models
---------------------------------------------------------------
For an action ``a`` the predicted belief is ``bel⁻ = Tᵀ bel``. Every predicted
node ``x'`` above ``α·max bel⁻`` contributes ``bel⁻(x') H(o | z = aspect(x'))``.
Nodes with the same aspect have the same expected observation, hence the same
posterior, so the candidates are grouped by aspect: with
``P[m, x] = Σ bel⁻`` over the nodes of model ``m`` with aspect ``x``, the
unnormalised object posterior for an expected observation ``z`` is the row
``L[z, :] @ Pᵀ``; one matrix product gives all candidate aspects at once.
Nodes below the threshold contribute ``H(o_t)`` (Alg. 3 line 16).

Multi-ply lookahead, the cost-aware score and the tie rule are described on
``ActiveBeliefPlanner`` and ``TIE_TOLERANCE_BITS``; the α boundary on
``ALPHA_BOUNDARY_REL_EPS``; bounded planning time (anytime iterative
deepening) on ``ActiveBeliefPlanner.choose``.

Support floor: nodes whose belief is below ``support_floor · max bel``
(default 1e-12) are left out of the prediction. Their mass is numerically
zero next to the mode, so they cannot change an entropy beyond ~1e-9 bits, but
skipping them keeps the work proportional to the live part of the belief.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from abp_belief.cube import ACTIONS, NOMINAL_DURATION_S, STATES_PER_MODEL
from abp_belief.filter import entropy_bits

SUPPORT_FLOOR = 1e-12
# Expected gains closer than this are ties, resolved towards the shorter action.
# Not float noise only: once the top hypotheses are told apart only by an action
# that needs a preparatory move (FLIP from an aligned view, after ORBIT ±45°),
# every 1-ply gain is ~0 apart from crumbs on hypotheses at 1e-3; a strict
# argmax then chases those crumbs with long ORBITs while the cheap ±45° step
# that enables the decisive action is never taken.
TIE_TOLERANCE_BITS = 1e-3
# Alg. 3 line 8 keeps a predicted node iff bel⁻(x') > α·max bel⁻. With the default
# p_fail_lift = p_fail_flip = α = 0.1, the failed-LIFT/FLIP node of an eccentric
# twin sits *exactly* at α·max in exact arithmetic, so float round-off decided the
# strict test and gains jumped by up to 0.12 bits between runs. A node must now
# exceed the threshold by this relative margin: nodes within 1e-9 of the
# boundary are excluded, as exact arithmetic with the strict ">" excludes them.
ALPHA_BOUNDARY_REL_EPS = 1e-9


def above_alpha(mass: np.ndarray, peak, alpha: float) -> np.ndarray:
    """Alg. 3's candidate test ``mass > α·peak`` with the deterministic boundary."""
    return mass > alpha * (1.0 + ALPHA_BOUNDARY_REL_EPS) * peak


class SearchTimeout(Exception):
    """Raised inside the lookahead when the planning budget is spent."""


def _row_entropies_bits(u: np.ndarray) -> np.ndarray:
    """Entropy (bits) of every row of a non-negative matrix after normalising it."""
    q = u / u.sum(axis=1, keepdims=True)
    with np.errstate(divide='ignore', invalid='ignore'):
        terms = np.where(q > 0, q * np.log2(q), 0.0)
    return -terms.sum(axis=1)


@dataclass
class Decision:
    """What a planner chose and why."""

    action: str
    action_index: int
    information_gain: np.ndarray | None  # (len(ACTIONS),) expected IG in bits, None for random
    score: np.ndarray | None  # what was maximised (IG, or IG per second)
    entropy: float  # H(o_t) of the belief the decision was made on, bits
    planning_time_s: float
    infeasible: list[str] = field(default_factory=list)  # better-ranked actions refused
    search_depth: int = 1  # plies of the deepest search that completed (anytime planners)

    def as_dict(self) -> dict:
        return {
            'action': self.action,
            'information_gain': None
            if self.information_gain is None
            else dict(zip(ACTIONS, map(float, self.information_gain))),
            'entropy': self.entropy,
            'planning_time_s': self.planning_time_s,
            'infeasible': list(self.infeasible),
            'search_depth': self.search_depth,
        }


def _first_feasible(order, feasible):
    """Walk the ranking; infeasible actions fall through to the next best."""
    refused = []
    for index in order:
        name = ACTIONS[index]
        if feasible is None or feasible(name):
            return int(index), refused
        refused.append(name)
    raise RuntimeError('no feasible action: the motion planner refused ' + ', '.join(refused))


def _rank(score: np.ndarray, tolerance: float, tie_key: np.ndarray) -> list[int]:
    """Actions from best to worst; scores within ``tolerance`` of each other are ties,
    resolved by ``tie_key`` (smaller first) so float noise cannot pick the winner."""
    remaining = list(range(len(score)))
    order = []
    while remaining:
        best = max(score[i] for i in remaining)
        tied = [i for i in remaining if score[i] >= best - tolerance]
        pick = min(tied, key=lambda i: (tie_key[i], i))
        order.append(pick)
        remaining.remove(pick)
    return order


class RandomPlanner:
    """Uniformly random feasible action (the paper's baseline); seeded."""

    name = 'random'

    def __init__(self, model_set=None, seed: int = 0, **_ignored):
        self.rng = np.random.default_rng(seed)

    def choose(self, belief, feasible=None) -> Decision:
        start = time.perf_counter()
        order = self.rng.permutation(len(ACTIONS))
        index, refused = _first_feasible(order, feasible)
        return Decision(
            action=ACTIONS[index],
            action_index=index,
            information_gain=None,
            score=None,
            entropy=float('nan'),
            planning_time_s=time.perf_counter() - start,
            infeasible=refused,
        )


class ActiveBeliefPlanner:
    """Greedy / multi-ply expected-information-gain planner (Alg. 3).

    plies=1 is Algorithm 3 as published. plies>1 expands the tree with the same
    α pruning at every level: a branch is an expected observation (an aspect of
    a candidate node); its value is the expected entropy after the remaining
    plies, minimised over the next action. To keep deep plies affordable,
    branches with probability below ``branch_min_prob`` are not expanded (they
    are credited with the mean further reduction of the expanded ones, so the
    pruning does not favour actions with few outcomes) and branch beliefs are
    truncated to the nodes holding all but ``lookahead_tail`` of their mass;
    the gain of a truncated branch is measured against the truncated entropy.
    A plan is scored by its expected
    final entropy plus ``intermediate_weight`` times the entropies on the way:
    without that, "do nothing, then the best (d-1)-step plan" ties with "the
    best plan" whenever d-1 steps already settle the belief, and the lookahead
    stalls on no-op actions (seen with 3 plies: PUSH on uniform cubes forever).

    cost_aware=True maximises expected bits per second of nominal action time
    (``rates``): with plies=1 the 1-ply IG / duration, with plies=2 also every
    fixed two-step plan, charged for both actions.

    measure="error" replaces the entropy by 1 - max object posterior (the
    quantity the stopping rule looks at); an experiment, not used by the
    named planners.

    planning_budget_s (None: unbounded) makes the multi-ply planners anytime:
    see ``choose``. ``clock`` (default ``time.perf_counter``) is what the
    budget is measured with; tests inject a fake one.
    """

    def __init__(
        self,
        model_set,
        alpha: float = 0.1,
        plies: int = 1,
        cost_aware: bool = False,
        durations: dict | None = None,
        support_floor: float = SUPPORT_FLOOR,
        lookahead_tail: float = 1e-2,
        branch_min_prob: float = 0.05,
        tie_tolerance: float = TIE_TOLERANCE_BITS,
        intermediate_weight: float = 0.1,
        measure: str = 'entropy',
        name: str | None = None,
        planning_budget_s: float | None = None,
        clock=None,
    ):
        if not 0.0 <= alpha <= 1.0:
            raise ValueError(f'alpha must be in [0, 1], got {alpha}')
        if plies < 1:
            raise ValueError(f'plies must be >= 1, got {plies}')
        self.model_set = model_set
        self.alpha = float(alpha)
        self.plies = int(plies)
        self.cost_aware = bool(cost_aware)
        self.durations = dict(NOMINAL_DURATION_S if durations is None else durations)
        missing = [a for a in ACTIONS if a not in self.durations]
        if missing:
            raise ValueError(f'durations lack {missing}')
        self.duration = np.array([float(self.durations[a]) for a in ACTIONS])
        if np.any(self.duration <= 0):
            raise ValueError('action durations must be positive')
        self.support_floor = float(support_floor)
        self.lookahead_tail = float(lookahead_tail)
        self.branch_min_prob = float(branch_min_prob)
        self.tie_tolerance = float(tie_tolerance)
        self.intermediate_weight = float(intermediate_weight)
        self._open_loop = False
        if measure not in ('entropy', 'error'):
            raise ValueError(f"measure must be 'entropy' or 'error', got {measure!r}")
        self.measure = measure
        if planning_budget_s is not None and not planning_budget_s > 0.0:
            raise ValueError(f'planning_budget_s must be > 0 (or None), got {planning_budget_s}')
        self.planning_budget_s = None if planning_budget_s is None else float(planning_budget_s)
        self.clock = time.perf_counter if clock is None else clock
        self._deadline = None  # set only while a budgeted search runs
        self._follow_ups = None  # set only while choose() runs: see _allowed_mask
        self.name = name or ('cost' if cost_aware else ('abp' if plies == 1 else f'abp{plies}'))

        ms = model_set
        self.num_nodes = int(ms.num_nodes)
        self.num_actions = len(ACTIONS)
        self.node_aspect = np.asarray(ms.node_aspect, dtype=np.intp)
        self.num_aspects = int(np.asarray(ms.aspects).shape[0])
        self.likelihood = np.asarray(ms.observation.aspect_likelihood, dtype=np.float64)
        # Successor tables flattened to (action, mass * 48 + state, K) so that one
        # np.take gathers every action's outcomes for a whole support at once.
        out_states = np.asarray(ms.outcome_states)
        out_probs = np.asarray(ms.outcome_probs, dtype=np.float64)
        n_act, n_mass, n_states, k = out_states.shape
        self._succ_state = out_states.reshape(n_act, n_mass * n_states, k).astype(np.intp)
        self._succ_prob = out_probs.reshape(n_act, n_mass * n_states, k)
        self._own_transposes: dict = {}
        self._dense_key = (
            np.arange(self.num_nodes, dtype=np.intp) // STATES_PER_MODEL * self.num_aspects
            + self.node_aspect
        )
        self._node_row = (
            np.asarray(ms.mass, dtype=np.intp).repeat(STATES_PER_MODEL) * STATES_PER_MODEL
            + np.tile(np.arange(STATES_PER_MODEL), ms.num_models)
        )

    # ------------------------------------------------------------------ public

    def expected_entropy(self, belief: np.ndarray, plies: int | None = None
                         ) -> tuple[np.ndarray, float]:
        """(τ_a for every action, H(o_t)): expected object entropy after the plies
        (default ``self.plies``; for plies > 1 the weighted mean over the plies, see
        `intermediate_weight`)."""
        plies = self.plies if plies is None else int(plies)
        nodes, mass = self._support(belief)
        h0 = self._entropy_of(nodes, mass)
        values = self._values(nodes, mass, h0, plies)
        return values / (1.0 + self.intermediate_weight * (plies - 1)), h0

    def _support(self, belief) -> tuple[np.ndarray, np.ndarray]:
        belief = np.asarray(belief, dtype=np.float64)
        nodes = np.flatnonzero(belief > self.support_floor * belief.max())
        return nodes, belief[nodes] / belief[nodes].sum()

    def information_gain(self, belief: np.ndarray) -> np.ndarray:
        tau, h0 = self.expected_entropy(belief)
        return h0 - tau

    def rates(self, belief: np.ndarray, plies: int | None = None
              ) -> tuple[np.ndarray, np.ndarray, float]:
        """Cost-aware score per first action, bits per second: with plies=1 the
        1-ply IG / duration; with plies=2 the best of that and of every fixed
        two-step plan (a, b): expected gain after both / (d_a + d_b), so a
        cheap preparatory move is credited with what it enables and charged
        for it. Returns (scores, 1-ply IG, H(o_t))."""
        plies = self.plies if plies is None else int(plies)
        if plies == 1:
            tau, h0 = self.expected_entropy(belief, 1)
            return (h0 - tau) / self.duration, h0 - tau, h0
        nodes, mass = self._support(belief)
        h0 = self._entropy_of(nodes, mass)
        self._open_loop = True
        try:
            table = self._values(nodes, mass, h0, 2)  # (A, 1 + A)
        finally:
            self._open_loop = False
        gain1 = h0 - table[:, 0]
        rate2 = (h0 - table[:, 1:]) / (self.duration[:, None] + self.duration[None, :])
        if self._follow_ups is not None:
            rate2 = rate2[:, self._follow_ups]
        return np.maximum(gain1 / self.duration, rate2.max(axis=1)), gain1, h0

    def choose(self, belief, feasible=None) -> Decision:
        """Best feasible action for ``belief`` (an (N,) array or an object with
        ``.belief``).

        With ``planning_budget_s`` set and plies > 1 the search is anytime
        (iterative deepening): the 1-ply scores are always computed (the floor,
        Alg. 3 itself), then 2 plies, then 3, up to ``plies``; each deeper
        search runs until it completes or the budget is spent, and the scores
        of the deepest *completed* search decide (``Decision.search_depth``).
        Scores of different depths are never mixed: a partial deeper search is
        thrown away, and a depth predicted not to finish in the time left (from
        the growth of the previous depths' times) is not started. The budget
        is checked between the 1-ply evaluations inside the tree, so a decision
        may overrun it by about one of those (a few ms at |M| = 1470); the 1-ply
        floor is not interrupted.
        """
        belief = np.asarray(getattr(belief, 'belief', belief), dtype=np.float64)
        start = time.perf_counter()
        try:
            self._follow_ups = self._allowed_mask(feasible)
            return self._choose(belief, feasible, start)
        finally:
            self._follow_ups = None

    def _allowed_mask(self, feasible):
        """Actions a deeper ply may plan as follow-ups: the ones feasible now. An
        action refused now is assumed refused later too; planning on it would
        credit a preparatory move with a gain that never comes (with LIFT and
        FLIP refused, abp2 and cost stalled on ORBIT before this mask)."""
        if feasible is None:
            return None
        mask = np.array([bool(feasible(a)) for a in ACTIONS])
        return mask if mask.any() else None  # nothing feasible: choose() raises

    def _choose(self, belief, feasible, start) -> Decision:
        budgeted = self.planning_budget_s is not None and self.plies > 1
        deadline = self.clock() + self.planning_budget_s if budgeted else None
        depth = 1 if budgeted else self.plies
        began = self.clock()
        score, gain, h0 = self._scores(belief, depth)
        spent = [self.clock() - began]  # time of each completed depth
        while budgeted and depth < self.plies:
            # Do not start a depth that is predicted not to finish: its time is
            # the last depth's times the last growth (first step: the branching
            # factor, one child search per action); a doomed search would only
            # burn the budget and be thrown away.
            growth = spent[-1] / max(spent[-2], 1e-9) if len(spent) > 1 else self.num_actions
            now = self.clock()
            if now + spent[-1] * max(growth, 1.0) > deadline:
                break
            self._deadline = deadline
            try:
                deeper = self._scores(belief, depth + 1)
            except SearchTimeout:
                break
            finally:
                self._deadline = None
            score, gain, h0 = deeper
            depth += 1
            spent.append(self.clock() - now)
        # Ties (e.g. nothing left to learn in one step) go to the cheaper action.
        # The tolerance shrinks with the entropy left (below 1 bit): near the
        # stop, the last 1e-3..1e-5 of doubt is what the actions must resolve,
        # and a fixed 1e-3 bits would call every action a tie there.
        tolerance = self.tie_tolerance * min(1.0, h0)
        if self.cost_aware:
            tolerance /= self.duration.max()
        order = _rank(score, tolerance, self.duration)
        index, refused = _first_feasible(order, feasible)
        return Decision(
            action=ACTIONS[index],
            action_index=index,
            information_gain=gain,
            score=score,
            entropy=h0,
            planning_time_s=time.perf_counter() - start,
            infeasible=refused,
            search_depth=depth,
        )

    def _scores(self, belief, plies) -> tuple[np.ndarray, np.ndarray, float]:
        """(score maximised, information gain, H(o_t)) of a ``plies``-deep search."""
        if self.cost_aware:
            return self.rates(belief, plies)
        tau, h0 = self.expected_entropy(belief, plies)
        return h0 - tau, h0 - tau, h0

    def _check_budget(self):
        if self._deadline is not None and self.clock() >= self._deadline:
            raise SearchTimeout

    # ---------------------------------------------------------------- internals

    def _entropy_of(self, nodes, mass) -> float:
        marginal = np.bincount(nodes // STATES_PER_MODEL, mass)
        if self.measure == 'error':
            return 1.0 - marginal.max() / marginal.sum()
        return entropy_bits(marginal)

    def _row_measure(self, u: np.ndarray) -> np.ndarray:
        if self.measure == 'error':
            return 1.0 - u.max(axis=1) / u.sum(axis=1)
        return _row_entropies_bits(u)

    def _head(self, post: np.ndarray) -> np.ndarray:
        """Mask of the nodes that carry all but ``lookahead_tail`` of the mass (the
        lightest nodes are dropped): bounds the mass a lookahead branch ignores,
        unlike a floor relative to the peak that can cut whole runner-up models."""
        live = post > 1e-9 * post.max()
        if self.lookahead_tail <= 0.0:
            return post > 0
        idx = np.flatnonzero(live)
        order = idx[np.argsort(post[idx], kind='stable')]
        tail = np.cumsum(post[order])
        cut = np.searchsorted(tail, self.lookahead_tail * post.sum(), side='right')
        live[order[:cut]] = False
        return live

    def _transpose(self, a):
        cached = getattr(self.model_set, 'transition_transpose', None)
        if cached is not None:
            return cached(a)
        if a not in self._own_transposes:
            self._own_transposes[a] = self.model_set.transitions[ACTIONS[a]].T.tocsr()
        return self._own_transposes[a]

    def _values(self, nodes, mass, h0, depth) -> np.ndarray:
        """Expected object entropy after `depth` plies, for each first action."""
        n = self.num_nodes
        self._check_budget()
        if len(nodes) * 8 > n:
            # Wide support: one sparse mat-vec per action over the whole node
            # space, aggregated with precomputed (model, aspect) keys.
            dense = np.zeros(n)
            dense[nodes] = mass
            return np.array(
                [
                    self._action_value(None, self._transpose(a) @ dense, None, h0, depth)
                    for a in range(self.num_actions)
                ]
            )
        # Narrow support (late decisions, deep plies): gather successors directly.
        rows = self._node_row[nodes]
        base = (nodes - nodes % STATES_PER_MODEL)[None, :, None]
        succ = np.take(self._succ_state, rows, axis=1) + base  # (A, S, K)
        prob = np.take(self._succ_prob, rows, axis=1) * mass[None, :, None]
        succ += (np.arange(self.num_actions) * n)[:, None, None]
        live = prob > 0
        keys, inverse = np.unique(succ[live], return_inverse=True)
        pred = np.bincount(inverse.ravel(), prob[live])
        bounds = np.searchsorted(keys, np.arange(self.num_actions + 1) * n)
        # Models numbered over this support only, so P stays as small as the support.
        models = np.unique(nodes // STATES_PER_MODEL)
        if depth == 1:
            return self._leaf_values(keys, pred, bounds, models, h0)
        values = []
        for a in range(self.num_actions):
            self._check_budget()
            nodes_a = keys[bounds[a]:bounds[a + 1]] - a * n
            model_c = np.searchsorted(models, nodes_a // STATES_PER_MODEL)
            values.append(
                self._action_value(
                    nodes_a, pred[bounds[a]:bounds[a + 1]], (model_c, len(models)), h0, depth
                )
            )
        return np.array(values)

    def _leaf_values(self, keys, pred, bounds, models, h0) -> np.ndarray:
        """One-ply τ_a of every action at once on a narrow support (the leaves of
        the lookahead tree, where most of the work is): same arithmetic as
        ``_action_value`` with the per-action steps batched."""
        n, n_act, n_asp = self.num_nodes, self.num_actions, self.num_aspects
        counts = np.diff(bounds)
        act = np.repeat(np.arange(n_act), counts)
        nodes_all = keys - act * n
        total = np.bincount(act, pred, minlength=n_act)
        mass = pred / total[act]
        aspect = self.node_aspect[nodes_all]
        model_c = np.searchsorted(models, nodes_all // STATES_PER_MODEL)
        rows = len(models)
        aggregated = np.bincount(
            (act * rows + model_c) * n_asp + aspect, mass, minlength=n_act * rows * n_asp
        ).reshape(n_act, rows, n_asp)
        peak = np.maximum.reduceat(mass, bounds[:-1])
        candidate = above_alpha(mass, peak[act], self.alpha)
        weight = np.bincount(
            act[candidate] * n_asp + aspect[candidate], mass[candidate], minlength=n_act * n_asp
        ).reshape(n_act, n_asp)
        values = (1.0 - weight.sum(axis=1)) * h0
        for a in range(n_act):
            self._check_budget()
            z_rows = np.flatnonzero(weight[a])
            entropy = self._row_measure(self.likelihood[z_rows] @ aggregated[a].T)
            values[a] += weight[a, z_rows] @ entropy
        return values

    def _action_value(self, nodes_a, mass_a, models, h0, depth) -> float:
        """τ_a of one action from its predicted belief: on the sparse ``nodes_a``
        with ``models`` = (compact model per node, number of models), or on every
        node when ``nodes_a`` is None."""
        self._check_budget()  # one check per action of a wide support, too
        mass_a = mass_a / mass_a.sum()
        n_asp = self.num_aspects
        if nodes_a is None:
            aspect = self.node_aspect
            rows, key = self.model_set.num_models, self._dense_key
        else:
            aspect = self.node_aspect[nodes_a]
            model_c, rows = models
            key = model_c * n_asp + aspect
        # P[m, x]: predicted mass of model m on nodes of aspect x.
        aggregated = np.bincount(key, mass_a, minlength=rows * n_asp).reshape(rows, n_asp)
        # Candidates of Alg. 3 line 8, grouped by their expected observation.
        candidate = above_alpha(mass_a, mass_a.max(), self.alpha)
        weight = np.bincount(aspect[candidate], mass_a[candidate], minlength=n_asp)
        z_rows = np.flatnonzero(weight)
        weight = weight[z_rows]
        like = self.likelihood[z_rows]  # (Z, A)
        posterior_entropy = self._row_measure(like @ aggregated.T)
        value = float(weight @ posterior_entropy) + (1.0 - weight.sum()) * h0
        if depth == 1:
            return value
        # Every branch keeps its posterior entropy over the remaining plies unless
        # expanded: intermediate entropies weigh `intermediate_weight`, the last 1.
        # Open loop (cost-aware 2-step plans): final entropy for every fixed
        # second action, returned as [τ_a, τ_a,b for each b].
        open_loop = self._open_loop and depth == 2
        one_ply = value
        lam = 0.0 if open_loop else self.intermediate_weight
        value *= 1.0 + lam * (depth - 1)
        hold = 1.0 + lam * (depth - 2)
        # Deeper plies: replace each expanded branch's entropy by its best continuation.
        # Unlikely branches are not expanded; they are credited with the mean
        # further reduction of the expanded ones so pruning does not bias the
        # comparison towards actions with few outcomes.
        expanded = weight >= self.branch_min_prob
        if not expanded.any():
            expanded[np.argmax(weight)] = True
        further = 0.0
        for j in np.flatnonzero(expanded):
            self._check_budget()
            post = like[j][aspect] * mass_a
            keep = self._head(post)
            child_nodes = np.flatnonzero(keep) if nodes_a is None else nodes_a[keep]
            child_mass = post[keep] / post[keep].sum()
            child_h0 = self._entropy_of(child_nodes, child_mass)
            next_values = self._values(child_nodes, child_mass, child_h0, depth - 1)
            if open_loop:
                best_next = next_values
            elif self._follow_ups is None:
                best_next = next_values.min()
            else:
                best_next = next_values[self._follow_ups].min()
            # The reduction is measured on the truncated child against its own
            # entropy: dropping the tail must not pass for information gained.
            further = further + weight[j] * (hold * child_h0 - best_next)
        value = value - further * weight.sum() / weight[expanded].sum()
        return np.concatenate([[one_ply], value]) if open_loop else value


PLANNER_NAMES = ('random', 'abp', 'abp2', 'abp3', 'cost')


def make_planner(name: str, model_set, **options):
    """Planner by name: random, abp (Alg. 3, 1-ply), abp2, abp3 (multi-ply), cost
    (bits per second of nominal action time over 1- and 2-step plans).

    Options go to the planner (alpha, seed, durations, planning_budget_s, ...);
    options a planner does not use are ignored so one option set serves a whole
    benchmark. ``planning_budget_s`` bounds abp2/abp3/cost (anytime search); 1-ply
    ``abp`` ignores it (it is the floor every budgeted search starts from).
    """
    if name == 'random':
        return RandomPlanner(model_set, seed=options.get('seed', 0))
    known = {
        'alpha',
        'durations',
        'support_floor',
        'lookahead_tail',
        'branch_min_prob',
        'tie_tolerance',
        'intermediate_weight',
        'planning_budget_s',
        'clock',
    }
    kwargs = {k: v for k, v in options.items() if k in known and v is not None}
    if name == 'abp':
        kwargs.pop('planning_budget_s', None)
        return ActiveBeliefPlanner(model_set, plies=1, name=name, **kwargs)
    if name in ('abp2', 'abp3'):
        return ActiveBeliefPlanner(model_set, plies=int(name[-1]), name=name, **kwargs)
    if name == 'cost':
        return ActiveBeliefPlanner(model_set, plies=2, cost_aware=True, name=name, **kwargs)
    raise ValueError(f"unknown planner {name!r}; choose from {', '.join(PLANNER_NAMES)}")
