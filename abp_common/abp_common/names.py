"""Topic, service and action names of the abp graph, defined once.

All are relative (no leading slash), so `--ros-args -r __ns:=/robot1` (or
`start_graph.sh --namespace robot1`) moves a whole graph under a namespace; the
camera and controller topics follow the usual ROS driver names. `/clock` stays
absolute, as rclpy's time source subscribes to it. Tools that take absolute names
(bag topics) use `absolute(name, namespace)`.
"""

# Robot sensors and commands (sim bridge or the robot's drivers; docs/INTERFACES.md).
IMAGE = 'camera/image_raw'
CAMERA_INFO = 'camera/camera_info'
JOINT_STATES = 'joint_states'
ODOM = 'odom'
CMD_VEL = 'cmd_vel'
CLOCK = '/clock'
# Controller name -> its JointTrajectory command topic.
TRAJECTORY_TOPIC = '{controller}/joint_trajectory'

# The recognition graph.
TAG_DETECTIONS = 'abp/tag_detections'
ASPECT_OBSERVATION = 'abp/aspect_observation'
BELIEF = 'abp/belief'
BELIEFS = 'abp/beliefs'  # every object's belief (abp_msgs/SceneBelief)
EXECUTED_ACTION = 'abp/executed_action'
PLAN = 'abp/plan'
MARKERS = 'abp/markers'
SKILLS_ACTIVE = 'abp/skills/active'
GROUND_TRUTH = 'abp/sim/ground_truth'  # tests and benchmarks only: no recogniser reads it
SCENE_TRUTH = 'abp/sim/scene_truth'    # every cube of the scene; tests and benchmarks only

# Services and actions.
RESET_BELIEF = 'abp/reset_belief'
CHECK_FEASIBILITY = 'abp/skills/check_feasibility'
RESET_WORLD = 'sim_bridge/reset_world'
RECOGNIZE = 'abp/recognize'
SKILL_ACTION = 'abp/skills/{skill}'  # skill: orbit, push, lift, flip
SKILLS = ('orbit', 'push', 'lift', 'flip')


def trajectory_topic(controller):
    return TRAJECTORY_TOPIC.format(controller=controller)


def skill_action(skill):
    if skill not in SKILLS:
        raise ValueError(f'unknown skill {skill!r}: one of {", ".join(SKILLS)}')
    return SKILL_ACTION.format(skill=skill)


def absolute(name, namespace=''):
    """`name` resolved in `namespace` ('' or '/' = the root), as tools like bags show it."""
    if name.startswith('/'):
        return name
    namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return f'{namespace}/{name}'
