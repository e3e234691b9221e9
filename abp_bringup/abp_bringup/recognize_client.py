"""`recognize`: sends one Recognize goal and prints a readable trace and the result.

    recognize [--planner MODE] [--max-actions N] [--stopping-rule RULE] [--target-error E]
              [--threshold P] [--result-json FILE] [--timeout S] [--wait S]
              [--task identify_all|find|identify [--target-model ID] [--track-id T]]
              [--ros-args -r __ns:=/robot1]

Trace lines show each chosen action with its expected information gain, the top
beliefs and the entropy. Beliefs come from the goal's feedback as well as from
abp/belief, so the trace does not depend on when the topic subscription matched.
In sim, the result is compared with the sim bridge's ground truth (read here, by the
user-facing client, never by a recognition node).
Exit code 0 when the recognition succeeded (and matched the ground truth when
there is one), 1 otherwise, 2 for bad arguments, 130 on Ctrl-C (the goal is
cancelled first). Names are relative (abp_common.names): under a namespace the client
finds that graph's Recognize server. With `--task` (several cubes: docs/MULTI_OBJECT.md)
the result lists every object track (`objects` in the JSON) and, for `find`, the track
found; the ground truth is compared with the one-object fields only.
"""

import argparse
import json
import math
import signal
import sys
import time

import rclpy
from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from abp_common import names, qos
from abp_common.server_handshake import wait_until_answering
from abp_msgs.action import Recognize
from abp_msgs.msg import Belief, ExecutedAction, PlanStep, SimGroundTruth

TRACE_DEPTH = 50
TASKS = (Recognize.Goal.TASK_IDENTIFY_ALL, Recognize.Goal.TASK_FIND,
         Recognize.Goal.TASK_IDENTIFY)
STATUS_NAMES = {GoalStatus.STATUS_SUCCEEDED: 'succeeded', GoalStatus.STATUS_ABORTED: 'aborted',
                GoalStatus.STATUS_CANCELED: 'cancelled'}


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='recognize', description=__doc__.split('\n\n')[0])
    parser.add_argument('--planner', default='', help="random, abp, abp2, abp3 or cost "
                        "(default: the planner node's parameter)")
    parser.add_argument('--max-actions', type=int, default=0)
    parser.add_argument('--stopping-rule', default='', choices=('', 'error', 'posterior',
                                                                 'fixed'),
                        help="default: the planner node's parameter (error)")
    parser.add_argument('--target-error', type=float, default=0.0,
                        help='target P(wrong object) of the error rule; 0 = the node default')
    parser.add_argument('--threshold', type=float, default=0.0,
                        help='top posterior of the posterior rule; 0 = the node default')
    parser.add_argument('--result-json', default='')
    parser.add_argument('--timeout', type=float, default=1800.0,
                        help='wall-clock seconds before the goal is cancelled')
    parser.add_argument('--wait', type=float, default=120.0,
                        help='seconds to wait for the graph (the Recognize server)')
    parser.add_argument('--task', default='', choices=('', *TASKS),
                        help='a task over several cubes (default: the one cube in front)')
    parser.add_argument('--target-model', default='', help='the model id --task find seeks')
    parser.add_argument('--track-id', default='', help='the track --task identify names')
    args = parser.parse_args(argv)
    if (args.task == Recognize.Goal.TASK_FIND) != bool(args.target_model) or \
            (args.task == Recognize.Goal.TASK_IDENTIFY) != bool(args.track_id):
        parser.error('--target-model goes with --task find, --track-id with --task identify '
                     '(each needs it)')
    if args.max_actions < 0 or not 0.0 <= args.threshold < 1.0 or \
            not 0.0 <= args.target_error < 0.5:
        parser.error('--max-actions must be >= 0, --threshold in [0, 1) and --target-error '
                     'in [0, 0.5)')
    return args


def top_beliefs(belief, count=3):
    return ', '.join(f'{oid} {p:.3f}' for oid, p in
                     zip(belief.object_ids[:count], belief.probabilities))


class Tracer:
    """Prints the trace from abp/plan, abp/executed_action and abp/belief."""

    def __init__(self, node):
        self.belief = None
        self.ground_truth = None
        self.printed_steps = set()
        self.printing = False  # beliefs from before our goal (latched, or another episode's)
        self.executed = 0
        events = qos.reliable(TRACE_DEPTH)
        # Volatile: what the planner publishes before these match is not seen.
        self.event_subscriptions = (
            node.create_subscription(PlanStep, names.PLAN, self.on_plan, events),
            node.create_subscription(ExecutedAction, names.EXECUTED_ACTION, self.on_executed,
                                     events))
        node.create_subscription(Belief, names.BELIEF, self.on_belief, qos.LATCHED)
        node.create_subscription(SimGroundTruth, names.GROUND_TRUTH, self.on_truth,
                                 qos.LATCHED)

    def on_plan(self, msg):
        gain = msg.expected_information_gain
        scored = f'expected IG {gain:6.3f} bits' if math.isfinite(gain) else \
            f'({msg.planner_mode}: no IG scored)'
        line = f'plan      {msg.action:<10} {scored}'
        refused = [a for a, ok in zip(msg.candidate_actions, msg.candidate_feasible) if not ok]
        if refused:
            line += f"  (infeasible: {', '.join(refused)})"
        print(line, flush=True)

    def matched(self):
        """Whether the plan and executed-action subscriptions have matched a publisher."""
        return all(sub.get_publisher_count() > 0 for sub in self.event_subscriptions)

    def on_executed(self, msg):
        self.executed += 1
        outcome = 'done' if msg.success else f'FAILED: {msg.reason}'
        duration = msg.duration.sec + msg.duration.nanosec * 1e-9
        print(f'action {msg.sequence:<3}{msg.action:<10} {outcome} ({duration:.1f} s)',
              flush=True)

    def on_feedback(self, feedback_msg):
        self.on_belief(feedback_msg.feedback.belief)

    def on_belief(self, msg):
        # The same belief can come twice (topic and feedback): print each step once.
        if not self.printing or msg.step in self.printed_steps:
            return
        self.printed_steps.add(msg.step)
        self.belief = msg
        if msg.object_ids:
            print(f'belief    step {msg.step:<3} H {msg.entropy:6.3f} bits  top: '
                  f'{top_beliefs(msg)}', flush=True)

    def on_truth(self, msg):
        self.ground_truth = msg


def spin_until(node, predicate, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not predicate():
        rclpy.spin_once(node, timeout_sec=0.05)
    return predicate()


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_args(remove_ros_args(['recognize', *argv])[1:])
    # Ctrl-C must reach the code below as KeyboardInterrupt, with the context still up, so
    # that the goal can be cancelled: rclpy's own handler would shut the context down first.
    # Set explicitly: a shell script's background job starts with SIGINT ignored.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    rclpy.init(args=['recognize', *argv], signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('recognize_client')
    tracer = Tracer(node)
    client = ActionClient(node, Recognize, names.RECOGNIZE)
    server = names.absolute(names.RECOGNIZE, node.get_namespace())
    handle = None
    try:
        # A handshake, not just server_is_ready(): a goal sent before the planner has
        # discovered this client is lost, or is run with its acceptance never heard.
        if not wait_until_answering(client, lambda done, seconds: spin_until(node, done, seconds),
                                    args.wait):
            print(f'[recognize] no {server} server within {args.wait:.0f} s: is the '
                  'planner running?', file=sys.stderr)
            return 1
        # The planner's plan and action topics are volatile: match them before the goal,
        # so that the trace has the first action (bounded: a trace is not worth a hang).
        if not spin_until(node, tracer.matched, 10.0):
            print("[recognize] warning: not subscribed to the planner's plans and actions "
                  'after 10 s; the trace may miss the first ones', file=sys.stderr)
        goal = Recognize.Goal(planner_mode=args.planner, max_actions=args.max_actions,
                              posterior_threshold=args.threshold,
                              stopping_rule=args.stopping_rule,
                              target_error=args.target_error, task=args.task,
                              target_model=args.target_model, track_id=args.track_id)
        tracer.printing = True
        sent = client.send_goal_async(goal, feedback_callback=tracer.on_feedback)
        spin_until(node, sent.done, 30.0)
        handle = sent.result() if sent.done() else None
        if handle is None or not handle.accepted:
            print('[recognize] goal rejected (unknown planner mode or stopping rule, or a '
                  'recognition is already running: see the planner log)', file=sys.stderr)
            return 1
        print(f"recognize goal accepted (planner {args.planner or 'default'})", flush=True)
        result_future = handle.get_result_async()
        if not spin_until(node, result_future.done, args.timeout):
            print(f'[recognize] no result within {args.timeout:.0f} s; cancelling',
                  file=sys.stderr)
            cancel = handle.cancel_goal_async()
            spin_until(node, cancel.done, 10.0)
            spin_until(node, result_future.done, 30.0)
            if not result_future.done():
                return 1
        response = result_future.result()
        # DDS keeps no order between the result and the topics: wait for the last action's
        # message (bounded), then briefly for the belief that follows it.
        spin_until(node, lambda: tracer.executed >= response.result.actions_taken, 5.0)
        spin_until(node, lambda: False, 0.3)
        return report(response, tracer, args.result_json)
    except KeyboardInterrupt:
        if handle is not None and handle.accepted:
            print('\n[recognize] Ctrl-C: cancelling the goal', file=sys.stderr)
            cancel = handle.cancel_goal_async()
            spin_until(node, cancel.done, 5.0)
        return 130
    finally:
        client.destroy()
        node.destroy_node()
        rclpy.try_shutdown()


def report(response, tracer, result_json):
    result = response.result
    elapsed = result.elapsed.sec + result.elapsed.nanosec * 1e-9
    summary = {
        'status': STATUS_NAMES.get(response.status, str(response.status)),
        'success': bool(result.success),
        'reason': result.reason,
        'object_id': result.object_id,
        'posterior': float(result.posterior),
        'actions': int(result.actions_taken),
        'candidates': dict(zip(result.top_object_ids, map(float, result.top_posteriors))),
        'elapsed_s': elapsed,
        'entropy': float(tracer.belief.entropy) if tracer.belief else None,
    }
    if result.objects or result.found_track_id:
        summary['objects'] = [
            {'track_id': o.track_id, 'object_id': o.object_id, 'posterior': float(o.posterior),
             'actions': int(o.actions_taken), 'decided': bool(o.decided), 'reason': o.reason}
            for o in result.objects]
        summary['found_track_id'] = result.found_track_id
    identified = response.status == GoalStatus.STATUS_SUCCEEDED and bool(result.success)
    truth = tracer.ground_truth
    if 'objects' in summary and not result.object_id:
        truth = None   # a task over every cube: the first cube's truth says nothing of it
    if truth is not None:
        summary['ground_truth'] = truth.object_id
        # An aborted goal still names its most likely object: that is no identification,
        # so 'correct' needs both; the most likely object is reported apart.
        summary['most_likely_correct'] = truth.object_id == result.object_id
        summary['correct'] = identified and summary['most_likely_correct']
    print(f"result: {summary['status']}: {result.object_id or '-'} posterior "
          f"{result.posterior:.3f} after {result.actions_taken} actions, {elapsed:.1f} s "
          f"({result.reason})", flush=True)
    for entry in summary.get('objects', []):
        print(f"  track {entry['track_id']}: {entry['object_id'] or '-'} "
              f"{entry['posterior']:.3f}, {entry['actions']} actions, "
              f"{'named' if entry['decided'] else 'not named'} ({entry['reason']})", flush=True)
    if response.status != GoalStatus.STATUS_SUCCEEDED and result.top_object_ids:
        print('not identified; candidates: ' + ', '.join(
            f'{oid} {p:.3f}' for oid, p in zip(result.top_object_ids, result.top_posteriors)),
            flush=True)
    if truth is not None:
        print(f'ground truth: {truth.object_id} -> {truth_verdict(summary)}', flush=True)
    if result_json:
        with open(result_json, 'w') as out:
            json.dump(summary, out, indent=2)
    return 0 if identified and summary.get('correct', True) else 1


def truth_verdict(summary):
    """'correct', 'WRONG' (identified the wrong object) or 'not identified' (with whether
    the most likely object was the right one) of a report summary with a ground truth."""
    if summary['correct']:
        return 'correct'
    if summary['status'] == 'succeeded' and summary['success']:
        return 'WRONG'
    likely = 'right' if summary['most_likely_correct'] else 'wrong'
    return f'not identified (most likely object {likely})'


if __name__ == '__main__':
    sys.exit(main())
