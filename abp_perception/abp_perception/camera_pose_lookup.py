"""The camera's pose in the base frame at an image's stamp, from /joint_states (plain
Python, no rclpy): the artag_detector's forward kinematics, kept here so that the node
stays wiring.

The node takes /joint_states on a thread of its own and images on its executor: `add`
runs on the first, `must_wait` and `pose_at` on both, so the joint-state buffer and the
newest joint vector are read and written under one lock. Kinematics (Pinocchio) runs
outside it, on the image side only.

`lookup` 'interpolate' (the default): the joints that move the camera frame are
interpolated at the image stamp (`joint_state_buffer.JointStateBuffer`); 'latest': the
newest joint state. A fixed camera pose (no joints) replaces both."""

import threading

from .camera_model import joints_moving_frame
from .joint_state_buffer import JointStateBuffer, OutsideBuffer


class CameraPoseLookup:
    def __init__(self, kinematics, lookup='interpolate', buffer_s=2.0, tolerance_s=0.02,
                 fixed_pose=None):
        self.kinematics = kinematics
        self.lookup = lookup
        self.fixed_pose = fixed_pose
        self._buffer = JointStateBuffer(buffer_s, tolerance_s)
        self._lock = threading.Lock()
        self._newest = None          # joint vector of the newest joint states
        self._moving = {}            # URDF frame -> joints that move it

    @property
    def has_joint_states(self):
        return self._newest is not None

    def add(self, t_ns, names, positions):
        """One /joint_states message; ValueError when it names no joint of the robot."""
        joints = dict(zip(names, positions))
        if not any(self.kinematics.has_joint(n) for n in joints):
            raise ValueError('joint_states names no joint of the robot')
        with self._lock:
            self._newest = self.kinematics.q_from_mapping(joints, default=self._newest)
            self._buffer.add(t_ns, names, positions)

    def _joints_of(self, frame):
        joints = self._moving.get(frame)
        if joints is None:
            joints = self._moving[frame] = joints_moving_frame(self.kinematics.model, frame)
        return joints

    def must_wait(self, t_ns, frame):
        """Whether the joint states that move `frame` do not reach stamp `t_ns` yet."""
        if self.lookup != 'interpolate' or self._newest is None or \
                self.fixed_pose is not None or t_ns == 0:
            return False
        joints = self._joints_of(frame)
        with self._lock:
            newest = self._buffer.newest_of(joints)
        return newest is not None and newest < t_ns

    def pose_at(self, frame, t_ns):
        """(pose of URDF `frame` in the base frame at `t_ns`, or None before any joint
        state; the joints taken unstamped, if any). The newest joint state is taken for
        'latest' and for an unstamped image (t_ns 0). Raises OutsideBuffer when the
        buffered joint states do not reach the stamp."""
        if self.fixed_pose is not None:
            return self.fixed_pose, ()
        interpolate = self.lookup == 'interpolate' and t_ns != 0
        joints = self._joints_of(frame)
        with self._lock:
            q = self._newest
            found = self._buffer.at(t_ns, joints) if interpolate and q is not None else None
        if q is None:
            return None, ()
        unstamped = ()
        if found is not None:
            unstamped = found.unstamped
            q = self.kinematics.q_from_mapping(found.positions, default=q)
        return self.kinematics.frame_pose(q, frame), unstamped


__all__ = ['CameraPoseLookup', 'OutsideBuffer']
