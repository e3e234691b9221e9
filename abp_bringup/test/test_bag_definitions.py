"""Bags recorded before abp_msgs gained the multi-object fields (issue 37 added track_id
to AspectObservation and ExecutedAction, and cube_pose): they are read with the
definitions they were recorded with, and the player converts them to the current ones.
No DDS: the committed episodes of bags/ and rclpy's message classes."""

import pathlib

import pytest

pytest.importorskip('rclpy')

from abp_bringup.bag import outdated_types, read_messages  # noqa: E402
from abp_bringup.bag_player import current_messages  # noqa: E402
from abp_bringup.bag_ros import current_message, message_class  # noqa: E402
from abp_msgs.msg import AspectObservation, ExecutedAction  # noqa: E402

BAG = pathlib.Path(__file__).resolve().parents[2] / 'bags' / 'robot-seed1-uniform'
pytestmark = pytest.mark.skipif(not (BAG / 'metadata.yaml').exists(),
                                reason=f'no committed episode {BAG}')
OLD = {'abp_msgs/msg/AspectObservation', 'abp_msgs/msg/ExecutedAction'}


def test_types_recorded_before_the_track_ids_are_outdated():
    assert set(outdated_types(BAG)) == OLD


def test_old_messages_become_current_ones_with_the_new_fields_at_their_defaults():
    recorded = {}
    for topic, msgtype, _, msg in read_messages(BAG):
        if msgtype in OLD:
            recorded.setdefault(msgtype, []).append(msg)
    action = recorded['abp_msgs/msg/ExecutedAction'][0]
    assert not hasattr(action, 'track_id')   # as recorded
    current = current_message(action, ExecutedAction)
    assert (current.action, current.sequence, current.success, current.reason) == (
        action.action, action.sequence, action.success, action.reason)
    assert current.duration.sec == action.duration.sec and current.track_id == ''
    observation = next(o for o in recorded['abp_msgs/msg/AspectObservation'] if o.hypotheses)
    converted = current_message(observation, AspectObservation)
    assert converted.track_id == '' and converted.cube_pose.orientation.w == 1.0
    assert list(converted.hypotheses[0].slots) == list(observation.hypotheses[0].slots)
    assert converted.features[0].position.x == observation.features[0].position.x
    assert converted.header.frame_id == observation.header.frame_id
    assert len(converted.hypotheses) == len(observation.hypotheses)


def test_the_player_converts_only_the_outdated_types():
    from abp_bringup.bag import read_bag
    outdated = outdated_types(BAG)
    out = list(current_messages(read_bag(BAG, ['/abp/executed_action', '/abp/belief']),
                                outdated))
    actions = [data for topic, _, _, data in out if topic == '/abp/executed_action']
    beliefs = [data for topic, _, _, data in out if topic == '/abp/belief']
    assert actions and all(isinstance(a, message_class('abp_msgs/msg/ExecutedAction'))
                           for a in actions)
    assert beliefs and all(isinstance(b, (bytes, memoryview)) for b in beliefs)
