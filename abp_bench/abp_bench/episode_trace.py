"""`episode_trace`: per executed action, what the world did and what the robot's tables and
belief made of it, from bags of simulated episodes (`graph_benchmark --record DIR`).

    episode_trace --bags DIR/labels.yaml [--models FILE|robot] [--seed S] [--rare 0.02]
                  [--json OUT]

For each action of each bag: the true state before and after (the sim's ground truth,
``up face/yaw step``), the probability that the tables give this transition for the true
object's mass variant, the best such probability among the other members of its twin
family (same faces, another mass), and the belief's probability of the true object
after the action; and whether the world saw a manual action at all (its count of manual
actions moved: a push, or a grasp that rose). A transition the true model calls rare
(below ``--rare``) while a twin does not is evidence for the wrong twin: the finding the
trace exists to count. A drop of the belief without a rare transition points at the
observations instead.

No rclpy: the bags are read with `rosbags` (`abp_belief.atg_from_bags`).
"""

import argparse
import json
import os
import sys
from collections import Counter

import numpy as np

from abp_belief import atg_from_bags, atg_learning
from abp_belief.cube import (
    ACTIONS,
    FACE_NAMES,
    MANUAL_ACTIONS,
    MASS_NAMES,
    NUM_YAWS,
    TRANSITION_RULES,
)
from abp_belief.modelset import TransitionParams
from abp_belief.population import model_set_from_config
from abp_common import names

DEFAULT_RARE = 0.02


def model_set_of(models, seed, rules='corrected'):
    """The model set of start_graph.sh (and graph_benchmark) --models `models` --seed `seed`
    --tables `rules`."""
    if os.path.isfile(models):  # a model file, as start_graph.sh --models path/to/models.npz
        return model_set_from_config(model_file=models)
    params = TransitionParams(rules=rules)
    if models.startswith('random:'):
        return model_set_from_config('random', int(models.split(':')[1]), seed=seed,
                                     transition_params=params)
    return model_set_from_config(models, seed=seed, transition_params=params)


def state_name(state: int) -> str:
    return f'{FACE_NAMES[state // NUM_YAWS]}/{state % NUM_YAWS}' if state >= 0 else '?'


def read_beliefs(path):
    """[(header stamp ns, {object id: probability})] of a bag's belief messages."""
    from rosbags.rosbag2 import Reader
    store = atg_from_bags.typestore()
    beliefs = []
    try:
        with Reader(path) as reader:
            wanted = [c for c in reader.connections
                      if c.topic == '/' + names.BELIEF or c.topic.endswith('/' + names.BELIEF)]
            for connection, _, data in reader.messages(connections=wanted):
                msg = store.deserialize_cdr(data, connection.msgtype)
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                beliefs.append((stamp, dict(zip(msg.object_ids, map(float, msg.probabilities)))))
    except Exception as exc:  # rosbags raises several types for unreadable bags
        raise atg_from_bags.BagLearningError(f'cannot read bag {path}: {exc}') from exc
    beliefs.sort(key=lambda b: b[0])
    return beliefs


def _belief_of_truth(beliefs, stamps, truth):
    """P(truth) in the last belief stamped at or before each of `stamps` (nan: none yet;
    0 when the message lists other objects only, i.e. the truth is below its top list)."""
    times = np.array([b[0] for b in beliefs], dtype=np.int64)
    out = np.full(len(stamps), np.nan)
    for k, i in enumerate(np.searchsorted(times, stamps, side='right') - 1):
        if i >= 0:
            out[k] = beliefs[i][1].get(truth, 0.0)
    return out


def trace_episode(path, label, model_set, table, rare=DEFAULT_RARE):
    """One dict per executed action of the bag at `path` (see the module doc)."""
    episode = atg_from_bags.read_episode(path)
    truth = episode.truth_object or label
    if truth not in model_set.names:
        raise atg_from_bags.BagLearningError(
            f'{path}: object {truth!r} is not in the model set')
    index = model_set.model_index(truth)
    family = np.flatnonzero((model_set.faces == model_set.faces[index]).all(axis=1))
    masses = model_set.mass[family]
    own = int(model_set.mass[index])
    beliefs = read_beliefs(path)
    before = _belief_of_truth(beliefs, episode.act_start, truth)
    # The belief after an action: the last one before the next action starts (or the end).
    next_start = np.append(episode.act_start[1:], np.iinfo(np.int64).max)
    after = _belief_of_truth(beliefs, next_start, truth)
    world_actions = episode.world_actions()
    rows = []
    for k, (s, s2) in enumerate(episode.true_transitions()):
        a = int(episode.act_index[k])
        row = dict(bag=str(path), truth=truth, step=k + 1,
                   action=ACTIONS[a] if a >= 0 else '?',
                   success=bool(episode.act_success[k]), before=state_name(int(s)),
                   after=state_name(int(s2)), p_truth_before=float(before[k]),
                   p_truth_after=float(after[k]))
        if row['action'] in MANUAL_ACTIONS and world_actions[k] >= 0:
            row['world_saw_action'] = bool(world_actions[k] > 0)
        if a >= 0 and s >= 0 and s2 >= 0:
            p = table[a, masses, s, s2]
            others = masses != own
            row['p_table_true'] = float(table[a, own, s, s2])
            if others.any():
                j = int(np.argmax(np.where(others, p, -1.0)))
                row['p_table_best_twin'] = float(p[j])
                row['best_twin'] = MASS_NAMES[int(masses[j])]
            row['rare'] = row['success'] and row['p_table_true'] < rare
        rows.append(row)
    return rows


def summary(rows, rare=DEFAULT_RARE):
    """Counts per (action, true mass): actions, manual ones done that the world did not see,
    rare transitions, rare ones that a twin explains better, and belief drops (P(truth)
    down by half or more) without one."""
    table = Counter()
    for r in rows:
        if 'p_table_true' not in r or not r['success']:
            continue
        key = (r['action'] if r['action'] in MANUAL_ACTIONS else 'ORBIT', r['truth'].split('/')[1])
        table[key + ('actions',)] += 1
        table[key + ('unseen',)] += r.get('world_saw_action') is False
        if r['rare']:
            table[key + ('rare',)] += 1
            if r.get('p_table_best_twin', 0.0) > r['p_table_true']:
                table[key + ('twin_better',)] += 1
        elif r['p_truth_after'] < 0.5 * r['p_truth_before']:
            table[key + ('drop_no_rare',)] += 1
    keys = sorted({k[:2] for k in table})
    lines = [f'| action | true mass | done | world saw none | rare (p < {rare:g}) '
             '| of them, a twin more likely | belief in truth halved without a rare '
             'transition |', '|---|---|---:|---:|---:|---:|---:|']
    for key in keys:
        lines.append(f'| {key[0]} | {key[1]} | {table[key + ("actions",)]} | '
                     f'{table[key + ("unseen",)] if key[0] != "ORBIT" else "-"} | '
                     f'{table[key + ("rare",)]} | {table[key + ("twin_better",)]} | '
                     f'{table[key + ("drop_no_rare",)]} |')
    return '\n'.join(lines)


def episode_markdown(rows):
    lines = [f"**{rows[0]['bag']}** (truth {rows[0]['truth']})", '',
             '| step | action | ok | world saw it | true before -> after | p table (truth) | '
             'best twin p | P(truth) before -> after |', '|---:|---|---|---|---|---:|---|---|']
    for r in rows:
        twin = (f"{r['best_twin']} {r['p_table_best_twin']:.3f}" if 'best_twin' in r else '-')
        p_true = f"{r['p_table_true']:.3f}" if 'p_table_true' in r else '-'
        mark = ' **rare**' if r.get('rare') else ''
        seen = {True: 'yes', False: '**no**'}.get(r.get('world_saw_action'), '-')
        lines.append(f"| {r['step']} | {r['action']} | {'yes' if r['success'] else 'no'} | "
                     f"{seen} | "
                     f"{r['before']} -> {r['after']} | {p_true}{mark} | {twin} | "
                     f"{r['p_truth_before']:.3f} -> {r['p_truth_after']:.3f} |")
    return '\n'.join(lines)


def parse_args(argv):
    p = argparse.ArgumentParser(prog='episode_trace', description=__doc__.split('\n\n')[0])
    p.add_argument('--bags', required=True, metavar='LABELS',
                   help='labels file (bag -> object): graph_benchmark --record DIR writes '
                   'DIR/labels.yaml')
    p.add_argument('--models', default='robot',
                   help='the model set the belief used, as graph_benchmark --models')
    p.add_argument('--seed', type=int, default=0, help='model-set seed (as graph_benchmark)')
    p.add_argument('--tables', choices=TRANSITION_RULES, default='corrected',
                   help='hand-written table of a generated set, as graph_benchmark --tables '
                   '(paper for bags of the rules world)')
    p.add_argument('--rare', type=float, default=DEFAULT_RARE,
                   help='a transition below this table probability counts as rare')
    p.add_argument('--json', metavar='OUT', help='write every row here')
    args = p.parse_args(argv)
    if not 0.0 < args.rare < 1.0:
        p.error('--rare must be in (0, 1)')
    return args


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        model_set = model_set_of(args.models, args.seed, args.tables)
        table = atg_learning.dense_table(model_set.outcome_states, model_set.outcome_probs)
        rows = []
        for bag, label in atg_from_bags.load_labels(args.bags):
            episode_rows = trace_episode(bag, label, model_set, table, args.rare)
            if episode_rows:
                print(episode_markdown(episode_rows) + '\n')
            rows += episode_rows
    except (atg_from_bags.BagLearningError, OSError, ValueError) as error:
        print(f'episode_trace: {error}', file=sys.stderr)
        return 2
    print(summary(rows, args.rare))
    if args.json:
        with open(args.json, 'w') as out:
            json.dump(rows, out, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
