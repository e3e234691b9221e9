"""The sim_bridge node's parameters, their checks, and what they build (plain Python, no
rclpy): one `ParamSpec` table (`PARAMETERS`) the node declares with
`abp_common.parameters.declare_all`, `build(values)` which turns a {name: value} mapping
into the simulation's pieces or raises ValueError naming the parameter that is wrong, and
`refusal(values, changes)`, the rule for changes at run time.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from abp_belief.model_set_config import POPULATION_SPECS
from abp_common.base_command import SPECS as BASE_COMMAND_SPECS
from abp_common.param_spec import (
    BOOL,
    DOUBLE,
    DOUBLE_ARRAY,
    INT,
    INT_ARRAY,
    STRING,
    ParamSpec,
    check_all,
    probability,
)
from abp_common.param_spec import defaults as spec_defaults
from abp_description.robot_profile import PROFILE_SPEC

from .flat_renderer import DEFAULT_DICTIONARY, ImageEffects, check_tag_ids
from .rules_contact import ContactParams
from .rules_physics import Cube, Failures
from .rules_world import SimSettings
from .scenario import (
    HiddenModel,
    choose_hidden_model,
    facing_yaw,
    hidden_model,
    initial_cube,
    load_model_set,
    make_distractors,
    place_cubes,
    scene_models,
)

SEED_RANGE = (0, 2**31 - 1)
# The model set the hidden cube is drawn from: the belief node's own parameters (so one
# `/**:` block of abp.yaml sets both). Here they are not read-only: like every world
# parameter, a new model set takes effect at the next ~/reset_world.
MODEL_SET_SPECS = tuple(replace(p, read_only=False) for p in POPULATION_SPECS)

# The scripted operator's world draws the cube too (read-only there).
DICTIONARY_SPEC = ParamSpec(
    'dictionary', STRING, DEFAULT_DICTIONARY, 'ArUco dictionary (OpenCV name, e.g. '
    'DICT_APRILTAG_36h11) of the tags drawn on the cube and the distractors; the '
    "artag_detector's parameter of the same name must match (start_graph.sh --dictionary "
    'sets both).')

WORLDS = ('rules', 'mujoco')
MUJOCO_ONLY = ' (world mujoco only)'

PARAMETERS = (
    PROFILE_SPEC,   # first: the node reads it before the others (their robot defaults)
    ParamSpec('world', STRING, 'mujoco', 'Which world: mujoco = MuJoCo physics and rendering '
              '(outcomes from mass, friction and contacts); rules = the contact rules of '
              'docs/SIM_BRIDGE.md and the flat renderer (fast, for tests).', choices=WORLDS,
              read_only=True),
    # -- time ---------------------------------------------------------------------------
    ParamSpec('rate', DOUBLE, 50.0, 'Simulation tick rate, Hz of simulation time: base and '
              'joint integration, contacts, /joint_states, /odom and /clock.', (1.0, 1000.0)),
    ParamSpec('speedup', DOUBLE, 1.0, 'Simulation time per wall-clock time: 1 = real time, '
              '10 = ten times faster (0 < speedup <= 100). Takes effect at once. If the '
              'machine cannot keep up, simulation time runs slower (never inconsistently).',
              (0.0, 100.0)),
    ParamSpec('publish_clock', BOOL, True, 'Publish /clock (other nodes then run with '
              'use_sim_time:=true) and stamp everything with simulation time starting at 0. '
              'false: stamps are wall-clock time at start + simulation time (no /clock).',
              read_only=True),
    ParamSpec('camera_rate', DOUBLE, 10.0, 'Camera frame rate, Hz of simulation time '
              '(0 = no camera); at most `rate`.', (0.0, 1000.0)),
    ParamSpec('ground_truth_rate', DOUBLE, 5.0, 'Rate of /abp/sim/ground_truth, Hz of '
              'simulation time (it is also published at once after every contact event and '
              'reset; 0 = only then).', (0.0, 1000.0)),
    ParamSpec('state_rate', DOUBLE, 25.0, 'Rate of /joint_states and /odom, Hz of simulation '
              'time (at most `rate`; every tick at `rate`): the skills control at 20 Hz. A tick '
              'that takes a camera frame always publishes them, so an image has the joint '
              'state at its stamp.', (1.0, 1000.0)),
    ParamSpec('clock_max_wall_rate', DOUBLE, 50.0, 'At most this many /clock messages per '
              'second of wall time (0 = one every tick): every node taking sim time wakes for '
              'each, and at a speed-up one a tick is too many. Nodes then see simulation time '
              'in steps of at most speedup / clock_max_wall_rate s.', (0.0, 10000.0)),
    ParamSpec('camera_max_wall_rate', DOUBLE, 20.0, 'At most this many camera frames per '
              'second of wall time (0 = no limit): at a speed-up the frames the detector '
              'could not take are not rendered. A frame is also skipped (never queued) while '
              'the previous one is still being rendered: the simulation never waits for the '
              'renderer.', (0.0, 1000.0)),
    ParamSpec('command_wait', DOUBLE, 0.15, 'While the base drives, a /cmd_vel later than '
              'this (s of simulation time) makes the simulation wait for it, up to 0.5 s of '
              'wall time: a machine too loaded to run the skills at the speed-up slows '
              'simulation time instead of letting the base drive on (0 = never wait; then '
              'only cmd_vel_timeout applies, as on a robot).', (0.0, 10.0)),
    ParamSpec('cmd_vel_timeout', DOUBLE, 0.5, 'The base stops when no /cmd_vel arrived for '
              'this long (s of simulation time).', (0.001, 60.0)),
    *BASE_COMMAND_SPECS,
    ParamSpec('stopped_velocity_tolerance', DOUBLE, 0.01, 'The simulated trajectory '
              "controllers' default goal velocity tolerance, rad/s (as Jazzy's "
              'joint_trajectory_controller constraints.stopped_velocity_tolerance).',
              (0.0, 10.0), read_only=True),
    # -- the hidden cube ------------------------------------------------------------------
    ParamSpec('face_tags', INT_ARRAY, None, 'Explicit hidden cube: tag id on each body face '
              '(+x -x +y -y +z -z), 6 distinct ids 0..49; empty = take it from the model set.'),
    ParamSpec('mass_index', INT, 0, 'With face_tags: 0 = uniform mass, 1 + f = heavy towards '
              'body face f.', (0, 6)),
    *MODEL_SET_SPECS,
    ParamSpec('model_index', INT, -1, 'Index of the hidden model in the model set; -1 = drawn '
              'with cube_seed.', (-1, 10**7)),
    ParamSpec('cube_seed', INT, 0, 'Seed of the random choice of the hidden model.',
              SEED_RANGE),
    ParamSpec('cube_size', DOUBLE, 0.10, 'Cube edge, m.', (0.02, 0.5)),
    ParamSpec('tag_size', DOUBLE, 0.08, 'Tag (black square) edge, m; smaller than cube_size.',
              (0.005, 0.5)),
    DICTIONARY_SPEC,
    ParamSpec('mass_offset', DOUBLE, 0.025, 'Centre of mass offset towards the heavy face, m '
              '(less than half the edge).', (0.0, 0.25)),
    ParamSpec('cube_x', DOUBLE, 0.40, 'Initial cube centre x in odom, m (the robot starts at '
              'the origin facing +x).', (-100.0, 100.0)),
    ParamSpec('cube_y', DOUBLE, 0.0, 'Initial cube centre y in odom, m.', (-100.0, 100.0)),
    ParamSpec('cube_yaw', DOUBLE, 0.0, 'Initial cube yaw about the vertical, rad (applied '
              'after cube_up_face).', (-10.0, 10.0)),
    ParamSpec('cube_up_face', INT, 4, 'Initial body face up (0:+x 1:-x 2:+y 3:-y 4:+z 5:-z), '
              "with MODEL.md's reference rotation R_UP.", (0, 5)),
    # -- several cubes (docs/MULTI_OBJECT.md) ----------------------------------------------
    ParamSpec('num_cubes', INT, 1, 'Cubes in the scene. 1: the hidden cube alone at cube_x, '
              'cube_y (as always). K > 1: the hidden cube and K - 1 further models of the set '
              '(no repeats, drawn with cube_seed), placed with cube_seed in the sector '
              'scene_radius x +-scene_half_angle_deg in front of the start pose, at least '
              'cube_spacing apart (cube_x, cube_y ignored; each cube turned to face the robot, '
              'then by cube_yaw for the first and a seeded multiple of 45 deg for the others). '
              'Manual actions act on the cube the hands touch.', (1, 20)),
    ParamSpec('twin_cubes', BOOL, False, 'With num_cubes >= 2: the first two cubes are '
              'eccentric mass twins (same faces, different mass); model_index -1 draws the '
              'pair.'),
    ParamSpec('cube_spacing', DOUBLE, 0.3, 'With num_cubes > 1: least distance between two '
              'cube centres, m (the aspect matcher tells cubes apart when their tags are '
              'more than an edge apart: keep it >= 2 edges, and twice its track_gate).',
              (0.12, 5.0)),
    ParamSpec('scene_radius', DOUBLE_ARRAY, [0.45, 0.85], 'With num_cubes > 1: [r_min, r_max], '
              'the distances from the start pose the cubes are placed at, m (the camera sees '
              '0.3..1.4 m when aimed at 0.65 m).'),
    ParamSpec('scene_half_angle_deg', DOUBLE, 20.0, 'With num_cubes > 1: the cubes are placed '
              'within this bearing of the start heading, deg (the camera sees +-30 deg).',
              (1.0, 180.0)),
    # -- camera ---------------------------------------------------------------------------
    ParamSpec('camera_encoding', STRING, 'mono8', 'Image encoding.',
              choices=('mono8', 'bgr8')),
    ParamSpec('publish_compressed', BOOL, False, 'Also publish each frame JPEG-encoded on '
              "camera/image_raw/compressed (sensor_msgs/CompressedImage, image_transport's "
              'compressed transport; encoded only while someone subscribes): for a tag '
              'detector across a slow link (docs/OFFBOARD.md).', read_only=True),
    ParamSpec('jpeg_quality', INT, 90, 'JPEG quality of camera/image_raw/compressed.',
              (1, 100), read_only=True),
    ParamSpec('camera_noise_std', DOUBLE, 1.0, 'Gaussian image noise, grey levels.',
              (0.0, 100.0)),
    ParamSpec('camera_blur_sigma', DOUBLE, 0.5, 'Gaussian blur sigma, pixels.', (0.0, 20.0)),
    ParamSpec('camera_gain', DOUBLE, 1.0, 'Exposure gain (multiplies intensities).',
              (0.05, 20.0)),
    probability('p_missed_tag', 0.0, 'Probability that a tag is not drawn in a frame '
                '(glare, occlusion): fault injection for the detector and matcher.'),
    ParamSpec('camera_supersample', INT, 4, 'Renderer supersampling of face outlines '
              '(1 = fastest).', (1, 8)),
    ParamSpec('camera_noise_bank', INT, 8, 'Image noise from this many pre-drawn noise frames '
              '(a random window of one each frame; much faster); 0 = fresh Gaussian noise '
              'every frame.', (0, 64)),
    ParamSpec('distractors', INT, 0, 'Flat tags on the floor around the cube that are not on '
              'it (ids n_tags..49 not on the cube).', (0, 20)),
    ParamSpec('distractor_seed', INT, 0, 'Seed of the distractors.', SEED_RANGE),
    ParamSpec('look_at_cube', BOOL, True, 'Start with the head pan/tilt pointing the camera '
              'at the cube (ignored when initial_positions is given).'),
    ParamSpec('initial_positions', DOUBLE_ARRAY, None, 'Initial joint positions, 13 values in '
              'URDF joint order (as /joint_states); empty = all zero (arms hanging).'),
    # -- contacts and failures ------------------------------------------------------------
    ParamSpec('hand_radius', DOUBLE, 0.03, 'Radius of the hand balls for contacts, m.',
              (0.005, 0.2)),
    probability('p_slip_grasp', 0.0, 'Probability that a grasp slips (LIFT/FLIP: no '
                'change).'),
    probability('p_missed_push', 0.0, 'Probability that a push meets nothing (no change).'),
    probability('p_push_neighbour', 0.0, 'Probability that a push pivots the other way '
                '(a sliding push pivots either way).'),
    ParamSpec('orbit_odometry_noise', DOUBLE_ARRAY, [0.0, 0.0], '[sigma_m, sigma_rad]: at the '
              'end of every base motion the true base pose moves by N(0, sigma_m^2) in x and '
              'y and N(0, sigma_rad^2) in yaw, unseen by /odom.'),
    ParamSpec('failure_seed', INT, 0, 'Seed of the failure draws, odometry noise and image '
              'noise.', SEED_RANGE),
    # -- MuJoCo physics (docs/SIM_BRIDGE.md "The MuJoCo world") -----------------------------
    ParamSpec('physics_rate', DOUBLE, 500.0, 'MuJoCo steps per second of simulation time, at '
              'least (each tick is split into equal steps)' + MUJOCO_ONLY + '.',
              (500.0, 10000.0)),
    ParamSpec('cube_mass', DOUBLE, 0.75, 'Total cube mass, kg' + MUJOCO_ONLY + '.',
              (0.01, 50.0)),
    ParamSpec('heavy_mass_ratio', DOUBLE, 0.625, 'Eccentric cubes: mass of the heavy inner slab '
              '(2 cm thick, against the heavy face) / total mass; 0.625 puts the centre of mass '
              '2.5 cm off centre' + MUJOCO_ONLY + '.', (0.0, 0.95)),
    ParamSpec('cube_friction', DOUBLE, 0.5, 'Sliding friction coefficient of the cube'
              + MUJOCO_ONLY + '.', (0.01, 5.0)),
    ParamSpec('floor_friction', DOUBLE, 0.5, 'Sliding friction coefficient of the floor'
              + MUJOCO_ONLY + '.', (0.01, 5.0)),
    ParamSpec('hand_friction', DOUBLE, 1.0, 'Sliding friction coefficient of the hand pads'
              + MUJOCO_ONLY + '.', (0.01, 5.0)),
    ParamSpec('hand_torsional_friction', DOUBLE, 0.001, 'Torsional friction of the hand pads, '
              'm (torque about the contact normal per newton; 0 = none)' + MUJOCO_ONLY + '.',
              (0.0, 0.1)),
    ParamSpec('friction_scale', DOUBLE, 1.0, 'Multiplies every friction coefficient (cube, '
              'floor, hands): a slippery or sticky world' + MUJOCO_ONLY + '.', (0.01, 10.0)),
    ParamSpec('servo_stiffness_scale', DOUBLE, 1.0, 'Multiplies the torso and arm servo '
              'gains (a weaker squeeze, more sag under load)' + MUJOCO_ONLY + '.',
              (0.01, 10.0)),
    ParamSpec('grasp_opening', DOUBLE, 0.0, 'Each hand is held this far outwards of its '
              'commanded path, m (less squeeze, or none: the skills squeeze 5 mm)'
              + MUJOCO_ONLY + '.', (0.0, 0.1)),
    ParamSpec('joint_offsets', DOUBLE_ARRAY, None, 'Calibration errors: 13 angles (rad, URDF '
              'joint order) added to the servo set points; empty = none' + MUJOCO_ONLY + '.'),
    ParamSpec('slip_grasp_opening', DOUBLE, 0.01, 'p_slip_grasp in the MuJoCo world: a '
              'faulty contact episode holds each hand this much further outwards, m '
              '(added to grasp_opening).', (0.0, 0.1)),
    ParamSpec('missed_push_offset', DOUBLE, 0.10, 'p_missed_push in the MuJoCo world: a '
              'faulty contact episode holds each hand this much further outwards, m '
              '(sideways: a push passes beside the cube, a grasp closes on nothing).',
              (0.0, 0.3)),
    ParamSpec('camera_shadows', BOOL, False, 'Render shadows (costs 10-20x render time)'
              + MUJOCO_ONLY + '.'),
    ParamSpec('camera_offsamples', INT, 0, 'Multisampling (anti-aliasing) samples'
              + MUJOCO_ONLY + '.', (0, 16)),
)
PARAMETER_NAMES = tuple(p.name for p in PARAMETERS)
_BY_NAME = {p.name: p for p in PARAMETERS}
# Parameters that act at once; the read-only ones at start only; all others take effect
# at the next ~/reset_world.
LIVE_PARAMETERS = frozenset({'speedup'})


def defaults():
    return spec_defaults(PARAMETERS)


def description_note(spec):
    """When a change of the parameter takes effect (appended to its description)."""
    if spec.read_only:
        return ' (read at start only)'
    return '' if spec.name in LIVE_PARAMETERS else ' (changes take effect at ~/reset_world)'


@dataclass
class CameraConfig:
    rate: float
    encoding: str
    effects: ImageEffects
    supersample: int
    noise_bank: int
    tag_size: float
    cube_size: float
    p_missed_tag: float = _BY_NAME['p_missed_tag'].default
    dictionary: str = DEFAULT_DICTIONARY


def _default(name):
    """The default of parameter `name`: the dataclasses below take theirs from PARAMETERS,
    so a default is written once."""
    return _BY_NAME[name].default


@dataclass
class MujocoConfig:
    """The MuJoCo world's physical quantities and fault magnitudes (world mujoco)."""
    physics_rate: float = _default('physics_rate')
    cube_mass: float = _default('cube_mass')
    heavy_mass_ratio: float = _default('heavy_mass_ratio')
    cube_friction: float = _default('cube_friction')
    floor_friction: float = _default('floor_friction')
    hand_friction: float = _default('hand_friction')
    hand_torsional_friction: float = _default('hand_torsional_friction')
    friction_scale: float = _default('friction_scale')
    servo_stiffness_scale: float = _default('servo_stiffness_scale')
    grasp_opening: float = _default('grasp_opening')
    joint_offsets: tuple = ()     # parameter joint_offsets: none (its default) = no offsets
    slip_grasp_opening: float = _default('slip_grasp_opening')
    missed_push_offset: float = _default('missed_push_offset')
    shadows: bool = _default('camera_shadows')
    offsamples: int = _default('camera_offsamples')


@dataclass
class SimBridgeConfig:
    values: dict                 # the parameter values it was built from
    hidden: HiddenModel
    cube: Cube
    settings: SimSettings
    failures: Failures
    camera: CameraConfig
    distractors: list = field(default_factory=list)   # built from parameter distractors
    speedup: float = _default('speedup')
    publish_clock: bool = _default('publish_clock')
    ground_truth_rate: float = _default('ground_truth_rate')
    failure_seed: int = _default('failure_seed')
    look_at_cube: bool = _default('look_at_cube')
    world: str = _default('world')
    mujoco: MujocoConfig = field(default_factory=MujocoConfig)
    # (HiddenModel, Cube) of the scene's further cubes (num_cubes > 1).
    more_cubes: list = field(default_factory=list)

    @property
    def hiddens(self):
        """Every cube's model, the first being `hidden`."""
        return [self.hidden, *(h for h, _ in self.more_cubes)]

    @property
    def cubes(self):
        """Every cube (its pose and mass), the first being `cube`."""
        return [self.cube, *(c for _, c in self.more_cubes)]

    @property
    def look_at_point(self):
        """Where the head looks at the start: the cube, or the centroid of the cubes."""
        return np.mean([c.position for c in self.cubes], axis=0)


def _array(value):
    return [] if value is None else list(value)


def check_speedup(value):
    value = float(value)
    if not (np.isfinite(value) and 0.0 < value <= 100.0):
        raise ValueError(f'speedup must be > 0 and <= 100, got {value}')
    return value


def check_dictionary(name, face_tags, distractors):
    """ValueError, naming the parameter, unless `name` is an ArUco dictionary that holds
    every tag id of the hidden cube and the distractors."""
    try:
        check_tag_ids(name, [*face_tags, *(d.tag_id for d in distractors)])
    except ValueError as err:
        raise ValueError(f'dictionary: {err}') from err


def build(values):
    """SimBridgeConfig from parameter values (missing names take their defaults).
    Raises ValueError with the offending parameter's name."""
    v = defaults()
    unknown = set(values) - set(v)
    if unknown:
        raise ValueError(f'unknown parameters: {sorted(unknown)}')
    v.update(values)
    check_all(PARAMETERS, v)
    rate = float(v['rate'])
    speedup = check_speedup(v['speedup'])
    camera_rate = float(v['camera_rate'])
    if camera_rate > rate:
        raise ValueError(f'camera_rate ({camera_rate} Hz) must not exceed rate ({rate} Hz)')
    if float(v['state_rate']) > rate:
        raise ValueError(f"state_rate ({v['state_rate']} Hz) must not exceed rate ({rate} Hz)")
    gt_rate = float(v['ground_truth_rate'])
    if gt_rate > rate:
        raise ValueError(f'ground_truth_rate ({gt_rate} Hz) must not exceed rate ({rate} Hz)')
    cube_size, tag_size = float(v['cube_size']), float(v['tag_size'])
    if not tag_size < cube_size:
        raise ValueError(f'tag_size ({tag_size} m) must be smaller than cube_size '
                         f'({cube_size} m)')
    if not float(v['mass_offset']) < cube_size / 2:
        raise ValueError(f"mass_offset ({v['mass_offset']} m) must be less than half the "
                         f'cube_size ({cube_size} m)')
    face_tags = _array(v['face_tags'])
    try:
        hidden = choose_hidden_model(face_tags, v['mass_index'], v['model_set'],
                                     v['model_set_size'], v['n_tags'], v['seed'],
                                     v['model_file'], v['model_index'], v['cube_seed'])
    except ValueError as err:
        raise ValueError(f'hidden cube: {err}') from err
    hiddens, cubes = _scene(v, hidden, cube_size)
    hidden, cube = hiddens[0], cubes[0]
    if np.hypot(cube.position[0], cube.position[1]) < cube.half * np.sqrt(2) + 0.05:
        raise ValueError('cube_x, cube_y: the cube must not stand on the robot (keep it at '
                         'least 12 cm from the odom origin)')
    noise = _array(v['orbit_odometry_noise'])
    try:
        settings = SimSettings(rate=rate, cmd_vel_timeout=float(v['cmd_vel_timeout']),
                               orbit_odometry_noise=tuple(noise),
                               initial_positions=tuple(_array(v['initial_positions'])),
                               contact=ContactParams(hand_radius=float(v['hand_radius'])))
    except ValueError as err:
        raise ValueError(str(err)) from err
    if settings.initial_positions and len(settings.initial_positions) != 13:
        raise ValueError('initial_positions must give 13 joint positions (URDF joint order, '
                         f'as /joint_states), got {len(settings.initial_positions)}')
    failures = Failures(p_slip_grasp=float(v['p_slip_grasp']),
                        p_missed_push=float(v['p_missed_push']),
                        p_push_neighbour=float(v['p_push_neighbour']))
    effects = ImageEffects(gain=float(v['camera_gain']), blur_sigma=float(v['camera_blur_sigma']),
                           noise_std=float(v['camera_noise_std']))
    camera = CameraConfig(camera_rate, v['camera_encoding'], effects,
                          int(v['camera_supersample']), int(v['camera_noise_bank']), tag_size,
                          cube_size, float(v['p_missed_tag']), str(v['dictionary']))
    distractors = make_distractors(int(v['distractors']), int(v['distractor_seed']),
                                   cube.position[:2], tag_size, hidden.n_tags,
                                   avoid={t for h in hiddens for t in h.face_tags})
    check_dictionary(camera.dictionary, {t for h in hiddens for t in h.face_tags}, distractors)
    offsets = tuple(float(x) for x in _array(v['joint_offsets']))
    if offsets and len(offsets) != 13:
        raise ValueError('joint_offsets must give 13 angles (URDF joint order, as '
                         f'/joint_states) or none, got {len(offsets)}')
    mujoco = MujocoConfig(**{name: v[name] for name in (
        'physics_rate', 'cube_mass', 'heavy_mass_ratio', 'cube_friction', 'floor_friction',
        'hand_friction', 'hand_torsional_friction', 'friction_scale', 'servo_stiffness_scale',
        'grasp_opening', 'slip_grasp_opening', 'missed_push_offset')},
        joint_offsets=offsets, shadows=bool(v['camera_shadows']),
        offsamples=int(v['camera_offsamples']))
    return SimBridgeConfig(dict(v), hidden, cube, settings, failures, camera, distractors,
                           speedup, bool(v['publish_clock']), gt_rate, int(v['failure_seed']),
                           bool(v['look_at_cube']), str(v['world']), mujoco,
                           list(zip(hiddens[1:], cubes[1:])))


def _scene(v, hidden, cube_size):
    """([HiddenModel], [Cube]) of the scene: the hidden cube at cube_x, cube_y alone, or
    num_cubes models of the set placed by scenario.place_cubes."""
    count, up, offset = int(v['num_cubes']), int(v['cube_up_face']), float(v['mass_offset'])
    if count == 1:
        if v['twin_cubes']:
            raise ValueError('twin_cubes needs num_cubes >= 2')
        return [hidden], [initial_cube(hidden, float(v['cube_x']), float(v['cube_y']),
                                       float(v['cube_yaw']), up, cube_size, offset)]
    if hidden.model_index < 0:
        raise ValueError('num_cubes > 1 draws the cubes from the model set: leave face_tags '
                         'empty')
    models = load_model_set(v['model_set'], v['model_set_size'], v['n_tags'], v['seed'],
                            v['model_file'])
    first = -1 if v['twin_cubes'] and int(v['model_index']) == -1 else hidden.model_index
    try:
        indices = scene_models(first, count, models, int(v['cube_seed']), bool(v['twin_cubes']))
    except ValueError as err:
        raise ValueError(f'num_cubes: {err}') from err
    radius = _array(v['scene_radius'])
    if len(radius) != 2:
        raise ValueError(f'scene_radius must be [r_min, r_max], got {radius}')
    centres = place_cubes(count, int(v['cube_seed']), float(v['cube_spacing']), radius,
                          float(v['scene_half_angle_deg']))
    steps = np.random.default_rng([int(v['cube_seed']), 39]).integers(8, size=count)
    hiddens, cubes = [], []
    for k, (index, xy) in enumerate(zip(indices, centres)):
        h = hidden_model(models, index)
        yaw = facing_yaw(xy) + (float(v['cube_yaw']) if k == 0 else steps[k] * np.pi / 4)
        hiddens.append(h)
        cubes.append(initial_cube(h, float(xy[0]), float(xy[1]), yaw, up, cube_size, offset))
    return hiddens, cubes


def scene_summary(config):
    """The scene's cubes for the log: today's text with one cube."""
    text = ', '.join(f'{h.object_id} (model_index {h.model_index})' for h in config.hiddens)
    return f'hidden cube {text}' if len(config.hiddens) == 1 else \
        f'{len(config.hiddens)} hidden cubes {text}'


def refusal(values, changes):
    """Why a parameter change is refused ('' when it is accepted): `values` are the current
    {name: value}, `changes` the new ones (names that are not the sim bridge's, such as
    use_sim_time, are ignored). A change is accepted when the world it describes builds."""
    changes = {name: value for name, value in changes.items() if name in _BY_NAME}
    for name in changes:
        if _BY_NAME[name].read_only:
            return f'{name} is read at start only: restart'
    if not changes:
        return ''
    try:
        build({**values, **changes})
    except ValueError as err:
        return str(err)
    return ''


__all__ = ['LIVE_PARAMETERS', 'MODEL_SET_SPECS', 'PARAMETERS', 'PARAMETER_NAMES', 'WORLDS',
           'CameraConfig', 'MujocoConfig', 'SimBridgeConfig', 'build', 'check_speedup', 'defaults',
           'description_note', 'refusal', 'scene_summary']
