"""The message types of abp bags for the `rosbags` library: ROS 2 Jazzy's standard types
plus every abp_msgs message, read from its .msg files (no rclpy, no generated code).

Used by the bag recorder and player (abp_bringup) and by the ATG learner's bag source
(abp_belief); `rosbags` is imported only when a typestore is made.
"""

import functools
import pathlib


def abp_msgs_dir() -> pathlib.Path:
    """The installed abp_msgs share directory (ament index), or the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return pathlib.Path(get_package_share_directory('abp_msgs'))
    except (ImportError, LookupError):
        return pathlib.Path(__file__).resolve().parents[2] / 'abp_msgs'


@functools.lru_cache(maxsize=1)
def typestore():
    """Jazzy's standard types plus every abp_msgs message. Raises FileNotFoundError when
    the abp_msgs definitions cannot be found."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    msg_dir = abp_msgs_dir() / 'msg'
    for path in sorted(msg_dir.glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'abp_msgs/msg/{path.stem}'))
    if not types:
        raise FileNotFoundError(f'no abp_msgs message definitions found in {msg_dir}')
    store.register(types)
    return store
