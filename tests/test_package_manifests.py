"""Every package's package.xml lists what its Python code imports (rosdep trusts it), and
no package a robot runs pulls in the simulator or the benchmark-only libraries.

Static (AST) scan of the sources: no ROS graph needed.
"""

import ast
import pathlib
import sys
import xml.etree.ElementTree as ET

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent
PACKAGES = sorted(p.parent for p in REPO.glob('abp_*/package.xml'))
# Import name -> rosdep key, where they differ.
ROSDEP_KEY = {
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib', 'tqdm': 'python3-tqdm', 'pytest': 'python3-pytest',
    'OpenGL': 'python3-opengl',
}
# Imports no rosdep key provides in a usable version (tests/fixtures/rosdistro/
# rosdep_keys.yaml says why): pinned in requirements/robot.txt instead, and named in
# requirements/requirements.txt for the wheel install. Import name -> PyPI name.
FROM_ROBOT_TXT = {'cv2': 'opencv-python-headless', 'mujoco': 'mujoco', 'rosbags': 'rosbags',
                  'ruckig': 'ruckig'}
NOT_DEPENDENCIES = {'setuptools'} | set(sys.stdlib_module_names)
# What a robot install must never need (issue 11): the simulator and benchmark tooling.
BENCH_ONLY = {'abp_sim_bridge', 'python3-matplotlib', 'python3-tqdm'}
RUNTIME_WITHOUT_BENCH = ('abp_belief', 'abp_bringup', 'abp_common', 'abp_description',
                         'abp_perception', 'abp_planner', 'abp_skills')


def imported_keys(files, own):
    keys = {}
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split('.')[0]
                if top in NOT_DEPENDENCIES or top == own or top in {'tests', 'conftest'}:
                    continue
                if top in FROM_ROBOT_TXT:
                    continue  # test_pip_only_imports_are_pinned_for_the_robot
                keys.setdefault(ROSDEP_KEY.get(top, top), path.relative_to(REPO))
    return keys


def declared(package, tags):
    root = ET.parse(package / 'package.xml').getroot()
    return {e.text.strip() for tag in tags for e in root.iter(tag)}


def sources(package):
    code = [p for p in (package / package.name).rglob('*.py')]
    code += [p for p in package.glob('launch/*.py')]
    tests = list((package / 'test').rglob('*.py')) if (package / 'test').is_dir() else []
    local = {p.stem for p in tests}  # test helpers imported by name
    return code, tests, local


@pytest.mark.parametrize('package', PACKAGES, ids=lambda p: p.name)
def test_package_xml_lists_every_import(package):
    code, tests, local = sources(package)
    runtime = declared(package, ('depend', 'exec_depend'))
    missing = {k: str(f) for k, f in imported_keys(code, package.name).items()
               if k not in runtime}
    assert not missing, f'{package.name}/package.xml lacks exec_depend for {missing}'
    testing = runtime | declared(package, ('test_depend',))
    missing = {k: str(f) for k, f in imported_keys(tests, package.name).items()
               if k not in testing and k not in local}
    assert not missing, f'{package.name}/package.xml lacks test_depend for {missing}'


@pytest.mark.parametrize('name', RUNTIME_WITHOUT_BENCH)
def test_runtime_packages_never_need_the_simulator_or_benchmark_tools(name):
    package = REPO / name
    code, _, _ = sources(package)
    imports = set(imported_keys([p for p in code if p.parent.name != 'launch'], name))
    assert not imports & BENCH_ONLY, f'{name} imports {imports & BENCH_ONLY}'


def exec_depends(name):
    package = REPO / name
    return declared(package, ('depend', 'exec_depend')) if package.is_dir() else set()


@pytest.mark.parametrize('name', RUNTIME_WITHOUT_BENCH)
def test_runtime_packages_never_exec_depend_on_the_simulator(name):
    """Through the workspace's packages too: rosdep and colcon follow exec_depend, so one
    runtime package naming abp_sim_bridge would put MuJoCo on every robot."""
    seen, todo, bench = set(), [name], {}
    while todo:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        for key in exec_depends(current):
            if key in BENCH_ONLY:
                bench[key] = current
            elif key.startswith('abp_'):
                todo.append(key)
    assert not bench, f'{name} exec-depends on {bench} (key: the package that names it)'


def test_the_robot_graph_needs_only_runtime_packages():
    from abp_common.graph_nodes import GRAPH

    for node in GRAPH:
        assert (node.package in BENCH_ONLY) == node.sim_only, node
        if not node.sim_only:   # runs on a robot or with the operator: no simulator
            assert node.package in RUNTIME_WITHOUT_BENCH, node
            assert node.package in exec_depends('abp_bringup') | {'abp_bringup'}, \
                f'abp_bringup starts {node.executable} but does not exec-depend on it'


# Issue 11: a node file a reader can hold; the anchors' node files are 70-200 lines.
MAX_NODE_FILE_LINES = 450


@pytest.mark.parametrize('path', sorted(REPO.glob('abp_*/abp_*/*_node.py')),
                         ids=lambda p: p.name)
def test_node_file_is_short(path):
    lines = len(path.read_text().splitlines())
    assert lines <= MAX_NODE_FILE_LINES, \
        f'{path.relative_to(REPO)} has {lines} lines (at most {MAX_NODE_FILE_LINES})'


def requirement_names(path):
    names = {}
    for line in path.read_text().splitlines():
        line = line.split('#')[0].strip()
        if line:
            name, _, version = line.partition('==')
            names[name.strip().lower()] = version.strip()
    return names


def test_pip_only_imports_are_pinned_for_the_robot():
    robot = requirement_names(REPO / 'requirements' / 'robot.txt')
    wheels = requirement_names(REPO / 'requirements' / 'requirements.txt')
    for module, name in FROM_ROBOT_TXT.items():
        assert robot.get(name), f'requirements/robot.txt lacks an exact pin of {name} ({module})'
        assert name in wheels, f'requirements/requirements.txt lacks {name} ({module})'
