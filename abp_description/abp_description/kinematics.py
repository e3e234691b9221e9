"""Forward kinematics of the robot of a robot profile on Pinocchio (no rclpy).

Joint vectors here are what /joint_states carries: one position per 1-DOF joint (the
uBot-6: 13), in `RobotKinematics.joint_names` order. Pinocchio stores each continuous
joint as (cos, sin); `to_pinocchio` converts. Multi-DOF joints (a floating or planar base
in the URDF) carry no joint state: they are left out of `joint_names` and held at their
neutral configuration, because the base's planar pose in the world comes from odometry.
Poses are 4x4 homogeneous matrices in the profile's base frame (the uBot-6's is on the
floor between the wheels, x forward, z up).
"""

import numpy as np
import pinocchio as pin

from abp_description.frames import base_to_world
from abp_description.robot_profile import load_profile

# The shipped profile's frames, for callers that serve that robot only.
_DEFAULT = load_profile()
CAMERA_FRAME = _DEFAULT.frames.camera_optical
HAND_FRAMES = _DEFAULT.hand_frames
BASE_FRAME = _DEFAULT.frames.base


class RobotKinematics:
    """Pinocchio model of the robot with a joint-state-shaped interface."""

    def __init__(self, urdf=None, urdf_xml=None, profile=None):
        """The robot of `profile` (a RobotProfile; default: the shipped uBot-6 profile),
        from the URDF file `urdf` (default: the profile's), or from the URDF text
        `urdf_xml` (a robot_description received on a topic; `urdf_path` then names no
        file)."""
        self.profile = profile if profile is not None else load_profile()
        if urdf_xml is not None:
            self.urdf_path = '<robot_description>'
            self.model = pin.buildModelFromXML(urdf_xml)
        else:
            self.urdf_path = str(urdf) if urdf is not None else self.profile.urdf_file()
            self.model = pin.buildModelFromUrdf(self.urdf_path)
        self.data = self.model.createData()
        named = list(zip(self.model.names[1:], list(self.model.joints)[1:]))  # no 'universe'
        # Only 1-DOF joints have a joint state; multi-DOF ones stay neutral (module doc).
        self.multi_dof_joints = tuple(n for n, j in named if j.nv != 1)
        named = [(n, j) for n, j in named if j.nv == 1]
        joints = [j for _, j in named]
        self.joint_names = tuple(n for n, _ in named)
        self._neutral_pin = pin.neutral(self.model)
        self._idx_q = np.array([j.idx_q for j in joints], dtype=int)
        self._idx_v = np.array([j.idx_v for j in joints], dtype=int)
        # A joint with nq == 2 and nv == 1 is a continuous (unbounded) revolute joint.
        self._continuous = np.array([j.nq == 2 for j in joints], dtype=bool)
        lower = self.model.lowerPositionLimit[self._idx_q].copy()
        upper = self.model.upperPositionLimit[self._idx_q].copy()
        lower[self._continuous] = -np.inf
        upper[self._continuous] = np.inf
        self.lower_limits = lower
        self.upper_limits = upper
        self.velocity_limits = self.model.velocityLimit[self._idx_v].copy()
        self.effort_limits = self.model.effortLimit[self._idx_v].copy()

    @property
    def nq(self):
        """Number of joint positions (one per actuated joint, as in /joint_states)."""
        return len(self.joint_names)

    @property
    def continuous_joints(self):
        return tuple(n for n, c in zip(self.joint_names, self._continuous) if c)

    def joint_index(self, name):
        return self.joint_names.index(name)

    def neutral(self):
        """All joints at zero (arms hanging, head level), clipped into the limits."""
        return np.clip(np.zeros(self.nq), self.lower_limits, self.upper_limits)

    def q_from_mapping(self, positions, default=None):
        """Joint vector from a {name: position} mapping (e.g. a JointState); others default."""
        q = self.neutral() if default is None else np.array(default, dtype=float)
        for name, value in positions.items():
            if name in self.joint_names:
                q[self.joint_names.index(name)] = float(value)
        return q

    def within_limits(self, q, tol=1e-9):
        q = np.asarray(q, dtype=float)
        return bool(np.all(q >= self.lower_limits - tol) and np.all(q <= self.upper_limits + tol))

    def clip(self, q):
        return np.clip(np.asarray(q, dtype=float), self.lower_limits, self.upper_limits)

    def to_pinocchio(self, q):
        """Pinocchio configuration (cos/sin for the continuous joints) from joint positions."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise ValueError(f'expected {self.nq} joint positions, got shape {q.shape}')
        q_pin = self._neutral_pin.copy()
        for i, (iq, cont) in enumerate(zip(self._idx_q, self._continuous)):
            if cont:
                q_pin[iq], q_pin[iq + 1] = np.cos(q[i]), np.sin(q[i])
            else:
                q_pin[iq] = q[i]
        return q_pin

    def has_joint(self, name):
        """True when `name` is one of the robot's joints."""
        return name in self.joint_names

    def has_frame(self, name):
        return self.model.existFrame(name)

    def _frame_id(self, name):
        if not self.model.existFrame(name):
            raise KeyError(f'no frame {name!r} in {self.urdf_path}')
        return self.model.getFrameId(name)

    def frame_pose(self, q, frame_name):
        """4x4 pose of a frame in base_link at joint positions q."""
        fid = self._frame_id(frame_name)
        pin.framesForwardKinematics(self.model, self.data, self.to_pinocchio(q))
        return self.data.oMf[fid].homogeneous.copy()

    def frame_poses(self, q, frame_names):
        """Several frame poses from one forward-kinematics pass: {name: 4x4}."""
        ids = [self._frame_id(n) for n in frame_names]
        pin.framesForwardKinematics(self.model, self.data, self.to_pinocchio(q))
        return {n: self.data.oMf[i].homogeneous.copy() for n, i in zip(frame_names, ids)}

    def camera_pose(self, q):
        """Pose of the profile's camera optical frame (z forward, x right, y down) in the
        base frame."""
        return self.frame_pose(q, self.profile.frames.camera_optical)

    def hand_pose(self, q, side):
        return self.frame_pose(q, self.profile.hand_frames[side])

    def frame_jacobian(self, q, frame_name):
        """6 x nq Jacobian (linear; angular) of a frame, in base_link-aligned axes."""
        fid = self._frame_id(frame_name)
        jac = pin.computeFrameJacobian(
            self.model, self.data, self.to_pinocchio(q), fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        return jac[:, self._idx_v]


def look_at(kin, q, target_in_base, iterations=12):
    """Head pan/tilt (within limits) pointing the camera's optical axis at `target_in_base`
    (a point in base_link). Returns (q with the head joints set, angular error in rad).

    The one head-aiming rule of the project: the skills, the simulator and the benchmark
    scenes all aim the camera with it."""
    q = np.asarray(q, dtype=float).copy()
    target = np.asarray(target_in_base, dtype=float)
    head = kin.profile.head
    i_pan, i_tilt = kin.joint_index(head.pan_joint), kin.joint_index(head.tilt_joint)

    def direction_in_camera(q):
        cam = kin.camera_pose(q)
        return cam[:3, :3].T @ (target - cam[:3, 3])  # optical frame: x right, y down, z ahead

    err = np.pi
    for _ in range(iterations):
        d = direction_in_camera(q)
        if d[2] <= 1e-9:
            # Behind the camera: turn towards it roughly first.
            q[i_pan] += 0.5 * np.sign(-d[0]) if abs(d[0]) > 1e-9 else 0.5
        else:
            # Positive pan turns the view left (-x), positive tilt turns it down (+y).
            q[i_pan] -= np.arctan2(d[0], d[2])
            q[i_tilt] += np.arctan2(d[1], np.hypot(d[0], d[2]))
        q = kin.clip(q)
        d = direction_in_camera(q)
        err = float(np.arccos(np.clip(d[2] / max(np.linalg.norm(d), 1e-12), -1, 1)))
        if err < 1e-4:
            break
    return q, err


def look_at_world(kin, q, base_pose, target_in_world, iterations=12):
    """look_at for a world point seen from the planar base pose (x, y, yaw)."""
    world_to_base = np.linalg.inv(base_to_world(base_pose))
    target = world_to_base[:3, :3] @ np.asarray(target_in_world, dtype=float) \
        + world_to_base[:3, 3]
    return look_at(kin, q, target, iterations)
