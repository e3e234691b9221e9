"""The skills answer from the robot profile: a skill it does not list is infeasible (so
the planner, which asks the feasibility service, leaves it out), and the push arm is one
of the profile's push arms."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from abp_description.kinematics import RobotKinematics
from abp_description.robot_profile import default_profile_path, load_profile
from abp_skills.plans import ACTIONS, SkillPlanner

CUBE = np.array([0.45, 0.0, 0.05])   # at manipulation_distance: no base approach


@pytest.fixture(scope='module')
def push_only(tmp_path_factory):
    """The uBot-6 with ORBIT and a left-hand PUSH only (its URDF and camera unchanged)."""
    default = Path(default_profile_path())
    doc = yaml.safe_load(default.read_text())
    for key in ('urdf', 'camera_calibration'):
        doc[key] = str((default.parent / doc[key]).resolve())
    doc['name'] = 'ubot6_push_only'
    doc['skills'] = {'orbit': None, 'push': {'arms': ['left']}}
    path = tmp_path_factory.mktemp('profile') / 'push_only.yaml'
    path.write_text(yaml.safe_dump(doc))
    return load_profile(path)


def test_a_skill_the_profile_lacks_is_infeasible(push_only):
    planner = SkillPlanner(RobotKinematics(profile=push_only))
    assert planner.config.push_hand == 'left'    # the profile's first push arm
    q = planner.home(look=CUBE)
    verdicts = {a: planner.feasibility(a, q, CUBE) for a in ACTIONS}
    for action in ('LIFT', 'FLIP'):
        ok, reason = verdicts[action]
        assert not ok and f'has no {action} skill' in reason and 'ubot6_push_only' in reason
    assert verdicts['PUSH'][0], verdicts['PUSH'][1]
    assert all(ok for a, (ok, _) in verdicts.items() if a.startswith('ORBIT'))
    plan = planner.plan('lift', q, CUBE)
    assert not plan.ok and 'has no LIFT skill' in plan.reason
    with pytest.raises(ValueError, match='push_hand must be one of left'):
        planner.with_config(push_hand='right')


def test_the_ubot6_profile_keeps_every_skill():
    planner = SkillPlanner(RobotKinematics(profile=load_profile()))
    q = planner.home(look=CUBE)
    assert all(planner.feasibility(a, q, CUBE)[0] for a in ACTIONS)
