"""The scripted operator: a simulated person who reads the operator_skills node's requests
on its terminal, does what they say to the cube of an `operator_world.OperatorWorld`, and
answers (plain Python, no rclpy; the node is `scripted_operator_node`).

It reads what a person reads: the request's words (abp_skills.operator_prompts), not the
goal. `PromptReader` cuts the terminal's text into requests, `parse_request` reads which
action, which way and how much from the words.

What the action does to the cube is MODEL.md's physics, the same ATG table the belief uses
(`transition_rules`, by default `corrected`, the MuJoCo outcome survey's physics of the
robot world): `abp_belief.cube.nominal_outcomes` of the hidden cube's mass and the cube's
discrete state as the camera sees it, one outcome drawn by its weight where the table
splits. So the eccentric twins (same tags, another heavy face) differ here exactly where
they differ in the robot world: a front-heavy cube rolls over on a LIFT, a top-heavy one
tips on or stays on a FLIP, a bottom-heavy one does not roll, and so on. The table's
failure and unmodelled shares are the robot's faults and are not drawn: a person does
the action they did. Their mistakes are `wrong_action_fraction`: that share of the
requests they carry out as another action (one of the other seven ATG actions, drawn
evenly: a turn the wrong way or by the wrong amount, another manual action), and say
done.

The outcome is applied by setting the cube's pose: the new discrete state's rotation
(turned by a small random yaw, `yaw_jitter_deg`, as hands leave it), at rest on the
table. PUSH also slides it the asked distance away from the camera; once it is more than
`push_reach` from where it started, the person slides it straight back to its mark (a
translation towards the camera, which changes no state) so that it stays in view.
"""

import re
from dataclasses import dataclass

import numpy as np

from abp_belief.cube import ACTIONS, ORBIT_STEPS, STATE_ROTATIONS, nominal_outcomes, state_of
from abp_description.frames import rot_z_deg

# The ORBIT action of each signed angle a request can name.
ORBIT_OF_ANGLE = {45.0: 'ORBIT_P45', -45.0: 'ORBIT_M45', 90.0: 'ORBIT_P90',
                  -90.0: 'ORBIT_M90', 180.0: 'ORBIT_180', -180.0: 'ORBIT_180'}
DEFAULT_PUSH_M = 0.10
_NUMBER = r'(\d+(?:\.\d+)?)'
_PROMPT = re.compile(r'=== abp asks: (?P<title>.+?) \(answer within \d+ s\) ===\n'
                     r'(?P<body>.*?)\n> ', re.S)
_WORDS = {
    'orbit': re.compile(r'^Turn the cube (?:[a-z ]+ \()?' + _NUMBER +
                        r' deg\)? (counter-clockwise|clockwise|either way round)'),
    'push': re.compile(r'^Push the cube ' + _NUMBER + r' cm straight away from the camera'),
    'lift': re.compile(r'^Lift the cube by two opposite faces.*? ' + _NUMBER + r' cm up'),
    'flip': re.compile(r'^Tip the cube (?:over|by ' + _NUMBER + r' deg) away from you'),
}
_TITLE_SKILL = {'ORBIT': 'orbit', 'PUSH': 'push', 'LIFT': 'lift', 'FLIP': 'flip'}


class RequestUnclear(ValueError):
    """Words the scripted person cannot turn into an action."""


@dataclass(frozen=True)
class Request:
    """What a request asks: the skill, the ATG action ('' for an ORBIT by another angle),
    and how much: deg for ORBIT (signed, + = counter-clockwise from above) and FLIP, m for
    PUSH and LIFT."""
    title: str
    skill: str
    action: str
    amount: float


class PromptReader:
    """Collects the terminal's text; `feed(text)` returns the requests completed by it,
    as (title, words) in order (words: the request's lines before its answer hint, joined
    into one line)."""

    def __init__(self):
        self._text = ''

    def feed(self, text):
        # A pty's output processing turns each \n into \r\n.
        self._text += text.replace('\r', '')
        out = []
        while True:
            match = _PROMPT.search(self._text)
            if match is None:
                break
            lines = match['body'].split('\n')[:-1]       # the last line is the answer hint
            out.append((match['title'].strip(), ' '.join(' '.join(lines).split())))
            self._text = self._text[match.end():]
        # Keep only what may still become a request (the text from its last header on).
        start = self._text.rfind('=== abp asks:')
        self._text = self._text[start:] if start >= 0 else self._text[-20:]
        return out


def parse_request(title, words):
    """The Request of a request's title and words; RequestUnclear when the words say no
    action or disagree with the title."""
    skill = _TITLE_SKILL.get(title.split(' ', 1)[0])
    if skill is None:
        raise RequestUnclear(f'I do not know the action {title!r}')
    match = _WORDS[skill].search(words)
    if match is None:
        raise RequestUnclear(f'I cannot read what to do for {title}: {words[:60]!r}')
    if skill == 'orbit':
        size, way = float(match[1]), match[2]
        angle = -size if way == 'clockwise' else size
        action = ORBIT_OF_ANGLE.get(round(angle, 6), '')
        return Request(title, skill, action, angle)
    if skill == 'flip':
        return Request(title, skill, 'FLIP', float(match[1] or 90.0))
    return Request(title, skill, skill.upper(), float(match[1]) / 100.0)


@dataclass(frozen=True)
class Done:
    """What the scripted person did for one request."""
    request: Request
    action: str           # the ATG action carried out
    wrong: bool           # not the one asked
    state_before: int
    state_after: int
    moved_m: float

    def __str__(self):
        what = (f'{self.action} instead of {self.request.title} (wrong action)' if self.wrong
                else f'{self.request.title} as asked')
        return (f'{what}: state {self.state_before} -> {self.state_after}'
                + (f', moved {100 * self.moved_m:.0f} cm' if self.moved_m > 1e-4 else ''))


class ScriptedPerson:
    """Carries out requests on an OperatorWorld whose hidden cube has `mass_index`.

    `rng`: a numpy Generator (the seeded draws: wrong actions, split outcomes, jitter)."""

    def __init__(self, mass_index, rng, rules='corrected', wrong_action_fraction=0.0,
                 yaw_jitter_deg=2.0, push_reach=0.2):
        if not 0.0 <= wrong_action_fraction <= 1.0:
            raise ValueError(f'wrong_action_fraction must be in [0, 1], got '
                             f'{wrong_action_fraction}')
        self.mass_index = int(mass_index)
        self.rng = rng
        self.rules = rules
        self.wrong_action_fraction = float(wrong_action_fraction)
        self.yaw_jitter_deg = float(yaw_jitter_deg)
        self.push_reach = float(push_reach)
        self.actions = 0
        self.wrong_actions = 0

    def choose(self, request):
        """(ATG action to carry out, wrong?) for a request."""
        if self.rng.random() < self.wrong_action_fraction:
            others = [a for a in ACTIONS if a != request.action]
            return str(self.rng.choice(others)), True
        return request.action, False

    def rotation(self, action, request, state):
        """The rotation Q in V (R' = Q R) that `action` gives from `state`."""
        if action == '':          # an ORBIT by an angle that is no ATG action
            return rot_z_deg(request.amount)
        if action in ORBIT_STEPS:
            return rot_z_deg(45.0 * ORBIT_STEPS[action])
        outcomes = nominal_outcomes(action, self.mass_index, state, self.rules)
        weights = np.array([w for _, w in outcomes])
        pick = int(self.rng.choice(len(outcomes), p=weights / weights.sum()))
        return outcomes[pick][0]

    def carry_out(self, request, world):
        """Do `request` (or the wrong action) to `world`'s cube; returns Done."""
        action, wrong = self.choose(request)
        up, yaw = world.discrete_state()
        before = state_of(up, yaw)
        view = world.view_frame()
        q = self.rotation(action, request, before)
        jitter = np.clip(self.rng.normal(0.0, self.yaw_jitter_deg), -10.0, 10.0) \
            if self.yaw_jitter_deg > 0 else 0.0
        rotation = view @ rot_z_deg(jitter) @ q @ STATE_ROTATIONS[before]
        xy = world.cube_pose()[:2, 3].copy()
        start = xy.copy()
        if action == 'PUSH':
            distance = request.amount if request.skill == 'push' else DEFAULT_PUSH_M
            xy = xy - view[:2, 0] * distance           # away from the camera: -x_V
            if np.linalg.norm(xy - world.home_xy) > self.push_reach + 1e-9:
                xy = world.home_xy.copy()              # slid back to its mark
        world.place(xy, rotation)
        up, yaw = world.discrete_state()
        self.actions += 1
        self.wrong_actions += int(wrong)
        return Done(request, action, wrong, before, state_of(up, yaw),
                    float(np.linalg.norm(xy - start)))


__all__ = ['Done', 'ORBIT_OF_ANGLE', 'PromptReader', 'Request', 'RequestUnclear',
           'ScriptedPerson', 'parse_request']
