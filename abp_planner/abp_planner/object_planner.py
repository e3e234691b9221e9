"""A planner over (object, action) for a factored multi-object belief (issue 37). No rclpy.

Every object k has its own belief, so the expected information gain of action a on k
depends on k's belief alone: ``IG(k, a)`` is the single-object planner's score
(``ActiveBeliefPlanner``, Alg. 3 or the cost-aware 2-ply search) on ``beliefs[k]``.
The best action for k is the one that planner chooses (its ranking, tie rule and
feasibility fall-through), so an object is worked on exactly as it would be alone.
Which object: the one whose chosen action brings the most bits per second once the
trip to it is counted,

    score(k) = bits(k) / (duration(a_k) + travel_s(k)),

with ``bits(k)`` the 1-ply expected gain of a_k (``abp``), or for the cost-aware
planner its score (bits/s, which may credit a preparatory move with the gain of a
2-step plan) times duration(a_k). ``object_score='gain'`` drops the time and takes the
largest ``bits(k)`` (the paper's pure information gain), ties to the nearer object.

Travel cost (``TravelModel``): the robot stands at the cube it last acted on; reaching
another cube costs ``approach_s + distance / speed_mps`` seconds, distance in the plane
between the cubes' positions (``odom`` x, y). A plain straight-line model: it ignores
obstacles (the other cubes) and the base's turning; the defaults (0.1 m/s, 10 s to
stop and square up to the new cube) make a 1 m trip cost about one ORBIT 90° + PUSH.

Only the object that was acted on changes between two decisions, so each object's
single-object decision is cached under its belief version (``FactoredBelief.version``)
and the feasibility verdicts: a decision at K objects costs one single-object decision
plus K dictionary look-ups, except the first one (K decisions).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from abp_belief.cube import ACTIONS

OBJECT_SCORES = ('rate', 'gain')


@dataclass(frozen=True)
class TravelModel:
    """Seconds to go from standing at one cube to standing at another (module doc)."""

    speed_mps: float = 0.1
    approach_s: float = 10.0

    def __post_init__(self):
        if not self.speed_mps > 0.0:
            raise ValueError(f'TravelModel.speed_mps must be > 0, got {self.speed_mps}')
        if not self.approach_s >= 0.0:
            raise ValueError(f'TravelModel.approach_s must be >= 0, got {self.approach_s}')

    def seconds(self, start, goals) -> np.ndarray:
        """Travel time from the plane position ``start`` to each of ``goals`` ((K, 2)
        positions); 0 for a goal at the start itself. ``start`` None: the robot stands
        at no cube yet and pays the approach only."""
        goals = np.asarray(goals, dtype=np.float64).reshape(-1, 2)
        if start is None:
            return np.full(len(goals), self.approach_s)
        distance = np.linalg.norm(goals - np.asarray(start, dtype=np.float64)[None, :], axis=1)
        return np.where(distance > 0.0, self.approach_s + distance / self.speed_mps, 0.0)


@dataclass
class ObjectDecision:
    """The (object, action) chosen and the per-object evidence behind it."""

    object_id: object
    action: str
    action_index: int
    object_ids: list
    information_gain: np.ndarray  # (K, |A|) expected IG in bits (1-ply), per object
    action_score: np.ndarray  # (K, |A|) what the single-object planner maximised
    chosen_actions: list  # per object: the single-object planner's choice
    object_score: np.ndarray  # (K,) score(k) of the module doc
    travel_s: np.ndarray  # (K,) travel time to each object
    planning_time_s: float
    objects_planned: int  # single-object decisions computed (not from the cache)
    infeasible: list = field(default_factory=list)  # of the chosen object


class ObjectActionPlanner:
    """``choose(belief, candidates, ...) -> ObjectDecision`` over a ``FactoredBelief``.

    ``planner`` is a single-object ``ActiveBeliefPlanner`` (``make_planner('abp' |
    'abp2' | 'cost', ...)``); its scores are reused per object, unchanged.
    """

    def __init__(self, planner, travel: TravelModel | None = None, object_score: str = 'rate'):
        if object_score not in OBJECT_SCORES:
            raise ValueError(f"object_score must be one of {', '.join(OBJECT_SCORES)}, "
                             f'got {object_score!r}')
        if not hasattr(planner, 'duration'):
            raise ValueError(f'planner {getattr(planner, "name", planner)!r} has no expected '
                             'gains to compare objects by (use abp, abp2, abp3 or cost)')
        self.planner = planner
        self.travel = travel if travel is not None else TravelModel()
        self.object_score = object_score
        self.duration = np.asarray(planner.duration, dtype=np.float64)
        self._cache: dict = {}

    def clear_cache(self) -> None:
        self._cache.clear()

    def choose(self, belief, candidates=None, positions=None, robot_at=None,
               feasible=None) -> ObjectDecision:
        """Best (object, action) among ``candidates`` (object ids; None: every object).

        ``positions``: {object_id: (x, y)} in the plane (None: no travel cost);
        ``robot_at``: the (x, y) the robot stands at (None: nowhere yet, every object
        costs the approach); ``feasible(object_id, action) -> bool`` the motion planner's
        verdict (None: everything feasible)."""
        start = time.perf_counter()
        ids = list(belief.object_ids if candidates is None else candidates)
        if not ids:
            raise ValueError('no object to plan for')
        decisions, planned = [], 0
        for object_id in ids:
            verdict = None if feasible is None else \
                (lambda action, o=object_id: bool(feasible(o, action)))
            flags = None if verdict is None else tuple(verdict(a) for a in ACTIONS)
            key = (object_id, belief.version(object_id), flags)
            decision = self._cache.get(object_id)
            if decision is None or decision[0] != key:
                decision = (key, self.planner.choose(belief.belief(object_id), verdict))
                self._cache[object_id] = decision
                planned += 1
            decisions.append(decision[1])
        if positions is None:
            travel = np.zeros(len(ids))
        else:
            travel = self.travel.seconds(robot_at, [positions[o] for o in ids])
        chosen = np.array([d.action_index for d in decisions])
        gain = np.array([d.information_gain for d in decisions])
        score = np.array([d.score for d in decisions])
        rows = np.arange(len(ids))
        if self.planner.cost_aware:
            bits = score[rows, chosen] * self.duration[chosen]
        else:
            bits = gain[rows, chosen]
        if self.object_score == 'gain':
            object_score = bits
        else:
            object_score = bits / (self.duration[chosen] + travel)
        # Ties (within float noise) go to the nearer object, then to the earlier track.
        best = object_score.max()
        tied = np.flatnonzero(object_score >= best - 1e-12 * max(1.0, abs(best)))
        pick = int(tied[np.argmin(travel[tied])])
        picked = decisions[pick]
        return ObjectDecision(
            object_id=ids[pick],
            action=picked.action,
            action_index=picked.action_index,
            object_ids=ids,
            information_gain=gain,
            action_score=score,
            chosen_actions=[d.action for d in decisions],
            object_score=object_score,
            travel_s=travel,
            planning_time_s=time.perf_counter() - start,
            objects_planned=planned,
            infeasible=list(picked.infeasible),
        )
