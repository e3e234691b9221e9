import numpy as np
import pytest

from abp_belief import filter as belief_filter
from abp_belief import population

ACTIONS = population.cube.ACTIONS
BeliefFilter = belief_filter.BeliefFilter

# Open loop, so it must work from either yaw parity: the +-45 deg orbits change the
# parity every cycle and the manual actions sit between different orbits.
SCRIPT = ['FLIP', 'ORBIT_P90', 'LIFT', 'PUSH', 'ORBIT_P45', 'FLIP', 'ORBIT_P90', 'PUSH', 'LIFT',
          'ORBIT_M45', 'FLIP', 'ORBIT_180', 'PUSH', 'ORBIT_P45']


class Simulation:
    """The paper's model-sampled simulation: outcomes from the ATG, observations from p(z|x)."""

    def __init__(self, model_set, true_model, rng):
        self.ms, self.rng = model_set, rng
        self.node = true_model * 48 + int(rng.integers(48))

    def act(self, action):
        nxt, probs = self.ms.successors(ACTIONS.index(action), [self.node])
        self.node = int(self.rng.choice(nxt[0], p=probs[0]))

    def observe(self):
        return self.ms.observation.sample(self.ms.node_aspect[self.node], self.rng)


def _run(model_set, flt, sim, steps):
    flt.correct(sim.observe())
    for i in range(steps):
        action = SCRIPT[i % len(SCRIPT)]
        sim.act(action)
        flt.predict(action)
        flt.correct(sim.observe())


def test_initial_belief_and_entropy(robot):
    flt = BeliefFilter(robot)
    assert flt.belief.shape == (robot.num_nodes,)
    assert flt.belief.sum() == pytest.approx(1.0)
    assert flt.entropy() == pytest.approx(np.log2(30))
    prior = np.zeros(30)
    prior[[2, 5]] = [1.0, 3.0]
    flt = BeliefFilter(robot, prior=prior)
    assert flt.object_marginal()[[2, 5]] == pytest.approx([0.25, 0.75])
    assert flt.entropy() == pytest.approx(belief_filter.entropy_bits([0.25, 0.75]))
    with pytest.raises(ValueError, match='shape'):
        BeliefFilter(robot, prior=np.ones(29))
    with pytest.raises(ValueError):
        BeliefFilter(robot, prior=-np.ones(30))


def test_belief_converges_to_true_model_in_simulation(robot_paper):
    # Every model of the robot set, including all 14 eccentric-twin models. The script's
    # PUSHes tell side-heavy twins apart only in the paper's table (the corrected one's PUSH
    # slides), so the paper's is the one where 36 scripted actions settle every model.
    robot = robot_paper
    for true_model in range(robot.num_models):
        rng = np.random.default_rng(1000 + true_model)
        flt = BeliefFilter(robot)
        _run(robot, flt, Simulation(robot, true_model, rng), steps=36)
        marginal = flt.object_marginal()
        assert np.argmax(marginal) == true_model, robot.names[true_model]
        assert marginal[true_model] > 0.95, (robot.names[true_model], marginal[true_model])
        assert flt.entropy() < 0.5


def test_converges_on_random_120_set():
    ms = population.random_visual_subset(120, seed=5)
    for true_model in (0, 77):
        rng = np.random.default_rng(true_model)
        flt = BeliefFilter(ms)
        _run(ms, flt, Simulation(ms, true_model, rng), steps=24)
        assert flt.object_marginal()[true_model] > 0.95


def _foreign_aspect(model_set, model, shown_by=None):
    """An aspect row that `model` never shows (optionally one that model `shown_by` shows)."""
    own = set(model_set.node_aspect[model * 48:(model + 1) * 48].tolist())
    candidates = range(model_set.num_aspects) if shown_by is None else \
        model_set.node_aspect[shown_by * 48:(shown_by + 1) * 48].tolist()
    return next(r for r in candidates if r not in own)


def test_belief_recovers_after_a_wrong_first_observation(robot):
    true_model = 4
    rng = np.random.default_rng(11)
    flt = BeliefFilter(robot)
    sim = Simulation(robot, true_model, rng)
    flt.correct(robot.aspect_key(_foreign_aspect(robot, true_model)))
    assert flt.object_marginal()[true_model] < 0.01
    for i in range(36):
        action = SCRIPT[i % len(SCRIPT)]
        sim.act(action)
        flt.predict(action)
        flt.correct(sim.observe())
    assert flt.object_marginal()[true_model] > 0.95


def test_belief_dips_and_recovers_after_a_wrong_second_observation(robot):
    true_model = 20
    rng = np.random.default_rng(5)
    flt = BeliefFilter(robot)
    sim = Simulation(robot, true_model, rng)
    flt.correct(sim.observe())                      # belief still spread over candidates
    marginal = flt.object_marginal()
    before = marginal[true_model]
    others = robot.visual_id != robot.visual_id[true_model]
    runner_up = int(np.flatnonzero(others)[np.argmax(marginal[others])])
    flt.correct(robot.aspect_key(_foreign_aspect(robot, true_model, shown_by=runner_up)))
    dipped = flt.object_marginal()[true_model]
    assert np.isfinite(flt.belief).all() and flt.belief.sum() == pytest.approx(1.0)
    assert dipped < 0.5 * before
    for i in range(36):
        action = SCRIPT[i % len(SCRIPT)]
        sim.act(action)
        flt.predict(action)
        flt.correct(sim.observe())
    assert flt.object_marginal()[true_model] > 0.95


def test_stable_over_500_steps_on_full_set(full7):
    rng = np.random.default_rng(99)
    flt = BeliefFilter(full7)
    sim = Simulation(full7, 1234, rng)
    for step in range(500):
        action = ACTIONS[int(rng.integers(len(ACTIONS)))]
        sim.act(action)
        flt.predict(action)
        z = sim.observe() if step % 25 else (3, -1, -1, -1)    # occasional junk observation
        flt.correct(z)
        assert np.isfinite(flt.belief).all()
        assert flt.belief.min() >= 0.0
        assert abs(flt.belief.sum() - 1.0) < 1e-9
    assert np.isfinite(flt.entropy())
    assert np.argmax(flt.object_marginal()) == 1234


def test_stable_under_adversarial_observations(robot):
    flt = BeliefFilter(robot)
    rng = np.random.default_rng(0)
    for _ in range(500):
        flt.predict(int(rng.integers(len(ACTIONS))))
        flt.correct((3, int(rng.integers(-1, 7)), int(rng.integers(-1, 7)), 6))
        assert np.isfinite(flt.belief).all() and abs(flt.belief.sum() - 1) < 1e-9


def test_unnormalisable_update_raises_and_keeps_belief(robot, monkeypatch):
    flt = BeliefFilter(robot)
    before = flt.belief.copy()
    monkeypatch.setattr(robot.observation, 'likelihood', lambda z: np.zeros(robot.num_aspects))
    with pytest.raises(belief_filter.BeliefUpdateError, match='total likelihood'):
        flt.correct((2, 0, 1, -1))
    assert np.array_equal(flt.belief, before)


def test_predict_accepts_names_and_indices_and_reset(robot):
    a = BeliefFilter(robot)
    b = BeliefFilter(robot)
    a.correct((2, 0, 1, -1))
    b.correct((2, 0, 1, -1))
    a.predict('PUSH')
    b.predict(5)
    assert np.array_equal(a.belief, b.belief)
    with pytest.raises(ValueError):
        a.predict('WAVE')
    a.reset()
    assert a.entropy() == pytest.approx(np.log2(30))
