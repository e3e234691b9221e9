"""The `sim_bridge` node over real DDS in the MuJoCo world (world:=mujoco): it publishes
/clock, /joint_states, /odom, camera images in which ArUco finds the cube's tags, and the
ground truth; a joint trajectory moves a joint; a missing EGL is a configuration error."""

import os
import subprocess

import cv2
import numpy as np
import pytest

pytest.importorskip('rclpy')
pytest.importorskip('abp_sim_bridge.mujoco_scene')  # MuJoCo, with MUJOCO_GL=egl

from test_sim_bridge_node import (  # noqa: E402
    TAGS,
    bridge_executable,
    ns,
    start_bridge,
    tester_factory,  # noqa: F401 -- the fixture
    to_duration,
    to_time,
)
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint  # noqa: E402

pytestmark = pytest.mark.timeout(180)


def test_mujoco_world_publishes_state_images_and_follows_a_trajectory(ros_processes,
                                                                      tester_factory):  # noqa: F811
    proc = start_bridge(ros_processes, world='mujoco', speedup=2.0, camera_encoding='mono8',
                        face_tags=str(TAGS).replace(' ', ''), mass_index=3)
    t = tester_factory('clock', 'joint_states', 'odom', 'image', 'camera_info', 'ground_truth')
    assert t.spin_until(lambda: len(t.msgs['image']) >= 2 and t.msgs['ground_truth']
                        and t.msgs['odom'] and t.msgs['clock'] and t.msgs['camera_info'], 60), \
        {k: len(v) for k, v in t.msgs.items()}
    gt = t.last('ground_truth')
    assert list(gt.face_tags) == TAGS and gt.mass_index == 3
    # The cube stands with body +z up, body -x (face 1) towards the robot: state 36.
    assert (gt.up_face, gt.yaw_step, gt.state) == (4, 4, 36)
    assert gt.cube_pose.position.x == pytest.approx(0.40, abs=0.01)
    assert gt.cube_pose.position.z == pytest.approx(0.05, abs=0.005)
    odom = t.last('odom')
    assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_link')
    assert abs(odom.pose.pose.position.x) < 1e-3

    img_msg = t.msgs['image'][-1]
    assert (img_msg.encoding, img_msg.width, img_msg.height) == ('mono8', 640, 480)
    img = np.frombuffer(bytes(img_msg.data), np.uint8).reshape(480, 640)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    _, ids, _ = detector.detectMarkers(img)
    found = set() if ids is None else set(ids.ravel().tolist())
    assert found == {TAGS[4], TAGS[1]}, found  # top and front, as the state says

    # A head trajectory, stamped ahead in simulation time, moves the pan joint.
    pub = t.node.create_publisher(JointTrajectory, '/head_controller/joint_trajectory', 10)
    assert t.spin_until(lambda: pub.get_subscription_count() > 0, 10)
    last = t.last('joint_states')
    pan0 = last.position[last.name.index('head_pan_joint')]
    # 3 s of simulation time ahead (1.5 s of wall time): it must arrive before it starts.
    start = ns(last.header.stamp) + 3_000_000_000
    tilt0 = last.position[last.name.index('head_tilt_joint')]
    traj = JointTrajectory(joint_names=['head_pan_joint', 'head_tilt_joint'])
    traj.header.stamp = to_time(start)
    traj.points = [JointTrajectoryPoint(positions=[pan0 + 0.4, tilt0],
                                        time_from_start=to_duration(1.0))]
    pub.publish(traj)
    done = start + 2_000_000_000
    assert t.spin_until(lambda: ns(t.last('joint_states').header.stamp) > done, 60)
    js = t.last('joint_states')
    assert js.position[js.name.index('head_pan_joint')] == pytest.approx(pan0 + 0.4, abs=0.01)
    clocks = [ns(m.clock) for m in t.msgs['clock']]
    assert np.all(np.diff(clocks) > 0)
    assert proc.poll() is None


def test_missing_egl_is_a_configuration_error():
    env = {**os.environ, 'MUJOCO_GL': 'egl', 'MUJOCO_EGL_DEVICE_ID': '99'}  # no such device
    result = subprocess.run([bridge_executable(), '--ros-args', '-p', 'world:=mujoco'],
                            capture_output=True, text=True, timeout=60, env=env)
    assert result.returncode == 2, result.stderr
    assert 'configuration error' in result.stderr and 'EGL' in result.stderr
    assert 'apt-get install' in result.stderr
    assert 'Traceback' not in result.stderr
