"""Robot model + world + renderer together: what the head camera sees of the cube matches
the ground-truth discrete state's aspect (MODEL.md: top + front, or top + right + left)."""

import cv2
import numpy as np
import pytest

from abp_description import camera_intrinsics
from abp_description.kinematics import RobotKinematics, base_to_world
from abp_sim_bridge.renderer import ArcubeRenderer, ImageEffects
from abp_sim_bridge.world import Cube, World, discrete_state, facing_pose, view_frame

TAGS = np.array([3, 0, 6, 2, 5, 1])  # tag id on each body face


def rz(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def expected_tags(cube, robot_pose):
    """Top face plus the faces whose normals point towards the robot (MODEL.md aspects)."""
    up, yaw = discrete_state(cube, robot_pose)
    to_robot = np.array([*(robot_pose[:2] - cube.position[:2]), 0.0])
    to_robot /= np.linalg.norm(to_robot)
    faces = {up}
    for f in range(6):
        n = cube.face_normal(f)
        if abs(n[2]) < 0.5 and n @ to_robot > 0.5:
            faces.add(f)
    assert len(faces) == (2 if yaw % 2 == 0 else 3)
    return {int(TAGS[f]) for f in faces}


def head_looking_at(kin, base_pose, target):
    """Joint vector with the head's pan/tilt aimed at a world point (fixed-point iteration)."""
    q = kin.neutral()
    pan, tilt = kin.joint_index('head_pan_joint'), kin.joint_index('head_tilt_joint')
    for _ in range(5):
        cam = base_to_world(base_pose) @ kin.camera_pose(q)
        d = cam[:3, :3].T @ (target - cam[:3, 3])  # target in the optical frame
        q[pan] -= np.arctan2(d[0], d[2])   # image right is a negative pan
        q[tilt] += np.arctan2(d[1], d[2])  # image down is a positive tilt
    return q


@pytest.mark.parametrize('heavy', [None, 4])
def test_head_camera_sees_the_aspect_of_the_true_state(heavy):
    kin = RobotKinematics()
    cam = camera_intrinsics()
    renderer = ArcubeRenderer(cam.K, cam.width, cam.height,
                              effects=ImageEffects(blur_sigma=0.5, noise_std=1.5))
    params = cv2.aruco.DetectorParameters()
    detector = cv2.aruco.ArucoDetector(renderer.dictionary, params)
    cube = Cube.on_floor(2.0, 1.0, rz(-20 + 3), heavy)  # yaw 3 deg off the grid
    world = World(cube, facing_pose(cube.position, np.radians(-20), 0.6))
    seen_states = set()
    plan = ['O45', 'O45', 'FLIP', 'O90', 'FLIP', 'O-45', 'LIFT', 'O-45', 'FLIP', 'O180', 'FLIP']
    for step, action in enumerate(plan):
        q = head_looking_at(kin, world.robot_pose, world.cube.position)
        assert kin.within_limits(q)
        camera_pose = base_to_world(world.robot_pose) @ kin.camera_pose(q)
        img = renderer.render(camera_pose, world.cube.pose(), TAGS)
        _, ids, _ = detector.detectMarkers(img)
        got = set() if ids is None else set(ids.ravel().tolist())
        assert got == expected_tags(world.cube, world.robot_pose), step
        seen_states.add(world.state())
        centre_px = cam.K @ (np.linalg.inv(camera_pose) @ [*world.cube.position, 1])[:3]
        assert np.allclose(centre_px[:2] / centre_px[2], [cam.cx, cam.cy], atol=2)
        v = view_frame(world.cube.position, world.robot_pose)
        half = world.cube.half
        left, right = world.cube.position - half * v[:, 1], world.cube.position + half * v[:, 1]
        if action.startswith('O'):
            world.orbit(np.radians(float(action[1:])), 0.6)
        elif action == 'FLIP':
            world.flip(left, right, v[:, 0])
        else:
            world.lift(left, right, 0.08)
    assert len(seen_states) >= 5
