"""`scripts/start_graph.sh --operator person` end to end: frames rendered by the MuJoCo
camera, played by the camera node from a folder, through the detector (its camera pose
from --camera-pose, no joint states, no robot_state), the matcher, the belief and the
planner, to the operator node, whose requests the test reads on a pty and answers as a
person would; the Recognize client's result ends the run.

The frames do not change with the answers (a folder of pictures is no world), so this
checks the wiring, not recognition: every request is answered, each answer reaches the
planner as an executed action, and the episode ends with a result after the action
budget."""

import json
import os
import re
import select
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
pytest.importorskip('mujoco')

from scipy.spatial.transform import Rotation  # noqa: E402

from abp_belief.cube import R_UP  # noqa: E402
from abp_belief.population import robot_set  # noqa: E402
from abp_description import camera_yaml_path  # noqa: E402
from abp_description.frames import rot_z  # noqa: E402
from abp_description.kinematics import RobotKinematics, look_at_world  # noqa: E402
from abp_perception import camera_calibration_file  # noqa: E402
from abp_perception.camera_model import OPTICAL_IN_BODY  # noqa: E402
from abp_sim_bridge.mujoco_scene import CubeSpec  # noqa: E402
from abp_sim_bridge.mujoco_world import MujocoSettings, MujocoWorld  # noqa: E402

pytestmark = pytest.mark.timeout(900)

REPO = Path(__file__).resolve().parents[2]
SEED = 3
ACTIONS = 3


def render_frames(folder, faces, count=3):
    """PNGs of the robot's head camera looking at a cube 0.4 m ahead; returns the camera
    pose for --camera-pose (x y z roll pitch yaw of the camera body in base_link)."""
    kin = RobotKinematics()
    spec = CubeSpec(position=(0.40, 0.0, 0.05), rotation=rot_z(np.radians(180.0)) @ R_UP[4])
    q0, _ = look_at_world(kin, kin.neutral(), (0.0, 0.0, 0.0), spec.position)
    world = MujocoWorld(spec, faces, MujocoSettings(initial_positions=tuple(q0)), kin)
    try:
        folder.mkdir()
        for i in range(count):
            for _ in range(int(round(0.1 / world.dt))):     # the cube settles
                world.step()
            cv2.imwrite(str(folder / f'frame_{i:03d}.png'), world.render(encoding='bgr8'))
        optical = kin.frame_pose(world.q.copy(), 'camera_optical_frame')
    finally:
        world.close()
    body = optical[:3, :3] @ OPTICAL_IN_BODY.T
    rpy = Rotation.from_matrix(body).as_euler('xyz', degrees=True)
    return ' '.join(f'{v:.6f}' for v in (*optical[:3, 3], *rpy))


def executable(package, name):
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def test_fixed_camera_pose_puts_the_tags_on_the_cube(ros_processes, tester, spin, tmp_path):
    """The detector with --camera-pose's parameter and no joint states: the tags of the
    MuJoCo frames land in base_link on the cube (centre 0.40, 0, 0.05), as with the
    robot's forward kinematics (abp_bench/test/test_camera_node_on_mujoco.py)."""
    from abp_common import names, qos
    from abp_msgs.msg import TagDetectionArray

    models = robot_set(seed=SEED)
    model = int(np.flatnonzero(models.mass == 0)[5])
    pose = render_frames(tmp_path / 'frames', tuple(int(t) for t in models.faces[model]))
    calibration = tmp_path / 'camera.yaml'
    camera_calibration_file.save(str(calibration),
                                 camera_calibration_file.load(camera_yaml_path()))
    node, executor = tester
    detections = []
    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    values = ','.join(pose.split())
    ros_processes.start([executable('abp_perception', 'artag_detector'), '--ros-args',
                         '-p', f'fixed_camera_pose:=[{values}]'])
    ros_processes.start([executable('abp_perception', 'camera'), '--ros-args',
                         '-p', f"source:={tmp_path / 'frames'}",
                         '-p', f'calibration_file:={calibration}',
                         '-p', 'frame_id:=webcam_optical', '-p', 'loop:=true'])
    assert spin(executor, lambda: any(d.detections for d in detections), 120), \
        f'{len(detections)} detection messages, none with tags'
    det = [d for d in detections if d.detections][-1]
    assert det.header.frame_id == 'base_link' and det.camera_frame_id == 'webcam_optical'
    assert len(det.detections) >= 2
    for d in det.detections:
        p = d.pose.pose.position
        assert np.linalg.norm([p.x - 0.40, p.y, p.z - 0.05]) < 0.09, (p, pose)


def test_start_graph_with_a_person_answering_on_a_terminal(ros_processes, tmp_path):
    models = robot_set(seed=SEED)
    model = int(np.flatnonzero(models.mass == 0)[5])
    pose = render_frames(tmp_path / 'frames', tuple(int(t) for t in models.faces[model]))
    calibration = tmp_path / 'camera.yaml'
    camera_calibration_file.save(str(calibration),
                                 camera_calibration_file.load(camera_yaml_path()))
    master, slave = os.openpty()
    result_json = tmp_path / 'result.json'
    graph = ros_processes.start([
        str(REPO / 'scripts' / 'start_graph.sh'), '--no-build', '--no-respawn',
        '--operator', 'person', '--camera', str(tmp_path / 'frames'),
        '--calibration', str(calibration), '--camera-pose', pose,
        '--operator-terminal', os.ttyname(slave), '--seed', str(SEED),
        '--max-actions', str(ACTIONS), '--result-json', str(result_json),
        '--log-dir', str(tmp_path / 'log')])
    shown, answered = '', 0
    deadline = time.monotonic() + 800
    try:
        while graph.poll() is None and time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.5)
            if ready:
                shown += os.read(master, 4096).decode(errors='replace')
            # Answer each request once its prompt is complete.
            while len(re.findall(r'=== abp asks: .*?\n> ', shown, re.S)) > answered:
                answered += 1
                os.write(master, b'd\n')
        assert graph.poll() is not None, 'the graph did not finish'
        output = ros_processes.output(graph)
    finally:
        os.close(master)
        os.close(slave)
    assert 'Operator ready' in shown
    requests = re.findall(r'=== abp asks: (\S+)', shown)
    summary = json.loads(result_json.read_text())
    assert summary['actions'] == answered == len(requests) >= 1, (summary, requests, output)
    assert shown.count('done, thank you') == answered
    assert summary['status'] in ('succeeded', 'aborted')
    assert 'operator (person) graph' in output


@pytest.mark.parametrize('args, message', [
    (['--operator', 'robot'], '--operator must be person'),
    (['--operator', 'person'], '--operator person needs --camera and --calibration'),
    (['--camera', '/dev/video0'], '--camera and --calibration go with --operator person'),
    (['--operator', 'person', '--camera', '/dev/video0', '--calibration', 'missing.yaml'],
     '--calibration file missing.yaml not found'),
    (['--operator', 'person', '--camera', 'no/such/folder', '--calibration', '{yaml}'],
     '--camera no/such/folder: no such device, file or folder'),
    (['--operator', 'person', '--camera', '/dev/video0', '--calibration', '{yaml}',
      '--camera-pose', '0 0 0.4 0 45'], '--camera-pose needs 6 numbers'),
    (['--operator', 'person', '--camera', '/dev/video0', '--calibration', '{yaml}',
      '--camera-pose', '0 0 0.4 0 down 0'], '--camera-pose: down is not a number'),
    (['--operator', 'person', '--robot', '--camera', '/dev/video0', '--calibration', '{yaml}'],
     'leave out --robot'),
])
def test_start_graph_refuses_bad_operator_options(ros_processes, tmp_path, args, message):
    calibration = tmp_path / 'camera.yaml'
    calibration.write_text('image_width: 640\n')
    argv = [str(REPO / 'scripts' / 'start_graph.sh'), '--no-build',
            *[a.replace('{yaml}', str(calibration)) for a in args]]
    proc = ros_processes.start(argv)
    assert proc.wait(timeout=60) == 2
    assert message in ros_processes.output(proc)
