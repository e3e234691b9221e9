"""Stand-in for `launch_ros.actions` (Jazzy): Node and SetParameter, recorded."""

from launch import checked

# Keyword arguments Node passes on to launch.actions.ExecuteProcess / ExecuteLocal and
# launch.Action (Jazzy).
PROCESS_KWARGS = (
    'condition', 'cwd', 'env', 'additional_env', 'shell', 'sigterm_timeout',
    'sigkill_timeout', 'emulate_tty', 'prefix', 'output', 'output_format', 'log_cmd',
    'on_exit', 'respawn', 'respawn_delay', 'respawn_max_retries', 'cached_output')


class Node:
    def __init__(self, *, executable, package=None, name=None, namespace=None,
                 exec_name=None, parameters=None, remappings=None, ros_arguments=None,
                 arguments=None, **kwargs):
        self.executable = executable
        self.package = package
        self.name = name
        self.namespace = namespace
        self.parameters = list(parameters or [])
        self.remappings = remappings
        self.ros_arguments = ros_arguments
        self.arguments = arguments
        self.process = checked('Node', kwargs, PROCESS_KWARGS)
        self.condition = kwargs.get('condition')


class SetParameter:
    def __init__(self, name, value, **kwargs):
        self.name = name
        self.value = value
        self.condition = checked('SetParameter', kwargs, ('condition',)).get('condition')
