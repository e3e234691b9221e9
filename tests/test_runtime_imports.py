"""The robot and operator graphs' node processes load no offline or simulator code: not the ATG
learner (atg_learning, atg_from_bags, learn_atg_cli, which import the runtime model set,
never the other way round: transition_tables is the seam), not the sim bridge, the
benchmarks or MuJoCo. Checked on what an import really loads (sys.modules), so a lazy or
transitive import counts too; test_code_layout checks there is no cycle."""

import json
import re
import subprocess
import sys

from abp_common.graph_nodes import GRAPH
from tests.helpers.manifests import REPO

OFFLINE_MODULES = {'atg_learning', 'atg_from_bags', 'learn_atg_cli'}
OFFLINE_PACKAGES = {'abp_sim_bridge', 'abp_bench', 'mujoco', 'matplotlib', 'tqdm'}


def node_modules():
    """The module of the entry point (setup.py console_scripts) of each node that runs
    without the simulator (robot and operator graphs), and the lifecycle manager's."""
    wanted = {(n.package, n.executable) for n in GRAPH if not n.sim_only}
    wanted.add(('abp_bringup', 'lifecycle_manager'))
    modules = []
    for package, executable in sorted(wanted):
        setup = (REPO / package / 'setup.py').read_text()
        found = re.search(rf"'{executable} = ([\w.]+):\w+'", setup)
        assert found, f'{package}/setup.py has no entry point {executable}'
        modules.append(found.group(1))
    return modules


def test_node_processes_load_no_offline_or_simulator_code():
    probe = ('import importlib, json, sys\n'
             'for name in sys.argv[1:]:\n'
             '    importlib.import_module(name)\n'
             'print(json.dumps(sorted(sys.modules)))\n')
    modules = node_modules()
    assert len(modules) == len({n.executable for n in GRAPH if not n.sim_only}) + 1
    out = subprocess.run([sys.executable, '-c', probe, *modules], capture_output=True,
                         text=True, check=True).stdout
    loaded = set(json.loads(out))
    offline = sorted(m for m in loaded if m.split('.')[-1] in OFFLINE_MODULES
                     or m.split('.')[0] in OFFLINE_PACKAGES)
    assert not offline, f'importing {modules} loads {offline}'
    # The probe would pass vacuously if the names were wrong: the runtime model set is there.
    assert 'abp_belief.modelset' in loaded
