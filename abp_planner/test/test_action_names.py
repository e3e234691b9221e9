"""The action vocabulary exists twice, for two audiences: abp_belief.cube.ACTIONS (the
science) and the string constants of abp_msgs/ExecutedAction (the interface). They must
agree, and the planner node must map every one of them to a skill."""

import pytest

from abp_belief.cube import ACTIONS, NOMINAL_DURATION_S

msg = pytest.importorskip('abp_msgs.msg')


def message_constants(message_type):
    # rosidl's generated metaclass hands its constants to the class namespace.
    return type(message_type).__prepare__(message_type.__name__, ())


def test_executed_action_constants_are_the_action_vocabulary():
    constants = message_constants(msg.ExecutedAction)
    assert list(constants) == list(ACTIONS)
    assert all(constants[name] == name for name in ACTIONS)
    assert set(NOMINAL_DURATION_S) == set(ACTIONS)


def test_planner_skill_clients_map_every_action_to_a_skill():
    skill_clients = pytest.importorskip('abp_planner.skill_clients')
    assert list(skill_clients.SKILLS) == list(ACTIONS)
    assert {skill for skill, _ in skill_clients.SKILLS.values()} == set(skill_clients.SKILL_TYPES)
