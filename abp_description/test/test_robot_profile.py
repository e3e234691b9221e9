"""The robot profile: the uBot-6's loads with the facts the stack used to hard-code, and a
bad profile is refused with a message naming the file and the key."""

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from abp_description import controllers
from abp_description.kinematics import RobotKinematics
from abp_description.robot_profile import (
    PROFILE_SPEC,
    ProfileError,
    default_profile_path,
    load_profile,
    profile_from_dict,
)

DEFAULT = Path(default_profile_path())


def ubot_doc():
    return yaml.safe_load(DEFAULT.read_text())


def write(tmp_path, doc, name='robot.yaml'):
    """A copy of `doc` beside the uBot-6's URDF and camera file (absolute paths)."""
    doc = copy.deepcopy(doc)
    for key in ('urdf', 'camera_calibration'):
        if doc.get(key) not in (None, 'topic'):
            doc[key] = str((DEFAULT.parent / doc[key]).resolve())
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_the_ubot6_profile_is_the_default_and_holds_its_facts():
    profile = load_profile()
    assert load_profile('') is profile and load_profile(DEFAULT) is profile   # cached
    assert PROFILE_SPEC.name == 'robot_profile' and PROFILE_SPEC.default == ''
    assert profile.name == 'ubot6' and Path(profile.urdf_file()).is_file()
    assert [c.name for c in profile.controllers] == [
        'torso_controller', 'left_arm_controller', 'right_arm_controller', 'head_controller']
    assert profile.body_joints == controllers.BODY_JOINTS and len(profile.body_joints) == 11
    assert profile.sides == ('left', 'right')
    assert profile.frames.base == 'base_link'
    assert profile.hand_frames == {'left': 'left_hand_link', 'right': 'right_hand_link'}
    assert set(profile.skills) == {'orbit', 'push', 'lift', 'flip'}
    assert profile.skill_arms('push')[0] == 'right' and profile.skill_arms('orbit') == ()
    assert [b.name for b in profile.collision.bodies] == [
        'chassis', 'torso', 'head', 'left wheel', 'right wheel']
    assert profile.base.orbit.min_radius == 0.30 and profile.base.command_type == 'twist_stamped'


def test_kinematics_carry_the_profile(tmp_path):
    doc = ubot_doc()
    doc['name'] = 'copy'
    profile = load_profile(write(tmp_path, doc))
    kin = RobotKinematics(profile=profile)
    assert kin.profile is profile and kin.nq == 13
    assert np.allclose(kin.camera_pose(kin.neutral()), RobotKinematics().camera_pose(kin.neutral()))


def _refused(tmp_path, doc, *parts):
    with pytest.raises(ProfileError) as error:
        load_profile(write(tmp_path, doc, f'bad{abs(hash(str(parts)))}.yaml'))
    message = str(error.value)
    for part in parts:
        assert part in message, message
    return message


def test_a_missing_key_is_named(tmp_path):
    doc = ubot_doc()
    del doc['frames']['camera_optical']
    _refused(tmp_path, doc, 'frames.camera_optical', 'missing')
    doc = ubot_doc()
    del doc['controllers']
    _refused(tmp_path, doc, 'controllers', 'missing')


def test_an_unknown_key_is_named(tmp_path):
    doc = ubot_doc()
    doc['base']['orbit']['max_radious'] = 2.0
    _refused(tmp_path, doc, 'base.orbit', 'unknown key', 'max_radious')


def test_bad_values_are_named(tmp_path):
    doc = ubot_doc()
    doc['base']['orbit']['min_radius'] = -0.3
    _refused(tmp_path, doc, 'base.orbit.min_radius', 'must be > 0')
    doc = ubot_doc()
    doc['base']['orbit']['min_radius'] = 2.0
    _refused(tmp_path, doc, 'min_radius must be < max_radius')
    doc = ubot_doc()
    doc['base']['command_type'] = 'twist_with_covariance'
    _refused(tmp_path, doc, 'base.command_type', 'twist_stamped, twist')
    doc = ubot_doc()
    doc['collision']['bodies'][0]['box'] = [0.1, 0.1]
    _refused(tmp_path, doc, 'collision.bodies[0].box', '3 positive numbers')
    doc = ubot_doc()
    doc['controllers']['head_controller']['interface'] = 'service'
    _refused(tmp_path, doc, 'controllers.head_controller.interface', 'action, topic')
    doc = ubot_doc()
    doc['simulation']['grasp_opening_joints']['left_shoulder_roll_joint'] = 0
    _refused(tmp_path, doc, 'simulation.grasp_opening_joints.left_shoulder_roll_joint',
             'nonzero number')
    doc = ubot_doc()
    doc['models'] = 'no_such_models.npz'
    _refused(tmp_path, doc, 'models', 'no file')


def test_unknown_skills_and_impossible_arms_are_refused(tmp_path):
    doc = ubot_doc()
    doc['skills']['wave'] = {'arms': ['left']}
    _refused(tmp_path, doc, 'skills.wave', "unknown skill 'wave'", 'orbit, push, lift, flip')
    doc = ubot_doc()
    doc['skills']['push'] = {'arms': ['middle']}
    _refused(tmp_path, doc, 'skills.push', 'middle', "not among the profile's arms")
    doc = ubot_doc()
    doc['skills']['lift'] = {'arms': ['left']}
    _refused(tmp_path, doc, 'skills.lift', 'two-hand squeeze')


def test_names_the_urdf_lacks_are_refused(tmp_path):
    doc = ubot_doc()
    doc['arms']['left']['hand_frame'] = 'left_gripper_link'
    doc['controllers']['head_controller']['joints'] = ['head_pan_joint', 'head_tilt_joint']
    doc['controllers']['torso_controller']['joints'] = ['torso_yaw_joint']
    doc['torso']['joint'] = 'torso_yaw_joint'
    message = _refused(tmp_path, doc, 'does not fit its URDF', "no link 'left_gripper_link'")
    assert "controllers.torso_controller: no movable joint 'torso_yaw_joint'" in message


def test_files_that_are_not_profiles(tmp_path):
    with pytest.raises(ProfileError, match='cannot be read'):
        load_profile(tmp_path / 'missing.yaml')
    path = tmp_path / 'list.yaml'
    path.write_text('- a\n- b\n')
    with pytest.raises(ProfileError, match='top level: must be a mapping'):
        load_profile(path)
    doc = ubot_doc()
    doc['urdf'] = 'no_such.urdf'
    with pytest.raises(ProfileError, match='urdf: no file'):
        profile_from_dict(doc, str(DEFAULT))


def test_a_profile_may_take_its_urdf_from_the_topic(tmp_path):
    doc = ubot_doc()
    doc['urdf'] = 'topic'
    profile = load_profile(write(tmp_path, doc))
    assert profile.urdf_from_topic
    with pytest.raises(ProfileError, match='needs a URDF file'):
        profile.urdf_file()


def test_a_robot_without_torso_or_lift(tmp_path):
    # The shape of a smaller robot: no torso entry, ORBIT and PUSH with one arm.
    doc = ubot_doc()
    del doc['torso']
    doc['skills'] = {'orbit': None, 'push': {'arms': ['right']}}
    _refused(tmp_path, doc, 'postures.home', 'unknown key(s) torso')   # no torso to set
    for posture in doc['postures'].values():
        del posture['torso']
    profile = load_profile(write(tmp_path, doc))
    assert profile.torso is None and not profile.has_skill('lift')
    assert profile.skill_arms('push') == ('right',)
    assert profile.postures['home'].torso is None


def test_postures_fit_the_arms(tmp_path):
    doc = ubot_doc()
    doc['postures']['ready']['arms']['left'] = [0.0, 0.0]
    _refused(tmp_path, doc, 'postures.ready.arms.left', 'list of 4 numbers')
    doc = ubot_doc()
    del doc['postures']
    _refused(tmp_path, doc, 'postures', 'missing')     # the manual skills need them
    doc['skills'] = {'orbit': None}
    assert not load_profile(write(tmp_path, doc, 'orbit_only.yaml')).postures
    doc = ubot_doc()
    doc['postures']['rest'] = doc['postures']['home']
    _refused(tmp_path, doc, "unknown posture 'rest'")


PLANAR_URDF = """<?xml version="1.0"?>
<robot name="planar_bot">
  <link name="world_link"/>
  <link name="body"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01"
    ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="floor_joint" type="planar"><parent link="world_link"/><child link="body"/>
    <axis xyz="0 0 1"/></joint>
  <link name="arm"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01"
    ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="body"/><child link="arm"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 1 0"/>
    <limit lower="-1" upper="1" effort="10" velocity="1"/></joint>
  <link name="tool"/>
  <joint name="tool_joint" type="fixed"><parent link="arm"/><child link="tool"/>
    <origin xyz="0.3 0 0"/></joint>
</robot>
"""


def test_multi_dof_joints_load_and_stay_neutral(tmp_path):
    urdf = tmp_path / 'planar.urdf'
    urdf.write_text(PLANAR_URDF)
    kin = RobotKinematics(urdf)
    assert kin.joint_names == ('shoulder',) and kin.multi_dof_joints == ('floor_joint',)
    pose = kin.frame_pose(np.array([0.0]), 'tool')
    assert np.allclose(pose[:3, 3], [0.3, 0.0, 0.5])    # the planar joint at its neutral
    assert kin.frame_jacobian(np.array([0.0]), 'tool').shape == (6, 1)


def test_the_second_robot_shares_no_name_with_the_first_and_names_its_tables():
    """rover5: another base frame, camera frame, controllers and arm; ORBIT and PUSH only;
    its learned ATG model set beside it."""
    ubot, rover = load_profile(), load_profile(DEFAULT.with_name('rover5.yaml'))
    assert rover.name == 'rover5' and rover.torso is None and rover.sides == ('arm',)
    assert set(rover.skills) == {'orbit', 'push'} and not rover.has_skill('lift')
    kin = RobotKinematics(profile=rover)
    assert not set(kin.joint_names) & set(RobotKinematics().joint_names)
    assert rover.frames.base != ubot.frames.base
    assert rover.frames.camera_optical != ubot.frames.camera_optical
    assert not set(rover.controller_joints) & set(ubot.controller_joints)
    assert Path(rover.models).is_file() and Path(rover.models).parent == DEFAULT.parent
    assert ubot.models is None
