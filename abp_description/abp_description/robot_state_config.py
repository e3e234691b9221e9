"""The robot_state node's parameters as a ROS-free table (abp_common.param_spec).

Named as robot_state_publisher names its own where they mean the same (publish_frequency,
ignore_timestamp), and diff_drive_controller's enable_odom_tf for the odometry transform.
"""

from abp_common.param_spec import BOOL, DOUBLE, STRING, ParamSpec

from .robot_profile import PROFILE_SPEC

URDF_FROM_FILE, URDF_FROM_TOPIC = 'file', 'topic'

ROBOT_STATE_SPECS = (
    ParamSpec('urdf_source', STRING, URDF_FROM_FILE,
              "Where the URDF comes from: 'file' (urdf_file; the node then publishes it on "
              "robot_description, latched) or 'topic' (robot_description, latched, from "
              'another node, as on a robot whose bringup publishes it).',
              read_only=True, choices=(URDF_FROM_FILE, URDF_FROM_TOPIC)),
    ParamSpec('urdf_file', STRING, '', "The URDF file with urdf_source 'file' (empty: the "
              "robot profile's).", read_only=True),
    PROFILE_SPEC,
    ParamSpec('publish_frequency', DOUBLE, 50.0,
              'Most joint states per second of their stamps put on /tf (as '
              "robot_state_publisher's publish_frequency); 50 publishes every joint state of "
              "the sim bridge's 50 Hz.", (0.1, 1000.0)),
    ParamSpec('ignore_timestamp', BOOL, False,
              'Publish every joint state, whatever its stamp (publish_frequency unused).'),
    ParamSpec('enable_odom_tf', BOOL, True,
              'Publish odom -> base_link from the odometry topic on /tf (as '
              "diff_drive_controller's enable_odom_tf). Turn it off on a robot whose base "
              'controller publishes that transform itself.'),
    ParamSpec('cube_frame', STRING, 'cube',
              "tf frame of the aspect matcher's cube estimate (the best hypothesis of "
              'abp/aspect_observation), published as a child of the odometry frame at each '
              'odometry stamp from the first estimate on; empty: not published.',
              read_only=True),
    ParamSpec('odom_history', DOUBLE, 10.0,
              'Seconds of odometry kept to place a cube estimate, seen at an image stamp, in '
              'the odometry frame (as a tf buffer cache).', (0.5, 600.0), read_only=True),
)

__all__ = ['ROBOT_STATE_SPECS', 'URDF_FROM_FILE', 'URDF_FROM_TOPIC']
