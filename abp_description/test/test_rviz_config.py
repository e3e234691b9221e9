"""The shipped RViz config shows what the graph publishes, as it publishes it: fixed frame
odom, the robot from the latched robot_description, tf, the camera and the planner's
latched markers (a volatile reader of a latched topic started late would get nothing)."""

import pathlib

import yaml

from abp_common import names

RVIZ = pathlib.Path(__file__).resolve().parent.parent / 'rviz' / 'abp.rviz'


def displays():
    config = yaml.safe_load(RVIZ.read_text())
    manager = config['Visualization Manager']
    return manager, {d['Class'].split('/')[-1]: d for d in manager['Displays']}


def test_fixed_frame_and_displays():
    manager, shown = displays()
    assert manager['Global Options']['Fixed Frame'] == 'odom'
    assert {'RobotModel', 'TF', 'MarkerArray', 'Image'} <= set(shown)
    assert all(d['Enabled'] for d in shown.values())


def test_topics_and_durability_match_the_publishers():
    _, shown = displays()
    robot = shown['RobotModel']
    assert robot['Description Source'] == 'Topic'
    assert robot['Description Topic']['Value'] == '/robot_description'
    assert robot['Description Topic']['Durability Policy'] == 'Transient Local'
    markers = shown['MarkerArray']['Topic']
    assert markers['Value'] == names.absolute(names.MARKERS)
    assert markers['Durability Policy'] == 'Transient Local'      # qos.LATCHED
    image = shown['Image']['Topic']
    assert image['Value'] == names.absolute(names.IMAGE)
    assert image['Durability Policy'] == 'Volatile'
