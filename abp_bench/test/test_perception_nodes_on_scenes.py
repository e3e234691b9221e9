"""The perception nodes over real DDS on a rendered camera image (abp_bench.scenes): the
image, its camera_info and the joint states go in; tag detections in base_link and the
right aspect observation come out."""

import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')
if not hasattr(pytest.importorskip('abp_msgs.msg'), 'AspectObservation'):
    pytest.skip('abp_msgs is not built: run scripts/bootstrap.sh and source scripts/env.sh',
                allow_module_level=True)

from builtin_interfaces.msg import Time  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, JointState  # noqa: E402

from abp_belief import cube  # noqa: E402
from abp_belief.population import robot_set  # noqa: E402
from abp_bench.scenes import SceneGenerator  # noqa: E402
from abp_common import names, qos  # noqa: E402
from abp_description import camera_intrinsics  # noqa: E402
from abp_description.kinematics import RobotKinematics, look_at  # noqa: E402
from abp_msgs.msg import AspectObservation, TagDetectionArray  # noqa: E402

SEED = 3
CUBE_CENTRE = np.array([1.0, 0.0, 0.05])
NEAR_CUBE_CENTRE = np.array([0.40, 0.0, 0.05])
HEAD_TILT = 0.6


def executable(name):
    prefix = ament_index.get_package_prefix('abp_perception')
    return os.path.join(prefix, 'lib', 'abp_perception', name)


@pytest.fixture(scope='module')
def world():
    kin = RobotKinematics()
    q = kin.neutral()
    q[kin.joint_index('head_tilt_joint')] = HEAD_TILT
    cam = camera_intrinsics()
    gen = SceneGenerator(cam.K, cam.width, cam.height, seed=5)
    return kin, q, cam, gen, robot_set(seed=SEED)


def camera_info_msg(cam):
    msg = CameraInfo(width=cam.width, height=cam.height, distortion_model='plumb_bob',
                     k=[float(v) for v in cam.K.ravel()], d=[float(v) for v in cam.D])
    msg.header.frame_id = cam.frame_id
    return msg


def mono8_msg(gray, frame_id, stamp):
    msg = Image(height=gray.shape[0], width=gray.shape[1], encoding='mono8',
                step=gray.shape[1], data=gray.tobytes())
    msg.header.frame_id, msg.header.stamp = frame_id, stamp
    return msg


def test_rendered_image_gives_the_right_aspect_observation(ros_processes, tester, spin,
                                                            world):
    kin, q, cam, gen, models = world
    ros_processes.start([executable('artag_detector')])
    ros_processes.start([executable('aspect_matcher'), '--ros-args', '-p', 'model_set:=robot',
                         '-p', f'seed:={SEED}'])
    node, executor = tester
    observations, detections = [], []
    node.create_subscription(AspectObservation, names.ASPECT_OBSERVATION,
                             observations.append, qos.RELIABLE)
    node.create_subscription(TagDetectionArray, names.TAG_DETECTIONS, detections.append,
                             qos.RELIABLE)
    image_pub = node.create_publisher(Image, names.IMAGE, qos.SENSOR_DATA)
    info_pub = node.create_publisher(CameraInfo, names.CAMERA_INFO, qos.SENSOR_DATA)
    joint_pub = node.create_publisher(JointState, names.JOINT_STATES, qos.RELIABLE)
    assert spin(executor, lambda: image_pub.get_subscription_count() > 0
                and joint_pub.get_subscription_count() > 0
                and info_pub.get_subscription_count() > 0, 30), 'detector did not come up'
    # The matcher is up when it subscribes to the detections and publishes observations:
    # graph events, so the first frame is not spent on discovery.
    assert spin(executor, lambda: node.count_subscribers(names.TAG_DETECTIONS) >= 2
                and node.count_publishers(names.ASPECT_OBSERVATION) >= 1, 60), \
        'aspect matcher did not come up'
    # Two cases with the head tilted 0.6 rad to a cube 1 m away, one at the sim bridge's
    # default cube pose (0.40 m in front, head tilted ~1.1 rad).
    near_q, _ = look_at(kin, kin.neutral(), NEAR_CUBE_CENTRE)
    cases = [(4, 32, CUBE_CENTRE, q), (4, 33, CUBE_CENTRE, q), (21, 13, NEAR_CUBE_CENTRE, near_q)]
    for k, (model, state, centre, joint_q) in enumerate(cases):
        faces = models.faces[model]
        scene = gen.render_view(kin.camera_pose(joint_q), faces, state, centre,
                                yaw_error_deg=3.0)
        stamp = Time(sec=100 + k, nanosec=12345)
        joints = JointState(name=list(kin.joint_names), position=[float(v) for v in joint_q])
        for _ in range(5):                       # the detector has these joints before images
            joint_pub.publish(joints)
            spin(executor, lambda: False, 0.1)
        observations.clear()
        detections.clear()

        def publish_until_observed():
            info_pub.publish(camera_info_msg(cam))
            joint_pub.publish(joints)
            image_pub.publish(mono8_msg(scene.image, cam.frame_id, stamp))
            # The detection and the observation made from it reach this node on two
            # subscriptions, in either order: wait for both.
            return spin(executor, lambda: any(o.header.stamp == stamp for o in observations)
                        and any(d.header.stamp == stamp for d in detections), 0.5)

        # Best-effort images can be lost on a loaded machine: publish until observed,
        # bounded by a deadline rather than a count of attempts.
        deadline = time.monotonic() + 60.0
        while not publish_until_observed():
            assert time.monotonic() < deadline, \
                f'no aspect observation for model {model} state {state}'
        obs = [o for o in observations if o.header.stamp == stamp][0]
        det = [d for d in detections if d.header.stamp == stamp][0]
        expected = cube.aspect_of(faces, state)
        assert det.header.frame_id == 'base_link'
        assert det.camera_frame_id == cam.frame_id
        assert sorted(d.id for d in det.detections) == sorted(expected[1:1 + expected[0]])
        for d in det.detections:
            truth = [t for t in scene.tags if t.tag_id == d.id][0]
            p = d.pose.pose.position
            assert np.linalg.norm([p.x - truth.centre[0], p.y - truth.centre[1],
                                   p.z - truth.centre[2]]) < 0.01
            assert np.all(np.linalg.eigvalsh(np.reshape(d.pose.covariance, (6, 6))) > 0)
        assert obs.header.frame_id == 'base_link'
        assert len(obs.features) == len(det.detections)
        best = obs.hypotheses[0]
        assert (best.aspect_type, *best.slots) == expected
        pos = best.object_pose.pose.position
        assert np.linalg.norm([pos.x, pos.y, pos.z] - centre) < 0.02
        assert sorted(best.feature_indices) == list(range(expected[0]))
