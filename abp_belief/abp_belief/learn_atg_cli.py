"""`ros2 run abp_belief learn_atg`: learn ATG transition tables from experience and write a
model-set file that belief, planner, aspect matcher and sim bridge load through the
`model_file` parameter (`scripts/start_graph.sh --models FILE`). Science: `atg_learning`.

Examples:
  learn_atg --survey bench_out/survey/survey.json --out learned_robot.npz
  learn_atg --survey bench_out/survey/survey.json --set full --out learned_full.npz \\
      --report learned_vs_hand.md
  learn_atg --survey survey.json --alpha 0 --out survey_table.npz     # empirical (a world)
  learn_atg --survey survey.json --contact-fault-rate 0.1 --out learned_faults.npz
  learn_atg --survey survey.json --trials-per-class 5 --out learned_n5.npz
  learn_atg --survey survey_seed0.json survey_seed1.json --out learned.npz   # pooled
  learn_atg --bags labels.yaml --seed 1 --out learned_bags.npz    # recorded episodes

A labels file (--bags) names the object each bag holds (YAML ``bag: object`` or a list of
``{bag, object}``; CSV rows ``bag,object``); paths are relative to the file. The states
before and after each executed action are inferred from the bag's aspect observations
(atg_from_bags); objects are looked up in the model set (--set/--seed/--population) or
parsed from their names (``c0-3-2-4-6-5/m+z``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from . import atg_from_bags, atg_learning, model_file, population
from .cube import TRANSITION_RULES
from .modelset import TransitionParams

SETS = ('robot', 'full', 'random', 'visual')


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='learn_atg', formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__,
        description='Learn p(next state | action, mass variant, state) from experience with a '
        'Dirichlet prior and write a versioned, checksummed model-set file.')
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument('--survey', metavar='JSON', nargs='+',
                        help='outcome_survey JSON (bench_out/survey/survey.json); several '
                        'surveys of the same world (e.g. run with different --seed) pool '
                        'their trials')
    source.add_argument('--bags', metavar='LABELS',
                        help='labels file of recorded episodes: bag -> object name (YAML or '
                        'CSV)')
    p.add_argument('--out', metavar='FILE', help='write the learned model set here (.npz)')
    p.add_argument('--set', choices=SETS, default='robot', dest='which',
                   help='population whose tables are replaced (default robot)')
    p.add_argument('--size', type=int, default=30, help='visual cubes for --set random')
    p.add_argument('--seed', type=int, default=0, help='seed for --set random/robot')
    p.add_argument('--tags', type=int, default=7, help='tag-set size')
    p.add_argument('--population', metavar='FILE',
                   help='take the models from this model file instead of --set')
    p.add_argument('--alpha', type=float, default=atg_learning.DEFAULT_ALPHA,
                   help='Dirichlet concentration in pseudo-trials (0 = empirical; default '
                   f'{atg_learning.DEFAULT_ALPHA:g})')
    p.add_argument('--prior', choices=atg_learning.PRIORS, default='table',
                   help="prior mean: 'table' = hand-written table + epsilon spread over the "
                   "neighbourhood (default); 'uniform' = uniform over neighbourhood + table "
                   'support')
    p.add_argument('--epsilon', type=float, default=atg_learning.DEFAULT_EPSILON,
                   help='prior mass spread over the neighbourhood (prior table)')
    p.add_argument('--neighbourhood', choices=atg_learning.NEIGHBOURHOODS,
                   default=atg_learning.DEFAULT_NEIGHBOURHOOD,
                   help='outcomes kept possible although never seen (manual actions)')
    p.add_argument('--no-pool', action='store_true',
                   help='do not pool the symmetry classes (each transition counts at its '
                   'own cell only)')
    p.add_argument('--trials-per-class', type=int, default=None, metavar='N',
                   help='use only N trials of each survey class (learning curves)')
    p.add_argument('--subsample-seed', type=int, default=None,
                   help='draw the N trials at random with this seed (default: the first N)')
    p.add_argument('--broad', type=float, default=atg_from_bags.DEFAULT_BROAD,
                   help='--bags: weight of the broad neighbourhood mixed into the current '
                   f'table when inferring states (default {atg_from_bags.DEFAULT_BROAD:g})')
    p.add_argument('--views-per-segment', type=float,
                   default=atg_from_bags.DEFAULT_VIEWS_PER_SEGMENT,
                   help="--bags: at most this many observations' worth of evidence per "
                   'state between two actions (default '
                   f'{atg_from_bags.DEFAULT_VIEWS_PER_SEGMENT:g})')
    p.add_argument('--contact-fault-rate', type=float, default=0.0, metavar='F',
                   help="the robot's rate of PUSH/LIFT/FLIP that report success but never "
                   "moved the cube (missed push, slipped grasp), mixed into the learned rows "
                   "as 'no change' (atg_learning.with_contact_faults); e.g. 0.1, the model "
                   "set's p_fail_*. For experience without robot faults (the survey); the "
                   "robot's own bags already hold its faults. Default 0")
    p.add_argument('--tables', choices=TRANSITION_RULES, default='corrected',
                   help="the hand-written table (docs/MODEL.md) that is the prior mean, the "
                   "report's comparison and, with --bags, the tables the states are inferred "
                   "with: corrected (default) or paper")
    p.add_argument('--report', metavar='MD', help='write learned vs hand-written (Markdown)')
    p.add_argument('--json', action='store_true', help='print a JSON summary')
    return p


def _population(args, params: TransitionParams):
    return population.model_set_from_config(
        args.which, args.size, args.tags, args.seed, model_file=args.population or '',
        transition_params=params)


def _fault_rates(args) -> dict:
    rate = args.contact_fault_rate
    if not 0.0 <= rate < 1.0:
        raise ValueError(f'--contact-fault-rate must be in [0, 1), got {rate}')
    return {action: rate for action in ('PUSH', 'LIFT', 'FLIP')} if rate > 0 else {}


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    if args.bags and (args.trials_per_class is not None or args.subsample_seed is not None):
        print(f'{parser.prog}: error: --trials-per-class/--subsample-seed apply to --survey',
              file=sys.stderr)
        return 2
    if args.survey and len(args.survey) > 1 and args.trials_per_class is not None:
        print(f'{parser.prog}: error: --trials-per-class needs a single --survey (which '
              "survey's first N trials would it keep?)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    truth = None
    params = TransitionParams(rules=args.tables)
    try:
        base = _population(args, params) if args.bags else None    # objects are looked up in it
        if args.bags:
            if not 0.0 <= args.broad <= 1.0 or not args.views_per_segment > 0:
                raise ValueError('--broad must be in [0, 1] and --views-per-segment > 0')
            experience, inferences = atg_from_bags.experience_from_bags(
                args.bags, base, broad=args.broad, views_per_segment=args.views_per_segment)
            truth = atg_from_bags.truth_agreement(inferences)
        else:
            experience = atg_learning.Experience.concatenate([
                atg_learning.experience_from_survey(path, args.trials_per_class,
                                                    args.subsample_seed)
                for path in args.survey])
        learned = atg_learning.learn(experience, alpha=args.alpha, prior=args.prior,
                                     epsilon=args.epsilon,
                                     neighbourhood_kind=args.neighbourhood,
                                     pool=not args.no_pool,
                                     fault_rates=_fault_rates(args),
                                     params=params)
        t_learn = time.perf_counter() - t0
        models = atg_learning.with_tables(base or _population(args, params), learned)
    except (ValueError, model_file.ModelFileError) as exc:
        print(f'{parser.prog}: error: {exc}', file=sys.stderr)
        return 2
    hand = atg_learning.hand_table(params)
    tv = atg_learning.total_variation(learned.probs, hand)
    try:
        if args.out:
            model_file.save(models, args.out)
        if args.report:
            with open(args.report, 'w') as stream:
                stream.write(atg_learning.comparison_markdown(
                    learned, hand, f'Learned vs hand-written ({args.tables}) ATG tables'))
    except OSError as exc:
        print(f'{parser.prog}: error: cannot write: {exc}', file=sys.stderr)
        return 1
    trials = learned.trials
    summary = dict(
        transitions=len(experience), models=models.num_models,
        outcomes_per_cell_max=int(models.outcome_states.shape[3]),
        trials_per_cell=dict(min=float(trials.min()), max=float(trials.max())),
        cells_tv_over_0_1=int((tv > atg_learning.TV_HIGHLIGHT).sum()), cells=int(tv.size),
        tv_mean=round(float(tv.mean()), 4), learn_s=round(t_learn, 3),
        total_s=round(time.perf_counter() - t0, 3), out=args.out, report=args.report)
    if args.bags:
        summary.update(bags=experience.source['bags'], actions=experience.source['actions'],
                       failed_actions=experience.source['failed_actions'],
                       read_infer_s=experience.source['read_infer_s'],
                       ground_truth=truth)
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"learn_atg: {summary['transitions']} transitions -> {models.num_models} models, "
              f"<= {summary['outcomes_per_cell_max']} outcomes per cell, "
              f"{summary['cells_tv_over_0_1']}/{summary['cells']} cells differ from the "
              f'hand-written table by TV > 0.1 (mean TV {np.round(tv.mean(), 3)}); '
              f"learned in {summary['learn_s']} s, total {summary['total_s']} s"
              + (f'; wrote {args.out}' if args.out else ''))
        if args.bags:
            print(f"learn_atg: {summary['bags']} bags, {summary['actions']} executed actions "
                  f"counted ({summary['failed_actions']} failed, not counted), read and "
                  f"inferred in {summary['read_infer_s']} s")
            if truth and truth['actions']:
                print(f"learn_atg: ground truth in the bags: MAP (before, after) right for "
                      f"{100 * truth['map_pair']:.0f} % of {truth['actions']} actions, mean "
                      f"posterior on the true pair {truth['mass_on_true_pair']:.3f}")
            if truth and truth['label_mismatch']:
                print(f"learn_atg: warning: the ground-truth object differs from the label "
                      f"in {', '.join(truth['label_mismatch'])}", file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
