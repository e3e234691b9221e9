"""The planner's RViz markers: in the observation's frame at the observation's stamp (the
frame and time /tf places them at), not at the time they are drawn."""

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose
from visualization_msgs.msg import Marker

from abp_msgs.msg import Belief
from abp_planner.markers import belief_markers


def test_markers_carry_the_observation_frame_and_stamp():
    pose = Pose()
    pose.position.x, pose.orientation.w = 0.6, 1.0
    seen, now = Time(sec=12, nanosec=345), Time(sec=14)
    belief = Belief(object_ids=['a', 'b'], probabilities=[0.7, 0.3], entropy=0.9, step=2)
    markers = belief_markers(belief, ('base_link', pose, seen), now).markers
    assert [m.type for m in markers] == [Marker.CUBE, Marker.TEXT_VIEW_FACING]
    for marker in markers:
        assert marker.header.frame_id == 'base_link' and marker.header.stamp == seen
    assert markers[1].pose.position.z > pose.position.z and 'a: 0.70' in markers[1].text
    # An observation without a frame is in the base frame; no cube pose clears them all.
    assert belief_markers(None, ('', pose, seen), now).markers[0].header.frame_id == \
        'base_link'
    (clear,) = belief_markers(belief, None, now).markers
    assert clear.action == Marker.DELETEALL and clear.header.stamp == now
