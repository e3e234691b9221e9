import itertools
from math import comb

import numpy as np
import pytest

from abp_belief import cube, population


def _brute_force_count(n):
    """Distinct cubes by explicit rotation matrices (independent of ROTATION_FACE_SOURCE)."""
    even = cube.STATE_ROTATIONS[cube.STATE_YAW % 2 == 0]                   # the 24 rotations
    # perm[r, f] = body face that face f is carried to by rotation r.
    moved = np.einsum('rij,fj->rfi', even, cube.FACE_NORMALS)
    perm = np.argmax(np.all(np.isclose(moved[:, :, None, :], cube.FACE_NORMALS[None, None]),
                            axis=3), axis=2)
    seen = set()
    for tags in itertools.permutations(range(n), 6):
        variants = []
        for r in range(24):
            rotated = [0] * 6
            for f in range(6):
                rotated[perm[r, f]] = tags[f]
            variants.append(tuple(rotated))
        seen.add(min(variants))
    return len(seen)


@pytest.mark.parametrize('n', [6, 7, 8])
def test_visual_cube_counts(n):
    cubes = population.visual_cubes(n)
    assert cubes.shape == (comb(n, 6) * 30, 6)
    assert cubes.dtype == np.int16
    assert len({tuple(r) for r in cubes}) == cubes.shape[0]
    assert np.array_equal(cube.canonical_faces(cubes), cubes)         # canonical representatives
    assert (np.sort(cubes, axis=1)[:, 1:] != np.sort(cubes, axis=1)[:, :-1]).all()
    assert cubes.min() >= 0 and cubes.max() < n


def test_known_counts_and_brute_force():
    assert population.visual_cubes(7).shape[0] == 210
    assert population.visual_cubes(8).shape[0] == 840
    assert _brute_force_count(7) == 210
    canon = {tuple(r) for r in population.visual_cubes(7)}
    assert canon == {tuple(r) for r in cube.canonical_faces(
        np.array(list(itertools.permutations(range(7), 6))))}


@pytest.mark.parametrize('bad', [5, 51, 0])
def test_tag_range_rejected(bad):
    with pytest.raises(ValueError, match='6..50'):
        population.visual_cubes(bad)
    with pytest.raises(ValueError, match='6..50'):
        population.random_visual_subset(3, n_tags=bad)


def test_full_set(full7):
    assert full7.num_models == 1470
    assert full7.num_visual_cubes == 210
    assert full7.num_nodes == 1470 * 48
    counts = np.bincount(full7.visual_id)
    assert (counts == 7).all()
    for v in (0, 100, 209):
        members = np.flatnonzero(full7.visual_id == v)
        assert sorted(full7.mass[members].tolist()) == list(range(7))
        assert (full7.faces[members] == full7.faces[members[0]]).all()
    assert len(set(full7.names)) == 1470
    # 42 ordered (top, front) pairs + 210 ordered (top, right, left) corner triples.
    assert full7.num_aspects == 42 + 210


def test_robot_set_twin_structure(robot):
    assert robot.num_models == 30
    assert robot.num_visual_cubes == 18
    counts = np.bincount(robot.visual_id)
    assert sorted(counts.tolist()) == [1] * 16 + [7] * 2
    for v in np.flatnonzero(counts == 7):
        members = np.flatnonzero(robot.visual_id == v)
        assert sorted(robot.mass[members].tolist()) == list(range(7))
        assert (robot.faces[members] == robot.faces[members[0]]).all()
    for v in np.flatnonzero(counts == 1):
        assert robot.mass[robot.visual_id == v].tolist() == [0]
    assert len(set(robot.names)) == 30
    assert population.robot_set(seed=0).names == robot.names           # seeded
    assert population.robot_set(seed=1).names != robot.names


@pytest.mark.parametrize('size', [30, 60, 120])
def test_random_visual_subsets_are_seeded_distinct_uniform_mass(size):
    a = population.random_visual_subset(size, seed=3)
    b = population.random_visual_subset(size, seed=3)
    c = population.random_visual_subset(size, seed=4)
    assert a.num_models == a.num_visual_cubes == size
    assert (a.mass == 0).all()
    assert np.array_equal(a.faces, b.faces)
    assert not np.array_equal(a.faces, c.faces)
    all_cubes = {tuple(r) for r in population.visual_cubes(7)}
    assert {tuple(r) for r in a.faces} <= all_cubes


def test_random_subset_size_validation():
    with pytest.raises(ValueError, match='1..210'):
        population.random_visual_subset(211)
    with pytest.raises(ValueError, match='1..210'):
        population.random_visual_subset(0)


def test_large_tag_sets_only_random():
    with pytest.raises(ValueError, match='random_visual_subset'):
        population.visual_cubes(50)
    ms = population.random_visual_subset(40, n_tags=50, seed=1)
    assert ms.num_visual_cubes == 40
    assert ms.faces.max() < 50
    assert np.array_equal(cube.canonical_faces(ms.faces), ms.faces)
    again = population.random_visual_subset(40, n_tags=50, seed=1)
    assert np.array_equal(ms.faces, again.faces)


def test_every_visual_cube_has_its_own_aspect_set():
    ms = population.visual_set(7)
    signatures = {frozenset(ms.node_aspect[m * 48:(m + 1) * 48].tolist())
                  for m in range(ms.num_models)}
    assert len(signatures) == 210
