"""Topic names in bags (no DDS): the graph's relative names resolve in the recorder's
namespace to the absolute names rosbag2 stores, and map back for their QoS."""

import pytest

from abp_bringup.bag import (
    GRAPH_TOPICS,
    IMAGE_TOPICS,
    RECORDER_SPECS,
    graph_name,
    graph_topics,
    recorded_topics,
)
from abp_common import names
from abp_common.param_spec import check_all


def test_graph_topics_are_absolute_in_the_recorders_namespace():
    root = graph_topics()
    assert root['/abp/belief'] == 'abp_msgs/msg/Belief'
    assert '/camera/image_raw' not in root
    assert '/camera/image_raw' in graph_topics(images=True)
    robot = graph_topics('robot1', images=True)
    assert robot['/robot1/abp/tag_detections'] == 'abp_msgs/msg/TagDetectionArray'
    assert set(robot) == {names.absolute(name, 'robot1')
                          for name in {**GRAPH_TOPICS, **IMAGE_TOPICS}}
    # tf is absolute, as tf2_ros publishes it: a namespace does not move it.
    assert robot['/tf_static'] == 'tf2_msgs/msg/TFMessage'
    assert '/robot1/tf_static' not in robot
    assert graph_topics('/robot1/') == graph_topics('robot1')


@pytest.mark.parametrize('topic, name', [
    ('/abp/belief', 'abp/belief'), ('/robot1/abp/belief', 'abp/belief'),
    ('/a/b/camera/image_raw', 'camera/image_raw'), ('/odom', 'odom'),
    ('/wheel_odom', ''), ('/abp/other', ''), ('/tf_static', '/tf_static'),
    ('/robot1/tf_static', ''),
])
def test_graph_name_maps_a_bag_topic_back(topic, name):
    assert graph_name(topic) == name


def test_recorded_topics_resolve_relative_and_keep_absolute_names():
    assert recorded_topics() == graph_topics()
    assert recorded_topics(None, True, '/robot1') == graph_topics('robot1', images=True)
    chosen = recorded_topics(['abp/belief', '/robot1/abp/plan', ''], False, '/robot1')
    assert chosen == {'/robot1/abp/belief': 'abp_msgs/msg/Belief',
                      '/robot1/abp/plan': 'abp_msgs/msg/PlanStep'}
    with pytest.raises(ValueError, match='not graph topics'):
        recorded_topics(['/abp/belief'], namespace='/robot1')


def test_recorder_parameters_refuse_an_unknown_storage():
    check_all(RECORDER_SPECS, {'storage': 'sqlite3'})
    with pytest.raises(ValueError, match='storage must be one of mcap, sqlite3'):
        check_all(RECORDER_SPECS, {'storage': 'zip'})
