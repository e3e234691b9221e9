"""The mobile base's velocity command, as the robot's base controller takes it.

Jazzy's diff_drive_controller takes geometry_msgs/TwistStamped (on `<controller>/cmd_vel`,
usually remapped); older bases and many simulators take plain geometry_msgs/Twist. The
skills (publisher) and the sim bridge (subscriber) both read the two parameters below, so
one YAML section sets both sides. A mismatch (one side Twist, the other TwistStamped on
the same topic) carries nothing and DDS says nothing: `type_mismatch` names it.
"""

from geometry_msgs.msg import Twist, TwistStamped

from .param_spec import STRING, ParamSpec

TWIST_STAMPED, TWIST = 'twist_stamped', 'twist'
MESSAGE_TYPES = {TWIST_STAMPED: TwistStamped, TWIST: Twist}
TYPE_NAMES = {TWIST_STAMPED: 'geometry_msgs/msg/TwistStamped', TWIST: 'geometry_msgs/msg/Twist'}

SPECS = (
    ParamSpec('base_command_type', STRING, TWIST_STAMPED, 'Message type of the base '
              "velocity command: twist_stamped (geometry_msgs/TwistStamped, what Jazzy's "
              'diff_drive_controller takes) or twist (geometry_msgs/Twist, older bases).',
              read_only=True, choices=tuple(MESSAGE_TYPES)),
    ParamSpec('base_command_topic', STRING, 'cmd_vel', 'Topic of the base velocity command '
              "(relative names resolve in the node's namespace; diff_drive_controller "
              'listens on diff_drive_controller/cmd_vel unless remapped).', read_only=True),
)


def message_type(kind):
    return MESSAGE_TYPES[kind]


def command(kind, v, w, stamp=None, base_frame=''):
    """The command driving at v (m/s) and w (rad/s); `stamp` (builtin_interfaces/Time)
    and `base_frame` (the robot profile's) for TwistStamped, in the base frame as
    diff_drive_controller expects."""
    if kind == TWIST:
        msg = Twist()
        twist = msg
    else:
        msg = TwistStamped()
        msg.header.frame_id = base_frame
        if stamp is not None:
            msg.header.stamp = stamp
        twist = msg.twist
    twist.linear.x, twist.angular.z = float(v), float(w)
    return msg


def twist_of(msg):
    """The Twist inside a command of either type."""
    return msg.twist if isinstance(msg, TwistStamped) else msg


def type_mismatch(kind, topic, endpoints):
    """A sentence naming the endpoints (rclpy TopicEndpointInfo) on `topic` that use the
    other base command type, or None when there is none."""
    others = sorted({f'{e.node_namespace.rstrip("/")}/{e.node_name} ({e.topic_type})'
                     for e in endpoints if e.topic_type != TYPE_NAMES[kind]})
    if not others:
        return None
    return (f'{topic} carries {TYPE_NAMES[kind]} here but {", ".join(others)} use another '
            'type: set base_command_type the same on both sides')


__all__ = ['SPECS', 'TWIST', 'TWIST_STAMPED', 'command', 'message_type', 'twist_of',
           'type_mismatch']
