"""`ros2 run abp_belief models`: build, save, load and summarise ARcube model sets.

Examples:
  models --set full --tags 7                 # 1470 models, readable summary
  models --set random --size 60 --seed 2 --out m60.npz
  models --load m60.npz --json
  models --set robot --tables paper --out robot_paper.npz
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter

import numpy as np

from . import model_file, population
from .cube import MAX_TAGS, MIN_TAGS, TRANSITION_RULES
from .modelset import TransitionParams

SETS = ('full', 'random', 'robot', 'visual')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='models', description='Build or inspect ARcube model sets (Aspect Transition '
        'Graphs) and print a summary.',
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument('--tags', type=int, default=7, metavar='N',
                        help=f'size of the tag set ({MIN_TAGS}..{MAX_TAGS}, default 7)')
    parser.add_argument('--set', choices=SETS, default=None, dest='which',
                        help="full: every visual cube x 7 masses; visual: every visual cube, "
                             "uniform; random: --size random visual cubes, uniform; robot: the "
                             "paper's 30-model uBot-6 set (default full)")
    parser.add_argument('--size', type=int, default=None, metavar='M',
                        help='number of visual cubes for --set random (default 30)')
    parser.add_argument('--seed', type=int, default=0, metavar='S',
                        help='random seed for --set random/robot (default 0)')
    parser.add_argument('--tables', choices=TRANSITION_RULES, default='corrected',
                        help="hand-written ATG table (docs/MODEL.md): corrected (the nodes' "
                             "default) or paper (the paper's, as the planner benchmark uses)")
    parser.add_argument('--out', metavar='FILE', help='save the model set to FILE (.npz)')
    parser.add_argument('--load', metavar='FILE', help='load a model set from FILE instead')
    parser.add_argument('--json', action='store_true', help='print a compact JSON summary')
    return parser


def summarize(model_set, description: str) -> dict:
    per_aspect = model_set.models_per_aspect()
    histogram = Counter(per_aspect.tolist())
    return {
        'set': description,
        'n_tags': model_set.n_tags,
        'models': model_set.num_models,
        'visual_cubes': model_set.num_visual_cubes,
        'eccentric_models': int(np.count_nonzero(model_set.mass)),
        'aspect_nodes': model_set.num_nodes,
        'distinct_aspects': model_set.num_aspects,
        # For each aspect: number of models showing it in >= 1 state, i.e. how many
        # models a single first observation of it leaves possible.
        'models_per_aspect': {'min': int(per_aspect.min()), 'max': int(per_aspect.max()),
                              'mean': round(float(per_aspect.mean()), 3)},
        'models_per_aspect_histogram': {str(k): histogram[k] for k in sorted(histogram)},
        'transition_nnz': {name: int(t.nnz) for name, t in model_set.transitions.items()},
    }


def _print_readable(summary: dict, out):
    print(f"model set        : {summary['set']}", file=out)
    print(f"tags             : {summary['n_tags']}", file=out)
    print(f"models           : {summary['models']} "
          f"({summary['eccentric_models']} eccentric)", file=out)
    print(f"visual cubes     : {summary['visual_cubes']}", file=out)
    print(f"aspect nodes     : {summary['aspect_nodes']}", file=out)
    print(f"distinct aspects : {summary['distinct_aspects']}", file=out)
    mpa = summary['models_per_aspect']
    print(f"models sharing one first observation: min {mpa['min']}, mean {mpa['mean']}, "
          f"max {mpa['max']}", file=out)
    print('  models  aspects', file=out)
    for k, count in summary['models_per_aspect_histogram'].items():
        print(f'  {int(k):6d}  {count:7d}', file=out)


def _usage_error(parser: argparse.ArgumentParser, message: str) -> int:
    """Like parser.error (usage + message, status 2) but returned, not raised."""
    parser.print_usage(sys.stderr)
    print(f'{parser.prog}: error: {message}', file=sys.stderr)
    return 2


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:                     # --help (0) or a usage error (2)
        return int(exc.code or 0)

    if args.load and args.which:
        return _usage_error(parser, '--load and --set are mutually exclusive')
    if args.size is not None and args.which != 'random':
        return _usage_error(parser, '--size only applies to --set random')
    which = args.which or 'full'
    size = 30 if args.size is None else args.size
    description = f'loaded from {args.load}' if args.load else {
        'full': 'full', 'visual': 'visual', 'random': f'random (size {size}, seed {args.seed})',
        'robot': f'robot (seed {args.seed})'}[which]
    try:
        model_set = population.model_set_from_config(
            which, size, args.tags, args.seed, model_file=args.load or '',
            transition_params=TransitionParams(rules=args.tables))
    except (ValueError, model_file.ModelFileError) as exc:
        return _usage_error(parser, str(exc))

    if args.out:
        try:
            model_file.save(model_set, args.out)
        except OSError as exc:
            print(f'{parser.prog}: error: cannot write {args.out}: {exc.strerror or exc}',
                  file=sys.stderr)
            return 1

    summary = summarize(model_set, description)
    if args.out:
        summary['saved_to'] = args.out
    if args.json:
        print(json.dumps(summary, separators=(',', ':')))
    else:
        _print_readable(summary, sys.stdout)
        if args.out:
            print(f'saved to         : {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
