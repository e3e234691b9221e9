"""The operator skill server over real DDS, used the way a person uses it: the node's
terminal is a pty, and the test reads the requests on it and types the answers.

A done answer for each action (with a bad answer first, which is asked again), a
could-not-do with its reason, a busy refusal, a cancel that withdraws the request, a
timeout, and the feasibility service for all actions and for a person who only turns
the cube."""

import os
import re
import select
import time

import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')
try:
    from abp_msgs.action import Flip, Lift, Orbit, Push
    from abp_msgs.srv import CheckFeasibility
except ImportError:
    pytest.skip('abp_msgs is not built/sourced (scripts/bootstrap.sh; source scripts/env.sh)',
                allow_module_level=True)

from action_msgs.msg import GoalStatus  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402

pytestmark = pytest.mark.timeout(300)

ANSWER_WAIT_S = 60.0     # generous: the machine is shared


def executable(name):
    return os.path.join(ament_index.get_package_prefix('abp_skills'), 'lib', 'abp_skills', name)


class Person:
    """The other end of the node's terminal: reads what it shows, types lines."""

    def __init__(self):
        self.master, slave = os.openpty()
        self.device = os.ttyname(slave)
        self._slave = slave          # kept open so the pty lives until the node opens it
        self.seen = ''               # everything shown so far
        self._unread = ''

    def read_until(self, pattern, timeout=ANSWER_WAIT_S):
        """Read the terminal until `pattern` (a regex) appears in what is unread; returns
        the text read up to and including it."""
        deadline = time.monotonic() + timeout
        while True:
            found = re.search(pattern, self._unread)
            if found:
                text, self._unread = self._unread[:found.end()], self._unread[found.end():]
                return text
            remaining = deadline - time.monotonic()
            assert remaining > 0, (f'the terminal did not show {pattern!r} in {timeout} s; '
                                   f'it showed: {self._unread[-2000:]!r}')
            ready, _, _ = select.select([self.master], [], [], min(remaining, 0.5))
            if ready:
                chunk = os.read(self.master, 4096).decode(errors='replace')
                self.seen += chunk
                self._unread += chunk

    def type(self, line):
        os.write(self.master, (line + '\n').encode())

    def close(self):
        for fd in (self.master, self._slave):
            os.close(fd)


@pytest.fixture
def person():
    p = Person()
    yield p
    p.close()


def start_operator(ros_processes, person, **params):
    argv = [executable('operator_skills'), '--ros-args', '-p', f'terminal:={person.device}']
    for key, value in params.items():
        argv += ['-p', f'{key}:={value}']
    proc = ros_processes.start(argv)
    person.read_until(r'Operator ready')
    return proc


def clients(node):
    return {'orbit': ActionClient(node, Orbit, 'abp/skills/orbit'),
            'push': ActionClient(node, Push, 'abp/skills/push'),
            'lift': ActionClient(node, Lift, 'abp/skills/lift'),
            'flip': ActionClient(node, Flip, 'abp/skills/flip')}


def send(executor, spin, client, goal):
    future = client.send_goal_async(goal)
    assert spin(executor, future.done, 30.0), 'no goal response'
    handle = future.result()
    assert handle.accepted
    return handle


def result_of(executor, spin, handle, timeout=ANSWER_WAIT_S):
    future = handle.get_result_async()
    assert spin(executor, future.done, timeout), 'no result'
    response = future.result()
    return response.status, response.result


def test_a_person_answers_every_action(ros_processes, tester, spin, answering, call_service,
                                       person):
    node, executor = tester
    start_operator(ros_processes, person, skill_timeout=600.0)
    actions = clients(node)
    for skill, client in actions.items():
        assert answering(executor, client, 60.0), f'the {skill} server does not answer'

    feasible = call_service(executor, node.create_client(
        CheckFeasibility, 'abp/skills/check_feasibility'), CheckFeasibility.Request(), 60.0)
    assert list(feasible.actions) == ['ORBIT_P45', 'ORBIT_M45', 'ORBIT_P90', 'ORBIT_M90',
                                      'ORBIT_180', 'PUSH', 'LIFT', 'FLIP']
    assert all(feasible.feasible)

    asked = [('orbit', Orbit.Goal(angle_deg=90.0), r'ORBIT \+90 deg[\s\S]*counter-clockwise'
                                                   r'[\s\S]*right side'),
             ('orbit', Orbit.Goal(angle_deg=-45.0), r'ORBIT -45 deg[\s\S]*clockwise'),
             ('orbit', Orbit.Goal(angle_deg=180.0), r'ORBIT \+180 deg[\s\S]*half turn'),
             ('push', Push.Goal(face='front'), r'PUSH 10 cm[\s\S]*away from the\s+camera'),
             ('lift', Lift.Goal(lift_height=0.05), r'LIFT 5 cm[\s\S]*two opposite faces'),
             ('flip', Flip.Goal(), r'FLIP 90 deg[\s\S]*away from you')]
    for skill, goal, words in asked:
        handle = send(executor, spin, actions[skill], goal)
        person.read_until(words)
        person.read_until(r'> ')
        person.type('maybe later')           # not an answer: asked again, nothing ends
        person.read_until(r"'maybe later' is not an answer")
        person.type('d')
        status, result = result_of(executor, spin, handle)
        assert status == GoalStatus.STATUS_SUCCEEDED, result.reason
        assert result.success and result.reason == ''
        person.read_until(r'done, thank you')

    # Could not do it: aborted with the person's reason.
    handle = send(executor, spin, actions['push'], Push.Goal())
    person.read_until(r'PUSH 10 cm[\s\S]*> ')
    person.type('n the cube is stuck to the table')
    status, result = result_of(executor, spin, handle)
    assert status == GoalStatus.STATUS_ABORTED
    assert not result.success
    assert result.reason == 'the operator could not do it: the cube is stuck to the table'

    # While a request waits for the person, another goal is refused as busy; a cancel then
    # withdraws the request on the terminal.
    waiting = send(executor, spin, actions['lift'], Lift.Goal())
    person.read_until(r'LIFT 10 cm[\s\S]*> ')
    status, result = result_of(executor, spin, send(executor, spin, actions['flip'],
                                                    Flip.Goal()))
    assert status == GoalStatus.STATUS_ABORTED
    assert result.reason.startswith('rejected: busy: the operator is doing LIFT 10 cm')
    cancel = waiting.cancel_goal_async()
    assert spin(executor, cancel.done, 30.0)
    person.read_until(r'WITHDRAWN: LIFT 10 cm is no longer wanted')
    status, result = result_of(executor, spin, waiting)
    assert status == GoalStatus.STATUS_CANCELED
    assert 'withdrawn' in result.reason


def test_an_unanswered_request_times_out_and_feasibility_follows_the_person(
        ros_processes, tester, spin, answering, call_service, person):
    node, executor = tester
    start_operator(ros_processes, person, skill_timeout=2.0, operator_actions="['orbit']")
    actions = clients(node)
    for client in actions.values():
        assert answering(executor, client, 60.0)

    request = CheckFeasibility.Request(actions=['ORBIT_P90', 'PUSH', 'FLIP', 'JUMP'])
    feasible = call_service(executor, node.create_client(
        CheckFeasibility, 'abp/skills/check_feasibility'), request, 60.0)
    assert list(feasible.feasible) == [True, False, False, False]
    assert feasible.reasons[0] == ''
    assert 'does not do push' in feasible.reasons[1]
    assert feasible.reasons[3] == "unknown action 'JUMP'"

    status, result = result_of(executor, spin, send(executor, spin, actions['flip'],
                                                    Flip.Goal()))
    assert status == GoalStatus.STATUS_ABORTED
    assert result.reason == 'refused: the operator does not do flip (parameter operator_actions)'

    started = time.monotonic()
    handle = send(executor, spin, actions['orbit'], Orbit.Goal(angle_deg=-90.0))
    status, result = result_of(executor, spin, handle)
    assert status == GoalStatus.STATUS_ABORTED
    assert result.reason == 'timeout: the operator did not answer within 2 s (skill_timeout)'
    assert time.monotonic() - started >= 2.0
    assert result.duration.sec >= 2
    person.read_until(r'ORBIT -90 deg[\s\S]*No answer within 2 s: ORBIT -90 deg is\s+withdrawn')


def test_a_terminal_that_cannot_be_opened_is_a_configuration_error(ros_processes, tmp_path):
    proc = ros_processes.start([executable('operator_skills'), '--ros-args', '-p',
                                f'terminal:={tmp_path / "no-such-tty"}'])
    assert proc.wait(timeout=60) == 2
    assert 'parameter terminal: cannot open' in ros_processes.output(proc)
