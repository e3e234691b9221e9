"""One Recognize episode as a plain class (no rclpy): when to stop, what to do after a
failed skill, how long to wait for evidence.

`EpisodeRunner.run()` resets the belief, waits for the first observation, then loops:
check the stopping rule and cancellation, ask the planner for the best feasible action
(retrying while nothing is feasible, for up to the observation timeout), run the skill,
announce it, and wait for the belief that includes the action's evidence. A failed
skill is left out of the next decision (re-plan), and a skill that failed
`skill_failure_limit` times in the episode is left out of every later one (a grasp
that slipped twice will likely slip again, and its expected gain stays high because
a failure brings no evidence); either comes back only when nothing else is feasible
(retry). Before each decision, and whenever a skill fails or no fresh evidence comes,
the runner asks which nodes it needs are gone; it then pauses until they are back (for
up to `node_return_timeout_s`), re-observes (from a reset belief if the belief node was
among them, since a restarted belief node has lost the evidence) and goes on, or aborts
with a reason that names them. The ROS side (`planner_node`) provides the
`EpisodePorts`: the belief as received on abp/belief, the skill and service calls, the
publishers and the graph's view of the nodes. Time comes from the injected `clock` /
`sleep`, so the rules are unit-tested without DDS.
"""

import time
from collections import Counter
from typing import NamedTuple, Protocol

import numpy as np

from abp_belief.belief_config import BELIEF_STEP_KEY, EVIDENCE_GATE_KEY
from abp_common import diagnostic_keys as keys

SUCCEEDED, CANCELED, ABORTED = 'succeeded', 'canceled', 'aborted'
# Pause between feasibility checks while no action is feasible.
FEASIBILITY_RETRY_S = 0.5
# After a missed observation: how long to wait for any belief at all.
LATEST_BELIEF_WAIT_S = 1.0
# While paused for a lost node: how often to look for it again.
NODE_POLL_S = 0.5
# While waiting for an action's evidence: how often to ask whether its sources are gone.
EVIDENCE_CHECK_S = 1.0
# The name `missing_nodes()` gives the belief node (its return means re-observing).
BELIEF_NODE = 'belief'


class ObservationTally:
    """What reached the planner since the episode's belief reset, so that an episode that
    never sees the cube says why: no observation at all, observations without an aspect
    hypothesis (the cube not in view, too few tags), or observations with one that no
    belief followed (the belief node not taking them); and how many beliefs arrived (none:
    this node's own inputs stalled). Counts only; callbacks on several threads may add
    while the runner reads, and a count off by one is harmless."""

    def __init__(self):
        self.reset()

    def reset(self):
        self.total = 0
        self.with_hypotheses = 0
        self.last_tags = ()
        self.beliefs = 0
        self.last_step = None

    def add(self, num_hypotheses, tag_ids):
        self.total += 1
        self.with_hypotheses += num_hypotheses > 0
        self.last_tags = tuple(tag_ids)

    def add_belief(self, step):
        self.beliefs += 1
        self.last_step = int(step)

    def describe(self):
        if self.total == 0:
            seen = 'no aspect observation arrived (is perception running?)'
        elif self.with_hypotheses == 0:
            tags = ', '.join(str(t) for t in self.last_tags) or 'none'
            seen = (f'{self.total} aspect observations arrived, none with an aspect '
                    f'hypothesis (tags in the last one: {tags}; is the cube in view?)')
        else:
            seen = (f'{self.with_hypotheses} of {self.total} aspect observations had an '
                    'aspect hypothesis, but no belief took one (does the belief node '
                    'receive them?)')
        last = f', the last at step {self.last_step}' if self.last_step is not None else ''
        plural = '' if self.beliefs == 1 else 's'
        return f'{seen}; {self.beliefs} belief{plural} since the reset{last}'


# Limits of the belief node's report: characters per quoted key or value, rejection kinds.
REPORT_CHARS, REPORT_ITEMS = 120, 10


def of_the_belief_node(publishers):
    """The endpoint gids among `publishers` ({gid: (namespace, node name)}) that are the
    belief node's: those of a node named as the belief node; if there is none, all of them
    (a renamed node, or one the graph lists without its name yet)."""
    named = {gid for gid, node in publishers.items() if node[1] == BELIEF_NODE}
    return named or set(publishers)


def belief_node_report(values, age_s, observation_topic='abp/aspect_observation'):
    """One clause on what the belief node says of itself in its latest /diagnostics status
    (`values`: {key: text}, `age_s` since it arrived; None: no status): whether it receives
    the observations, what it rejected, and what its evidence gate will do. It tells a
    stall in the belief node from one between the belief node and the planner."""
    if values is None:
        return 'no /diagnostics status of the belief node arrived'
    labels = ((keys.inputs_key(observation_topic), '{} aspect observations received'),
              (keys.age_key(observation_topic), 'the last {} s before'),
              (keys.REJECTED_TOTAL, '{} inputs rejected'), (BELIEF_STEP_KEY, 'at step {}'),
              (EVIDENCE_GATE_KEY, 'evidence gate: {}'))
    # Bounded: /diagnostics is anyone's topic, and this text ends up in a goal result.
    values = {key[:REPORT_CHARS]: value[:REPORT_CHARS] for key, value in values.items()}
    parts = [label.format(values[key]) for key, label in labels if key in values]
    rejected = [f'{count} {key.removeprefix(keys.REJECTED_PREFIX)}'
                for key, count in values.items()
                if keys.parse_rejected(key) is not None][:REPORT_ITEMS]
    if rejected:
        parts.append(f'rejected: {", ".join(rejected)}')
    return f'the belief node reported {age_s:.1f} s ago: {", ".join(parts)}'


class RecognitionAborted(Exception):
    """The loop cannot go on (no observation, no feasible action); the reason is the message."""


class _Cancelled(Exception):
    """The goal was cancelled while the runner waited (ends the episode as CANCELED)."""


class StopCheck(NamedTuple):
    stop: bool
    success: bool  # the recognition reached its goal (vs. gave up)
    reason: str


class PosteriorStop:
    """Stop with success once the top object posterior reaches `threshold`; stop without
    once `max_actions` actions are spent. Any object with this `check` can replace it."""

    def __init__(self, threshold, max_actions):
        self.threshold = float(threshold)
        self.max_actions = int(max_actions)

    def check(self, belief, actions_taken):
        posterior = top_posterior(belief)
        if posterior >= self.threshold:
            return StopCheck(True, True, f'posterior {posterior:.3f} >= {self.threshold}')
        if actions_taken >= self.max_actions:
            return StopCheck(True, False, f'action budget of {self.max_actions} spent')
        return StopCheck(False, False, '')


class RuleStop:
    """A `stopping.StoppingRule` on the abp_msgs/Belief the node receives: the rule sees the
    dense node belief (so its twin test works), and its verdict becomes a StopCheck whose
    success says whether the object was identified (not just the action budget spent)."""

    def __init__(self, rule, num_nodes):
        self.rule = rule
        self.num_nodes = int(num_nodes)

    def check(self, belief, actions_taken):
        if not belief.node_indices:
            decision = self.rule.check_marginal(np.asarray(belief.probabilities), actions_taken)
        else:
            decision = self.rule.check(belief_array(belief, self.num_nodes), actions_taken)
        return StopCheck(decision.stop, decision.identified, decision.reason)


class EpisodeResult(NamedTuple):
    outcome: str  # SUCCEEDED, CANCELED or ABORTED (how the goal ends)
    success: bool
    reason: str
    actions_taken: int
    belief: object  # the last belief (abp_msgs/Belief), None if there was none


class EpisodePorts(Protocol):
    """What the runner needs from the ROS side. A belief is an abp_msgs/Belief (or any
    object with step, probabilities, object_ids, entropy, node_indices and
    node_probabilities)."""

    def reset_belief(self) -> None:
        """Reset the belief node; raise RecognitionAborted if that fails."""

    def observations_since_reset(self) -> str:
        """What perception sent since the last reset (ObservationTally.describe)."""

    def wait_for_belief(self, predicate, timeout_s):
        """The latest belief once `predicate(belief)` holds, or None after `timeout_s`."""

    def latest_belief(self):
        """The latest belief received, or None."""

    def belief_restarted(self) -> bool:
        """True once after a belief whose step went back without a reset having been
        asked for: a new belief node (belief_inbox)."""

    def check_feasibility(self) -> dict:
        """{action: (feasible, reason)}; actions left out count as feasible."""

    def run_skill(self, action) -> tuple:
        """Run the skill to its end: (success, reason, duration)."""

    def cancel_requested(self) -> bool: ...

    def missing_nodes(self) -> list:
        """Names of the nodes the episode needs that are gone (BELIEF_NODE for the belief
        node); empty when all are there. A respawned belief node may be reported once
        only (its new publisher is then known), so the caller acts on the list it got."""

    def publish_plan(self, decision, feasible) -> None: ...

    def publish_feedback(self, belief, decision, actions_taken) -> None: ...

    def publish_executed(self, action, sequence, success, reason, duration) -> None: ...


def top_posterior(belief):
    return max(belief.probabilities) if belief.probabilities else 0.0


def belief_array(belief, num_nodes):
    """The (num_nodes,) normalised node belief of a sparse abp_msgs/Belief."""
    out = np.zeros(num_nodes)
    out[np.asarray(belief.node_indices, dtype=np.int64)] = belief.node_probabilities
    return out / out.sum()


def expected_gain(decision):
    """Expected information gain (bits) of the chosen action; NaN for the random planner."""
    if decision.information_gain is None:
        return float('nan')
    return float(decision.information_gain[decision.action_index])


class EpisodeRunner:
    """Runs one episode: `run()` -> EpisodeResult.

    planner: `choose(belief_array, feasible) -> Decision` (abp_planner.planner).
    stopping: `check(belief, actions_taken) -> StopCheck` (e.g. PosteriorStop).
    logger: info / warning / error (an rclpy or a logging logger)."""

    def __init__(self, planner, ports, num_nodes, stopping, observation_timeout_s, logger,
                 clock=time.monotonic, sleep=time.sleep, node_return_timeout_s=60.0,
                 skill_failure_limit=2):
        self.planner = planner
        self.ports = ports
        self.num_nodes = int(num_nodes)
        self.stopping = stopping
        self.observation_timeout_s = float(observation_timeout_s)
        self.node_return_timeout_s = float(node_return_timeout_s)
        self.skill_failure_limit = int(skill_failure_limit)
        self.log = logger
        self.clock = clock
        self.sleep = sleep

    def run(self):
        ports = self.ports
        actions_taken = 0
        try:
            belief = self._start()
            refused_after_failure = set()
            failures = Counter()
            while True:
                check = self.stopping.check(belief, actions_taken)
                if check.stop:
                    return EpisodeResult(SUCCEEDED, check.success, check.reason, actions_taken,
                                         belief)
                if ports.cancel_requested():
                    return EpisodeResult(CANCELED, False, 'cancelled', actions_taken, belief)
                belief = self._wait_for_lost_nodes(belief)
                given_up = {a for a, n in failures.items() if n >= self.skill_failure_limit}
                decision, feasible = self._decide(belief, refused_after_failure | given_up)
                ports.publish_plan(decision, feasible)
                ports.publish_feedback(belief, decision, actions_taken)
                self.log.info(
                    f'action {actions_taken + 1}: {decision.action} '
                    f'(IG {expected_gain(decision):.3f} bits, H {belief.entropy:.3f} bits, top '
                    f'{belief.object_ids[0] if belief.object_ids else "-"} '
                    f'{top_posterior(belief):.3f})')
                step_before = belief.step
                success, reason, duration = ports.run_skill(decision.action)
                actions_taken += 1
                ports.publish_executed(decision.action, actions_taken, success, reason, duration)
                if ports.cancel_requested():
                    return EpisodeResult(CANCELED, False, 'cancelled', actions_taken, belief)
                if success:
                    refused_after_failure.clear()
                    expected_step = step_before + 2  # prediction, then a fresh correction
                else:
                    # Re-plan without the action that just failed, once.
                    self.log.warning(f'{decision.action} failed: {reason}; re-planning')
                    refused_after_failure.add(decision.action)
                    failures[decision.action] += 1
                    if failures[decision.action] == self.skill_failure_limit:
                        self.log.warning(
                            f'{decision.action} failed {self.skill_failure_limit} times in '
                            'this episode: not choosing it again unless nothing else is '
                            'feasible')
                    expected_step = step_before + 1  # a fresh correction only
                belief = self._wait_for_evidence(expected_step, step_before) or belief
        except _Cancelled:
            return EpisodeResult(CANCELED, False, 'cancelled', actions_taken,
                                 ports.latest_belief())
        except RecognitionAborted as error:
            self.log.error(f'recognition aborted: {error}')
            return EpisodeResult(ABORTED, False, str(error), actions_taken,
                                 ports.latest_belief())

    def _start(self):
        """Reset the belief and wait for the first observation of this episode."""
        self.ports.reset_belief()
        first = self.ports.wait_for_belief(lambda b: b.step >= 1, self.observation_timeout_s)
        if first is None:
            raise RecognitionAborted(
                f'no observation of the cube within {self.observation_timeout_s:.1f} s: '
                f'{self.ports.observations_since_reset()}')
        return first

    def _wait_for_lost_nodes(self, belief, missing=None):
        """`belief` if every needed node is there (`missing`, asked for when None); else
        pause until they are back and return the belief re-observed after their return,
        or abort naming them."""
        if missing is None:
            missing = self.ports.missing_nodes()
        if not missing:
            return belief
        gone = set(missing)
        self.log.warning(f'episode paused: {", ".join(sorted(gone))} gone; waiting up to '
                         f'{self.node_return_timeout_s:.0f} s for '
                         f'{"it" if len(gone) == 1 else "them"} to come back')
        deadline = self.clock() + self.node_return_timeout_s
        while missing:
            if self.ports.cancel_requested():
                raise _Cancelled()
            if self.clock() > deadline:
                raise RecognitionAborted(
                    f'{", ".join(sorted(missing))} gone and not back within '
                    f'{self.node_return_timeout_s:.0f} s')
            self.sleep(NODE_POLL_S)
            missing = self.ports.missing_nodes()
            gone.update(missing)
        self.log.info(f'{", ".join(sorted(gone))} back: re-observing')
        if BELIEF_NODE in gone:
            return self._start()  # the evidence died with the old belief node
        latest = self.ports.wait_for_belief(lambda b: True, self.observation_timeout_s)
        return latest if latest is not None else belief

    def _decide(self, belief, excluded):
        """The planner's choice among the feasible actions: (decision, feasibility).

        "Nothing feasible" is often transient (the skills have not yet seen a cube
        pose estimate, or the estimate is momentarily stale), so it is re-checked
        for up to the observation timeout before the recognition is aborted.
        """
        nodes = belief_array(belief, self.num_nodes)
        deadline = self.clock() + self.observation_timeout_s
        while True:
            feasible = self.ports.check_feasibility()

            def allowed(action, feasible=feasible):
                return feasible.get(action, (True, ''))[0] and action not in excluded

            try:
                return self.planner.choose(nodes, feasible=allowed), feasible
            except RuntimeError as error:
                if excluded:
                    # Every other action is infeasible: allow a retry of the failed ones.
                    excluded = set()
                    continue
                if self.clock() > deadline:
                    reasons = '; '.join(f'{a}: {r}' for a, (ok, r) in feasible.items() if not ok)
                    raise RecognitionAborted(f'{error} ({reasons})') from error
                self.sleep(FEASIBILITY_RETRY_S)

    def _wait_for_evidence(self, expected_step, step_before):
        """The belief with the action's evidence; after the timeout, the latest one.

        A belief whose step went back is from a belief node that restarted (a respawn)
        before DDS noticed the old one gone: its belief lacks this episode's evidence, so
        the episode re-observes from a reset belief."""
        deadline = self.clock() + self.observation_timeout_s
        while True:
            fresh = self.ports.wait_for_belief(
                lambda b: b.step >= expected_step or b.step < step_before,
                max(0.0, min(EVIDENCE_CHECK_S, deadline - self.clock())))
            if fresh is not None or self.clock() >= deadline:
                break
            # No evidence yet: the nodes it comes from may be gone (a link that dropped
            # takes them all): pause for them, naming them, rather than plan on without.
            # Asked once: a respawned belief node is reported once (EpisodePorts); asked
            # again it would be "all there", and the episode would plan on the old belief
            # (a CI run: the respawned belief node was never re-observed).
            missing = self.ports.missing_nodes()
            if missing:
                return self._wait_for_lost_nodes(None, missing)
        if self.ports.belief_restarted() or (fresh is not None and fresh.step < step_before):
            self.log.warning(f'the belief went back from step {step_before} (now step '
                             f'{fresh.step if fresh is not None else "-"}): the belief node '
                             'restarted; re-observing')
            return self._start()
        if fresh is None:
            self.log.warning(
                'no fresh observation after the action within '
                f'{self.observation_timeout_s:.1f} s; planning on the latest belief')
            fresh = self.ports.wait_for_belief(lambda b: True, LATEST_BELIEF_WAIT_S)
        return fresh


__all__ = ['ABORTED', 'BELIEF_NODE', 'CANCELED', 'SUCCEEDED', 'EpisodePorts', 'EpisodeResult',
           'of_the_belief_node',
           'EpisodeRunner', 'PosteriorStop', 'RecognitionAborted', 'StopCheck', 'belief_array',
           'belief_node_report', 'expected_gain', 'top_posterior']
