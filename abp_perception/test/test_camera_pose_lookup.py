"""The detector's camera pose at an image stamp, without ROS: interpolation, waiting for
the joint states that reach a stamp, refusal outside the buffer, and two threads."""

import threading

import numpy as np
import pytest

from abp_description.kinematics import RobotKinematics
from abp_perception.camera_pose_lookup import CameraPoseLookup, OutsideBuffer

FRAME = 'camera_optical_frame'
JOINTS = ['torso_pitch_joint', 'head_pan_joint', 'head_tilt_joint']


def s(seconds):
    return int(seconds * 1e9)


@pytest.fixture(scope='module')
def kinematics():
    return RobotKinematics()


def add(lookup, t, pan):
    lookup.add(s(t), JOINTS, [0.0, pan, 0.3])


def test_the_pose_at_a_stamp_between_two_joint_states_is_interpolated(kinematics):
    lookup = CameraPoseLookup(kinematics)
    assert lookup.pose_at(FRAME, s(1.0)) == (None, ())   # no joint state yet
    add(lookup, 1.0, 0.0)
    add(lookup, 1.1, 0.2)
    pose, unstamped = lookup.pose_at(FRAME, s(1.05))
    q = kinematics.q_from_mapping(dict(zip(JOINTS, [0.0, 0.1, 0.3])))
    np.testing.assert_allclose(pose, kinematics.frame_pose(q, FRAME), atol=1e-9)
    assert unstamped == ()
    # 'latest' takes the newest, whatever the stamp.
    latest = CameraPoseLookup(kinematics, lookup='latest')
    add(latest, 1.0, 0.0)
    add(latest, 1.1, 0.2)
    q_newest = kinematics.q_from_mapping(dict(zip(JOINTS, [0.0, 0.2, 0.3])))
    np.testing.assert_allclose(latest.pose_at(FRAME, s(1.05))[0],
                               kinematics.frame_pose(q_newest, FRAME), atol=1e-9)


def test_an_image_after_the_newest_joint_state_waits_and_one_before_the_buffer_is_refused(
        kinematics):
    lookup = CameraPoseLookup(kinematics, buffer_s=0.5)
    assert not lookup.must_wait(s(2.0), FRAME)      # nothing to wait for before any state
    add(lookup, 1.0, 0.0)
    add(lookup, 1.4, 0.1)
    assert lookup.must_wait(s(1.45), FRAME)
    assert not lookup.must_wait(s(1.4), FRAME)
    assert not lookup.must_wait(0, FRAME)           # an unstamped image takes the newest
    with pytest.raises(OutsideBuffer):
        lookup.pose_at(FRAME, s(0.5))


def test_a_joint_state_of_another_robot_is_refused(kinematics):
    with pytest.raises(ValueError, match='no joint of the robot'):
        CameraPoseLookup(kinematics).add(s(1.0), ['not_a_joint'], [0.0])


def test_joint_states_from_one_thread_and_poses_from_another(kinematics):
    lookup = CameraPoseLookup(kinematics)
    add(lookup, 0.0, 0.0)
    errors = []

    def feed():
        for k in range(1, 2001):
            add(lookup, k * 0.001, 0.001 * k)

    feeder = threading.Thread(target=feed)
    feeder.start()
    while feeder.is_alive():
        try:
            pose, _ = lookup.pose_at(FRAME, 0)
            assert pose is not None and np.isfinite(pose).all()
        except Exception as error:  # noqa: BLE001 -- collected and reported below
            errors.append(error)
    feeder.join()
    assert not errors, errors[:3]
    assert not lookup.must_wait(s(2.0), FRAME)
