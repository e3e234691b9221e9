"""Aspect matching (Alg. 2) on ideal features: stray pairs, unknown ids, empty input, every
robot-set aspect, the lookup table, bad settings. On rendered scenes: abp_bench/test."""

import numpy as np
import pytest

from abp_belief.population import robot_set
from abp_perception.matcher import AspectMatcher, Feature


def test_stray_pair_of_in_range_tags_gets_no_consistent_votes(full_matcher):
    # Two in-range tags 0.3 m apart on the floor: wrong distance, wrong geometry.
    cov = np.eye(3) * 1e-6
    feats = [Feature(1, np.array([1.0, 0.2, 0.0]), cov, np.array([0.0, 0.0, 1.0])),
             Feature(2, np.array([1.0, -0.1, 0.0]), cov, np.array([0.0, 0.0, 1.0]))]
    assert full_matcher.match(feats).hypotheses == []


def test_zero_one_and_unknown_features(full_matcher):
    empty = full_matcher.match([])
    assert empty.hypotheses == [] and empty.best is None and empty.ignored_features == 0
    cov = np.eye(3) * 1e-6
    one = full_matcher.match([Feature(3, np.array([1.0, 0.0, 0.1]), cov,
                                      np.array([0.0, 0.0, 1.0]))])
    assert one.hypotheses == []
    unknown = [Feature(40, np.array([1.0, 0.0, 0.1]), cov, np.array([0.0, 0.0, 1.0])),
               Feature(-1, np.array([1.0, 0.05, 0.05]), cov, np.array([1.0, 0.0, 0.0])),
               Feature(2, np.array([np.nan, 0.0, 0.0]), cov, np.array([1.0, 0.0, 0.0]))]
    res = full_matcher.match(unknown)
    assert res.hypotheses == [] and res.ignored_features == 3 and res.ignored_ids == [-1, 40]


def test_ideal_features_of_every_robot_set_aspect():
    models = robot_set(seed=0)
    matcher = AspectMatcher(models)
    h = models.cube_size
    cov = np.eye(3) * 1e-6
    centre = np.array([1.2, -0.3, h / 2])
    # V frame at that centre: x towards the base origin.
    x = -centre.copy()
    x[2] = 0
    x /= np.linalg.norm(x)
    rv = np.column_stack([x, np.cross([0, 0, 1.0], x), [0, 0, 1.0]])
    for row in range(len(models.aspects)):
        tags = models.aspect_feature_tags(row)
        pos = models.aspect_feature_positions(row)
        feats = [Feature(int(t), centre + rv @ p, cov, rv @ (p / np.linalg.norm(p)))
                 for t, p in zip(tags, pos)]
        best = matcher.match(feats).best
        assert best.key == models.aspect_key(row)
        np.testing.assert_allclose(best.position, centre, atol=1e-6)
        np.testing.assert_allclose(best.rotation, rv, atol=1e-6)


def test_lookup_table_lists_every_slot_pair_of_every_aspect(full_models, full_matcher):
    m = full_matcher
    n = full_models.n_tags
    counts = np.zeros(n * n, dtype=int)
    for row in full_models.aspects:
        tags = row[1:1 + row[0]]
        for a in range(len(tags)):
            for b in range(len(tags)):
                if a != b:
                    counts[tags[a] * n + tags[b]] += 1
    np.testing.assert_array_equal((m._table >= 0).sum(axis=1), counts)
    entries = m._table[m._table >= 0]
    rows, sa, sb = m._entry_row[entries], m._entry_sa[entries], m._entry_sb[entries]
    keys = np.repeat(np.arange(n * n), (m._table >= 0).sum(axis=1))
    np.testing.assert_array_equal(m.aspect_tags[rows, sa] * n + m.aspect_tags[rows, sb], keys)


def test_bad_matcher_settings_are_refused(full_models):
    for kwargs in ({'voxel_size': 0.0}, {'orientation_sigma_deg': 0.0},
                   {'max_hypotheses': 0}, {'distance_samples': -1}):
        with pytest.raises(ValueError):
            AspectMatcher(full_models, **kwargs)
