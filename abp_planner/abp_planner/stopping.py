"""When to stop recognising: stopping rules that account for the sensor. No rclpy.

The recogniser stops and names the model with the highest posterior. The rules
here see only the node belief (a NumPy array, ``node = 48 * model + state``),
the number of actions taken and the observation-model parameters; the same
``StoppingRule`` serves the benchmark, the planner node and the Recognize goal.

Rules (``kind``)
----------------
``"error"`` (default): stop when the probability of naming the wrong object
    given the evidence, ``1 - max_o bel(o)``, is at most ``target_error``
    (0.003); with ``fault_margin=True`` that probability is first discounted
    for one unexpected sensor fault (below).
``"posterior"``: the old rule, stop when the top object posterior exceeds
    ``stop_posterior`` (0.95).
``"fixed"``: never stop early; run ``max_actions`` (the paper's protocol,
    "simulated for 30 actions").
Every rule also stops at ``max_actions``.

Why the ``"error"`` rule, from the observation model
---------------------------------------------------
The filter conditions on every observation through p(z | x) of MODEL.md,
which already holds the chance that a slot reports a wrong tag (``p_false``),
misses one (``p_miss``) or that the 2/3-feature geometry is misread
(``p_type``). So the posterior is the probability of each object *given that
the last observation may have been a false tag or a misread*:
``P(wrong | evidence) = 1 - max_o bel(o)`` exactly, under the model. The
error rate of any stopping rule is the mean of that quantity at the stop, so
stopping when it is <= ``target_error`` bounds the error rate by the target.
The 0.95 rule allowed 5 %, and one observation can carry a decision past it:
a slot that reports one specific wrong tag (probability ``p_false / (n_tags -
1)``, 0.33 % at the defaults) shifts the odds between two models by

    ρ = p(z = t | x = t) / p(z = t | x = t') = (1 - p_miss - p_false) (n_tags - 1) / p_false

(279 at the defaults, ρ² for two slots), more than the 19:1 that 0.95
needs; the traced misses of the 0.95 rule were all single false tags. Because
of these discrete jumps the posterior overshoots any threshold: with the
0.003 target the mean of ``1 - p_top`` at the stop is about 5e-5 (measured,
docs/BENCHMARKS.md), i.e. the stop waits for the observation that confirms
the decision after the one that made it.

``fault_margin=True`` guards against a sensor that is worse than the model
(e.g. a distractor tag seen twice from one pose, a correlated false tag the
model cannot expect): it asks that the decision survive removing one
single-slot false tag from the evidence. Removing it multiplies the odds
against the top answer by at most ρ, so with ``O = (1 - p_top) / p_top`` it
bounds ``e_fault = ρ O / (1 + ρ O) <= target_error``. This costs about 1.5
more actions per trial at |M| = 30-120. Type misreads give larger ratios, but
a misread is only misleading when its random tags form exactly an aspect of a
competing model (probability ``p_type / (n_tags + 1)^k`` <= 2e-4 per
observation at the defaults), and missed tags (``-1``) favour no model.

Undecidable twins
-----------------
Some models can never be told apart from the current belief (an eccentric
cube resting on its heavy face never shows its bottom tag, and the full set
holds its twin with the other unused tag there). Their posteriors stay at
1/k each forever, so no rule on ``p_top`` alone ever stops. When the rule is
built with ``node_class`` (``StoppingRule.for_model_set``: probabilistic
bisimulation classes of the ATG nodes, computed once per model set), models
whose belief is spread identically over the classes are treated as one
answer: no action sequence can change their posterior ratio. The rule stops
when the *class* of the top model satisfies the bound above; the reason names
the twins and the reported object is a coin flip among them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from abp_belief.cube import STATES_PER_MODEL
from abp_belief.observation import ObservationParams

STOP_RULES = ('error', 'posterior', 'fixed')
DEFAULT_TARGET_ERROR = 0.003  # the 99.7 % accuracy goal
DEFAULT_STOP_POSTERIOR = 0.95
DEFAULT_MAX_ACTIONS = 30
# Twins: at most this many models may share the top model's answer class (more
# would mean a belief far from converged; the class test is then skipped).
MAX_TWIN_CLASS = 16


ACTION_LIMIT = 'action limit'  # reason prefix of a stop without an answer


class StopDecision(NamedTuple):
    stop: bool
    reason: str

    @property
    def identified(self) -> bool:
        """Stopped because the answer is certain enough (not for the action limit)."""
        return self.stop and not self.reason.startswith(ACTION_LIMIT)


def fault_likelihood_ratio(observation_params: ObservationParams | None = None,
                           n_tags: int = 7) -> float:
    """ρ: the largest shift of the odds between two models that one false tag
    can cause, p_hit / p_wrong of the observation model (MODEL.md)."""
    p = observation_params if observation_params is not None else ObservationParams()
    p_hit = 1.0 - p.p_miss - p.p_false
    p_wrong = p.p_false / (int(n_tags) - 1)
    return p_hit / p_wrong


def fault_discounted_error(p_top, ratio: float) -> np.ndarray:
    """Probability of being wrong if one observation favouring the top answer by
    ``ratio`` was a fault: ρ O / (1 + ρ O), O = (1 - p_top) / p_top. Vectorised."""
    p_top = np.clip(np.asarray(p_top, dtype=np.float64), 1e-300, 1.0)
    odds_against = ratio * (1.0 - p_top) / p_top
    return odds_against / (1.0 + odds_against)


def bisimulation_classes(model_set, decimals: int = 9, max_rounds: int = 64) -> np.ndarray:
    """(N,) class of every ATG node under probabilistic bisimulation.

    Two nodes share a class iff they show the same aspect and, for every action,
    move into each class with the same probability (rounded to ``decimals``).
    Nodes in one class produce the same distribution of observation sequences
    under any policy, so a belief's distribution over classes is all that
    further actions can ever reveal. Partition refinement from the aspects,
    each round one ``np.unique`` over (N, 1 + 2 K |A|) signatures.
    """
    n = int(model_set.num_nodes)
    nodes = np.arange(n, dtype=np.int64)
    outcomes = []
    for a in range(int(np.asarray(model_set.outcome_states).shape[0])):
        succ, prob = model_set.successors(a, nodes)
        outcomes.append((succ.astype(np.int64), np.round(prob, decimals)))
    classes = np.unique(np.asarray(model_set.node_aspect), return_inverse=True)[1].reshape(-1)
    count = int(classes.max()) + 1
    for _ in range(max_rounds):
        columns = [classes[:, None]]
        for succ, prob in outcomes:
            target = np.where(prob > 0, classes[succ], -1)
            # Canonical multiset of (class, prob): merge equal classes, sort by class.
            order = np.argsort(target, axis=1, kind='stable')
            target = np.take_along_axis(target, order, axis=1)
            merged = np.take_along_axis(prob, order, axis=1).copy()
            for j in range(1, target.shape[1]):
                same = target[:, j] == target[:, j - 1]
                merged[same, j] += merged[same, j - 1]
                merged[same, j - 1] = 0.0
            target = np.where(merged > 0, target, -1)
            order = np.argsort(target, axis=1, kind='stable')
            columns.append(np.take_along_axis(target, order, axis=1))
            columns.append(np.round(np.take_along_axis(merged, order, axis=1) * 10**decimals)
                           .astype(np.int64))
        signature = np.ascontiguousarray(np.concatenate(columns, axis=1))
        row_view = signature.view([('', signature.dtype)] * signature.shape[1]).reshape(-1)
        refined = np.unique(row_view, return_inverse=True)[1].reshape(-1)
        new_count = int(refined.max()) + 1
        classes = refined
        if new_count == count:
            break
        count = new_count
    return classes


class StoppingRule:
    """``check(belief, actions_taken) -> StopDecision(stop, reason)``.

    belief: (N,) node belief (or (M, 48)); need not be normalised.
    Parameters are those of the module docstring; ``node_class`` enables the
    twin test (build with ``for_model_set``).
    """

    def __init__(
        self,
        kind: str = 'error',
        target_error: float = DEFAULT_TARGET_ERROR,
        stop_posterior: float = DEFAULT_STOP_POSTERIOR,
        max_actions: int = DEFAULT_MAX_ACTIONS,
        observation_params: ObservationParams | None = None,
        n_tags: int = 7,
        node_class: np.ndarray | None = None,
        fault_margin: bool = False,
    ):
        if kind not in STOP_RULES:
            raise ValueError(f"stopping rule must be one of {', '.join(STOP_RULES)}, got {kind!r}")
        if not 0.0 < target_error < 1.0:
            raise ValueError(f'target_error must be in (0, 1), got {target_error}')
        if not 0.0 < stop_posterior < 1.0:
            raise ValueError(f'stop_posterior must be in (0, 1), got {stop_posterior}')
        if max_actions < 0:
            raise ValueError(f'max_actions must be >= 0, got {max_actions}')
        self.kind = kind
        self.target_error = float(target_error)
        self.stop_posterior = float(stop_posterior)
        self.max_actions = int(max_actions)
        self.observation_params = observation_params or ObservationParams()
        self.n_tags = int(n_tags)
        # fault_margin=False: plain Bayes risk, stop when 1 - p_top <= target_error.
        self.fault_margin = bool(fault_margin)
        self.fault_ratio = (fault_likelihood_ratio(self.observation_params, self.n_tags)
                            if fault_margin else 1.0)
        self.node_class = None if node_class is None else np.asarray(node_class, dtype=np.int64)

    @classmethod
    def for_model_set(cls, model_set, kind: str = 'error', twins: bool = True, **options):
        """A rule with the model set's observation parameters (and twin classes)."""
        return cls(kind=kind, observation_params=model_set.observation_params,
                   n_tags=model_set.n_tags,
                   node_class=bisimulation_classes(model_set) if twins else None, **options)

    def error_probability(self, belief) -> float:
        """The quantity the ``"error"`` rule bounds, for the top object alone
        (``1 - p_top``, or ``e_fault`` with the fault margin)."""
        marginal = _object_marginal(belief)
        return float(fault_discounted_error(marginal.max() / marginal.sum(), self.fault_ratio))

    def check(self, belief, actions_taken: int = 0) -> StopDecision:
        """Verdict on the (N,) node belief after ``actions_taken`` actions."""
        return self._check(_object_marginal(belief), belief, actions_taken)

    def check_marginal(self, object_marginal, actions_taken: int = 0) -> StopDecision:
        """The same verdict from the (M,) object marginal only (e.g. abp_msgs/Belief's
        probabilities); the twin test needs node beliefs and is skipped."""
        return self._check(np.asarray(object_marginal, dtype=np.float64), None, actions_taken)

    def _check(self, marginal, belief, actions_taken) -> StopDecision:
        marginal = marginal / marginal.sum()
        top = int(np.argmax(marginal))
        p_top = float(marginal[top])
        if self.kind == 'posterior' and p_top > self.stop_posterior:
            return StopDecision(True, f'model {top}: posterior {p_top:.4f} > '
                                f'{self.stop_posterior}')
        if self.kind == 'error':
            error = float(fault_discounted_error(p_top, self.fault_ratio))
            if error <= self.target_error:
                discount = ' after one-fault discount' if self.fault_margin else ''
                return StopDecision(True, f'model {top}: P(wrong) {error:.2e} <= '
                                    f'{self.target_error:g}{discount} (posterior {p_top:.6f})')
            twins = self.twin_class(belief, top) if belief is not None else np.array([top])
            if twins.size > 1:
                p_class = float(marginal[twins].sum())
                error = float(fault_discounted_error(p_class, self.fault_ratio))
                if error <= self.target_error:
                    return StopDecision(True, "indistinguishable models "
                                        f"{', '.join(map(str, twins))}: P(outside) {error:.2e} "
                                        f"<= {self.target_error:g}; reporting model {top}")
        if actions_taken >= self.max_actions:
            return StopDecision(True, f'{ACTION_LIMIT} {self.max_actions} reached '
                                f'(model {top}, posterior {p_top:.4f})')
        return StopDecision(False, f'model {top}: posterior {p_top:.4f}, continuing')

    def twin_class(self, belief, top: int | None = None) -> np.ndarray:
        """Models (sorted) that no action sequence can tell apart from ``top`` under
        the current belief: their belief over bisimulation classes is proportional
        to the top model's (total-variation distance within the error budget)."""
        per_model = np.asarray(belief, dtype=np.float64).reshape(-1, STATES_PER_MODEL)
        marginal = per_model.sum(axis=1)
        top = int(np.argmax(marginal)) if top is None else int(top)
        if self.node_class is None:
            return np.array([top])
        # Only models that matter for the bound: the heaviest ones holding all
        # but target_error / ρ of the mass (the rest cannot change the verdict).
        order = np.argsort(marginal)[::-1][:MAX_TWIN_CLASS]
        total = marginal.sum()
        order = order[marginal[order] > 1e-3 * self.target_error / self.fault_ratio * total]
        if top not in order:
            order = np.concatenate([[top], order])
        node_class = self.node_class.reshape(-1, STATES_PER_MODEL)[order]       # (k, 48)
        weights = per_model[order] / marginal[order, None]
        classes, compact = np.unique(node_class, return_inverse=True)
        rows = np.repeat(np.arange(len(order)), STATES_PER_MODEL)
        spread = np.zeros((len(order), classes.size))
        np.add.at(spread, (rows, compact.reshape(-1)), weights.reshape(-1))
        reference = spread[np.flatnonzero(order == top)[0]]
        distance = 0.5 * np.abs(spread - reference).sum(axis=1)
        tolerance = self.target_error / self.fault_ratio
        return np.sort(order[distance <= tolerance])


def _object_marginal(belief) -> np.ndarray:
    return np.asarray(belief, dtype=np.float64).reshape(-1, STATES_PER_MODEL).sum(axis=1)
