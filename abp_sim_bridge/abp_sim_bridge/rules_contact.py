"""The rules world's hand-cube contacts from the hands' real motion: push strokes,
grasps, lifts, flips (plain NumPy, no rclpy).

`ContactTracker.update` is called once per simulation tick with the world positions of
the two hand-ball centres. It implements the contact rules of docs/INTERFACES.md ("The
cube and the manual actions") and hands every outcome to rules_physics
(`World.push`, `apply_lift`, `apply_flip`); it never looks at the ATG tables.

Rules (hands are balls of radius `hand_radius` at the hand-link origins):

- **Push.** The *front* face is the cube face whose outward normal points most towards the
  robot base. A hand stroke starts when the ball first touches the cube: on the front face
  (ball centre in front of the face, inside its outline) it becomes a push stroke;
  anywhere else (an edge, another face) it does nothing until the hand leaves the cube
  again (more than `leave_clearance` away). Once the ball has gone `push_engage` (2 cm)
  past the face plane, the motion since first touch must lie within
  `max_push_incidence` (30°) of the face's inward normal, else the hand glances off;
  then `World.push` decides with the hidden mass: the cube slides (and from then on
  slides with the hand, keeping the face against the ball until the stroke ends) or
  pivots ≈45° (the stroke is then spent), or the push misses (`p_missed_push`).
  One hand per push: each hand has its own stroke.
- **Grasp.** Both balls within `contact_tol` (1 cm) of the planes of two opposite side
  faces, each inside its face outline, at the same tick. The contact points are the
  balls' feet on those planes. A grasp whose two contact points both lie in the third of
  their faces closest to the robot is a *flip grasp*, any other a *lift grasp*.
  `p_slip_grasp` is drawn when the grasp forms: a slipping grasp never moves the cube.
- **Holding.** While grasped, the cube is *displayed* carried by the hands (translated
  with the midpoint of the two balls, never below its resting height; no rotation). Its
  physical outcome is resolved on release. The grasp is released when the hands open:
  their distance grows more than `release_opening` (1 cm) beyond the smallest distance
  seen during the grasp. After a release, a new grasp needs a hand to leave its face first.
- **On release.** A flip grasp whose hand midpoint moved up *and* towards the robot
  (each by at least `roll_min_component` = 2 cm, together by at least
  `roll_distance` = 5 cm) at some time during the grasp is a FLIP: `apply_flip` rolls the
  cube towards the robot as its mass dictates. Otherwise a grasp raised by at least
  `lift_height` (5 cm) is a LIFT: `apply_lift` turns the cube about the hand axis as its
  mass dictates (with the real grasp points and the real raise). Otherwise the grasp did
  nothing. The cube is put down where the hands released it (the carried horizontal
  offset is kept), except after a slipped grasp.

Each completed PUSH, LIFT or FLIP (including missed or slipped ones) is a `ContactEvent`
with `is_action` true; a grasp released without a lift or a roll gives an event with
`action` empty.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from abp_description.controllers import SIDES

from .rules_physics import (
    FACE_NORMALS,
    OPPOSITE_FACE,
    SLID,
    SLIPPED,
    Cube,
    World,
    apply_flip,
    apply_lift,
)
from .world_interface import ContactEvent

_Z = np.array([0.0, 0.0, 1.0])


@dataclass
class ContactParams:
    hand_radius: float = 0.03          # m, the hand ball (INTERFACES.md)
    contact_tol: float = 0.01          # m, a ball this close to a face plane touches it
    push_engage: float = 0.02          # m, stroke past the face plane before the cube moves
    max_push_incidence: float = np.radians(30)  # motion vs the face's inward normal
    leave_clearance: float = 0.01      # m, a hand this far from the cube ends its stroke
    release_opening: float = 0.01      # m, hands opening this much release a grasp
    lift_height: float = 0.05          # m, raise needed for a LIFT
    roll_distance: float = 0.05        # m, up-and-back motion needed for a FLIP
    roll_min_component: float = 0.02   # m, each of up and back at least this
    flip_zone: float = 1.0 / 3.0       # fraction of the face (robot side) for a flip grasp

    def __post_init__(self):
        for name in ('hand_radius', 'contact_tol', 'push_engage', 'leave_clearance',
                     'release_opening', 'lift_height', 'roll_distance'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0')
        if not 0 < self.flip_zone < 1:
            raise ValueError('flip_zone must be in (0, 1)')


@dataclass
class _Stroke:
    state: str = 'free'                  # free | front | slide | spent
    face: int = -1
    entry: np.ndarray | None = None      # ball centre at first touch
    direction: np.ndarray | None = None  # horizontal push direction while sliding


@dataclass
class Grasp:
    kind: str                      # 'lift' or 'flip'
    faces: tuple                   # (left face, right face), body faces
    points: dict                   # side -> contact point on the face plane (world)
    mid0: np.ndarray               # hands' midpoint when the grasp formed
    towards_robot: np.ndarray      # horizontal unit vector from the cube to the robot
    cube0: Cube                    # the cube when the grasp formed
    slipped: bool = False
    sep_min: float = np.inf
    max_raise: float = 0.0
    rolled: bool = False
    carry: np.ndarray = field(default_factory=lambda: np.zeros(3))


def box_relation(cube, point):
    """(distance from `point` to the cube's solid, face, inside): `face` is the body face
    whose open slab the point lies in front of (outside along exactly one body axis), else
    None (in front of an edge or corner, or inside)."""
    local = cube.rotation.T @ (np.asarray(point, dtype=float) - cube.position)
    outside = np.abs(local) - cube.half
    clamped = np.clip(local, -cube.half, cube.half)
    dist = float(np.linalg.norm(local - clamped))
    out_axes = np.flatnonzero(outside > 0)
    if len(out_axes) == 1:
        axis = int(out_axes[0])
        return dist, 2 * axis + (0 if local[axis] > 0 else 1), False
    return dist, None, len(out_axes) == 0


def front_face(cube, base_xy):
    """Body face whose outward normal points most towards the robot base."""
    u = towards_robot(cube, base_xy)
    return int(np.argmax((cube.rotation @ FACE_NORMALS.T).T @ u))


def towards_robot(cube, base_xy):
    d = np.array([base_xy[0] - cube.position[0], base_xy[1] - cube.position[1], 0.0])
    n = np.linalg.norm(d)
    if n < 1e-9:
        return np.array([1.0, 0.0, 0.0])
    return d / n


def _horizontal(v):
    v = np.array(v, dtype=float)
    v[2] = 0.0
    n = np.linalg.norm(v)
    return None if n < 1e-9 else v / n


class ContactTracker:
    """Detects pushes, grasps, lifts and flips from the hands' positions, tick by tick."""

    def __init__(self, params=None, sides=SIDES):
        """`sides`: the robot's hands (its profile's arms); a grasp needs exactly two."""
        self.params = params or ContactParams()
        self.sides = tuple(sides)
        self.reset()

    def reset(self):
        self.strokes = {s: _Stroke() for s in self.sides}
        self.grasp = None
        self._regrasp_blocked = False  # after a release, until a hand leaves its face

    # -- display ----------------------------------------------------------------------
    def display_cube(self, world):
        """The cube as it should be drawn: carried by the hands during a grasp."""
        g = self.grasp
        if g is None or g.slipped:
            return world.cube
        lift = np.array([g.carry[0], g.carry[1], max(0.0, g.carry[2])])
        return g.cube0.with_pose(g.cube0.position + lift, g.cube0.rotation)

    # -- the tick ---------------------------------------------------------------------
    def update(self, world: World, hands, base_pose):
        """Advance the contact state with the hand-ball centres `hands` ({side: (3,)},
        world frame) and the true base pose (x, y, yaw). Returns a list of ContactEvent."""
        hands = {s: np.asarray(hands[s], dtype=float) for s in self.sides}
        events = []
        if self.grasp is None and self._far(world.cube, hands):
            # Quick exit: neither hand anywhere near the cube (the common case).
            for s in self.sides:
                self.strokes[s] = _Stroke()
            self._regrasp_blocked = False
            return events
        if self.grasp is not None:
            event = self._update_grasp(world, hands)
            if event is not None:
                events.append(event)
            return events
        if self._try_grasp(world, hands, base_pose):
            return events
        for side in self.sides:
            event = self._update_stroke(world, side, hands[side], base_pose)
            if event is not None:
                events.append(event)
        return events

    def _far(self, cube, hands):
        reach = cube.half * np.sqrt(3) + self.params.hand_radius + self.params.leave_clearance \
            + self.params.contact_tol + 0.01
        c = cube.position
        return all((p[0] - c[0]) ** 2 + (p[1] - c[1]) ** 2 + (p[2] - c[2]) ** 2 > reach * reach
                   for p in hands.values())

    # -- pushes -------------------------------------------------------------------------
    def _update_stroke(self, world, side, p, base_pose):
        prm = self.params
        r = prm.hand_radius
        stroke = self.strokes[side]
        cube = world.cube
        dist, face, _ = box_relation(cube, p)
        if stroke.state != 'free' and dist > r + prm.leave_clearance:
            self.strokes[side] = _Stroke()
            return None
        if stroke.state == 'free':
            if dist <= r:
                if face is not None and face == front_face(cube, base_pose[:2]):
                    self.strokes[side] = _Stroke('front', face, p.copy())
                else:
                    self.strokes[side] = _Stroke('spent')
            return None
        if stroke.state == 'spent':
            return None
        n = cube.face_normal(stroke.face)
        gap = float((p - cube.face_centre(stroke.face)) @ n)
        depth = r - gap
        if stroke.state == 'front':
            if face != stroke.face:
                # The ball slid off the face outline (or went inside): no push.
                self.strokes[side] = _Stroke('spent')
                return None
            if depth < prm.push_engage:
                return None
            motion = p - stroke.entry
            dist_moved = np.linalg.norm(motion)
            cos_in = -(motion @ n) / dist_moved if dist_moved > 1e-9 else -1.0
            u = _horizontal(motion)
            if cos_in < np.cos(prm.max_push_incidence) or u is None:
                self.strokes[side] = _Stroke('spent')
                return ContactEvent('', 'glanced', f'{side} hand met the front face at '
                                    f'{np.degrees(np.arccos(np.clip(cos_in, -1, 1))):.0f}° '
                                    'from its normal: no push')
            foot = p - gap * n  # the ball's contact point on the face plane
            out = world.push(foot, u, depth)
            if out.effect == SLID:
                self.strokes[side] = _Stroke('slide', stroke.face, stroke.entry, u)
            else:
                self.strokes[side] = _Stroke('spent')
            return ContactEvent('PUSH', out.effect, f'{side} hand, stroke {100 * depth:.1f} cm')
        if stroke.state == 'slide':
            # The cube slides with the hand: keep the face against the ball.
            along = float(stroke.direction @ -n)
            if depth > 0 and face == stroke.face and along > 1e-3:
                world.cube = cube.with_pose(cube.position + stroke.direction * depth / along,
                                            cube.rotation)
        return None

    # -- grasps -------------------------------------------------------------------------
    def _side_face_contact(self, cube, p):
        """(face, foot) of a side face the ball touches within contact_tol, else None."""
        prm = self.params
        local = cube.rotation.T @ (p - cube.position)
        best = None
        for face, normal in enumerate(FACE_NORMALS):
            if abs(cube.face_normal(face)[2]) > 0.5:
                continue  # top / bottom: not a side face
            gap = float(local @ normal) - cube.half - prm.hand_radius
            if abs(gap) > prm.contact_tol:
                continue
            in_plane = local - (local @ normal) * normal
            if np.any(np.abs(in_plane) > cube.half):
                continue
            if best is None or abs(gap) < best[2]:
                foot_local = in_plane + cube.half * normal
                best = (face, cube.position + cube.rotation @ foot_local, abs(gap))
        return None if best is None else best[:2]

    def _try_grasp(self, world, hands, base_pose):
        if len(self.sides) != 2 or any(self.strokes[s].state in ('front', 'slide')
                                       for s in self.sides):
            return False
        cube = world.cube
        left, right = self.sides
        contacts = {s: self._side_face_contact(cube, hands[s]) for s in self.sides}
        if contacts[left] is None or contacts[right] is None:
            self._regrasp_blocked = False
            return False
        if self._regrasp_blocked:
            return False
        (fl, pl), (fr, pr) = contacts[left], contacts[right]
        if OPPOSITE_FACE[fl] != fr:
            return False
        u = towards_robot(cube, base_pose[:2])
        ahead = [float((pt - cube.position) @ u) for pt in (pl, pr)]
        zone = cube.half * (1 - 2 * self.params.flip_zone)  # near edge's third starts here
        kind = 'flip' if min(ahead) >= zone - 1e-9 else 'lift'
        slipped = bool(world.failures.p_slip_grasp > 0
                       and world.rng.random() < world.failures.p_slip_grasp)
        mid = (hands[left] + hands[right]) / 2
        self.grasp = Grasp(kind, (fl, fr), {left: pl, right: pr}, mid, u, cube,
                           slipped=slipped,
                           sep_min=float(np.linalg.norm(hands[right] - hands[left])))
        for s in self.sides:
            self.strokes[s] = _Stroke('spent')
        return True

    def _update_grasp(self, world, hands):
        prm = self.params
        g = self.grasp
        left, right = self.sides
        sep = float(np.linalg.norm(hands[right] - hands[left]))
        g.sep_min = min(g.sep_min, sep)
        mid = (hands[left] + hands[right]) / 2
        d = mid - g.mid0
        g.carry = d
        g.max_raise = max(g.max_raise, float(d[2]))
        up, back = float(d[2]), float(d @ g.towards_robot)
        if (up >= prm.roll_min_component and back >= prm.roll_min_component
                and np.hypot(up, back) >= prm.roll_distance):
            g.rolled = True
        if sep <= g.sep_min + prm.release_opening:
            return None
        return self._release(world, g)

    def _release(self, world, g):
        self.grasp = None
        self._regrasp_blocked = True
        prm = self.params
        pl, pr = (g.points[s] for s in self.sides)
        if g.kind == 'flip' and g.rolled:
            action = 'FLIP'
        elif g.max_raise >= prm.lift_height:
            action = 'LIFT'
        else:
            action = ''
        detail = (f'{g.kind} grasp, raised {100 * g.max_raise:.1f} cm'
                  + (', rolled towards the robot' if g.rolled else ''))
        if not action:
            effect = 'released'
            detail = 'grasp released without a lift or a roll; ' + detail
        elif g.slipped:
            effect = SLIPPED
        else:
            failures = replace(world.failures, p_slip_grasp=0.0)  # drawn when it formed
            if action == 'FLIP':
                out = apply_flip(g.cube0, pl, pr, g.towards_robot, world.rng, failures,
                                 world.physics)
            else:
                out = apply_lift(g.cube0, pl, pr, g.max_raise, world.rng, failures,
                                 world.physics)
            world.cube = out.cube
            effect = out.effect
        if not g.slipped:
            shift = np.array([g.carry[0], g.carry[1], 0.0])
            world.cube = world.cube.with_pose(world.cube.position + shift, world.cube.rotation)
        return ContactEvent(action, effect, detail)
