"""Every installed entry point (install/<pkg>/lib/<pkg>/<exe>, what `ros2 run` and
`ros2 launch` start) runs with an interpreter that imports the whole stack.

colcon writes the interpreter that ran it into each shebang; on a robot with
/opt/ros/jazzy, apt's `colcon` would write /usr/bin/python3, which cannot import the
packages of requirements/robot.txt (ros2/ros2cli#1024), so scripts/bootstrap.sh runs
colcon with the venv's Python. Here the shebang's interpreter must import rclpy and every
third-party module the nodes import, in the environment of scripts/env.sh.
"""

import os
import pathlib
import shutil
import subprocess

import pytest

from abp_common.graph_nodes import GRAPH
from tests.helpers.manifests import REPO

STACK_MODULES = ('rclpy', 'numpy', 'scipy', 'yaml', 'cv2', 'pinocchio', 'ruckig', 'rosbags',
                 'mujoco')
# The executables scripts/start_graph.sh and abp.launch.py start: every graph's nodes
# (abp_common.graph_nodes), the lifecycle manager and the Recognize client.
GRAPH_EXECUTABLES = {(node.package, node.executable) for node in GRAPH} | {
    ('abp_bringup', 'lifecycle_manager'), ('abp_bringup', 'recognize')}


def entry_points():
    found = {}
    for path in sorted(REPO.glob('install/*/lib/*/*')):
        package = path.parent.name
        if path.is_file() and path.parents[2].name == package and os.access(path, os.X_OK):
            found[(package, path.name)] = path
    return found


def interpreter(path):
    """The command the kernel runs for `path`: its shebang, `env NAME` resolved on PATH."""
    first = path.read_bytes().split(b'\n', 1)[0].decode()
    assert first.startswith('#!'), f'{path}: no shebang'
    words = first[2:].split()
    if pathlib.Path(words[0]).name == 'env':
        words = [arg for arg in words[1:] if not arg.startswith('-')]
        resolved = shutil.which(words[0])
        assert resolved, f'{path}: {words[0]} is not on PATH'
        words[0] = resolved
    return tuple(words)


ENTRY_POINTS = entry_points()


def test_the_graph_executables_are_installed():
    if not ENTRY_POINTS:
        pytest.fail('install/ has no entry points: run scripts/bootstrap.sh first')
    missing = GRAPH_EXECUTABLES - set(ENTRY_POINTS)
    assert not missing, f'not installed: {sorted(missing)}'


def test_every_entry_point_interpreter_imports_the_stack():
    by_interpreter = {}
    for (package, name), path in ENTRY_POINTS.items():
        by_interpreter.setdefault(interpreter(path), []).append(f'{package}/{name}')
    assert by_interpreter
    code = f'import {", ".join(STACK_MODULES)}'
    for command, users in by_interpreter.items():
        result = subprocess.run([*command, '-c', code], capture_output=True, text=True,
                                timeout=120)
        assert result.returncode == 0, (
            f'{" ".join(command)} (the shebang of {", ".join(sorted(users))}) cannot import '
            f'the stack:\n{result.stderr[-2000:]}')
