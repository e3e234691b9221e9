"""The rules world's physics against MODEL.md's rules, written out independently here.

Contacts are computed geometrically from the cube's faces as the robot sees them (V frame):
PUSH at the front face centre along -x_V, LIFT/FLIP grasps at the centres of the +-y_V
faces, FLIP rolling towards the robot (+x_V).
"""

import itertools

import numpy as np
import pytest
from sim_hand_paths import FACE_NORMALS as NORMALS
from sim_hand_paths import rx, ry

from abp_description.frames import rot_z_deg
from abp_sim_bridge import rules_physics as W
from abp_sim_bridge.rules_physics import (
    BLOCKED,
    MISSED,
    PIVOTED,
    ROTATED,
    SLID,
    SLIPPED,
    UNCHANGED,
    Cube,
    Failures,
    World,
    apply_flip,
    apply_lift,
    apply_orbit,
    apply_push,
    discrete_state,
    facing_pose,
    relative_rotation,
)

EDGE = 0.10
H = EDGE / 2


# The 24 cube rotations (every up face x 4 yaws), built independently of rules_physics.py.
ORIENTATIONS = []
for up_rot in (np.eye(3), rx(90), rx(180), rx(-90), ry(90), ry(-90)):
    for k in range(4):
        ORIENTATIONS.append(rot_z_deg(90 * k) @ up_rot)


# --- MODEL.md's expected rotation Q in V (R' = Q R), per action and mass direction d ----------

def close(d, v):
    return d is not None and np.allclose(d, v, atol=1e-6)


def expected_push(d):
    if close(d, [0, 1, 0]):
        return rot_z_deg(-45)
    if close(d, [0, -1, 0]):
        return rot_z_deg(45)
    return np.eye(3)


def expected_lift(d):
    if close(d, [0, 0, 1]):
        return ry(180)
    if close(d, [1, 0, 0]):
        return ry(90)
    if close(d, [-1, 0, 0]):
        return ry(-90)
    return np.eye(3)


def expected_flip(d):
    if d is None:
        return ry(-90)
    for v, q in (([1, 0, 0], ry(90)), ([-1, 0, 0], ry(-90)), ([0, 0, 1], ry(180)),
                 ([0, 0, -1], np.eye(3)), ([0, 1, 0], rx(-90)), ([0, -1, 0], rx(90))):
        if close(d, v):
            return q
    raise AssertionError(d)


# --- a scene: cube somewhere in the world, robot at a bearing facing it -----------------------

CUBE_XY = np.array([1.2, -0.7])
BEARING = np.radians(35.0)   # world direction from the cube to the robot
RADIUS = 0.35


def scene(rel_rotation, heavy_face, rel_yaw_deg=0.0):
    """Cube whose orientation in V is rot_z_deg(rel_yaw) @ rel_rotation, robot at BEARING."""
    v_to_world = rot_z_deg(np.degrees(BEARING))
    cube = Cube.on_floor(*CUBE_XY, v_to_world @ rot_z_deg(rel_yaw_deg) @ rel_rotation, heavy_face)
    robot = facing_pose(cube.position, BEARING, RADIUS)
    return cube, robot, v_to_world


def v_axes(v_to_world):
    return v_to_world[:, 0], v_to_world[:, 1]


def mass_dir_v(cube, robot):
    if cube.heavy_face is None:
        return None
    return relative_rotation(cube, robot) @ NORMALS[cube.heavy_face]


def assert_rotation(cube_after, v_to_world, expected_rel):
    """Orientation in the V frame of the start (a pivot moves the centre, hence V, a bit)."""
    np.testing.assert_allclose(v_to_world.T @ cube_after.rotation, expected_rel, atol=1e-6)
    assert cube_after.position[2] == pytest.approx(H)


def push_nominal(cube, v_to_world, stroke=0.06):
    x_v, _ = v_axes(v_to_world)
    start = cube.position + (H + 0.02) * x_v  # hand 2 cm in front of the front face
    return apply_push(cube, start, -x_v, stroke)


def grasp_points(cube, v_to_world):
    _, y_v = v_axes(v_to_world)
    return cube.position - H * y_v, cube.position + H * y_v  # left hand on -y_V (robot's left)


CASES = [(r, m) for r in range(24) for m in [None, 0, 1, 2, 3, 4, 5]]


@pytest.mark.parametrize('orientation, heavy', CASES)
def test_manual_actions_match_model_at_even_yaw(orientation, heavy):
    for rel_yaw in (0, 90):  # even yaws; 90 is covered by ORIENTATIONS too, but with the robot
        cube, robot, v2w = scene(ORIENTATIONS[orientation], heavy, rel_yaw)
        rel = relative_rotation(cube, robot)
        d = mass_dir_v(cube, robot)
        up0, yaw0 = discrete_state(cube, robot)
        assert yaw0 % 2 == 0

        out = push_nominal(cube, v2w)
        assert out.effect == (PIVOTED if close(d, [0, 1, 0]) or close(d, [0, -1, 0]) else SLID)
        assert_rotation(out.cube, v2w, expected_push(d) @ rel)
        if out.effect == PIVOTED:
            up1, yaw1 = discrete_state(out.cube, robot)
            assert up1 == up0 and yaw1 == (yaw0 + (-1 if close(d, [0, 1, 0]) else 1)) % 8

        left, right = grasp_points(cube, v2w)
        out = apply_lift(cube, left, right, lift_height=0.08)
        assert_rotation(out.cube, v2w, expected_lift(d) @ rel)
        assert out.effect == (UNCHANGED if np.allclose(expected_lift(d), np.eye(3)) else ROTATED)
        np.testing.assert_allclose(out.cube.position[:2], cube.position[:2], atol=1e-9)

        x_v, _ = v_axes(v2w)
        out = apply_flip(cube, left, right, roll_direction_world=x_v)
        assert_rotation(out.cube, v2w, expected_flip(d) @ rel)


@pytest.mark.parametrize('heavy', [None, 0, 1, 2, 3, 4, 5])
def test_manual_actions_at_odd_yaw_change_nothing(heavy):
    for orientation in (0, 5, 13, 22):
        for rel_yaw in (45, -45, 135):
            cube, robot, v2w = scene(ORIENTATIONS[orientation], heavy, rel_yaw)
            assert discrete_state(cube, robot)[1] % 2 == 1
            assert push_nominal(cube, v2w).effect == MISSED
            left, right = grasp_points(cube, v2w)
            assert apply_lift(cube, left, right, 0.08).effect == SLIPPED
            x_v, _ = v_axes(v2w)
            assert apply_flip(cube, left, right, x_v).effect == SLIPPED


def test_cross_check_with_abp_belief_tables_if_available():
    cube_mod = pytest.importorskip('abp_belief.cube')
    np.testing.assert_allclose(W.R_UP, cube_mod.R_UP)
    for state in range(48):
        rot = cube_mod.state_rotation(state)
        for mass in range(7):
            cube, robot, v2w = scene(rot, None if mass == 0 else mass - 1)
            assert discrete_state(cube, robot) == (state // 8, state % 8)
            left, right = grasp_points(cube, v2w)
            x_v, _ = v_axes(v2w)
            results = {
                'PUSH': push_nominal(cube, v2w).cube,
                'LIFT': apply_lift(cube, left, right, 0.08).cube,
                'FLIP': apply_flip(cube, left, right, x_v).cube,
            }
            for action, after in results.items():
                q = cube_mod.nominal_rotation(action, mass, state)
                expected = cube_mod.apply_rotation(q, state)
                up, yaw = discrete_state(after, robot)
                assert 8 * up + yaw == expected, (action, mass, state)


# --- PUSH details ----------------------------------------------------------------------------

def test_push_slide_moves_by_the_stroke_after_contact():
    cube, robot, v2w = scene(np.eye(3), None)
    x_v, _ = v_axes(v2w)
    out = apply_push(cube, cube.position + (H + 0.02) * x_v, -x_v, 0.07)
    assert out.effect == SLID
    np.testing.assert_allclose(out.cube.position, cube.position - 0.05 * x_v, atol=1e-9)
    np.testing.assert_allclose(out.cube.rotation, cube.rotation)


def test_push_that_misses_the_face_does_nothing():
    cube, robot, v2w = scene(np.eye(3), 2)
    x_v, y_v = v_axes(v2w)
    start = cube.position + (H + 0.02) * x_v
    for miss in (start + 0.07 * y_v, start - 0.07 * y_v, start + np.array([0, 0, 0.07])):
        out = apply_push(cube, miss, -x_v, 0.08)
        assert out.effect == MISSED and out.cube is cube
    assert apply_push(cube, start, -x_v, 0.015).effect == MISSED  # stroke stops short
    assert apply_push(cube, start, -x_v, 0.025).effect == UNCHANGED  # touches, barely moves
    assert apply_push(cube, start, x_v, 0.08).effect == MISSED  # pushing away from it


def test_off_centre_push_pivots_a_uniform_cube_the_physical_way():
    # The centre of friction is under the centre of mass: pushing the right half of the
    # front face (robot's right, +y_V) turns the cube towards the left (+45° about z).
    cube, robot, v2w = scene(np.eye(3), None)
    x_v, y_v = v_axes(v2w)
    start = cube.position + (H + 0.02) * x_v + 0.03 * y_v
    out = apply_push(cube, start, -x_v, 0.06)
    assert out.effect == PIVOTED
    assert discrete_state(out.cube, robot) == (4, 1)


def test_push_of_heavy_side_pivots_about_the_dragging_side():
    cube, robot, v2w = scene(np.eye(3), 2)  # body +y = +y_V heavy
    out = push_nominal(cube, v2w)
    _, y_v = v_axes(v2w)
    heavy_side_before = cube.position + H * y_v
    # the middle of the heavy side stays put; the centre moves
    after = out.cube.position + out.cube.rotation @ (cube.rotation.T @ (heavy_side_before
                                                                        - cube.position))
    np.testing.assert_allclose(after, heavy_side_before, atol=1e-9)


# --- LIFT and FLIP details -------------------------------------------------------------------

def test_lift_needs_opposite_faces_and_height():
    cube, robot, v2w = scene(np.eye(3), 4)  # heavy top: LIFT turns it over
    x_v, y_v = v_axes(v2w)
    left, right = grasp_points(cube, v2w)
    assert apply_lift(cube, left, right, 0.08).effect == ROTATED
    assert apply_lift(cube, left, right, 0.01).effect == BLOCKED  # corners hit the floor
    front = cube.position + H * x_v
    assert apply_lift(cube, left, front, 0.08).effect == SLIPPED  # adjacent faces
    assert apply_lift(cube, left - 0.03 * y_v, right, 0.08).effect == SLIPPED  # not touching
    assert apply_lift(cube, left, right + 0.07 * x_v, 0.08).effect == SLIPPED  # off the face


def test_lift_grasp_off_centre_still_hangs_the_mass_down():
    cube, robot, v2w = scene(np.eye(3), 0)  # heavy front (+x_V): +90 about y
    x_v, _ = v_axes(v2w)
    left, right = grasp_points(cube, v2w)
    shift = np.array([0.0, 0.0, 0.012]) + 0.01 * x_v
    out = apply_lift(cube, left + shift, right + shift, 0.1)
    assert_rotation(out.cube, v2w, ry(90))
    # A uniform cube held a little off-centre is held by the grip's friction.
    uniform, _, _ = scene(np.eye(3), None)
    assert apply_lift(uniform, left + 0.005 * x_v, right + 0.005 * x_v, 0.1).effect == UNCHANGED


def test_flip_roll_direction_sets_the_uniform_turn():
    cube, robot, v2w = scene(np.eye(3), None)
    x_v, _ = v_axes(v2w)
    left, right = grasp_points(cube, v2w)
    assert_rotation(apply_flip(cube, left, right, x_v).cube, v2w, ry(-90))
    assert_rotation(apply_flip(cube, left, right, -x_v).cube, v2w, ry(90))
    _, y_v = v_axes(v2w)
    assert apply_flip(cube, left, right, y_v).effect == SLIPPED  # along the hand axis


# --- failures --------------------------------------------------------------------------------

def test_injected_failures_happen_at_their_rate():
    rng = np.random.default_rng(7)
    fails = Failures(p_slip_grasp=0.3, p_missed_push=0.2)
    cube, robot, v2w = scene(np.eye(3), 4)
    left, right = grasp_points(cube, v2w)
    n = 2000
    slips = sum(apply_lift(cube, left, right, 0.08, rng, fails).effect == SLIPPED
                for _ in range(n))
    assert slips / n == pytest.approx(0.3, abs=0.04)
    x_v, _ = v_axes(v2w)
    start = cube.position + (H + 0.02) * x_v
    misses = sum(apply_push(cube, start, -x_v, 0.06, rng, fails).effect == MISSED
                 for _ in range(n))
    assert misses / n == pytest.approx(0.2, abs=0.04)


def test_push_neighbour_failure_pivots_the_other_way():
    rng = np.random.default_rng(3)
    cube, robot, v2w = scene(np.eye(3), 2)  # nominal: yaw -1
    fails = Failures(p_push_neighbour=1.0)
    x_v, _ = v_axes(v2w)
    out = apply_push(cube, cube.position + (H + 0.02) * x_v, -x_v, 0.06, rng, fails)
    assert discrete_state(out.cube, robot) == (4, 1)
    uniform, _, _ = scene(np.eye(3), None)
    yaws = {discrete_state(apply_push(uniform, uniform.position + (H + 0.02) * x_v, -x_v, 0.06,
                                      rng, fails).cube, robot)[1] for _ in range(40)}
    assert yaws == {1, 7}


def test_failures_validate():
    with pytest.raises(ValueError):
        Failures(p_slip_grasp=1.5)
    with pytest.raises(ValueError):
        Failures(orbit_angle_std=-1.0)


# --- ORBIT and the discrete state ------------------------------------------------------------

@pytest.mark.parametrize('steps', [1, -1, 2, -2, 4])
def test_orbit_changes_relative_yaw(steps):
    cube, robot, _ = scene(ORIENTATIONS[7], None)
    up0, yaw0 = discrete_state(cube, robot)
    out = apply_orbit(robot, cube, np.radians(45 * steps), RADIUS)
    assert discrete_state(cube, out.pose) == (up0, (yaw0 + steps) % 8)
    np.testing.assert_allclose(out.pose, out.odometry)
    dist = np.hypot(*(out.pose[:2] - cube.position[:2]))
    assert dist == pytest.approx(RADIUS)
    heading = np.array([np.cos(out.pose[2]), np.sin(out.pose[2])])
    np.testing.assert_allclose(heading, (cube.position[:2] - out.pose[:2]) / dist, atol=1e-9)


def test_orbit_noise_and_slip():
    rng = np.random.default_rng(11)
    cube, robot, _ = scene(np.eye(3), None)
    fails = Failures(orbit_angle_std=np.radians(3), orbit_radius_std=0.01, p_orbit_slip=0.25)
    yaws = []
    for _ in range(400):
        out = apply_orbit(robot, cube, np.radians(90), RADIUS, rng, fails)
        yaws.append(discrete_state(cube, out.pose)[1])
    counts = np.bincount(yaws, minlength=8)
    assert counts[2] / 400 == pytest.approx(0.75, abs=0.06)
    assert counts[1] + counts[3] + counts[2] == 400


def test_world_tracks_odometry_drift():
    cube = Cube.on_floor(0.0, 0.0)
    world = World(cube, facing_pose(cube.position, 0.0, 0.4),
                  Failures(orbit_angle_std=np.radians(5)), seed=4)
    for _ in range(4):
        world.orbit(np.radians(90), 0.4)
    assert world.state()[0] == 4 and world.state()[1] in (7, 0, 1)
    assert not np.allclose(world.robot_pose, world.odometry_pose)
    # Odometry believes it went exactly around once: back where it started.
    np.testing.assert_allclose(world.odometry_pose, facing_pose(cube.position, 0.0, 0.4),
                               atol=1e-9)


def test_discrete_state_rounds_to_nearest_and_ignores_heading():
    for orientation, yaw in itertools.product((0, 9, 17), range(8)):
        cube, robot, _ = scene(ORIENTATIONS[orientation], None, 45 * yaw + 12.0)
        expected = discrete_state(scene(ORIENTATIONS[orientation], None, 45 * yaw)[0], robot)
        assert discrete_state(cube, robot) == expected
        turned = robot.copy()
        turned[2] += 0.4  # the base's own heading does not enter V
        assert discrete_state(cube, turned) == expected
        assert discrete_state(cube.pose(), robot) == expected
    cube, robot, _ = scene(np.eye(3), None)
    assert discrete_state(cube, robot) == (4, 0)


def test_settle_snaps_small_tilts():
    cube = Cube(np.array([0.0, 0.0, 0.3]), rx(8) @ rot_z_deg(20), None)
    settled = W.settle(cube)
    np.testing.assert_allclose(settled.rotation, rot_z_deg(20), atol=1e-9)
    assert settled.position[2] == pytest.approx(H)


def test_cube_validation_and_mass_index():
    with pytest.raises(ValueError):
        Cube.on_floor(0, 0, heavy_face=6)
    with pytest.raises(ValueError):
        Cube.on_floor(0, 0, mass_offset=0.06)
    assert Cube.from_mass_index([0, 0, H], np.eye(3), 3).heavy_face == 2
    assert Cube.from_mass_index([0, 0, H], np.eye(3), 0).mass_index == 0
