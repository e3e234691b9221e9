"""The crash test (issue 14): each of the graph's nodes (abp_bench.soak.GRAPH_NODES)
killed with SIGKILL mid-episode, in turn, on one running graph (`python -m abp_bench.soak
--episodes 0 --kill ...`, rules world). Each time the episode must end (correct, or
aborted / lost with a reason), the node must be back (a new process, active again under
the lifecycle manager) and the next goal must succeed with the right object; no process
of the graph may be left afterwards. The driver inherits this session's isolated
ROS_DOMAIN_ID from the root conftest."""

import json
import re
import sys

import pytest

from abp_bench.soak import GRAPH_NODES
from tests.helpers.graph import node_log_tails, run_to_end

# Idle, the whole test takes about 3 minutes (14 episodes of 10-20 s, each node back
# within seconds). The deadlines leave room for a loaded machine, and stop the driver
# (which stops its graph) with a trace well before pytest-timeout would.
EPISODE_TIMEOUT_S = 240
DRIVER_TIMEOUT_S = 1500


@pytest.mark.timeout(DRIVER_TIMEOUT_S + 300)
def test_every_node_killed_mid_episode_comes_back_and_the_next_goal_succeeds(tmp_path):
    report = tmp_path / 'crash.json'
    code, trace, timed_out = run_to_end(
        [sys.executable, '-m', 'abp_bench.soak', '--episodes', '0', '--no-build',
         '--episode-timeout', str(EPISODE_TIMEOUT_S), '--kill', *GRAPH_NODES,
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
    assert sorted(crashes) == sorted(GRAPH_NODES), trace
    for name, crash in crashes.items():
        if crash['outcome'] == 'succeeded':
            assert crash['correct'], (name, trace)
        else:
            assert crash['outcome'] in ('aborted', 'lost') and crash['reason'], (name, trace)
        assert crash['back_s'] is not None, (name, trace)
        assert crash['next']['outcome'] == 'succeeded' and crash['next']['correct'], \
            (name, trace)
    assert result['stopped'] and not result['leftovers'], trace
    assert code == 0, trace
