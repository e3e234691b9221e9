"""Planner benchmark: the paper's simulation (Tables II and IV, Fig. 3).

    ros2 run abp_bench planner_benchmark --models 30 60 120 --trials 30 \\
        --planners random abp --seed 0 --json out.json --plot docs/img/fig3.png

Prints a Markdown table laid out like Table II (plus accuracy, Table IV, and
the per-decision planning latency) with the published figures side by side.

Model error (issue 13): ``--world-models FILE`` draws the true object's outcomes from
FILE's transition tables (e.g. the MuJoCo survey's, `learn_atg --alpha 0`), while the
belief and the planner use ``--belief-models FILE`` (e.g. a learned set) or, by default,
the hand-written tables. Only the tables are taken from the files (they are per mass
variant, docs/MODEL.md); the models (|M|, seed) and the observation model stay those of
``--models``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from multiprocessing import get_context

import numpy as np
from tqdm import tqdm

from abp_belief.cube import ACTIONS, TRANSITION_RULES
from abp_bench import multi_object_benchmark
from abp_bench.model_sets import (
    MODEL_SET_CHOICES,
    OBJECT_FAMILIES,
    build_model_set,
    object_families,
    with_model_tables,
)
from abp_planner.planner import PLANNER_NAMES, make_planner
from abp_planner.simulator import MAX_ACTIONS, STOP_POSTERIOR, run_trial, trial_rngs
from abp_planner.stopping import (
    DEFAULT_TARGET_ERROR,
    STOP_RULES,
    StoppingRule,
    fault_discounted_error,
    fault_likelihood_ratio,
)

# Published figures: Table II (object belief, entropy, actions, time) and
# Table IV (simulated accuracy), both with alpha = 0.1.
PAPER = {
    ('30', 'random'): ('0.89 ± 0.24', '0.29 ± 0.49', 14.2, 531.3, 90.00),
    ('30', 'abp'): ('1.00 ± 0.00', '0.00 ± 0.00', 4.5, 173.8, 100.00),
    ('60', 'random'): ('0.94 ± 0.16', '0.17 ± 0.22', 20.2, 756.5, 96.67),
    ('60', 'abp'): ('1.00 ± 0.00', '0.00 ± 0.00', 5.1, 205.4, 100.00),
    ('120', 'random'): ('0.93 ± 0.16', '0.25 ± 0.48', 18.8, 686.1, 96.67),
    ('120', 'abp'): ('1.00 ± 0.00', '0.00 ± 0.00', 5.9, 264.4, 100.00),
}

# One worker process keeps its model sets and belief filters between tasks.
_WORKER: dict = {}


def _worker_trial(task):
    label, planner_name, trial, seed, options = task
    from abp_belief.filter import BeliefFilter

    tables = options.get('tables', 'paper')
    key = (label, seed, tables, options.get('belief_models'), options.get('world_models'))
    if key not in _WORKER:
        ms = with_model_tables(build_model_set(label, seed, tables),
                               options.get('belief_models'))
        # The world: the same models and observation model, its own transition tables.
        world = with_model_tables(ms, options.get('world_models'))
        _WORKER[key] = (ms, BeliefFilter(ms), {}, world, np.array(object_families(ms)))
    ms, bf, rules, world, families = _WORKER[key]
    rule_key = (options.get('stop', 'error'), options.get('target_error', DEFAULT_TARGET_ERROR),
                options.get('stop_posterior', STOP_POSTERIOR),
                options.get('max_actions', MAX_ACTIONS), options.get('fault_margin', False))
    if rule_key not in rules:
        # Twin classes are computed once per model set and worker (1.4 s at 1470).
        rules[rule_key] = StoppingRule.for_model_set(
            ms, kind=rule_key[0], target_error=rule_key[1], stop_posterior=rule_key[2],
            max_actions=rule_key[3], fault_margin=rule_key[4])
    stopping = rules[rule_key]
    truth_rng, noise_rng = trial_rngs(seed, trial)
    # The random planner's own stream is per trial too, so results do not
    # depend on how trials are spread over workers.
    planner = make_planner(planner_name, ms, seed=seed * 1_000_003 + trial, **options)
    refused = frozenset(options.get('refuse') or ())
    family = options.get('family')
    true_models = np.flatnonzero(families == family) if family else None
    result = run_trial(
        world,  # outcomes and observations of the true object; planner and filter use ms
        planner,
        truth_rng,
        noise_rng,
        belief_filter=bf,
        stopping=stopping,
        feasible=(lambda action: action not in refused) if refused else None,
        true_models=true_models,
    )
    return label, planner_name, trial, result.as_dict()


def summarise(trials: list[dict]) -> dict:
    bel = np.array([t['final_true_posterior'] for t in trials])
    ent = np.maximum([t['final_entropy'] for t in trials], 0.0)  # -0.0 round-off
    acts = np.array([t['num_actions'] for t in trials], dtype=float)
    time_s = np.array([t['time_s'] for t in trials])
    correct = np.array([t['correct'] for t in trials])
    decidable = np.array([t['decidable'] for t in trials])
    lat = np.concatenate([t['latency_ms'] for t in trials] + [np.zeros(0)])
    depth = np.concatenate([t.get('search_depth', []) for t in trials] + [np.zeros(0)])
    return {
        'trials': len(trials),
        'obj_bel_mean': float(bel.mean()),
        'obj_bel_std': float(bel.std()),
        'entropy_mean': float(ent.mean()),
        'entropy_std': float(ent.std()),
        'actions_mean': float(acts.mean()),
        'time_mean_s': float(time_s.mean()),
        'accuracy': float(correct.mean()),
        'identified': float(np.mean([t['identified'] for t in trials])),
        'decidable_trials': int(decidable.sum()),
        'accuracy_decidable': float(correct[decidable].mean()) if decidable.any() else float('nan'),
        'identified_decidable': float(np.mean([t['identified'] for t in trials if t['decidable']]))
        if decidable.any()
        else float('nan'),
        'decisions': int(lat.size),
        'latency_ms_median': float(np.median(lat)) if lat.size else float('nan'),
        'latency_ms_p95': float(np.percentile(lat, 95)) if lat.size else float('nan'),
        'latency_ms_max': float(lat.max()) if lat.size else float('nan'),
        'errors': int((~correct).sum()),
        'errors_decidable': int((~correct & decidable).sum()),
        'search_depth_mean': float(depth.mean()) if depth.size else float('nan'),
        'stopped_as_twins': int(sum(t.get('stop_reason', '').startswith('indistinguishable')
                                    for t in trials)),
    }


def markdown_table(summaries: dict, labels, planners) -> str:
    head = (
        '| \\|M\\| | Method | Trials | Obj. Bel. | Entropy | Actions | Time (s) | Accuracy '
        '| Paper Obj. Bel. | Paper Entropy | Paper Actions | Paper Time (s) | Paper Acc. '
        '| Decidable: trials, accuracy, identified | Plan ms median | p95 | max '
        '| Errors (decidable) | Depth |'
    )
    lines = [head, '|' + '---|' * 19]
    for label in labels:
        for name in planners:
            s = summaries.get((label, name))
            if s is None:
                continue
            paper = PAPER.get((label, name))
            paper_cells = (
                [paper[0], paper[1], f'{paper[2]:.1f}', f'{paper[3]:.1f}', f'{paper[4]:.2f}%']
                if paper
                else ['–'] * 5
            )
            cells = [
                label,
                name,
                str(s['trials']),
                f"{s['obj_bel_mean']:.2f} ± {s['obj_bel_std']:.2f}",
                f"{s['entropy_mean']:.2f} ± {s['entropy_std']:.2f}",
                f"{s['actions_mean']:.1f}",
                f"{s['time_mean_s']:.1f}",
                f"{100 * s['accuracy']:.2f}%",
                *paper_cells,
                f"{s['decidable_trials']}, {100 * s['accuracy_decidable']:.1f}%, "
                f"{100 * s['identified_decidable']:.1f}%",
                f"{s['latency_ms_median']:.2f}",
                f"{s['latency_ms_p95']:.2f}",
                f"{s['latency_ms_max']:.2f}",
                f"{s['errors']} ({s['errors_decidable']})",
                f"{s['search_depth_mean']:.2f}",
            ]
            lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def family_table(results: dict, labels, planners, seed: int) -> str | None:
    """Accuracy and mean actions per object family (`object_families`), for the model sets
    that have mass twins; None when none has."""
    lines = ['| \\|M\\| | Method | family | trials | accuracy | mean actions |',
             '|---|---|---|---:|---:|---:|']
    for label in labels:
        families = object_families(build_model_set(label, seed))
        if set(families) == {'visual only'}:
            continue
        for name in planners:
            trials = results.get((label, name), [])
            for family in OBJECT_FAMILIES:
                sel = [t for t in trials if families[t['true_model']] == family]
                if sel:
                    accuracy = 100.0 * sum(bool(t['correct']) for t in sel) / len(sel)
                    actions = float(np.mean([t['num_actions'] for t in sel]))
                    lines.append(f'| {label} | {name} | {family} | {len(sel)} | '
                                 f'{accuracy:.1f}% | {actions:.2f} |')
    return '\n'.join(lines) if len(lines) > 2 else None


def plot_traces(results: dict, labels, planners, path: str, max_actions: int) -> None:
    """Correct-object belief vs action step (mean and a ±1 std band), like Fig. 3.
    A trial that stopped early keeps its last belief for the remaining steps."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(labels), figsize=(4.2 * len(labels), 3.4), squeeze=False)
    steps = np.arange(max_actions + 1)
    for ax, label in zip(axes[0], labels):
        for name in planners:
            trials = results.get((label, name))
            if not trials:
                continue
            traces = np.array(
                [
                    np.pad(t['true_posterior'], (0, max_actions + 1 - len(t['true_posterior'])),
                           mode='edge')
                    for t in trials
                ]
            )
            mean, std = traces.mean(axis=0), traces.std(axis=0)
            (line,) = ax.plot(steps, mean, label=name)
            ax.fill_between(steps, np.clip(mean - std, 0, 1), np.clip(mean + std, 0, 1),
                            color=line.get_color(), alpha=0.2)
        ax.set_title(f'|M| = {label}')
        ax.set_xlabel('action step')
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel('belief in the correct object')
    axes[0][-1].legend(loc='lower right')
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# Rules replayed by --stop-curve: thresholds on the top posterior (the old rule's
# family) and target errors of the fault-discounted rule (stopping.py).
CURVE_POSTERIOR_THRESHOLDS = (0.9, 0.95, 0.99, 0.999, 0.9999, 0.99999, 0.999999)
CURVE_TARGET_ERRORS = (0.3, 0.1, 0.03, 0.01, 0.003, 0.001, 0.0003)


def replay_stop(trial: dict, stop_step) -> tuple[int, bool]:
    """(actions, correct) if ``stop_step(top_posterior, answer_posterior)`` (per-step
    arrays) had stopped the trial: its first True step, else the last one."""
    top = np.asarray(trial['top_posterior'])
    answer = np.asarray(trial['answer_posterior'])
    hits = np.flatnonzero(stop_step(top, answer))
    step = int(hits[0]) if hits.size else len(top) - 1
    return step, bool(trial['top_is_true'][step])


def stop_curves(trials: list[dict], fault_ratio: float) -> dict:
    """Error rate (on decidable trials) and mean actions (on all) of every replayed
    rule on trials that ran all their actions (the ``fixed`` rule): the planner
    does not see the stopping rule, so truncating one long trajectory is exactly
    what each rule would do. The error rules also stop on the twin class
    (``answer_posterior``), as ``StoppingRule`` does."""
    rules = {
        'posterior > t (old rule)': [
            (t, lambda top, ans, t=t: top > t) for t in CURVE_POSTERIOR_THRESHOLDS
        ],
        'error rule + fault margin: e_fault <= e': [
            (e, lambda top, ans, e=e: (fault_discounted_error(top, fault_ratio) <= e)
             | (fault_discounted_error(ans, fault_ratio) <= e))
            for e in CURVE_TARGET_ERRORS
        ],
        'error rule: 1 - posterior <= e': [
            (e, lambda top, ans, e=e: (1.0 - top <= e) | (1.0 - ans <= e))
            for e in CURVE_TARGET_ERRORS
        ],
    }
    decidable = np.array([t['decidable'] for t in trials])
    curves = {}
    for family, members in rules.items():
        points = []
        for parameter, rule in members:
            outcomes = [replay_stop(t, rule) for t in trials]
            actions = np.array([o[0] for o in outcomes], dtype=float)
            errors = np.array([not o[1] for o in outcomes]) & decidable
            points.append({'parameter': parameter, 'actions_mean': float(actions.mean()),
                           'error_rate': float(errors.sum() / max(decidable.sum(), 1)),
                           'errors': int(errors.sum()), 'decidable': int(decidable.sum())})
        curves[family] = points
    return curves


def plot_stop_curves(all_curves: dict, path: str, trials: int) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    keys = list(all_curves)
    fig, axes = plt.subplots(1, len(keys), figsize=(4.4 * len(keys), 4.0), squeeze=False,
                             sharey=True)
    floor = 0.5 / trials  # zero errors drawn half a trial below one error
    for ax, key in zip(axes[0], keys):
        for (family, points), marker in zip(all_curves[key].items(), 'osx^'):
            x = [p['actions_mean'] for p in points]
            y = [max(p['error_rate'], floor) for p in points]
            ax.plot(x, y, marker=marker, label=family, alpha=0.8)
            if family.startswith('posterior'):  # label the old rule's thresholds
                for p, xi, yi in zip(points, x, y):
                    ax.annotate(f"{p['parameter']:g}", (xi, yi), fontsize=6,
                                textcoords='offset points', xytext=(2, 5))
        ax.set_yscale('log')
        ax.set_ylim(floor / 1.6, 0.2)
        ax.axhline(0.003, color='grey', lw=0.8, ls='--')
        ax.axhline(floor, color='grey', lw=0.5, ls=':')
        decidable = next(iter(all_curves[key].values()))[0].get('decidable', trials)
        ax.set_title(f'|M| = {key[0]}, {key[1]} ({decidable} decidable)', fontsize=9)
        ax.set_xlabel('mean actions to the stop')
        ax.grid(alpha=0.3, which='both')
    axes[0][0].set_ylabel('error rate on decidable trials\n(dotted: no error; dashed: 0.3 %)')
    axes[0][-1].legend(loc='upper right', fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_args(argv):
    p = argparse.ArgumentParser(
        prog='planner_benchmark',
        description='Model-sampled simulation of the Active Belief Planner (paper Tables II/IV).',
    )
    p.add_argument('--models', nargs='+', default=['30', '60', '120'], choices=MODEL_SET_CHOICES,
                   help='model sets: random visual subsets of 30/60/120, the full 1470 set, '
                   'the robot set')
    p.add_argument('--trials', type=int, default=30, help='trials per model set and planner')
    p.add_argument('--planners', nargs='+', default=None, choices=PLANNER_NAMES,
                   help='default: random abp; with --objects K > 1: cost')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--alpha', type=float, default=0.1, help='Alg. 3 expansion threshold')
    p.add_argument('--max-actions', type=int, default=MAX_ACTIONS)
    p.add_argument('--stop', choices=STOP_RULES, default='error',
                   help="stopping rule (abp_planner.stopping): 'error' = fault-discounted "
                   "P(wrong) <= --target-error (default), 'posterior' = top posterior > "
                   "--stop-posterior (the old rule), 'fixed' = all --max-actions actions")
    p.add_argument('--target-error', type=float, default=DEFAULT_TARGET_ERROR,
                   help='target error of --stop error')
    p.add_argument('--fault-margin', action='store_true',
                   help='--stop error: discount P(wrong) for one unexpected false tag')
    p.add_argument('--stop-posterior', type=float, default=STOP_POSTERIOR)
    p.add_argument('--no-early-stop', action='store_true',
                   help="same as --stop fixed: run all --max-actions actions (paper: "
                   "'simulated for 30 actions'); actions and time count up to the first time "
                   "the true object's posterior exceeds --stop-posterior, belief/entropy/"
                   "accuracy are taken at the end")
    p.add_argument('--planning-budget-s', type=float, default=None,
                   help='planning-time budget per decision for abp2/abp3/cost (anytime '
                   'iterative deepening); default unbounded')
    p.add_argument('--stop-curve',
                   help='with --stop fixed: replay stopping rules on the full trajectories and '
                   'write error rate vs mean actions (PNG) here')
    p.add_argument('--tie-tolerance', type=float, default=None,
                   help="expected gains closer than this (bits) are ties, resolved towards the "
                   "shorter action (default: the planner's, 1e-3)")
    p.add_argument('--tables', choices=TRANSITION_RULES, default='paper',
                   help="hand-written ATG table of the generated sets (docs/MODEL.md): paper "
                   "(default: the paper's protocol) or corrected (the nodes' default)")
    p.add_argument('--world-models', metavar='FILE',
                   help="draw the true object's outcomes from this model file's transition "
                   'tables (e.g. learn_atg --alpha 0 from the MuJoCo survey); default: the '
                   "belief's own tables")
    p.add_argument('--belief-models', metavar='FILE',
                   help='transition tables of the belief and the planner (e.g. a learn_atg '
                   'file); default: the hand-written ones of --tables')
    p.add_argument('--refuse', nargs='+', default=[], choices=ACTIONS, metavar='ACTION',
                   help='actions the feasibility check refuses at every decision (as when '
                   'IK fails or a grasp keeps slipping), e.g. --refuse LIFT FLIP')
    p.add_argument('--family', choices=OBJECT_FAMILIES,
                   help='draw the true object only from this object family (the "By object '
                   'family" table), e.g. "twin family, uniform" to measure the uniform cubes '
                   'that have mass twins with many trials; the set must have that family')
    multi_object_benchmark.add_arguments(p)
    p.add_argument('--jobs', type=int, default=1, help='worker processes')
    p.add_argument('--json', help='write summaries and every trial here')
    p.add_argument('--plot', help='write the Fig. 3-style belief plot (PNG) here')
    args = p.parse_args(argv)
    if args.planners is None:
        args.planners = ['random', 'abp'] if args.objects == 1 else ['cost']
    multi_object_benchmark.check_arguments(p, args)
    if args.trials < 1:
        p.error('--trials must be >= 1')
    if not 0.0 <= args.alpha <= 1.0:
        p.error('--alpha must be in [0, 1]')
    if args.jobs < 1:
        p.error('--jobs must be >= 1')
    if args.no_early_stop:
        args.stop = 'fixed'
    if args.stop_curve and args.stop != 'fixed':
        p.error('--stop-curve needs --stop fixed (trajectories of all --max-actions actions)')
    if args.planning_budget_s is not None and not args.planning_budget_s > 0:
        p.error('--planning-budget-s must be > 0')
    if args.family:
        for label in args.models:
            if args.family not in object_families(build_model_set(label, args.seed, args.tables)):
                p.error(f'--family {args.family!r}: model set {label} has no such object')
    for path in (args.world_models, args.belief_models):
        if path:
            from abp_belief import model_file
            try:
                model_file.load(path)  # fail here, not in a worker
            except model_file.ModelFileError as exc:
                p.error(str(exc))
    return args


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    options = {
        'alpha': args.alpha,
        'max_actions': args.max_actions,
        'stop_posterior': args.stop_posterior,
        'stop': args.stop,
        'target_error': args.target_error,
        'fault_margin': args.fault_margin,
        'tie_tolerance': args.tie_tolerance,
        'planning_budget_s': args.planning_budget_s,
        'tables': args.tables,
        'belief_models': args.belief_models,
        'world_models': args.world_models,
        'refuse': tuple(args.refuse),
        'family': args.family,
    }
    if args.objects > 1:
        return multi_object_benchmark.main_objects(args, options)
    tasks = [
        (label, name, trial, args.seed, options)
        for label in args.models
        for name in args.planners
        for trial in range(args.trials)
    ]
    results: dict = {}
    start = time.perf_counter()
    with tqdm(total=len(tasks), file=sys.stderr, desc='trials', unit='trial') as bar:
        if args.jobs == 1:
            outputs = (_worker_trial(t) for t in tasks)
            pool = None
        else:
            pool = get_context('fork').Pool(args.jobs)
            outputs = pool.imap_unordered(_worker_trial, tasks)
        for label, name, trial, record in outputs:
            record['trial'] = trial
            results.setdefault((label, name), []).append(record)
            bar.set_postfix_str(f'|M|={label} {name}')
            bar.update()
        if pool is not None:
            pool.close()
            pool.join()
    for trials in results.values():
        trials.sort(key=lambda t: t['trial'])
    summaries = {key: summarise(trials) for key, trials in results.items()}
    print(markdown_table(summaries, args.models, args.planners))
    print(f"\n({len(tasks)} trials in {time.perf_counter() - start:.1f} s wall, seed {args.seed}, "
          f"alpha {args.alpha}, stop {args.stop}, target error {args.target_error:g}"
          f"{' with fault margin' if args.fault_margin else ''}, "
          f"planning budget {args.planning_budget_s} s"
          f"{'; refused ' + ' '.join(args.refuse) if args.refuse else ''}"
          f"{'; true objects: ' + args.family + ' only' if args.family else ''}; tables: belief "
          f"{args.belief_models or 'hand-written ' + args.tables}, world "
          f"{args.world_models or 'same'})")
    by_family = family_table(results, args.models, args.planners, args.seed)
    if by_family:
        print('\nBy object family (mass twins share their faces):\n')
        print(by_family)
    curves = {}
    if args.stop_curve:
        ratio = fault_likelihood_ratio()
        curves = {key: stop_curves(trials, ratio) for key, trials in results.items()}
        for key, families in curves.items():
            for family, points in families.items():
                cells = ', '.join(f"{q['parameter']:g}: {q['actions_mean']:.2f} act, "
                                  f"{q['errors']} err" for q in points)
                print(f'|M|={key[0]} {key[1]} {family}: {cells}')
        plot_stop_curves(curves, args.stop_curve, args.trials)
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(
                {
                    'config': vars(args),
                    'summaries': [
                        {'models': k[0], 'planner': k[1], **v} for k, v in summaries.items()
                    ],
                    'stop_curves': [
                        {'models': k[0], 'planner': k[1], 'curves': v} for k, v in curves.items()
                    ],
                    'trials': [
                        {'models': k[0], 'planner': k[1], **t}
                        for k, ts in results.items()
                        for t in ts
                    ],
                },
                f,
                indent=1,
            )
    if args.plot:
        plot_traces(results, args.models, args.planners, args.plot, args.max_actions)
    return 0


if __name__ == '__main__':
    sys.exit(main())
