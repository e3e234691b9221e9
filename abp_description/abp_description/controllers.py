"""The default robot's joint groups and trajectory controllers, read from its profile.

Controller `<name>` takes trajectory_msgs/JointTrajectory on `<name>/joint_trajectory`
(see abp_common.names) for its joints, in the order listed in the profile. These tables
are the shipped (uBot-6) profile's, for code that serves that robot only (benchmarks);
a node that takes a `robot_profile` reads `RobotProfile.controller_joints` and friends
from the profile it loaded instead.
"""

from .robot_profile import load_profile

_PROFILE = load_profile()
SIDES = _PROFILE.sides
TORSO_JOINT = _PROFILE.torso.joint
HEAD_JOINTS = (_PROFILE.head.pan_joint, _PROFILE.head.tilt_joint)
ARM_JOINTS = _PROFILE.arm_joints
WHEEL_JOINTS = _PROFILE.base.wheel_joints
# Controller name -> its joints, in message order.
CONTROLLERS = _PROFILE.controller_joints
# The joints trajectories command, in controller order.
BODY_JOINTS = _PROFILE.body_joints


def other_side(side):
    return 'right' if side == 'left' else 'left'


__all__ = ['ARM_JOINTS', 'BODY_JOINTS', 'CONTROLLERS', 'HEAD_JOINTS', 'SIDES', 'TORSO_JOINT',
           'WHEEL_JOINTS', 'other_side']
