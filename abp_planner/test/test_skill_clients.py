"""SkillClients over real rclpy action servers: a skill server that answers the handshake
but leaves the graph before answering the goal is reported gone at once, not after the
goal-answer timeout as a "rejected" goal (a link drop while a goal is on its way: the
planner then pauses naming what it lost, abp_bench/test/test_two_hosts.py)."""

import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.action import ActionServer, GoalResponse  # noqa: E402
from rclpy.callback_groups import ReentrantCallbackGroup  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402

from abp_common import names  # noqa: E402
from abp_msgs.action import Orbit  # noqa: E402
from abp_msgs.msg import ExecutedAction  # noqa: E402
from abp_planner.skill_clients import GOAL_ANSWER_TIMEOUT_S, SkillClients  # noqa: E402

WAIT_S = 30.0


def test_a_server_gone_before_answering_the_goal_is_reported_gone(rclpy_context):
    planner = rclpy.create_node('skill_clients_test', context=rclpy_context)
    clients = SkillClients(planner)
    planner_executor = MultiThreadedExecutor(num_threads=2, context=rclpy_context)
    planner_executor.add_node(planner)

    server_node = rclpy.create_node('orbit_server_test', context=rclpy_context)
    goal_arrived, release = threading.Event(), threading.Event()

    def hold_the_goal(_request):
        goal_arrived.set()
        release.wait(WAIT_S)   # never answers while the test runs
        return GoalResponse.REJECT
    server = ActionServer(server_node, Orbit, names.skill_action('orbit'),
                          lambda handle: Orbit.Result(),
                          goal_callback=hold_the_goal,
                          callback_group=ReentrantCallbackGroup())
    server_executor = MultiThreadedExecutor(num_threads=2, context=rclpy_context)
    server_executor.add_node(server_node)
    spinners = [threading.Thread(target=e.spin, daemon=True)
                for e in (planner_executor, server_executor)]
    for spinner in spinners:
        spinner.start()
    outcome = {}

    def run():
        outcome['result'] = clients.run(ExecutedAction.ORBIT_P45, 60.0, lambda: False)
        outcome['done_at'] = time.monotonic()
    runner = threading.Thread(target=run, daemon=True)
    try:
        runner.start()
        assert goal_arrived.wait(WAIT_S), 'the goal never reached the server'
        # The server leaves the graph with the goal unanswered (its process died, or the
        # link to it is down and its lease ran out).
        gone_at = time.monotonic()
        server_executor.remove_node(server_node)
        server.destroy()
        server_node.destroy_node()
        runner.join(WAIT_S)
        assert not runner.is_alive(), 'run() did not return'
        success, reason, _ = outcome['result']
        assert not success
        assert 'went away before answering the goal' in reason, reason
        assert outcome['done_at'] - gone_at < GOAL_ANSWER_TIMEOUT_S
    finally:
        release.set()
        for executor in (planner_executor, server_executor):
            executor.shutdown()
        planner.destroy_node()
