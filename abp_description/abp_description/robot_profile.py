"""The robot profile: every robot-specific fact of the stack in one YAML file beside a URDF
(plain Python, no rclpy).

A node reads it through its one `robot_profile` parameter (`PROFILE_SPEC`: a path; empty =
the uBot-6 profile shipped in this package's share/profiles). `load_profile` parses it into
a frozen `RobotProfile` and refuses a bad file with a message naming the file and the key:
a missing or unknown key, a value of the wrong kind, a skill the stack does not know, and,
when the URDF is a file, a joint or link the URDF does not have. docs/PORTING.md describes
the fields; profiles/ubot6.yaml is the worked example.
"""

import functools
import math
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType

import yaml

from abp_common.param_spec import STRING, ParamSpec

from .data_files import _data_file

DEFAULT_PROFILE = 'ubot6.yaml'
PROFILE_DIR = 'profiles'
URDF_FROM_TOPIC = 'topic'   # `urdf: topic`: the URDF arrives on /robot_description
SKILLS = ('orbit', 'push', 'lift', 'flip')      # what the stack's skill servers can do
BIMANUAL_SKILLS = ('lift', 'flip')               # a two-hand squeeze: needs two arms
COMMAND_TYPES = ('twist_stamped', 'twist')
INTERFACES = ('action', 'topic')
ORBIT_FIELDS = ('linear_velocity', 'linear_acceleration', 'linear_jerk', 'angular_velocity',
                'angular_acceleration', 'angular_jerk')

PROFILE_SPEC = ParamSpec(
    'robot_profile', STRING, '',
    'Robot profile YAML (URDF, controllers, frames, collision shapes, skills; '
    'docs/PORTING.md); empty = the uBot-6 profile of abp_description (profiles/ubot6.yaml).',
    read_only=True)


class ProfileError(ValueError):
    """A robot profile that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class Controller:
    name: str
    joints: tuple
    interface: str


@dataclass(frozen=True)
class Arm:
    side: str
    controller: str
    joints: tuple           # the controller's joints, in its order
    upper_arm_link: str     # capsule from this link's origin (shoulder) ...
    forearm_link: str       # ... to this one's (elbow), then to the hand
    hand_frame: str


@dataclass(frozen=True)
class BodyShape:
    """A body part for the clearance checks: a box (half extents) or a cylinder (axis =
    the frame's y), centred at `offset` in `frame`."""

    name: str
    frame: str
    offset: tuple
    box: tuple | None = None
    radius: float = 0.0
    half_length: float = 0.0


@dataclass(frozen=True)
class CollisionGeometry:
    upper_arm_radius: float
    forearm_radius: float
    hand_radius: float
    shoulder_bodies: tuple   # bodies an upper arm may touch (attached at the shoulder)
    bodies: tuple            # BodyShape


@dataclass(frozen=True)
class OrbitLimits:
    min_radius: float
    max_radius: float
    linear_velocity: float
    linear_acceleration: float
    linear_jerk: float
    angular_velocity: float
    angular_acceleration: float
    angular_jerk: float


@dataclass(frozen=True)
class Base:
    command_type: str
    command_topic: str
    wheel_joints: tuple
    orbit: OrbitLimits


@dataclass(frozen=True)
class Frames:
    base: str
    camera_optical: str
    camera_mount: str


@dataclass(frozen=True)
class Head:
    controller: str
    pan_joint: str
    tilt_joint: str


@dataclass(frozen=True)
class Torso:
    controller: str
    joint: str
    link: str


@dataclass(frozen=True)
class Posture:
    """A named posture: the torso angle (None without a torso) and {arm: joint values}."""

    torso: float | None
    arms: MappingProxyType


POSTURES = ('home', 'ready', 'reach')   # what the manual skills' plans are built from


@dataclass(frozen=True)
class RobotProfile:
    """A checked robot profile. Mappings are read-only; `path` is the file it came from."""

    name: str
    path: str
    urdf: str                 # absolute URDF path, or URDF_FROM_TOPIC
    camera_calibration: str   # absolute path
    base: Base
    controllers: tuple        # Controller, in the order trajectories are sent
    frames: Frames
    head: Head
    torso: Torso | None
    arms: MappingProxyType    # side -> Arm
    collision: CollisionGeometry
    skills: MappingProxyType  # skill -> arms it uses (empty for orbit)
    servo_gains: MappingProxyType   # simulator: joint name or part of one -> (kp, kv, arm.)
    grasp_opening_joints: MappingProxyType   # simulator: joint -> rad per m of opening
    postures: MappingProxyType   # name (POSTURES) -> Posture; empty without manual skills
    models: str | None = None   # absolute path of the ATG model set learned for this robot

    # -- derived tables ------------------------------------------------------------------
    @property
    def controller_joints(self):
        """{controller name: its joints in message order}."""
        return {c.name: c.joints for c in self.controllers}

    @property
    def body_joints(self):
        """The joints trajectories command, in controller order."""
        return tuple(j for c in self.controllers for j in c.joints)

    @property
    def sides(self):
        return tuple(self.arms)

    @property
    def arm_joints(self):
        return {side: arm.joints for side, arm in self.arms.items()}

    @property
    def hand_frames(self):
        return {side: arm.hand_frame for side, arm in self.arms.items()}

    @property
    def urdf_from_topic(self):
        return self.urdf == URDF_FROM_TOPIC

    def has_skill(self, skill):
        return skill in self.skills

    def skill_arms(self, skill):
        """The arms a skill uses ((), for ORBIT or a skill the robot lacks)."""
        return self.skills.get(skill, ())

    def urdf_file(self):
        """The URDF path; ProfileError when the profile takes it from /robot_description."""
        if self.urdf_from_topic:
            raise ProfileError(f'{self.path}: urdf is {URDF_FROM_TOPIC!r}; this reader needs '
                               'a URDF file (set urdf to a path)')
        return self.urdf


def with_profile_defaults(specs, profile):
    """`specs` (ParamSpecs) with the defaults the robot profile sets: the base command's
    type and topic (abp_common.base_command.SPECS)."""
    robot = {'base_command_type': profile.base.command_type,
             'base_command_topic': profile.base.command_topic}
    return tuple(replace(s, default=robot[s.name]) if s.name in robot else s for s in specs)


# -- loading ------------------------------------------------------------------------------
def default_profile_path():
    """The shipped uBot-6 profile (installed share dir, else the source tree)."""
    return str(_data_file(PROFILE_DIR, DEFAULT_PROFILE))


def load_profile(path=None):
    """The RobotProfile of the YAML file `path` (None or '': the uBot-6's); cached per file."""
    path = default_profile_path() if not path else str(path)
    return _load_resolved(str(Path(path).expanduser().resolve()))


@functools.lru_cache(maxsize=8)
def _load_resolved(path):
    try:
        with open(path) as stream:
            doc = yaml.safe_load(stream)
    except OSError as error:
        raise ProfileError(f'robot profile {path}: cannot be read ({error.strerror})') from None
    except yaml.YAMLError as error:
        raise ProfileError(f'robot profile {path}: not YAML ({error})') from None
    return profile_from_dict(doc, path)


class _Reader:
    """Typed access to one mapping of the YAML, with errors naming file and key."""

    def __init__(self, doc, where, key=''):
        self.where, self.key = where, key
        if not isinstance(doc, dict):
            raise self.error(f'must be a mapping, got {type(doc).__name__}')
        self.doc = doc
        self.used = set()

    def error(self, message, key=None):
        name = key if key is not None else self.key
        return ProfileError(f'robot profile {self.where}: {name or "top level"}: {message}')

    def _path(self, name):
        return f'{self.key}.{name}' if self.key else name

    def raw(self, name, default=...):
        self.used.add(name)
        if name not in self.doc:
            if default is ...:
                raise self.error('missing', self._path(name))
            return default
        return self.doc[name]

    def text(self, name, default=..., choices=()):
        value = self.raw(name, default)
        if not isinstance(value, str) or not value:
            raise self.error(f'must be a non-empty string, got {value!r}', self._path(name))
        if choices and value not in choices:
            raise self.error(f'must be one of {", ".join(choices)}, got {value!r}',
                             self._path(name))
        return value

    def number(self, name, default=..., positive=True):
        value = self.raw(name, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise self.error(f'must be a number, got {value!r}', self._path(name))
        if positive and value <= 0:
            raise self.error(f'must be > 0, got {value}', self._path(name))
        return float(value)

    def names(self, name, default=..., allow_empty=False):
        value = self.raw(name, default)
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise self.error(f'must be a list of names, got {value!r}', self._path(name))
        if not value and not allow_empty:
            raise self.error('must not be empty', self._path(name))
        if len(set(value)) != len(value):
            raise self.error(f'names repeat in {value}', self._path(name))
        return tuple(value)

    def vector(self, name, length, positive=False):
        value = self.raw(name)
        ok = isinstance(value, list) and len(value) == length and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and (v > 0 or not positive) for v in value)
        if not ok:
            kind = 'positive numbers' if positive else 'numbers'
            raise self.error(f'must be a list of {length} {kind}, got {value!r}',
                             self._path(name))
        return tuple(float(v) for v in value)

    def child(self, name, default=...):
        return _Reader(self.raw(name, default), self.where, self._path(name))

    def done(self):
        unknown = sorted(set(self.doc) - self.used)
        if unknown:
            raise self.error(f'unknown key(s) {", ".join(map(str, unknown))}')


def _relative_file(reader, name, base_dir):
    value = reader.text(name)
    if value == URDF_FROM_TOPIC and name == 'urdf':
        return value
    path = (base_dir / value).resolve()
    if not path.is_file():
        raise reader.error(f'no file {path}', reader._path(name))
    return str(path)


def _orbit(reader):
    values = {f: reader.number(f) for f in ('min_radius', 'max_radius', *ORBIT_FIELDS)}
    reader.done()
    if values['min_radius'] >= values['max_radius']:
        raise reader.error('min_radius must be < max_radius')
    return OrbitLimits(**values)


def _controllers(reader):
    out = []
    for name in reader.doc:
        entry = reader.child(name)
        out.append(Controller(str(name), entry.names('joints'),
                              entry.text('interface', 'action', INTERFACES)))
        entry.done()
    reader.used.update(reader.doc)
    if not out:
        raise reader.error('no controllers')
    joints = [j for c in out for j in c.joints]
    repeated = sorted({j for j in joints if joints.count(j) > 1})
    if repeated:
        raise reader.error(f'joints in more than one controller: {", ".join(repeated)}')
    return tuple(out)


def _body(reader):
    name, frame = reader.text('name'), reader.text('frame')
    offset = reader.vector('offset', 3)
    if ('box' in reader.doc) == ('cylinder' in reader.doc):
        raise reader.error('needs exactly one of box or cylinder')
    if 'box' in reader.doc:
        shape = BodyShape(name, frame, offset, box=reader.vector('box', 3, positive=True))
    else:
        cyl = reader.child('cylinder')
        shape = BodyShape(name, frame, offset, radius=cyl.number('radius'),
                          half_length=cyl.number('half_length'))
        cyl.done()
    reader.done()
    return shape


def _collision(reader):
    bodies_doc = reader.raw('bodies')
    if not isinstance(bodies_doc, list):
        raise reader.error('must be a list', reader._path('bodies'))
    bodies = tuple(_body(_Reader(b, reader.where, f'{reader._path("bodies")}[{i}]'))
                   for i, b in enumerate(bodies_doc))
    geometry = CollisionGeometry(
        reader.number('upper_arm_radius'), reader.number('forearm_radius'),
        reader.number('hand_radius'), reader.names('shoulder_bodies', [], allow_empty=True),
        bodies)
    reader.done()
    unknown = set(geometry.shoulder_bodies) - {b.name for b in bodies}
    if unknown:
        raise reader.error(f'shoulder_bodies names no body: {", ".join(sorted(unknown))}')
    return geometry


def _skills(reader, arms):
    skills = {}
    for skill in reader.doc:
        if skill not in SKILLS:
            raise reader.error(f'unknown skill {skill!r}; the stack has {", ".join(SKILLS)}',
                               reader._path(str(skill)))
        value = reader.doc[skill]
        entry = _Reader({} if value is None else value, reader.where, reader._path(skill))
        used = entry.names('arms', [], allow_empty=True)
        entry.done()
        missing = [a for a in used if a not in arms]
        if missing:
            raise entry.error(f'arms {", ".join(missing)} not among the profile\'s arms '
                              f'({", ".join(arms) or "none"})')
        if skill == 'orbit' and used:
            raise entry.error('ORBIT drives the base; it uses no arms')
        if skill != 'orbit' and not used:
            raise entry.error(f'{skill} needs arms')
        if skill in BIMANUAL_SKILLS and len(used) != 2:
            raise entry.error(f'{skill} is a two-hand squeeze: it needs exactly two arms')
        skills[skill] = used
    reader.used.update(reader.doc)
    return MappingProxyType(skills)


def _servo_gains(reader):
    gains = {}
    for key in reader.doc:
        value = reader.raw(key)
        if not (isinstance(value, list) and len(value) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0
                for v in value)):
            raise reader.error(f'must be [kp, kv, armature] (numbers >= 0), got {value!r}',
                               reader._path(str(key)))
        gains[str(key)] = tuple(float(v) for v in value)
    return MappingProxyType(gains)


def _postures(reader, arms, torso):
    postures = {}
    for name in reader.doc:
        if name not in POSTURES:
            raise reader.error(f'unknown posture {name!r}; the skills use {", ".join(POSTURES)}',
                               reader._path(str(name)))
    for name in (POSTURES if reader.doc else ()):
        entry = reader.child(name)
        angle = entry.number('torso', positive=False) if torso is not None else None
        values = entry.child('arms')
        by_arm = {}
        for side, arm in arms.items():
            by_arm[side] = values.vector(side, len(arm.joints))
        values.done()
        entry.done()
        postures[name] = Posture(angle, MappingProxyType(by_arm))
    reader.used.update(reader.doc)
    return MappingProxyType(postures)


def _opening_gains(reader):
    gains = {}
    for key in reader.doc:
        value = reader.raw(key)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or value == 0 \
                or not math.isfinite(value):
            raise reader.error(f'must be a nonzero number (rad per m of opening), got {value!r}',
                               reader._path(str(key)))
        gains[str(key)] = float(value)
    return MappingProxyType(gains)


def profile_from_dict(doc, path='<profile>'):
    """A RobotProfile from the parsed YAML `doc` (relative files from `path`'s folder)."""
    top = _Reader(doc, path)
    base_dir = Path(path).parent
    name = top.text('name')
    urdf = _relative_file(top, 'urdf', base_dir)
    camera = _relative_file(top, 'camera_calibration', base_dir)
    base_reader = top.child('base')
    base = Base(base_reader.text('command_type', choices=COMMAND_TYPES),
                base_reader.text('command_topic'),
                base_reader.names('wheel_joints', [], allow_empty=True),
                _orbit(base_reader.child('orbit')))
    base_reader.done()
    if len(base.wheel_joints) not in (0, 2):
        raise base_reader.error('wheel_joints: list the left then the right wheel joint '
                                '(or none)')
    controllers = _controllers(top.child('controllers'))
    by_name = {c.name: c for c in controllers}

    def controller_of(reader, key='controller'):
        value = reader.text(key)
        if value not in by_name:
            raise reader.error(f'no controller {value!r} in controllers', reader._path(key))
        return by_name[value]

    fr = top.child('frames')
    frames = Frames(fr.text('base'), fr.text('camera_optical'), fr.text('camera_mount'))
    fr.done()
    hd = top.child('head')
    head = Head(controller_of(hd).name, hd.text('pan_joint'), hd.text('tilt_joint'))
    hd.done()
    if set(by_name[head.controller].joints) != {head.pan_joint, head.tilt_joint}:
        raise hd.error(f'{head.controller} must command exactly pan_joint and tilt_joint')
    torso = None
    if top.doc.get('torso') is not None:
        tr = top.child('torso')
        torso = Torso(controller_of(tr).name, tr.text('joint'), tr.text('link'))
        tr.done()
        if by_name[torso.controller].joints != (torso.joint,):
            raise tr.error(f'{torso.controller} must command the torso joint alone')
    else:
        top.used.add('torso')
    arms_reader = top.child('arms', {})
    arms = {}
    for side in arms_reader.doc:
        ar = arms_reader.child(side)
        controller = controller_of(ar)
        arms[str(side)] = Arm(str(side), controller.name, controller.joints,
                              ar.text('upper_arm_link'), ar.text('forearm_link'),
                              ar.text('hand_frame'))
        ar.done()
    arms_reader.used.update(arms_reader.doc)
    collision = _collision(top.child('collision'))
    skills = _skills(top.child('skills'), arms)
    manual = [k for k in skills if k != 'orbit']
    postures = _postures(top.child('postures', {} if not manual else ...), arms, torso)
    sim = top.child('simulation', {})
    gains = _servo_gains(sim.child('servo_gains', {}))
    opening = _opening_gains(sim.child('grasp_opening_joints', {}))
    sim.done()
    # The ATG tables learned for this robot (learn_atg); start_graph.sh's default --models.
    models = None
    if top.doc.get('models') is not None:
        models = _relative_file(top, 'models', base_dir)
    else:
        top.used.add('models')
    top.done()
    profile = RobotProfile(name, str(path), urdf, camera, base, controllers, frames, head, torso,
                           MappingProxyType(arms), collision, skills, gains, opening,
                           postures, models)
    if not profile.urdf_from_topic:
        check_against_urdf(profile, _urdf_names(urdf, path))
    return profile


def _urdf_names(urdf, where):
    """({link names}, {joint name: type}) of a URDF file."""
    try:
        root = ElementTree.parse(urdf).getroot()
    except (OSError, ElementTree.ParseError) as error:
        raise ProfileError(f'robot profile {where}: urdf {urdf}: {error}') from None
    links = {e.get('name') for e in root.iter('link')}
    joints = {e.get('name'): e.get('type') for e in root.iter('joint')}
    return links, joints


def check_against_urdf(profile, urdf_names):
    """ProfileError unless every joint and link the profile names is in the URDF
    (`urdf_names`: ({links}, {joint: type})), commanded joints being movable."""
    links, joints = urdf_names
    problems = []
    movable = {n for n, t in joints.items() if t not in ('fixed', 'floating', 'planar')}
    for c in profile.controllers:
        problems += [f'controllers.{c.name}: no movable joint {j!r}'
                     for j in c.joints if j not in movable]
    problems += [f'base.wheel_joints: no movable joint {j!r}'
                 for j in profile.base.wheel_joints if j not in movable]
    problems += [f'simulation.grasp_opening_joints: no movable joint {j!r}'
                 for j in profile.grasp_opening_joints if j not in movable]
    frames = [('frames.base', profile.frames.base),
              ('frames.camera_optical', profile.frames.camera_optical),
              ('frames.camera_mount', profile.frames.camera_mount)]
    if profile.torso is not None:
        frames.append(('torso.link', profile.torso.link))
    for side, arm in profile.arms.items():
        frames += [(f'arms.{side}.{key}', getattr(arm, key))
                   for key in ('upper_arm_link', 'forearm_link', 'hand_frame')]
    frames += [(f'collision.bodies ({b.name})', b.frame) for b in profile.collision.bodies]
    problems += [f'{key}: no link {value!r}' for key, value in frames if value not in links]
    if problems:
        raise ProfileError(f'robot profile {profile.path} does not fit its URDF '
                           f'{profile.urdf}: ' + '; '.join(problems))


__all__ = ['Arm', 'Base', 'BodyShape', 'CollisionGeometry', 'Controller', 'Frames', 'Head',
           'OrbitLimits', 'POSTURES', 'PROFILE_SPEC', 'Posture', 'ProfileError', 'RobotProfile',
           'SKILLS', 'Torso',
           'check_against_urdf', 'default_profile_path', 'load_profile', 'profile_from_dict',
           'with_profile_defaults']
