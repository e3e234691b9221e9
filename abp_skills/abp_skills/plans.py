"""The skills' motions as phases of joint trajectories, and their feasibility (no rclpy).

Everything is placed relative to the cube's estimated centre in `base_link` and the view
frame V of docs/MODEL.md (x_V horizontal from the cube towards the robot, z up, y_V on
the robot's right). The hands are balls: the contact ball of `hand_radius` (the sim
bridge's 0.03 m, docs/INTERFACES.md) touches a face when its centre is `hand_radius`
from the face plane.

- PUSH (one hand, `push_hand`): hover above the pre-contact point, go down in front of
  the front face, touch it (contact), push `push_stroke` along -x_V through the face
  centre (stroke), back off and go home (retreat).
- LIFT: both hands beside the ±y_V faces at their centres, close in (contact, squeezing
  `grasp_squeeze`), raise by `lift_height` and lower again (stroke), open and go home.
  The squeeze is the grip force of the position-servoed arms: the pads' torsional
  friction, proportional to it, is what keeps a cube gripped off its centre of mass
  (the estimate's error) from swinging about the hand axis.
- FLIP: as LIFT but the contacts are `flip_grasp_offset` towards the robot from the face
  centres (inside the third of the face nearest the robot), squeezing only `flip_squeeze`
  (at an odd yaw the hands meet the two front faces at 45°, and pads with a friction
  coefficient above 1 jam in that wedge; a light squeeze lets it slip rather than carry
  the cube through the roll; the roll itself needs little grip); the stroke rolls the hands up
  by `flip_up` and back towards the robot by `flip_back` along a quarter ellipse, then
  lowers them straight down and lets go: the cube is set down where the roll left it.
- ORBIT: `base_motion.plan_orbit` for the base; feasibility here (radius, clearance).

Free motions are joint-space Ruckig segments; contact, stroke and release moves are
straight (or elliptic) hand paths timed by a Ruckig path profile and mapped to joints by
IK at every sample. Every sample of every phase is checked for self-collision and floor
clearance (free motions also against the cube). A plan that fails says why.

Modules: ``plan_types`` (SkillConfig, CubeFrame, Phase, SkillPlan, PlanError, the action
names), ``arm_plans`` (``ArmPlanner``: postures, motion building blocks and the PUSH, LIFT
and FLIP plans) and here ``SkillPlanner``, the facade the nodes use (plan requests,
ORBIT, the base approach, feasibility), which re-exports the names it always had.
"""

from dataclasses import replace

import numpy as np

from abp_description.frames import se2_compose

from .arm_plans import ArmPlanner
from .base_motion import plan_orbit
from .plan_types import (
    ACTIONS,
    APPROACH_BEARING_TOLERANCE,
    MANUAL_SKILLS,
    ORBIT_ACTIONS,
    ORBIT_ANGLES_DEG,
    PHASES,
    YAW_STEP_DEG,
    CubeFrame,
    Phase,
    PlanError,
    SkillConfig,
    SkillPlan,
)

__all__ = ['ACTIONS', 'APPROACH_BEARING_TOLERANCE', 'CubeFrame', 'MANUAL_SKILLS', 'ORBIT_ACTIONS',
           'ORBIT_ANGLES_DEG', 'PHASES', 'Phase', 'PlanError', 'SkillConfig', 'SkillPlan',
           'SkillPlanner', 'YAW_STEP_DEG']


class SkillPlanner(ArmPlanner):
    """Builds the skills' plans from the current joints and the cube's estimate: the
    manual skills' arm plans (``arm_plans.ArmPlanner``), ORBIT, the base approach and the
    ATG actions' feasibility."""

    def with_config(self, **changes):
        return SkillPlanner(self.kin, replace(self.config, **changes))

    # -- the manual skills (ArmPlanner._plan_<skill>) ------------------------------------
    def lacks(self, skill):
        """The refusal of a skill the robot profile does not list."""
        return (f'the robot ({self.profile.name}) has no {skill.upper()} skill '
                '(not in its robot profile)')

    def plan(self, skill, q_current, cube_centre, **overrides):
        """SkillPlan for 'push', 'lift' or 'flip' from joints `q_current` (13) with the cube
        centre at `cube_centre` (base_link). Overrides: push_stroke, lift_height,
        flip_roll_deg (goal fields)."""
        if skill not in MANUAL_SKILLS:
            raise ValueError(f'unknown manual skill {skill!r}')
        if not self.profile.has_skill(skill):
            return SkillPlan(skill, False, self.lacks(skill))
        planner = self.with_config(**{k: v for k, v in overrides.items() if v})
        try:
            cube = planner.cube_frame(cube_centre)
            return getattr(planner, f'_plan_{skill}')(np.asarray(q_current, float), cube)
        except PlanError as error:
            return SkillPlan(skill, False, str(error))
        except ValueError as error:
            return SkillPlan(skill, False, str(error))

    # -- ORBIT --------------------------------------------------------------------------
    def orbit_radius(self, current_distance, requested=0.0):
        """The radius ORBIT drives at: `requested` if > 0, else the current distance,
        clamped into [orbit_min_radius, orbit_max_radius]."""
        cfg = self.config
        r = requested if requested and requested > 0 else current_distance
        return float(np.clip(r, cfg.orbit_min_radius, cfg.orbit_max_radius))

    def orbit_feasibility(self, angle_deg, cube_centre, requested_radius=0.0):
        """(ok, reason, radius) for ORBIT(angle_deg) with the cube at `cube_centre`."""
        cfg = self.config
        if not self.profile.has_skill('orbit'):
            return False, self.lacks('orbit'), 0.0
        if not any(abs(angle_deg - a) < 1e-6 for a in ORBIT_ANGLES_DEG):
            return False, (f'orbit angle {angle_deg:g} deg is not one of '
                           f'{", ".join(f"{a:g}" for a in ORBIT_ANGLES_DEG)}'), 0.0
        if requested_radius and not (cfg.orbit_min_radius <= requested_radius
                                     <= cfg.orbit_max_radius):
            return False, (f'orbit radius {requested_radius:.2f} m outside '
                           f'[{cfg.orbit_min_radius:.2f}, {cfg.orbit_max_radius:.2f}] m'), 0.0
        c = np.asarray(cube_centre, dtype=float)
        dist = float(np.hypot(c[0], c[1]))
        if dist > cfg.orbit_max_radius + 0.5:
            return False, (f'cube {dist:.2f} m away: too far to orbit (max radius '
                           f'{cfg.orbit_max_radius:.2f} m)'), 0.0
        return True, '', self.orbit_radius(dist, requested_radius)

    def orbit_plan(self, angle_deg, base_pose, cube_centre, requested_radius=0.0):
        """OrbitPlan in the odom frame from the base pose (x, y, yaw) and the cube centre
        in base_link."""
        ok, reason, radius = self.orbit_feasibility(angle_deg, cube_centre, requested_radius)
        if not ok:
            raise PlanError(reason)
        c = np.asarray(cube_centre, dtype=float)
        cube_xy = se2_compose(base_pose, (c[0], c[1], 0.0))[:2]
        return plan_orbit(base_pose, cube_xy, np.radians(angle_deg), radius, self.config.base)

    # -- the base approach of the manual skills ----------------------------------------
    def base_approach(self, cube_centre):
        """(needed, ok, reason, cube_after): whether a manual skill first drives the base
        (turn to face the cube, straight to `manipulation_distance`), whether it may, and
        the cube centre in base_link after it (nominal)."""
        cfg = self.config
        c = np.asarray(cube_centre, dtype=float).reshape(3)
        dist = float(np.hypot(c[0], c[1]))
        bearing = float(np.arctan2(c[1], c[0]))
        needed = cfg.base_approach and (abs(dist - cfg.manipulation_distance)
                                        > cfg.approach_tolerance
                                        or abs(bearing) > APPROACH_BEARING_TOLERANCE)
        if not needed:
            return False, True, '', c
        if abs(dist - cfg.manipulation_distance) > cfg.max_base_approach:
            return True, False, (
                f'cube {dist:.2f} m away: out of reach (the base approaches only within '
                f'{cfg.manipulation_distance:.2f} +- {cfg.max_base_approach:.2f} m)'), c
        return True, True, '', np.array([cfg.manipulation_distance, 0.0, c[2]])

    # -- feasibility of the ATG's actions ------------------------------------------------
    def feasibility(self, action, q_current, cube_centre):
        """(ok, reason) of an ACTIONS name at the cube estimate."""
        if action in ORBIT_ACTIONS:
            ok, reason, _ = self.orbit_feasibility(ORBIT_ACTIONS[action], cube_centre)
            return ok, reason
        if action in ('PUSH', 'LIFT', 'FLIP'):
            if not self.profile.has_skill(action.lower()):
                return False, self.lacks(action.lower())
            _, ok, reason, cube_after = self.base_approach(cube_centre)
            if not ok:
                return False, reason
            # The same plan on a coarser time grid (a skill that runs plans it again in full).
            coarse = self.with_config(check_stride=self.config.feasibility_check_stride,
                                      sample_dt=max(self.config.sample_dt, 0.1))
            plan = coarse.plan(action.lower(), q_current, cube_after)
            return plan.ok, plan.reason
        return False, f'unknown action {action!r} (expected one of {", ".join(ACTIONS)})'
