"""Robot model + rules world + flat renderer together: what the head camera sees of the cube matches
the ground-truth discrete state's aspect (MODEL.md: top + front, or top + right + left)."""

import cv2
import numpy as np
import pytest

from abp_description import camera_intrinsics
from abp_description.frames import base_to_world, rot_z_deg
from abp_description.kinematics import RobotKinematics, look_at_world
from abp_sim_bridge.flat_renderer import ArcubeRenderer, ImageEffects
from abp_sim_bridge.rules_physics import Cube, World, discrete_state, facing_pose, view_frame

TAGS = np.array([3, 0, 6, 2, 5, 1])  # tag id on each body face


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


@pytest.mark.parametrize('heavy', [None, 4])
def test_head_camera_sees_the_aspect_of_the_true_state(heavy):
    kin = RobotKinematics()
    cam = camera_intrinsics()
    renderer = ArcubeRenderer(cam.K, cam.width, cam.height,
                              effects=ImageEffects(blur_sigma=0.5, noise_std=1.5))
    params = cv2.aruco.DetectorParameters()
    detector = cv2.aruco.ArucoDetector(renderer.dictionary, params)
    cube = Cube.on_floor(2.0, 1.0, rot_z_deg(-20 + 3), heavy)  # yaw 3 deg off the grid
    world = World(cube, facing_pose(cube.position, np.radians(-20), 0.6))
    seen_states = set()
    plan = ['O45', 'O45', 'FLIP', 'O90', 'FLIP', 'O-45', 'LIFT', 'O-45', 'FLIP', 'O180', 'FLIP']
    for step, action in enumerate(plan):
        q, _ = look_at_world(kin, kin.neutral(), world.robot_pose, world.cube.position)
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
