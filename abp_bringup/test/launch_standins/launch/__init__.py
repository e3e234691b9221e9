"""Stand-in for ROS 2 Jazzy's `launch` package (see ../README.md): records only."""


class LaunchDescription:
    def __init__(self, initial_entities=None, *, deprecated_reason=None):
        self.entities = list(initial_entities or [])


def checked(owner, kwargs, allowed):
    """Refuse a keyword argument the real Jazzy class does not take."""
    unknown = set(kwargs) - set(allowed)
    if unknown:
        raise TypeError(f'{owner}: unexpected keyword arguments {sorted(unknown)}')
    return kwargs
