"""The Recognize tasks over several cubes (issue 37): the real planner and belief nodes
over DDS, closing the loop through the model-sampled world with three cubes
(tests/helpers/model_world_node.py: one observation per cube with its track id; a skill's
outcome goes to the cube named by the planner's abp/executed_action)."""

import collections
import sys

import pytest

rclpy = pytest.importorskip('rclpy')

from action_msgs.msg import GoalStatus  # noqa: E402
from test_planner_node import (  # noqa: E402
    PARAMS,
    SEED,
    WORLD,
    client,  # noqa: F401 -- the fixture
    executable,
    recognize,
)

from abp_belief.population import robot_set  # noqa: E402
from abp_common.qos import LATCHED_READER  # noqa: E402
from abp_msgs.action import Recognize  # noqa: E402
from abp_msgs.msg import SceneBelief  # noqa: E402

# Three cubes with different faces (uniform mass: no twins among them).
SCENE_MODELS = (0, 7, 28)
TRACKS = ('cube1', 'cube2', 'cube3')
ABSENT_MODEL = 5


def start_scene(ros_processes, models=SCENE_MODELS):
    ros_processes.start([executable('abp_belief', 'belief'), *PARAMS])
    ros_processes.start([executable('abp_planner', 'planner'), *PARAMS,
                         '-p', 'observation_timeout:=5.0'])
    ros_processes.start([sys.executable, str(WORLD), 'robot', str(SEED),
                         ','.join(map(str, models))])


def scene_tracks_seen(node, executor, spin, tracks=TRACKS, timeout=60):
    """True once /abp/beliefs holds every track of `tracks` with an observation (the
    identify task names a track the belief node must know)."""
    scenes = []
    subscription = node.create_subscription(SceneBelief, '/abp/beliefs', scenes.append,
                                            LATCHED_READER)

    def seen():
        return scenes and all(any(o.track_id == t and o.belief.step >= 1
                                  for o in scenes[-1].objects) for t in tracks)
    try:
        return spin(executor, seen, timeout)
    finally:
        node.destroy_subscription(subscription)


def task_goal(task, **fields):
    return Recognize.Goal(planner_mode='abp', max_actions=30, task=task, **fields)


def per_track(executed):
    return collections.Counter(e.track_id for e in executed)


def test_identify_all_names_every_cube_of_a_three_cube_scene(
        ros_processes, client, spin, answering):  # noqa: F811
    node, executor, action_client, executed, plans = client
    start_scene(ros_processes)
    feedback = []
    response = recognize(executor, action_client, spin, answering,
                         task_goal(Recognize.Goal.TASK_IDENTIFY_ALL), feedback,
                         executed=executed, plans=plans)
    models = robot_set(seed=SEED)
    result = response.result
    assert response.status == GoalStatus.STATUS_SUCCEEDED, result.reason
    assert result.success and result.found_track_id == ''
    named = {o.track_id: o for o in result.objects}
    assert sorted(named) == list(TRACKS)
    for track, model in zip(TRACKS, SCENE_MODELS):
        assert named[track].object_id == models.names[model], (track, named[track])
        assert named[track].decided, named[track].reason
    # Every action was announced on the cube it was for, and counted there.
    assert result.actions_taken == len(executed) >= 3
    assert all(e.track_id in TRACKS for e in executed)
    assert {t: named[t].actions_taken for t in TRACKS if named[t].actions_taken} == \
        dict(per_track(executed))
    # One feedback per decision, before its action (another topic: it may come later).
    assert spin(executor, lambda: len(feedback) >= len(executed), 10)
    assert [f.chosen_track_id for f in feedback] == [e.track_id for e in executed]


def test_find_stops_at_the_target_and_rules_out_an_absent_model(
        ros_processes, client, spin, answering):  # noqa: F811
    node, executor, action_client, executed, plans = client
    start_scene(ros_processes)
    models = robot_set(seed=SEED)
    target_track = TRACKS[1]
    response = recognize(executor, action_client, spin, answering,
                         task_goal(Recognize.Goal.TASK_FIND,
                                   target_model=models.names[SCENE_MODELS[1]]),
                         executed=executed, plans=plans)
    result = response.result
    assert response.status == GoalStatus.STATUS_SUCCEEDED, result.reason
    assert result.found_track_id == target_track, result.reason
    assert result.object_id == models.names[SCENE_MODELS[1]]
    assert len(result.objects) == 3
    found = next(o for o in result.objects if o.track_id == target_track)
    assert found.decided and found.object_id == models.names[SCENE_MODELS[1]]

    # A model no cube is: every cube surely not it (or the budget spent), nothing found.
    executed.clear()
    plans.clear()
    response = recognize(executor, action_client, spin, answering,
                         task_goal(Recognize.Goal.TASK_FIND,
                                   target_model=models.names[ABSENT_MODEL]),
                         executed=executed, plans=plans)
    result = response.result
    assert result.found_track_id == ''
    if response.status == GoalStatus.STATUS_SUCCEEDED:
        assert result.success and 'no object is model' in result.reason, result.reason
    else:
        assert response.status == GoalStatus.STATUS_ABORTED
        assert 'action limit' in result.reason, result.reason
    assert all(o.object_id != models.names[ABSENT_MODEL] for o in result.objects)


def test_identify_names_only_the_given_track_and_bad_goals_say_why(
        ros_processes, client, spin, answering):  # noqa: F811
    node, executor, action_client, executed, plans = client
    start_scene(ros_processes)
    models = robot_set(seed=SEED)
    assert scene_tracks_seen(node, executor, spin), 'the belief node never saw every cube'
    response = recognize(executor, action_client, spin, answering,
                         task_goal(Recognize.Goal.TASK_IDENTIFY, track_id=TRACKS[2]),
                         executed=executed, plans=plans)
    result = response.result
    assert response.status == GoalStatus.STATUS_SUCCEEDED, result.reason
    assert result.object_id == models.names[SCENE_MODELS[2]]
    assert set(per_track(executed)) == {TRACKS[2]}
    named = {o.track_id: o for o in result.objects}
    assert named[TRACKS[2]].decided and named[TRACKS[2]].actions_taken == len(executed)
    assert all(named[t].actions_taken == 0 for t in named if t != TRACKS[2])

    # Goals the planner cannot run end at once, saying why.
    for goal, words in ((task_goal(Recognize.Goal.TASK_IDENTIFY, track_id='cube9'),
                         ("'cube9'", 'cube1')),
                        (task_goal(Recognize.Goal.TASK_FIND, target_model='no-such-cube'),
                         ('no-such-cube', 'not a model')),
                        (task_goal(Recognize.Goal.TASK_FIND), ('needs target_model',))):
        response = recognize(executor, action_client, spin, answering, goal, timeout=30)
        assert response.status == GoalStatus.STATUS_ABORTED
        assert response.result.actions_taken == 0
        assert all(w in response.result.reason for w in words), response.result.reason
    # An unknown task is refused outright.
    handle_future = action_client.send_goal_async(task_goal('arrange'))
    assert spin(executor, handle_future.done, 10)
    assert not handle_future.result().accepted
