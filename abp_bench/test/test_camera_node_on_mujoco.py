"""The camera node playing frames written by the MuJoCo camera, through the real
detector, aspect matcher and belief nodes, over real DDS (issue 35's goal: camera node ->
detector -> matcher -> belief, no planner or skills).

The MuJoCo world renders an ARcube of the robot set in front of the robot's head camera;
the frames go to a folder, with a camera_calibration YAML of the sim camera's intrinsics.
The `camera` node plays the folder under a driver's frame id (`webcam_optical`, mapped by
the detector's `frame_map`); the test publishes the robot's (fixed) joint states so that
the detections come in base_link, as the matcher needs. The tags in the frames, the
aspect they show and a belief that ranks the true cube first must come out."""

import os

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')
pytest.importorskip('mujoco')

from sensor_msgs.msg import JointState  # noqa: E402

from abp_belief import cube  # noqa: E402
from abp_belief.cube import R_UP  # noqa: E402
from abp_belief.population import robot_set  # noqa: E402
from abp_common import names, qos  # noqa: E402
from abp_description import camera_yaml_path  # noqa: E402
from abp_description.frames import rot_z  # noqa: E402
from abp_description.kinematics import RobotKinematics, look_at_world  # noqa: E402
from abp_msgs.msg import AspectObservation, Belief, TagDetectionArray  # noqa: E402
from abp_perception import camera_calibration_file  # noqa: E402
from abp_sim_bridge.mujoco_scene import CubeSpec  # noqa: E402
from abp_sim_bridge.mujoco_world import MujocoSettings, MujocoWorld  # noqa: E402

pytestmark = pytest.mark.timeout(240)

SEED = 3
FRAMES = 4
DRIVER_FRAME = 'webcam_optical'


def executable(package, name):
    return os.path.join(ament_index.get_package_prefix(package), 'lib', package, name)


def render_episode_frames(folder, models, model, yaw_deg):
    """Write FRAMES PNGs of the MuJoCo camera looking at `model` (its +z face up, turned
    by `yaw_deg`) into `folder`; returns (robot joint positions, discrete state)."""
    kin = RobotKinematics()
    spec = CubeSpec(position=(0.40, 0.0, 0.05), rotation=rot_z(np.radians(yaw_deg)) @ R_UP[4])
    q0, _ = look_at_world(kin, kin.neutral(), (0.0, 0.0, 0.0), spec.position)
    world = MujocoWorld(spec, tuple(int(t) for t in models.faces[model]),
                        MujocoSettings(initial_positions=tuple(q0)), kin)
    try:
        folder.mkdir()
        for i in range(FRAMES):
            for _ in range(int(round(0.1 / world.dt))):     # the cube settles
                world.step()
            cv2.imwrite(str(folder / f'frame_{i:03d}.png'), world.render(encoding='bgr8'))
        up, yaw = world.discrete_state()
        return kin, world.q.copy(), cube.state_of(up, yaw)
    finally:
        world.close()


# A 2-tag aspect through raw images, a 3-tag one through the camera's JPEG frames.
@pytest.mark.parametrize('yaw_deg, transport', [(180.0, 'raw'), (225.0, 'compressed')])
def test_mujoco_frames_through_camera_detector_matcher_and_belief(
        ros_processes, tester, spin, tmp_path, yaw_deg, transport):
    models = robot_set(seed=SEED)
    model = int(np.flatnonzero(models.mass == 0)[5])          # a uniform cube
    kin, q, state = render_episode_frames(tmp_path / 'frames', models, model, yaw_deg)
    expected = cube.aspect_of(models.faces[model], state)
    assert expected[0] == (2 if yaw_deg % 90 == 0 else 3)
    calibration = tmp_path / 'camera.yaml'
    camera_calibration_file.save(str(calibration),
                                 camera_calibration_file.load(camera_yaml_path()))

    model_args = ['-p', 'model_set:=robot', '-p', f'seed:={SEED}']
    ros_processes.start([executable('abp_perception', 'artag_detector'), '--ros-args',
                         '-p', f"frame_map:=['{DRIVER_FRAME}:camera_optical_frame']",
                         '-p', f'image_transport:={transport}',
                         # A fixed camera: the newest joint state is the pose at any stamp.
                         '-p', 'joint_state_lookup:=latest'])
    ros_processes.start([executable('abp_perception', 'aspect_matcher'), '--ros-args',
                         *model_args])
    ros_processes.start([executable('abp_belief', 'belief'), '--ros-args', *model_args])
    node, executor = tester
    detections, observations, beliefs = [], [], []
    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    node.create_subscription(AspectObservation, names.ASPECT_OBSERVATION,
                             observations.append, qos.RELIABLE)
    node.create_subscription(Belief, names.BELIEF, beliefs.append, qos.LATCHED_READER)
    joints = JointState(name=list(kin.joint_names), position=[float(v) for v in q])
    joint_pub = node.create_publisher(JointState, names.JOINT_STATES, qos.RELIABLE)

    def publish_joints():
        joints.header.stamp = node.get_clock().now().to_msg()
        joint_pub.publish(joints)

    node.create_timer(0.05, publish_joints)
    # The camera starts once the detector hears the joint states and the matcher and the
    # belief are subscribed: graph events, not sleeps.
    assert spin(executor, lambda: joint_pub.get_subscription_count() >= 1
                and node.count_subscribers(names.TAG_DETECTIONS) >= 2
                and node.count_subscribers(names.ASPECT_OBSERVATION) >= 2
                and any(b.step == 0 for b in beliefs), 90), 'the nodes did not come up'
    camera = ros_processes.start([
        executable('abp_perception', 'camera'), '--ros-args',
        '-p', f"source:={tmp_path / 'frames'}", '-p', f'calibration_file:={calibration}',
        '-p', f'frame_id:={DRIVER_FRAME}', '-p', 'rate:=5.0', '-p', 'loop:=true',
        '-p', f"publish_compressed:={'true' if transport == 'compressed' else 'false'}"])

    assert spin(executor, lambda: any(b.step >= 1 for b in beliefs) and observations, 120), \
        f'{len(detections)} detections, {len(observations)} observations; camera exit ' \
        f'code {camera.poll()}'
    seen = [d for d in detections if d.detections]
    assert seen, 'no tags detected in the MuJoCo frames'
    det = seen[-1]
    assert det.camera_frame_id == DRIVER_FRAME and det.header.frame_id == 'base_link'
    assert sorted(d.id for d in det.detections) == sorted(expected[1:1 + expected[0]])
    # Tag centres in base_link lie on the cube: within half its diagonal of its centre.
    for d in det.detections:
        p = d.pose.pose.position
        assert np.linalg.norm([p.x - 0.40, p.y, p.z - 0.05]) < 0.09
    best = observations[-1].hypotheses[0]
    assert (best.aspect_type, *best.slots) == expected
    belief = [b for b in beliefs if b.step >= 1][-1]
    top = belief.probabilities[0]
    leaders = [name for name, p in zip(belief.object_ids, belief.probabilities)
               if p >= top - 1e-9]
    assert models.names[model] in leaders, (models.names[model], leaders)
    assert top > 1.5 / models.num_models          # the view moved the belief off uniform
