"""Tasks over several objects (issue 37): each task's stop rule and candidate objects, and
the model-sampled scene simulation that runs them (a cube in a scene is worked on as it
would be alone)."""

import numpy as np
import pytest

from abp_belief import population
from abp_belief.factored_belief import FactoredBelief
from abp_planner.object_planner import ObjectActionPlanner
from abp_planner.planner import make_planner
from abp_planner.scene_simulator import SceneCube, place_cubes, run_scene
from abp_planner.simulator import run_trial
from abp_planner.stopping import StoppingRule
from abp_planner.tasks import Task, TaskMonitor


@pytest.fixture(scope='module')
def robot():
    return population.robot_set(seed=0)


@pytest.fixture(scope='module')
def rule(robot):
    return StoppingRule.for_model_set(robot, max_actions=30)


def weights(model_set, spread: dict):
    w = np.zeros(model_set.num_models)
    for model, p in spread.items():
        w[model] = p
    return w


def scene(model_set, **priors):
    """A FactoredBelief whose objects start from the given model weights (None: uniform)."""
    belief = FactoredBelief(model_set)
    for name, spread in priors.items():
        belief.add_object(name, None if spread is None else weights(model_set, spread))
    return belief


def test_identify_all_waits_for_every_object(robot, rule):
    monitor = TaskMonitor(Task('identify_all'), rule)
    belief = scene(robot, a={5: 1.0}, b=None)
    verdict = monitor.check(belief, {'a': 2, 'b': 1})
    assert not verdict.done and verdict.candidates == ['b']
    belief = scene(robot, a={5: 1.0}, b={9: 1.0})
    verdict = monitor.check(belief, {})
    assert verdict.done and verdict.success
    # An object at its own action limit ends the task without success.
    belief = scene(robot, a={5: 1.0}, b=None)
    verdict = monitor.check(belief, {'b': rule.max_actions})
    assert verdict.done and not verdict.success and 'action limit' in verdict.reason
    results = {r.object_id: r for r in monitor.object_results(belief, {'a': 3, 'b': 30})}
    assert (results['a'].model, results['a'].actions, results['a'].identified) == (5, 3, True)
    assert (results['b'].actions, results['b'].identified) == (30, False)


def test_find_stops_when_one_object_is_the_model(robot, rule):
    monitor = TaskMonitor(Task('find', model=5), rule)
    verdict = monitor.check(scene(robot, a=None, b={5: 1.0}, c=None), {})
    assert verdict.done and verdict.success and verdict.found_object == 'b'


def test_find_stops_when_every_object_is_surely_not_the_model(robot, rule):
    monitor = TaskMonitor(Task('find', model=5), rule)
    verdict = monitor.check(scene(robot, a={9: 1.0}, b={12: 0.5, 13: 0.5}), {})
    assert verdict.done and verdict.success and verdict.found_object is None
    assert 'no object is model 5' in verdict.reason
    # Each object alone below the bound, the scene not: the model may still be there.
    each = 1.0 - 0.6 * rule.target_error
    verdict = monitor.check(scene(robot, a={5: 1 - each, 9: each}, b={5: 1 - each, 8: each}), {})
    assert not verdict.done and set(verdict.candidates) == {'a', 'b'}
    # b is not identified (12 or 13) but surely not 5: identify_all would go on.
    assert not TaskMonitor(Task('identify_all'), rule).check(
        scene(robot, a={9: 1.0}, b={12: 0.5, 13: 0.5}), {}).done


def test_absence_must_survive_one_false_tag(robot, rule):
    """P(any) just under the bound: enough for a plain claim, not for 'none is it',
    which one false tag could have caused."""
    p = 0.5 * rule.target_error
    belief = scene(robot, a={5: p, 9: 1 - p})
    assert not TaskMonitor(Task('find', model=5), rule).check(belief, {}).done
    plain = TaskMonitor(Task('find', model=5), rule, absence_fault_margin=False)
    assert plain.check(belief, {}).success
    tiny = rule.target_error / 1000  # ρ = 279 at the defaults: ρ·tiny < target_error
    verdict = TaskMonitor(Task('find', model=5), rule).check(
        scene(robot, a={5: tiny, 9: 1 - tiny}), {})
    assert verdict.done and verdict.success


def test_find_acts_on_the_most_likely_carrier(robot, rule):
    monitor = TaskMonitor(Task('find', model=5), rule)
    belief = scene(robot, a={5: 0.5, 6: 0.5}, b={5: 0.1, 7: 0.9}, c={8: 1.0})
    verdict = monitor.check(belief, {})
    assert not verdict.done and verdict.candidates == ['a']
    # a at its action limit: b is the one left to ask.
    verdict = monitor.check(belief, {'a': rule.max_actions})
    assert not verdict.done and verdict.candidates == ['b']
    # c holds none of model 5: acting on it cannot help.
    verdict = monitor.check(belief, {'a': rule.max_actions, 'b': rule.max_actions})
    assert verdict.done and not verdict.success and 'action limit' in verdict.reason


def test_find_holds_the_claim_to_the_rule_confidence(robot, rule):
    monitor = TaskMonitor(Task('find', model=5), rule)
    almost = 1.0 - 2 * rule.target_error
    verdict = monitor.check(scene(robot, a={5: almost, 6: 1.0 - almost}), {})
    assert not verdict.done
    sure = 1.0 - rule.target_error / 2
    verdict = monitor.check(scene(robot, a={5: sure, 6: 1.0 - sure}), {})
    assert verdict.done and verdict.found_object == 'a'


def test_identify_one_object_ignores_the_others(robot, rule):
    belief = scene(robot, a={5: 1.0}, b=None)
    assert TaskMonitor(Task('identify', object_id='a'), rule).check(belief, {}).success
    verdict = TaskMonitor(Task('identify', object_id='b'), rule).check(belief, {})
    assert not verdict.done and verdict.candidates == ['b']
    with pytest.raises(ValueError, match='no such object'):
        TaskMonitor(Task('identify', object_id='z'), rule).check(belief, {})


def test_tasks_parse_from_text(robot):
    assert Task.parse('') == Task('identify_all')
    assert Task.parse('identify_all') == Task('identify_all')
    assert Task.parse('find 7', robot) == Task('find', model=7)
    assert Task.parse(f'find {robot.names[4]}', robot) == Task('find', model=4)
    assert Task.parse('identify 3') == Task('identify', object_id=3)
    assert Task.parse('identify cube_a') == Task('identify', object_id='cube_a')
    for bad in ('find', 'find nothing_like_it', 'find 999', 'arrange 1 2', 'identify'):
        with pytest.raises(ValueError):
            Task.parse(bad, robot)
    with pytest.raises(ValueError, match='needs a model'):
        Task('find')


def _cube_rngs(scene_seed, j):
    return (np.random.default_rng(np.random.SeedSequence([scene_seed, j, 0])),
            np.random.default_rng(np.random.SeedSequence([scene_seed, j, 1])))


def test_scene_cubes_are_worked_on_as_alone(robot, rule):
    """identify_all spends on each cube exactly the actions its single-cube trial spends
    with the same noise (the beliefs are independent and each object's action is the
    single planner's); find of a cube in the scene stops no later."""
    planner = make_planner('abp', robot)
    models = [2, 11, 27]  # an eccentric twin, two plain cubes
    positions = place_cubes(3, np.random.default_rng(4))
    assert min(np.linalg.norm(positions[i] - positions[j])
               for i in range(3) for j in range(i)) >= 0.3
    cubes, single = [], []
    for j, model in enumerate(models):
        truth_rng, noise_rng = _cube_rngs(8, j)
        trial = run_trial(robot, planner, truth_rng, noise_rng, stopping=rule,
                          true_models=[model])
        single.append(trial.num_actions)
        cubes.append(SceneCube(j + 1, model, trial.initial_state, tuple(positions[j])))
    objects = ObjectActionPlanner(planner)

    def run(task):
        noise = {c.object_id: _cube_rngs(8, j)[1] for j, c in enumerate(cubes)}
        return run_scene(robot, robot, objects, TaskMonitor(task, rule), cubes, noise)

    everything = run(Task('identify_all'))
    assert everything.success
    per_cube = [sum(1 for o, _ in everything.actions if o == c.object_id) for c in cubes]
    assert per_cube == single
    assert [o['actions'] for o in everything.objects] == single
    assert all(o['model'] == o['true_model'] for o in everything.objects)
    assert everything.travel_time_s > 0 and len(everything.planning_ms) == sum(single)
    found = run(Task('find', model=11))
    assert found.found_object == 2 and found.num_actions <= everything.num_actions
    one = run(Task('identify', object_id=3))
    assert one.success and {o for o, _ in one.actions} <= {3}
    assert one.num_actions == single[2]
