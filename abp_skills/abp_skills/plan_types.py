"""What the skills' plans are made of and the parameters they are built from (no rclpy):
``SkillConfig`` (geometry and motion parameters), ``CubeFrame`` (the cube centre and its view
frame V in base_link), ``Phase`` / ``SkillPlan`` (a plan's joint trajectories) and
``PlanError``; the ATG's action names and ORBIT angles. ``plans`` documents the motions.
"""

from dataclasses import dataclass, field

import numpy as np

from abp_belief.cube import ACTIONS, ORBIT_STEPS

from .base_motion import BaseLimits
from .collision import Box
from .motion_profiles import SampledTrajectory

MANUAL_SKILLS = ('push', 'lift', 'flip')
# The ATG's actions (ACTIONS, in the planner's and the belief's order) and the ORBIT
# angles: ORBIT(θ) turns the cube's relative yaw by θ = 45° x the belief's ORBIT_STEPS,
# so the angle the base drives is the yaw change the belief predicts.
YAW_STEP_DEG = 45.0
ORBIT_ACTIONS = {name: YAW_STEP_DEG * steps for name, steps in ORBIT_STEPS.items()}
# An Orbit goal may also ask for -180 deg: the same view change, driven the other way round.
ORBIT_ANGLES_DEG = (*ORBIT_ACTIONS.values(), -180.0)
PHASES = ('approach', 'contact', 'stroke', 'retreat')

# A cube off straight ahead by more than this makes a manual skill turn the base first.
APPROACH_BEARING_TOLERANCE = np.radians(5.0)


@dataclass
class SkillConfig:
    """Geometry and motion parameters of the skills (the node's ROS parameters)."""

    cube_size: float = 0.10            # m, ARcube edge
    support_height: float = 0.0        # m, height of the surface under the cube in base_link
    use_estimated_height: bool = False  # True: take the cube's z from the estimate
    hand_radius: float = 0.03          # m, contact ball of a hand
    # How far the grasps press into the faces: the position-servoed arms' grip force.
    # (The URDF's pads are 0.035 m balls, so they are commanded 5 mm further in still.)
    grasp_squeeze: float = 0.015       # m, LIFT
    flip_squeeze: float = 0.0          # m, FLIP: a light grip (see the module doc)
    approach_gap: float = 0.05         # m, free space between a hand and a face before contact
    hover_height: float = 0.08         # m, via point above the pre-contact posture
    push_hand: str = 'right'          # an arm of the robot profile's push skill
    push_stroke: float = 0.05          # m, hand travel beyond first contact
    lift_height: float = 0.08          # m
    flip_grasp_offset: float = 0.03    # m, contacts this far from the face centres to the robot
    flip_up: float = 0.07              # m
    flip_back: float = 0.06            # m
    flip_roll_deg: float = 90.0
    joint_velocity_scale: float = 0.5  # fraction of the URDF velocity limits
    joint_acceleration: float = 2.0    # rad/s^2
    joint_jerk: float = 10.0           # rad/s^3
    cartesian_velocity: float = 0.08   # m/s, hand speed on contact/stroke paths
    cartesian_acceleration: float = 0.3
    cartesian_jerk: float = 2.0
    sample_dt: float = 0.05            # s between trajectory points
    ik_tolerance: float = 0.002        # m
    collision_margin: float = 0.01     # m
    check_stride: int = 2              # collision-check every n-th trajectory sample
    feasibility_check_stride: int = 2  # the same for feasibility answers, on a 0.1 s grid
    base_approach: bool = True         # manual skills first drive to manipulation_distance
    # m, cube centre from base_link for PUSH/LIFT/FLIP. The middle of the distances where
    # all three plans clear the body (0.41-0.51 m within 5 deg of straight ahead; closer,
    # an upper arm passes the chassis within collision_margin), so that the approach's
    # landing error (OrbitTracker's 2 cm) and approach_tolerance stay inside it.
    manipulation_distance: float = 0.45
    max_base_approach: float = 0.35    # m, the furthest a manual skill drives to get there
    approach_tolerance: float = 0.03   # m; and bearing 5 deg: closer needs no base motion
    orbit_min_radius: float = 0.30     # m (turning in place must clear the cube)
    orbit_max_radius: float = 1.00
    base: BaseLimits = field(default_factory=BaseLimits)

    def validate(self):
        positive = ('cube_size', 'hand_radius', 'approach_gap', 'push_stroke', 'lift_height',
                    'flip_up', 'flip_back', 'flip_roll_deg', 'joint_velocity_scale',
                    'joint_acceleration', 'joint_jerk', 'cartesian_velocity',
                    'cartesian_acceleration', 'cartesian_jerk', 'sample_dt', 'ik_tolerance',
                    'orbit_min_radius', 'orbit_max_radius', 'manipulation_distance',
                    'approach_tolerance')
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if int(self.check_stride) < 1 or int(self.feasibility_check_stride) < 1:
            raise ValueError('check_stride and feasibility_check_stride must be >= 1')
        if not isinstance(self.push_hand, str) or not self.push_hand:
            raise ValueError(f'push_hand must name an arm, got {self.push_hand!r}')
        for name in ('grasp_squeeze', 'flip_squeeze'):
            if not 0 <= getattr(self, name) < self.hand_radius:
                raise ValueError(f'{name} must be in [0, hand_radius)')
        if not 0 <= self.flip_grasp_offset < self.cube_size / 2:
            raise ValueError('flip_grasp_offset must be in [0, cube_size / 2)')
        if self.joint_velocity_scale > 1:
            raise ValueError('joint_velocity_scale must be <= 1')
        if self.max_base_approach < 0:
            raise ValueError('max_base_approach must be >= 0')
        if self.orbit_min_radius >= self.orbit_max_radius:
            raise ValueError('orbit_min_radius must be < orbit_max_radius')
        return self


@dataclass
class CubeFrame:
    """The cube centre and its view frame V in base_link."""

    centre: np.ndarray
    x: np.ndarray        # horizontal, from the cube towards the robot (front-face normal)
    y: np.ndarray        # z × x: on the robot's right
    size: float

    @classmethod
    def from_centre(cls, centre, size):
        c = np.asarray(centre, dtype=float).reshape(3)
        x = np.array([-c[0], -c[1], 0.0])
        n = np.linalg.norm(x)
        if n < 1e-6:
            raise ValueError('the cube centre is above the base origin')
        x /= n
        y = np.cross([0.0, 0.0, 1.0], x)
        return cls(c, x, y, float(size))

    @property
    def half(self):
        return self.size / 2

    @property
    def distance(self):
        return float(np.hypot(self.centre[0], self.centre[1]))

    def point(self, vx, vy, vz):
        """A point given in V coordinates (origin at the cube centre), in base_link."""
        return self.centre + vx * self.x + vy * self.y + np.array([0.0, 0.0, vz])

    def box(self, grow=0.0, squeeze_y=0.0):
        """The cube as a Box, grown by `grow` and narrowed by `squeeze_y` along y_V."""
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2] = self.x, self.y, (0.0, 0.0, 1.0)
        pose[:3, 3] = self.centre
        half = np.full(3, self.half + grow)
        half[1] -= squeeze_y
        return Box('cube', pose, half)


@dataclass
class Phase:
    name: str
    trajectory: SampledTrajectory   # over BODY_JOINTS
    # The hands press into the cube (a squeeze > 0): the faces stop the arms short of the
    # commanded path, so the joints do not arrive at its end (contact_goal_tolerance).
    pressing: bool = False

    @property
    def duration(self):
        return self.trajectory.duration


@dataclass
class SkillPlan:
    skill: str
    ok: bool
    reason: str = ''
    phases: list = field(default_factory=list)
    targets: dict = field(default_factory=dict)   # named hand targets, for inspection

    @property
    def duration(self):
        return float(sum(p.duration for p in self.phases))


class PlanError(RuntimeError):
    pass


__all__ = ['ACTIONS', 'APPROACH_BEARING_TOLERANCE', 'CubeFrame', 'MANUAL_SKILLS', 'ORBIT_ACTIONS',
           'ORBIT_ANGLES_DEG', 'PHASES', 'Phase', 'PlanError', 'SkillConfig', 'SkillPlan',
           'YAW_STEP_DEG']
