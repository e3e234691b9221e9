"""The robot's joint groups and trajectory controllers: the one table every package uses.

Controller `<name>` takes trajectory_msgs/JointTrajectory on `<name>/joint_trajectory`
(see abp_common.names) for its joints, in the order listed here.
"""

SIDES = ('left', 'right')
TORSO_JOINT = 'torso_pitch_joint'
HEAD_JOINTS = ('head_pan_joint', 'head_tilt_joint')
ARM_JOINTS = {
    side: tuple(f'{side}_{j}_joint' for j in
                ('shoulder_pitch', 'shoulder_roll', 'upper_arm_yaw', 'elbow'))
    for side in SIDES
}
WHEEL_JOINTS = ('left_wheel_joint', 'right_wheel_joint')
# Controller name -> its joints, in message order.
CONTROLLERS = {
    'torso_controller': (TORSO_JOINT,),
    'left_arm_controller': ARM_JOINTS['left'],
    'right_arm_controller': ARM_JOINTS['right'],
    'head_controller': HEAD_JOINTS,
}
# The joints trajectories command, in controller order.
BODY_JOINTS = tuple(j for joints in CONTROLLERS.values() for j in joints)


def other_side(side):
    return 'right' if side == 'left' else 'left'


__all__ = ['ARM_JOINTS', 'BODY_JOINTS', 'CONTROLLERS', 'HEAD_JOINTS', 'SIDES', 'TORSO_JOINT',
           'WHEEL_JOINTS', 'other_side']
