"""`rosdep install --from-paths . --ignore-src` resolves every dependency: each one that a
package.xml (abp_*/ and vendor/*/) lists is a package of this workspace, a package ROS 2
Jazzy releases, or a rosdep key of ros/rosdistro (rosdep/base.yaml, rosdep/python.yaml).

Checked against tests/fixtures/rosdistro/, written from rosdistro at the commit it names
(tests/helpers/rosdistro_fixture.py regenerates it). A new system dependency fails here
until it is checked against rosdistro and added there.
"""

import pytest
import yaml

from tests.helpers.manifests import REPO, dependencies, workspace_packages

FIXTURE = REPO / 'tests' / 'fixtures' / 'rosdistro'
KEYS = yaml.safe_load((FIXTURE / 'rosdep_keys.yaml').read_text())
JAZZY = {line.strip() for line in (FIXTURE / 'jazzy_packages.txt').read_text().splitlines()
         if line.strip() and not line.startswith('#')}
DEPENDENCIES = dependencies()


def test_fixture_names_the_rosdistro_commit_and_real_package_names():
    assert len(KEYS['rosdistro_commit']) == 40
    # Spot checks that the list is Jazzy's own: core packages and the vendored messages.
    assert {'rclpy', 'launch_ros', 'control_msgs', 'tf2_msgs', 'pinocchio'} <= JAZZY
    assert len(JAZZY) > 1000


@pytest.mark.parametrize('manifest,tag,dep', DEPENDENCIES,
                         ids=[f'{m.split("/")[0]}:{d}' for m, _, d in DEPENDENCIES])
def test_dependency_resolves(manifest, tag, dep):
    if dep in KEYS['not_used']:
        pytest.fail(f'{manifest} <{tag}>{dep}: {KEYS["not_used"][dep]["why"]}')
    assert dep in workspace_packages() or dep in JAZZY or dep in KEYS['keys'], (
        f'{manifest} <{tag}>{dep}: not a workspace package, not a ROS 2 Jazzy package and '
        f'not a rosdep key (checked against rosdistro {KEYS["rosdistro_commit"]}); '
        'rosdep install would stop on it')


def test_every_key_of_the_fixture_is_used():
    used = {dep for _, _, dep in DEPENDENCIES}
    assert set(KEYS['keys']) <= used, f'stale keys in the fixture: {set(KEYS["keys"]) - used}'


def test_every_key_resolves_on_ubuntu():
    for key, rule in KEYS['keys'].items():
        assert rule.get('ubuntu'), f'{key} has no Ubuntu rule in {rule["file"]}'
