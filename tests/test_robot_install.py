"""requirements/robot.txt installs beside a robot's ROS 2 Jazzy (Ubuntu 24.04: CPython 3.12,
apt's NumPy 1.26.4, which the ROS message packages and SciPy are built against).

pip's own resolver runs on the file for CPython 3.12 wheels (`--dry-run`: nothing is
installed, nothing touches .venv) with numpy==1.26.4 added, as the robot's apt NumPy is.
It must succeed, keep NumPy at 1.26.4, and pick exactly the pinned version of every
package: the file is a complete lock. Skipped, saying so, only when the package index
cannot be reached.
"""

import json
import subprocess
import sys

import pytest

from tests.helpers.manifests import REPO

ROBOT_TXT = REPO / 'requirements' / 'robot.txt'
APT_NUMPY = 'numpy==1.26.4'
PLATFORMS = {
    'x86_64': ('manylinux2014_x86_64', 'manylinux_2_17_x86_64', 'manylinux_2_28_x86_64'),
    'aarch64': ('manylinux2014_aarch64', 'manylinux_2_17_aarch64', 'manylinux_2_28_aarch64'),
}
# No CPython 3.12 wheel for aarch64: pip builds it from source there (robot.txt says so).
SOURCE_BUILT_ON = {'aarch64': {'ruckig'}}
PIP = [sys.executable, '-m', 'pip', '--disable-pip-version-check', '--no-input']


def pins(path=ROBOT_TXT):
    out = {}
    for line in path.read_text().splitlines():
        line = line.split('#')[0].strip()
        if not line:
            continue
        name, sep, version = line.partition('==')
        assert sep and version, f'{path.name}: {line!r} is not pinned to an exact version'
        out[canonical(name)] = version.strip()
    return out


def canonical(name):
    return name.strip().lower().replace('_', '-').replace('.', '-')


@pytest.fixture(scope='module')
def index_reachable():
    probe = subprocess.run(PIP + ['index', 'versions', 'ruckig', '--timeout', '5',
                                  '--retries', '0'],
                           capture_output=True, text=True, timeout=60)
    if probe.returncode != 0:
        pytest.skip('the Python package index cannot be reached, so pip cannot resolve '
                    f'requirements/robot.txt here: {probe.stderr.strip()[-300:]}')


def dry_run(tmp_path, arch, requirements):
    report = tmp_path / f'report-{arch}.json'
    platforms = [arg for tag in PLATFORMS[arch] for arg in ('--platform', tag)]
    result = subprocess.run(
        PIP + ['install', '--dry-run', '--ignore-installed', '--quiet', '--report',
               str(report), '--python-version', '3.12', *platforms, '--only-binary=:all:',
               '-r', str(requirements), APT_NUMPY],
        capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, (
        f'pip cannot resolve requirements/robot.txt with {APT_NUMPY} for CPython 3.12 '
        f'{arch}:\n{result.stderr[-3000:]}')
    return {canonical(item['metadata']['name']): item['metadata']['version']
            for item in json.loads(report.read_text())['install']}


def test_every_line_is_an_exact_pin_and_numpy_stays_1_26():
    pinned = pins()
    assert pinned['numpy'] == '1.26.4'
    # The packages the stack imports that apt's ROS does not give (package.xml comments).
    assert {'opencv-python-headless', 'ruckig', 'rosbags', 'mujoco', 'tqdm', 'pytest',
            'ruff'} <= set(pinned)
    opencv = tuple(int(part) for part in pinned['opencv-python-headless'].split('.')[:2])
    assert (4, 7) <= opencv < (4, 12), (
        'opencv-python-headless: 4.7 brought cv2.aruco.ArucoDetector, 4.12 needs NumPy 2')


@pytest.mark.parametrize('arch', sorted(PLATFORMS))
def test_resolves_against_apt_numpy(index_reachable, tmp_path, arch):
    pinned = pins()
    skip = SOURCE_BUILT_ON.get(arch, set())
    requirements = tmp_path / 'robot.txt'
    requirements.write_text(''.join(f'{name}=={version}\n' for name, version in pinned.items()
                                    if name not in skip))
    chosen = dry_run(tmp_path, arch, requirements)
    assert chosen.get('numpy') == '1.26.4', f'pip would replace apt NumPy: {chosen}'
    wrong = {name: (version, chosen.get(name)) for name, version in pinned.items()
             if name not in skip and chosen.get(name) != version}
    assert not wrong, f'pinned -> chosen: {wrong}'
    unpinned = set(chosen) - set(pinned)
    assert not unpinned, f'not pinned in requirements/robot.txt: {sorted(unpinned)}'
