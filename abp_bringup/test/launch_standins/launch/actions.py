"""Stand-in for `launch.actions` (Jazzy): the arguments of an action, recorded."""

from launch import checked

# launch.Action.__init__ takes `condition`.
ACTION_KWARGS = ('condition',)


class DeclareLaunchArgument:
    def __init__(self, name, *, default_value=None, description=None, choices=None, **kwargs):
        self.name = name
        self.default_value = default_value
        self.description = description
        self.choices = choices
        self.condition = checked('DeclareLaunchArgument', kwargs, ACTION_KWARGS).get('condition')
