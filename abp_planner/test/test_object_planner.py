"""The planner over (object, action) (issue 37): it reuses the single-object planner's
scores per object, picks the object where the information gain (or gain per second,
with the trip to the cube) is highest, and recomputes only the objects that changed."""

import numpy as np
import pytest

from abp_belief import population
from abp_belief.factored_belief import FactoredBelief
from abp_planner.object_planner import ObjectActionPlanner, TravelModel
from abp_planner.planner import make_planner


@pytest.fixture(scope='module')
def robot():
    return population.robot_set(seed=0)


def one_hot(model_set, *models):
    weights = np.zeros(model_set.num_models)
    weights[list(models)] = 1.0
    return weights


def twin_pair(model_set):
    """Two eccentric models of one visual cube: only manual actions tell them apart."""
    eccentric = np.flatnonzero(model_set.mass > 0)
    same = eccentric[model_set.visual_id[eccentric] == model_set.visual_id[eccentric[0]]]
    return int(same[0]), int(same[1])


def scene_belief(model_set):
    """Object 1 known (no gain left), 2 one of two twins (some gain), 3 anything (most)."""
    belief = FactoredBelief(model_set)
    visual_only = int(np.flatnonzero(model_set.mass == 0)[0])
    belief.add_object(1, prior=one_hot(model_set, visual_only))
    belief.add_object(2, prior=one_hot(model_set, *twin_pair(model_set)))
    belief.add_object(3)
    return belief


def test_chooses_the_object_with_the_highest_information_gain(robot):
    belief = scene_belief(robot)
    planner = make_planner('abp', robot)
    gains = {o: planner.information_gain(belief.belief(o)) for o in belief.object_ids}
    assert gains[1].max() == pytest.approx(0.0, abs=1e-9)
    assert 0.0 < gains[2].max() < gains[3].max()
    decision = ObjectActionPlanner(planner, object_score='gain').choose(belief)
    assert decision.object_id == 3
    assert decision.action == planner.choose(belief.belief(3)).action
    np.testing.assert_array_equal(decision.information_gain[2], gains[3])
    # Among objects 1 and 2 only, 2 is where something is left to learn.
    decision = ObjectActionPlanner(planner, object_score='gain').choose(belief, [1, 2])
    assert decision.object_id == 2


def test_travel_cost_keeps_the_robot_at_a_cube_worth_acting_on(robot):
    belief = scene_belief(robot)
    planner = make_planner('abp', robot)
    positions = {1: (0.0, 0.0), 2: (0.0, 0.0), 3: (100.0, 0.0)}
    objects = ObjectActionPlanner(planner, TravelModel(speed_mps=0.1, approach_s=10.0))
    # At object 2 (0.14 bits in 45 s), object 3's 1.5 bits are not worth a 1010 s trip;
    # 0.5 m away (15 s) they are.
    assert objects.choose(belief, [2, 3], positions, robot_at=(0.0, 0.0)).object_id == 2
    near = {**positions, 3: (0.5, 0.0)}
    objects.clear_cache()
    decision = objects.choose(belief, [2, 3], near, robot_at=(0.0, 0.0))
    assert decision.object_id == 3
    np.testing.assert_allclose(decision.travel_s, [0.0, 15.0])


def test_one_object_decides_as_the_single_object_planner(robot):
    rng = np.random.default_rng(2)
    belief = FactoredBelief(robot, [42])
    belief.correct(42, robot.observation.sample(int(robot.node_aspect[7 * 48 + 3]), rng))
    for name in ('abp', 'cost'):
        planner = make_planner(name, robot)
        single = planner.choose(belief.belief(42))
        decision = ObjectActionPlanner(planner).choose(belief, positions={42: (1.0, 1.0)})
        assert (decision.object_id, decision.action) == (42, single.action)
        np.testing.assert_array_equal(decision.information_gain[0], single.information_gain)


def test_only_changed_objects_are_planned_again(robot):
    belief = scene_belief(robot)
    objects = ObjectActionPlanner(make_planner('abp', robot))
    assert objects.choose(belief).objects_planned == 3
    assert objects.choose(belief).objects_planned == 0
    z = robot.observation.sample(int(robot.node_aspect[0]), np.random.default_rng(0))
    belief.step(3, 'PUSH', z)
    again = objects.choose(belief)
    assert again.objects_planned == 1
    fresh = ObjectActionPlanner(make_planner('abp', robot)).choose(belief)
    np.testing.assert_array_equal(again.information_gain, fresh.information_gain)
    assert (again.object_id, again.action) == (fresh.object_id, fresh.action)


def test_feasibility_is_asked_per_object(robot):
    belief = scene_belief(robot)
    planner = make_planner('abp', robot)
    best = planner.choose(belief.belief(3)).action
    objects = ObjectActionPlanner(planner, object_score='gain')
    decision = objects.choose(belief, feasible=lambda o, a: not (o == 3 and a == best))
    assert best in decision.infeasible or decision.object_id != 3
    assert not (decision.object_id == 3 and decision.action == best)


def test_bad_settings_are_refused(robot):
    with pytest.raises(ValueError, match='object_score'):
        ObjectActionPlanner(make_planner('abp', robot), object_score='fastest')
    with pytest.raises(ValueError, match='no expected gains'):
        ObjectActionPlanner(make_planner('random', robot))
    with pytest.raises(ValueError, match='speed_mps'):
        TravelModel(speed_mps=0.0)
    with pytest.raises(ValueError, match='no object'):
        ObjectActionPlanner(make_planner('abp', robot)).choose(FactoredBelief(robot))
