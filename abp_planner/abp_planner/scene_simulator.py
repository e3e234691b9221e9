"""Model-sampled simulation of a scene of K cubes (issue 37), no rclpy.

The single-object protocol of ``simulator.py`` per cube, with the multi-object parts
between: every cube has its true model, initial state, plane position and its own noise
stream; the scene starts with one view of every cube (each cube's first observation,
as a single trial starts with one, here corrected for all K in one batched update);
then, until the task's monitor says done, the ``ObjectActionPlanner`` chooses (object,
action), the robot goes to that cube (travel time of the planner's ``TravelModel``), the
action's outcome is drawn from that cube's true model (``sample_outcome``) and an
observation of that cube only is drawn (``ObservationModel.sample``) and corrected.

The cube acted on is the only one whose world state changes, and the robot comes back
to a cube at the station it left it from (the state relative to the robot is kept; the
wiring turns it with ``FactoredBelief.shift_yaw`` when the bearing changes). Cubes seen
in the background while acting on another are not observed here (no shared views): the
closed loop is where those help.

Cube j draws its outcomes and observations from its own stream in the order
``run_trial`` does, so with the same stream a cube sees exactly the noise it would see
alone (``planner_benchmark --objects K`` compares with those single-cube trials).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from abp_belief.cube import ACTIONS, NOMINAL_DURATION_S, STATES_PER_MODEL
from abp_belief.factored_belief import FactoredBelief

from .object_planner import ObjectActionPlanner
from .simulator import sample_outcome
from .tasks import TaskMonitor


@dataclass
class SceneCube:
    object_id: int  # track id
    true_model: int
    initial_state: int
    position: tuple  # (x, y) in the plane, m


@dataclass
class SceneRun:
    task: str
    done_reason: str
    success: bool  # the task's question answered (monitor), not checked against truth
    found_object: int | None
    objects: list  # ObjectResult.as_dict() per cube, plus 'true_model'
    actions: list  # (object_id, action) in order
    action_time_s: float  # nominal durations of the actions
    travel_time_s: float
    planning_ms: list = field(default_factory=list)
    objects_planned: list = field(default_factory=list)  # per decision (K: nothing cached)
    update_ms: list = field(default_factory=list)  # belief predict+correct per action
    first_view_ms: float = 0.0  # the batched first correction of all K cubes

    @property
    def num_actions(self) -> int:
        return len(self.actions)

    def as_dict(self) -> dict:
        d = asdict(self)
        d['num_actions'] = self.num_actions
        return d


def run_scene(world, belief_model_set, planner: ObjectActionPlanner, monitor: TaskMonitor,
              cubes: list[SceneCube], noise_rngs: dict, durations: dict | None = None,
              feasible=None) -> SceneRun:
    """One scene under ``monitor``'s task. ``world`` draws outcomes and observations,
    the belief and the planner use ``belief_model_set``. ``noise_rngs``: {object_id:
    Generator}; ``feasible(object_id, action)`` as the planner takes it."""
    durations = NOMINAL_DURATION_S if durations is None else durations
    ids = [c.object_id for c in cubes]
    truth = {c.object_id: c for c in cubes}
    state = {c.object_id: c.initial_state for c in cubes}
    positions = {c.object_id: c.position for c in cubes}
    belief = FactoredBelief(belief_model_set, ids)
    planner.clear_cache()

    def observation(object_id):
        node = truth[object_id].true_model * STATES_PER_MODEL + state[object_id]
        return world.observation.sample(int(world.node_aspect[node]), noise_rngs[object_id])

    first = {o: observation(o) for o in ids}
    start = time.perf_counter()
    belief.correct_many(first)
    first_view_ms = (time.perf_counter() - start) * 1e3
    spent = {o: 0 for o in ids}
    actions, planning, planned, updates = [], [], [], []
    travel_total, robot_at = 0.0, None
    verdict = monitor.check(belief, spent)
    while not verdict.done:
        decision = planner.choose(belief, verdict.candidates, positions, robot_at, feasible)
        planning.append(decision.planning_time_s * 1e3)
        planned.append(decision.objects_planned)
        k = decision.object_id
        travel_total += float(decision.travel_s[decision.object_ids.index(k)])
        robot_at = positions[k]
        a = decision.action_index
        state[k] = sample_outcome(world, truth[k].true_model, state[k], a, noise_rngs[k])
        z = observation(k)
        start = time.perf_counter()
        belief.step(k, ACTIONS[a], z)
        updates.append((time.perf_counter() - start) * 1e3)
        spent[k] += 1
        actions.append((k, ACTIONS[a]))
        verdict = monitor.check(belief, spent)
    objects = []
    for result in monitor.object_results(belief, spent):
        entry = result.as_dict()
        entry['true_model'] = truth[result.object_id].true_model
        entry['true_posterior'] = float(
            belief.object_marginal(result.object_id)[entry['true_model']])
        objects.append(entry)
    return SceneRun(
        task=str(monitor.task),
        done_reason=verdict.reason,
        success=verdict.success,
        found_object=verdict.found_object,
        objects=objects,
        actions=actions,
        action_time_s=float(sum(durations[a] for _, a in actions)),
        travel_time_s=travel_total,
        planning_ms=planning,
        objects_planned=planned,
        update_ms=updates,
        first_view_ms=first_view_ms,
    )


def place_cubes(count: int, rng: np.random.Generator, min_distance_m: float = 0.3,
                extent_m: float = 1.5, tries: int = 10_000) -> np.ndarray:
    """``count`` plane positions in [0, extent]² at least ``min_distance_m`` apart
    (rejection sampling); (count, 2)."""
    placed: list[np.ndarray] = []
    for _ in range(tries):
        if len(placed) == count:
            break
        p = rng.uniform(0.0, extent_m, size=2)
        if all(np.linalg.norm(p - q) >= min_distance_m for q in placed):
            placed.append(p)
    if len(placed) < count:
        raise ValueError(f'cannot place {count} cubes {min_distance_m} m apart in a '
                         f'{extent_m} m square')
    return np.array(placed)
