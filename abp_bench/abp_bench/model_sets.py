"""The model sets of the model-sampled benchmarks (``planner_benchmark``, one or several
objects) and their object families. No rclpy."""

from __future__ import annotations

import numpy as np

MODEL_SET_CHOICES = ('30', '60', '120', '1470', 'robot')


def build_model_set(label: str, seed: int, tables: str = 'paper'):
    """The model set `label` with the hand-written table `tables` (the paper's by default:
    the protocol and Table II are the paper's)."""
    from abp_belief import population
    from abp_belief.modelset import TransitionParams

    params = TransitionParams(rules=tables)
    if label == '1470':
        return population.full_set(transition_params=params)
    if label == 'robot':
        return population.robot_set(seed=seed, transition_params=params)
    return population.random_visual_subset(int(label), seed=seed, transition_params=params)


def with_model_tables(model_set, path: str | None):
    """`model_set`'s models with the transition tables of the model file `path` (None:
    unchanged)."""
    if not path:
        return model_set
    from abp_belief import model_file
    from abp_belief.atg_learning import with_tables

    return with_tables(model_set, model_file.load(path))


OBJECT_FAMILIES = ('visual only', 'twin family, uniform', 'twin family, eccentric')


def object_families(model_set) -> list[str]:
    """Per model: 'visual only' (no other model has its faces), or, in a family of mass
    twins (same faces), 'twin family, uniform' or 'twin family, eccentric'. A uniform
    member has to rule out every twin by what the cube does, a visual-only one needs
    only its tags."""
    faces = np.asarray(model_set.faces)
    _, family, size = np.unique(faces, axis=0, return_inverse=True, return_counts=True)
    twins = size[family.reshape(-1)] > 1
    uniform = np.asarray(model_set.mass) == 0
    visual, twin_uniform, twin_eccentric = OBJECT_FAMILIES
    return np.where(~twins, visual, np.where(uniform, twin_uniform, twin_eccentric)).tolist()
