"""Micro-benchmark of one Bayes-filter step (predict + correct); prints a Markdown table.

Goal: < 1 ms at |M| = 120 and < 10 ms at the full n=7 set (1470 models).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from abp_belief import population
from abp_belief.cube import ACTIONS
from abp_belief.filter import BeliefFilter


def _matrix_bytes(matrix) -> int:
    return matrix.data.nbytes + matrix.indices.nbytes + matrix.indptr.nbytes


def bench_one(model_set, repeats: int, rng: np.random.Generator) -> dict:
    flt = BeliefFilter(model_set)
    true_model = int(rng.integers(model_set.num_models))
    nodes = true_model * 48 + rng.integers(0, 48, size=repeats)
    observations = [model_set.observation.sample(model_set.node_aspect[n], rng) for n in nodes]
    actions = rng.integers(0, len(ACTIONS), size=repeats)
    for a in range(len(ACTIONS)):                     # build the cached transposes first
        model_set.transition_transpose(a)
    times = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        flt.predict(int(actions[i]))
        flt.correct(observations[i])
        times[i] = time.perf_counter() - start
        if i % 50 == 49:
            flt.reset()                               # keep the belief spread, as at the start
    transitions = sum(_matrix_bytes(t) for t in model_set.transitions.values())
    transposes = sum(_matrix_bytes(model_set.transition_transpose(a)) for a in range(len(ACTIONS)))
    other = (flt.belief.nbytes * 2 + model_set.node_aspect.nbytes
             + model_set.observation.aspect_likelihood.nbytes
             + model_set.outcome_states.nbytes + model_set.outcome_probs.nbytes)
    return {'models': model_set.num_models, 'nodes': model_set.num_nodes,
            'aspects': model_set.num_aspects,
            'median_ms': float(np.median(times) * 1e3),
            'p90_ms': float(np.quantile(times, 0.9) * 1e3),
            'transitions_mib': transitions / 2**20, 'transposes_mib': transposes / 2**20,
            'other_mib': other / 2**20}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='bench_filter', description=__doc__)
    parser.add_argument('--repeats', type=int, default=300, help='filter steps per size')
    parser.add_argument('--seed', type=int, default=0)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    if args.repeats < 1:
        print('bench_filter: error: --repeats must be >= 1', file=sys.stderr)
        return 2
    rng = np.random.default_rng(args.seed)
    sets = [('random 30', lambda: population.random_visual_subset(30, seed=args.seed)),
            ('random 120', lambda: population.random_visual_subset(120, seed=args.seed)),
            ('full n=7', lambda: population.full_set(7))]
    print('| set | models | nodes | aspects | build (s) | predict+correct median (ms) '
          '| p90 (ms) | T (MiB) | T^T (MiB) | other arrays (MiB) |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
    for label, make in sets:
        start = time.perf_counter()
        model_set = make()
        build = time.perf_counter() - start
        r = bench_one(model_set, args.repeats, rng)
        print(f"| {label} | {r['models']} | {r['nodes']} | {r['aspects']} | {build:.2f} "
              f"| {r['median_ms']:.3f} | {r['p90_ms']:.3f} | {r['transitions_mib']:.2f} "
              f"| {r['transposes_mib']:.2f} | {r['other_mib']:.2f} |", flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
