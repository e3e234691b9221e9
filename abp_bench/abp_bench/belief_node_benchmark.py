"""CPU time of one belief update in the belief node, with K object tracks (issue 37).

    python -m abp_bench.belief_node_benchmark --model-set robot --objects 1 3 --rounds 200

One process, the real BeliefNode (abp_belief.belief_node) configured and activated, its
subscription callbacks called in turn as its executor would call them: per round and per
track, an executed action (prediction) and an observation sampled from a random aspect
node (correction). Each update includes what the node publishes after it: /abp/belief
and /abp/beliefs (SceneBelief with every object) on real publishers, without subscribers
(serialisation, no delivery). The K values are measured interleaved, `--repeats` times
each, after a full reset. CPU time (time.process_time), not wall time: on a loaded
machine the wall time mostly measures when the scheduler let the process run.
"""

import argparse
import os
import sys
import time

import numpy as np
import rclpy

from abp_belief.belief_node import BeliefNode
from abp_belief.cube import ACTIONS
from abp_msgs.msg import AspectHypothesis, AspectObservation, ExecutedAction
from abp_msgs.srv import ResetBelief


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='belief_node_benchmark',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--model-set', default='robot', help='robot, full, visual, random')
    parser.add_argument('--objects', type=int, nargs='+', default=[1, 3],
                        help='numbers of object tracks K to compare')
    parser.add_argument('--rounds', type=int, default=100,
                        help='action + observation pairs per track and repeat')
    parser.add_argument('--repeats', type=int, default=2, help='interleaved repeats per K')
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args(argv)
    if min(args.objects) < 1 or args.rounds < 1 or args.repeats < 1:
        parser.error('--objects, --rounds and --repeats must be >= 1')
    return args


class Inputs:
    """Observations and actions with rising stamps, sampled from the node's model set."""

    def __init__(self, model_set, seed):
        self.model_set = model_set
        self.rng = np.random.default_rng(seed)
        self.sec = 0

    def observation(self, track):
        models, rng = self.model_set, self.rng
        z = models.observation.sample(models.node_aspect[int(rng.integers(models.num_nodes))],
                                      rng)
        self.sec += 1
        msg = AspectObservation(track_id=track, hypotheses=[AspectHypothesis(
            aspect_type=z[0], slots=list(z[1:]), support=3.0, score=1.0)])
        msg.header.stamp.sec = self.sec
        return msg

    def action(self, track):
        self.sec += 1
        msg = ExecutedAction(action=ACTIONS[int(self.rng.integers(len(ACTIONS)))],
                             success=True, track_id=track)
        msg.header.stamp.sec = self.sec
        return msg


def measure(node, inputs, k, rounds):
    """CPU seconds per update (one prediction or one correction) with k tracks."""
    node._on_reset(ResetBelief.Request(), ResetBelief.Response())
    tracks = [''] if k == 1 else [f'cube_{i}' for i in range(k)]
    for track in tracks:
        node._on_observation(inputs.observation(track))
    samples = []
    for _ in range(rounds):
        for track in tracks:
            action, observation = inputs.action(track), inputs.observation(track)
            start = time.process_time()
            node._on_executed_action(action)
            node._on_observation(observation)
            samples.append((time.process_time() - start) / 2)
    return samples


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    rclpy.init(args=['belief_node_benchmark', '--ros-args', '-p',
                     f'model_set:={args.model_set}', '-p', f'seed:={args.seed}',
                     '-p', 'correct_once_per_action:=true',
                     '-p', f'max_tracks:={max(args.objects)}'])
    node = BeliefNode()
    try:
        node.start()
        inputs = Inputs(node.model_set, args.seed)
        samples = {k: [] for k in args.objects}
        for _ in range(args.repeats):
            for k in args.objects:
                samples[k] += measure(node, inputs, k, args.rounds)
        print(f'model set {args.model_set}: {node.model_set.num_models} models, '
              f'load average {os.getloadavg()[0]:.1f}')
        base = np.median(samples[args.objects[0]])
        for k, values in samples.items():
            median = np.median(values)
            print(f'K = {k}: median CPU per update {median * 1e6:.0f} us '
                  f'(p95 {np.percentile(values, 95) * 1e6:.0f} us, n = {len(values)}), '
                  f'{median / base:.2f} x K = {args.objects[0]}')
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
