"""The planner's clients of the skill servers (abp/skills/{orbit,push,lift,flip}).

`SkillClients.run(action, ...)` sends one planner action as a skill goal and waits for
its result, watching that the server that took the goal stays on the graph. ROS wiring
of the planner node, split from it so that the node file holds the node.

rclpy 7.1's ActionClient registers a request only after sending it, so a reply
processed by another executor thread in between is dropped ("Ignoring unexpected goal
response", ros2/rclpy#1123): the planner then took a goal the server had accepted and
run for a rejection. Requests are therefore made on the executor, in the clients' own
mutually exclusive callback group, where no reply can be taken meanwhile.
"""

import queue
import threading
import time

from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.duration import Duration
from rclpy.task import Future

from abp_common import names
from abp_common.server_handshake import PROBE_TIMEOUT_S, ask_action_server
from abp_msgs.action import Flip, Lift, Orbit, Push
from abp_msgs.msg import ExecutedAction

# While a goal is sent or a skill runs: how often to check that its server is still there.
SERVER_CHECK_S = 1.0
GOAL_ANSWER_TIMEOUT_S = 10.0
# For reasons: GoalStatus value -> 'aborted', 'canceled', ...
STATUS_NAMES = {getattr(GoalStatus, name): name[len('STATUS_'):].lower()
                for name in dir(GoalStatus) if name.startswith('STATUS_')}

SKILL_TYPES = {'orbit': Orbit, 'push': Push, 'lift': Lift, 'flip': Flip}
# Planner action name -> (skill on abp/skills/<skill>, its goal).
SKILLS = {
    ExecutedAction.ORBIT_P45: ('orbit', lambda: Orbit.Goal(angle_deg=45.0)),
    ExecutedAction.ORBIT_M45: ('orbit', lambda: Orbit.Goal(angle_deg=-45.0)),
    ExecutedAction.ORBIT_P90: ('orbit', lambda: Orbit.Goal(angle_deg=90.0)),
    ExecutedAction.ORBIT_M90: ('orbit', lambda: Orbit.Goal(angle_deg=-90.0)),
    ExecutedAction.ORBIT_180: ('orbit', lambda: Orbit.Goal(angle_deg=180.0)),
    ExecutedAction.PUSH: ('push', lambda: Push.Goal(face='front')),
    ExecutedAction.LIFT: ('lift', lambda: Lift.Goal()),
    ExecutedAction.FLIP: ('flip', lambda: Flip.Goal()),
}


def wait_future(future, timeout):
    """The future's result, or None if it is not done within `timeout` seconds (the
    executor runs on other threads: this thread only waits)."""
    event = threading.Event()
    future.add_done_callback(lambda _: event.set())
    if not event.wait(timeout):
        return None
    return future.result()


def call_with_retry(client, request, timeout, attempt_s=2.0):
    """Call an idempotent service (a reset, a query), asking again every `attempt_s`:
    a reply to a client the server has not yet discovered is dropped by DDS."""
    deadline = time.monotonic() + timeout
    while True:
        remaining = deadline - time.monotonic()
        future = client.call_async(request)
        response = wait_future(future, min(attempt_s, max(remaining, 0.0)))
        if response is not None or time.monotonic() >= deadline:
            if response is None:
                client.remove_pending_request(future)
            return response
        client.remove_pending_request(future)


class SkillClients:
    """One ActionClient per skill on `node`, with requests made on its executor."""

    def __init__(self, node):
        self._node = node
        self._group = MutuallyExclusiveCallbackGroup()
        self.clients = {
            skill: ActionClient(node, action_type, names.skill_action(skill),
                                callback_group=self._group)
            for skill, action_type in SKILL_TYPES.items()
        }
        self._calls = queue.SimpleQueue()
        self._trigger = node.create_guard_condition(self._make_calls,
                                                    callback_group=self._group)

    def ready(self):
        """The skills whose server is on the graph now."""
        return [skill for skill, client in self.clients.items() if client.server_is_ready()]

    def run(self, action, timeout_s, cancel_requested):
        """Send the skill goal of planner action `action` and wait for its result:
        (success, reason, duration msg). `cancel_requested()` is polled; a cancel or the
        timeout cancels the skill goal."""
        skill, make_goal = SKILLS[action]
        client = self.clients[skill]
        clock = self._node.get_clock()
        if not client.wait_for_server(timeout_sec=5.0):
            return (False, f'skill server {names.skill_action(skill)} not available',
                    Duration().to_msg())
        if not self._server_answers(client, 5.0):
            return (False, f'skill server {names.skill_action(skill)} does not answer',
                    Duration().to_msg())
        started = clock.now()
        # The server, by its status publishers: if they all leave the graph (a killed
        # server's or a lost link's lease ends), a goal sent to it died with it. A
        # respawned server answers under the same name but never knew the goal; without
        # this the episode waited for the whole skill_timeout.
        servers = self._status_publishers(skill)
        sent = self._request(lambda: client.send_goal_async(make_goal()))
        send, gone = self._wait_while_there(sent, skill, servers, GOAL_ANSWER_TIMEOUT_S)
        if gone:
            return (False, f'skill server {names.skill_action(skill)} went away before '
                    'answering the goal', Duration().to_msg())
        if send is None:
            return (False, f'{skill} goal got no answer within {GOAL_ANSWER_TIMEOUT_S:.0f} s',
                    Duration().to_msg())
        if not send.accepted:
            return False, f'{skill} goal rejected', Duration().to_msg()
        result_future = self._request(send.get_result_async)
        deadline = time.monotonic() + timeout_s
        next_check = time.monotonic() + SERVER_CHECK_S
        while not result_future.done():
            if time.monotonic() > next_check:
                next_check = time.monotonic() + SERVER_CHECK_S
                if self._servers_gone(skill, servers):
                    return (False, f'skill server {names.skill_action(skill)} went away during '
                            'the skill (the goal is lost)', (clock.now() - started).to_msg())
            if cancel_requested() or time.monotonic() > deadline:
                why = 'cancelled' if cancel_requested() else f'timed out after {timeout_s:.0f} s'
                wait_future(self._request(send.cancel_goal_async), 5.0)
                wait_future(result_future, 10.0)
                return False, f'{skill} {why}', (clock.now() - started).to_msg()
            time.sleep(0.02)
        response = result_future.result()
        if response is None:
            return False, f'{skill} result lost', (clock.now() - started).to_msg()
        result = response.result
        reason = result.reason
        if not result.success and not reason:
            # Our servers always give a reason; an empty one is a result the action
            # layer made up (e.g. for a goal its server no longer knew): say so.
            status = STATUS_NAMES.get(response.status, response.status)
            reason = f'{skill} ended with goal status {status} and no reason'
        return bool(result.success), reason, result.duration

    def _wait_while_there(self, future, skill, servers, timeout_s):
        """(result, gone): the future's result, or None after `timeout_s`; gone is True
        when every one of `servers` left the graph first (checked each SERVER_CHECK_S)."""
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            result = wait_future(future, max(0.0, min(SERVER_CHECK_S, remaining)))
            if result is not None or remaining <= 0:
                return result, False
            if self._servers_gone(skill, servers):
                return None, True

    def _servers_gone(self, skill, servers):
        """True when every one of `servers` (the skill's status publishers when its goal was
        sent; none known: never gone) has left the graph."""
        return bool(servers) and not servers & self._status_publishers(skill)

    def _status_publishers(self, skill):
        topic = names.absolute(names.skill_action(skill), self._node.get_namespace()) + \
            '/_action/status'
        return {bytes(info.endpoint_gid)
                for info in self._node.get_publishers_info_by_topic(topic)}

    def _request(self, make_request):
        """A future of `make_request()` (an ActionClient *_async call), made on the
        executor inside the clients' callback group (see the module docstring)."""
        outer = Future()
        self._calls.put((make_request, outer))
        self._trigger.trigger()
        return outer

    def _make_calls(self):
        while True:
            try:
                make_request, outer = self._calls.get_nowait()
            except queue.Empty:
                return
            try:
                inner = make_request()
            except Exception as error:  # noqa: BLE001 -- handed to the waiting thread
                outer.set_exception(error)
                continue
            inner.add_done_callback(lambda done, outer=outer: self._forward(done, outer))

    def _forward(self, done, outer):
        error = done.exception()
        if error is not None:
            self._node.get_logger().error(f'skill request failed: {error}')
        outer.set_result(None if error is not None else done.result())

    def _server_answers(self, client, timeout):
        """Handshake before a goal (abp_common.server_handshake): a goal sent while the
        server has not yet discovered this client is lost, and the planner would wait out
        the skill timeout for nothing."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            probe = self._request(lambda: ask_action_server(client))
            if wait_future(probe, PROBE_TIMEOUT_S) is not None:
                return True
        return False
