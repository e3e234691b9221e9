"""A panning head and a still ARcube, rendered for the image-latency measurement (plain
NumPy + OpenCV, no rclpy; the ROS side is `abp_bench.image_latency_benchmark`).

The robot stands still with an ARcube 1 m ahead on the floor; the head tilts to look at
it and pans in a triangle wave at `speed` rad/s (+-`amplitude` rad) around it. Frame k
is the camera image at time k / fps after the start, rendered by the sim bridge's flat
renderer from the camera pose that abp_description's kinematics give for the joint state
of that instant. A detection's cube centre (each tag's position minus half a cube edge
along its normal, averaged) is compared with the cube's true centre in base_link.
"""

from dataclasses import dataclass

import numpy as np

from abp_description import camera_intrinsics
from abp_description.frames import rotation_from_quaternion
from abp_description.kinematics import RobotKinematics, look_at
from abp_description.robot_profile import load_profile
from abp_sim_bridge.flat_renderer import DEFAULT_EDGE, ArcubeRenderer

CUBE_CENTRE = np.array([1.0, 0.0, DEFAULT_EDGE / 2])
CUBE_TAGS = (0, 1, 2, 3, 4, 5)
PAN_JOINT = load_profile().head.pan_joint   # the default robot's


@dataclass
class HeadMotion:
    """Head pan in a triangle wave: 0 at t = 0, rising at `speed` to `amplitude`, down to
    -`amplitude`, and so on (the camera never stops long enough to hide a latency)."""
    speed: float = 0.5           # rad/s
    amplitude: float = 0.25      # rad

    def pan(self, t_s):
        period = 4.0 * self.amplitude / self.speed
        phase = (np.asarray(t_s, dtype=float) + 0.25 * period) % period
        return self.amplitude - self.speed * np.abs(phase - 0.5 * period)


class HeadMotionScene:
    """Joint states and camera images of the panning head, and the cube's truth."""

    def __init__(self, motion=None, seed=0):
        self.kin = RobotKinematics()
        self.camera = camera_intrinsics()
        self.motion = motion if motion is not None else HeadMotion()
        self.q0, _ = look_at(self.kin, self.kin.neutral(), CUBE_CENTRE)
        self.pan_index = self.kin.joint_index(PAN_JOINT)
        self.pan0 = float(self.q0[self.pan_index])
        self.renderer = ArcubeRenderer(self.camera.K, self.camera.width, self.camera.height,
                                       seed=seed)
        self.cube_pose = np.eye(4)
        self.cube_pose[:3, 3] = CUBE_CENTRE

    def joints(self, t_s):
        """Joint positions (URDF order, as /joint_states) at t_s after the start."""
        q = self.q0.copy()
        q[self.pan_index] = self.pan0 + float(self.motion.pan(t_s))
        return q

    def render(self, t_s):
        """The mono8 camera image at t_s (the world is base_link: the robot stands still)."""
        camera_pose = self.kin.camera_pose(self.joints(t_s))
        return self.renderer.render(camera_pose, self.cube_pose, CUBE_TAGS)


def cube_centre_from_tags(tags, cube_edge=DEFAULT_EDGE):
    """Cube centre implied by tag poses [(position xyz, quaternion xyzw)] in one frame:
    each tag's position minus half an edge along its normal (ArUco z), averaged."""
    centres = []
    for position, (qx, qy, qz, qw) in tags:
        normal = rotation_from_quaternion(qx, qy, qz, qw)[:, 2]
        centres.append(np.asarray(position, dtype=float) - 0.5 * cube_edge * normal)
    return np.mean(centres, axis=0) if centres else None


def error_summary(errors_m):
    """{'frames', 'median_mm', 'p95_mm', 'max_mm'} of per-frame position errors (m)."""
    e = np.asarray(errors_m, dtype=float) * 1e3
    if e.size == 0:
        return {'frames': 0, 'median_mm': float('nan'), 'p95_mm': float('nan'),
                'max_mm': float('nan')}
    return {'frames': int(e.size), 'median_mm': float(np.median(e)),
            'p95_mm': float(np.percentile(e, 95)), 'max_mm': float(e.max())}


__all__ = ['CUBE_CENTRE', 'CUBE_TAGS', 'HeadMotion', 'HeadMotionScene', 'PAN_JOINT',
           'cube_centre_from_tags', 'error_summary']
