"""The words a person is asked, how their answers are read, and what they can do (no ROS)."""

import os
from types import SimpleNamespace

import numpy as np
import pytest

from abp_belief.cube import ACTIONS, ORBIT_STEPS, nominal_rotation
from abp_skills.operator_prompts import (
    OPERATOR_SKILLS,
    RequestError,
    check_operator_actions,
    feasibility,
    parse_answer,
    request_for,
)
from abp_skills.operator_terminal import OperatorTerminal, TerminalClosed


def orbit(angle):
    return request_for('orbit', SimpleNamespace(angle_deg=angle, radius=0.0))


def test_orbit_words_turn_the_cube_the_way_the_model_does():
    # The model: ORBIT +90 turns the cube by rot_z(+90) in V (x towards the camera, z up,
    # y the camera's right): the face that looked at the camera (+x) goes to +y.
    state = 8 * 4 + 0                       # +z up, yaw 0
    q = nominal_rotation('ORBIT_P90', 0, state)
    assert np.allclose(q @ [1, 0, 0], [0, 1, 0])
    assert 'counter-clockwise, seen from above' in orbit(90.0).words
    assert 'right side, as the camera sees it' in orbit(90.0).words
    assert 'clockwise, seen from above' in orbit(-90.0).words
    assert 'counter' not in orbit(-90.0).words
    assert 'left side' in orbit(-90.0).words
    assert orbit(45.0).title == 'ORBIT +45 deg' and 'eighth of a turn' in orbit(45.0).words
    assert 'half turn (180 deg) either way' in orbit(180.0).words
    assert 'half turn' in orbit(-180.0).words
    # Every orbit action of the model has words.
    for name, steps in ORBIT_STEPS.items():
        assert orbit(45.0 * steps).skill == 'orbit', name
    for bad in (0.0, float('nan'), 400.0):
        with pytest.raises(RequestError, match='angle_deg'):
            orbit(bad)


def test_flip_words_put_the_front_face_on_top():
    state = 8 * 4 + 0
    q = nominal_rotation('FLIP', 0, state)            # uniform cube: R' = Q R in V
    assert np.allclose(q @ [1, 0, 0], [0, 0, 1])      # the face at the camera goes on top
    assert np.allclose(q @ [0, 0, -1], [1, 0, 0])     # the bottom comes to the camera
    flip = request_for('flip', SimpleNamespace(roll_deg=0.0))
    assert 'away from you' in flip.words and 'ends up on top' in flip.words
    assert flip.title == 'FLIP 90 deg'


def test_push_and_lift_lengths_come_from_the_goal_or_the_default():
    assert request_for('push', SimpleNamespace(face='', stroke_length=0.0)).title == 'PUSH 10 cm'
    push = request_for('push', SimpleNamespace(face='front', stroke_length=0.2), 0.1)
    assert push.title == 'PUSH 20 cm' and 'away from the camera' in push.words
    with pytest.raises(RequestError, match='front face'):
        request_for('push', SimpleNamespace(face='left', stroke_length=0.0))
    with pytest.raises(RequestError, match='stroke_length'):
        request_for('push', SimpleNamespace(face='front', stroke_length=-1.0))
    lift = request_for('lift', SimpleNamespace(lift_height=0.0), lift_height=0.15)
    assert lift.title == 'LIFT 15 cm' and 'two opposite faces' in lift.words
    with pytest.raises(RequestError, match='unknown skill'):
        request_for('jump', SimpleNamespace())


@pytest.mark.parametrize('line, kind, text', [
    ('d', 'done', ''), ('  Done ', 'done', ''), ('yes', 'done', ''),
    ('n too heavy', 'not_done', 'too heavy'), ('no: it fell off', 'not_done', 'it fell off'),
    ('x', 'not_done', 'no reason given'), ("can't reach it", 'not_done', "can't reach it"),
    ('?', 'help', ''), ('help', 'help', ''),
])
def test_answers(line, kind, text):
    answer = parse_answer(line)
    assert (answer.kind, answer.text) == (kind, text)


@pytest.mark.parametrize('line', ['', 'nope', 'dd', 'q' * 200, '\x1b[A', 'déjà'])
def test_anything_else_is_named_and_asked_again(line):
    answer = parse_answer(line)
    assert answer.kind == 'invalid'
    assert 'type  d  when done' in answer.text
    assert len(answer.text) < 200


def test_feasibility_from_what_the_person_does():
    actions, verdicts = feasibility([], OPERATOR_SKILLS)
    assert actions == list(ACTIONS) and all(ok for ok, _ in verdicts)
    actions, verdicts = feasibility(['PUSH', 'ORBIT_180', 'WAVE'], ('orbit',))
    assert verdicts == [(False, 'the operator does not do push (parameter operator_actions)'),
                        (True, ''), (False, "unknown action 'WAVE'")]
    assert check_operator_actions([' Orbit', 'push']) == ('orbit', 'push')
    with pytest.raises(ValueError, match="unknown skill.*'wave'"):
        check_operator_actions(['orbit', 'wave'])
    with pytest.raises(ValueError, match='twice'):
        check_operator_actions(['orbit', 'orbit'])


def test_terminal_reads_typed_lines_and_reports_its_end():
    master, slave = os.openpty()
    try:
        terminal = OperatorTerminal(os.ttyname(slave))
        assert terminal.show('question?\n')
        assert b'question?' in os.read(master, 1024)
        assert terminal.next_line(0.05) is None
        os.write(master, b'n it rolled away\n')
        assert terminal.next_line(10.0) == 'n it rolled away'
    finally:
        os.close(master)
        os.close(slave)
    with pytest.raises(TerminalClosed):       # the person's end went away
        for _ in range(200):
            terminal.next_line(0.05)
    with pytest.raises(TerminalClosed):       # and it stays so
        terminal.next_line(0.0)
