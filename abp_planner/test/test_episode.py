"""The Recognize episode without DDS: stopping, re-plan after a failure, retry, the
feasibility wait, missing observations and cancellation, on a fake clock."""

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from abp_belief.cube import ACTIONS
from abp_planner.episode import (
    ABORTED,
    BELIEF_NODE,
    CANCELED,
    FEASIBILITY_RETRY_S,
    SUCCEEDED,
    EpisodeRunner,
    ObservationTally,
    PosteriorStop,
    RecognitionAborted,
    RuleStop,
    belief_array,
    belief_node_report,
    expected_gain,
)
from abp_planner.planner import Decision
from abp_planner.stopping import StoppingRule

NUM_NODES = 96  # two models


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds


def belief(step, posterior):
    return SimpleNamespace(step=step, probabilities=[posterior, 1.0 - posterior],
                           object_ids=['a', 'b'], entropy=1.0, node_indices=[0, 48],
                           node_probabilities=[posterior, 1.0 - posterior])


class FakePlanner:
    """Takes the first allowed action of `preference`; raises like the real one."""

    def __init__(self, preference=ACTIONS):
        self.preference = list(preference)
        self.beliefs = []

    def choose(self, nodes, feasible=None):
        self.beliefs.append(nodes)
        for action in self.preference:
            if feasible is None or feasible(action):
                index = ACTIONS.index(action)
                gain = np.zeros(len(ACTIONS))
                gain[index] = 0.5
                return Decision(action, index, gain, gain, 1.0, 0.001)
        raise RuntimeError('no feasible action: the motion planner refused everything')


class FakePorts:
    """A belief node and skills in one: each action raises the posterior by `gain`;
    a successful skill gives a prediction and a correction (+2 steps), a failed one a
    correction (+1). `observe=False` withholds observations."""

    def __init__(self, clock, gain=0.2, fail=(), feasible=None, observe=True,
                 first_posterior=0.5, cancel_after=None, missing=None):
        self.clock = clock
        self.missing = missing  # missing(ports) -> names of the nodes gone now
        self.resets = 0
        self.gain = gain
        self.fail = set(fail)
        self.feasible = feasible if feasible is not None else {}
        self.observe = observe
        self.belief = None
        self.first_posterior = first_posterior
        self.cancel_after = cancel_after
        self.plans, self.feedback, self.executed, self.skills = [], [], [], []
        self.feasibility_checks = 0

    def reset_belief(self):
        self.resets += 1
        self.belief = belief(1 if self.observe else 0, self.first_posterior)

    def missing_nodes(self):
        return list(self.missing(self)) if self.missing else []

    def observations_since_reset(self):
        return 'no aspect observation arrived (is perception running?); 1 belief since ' \
            'the reset, the last at step 0'

    def wait_for_belief(self, predicate, timeout_s):
        if self.belief is not None and predicate(self.belief):
            return self.belief
        self.clock.sleep(timeout_s)
        return None

    def latest_belief(self):
        return self.belief

    def belief_restarted(self):
        return False

    def check_feasibility(self):
        self.feasibility_checks += 1
        feasible = self.feasible
        return feasible(self.clock()) if callable(feasible) else feasible

    def run_skill(self, action):
        self.skills.append(action)
        if action in self.fail:
            return False, f'{action} slipped', 3.0
        step = self.belief.step + (2 if self.observe else 1)
        self.belief = belief(step, min(1.0, self.belief.probabilities[0] + self.gain))
        return True, '', 3.0

    def cancel_requested(self):
        return self.cancel_after is not None and len(self.executed) >= self.cancel_after

    def publish_plan(self, decision, feasible):
        self.plans.append(decision.action)

    def publish_feedback(self, belief, decision, actions_taken):
        self.feedback.append((belief.step, decision.action, actions_taken))

    def publish_executed(self, action, sequence, success, reason, duration):
        self.executed.append((action, sequence, success, reason))


def run(ports, planner=None, threshold=0.95, max_actions=30, timeout=20.0, node_return=60.0,
        failure_limit=2):
    clock = ports.clock
    runner = EpisodeRunner(planner or FakePlanner(), ports, NUM_NODES,
                           PosteriorStop(threshold, max_actions), timeout,
                           logging.getLogger('episode'), clock=clock, sleep=clock.sleep,
                           node_return_timeout_s=node_return, skill_failure_limit=failure_limit)
    return runner.run()


def test_a_lost_belief_node_pauses_the_episode_and_its_return_restarts_the_evidence():
    clock = FakeClock()
    # The belief node dies after the first action and is back 10 s later (respawned).
    died = {}

    def missing(ports):
        if len(ports.executed) >= 1:
            died.setdefault('at', clock())
        return [BELIEF_NODE] if 'at' in died and clock() < died['at'] + 10.0 else []

    ports = FakePorts(clock, gain=0.2, missing=missing)
    result = run(ports)
    assert result.outcome == SUCCEEDED and result.success
    # Paused (no action during the 10 s), then re-observed from a reset belief.
    assert ports.resets == 2 and clock() >= 10.0
    assert result.actions_taken == 1 + 3  # the evidence of the first action was lost


def test_a_respawn_reported_once_while_waiting_for_evidence_is_re_observed(caplog):
    """The belief node is killed after the first action and respawned before DDS drops
    the old one: the action's evidence never comes, and the ROS side reports the belief
    node lost once only (at its first sight of the new node's publisher), as
    PlannerNode.missing_nodes does. The episode must re-observe, not plan on the old
    belief (a CI run: asked twice, the second answer was "all there")."""
    clock = FakeClock()
    seen = []

    def respawned_once(ports):
        if ports.executed and not seen:
            seen.append(clock())
            return [BELIEF_NODE]
        return []

    class NoEvidence(FakePorts):
        def run_skill(self, action):
            outcome = super().run_skill(action)
            if len(self.skills) == 1:
                self.belief = belief(1, self.first_posterior)  # its evidence died
            return outcome

    ports = NoEvidence(clock, gain=0.2, missing=respawned_once)
    with caplog.at_level(logging.INFO, logger='episode'):
        result = run(ports, timeout=5.0)
    assert result.outcome == SUCCEEDED and result.success
    said = [r.getMessage() for r in caplog.records]
    assert any('belief back: re-observing' in line for line in said), said
    assert ports.resets == 2
    # Noticed at the first evidence check, a second after the action.
    assert seen == [1.0]


def test_evidence_cut_off_by_a_lost_link_pauses_the_episode_naming_what_is_gone(caplog):
    """A link to the robot drops as the first action is done: its evidence and the nodes
    it comes from are gone for 10 s. The runner pauses naming them (it does not wait out
    the observation timeout and plan on), and goes on when they are back."""
    clock = FakeClock()
    lost = ['aspect observations (/abp/aspect_observation)',
            'skill servers (/abp/skills/orbit)']

    def link_down(ports):
        return bool(ports.executed) and clock() < 10.0

    class Dropped(FakePorts):
        def wait_for_belief(self, predicate, timeout_s):
            if link_down(self):
                self.clock.sleep(timeout_s)
                return None
            return super().wait_for_belief(predicate, timeout_s)

    ports = Dropped(clock, gain=0.2, missing=lambda p: lost if link_down(p) else [])
    with caplog.at_level(logging.INFO, logger='episode'):
        result = run(ports, timeout=20.0)
    assert result.outcome == SUCCEEDED and result.success
    paused = [r.getMessage() for r in caplog.records if 'episode paused' in r.getMessage()]
    assert len(paused) == 1 and all(name in paused[0] for name in lost), paused
    assert any('back: re-observing' in r.getMessage() for r in caplog.records)
    # Noticed within a second of the evidence wait, not after the 20 s timeout.
    assert 10.0 <= clock() < 12.0
    assert ports.resets == 1   # the belief node was not lost: no reset


def test_a_belief_that_goes_back_means_a_restarted_belief_node():
    # Respawned before DDS saw the old node go: no pause, but its belief starts again.
    class Respawned(FakePorts):
        def run_skill(self, action):
            outcome = super().run_skill(action)
            if len(self.skills) == 2:
                self.belief = belief(0, 0.5)
            return outcome

    ports = Respawned(FakeClock(), gain=0.2)
    result = run(ports)
    assert result.outcome == SUCCEEDED and result.success
    assert ports.resets == 2 and result.actions_taken == 2 + 3


def test_a_node_that_does_not_come_back_aborts_the_goal_naming_it():
    clock = FakeClock()
    gone = 'skill server /abp/skills/push'
    ports = FakePorts(clock, missing=lambda p: [gone] if p.executed else [])
    result = run(ports, node_return=30.0)
    assert result.outcome == ABORTED and not result.success
    assert result.reason == f'{gone} gone and not back within 30 s'
    assert result.actions_taken == 1 and 30.0 <= clock() <= 31.0
    assert ports.resets == 1  # no belief node was lost: nothing to re-observe


def test_cancel_while_paused_for_a_node_ends_the_goal_as_cancelled():
    clock = FakeClock()
    ports = FakePorts(clock, missing=lambda p: [BELIEF_NODE] if clock() < 5.0 else [])
    ports.cancel_requested = lambda: clock() >= 2.0
    result = run(ports)
    assert result.outcome == CANCELED and result.reason == 'cancelled'
    assert not ports.executed


def test_stops_when_the_first_observation_is_enough():
    ports = FakePorts(FakeClock(), first_posterior=0.99)
    result = run(ports)
    assert (result.outcome, result.success, result.actions_taken) == (SUCCEEDED, True, 0)
    assert result.reason.startswith('posterior 0.990 >=') and not ports.executed


def test_acts_until_the_posterior_reaches_the_threshold():
    ports = FakePorts(FakeClock(), gain=0.2)
    planner = FakePlanner()
    result = run(ports, planner, threshold=0.95)
    assert result.outcome == SUCCEEDED and result.success
    assert result.actions_taken == 3 and result.belief.probabilities[0] >= 0.95
    assert [e[1] for e in ports.executed] == [1, 2, 3]
    assert ports.plans == [e[0] for e in ports.executed] == ['ORBIT_P45'] * 3
    assert [f[2] for f in ports.feedback] == [0, 1, 2]
    # The planner gets the normalised node array, not a message or a filter.
    assert planner.beliefs[0].shape == (NUM_NODES,)
    assert planner.beliefs[0].sum() == pytest.approx(1.0)


def test_action_budget_ends_without_success():
    ports = FakePorts(FakeClock(), gain=0.0)
    result = run(ports, max_actions=2)
    assert (result.outcome, result.success) == (SUCCEEDED, False)
    assert result.reason == 'action budget of 2 spent' and result.actions_taken == 2


def test_failed_action_is_left_out_of_the_next_decision():
    ports = FakePorts(FakeClock(), fail={'ORBIT_P45'})
    run(ports)
    assert ports.skills[:2] == ['ORBIT_P45', 'ORBIT_M45']
    assert ports.executed[0] == ('ORBIT_P45', 1, False, 'ORBIT_P45 slipped')
    # After a success the failed action may be chosen again.
    assert ports.skills[2] == 'ORBIT_P45'


def test_a_skill_that_keeps_failing_is_given_up_for_the_episode():
    # The planner prefers LIFT, which always slips: after the second failure it is
    # never chosen again, although it would be after a success in between.
    planner = FakePlanner(['LIFT', 'PUSH'])
    ports = FakePorts(FakeClock(), gain=0.0, fail={'LIFT'})
    result = run(ports, planner, max_actions=8)
    assert ports.skills == ['LIFT', 'PUSH', 'LIFT'] + ['PUSH'] * 5
    assert result.actions_taken == 8


@pytest.mark.parametrize('limit', [1, 3])
def test_the_failure_limit_is_a_parameter(limit):
    planner = FakePlanner(['LIFT', 'PUSH'])
    ports = FakePorts(FakeClock(), gain=0.0, fail={'LIFT'})
    run(ports, planner, max_actions=8, failure_limit=limit)
    assert ports.skills.count('LIFT') == limit


def test_failed_action_is_retried_when_nothing_else_is_feasible():
    only = {a: (a == 'LIFT', 'blocked') for a in ACTIONS}
    ports = FakePorts(FakeClock(), fail={'LIFT'}, feasible=only)
    result = run(ports, max_actions=3)
    assert ports.skills == ['LIFT'] * 3
    assert result.reason == 'action budget of 3 spent'


def test_transiently_infeasible_actions_are_rechecked():
    clock = FakeClock()
    ports = FakePorts(clock, first_posterior=0.9,
                      feasible=lambda now: {} if now >= 2.0 else
                      {a: (False, 'no cube pose') for a in ACTIONS})
    result = run(ports)
    assert result.outcome == SUCCEEDED and ports.skills == ['ORBIT_P45']
    assert ports.feasibility_checks == 1 + int(2.0 / FEASIBILITY_RETRY_S)


def test_nothing_feasible_aborts_after_the_observation_timeout():
    ports = FakePorts(FakeClock(), feasible={a: (False, 'too close') for a in ACTIONS})
    result = run(ports, timeout=3.0)
    assert result.outcome == ABORTED and not result.success
    assert 'no feasible action' in result.reason and 'PUSH: too close' in result.reason
    assert ports.clock() >= 3.0 and not ports.executed


def test_no_first_observation_aborts():
    ports = FakePorts(FakeClock(), observe=False)
    result = run(ports, timeout=5.0)
    assert result.outcome == ABORTED
    assert result.reason == ('no observation of the cube within 5.0 s: no aspect observation '
                             'arrived (is perception running?); 1 belief since the reset, '
                             'the last at step 0')


def test_observation_tally_says_why_no_belief_came():
    tally = ObservationTally()
    assert tally.describe() == ('no aspect observation arrived (is perception running?); '
                                '0 beliefs since the reset')
    tally.add_belief(0)
    tally.add(0, [3])
    tally.add(0, [])
    assert tally.describe() == ('2 aspect observations arrived, none with an aspect '
                                'hypothesis (tags in the last one: none; is the cube in view?); '
                                '1 belief since the reset, the last at step 0')
    tally.add(2, [1, 4])
    assert tally.describe().startswith('1 of 3 aspect observations had an aspect hypothesis')
    tally.reset()
    assert tally.total == 0 and tally.with_hypotheses == 0 and tally.beliefs == 0


def test_reset_failure_aborts():
    ports = FakePorts(FakeClock())

    def refuse():
        raise RecognitionAborted('belief reset failed: no answer')

    ports.reset_belief = refuse
    result = run(ports)
    assert (result.outcome, result.reason, result.belief) == \
        (ABORTED, 'belief reset failed: no answer', None)


def test_missing_observation_after_an_action_plans_on_the_latest_belief():
    clock = FakeClock()
    ports = FakePorts(clock, first_posterior=0.9)
    ports.reset_belief()
    first_run_skill = ports.run_skill

    def skill_without_correction(action):
        ok = first_run_skill(action)
        ports.belief.step -= 1  # the prediction arrived, the correction did not
        return ok

    ports.reset_belief = lambda: None
    ports.run_skill = skill_without_correction
    result = run(ports, timeout=4.0)
    assert result.outcome == SUCCEEDED and result.actions_taken == 1
    assert clock() == pytest.approx(4.0)  # waited the observation timeout once


def test_cancel_before_and_after_a_skill():
    ports = FakePorts(FakeClock(), cancel_after=0)
    result = run(ports)
    assert (result.outcome, result.reason, result.actions_taken) == (CANCELED, 'cancelled', 0)
    ports = FakePorts(FakeClock(), gain=0.0, cancel_after=1)
    result = run(ports)
    assert (result.outcome, result.actions_taken) == (CANCELED, 1)
    assert len(ports.executed) == 1


def test_helpers():
    msg = belief(1, 0.75)
    nodes = belief_array(msg, NUM_NODES)
    assert nodes[0] == 0.75 and nodes[48] == 0.25 and nodes.sum() == 1.0
    assert np.isnan(expected_gain(Decision('PUSH', 5, None, None, float('nan'), 0.0)))
    stop = PosteriorStop(0.9, 4)
    assert stop.check(belief(1, 0.9), 0).success
    assert stop.check(belief(1, 0.5), 4) == (True, False, 'action budget of 4 spent')
    assert not stop.check(belief(1, 0.5), 3).stop


def test_rule_stop_reports_identification_only_for_an_answer():
    rule = RuleStop(StoppingRule(kind='error', target_error=0.003, max_actions=4), NUM_NODES)
    assert rule.check(belief(3, 0.999), 1) == (True, True, rule.check(belief(3, 0.999),
                                                                        1).reason)
    assert 'P(wrong)' in rule.check(belief(3, 0.999), 1).reason
    unsure = rule.check(belief(3, 0.9), 1)
    assert not unsure.stop
    spent = rule.check(belief(3, 0.9), 4)
    assert spent.stop and not spent.success and 'action limit' in spent.reason
    # Without node beliefs the rule decides on the object marginal.
    marginal_only = SimpleNamespace(step=1, probabilities=[0.999, 0.001], object_ids=['a', 'b'],
                                    entropy=0.0, node_indices=[], node_probabilities=[])
    assert rule.check(marginal_only, 0).success


def test_belief_node_report_quotes_its_inputs_and_its_gate():
    assert belief_node_report(None, 0.0) == 'no /diagnostics status of the belief node arrived'
    values = {'abp/aspect_observation inputs': '412',
              'abp/aspect_observation age of last input (s)': '0.07',
              'abp/aspect_observation rate (Hz)': '14.9', 'rejected total': '0',
              'belief step': '0', 'evidence gate': 'the next observation stamped at or after '
                                                   '12.000 s corrects'}
    assert belief_node_report(values, 0.42) == (
        'the belief node reported 0.4 s ago: 412 aspect observations received, the last '
        '0.07 s before, 0 inputs rejected, at step 0, evidence gate: the next observation '
        'stamped at or after 12.000 s corrects')
    values.update({'rejected total': '3', 'rejected abp/aspect_observation frame': '3'})
    assert belief_node_report(values, 0.42).endswith(
        '3 inputs rejected, at step 0, evidence gate: the next observation stamped at or '
        'after 12.000 s corrects, rejected: 3 abp/aspect_observation frame')
    values['evidence gate'] = 'x' * 10_000
    assert len(belief_node_report(values, 0.42)) < 1000
