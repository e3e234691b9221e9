"""Draw the plots of docs/RESULTS.md from the figures recorded there (no new measurement).

    python docs/img/make_results_plots.py [--out docs/img]

Every number below is copied from docs/RESULTS.md, which names the command, the commit and
the machine load of each; change them there and here together.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after the backend is chosen)
import matplotlib.ticker  # noqa: E402

SIZES = ('30', '60', '120')

# Table II protocol (docs/RESULTS.md "Table II"): mean actions to recognition,
# planner_benchmark --seed 0 --trials 30 --stop posterior.
TABLE_II_ACTIONS = {
    'random, paper': (14.2, 20.2, 18.8),
    'random, ours': (6.3, 9.1, 13.5),
    'ABP, paper': (4.5, 5.1, 5.9),
    'abp, ours': (2.2, 3.2, 4.2),
    'cost, ours': (2.4, 3.4, 4.1),
}

# Default stop and planner (docs/RESULTS.md "Table II"): cost, 0.1 s budget, P(wrong) <= 0.003,
# mean actions over seeds 0 / 1 / 2, 300 trials each.
DEFAULT_COST_ACTIONS = {'30': (3.78, 3.95, 3.68), '60': (4.68, 4.79, 4.40),
                        '120': (5.69, 5.72, 5.40)}

# Planning time at |M| = 1470, 0.1 s budget (docs/RESULTS.md "Planning time"): ms.
PLANNING_MS_1470 = {  # planner: (median, p95, max)
    'abp': (5.06, 14.6, 24.0),
    'abp2': (14.25, 70.1, 102.8),
    'abp3': (45.67, 100.1, 101.8),
    'cost': (14.71, 65.2, 101.1),
}

# Tag recall within 1.5 m per condition (docs/RESULTS.md "Perception"): ours, OpenCV (%).
RECALL_1_5M = {
    'plain': (100.0, 98.3), 'textured': (100.0, 97.1), 'clutter': (99.5, 94.5),
    'gradient': (98.8, 86.8), 'motion blur': (89.3, 53.0), 'JPEG 30-60': (99.0, 73.6),
    'occlusion': (97.0, 91.9), 'all at once': (91.7, 66.9), 'every condition': (97.1, 82.3),
}

# Cancel to last joint motion, 9 runs, s of sim time (docs/RESULTS.md "Cancel").
CANCEL_HOLD_S = (0.02, 0.04, 0.06, 0.06, 0.06, 0.08, 0.08, 0.14, 0.34)


def table_ii(out):
    fig, (left, right) = plt.subplots(1, 2, figsize=(7.5, 3.0), width_ratios=(3, 2))
    width = 0.16
    colours = ('#bbbbbb', '#666666', '#9ecae1', '#3182bd', '#e6550d')
    for k, (name, values) in enumerate(TABLE_II_ACTIONS.items()):
        xs = [i + (k - 2) * width for i in range(len(SIZES))]
        left.bar(xs, values, width, label=name, color=colours[k])
    left.set_xticks(range(len(SIZES)), [f'|M| = {s}' for s in SIZES])
    left.set_ylabel('mean actions to recognition')
    left.set_title('Paper protocol (stop at posterior 0.95)', fontsize=9)
    left.legend(fontsize=7, ncol=2)
    paper = TABLE_II_ACTIONS['ABP, paper']
    for i, s in enumerate(SIZES):
        runs = DEFAULT_COST_ACTIONS[s]
        right.plot([i] * len(runs), runs, 'o', color='#e6550d', ms=4,
                   label='cost, 3 seeds' if i == 0 else None)
        right.plot([i - 0.25, i + 0.25], [paper[i]] * 2, color='#9ecae1', lw=2,
                   label='ABP, paper' if i == 0 else None)
    right.set_xticks(range(len(SIZES)), SIZES)
    right.set_xlabel('|M|')
    right.set_ylim(0, 7)
    right.set_title('Default: P(wrong) <= 0.003, 100 % right', fontsize=9)
    right.legend(fontsize=7, loc='lower right')
    fig.tight_layout()
    fig.savefig(out / 'results_table2_actions.png', dpi=90)
    plt.close(fig)


def planning_time(out):
    fig, ax = plt.subplots(figsize=(5.0, 2.8))
    names = list(PLANNING_MS_1470)
    for k, (label, marker) in enumerate((('median', 'o'), ('p95', 's'), ('max', '^'))):
        ax.plot(names, [PLANNING_MS_1470[n][k] for n in names], marker, label=label, ms=6)
    ax.axhline(100, color='grey', ls='--', lw=1)
    ax.text(1.5, 125, 'budget 0.1 s', fontsize=7, color='grey', ha='center')
    ax.set_yscale('log')
    ax.set_ylim(3, 300)
    ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set_ylabel('ms per decision')
    ax.set_title('Planning time at |M| = 1470 (100 trials)', fontsize=9)
    ax.legend(fontsize=7, loc='lower right')
    fig.tight_layout()
    fig.savefig(out / 'results_planning_time_1470.png', dpi=90)
    plt.close(fig)


def perception_recall(out):
    fig, ax = plt.subplots(figsize=(7.0, 2.8))
    names = list(RECALL_1_5M)
    xs = range(len(names))
    ax.bar([x - 0.2 for x in xs], [RECALL_1_5M[n][0] for n in names], 0.4, label='abp',
           color='#3182bd')
    ax.bar([x + 0.2 for x in xs], [RECALL_1_5M[n][1] for n in names], 0.4,
           label='plain OpenCV ArUco', color='#bbbbbb')
    ax.axhline(97, color='grey', ls='--', lw=1, label='goal 97 %')
    ax.set_xticks(list(xs), names, rotation=25, ha='right', fontsize=8)
    ax.set_ylim(40, 101)
    ax.set_ylabel('tag recall within 1.5 m (%)')
    ax.legend(fontsize=7, ncol=3, loc='lower center', bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.tight_layout()
    fig.savefig(out / 'results_perception_recall.png', dpi=90)
    plt.close(fig)


def cancel_hold(out):
    fig, ax = plt.subplots(figsize=(5.0, 1.6))
    # Equal times stack upwards so that each run shows.
    heights = [CANCEL_HOLD_S[:i].count(t) for i, t in enumerate(CANCEL_HOLD_S)]
    ax.plot(CANCEL_HOLD_S, heights, 'o', color='#3182bd')
    ax.set_ylim(-0.7, 3)
    ax.axvline(0.3, color='grey', ls='--', lw=1)
    ax.text(0.305, 2.2, 'goal 0.3 s', fontsize=7, color='grey')
    ax.set_yticks([])
    ax.set_xlim(0, 0.4)
    ax.set_xlabel('cancel request -> last joint motion (s of sim time), 9 runs')
    fig.tight_layout()
    fig.savefig(out / 'results_cancel_hold.png', dpi=90)
    plt.close(fig)


PLOTS = (table_ii, planning_time, perception_recall, cancel_hold)
FILES = ('results_table2_actions.png', 'results_planning_time_1470.png',
         'results_perception_recall.png', 'results_cancel_hold.png')


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path(__file__).resolve().parent,
                        help="folder for the PNG files (default: this script's folder)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for plot in PLOTS:
        plot(args.out)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
