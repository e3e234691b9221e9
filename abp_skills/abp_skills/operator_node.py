"""A person as the skills: the `operator_skills` node (no robot, a fixed camera).

Serves what `skill_servers` serves, under the same names and types, so the planner runs
unchanged: the actions /abp/skills/{orbit,push,lift,flip} (abp_msgs/action/*) and the
service /abp/skills/check_feasibility (abp_msgs/srv/CheckFeasibility). Each goal is put
to a person on a terminal in words (`operator_prompts`: what to do, seen from the
camera), and the person answers with one line:

  d            done: the goal succeeds
  n REASON     could not do it: the goal aborts with reason "the operator could not do
               it: REASON"
  ?            show the request again
  (other)      named as not an answer, and the question is asked again

No answer within `skill_timeout` (wall seconds: a person's time, also under sim time)
aborts the goal with the reason, and tells the person the request is withdrawn; a
cancel withdraws the request on the terminal and ends the goal canceled. One request
at a time: a goal that arrives while the person is busy is aborted "rejected: busy: ...".
Lines typed while nothing is asked are answered "nothing is asked now" when the next
request starts and are not taken as its answer.

The feasibility service answers from what the person does: every ORBIT, PUSH, LIFT and
FLIP action, or only those of the skills in `operator_actions` (a skill left out has its
action server still, whose goals abort saying why).

Parameters: `terminal` ('' = this process's stdin/stdout; a device such as /dev/tty,
what scripts/start_graph.sh --operator person passes, or a pty), `skill_timeout`,
`operator_actions`, `push_distance` and `lift_height` (the words of a goal that leaves
its length 0). A terminal that cannot be opened is a configuration error.
"""

import sys
import threading
import time
from functools import partial

import rclpy
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor

from abp_common import names
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.param_spec import DOUBLE, STRING, STRING_ARRAY, ParamSpec
from abp_common.parameters import declare_all
from abp_msgs.srv import CheckFeasibility

from .operator_prompts import (
    OPERATOR_SKILLS,
    RequestError,
    check_operator_actions,
    feasibility,
    format_request,
    parse_answer,
    request_for,
)
from .operator_terminal import OperatorTerminal, TerminalClosed
from .skill_goals import SKILL_TYPES, end_goal

# How often a waiting goal looks for a cancel, s.
POLL_S = 0.1

OPERATOR_SPECS = (
    ParamSpec('terminal', STRING, '', "Where the person reads and answers: '' = this "
              "process's stdin/stdout; else a terminal device (/dev/tty, a pty).",
              read_only=True),
    ParamSpec('skill_timeout', DOUBLE, 120.0, 'Wall seconds the person has to answer a '
              "request; then the goal aborts. Keep it below the planner's skill_timeout.",
              (1.0, 3600.0)),
    ParamSpec('operator_actions', STRING_ARRAY, list(OPERATOR_SKILLS), 'Skills the person '
              'will do (orbit, push, lift, flip); the others are infeasible.', read_only=True),
    ParamSpec('push_distance', DOUBLE, 0.10, 'PUSH distance asked when a goal leaves '
              'stroke_length 0, m.', (0.01, 0.5)),
    ParamSpec('lift_height', DOUBLE, 0.10, 'LIFT height asked when a goal leaves '
              'lift_height 0, m.', (0.01, 0.5)),
)


class OperatorSkillsNode(ManagedNode):
    """Configure opens the terminal; activate the four action servers and the
    feasibility service."""

    def __init__(self):
        super().__init__('operator_skills')
        self.terminal = None      # opened once per process (its reader may block in a read)
        self._busy = threading.Lock()
        self._current = ''

    def configure(self):
        values = self._values = declare_all(self, OPERATOR_SPECS)
        self.skills = check_operator_actions(values['operator_actions'])
        if self.terminal is None:
            try:
                self.terminal = OperatorTerminal(values['terminal'])
            except OSError as error:
                raise ValueError(f'parameter terminal: cannot open {values["terminal"]!r} '
                                 f'({error.strerror or error}): start the node from a '
                                 'terminal, or give one') from None
        self.callback_group = ReentrantCallbackGroup()

    def activate(self):
        for skill in OPERATOR_SKILLS:
            ActionServer(self, SKILL_TYPES[skill], names.skill_action(skill),
                         execute_callback=partial(self._execute, skill),
                         goal_callback=lambda _goal: GoalResponse.ACCEPT,
                         cancel_callback=lambda _handle: CancelResponse.ACCEPT,
                         callback_group=self.callback_group)
        self.create_service(CheckFeasibility, names.CHECK_FEASIBILITY, self._on_feasibility,
                            callback_group=self.callback_group)
        self.get_logger().info(
            f'operator ready on {self.terminal.name}: the person does '
            f'{", ".join(self.skills) or "nothing"}; '
            f'{self.get_parameter("skill_timeout").value:.0f} s to answer each request')
        self.terminal.show('\n[abp] Operator ready: requests for you will appear here.\n')

    # -- the feasibility service ---------------------------------------------------------
    def _on_feasibility(self, request, response):
        actions, verdicts = feasibility(request.actions, self.skills)
        response.actions = actions
        response.feasible = [ok for ok, _ in verdicts]
        response.reasons = [why for _, why in verdicts]
        return response

    # -- a goal ----------------------------------------------------------------------------
    def _execute(self, skill, goal_handle):
        started = time.monotonic()
        if skill not in self.skills:
            return self._finish(skill, goal_handle, 'abort', f'refused: the operator does '
                                f'not do {skill} (parameter operator_actions)', started)
        try:
            request = request_for(skill, goal_handle.request, self._param('push_distance'),
                                  self._param('lift_height'))
        except RequestError as error:
            return self._finish(skill, goal_handle, 'abort', f'refused: {error}', started)
        if not self._busy.acquire(blocking=False):
            return self._finish(skill, goal_handle, 'abort',
                                f'rejected: busy: the operator is doing {self._current}',
                                started)
        try:
            self._current = request.title
            outcome, reason = self._ask(skill, goal_handle, request, started)
        finally:
            self._current = ''
            self._busy.release()
        return self._finish(skill, goal_handle, outcome, reason, started)

    def _ask(self, skill, goal_handle, request, started):
        """Put `request` to the person and wait for the answer: (outcome, reason)."""
        terminal = self.terminal
        timeout = self._param('skill_timeout')
        if terminal.drain():
            terminal.show('\n(nothing was asked when you typed that: it is not taken as an '
                          'answer)\n')
        self.get_logger().info(f'asking the operator: {request.title}: {request.words}')
        terminal.show(format_request(request, timeout))
        feedback = SKILL_TYPES[skill].Feedback(phase='waiting for the operator', progress=0.0)
        goal_handle.publish_feedback(feedback)
        while True:
            if goal_handle.is_cancel_requested:
                terminal.show(f'\n[abp] WITHDRAWN: {request.title} is no longer wanted. Do not '
                              'do it; leave the cube as it is.\n')
                return 'cancel', 'canceled: the request was withdrawn from the operator'
            if not goal_handle.is_active:
                return 'abort', 'goal no longer active'
            if not rclpy.ok(context=self.context):
                return 'abort', 'shutting down'
            remaining = started + timeout - time.monotonic()
            if remaining <= 0.0:
                terminal.show(f'\n[abp] No answer within {timeout:.0f} s: {request.title} is '
                              'withdrawn. Leave the cube as it is.\n')
                return 'abort', (f'timeout: the operator did not answer within '
                                 f'{timeout:.0f} s (skill_timeout)')
            try:
                line = terminal.next_line(min(POLL_S, remaining))
            except TerminalClosed as closed:
                return 'abort', f'no operator: {closed}'
            if line is None:
                continue
            answer = parse_answer(line)
            if answer.kind == 'done':
                terminal.show(f'[abp] {request.title}: done, thank you.\n')
                return 'succeed', ''
            if answer.kind == 'not_done':
                terminal.show(f'[abp] {request.title}: not done ({answer.text}).\n')
                return 'abort', f'the operator could not do it: {answer.text}'
            if answer.kind == 'help':
                terminal.show(format_request(request, max(remaining, 0.0)))
            else:
                terminal.show(f'{answer.text}\n> ')

    def _finish(self, skill, goal_handle, outcome, reason, started):
        return end_goal(goal_handle, skill, outcome, reason, time.monotonic() - started,
                        self.get_logger())

    def _param(self, name):
        return self.get_parameter(name).value


def main(args=None):
    return run_node('operator_skills', OperatorSkillsNode, args,
                    config_errors=(TypeError, rclpy.exceptions.ParameterException),
                    make_executor=partial(MultiThreadedExecutor, num_threads=4))


if __name__ == '__main__':
    sys.exit(main())
