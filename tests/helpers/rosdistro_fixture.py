"""Write tests/fixtures/rosdistro/ from a checkout of the public ros/rosdistro repository:
the names of the packages Jazzy releases (jazzy/distribution.yaml), and, for every
rosdep key the workspace's package.xml files use that is neither a workspace package nor
a Jazzy package, its Ubuntu/Debian rules from rosdep/base.yaml or rosdep/python.yaml.

    python -m tests.helpers.rosdistro_fixture /path/to/rosdistro

The `not_used` section of rosdep_keys.yaml (written by hand: keys that exist but are
not used on purpose, and why) is kept as it is.
"""

import pathlib
import subprocess
import sys

import yaml

from tests.helpers.manifests import REPO, dependencies, workspace_packages

FIXTURE = REPO / 'tests' / 'fixtures' / 'rosdistro'
PACKAGES_FILE = FIXTURE / 'jazzy_packages.txt'
KEYS_FILE = FIXTURE / 'rosdep_keys.yaml'
RULE_FILES = ('rosdep/base.yaml', 'rosdep/python.yaml')
PLATFORMS = ('ubuntu', 'debian')


def jazzy_packages(rosdistro):
    dist = yaml.safe_load((rosdistro / 'jazzy' / 'distribution.yaml').read_text())
    names = set()
    for repo, info in dist['repositories'].items():
        release = info.get('release')
        if release:
            names.update(release.get('packages') or [repo])
    return names


def main(argv):
    rosdistro = pathlib.Path(argv[1])
    commit = subprocess.run(['git', '-C', str(rosdistro), 'log', '-1', '--format=%H %cs'],
                            capture_output=True, text=True, check=True).stdout.split()
    released = jazzy_packages(rosdistro)
    FIXTURE.mkdir(parents=True, exist_ok=True)
    PACKAGES_FILE.write_text(
        f'# Packages released for ROS 2 Jazzy: jazzy/distribution.yaml of ros/rosdistro\n'
        f'# at commit {commit[0]} ({commit[1]}); tests/helpers/rosdistro_fixture.py.\n'
        + ''.join(f'{name}\n' for name in sorted(released)))
    rules = {}
    for name in RULE_FILES:
        for key, rule in yaml.safe_load((rosdistro / name).read_text()).items():
            rules[key] = (name, rule)
    own = workspace_packages()
    keys = {}
    for dep in sorted({d for _, _, d in dependencies()} - own - released):
        if dep not in rules:
            raise SystemExit(f'{dep}: neither a workspace package, a Jazzy package nor a '
                             f'rosdep key at rosdistro {commit[0]}')
        source, rule = rules[dep]
        keys[dep] = {'file': source, **{p: rule[p] for p in PLATFORMS if p in rule}}
    old = yaml.safe_load(KEYS_FILE.read_text()) if KEYS_FILE.exists() else {}
    KEYS_FILE.write_text(
        '# rosdep keys the package.xml files use (tests/test_rosdep_keys.py), as\n'
        '# ros/rosdistro defines them; regenerate with tests/helpers/rosdistro_fixture.py.\n'
        + yaml.safe_dump({'rosdistro_commit': commit[0], 'rosdistro_date': commit[1],
                          'keys': keys, 'not_used': old.get('not_used', {})},
                         sort_keys=False, width=88))


if __name__ == '__main__':
    main(sys.argv)
