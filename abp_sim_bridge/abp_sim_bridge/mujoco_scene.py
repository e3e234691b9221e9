"""The MuJoCo scene of the sim bridge, generated at start (plain Python + mujoco, no rclpy).

One source of the robot's geometry: the robot profile's URDF (`abp_description.robot_profile`),
loaded by MuJoCo's URDF importer with fixed links kept as bodies and visual geoms kept,
plus these MJCF additions made with `mujoco.MjSpec`:

- **Base** on planar joints `base_x`, `base_y` (world-aligned slides) and `base_yaw`
  (hinge about z), each driven by a velocity actuator: the world does the diff-drive
  kinematics (v, w in the base frame -> world-frame rates) and the limits.
- **Servos**: a position actuator (PD with URDF effort limits) on every torso, arm and head
  joint, with motor armature and gravity compensation of the robot's own links (as a
  real arm controller would have; the load, the cube, is not compensated).
  The wheels are passive and do not collide (the base slides; odometry gives their angle).
- **Collisions**: robot geoms collide with the floor and the cube only, never with each
  other (the URDF's primitives overlap at the joints); visual copies never collide.
  The hands are the URDF's balls (0.035 m), with their own (pad) friction.
- **ARcube**: a free body with a box of edge `edge`, uniform mass or a heavy inner slab
  near one body face (`heavy_mass_ratio` of the total mass), face tags as textured
  quads made with `cv2.aruco` (the cube's `dictionary`, DICT_4X4_50 by default) at start,
  in renderer.py's tag axes.
- **Floor**, two lights, and the head camera `head_camera` on `camera_link` with the
  calibrated vertical field of view. MuJoCo cameras look along -z with y up; the ROS
  optical frame looks along +z with y down: the camera frame is the optical frame turned
  180 deg about its x axis.
- `<visual><quality shadowsize="0" offsamples="0"/>` by default: shadows and multisampling
  cost 10-20x in render time here and do not help tag detection.
"""

import os
from dataclasses import dataclass, field

# Headless rendering by default; MUJOCO_GL is read when mujoco is imported.
os.environ.setdefault('MUJOCO_GL', 'egl')

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from abp_belief.cube import FACE_NORMALS, NUM_YAWS, R_UP  # noqa: E402
from abp_description import camera_intrinsics  # noqa: E402
from abp_description.robot_profile import load_profile  # noqa: E402

from .flat_renderer import (  # noqa: E402
    DEFAULT_DICTIONARY,
    FACE_TAG_AXES,
    check_tag_ids,
    tag_dictionary,
)

BASE_JOINTS = ('base_x', 'base_y', 'base_yaw')
CUBE_BODY = 'arcube'
CUBE_GEOM = 'arcube_box'
CAMERA_NAME = 'head_camera'
FLOOR_GEOM = 'floor'
HAND_GEOM_SUFFIX = '_ball'   # a hand body's collision pad: '<hand frame>_ball'
# Collision bits: robot geoms (ROBOT) touch floor and cube (WORLD) but never each other.
WORLD_BIT, ROBOT_BIT = 1, 2
COLLISION_GROUP = 3  # collision copies of the URDF geoms: not drawn by default

# Servo gains per joint, (kp N m/rad, kv N m s/rad, armature kg m^2), come from the robot
# profile's simulation.servo_gains: for the uBot-6 stiff enough that the hands follow the
# skills' paths within millimetres and squeeze a grasped cube with ~10-20 N, with armature
# (reflected motor inertia) that keeps them stable at a 2 ms step.
BASE_GAINS = {'base_x': 1500.0, 'base_y': 1500.0, 'base_yaw': 300.0}  # velocity servo kv
BASE_FORCE = {'base_x': 400.0, 'base_y': 400.0, 'base_yaw': 150.0}   # N, N m


@dataclass
class CubeSpec:
    """The ARcube of the scene: geometry, tags, mass and friction."""

    position: tuple = (0.40, 0.0, 0.05)   # centre, world
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # body -> world
    face_tags: tuple = (0, 1, 2, 3, 4, 5)  # tag id on body faces +x -x +y -y +z -z (-1 blank)
    edge: float = 0.10                    # m (docs/MODEL.md)
    tag_edge: float = 0.08                # m
    mass: float = 0.75                    # kg, total
    heavy_face: int | None = None         # body face the heavy slab lies against; None uniform
    heavy_mass_ratio: float = 0.625       # slab mass / total mass (offset 0.025 m)
    heavy_slab_thickness: float = 0.02    # m; the slab lies against the inside of the face
    friction: float = 0.5                 # sliding friction on the floor and its default
    dictionary: str = DEFAULT_DICTIONARY  # ArUco dictionary of its tags (and distractors')

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=float).reshape(3)
        self.rotation = np.asarray(self.rotation, dtype=float).reshape(3, 3)
        if not 0 < self.tag_edge < self.edge:
            raise ValueError('tag_edge must be in (0, edge)')
        if not self.mass > 0:
            raise ValueError('cube mass must be > 0')
        if self.heavy_face is not None and not 0 <= int(self.heavy_face) < 6:
            raise ValueError(f'heavy_face must be None or 0..5, got {self.heavy_face}')
        if not 0 <= self.heavy_mass_ratio < 1:
            raise ValueError('heavy_mass_ratio must be in [0, 1)')
        if not 0 < self.heavy_slab_thickness < self.edge / 2:
            raise ValueError('heavy_slab_thickness must be in (0, edge / 2)')
        if not self.friction > 0:
            raise ValueError('cube friction must be > 0')
        check_tag_ids(self.dictionary, self.face_tags)

    @property
    def half(self):
        return self.edge / 2

    @property
    def slab_offset(self):
        """Distance of the slab's centre from the cube centre."""
        return self.half - self.heavy_slab_thickness / 2

    @property
    def mass_offset(self):
        """Centre of mass from the cube centre towards the heavy face (0 for uniform)."""
        if self.heavy_face is None:
            return 0.0
        return self.heavy_mass_ratio * self.slab_offset


@dataclass
class SceneSettings:
    """Physics and rendering options of the scene."""

    timestep: float = 0.002               # s (500 Hz)
    hand_friction: float = 1.0            # sliding friction of the hand pads
    hand_torsional_friction: float = 0.001  # m: torque about a contact normal per newton
    floor_friction: float = 0.5
    servo_stiffness_scale: float = 1.0    # scales kp (and kv) of the arm and torso servos
    shadows: bool = False                 # shadow map 4096 (MuJoCo's default 4096)
    offsamples: int = 0                   # multisampling (anti-aliasing) samples
    width: int | None = None              # camera image; None = camera.yaml's
    height: int | None = None

    def __post_init__(self):
        if not 0 < self.timestep <= 0.002:
            raise ValueError('timestep must be in (0, 0.002] s (physics at >= 500 Hz)')
        for name in ('hand_friction', 'floor_friction', 'servo_stiffness_scale'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0')
        if self.hand_torsional_friction < 0:
            raise ValueError('hand_torsional_friction must be >= 0')


@dataclass(frozen=True)
class CubeState:
    """The cube's continuous pose and hidden mass (ground truth)."""

    position: np.ndarray     # (3,) centre, world
    rotation: np.ndarray     # (3, 3) body -> world
    heavy_face: int | None
    edge: float
    mass_offset: float

    def pose(self):
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = self.rotation, self.position
        return out


def discrete_state(cube_pose, base_pose):
    """MODEL.md's (up, yaw) of a cube (4x4 world pose) seen from the base (x, y, yaw):
    `up` the body face pointing most upwards, `yaw` the nearest 45-deg step of Rz in
    R = Rz(yaw) R_UP[up], R the rotation body -> view frame V (x_V from the cube towards
    the robot, z up)."""
    to_robot = np.asarray(base_pose[:2], dtype=float) - cube_pose[:2, 3]
    x_v = np.array([*to_robot, 0.0]) / np.linalg.norm(to_robot)
    view = np.column_stack([x_v, np.cross([0.0, 0.0, 1.0], x_v), [0.0, 0.0, 1.0]])
    rel = view.T @ cube_pose[:3, :3]
    up = int(np.argmax((rel @ FACE_NORMALS.T)[2]))
    rz = rel @ R_UP[up].T
    yaw = int(np.round(np.arctan2(rz[1, 0], rz[0, 0]) / (2 * np.pi / NUM_YAWS))) % NUM_YAWS
    return up, yaw


def tag_texture(tag_id, edge, tag_edge, pixels=256, dictionary=DEFAULT_DICTIONARY):
    """RGB image of one face: white square with the tag `tag_id` of the ArUco `dictionary`
    (an OpenCV name) centred (tag_id < 0: blank). Row 0 is the top of the tag image."""
    img = np.full((pixels, pixels), 255, np.uint8)
    if tag_id >= 0:
        side = int(round(pixels * tag_edge / edge))
        aruco = cv2.aruco.getPredefinedDictionary(tag_dictionary(dictionary)[0])
        marker = cv2.aruco.generateImageMarker(aruco, int(tag_id), side)
        start = (pixels - side) // 2
        img[start:start + side, start:start + side] = marker
    return np.ascontiguousarray(np.repeat(img[:, :, None], 3, axis=2))


def hand_bodies(profile):
    """{side: MuJoCo body of the hand}: the hand frames (links) of the profile."""
    return profile.hand_frames


def _urdf_spec(profile):
    """The URDF as an MjSpec with fixed links as bodies and visual geoms kept."""
    with open(profile.urdf_file()) as stream:
        text = stream.read()
    head = text.index('>', text.index('<robot')) + 1
    options = ('<mujoco><compiler fusestatic="false" discardvisual="false" '
               'balanceinertia="true"/></mujoco>')
    return mujoco.MjSpec.from_string(text[:head] + options + text[head:])


def _servo_gains(joint, gains):
    """The profile's gains of `joint`: by its name, else by a key that is part of it."""
    if joint in gains:
        return gains[joint]
    for key, value in gains.items():
        if key in joint:
            return value
    raise KeyError(f'no servo gains for joint {joint!r} (robot profile simulation.servo_gains)')


def _setup_robot(spec, settings, profile):
    """Planar base joints, servos, collision filters and gravity compensation."""
    base = spec.body(profile.frames.base)
    wheel_joints = set(profile.base.wheel_joints)
    wheel_bodies = {j.parent.name for j in spec.joints if j.name in wheel_joints}
    hands = set(hand_bodies(profile).values())
    head_joints = {profile.head.pan_joint, profile.head.tilt_joint}
    for name, kind, axis in (('base_x', mujoco.mjtJoint.mjJNT_SLIDE, (1, 0, 0)),
                             ('base_y', mujoco.mjtJoint.mjJNT_SLIDE, (0, 1, 0)),
                             ('base_yaw', mujoco.mjtJoint.mjJNT_HINGE, (0, 0, 1))):
        base.add_joint(name=name, type=kind, axis=list(axis))
    for body in spec.bodies:
        if body.name == 'world':
            continue
        body.gravcomp = 1.0  # the controllers compensate the robot's own weight
        for geom in body.geoms:
            if geom.contype == 0 and geom.conaffinity == 0:
                continue  # visual copy
            geom.group = COLLISION_GROUP
            wheel = body.name in wheel_bodies
            geom.contype = 0 if wheel else ROBOT_BIT
            geom.conaffinity = 0
            if body.name in hands:  # the pads
                geom.name = body.name + HAND_GEOM_SUFFIX
                geom.friction = [settings.hand_friction, settings.hand_torsional_friction,
                                 0.0001]
                geom.condim = 4 if settings.hand_torsional_friction > 0 else 3
    scale = settings.servo_stiffness_scale
    for joint in list(spec.joints):
        if joint.name in BASE_JOINTS:
            act = spec.add_actuator(name=joint.name, target=joint.name,
                                    trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.set_to_velocity(kv=BASE_GAINS[joint.name])
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-BASE_FORCE[joint.name], BASE_FORCE[joint.name]]
            continue
        if joint.name in wheel_joints:
            joint.damping = [0.05, 0.0, 0.0]
            continue
        kp, kv, armature = _servo_gains(joint.name, profile.servo_gains)
        if joint.name not in head_joints:
            kp, kv = kp * scale, kv * np.sqrt(scale)
        joint.armature = armature
        joint.actgravcomp = True
        act = spec.add_actuator(name=joint.name, target=joint.name,
                                trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=kp, kv=kv)
        effort = float(joint.actfrcrange[1]) if joint.actfrclimited else 0.0
        if effort > 0:
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-effort, effort]


def _add_camera(spec, settings, profile):
    intr = camera_intrinsics(profile.camera_calibration)
    height = settings.height or intr.height
    # Same vertical field of view at any image height: fy scales with the height.
    fovy = np.degrees(2 * np.arctan(intr.height / (2 * intr.fy)))
    optical = spec.body(profile.frames.camera_optical)
    # MuJoCo camera axes in the optical frame: x = x, y = -y, z = -z.
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.diag([1.0, -1.0, -1.0]).ravel())
    optical.add_camera(name=CAMERA_NAME, pos=[0, 0, 0], quat=list(quat), fovy=float(fovy))
    return height


def cube_prefix(index):
    """Name prefix of cube `index` of a scene's bodies, geoms, textures: the first cube's
    names are those of a one-cube scene (arcube, arcube_box, arcube_face_0, ...)."""
    return CUBE_BODY if index == 0 else f'{CUBE_BODY}{index}'


def _add_cube(spec, cube, prefix=CUBE_BODY):
    body = spec.worldbody.add_body(name=prefix, pos=list(cube.position))
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(cube.rotation).ravel())
    body.quat = list(quat)
    body.add_freejoint(name=f'{prefix}_free')
    heavy = cube.heavy_face is not None and cube.heavy_mass_ratio > 0
    slab_mass = cube.mass * cube.heavy_mass_ratio if heavy else 0.0
    body.add_geom(name=f'{prefix}_box', type=mujoco.mjtGeom.mjGEOM_BOX, size=[cube.half] * 3,
                  mass=cube.mass - slab_mass, friction=[cube.friction, 0.0, 0.0],
                  contype=WORLD_BIT, conaffinity=WORLD_BIT | ROBOT_BIT, condim=3,
                  rgba=[1, 1, 1, 1])
    if heavy:
        normal = FACE_NORMALS[int(cube.heavy_face)]
        size = np.where(normal != 0, cube.heavy_slab_thickness / 2, cube.half - 0.005)
        body.add_geom(name=f'{prefix}_heavy_slab', type=mujoco.mjtGeom.mjGEOM_BOX,
                      size=list(size), pos=list(normal * cube.slab_offset), mass=slab_mass,
                      contype=0, conaffinity=0, group=COLLISION_GROUP, rgba=[0.3, 0.3, 0.3, 1])
    # Tag quads just outside the faces (visual only, massless: shell inertia, no density).
    h, lift = cube.half, 0.0003
    corners = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])  # tag-image TL, TR, BR, BL
    for face, tag in enumerate(cube.face_tags):
        axes = FACE_TAG_AXES[face]
        verts = corners @ axes[:, :2].T + (h + lift) * axes[:, 2]
        tex = spec.add_texture(name=f'{prefix}_tag_{face}', type=mujoco.mjtTexture.mjTEXTURE_2D)
        image = tag_texture(int(tag), cube.edge, cube.tag_edge, dictionary=cube.dictionary)
        tex.width, tex.height, tex.nchannel = image.shape[1], image.shape[0], 3
        tex.data = image.tobytes()
        mat = spec.add_material(name=f'{prefix}_face_{face}')
        mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
        mesh = spec.add_mesh(name=f'{prefix}_face_{face}')
        mesh.uservert = verts.ravel().tolist()
        mesh.userface = [0, 3, 2, 0, 2, 1]  # counter-clockwise seen from outside
        # MuJoCo's texture v runs from the first image row (v = 0) down.
        mesh.usertexcoord = [0, 0, 1, 0, 1, 1, 0, 1]
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        body.add_geom(name=f'{prefix}_face_{face}', type=mujoco.mjtGeom.mjGEOM_MESH,
                      meshname=mesh.name, material=mat.name, contype=0, conaffinity=0,
                      group=1, mass=0.0, density=0.0)
    return body


def _add_distractors(spec, distractors, dictionary):
    """Flat tags lying in the scene (flat_renderer.Distractor: tag centre pose in ArUco
    axes, tag size, white margin), visual only."""
    for k, tag in enumerate(distractors):
        h = tag.size * (0.5 + tag.margin)
        corners = np.array([[-h, h], [h, h], [h, -h], [-h, -h]])
        pose = np.asarray(tag.pose, dtype=float)
        verts = corners @ pose[:3, :2].T + pose[:3, 3] + 0.0005 * pose[:3, 2]
        tex = spec.add_texture(name=f'distractor_{k}', type=mujoco.mjtTexture.mjTEXTURE_2D)
        image = tag_texture(int(tag.tag_id), 2 * h, tag.size, dictionary=dictionary)
        tex.width, tex.height, tex.nchannel = image.shape[1], image.shape[0], 3
        tex.data = image.tobytes()
        mat = spec.add_material(name=f'distractor_{k}')
        mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
        mesh = spec.add_mesh(name=f'distractor_{k}')
        mesh.uservert = verts.ravel().tolist()
        mesh.userface = [0, 3, 2, 0, 2, 1]
        mesh.usertexcoord = [0, 0, 1, 0, 1, 1, 0, 1]
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        spec.worldbody.add_geom(name=f'distractor_{k}', type=mujoco.mjtGeom.mjGEOM_MESH,
                                meshname=mesh.name, material=mat.name, contype=0,
                                conaffinity=0, group=1)


def rendered_as(img, encoding):
    """An RGB frame from mujoco.Renderer as a sensor_msgs/Image `encoding` (rgb8, bgr8 or
    mono8)."""
    if encoding == 'rgb8':
        return img
    if encoding == 'bgr8':
        return np.ascontiguousarray(img[:, :, ::-1])
    if encoding == 'mono8':
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    raise ValueError(f'encoding must be rgb8, bgr8 or mono8, got {encoding!r}')


def add_room(spec, shadows):
    """The light, haze and checkered floor every abp scene shares; returns the floor geom
    (its contacts are the caller's)."""
    spec.visual.headlight.ambient = [0.45, 0.45, 0.45]
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    spec.visual.rgba.haze = [0.62, 0.66, 0.7, 1.0]
    world = spec.worldbody
    checker = spec.add_texture(name='floor_grid', type=mujoco.mjtTexture.mjTEXTURE_2D,
                               builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=256,
                               height=256, rgb1=[0.55, 0.52, 0.48], rgb2=[0.5, 0.47, 0.43])
    floor_mat = spec.add_material(name='floor', texrepeat=[8, 8])
    floor_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = checker.name
    floor = world.add_geom(name=FLOOR_GEOM, type=mujoco.mjtGeom.mjGEOM_PLANE,
                           size=[0, 0, 0.05], material='floor')
    world.add_light(name='sun', pos=[1.0, 1.0, 3.0], dir=[-0.3, -0.3, -1.0],
                    diffuse=[0.6, 0.6, 0.6], castshadow=shadows)
    return floor


def build_spec(cube=None, settings=None, distractors=(), profile=None, more_cubes=()):
    """The scene as an MjSpec (see the module doc); `distractors`: flat tags elsewhere;
    `profile`: the robot (default: the uBot-6 profile); `more_cubes`: further CubeSpecs
    of a scene of several cubes (free bodies `cube_prefix(1)`, ...; they touch each other)."""
    cube = cube or CubeSpec()
    settings = settings or SceneSettings()
    profile = profile if profile is not None else load_profile()
    spec = _urdf_spec(profile)
    spec.modelname = 'abp_scene'
    spec.option.timestep = settings.timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC  # friction without pyramid bias
    spec.option.noslip_iterations = 2  # grasped objects do not creep out of the hands
    spec.visual.quality.shadowsize = 4096 if settings.shadows else 0
    spec.visual.quality.offsamples = int(settings.offsamples)
    intr = camera_intrinsics(profile.camera_calibration)
    width = settings.width or intr.width
    height = settings.height or intr.height
    spec.visual.global_.offwidth = max(int(width), 640)
    spec.visual.global_.offheight = max(int(height), 480)
    _setup_robot(spec, settings, profile)
    _add_camera(spec, settings, profile)
    floor = add_room(spec, settings.shadows)
    floor.friction = [settings.floor_friction, 0.005, 0.0001]
    floor.contype, floor.conaffinity = WORLD_BIT, WORLD_BIT | ROBOT_BIT
    _add_cube(spec, cube)
    for index, other in enumerate(more_cubes, start=1):
        _add_cube(spec, other, cube_prefix(index))
    _add_distractors(spec, distractors, cube.dictionary)
    return spec


def build_model(cube=None, settings=None, distractors=(), profile=None, more_cubes=()):
    """(MjModel, MjSpec) of the scene."""
    spec = build_spec(cube, settings, distractors, profile, more_cubes)
    return spec.compile(), spec


__all__ = ['BASE_JOINTS', 'CAMERA_NAME', 'CUBE_BODY', 'CUBE_GEOM', 'CubeSpec', 'CubeState',
           'HAND_GEOM_SUFFIX', 'SceneSettings', 'build_model', 'build_spec', 'cube_prefix',
           'discrete_state', 'hand_bodies', 'tag_texture']
