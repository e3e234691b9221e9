"""outcome_survey: what PUSH, LIFT, FLIP and the ORBIT angles really do to an ARcube in the
MuJoCo world, from every relative state the models know, next to the hand-written ATG
tables (docs/MODEL.md, `abp_belief.modelset.build_outcome_tables`).

    outcome_survey [--trials 20] [--jobs CORES] [--out bench_out/survey] [--seed 0]
                   [--actions PUSH LIFT ...] [--masses u m+x ...] [--parity even|odd|both]

**What runs.** The skills' real plans (`abp_skills.plans.SkillPlanner`; ORBIT:
`orbit_plan` tracked on odometry by `base_motion.OrbitTracker` at the skill node's 20 Hz)
drive a `MujocoWorld` directly, without DDS (`abp_bench.mujoco_skill_runner`). The robot
stands at the origin in its home posture looking at the cube; the manual skills are
planned once per worker at the nominal cube centre (the skills' `manipulation_distance`,
0, 0.05) m in base_link (where the base approach puts the cube, so no base motion), and
the cube really stands `--pos-jitter` (+-1 cm, uniform in x and y) and `--yaw-jitter-deg`
(+-3 deg) off that: the randomised start doubles as a cube-estimate error of that size.
The cube-floor friction (cube and floor coefficients together) and the hand-pad friction
(sliding and torsional) are scaled independently by uniform factors in 1 +-
`--friction-jitter` (20 %). ORBIT plans at the cube's true centre, and the world's
odometry noise (`--orbit-noise`, sigma_m sigma_rad per base motion; default the graph
benchmark's fault setting) displaces the true base at the end of each base motion, unseen
by odometry. `--faults` adds the graph benchmark's contact faults: each manual trial draws
a slipping grasp (hands 1 cm further out) and a missed push (10 cm out), each with
probability 0.1, as the sim bridge's MuJoCo world draws them per manual action; a survey
with faults is the experience of a robot that has them, for `learn_atg`. A trial's outcome
is the cube's discrete state (MODEL.md: up face x 45-deg yaw step, relative to the true
base) after the skill has ended and the cube has settled;
`abp_sim_bridge.mujoco_world.discrete_state` rounds the pose.

**Symmetry classes.** The world is the robot, a floor and a box whose only asymmetry is the
heavy slab: the box is invariant under the cube group, and the slab (square, centred on its
face) under the quarter turns about its face normal. So the physics of a start cell (mass
variant, state) depends only on the box's orientation in the view frame V, which is fixed
by the yaw parity (even: faces aligned with V; odd: an edge towards the robot), and on the
slab's direction d in V (none for uniform mass). The tag textures are visual only. Cells
with the same (parity, d) are one class: 7 per parity (even: none, +-x_V, +-y_V, +-z_V;
odd: none, +-z_V and the four horizontal diagonals), 14 classes for the 336 cells of each
manual action. A class member is the representative's pose turned by a body-frame cube
rotation S = R(member)^T R(rep) with S n_rep = n_member, so a representative ending in
state s' maps to the member ending in `apply_rotation(R(s') R(rep)^T, member)`: the same
motion Q in V. No mirror symmetry is used (PUSH uses the right hand; the arms' paths are
not exactly mirror images). ORBIT never touches the cube (the survey counts trials where a
hand or the base did): its outcome depends on the base motion and odometry only, so its
classes are the two parities with any mass (2 classes of 168 cells per angle). The
simulator never reads the ATG tables: the workers import only MODEL.md's frame conventions
(`abp_belief.cube` constants); the comparison step alone builds the tables.
`--symmetry-check` re-runs a few non-representative members with the representative's seeds
and reports whether their outcomes equal the mapped ones.

**Outputs** (`--out`): `survey.json` (all counts per cell, per-trial records with their
seeds and randomisation, settings, versions, timing), `survey.md` (one row per action and
class, in relative terms, plus the goals), `survey.png` (per action: empirical next-state
distribution of all 336 cells next to the table's; cells differing by more than 10
percentage points in any outcome are marked).
"""

import argparse
import json
import os
import pickle
import platform
import resource
import subprocess
import sys
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from abp_belief.cube import (
    ACTIONS,
    FACE_NORMALS,
    MASS_NAMES,
    NUM_MASS_VARIANTS,
    NUM_YAWS,
    ORBIT_STEPS,
    STATE_ROTATIONS,
    STATES_PER_MODEL,
    TRANSITION_RULES,
    apply_rotation,
)
from abp_description.frames import axis_angle_deg, rot_z_deg
from abp_description.robot_profile import load_profile
from abp_skills.plans import SkillConfig

# m, base_link: the skills' plan and the cube's mean (where the base approach puts the cube)
NOMINAL_CENTRE = (SkillConfig.manipulation_distance, 0.0, SkillConfig.cube_size / 2)
DIFF_THRESHOLD = 0.10                  # a flagged cell differs by more than this anywhere
GOAL_UNIFORM_NOMINAL = 0.95
FAULT_RATE = 0.1                       # --faults: graph_benchmark's p_slip_grasp, p_missed_push
MASS_LABELS = ('uniform', 'heavy +x', 'heavy -x', 'heavy +y', 'heavy -y', 'heavy +z',
               'heavy -z')
PARITIES = ('even', 'odd')
# Symmetry check: (action, class label) pairs re-run through other members.
SYMMETRY_CLASSES = (('PUSH', 'mass +y_V, even yaw'), ('LIFT', 'mass +x_V, even yaw'),
                    ('FLIP', 'mass -y_V, even yaw'), ('FLIP', 'mass +x+y_V, odd yaw'))


# -- classes -----------------------------------------------------------------------------
def direction_label(d):
    """'+y_V', '-z_V', '+x-y_V' for a direction in V (None: 'uniform')."""
    if d is None:
        return 'uniform'
    parts = [('+' if v > 0 else '-') + axis for v, axis in zip(d, 'xyz') if abs(v) > 1e-6]
    return ''.join(parts) + '_V'


@dataclass
class CellClass:
    """Start cells (mass index, state) with the same physics for one action."""

    action: str
    label: str
    members: list = field(default_factory=list)   # [(mass, state)]

    @property
    def rep(self):
        return self.members[0]


def cell_key(action, mass, state):
    """(label) of the physics class of a start cell (see the module doc)."""
    parity = PARITIES[state % 2]
    if action in ORBIT_STEPS:
        return f'any mass, {parity} yaw'
    if mass == 0:
        return f'uniform, {parity} yaw'
    d = np.round(STATE_ROTATIONS[state] @ FACE_NORMALS[mass - 1], 6)
    return f'mass {direction_label(d)}, {parity} yaw'


def build_classes(actions=ACTIONS, masses=range(NUM_MASS_VARIANTS), parities=PARITIES):
    """{action: [CellClass]} over the selected cells, in a stable order."""
    out = {}
    for action in actions:
        classes = {}
        for m in masses:
            for s in range(STATES_PER_MODEL):
                if PARITIES[s % 2] not in parities:
                    continue
                key = cell_key(action, m, s)
                classes.setdefault(key, CellClass(action, key)).members.append((m, s))
        out[action] = list(classes.values())
    return out


def map_outcome(rep_state, rep_next, member_state):
    """The member's next state for the representative's motion rep_state -> rep_next."""
    q = STATE_ROTATIONS[rep_next] @ STATE_ROTATIONS[rep_state].T
    return apply_rotation(q, member_state)


def trial_seed(seed, action, label, trial):
    key = [int(seed), ACTIONS.index(action), zlib.crc32(label.encode()), int(trial)]
    return int(np.random.SeedSequence(key).generate_state(1)[0])


# -- the simulation (worker side: no ATG table is read here) ------------------------------
@dataclass(frozen=True)
class Randomisation:
    pos_jitter: float = 0.01           # m, uniform +- in x and y
    yaw_jitter_deg: float = 3.0        # uniform +-
    friction_jitter: float = 0.2       # relative, uniform +-
    orbit_noise: tuple = (0.01, 0.02)  # (m, rad) per base motion
    settle: float = 1.5                # s after a manual skill's plan ends
    plan_at_true_centre: bool = False  # False: plans at NOMINAL_CENTRE (estimate error)
    # Contact faults per manual trial, drawn as the sim bridge's MuJoCo world draws them per
    # contact episode (abp_sim_bridge.worlds): the hands held this much further out.
    p_slip_grasp: float = 0.0
    p_missed_push: float = 0.0
    slip_grasp_opening: float = 0.01   # m (sim bridge parameter slip_grasp_opening)
    missed_push_offset: float = 0.10   # m (sim bridge parameter missed_push_offset)


_WORKER = {}


def _init_worker(robot_profile=''):
    """The worker's robot (`robot_profile`: a profile YAML; empty = the uBot-6) and plans."""
    os.environ.setdefault('MUJOCO_GL', 'egl')
    from abp_description.kinematics import RobotKinematics
    from abp_skills.plans import SkillPlanner

    kin = RobotKinematics(profile=load_profile(robot_profile))
    planner = SkillPlanner(kin)
    _WORKER.update(kin=kin, planner=planner, plans={},
                   q0=planner.home(kin.neutral(), look=np.array(NOMINAL_CENTRE)))


def _plan(skill, world=None):
    """The skill's plan at the nominal cube centre (cached), or at the world's true cube
    centre if `world` is given."""
    if world is not None:
        from abp_bench.mujoco_skill_runner import cube_in_base
        return _WORKER['planner'].plan(skill, _WORKER['q0'], cube_in_base(world))
    plans = _WORKER['plans']
    if skill not in plans:
        plans[skill] = _WORKER['planner'].plan(skill, _WORKER['q0'], np.array(NOMINAL_CENTRE))
    return plans[skill]


def _relative_rotation(world):
    """Cube rotation body -> V (x_V from the cube to the true base, z up)."""
    pose, base = world.cube_pose(), world.robot_pose()
    to_robot = base[:2] - pose[:2, 3]
    x_v = np.array([*to_robot, 0.0]) / np.linalg.norm(to_robot)
    view = np.column_stack([x_v, np.cross([0.0, 0.0, 1.0], x_v), [0.0, 0.0, 1.0]])
    return view.T @ pose[:3, :3]


def simulate(task):
    """One trial: task = dict(action, mass, state, seed, rand (Randomisation fields)).
    Returns the final discrete state and diagnostics."""
    if not _WORKER:
        _init_worker()
    from abp_bench.mujoco_skill_runner import make_world, run_orbit, run_plan
    from abp_sim_bridge.mujoco_world import draw_contact_fault

    t0, cpu0 = time.perf_counter(), time.process_time()
    action, mass, state = task['action'], int(task['mass']), int(task['state'])
    rand = Randomisation(**task['rand'])
    rng = np.random.default_rng(task['seed'])
    dx, dy = rng.uniform(-rand.pos_jitter, rand.pos_jitter, 2)
    dyaw = np.radians(rng.uniform(-rand.yaw_jitter_deg, rand.yaw_jitter_deg))
    f_floor, f_hand = 1.0 + rng.uniform(-rand.friction_jitter, rand.friction_jitter, 2)
    world_seed = int(rng.integers(2**31))
    up, yaw = divmod(state, NUM_YAWS)
    # Robot at the origin facing +x, cube on +x: x_V is world -x, so world yaw = yaw - 180.
    kin, planner = _WORKER['kin'], _WORKER['planner']
    changes = dict(cube_friction=0.5 * f_floor, floor_friction=0.5 * f_floor,
                   hand_friction=1.0 * f_hand, hand_torsional_friction=0.001 * f_hand,
                   seed=world_seed)
    fault = ''
    if action in ORBIT_STEPS:
        changes['orbit_odometry_noise'] = tuple(rand.orbit_noise)
    elif rand.p_slip_grasp > 0 or rand.p_missed_push > 0:
        # Drawn after the other draws, so a survey without faults keeps its trials.
        changes['grasp_opening'], fault = draw_contact_fault(
            rng, rand.p_slip_grasp, rand.p_missed_push, rand.slip_grasp_opening,
            rand.missed_push_offset)
    world = make_world(kin, heavy_face=None if mass == 0 else mass - 1,
                       cube_x=NOMINAL_CENTRE[0] + dx, cube_y=NOMINAL_CENTRE[1] + dy,
                       cube_yaw=np.radians(45.0 * yaw - 180.0) + dyaw, up_face=up,
                       q0=_WORKER['q0'], **changes)
    record = dict(dx=float(dx), dy=float(dy), dyaw_deg=float(np.degrees(dyaw)),
                  friction_floor_scale=float(f_floor), friction_hand_scale=float(f_hand),
                  world_seed=world_seed, fault=fault,
                  start_ok=world.discrete_state() == (up, yaw))
    start_rot, start_world = _relative_rotation(world), world.cube_pose()
    start_pos = start_world[:3, 3]
    ran, reason, touched = True, '', False
    if action in ORBIT_STEPS:
        ok, reason, events = run_orbit(world, planner, 45.0 * ORBIT_STEPS[action])
        touched = any(e.is_action or e.effect == 'grasp released' for e in events)
    else:
        plan = _plan(action.lower(), world if rand.plan_at_true_centre else None)
        if not plan.ok:
            ran, reason, events = False, plan.reason, []
        else:
            events = run_plan(world, plan, rand.settle)
    end_rot = _relative_rotation(world)
    q = end_rot @ start_rot.T
    up_normal = end_rot @ FACE_NORMALS.T
    tilt = float(np.degrees(np.arccos(np.clip(np.max(up_normal[2]), -1.0, 1.0))))
    final = world.discrete_state()
    moved_cm = float(100 * np.linalg.norm(world.cube_pose()[:2, 3] - start_pos[:2]))
    turn_deg = float(np.degrees(np.arccos(np.clip((np.trace(q) - 1) / 2, -1.0, 1.0))))
    world_turn = world.cube_pose()[:3, :3] @ start_world[:3, :3].T
    world_turn_deg = float(np.degrees(np.arccos(np.clip((np.trace(world_turn) - 1) / 2,
                                                        -1.0, 1.0))))
    if action in ORBIT_STEPS:   # the cube should not move: anything that did touched it
        touched = touched or moved_cm > 0.5 or world_turn_deg > 2.0
    record.update(
        ran=ran, reason=reason, touched=touched,
        final_state=int(8 * final[0] + final[1]) if ran else None,
        events=[str(e) for e in events if e.is_action or e.effect != 'odometry error'],
        effects=[e.effect for e in events if e.is_action],
        turn_deg=turn_deg, world_turn_deg=world_turn_deg,
        yaw_deg=float(np.degrees(np.arctan2(q[1, 0], q[0, 0]))),
        tilt_deg=tilt, moved_cm=moved_cm,
        sim_s=float(world.time), wall_s=time.perf_counter() - t0,
        cpu_s=time.process_time() - cpu0)
    return record


# -- the comparison (the only place the tables are read) ----------------------------------
def table_distributions(tables='corrected'):
    """(8, 7, 48, 48) p(next | action, mass, state) of abp_belief's hand-written ATG table
    `tables` (docs/MODEL.md: corrected or paper)."""
    from abp_belief.atg_learning import hand_table
    from abp_belief.modelset import TransitionParams

    return hand_table(TransitionParams(rules=tables))


def rotation_name(q):
    """Short name of a rotation in V: 'none', 'Rz+45', 'Ry-90', 'Rx180', 'R(+x+y)+90', or
    a simple roll followed by a turn about z, 'Ry+90 Rz-45' (= Rz(-45) Ry(+90))."""
    name = _axis_angle_name(q)
    if '(' not in name or ',' not in name:
        return name
    for k in (0, 1, -1, 2, -2, 3, -3, 4):
        rest = _axis_angle_name(rot_z_deg(-45.0 * k) @ np.asarray(q, dtype=float))
        if ',' not in rest:
            return f'{rest} Rz{45 * k:+d}' if k != 4 else f'{rest} Rz180'
    return name


def _axis_angle_name(q):
    angle, axis = axis_angle_deg(q)
    if angle < 1.0:
        return 'none'
    if angle > 179.0:
        axis *= np.sign(axis[np.nonzero(np.abs(axis) > 1e-6)[0][0]])
    axis = np.where(np.abs(axis) < 1e-6, 0.0, axis)
    nonzero = [i for i in range(3) if axis[i] != 0]
    deg = f'{round(angle):d}' if angle > 179.0 else f'{round(angle):+d}'
    if len(nonzero) == 1:
        i = nonzero[0]
        sign = 1 if axis[i] > 0 else -1
        if angle > 179.0:
            return f'R{"xyz"[i]}180'
        return f'R{"xyz"[i]}{round(sign * angle):+d}'
    parts = ''.join(('+' if axis[i] > 0 else '-') + 'xyz'[i] for i in nonzero)
    if len(set(np.round(np.abs(axis[nonzero]), 4))) > 1:
        parts = ','.join(f'{v:+.2f}' for v in axis)
    return f'R({parts}){deg}'


def relative_distribution(dist, state):
    """{rotation name: p} of a next-state distribution (48,) from `state`."""
    out = {}
    for nxt in np.nonzero(dist > 1e-12)[0]:
        name = rotation_name(STATE_ROTATIONS[nxt] @ STATE_ROTATIONS[state].T)
        out[name] = out.get(name, 0.0) + float(dist[nxt])
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def _fmt_dist(dist):
    return ', '.join(f'{name} {100 * p:.0f}%' for name, p in dist.items()) or '-'


# -- the survey --------------------------------------------------------------------------
@dataclass
class SurveyResult:
    classes: dict
    counts: np.ndarray          # (8, 7, 48, 48) int
    trials: dict                # (action, label) -> [record]
    checks: list                # symmetry check records
    wall_s: float
    settings: dict


def _tasks(classes, trials, orbit_trials, seed, rand):
    tasks = []
    for action, cls_list in classes.items():
        n = orbit_trials if action in ORBIT_STEPS else trials
        for cls in cls_list:
            m, s = cls.rep
            for t in range(n):
                tasks.append(dict(kind='survey', action=action, label=cls.label, trial=t,
                                  mass=m, state=s, seed=trial_seed(seed, action, cls.label, t),
                                  rand=rand.__dict__))
    return tasks


def _check_tasks(classes, seed, rand, members=2, trials=3):
    tasks = []
    for action, label in SYMMETRY_CLASSES:
        cls = next((c for c in classes.get(action, []) if c.label == label), None)
        if cls is None or len(cls.members) < 2:
            continue
        # Other members, preferring other mass variants than the representative's.
        others = sorted(cls.members[1:], key=lambda ms: (ms[0] == cls.rep[0], ms))
        step = max(1, len(others) // members)
        for m, s in others[::step][:members]:
            for t in range(trials):
                tasks.append(dict(kind='check', action=action, label=label, trial=t,
                                  mass=m, state=s, seed=trial_seed(seed, action, label, t),
                                  rand=rand.__dict__))
    return tasks


def _run_task(task):
    record = simulate(task)
    return task, record


def run_survey(classes, trials=20, orbit_trials=None, jobs=None, seed=0, rand=None,
               symmetry_check=True, progress=True, robot_profile=''):
    rand = rand or Randomisation()
    orbit_trials = trials if orbit_trials is None else orbit_trials
    tasks = _tasks(classes, trials, orbit_trials, seed, rand)
    if symmetry_check:
        tasks += _check_tasks(classes, seed, rand, trials=min(3, trials))
    # Long skills first, so the pool does not end on one straggler.
    weight = {'FLIP': 4, 'ORBIT_180': 3, 'LIFT': 3}
    tasks.sort(key=lambda t: -weight.get(t['action'], 2))
    jobs = jobs or os.cpu_count() or 1
    results = []
    cpu_start = sum(getattr(resource.getrusage(who), f) for who in
                    (resource.RUSAGE_CHILDREN, resource.RUSAGE_SELF)
                    for f in ('ru_utime', 'ru_stime'))
    t0 = time.perf_counter()
    bar = _progress(len(tasks), progress)
    if jobs == 1:
        _WORKER.clear()   # this process simulates: with the survey's robot
        _init_worker(robot_profile)
        for task in tasks:
            results.append(_run_task(task))
            bar.update()
    else:
        import multiprocessing

        with ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker,
                                 initargs=(robot_profile,),
                                 mp_context=multiprocessing.get_context('spawn')) as pool:
            futures = [pool.submit(_run_task, task) for task in tasks]
            for future in as_completed(futures):
                results.append(future.result())
                bar.update()
    bar.close()
    wall = time.perf_counter() - t0
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    own = resource.getrusage(resource.RUSAGE_SELF)
    cpu = children.ru_utime + children.ru_stime + own.ru_utime + own.ru_stime - cpu_start
    counts = np.zeros((len(ACTIONS), NUM_MASS_VARIANTS, STATES_PER_MODEL, STATES_PER_MODEL),
                      dtype=np.int64)
    by_class = {}
    checks = []
    for task, record in sorted(results, key=lambda r: (r[0]['kind'], r[0]['action'],
                                                       r[0]['label'], r[0]['mass'],
                                                       r[0]['state'], r[0]['trial'])):
        record = dict(trial=task['trial'], seed=task['seed'], mass=task['mass'],
                      state=task['state'], **record)
        if task['kind'] == 'check':
            checks.append(dict(action=task['action'], label=task['label'], **record))
            continue
        by_class.setdefault((task['action'], task['label']), []).append(record)
    for action, cls_list in classes.items():
        a = ACTIONS.index(action)
        for cls in cls_list:
            rep_m, rep_s = cls.rep
            for record in by_class.get((action, cls.label), []):
                if record['final_state'] is None:
                    continue
                for m, s in cls.members:
                    counts[a, m, s, map_outcome(rep_s, record['final_state'], s)] += 1
    # Symmetry check: each member's own outcome against the representative's, mapped.
    for check in checks:
        rep = next(c for c in classes[check['action']] if c.label == check['label']).rep
        rep_record = next(r for r in by_class[(check['action'], check['label'])]
                          if r['trial'] == check['trial'])
        mapped = map_outcome(rep[1], rep_record['final_state'], check['state'])
        check.update(rep_mass=rep[0], rep_state=rep[1], rep_final=rep_record['final_state'],
                     mapped_final=int(mapped), agrees=check['final_state'] == mapped,
                     rep_yaw_deg=rep_record['yaw_deg'], rep_turn_deg=rep_record['turn_deg'])
    settings = dict(trials=trials, orbit_trials=orbit_trials, jobs=jobs, seed=seed,
                    randomisation=rand.__dict__, nominal_centre=NOMINAL_CENTRE,
                    diff_threshold=DIFF_THRESHOLD, tasks=len(tasks), cpu_s=cpu,
                    load_average=os.getloadavg(),
                    robot=load_profile(robot_profile).name, robot_profile=robot_profile)
    return SurveyResult(classes, counts, by_class, checks, wall, settings)


class _NoBar:
    def update(self, n=1):
        pass

    def close(self):
        pass


def _progress(total, enabled):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm
    return tqdm(total=total, unit='trial', smoothing=0.05, dynamic_ncols=True)


# -- reports -----------------------------------------------------------------------------
def compare(result):
    """Per cell: empirical vs table distribution, the largest difference and the flag."""
    table = table_distributions(result.settings.get('tables', 'corrected'))
    n = result.counts.sum(axis=3)
    emp = np.where(n[..., None] > 0, result.counts / np.maximum(n, 1)[..., None], np.nan)
    diff = np.where(n > 0, np.abs(np.nan_to_num(emp) - table).max(axis=3), 0.0)
    flagged = (n > 0) & (diff > DIFF_THRESHOLD + 1e-9)
    return emp, table, diff, flagged, n


def _class_rows(result, emp, table, diff, flagged, n):
    rows = []
    for action, cls_list in result.classes.items():
        a = ACTIONS.index(action)
        for cls in cls_list:
            records = result.trials.get((action, cls.label), [])
            rep_m, rep_s = cls.rep
            sim = relative_distribution(np.nan_to_num(emp[a, rep_m, rep_s]), rep_s)
            tables = {json.dumps(relative_distribution(table[a, m, s], s), sort_keys=True)
                      for m, s in cls.members}
            tab = relative_distribution(table[a, rep_m, rep_s], rep_s)
            members_flagged = int(sum(flagged[a, m, s] for m, s in cls.members))
            effects = {}
            for r in records:
                for e in r['effects'] or ['(no action event)']:
                    effects[e] = effects.get(e, 0) + 1
            yaw = np.radians([r['yaw_deg'] for r in records if r['ran']])
            turn = [r['turn_deg'] for r in records if r['ran']]
            rows.append(dict(
                action=action, label=cls.label, cells=len(cls.members),
                rep=f'{MASS_NAMES[rep_m]}/{rep_s}', trials=len(records),
                not_run=sum(not r['ran'] for r in records),
                touched=sum(_touched(r) for r in records) if action in ORBIT_STEPS else 0,
                start_mismatch=sum(not r['start_ok'] for r in records),
                sim=sim, table=tab, table_varies=len(tables) > 1,
                max_diff=float(max(diff[a, m, s] for m, s in cls.members)),
                flagged_cells=members_flagged, effects=effects,
                yaw_deg=_circular_mean_std_deg(yaw) if len(yaw) else None,
                turn_deg=(float(np.mean(turn)), float(np.std(turn))) if turn else None,
                tilt_max_deg=max((r['tilt_deg'] for r in records), default=0.0),
                moved_cm=float(np.mean([r['moved_cm'] for r in records])) if records else 0.0))
    return rows


def _touched(record):
    if 'world_turn_deg' in record:
        return bool(record['touched'])
    # Results of the first version (touch from the cube's motion in V, wrong for ORBIT).
    return bool(record['moved_cm'] > 0.5 or record['effects'])


def _circular_mean_std_deg(angles):
    mean = np.angle(np.mean(np.exp(1j * np.asarray(angles))))
    spread = np.sqrt(np.mean(np.angle(np.exp(1j * (np.asarray(angles) - mean))) ** 2))
    return float(np.degrees(mean)), float(np.degrees(spread))


def _goals(result, emp, table, n):
    """Uniform cells: share of trials with the table's most likely outcome (MODEL.md's
    nominal), per cell."""
    shares = []
    for action, cls_list in result.classes.items():
        a = ACTIONS.index(action)
        for cls in cls_list:
            for m, s in cls.members:
                if m != 0 or n[a, m, s] == 0:
                    continue
                nominal = int(np.argmax(table[a, m, s]))
                shares.append((action, s, float(emp[a, m, s, nominal])))
    ok = sum(share >= GOAL_UNIFORM_NOMINAL for _, _, share in shares)
    return dict(uniform_cells=len(shares), uniform_cells_at_goal=ok,
                uniform_failing=[dict(action=a, state=s, nominal_share=v)
                                 for a, s, v in shares if v < GOAL_UNIFORM_NOMINAL])


def _versions():
    import mujoco

    out = dict(python=sys.version.split()[0], numpy=np.__version__, mujoco=mujoco.__version__,
               platform=platform.platform(), cpus=os.cpu_count())
    try:
        repo = Path(__file__).resolve().parents[2]
        out['git_commit'] = subprocess.run(['git', '-C', str(repo), 'rev-parse', 'HEAD'],
                                           capture_output=True, text=True,
                                           timeout=10).stdout.strip()
        dirty = subprocess.run(['git', '-C', str(repo), 'status', '--porcelain'],
                               capture_output=True, text=True, timeout=10).stdout
        out['git_dirty_files'] = len(dirty.splitlines())
    except (OSError, subprocess.SubprocessError):
        pass
    return out


def write_json(path, result, emp, table, diff, flagged, n, rows, goals):
    cells = []
    for a, action in enumerate(ACTIONS):
        for m in range(NUM_MASS_VARIANTS):
            for s in range(STATES_PER_MODEL):
                if n[a, m, s] == 0:
                    continue
                nz = np.nonzero(result.counts[a, m, s])[0]
                tz = np.nonzero(table[a, m, s] > 1e-12)[0]
                cells.append(dict(
                    action=action, mass=MASS_NAMES[m], mass_index=m, state=s,
                    klass=cell_key(action, m, s), trials=int(n[a, m, s]),
                    counts={int(k): int(result.counts[a, m, s, k]) for k in nz},
                    table={int(k): round(float(table[a, m, s, k]), 6) for k in tz},
                    max_diff=round(float(diff[a, m, s]), 6), flagged=bool(flagged[a, m, s])))
    doc = dict(
        description='outcome_survey: MuJoCo outcomes of the skills vs the ATG tables '
                    '(abp_belief.modelset.build_outcome_tables); states as MODEL.md '
                    '(8 * up + yaw, relative to the robot)',
        settings=result.settings, versions=_versions(), wall_s=result.wall_s,
        core_s=float(sum(r['wall_s'] for recs in result.trials.values() for r in recs)
                     + sum(c['wall_s'] for c in result.checks)),
        goals=goals, classes=rows, cells=cells,
        trials=[dict(action=a, klass=label, **r) for (a, label), recs in result.trials.items()
                for r in recs],
        symmetry_check=result.checks)
    Path(path).write_text(json.dumps(doc, indent=1))


def write_markdown(path, result, rows, goals, flagged):
    s = result.settings
    rand = s['randomisation']
    lines = [
        '# Outcome survey: MuJoCo physics vs the ATG tables',
        '',
        f'{s["trials"]} trials per manual class, {s["orbit_trials"]} per ORBIT class; '
        f'start +-{100 * rand["pos_jitter"]:g} cm, +-{rand["yaw_jitter_deg"]:g} deg, '
        f'friction +-{100 * rand["friction_jitter"]:g} %, ORBIT odometry noise '
        f'{rand["orbit_noise"][0]:g} m / {rand["orbit_noise"][1]:g} rad; seed {s["seed"]}; '
        f'skills plan at the {"true" if rand.get("plan_at_true_centre") else "nominal"} cube '
        f'centre; {s["tasks"]} simulations on {s["jobs"]} workers in {result.wall_s / 60:.1f} min '
        f'wall, {s.get("cpu_s", 0) / 60:.1f} min CPU (load average at the end '
        f'{", ".join(f"{v:.1f}" for v in s.get("load_average", ()))}).',
        '',
        'Outcomes are rotations Q of the cube in the view frame V (x_V from the cube to the '
        'robot, z up; next state = Q applied to the start state, MODEL.md): `Rz-45` turns '
        'the cube 45 deg clockwise seen from above, `Ry-90` rolls its front face to the '
        'top, `R(+x+y)-90` is a roll about a horizontal diagonal. A class is the set of '
        'start cells (mass variant, state) with the same physics (module doc of '
        '`abp_bench.outcome_survey`); "flagged" counts its cells whose empirical and table '
        'distributions differ by more than 10 points in some next state. The table: '
        f"MODEL.md's hand-written one, {s.get('tables', 'corrected')} rules.",
        '',
        f"Goal (uniform cells give MODEL.md's nominal outcome in >= 95 % of trials): "
        f'{goals["uniform_cells_at_goal"]}/{goals["uniform_cells"]} cells.',
        f'Flagged cells: {int(flagged.sum())} of {int(sum(r["cells"] for r in rows))}.',
        '',
        '| action | class | cells | rep | sim | table | max diff | flagged | effects | '
        'yaw (deg) | tilt max | moved |',
        '|---|---|---:|---|---|---|---:|---:|---|---|---:|---:|',
    ]
    for r in rows:
        effects = ', '.join(f'{k} {v}' for k, v in sorted(r['effects'].items(),
                                                          key=lambda kv: -kv[1]))
        yaw = f'{r["yaw_deg"][0]:+.0f} +- {r["yaw_deg"][1]:.0f}' if r['yaw_deg'] else '-'
        notes = []
        if r['not_run']:
            notes.append(f'{r["not_run"]} not run')
        if r['touched']:
            notes.append(f'{r["touched"]} touched')
        if r['start_mismatch']:
            notes.append(f'{r["start_mismatch"]} start off')
        if r['table_varies']:
            notes.append('table varies in class')
        sim = _fmt_dist(r['sim']) + (f' ({"; ".join(notes)})' if notes else '')
        mark = ' **X**' if r['flagged_cells'] else ''
        lines.append(
            f'| {r["action"]} | {r["label"]} | {r["cells"]} | {r["rep"]} | {sim} | '
            f'{_fmt_dist(r["table"])} | {100 * r["max_diff"]:.0f}{mark} | '
            f'{r["flagged_cells"]} | {effects} | {yaw} | {r["tilt_max_deg"]:.0f} | '
            f'{r["moved_cm"]:.1f} cm |')
    if result.checks:
        agree = sum(c['agrees'] for c in result.checks)
        lines += ['', '## Symmetry check', '',
                  f"Members re-run with the representative's seeds: {agree}/"
                  f'{len(result.checks)} outcomes equal the mapped representative outcome.',
                  '', '| action | class | rep -> next | member | member -> next | mapped | '
                  'yaw rep / member (deg) |', '|---|---|---|---|---|---|---|']
        for c in result.checks:
            lines.append(
                f'| {c["action"]} | {c["label"]} | {MASS_NAMES[c["rep_mass"]]}/'
                f'{c["rep_state"]} -> {c["rep_final"]} | {MASS_NAMES[c["mass"]]}/{c["state"]} '
                f'| {c["final_state"]} | {c["mapped_final"]}{"" if c["agrees"] else " **X**"} '
                f'| {c["rep_yaw_deg"]:+.1f} / {c["yaw_deg"]:+.1f} |')
    if goals['uniform_failing']:
        lines += ['', 'Uniform cells below the goal: ' + ', '.join(
            f'{g["action"]} state {g["state"]} ({100 * g["nominal_share"]:.0f} %)'
            for g in goals['uniform_failing'])]
    Path(path).write_text('\n'.join(lines) + '\n')


def write_heatmap(path, emp, table, diff, flagged, n):
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    rows = NUM_MASS_VARIANTS * STATES_PER_MODEL
    fig, axes = plt.subplots(2, 8, figsize=(26, 19))
    fig.subplots_adjust(left=0.05, right=0.93, bottom=0.06, top=0.93, wspace=0.08,
                        hspace=0.22)
    cmap = plt.get_cmap('viridis').with_extremes(bad='#d9d9d9')
    for a, action in enumerate(ACTIONS):
        e = emp[a].reshape(rows, STATES_PER_MODEL)
        t = table[a].reshape(rows, STATES_PER_MODEL)
        f = flagged[a].reshape(rows)
        d = np.abs(np.nan_to_num(e, nan=0.0) - t) > DIFF_THRESHOLD + 1e-9
        d &= f[:, None]
        for k, (img, title) in enumerate(((e, 'MuJoCo'), (t, 'table'))):
            ax = axes[a // 4, 2 * (a % 4) + k]
            im = ax.imshow(img, aspect='auto', cmap=cmap, vmin=0, vmax=1,
                           interpolation='none')
            ax.set_title(f'{action}: {title}', fontsize=12)
            ax.set_xticks(np.arange(0, STATES_PER_MODEL, 8))
            ax.set_xticklabels([f'up {name}' for name in ('+x', '-x', '+y', '-y', '+z', '-z')],
                               rotation=90, fontsize=8)
            ax.set_xlabel('next state (8 * up + yaw)', fontsize=8)
            ax.set_yticks(np.arange(STATES_PER_MODEL / 2, rows, STATES_PER_MODEL))
            ax.set_yticklabels(MASS_LABELS if k == 0 and a % 4 == 0 else [], fontsize=9)
            for y in range(STATES_PER_MODEL, rows, STATES_PER_MODEL):
                ax.axhline(y - 0.5, color='white', lw=0.8)
            ys, xs = np.nonzero(d)
            ax.scatter(xs, ys, s=10, marker='s', facecolors='none', edgecolors='red',
                       linewidths=0.6)
            flagged_rows = np.nonzero(f)[0]
            ax.scatter(np.full(flagged_rows.size, STATES_PER_MODEL - 0.2), flagged_rows,
                       s=6, marker='<', color='red', clip_on=False)
            ax.set_xlim(-0.5, STATES_PER_MODEL - 0.5)
    fig.colorbar(im, cax=fig.add_axes([0.95, 0.3, 0.012, 0.4]),
                 label='p(next state | start cell)')
    fig.suptitle('Outcome survey: start cell (mass variant, state 0..47 in each block) -> '
                 'next state; MuJoCo (left) vs ATG table (right); red: differs by > 10 '
                 'points (cell marked at the right edge, outcomes outlined); grey: not '
                 'surveyed', fontsize=14)
    fig.savefig(path, dpi=70)
    plt.close(fig)


def write_outputs(result, out_dir, tables='corrected'):
    result.settings['tables'] = tables               # the hand-written table compared with
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / 'survey.pkl', 'wb') as stream:   # to redo the reports: --report-only
        pickle.dump(result, stream)
    emp, table, diff, flagged, n = compare(result)
    rows = _class_rows(result, emp, table, diff, flagged, n)
    goals = _goals(result, emp, table, n)
    write_json(out / 'survey.json', result, emp, table, diff, flagged, n, rows, goals)
    write_markdown(out / 'survey.md', result, rows, goals, flagged)
    write_heatmap(out / 'survey.png', emp, table, diff, flagged, n)
    return rows, goals, flagged


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--trials', type=int, default=20, help='trials per manual class')
    parser.add_argument('--orbit-trials', type=int, default=None,
                        help='trials per ORBIT class (default: --trials)')
    parser.add_argument('--jobs', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--out', default='bench_out/survey')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--robot-profile', default='', metavar='YAML',
                        help="the robot's profile (abp_description/profiles/*.yaml; default "
                             'the uBot-6): its skills push, lift and flip the cube')
    parser.add_argument('--actions', nargs='+', default=list(ACTIONS), choices=ACTIONS)
    parser.add_argument('--masses', nargs='+', default=list(MASS_NAMES), choices=MASS_NAMES,
                        help='mass variants (u = uniform, m+x = heavy body +x, ...)')
    parser.add_argument('--parity', choices=('even', 'odd', 'both'), default='both',
                        help='start yaws: even (faces aligned), odd (edge to the robot)')
    parser.add_argument('--classes', nargs='+', default=None, metavar='LABEL',
                        help="only these classes, e.g. 'uniform, even yaw'")
    parser.add_argument('--plan-at', choices=('nominal', 'true'), default='nominal',
                        help='manual skills plan at the nominal cube centre (the start '
                             'jitter is then also an estimate error) or at the true one')
    parser.add_argument('--max-classes', type=int, default=0,
                        help='at most this many classes per action (0 = all)')
    parser.add_argument('--pos-jitter', type=float, default=0.01, help='m')
    parser.add_argument('--yaw-jitter-deg', type=float, default=3.0)
    parser.add_argument('--friction-jitter', type=float, default=0.2)
    parser.add_argument('--orbit-noise', type=float, nargs=2, default=(0.01, 0.02),
                        metavar=('SIGMA_M', 'SIGMA_RAD'))
    parser.add_argument('--faults', action='store_true',
                        help="contact faults at graph_benchmark --faults' rates: each manual "
                             'trial draws a slipping grasp and a missed push with '
                             'probability 0.1 each (override with --p-slip-grasp, '
                             '--p-missed-push)')
    parser.add_argument('--p-slip-grasp', type=float, default=None,
                        help='probability of a slipping grasp per manual trial (hands 1 cm out)')
    parser.add_argument('--p-missed-push', type=float, default=None,
                        help='probability of a missed push per manual trial (hands 10 cm out)')
    parser.add_argument('--tables', choices=TRANSITION_RULES, default='corrected',
                        help='the hand-written ATG table to compare with (docs/MODEL.md)')
    parser.add_argument('--no-symmetry-check', action='store_true')
    parser.add_argument('--no-progress', action='store_true')
    parser.add_argument('--report-only', action='store_true',
                        help='rewrite the reports from --out/survey.pkl without simulating')
    args = parser.parse_args(argv)
    if args.report_only:
        with open(Path(args.out) / 'survey.pkl', 'rb') as stream:
            result = pickle.load(stream)
        _, goals, flagged = write_outputs(result, args.out, args.tables)
        print(f'{int(flagged.sum())} flagged cells; wrote {args.out}/survey.{{json,md,png}}')
        return 0
    if args.trials < 1 or (args.orbit_trials is not None and args.orbit_trials < 1):
        parser.error('--trials and --orbit-trials must be >= 1')
    parities = PARITIES if args.parity == 'both' else (args.parity,)
    classes = build_classes(args.actions, [MASS_NAMES.index(m) for m in args.masses],
                            parities)
    if args.classes:
        classes = {a: [c for c in cls if c.label in args.classes] for a, cls in classes.items()}
    if args.max_classes > 0:
        classes = {a: c[:args.max_classes] for a, c in classes.items()}
    fault_rate = FAULT_RATE if args.faults else 0.0
    p_slip = fault_rate if args.p_slip_grasp is None else args.p_slip_grasp
    p_miss = fault_rate if args.p_missed_push is None else args.p_missed_push
    if not (0.0 <= p_slip <= 1.0 and 0.0 <= p_miss <= 1.0):
        parser.error('--p-slip-grasp and --p-missed-push must be in [0, 1]')
    rand = Randomisation(args.pos_jitter, args.yaw_jitter_deg, args.friction_jitter,
                         tuple(args.orbit_noise), plan_at_true_centre=args.plan_at == 'true',
                         p_slip_grasp=p_slip, p_missed_push=p_miss)
    n_classes = sum(len(c) for c in classes.values())
    print(f'outcome_survey: {n_classes} classes, {args.trials} trials each '
          f'({args.orbit_trials or args.trials} for ORBIT), {args.jobs} workers', flush=True)
    result = run_survey(classes, args.trials, args.orbit_trials, args.jobs, args.seed, rand,
                        symmetry_check=not args.no_symmetry_check,
                        progress=not args.no_progress, robot_profile=args.robot_profile)
    rows, goals, flagged = write_outputs(result, args.out, args.tables)
    print(f'{len(rows)} classes, {int(flagged.sum())} flagged cells, '
          f'uniform goal {goals["uniform_cells_at_goal"]}/{goals["uniform_cells"]}; '
          f'{result.wall_s / 60:.1f} min; wrote {args.out}/survey.{{json,md,png}}')
    return 0


if __name__ == '__main__':
    # Run the imported module's main, so that pickled results name abp_bench.outcome_survey.
    from abp_bench.outcome_survey import main as _main

    sys.exit(_main())
