"""Timing of the skills' science (no ROS graph): IK solves, Ruckig trajectory generation,
ORBIT planning, whole PUSH/LIFT/FLIP plans and the feasibility answer.

    skills_benchmark [--repeats N] [--seed S]

Prints a Markdown table (median and 90th percentile, milliseconds) for docs/BENCHMARKS.md.
"""

import argparse
import platform
import sys
import time

import numpy as np

from abp_belief.cube import ACTIONS
from abp_description.kinematics import RobotKinematics
from abp_skills.base_motion import plan_orbit
from abp_skills.motion_profiles import joint_trajectory, path_profile
from abp_skills.plans import SkillPlanner


def _time(fn, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return np.array(out) * 1e3


def run(repeats=200, seed=0):
    rng = np.random.default_rng(seed)
    kin = RobotKinematics()
    planner = SkillPlanner(kin)
    cube = np.array([0.40, 0.0, 0.05])
    home = planner.home(look=cube)
    seed_q = planner.reach_seed(home)
    rows = []

    # IK: two-hand grasp targets around the nominal cube, cold start from home.
    targets = []
    for _ in range(repeats):
        c = cube + [rng.uniform(-0.05, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(0, 0.08)]
        targets.append({'left': c + [0, 0.075, 0], 'right': c - [0, 0.075, 0]})
    it = iter(targets)
    success = []

    def two_hands():
        r = planner.ik.solve(next(it), home, seeds=[seed_q])
        success.append(r.success)
    rows.append(('IK, two hands + torso (9 DOF), from home', _time(two_hands, repeats),
                 f'{100 * np.mean(success):.0f} % solved'))

    # IK: one hand, warm start from a nearby solution (a Cartesian path step).
    q_grasp = planner.ik.solve(targets[0], home, seeds=[seed_q]).q
    p0 = planner.ik.hand_positions(q_grasp)['right']
    steps = [p0 + rng.normal(0, 0.005, 3) for _ in range(repeats)]
    it2 = iter(steps)
    rows.append(('IK, one hand + torso, warm start 5 mm away',
                 _time(lambda: planner.ik.solve({'right': next(it2)}, q_grasp), repeats), ''))

    # Unreachable targets (the refusal path).
    far = {'left': [1.0, 0.1, 0.05], 'right': [1.0, -0.1, 0.05]}
    n_far = max(10, repeats // 10)
    rows.append(('IK, unreachable target (refusal)',
                 _time(lambda: planner.ik.solve(far, home, seeds=[seed_q]), n_far), ''))

    # Ruckig: 11-DOF rest-to-rest segment home -> grasp posture, sampled at 50 ms.
    body_joints = kin.profile.body_joints
    idx = [kin.joint_index(n) for n in body_joints]
    goals = []
    for t in targets[:repeats]:
        r = planner.ik.solve(t, home, seeds=[seed_q])
        if r.success:
            goals.append(r.q[idx])
    it3 = iter(goals * (repeats // max(1, len(goals)) + 1))
    rows.append(('Ruckig joint trajectory, 11 DOF, one segment + sampling',
                 _time(lambda: joint_trajectory(body_joints, home[idx], [next(it3)],
                                                planner.joint_limits), repeats), ''))
    rows.append(('Ruckig path profile (1-D, 8 cm)',
                 _time(lambda: path_profile(0.08, 0.08, 0.3, 2.0), repeats), ''))
    angles = np.radians([45, -45, 90, -90, 180])
    it4 = iter(list(angles) * repeats)
    rows.append(('ORBIT plan (turn, arc, turn; Ruckig per piece)',
                 _time(lambda: plan_orbit(np.zeros(3), cube[:2], next(it4), 0.4), repeats), ''))

    n_plans = max(5, repeats // 20)
    for skill in ('push', 'lift', 'flip'):
        plan = planner.plan(skill, home, cube)
        rows.append((f'{skill.upper()} plan (IK paths, Ruckig, collision checks)',
                     _time(lambda s=skill: planner.plan(s, home, cube), n_plans),
                     f'motion {plan.duration:.1f} s'))
    rows.append(('Feasibility of all 8 actions',
                 _time(lambda: [planner.feasibility(a, home, cube) for a in ACTIONS], n_plans),
                 ''))
    return rows


def table(rows):
    lines = ['| operation | median (ms) | p90 (ms) | n | note |', '|---|---:|---:|---:|---|']
    for name, times, note in rows:
        lines.append(f'| {name} | {np.median(times):.2f} | {np.percentile(times, 90):.2f} | '
                     f'{len(times)} | {note} |')
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=200)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error('--repeats must be >= 1')
    rows = run(args.repeats, args.seed)
    print(f'skills benchmark: {platform.processor() or platform.machine()}, '
          f'Python {platform.python_version()}, repeats {args.repeats}, seed {args.seed}')
    print(table(rows))
    return 0


if __name__ == '__main__':
    sys.exit(main())
