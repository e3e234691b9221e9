"""`scripts/start_graph.sh --operator scripted` end to end: the operator graph (detector
with a fixed camera pose, matcher, belief, operator_skills, planner) with the MuJoCo
world's fixed camera and a scripted person on operator_skills' terminal (a pty), who does
each request to the hidden cube (abp_sim_bridge.scripted_operator_node). One episode runs
to a correct identification; one, with the person silent, ends after skill_timeout with
the request aborted and the recognition stopped cleanly with a result."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip('rclpy')
pytest.importorskip('abp_sim_bridge.mujoco_scene')  # MuJoCo, with MUJOCO_GL=egl

from abp_belief.population import robot_set  # noqa: E402

pytestmark = pytest.mark.timeout(900)

REPO = Path(__file__).resolve().parents[2]
SEED = 0


def start_graph(ros_processes, tmp_path, *args):
    result_json = tmp_path / 'result.json'
    graph = ros_processes.start([
        str(REPO / 'scripts' / 'start_graph.sh'), '--no-build', '--no-respawn',
        '--operator', 'scripted', '--seed', str(SEED), '--result-json', str(result_json),
        '--log-dir', str(tmp_path / 'log'), *args])
    graph.wait(timeout=800)
    output = ros_processes.output(graph)
    assert result_json.exists(), output
    return json.loads(result_json.read_text()), output, tmp_path / 'log'


def test_a_scripted_operator_episode_identifies_the_cube(ros_processes, tmp_path):
    models = robot_set(seed=SEED)
    eccentric = int(np.flatnonzero(models.mass != 0)[0])   # it has a uniform twin
    summary, output, logs = start_graph(ros_processes, tmp_path, '--object', str(eccentric),
                                        '--max-actions', '12')
    assert 'scripted operator graph' in output
    assert summary['ground_truth'] == models.names[eccentric]
    assert summary['correct'], (summary, output)
    operator_log = (logs / 'scripted_operator.log').read_text()
    done = re.findall(r'did (.*)', operator_log)
    # Every action the planner took was a request the person read, did and answered.
    assert len(done) == summary['actions'] >= 1, (done, summary)
    assert all('as asked' in line for line in done)
    skills_log = (logs / 'operator_skills.log').read_text()
    assert skills_log.count('succeed after') == summary['actions']


def test_a_silent_operator_ends_the_request_after_skill_timeout(ros_processes, tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text('/**/operator_skills:\n  ros__parameters:\n    skill_timeout: 4.0\n')
    summary, output, logs = start_graph(ros_processes, tmp_path, '--operator-silent',
                                        '--max-actions', '1', '--params', str(params))
    assert summary['actions'] == 1
    assert not summary['success'] and not summary['correct']
    assert summary['elapsed_s'] >= 4.0
    skills_log = (logs / 'operator_skills.log').read_text()
    assert re.search(r'\w+: abort after (?:[4-9]|[1-9]\d+)\.\d s \(timeout: the operator did '
                     r'not answer within 4 s \(skill_timeout\)\)', skills_log), skills_log
    operator_log = (logs / 'scripted_operator.log').read_text()
    assert 'staying silent' in operator_log and 'did ' not in operator_log
    planner_log = (logs / 'planner.log').read_text()
    assert 'failed: timeout: the operator did not answer' in planner_log


@pytest.mark.parametrize('args, message', [
    (['--operator', 'scripted', '--camera', '/dev/video0'],
     '--operator scripted renders its own camera'),
    (['--operator', 'scripted', '--wrong-action-fraction', '1.5'],
     '--wrong-action-fraction must be a number from 0 to 1'),
    (['--wrong-action-fraction', '0.1'], 'go with --operator scripted'),
    (['--operator-silent'], 'go with --operator scripted'),
    (['--operator', 'scripted', '--robot'], 'leave out --robot'),
])
def test_start_graph_refuses_bad_scripted_options(ros_processes, args, message):
    proc = ros_processes.start([str(REPO / 'scripts' / 'start_graph.sh'), '--no-build', *args])
    assert proc.wait(timeout=60) == 2
    assert message in ros_processes.output(proc)
