"""/tf gives the camera pose the detector uses (issue 32), without DDS: the detector's own
joint-state lookup at an image stamp (abp_perception.joint_state_buffer, then the forward
kinematics, as artag_detector_node._camera_pose does) against robot_state's per-joint
transforms at the joint states' stamps (abp_description.robot_state), interpolated edge
by edge as tf2 does (linear translation, slerp rotation) and composed up to base_link.
The DDS side (what robot_state publishes is what a tf-only listener gets) is
abp_description/test/test_robot_state_node.py."""

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from abp_description.kinematics import CAMERA_FRAME, RobotKinematics
from abp_description.robot_state import KinematicTree, matrix_from
from abp_perception.joint_state_buffer import JointStateBuffer

STEP_NS = 20_000_000
T0_NS = 5_000_000_000


def joint_states(kin, count):
    """(stamp, positions) of a head sweep with uneven steps, the torso pitching too."""
    out = []
    for k in range(count):
        t = k * STEP_NS * 1e-9
        q = kin.clip(np.linspace(-0.3, 0.4, kin.nq))
        q[kin.joint_index('head_pan_joint')] = 0.9 * np.sin(3.0 * t)
        q[kin.joint_index('head_tilt_joint')] = 0.2 + 0.5 * t * t
        q[kin.joint_index('torso_pitch_joint')] = 0.1 * np.cos(4.0 * t)
        out.append((T0_NS + k * STEP_NS, kin.clip(q)))
    return out


def tf_pose(tree, samples, t_ns):
    """base_link -> camera_optical_frame from the tree's edges, each interpolated at t."""
    (ta, qa), (tb, qb) = next((a, b) for a, b in zip(samples, samples[1:])
                              if a[0] <= t_ns <= b[0])
    fraction = (t_ns - ta) / (tb - ta)
    names = tree.kin.joint_names
    at_a = {e.child: (e.parent, matrix_from(tr, q))
            for e, tr, q in tree.moving_transforms(dict(zip(names, qa)))}
    at_b = {e.child: (e.parent, matrix_from(tr, q))
            for e, tr, q in tree.moving_transforms(dict(zip(names, qb)))}
    static = {e.child: (e.parent, matrix_from(tr, q)) for e, tr, q in tree.static_transforms()}
    pose, frame = np.eye(4), CAMERA_FRAME
    while frame != tree.root:
        if frame in static:
            parent, edge = static[frame]
        else:
            parent, a = at_a[frame]
            b = at_b[frame][1]
            edge = np.eye(4)
            edge[:3, :3] = Slerp([0, 1], Rotation.from_matrix([a[:3, :3], b[:3, :3]]))(
                fraction).as_matrix()
            edge[:3, 3] = (1 - fraction) * a[:3, 3] + fraction * b[:3, 3]
        pose, frame = edge @ pose, parent
    return pose


def test_interpolated_tf_is_the_detector_camera_pose():
    kin = RobotKinematics()
    tree = KinematicTree(kin)
    samples = joint_states(kin, 15)
    buffer = JointStateBuffer()
    for stamp, q in samples:
        buffer.add(stamp, kin.joint_names, q)
    worst = (0.0, 0.0)
    for k in range(len(samples) - 1):
        for fraction in (0.1, 0.5, 0.77):
            t_ns = samples[k][0] + int(fraction * STEP_NS)
            # The detector: the joints at the image stamp, then forward kinematics.
            found = buffer.at(t_ns, kin.joint_names)
            detector = kin.frame_pose(kin.q_from_mapping(found.positions), CAMERA_FRAME)
            got = tf_pose(tree, samples, t_ns)
            angle = np.degrees(Rotation.from_matrix(got[:3, :3].T @ detector[:3, :3])
                               .magnitude())
            worst = (max(worst[0], float(np.linalg.norm(got[:3, 3] - detector[:3, 3]))),
                     max(worst[1], float(angle)))
    assert worst[0] <= 1e-3 and worst[1] <= 0.1, worst
