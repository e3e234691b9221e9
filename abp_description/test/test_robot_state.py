"""robot_state (no ROS graph): the tf edges of the URDF, their transforms against the
kinematics, robot_state_publisher's publish throttle, and the interpolated pose history."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import abp_description
from abp_description.frames import rot_z
from abp_description.kinematics import RobotKinematics
from abp_description.robot_state import (
    KinematicTree,
    PoseHistory,
    PublishThrottle,
    interpolate,
    matrix_from,
    translation_quaternion,
)


@pytest.fixture(scope='module')
def tree():
    return KinematicTree(RobotKinematics())


def urdf_joints():
    """{joint: (type, parent, child)} read from the URDF itself."""
    root = ET.parse(abp_description.urdf_path()).getroot()
    return {j.get('name'): (j.get('type'), j.find('parent').get('link'),
                            j.find('child').get('link')) for j in root.findall('joint')}


def test_one_edge_per_urdf_joint_parent_to_child(tree):
    expected = urdf_joints()
    assert {e.joint: (e.parent, e.child) for e in tree.edges} == \
        {name: (parent, child) for name, (_, parent, child) in expected.items()}
    assert {e.joint for e in tree.fixed_edges} == \
        {name for name, (kind, _, _) in expected.items() if kind == 'fixed'}
    assert tree.root == 'base_link'
    assert 'camera_optical_frame' in tree.links


def compose(tree, transforms, link):
    """Pose of `link` in the root by walking the edges up."""
    by_child = {e.child: (e.parent, matrix_from(t, q)) for e, t, q in transforms}
    pose = np.eye(4)
    while link != tree.root:
        parent, matrix = by_child[link]
        pose = matrix @ pose
        link = parent
    return pose


def test_edges_compose_to_the_kinematics_poses(tree):
    kin = tree.kin
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = kin.clip(rng.uniform(-1.5, 1.5, kin.nq))
        transforms = tree.moving_transforms(dict(zip(kin.joint_names, q)))
        transforms += tree.static_transforms()
        assert len(transforms) == len(tree.edges)
        for _, _, quaternion in transforms:
            assert np.linalg.norm(quaternion) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(compose(tree, transforms, 'camera_optical_frame'),
                                   kin.camera_pose(q), atol=1e-12)
        for side in ('left', 'right'):
            np.testing.assert_allclose(compose(tree, transforms, f'{side}_hand_link'),
                                       kin.hand_pose(q, side), atol=1e-12)


def test_only_the_named_joints_are_published(tree):
    transforms = tree.moving_transforms({'head_pan_joint': 0.3, 'not_a_joint': 1.0})
    assert [(e.parent, e.child) for e, _, _ in transforms] == [('torso_link',
                                                                'head_pan_link')]
    _, translation, quaternion = transforms[0]
    assert Rotation.from_quat(quaternion).as_rotvec() == pytest.approx([0, 0, 0.3])
    assert tree.moving_transforms({'not_a_joint': 1.0}) == []


def test_a_urdf_text_builds_the_same_tree(tree):
    with open(abp_description.urdf_path()) as stream:
        other = KinematicTree(RobotKinematics(urdf_xml=stream.read()))
    assert other.edges == tree.edges
    with pytest.raises(ValueError):
        RobotKinematics(urdf_xml='<robot name="broken"><link name="a"/><joint')


def test_throttle_follows_robot_state_publisher():
    throttle = PublishThrottle(20.0)          # 50 ms
    names = ['a', 'b']
    assert throttle.due(names, 1_000_000_000)
    throttle.published(names, 1_000_000_000)
    assert not throttle.due(names, 1_049_999_999)
    assert throttle.due(names, 1_050_000_000)
    assert throttle.due(['a', 'new'], 1_000_000_001)   # a joint never published
    throttle.reset()
    assert throttle.due(names, 0)
    with pytest.raises(ValueError):
        PublishThrottle(0.0)


def pose(x, y, yaw):
    out = np.eye(4)
    out[:3, :3] = rot_z(yaw)
    out[:2, 3] = x, y
    return out


def test_pose_history_interpolates_and_never_extrapolates():
    history = PoseHistory(span_s=1.0)

    def add(t_ns, x, y, yaw):
        history.add(t_ns, *translation_quaternion(pose(x, y, yaw)))
    add(1_000_000_000, 0.0, 0.0, 0.0)
    add(1_100_000_000, 1.0, 0.0, 0.4)
    np.testing.assert_allclose(history.at(1_025_000_000), pose(0.25, 0.0, 0.1), atol=1e-12)
    np.testing.assert_allclose(history.at(1_100_000_000), pose(1.0, 0.0, 0.4), atol=1e-12)
    assert history.at(999_999_999) is None and history.at(1_100_000_001) is None
    add(2_150_000_000, 2.0, 0.0, 0.0)   # the first two fall out of the span
    assert len(history) == 1
    add(5, 0.0, 0.0, 0.0)               # time went back: start again
    assert len(history) == 1 and history.latest_stamp() == 5


def test_interpolate_slerps_the_rotation():
    a, b = pose(0, 0, -0.2), pose(0, 0, 0.6)
    np.testing.assert_allclose(interpolate(a, b, 0.5), pose(0, 0, 0.2), atol=1e-12)
    translation, quaternion = translation_quaternion(pose(1.0, 2.0, 0.5))
    assert np.allclose(translation, [1.0, 2.0, 0.0]) and quaternion[3] > 0
    np.testing.assert_allclose(matrix_from(translation, quaternion), pose(1.0, 2.0, 0.5),
                               atol=1e-12)
