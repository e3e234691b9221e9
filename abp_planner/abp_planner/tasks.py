"""Recognition tasks over several objects (issue 37; Ruiken et al., "Reconfigurable
Tasks in Belief-Space Planning", 2016). No rclpy.

A task says when recognition is done and which objects are still worth acting on; the
per-object verdicts are the single-object ``StoppingRule``'s, with its confidence:

``identify_all``
    Every object named: each object stops by the rule on its own belief and its own
    action count (the rule's ``max_actions`` is per object). Done when all have.
``find MODEL``
    Stop as soon as one object *is* MODEL with the rule's confidence, or every object
    is surely *not* MODEL. "Is" is the claim ``P_k(MODEL)`` (with the rule's twin
    classes: the mass of the models no action can tell from MODEL) held to the same
    bound as an identification (``P(wrong) <= target_error``, with the fault margin
    if the rule has it; ``posterior`` rules: ``> stop_posterior``); "none is" is one
    claim about the scene, ``1 - P(any) = prod_k (1 - P_k(MODEL))`` held to it (not
    each object on its own: K objects at the bound would leave K times the error),
    and by default with the rule's one-fault discount (``absence_fault_margin``): the
    prior puts the model in a scene of K cubes with probability ~K/|M| only, while
    whoever asks to find it mostly expects it there; without the discount one false
    tag on the first view ruled the target out in 1 of 30 model-sampled scenes with
    the target present (K = 5). The planner acts on the object most likely to be
    MODEL: confirming it ends the task, ruling it out lowers P(any).
``identify OBJECT``
    Today's single-object behaviour, on one track.

``TaskMonitor.check(belief, actions)`` gives the verdict; ``TaskMonitor.result`` the
answer with one entry per object (id, MAP model and its posterior, actions spent).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Hashable

import numpy as np

from abp_belief.cube import STATES_PER_MODEL

from .stopping import (
    ACTION_LIMIT,
    StoppingRule,
    fault_discounted_error,
    fault_likelihood_ratio,
)

TASK_KINDS = ('identify_all', 'find', 'identify')


@dataclass(frozen=True)
class Task:
    kind: str = 'identify_all'
    model: int | None = None  # find: the model index sought
    object_id: Hashable | None = None  # identify: the track

    def __post_init__(self):
        if self.kind not in TASK_KINDS:
            raise ValueError(f"task must be one of {', '.join(TASK_KINDS)}, got {self.kind!r}")
        if self.kind == 'find' and self.model is None:
            raise ValueError('task find needs a model')
        if self.kind == 'identify' and self.object_id is None:
            raise ValueError('task identify needs an object id')

    @classmethod
    def parse(cls, text: str, model_set=None) -> 'Task':
        """'identify_all', 'find MODEL' (a model name of ``model_set`` or an index),
        'identify OBJECT' (a track id; digits become an int); '' is identify_all."""
        words = text.split()
        if not words or words == ['identify_all']:
            return cls('identify_all')
        if len(words) == 2 and words[0] == 'find':
            return cls('find', model=_model_index(words[1], model_set))
        if len(words) == 2 and words[0] == 'identify':
            return cls('identify', object_id=int(words[1]) if words[1].isdigit() else words[1])
        raise ValueError(f"task {text!r}: expected 'identify_all', 'find MODEL' or "
                         "'identify OBJECT'")

    def __str__(self) -> str:
        if self.kind == 'find':
            return f'find {self.model}'
        if self.kind == 'identify':
            return f'identify {self.object_id}'
        return 'identify_all'


def _model_index(word: str, model_set) -> int:
    if word.isdigit():
        index = int(word)
        if model_set is not None and not 0 <= index < model_set.num_models:
            raise ValueError(f'find {word}: model index out of range 0..'
                             f'{model_set.num_models - 1}')
        return index
    if model_set is None:
        raise ValueError(f'find {word!r}: a model name needs the model set')
    try:
        return int(model_set.model_index(word))
    except (KeyError, ValueError):
        raise ValueError(f'find {word!r}: no such model in the model set') from None


@dataclass
class ObjectResult:
    object_id: Hashable
    model: int  # MAP model
    posterior: float  # its posterior
    actions: int  # actions spent on this object
    identified: bool  # its stop rule named it (identify tasks) / decided it (find)
    reason: str

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class TaskVerdict:
    done: bool
    reason: str
    candidates: list = field(default_factory=list)  # objects the planner may act on
    found_object: Hashable | None = None  # find: the object that is the model
    success: bool = False  # the task's question answered (not stopped by action limits)


class TaskMonitor:
    """The stop rule and candidate objects of ``task`` under ``rule``."""

    def __init__(self, task: Task, rule: StoppingRule, absence_fault_margin: bool = True):
        self.task = task
        self.rule = rule
        # find: "no object is it" must survive one false tag (module doc).
        self.absence_ratio = (fault_likelihood_ratio(rule.observation_params, rule.n_tags)
                              if absence_fault_margin else rule.fault_ratio)

    # -- claims held to the rule's confidence --------------------------------------------------
    def confident(self, p_claim: float, fault_ratio: float | None = None) -> bool:
        """The rule would accept a claim of probability ``p_claim`` (``fault_ratio``:
        discount it for one false observation of that odds ratio; None: the rule's)."""
        if self.rule.kind == 'error':
            ratio = self.rule.fault_ratio if fault_ratio is None else fault_ratio
            return float(fault_discounted_error(p_claim, ratio)) <= self.rule.target_error
        if self.rule.kind == 'posterior':
            return p_claim > self.rule.stop_posterior
        return False  # 'fixed': never early

    def target_probability(self, node_belief) -> float:
        """P(object is the sought model), twins of it (rule's classes) included."""
        per_model = np.asarray(node_belief, dtype=np.float64).reshape(-1, STATES_PER_MODEL)
        marginal = per_model.sum(axis=1)
        marginal = marginal / marginal.sum()
        target = self.task.model
        if self.rule.node_class is None or not marginal[target] > 0.0:
            return float(marginal[target])  # (no mass: no twin spread to compare with)
        models = self.rule.twin_class(node_belief, target)
        return float(marginal[np.union1d(models, [target])].sum())

    # -- verdict ---------------------------------------------------------------------------
    def check(self, belief, actions: dict) -> TaskVerdict:
        """``belief``: a FactoredBelief; ``actions``: {object_id: actions spent on it}."""
        kind = self.task.kind
        if kind == 'find':
            return self._check_find(belief, actions)
        ids = [self.task.object_id] if kind == 'identify' else list(belief.object_ids)
        if kind == 'identify' and self.task.object_id not in belief:
            raise ValueError(f'identify {self.task.object_id!r}: no such object; tracked: '
                             f'{list(belief.object_ids)}')
        open_ids, limited = [], []
        for object_id in ids:
            verdict = self.rule.check(belief.belief(object_id), actions.get(object_id, 0))
            if not verdict.stop:
                open_ids.append(object_id)
            elif not verdict.identified:
                limited.append(object_id)
        if open_ids:
            return TaskVerdict(False, f'{len(open_ids)} of {len(ids)} objects still open',
                               candidates=open_ids)
        if limited:
            return TaskVerdict(True, f'{ACTION_LIMIT} reached on objects '
                               f"{', '.join(map(str, limited))}")
        return TaskVerdict(True, f'{len(ids)} object(s) identified', success=True)

    def _check_find(self, belief, actions: dict) -> TaskVerdict:
        target = self.task.model
        ids = list(belief.object_ids)
        probability = np.array([self.target_probability(belief.belief(o)) for o in ids])
        for object_id, p in zip(ids, probability):
            if self.confident(p):
                return TaskVerdict(True, f'object {object_id} is model {target} '
                                   f'(P {p:.6f})', found_object=object_id, success=True)
        # "No object is it" is one claim about the whole scene: its error is the chance
        # that at least one object is the model, not each object's alone (three objects
        # at 0.002 each leave a 0.006 chance that the model is there).
        p_any = 1.0 - float(np.prod(1.0 - probability))
        if self.confident(1.0 - p_any, self.absence_ratio):
            return TaskVerdict(True, f'no object is model {target} (P(any) {p_any:.2e})',
                               success=True)
        # An object at its action limit stays as undecided as it is; one that holds no
        # mass of the model cannot change P(any) by acting on it.
        negligible = 1e-6 * self.rule.target_error
        open_ids = [k for k, o in enumerate(ids)
                    if actions.get(o, 0) < self.rule.max_actions and probability[k] > negligible]
        if not open_ids:
            return TaskVerdict(True, f'{ACTION_LIMIT} reached: model {target} neither found '
                               f'nor ruled out (P(any) {p_any:.2e})')
        # The most likely carriers of the model first (ties: all of them).
        top = probability[open_ids].max()
        candidates = [ids[k] for k in open_ids if probability[k] >= top * (1 - 1e-9)]
        return TaskVerdict(False, f'model {target}: P(any object) {p_any:.2e}, asking '
                           f"{', '.join(map(str, candidates))}", candidates=candidates)

    # -- answer ------------------------------------------------------------------------------
    def object_results(self, belief, actions: dict) -> list[ObjectResult]:
        results = []
        for object_id in belief.object_ids:
            model, posterior = belief.most_likely_model(object_id)
            spent = int(actions.get(object_id, 0))
            if self.task.kind == 'find':
                p = self.target_probability(belief.belief(object_id))
                decided = self.confident(p) or self.confident(1.0 - p)
                reason = f'P(model {self.task.model}) {p:.6f}'
            else:
                verdict = self.rule.check(belief.belief(object_id), spent)
                decided, reason = verdict.identified, verdict.reason
            results.append(ObjectResult(object_id, model, posterior, spent, bool(decided),
                                        reason))
        return results
