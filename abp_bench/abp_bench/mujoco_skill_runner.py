"""Run the skills' real plans (abp_skills.plans, abp_skills.base_motion) on a MujocoWorld
without DDS: their joint trajectories go straight to the world's controllers, and ORBIT's
base plan is tracked on the world's odometry by the skills' own `OrbitTracker` at the skill
node's control rate, its commands going straight to the world's /cmd_vel input.

Used by `outcome_survey` and by the skill-driven tests of the MuJoCo world
(abp_bench/test/test_mujoco_skills.py)."""

import numpy as np

from abp_belief.cube import R_UP
from abp_description.frames import rot_z
from abp_description.kinematics import look_at_world
from abp_sim_bridge.joint_trajectory_follower import TrajectoryPoint
from abp_sim_bridge.mujoco_scene import CubeSpec
from abp_sim_bridge.mujoco_world import MujocoSettings, MujocoWorld

FACE_TAGS = (0, 1, 2, 3, 4, 5)
# Body face the mass lies towards, by its direction in the view frame V when the cube
# stands as spawned here (state 36: body +x away from the robot, so V = -body x).
HEAVY_FACE_BY_V = {'none': None, '+x_V': 1, '-x_V': 0, '+y_V': 3, '-y_V': 2, '+z_V': 4,
                   '-z_V': 5}
# The skill node's defaults (abp_skills.skill_params) used here.
CONTROL_RATE = 20.0          # Hz, base control loop
ORBIT_YAW_TOLERANCE = np.radians(2.0)
ORBIT_POSITION_TOLERANCE = 0.02
SETTLE_TIMEOUT = 2.0


def make_world(kin, heavy_face=None, cube_x=0.40, cube_yaw=0.0, up_face=4, q0=None,
               cube_y=0.0, **changes):
    """World with the robot at the origin looking at a cube at (cube_x, cube_y) standing on
    body face `up_face` (MODEL.md's R_UP) turned by `cube_yaw` (rad, world z).
    `q0`: initial joints (default: neutral, head on the cube); `changes`: MujocoSettings."""
    cube = CubeSpec(position=(cube_x, cube_y, 0.05),
                    rotation=rot_z(cube_yaw) @ R_UP[up_face], heavy_face=heavy_face)
    if q0 is None:
        q0, _ = look_at_world(kin, kin.neutral(), (0.0, 0.0, 0.0), cube.position)
    settings = MujocoSettings(initial_positions=tuple(q0), **changes)
    return MujocoWorld(cube, FACE_TAGS, settings, kin)


def cube_in_base(world):
    """The cube's true centre in base_link."""
    x, y, yaw = world.robot_pose()
    c, s = np.cos(yaw), np.sin(yaw)
    rel = world.cube_pose()[:3, 3] - np.array([x, y, 0.0])
    return np.array([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2]])


def send_trajectories(world, trajectories, start_delay=0.05):
    """Send SampledTrajectory pieces (over the same joints) back to back as one trajectory
    per controller, stamped together; returns the time until their end (s)."""
    times, pos, vel, offset = [], [], [], 0.0
    for traj in trajectories:
        times.append(traj.times[1:] + offset if times else traj.times + offset)
        pos.append(traj.positions[1:] if len(times) > 1 else traj.positions)
        vel.append(traj.velocities[1:] if len(times) > 1 else traj.velocities)
        offset += traj.duration
    times, pos, vel = np.concatenate(times), np.vstack(pos), np.vstack(vel)
    names = list(trajectories[0].joint_names)
    stamp = world.time + start_delay
    for controller, joints in world.kin.profile.controller_joints.items():
        if not all(j in names for j in joints):
            continue
        cols = [names.index(j) for j in joints]
        points = [TrajectoryPoint(t + 1e-3, p[cols], v[cols]) for t, p, v in
                  zip(times, pos, vel)]
        world.set_trajectory(controller, list(joints), points, stamp)
    return start_delay + offset


def send_plan(world, plan, start_delay=0.05):
    """Send all phases of a SkillPlan as one trajectory per controller, stamped together."""
    assert plan.ok, plan.reason
    return send_trajectories(world, [p.trajectory for p in plan.phases], start_delay)


def run_for(world, seconds):
    for _ in range(int(np.ceil(seconds / world.dt))):
        world.step()


def run_plan(world, plan, settle=1.5):
    """Run a SkillPlan to its end and let the cube settle; returns the events of the run."""
    duration = send_plan(world, plan)
    first = len(world.events)
    run_for(world, duration + settle)
    return [e for _, e in world.events[first:]]


def run_skill(world, planner, skill, settle=1.5, **overrides):
    """Plan `skill` at the world's true cube centre (base_link), run it to the end and let
    the cube settle; returns the events of the run."""
    plan = planner.plan(skill, world.q, cube_in_base(world), **overrides)
    return run_plan(world, plan, settle)


def run_orbit(world, planner, angle_deg, radius=0.0, settle=0.5):
    """ORBIT(angle_deg) as the skill server runs it: arms home first (`go_home`), then the
    base plan (`orbit_plan`, at the cube's true centre) tracked closed-loop on the world's
    odometry by `OrbitTracker` at CONTROL_RATE. The head is not re-aimed while driving
    (it does not touch anything). Returns (ok, reason, events)."""
    from abp_skills.base_motion import OrbitTracker

    first = len(world.events)
    centre = cube_in_base(world)
    home = planner.go_home(world.q, look=centre)
    if home is not None:
        run_for(world, send_trajectories(world, [home]) + 0.2)
    odom = world.base_in_odom()
    plan = planner.orbit_plan(angle_deg, odom, cube_in_base(world), radius)
    tracker = OrbitTracker(plan, planner.config.base, yaw_tolerance=ORBIT_YAW_TOLERANCE,
                           position_tolerance=ORBIT_POSITION_TOLERANCE,
                           settle_time=max(SETTLE_TIMEOUT, 0.5))
    ticks = max(1, int(round(1.0 / (CONTROL_RATE * world.dt))))
    t0 = world.time
    ok, reason = False, ''
    while True:
        v, w, _, done, ok = tracker.command(world.time - t0, world.base_in_odom())
        if done:
            world.set_cmd_vel(0.0, 0.0)
            if not ok:
                b, h, r = tracker.final_errors(world.base_in_odom())
                reason = (f'the base did not settle: bearing {np.degrees(b):.1f} deg, '
                          f'heading {np.degrees(h):.1f} deg, radius {100 * r:.1f} cm off')
            break
        world.set_cmd_vel(v, w)
        for _ in range(ticks):
            world.step()
    run_for(world, settle)   # the base stops (and odometry noise, if any, applies)
    return ok, reason, [e for _, e in world.events[first:]]
