"""The robot's tf tree from its kinematics, as robot_state_publisher computes it (no rclpy).

`KinematicTree` turns the URDF's joints into tf edges: one transform per joint, from the
joint's parent link to its child link (tf's header.frame_id = parent, child_frame_id =
child). Fixed joints give the static transforms (/tf_static), the others a transform at
each joint state (/tf). The transforms are the Pinocchio placements of
`kinematics.RobotKinematics`, so /tf composes to exactly the poses the rest of the stack
computes (the detector's camera pose is `RobotKinematics.camera_pose`).

`PublishThrottle` is robot_state_publisher's rate limit on the joint states' stamps;
`PoseHistory` a short buffer of stamped poses interpolated as tf2 does (linear
translation, slerp rotation), used to place an object seen in the base frame at an image
stamp into the odometry frame.
"""

from collections import deque
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .frames import quaternion_from_rotation, rotation_from_quaternion

_NS = 1_000_000_000


@dataclass(frozen=True)
class Edge:
    """One URDF joint as a tf edge."""
    joint: str
    parent: str
    child: str
    moving: bool


class KinematicTree:
    """The tf edges of a `RobotKinematics` model and their transforms (4x4 matrices)."""

    def __init__(self, kin):
        self.kin = kin
        model = kin.model
        frames = list(model.frames)
        child_of = {f.parentFrame: i for i, f in enumerate(frames)
                    if f.type == pin.FrameType.BODY}
        edges, frame_ids = [], {}
        for index, frame in enumerate(frames):
            if index == 0 or frame.type not in (pin.FrameType.JOINT,
                                                 pin.FrameType.FIXED_JOINT):
                continue   # frame 0 is Pinocchio's own 'universe'
            if index not in child_of:
                raise ValueError(f'{kin.urdf_path}: joint {frame.name} has no child link')
            parent, child = frames[frame.parentFrame], frames[child_of[index]]
            moving = frame.type == pin.FrameType.JOINT
            edges.append(Edge(frame.name, parent.name, child.name, moving))
            frame_ids[parent.name] = frame.parentFrame
            frame_ids[child.name] = child_of[index]
        self.edges = tuple(edges)
        children = {e.child for e in edges}
        roots = sorted({e.parent for e in edges} - children) or [frames[-1].name]
        if len(roots) != 1:
            raise ValueError(f'{kin.urdf_path}: links {roots} have no parent (not one tree)')
        self.root = roots[0]   # the robot's base link: the child of odom
        self._ids = frame_ids
        self._moving = {e.joint: e for e in edges if e.moving}
        self.links = tuple(sorted(frame_ids))

    @property
    def fixed_edges(self):
        return tuple(e for e in self.edges if not e.moving)

    @property
    def moving_edges(self):
        return tuple(self._moving.values())

    def _relative(self, edge):
        """(translation, unit quaternion x, y, z, w) of the edge's child in its parent,
        from the last forward-kinematics pass (self.kin.data)."""
        placements = self.kin.data.oMf
        relative = placements[self._ids[edge.parent]].actInv(placements[self._ids[edge.child]])
        quaternion = pin.Quaternion(relative.rotation)
        quaternion.normalize()
        return relative.translation.copy(), quaternion.coeffs().copy()   # coeffs: x, y, z, w

    def _forward(self, q):
        pin.framesForwardKinematics(self.kin.model, self.kin.data, self.kin.to_pinocchio(q))

    def static_transforms(self):
        """[(edge, translation, quaternion)] of every fixed joint: constant, so computed
        at the neutral pose."""
        self._forward(self.kin.neutral())
        return [(e, *self._relative(e)) for e in self.fixed_edges]

    def moving_transforms(self, positions):
        """[(edge, translation, quaternion)] of the moving joints named in `positions`
        ({joint: position}); joints the robot does not have are ignored, as
        robot_state_publisher does."""
        named = [self._moving[name] for name in positions if name in self._moving]
        if not named:
            return []
        self._forward(self.kin.q_from_mapping(positions))
        return [(e, *self._relative(e)) for e in named]

    def link_pose(self, positions, link):
        """4x4 pose of `link` in the root link at the joint positions {joint: position}."""
        return self.kin.frame_pose(self.kin.q_from_mapping(positions), link)


def translation_quaternion(matrix):
    """(translation (3,), unit quaternion (x, y, z, w)) of a 4x4 pose."""
    matrix = np.asarray(matrix, dtype=float)
    return matrix[:3, 3].copy(), quaternion_from_rotation(matrix[:3, :3])


def matrix_from(translation, quaternion):
    """4x4 pose from a translation and a quaternion (x, y, z, w; normalised here)."""
    out = np.eye(4)
    out[:3, :3] = rotation_from_quaternion(*quaternion)
    out[:3, 3] = translation
    return out


class PublishThrottle:
    """robot_state_publisher's rule: a joint state is published when its stamp is at least
    1/frequency after the stamp last published for the least recently published of its
    joints (a joint never published passes at once). `reset()` after time went back."""

    def __init__(self, frequency_hz):
        if not frequency_hz > 0:
            raise ValueError('publish frequency must be positive')
        self.interval_ns = int(round(_NS / frequency_hz))
        self._last = {}

    def due(self, joint_names, stamp_ns):
        last = [self._last.get(name) for name in joint_names]
        if not last or None in last:
            return True
        return stamp_ns >= min(last) + self.interval_ns

    def published(self, joint_names, stamp_ns):
        for name in joint_names:
            self._last[name] = stamp_ns

    def reset(self):
        self._last.clear()


class PoseHistory:
    """Stamped poses of one frame (odometry) as (translation, unit quaternion x, y, z, w),
    kept for `span_s` seconds of stamps; `at(stamp)` is the 4x4 pose interpolated between
    the two nearest (never extrapolated), as tf2 does."""

    def __init__(self, span_s=10.0):
        self.span_ns = int(span_s * _NS)
        self._stamps = deque()
        self._poses = deque()

    def __len__(self):
        return len(self._stamps)

    def add(self, stamp_ns, translation, quaternion):
        pose = (translation, quaternion)
        if self._stamps and stamp_ns < self._stamps[-1]:
            self.clear()   # time went back (a restarted simulation, a replay)
        if self._stamps and stamp_ns == self._stamps[-1]:
            self._poses[-1] = pose
            return
        self._stamps.append(int(stamp_ns))
        self._poses.append(pose)
        while self._stamps[0] < stamp_ns - self.span_ns:
            self._stamps.popleft()
            self._poses.popleft()

    def clear(self):
        self._stamps.clear()
        self._poses.clear()

    def latest_stamp(self):
        return self._stamps[-1] if self._stamps else None

    def span(self):
        """(oldest, newest) stamp kept, or None."""
        return (self._stamps[0], self._stamps[-1]) if self._stamps else None

    def at(self, stamp_ns):
        """The 4x4 pose at `stamp_ns`, or None when it is outside the history."""
        stamps = self._stamps
        if not stamps or not stamps[0] <= stamp_ns <= stamps[-1]:
            return None
        i = int(np.searchsorted(np.fromiter(stamps, dtype=np.int64), stamp_ns))
        if stamps[i] == stamp_ns:
            return matrix_from(*self._poses[i])
        return interpolate(matrix_from(*self._poses[i - 1]), matrix_from(*self._poses[i]),
                           (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1]))


def interpolate(a, b, fraction):
    """4x4 pose a fraction of the way from a to b: linear translation, slerp rotation."""
    from scipy.spatial.transform import Rotation, Slerp  # slow to import: when needed
    rotations = Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]]))
    out = np.eye(4)
    out[:3, :3] = Slerp([0.0, 1.0], rotations)(fraction).as_matrix()
    out[:3, 3] = (1.0 - fraction) * a[:3, 3] + fraction * b[:3, 3]
    return out


__all__ = ['Edge', 'KinematicTree', 'PoseHistory', 'PublishThrottle', 'interpolate',
           'matrix_from', 'translation_quaternion']
