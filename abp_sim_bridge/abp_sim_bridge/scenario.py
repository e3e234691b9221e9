"""The simulated scene's set-up: which hidden cubes, where, and the distractor tags
(plain Python, no rclpy).

A scene holds one cube (as always) or K > 1 (`scene_models`, `place_cubes`): K models of
the set without repeats (optionally with a pair of eccentric mass twins, the same faces
and different mass), at seeded positions at least `spacing` apart in a sector in front of
the robot's start pose (the camera sees it when the head aims at the cubes' centroid).

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


def eccentric_twins(models):
    """Pairs (i, j), i < j, of models of the set with the same faces and different mass."""
    faces = np.asarray(models.faces)
    pairs = []
    for i in range(len(faces)):
        same = np.flatnonzero(np.all(faces[i + 1:] == faces[i], axis=1)) + i + 1
        pairs += [(i, int(j)) for j in same if int(models.mass[j]) != int(models.mass[i])]
    return pairs


def scene_models(first, count, models, seed=0, twins=False):
    """Model indices of a K-cube scene: `first` (the hidden cube's index, -1 = draw it
    too), then models of the set drawn with `seed`, without repeats. `twins`: the first
    two are eccentric mass twins (`first` must have a twin then)."""
    count = int(count)
    if count > models.num_models:
        raise ValueError(f'num_cubes ({count}) exceeds the {models.num_models} models of the '
                         'set (models are drawn without repeats)')
    rng = np.random.default_rng([int(seed), 37])
    chosen = [] if first < 0 else [int(first)]
    if twins:
        if count < 2:
            raise ValueError('twin_cubes needs num_cubes >= 2')
        pairs = eccentric_twins(models)
        if first >= 0:
            pairs = [p for p in pairs if first in p]
        if not pairs:
            raise ValueError('twin_cubes: the model set has no eccentric mass twins'
                             + (f' of model {first}' if first >= 0 else ''))
        pair = pairs[int(rng.integers(len(pairs)))]
        chosen = [first, pair[1] if pair[0] == first else pair[0]] if first >= 0 \
            else list(pair)
    elif not chosen:
        chosen = [int(rng.integers(models.num_models))]
    rest = [i for i in range(models.num_models) if i not in chosen]
    chosen += [int(i) for i in rng.choice(rest, size=count - len(chosen), replace=False)]
    return chosen[:count]


def hidden_model(models, index):
    """The HiddenModel of model `index` of the set `models`."""
    return HiddenModel(models.names[index], int(index),
                       tuple(int(t) for t in models.faces[index]), int(models.mass[index]),
                       int(models.n_tags), int(models.num_models))


# Placement attempts before a scene is declared impossible (seconds at worst, never a hang).
PLACEMENT_ATTEMPTS = 20000


def place_cubes(count, seed, spacing=0.3, radius=(0.45, 0.85), half_angle_deg=20.0):
    """(count, 2) cube centres (x, y) in odom, seeded: in the sector of radii `radius` (m
    from the robot's start at the origin) and bearings within +-`half_angle_deg` of its
    heading (+x), every two at least `spacing` apart. ValueError when the sector cannot
    hold them (an area bound first, then a bounded number of random attempts)."""
    count, spacing = int(count), float(spacing)
    r_min, r_max = (float(r) for r in radius)
    half = np.radians(float(half_angle_deg))
    if not 0 < r_min < r_max or not 0 < half <= np.pi:
        raise ValueError(f'scene_radius must be [r_min, r_max] with 0 < r_min < r_max, and '
                         f'scene_half_angle_deg in (0, 180], got {list(radius)}, '
                         f'{half_angle_deg}')
    area = half * (r_max ** 2 - r_min ** 2)
    # Disks of radius spacing/2 around the centres cannot overlap; the sector grown by
    # spacing/2 must hold their area (a loose bound: it only catches hopeless scenes fast).
    grown = (half + spacing / (2 * r_min)) * ((r_max + spacing / 2) ** 2
                                              - max(r_min - spacing / 2, 0) ** 2)
    if count * np.pi * (spacing / 2) ** 2 > grown:
        raise ValueError(_impossible(count, spacing, radius, half_angle_deg, area))
    rng = np.random.default_rng([int(seed), 38])
    placed = []
    for _ in range(PLACEMENT_ATTEMPTS):
        if len(placed) == count:
            break
        # Uniform in the sector's area.
        r = np.sqrt(rng.uniform(r_min ** 2, r_max ** 2))
        a = rng.uniform(-half, half)
        xy = np.array([r * np.cos(a), r * np.sin(a)])
        if all(np.linalg.norm(xy - q) >= spacing for q in placed):
            placed.append(xy)
        elif rng.random() < 0.01:
            placed = []   # a crowded start: begin again rather than fill gaps forever
    if len(placed) < count:
        raise ValueError(_impossible(count, spacing, radius, half_angle_deg, area))
    return np.array(placed)


def _impossible(count, spacing, radius, half_angle_deg, area):
    return (f'num_cubes: cannot place {count} cubes at least {spacing} m apart (cube_spacing) '
            f'in the sector of radius {radius[0]}..{radius[1]} m and +-{half_angle_deg} deg '
            f'(scene_radius, scene_half_angle_deg; {area:.2f} m^2): fewer cubes, a smaller '
            'spacing or a larger sector')


def facing_yaw(xy):
    """Yaw of a cube at `xy` that shows the robot at the origin what a cube at (x, 0)
    with yaw 0 shows (its relative yaw 0)."""
    return float(np.arctan2(xy[1], xy[0]))


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


__all__ = ['HiddenModel', 'MODEL_SETS', 'PLACEMENT_ATTEMPTS', 'canonical_name',
           'check_face_tags', 'choose_hidden_model', 'drawn_tags', 'eccentric_twins',
           'facing_yaw', 'hidden_model', 'initial_cube', 'load_model_set', 'make_distractors',
           'place_cubes', 'scene_models']
