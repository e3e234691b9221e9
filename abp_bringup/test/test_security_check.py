"""SROS2 asked for where the rmw cannot do it (abp_bringup.security_check): start_graph.sh
refuses at start with the reason, and starts nothing; without ROS_SECURITY_ENABLE=true
nothing changes. The probe asks the real rmw (a node created in a child process with a
throwaway keystore), so on a machine whose Fast DDS has DDS Security the refusal tests
skip, saying so."""

import os
import pathlib
import subprocess
import sys

import pytest

from abp_bringup.security_check import NO_SECURITY, probe_rmw, refusal, security_requested

REPO = pathlib.Path(__file__).resolve().parents[2]
START_GRAPH = REPO / 'scripts' / 'start_graph.sh'


def clean_environment(**values):
    env = {k: v for k, v in os.environ.items() if not k.startswith('ROS_SECURITY_')}
    env.update(values)
    return env


@pytest.fixture(scope='module')
def rmw_without_security():
    capable, said = probe_rmw(clean_environment())
    if capable:
        pytest.skip(f'this rmw has DDS Security (the probe said: {said[-300:]})')
    return said


@pytest.mark.parametrize('value', [None, 'false', '0', 'TRUE', ''])
def test_security_not_asked_for_is_not_checked(value):
    """rcl turns security on for the exact value 'true' only: anything else runs as
    before, with no probe started (refusal answers without creating a node)."""
    env = clean_environment() if value is None else clean_environment(ROS_SECURITY_ENABLE=value)
    assert not security_requested(env)
    assert refusal(env) is None
    done = subprocess.run([sys.executable, '-m', 'abp_bringup.security_check'], env=env,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and not done.stderr, done


def test_the_probe_hears_the_rmw_refuse_security(rmw_without_security):
    assert NO_SECURITY in rmw_without_security


@pytest.mark.parametrize('strategy, consequence', [
    ('Enforce', 'the nodes would fail to start.'),
    (None, 'run unencrypted and unauthenticated'),
])
def test_start_graph_refuses_security_it_cannot_provide(rmw_without_security, tmp_path,
                                                        strategy, consequence):
    env = clean_environment(ROS_SECURITY_ENABLE='true',
                            ROS_SECURITY_KEYSTORE=str(tmp_path / 'keystore'))
    if strategy:
        env['ROS_SECURITY_STRATEGY'] = strategy
    log_dir = tmp_path / 'logs'
    done = subprocess.run([START_GRAPH, '--no-build', '--world', 'rules', '--log-dir', log_dir],
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert 'ROS_SECURITY_ENABLE=true asks for SROS2' in done.stderr, done.stderr
    assert "doesn't have the security libraries" in done.stderr
    assert consequence in done.stderr and 'Unset ROS_SECURITY_ENABLE' in done.stderr
    # Refused before anything started: no node, no log.
    assert not log_dir.exists() or not list(log_dir.glob('*.log')), list(log_dir.iterdir())
    assert not (tmp_path / 'keystore').exists(), 'the user keystore is never written'
