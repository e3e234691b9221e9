"""The goals of abp_bench.link_benchmark, sent from the workstation's network namespace:
`python -m abp_bench.link_driver --episodes N --drops D --past-timeout P --link-suffix X
--planner-log FILE --json FILE`.

Before each goal it hides a random cube of the robot set in the sim (abp_bench.soak's
Driver). Kinds of episode: `clean`; `drop` (the link down for --link-down-s from the
first plan, i.e. while the first skill runs: it must end correct, and the planner's log
must show a pause); `past` (the link down from the first plan until the goal ends: an
abort that names the lost nodes), each followed by `after` (sent once the lifecycle
manager's graph_ready is true again: it must end correct). The link is driven through
`ip -n` on the namespaces of abp_bench.netns_link named by --link-suffix.
"""

import argparse
import json
import pathlib
import sys
import time

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus
from rclpy.signals import SignalHandlerOptions

from abp_belief.population import robot_set
from abp_common import names, qos
from abp_common.server_handshake import wait_until_answering
from abp_msgs.action import Recognize
from abp_msgs.msg import PlanStep

from .netns_link import TwoHostLink
from .soak import Driver

STATUS = {GoalStatus.STATUS_SUCCEEDED: 'succeeded', GoalStatus.STATUS_ABORTED: 'aborted',
          GoalStatus.STATUS_CANCELED: 'cancelled'}
PAUSE_LINE = 'episode paused:'


def pauses(planner_log):
    try:
        return pathlib.Path(planner_log).read_text(errors='replace').count(PAUSE_LINE)
    except OSError:
        return 0


def episode(driver, plans, link, kind, link_down_s, timeout):
    """One goal of `kind`; returns its record."""
    record = {'kind': kind}
    if not wait_until_answering(driver.recognize, driver.spin_until, 120.0):
        return {**record, 'outcome': 'no server', 'correct': False}
    plans.clear()
    started = time.monotonic()
    sent = driver.recognize.send_goal_async(Recognize.Goal())
    if not driver.spin_until(sent.done, 30.0) or not sent.result().accepted:
        return {**record, 'outcome': 'rejected', 'correct': False}
    result = sent.result().get_result_async()
    if kind in ('drop', 'past'):
        driver.spin_until(lambda: plans or result.done(), timeout)
        if result.done():
            record['note'] = 'ended before the first plan: no drop'
        else:
            link.set_up(False)
            down_at = time.monotonic()
            try:
                # `drop`: the outage is a fixed time (the fault); `past`: until the end.
                driver.spin_until(result.done, link_down_s if kind == 'drop' else timeout)
                record['ended_during_outage'] = result.done()
            finally:
                link.set_up(True)
            record['down_s'] = round(time.monotonic() - down_at, 1)
    driver.spin_until(result.done, max(0.0, started + timeout - time.monotonic()))
    record['wall_s'] = round(time.monotonic() - started, 1)
    if not result.done():
        return {**record, 'outcome': 'timeout', 'correct': False}
    response = result.result()
    truth = driver.truth.object_id if driver.truth is not None else ''
    return {**record, 'outcome': STATUS.get(response.status, str(response.status)),
            'reason': response.result.reason, 'answer': response.result.object_id,
            'ground_truth': truth,
            'correct': bool(response.result.success) and response.result.object_id == truth,
            'actions': int(response.result.actions_taken)}


def expected(record):
    """Whether an episode met its kind's expectation."""
    if record['kind'] == 'past':
        return record['outcome'] == 'aborted' and 'not back within' in record.get('reason', '')
    if record['kind'] == 'drop':
        return record['correct'] and record.get('paused', 0) >= 1 and \
            not record.get('ended_during_outage', False)
    return record['correct']


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m abp_bench.link_driver',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--episodes', type=int, default=10)
    parser.add_argument('--drops', type=int, default=0)
    parser.add_argument('--past-timeout', type=int, default=0)
    parser.add_argument('--link-down-s', type=float, default=10.0)
    parser.add_argument('--link-suffix', required=True)
    parser.add_argument('--planner-log', required=True)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--timeout', type=float, default=600.0)
    parser.add_argument('--json', required=True)
    args = parser.parse_args(argv)
    link = TwoHostLink(suffix=args.link_suffix)   # made by the benchmark; only driven here
    models = robot_set(seed=args.seed)
    rng = np.random.default_rng(args.seed)
    kinds = ['clean'] * args.episodes + ['drop'] * args.drops + \
        ['past', 'after'] * args.past_timeout
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    context = rclpy.get_default_context()
    driver = Driver(context)
    plans = []
    driver.node.create_subscription(PlanStep, names.PLAN, plans.append, qos.RELIABLE)
    records = []
    try:
        if not driver.spin_until(lambda: driver.graph_ready, 600.0):
            raise RuntimeError('the graph was not ready within 600 s')
        for number, kind in enumerate(kinds):
            if kind == 'after' and not driver.spin_until(lambda: driver.graph_ready, 300.0):
                records.append({'kind': kind, 'outcome': 'graph not ready', 'correct': False})
                continue
            index = int(rng.integers(len(models.names)))
            driver.hide(index, models.names[index], failure_seed=number)
            paused_before = pauses(args.planner_log)
            record = episode(driver, plans, link, kind, args.link_down_s, args.timeout)
            # The planner's log is written as it goes: a pause is in it by the episode's end.
            record.update(number=number, paused=pauses(args.planner_log) - paused_before)
            record['as_expected'] = expected(record)
            records.append(record)
            print(json.dumps(record), flush=True)
            # After `past`, graph_ready is false (the manager, beside this driver, said so
            # when the robot's nodes stopped answering): `after` waits for it to clear.
    finally:
        driver.close()
        rclpy.try_shutdown()
    passed = bool(records) and len(records) == len(kinds) and \
        all(r['as_expected'] for r in records)
    pathlib.Path(args.json).write_text(json.dumps({'episodes': records, 'passed': passed}))
    print(f'{sum(r["as_expected"] for r in records)} of {len(kinds)} episodes as expected',
          flush=True)
    return 0 if passed else 1


if __name__ == '__main__':
    sys.exit(main())
