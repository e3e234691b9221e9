"""``planner_benchmark --objects K`` (K > 1): model-sampled scenes of K cubes (issue 37).

    python -m abp_bench.planner_benchmark --objects 3 --twins --models robot \\
        --planners cost --trials 20 --seed 0 --json multi.json

Per scene (seeded: scene s of seed S draws its models, positions and targets from
``SeedSequence([S, s, 2])``, cube j its initial state from ``[S, s, 100 + j, 0]`` and its
outcome/observation noise from ``[S, s, 100 + j, 1]``): K distinct models of the set
(``--twins``: two eccentric mass twins, visually identical, plus K - 2 cubes with other
faces) at plane positions at least 0.3 m apart in a 1.5 m square. Then, each with fresh
copies of the cubes' noise streams:

- ``single``: every cube alone, with the existing single-object trial (``run_trial``,
  the planner benchmark's simulation) on its own streams: the baseline;
- ``identify_all``, ``find_present`` (find the model of a cube drawn from the scene),
  ``find_absent`` (find a model not in the scene) and ``identify_one`` (identify track 1),
  each with ``scene_simulator.run_scene``.

Scored against the truth: identify_all succeeds when every cube is named correctly;
find succeeds when it reports the cube that is the target (or one no action can tell
from it: ``indistinguishable_models``) or, target absent, that no cube is it. A wrong
identification is an object the task declared decided with a wrong answer.

Also timed in-process: the belief update of a K-object belief against the single-object
filter (``update_timing``), so the K = 3 ≤ 3 × K = 1 goal is measured on the same load.
"""

from __future__ import annotations

import os
import time

import numpy as np

from abp_belief.cube import STATES_PER_MODEL
from abp_belief.factored_belief import FactoredBelief
from abp_belief.filter import BeliefFilter
from abp_bench.model_sets import build_model_set, object_families, with_model_tables
from abp_planner.object_planner import OBJECT_SCORES, ObjectActionPlanner, TravelModel
from abp_planner.planner import make_planner
from abp_planner.scene_simulator import SceneCube, place_cubes, run_scene
from abp_planner.simulator import indistinguishable_models, run_trial
from abp_planner.stopping import StoppingRule
from abp_planner.tasks import Task, TaskMonitor

SCENE_TASKS = ('identify_all', 'find_present', 'find_absent', 'identify_one')
MULTI_PLANNERS = ('abp', 'abp2', 'abp3', 'cost')


def add_arguments(parser) -> None:
    parser.add_argument('--objects', type=int, default=1, metavar='K',
                        help='cubes per scene (default 1: the single-object benchmark); K > 1 '
                        'runs the multi-object scenes of abp_bench.multi_object_benchmark, '
                        '--trials scenes per model set and planner')
    parser.add_argument('--twins', action='store_true',
                        help='--objects >= 2: put a pair of eccentric mass twins (visually '
                        'identical) into every scene')
    parser.add_argument('--object-score', choices=OBJECT_SCORES, default='rate',
                        help='--objects: choose the object by bits per second including the '
                        'travel to it (rate, default) or by expected gain alone (gain)')
    parser.add_argument('--travel-speed', type=float, default=TravelModel.speed_mps,
                        help='--objects: base speed between cubes, m/s')
    parser.add_argument('--approach-s', type=float, default=TravelModel.approach_s,
                        help='--objects: seconds to stop and square up to another cube')


def check_arguments(parser, args) -> None:
    if args.objects < 1:
        parser.error('--objects must be >= 1')
    if args.objects == 1:
        if args.twins:
            parser.error('--twins needs --objects >= 2')
        return
    unusable = [p for p in args.planners if p not in MULTI_PLANNERS]
    if unusable:
        parser.error(f"--objects: planner(s) {', '.join(unusable)} have no expected gains to "
                     f"choose an object by; use {', '.join(MULTI_PLANNERS)}")
    if args.stop_curve or args.family or args.refuse:
        parser.error('--objects does not combine with --stop-curve, --family or --refuse')
    try:
        TravelModel(args.travel_speed, args.approach_s)
    except ValueError as exc:
        parser.error(str(exc))
    for label in args.models:
        ms = build_model_set(label, args.seed, args.tables)
        if args.objects > ms.num_models:
            parser.error(f'--objects {args.objects}: model set {label} has only '
                         f'{ms.num_models} models')
        if args.twins and 'twin family, eccentric' not in object_families(ms):
            parser.error(f'--twins: model set {label} has no eccentric mass twins '
                         '(use robot or 1470)')


def cube_rngs(seed: int, scene: int, j: int) -> tuple[np.random.Generator, np.random.Generator]:
    """(truth rng, noise rng) of cube j of a scene, in run_trial's roles."""
    return (np.random.default_rng(np.random.SeedSequence([seed, scene, 100 + j, 0])),
            np.random.default_rng(np.random.SeedSequence([seed, scene, 100 + j, 1])))


def initial_state(seed: int, scene: int, j: int) -> int:
    """The state ``run_trial(..., true_models=[m])`` draws from cube j's truth rng."""
    truth_rng, _ = cube_rngs(seed, scene, j)
    truth_rng.integers(1)  # run_trial's pick from the one-model list
    return int(truth_rng.integers(STATES_PER_MODEL))


def draw_scene(model_set, seed: int, scene: int, k: int, twins: bool) -> dict:
    """Models, positions and find targets of one scene (module doc)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, scene, 2]))
    m = model_set.num_models
    if twins:
        faces = np.asarray(model_set.faces)
        _, family = np.unique(faces, axis=0, return_inverse=True)
        family = family.reshape(-1)
        eccentric = np.asarray(model_set.mass) > 0
        counts = np.bincount(family[eccentric], minlength=family.max() + 1)
        twin_family = rng.choice(np.flatnonzero(counts >= 2))
        pair = rng.choice(np.flatnonzero(eccentric & (family == twin_family)), 2, replace=False)
        others = np.flatnonzero(family != twin_family)
        models = np.concatenate([pair, rng.choice(others, k - 2, replace=False)])
        models = rng.permutation(models)
    else:
        models = rng.choice(m, k, replace=False)
    positions = place_cubes(k, rng)
    present = int(models[rng.integers(k)])
    absent = int(rng.choice(np.setdiff1d(np.arange(m), models)))
    cubes = [SceneCube(object_id=j + 1, true_model=int(models[j]),
                       initial_state=initial_state(seed, scene, j),
                       position=(float(positions[j, 0]), float(positions[j, 1])))
             for j in range(k)]
    return {'cubes': cubes, 'find_present': present, 'find_absent': absent}


_WORKER: dict = {}


def _setup(label, seed, options):
    tables = options.get('tables', 'paper')
    key = (label, seed, tables, options.get('belief_models'), options.get('world_models'))
    if key not in _WORKER:
        ms = with_model_tables(build_model_set(label, seed, tables), options.get('belief_models'))
        world = with_model_tables(ms, options.get('world_models'))
        rule = StoppingRule.for_model_set(
            ms, kind=options['stop'], target_error=options['target_error'],
            stop_posterior=options['stop_posterior'], max_actions=options['max_actions'],
            fault_margin=options['fault_margin'])
        _WORKER[key] = (ms, world, rule, BeliefFilter(ms))
    return _WORKER[key]


def _scene_task(task) -> tuple:
    """One scene of one planner: the single-cube baseline and the four task runs."""
    label, planner_name, scene, seed, options = task
    ms, world, rule, single_filter = _setup(label, seed, options)
    planner = make_planner(planner_name, ms, **options)
    objects = ObjectActionPlanner(
        planner, TravelModel(options['travel_speed'], options['approach_s']),
        object_score=options['object_score'])
    drawn = draw_scene(ms, seed, scene, options['objects'], options['twins'])
    cubes = drawn['cubes']
    record = {'scene': scene, 'cubes': [vars(c) for c in cubes],
              'target_present': drawn['find_present'], 'target_absent': drawn['find_absent']}
    twins_of = {c.object_id: indistinguishable_models(world, c.true_model, c.initial_state)
                for c in cubes}
    record['decidable'] = {c.object_id: bool(twins_of[c.object_id].size == 0) for c in cubes}
    single = []
    for j, c in enumerate(cubes):
        truth_rng, noise_rng = cube_rngs(seed, scene, j)
        trial = run_trial(world, planner, truth_rng, noise_rng, belief_filter=single_filter,
                          stopping=rule, true_models=[c.true_model])
        assert trial.initial_state == c.initial_state
        single.append({'object_id': c.object_id, 'actions': trial.num_actions,
                       'correct': trial.correct, 'identified': trial.identified,
                       'latency_ms': trial.latency_ms})
    record['single'] = single
    tasks = {'identify_all': Task('identify_all'),
             'find_present': Task('find', model=drawn['find_present']),
             'find_absent': Task('find', model=drawn['find_absent']),
             'identify_one': Task('identify', object_id=cubes[0].object_id)}
    for name, scene_task in tasks.items():
        noise = {c.object_id: cube_rngs(seed, scene, j)[1] for j, c in enumerate(cubes)}
        run = run_scene(world, ms, objects, TaskMonitor(scene_task, rule), cubes, noise)
        record[name] = score_run(name, run.as_dict(), cubes, twins_of, scene_task)
    return label, planner_name, scene, record


def score_run(name: str, run: dict, cubes, twins_of: dict, task: Task) -> dict:
    """``run`` with ``correct`` and ``wrong`` (decided objects answered wrongly) added."""
    truth = {c.object_id: c.true_model for c in cubes}
    if name in ('identify_all', 'identify_one'):
        named = [o for o in run['objects']
                 if name == 'identify_all' or o['object_id'] == task.object_id]
        wrong = [o['object_id'] for o in named if o['identified'] and o['model'] != o['true_model']]
        run['correct'] = bool(run['success'] and all(o['model'] == o['true_model']
                                                      for o in named))
    else:
        found = run['found_object']
        present = [o for o, m in truth.items()
                   if m == task.model or task.model in twins_of[o]]
        if found is not None:
            wrong = [] if found in present else [found]
            run['correct'] = not wrong
        else:
            wrong = list(present) if run['success'] else []  # "no cube is it" while one is
            run['correct'] = bool(run['success'] and not present)
    run['wrong'] = wrong
    return run


def update_timing(model_set, k: int, repeats: int = 2000, seed: int = 0) -> dict:
    """Median CPU time (µs; wall time under ``wall_*``) of belief updates: the
    single-object filter's step
    (predict + correct) and correct, against a K-object belief's step on one object, K
    steps (every object acted on and seen) and the batched correction of K objects. The
    operations are timed in turn within each repeat, so a change of machine load during
    the measurement weighs on all of them alike."""
    rng = np.random.default_rng(seed)
    aspects = rng.integers(0, model_set.observation.num_aspects, size=64)
    zs = [model_set.observation.sample(int(a), rng) for a in aspects]
    ids = list(range(1, k + 1))
    single = BeliefFilter(model_set)
    fb = FactoredBelief(model_set, ids)
    actions = ('ORBIT_P45', 'PUSH', 'LIFT', 'FLIP')
    operations = {
        'single_step_us': lambda i: (single.predict(actions[i % 4]), single.correct(zs[i % 64])),
        'single_correct_us': lambda i: single.correct(zs[i % 64]),
        'k_step_one_object_us': lambda i: fb.step(ids[i % k], actions[i % 4], zs[i % 64]),
        'k_step_every_object_us': lambda i: [fb.step(o, actions[(i + o) % 4], zs[(i + o) % 64])
                                             for o in ids],
        'k_correct_many_us': lambda i: fb.correct_many({o: zs[(i + o) % 64] for o in ids}),
    }
    # Every operation starts from the belief after one observation: repeated updates on
    # unrelated observations would drive the beliefs into denormal floats (slow, unreal).
    start_belief = BeliefFilter(model_set)
    start_belief.correct(zs[0])
    times = {name: np.empty(repeats) for name in operations}
    wall = {name: np.empty(repeats) for name in operations}
    for i in range(repeats):
        for name, operation in operations.items():
            single.belief = start_belief.belief.copy()
            fb.beliefs[:] = start_belief.belief
            start, start_cpu = time.perf_counter(), time.thread_time()
            operation(i)
            times[name][i] = time.thread_time() - start_cpu
            wall[name][i] = time.perf_counter() - start
    # CPU time of this thread: on a shared, overloaded machine the wall time of a
    # millisecond-long update mostly measures when the scheduler let it run.
    timing = {name: float(np.median(t) * 1e6) for name, t in times.items()}
    timing.update({'wall_' + name: float(np.median(t) * 1e6) for name, t in wall.items()})
    timing['ratio_step_one_object'] = timing['k_step_one_object_us'] / timing['single_step_us']
    timing['ratio_step_every_object'] = (timing['k_step_every_object_us']
                                         / timing['single_step_us'])
    timing['ratio_correct_many'] = timing['k_correct_many_us'] / timing['single_correct_us']
    return timing


def load_average() -> str:
    one, five, fifteen = os.getloadavg()
    return f'{one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} cores'


def _percentile(values, q) -> float:
    values = np.asarray(values, dtype=np.float64)
    return float(np.percentile(values, q)) if values.size else float('nan')


def summarise_scenes(records: list[dict]) -> dict:
    """Per task: scenes, success against the truth, wrong identifications (all, and on
    decidable objects), actions, time, planning and update latency; plus the goals'
    ratios (identify_all vs the single-cube sum, find vs identify_all)."""
    summary = {'scenes': len(records)}
    single_actions = np.array([sum(s['actions'] for s in r['single']) for r in records],
                              dtype=float)
    single_lat = [x for r in records for s in r['single'] for x in s['latency_ms']]
    summary['single'] = {
        'actions_mean': float(single_actions.mean()),
        'correct_objects': int(sum(s['correct'] for r in records for s in r['single'])),
        'objects': int(sum(len(r['single']) for r in records)),
        'planning_ms_median': _percentile(single_lat, 50),
        'planning_ms_p95': _percentile(single_lat, 95),
    }
    for name in SCENE_TASKS:
        runs = [r[name] for r in records]
        lat = [x for run in runs for x in run['planning_ms']]
        # The first decision of a run plans every candidate object (nothing cached yet).
        cold = [run['planning_ms'][0] for run in runs if run['planning_ms']]
        upd = [x for run in runs for x in run['update_ms']]
        wrong_decidable = sum(1 for r in records for o in r[name]['wrong']
                              if r['decidable'][o])
        actions = np.array([run['num_actions'] for run in runs], dtype=float)
        summary[name] = {
            'success': float(np.mean([run['correct'] for run in runs])),
            'task_answered': float(np.mean([run['success'] for run in runs])),
            'wrong': int(sum(len(run['wrong']) for run in runs)),
            'wrong_decidable': int(wrong_decidable),
            'actions_mean': float(actions.mean()),
            'action_time_mean_s': float(np.mean([run['action_time_s'] for run in runs])),
            'travel_time_mean_s': float(np.mean([run['travel_time_s'] for run in runs])),
            'decisions': len(lat),
            'planning_ms_median': _percentile(lat, 50),
            'planning_ms_p95': _percentile(lat, 95),
            'planning_ms_max': _percentile(lat, 100),
            'cold_planning_ms_median': _percentile(cold, 50),
            'update_ms_median': _percentile(upd, 50),
        }
    all_actions = np.array([r['identify_all']['num_actions'] for r in records], dtype=float)
    summary['identify_all_vs_single'] = float(all_actions.sum() / max(single_actions.sum(), 1))
    summary['identify_all_vs_single_max_scene'] = float(
        np.max(all_actions / np.maximum(single_actions, 1)))
    find_actions = np.array([r['find_present']['num_actions'] for r in records], dtype=float)
    summary['find_present_saving'] = float(1.0 - find_actions.sum() / max(all_actions.sum(), 1))
    summary['find_present_saving_scene_median'] = float(np.median(
        1.0 - find_actions / np.maximum(all_actions, 1)))
    return summary


def markdown_tables(summaries: dict, timings: dict) -> str:
    lines = ['| \\|M\\| | Planner | Task | Scenes | Success | Wrong (decidable) | Actions '
             '| Action time (s) | Travel (s) | Plan ms median | p95 | first decision median '
             '| Update ms median |', '|' + '---|' * 13]
    for (label, planner), s in summaries.items():
        lines.append(f"| {label} | {planner} | single cubes (sum) | {s['scenes']} | "
                     f"{s['single']['correct_objects']}/{s['single']['objects']} cubes | – | "
                     f"{s['single']['actions_mean']:.2f} | – | – | "
                     f"{s['single']['planning_ms_median']:.1f} | "
                     f"{s['single']['planning_ms_p95']:.1f} | – | – |")
        for name in SCENE_TASKS:
            t = s[name]
            lines.append(
                f"| {label} | {planner} | {name} | {s['scenes']} | {100 * t['success']:.1f}% | "
                f"{t['wrong']} ({t['wrong_decidable']}) | {t['actions_mean']:.2f} | "
                f"{t['action_time_mean_s']:.0f} | {t['travel_time_mean_s']:.0f} | "
                f"{t['planning_ms_median']:.1f} | {t['planning_ms_p95']:.1f} | "
                f"{t['cold_planning_ms_median']:.1f} | {t['update_ms_median']:.3f} |")
    lines += ['', '| \\|M\\| | Planner | identify_all / single-cube sum (max scene) '
              '| find_present saving vs identify_all (scene median) |', '|---|---|---|---|']
    for (label, planner), s in summaries.items():
        lines.append(f"| {label} | {planner} | {s['identify_all_vs_single']:.3f} "
                     f"({s['identify_all_vs_single_max_scene']:.2f}) | "
                     f"{100 * s['find_present_saving']:.1f}% "
                     f"({100 * s['find_present_saving_scene_median']:.1f}%) |")
    lines += ['', 'Belief update, median CPU µs (wall µs), ratio to one cube:', '',
              '| \\|M\\| | K | single step | K-belief step, one object, ratio '
              '| K steps, every object, ratio | single correct '
              '| batched correct of K, ratio |', '|---|---|---|---|---|---|---|']
    for label, t in timings.items():
        def cell(name):
            return f"{t[name]:.1f} ({t['wall_' + name]:.1f})"
        lines.append(
            f"| {label} | {t['k']} | {cell('single_step_us')} | "
            f"{cell('k_step_one_object_us')}, {t['ratio_step_one_object']:.2f} | "
            f"{cell('k_step_every_object_us')}, {t['ratio_step_every_object']:.2f} | "
            f"{cell('single_correct_us')} | {cell('k_correct_many_us')}, "
            f"{t['ratio_correct_many']:.2f} |")
    return '\n'.join(lines)


def main_objects(args, options: dict) -> int:
    """The --objects K > 1 run of planner_benchmark (its parsed ``args`` and options)."""
    import json
    import sys
    from multiprocessing import get_context

    from tqdm import tqdm

    options = dict(options, objects=args.objects, twins=args.twins,
                   object_score=args.object_score, travel_speed=args.travel_speed,
                   approach_s=args.approach_s)
    load_before = load_average()
    tasks = [(label, name, scene, args.seed, options)
             for label in args.models for name in args.planners for scene in range(args.trials)]
    records: dict = {}
    start = time.perf_counter()
    with tqdm(total=len(tasks), file=sys.stderr, desc='scenes', unit='scene') as bar:
        pool = None if args.jobs == 1 else get_context('fork').Pool(args.jobs)
        outputs = (map(_scene_task, tasks) if pool is None
                   else pool.imap_unordered(_scene_task, tasks))
        for label, name, scene, record in outputs:
            records.setdefault((label, name), []).append(record)
            bar.update()
        if pool is not None:
            pool.close()
            pool.join()
    wall = time.perf_counter() - start
    for recs in records.values():
        recs.sort(key=lambda r: r['scene'])
    summaries = {key: summarise_scenes(recs) for key, recs in records.items()}
    timings = {}
    for label in args.models:
        ms = _setup(label, args.seed, options)[0]
        timings[label] = dict(update_timing(ms, args.objects), k=args.objects)
    print(markdown_tables(summaries, timings))
    twins = ' with eccentric twins' if args.twins else ''
    print(f"\n({len(tasks)} scenes of {args.objects} cubes{twins}"
          f" in {wall:.1f} s wall, seed {args.seed}, stop {args.stop}, target error "
          f"{args.target_error:g}{' with fault margin' if args.fault_margin else ''}, object "
          f"score {args.object_score}, travel {args.travel_speed} m/s + {args.approach_s} s, "
          f"planning budget {args.planning_budget_s} s; load average {load_before} before, "
          f"{load_average()} after)")
    if args.json:
        with open(args.json, 'w') as f:
            json.dump({'config': vars(args),
                       'summaries': [{'models': k[0], 'planner': k[1], **v}
                                     for k, v in summaries.items()],
                       'update_timing': timings,
                       'scenes': [{'models': k[0], 'planner': k[1], **r}
                                  for k, recs in records.items() for r in recs]},
                      f, indent=1, default=str)
    return 0
