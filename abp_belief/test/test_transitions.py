import numpy as np
import pytest

from abp_belief import cube, modelset, population
from abp_belief import filter as belief_filter
from abp_belief.atg_learning import neighbourhood

ACTIONS, FACE_NORMALS = cube.ACTIONS, cube.FACE_NORMALS
BeliefFilter = belief_filter.BeliefFilter
TransitionParams, build_outcome_tables = modelset.TransitionParams, modelset.build_outcome_tables

MANUAL = [ACTIONS.index(a) for a in ('PUSH', 'LIFT', 'FLIP')]
ORBITS = [ACTIONS.index(a) for a in cube.ORBIT_STEPS]


def _outcomes(ms, action, mass, state):
    a = ACTIONS.index(action)
    probs = ms.outcome_probs[a, mass, state]
    return {int(s): float(p) for s, p in zip(ms.outcome_states[a, mass, state], probs) if p > 0}


def _mass_dir(mass, state):
    return cube.STATE_ROTATIONS[state] @ FACE_NORMALS[mass - 1]


def _states_with_mass_at(mass, direction):
    return [s for s in range(0, 48, 2) if np.allclose(_mass_dir(mass, s), direction)]


def test_every_transition_row_sums_to_one(full7):
    assert np.allclose(full7.outcome_probs.sum(axis=3), 1.0, atol=1e-12)
    for name, matrix in full7.transitions.items():
        assert matrix.shape == (full7.num_nodes, full7.num_nodes)
        row_sums = np.asarray(matrix.sum(axis=1)).ravel()
        assert np.allclose(row_sums, 1.0, atol=1e-12), name
        assert matrix.data.min() > 0
        # Transitions never leave the model.
        rows = np.repeat(np.arange(full7.num_nodes), np.diff(matrix.indptr))
        assert (rows // 48 == matrix.indices // 48).all()


def test_successors_match_the_sparse_matrices(robot, rng):
    nodes = rng.integers(0, robot.num_nodes, size=50)
    for a, name in enumerate(ACTIONS):
        nxt, probs = robot.successors(a, nodes)
        dense = robot.transitions[name][nodes].toarray()
        rebuilt = np.zeros_like(dense)
        np.add.at(rebuilt, (np.arange(nodes.size)[:, None], nxt), probs)
        assert np.allclose(dense, rebuilt)


def test_orbit_changes_yaw_with_slip_and_ignores_mass():
    params = TransitionParams()
    states, probs = build_outcome_tables(params)
    for action, steps in cube.ORBIT_STEPS.items():
        a = ACTIONS.index(action)
        for m in range(1, 7):
            assert np.array_equal(states[a, m], states[a, 0])
            assert np.array_equal(probs[a, m], probs[a, 0])
        for s in range(48):
            up, yaw = divmod(s, 8)
            got = {int(x): p for x, p in zip(states[a, 0, s], probs[a, 0, s]) if p > 0}
            assert got == pytest.approx({8 * up + (yaw + steps) % 8: 1 - params.p_orbit_slip,
                                         8 * up + (yaw + steps + 1) % 8: params.p_orbit_slip / 2,
                                         8 * up + (yaw + steps - 1) % 8: params.p_orbit_slip / 2})


def test_paper_manual_actions_at_odd_yaw_do_nothing(full7_paper):
    for a in MANUAL:
        for m in range(7):
            for s in range(1, 48, 2):
                assert _outcomes(full7_paper, ACTIONS[a], m, s) == {s: 1.0}


def test_paper_push_pivots_mass_side_and_slides_otherwise(full7_paper):
    full7 = full7_paper
    p = full7.transition_params
    for m in range(1, 7):
        for s in _states_with_mass_at(m, [0, 1, 0]):          # heavy right side drags: yaw - 1
            up, yaw = divmod(s, 8)
            assert _outcomes(full7, 'PUSH', m, s) == pytest.approx(
                {8 * up + (yaw - 1) % 8: 1 - p.p_fail_push - p.p_push_neighbour,
                 s: p.p_fail_push, 8 * up + (yaw + 1) % 8: p.p_push_neighbour})
        for s in _states_with_mass_at(m, [0, -1, 0]):
            up, yaw = divmod(s, 8)
            assert _outcomes(full7, 'PUSH', m, s)[8 * up + (yaw + 1) % 8] == pytest.approx(
                1 - p.p_fail_push - p.p_push_neighbour)
        for d in ([1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]):
            for s in _states_with_mass_at(m, d):
                up, yaw = divmod(s, 8)
                assert _outcomes(full7, 'PUSH', m, s) == pytest.approx(
                    {s: 1 - p.p_push_neighbour, 8 * up + (yaw + 1) % 8: p.p_push_neighbour / 2,
                     8 * up + (yaw - 1) % 8: p.p_push_neighbour / 2})
    for s in range(0, 48, 2):                                  # uniform slides
        assert _outcomes(full7, 'PUSH', 0, s)[s] == pytest.approx(1 - p.p_push_neighbour)


def test_push_pivot_shows_a_three_feature_aspect():
    faces = [0, 1, 2, 3, 4, 5]
    s = 8 * 4                                                   # identity: +y face on the right
    mass = 1 + 2                                                # heavy +y face
    q = cube.nominal_rotation('PUSH', mass, s)
    after = cube.apply_rotation(q, s)
    assert after == s + 7                                       # yaw -1 (mod 8)
    assert cube.aspect_of(faces, after)[0] == 3
    # The light -y side advanced towards -x... so the front face +x now faces the robot's left.
    assert cube.aspect_of(faces, after) == (3, 4, 2, 0)


def test_paper_lift_physics(full7_paper):
    full7 = full7_paper
    fail = full7.transition_params.p_fail_lift
    for m in range(1, 7):
        f = m - 1
        for s in _states_with_mass_at(m, [0, 0, 1]):            # mass on top: 180 deg about y
            out = _outcomes(full7, 'LIFT', m, s)
            assert out[s] == pytest.approx(fail)
            (flipped,) = [x for x in out if x != s]
            assert out[flipped] == pytest.approx(1 - fail)
            assert cube.STATE_UP_FACE[flipped] == cube.OPPOSITE_FACE[f]
            assert np.allclose(cube.STATE_ROTATIONS[flipped],
                               cube.rot_y(180) @ cube.STATE_ROTATIONS[s])
            assert np.allclose(_mass_dir(m, flipped), [0, 0, -1])
        for d in ([1, 0, 0], [-1, 0, 0]):                       # mass front/back ends down
            for s in _states_with_mass_at(m, d):
                out = _outcomes(full7, 'LIFT', m, s)
                (moved,) = [x for x in out if x != s]
                assert np.allclose(_mass_dir(m, moved), [0, 0, -1])
                assert cube.STATE_YAW[moved] % 2 == 0
        for d in ([0, 0, -1], [0, 1, 0], [0, -1, 0]):
            for s in _states_with_mass_at(m, d):
                assert _outcomes(full7, 'LIFT', m, s) == {s: 1.0}
    for s in range(0, 48, 2):
        assert _outcomes(full7, 'LIFT', 0, s) == {s: 1.0}


def test_paper_flip_physics(full7_paper):
    full7 = full7_paper
    fail = full7.transition_params.p_fail_flip
    for s in range(0, 48, 2):
        out = _outcomes(full7, 'FLIP', 0, s)                    # uniform: front to top
        (moved,) = [x for x in out if x != s]
        assert out[moved] == pytest.approx(1 - fail)
        assert cube.STATE_TOP_FACE[moved] == cube.STATE_FRONT_FACE[s]
        assert cube.STATE_FRONT_FACE[moved] == cube.OPPOSITE_FACE[cube.STATE_TOP_FACE[s]]
    for m in range(1, 7):
        for s in range(0, 48, 2):                               # eccentric: mass to the base
            out = _outcomes(full7, 'FLIP', m, s)
            if np.allclose(_mass_dir(m, s), [0, 0, -1]):
                assert out == {s: 1.0}
                continue
            (moved,) = [x for x in out if x != s]
            assert np.allclose(_mass_dir(m, moved), [0, 0, -1])
            assert cube.STATE_YAW[moved] % 2 == 0
    # d = +y: -90 deg about x (specific case from MODEL.md).
    (s,) = [x for x in _states_with_mass_at(3, [0, 1, 0]) if x // 8 == 4]
    (moved,) = [x for x in _outcomes(full7, 'FLIP', 3, s) if x != s]
    assert np.allclose(cube.STATE_ROTATIONS[moved], cube.rot_x(-90) @ cube.STATE_ROTATIONS[s])


def _twin_group(robot):
    counts = np.bincount(robot.visual_id)
    v = int(np.flatnonzero(counts == 7)[0])
    members = np.flatnonzero(robot.visual_id == v)
    assert sorted(robot.mass[members].tolist()) == list(range(7))
    return members


def test_twins_are_indistinguishable_by_orbits(robot):
    members = _twin_group(robot)
    local_rng = np.random.default_rng(7)
    for true_twin in members[[0, 3, 6]]:
        flt = BeliefFilter(robot)
        node = true_twin * 48 + int(local_rng.integers(48))
        for _ in range(40):
            a = int(local_rng.choice(ORBITS))
            flt.predict(a)
            nxt, probs = robot.successors(a, [node])
            node = int(local_rng.choice(nxt[0], p=probs[0]))
            flt.correct(robot.observation.sample(robot.node_aspect[node], local_rng))
        twin_belief = flt.object_marginal()[members]
        assert twin_belief.sum() > 0.99                    # the visual cube is identified ...
        assert np.allclose(twin_belief, twin_belief[0], rtol=1e-9)   # ... but not the mass
        states = flt.state_marginal()[members]
        assert np.allclose(states, states[0], rtol=1e-9, atol=1e-300)


def _twin_marginal_after(model_set, action, start, mass_face_dir):
    """Object marginal over a twin family, from a known start state, after `action` and the
    aspect of its first nominal outcome for the twin whose heavy face points along
    `mass_face_dir` at `start`; and that twin's index."""
    members = _twin_group(model_set)
    twins = model_set.subset(members)
    (heavy,) = [m for m in range(1, 7) if np.allclose(_mass_dir(m, start), mass_face_dir)]
    flt = BeliefFilter(twins)
    flt.belief[:] = 0.0
    flt.belief[np.arange(7) * 48 + start] = 1.0 / 7             # same known start state
    flt.predict(action)
    (rotation, _), *_ = cube.nominal_outcomes(action, heavy, start,
                                              model_set.transition_params.rules)
    flt.correct(cube.aspect_of(twins.faces[0], cube.apply_rotation(rotation, start)))
    return flt.object_marginal(), int(np.flatnonzero(twins.mass == heavy)[0])


@pytest.mark.parametrize('action,mass_face_dir', [('PUSH', [0, 1, 0]), ('LIFT', [0, 0, 1]),
                                                   ('FLIP', [0, -1, 0])])
def test_paper_manual_actions_separate_twins(robot_paper, action, mass_face_dir):
    marginal, true_model = _twin_marginal_after(robot_paper, action, 8 * 4, mass_face_dir)
    assert marginal[true_model] > 0.8
    assert marginal[true_model] == marginal.max()


# -- the corrected table (MODEL.md: the cells the MuJoCo survey showed wrong) -------------


@pytest.fixture(scope='module')
def full7_rules():
    """The corrected rules alone, without their share of unmodelled outcomes."""
    return population.full_set(7, transition_params=TransitionParams(p_unmodelled=0.0))


def test_corrected_push_slides_whatever_the_mass(full7_rules):
    full7 = full7_rules
    p = full7.transition_params
    for m in range(7):
        for s in range(0, 48, 2):
            up, yaw = divmod(s, 8)
            assert _outcomes(full7, 'PUSH', m, s) == pytest.approx(
                {s: 1 - p.p_push_neighbour, 8 * up + (yaw + 1) % 8: p.p_push_neighbour / 2,
                 8 * up + (yaw - 1) % 8: p.p_push_neighbour / 2})
        for s in range(1, 48, 2):
            assert _outcomes(full7, 'PUSH', m, s) == {s: 1.0}


def test_corrected_lift_holds_a_top_heavy_cube_and_rolls_a_diagonal_one_at_odd_yaw(full7_rules):
    full7 = full7_rules
    fail = full7.transition_params.p_fail_lift
    for m in range(1, 7):
        for s in _states_with_mass_at(m, [0, 0, 1]):
            assert _outcomes(full7, 'LIFT', m, s) == {s: 1.0}
        for d in ([1, 0, 0], [-1, 0, 0]):                       # as the paper's table
            for s in _states_with_mass_at(m, d):
                out = _outcomes(full7, 'LIFT', m, s)
                (moved,) = [x for x in out if x != s]
                assert np.allclose(_mass_dir(m, moved), [0, 0, -1])
                assert out[moved] == pytest.approx(1 - fail)
        for s in range(1, 48, 2):
            d = _mass_dir(m, s)
            out = _outcomes(full7, 'LIFT', m, s)
            if abs(d[2]) > 0.5:                                 # heavy top or bottom: no roll
                assert out == {s: 1.0}
                continue
            # Heavy face down or towards the side it was on, half each; failure: no change.
            assert out[s] == pytest.approx(fail)
            moved = [x for x in out if x != s]
            assert len(moved) == 2
            ends = sorted(tuple(np.round(_mass_dir(m, x)).astype(int)) for x in moved)
            side = int(np.sign(d[1]))
            assert ends == sorted([(0, 0, -1), (0, side, 0)])
            assert all(out[x] == pytest.approx((1 - fail) / 2) for x in moved)
            assert all(cube.STATE_YAW[x] % 2 == 0 for x in moved)
    for s in range(48):
        assert _outcomes(full7, 'LIFT', 0, s) == {s: 1.0}


def test_corrected_flip_rolls_about_the_hand_axis(full7_rules):
    full7 = full7_rules
    fail = full7.transition_params.p_fail_flip
    front_to_top = cube.rot_y(-90)
    for m in range(7):
        for s in range(0, 48, 2):
            d = _mass_dir(m, s) if m else None
            out = _outcomes(full7, 'FLIP', m, s)
            rolled = cube.apply_rotation(front_to_top, s)
            if d is None or abs(d[1]) > 0.5 or np.allclose(d, [-1, 0, 0]):
                assert out == pytest.approx({rolled: 1 - fail, s: fail})
            elif np.allclose(d, [0, 0, 1]):                     # stays rolled or tips on
                over = cube.apply_rotation(cube.rot_y(180), s)
                assert out == pytest.approx({rolled: (1 - fail) / 2, over: (1 - fail) / 2,
                                             s: fail})
            elif np.allclose(d, [0, 0, -1]):
                assert out == {s: 1.0}
            else:                                               # heavy front: any of three
                back = cube.apply_rotation(cube.rot_y(90), s)
                assert out == pytest.approx({rolled: (1 - fail) / 3, back: (1 - fail) / 3,
                                             s: fail + (1 - fail) / 3})
        for s in range(1, 48, 2):
            assert _outcomes(full7, 'FLIP', m, s) == {s: 1.0}


@pytest.mark.parametrize('action,start,mass_face_dir', [
    ('LIFT', 32, [1, 0, 0]), ('FLIP', 32, [0, 0, 1]),
    ('LIFT', 33, [np.sqrt(0.5), np.sqrt(0.5), 0])])
def test_corrected_manual_actions_separate_twins(robot, action, start, mass_face_dir):
    marginal, true_model = _twin_marginal_after(robot, action, start, mass_face_dir)
    assert marginal[true_model] == marginal.max()
    assert marginal[true_model] > 0.4


def test_unknown_transition_rules_are_refused():
    with pytest.raises(ValueError, match='transition rules must be one of corrected, paper'):
        TransitionParams(rules='survey')
    with pytest.raises(ValueError, match='transition rules'):
        cube.nominal_outcomes('PUSH', 0, 0, rules='')


def test_paper_rules_are_the_paper_nominal_rotation():
    for a in range(len(ACTIONS)):
        for m in range(7):
            for s in range(48):
                ((q, w),) = cube.nominal_outcomes(a, m, s, rules='paper')
                assert w == 1.0 and np.array_equal(q, cube.nominal_rotation(a, m, s))


def test_corrected_table_spreads_its_unmodelled_share_over_the_neighbourhood(full7_rules):
    spread = TransitionParams()
    assert spread.p_unmodelled == pytest.approx(0.05)
    with_spread = population.full_set(7, transition_params=spread)
    near = neighbourhood('near')
    for action in ACTIONS:
        for m in range(7):
            for s in range(48):
                exact = _outcomes(full7_rules, action, m, s)
                got = _outcomes(with_spread, action, m, s)
                if action in cube.ORBIT_STEPS:               # the slip is modelled
                    assert got == pytest.approx(exact)
                    continue
                share = spread.p_unmodelled / near[s].sum()
                want = {x: (1 - spread.p_unmodelled) * p for x, p in exact.items()}
                for x in np.flatnonzero(near[s]):
                    want[int(x)] = want.get(int(x), 0.0) + share
                assert got == pytest.approx(want)
    # The paper's table has no such share.
    paper = build_outcome_tables(TransitionParams(rules='paper'))
    assert paper[0].shape[-1] == modelset.MAX_OUTCOMES
    assert build_outcome_tables(TransitionParams(rules='paper', p_unmodelled=0.3))[1] == \
        pytest.approx(paper[1])
