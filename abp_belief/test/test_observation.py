from collections import Counter

import numpy as np
import pytest

from abp_belief import observation

ObservationModel, ObservationParams = observation.ObservationModel, observation.ObservationParams


def test_aspect_likelihood_table_matches_formula(full7):
    obs = full7.observation
    p = obs.params
    table = obs.aspect_likelihood
    assert table.shape == (full7.num_aspects, full7.num_aspects)
    assert table.min() > 0
    p_hit = 1 - p.p_miss - p.p_false
    p_wrong = p.p_false / (full7.n_tags - 1)
    for z_row in (0, 5, 60, 251):
        z = full7.aspect_key(z_row)
        k = z[0]
        for x_row in (0, 7, 100, 200, z_row):
            x = full7.aspect_key(x_row)
            if x[0] != k:
                expected = p.p_type / (full7.n_tags + 1) ** k
            else:
                expected = 1 - p.p_type
                for j in range(k):
                    expected *= p_hit if z[1 + j] == x[1 + j] else p_wrong
            assert table[z_row, x_row] == pytest.approx(expected, rel=1e-12)
        # The table row and the generic path agree.
        generic = ObservationModel(full7.aspects, full7.n_tags, p)
        generic._table = None
        assert np.allclose(generic.likelihood(z), table[z_row], rtol=1e-12)


def test_missed_tags_and_exact_match_is_most_likely(full7):
    obs = full7.observation
    z_row = 42
    z = full7.aspect_key(z_row)
    lik = obs.likelihood(z)
    assert np.argmax(lik) == z_row
    missed = (z[0], z[1], -1, z[3])
    lik_missed = obs.likelihood(missed)
    assert lik_missed.min() > 0
    assert lik_missed[z_row] == pytest.approx(lik[z_row] / (1 - 0.05 - 0.02) * 0.05)
    assert np.all(obs.likelihood((2, -1, -1, -1)) > 0)


def test_likelihood_is_a_distribution_over_observations():
    # Sum of p(z | x) over every possible z (both types, -1..n-1 per slot) is 1.
    n = 6
    aspects = np.array([[2, 0, 1, -1], [3, 0, 1, 2]])
    obs = ObservationModel(aspects, n)
    total = np.zeros(2)
    tags = range(-1, n)
    for a in tags:
        for b in tags:
            total += obs.likelihood((2, a, b, -1))
            for c in tags:
                total += obs.likelihood((3, a, b, c))
    assert np.allclose(total, 1.0)


def test_sample_follows_the_likelihood(robot):
    obs = robot.observation
    rng = np.random.default_rng(3)
    for row in (0, robot.num_aspects - 1):
        n = 20000
        counts = Counter(obs.sample(row, rng) for _ in range(n))
        exact = robot.aspect_key(row)
        expected = obs.likelihood(exact)[row]
        assert counts[exact] / n == pytest.approx(expected, abs=0.01)
        other_type = sum(c for z, c in counts.items() if z[0] != exact[0])
        assert other_type / n == pytest.approx(obs.params.p_type, abs=0.004)
        for z in counts:
            assert len(z) == 4
            if z[0] == 2:
                assert z[3] == -1


def test_observation_validation(robot):
    obs = robot.observation
    for bad in [(4, 0, 1, -1), (2, 0, 7, -1), (2, 0, 1, 2), (3, 0, 1), 'abc', (2,)]:
        with pytest.raises(ValueError):
            obs.likelihood(bad)
    assert obs.likelihood((2, 0, 1)).shape == (robot.num_aspects,)   # 3-tuple = type 2
    with pytest.raises(ValueError, match='p_miss'):
        ObservationParams(p_miss=0.0)
    with pytest.raises(ValueError):
        ObservationParams(p_miss=0.6, p_false=0.5)


def test_unknown_aspect_observation_still_has_positive_likelihood():
    aspects = np.array([[2, 0, 1, -1], [2, 1, 2, -1]])
    obs = ObservationModel(aspects, 7)
    lik = obs.likelihood((3, 4, 5, 6))
    assert lik.shape == (2,) and lik.min() > 0
