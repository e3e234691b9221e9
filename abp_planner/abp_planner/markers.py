"""RViz markers for the recognition state: the estimated cube and the top beliefs.

Message construction only (no rclpy): a CUBE marker at the aspect matcher's latest
pose estimate, and a text marker above it listing the most probable objects.

Both are stamped in the observation's frame (base_link) at the observation's stamp (the
image's), which the robot_state node's /tf covers: RViz, with the fixed frame odom,
places them where the base was when the cube was seen, not where it is when the marker
is drawn (a stamp of zero would mean "latest"). RViz keeps about 10 s of /tf, so a
marker republished (a new belief) long after the last sighting keeps its old place.
"""

from geometry_msgs.msg import Pose
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from abp_description.robot_profile import load_profile

CUBE_EDGE = 0.10
TOP_OBJECTS_SHOWN = 3


def belief_markers(belief, cube_pose, stamp, cube_edge=CUBE_EDGE, base_frame=None):
    """MarkerArray for `belief` (abp_msgs/Belief or None) and `cube_pose`
    ((frame_id, geometry_msgs/Pose, stamp of the observation) or None); `stamp` (now)
    stamps the DELETEALL sent while there is no cube pose. `base_frame` (default: the
    default robot profile's) is the frame of an observation without one."""
    if base_frame is None:
        base_frame = load_profile().frames.base
    markers = MarkerArray()
    if cube_pose is None:
        clear = Marker(ns='abp', id=0, action=Marker.DELETEALL)
        clear.header.frame_id, clear.header.stamp = base_frame, stamp
        markers.markers.append(clear)
        return markers
    frame_id, pose, seen = cube_pose
    cube = Marker(ns='abp_cube', id=0, type=Marker.CUBE, action=Marker.ADD, pose=pose)
    cube.header.frame_id = frame_id or base_frame
    cube.header.stamp = seen
    cube.scale.x = cube.scale.y = cube.scale.z = cube_edge
    confidence = float(belief.probabilities[0]) if belief and belief.probabilities else 0.0
    # Red while uncertain, green once the belief has condensed.
    cube.color = ColorRGBA(r=1.0 - confidence, g=confidence, b=0.2, a=0.6)
    markers.markers.append(cube)

    text = Marker(ns='abp_belief', id=1, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
    text.header = cube.header
    text.pose = Pose()
    text.pose.position.x = pose.position.x
    text.pose.position.y = pose.position.y
    text.pose.position.z = pose.position.z + cube_edge
    text.pose.orientation.w = 1.0
    text.scale.z = 0.04
    text.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    if belief and belief.object_ids:
        lines = [f'{oid}: {p:.2f}' for oid, p in
                 zip(belief.object_ids[:TOP_OBJECTS_SHOWN], belief.probabilities)]
        lines.append(f'H = {belief.entropy:.2f} bits, step {belief.step}')
        text.text = '\n'.join(lines)
    else:
        text.text = 'no belief yet'
    markers.markers.append(text)
    return markers
