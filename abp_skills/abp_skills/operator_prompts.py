"""What a person is asked to do for each skill goal, and how their answer is read (no rclpy).

With a fixed camera and no robot, a person carries out the planner's actions
(`operator_node`). The words follow the model's physics (docs/MODEL.md), in the view frame
V of the camera: x from the cube towards the camera, z up, so y is the camera's right.

- ORBIT(theta): the robot would drive about the cube by -theta, which turns the cube by
  +theta relative to the robot: R' = rot_z(theta) R. With the camera fixed, the person
  turns the cube by +theta about its vertical axis: positive theta is counter-clockwise
  seen from above, and a quarter turn moves the face that looked at the camera to the
  cube's right side as the camera sees it (x goes to y).
- PUSH: the front face (towards the camera) pushed along its normal, away from the camera.
  An off-centre weight may pivot the cube: the person lets it.
- LIFT: grasped by the two side faces (the robot's hand axis is y: left and right as the
  camera sees them), raised and set down; it may swing about the grip.
- FLIP: the front face goes to the top and the bottom comes towards the camera: the cube
  is tipped over away from the camera, about its bottom edge farthest from it.

An answer is one line: `d` (done) or `n REASON` (could not do it); `?` shows the request
again; anything else is named and the question asked again (`parse_answer`).
"""

import math
import textwrap
from dataclasses import dataclass

from abp_belief.cube import ACTIONS, ORBIT_STEPS

OPERATOR_SKILLS = ('orbit', 'push', 'lift', 'flip')
# ATG action -> the skill a person does for it.
SKILL_OF_ACTION = {**{name: 'orbit' for name in ORBIT_STEPS},
                   'PUSH': 'push', 'LIFT': 'lift', 'FLIP': 'flip'}
assert set(SKILL_OF_ACTION) == set(ACTIONS)

DONE_WORDS = ('d', 'done', 'y', 'yes', 'ok')
NOT_DONE_WORDS = ('n', 'no', 'x', 'fail', 'failed', "can't", 'cannot', 'could not')
HELP_WORDS = ('?', 'h', 'help')
LINE_WIDTH = 78
ANSWER_HINT = 'type  d  when done, or  n REASON  if you could not do it (? shows it again)'


class RequestError(ValueError):
    """A goal a person cannot be asked to do (its fields out of range)."""


@dataclass(frozen=True)
class Request:
    """One thing to ask: a short title ('ORBIT +90 deg') and the words of what to do."""
    skill: str
    title: str
    words: str


@dataclass(frozen=True)
class Answer:
    """A parsed line: kind 'done', 'not_done', 'help' or 'invalid'; `text` is the reason
    (not_done) or what to tell the person (invalid)."""
    kind: str
    text: str = ''


def _finite_non_negative(name, value):
    if not math.isfinite(value) or value < 0:
        raise RequestError(f'{name} must be a finite number >= 0, got {value}')
    return value


def _turn_words(angle_deg):
    """'a quarter turn (90 deg)' and the like."""
    size = abs(angle_deg)
    named = {45.0: 'an eighth of a turn', 90.0: 'a quarter turn', 180.0: 'a half turn',
             135.0: 'three eighths of a turn', 270.0: 'three quarters of a turn'}
    name = named.get(round(size, 6))
    return f'{name} ({size:g} deg)' if name else f'{size:g} deg'


def orbit_request(angle_deg):
    if not math.isfinite(angle_deg) or angle_deg == 0.0 or abs(angle_deg) > 360.0:
        raise RequestError(f'angle_deg must be a non-zero angle within +-360 deg, got '
                           f'{angle_deg}')
    size = round(abs(angle_deg), 6)
    if size == 180.0:
        direction = 'either way round'
        outcome = 'the face that looked at the camera ends up facing away from it'
    else:
        ccw = angle_deg > 0
        direction = ('counter-clockwise, seen from above' if ccw else
                     'clockwise, seen from above')
        side = 'right' if ccw else 'left'
        if size == 90.0:
            outcome = (f"the face that looked at the camera ends up on the cube's {side} "
                       'side, as the camera sees it')
        elif size == 45.0:
            outcome = (f'an upright edge points at the camera, and the face that looked at '
                       f'it has turned half way to the {side}')
        else:
            outcome = ''
    words = (f'Turn the cube {_turn_words(angle_deg)} {direction}, about its vertical axis, '
             'in place: do not lift or slide it.' + (f' Then {outcome}.' if outcome else ''))
    return Request('orbit', f'ORBIT {angle_deg:+g} deg', words)


def push_request(face, stroke_length, default_distance):
    face = (face or 'front').strip().lower()
    if face != 'front':
        raise RequestError(f'only the front face (towards the camera) is pushed, not {face!r}')
    distance = _finite_non_negative('stroke_length', stroke_length) or default_distance
    words = (f'Push the cube {100 * distance:.0f} cm straight away from the camera, with one '
             'finger on the middle of the face that looks at the camera. Do not hold or '
             'steer it: if it turns by itself, let it.')
    return Request('push', f'PUSH {100 * distance:.0f} cm', words)


def lift_request(lift_height, default_height):
    height = _finite_non_negative('lift_height', lift_height) or default_height
    words = (f'Lift the cube by two opposite faces, its left and right faces as the camera '
             f'sees them (hold them loosely at their middles), {100 * height:.0f} cm up, and '
             'set it down where it was. If it swings in your grip, let it; do not turn it '
             'yourself.')
    return Request('lift', f'LIFT {100 * height:.0f} cm', words)


def flip_request(roll_deg):
    roll = _finite_non_negative('roll_deg', roll_deg) or 90.0
    turn = 'over' if round(roll, 6) == 90.0 else f'by {roll:g} deg'
    words = (f'Tip the cube {turn} away from you (you stand at the camera): roll it about its '
             'bottom edge farthest from the camera, so that the face that looked at the camera '
             'ends up on top.')
    return Request('flip', f'FLIP {roll:g} deg', words)


def request_for(skill, goal, push_distance=0.10, lift_height=0.10):
    """The Request of a skill goal (an abp_msgs Orbit/Push/Lift/Flip Goal or anything with
    its fields); raises RequestError for a goal a person cannot be asked to do."""
    if skill == 'orbit':
        return orbit_request(float(goal.angle_deg))
    if skill == 'push':
        return push_request(goal.face, float(goal.stroke_length), push_distance)
    if skill == 'lift':
        return lift_request(float(goal.lift_height), lift_height)
    if skill == 'flip':
        return flip_request(float(goal.roll_deg))
    raise RequestError(f'unknown skill {skill!r}: one of {", ".join(OPERATOR_SKILLS)}')


def format_request(request, timeout_s):
    """The text shown to the person: title, what to do, how to answer."""
    return (f'\n=== abp asks: {request.title} (answer within {timeout_s:.0f} s) ===\n'
            f'{textwrap.fill(request.words, LINE_WIDTH)}\n{ANSWER_HINT}\n> ')


def parse_answer(line):
    """An Answer for one typed line; never raises."""
    text = ' '.join(str(line).split())
    lowered = text.lower()
    if lowered in DONE_WORDS:
        return Answer('done')
    if lowered in HELP_WORDS:
        return Answer('help')
    for word in sorted(NOT_DONE_WORDS, key=len, reverse=True):
        if lowered == word or lowered.startswith((word + ' ', word + ':', word + ',')):
            # 'n too heavy' gives 'too heavy'; "can't reach it" is a reason as it stands.
            reason = text if ' ' in word or "'" in word or word == 'cannot' else \
                text[len(word):].lstrip(' :,').strip()
            return Answer('not_done', reason or 'no reason given')
    if not text:
        return Answer('invalid', f'(no answer yet) {ANSWER_HINT}')
    shown = text if len(text) <= 40 else text[:37] + '...'
    return Answer('invalid', f'{shown!r} is not an answer: {ANSWER_HINT}')


def check_operator_actions(skills):
    """The skills a person will do, checked: each one of OPERATOR_SKILLS, none twice."""
    skills = [str(s).strip().lower() for s in skills]
    unknown = [s for s in skills if s not in OPERATOR_SKILLS]
    if unknown:
        raise ValueError(f'operator_actions: unknown skill(s) {", ".join(map(repr, unknown))}: '
                         f'each one of {", ".join(OPERATOR_SKILLS)}')
    if len(set(skills)) != len(skills):
        raise ValueError(f'operator_actions: a skill named twice in {skills}')
    return tuple(skills)


def feasibility(actions, operator_skills):
    """[(feasible, reason)] of ATG actions (names of abp_belief.cube.ACTIONS) for a person
    who does `operator_skills`; an empty `actions` means all of them. Returns
    (actions, verdicts)."""
    actions = list(actions) or list(ACTIONS)
    verdicts = []
    for action in actions:
        skill = SKILL_OF_ACTION.get(action)
        if skill is None:
            verdicts.append((False, f'unknown action {action!r}'))
        elif skill not in operator_skills:
            verdicts.append((False, f'the operator does not do {skill} '
                                    '(parameter operator_actions)'))
        else:
            verdicts.append((True, ''))
    return actions, verdicts


__all__ = ['ANSWER_HINT', 'Answer', 'OPERATOR_SKILLS', 'Request', 'RequestError',
           'SKILL_OF_ACTION', 'check_operator_actions', 'feasibility', 'format_request',
           'parse_answer', 'request_for']
