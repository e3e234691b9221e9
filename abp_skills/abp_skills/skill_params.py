"""The skill servers' parameters as one plain table (no rclpy), and the SkillConfig they build.

`skills_parameter_specs(feasibility, profile)` is what `skills_node` declares with
`abp_common.parameters.declare_all`: `robot_profile`, `feasibility_service` (read-only: a
change needs a restart), the node's own timing parameters (`NODE_SPECS`), every
`SkillConfig` field but `base` under its own name and every `BaseLimits` field as
`base_<field>` (`CONFIG_SPECS`). The robot profile gives the robot's defaults: base
command type and topic, ORBIT radii and base limits, the push hands. `config_from_values`
turns the values back into a checked SkillConfig.
"""

from dataclasses import fields, replace

from abp_common import base_command, names
from abp_common.param_spec import BOOL, DOUBLE, INT, STRING, ParamSpec
from abp_description.robot_profile import ORBIT_FIELDS, PROFILE_SPEC, load_profile

from .base_motion import BaseLimits
from .plans import SkillConfig

TRAJECTORY_INTERFACES = ('auto', 'action', 'topic')

NODE_SPECS = (
    *base_command.SPECS,
    ParamSpec('trajectory_interface', STRING, 'auto',
              'How arm, torso and head trajectories reach the controllers: action = '
              'control_msgs/FollowJointTrajectory on <controller>/follow_joint_trajectory '
              '(goal tolerances, aborts and results reach the skill); topic = '
              'trajectory_msgs/JointTrajectory on <controller>/joint_trajectory (arrival '
              'judged from /joint_states); auto = the action where the controller offers '
              'it, else the topic.', read_only=True, choices=TRAJECTORY_INTERFACES),
    ParamSpec('max_estimate_age', DOUBLE, 5.0,
              'Seconds after which a cube pose estimate is too old to act on.', (0.1, 3600.0)),
    ParamSpec('max_state_age', DOUBLE, 1.0,
              'Seconds after which /joint_states or /odom count as lost.', (0.05, 60.0)),
    ParamSpec('state_wait_timeout', DOUBLE, 3.0,
              'Wall-clock seconds a skill waits for robot state before it refuses or aborts: '
              'for the first /joint_states and /odom (discovery after start-up), and, during '
              'a base motion (standing still), for /odom to be recent again.', (0.0, 60.0)),
    ParamSpec('timeout', DOUBLE, 120.0,
              'Seconds a skill may run before it stops and aborts.', (1.0, 3600.0)),
    ParamSpec('control_rate', DOUBLE, 20.0,
              'Hz of the base control loop and of progress checks.', (1.0, 200.0)),
    ParamSpec('goal_tolerance', DOUBLE, 0.05,
              'rad: joints within this of a phase end count as arrived.', (0.001, 1.0)),
    ParamSpec('contact_goal_tolerance', DOUBLE, 0.35,
              "rad: the same for a phase that presses the hands into the cube (LIFT's "
              'grasp and stroke): the faces stop the arms short of their commanded path, '
              'the more so the further the cube is from where the plan put it.',
              (0.001, 1.5)),
    ParamSpec('settle_timeout', DOUBLE, 2.0,
              'Seconds to wait for the joints (or the base) to arrive after a phase.',
              (0.0, 60.0)),
    ParamSpec('claim_settle_time', DOUBLE, 0.2,
              'Seconds a new goal waits to detect a simultaneous goal in another skills '
              'process.', (0.0, 5.0)),
    ParamSpec('trajectory_start_delay', DOUBLE, 0.25,
              "Wall-clock seconds ahead of now of the controllers' common header.stamp "
              "(in clock time at the clock's measured rate: a simulator's speed-up); a "
              'trajectory that arrives after its stamp starts part-way along its path. '
              '0 = zero stamp (start on receipt).', (0.0, 5.0)),
    ParamSpec('orbit_radius', DOUBLE, 0.0,
              'Default ORBIT radius (m) when the goal gives none; 0 = keep the current '
              'distance (clamped to orbit_min_radius..orbit_max_radius).', (0.0, 5.0)),
    ParamSpec('orbit_yaw_tolerance_deg', DOUBLE, 2.0,
              'ORBIT ends when bearing and heading are within this.', (0.1, 45.0)),
    ParamSpec('orbit_position_tolerance', DOUBLE, 0.02,
              'm, radius tolerance at the end of ORBIT.', (0.001, 0.5)),
)

# Descriptions of the SkillConfig fields exposed as parameters.
CONFIG_DESCRIPTIONS = {
    'cube_size': 'm, ARcube edge.',
    'support_height': 'm, height of the surface the cube rests on, in the base frame.',
    'use_estimated_height': 'Take the cube centre height from the estimate (else '
                            'support_height + cube_size / 2).',
    'hand_radius': "m, radius of the hands' contact balls (sim bridge: 0.03).",
    'grasp_squeeze': "m, how far LIFT's grasp presses into the faces (sets the grip force).",
    'flip_squeeze': "m, how far FLIP's grasp presses into the faces.",
    'approach_gap': 'm, free space between hand and face before contact and after release.',
    'hover_height': 'm, via point above the pre-contact posture.',
    'push_hand': "Hand that pushes: one of the robot profile's push arms.",
    'push_stroke': 'm, hand travel beyond first contact (the sim slides the cube after 2 cm).',
    'lift_height': 'm, default lift height.',
    'flip_grasp_offset': 'm, FLIP contacts this far from the face centres towards the robot.',
    'flip_up': 'm, FLIP roll: hands up.',
    'flip_back': 'm, FLIP roll: hands back towards the robot.',
    'flip_roll_deg': "Default FLIP roll angle (shape of the hands' roll path).",
    'joint_velocity_scale': 'Fraction of the URDF velocity limits used by trajectories.',
    'joint_acceleration': 'rad/s^2, joint acceleration limit.',
    'joint_jerk': 'rad/s^3, joint jerk limit.',
    'cartesian_velocity': 'm/s, hand speed on contact, stroke and release paths.',
    'cartesian_acceleration': 'm/s^2 on hand paths.',
    'cartesian_jerk': 'm/s^3 on hand paths.',
    'sample_dt': 's between trajectory points.',
    'ik_tolerance': 'm, IK position tolerance.',
    'collision_margin': 'm, clearance required between arm parts and the body.',
    'check_stride': 'Collision-check every n-th trajectory sample of a skill to run.',
    'feasibility_check_stride': 'The same for /abp/skills/check_feasibility answers.',
    'base_approach': 'PUSH/LIFT/FLIP first drive the base to manipulation_distance.',
    'manipulation_distance': 'm, cube centre distance for PUSH/LIFT/FLIP.',
    'max_base_approach': 'm, the furthest the base approach may drive.',
    'approach_tolerance': 'm, no base approach when the cube is this close to '
                          'manipulation_distance (and within 5 deg of straight ahead).',
    'orbit_min_radius': 'm, smallest ORBIT radius (turning in place clears the cube).',
    'orbit_max_radius': 'm, largest ORBIT radius.',
}
BASE_UNITS = {
    'linear_velocity': 'm/s', 'linear_acceleration': 'm/s^2', 'linear_jerk': 'm/s^3',
    'angular_velocity': 'rad/s', 'angular_acceleration': 'rad/s^2', 'angular_jerk': 'rad/s^3',
}
# Loose outer bounds of the SkillConfig doubles (SkillConfig.validate checks the rest).
CONFIG_RANGE = (0.0, 1000.0)
SUPPORT_HEIGHT_RANGE = (-1.0, 10.0)
BASE_RANGE = (0.0, 100.0)
_CONFIG_FIELDS = tuple(f.name for f in fields(SkillConfig) if f.name != 'base')
_BASE_FIELDS = tuple(f.name for f in fields(BaseLimits))


def _config_spec(name, default):
    description = CONFIG_DESCRIPTIONS.get(name, name)
    if isinstance(default, bool):
        return ParamSpec(name, BOOL, default, description)
    if isinstance(default, int):
        return ParamSpec(name, INT, default, description)
    if isinstance(default, str):
        return ParamSpec(name, STRING, default, description)
    bounds = SUPPORT_HEIGHT_RANGE if name == 'support_height' else CONFIG_RANGE
    return ParamSpec(name, DOUBLE, float(default), description, bounds)


def _config_specs():
    defaults = SkillConfig()
    specs = [_config_spec(name, getattr(defaults, name)) for name in _CONFIG_FIELDS]
    specs += [ParamSpec(f'base_{name}', DOUBLE, float(getattr(defaults.base, name)),
                        f'Base {name.replace("_", " ")} limit, {BASE_UNITS[name]}.', BASE_RANGE)
              for name in _BASE_FIELDS]
    return tuple(specs)


CONFIG_SPECS = _config_specs()


def _profile_defaults(profile):
    """{parameter: default} that the robot profile sets."""
    orbit, push = profile.base.orbit, profile.skill_arms('push')
    out = {'base_command_type': profile.base.command_type,   # as with_profile_defaults
           'base_command_topic': profile.base.command_topic,
           'orbit_min_radius': orbit.min_radius, 'orbit_max_radius': orbit.max_radius,
           **{f'base_{name}': getattr(orbit, name) for name in ORBIT_FIELDS}}
    if push:
        out['push_hand'] = push[0]
    return out


def skills_parameter_specs(feasibility=True, profile=None):
    """Every parameter of a skills node; `feasibility`: the default of feasibility_service;
    `profile` (a RobotProfile, default: the uBot-6's) the robot's defaults and push hands."""
    profile = profile if profile is not None else load_profile()
    host = ParamSpec('feasibility_service', BOOL, bool(feasibility),
                     f'Host /{names.CHECK_FEASIBILITY} in this process.', read_only=True)
    robot = _profile_defaults(profile)
    push_hands = profile.skill_arms('push')

    def for_robot(spec):
        if spec.name == 'push_hand':
            spec = replace(spec, choices=push_hands or (spec.default,))
        return replace(spec, default=robot[spec.name]) if spec.name in robot else spec

    return (PROFILE_SPEC, host, *(for_robot(s) for s in (*NODE_SPECS, *CONFIG_SPECS)))


def config_from_values(values, profile=None):
    """The validated SkillConfig of parameter values ({name: value}, CONFIG_SPECS names)
    for the robot of `profile` (default: the uBot-6's); raises ValueError naming the
    parameter that is wrong."""
    push_hands = (profile if profile is not None else load_profile()).skill_arms('push')
    if push_hands and values['push_hand'] not in push_hands:
        raise ValueError(f'push_hand must be one of {", ".join(push_hands)} (the robot '
                         f"profile's push arms), got {values['push_hand']!r}")
    for name in _BASE_FIELDS:
        if not values[f'base_{name}'] > 0:
            raise ValueError(f'base_{name} must be > 0')
    base = BaseLimits(**{name: float(values[f'base_{name}']) for name in _BASE_FIELDS})
    return SkillConfig(**{name: values[name] for name in _CONFIG_FIELDS}, base=base).validate()


__all__ = ['CONFIG_SPECS', 'NODE_SPECS', 'config_from_values', 'skills_parameter_specs']
