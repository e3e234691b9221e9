"""start_graph.sh's options for a split graph refuse bad values at once (exit code 2, the
option named), before anything starts: --perception-on, --jpeg-quality,
--discovery-server."""

import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
START_GRAPH = REPO / 'scripts' / 'start_graph.sh'


@pytest.mark.parametrize('args, message', [
    (['--perception-on', 'moon'], '--perception-on must be robot or workstation'),
    (['--jpeg-quality', '80'], '--jpeg-quality goes with --perception-on workstation'),
    (['--perception-on', 'workstation', '--jpeg-quality', '0'],
     '--jpeg-quality must be an integer from 1 to 100'),
    (['--perception-on', 'workstation', '--jpeg-quality', '101'],
     '--jpeg-quality must be an integer from 1 to 100'),
    (['--perception-on', 'workstation', '--operator', 'scripted'],
     '--perception-on workstation splits the sim or robot graph'),
    (['--discovery-server', '10.0.0.1'], '--discovery-server must be HOST:PORT'),
    (['--discovery-server', '10.0.0.1:0'], '--discovery-server must be HOST:PORT'),
    (['--discovery-server', '10.0.0.1:70000'], '--discovery-server must be HOST:PORT'),
    (['--discovery-server', 'a b:11811'], '--discovery-server must be HOST:PORT'),
])
def test_bad_split_options_are_refused(tmp_path, args, message):
    log_dir = tmp_path / 'logs'
    done = subprocess.run([START_GRAPH, '--no-build', *args, '--log-dir', log_dir],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and message in done.stderr, (done.stdout, done.stderr)
    assert not log_dir.exists(), 'refused before anything started'
