"""Hand IK and self-collision checks on the robot model (plain modules, no ROS graph)."""

import numpy as np
import pytest

from abp_description.controllers import ARM_JOINTS, TORSO_JOINT
from abp_description.kinematics import RobotKinematics, look_at
from abp_skills.collision import SelfCollision, segment_distance
from abp_skills.ik import HandIK
from abp_skills.plans import SkillPlanner


@pytest.fixture(scope='module')
def kin():
    return RobotKinematics()


@pytest.fixture(scope='module')
def ik(kin):
    return HandIK(kin, tol=1e-3)


@pytest.fixture(scope='module')
def planner(kin):
    return SkillPlanner(kin)


@pytest.mark.parametrize('x', [0.35, 0.40, 0.45, 0.50])
@pytest.mark.parametrize('z', [0.05, 0.13])
def test_two_hand_targets_are_reached_within_limits(kin, ik, planner, x, z):
    targets = {'left': np.array([x, 0.075, z]), 'right': np.array([x, -0.075, z])}
    q0 = planner.home()
    result = ik.solve(targets, q0, seeds=[planner.reach_seed(q0)])
    assert result.success, result.reason
    assert kin.within_limits(result.q)
    for side, target in targets.items():
        reached = kin.hand_pose(result.q, side)[:3, 3]
        assert np.linalg.norm(reached - target) <= 1e-3
    # Only the torso and the arms moved.
    moved = np.flatnonzero(np.abs(result.q - q0) > 1e-12)
    allowed = {kin.joint_index(n) for n in (TORSO_JOINT, *ARM_JOINTS['left'],
                                           *ARM_JOINTS['right'])}
    assert set(moved) <= allowed


def test_one_hand_without_torso_leaves_other_joints(kin, ik, planner):
    q0 = planner.home()
    target = kin.hand_pose(q0, 'right')[:3, 3] + [0.08, 0.02, -0.05]
    result = ik.solve({'right': target}, q0, use_torso=False)
    assert result.success, result.reason
    np.testing.assert_allclose(kin.hand_pose(result.q, 'right')[:3, 3], target, atol=1e-3)
    others = [i for i in range(kin.nq)
              if kin.joint_names[i] not in ARM_JOINTS['right']]
    np.testing.assert_array_equal(result.q[others], q0[others])


@pytest.mark.parametrize('target', [[1.5, 0.0, 0.05], [0.0, 0.0, 1.6], [0.4, 0.9, 0.05]])
def test_unreachable_targets_are_refused_with_a_reason(kin, ik, planner, target):
    q0 = planner.home()
    result = ik.solve({'left': target}, q0, seeds=[planner.reach_seed(q0)])
    assert not result.success
    assert 'out of reach' in result.reason and 'left hand' in result.reason
    assert result.error > 0.05
    assert kin.within_limits(result.q)  # the best effort still respects the limits


def test_limits_are_respected_while_pushing_against_them(kin, ik, planner):
    """Targets beyond the torso's range: the solver ends on the closest reachable point
    (torso at its limit, arms stretched) and clamping keeps every joint inside."""
    q0 = planner.home()
    result = ik.solve({'left': [0.65, 0.15, 0.0], 'right': [0.65, -0.15, 0.0]}, q0)
    assert not result.success
    assert kin.within_limits(result.q)
    assert 'torso_pitch_joint at limit' in result.reason
    assert result.error == pytest.approx(0.102, abs=0.005)  # shoulder-target gap - arm length


def test_ik_validates_its_input(ik, planner):
    with pytest.raises(ValueError):
        ik.solve({}, planner.home())
    with pytest.raises(ValueError):
        ik.solve({'middle': [0.3, 0, 0.3]}, planner.home())


def test_look_at_points_the_camera(kin, planner):
    for point in ([0.4, 0.0, 0.05], [0.5, 0.3, 0.05], [0.3, -0.2, 0.1]):
        q, err = look_at(kin, planner.home(), point)
        assert err < np.radians(0.5)
        cam = kin.camera_pose(q)
        d = np.asarray(point) - cam[:3, 3]
        assert np.dot(cam[:3, 2], d / np.linalg.norm(d)) > np.cos(np.radians(0.5))
        assert kin.within_limits(q)


def test_segment_distance():
    a, b = np.zeros(3), np.array([1.0, 0, 0])
    assert segment_distance(a, b, np.array([0.5, 1, 0]), np.array([0.5, 2, 0])) == \
        pytest.approx(1.0)
    assert segment_distance(a, b, np.array([0.5, -1, 0]), np.array([0.5, 1, 0])) == \
        pytest.approx(0.0)
    assert segment_distance(a, b, np.array([2.0, 0, 0]), np.array([3.0, 0, 0])) == \
        pytest.approx(1.0)


def test_self_collision(kin, ik, planner):
    col = SelfCollision(kin)
    home = planner.home()
    assert col.check(home) == (True, '')
    # All zeros: the URDF's hanging arms put the hands into the chassis/wheels.
    ok, reason = col.check(kin.neutral())
    assert not ok and 'self-collision' in reason
    # Hands brought together in front of the chest.
    q0 = planner.home()
    together = ik.solve({'left': [0.3, 0.02, 0.35], 'right': [0.3, -0.02, 0.35]}, q0)
    ok, reason = col.check(together.q)
    assert not ok and 'hands' in reason
    # Crossed arms: the left hand on the right side and vice versa.
    crossed = ik.solve({'left': [0.35, -0.12, 0.3], 'right': [0.35, 0.12, 0.25]}, q0)
    ok, reason = col.check(crossed.q)
    assert not ok and ('cross' in reason or 'touches the right' in reason), reason
    # A hand through the floor.
    low = ik.solve({'right': [0.4, -0.15, 0.01]}, q0, seeds=[planner.reach_seed(q0)])
    ok, reason = col.check(low.q, sides=('right',))
    assert not ok and 'floor' in reason
