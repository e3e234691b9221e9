"""ROS 2 wiring of the Active Belief Planner: the `planner` node.

Action server:  abp/recognize (abp_msgs/Recognize) runs the recognition loop.
Subscribes:     abp/belief (abp_msgs/Belief, latched; the sparse node belief is what the
                planner plans on), abp/aspect_observation (cube pose for markers)
Publishes:      abp/plan (abp_msgs/PlanStep), abp/executed_action (abp_msgs/ExecutedAction),
                abp/markers (visualization_msgs/MarkerArray)
Uses:           abp/skills/{orbit,push,lift,flip} actions, abp/skills/check_feasibility,
                abp/reset_belief

(Names are relative: /abp/... without a namespace.) The decision is
`abp_planner.planner`, the episode (stop, re-plan, retry, wait for evidence)
`abp_planner.episode.EpisodeRunner`; this module moves messages and implements the
runner's `EpisodePorts` for the goal being executed. A belief that is not over this
model set or is malformed (`check_belief`), and malformed observations, are rejected,
counted in /diagnostics and logged at most once per few seconds per kind
(abp_common.health); the planner keeps the last good belief.
"""

import queue
import sys
import threading
import time

import rclpy
from rclpy.action import ActionClient, ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.duration import Duration
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future
from visualization_msgs.msg import MarkerArray

from abp_belief.cube import ACTIONS
from abp_belief.model_file import ModelFileError, fingerprint
from abp_belief.model_set_config import MODEL_SET_SPECS, model_set_from_values
from abp_common import input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all, read_all
from abp_common.server_handshake import PROBE_TIMEOUT_S, ask_action_server
from abp_msgs.action import Flip, Lift, Orbit, Push, Recognize
from abp_msgs.msg import AspectObservation, Belief, ExecutedAction, PlanStep
from abp_msgs.srv import CheckFeasibility, ResetBelief

from .episode import (
    ABORTED,
    BELIEF_NODE,
    CANCELED,
    EpisodeRunner,
    RecognitionAborted,
    RuleStop,
    expected_gain,
)
from .markers import belief_markers
from .planner import PLANNER_NAMES, make_planner
from .planner_config import PLANNER_SPECS
from .stopping import STOP_RULES, StoppingRule

# Candidates a Recognize result lists.
TOP_CANDIDATES = 5
# While a skill runs: how often to check that the server that took the goal is still there.
SERVER_CHECK_S = 1.0

SKILL_TYPES = {'orbit': Orbit, 'push': Push, 'lift': Lift, 'flip': Flip}
# Planner action name -> (skill on abp/skills/<skill>, its goal).
SKILLS = {
    ExecutedAction.ORBIT_P45: ('orbit', lambda: Orbit.Goal(angle_deg=45.0)),
    ExecutedAction.ORBIT_M45: ('orbit', lambda: Orbit.Goal(angle_deg=-45.0)),
    ExecutedAction.ORBIT_P90: ('orbit', lambda: Orbit.Goal(angle_deg=90.0)),
    ExecutedAction.ORBIT_M90: ('orbit', lambda: Orbit.Goal(angle_deg=-90.0)),
    ExecutedAction.ORBIT_180: ('orbit', lambda: Orbit.Goal(angle_deg=180.0)),
    ExecutedAction.PUSH: ('push', lambda: Push.Goal(face='front')),
    ExecutedAction.LIFT: ('lift', lambda: Lift.Goal()),
    ExecutedAction.FLIP: ('flip', lambda: Flip.Goal()),
}


class PlannerNode(Node):
    def __init__(self):
        super().__init__('planner')
        values = declare_all(self, MODEL_SET_SPECS + PLANNER_SPECS)
        self.model_set = model_set_from_values(values)
        self.model_set_id = fingerprint(self.model_set)
        # The twin classes of the stopping rule depend on the model set only: once.
        self._twins = StoppingRule.for_model_set(self.model_set).node_class
        self._group = ReentrantCallbackGroup()
        self._belief_lock = threading.Condition()
        self._belief_msg = None
        self._cube_pose = None
        self._busy = threading.Lock()
        self._goal_handle = None  # the goal being executed (one at a time: _busy)
        self._known_belief_publishers = set()  # endpoint gids met in this episode
        self._skills_at_start = []  # skill servers there when the episode started
        self._mode = values['planner_mode']
        self.health = NodeHealth(self)
        self._belief_stamps = self.health.stamp_check()
        self._observation_stamps = self.health.stamp_check()

        # A deep reader: a burst on the topic must not push out the belief not yet taken.
        self._belief_sub = self.health.subscribe(
            Belief, names.BELIEF, self._on_belief, qos.LATCHED_READER,
            callback_group=self._group)
        self._observation_sub = self.health.subscribe(
            AspectObservation, names.ASPECT_OBSERVATION, self._on_observation, qos.RELIABLE,
            callback_group=self._group)
        self._plan_pub = self.create_publisher(PlanStep, names.PLAN, qos.RELIABLE)
        self._executed_pub = self.create_publisher(ExecutedAction, names.EXECUTED_ACTION,
                                                   qos.RELIABLE)
        self._markers_pub = self.create_publisher(MarkerArray, names.MARKERS, qos.LATCHED)
        # rclpy 7.1's ActionClient registers a request only after sending it, so a reply
        # processed by another executor thread in between is dropped ("Ignoring unexpected
        # goal response", ros2/rclpy#1123): the planner then took a goal the server had
        # accepted and run for a rejection. Requests are therefore made on the executor,
        # in the clients' own mutually exclusive group, where no reply can be taken meanwhile.
        self._skill_group = MutuallyExclusiveCallbackGroup()
        self._skill_clients = {
            skill: ActionClient(self, action_type, names.skill_action(skill),
                                callback_group=self._skill_group)
            for skill, action_type in SKILL_TYPES.items()
        }
        self._skill_calls = queue.SimpleQueue()
        self._skill_call_trigger = self.create_guard_condition(
            self._make_skill_calls, callback_group=self._skill_group)
        self._feasibility = self.create_client(CheckFeasibility, names.CHECK_FEASIBILITY,
                                               callback_group=self._group)
        self._reset = self.create_client(ResetBelief, names.RESET_BELIEF,
                                         callback_group=self._group)
        self._server = ActionServer(
            self, Recognize, names.RECOGNIZE, self._execute,
            goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=self._group)
        self.get_logger().info(
            f'planner ready over {self.model_set.num_models} models '
            f'(mode {values["planner_mode"]}, stopping rule {values["stopping_rule"]})')

    def _param(self, name):
        return self.get_parameter(name).value

    # -- inputs -------------------------------------------------------------------
    def _on_belief(self, msg: Belief):
        """Raises input_checks.Rejected for a belief the planner cannot plan on."""
        if msg.model_set_id and msg.model_set_id != self.model_set_id:
            raise Rejected('model_set', "belief is over a different model set than the "
                                        f"planner's ({msg.model_set_id[:12]} vs "
                                        f'{self.model_set_id[:12]}): give both nodes the '
                                        'same model-set parameters')
        check_belief(msg, self.model_set.num_nodes)
        self._belief_stamps.check(msg.header.stamp, self.health.now_ns())
        self._belief_stamps.taken(msg.header.stamp)
        with self._belief_lock:
            self._belief_msg = msg
            self._belief_lock.notify_all()
        self._publish_markers()

    def _on_observation(self, msg: AspectObservation):
        input_checks.aspect_observation(msg)
        self._observation_stamps.check(msg.header.stamp, self.health.now_ns())
        self._observation_stamps.taken(msg.header.stamp)
        if msg.hypotheses:
            self._cube_pose = (msg.header.frame_id, msg.hypotheses[0].object_pose.pose)
            self._publish_markers()

    # -- Recognize ----------------------------------------------------------------
    def _on_goal(self, goal):
        mode = goal.planner_mode or self._param('planner_mode')
        if mode not in PLANNER_NAMES:
            self.get_logger().warning(f'Recognize goal rejected: unknown planner mode {mode!r}')
            return GoalResponse.REJECT
        if goal.stopping_rule and goal.stopping_rule not in STOP_RULES:
            self.get_logger().warning('Recognize goal rejected: unknown stopping rule '
                                      f'{goal.stopping_rule!r} ({", ".join(STOP_RULES)})')
            return GoalResponse.REJECT
        if not 0.0 <= goal.target_error < 0.5 or not 0.0 <= goal.posterior_threshold < 1.0:
            self.get_logger().warning('Recognize goal rejected: target_error must be in '
                                      '[0, 0.5) and posterior_threshold in [0, 1)')
            return GoalResponse.REJECT
        if self._busy.locked():
            self.get_logger().warning('Recognize goal rejected: a recognition is running')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle):
        with self._busy:
            goal = goal_handle.request
            params = read_all(self, PLANNER_SPECS)
            self._goal_handle = goal_handle
            self._skills_at_start = []  # taken again at the episode's belief reset
            self._mode = goal.planner_mode or params['planner_mode']
            planner = make_planner(self._mode, self.model_set, alpha=params['alpha'],
                                   seed=params['planner_seed'],
                                   planning_budget_s=params['planning_budget_s'] or None)
            stopping = RuleStop(self._stopping_rule(goal, params), self.model_set.num_nodes)
            runner = EpisodeRunner(planner, self, self.model_set.num_nodes, stopping,
                                   params['observation_timeout'], self.get_logger(),
                                   node_return_timeout_s=params['node_return_timeout'],
                                   skill_failure_limit=params['skill_failure_limit'])
            started = self.get_clock().now()
            episode = runner.run()
            return self._finish(goal_handle, episode, started)

    def _stopping_rule(self, goal, params):
        """The goal's stopping rule; a field left at its zero value takes the parameter."""
        # A goal that names only a posterior threshold asks for the posterior rule.
        kind = goal.stopping_rule or ('posterior' if goal.posterior_threshold
                                      else params['stopping_rule'])
        target_error = goal.target_error or params['target_error']
        posterior = goal.posterior_threshold or params['posterior_threshold']
        return StoppingRule(kind=kind, target_error=target_error, stop_posterior=posterior,
                            max_actions=goal.max_actions or params['max_actions'],
                            observation_params=self.model_set.observation_params,
                            n_tags=self.model_set.n_tags, node_class=self._twins,
                            fault_margin=params['fault_margin'])

    def _finish(self, goal_handle, episode, started):
        result = Recognize.Result(actions_taken=episode.actions_taken, success=episode.success,
                                  reason=episode.reason)
        belief = episode.belief or Belief()
        if belief.object_ids:
            result.object_id = belief.object_ids[0]
            result.posterior = float(belief.probabilities[0])
            result.top_object_ids = list(belief.object_ids[:TOP_CANDIDATES])
            result.top_posteriors = [float(p) for p in belief.probabilities[:TOP_CANDIDATES]]
        result.elapsed = (self.get_clock().now() - started).to_msg()
        if episode.outcome == CANCELED:
            goal_handle.canceled()
        elif episode.outcome == ABORTED or not episode.success:
            # Not identified (budget spent, a node lost): never reported as a success.
            goal_handle.abort()
        else:
            goal_handle.succeed()
        self.get_logger().info(
            f'recognition finished: {result.object_id or "-"} ({result.posterior:.3f}) after '
            f'{episode.actions_taken} actions: {episode.reason}')
        return result

    # -- EpisodePorts (abp_planner.episode) ------------------------------------------
    def reset_belief(self):
        self._known_belief_publishers = self._belief_publishers()
        if not self._skills_at_start:
            self._skills_at_start = [skill for skill, client in self._skill_clients.items()
                                     if client.server_is_ready()]
        if not self._reset.wait_for_service(timeout_sec=10.0):
            raise RecognitionAborted(f'belief node not available ({names.RESET_BELIEF})')
        response = self._call(self._reset, ResetBelief.Request(), 10.0)
        if response is None or not response.success:
            raise RecognitionAborted('belief reset failed: '
                                     f'{response.message if response else "no answer"}')

    def wait_for_belief(self, predicate, timeout_s):
        deadline = time.monotonic() + timeout_s
        with self._belief_lock:
            while self._belief_msg is None or not predicate(self._belief_msg):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not rclpy.ok(context=self.context):
                    return None
                self._belief_lock.wait(min(remaining, 0.1))
            return self._belief_msg

    def latest_belief(self):
        with self._belief_lock:
            return self._belief_msg

    def cancel_requested(self):
        return self._goal_handle.is_cancel_requested

    def _belief_publishers(self):
        topic = names.absolute(names.BELIEF, self.get_namespace())
        return {bytes(info.endpoint_gid) for info in self.get_publishers_info_by_topic(topic)}

    def _skill_status_publishers(self, skill):
        topic = names.absolute(names.skill_action(skill), self.get_namespace()) + \
            '/_action/status'
        return {bytes(info.endpoint_gid) for info in self.get_publishers_info_by_topic(topic)}

    def missing_nodes(self):
        # DDS notices a killed process when its lease expires (~20 s), so a node is seen
        # gone some seconds after it died; the runner asks again before every decision.
        # A respawned belief node can appear before the dead one is seen gone: a belief
        # publisher the episode has not met counts as the old one lost (once).
        missing = []
        publishers = self._belief_publishers()
        new = publishers - self._known_belief_publishers
        self._known_belief_publishers |= publishers
        if not publishers or new:
            missing.append(BELIEF_NODE)
        if self._observation_sub.get_publisher_count() == 0:
            missing.append(f'aspect observations ({names.ASPECT_OBSERVATION})')
        # Only servers the episode started with: a graph may run a subset of the skills.
        skills = [skill for skill in self._skills_at_start
                  if not self._skill_clients[skill].server_is_ready()]
        if skills:
            missing.append(f'skill server{"s" if len(skills) > 1 else ""} '
                           f'({", ".join(names.skill_action(s) for s in skills)})')
        return missing

    def check_feasibility(self):
        if not self._param('use_feasibility'):
            return {}
        if not self._feasibility.wait_for_service(timeout_sec=2.0):
            self.get_logger().warning('feasibility service not available; assuming feasible',
                                      throttle_duration_sec=30.0)
            return {}
        response = self._call(self._feasibility, CheckFeasibility.Request(actions=list(ACTIONS)),
                              10.0)
        if response is None:
            self.get_logger().warning('feasibility service did not answer; assuming feasible')
            return {}
        return {a: (ok, reason) for a, ok, reason in
                zip(response.actions, response.feasible, response.reasons)}

    def run_skill(self, action):
        """Send the skill goal and wait for its result: (success, reason, duration msg)."""
        skill, make_goal = SKILLS[action]
        client = self._skill_clients[skill]
        timeout = self._param('skill_timeout')
        if not client.wait_for_server(timeout_sec=5.0):
            return (False, f'skill server {names.skill_action(skill)} not available',
                    Duration().to_msg())
        if not self._server_answers(client, 5.0):
            return (False, f'skill server {names.skill_action(skill)} does not answer',
                    Duration().to_msg())
        started = self.get_clock().now()
        send = self._wait_future(self._skill_request(lambda: client.send_goal_async(make_goal())),
                                 10.0)
        if send is None or not send.accepted:
            return False, f'{skill} goal rejected', Duration().to_msg()
        result_future = self._skill_request(send.get_result_async)
        deadline = time.monotonic() + timeout
        # The server that took the goal, by its status publishers: if they all leave the
        # graph (a killed server's lease ends, ~20 s), the goal died with it. A respawned
        # server answers under the same name but never knew the goal; without this the
        # episode waited for the whole skill_timeout.
        servers = self._skill_status_publishers(skill)
        next_check = time.monotonic() + SERVER_CHECK_S
        while not result_future.done():
            if servers and time.monotonic() > next_check:
                next_check = time.monotonic() + SERVER_CHECK_S
                if not servers & self._skill_status_publishers(skill):
                    return (False, f'skill server {names.skill_action(skill)} went away during '
                            'the skill (the goal is lost)',
                            (self.get_clock().now() - started).to_msg())
            if self.cancel_requested() or time.monotonic() > deadline:
                why = 'cancelled' if self.cancel_requested() else \
                    f'timed out after {timeout:.0f} s'
                self._wait_future(self._skill_request(send.cancel_goal_async), 5.0)
                self._wait_future(result_future, 10.0)
                return False, f'{skill} {why}', (self.get_clock().now() - started).to_msg()
            time.sleep(0.02)
        response = result_future.result()
        if response is None:
            return False, f'{skill} result lost', (self.get_clock().now() - started).to_msg()
        result = response.result
        return bool(result.success), result.reason, result.duration

    def publish_plan(self, decision, feasible):
        msg = PlanStep(planner_mode=self._mode, action=decision.action,
                       expected_information_gain=expected_gain(decision),
                       planning_time=decision.planning_time_s)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.candidate_actions = list(ACTIONS)
        gains = decision.information_gain
        msg.candidate_information_gains = [float(g) for g in gains] if gains is not None \
            else [float('nan')] * len(ACTIONS)
        msg.candidate_feasible = [feasible.get(a, (True, ''))[0] for a in ACTIONS]
        self._plan_pub.publish(msg)

    def publish_feedback(self, belief, decision, actions_taken):
        self._goal_handle.publish_feedback(Recognize.Feedback(
            belief=belief, chosen_action=decision.action,
            expected_information_gain=expected_gain(decision), actions_taken=actions_taken))

    def publish_executed(self, action, sequence, success, reason, duration):
        msg = ExecutedAction(action=action, sequence=sequence, success=success, reason=reason,
                             duration=duration)
        msg.header.stamp = self.get_clock().now().to_msg()
        self._executed_pub.publish(msg)

    # -- helpers ------------------------------------------------------------------
    def _skill_request(self, make_request):
        """A future of `make_request()` (an ActionClient *_async call), made on the
        executor inside the skill clients' callback group (see __init__)."""
        outer = Future()
        self._skill_calls.put((make_request, outer))
        self._skill_call_trigger.trigger()
        return outer

    def _make_skill_calls(self):
        while True:
            try:
                make_request, outer = self._skill_calls.get_nowait()
            except queue.Empty:
                return
            try:
                inner = make_request()
            except Exception as error:  # noqa: BLE001 -- handed to the waiting thread
                outer.set_exception(error)
                continue
            inner.add_done_callback(lambda done, outer=outer: self._forward(done, outer))

    def _forward(self, done, outer):
        error = done.exception()
        if error is not None:
            self.get_logger().error(f'skill request failed: {error}')
        outer.set_result(None if error is not None else done.result())

    def _wait_future(self, future, timeout):
        event = threading.Event()
        future.add_done_callback(lambda _: event.set())
        if not event.wait(timeout):
            return None
        return future.result()

    def _server_answers(self, client, timeout):
        """Handshake before a goal (abp_common.server_handshake): a goal sent while the
        server has not yet discovered this client is lost, and the planner would wait out
        the skill timeout for nothing."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            probe = self._skill_request(lambda: ask_action_server(client))
            if self._wait_future(probe, PROBE_TIMEOUT_S) is not None:
                return True
        return False

    def _call(self, client, request, timeout, attempt_s=2.0):
        """Call an idempotent service (a reset, a query), asking again every `attempt_s`:
        a reply to a client the server has not yet discovered is dropped by DDS."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            future = client.call_async(request)
            response = self._wait_future(future, min(attempt_s, max(remaining, 0.0)))
            if response is not None or time.monotonic() >= deadline:
                if response is None:
                    client.remove_pending_request(future)
                return response
            client.remove_pending_request(future)

    def _publish_markers(self):
        with self._belief_lock:
            belief = self._belief_msg
        self._markers_pub.publish(belief_markers(belief, self._cube_pose,
                                                 self.get_clock().now().to_msg()))


def check_belief(msg, num_nodes):
    """Raise input_checks.Rejected unless `msg` is a belief over `num_nodes` aspect nodes
    the planner can plan on: as many probabilities as indices (and object ids), indices
    in range, finite probabilities, at least one node."""
    n = len(msg.node_indices)
    input_checks.at_most('node indices', n, num_nodes)
    input_checks.at_most('object ids', len(msg.object_ids), num_nodes)
    if n != len(msg.node_probabilities):
        raise Rejected('size_mismatch', f'{n} node indices but {len(msg.node_probabilities)} '
                                        'node probabilities')
    if len(msg.object_ids) != len(msg.probabilities):
        raise Rejected('size_mismatch', f'{len(msg.object_ids)} object ids but '
                                        f'{len(msg.probabilities)} probabilities')
    if n == 0:
        raise Rejected('empty', 'belief without any aspect node')
    input_checks.finite('node probabilities', msg.node_probabilities)
    input_checks.finite('object probabilities', msg.probabilities)
    input_checks.finite('entropy and node floor', (msg.entropy, msg.node_floor))
    if max(msg.node_indices) >= num_nodes:
        raise Rejected('out_of_range', f'node index {max(msg.node_indices)} of {num_nodes} '
                                       'nodes')


def main(args=None):
    # Multi-threaded: the Recognize loop blocks while skill results and beliefs arrive.
    return run_node('planner', PlannerNode, args, config_errors=(ModelFileError,),
                    make_executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == '__main__':
    sys.exit(main())
