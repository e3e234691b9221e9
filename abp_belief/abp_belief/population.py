"""ARcube model populations (paper IV-A): visual cubes, mass variants, the paper's sets.

A visual cube is an assignment of 6 distinct tags to the body faces modulo the
24 cube rotations, represented by its lexicographically smallest face tuple.
All functions return cubes / models sorted lexicographically by (faces, mass).
"""

from __future__ import annotations

import functools
import itertools
from math import comb

import numpy as np

from . import cube
from .cube import NUM_MASS_VARIANTS, check_n_tags
from .modelset import ModelSet

CUBES_PER_TAG_SUBSET = 30            # 6! / 24
MAX_ENUMERATED_CUBES = 2_000_000     # n <= 21; beyond that only random subsets are drawn


@functools.cache
def _rank_patterns() -> np.ndarray:
    """The 30 canonical face tuples of the tag ranks 0..5, sorted.

    Canonical forms commute with any order-preserving relabelling of tags, so the
    cubes over a 6-subset S are exactly S[pattern] for these 30 patterns.
    """
    perms = np.array(list(itertools.permutations(range(6))), dtype=np.int64)   # (720, 6)
    canon = cube.canonical_faces(perms)
    patterns = np.unique(canon, axis=0)
    assert patterns.shape == (CUBES_PER_TAG_SUBSET, 6)
    patterns.flags.writeable = False
    return patterns


def num_visual_cubes(n_tags) -> int:
    return comb(check_n_tags(n_tags), 6) * CUBES_PER_TAG_SUBSET


def _sort_rows(rows: np.ndarray) -> np.ndarray:
    return rows[np.lexsort(rows.T[::-1])]


def visual_cubes(n_tags) -> np.ndarray:
    """All C(n,6)*30 visual cubes as canonical face tuples, (count, 6) int16, sorted."""
    n = check_n_tags(n_tags)
    count = num_visual_cubes(n)
    if count > MAX_ENUMERATED_CUBES:
        raise ValueError(f'{count} visual cubes for n_tags={n} is too many to enumerate '
                         f'(limit {MAX_ENUMERATED_CUBES}); use random_visual_subset')
    subsets = np.array(list(itertools.combinations(range(n), 6)), dtype=np.int16)
    cubes = subsets[:, _rank_patterns()].reshape(-1, 6)
    return _sort_rows(cubes)


def _random_visual_faces(size, n_tags, rng: np.random.Generator) -> np.ndarray:
    """`size` distinct random visual cubes (uniform over all of them), sorted."""
    n = check_n_tags(n_tags)
    count = num_visual_cubes(n)
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 1 <= size <= count:
        raise ValueError(f'size must be an integer in 1..{count} (visual cubes for '
                         f'n_tags={n}), got {size!r}')
    size = int(size)
    if count <= MAX_ENUMERATED_CUBES:
        chosen = np.sort(rng.choice(count, size=size, replace=False))
        return visual_cubes(n)[chosen]
    # Too many to enumerate: uniform 6-subset x uniform pattern is uniform over cubes;
    # reject duplicates (rare: size << count).
    patterns = _rank_patterns()
    found: dict[bytes, np.ndarray] = {}
    while len(found) < size:
        batch = 2 * (size - len(found)) + 8
        subsets = np.sort(np.argsort(rng.random((batch, n)), axis=1)[:, :6], axis=1)
        faces = subsets[np.arange(batch)[:, None], patterns[rng.integers(0, 30, size=batch)]]
        for row in faces.astype(np.int16):
            found.setdefault(row.tobytes(), row)
            if len(found) == size:
                break
    return _sort_rows(np.array(list(found.values()), dtype=np.int16))


def models_from_visual(faces, mass_variants, n_tags, **model_kwargs) -> ModelSet:
    """Every visual cube in `faces` x every mass index in `mass_variants`."""
    faces = np.asarray(faces)
    masses = np.asarray(mass_variants, dtype=np.int64)
    return ModelSet(np.repeat(faces, masses.size, axis=0), np.tile(masses, faces.shape[0]),
                    n_tags, **model_kwargs)


def full_set(n_tags=7, **model_kwargs) -> ModelSet:
    """Every visual cube x 7 mass variants (n=7: 1470 models)."""
    return models_from_visual(visual_cubes(n_tags), range(NUM_MASS_VARIANTS), n_tags,
                              **model_kwargs)


def visual_set(n_tags=7, **model_kwargs) -> ModelSet:
    """Every visual cube, uniform mass only (n=7: the paper's 210)."""
    return models_from_visual(visual_cubes(n_tags), [0], n_tags, **model_kwargs)


def random_visual_subset(size, n_tags=7, seed=0, **model_kwargs) -> ModelSet:
    """`size` distinct visual cubes drawn with `seed`, uniform mass only (paper Table II)."""
    faces = _random_visual_faces(size, n_tags, np.random.default_rng(seed))
    return models_from_visual(faces, [0], n_tags, **model_kwargs)


ROBOT_VISUAL_CUBES = 18
ROBOT_TWIN_CUBES = 2


def robot_set(seed=0, n_tags=7, **model_kwargs) -> ModelSet:
    """The paper's uBot-6 set: 18 visual cubes (uniform), two of them also with all 6
    eccentric twins -> 30 models, grouped by visual cube."""
    rng = np.random.default_rng(seed)
    faces = _random_visual_faces(ROBOT_VISUAL_CUBES, n_tags, rng)
    twins = set(rng.choice(ROBOT_VISUAL_CUBES, size=ROBOT_TWIN_CUBES, replace=False).tolist())
    rows, masses = [], []
    for v in range(ROBOT_VISUAL_CUBES):
        for m in (range(NUM_MASS_VARIANTS) if v in twins else [0]):
            rows.append(v)
            masses.append(m)
    return ModelSet(faces[rows], masses, n_tags, **model_kwargs)


MODEL_SETS = ('robot', 'random', 'full', 'visual')


def model_set_from_config(model_set='robot', model_set_size=30, n_tags=7, seed=0,
                          model_file='', **model_kwargs) -> ModelSet:
    """The model set every node builds from the same parameters (belief, planner,
    aspect matcher, sim bridge): a file when `model_file` is set, else a generated set.

    Raises ValueError for an unknown set, or model_file.ModelFileError for a bad file.
    """
    if model_file:
        from .model_file import load  # model_file imports modelset only: no cycle
        return load(model_file)
    if model_set == 'robot':
        return robot_set(seed=seed, n_tags=n_tags, **model_kwargs)
    if model_set == 'random':
        return random_visual_subset(model_set_size, n_tags=n_tags, seed=seed, **model_kwargs)
    if model_set == 'full':
        return full_set(n_tags=n_tags, **model_kwargs)
    if model_set == 'visual':
        return visual_set(n_tags=n_tags, **model_kwargs)
    raise ValueError(f"parameter model_set must be one of {', '.join(MODEL_SETS)}, "
                     f"got {model_set!r}")
