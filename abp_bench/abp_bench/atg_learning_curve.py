"""atg_learning_curve: what learning the ATG tables buys, against the experience it needs.

    atg_learning_curve --survey bench_out/survey/survey.json --out bench_out/atg \\
        [--counts 1 2 5 10 20] [--draws 3] [--models robot] [--trials 100] [--seed 0]

For each number n of trials per survey class, `learn_atg`'s learner (`abp_belief.
atg_learning`, default prior and alpha) is trained on n trials of each class (`--draws`
random subsets for n below the survey's count, all trials at the full count), and the
model-sampled planner benchmark (`planner_benchmark --belief-models`) runs with the world's
outcomes drawn from the full survey table (`learn_atg --alpha 0`) and the same seeds for
every point; the hand-written tables are the baseline. Writes `learning_curve.json`,
`learning_curve.png` (identification accuracy and mean actions against n) and
`learned_vs_hand.md` (the full-survey learned table next to the hand-written one).
At the full count the learner sees the very trials the world is drawn from (in-sample).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from abp_belief.cube import TRANSITION_RULES
from abp_bench import planner_benchmark


def _benchmark(models, trials, seed, world, belief=None, planner='abp', tables='paper'):
    """{model-set label: summary} of planner_benchmark with these tables."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / 'bench.json'
        argv = ['--models', *models, '--trials', str(trials), '--planners', planner,
                '--seed', str(seed), '--world-models', str(world), '--json', str(out),
                '--tables', tables]
        if belief:
            argv += ['--belief-models', str(belief)]
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            planner_benchmark.main(argv)
        planner_benchmark._WORKER.clear()
        doc = json.loads(out.read_text())
    return {s['models']: s for s in doc['summaries']}


def run(survey, out_dir, counts=(1, 2, 5, 10, 20), draws=3, models=('robot',), trials=100,
        seed=0, alpha=None, progress=True, tables='paper'):
    from abp_belief import atg_learning, model_file, population
    from abp_belief.modelset import TransitionParams

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = json.loads(Path(survey).read_text())
    full_n = int(doc['settings']['trials'])
    alpha = atg_learning.DEFAULT_ALPHA if alpha is None else alpha
    params = TransitionParams(rules=tables)   # the hand-written table: baseline and prior
    base = population.robot_set(seed=0, transition_params=params)  # tables per mass variant
    world_path = out / 'survey_table.npz'
    empirical = atg_learning.learn(atg_learning.experience_from_survey(doc), alpha=0.0)
    model_file.save(atg_learning.with_tables(base, empirical), world_path)
    t0 = time.perf_counter()
    hand = _benchmark(models, trials, seed, world_path, tables=tables)
    prior_path = out / 'prior_only.npz'      # the learner with no experience: its prior mean
    no_data = atg_learning.Experience(*([np.zeros(0, dtype=int)] * 4), np.zeros(0))
    model_file.save(atg_learning.with_tables(
        base, atg_learning.learn(no_data, alpha=alpha, params=params)), prior_path)
    prior_only = _benchmark(models, trials, seed, world_path, belief=prior_path)
    points = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in counts:
            n_draws = 1 if n >= full_n else draws
            for d in range(n_draws):
                t1 = time.perf_counter()
                exp = atg_learning.experience_from_survey(
                    doc, trials_per_class=n, subsample_seed=None if n >= full_n else 1000 + d)
                learned = atg_learning.learn(exp, alpha=alpha, params=params)
                learn_s = time.perf_counter() - t1
                path = Path(tmp) / f'learned_n{n}_d{d}.npz'
                model_file.save(atg_learning.with_tables(base, learned), path)
                if n >= full_n:
                    with open(out / 'learned_vs_hand.md', 'w') as stream:
                        stream.write(atg_learning.comparison_markdown(
                            learned, atg_learning.hand_table(params)))
                tv = atg_learning.total_variation(learned.probs, empirical.probs)
                res = _benchmark(models, trials, seed, world_path, belief=path)
                for label, s in res.items():
                    points.append(dict(models=label, n=n, draw=d, accuracy=s['accuracy'],
                                       actions_mean=s['actions_mean'],
                                       identified=s['identified'], learn_s=learn_s,
                                       tv_to_survey_mean=float(tv.mean())))
                if progress:
                    print(f'n={n} draw {d}: ' + ', '.join(
                        f"{k} acc {100 * v['accuracy']:.0f}% act {v['actions_mean']:.2f}"
                        for k, v in res.items()), file=sys.stderr, flush=True)
    result = dict(survey=str(survey), survey_trials=full_n, counts=list(counts), draws=draws,
                  alpha=alpha, trials=trials, seed=seed, models=list(models), tables=tables,
                  hand={k: dict(accuracy=v['accuracy'], actions_mean=v['actions_mean'])
                        for k, v in hand.items()},
                  prior_only={k: dict(accuracy=v['accuracy'], actions_mean=v['actions_mean'])
                              for k, v in prior_only.items()},
                  points=points, wall_s=time.perf_counter() - t0)
    (out / 'learning_curve.json').write_text(json.dumps(result, indent=1))
    plot(result, out / 'learning_curve.png')
    return result


def plot(result, path):
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for label in result['models']:
        pts = [p for p in result['points'] if p['models'] == label]
        ns = sorted({p['n'] for p in pts})
        for ax, key, scale in ((axes[0], 'accuracy', 100), (axes[1], 'actions_mean', 1)):
            xs = [p['n'] for p in pts]
            ys = [scale * p[key] for p in pts]
            mean = [scale * np.mean([p[key] for p in pts if p['n'] == n]) for n in ns]
            (line,) = ax.plot(ns, mean, marker='o', label=f'learned, |M| = {label}')
            ax.scatter(xs, ys, s=12, color=line.get_color(), alpha=0.4)
            ax.axhline(scale * result['hand'][label][key], color=line.get_color(), ls='--',
                       lw=1, label=f'hand-written, |M| = {label}')
            ax.axhline(scale * result['prior_only'][label][key], color=line.get_color(),
                       ls=':', lw=1, label=f'prior only (no data), |M| = {label}')
    for ax, title in zip(axes, ('identification accuracy (%)', 'mean actions to the stop')):
        ax.set_xscale('log')
        ax.set_xticks(result['counts'])
        ax.set_xticklabels([str(c) for c in result['counts']])
        ax.set_xlabel('survey trials per class used for learning')
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc='lower right')
    fig.suptitle(f"Learned ATGs: model-sampled benchmark ({result['trials']} trials per point, "
                 f"world drawn from the full MuJoCo survey table; dots: subsample draws)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='atg_learning_curve', description=__doc__.split('\n\n')[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--survey', default='bench_out/survey/survey.json')
    p.add_argument('--out', default='bench_out/atg')
    p.add_argument('--counts', type=int, nargs='+', default=[1, 2, 5, 10, 20])
    p.add_argument('--draws', type=int, default=3, help='random subsets per count below full')
    p.add_argument('--models', nargs='+', default=['robot'],
                   choices=planner_benchmark.MODEL_SET_CHOICES)
    p.add_argument('--trials', type=int, default=100, help='benchmark trials per point')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--alpha', type=float, default=None)
    p.add_argument('--tables', choices=TRANSITION_RULES, default='paper',
                   help="the hand-written table (docs/MODEL.md): the baseline and the "
                   "learner's prior mean (default paper, as planner_benchmark)")
    args = p.parse_args(argv)
    if min(args.counts) < 1 or args.draws < 1 or args.trials < 1:
        p.error('--counts, --draws and --trials must be >= 1')
    result = run(args.survey, args.out, args.counts, args.draws, args.models, args.trials,
                 args.seed, args.alpha, tables=args.tables)
    for label in result['models']:
        hand = result['hand'][label]
        prior = result['prior_only'][label]
        print(f"|M| = {label}: hand-written {100 * hand['accuracy']:.1f}% "
              f"{hand['actions_mean']:.2f} actions; prior only {100 * prior['accuracy']:.1f}% "
              f"{prior['actions_mean']:.2f} actions")
        for n in result['counts']:
            pts = [q for q in result['points'] if q['models'] == label and q['n'] == n]
            print(f"  n = {n:3d}: learned {100 * np.mean([q['accuracy'] for q in pts]):.1f}% "
                  f"{np.mean([q['actions_mean'] for q in pts]):.2f} actions "
                  f'({len(pts)} draws)')
    print(f"wrote {args.out}/learning_curve.{{json,png}} in {result['wall_s']:.0f} s")
    return 0


if __name__ == '__main__':
    sys.exit(main())
