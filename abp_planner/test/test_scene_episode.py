"""The multi-object Recognize episode without DDS (abp_planner.scene_episode and
scene_inbox): a model-sampled scene behind fake ports that publish scene beliefs the way
the belief node does (one Belief per track, steps per track), on a fake clock."""

import logging

import numpy as np
import pytest

from abp_belief import population
from abp_belief.cube import STATES_PER_MODEL, action_index
from abp_belief.factored_belief import FactoredBelief
from abp_msgs.msg import Belief, ObjectBelief, SceneBelief
from abp_planner.episode import ABORTED, BELIEF_NODE, CANCELED, SUCCEEDED, RecognitionAborted
from abp_planner.object_planner import ObjectActionPlanner
from abp_planner.planner import make_planner
from abp_planner.scene_episode import SceneEpisodeRunner, SceneView, task_of
from abp_planner.scene_inbox import SceneInbox
from abp_planner.stopping import StoppingRule
from abp_planner.tasks import Task, TaskMonitor

LOG = logging.getLogger('test_scene_episode')


@pytest.fixture(scope='module')
def models():
    return population.robot_set(seed=5)


def belief_message(node_belief, step, stamp_s, model_set):
    msg = Belief(step=step, total_models=model_set.num_models)
    msg.header.stamp.sec = int(stamp_s)
    marginal = node_belief.reshape(-1, STATES_PER_MODEL).sum(axis=1)
    order = np.argsort(-marginal, kind='stable')
    msg.object_ids = [model_set.names[i] for i in order[:5]]
    msg.probabilities = marginal[order[:5]].tolist()
    nodes = np.flatnonzero(node_belief > 0)
    msg.node_indices = nodes.tolist()
    msg.node_probabilities = node_belief[nodes].tolist()
    return msg


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds


class SceneWorldPorts:
    """Cubes of `truth` ({track: model}) sampled from the model set; the scene belief is
    a FactoredBelief updated as the belief node does (a correction on each track's first
    view after a reset, then a prediction and a correction per successful action on the
    track named by the executed action)."""

    def __init__(self, model_set, truth, seed=0, fail=(), clock=None):
        self.models = model_set
        self.truth = dict(truth)
        self.rng = np.random.default_rng(seed)
        self.state = {t: int(self.rng.integers(STATES_PER_MODEL)) for t in truth}
        self.fail = set(fail)   # (track, action) that fail
        self.clock = clock or FakeClock()
        self.resets, self.executed, self.feedback, self.plans = [], [], [], []
        self.belief = FactoredBelief(model_set)
        self.steps = {}
        self.scene = None
        self.lost = []
        self.hide_after_reset = set()

    def _observe(self, track):
        node = self.truth[track] * STATES_PER_MODEL + self.state[track]
        z = self.models.observation.sample(int(self.models.node_aspect[node]), self.rng)
        self.belief.correct(track, z)
        self.steps[track] += 1

    def _publish(self):
        scene = SceneBelief()
        for track in self.belief.object_ids:
            scene.objects.append(ObjectBelief(track_id=track, belief=belief_message(
                self.belief.belief(track), self.steps[track], self.clock.now, self.models)))
        self.scene = scene

    # -- ports --------------------------------------------------------------------------
    def reset_belief(self, track_id=''):
        self.resets.append(track_id)
        if track_id:
            if track_id not in self.belief:
                raise RecognitionAborted(f'belief reset failed: {track_id!r} not tracked')
            self.belief.reset(track_id)
            self.steps[track_id] = 0
            self._observe(track_id)
        else:
            self.belief = FactoredBelief(self.models)
            self.steps = {}
            for track in self.truth:
                if track in self.hide_after_reset:
                    continue
                self.belief.add_object(track)
                self.steps[track] = 0
                self._observe(track)
        self._publish()

    def wait_for_belief(self, predicate, timeout_s):
        if self.scene is not None and predicate(self.scene):
            return self.scene
        self.clock.now += timeout_s
        return None

    def latest_belief(self):
        return self.scene

    def belief_restarted(self):
        return False

    def observations_since_reset(self):
        return 'fake'

    def check_feasibility(self):
        return {}

    def run_skill(self, action, track_id=''):
        self.clock.now += 1.0
        if (track_id, action) in self.fail:
            return False, 'slipped', None
        return True, '', None

    def cancel_requested(self):
        return False

    def missing_nodes(self):
        return self.lost.pop(0) if self.lost else []

    def publish_plan(self, decision, feasible):
        self.plans.append(decision.action)

    def publish_feedback(self, belief, decision, actions_taken, track_id=''):
        self.feedback.append(track_id)

    def publish_executed(self, action, sequence, success, reason, duration, track_id=''):
        self.executed.append((track_id, action, success))
        if success:
            index = action_index(action)
            node = self.truth[track_id] * STATES_PER_MODEL + self.state[track_id]
            nodes, probs = self.models.successors(index, np.array([node]))
            self.state[track_id] = int(self.rng.choice(nodes[0], p=probs[0])) % STATES_PER_MODEL
            self.belief.predict(track_id, action)
            self.steps[track_id] += 1
            self._observe(track_id)
        # A failed skill brings no fresh view here (the runner waits out its timeout and
        # plans on the same belief): only the runner's exclusions keep it from the same
        # choice.
        self._publish()


def runner(models, ports, task, **kwargs):
    rule = StoppingRule.for_model_set(models, max_actions=kwargs.pop('max_actions', 30))
    planner = ObjectActionPlanner(make_planner('abp', models))
    return SceneEpisodeRunner(planner, ports, models, TaskMonitor(task, rule), 5.0, LOG,
                              clock=ports.clock, sleep=ports.clock.sleep, gather_s=0.5,
                              **kwargs)


TRUTH = {'cube1': 0, 'cube2': 7, 'cube3': 28}


def test_identify_all_names_every_track_acting_on_the_chosen_one(models):
    ports = SceneWorldPorts(models, TRUTH, seed=1)
    result = runner(models, ports, Task('identify_all')).run()
    assert (result.outcome, result.success) == (SUCCEEDED, True), result.reason
    named = {o.object_id: o for o in result.objects}
    assert {t: named[t].model for t in TRUTH} == TRUTH
    assert all(o.identified for o in result.objects)
    assert result.actions_taken == len(ports.executed)
    assert ports.feedback == [track for track, _, _ in ports.executed]
    assert result.actions_per_object == {t: n for t, n in
                                         _count(ports.executed).items()}
    assert ports.resets == ['']


def _count(executed):
    counts = {}
    for track, _, _ in executed:
        counts[track] = counts.get(track, 0) + 1
    return counts


def test_find_stops_at_the_target_track(models):
    ports = SceneWorldPorts(models, TRUTH, seed=2)
    result = runner(models, ports, Task('find', model=TRUTH['cube2'])).run()
    assert result.success and result.found_object == 'cube2', result.reason
    assert len(result.objects) == 3


def test_identify_acts_on_its_track_only_and_resets_only_it(models):
    ports = SceneWorldPorts(models, TRUTH, seed=3)
    ports.reset_belief()   # the scene the belief node had before the goal
    result = runner(models, ports, Task('identify', object_id='cube3')).run()
    assert result.success, result.reason
    assert {track for track, _, _ in ports.executed} == {'cube3'}
    assert ports.resets == ['', 'cube3']
    assert next(o for o in result.objects if o.object_id == 'cube3').model == TRUTH['cube3']


def test_an_unknown_track_aborts_with_the_reason(models):
    ports = SceneWorldPorts(models, TRUTH, seed=3)
    ports.reset_belief()
    result = runner(models, ports, Task('identify', object_id='cube9')).run()
    assert result.outcome == ABORTED and "'cube9'" in result.reason
    assert result.actions_taken == 0


FAILING = ('ORBIT_P45', 'ORBIT_P90', 'ORBIT_M45', 'ORBIT_M90')


def _failures_in_a_row(executed):
    """(track, action) failures that came right after the same failure on that track."""
    last, repeats = {}, []
    for track, action, ok in executed:
        if not ok and last.get(track) == (action, False):
            repeats.append((track, action))
        last[track] = (action, ok)
    return repeats


@pytest.mark.parametrize('seed', [4, 8])
def test_a_failed_skill_is_left_out_of_its_tracks_next_decision(models, seed):
    ports = SceneWorldPorts(models, TRUTH, seed=seed,
                            fail={(t, a) for t in TRUTH for a in FAILING})
    result = runner(models, ports, Task('identify_all')).run()
    assert any(not ok for _, _, ok in ports.executed), 'no failure: the test tests nothing'
    assert not _failures_in_a_row(ports.executed)
    assert result.success, result.reason


@pytest.mark.parametrize('seed', [4, 8])
def test_a_skill_is_given_up_on_a_track_after_the_failure_limit(models, seed):
    ports = SceneWorldPorts(models, TRUTH, seed=seed,
                            fail={(t, a) for t in TRUTH for a in FAILING})
    result = runner(models, ports, Task('identify_all'), skill_failure_limit=1).run()
    failed = [(t, a) for t, a, ok in ports.executed if not ok]
    assert failed and len(failed) == len(set(failed)), failed
    assert result.success, result.reason


def test_a_track_seen_late_joins_the_scene(models):
    ports = SceneWorldPorts(models, TRUTH, seed=5)
    ports.hide_after_reset = {'cube3'}
    run = runner(models, ports, Task('identify_all'))
    original = ports.publish_executed

    def executed_then_cube3_appears(*args, **kwargs):
        original(*args, **kwargs)
        if 'cube3' not in ports.belief:
            ports.belief.add_object('cube3')
            ports.steps['cube3'] = 0
            ports._observe('cube3')
            ports._publish()
    ports.publish_executed = executed_then_cube3_appears
    result = run.run()
    assert result.success and {o.object_id for o in result.objects} == set(TRUTH)
    assert any(track == 'cube3' for track, _, _ in ports.executed)


def test_a_lost_belief_node_restarts_from_a_reset(models):
    ports = SceneWorldPorts(models, TRUTH, seed=6)
    ports.lost = [[BELIEF_NODE], []]
    result = runner(models, ports, Task('identify_all')).run()
    assert result.success and ports.resets == ['', '']


def test_a_cancel_ends_the_episode(models):
    ports = SceneWorldPorts(models, TRUTH, seed=7)
    ports.cancel_requested = lambda: True
    assert runner(models, ports, Task('identify_all')).run().outcome == CANCELED


def test_task_of_names_what_is_wrong(models):
    assert task_of('identify_all') == Task('identify_all')
    assert task_of('find', models.names[7], model_names=models.names) == Task('find', model=7)
    assert task_of('identify', track_id='cube2') == Task('identify', object_id='cube2')
    for args, words in ((('find', 'nope'), 'not a model'), (('find',), 'needs target_model'),
                        (('identify',), 'needs track_id'), (('arrange',), 'unknown task')):
        with pytest.raises(ValueError, match=words):
            task_of(*args, model_names=models.names)


def test_scene_view_reads_a_belief_without_nodes_by_model(models):
    entry = ObjectBelief(track_id='a', belief=Belief(
        step=1, object_ids=[models.names[3], models.names[4]], probabilities=[0.75, 0.25]))
    view = SceneView(SceneBelief(objects=[entry]), models)
    assert view.most_likely_model('a') == (3, pytest.approx(0.75))
    assert view.belief('a').sum() == pytest.approx(1.0)


def scene(**steps):
    return SceneBelief(objects=[ObjectBelief(track_id=t, belief=Belief(step=s))
                                for t, s in steps.items()])


def test_scene_inbox_skips_scenes_from_before_the_reset_and_sees_a_restart():
    inbox = SceneInbox()
    inbox.reset_asked('')
    assert not inbox.offer(scene(a=4, b=2))          # in flight from before the reset
    assert inbox.offer(scene())                        # the reset's own (no track)
    assert inbox.offer(scene(a=1)) and inbox.offer(scene(a=1, b=1))
    assert not inbox.take_restart()
    inbox.offer(scene(a=3, b=1))
    assert not inbox.take_restart()
    inbox.offer(scene(b=1))                            # track a vanished: a new belief node
    assert inbox.take_restart() and not inbox.take_restart()
    inbox.offer(scene(a=1, b=0))                       # b went back
    assert inbox.take_restart()
    # One track's reset: skip until that track is at step 0.
    inbox.reset_asked('a')
    assert not inbox.offer(scene(a=2, b=1))
    assert inbox.offer(scene(a=0, b=1))
    assert inbox.wait(lambda s: True, 0.01).objects[0].belief.step == 0
    inbox.reset_asked('b')
    inbox.reset_refused()
    assert inbox.offer(scene(a=3, b=4))
