"""abp_bringup/launch/abp.launch.py, as `ros2 launch abp_bringup abp.launch.py` would use it.

The real `launch` and `launch_ros` are not installable here (not on PyPI), so the installed
launch file is imported against the stand-ins in launch_standins/ (they record what it
builds and refuse keyword arguments the Jazzy classes do not take), and the recorded
description is evaluated the way launch_ros evaluates it (substitutions performed, parameter
values read as YAML), for every combination of the launch arguments that matter. Checked:

- every (package, executable) it starts is installed in install/<pkg>/lib/<pkg>/;
- every parameter a node is given (its dictionaries, any SetParameter, and the keys of
  config/abp.yaml that apply to it) is declared by that node, with a value of the declared
  type that passes the declared range and choices, and the launch arguments reach the
  nodes. Sources are merged as rcl/rclpy merge them (by node-name entry in first-seen
  order, not file by file), and that merge is itself checked against a real rclpy node
  given the --ros-args launch_ros would build. The declarations are the nodes' own
  ParamSpec tables (abp_common.parameters.declare_all), loaded in-process;
- a configuration error is not respawned in a loop. Managed nodes start with
  `autostart: false`, so a bad parameter makes configure fail while the process stays up,
  unconfigured (checked below in-process with real rclpy for every managed node class, and
  over DDS with processes in test_lifecycle_manager.py): there is no exit to respawn. Their
  respawn, for real crashes, is bounded by respawn_max_retries; the lifecycle manager (not a
  managed node, which exits on a bad parameter) is not respawned at all.
"""

import importlib
import importlib.util
import itertools
import math
import pathlib
import re
import sys

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from abp_common.param_spec import (  # noqa: E402
    BOOL,
    BOOL_ARRAY,
    DOUBLE,
    DOUBLE_ARRAY,
    INT,
    INT_ARRAY,
    STRING,
    STRING_ARRAY,
)

HERE = pathlib.Path(__file__).resolve().parent
SOURCE = HERE.parent / 'launch' / 'abp.launch.py'
STANDINS = HERE / 'launch_standins'
MANAGER = 'lifecycle_manager'
# Node name -> the class the executable runs (the name each class gives its node).
MANAGED_CLASSES = {
    'sim_bridge': 'abp_sim_bridge.sim_bridge_node:SimBridgeNode',
    'robot_state': 'abp_description.robot_state_node:RobotStateNode',
    'artag_detector': 'abp_perception.artag_detector_node:ArtagDetectorNode',
    'aspect_matcher': 'abp_perception.aspect_matcher_node:AspectMatcherNode',
    'belief': 'abp_belief.belief_node:BeliefNode',
    'skill_servers': 'abp_skills.skills_node:SkillsNode',
    'planner': 'abp_planner.planner_node:PlannerNode',
}
# Launch arguments whose values change what is launched or what the nodes get.
SCENARIOS = [dict(zip(('sim', 'world', 'tables', 'namespace'), values)) for values in
             itertools.product(('true', 'false'), ('mujoco', 'rules'), ('', 'paper'),
                               ('', 'robot1'))]
GRAPH_WIDE = ('SetParameter', 'abp.yaml /**', 'graph-wide launch dict')
PYTHON_TYPES = {BOOL: bool, INT: int, DOUBLE: (int, float), STRING: str}
ELEMENT_TYPES = {BOOL_ARRAY: bool, INT_ARRAY: int, DOUBLE_ARRAY: (int, float),
                 STRING_ARRAY: str}


# -- the declarations: each node's ParamSpec tables, as its configure() declares them -----
def node_specs():
    from abp_belief.belief_config import BELIEF_SPECS
    from abp_belief.model_set_config import MODEL_SET_SPECS
    from abp_bringup.lifecycle_manager import MANAGER_SPECS
    from abp_common.health_stats import HEALTH_SPECS
    from abp_common.param_spec import ParamSpec
    from abp_description.robot_state_config import ROBOT_STATE_SPECS
    from abp_perception.node_parameters import DETECTOR_SPECS, MATCHER_SPECS
    from abp_planner.planner_config import PLANNER_SPECS
    from abp_sim_bridge import config as sim_config
    from abp_skills.skill_params import skills_parameter_specs

    # Declared by rclpy on every node, and by abp_common.lifecycle.ManagedNode.
    use_sim_time = ParamSpec('use_sim_time', BOOL, False, 'rclpy')
    autostart = ParamSpec('autostart', BOOL, True, 'ManagedNode')
    managed = {
        'sim_bridge': sim_config.PARAMETERS,
        'robot_state': ROBOT_STATE_SPECS,
        'artag_detector': DETECTOR_SPECS,
        'aspect_matcher': MODEL_SET_SPECS + MATCHER_SPECS,
        'belief': MODEL_SET_SPECS + BELIEF_SPECS,
        'skill_servers': skills_parameter_specs(True),
        'planner': MODEL_SET_SPECS + PLANNER_SPECS,
    }
    tables = {name: (*specs, *HEALTH_SPECS, autostart, use_sim_time)
              for name, specs in managed.items()}
    tables[MANAGER] = (*MANAGER_SPECS, use_sim_time)
    return {name: {spec.name: spec for spec in specs} for name, specs in tables.items()}


SPECS = node_specs()


# -- the launch file, imported against the stand-ins -----------------------------------
@pytest.fixture(scope='module')
def launch():
    """(launch file module, its LaunchDescription, the stand-in modules)."""
    share = pathlib.Path(ament_index.get_package_share_directory('abp_bringup'))
    installed = share / 'launch' / 'abp.launch.py'
    assert installed.read_text() == SOURCE.read_text(), \
        'install/ has an older abp.launch.py: run scripts/bootstrap.sh'
    names = ('launch', 'launch.actions', 'launch.conditions', 'launch.substitutions',
             'launch_ros', 'launch_ros.actions')
    saved = {name: sys.modules.pop(name) for name in list(sys.modules)
             if name.split('.')[0] in ('launch', 'launch_ros')}
    sys.path.insert(0, str(STANDINS))
    try:
        modules = {name: importlib.import_module(name) for name in names}
        spec = importlib.util.spec_from_file_location('abp_launch_file', installed)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        description = module.generate_launch_description()
        yield module, description, modules
    finally:
        sys.path.remove(str(STANDINS))
        for name in list(sys.modules):
            if name.split('.')[0] in ('launch', 'launch_ros'):
                del sys.modules[name]
        sys.modules.update(saved)


def config_file():
    share = pathlib.Path(ament_index.get_package_share_directory('abp_bringup'))
    return yaml.safe_load((share / 'config' / 'abp.yaml').read_text())


# -- evaluating what was recorded, as launch and launch_ros do ---------------------------
class Evaluator:
    def __init__(self, modules, arguments):
        self.subs = modules['launch.substitutions']
        self.conditions = modules['launch.conditions']
        self.arguments = arguments

    def text(self, value):
        if isinstance(value, str):
            return value
        if isinstance(value, self.subs.LaunchConfiguration):
            return self.arguments[value.variable_name]
        if isinstance(value, self.subs.PythonExpression):
            return str(eval(self.text(value.expression), {'math': math}))  # noqa: S307
        if isinstance(value, (list, tuple)):
            return ''.join(self.text(part) for part in value)
        raise TypeError(f'cannot evaluate {value!r}')

    def parameter(self, value):
        """launch_ros.utilities.evaluate_parameters: text is read as YAML when that gives
        a scalar; lists element by element."""
        if isinstance(value, (bool, int, float)):
            return value
        if isinstance(value, list) and value and not isinstance(value[0], str):
            value = [self.text(value)]
        if isinstance(value, list):
            return [self.parameter(item) for item in value]
        text = self.text(value)
        if text == '':
            return ''
        loaded = yaml.safe_load(text)
        return loaded if isinstance(loaded, (bool, int, float, str)) else text

    def holds(self, condition):
        if condition is None:
            return True
        text = self.text(condition.predicate_expression).strip().lower()
        if text not in ('true', '1', 'false', '0'):
            raise ValueError(f'condition {text!r} is neither true nor false')
        return (text in ('true', '1')) != condition.negate


def launched(launch, overrides):
    """[(node name, Node, {parameter: (value, source)}, evaluator)], {SetParameter: value}.

    The parameters a node ends up with, merged as rcl and rclpy merge them: every source
    (a SetParameter is a `-p` for `/**`, a parameter file's sections, a dictionary written
    by launch_ros under `/**` or, for a Node with a name, under its full name) adds to the
    entry of its node-name key; the entries are then applied in the order the keys first
    appeared (rclpy node.cpp, _populate_node_parameters_from_rcl_params), so a later file
    does not override an earlier node-specific section."""
    _, description, modules = launch
    actions = modules['launch.actions']
    ros = modules['launch_ros.actions']
    arguments = {}
    for entity in description.entities:
        if isinstance(entity, actions.DeclareLaunchArgument):
            arguments[entity.name] = entity.default_value
    for name, value in overrides.items():
        assert name in arguments, f'no launch argument {name}'
        arguments[name] = value
    for entity in description.entities:
        if isinstance(entity, actions.DeclareLaunchArgument) and entity.choices:
            assert arguments[entity.name] in entity.choices
    evaluate = Evaluator(modules, arguments)
    config = config_file()
    global_params = {}
    for entity in description.entities:
        if isinstance(entity, ros.SetParameter) and evaluate.holds(entity.condition):
            global_params[evaluate.text(entity.name)] = evaluate.parameter(entity.value)
    all_nodes = [e for e in description.entities if isinstance(e, ros.Node)]
    # A dictionary every Node gets is for the whole graph, as `/**:` in abp.yaml.
    shared = set.intersection(*({id(p) for p in e.parameters if isinstance(p, dict)}
                                for e in all_nodes))
    nodes = []
    for entity in all_nodes:
        if not evaluate.holds(entity.condition):
            continue
        name = evaluate.text(entity.name) if entity.name else evaluate.text(entity.executable)
        namespace = evaluate.text(entity.namespace or '').strip('/')
        full_name = f'/{namespace}/{name}' if namespace else f'/{name}'
        entries = {}  # node-name key -> {parameter: (value, source)}, in first-seen order

        def add(key, params, source):
            entries.setdefault(key, {}).update(
                {param: (value, source) for param, value in params.items()})

        add('/**', global_params, 'SetParameter')
        for source in entity.parameters:
            if isinstance(source, dict):
                kind = 'graph-wide launch dict' if id(source) in shared else 'launch dict'
                key = full_name if entity.name is not None else '/**'
                add(key, {k: evaluate.parameter(v) for k, v in source.items()}, kind)
            else:
                assert pathlib.Path(evaluate.text(source)).name == 'abp.yaml'
                for section, body in config.items():
                    add(section, (body or {}).get('ros__parameters', {}), f'abp.yaml {section}')
        given = {}
        for key, params in entries.items():
            if re.fullmatch(key.replace('/*', r'(/\w+)'), full_name):
                given.update(params)
        nodes.append((name, entity, given, evaluate))
    return nodes, global_params


def scenario_id(scenario):
    return ','.join(f'{key}={value or "-"}' for key, value in scenario.items())


# -- the tests -----------------------------------------------------------------------------
@pytest.mark.parametrize('scenario', SCENARIOS, ids=scenario_id)
def test_every_executable_is_installed(launch, scenario):
    nodes, _ = launched(launch, scenario)
    assert nodes
    for name, node, _, evaluate in nodes:
        package, executable = evaluate.text(node.package), evaluate.text(node.executable)
        path = pathlib.Path(ament_index.get_package_prefix(package)) / 'lib' / package / executable
        assert path.is_file(), f'{package} {executable}: {path} is not installed'
        assert name in SPECS, f'{package} {executable}: node {name} unknown to this test'


@pytest.mark.parametrize('scenario', SCENARIOS, ids=scenario_id)
def test_every_parameter_is_declared_by_its_node_with_a_valid_value(launch, scenario):
    nodes, global_params = launched(launch, scenario)
    names = {name for name, *_ in nodes}
    for name, _, given, _ in nodes:
        specs = SPECS[name]
        for key, (value, source) in given.items():
            if source in GRAPH_WIDE and key not in specs:
                continue  # for the whole graph: a node that does not declare it ignores it
            assert key in specs, f'{name} does not declare {key} (given by {source})'
            check_value(specs[key], value, f'{name}.{key} from {source}')
    # A graph-wide parameter must reach at least one node that declares it.
    everywhere = {key for *_, given, _ in nodes for key, (_, source) in given.items()
                  if source in GRAPH_WIDE}
    for key in everywhere:
        assert any(key in SPECS[name] for name in names), f'no launched node declares {key}'


def test_launch_arguments_reach_the_nodes(launch):
    """What `ros2 launch ... models:=full seed:=3 ...` asks is what the nodes get, after
    every parameter source in launch_ros's order (SetParameter values come first, then the
    node's own files and dictionaries: abp.yaml's `/**:` must not undo an argument)."""
    asked = {'sim': 'true', 'world': 'rules', 'models': 'full', 'seed': '3',
             'tables': 'corrected', 'planner': 'abp'}
    nodes, _ = launched(launch, asked)
    expected = {'model_set': 'full', 'seed': 3, 'transition_rules': 'corrected'}
    for name, _, given, _ in nodes:
        for key, value in expected.items():
            if key in SPECS[name]:
                assert given[key][0] == value, f'{name}.{key}: {given[key]}, asked {value}'
        if name == 'sim_bridge':
            assert given['world'][0] == 'rules' and given['cube_seed'][0] == 3
            assert given.get('use_sim_time', (False,))[0] is False  # it publishes /clock
        elif name == 'planner':
            assert given['planner_mode'][0] == 'abp'
        if name not in ('sim_bridge', MANAGER):
            assert given['use_sim_time'][0] is True, name
    robot, _ = launched(launch, {'sim': 'false'})
    assert 'sim_bridge' not in {name for name, *_ in robot}
    assert all(given.get('use_sim_time', (False,))[0] is False for _, _, given, _ in robot)


def ros_arguments(node, evaluate, global_params, tmp_path):
    """The --ros-args launch_ros (Jazzy, Node._perform_substitutions) gives the process:
    `-p` per SetParameter, then each parameter source in order, a dictionary as a file
    keyed by the node's full name when it has a name, else by `/**`."""
    args = []
    for key, value in global_params.items():
        args += ['-p', f'{key}:={yaml.safe_dump(value).splitlines()[0]}']
    name = evaluate.text(node.name) if node.name else None
    namespace = evaluate.text(node.namespace or '').strip('/')
    for index, source in enumerate(node.parameters):
        if isinstance(source, dict):
            key = (f'/{namespace}/{name}' if namespace else f'/{name}') if name else '/**'
            path = tmp_path / f'{evaluate.text(node.executable)}-{index}.yaml'
            path.write_text(yaml.safe_dump({key: {'ros__parameters': {
                k: evaluate.parameter(v) for k, v in source.items()}}}))
            args += ['--params-file', str(path)]
        else:
            args += ['--params-file', evaluate.text(source)]
    return args


def test_the_merge_above_is_what_rclpy_does(launch, tmp_path):
    """The evaluation these tests rely on, checked against real rcl/rclpy: each launched
    node's --ros-args, as launch_ros builds them, given to a real rclpy node of that name
    and namespace that declares whatever it is given."""
    asked = {'sim': 'true', 'world': 'rules', 'models': 'full', 'seed': '3',
             'tables': 'corrected', 'planner': 'abp', 'namespace': 'robot1'}
    nodes, global_params = launched(launch, asked)
    for name, node, given, evaluate in nodes:
        context = rclpy.context.Context()
        args = ros_arguments(node, evaluate, global_params, tmp_path)
        rclpy.init(args=['--ros-args', *args], context=context)
        try:
            real = rclpy.create_node(name, namespace='/robot1', context=context,
                                     automatically_declare_parameters_from_overrides=True)
            try:
                got = {param.name: param.value for param in real.get_parameters(
                    real.list_parameters([], 0).names)}
            finally:
                real.destroy_node()
        finally:
            rclpy.try_shutdown(context=context)
        expected = {key: value for key, (value, _) in given.items()}
        got = {key: list(value) if isinstance(value, (list, tuple)) else value
               for key, value in got.items() if key in expected}
        expected = {key: list(value) if isinstance(value, (list, tuple)) else value
                    for key, value in expected.items()}
        assert got == expected, f'{name}: rclpy {got} != evaluated {expected}'


def check_value(spec, value, what):
    if spec.kind in PYTHON_TYPES:
        kind = PYTHON_TYPES[spec.kind]
        assert isinstance(value, kind) and not (isinstance(value, bool) and kind is not bool), \
            f'{what}: {value!r} is not a {spec.kind}'
    else:
        assert isinstance(value, (list, tuple)) and all(
            isinstance(item, ELEMENT_TYPES[spec.kind]) for item in value), \
            f'{what}: {value!r} is not a {spec.kind}'
    spec.check(value)


def test_every_config_file_section_names_a_launched_node(launch):
    nodes, _ = launched(launch, {'sim': 'true'})
    names = {name for name, *_ in nodes}
    for section in config_file():
        assert section == '/**' or (section.startswith('/**/') and section[4:] in names), \
            f'config/abp.yaml section {section!r} applies to no launched node'


@pytest.mark.parametrize('scenario', SCENARIOS, ids=scenario_id)
def test_no_respawn_loop_on_a_configuration_error(launch, scenario):
    module = launch[0]
    nodes, _ = launched(launch, scenario)
    managed = []
    for name, node, given, _ in nodes:
        if name == MANAGER:
            assert not node.process.get('respawn'), 'the lifecycle manager must not respawn'
            manager = given
            continue
        managed.append(name)
        # Waits unconfigured: configure, not start-up, meets a bad parameter.
        assert given['autostart'] == (False, 'launch dict'), f'{name}: autostart not false'
        assert node.parameters[-1] == {'autostart': False}, \
            f'{name}: something after autostart:=false could override it'
        assert node.process.get('respawn') is True
        retries = node.process.get('respawn_max_retries', -1)
        assert 0 <= retries == module.RESPAWN_MAX_RETRIES, f'{name}: unbounded respawn'
    # The manager brings up exactly the launched managed nodes, in the launch order.
    assert list(manager['node_names'][0]) == managed
    # ... which are the graph's nodes of abp_common.graph_nodes, in its order.
    from abp_common.graph_nodes import ROBOT, SIM, graph_nodes
    graph = SIM if scenario['sim'] == 'true' else ROBOT
    assert managed == [n.name for n in graph_nodes(graph)]


def test_launch_argument_choices_are_the_nodes_choices(launch):
    module = launch[0]
    assert tuple(module.MODEL_SETS) == SPECS['belief']['model_set'].choices
    assert tuple(module.PLANNERS) == SPECS['planner']['planner_mode'].choices
    assert set(module.WORLDS) == set(SPECS['sim_bridge']['world'].choices)
    assert tuple(module.TABLES) == SPECS['belief']['transition_rules'].choices


def test_launch_refuses_an_argument_launch_ros_does_not_take(launch):
    ros = launch[2]['launch_ros.actions']
    with pytest.raises(TypeError, match='respawn_dela'):
        ros.Node(package='abp_belief', executable='belief', respawn_dela=1.0)


def bad_value(spec):
    low, high = spec.range
    return int(high) + 1 if spec.kind == INT else float(high) * 2.0 + 1.0


def test_a_bad_parameter_fails_configure_and_the_process_stays_up(tmp_path):
    """Every managed node class, built in-process with real rclpy and one out-of-range
    parameter, as the launch file starts it (autostart false): configure reports FAILURE
    naming the parameter, nothing raises, the node stays unconfigured."""
    from rclpy.lifecycle import TransitionCallbackReturn
    bad = {}
    for name in MANAGED_CLASSES:
        spec = next(s for s in SPECS[name].values()
                    if s.range is not None and s.kind in (INT, DOUBLE))
        bad[name] = (spec.name, bad_value(spec))
    params = tmp_path / 'bad.yaml'
    params.write_text(yaml.safe_dump({f'/**/{name}': {'ros__parameters': {
        'autostart': False, key: value}} for name, (key, value) in bad.items()}))
    rclpy.init(args=['--ros-args', '--params-file', str(params)])
    try:
        for name, target in MANAGED_CLASSES.items():
            module, cls = target.split(':')
            node = getattr(importlib.import_module(module), cls)()
            try:
                assert node.get_name() == name
                assert node.trigger_configure() == TransitionCallbackReturn.FAILURE, name
                assert node.state_label() == 'unconfigured'
                assert bad[name][0] in str(node.configuration_error), \
                    f'{name}: {node.configuration_error}'
            finally:
                node.destroy_node()
    finally:
        rclpy.try_shutdown()
