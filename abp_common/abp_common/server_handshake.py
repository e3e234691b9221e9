"""Make sure an action server can hear a client, and answer it, before a goal is sent.

`ActionClient.server_is_ready()` says that the *client* has discovered the server's
endpoints. The server discovers the client's on its own schedule, and until it has, DDS
drops what passes between them: a goal request sent too early is never seen, and a goal
response for a reader the server has not matched is dropped after rmw_fastrtps's 100 ms
wait ("Failed to send goal response"). Under load that window lasts long enough to lose a
goal; a lost goal response is worse than a lost request, because the server then runs a
goal the client believes was never accepted.

The handshake sends a request that has no effect, a cancel for a goal id nobody holds,
until the server answers it. rcl creates an action client's goal service before its cancel
service, and DDS announces (and each participant matches) a participant's endpoints in
the order they were created, so a server that has answered the cancel request has matched
the goal request and reply endpoints too. The goal sent after it is not lost in discovery.
"""

import time
import uuid

from rclpy.action.client import ClientGoalHandle
from unique_identifier_msgs.msg import UUID

# One probe's wait for an answer: long enough for a loaded machine's round trip, short
# enough that a probe lost in discovery is repeated soon.
PROBE_TIMEOUT_S = 1.0


def ask_action_server(action_client):
    """Send one harmless cancel request; the returned future completes when it is answered."""
    nobody_holds = UUID(uuid=list(uuid.uuid4().bytes))
    return ClientGoalHandle(action_client, nobody_holds, None).cancel_goal_async()


def wait_until_answering(action_client, spin_until, timeout, probe_timeout=PROBE_TIMEOUT_S):
    """True once the server has answered a probe; False if `timeout` seconds pass first.

    `spin_until(predicate, seconds)` spins the client's executor until `predicate()` is
    true or the time is up, and returns `predicate()`: the loop of a single-threaded
    client. A multi-threaded caller waits on `ask_action_server`'s future instead."""
    deadline = time.monotonic() + timeout
    # Unanswered probes stay pending: a late answer to a forgotten one would make rclpy
    # warn of "more than one action server". Any answer will do.
    probes = []
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0 or not spin_until(action_client.server_is_ready, remaining):
            return False
        probes.append(ask_action_server(action_client))
        if spin_until(lambda: any(p.done() for p in probes),
                      max(0.05, min(probe_timeout, deadline - time.monotonic()))):
            return True


__all__ = ['PROBE_TIMEOUT_S', 'ask_action_server', 'wait_until_answering']
