"""The sim bridge's outgoing messages built from the simulation's state: stamps, odometry,
the ground truth, the camera info and images (message filling only; the node publishes
them)."""

import cv2
import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from abp_common import names
from abp_description.frames import quaternion_from_yaw, rot_z
from abp_msgs.msg import SimGroundTruth, SimSceneTruth


def stamp(ns):
    ns = int(ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def pose(position, rotation):
    x, y, z, w = pin.Quaternion(np.asarray(rotation, dtype=float)).coeffs()
    return Pose(position=Point(x=float(position[0]), y=float(position[1]),
                               z=float(position[2])),
                orientation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)))


def fill_odometry(msg, stamp, sim):
    """Fill the (reused) Odometry `msg` from the simulation; only the sim thread calls it."""
    x, y, yaw = sim.world.odometry_pose
    v, w = sim.twist
    msg.header.stamp = stamp
    position, twist = msg.pose.pose, msg.twist.twist
    position.position.x, position.position.y = float(x), float(y)
    _, _, position.orientation.z, position.orientation.w = quaternion_from_yaw(yaw)
    twist.linear.x, twist.angular.z = float(v), float(w)
    return msg


def ground_truth(sim, hidden, stamp, frame_id, index=0):
    """What tests and benchmarks check against: hidden cube `index` of the scene (the
    first by default), its pose and state."""
    cube = sim.display_cube(index)
    up, yaw = sim.discrete_state(index)
    base = sim.world.robot_pose
    msg = SimGroundTruth()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.object_id = hidden.object_id
    msg.model_index = int(hidden.model_index)
    msg.face_tags = [int(t) for t in hidden.face_tags]
    msg.mass_index = int(hidden.mass_index)
    msg.cube_pose = pose(cube.position, cube.rotation)
    msg.base_pose = pose([base[0], base[1], 0.0], rot_z(base[2]))
    msg.state, msg.up_face, msg.yaw_step = 8 * up + yaw, up, yaw
    msg.manual_actions = sim.manual_actions
    msg.last_outcome = sim.last_outcome
    return msg


def scene_truth(sim, hiddens, stamp, frame_id):
    """Every cube of the scene (SimSceneTruth), in the order the scene placed them."""
    return SimSceneTruth(header=Header(stamp=stamp, frame_id=frame_id),
                         cubes=[ground_truth(sim, h, stamp, frame_id, i)
                                for i, h in enumerate(hiddens)])


def camera_info(intrinsics):
    """CameraInfo of the simulated camera: rectified images, so P = [K | 0]."""
    K = intrinsics.K
    msg = CameraInfo()
    msg.header.frame_id = intrinsics.frame_id
    msg.width, msg.height = intrinsics.width, intrinsics.height
    msg.distortion_model = intrinsics.distortion_model
    msg.d = [float(v) for v in intrinsics.distortion]
    msg.k = K.ravel().tolist()
    msg.r = np.eye(3).ravel().tolist()
    msg.p = np.hstack([K, np.zeros((3, 1))]).ravel().tolist()
    return msg

# image_transport's topic of the compressed transport beside the raw images.
COMPRESSED_IMAGE = names.IMAGE + '/compressed'


def image(pixels, encoding, stamp, frame_id):
    """A sensor_msgs/Image of a rendered frame (mono8 or bgr8 pixels)."""
    msg = Image(height=pixels.shape[0], width=pixels.shape[1], encoding=encoding,
                step=int(pixels.strides[0]), data=pixels.tobytes())
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    return msg


def publish_compressed(publisher, pixels, encoding, quality, header):
    """Publish the frame as JPEG on `publisher` (None: not asked for), encoded only while
    someone subscribes, as image_transport's publishers do."""
    if publisher is not None and publisher.get_subscription_count() > 0:
        publisher.publish(compressed_image(pixels, encoding, quality, header))


def compressed_image(image, encoding, quality, header):
    """A frame as image_transport's `compressed` transport sends it: JPEG, format
    '<encoding>; jpeg compressed <encoding>' (mono8 or bgr8 frames)."""
    ok, buf = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f'JPEG encoding of a {encoding} frame failed')
    return CompressedImage(header=header, format=f'{encoding}; jpeg compressed {encoding}',
                           data=buf.tobytes())
