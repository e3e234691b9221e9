"""One Recognize episode over several objects (issue 37; docs/MULTI_OBJECT.md) as a plain
class (no rclpy): the tasks identify_all, find MODEL and identify TRACK.

`SceneEpisodeRunner.run()` resets the belief (every track, or the one track of an
identify task), waits for the first observation and gathers the other cubes in view,
then loops: the task's verdict (`tasks.TaskMonitor`) on the scene belief as the belief
node publishes it (/abp/beliefs, one ATG belief per track), the (object, action) of the
`object_planner.ObjectActionPlanner` among the task's candidates, the skill, the
executed action announced with that track id, and the wait for that track's evidence.
The single-object episode's rules (`episode.EpisodeRunner`, whose lost-node pause this
class inherits) apply per track: a failed skill is left out of that track's next
decision, `skill_failure_limit` failures of one (track, action) leave it out for the
episode, a track whose step went back (or that vanished) means a new belief node, and the
episode re-observes from a reset. Tracks that appear later join the scene at the next
decision.

Skills act on the cube in front of the robot (no approach skill yet), so feasibility is
asked once per decision and applies to every object, and travel is not counted.

The ports are `episode.EpisodePorts` with scenes (SceneBelief-like messages) where that
protocol has beliefs, plus the track id in `run_skill`, `publish_feedback` and
`publish_executed`, and `reset_belief(track_id)`.
"""

from collections import Counter
from typing import NamedTuple

import numpy as np

from abp_belief.cube import STATES_PER_MODEL

from .episode import (
    ABORTED,
    BELIEF_NODE,
    CANCELED,
    EVIDENCE_CHECK_S,
    FEASIBILITY_RETRY_S,
    LATEST_BELIEF_WAIT_S,
    SUCCEEDED,
    EpisodeRunner,
    RecognitionAborted,
    _Cancelled,  # the base class's cancel signal, which this loop ends on as well
    belief_array,
)
from .scene_inbox import track_steps
from .tasks import Task, TaskMonitor

# After the first observation: how long to wait for each further cube in view to be seen.
DEFAULT_GATHER_S = 1.0


class SceneView:
    """A scene belief message as the object planner and the task monitor read a
    `FactoredBelief`: object_ids, `in`, belief(id), version(id), most_likely_model(id)."""

    def __init__(self, scene, model_set):
        self.scene = scene
        self.model_set = model_set
        self._entries = {entry.track_id: entry for entry in scene.objects}
        self._dense = {}

    @property
    def object_ids(self):
        return tuple(self._entries)

    def __len__(self):
        return len(self._entries)

    def __contains__(self, object_id):
        return object_id in self._entries

    def message(self, object_id):
        """The track's abp_msgs/Belief."""
        return self._entries[object_id].belief

    def step(self, object_id):
        return int(self._entries[object_id].belief.step)

    def version(self, object_id):
        """Changes whenever the track's belief does (its step, and its stamp across a reset)."""
        msg = self.message(object_id)
        return (int(msg.step), msg.header.stamp.sec, msg.header.stamp.nanosec)

    def belief(self, object_id):
        """The track's dense (N,) node belief (the top nodes the message carries,
        normalised; a message without nodes spreads each model's mass over its states)."""
        dense = self._dense.get(object_id)
        if dense is None:
            msg = self.message(object_id)
            num_nodes = self.model_set.num_nodes
            if len(msg.node_indices):
                dense = belief_array(msg, num_nodes)
            else:
                dense = np.zeros(num_nodes)
                index = {name: i for i, name in enumerate(self.model_set.names)}
                for name, p in zip(msg.object_ids, msg.probabilities):
                    start = index[name] * STATES_PER_MODEL
                    dense[start:start + STATES_PER_MODEL] = p / STATES_PER_MODEL
                dense = dense / dense.sum()
            dense.flags.writeable = False
            self._dense[object_id] = dense
        return dense

    def most_likely_model(self, object_id):
        marginal = self.belief(object_id).reshape(-1, STATES_PER_MODEL).sum(axis=1)
        model = int(np.argmax(marginal))
        return model, float(marginal[model])


class ChosenStep(NamedTuple):
    """The chosen (object, action) in the single-object `Decision`'s shape (what the
    node's plan and feedback messages read)."""

    object_id: str
    action: str
    action_index: int
    information_gain: np.ndarray  # of the chosen object, per action
    planning_time_s: float


class SceneEpisodeResult(NamedTuple):
    outcome: str  # SUCCEEDED, CANCELED or ABORTED
    success: bool
    reason: str
    actions_taken: int
    view: object  # SceneView of the last scene, None if none came
    objects: list  # tasks.ObjectResult per track (empty without a scene)
    found_object: str  # find: the track that is the model; '' otherwise
    actions_per_object: dict


def task_of(kind, target_model='', track_id='', model_names=()):
    """The `tasks.Task` of a Recognize goal's task fields; ValueError with the reason
    for an unknown task, an unknown model or a missing field."""
    if kind == 'identify_all':
        return Task('identify_all')
    if kind == 'find':
        if not target_model:
            raise ValueError('task find needs target_model')
        names = list(model_names)
        if target_model not in names:
            shown = target_model if len(target_model) <= 60 else target_model[:60] + '...'
            raise ValueError(f'task find: target_model {shown!r} is not a model of the '
                             f"planner's model set ({len(names)} models, e.g. "
                             f"{', '.join(names[:3])})")
        return Task('find', model=names.index(target_model))
    if kind == 'identify':
        if not track_id:
            raise ValueError('task identify needs track_id')
        return Task('identify', object_id=track_id)
    raise ValueError(f"unknown task {kind!r} (expected '', identify_all, find or identify)")


class SceneEpisodeRunner(EpisodeRunner):
    """Runs one multi-object episode: `run()` -> SceneEpisodeResult.

    object_planner: `ObjectActionPlanner`; monitor: `TaskMonitor`; model_set: the
    planner's (names and node count)."""

    def __init__(self, object_planner, ports, model_set, monitor: TaskMonitor,
                 observation_timeout_s, logger, gather_s=DEFAULT_GATHER_S, **kwargs):
        super().__init__(object_planner, ports, model_set.num_nodes, None,
                         observation_timeout_s, logger, **kwargs)
        self.model_set = model_set
        self.monitor = monitor
        self.gather_s = float(gather_s)
        task = monitor.task
        self.track_id = task.object_id if task.kind == 'identify' else ''

    # -- the loop ------------------------------------------------------------------------
    def run(self):
        ports = self.ports
        actions = Counter()
        total = 0
        view = None
        try:
            scene = self._start()
            refused_after_failure = {}   # track -> actions that just failed on it
            failures = Counter()         # (track, action) -> failures
            while True:
                view = SceneView(scene, self.model_set)
                verdict = self._verdict(view, actions)
                if verdict.done:
                    return self._result(SUCCEEDED, verdict.success, verdict.reason, total,
                                        view, actions, verdict.found_object)
                if ports.cancel_requested():
                    return self._result(CANCELED, False, 'cancelled', total, view, actions)
                resumed = self._wait_for_lost_nodes(scene)
                if resumed is not scene:
                    scene = resumed   # re-observed after a lost node: judge it again
                    continue
                given_up = {key for key, n in failures.items() if n >= self.skill_failure_limit}
                step, feasible = self._decide(view, verdict.candidates,
                                              refused_after_failure, given_up)
                track = step.object_id
                ports.publish_plan(step, feasible)
                ports.publish_feedback(view.message(track), step, total, track)
                top, posterior = view.most_likely_model(track)
                self.log.info(
                    f'action {total + 1}: {step.action} on track {track} (IG '
                    f'{float(step.information_gain[step.action_index]):.3f} bits, top '
                    f'{self.model_set.names[top]} {posterior:.3f}; {verdict.reason})')
                step_before = view.step(track)
                success, reason, duration = ports.run_skill(step.action, track)
                total += 1
                actions[track] += 1
                ports.publish_executed(step.action, total, success, reason, duration, track)
                if ports.cancel_requested():
                    return self._result(CANCELED, False, 'cancelled', total, view, actions)
                if success:
                    refused_after_failure.pop(track, None)
                    expected_step = step_before + 2  # prediction, then a fresh correction
                else:
                    self.log.warning(f'{step.action} on track {track} failed: {reason}; '
                                     're-planning')
                    refused_after_failure.setdefault(track, set()).add(step.action)
                    failures[(track, step.action)] += 1
                    expected_step = step_before + 1
                scene = self._wait_for_track_evidence(track, expected_step, step_before) \
                    or scene
        except _Cancelled:
            return self._result(CANCELED, False, 'cancelled', total, view, actions)
        except RecognitionAborted as error:
            self.log.error(f'recognition aborted: {error}')
            latest = ports.latest_belief()
            last_view = SceneView(latest, self.model_set) if latest is not None else view
            return self._result(ABORTED, False, str(error), total, last_view, actions)

    def _verdict(self, view, actions):
        if self.track_id and self.track_id not in view:
            raise RecognitionAborted(f'track {self.track_id!r} is no longer in the scene '
                                     f'belief (tracks: {", ".join(view.object_ids) or "none"})')
        return self.monitor.check(view, dict(actions))

    def _result(self, outcome, success, reason, total, view, actions, found=None):
        objects = [] if view is None or not len(view) else \
            self.monitor.object_results(view, dict(actions))
        return SceneEpisodeResult(outcome, success, reason, total, view, objects,
                                  '' if found is None else str(found), dict(actions))

    # -- start: reset, first observation, the other cubes in view ---------------------
    def _observed(self, scene):
        """Tracks of `scene` with an observation in their belief (step >= 1)."""
        steps = track_steps(scene)
        if self.track_id:
            return {self.track_id} if steps.get(self.track_id, 0) >= 1 else set()
        return {track for track, step in steps.items() if step >= 1}

    def _start(self):
        self.ports.reset_belief(self.track_id)
        self.planner.clear_cache()   # versions of a new belief node may repeat old ones
        first = self.ports.wait_for_belief(lambda s: bool(self._observed(s)),
                                           self.observation_timeout_s)
        if first is None:
            what = f'track {self.track_id!r}' if self.track_id else 'any cube'
            raise RecognitionAborted(
                f'no observation of {what} within {self.observation_timeout_s:.1f} s: '
                f'{self.ports.observations_since_reset()}')
        if self.track_id:
            return first
        # The other cubes of the view come as observations of their own, one after the
        # other: take each one that comes within gather_s of the last.
        seen = self._observed(first)
        deadline = self.clock() + self.observation_timeout_s
        while self.clock() < deadline:
            more = self.ports.wait_for_belief(lambda s: len(self._observed(s)) > len(seen),
                                              self.gather_s)
            if more is None or self.ports.belief_restarted():
                break
            first, seen = more, self._observed(more)
        latest = self.ports.latest_belief()
        return latest if latest is not None else first

    # -- decide -------------------------------------------------------------------------
    def _decide(self, view, candidates, refused_after_failure, given_up):
        """The object planner's (object, action) among the feasible ones: (ChosenStep,
        feasibility). "Nothing feasible" is re-checked for up to the observation timeout,
        after dropping the exclusions for failures (as the one-object episode)."""
        excluded = {(track, action) for track, refused in refused_after_failure.items()
                    for action in refused} | set(given_up)
        deadline = self.clock() + self.observation_timeout_s
        while True:
            feasible = self.ports.check_feasibility()

            def allowed(track, action, feasible=feasible, excluded=excluded):
                return feasible.get(action, (True, ''))[0] and (track, action) not in excluded

            try:
                decision = self.planner.choose(view, candidates, feasible=allowed)
            except RuntimeError as error:
                if excluded:
                    excluded = set()
                    continue
                if self.clock() > deadline:
                    reasons = '; '.join(f'{a}: {r}' for a, (ok, r) in feasible.items() if not ok)
                    raise RecognitionAborted(f'{error} ({reasons})') from error
                self.sleep(FEASIBILITY_RETRY_S)
                continue
            row = decision.object_ids.index(decision.object_id)
            return ChosenStep(decision.object_id, decision.action, decision.action_index,
                              decision.information_gain[row], decision.planning_time_s), feasible

    # -- evidence -----------------------------------------------------------------------
    def _wait_for_track_evidence(self, track, expected_step, step_before):
        """The scene with the action's evidence on `track`; after the timeout the latest.
        A track whose step went back or that vanished: a new belief node; re-observe."""

        def arrived(scene):
            steps = track_steps(scene)
            return track not in steps or steps[track] >= expected_step \
                or steps[track] < step_before

        deadline = self.clock() + self.observation_timeout_s
        while True:
            fresh = self.ports.wait_for_belief(
                arrived, max(0.0, min(EVIDENCE_CHECK_S, deadline - self.clock())))
            if fresh is not None or self.clock() >= deadline:
                break
            missing = self.ports.missing_nodes()
            if missing:
                return self._wait_for_lost_nodes(None, missing)
        went_back = fresh is not None and (track not in track_steps(fresh)
                                           or track_steps(fresh)[track] < step_before)
        if self.ports.belief_restarted() or went_back:
            self.log.warning(f'track {track} went back from step {step_before}: the belief '
                             'node restarted; re-observing')
            return self._start()
        if fresh is None:
            self.log.warning(f'no fresh observation of track {track} after the action within '
                             f'{self.observation_timeout_s:.1f} s; planning on the latest '
                             'belief')
            fresh = self.ports.wait_for_belief(lambda s: True, LATEST_BELIEF_WAIT_S)
        return fresh


__all__ = ['BELIEF_NODE', 'DEFAULT_GATHER_S', 'ChosenStep', 'SceneEpisodeResult',
           'SceneEpisodeRunner', 'SceneView', 'task_of']
