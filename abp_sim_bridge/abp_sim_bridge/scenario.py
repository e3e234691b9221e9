"""The simulated scene's set-up: which hidden cube, where, and the distractor tags
(plain Python, no rclpy).

The hidden cube is either given explicitly (six face tags + a mass index) or is one model
of an abp_belief model set (the same sets the belief node builds: robot / random / full /
visual, or a model file), chosen by index or at random with a seed.
"""

from dataclasses import dataclass

import numpy as np

from abp_belief.population import MODEL_SETS
from abp_description.frames import rot_z

from .flat_renderer import Distractor
from .rules_physics import R_UP, Cube

MAX_TAG_ID = 49  # ArUco DICT_4X4_50


@dataclass(frozen=True)
class HiddenModel:
    object_id: str          # the model's name (abp_belief naming, as in Belief.object_ids)
    model_index: int        # index in the model set, -1 when given explicitly
    face_tags: tuple        # tag id on each body face (+x -x +y -y +z -z)
    mass_index: int         # 0 uniform, 1 + f heavy towards body face f
    n_tags: int             # tags of the population (distractors use other ids)
    set_size: int = 0       # models in the set (0 when explicit)


def canonical_name(face_tags, mass_index):
    """abp_belief's model name of a cube given in any of its 24 orientations: the name of
    its canonical (lexicographically smallest) face tuple with the heavy face carried along."""
    from abp_belief import cube as bcube
    from abp_belief.modelset import model_name

    faces = np.asarray(face_tags, dtype=np.int64)
    variants = faces[bcube.ROTATION_FACE_SOURCE]                       # (24, 6)
    r = int(bcube.lexmin_index(variants[None])[0])
    mass = int(mass_index)
    if mass > 0:
        # New face g carries what was on face ROTATION_FACE_SOURCE[r, g]: so does the mass.
        mass = 1 + int(np.flatnonzero(bcube.ROTATION_FACE_SOURCE[r] == mass - 1)[0])
    return model_name(variants[r], mass)


def check_face_tags(face_tags):
    tags = [int(t) for t in face_tags]
    if len(tags) != 6:
        raise ValueError(f'face_tags must list 6 tag ids (one per body face +x -x +y -y +z -z), '
                         f'got {len(tags)}')
    if len(set(tags)) != 6:
        raise ValueError(f'face_tags must be 6 distinct tag ids, got {tags}')
    if min(tags) < 0 or max(tags) > MAX_TAG_ID:
        raise ValueError(f'face_tags must be ArUco DICT_4X4_50 ids 0..{MAX_TAG_ID}, got {tags}')
    return tuple(tags)


def load_model_set(model_set='robot', model_set_size=30, n_tags=7, seed=0, model_file=''):
    """The abp_belief ModelSet the belief node builds from the same parameters."""
    from abp_belief import model_file as model_io
    from abp_belief.population import model_set_from_config

    try:
        return model_set_from_config(model_set, model_set_size, n_tags, seed, model_file)
    except model_io.ModelFileError as err:
        raise ValueError(f'model_file: {err}') from err


def choose_hidden_model(face_tags=(), mass_index=0, model_set='robot', model_set_size=30,
                        n_tags=7, seed=0, model_file='', model_index=-1, cube_seed=0):
    """The hidden cube: explicit `face_tags` + `mass_index` when face_tags is non-empty,
    else model `model_index` of the model set (-1: drawn with `cube_seed`)."""
    mass_index = int(mass_index)
    if not 0 <= mass_index <= 6:
        raise ValueError(f'mass_index must be 0 (uniform) .. 6 (heavy face 5), got {mass_index}')
    if face_tags is not None and len(face_tags) > 0:
        tags = check_face_tags(face_tags)
        return HiddenModel(canonical_name(tags, mass_index), -1, tags, mass_index,
                           max(int(n_tags), max(tags) + 1))
    models = load_model_set(model_set, model_set_size, n_tags, seed, model_file)
    index = int(model_index)
    if index == -1:
        index = int(np.random.default_rng(cube_seed).integers(models.num_models))
    if not 0 <= index < models.num_models:
        raise ValueError(f'model_index must be -1 (random) or 0..{models.num_models - 1} '
                         f'for this model set of {models.num_models} models, got {index}')
    return HiddenModel(models.names[index], index,
                       tuple(int(t) for t in models.faces[index]), int(models.mass[index]),
                       int(models.n_tags), int(models.num_models))


def initial_cube(hidden, x=0.40, y=0.0, yaw=0.0, up_face=4, edge=0.10, mass_offset=0.025):
    """The hidden cube resting on the floor at (x, y): body face `up_face` up (MODEL.md's
    reference rotation R_UP), then turned by `yaw` (rad) about the vertical."""
    if not 0 <= int(up_face) <= 5:
        raise ValueError(f'cube_up_face must be a body face 0..5, got {up_face}')
    rotation = rot_z(float(yaw)) @ R_UP[int(up_face)]
    return Cube.from_mass_index([x, y, edge / 2], rotation, hidden.mass_index, edge,
                                mass_offset=mass_offset)


def make_distractors(count, seed, cube_xy, tag_size=0.08, first_id=7, avoid=(),
                     robot_xy=(0.0, 0.0)):
    """`count` flat tags lying on the floor around the cube (0.25..1.2 m from it, at least
    0.35 m from the robot's start), ids drawn from first_id..49 minus `avoid`."""
    count = int(count)
    if count <= 0:
        return []
    ids = [i for i in range(int(first_id), MAX_TAG_ID + 1) if i not in set(avoid)]
    if len(ids) < count:
        raise ValueError(f'only {len(ids)} tag ids are free for {count} distractors')
    rng = np.random.default_rng(seed)
    chosen = rng.choice(ids, size=count, replace=False)
    out = []
    cube_xy = np.asarray(cube_xy, dtype=float)
    robot_xy = np.asarray(robot_xy, dtype=float)
    placed = []
    for tag in chosen:
        for _ in range(1000):
            r, a = rng.uniform(0.25, 1.2), rng.uniform(-np.pi, np.pi)
            xy = cube_xy + r * np.array([np.cos(a), np.sin(a)])
            if np.linalg.norm(xy - robot_xy) < 0.35:
                continue
            if any(np.linalg.norm(xy - q) < 1.5 * tag_size * 1.25 for q in placed):
                continue
            break
        placed.append(xy)
        pose = np.eye(4)
        pose[:3, :3] = rot_z(rng.uniform(-np.pi, np.pi))  # tag z = world z: face up
        pose[:3, 3] = [xy[0], xy[1], 0.0005]
        out.append(Distractor(int(tag), pose, float(tag_size)))
    return out


def drawn_tags(face_tags, p_missed_tag, rng):
    """The face tags drawn in one camera frame: each is left blank (-1, a missed tag) with
    probability `p_missed_tag`, the fault injection for perception."""
    tags = np.asarray(face_tags)
    if p_missed_tag <= 0:
        return tuple(int(t) for t in tags)
    missed = rng.random(tags.size) < p_missed_tag
    return tuple(int(t) for t in np.where(missed, -1, tags))


__all__ = ['HiddenModel', 'MODEL_SETS', 'canonical_name', 'check_face_tags',
           'choose_hidden_model', 'drawn_tags', 'initial_cube', 'load_model_set',
           'make_distractors']
