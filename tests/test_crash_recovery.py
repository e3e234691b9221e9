"""The crash test (issue 14): every node of the graph (abp_bench.soak.GRAPH_NODES) killed
with SIGKILL mid-episode on one running graph (`python -m abp_bench.soak --episodes 0
--kill ...`, rules world), two different nodes together in an episode where they do not
share a role (`a+b`), so that the 7 nodes take 4 crash episodes instead of 7. Each time
the episode must end (correct, or aborted / lost with a reason), each killed node must be
back (a new process, active again under the lifecycle manager) and the next goal must
succeed with the right object; no process of the graph may be left afterwards. The
driver inherits this session's isolated ROS_DOMAIN_ID from the root conftest.

A killed belief node's episode must still end correct: the planner sees the new belief
node (its step went back) and re-observes from the reset belief (the whole-graph check
that tests/test_end_to_end.py used to make in an episode of its own; the planner's side
is also in abp_planner/test/test_planner_node.py). Its partner, robot_state, only
publishes the tf tree, which no recognition node reads."""

import json
import re
import sys

import pytest

from abp_bench.soak import GRAPH_NODES
from tests.helpers.graph import node_log_tails, run_to_end

# Pairs that do not share a role: the belief with the tf publisher, the two perception
# stages, the skills with the simulated robot they drive. The planner goes alone: its
# goal dies with it.
# The detector and the matcher were killed apart for a while: killed together (one
# clean-clone run in four), both came back active but no observation reached the belief.
# The cause was Fast DDS's shared memory, which the test graphs used until start_graph.sh
# gave them a UDP profile under LOCALHOST (docs/RECOVERY.md). Killed together again: 8 of
# 8 kills came back with the next goal correct (`soak --episodes 0 --kill
# artag_detector+aspect_matcher artag_detector+aspect_matcher`, two at a time beside a
# busy loop).
KILL_GROUPS = ('belief+robot_state', 'artag_detector+aspect_matcher',
               'skill_servers+sim_bridge', 'planner')
MUST_END_CORRECT = 'belief+robot_state'
# Idle, the whole test takes about 2.5 minutes (8 episodes of 10-20 s, each node back
# within seconds). The deadlines leave room for a loaded machine, and stop the driver
# (which stops its graph) with a trace well before pytest-timeout would.
EPISODE_TIMEOUT_S = 240
DRIVER_TIMEOUT_S = 1200


def test_the_kill_groups_cover_every_node_once():
    killed = [name for group in KILL_GROUPS for name in group.split('+')]
    assert sorted(killed) == sorted(GRAPH_NODES)


@pytest.mark.timeout(DRIVER_TIMEOUT_S + 300)
def test_every_node_killed_mid_episode_comes_back_and_the_next_goal_succeeds(tmp_path):
    report = tmp_path / 'crash.json'
    code, trace, timed_out = run_to_end(
        [sys.executable, '-m', 'abp_bench.soak', '--episodes', '0', '--no-build',
         '--episode-timeout', str(EPISODE_TIMEOUT_S), '--kill', *KILL_GROUPS,
         '--json', str(report)],
        DRIVER_TIMEOUT_S, tmp_path / 'soak-output.txt')
    # The driver prints where its graph's logs are: a failure report carries their tails
    # (the temporary directory does not outlive a CI machine).
    logs = re.search(r'logs in (\S+)\)', trace)
    if logs:
        trace += node_log_tails(logs.group(1), lines=60)
    assert not timed_out, trace
    assert report.exists(), trace
    result = json.loads(report.read_text())
    assert result['failed'] is None, trace
    crashes = {c['killed']: c for c in result['crashes']}
    assert sorted(crashes) == sorted(KILL_GROUPS), trace
    for group, crash in crashes.items():
        if crash['outcome'] == 'succeeded' or group == MUST_END_CORRECT:
            assert crash['outcome'] == 'succeeded' and crash['correct'], (group, trace)
        else:
            assert crash['outcome'] in ('aborted', 'lost') and crash['reason'], (group, trace)
        assert sorted(crash['back_s']) == sorted(group.split('+')), (group, trace)
        assert all(s is not None for s in crash['back_s'].values()), (group, trace)
        assert crash['next']['outcome'] == 'succeeded' and crash['next']['correct'], \
            (group, trace)
    assert result['stopped'] and not result['leftovers'], trace
    assert code == 0, trace
    # The driver's episode lines and its table (seen with -s): the times of each stage.
    print('\n'.join(line for line in trace.splitlines()
                    if line.startswith(('[soak]', '|', 'graph stopped'))))
