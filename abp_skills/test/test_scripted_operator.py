"""The scripted operator (abp_sim_bridge.scripted_operator, operator_world) reads the
operator_skills node's words as a person would, and what it does to the cube follows the
ATG table of the hidden cube's mass, so that eccentric twins differ as in the robot world."""

import cv2
import numpy as np
import pytest

pytest.importorskip('abp_sim_bridge.mujoco_scene')  # MuJoCo, with MUJOCO_GL=egl

from abp_belief.cube import (  # noqa: E402
    ACTIONS,
    MANUAL_ACTIONS,
    apply_rotation,
    nominal_outcomes,
    state_of,
)
from abp_sim_bridge.operator_world import OperatorWorld, cube_spot  # noqa: E402
from abp_sim_bridge.scenario import HiddenModel, choose_hidden_model  # noqa: E402
from abp_sim_bridge.scripted_operator import (  # noqa: E402
    PromptReader,
    Request,
    RequestUnclear,
    ScriptedPerson,
    parse_request,
)
from abp_skills.operator_prompts import format_request, request_for  # noqa: E402


class Goal:
    def __init__(self, **fields):
        self.angle_deg = self.stroke_length = self.lift_height = self.roll_deg = 0.0
        self.face = ''
        self.__dict__.update(fields)


@pytest.mark.parametrize('skill, goal, action, amount', [
    ('orbit', Goal(angle_deg=90.0), 'ORBIT_P90', 90.0),
    ('orbit', Goal(angle_deg=-90.0), 'ORBIT_M90', -90.0),
    ('orbit', Goal(angle_deg=45.0), 'ORBIT_P45', 45.0),
    ('orbit', Goal(angle_deg=-45.0), 'ORBIT_M45', -45.0),
    ('orbit', Goal(angle_deg=180.0), 'ORBIT_180', 180.0),
    ('orbit', Goal(angle_deg=-30.0), '', -30.0),
    ('push', Goal(stroke_length=0.0), 'PUSH', 0.10),
    ('push', Goal(stroke_length=0.05), 'PUSH', 0.05),
    ('lift', Goal(lift_height=0.0), 'LIFT', 0.10),
    ('flip', Goal(roll_deg=90.0), 'FLIP', 90.0),
])
def test_the_words_a_person_reads_say_the_action(skill, goal, action, amount):
    text = format_request(request_for(skill, goal), 120.0)
    reader = PromptReader()
    # The terminal delivers the text in pieces, one character at a time at worst, with
    # the pty's \r\n line ends.
    found = [r for ch in ('noise\n' + text).replace('\n', '\r\n') for r in reader.feed(ch)]
    assert len(found) == 1
    title, words = found[0]
    request = parse_request(title, words)
    assert (request.skill, request.action) == (skill, action)
    assert request.amount == pytest.approx(amount)


def test_words_it_cannot_read_are_said_so():
    with pytest.raises(RequestUnclear, match='cannot read'):
        parse_request('ORBIT +90 deg', 'Spin it fast.')
    with pytest.raises(RequestUnclear, match='do not know'):
        parse_request('DANCE 2 s', 'Dance.')


def test_the_wrong_action_share_is_drawn_with_the_seed():
    def draws(fraction, seed):
        person = ScriptedPerson(0, np.random.default_rng(seed), wrong_action_fraction=fraction)
        return [person.choose(Request('LIFT 10 cm', 'lift', 'LIFT', 0.1)) for _ in range(2000)]
    assert not any(wrong for _, wrong in draws(0.0, 1))
    assert all(wrong and action != 'LIFT' for action, wrong in draws(1.0, 1))
    tenth = draws(0.1, 7)
    assert 0.08 < np.mean([wrong for _, wrong in tenth]) < 0.12
    assert {a for a, wrong in tenth if wrong} == set(ACTIONS) - {'LIFT'}
    assert tenth == draws(0.1, 7)
    with pytest.raises(ValueError, match='wrong_action_fraction'):
        ScriptedPerson(0, np.random.default_rng(0), wrong_action_fraction=1.5)


def hidden(mass_index, faces=(0, 1, 2, 3, 4, 5)):
    return HiddenModel('cube', -1, faces, mass_index, 7)


@pytest.mark.parametrize('mass_index', range(7))
def test_manual_actions_follow_the_table_of_the_cube_mass(mass_index):
    """From every up face and yaw, each manual action leaves the cube in a state of the
    corrected table's outcomes for this mass (and ORBIT turns it by its steps)."""
    world = OperatorWorld(hidden(mass_index), [0, 0, 0.4, 0, 45, 0])
    person = ScriptedPerson(mass_index, np.random.default_rng(mass_index), yaw_jitter_deg=3.0)
    try:
        for up in range(6):
            for yaw in range(8):
                for action in (*MANUAL_ACTIONS, 'ORBIT_P45', 'ORBIT_M90'):
                    world.place(world.home_xy, world.view_frame()
                                @ _state_rotation(state_of(up, yaw)))
                    assert world.discrete_state() == (up, yaw)
                    done = person.carry_out(Request(action, '', action, 0.1), world)
                    expect = {apply_rotation(q, done.state_before) for q, w in
                              nominal_outcomes(action, mass_index, done.state_before) if w > 0}
                    assert done.state_after in expect, (action, up, yaw, done)
                    assert not done.wrong
    finally:
        world.close()


def _state_rotation(state):
    from abp_belief.cube import state_rotation
    return state_rotation(state)


def test_eccentric_twins_tell_apart_as_in_the_robot_world():
    """Same tags, heavy at the front or at the back: a LIFT rolls them opposite ways."""
    ends = {}
    for mass_index in (1, 2):                   # heavy +x (front at the start), heavy -x
        world = OperatorWorld(hidden(mass_index), [0, 0, 0.4, 0, 45, 0])
        person = ScriptedPerson(mass_index, np.random.default_rng(0))
        ends[mass_index] = person.carry_out(Request('LIFT', 'lift', 'LIFT', 0.1), world)
        world.close()
    assert ends[1].state_before == ends[2].state_before
    assert len({ends[1].state_after, ends[2].state_after, ends[1].state_before}) == 3


def test_a_push_slides_the_cube_away_and_back_to_its_mark():
    world = OperatorWorld(hidden(0), [0, 0, 0.4, 0, 45, 0])
    person = ScriptedPerson(0, np.random.default_rng(0), push_reach=0.2)
    try:
        home = world.home_xy.copy()
        xs = []
        for _ in range(3):
            person.carry_out(Request('PUSH 10 cm', 'push', 'PUSH', 0.10), world)
            xs.append(world.cube_pose()[0, 3])
        assert xs == pytest.approx([home[0] + 0.10, home[0] + 0.20, home[0]])
    finally:
        world.close()


def test_the_fixed_camera_sees_the_cube_tags():
    model = choose_hidden_model(model_index=4, model_set='robot')
    world = OperatorWorld(model, [0, 0, 0.4, 0, 45, 0])
    try:
        image = world.render('mono8')
    finally:
        world.close()
    assert image.shape == (480, 640)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    _, ids, _ = detector.detectMarkers(image)
    assert ids is not None and len(ids) >= 2
    assert set(ids.ravel()) <= set(model.face_tags)


def test_a_camera_that_does_not_look_at_the_table_is_refused():
    assert cube_spot([0, 0, 0.4, 0, 45, 0], 0.1) == pytest.approx([0.35, 0.0])
    with pytest.raises(ValueError, match='look down'):
        cube_spot([0, 0, 0.4, 0, -10, 0], 0.1)
