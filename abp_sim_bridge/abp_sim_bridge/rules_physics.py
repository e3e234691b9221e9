"""The rules world's physics of the ARcube for the robot's actions (plain NumPy, no
rclpy): outcomes of PUSH, LIFT, FLIP and ORBIT decided by rules.

The outcome of PUSH, LIFT and FLIP is computed from the cube's hidden mass and from the
motion the hands really made (contact points, stroke, grasp points), never from the ATG
tables of abp_belief; docs/MODEL.md states the rules this physics must reproduce.

- The cube is a continuous pose on the floor: centre `position` (world, m) and `rotation`
  (body -> world). Its mass is uniform or offset by `mass_offset` towards one body face.
- PUSH: the hand's straight stroke meets a side face (or misses it). A block pushed on a
  floor turns about its centre of friction, which is under the centre of mass: a push line
  through the centre of mass slides the cube, one beside it lets the heavy side drag and
  the cube pivots (≈45°, the light side advancing).
- LIFT: the hands squeeze two opposite faces; lifted, the cube turns about the hand axis
  until its centre of mass hangs below it, and is put down where it was.
- FLIP: the hands grasp two opposite faces near the robot and roll the cube towards it: a
  uniform cube turns its bottom towards the robot (the front comes on top); an eccentric
  cube comes to rest with its mass at the base (turning first about the hand axis, then
  about the horizontal axis across it).
- ORBIT: the base drives around the cube; odometry error is optional.
- `discrete_state` maps the continuous pose relative to the robot to MODEL.md's (up, yaw).

Failures are injected with a seeded numpy Generator and `Failures` probabilities.
Angles are radians unless a name says `_deg`.
"""

import itertools
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

# MODEL.md's cube conventions (body faces, the reference rotations R_UP): geometry, not
# the ATG tables.
from abp_belief.cube import FACE_NORMALS, NUM_YAWS, OPPOSITE_FACE, R_UP
from abp_description.frames import rot_z, se2_between, se2_compose, wrap_rad

Z = np.array([0.0, 0.0, 1.0])


# -- small rotation helpers ---------------------------------------------------------------

def rotation_about(axis, angle):
    """Rodrigues rotation matrix about a (not necessarily unit) axis."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def _orthonormalize(rot):
    u, _, vt = np.linalg.svd(rot)
    out = u @ vt
    if np.linalg.det(out) < 0:
        u[:, -1] *= -1
        out = u @ vt
    return out


def _signed_angle(v_from, v_to, axis):
    """Angle turning v_from onto v_to about axis (both taken in the plane normal to axis)."""
    axis = axis / np.linalg.norm(axis)
    a = v_from - (v_from @ axis) * axis
    b = v_to - (v_to @ axis) * axis
    return float(np.arctan2(np.cross(a, b) @ axis, a @ b))


def _unit(v, what):
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError(f'{what} must be a non-zero finite vector')
    return v / n


def _horizontal_unit(v, what):
    v = np.array(v, dtype=float)
    v[2] = 0.0
    return _unit(v, f'{what} (horizontal part)')


# -- the cube -------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Cube:
    """An ARcube at rest or in the hands: world pose of its centre, and its hidden mass."""

    position: np.ndarray                 # (3,) centre, world
    rotation: np.ndarray                 # (3, 3) body -> world
    heavy_face: int | None = None        # body face the mass sits towards; None = uniform
    edge: float = 0.10                   # m
    mass_offset: float = 0.025           # m, centre of mass from the centre towards heavy_face

    def __post_init__(self):
        object.__setattr__(self, 'position', np.array(self.position, dtype=float).reshape(3))
        object.__setattr__(self, 'rotation', np.array(self.rotation, dtype=float).reshape(3, 3))
        if self.heavy_face is not None and not 0 <= int(self.heavy_face) < 6:
            raise ValueError(f'heavy_face must be None or 0..5, not {self.heavy_face}')
        if not 0 <= self.mass_offset < self.edge / 2:
            raise ValueError('mass_offset must lie inside the cube')

    @classmethod
    def on_floor(cls, x, y, rotation=None, heavy_face=None, edge=0.10, **kw):
        """A cube resting on the floor (z = 0) with its centre above (x, y)."""
        rotation = np.eye(3) if rotation is None else rotation
        return cls(np.array([x, y, edge / 2]), rotation, heavy_face, edge, **kw)

    @classmethod
    def from_mass_index(cls, position, rotation, mass_index, edge=0.10, **kw):
        """mass_index as in abp_belief: 0 = uniform, 1 + f = heavy body face f."""
        m = int(mass_index)
        if not 0 <= m <= 6:
            raise ValueError(f'mass_index must be 0..6, not {mass_index}')
        return cls(position, rotation, None if m == 0 else m - 1, edge, **kw)

    @property
    def half(self):
        return self.edge / 2

    @property
    def mass_index(self):
        return 0 if self.heavy_face is None else 1 + int(self.heavy_face)

    def pose(self):
        """4x4 world pose of the body frame (what the renderer takes)."""
        out = np.eye(4)
        out[:3, :3] = self.rotation
        out[:3, 3] = self.position
        return out

    def face_normal(self, face):
        return self.rotation @ FACE_NORMALS[face]

    def face_centre(self, face):
        return self.position + self.half * self.face_normal(face)

    def centre_of_mass(self):
        if self.heavy_face is None:
            return self.position.copy()
        return self.position + self.mass_offset * self.face_normal(self.heavy_face)

    def mass_direction(self):
        """World unit vector from the centre towards the mass (None for uniform)."""
        return None if self.heavy_face is None else self.face_normal(self.heavy_face)

    def with_pose(self, position, rotation):
        return replace(self, position=position, rotation=rotation)

    def face_at(self, point, tol=0.01):
        """Body face on whose square `point` lies (within `tol` of its plane), else None."""
        local = self.rotation.T @ (np.asarray(point, dtype=float) - self.position)
        best, best_dist = None, tol
        for face, normal in enumerate(FACE_NORMALS):
            dist = abs(local @ normal - self.half)
            in_plane = local - (local @ normal) * normal
            if dist <= best_dist and np.all(np.abs(in_plane) <= self.half + 1e-9):
                best, best_dist = face, dist
        return best


# -- outcomes and failures ------------------------------------------------------------------

SLID = 'slid'                  # PUSH through the centre of mass: translated
PIVOTED = 'pivoted'            # PUSH beside the centre of mass: turned about z
ROTATED = 'rotated'            # LIFT/FLIP turned the cube
UNCHANGED = 'unchanged'        # contact made, but the cube ends as it was
MISSED = 'missed'              # PUSH: the stroke met no face (or slipped off it)
SLIPPED = 'slipped'            # LIFT/FLIP: the grasp did not hold
BLOCKED = 'blocked'            # LIFT: not raised enough for the cube to swing clear


class Outcome(NamedTuple):
    cube: Cube
    effect: str


@dataclass
class Failures:
    """Probabilities of injected failures (all off by default)."""

    p_slip_grasp: float = 0.0       # LIFT/FLIP grasp slips: no change
    p_missed_push: float = 0.0      # PUSH hand glances off: no change
    p_push_neighbour: float = 0.0   # PUSH pivots the other way (a slide pivots either way)
    orbit_angle_std: float = 0.0    # rad, Gaussian error of the angle driven around the cube
    orbit_radius_std: float = 0.0   # m
    p_orbit_slip: float = 0.0       # the orbit ends one 45° step off (either way)

    def __post_init__(self):
        for name in ('p_slip_grasp', 'p_missed_push', 'p_push_neighbour', 'p_orbit_slip'):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f'{name} must be a probability in [0, 1]')
        if self.orbit_angle_std < 0 or self.orbit_radius_std < 0:
            raise ValueError('orbit noise standard deviations must be >= 0')


@dataclass
class Physics:
    """Tunable constants of the contact physics."""

    contact_tol: float = 0.01          # m, a hand point counts as on a face within this
    max_push_incidence: float = np.radians(30)  # beyond: the hand glances off an edge
    min_travel: float = 0.01           # m, shorter strokes after contact move nothing
    pivot_offset: float = 0.0125       # m, centre of mass this far beside the push line pivots
    pivot_angle: float = np.radians(45)
    max_grasp_misalignment: float = np.radians(25)  # hand axis vs face normals
    grip_hold_arm: float = 0.008       # m, the grip's friction holds smaller gravity arms
    min_roll_cross: float = np.cos(np.radians(30))  # |roll x hand axis| needed to roll


def _chance(rng, p):
    return p > 0 and rng is not None and rng.random() < p


def settle(cube):
    """Put the cube down on the floor on the face pointing most downwards (snap the small
    tilt away, centre at half an edge above the floor)."""
    rot = _orthonormalize(cube.rotation)
    normals = rot @ FACE_NORMALS.T
    bottom = int(np.argmin(normals[2]))
    n = normals[:, bottom]
    axis = np.cross(n, -Z)
    if np.linalg.norm(axis) > 1e-12:
        angle = np.arctan2(np.linalg.norm(axis), n @ -Z)
        rot = rotation_about(axis, angle) @ rot
    elif n @ Z > 0:  # pragma: no cover - argmin never picks the up face
        rot = rotation_about([1.0, 0.0, 0.0], np.pi) @ rot
    position = cube.position.copy()
    position[2] = cube.half
    return cube.with_pose(position, rot)


def _rotate_about_line(cube, rot, point):
    """Rigidly rotate the cube by `rot` about a line through `point`."""
    point = np.asarray(point, dtype=float)
    return cube.with_pose(point + rot @ (cube.position - point), rot @ cube.rotation)


# -- PUSH -----------------------------------------------------------------------------------

def push_contact(cube, start_point, direction, stroke_length, physics=None):
    """Where a straight horizontal stroke from `start_point` first meets a side face.

    Returns (face, hit_point, travel_after_contact) or None when it meets no face squarely
    (outside the face, beyond the stroke, or at more than `max_push_incidence`)."""
    physics = physics or Physics()
    u = _horizontal_unit(direction, 'push direction')
    start = np.asarray(start_point, dtype=float)
    best = None
    for face in range(6):
        n = cube.face_normal(face)
        cos_in = -(n @ u)
        if cos_in < np.cos(physics.max_push_incidence) or abs(n[2]) > 0.5:
            continue
        t = (cube.face_centre(face) - start) @ n / (u @ n)
        if t < -physics.contact_tol or t > stroke_length:
            continue
        hit = start + t * u
        local = cube.rotation.T @ (hit - cube.position)
        local -= (local @ FACE_NORMALS[face]) * FACE_NORMALS[face]
        if np.any(np.abs(local) > cube.half):  # the line passes beside the face
            continue
        if best is None or t < best[2]:
            best = (face, hit, t)
    if best is None:
        return None
    face, hit, t = best
    return face, hit, stroke_length - max(t, 0.0)


def apply_push(cube, contact_point_world, push_direction_world, stroke_length, rng=None,
               failures=None, physics=None):
    """Push with a hand moving `stroke_length` m from `contact_point_world` along
    `push_direction_world` (its horizontal part). Returns Outcome(cube, effect)."""
    failures = failures or Failures()
    physics = physics or Physics()
    if not stroke_length >= 0:
        raise ValueError('stroke_length must be >= 0')
    contact = push_contact(cube, contact_point_world, push_direction_world, stroke_length,
                           physics)
    if contact is None or _chance(rng, failures.p_missed_push):
        return Outcome(cube, MISSED)
    face, hit, travel = contact
    if travel < physics.min_travel:
        return Outcome(cube, UNCHANGED)
    u = _horizontal_unit(push_direction_world, 'push direction')
    # Signed lateral offset of the centre of mass from the push line (about +z): its sign
    # is the way the cube turns when the heavy side drags.
    lateral = float(np.cross(u, cube.centre_of_mass() - hit) @ Z)
    turn = 0.0
    if abs(lateral) > physics.pivot_offset:
        turn = np.sign(lateral) * physics.pivot_angle
    if _chance(rng, failures.p_push_neighbour):
        turn = -turn if turn != 0.0 else rng.choice([-1.0, 1.0]) * physics.pivot_angle
    if turn == 0.0:
        return Outcome(cube.with_pose(cube.position + travel * u, cube.rotation), SLID)
    # Pivot about the middle of the dragging side (the side the turn keeps in place).
    side = np.cross(Z, u) * np.sign(turn)  # horizontal, pointing to the dragging side
    pivot = cube.position + cube.half * side
    pivot[2] = cube.position[2]
    return Outcome(settle(_rotate_about_line(cube, rot_z(turn), pivot)), PIVOTED)


# -- LIFT and FLIP --------------------------------------------------------------------------

def grasp_faces(cube, left_grasp_world, right_grasp_world, physics=None):
    """(left_face, right_face, hand_axis) when the hands hold two opposite faces squarely,
    else None (the grasp would slip)."""
    physics = physics or Physics()
    left = np.asarray(left_grasp_world, dtype=float)
    right = np.asarray(right_grasp_world, dtype=float)
    fl = cube.face_at(left, physics.contact_tol)
    fr = cube.face_at(right, physics.contact_tol)
    if fl is None or fr is None or OPPOSITE_FACE[fl] != fr:
        return None
    axis = right - left
    if np.linalg.norm(axis) < 1e-6:
        return None
    axis = axis / np.linalg.norm(axis)
    if axis @ cube.face_normal(fr) < np.cos(physics.max_grasp_misalignment):
        return None
    return fl, fr, axis


def _swing_clearance(cube, axis, axis_point):
    """Largest distance of a cube corner from the hand axis: what the axis must clear."""
    corners = np.array(list(itertools.product((-1, 1), repeat=3))) * cube.half
    rel = corners @ cube.rotation.T + cube.position - axis_point
    perp = rel - np.outer(rel @ axis, axis)
    return float(np.max(np.linalg.norm(perp, axis=1)))


def apply_lift(cube, left_grasp_world, right_grasp_world, lift_height, rng=None,
               failures=None, physics=None):
    """Grasp at the two points, raise by `lift_height` m and put the cube down again."""
    failures = failures or Failures()
    physics = physics or Physics()
    grasp = grasp_faces(cube, left_grasp_world, right_grasp_world, physics)
    if grasp is None or _chance(rng, failures.p_slip_grasp):
        return Outcome(cube, SLIPPED)
    _, _, axis = grasp
    point = (np.asarray(left_grasp_world, float) + np.asarray(right_grasp_world, float)) / 2
    arm = cube.centre_of_mass() - point
    arm -= (arm @ axis) * axis
    if np.linalg.norm(arm) < physics.grip_hold_arm:  # (nearly) on the axis: the grip holds
        return Outcome(cube, UNCHANGED)
    angle = _signed_angle(arm, -Z, axis)
    if abs(angle) > np.radians(1) and point[2] + lift_height < _swing_clearance(cube, axis, point):
        return Outcome(cube, BLOCKED)  # a corner catches the floor: it rocks back
    # Hang with the centre of mass below the axis, then land on the lowest face.
    turned = settle(_rotate_about_line(cube, rotation_about(axis, angle), point))
    return _labelled(cube, turned)


def _labelled(before, after):
    same = np.allclose(before.rotation, after.rotation, atol=1e-6)
    return Outcome(before if same else after, UNCHANGED if same else ROTATED)


def apply_flip(cube, left_grasp_world, right_grasp_world, roll_direction_world, rng=None,
               failures=None, physics=None):
    """Grasp at the two points and roll the cube so that its bottom turns towards
    `roll_direction_world` (towards the robot in the FLIP skill)."""
    failures = failures or Failures()
    physics = physics or Physics()
    grasp = grasp_faces(cube, left_grasp_world, right_grasp_world, physics)
    if grasp is None or _chance(rng, failures.p_slip_grasp):
        return Outcome(cube, SLIPPED)
    _, _, hand_axis = grasp
    roll = _horizontal_unit(roll_direction_world, 'roll direction')
    if np.linalg.norm(np.cross(roll, hand_axis)) < physics.min_roll_cross:
        return Outcome(cube, SLIPPED)  # cannot roll along the hand axis
    roll = _horizontal_unit(roll - (roll @ hand_axis) * hand_axis, 'roll direction')
    d = cube.mass_direction()
    if d is None:
        # Uniform: a quarter turn about the hand axis taking the bottom towards `roll`.
        rot = rotation_about(np.cross(-Z, roll), np.pi / 2)
    else:
        # Eccentric: the cube ends with its mass at the base. First about the hand axis ...
        rot = np.eye(3)
        across = d - (d @ hand_axis) * hand_axis
        if np.linalg.norm(across) > 1e-6:
            rot = rotation_about(hand_axis, _signed_angle(across, -Z, hand_axis))
        # ... then, if the mass lay along the hand axis, about the axis across it.
        d1 = rot @ d
        tilt = np.cross(d1, -Z)
        if np.linalg.norm(tilt) > 1e-9:
            rot = rotation_about(tilt, np.arctan2(np.linalg.norm(tilt), d1 @ -Z)) @ rot
    return _labelled(cube, settle(_rotate_about_line(cube, rot, cube.position)))


# -- ORBIT and the robot base ----------------------------------------------------------------

class OrbitResult(NamedTuple):
    pose: np.ndarray         # (x, y, yaw) where the base really ends
    odometry: np.ndarray     # (x, y, yaw) where odometry says it is (the nominal target)
    angle: float             # angle really driven, rad (the change of the cube's relative yaw)


def facing_pose(cube_position, bearing, radius):
    """Base pose (x, y, yaw) at `radius` from the cube in world direction `bearing`,
    facing the cube."""
    c = np.asarray(cube_position, dtype=float)
    return np.array([c[0] + radius * np.cos(bearing), c[1] + radius * np.sin(bearing),
                     wrap_rad(bearing + np.pi)])


def apply_orbit(robot_pose, cube, angle, radius, rng=None, failures=None):
    """Drive the base around the cube so that the cube's relative yaw changes by `angle`
    (MODEL.md's ORBIT(θ): the robot moves by -θ about the cube's vertical axis) and stop
    at `radius`, facing the cube."""
    failures = failures or Failures()
    robot = np.asarray(robot_pose, dtype=float)
    centre = cube.position
    bearing = np.arctan2(robot[1] - centre[1], robot[0] - centre[0])
    nominal = facing_pose(centre, bearing - angle, radius)
    real_angle, real_radius = float(angle), float(radius)
    if rng is not None:
        if failures.orbit_angle_std > 0:
            real_angle += rng.normal(0.0, failures.orbit_angle_std)
        if failures.orbit_radius_std > 0:
            real_radius += rng.normal(0.0, failures.orbit_radius_std)
            real_radius = max(cube.half + 0.05, real_radius)  # never drive into the cube
        if _chance(rng, failures.p_orbit_slip):
            real_angle += rng.choice([-1.0, 1.0]) * np.pi / 4
    real = facing_pose(centre, bearing - real_angle, real_radius)
    return OrbitResult(real, nominal, real_angle)


# -- ground truth: the discrete state of MODEL.md ----------------------------------------------

def view_frame(cube_position, robot_xy):
    """Rotation V -> world: x_V horizontal from the cube towards the robot, z_V up."""
    c = np.asarray(cube_position, dtype=float)
    x = _horizontal_unit(np.array([robot_xy[0] - c[0], robot_xy[1] - c[1], 0.0]),
                         'cube-to-robot direction')
    return np.column_stack([x, np.cross(Z, x), Z])


def relative_rotation(cube, robot_base_pose):
    """The cube's orientation R (body -> V) seen from the robot."""
    rot, pos = _rotation_position(cube)
    return view_frame(pos, robot_base_pose).T @ rot


def discrete_state(cube_pose, robot_base_pose):
    """(up, yaw) of MODEL.md nearest to the continuous relative pose: `up` the body face
    pointing most upwards in V, `yaw` the nearest 45° step of Rz in R = Rz(yaw) R_UP[up].
    `cube_pose` is a Cube or a 4x4 world pose; `robot_base_pose` is (x, y, yaw)."""
    rel = relative_rotation(cube_pose, robot_base_pose)
    up = int(np.argmax((rel @ FACE_NORMALS.T)[2]))
    rz = rel @ R_UP[up].T
    yaw = int(np.round(np.arctan2(rz[1, 0], rz[0, 0]) / (np.pi / 4))) % NUM_YAWS
    return up, yaw


def discrete_state_index(cube_pose, robot_base_pose):
    up, yaw = discrete_state(cube_pose, robot_base_pose)
    return NUM_YAWS * up + yaw


def _rotation_position(cube):
    if isinstance(cube, Cube):
        return cube.rotation, cube.position
    pose = np.asarray(cube, dtype=float)
    return pose[:3, :3], pose[:3, 3]


# -- a world to step ------------------------------------------------------------------------

@dataclass
class World:
    """The cube and the robot base with a seeded failure model; actions update both."""

    cube: Cube
    robot_pose: np.ndarray                  # true (x, y, yaw)
    failures: Failures = field(default_factory=Failures)
    physics: Physics = field(default_factory=Physics)
    seed: int | None = 0

    def __post_init__(self):
        self.robot_pose = np.asarray(self.robot_pose, dtype=float)
        self.odometry_pose = self.robot_pose.copy()
        self.rng = np.random.default_rng(self.seed)

    def state(self):
        return discrete_state(self.cube, self.robot_pose)

    def push(self, contact_point, direction, stroke_length):
        out = apply_push(self.cube, contact_point, direction, stroke_length, self.rng,
                         self.failures, self.physics)
        self.cube = out.cube
        return out

    def lift(self, left_grasp, right_grasp, lift_height):
        out = apply_lift(self.cube, left_grasp, right_grasp, lift_height, self.rng,
                         self.failures, self.physics)
        self.cube = out.cube
        return out

    def flip(self, left_grasp, right_grasp, roll_direction):
        out = apply_flip(self.cube, left_grasp, right_grasp, roll_direction, self.rng,
                         self.failures, self.physics)
        self.cube = out.cube
        return out

    def orbit(self, angle, radius):
        out = apply_orbit(self.robot_pose, self.cube, angle, radius, self.rng, self.failures)
        # Odometry integrates the commanded motion (in the base frame) from where it
        # believed the base was; the true pose took the noisy path.
        step = se2_between(self.robot_pose, out.odometry)
        self.odometry_pose = se2_compose(self.odometry_pose, step)
        self.robot_pose = out.pose
        return out

