"""One ATG belief per object (issue 37): the factored belief is K single-object filters.

- K = 1 gives exactly (bit for bit) the single-object BeliefFilter's numbers;
- two objects' updates are independent: A's sequence equals A alone, and an action or an
  observation for A leaves B's belief untouched;
- the batched updates (one product for several objects) equal the one-object updates;
- a yaw shift is the nominal ORBIT rotation.
"""

import numpy as np
import pytest

from abp_belief import cube
from abp_belief.factored_belief import FactoredBelief, UnknownObjectError
from abp_belief.filter import BeliefFilter

SCRIPT = ['FLIP', 'ORBIT_P90', 'LIFT', 'PUSH', 'ORBIT_P45', 'FLIP', 'ORBIT_M45', 'PUSH']


def simulate(model_set, true_model, rng):
    """(actions, observations) of a true cube driven through SCRIPT (first observation
    before any action)."""
    node = true_model * 48 + int(rng.integers(48))
    observations = [model_set.observation.sample(model_set.node_aspect[node], rng)]
    for action in SCRIPT:
        nxt, probs = model_set.successors(cube.ACTIONS.index(action), [node])
        node = int(rng.choice(nxt[0], p=probs[0]))
        observations.append(model_set.observation.sample(model_set.node_aspect[node], rng))
    return observations


def test_one_object_is_the_single_object_filter_bit_for_bit(robot):
    observations = simulate(robot, 17, np.random.default_rng(3))
    single = BeliefFilter(robot)
    factored = FactoredBelief(robot, ['cube_a'])
    assert np.array_equal(single.belief, factored.belief('cube_a'))
    assert single.correct(observations[0]) == factored.correct('cube_a', observations[0])
    for action, z in zip(SCRIPT, observations[1:]):
        single.predict(action)
        single_total = single.correct(z)
        assert factored.step('cube_a', action, z) == single_total
        assert np.array_equal(single.belief, factored.belief('cube_a'))
    assert np.array_equal(single.object_marginal(), factored.object_marginal('cube_a'))
    assert single.most_likely_model() == factored.most_likely_model('cube_a')
    assert single.entropy() == factored.entropy('cube_a')


def test_objects_update_independently(robot):
    rng = np.random.default_rng(5)
    obs_a = simulate(robot, 3, rng)
    obs_b = simulate(robot, 25, rng)
    alone_a, alone_b = BeliefFilter(robot), BeliefFilter(robot)
    both = FactoredBelief(robot, [1, 2])
    alone_a.correct(obs_a[0])
    alone_b.correct(obs_b[0])
    both.correct_many({1: obs_a[0], 2: obs_b[0]})
    # Interleave: A and B each follow their own script, in alternation.
    for action, z_a, z_b in zip(SCRIPT, obs_a[1:], obs_b[1:]):
        before_b = both.belief(2).copy()
        version_b = both.version(2)
        both.step(1, action, z_a)
        assert np.array_equal(both.belief(2), before_b), "A's update touched B"
        assert both.version(2) == version_b
        alone_a.predict(action)
        alone_a.correct(z_a)
        both.step(2, action, z_b)
        alone_b.predict(action)
        alone_b.correct(z_b)
        assert np.array_equal(both.belief(1), alone_a.belief)
        assert np.array_equal(both.belief(2), alone_b.belief)
    # A's marginal is not B's: the two cubes were different models.
    assert both.most_likely_model(1)[0] != both.most_likely_model(2)[0]


def test_an_observation_of_a_leaves_b_untouched(robot):
    both = FactoredBelief(robot, ['a', 'b'])
    z = robot.observation.sample(int(robot.node_aspect[5 * 48 + 9]), np.random.default_rng(0))
    both.correct('b', z)
    before_b = both.belief('b').copy()
    both.correct('a', z)
    both.predict('a', 'LIFT')
    both.shift_yaw('a', 2)
    assert np.array_equal(both.belief('b'), before_b)


def test_batched_updates_equal_one_object_updates(robot):
    rng = np.random.default_rng(11)
    observations = {k: simulate(robot, model, rng)[:2] for k, model in ((1, 4), (2, 9), (3, 28))}
    batched = FactoredBelief(robot, [1, 2, 3])
    one_by_one = FactoredBelief(robot, [1, 2, 3])
    totals = batched.correct_many({k: zs[0] for k, zs in observations.items()})
    for k, zs in observations.items():
        assert one_by_one.correct(k, zs[0]) == pytest.approx(totals[k - 1], rel=1e-12)
    batched.predict_many([1, 3], 'PUSH')
    one_by_one.predict(1, 'PUSH')
    one_by_one.predict(3, 'PUSH')
    # A subset of the objects, in another order than the stack's.
    batched.correct_many({3: observations[3][1], 1: observations[1][1]})
    one_by_one.correct(3, observations[3][1])
    one_by_one.correct(1, observations[1][1])
    np.testing.assert_allclose(batched.beliefs, one_by_one.beliefs, rtol=1e-12, atol=1e-300)
    assert np.array_equal(batched.belief(2), one_by_one.belief(2))


def test_yaw_shift_is_the_nominal_orbit(robot):
    belief = FactoredBelief(robot, [7])
    model, state = 12, cube.state_of(3, 6)
    prior = np.zeros(robot.num_nodes)
    prior[model * 48 + state] = 1.0
    belief.beliefs[0] = prior
    belief.shift_yaw(7, 1)
    expected = cube.apply_rotation(cube.nominal_rotation('ORBIT_P45', 0, state), state)
    assert np.flatnonzero(belief.belief(7)) == [model * 48 + expected]
    belief.shift_yaw(7, -3)
    back = cube.apply_rotation(cube.nominal_rotation('ORBIT_M90', 0, expected), expected)
    back = cube.apply_rotation(cube.nominal_rotation('ORBIT_M45', 0, back), back)
    assert np.flatnonzero(belief.belief(7)) == [model * 48 + back]


def test_objects_come_and_go_with_clear_errors(robot):
    belief = FactoredBelief(robot, [1, 2])
    with pytest.raises(ValueError, match='already tracked'):
        belief.add_object(1)
    with pytest.raises(UnknownObjectError, match='not tracked'):
        belief.correct(9, (2, 0, 1, -1))
    weights = np.zeros(robot.num_models)
    weights[4] = 1.0
    belief.add_object(3, prior=weights)
    assert belief.most_likely_model(3) == (4, pytest.approx(1.0))
    belief.remove_object(1)
    assert belief.object_ids == (2, 3)
    assert belief.most_likely_model(3)[0] == 4
    with pytest.raises(ValueError, match='prior must have shape'):
        belief.add_object(4, prior=[1.0, 2.0])
    with pytest.raises(ValueError, match='read-only'):
        belief.belief(2)[0] = 1.0
