"""ROS 2 wiring of the Active Belief Planner: the `planner` node.

Action server:  abp/recognize (abp_msgs/Recognize) runs the recognition loop.
Subscribes:     abp/belief (abp_msgs/Belief, latched; the sparse node belief is what the
                planner plans on), abp/beliefs (abp_msgs/SceneBelief, latched; one belief
                per object track, for the goals with a task), abp/aspect_observation
                (cube pose for markers)
Publishes:      abp/plan (abp_msgs/PlanStep), abp/executed_action (abp_msgs/ExecutedAction),
                abp/markers (visualization_msgs/MarkerArray)
Uses:           abp/skills/{orbit,push,lift,flip} actions, abp/skills/check_feasibility,
                abp/reset_belief

(Names are relative: /abp/... without a namespace.) The decision is
`abp_planner.planner`, the episode (stop, re-plan, retry, wait for evidence)
`abp_planner.episode.EpisodeRunner`, or for a goal with a task (identify_all, find,
identify: docs/MULTI_OBJECT.md) `abp_planner.scene_episode.SceneEpisodeRunner` over
(object, action); this module moves messages and implements the
runner's `EpisodePorts` for the goal being executed; `skill_clients` sends the skill
goals, `goal_results` builds the result. A belief that is not over this model set or is
malformed (`input_checks.belief`), and malformed observations, are rejected,
counted in /diagnostics and logged at most once per few seconds per kind
(abp_common.health); the planner keeps the last good belief.
"""

import collections
import sys
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from visualization_msgs.msg import MarkerArray

from abp_belief.cube import ACTIONS
from abp_belief.model_file import ModelFileError, fingerprint
from abp_belief.model_set_config import MODEL_SET_SPECS, model_set_from_values
from abp_common import input_checks, names, qos
from abp_common.health import DIAGNOSTICS, NodeHealth, node_of_status
from abp_common.input_checks import Rejected
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all, read_all
from abp_description.robot_profile import load_profile
from abp_msgs.action import Recognize
from abp_msgs.msg import (
    AspectObservation,
    Belief,
    ExecutedAction,
    PlanStep,
    SceneBelief,
)
from abp_msgs.srv import CheckFeasibility, ResetBelief

from .belief_inbox import BeliefInbox
from .episode import (
    BELIEF_NODE,
    EpisodeRunner,
    ObservationTally,
    RecognitionAborted,
    RuleStop,
    belief_node_report,
    expected_gain,
    of_the_belief_node,
)
from .goal_results import goal_end, scene_result, single_result
from .markers import belief_markers
from .object_planner import ObjectActionPlanner
from .planner import PLANNER_NAMES, make_planner
from .planner_config import PLANNER_SPECS
from .scene_episode import SceneEpisodeRunner, task_of
from .scene_inbox import SceneInbox, ScenePorts
from .skill_clients import SkillClients, call_with_retry
from .stopping import STOP_RULES, StoppingRule
from .tasks import TaskMonitor

# The Recognize goal's task values ('' is the one-object episode of before tasks).
TASKS = ('', Recognize.Goal.TASK_IDENTIFY_ALL, Recognize.Goal.TASK_FIND,
         Recognize.Goal.TASK_IDENTIFY)


class PlannerNode(ManagedNode):
    """Configure loads the model set; activate opens the topics, the clients and the
    Recognize server (abp_common.lifecycle)."""

    def __init__(self, **kwargs):
        super().__init__('planner', **kwargs)

    def configure(self):
        values = declare_all(self, MODEL_SET_SPECS + PLANNER_SPECS)
        self._base_frame = load_profile(values['robot_profile']).frames.base   # markers
        self.model_set = model_set_from_values(values)
        self.model_set_id = fingerprint(self.model_set)
        # The twin classes of the stopping rule depend on the model set only: once.
        self._twins = StoppingRule.for_model_set(self.model_set).node_class
        self._group = ReentrantCallbackGroup()
        # One exclusive group per input topic: in the reentrant group two threads could
        # take two messages of one topic and run their callbacks out of order. After a
        # reset the belief node sends step 0 and at once step 1; taken as 1 then 0, the
        # planner skipped step 1 as "from before the reset" and waited for a correction
        # that had come (the "no belief took one" stalls of the fresh-clone runs).
        self._belief_group = MutuallyExclusiveCallbackGroup()
        self._beliefs = BeliefInbox()
        self._scenes = SceneInbox()
        self._cube_pose = None
        self._observations = ObservationTally()
        self._belief_health = None  # (values, monotonic time) of the belief node's status
        self._rejected_at_reset = collections.Counter()  # own rejections before the episode
        self._busy = threading.Lock()
        self._goal_handle = None  # the goal being executed (one at a time: _busy)
        self._known_belief_publishers = set()  # endpoint gids met in this episode
        self._skills_at_start = []  # skill servers there when the episode started
        self._mode = values['planner_mode']
        self.health = NodeHealth(self)
        # Beliefs are live, on the clock the planner runs on: one stamped more than
        # max_stamp_lag before that clock is stale, however quiet the topic has been. (Judged
        # against the newest belief as well, a belief stamped near 0 passed while the newest
        # was younger than the lag: the bad-input sweep's got an episode named wrongly.)
        self._belief_stamps = self.health.stamp_check(trust_clock=True)
        self._observation_stamps = self.health.stamp_check()
        self._ready_line = (f'planner ready over {self.model_set.num_models} models '
                            f'(mode {values["planner_mode"]}, '
                            f'stopping rule {values["stopping_rule"]})')

    def activate(self):
        # Publishers first: the latched belief can arrive, and its callback publish
        # markers, as soon as the subscription below exists.
        self._plan_pub = self.create_publisher(PlanStep, names.PLAN, qos.RELIABLE)
        self._executed_pub = self.create_publisher(ExecutedAction, names.EXECUTED_ACTION,
                                                   qos.RELIABLE)
        self._markers_pub = self.create_publisher(MarkerArray, names.MARKERS, qos.LATCHED)
        # A deep reader: a burst on the topic must not push out the belief not yet taken.
        self._belief_sub = self.health.subscribe(
            Belief, names.BELIEF, self._on_belief, qos.LATCHED_READER,
            callback_group=self._belief_group)
        self._scene_sub = self.health.subscribe(
            SceneBelief, names.BELIEFS, self._on_scene, qos.LATCHED_READER,
            callback_group=self._belief_group)
        self._skills = SkillClients(self)
        self._feasibility = self.create_client(CheckFeasibility, names.CHECK_FEASIBILITY,
                                               callback_group=self._group)
        self._reset = self.create_client(ResetBelief, names.RESET_BELIEF,
                                         callback_group=self._group)
        self._server = ActionServer(
            self, Recognize, names.RECOGNIZE, self._execute,
            goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=self._group)
        # The 10 Hz observations and every node's /diagnostics on an input node of their
        # own (abp_common.input_node: this node's multi-threaded executor woke ~20 times a
        # message); its one thread keeps each topic in order. Closed at deactivate.
        inputs = self.create_input_node().node
        self._observation_sub = self.health.subscribe(
            AspectObservation, names.ASPECT_OBSERVATION, self._on_observation, qos.RELIABLE,
            node=inputs)
        # The belief node's own account, quoted when an episode gets no observation.
        inputs.create_subscription(
            DiagnosticArray, self.resolve_topic_name(DIAGNOSTICS), self._on_diagnostics, 10)
        self.get_logger().info(self._ready_line)

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
        input_checks.belief(msg, self.model_set.num_nodes)
        self._observations.add_belief(msg.step)
        try:
            self._belief_stamps.check(msg.header.stamp, self.health.now_ns())
        except Rejected:
            if msg.step == 0:
                # The reset's own belief, refused for its stamp (a clock that jumped): the
                # corrections after it are still this episode's, so it must not hold the
                # episode back until the observation timeout.
                self._beliefs.reset_belief_refused()
            raise
        self._belief_stamps.taken(msg.header.stamp)
        if self._beliefs.offer(msg):   # else latched or in flight from before the reset
            self._publish_markers()

    def _on_scene(self, msg: SceneBelief):
        """Raises input_checks.Rejected for a scene the planner cannot plan on."""
        if msg.model_set_id and msg.model_set_id != self.model_set_id:
            raise Rejected('model_set', 'scene belief is over a different model set than '
                                        "the planner's: give both nodes the same model-set "
                                        'parameters')
        for entry in msg.objects:
            input_checks.belief(entry.belief, self.model_set.num_nodes)
        self._scenes.offer(msg)

    def _on_observation(self, msg: AspectObservation):
        input_checks.aspect_observation(msg)
        self._observation_stamps.check(msg.header.stamp, self.health.now_ns())
        self._observation_stamps.taken(msg.header.stamp)
        self._observations.add(len(msg.hypotheses), (f.type for f in msg.features))
        if msg.hypotheses:
            self._cube_pose = (msg.header.frame_id, msg.hypotheses[0].object_pose.pose,
                               msg.header.stamp)
            self._publish_markers()

    def _on_diagnostics(self, msg: DiagnosticArray):
        for status in msg.status:
            node = node_of_status(status.name)
            if node is not None and node.rsplit('/', 1)[-1] == BELIEF_NODE:
                self._belief_health = ({kv.key: kv.value for kv in status.values},
                                       time.monotonic())

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
        if goal.task not in TASKS:
            self.get_logger().warning(f'Recognize goal rejected: unknown task {goal.task[:40]!r} '
                                      f'(expected one of {", ".join(map(repr, TASKS))})')
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
            if goal.task:
                return self._execute_task(goal_handle, goal, planner, params)
            stopping = RuleStop(self._stopping_rule(goal, params), self.model_set.num_nodes)
            runner = EpisodeRunner(planner, self, self.model_set.num_nodes, stopping,
                                   params['observation_timeout'], self.get_logger(),
                                   node_return_timeout_s=params['node_return_timeout'],
                                   skill_failure_limit=params['skill_failure_limit'])
            started = self.get_clock().now()
            episode = runner.run()
            return self._finish(goal_handle, episode, started)

    def _execute_task(self, goal_handle, goal, planner, params):
        """A goal with a task: the multi-object episode (scene_episode). A goal the task
        cannot run (unknown model, missing field, a planner without gains) is aborted at
        once with the reason."""
        started = self.get_clock().now()
        try:
            task = task_of(goal.task, goal.target_model, goal.track_id, self.model_set.names)
            object_planner = ObjectActionPlanner(planner)
        except ValueError as error:
            self.get_logger().warning(f'Recognize goal aborted: {error}')
            goal_handle.abort()
            return Recognize.Result(success=False, reason=str(error),
                                    elapsed=(self.get_clock().now() - started).to_msg())
        monitor = TaskMonitor(task, self._stopping_rule(goal, params))
        ports = ScenePorts(self, self._scenes, self._beliefs,
                           lambda: rclpy.ok(context=self.context))
        runner = SceneEpisodeRunner(object_planner, ports, self.model_set, monitor,
                                    params['observation_timeout'], self.get_logger(),
                                    gather_s=params['scene_gather_s'],
                                    node_return_timeout_s=params['node_return_timeout'],
                                    skill_failure_limit=params['skill_failure_limit'])
        return self._finish_task(goal_handle, runner.run(), started)

    def _finish_task(self, goal_handle, episode, started):
        result = scene_result(episode, self.model_set.names, goal_handle.request)
        named = ', '.join(f'{o.track_id}: {o.object_id} ({o.posterior:.3f})'
                          for o in result.objects) or '-'
        self.get_logger().info(f'task {goal_handle.request.task} finished after '
                               f'{episode.actions_taken} actions ({named}): {episode.reason}')
        return self._end(goal_handle, episode, result, started)

    def _end(self, goal_handle, episode, result, started):
        result.elapsed = (self.get_clock().now() - started).to_msg()
        getattr(goal_handle, goal_end(episode))()
        return result

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
        result = single_result(episode)
        self.get_logger().info(
            f'recognition finished: {result.object_id or "-"} ({result.posterior:.3f}) after '
            f'{episode.actions_taken} actions: {episode.reason}')
        return self._end(goal_handle, episode, result, started)

    # -- EpisodePorts (abp_planner.episode) ------------------------------------------
    def reset_belief(self, track_id=''):
        """Reset every track's belief (`track_id` '', a new scene) or one track's."""
        self._known_belief_publishers = of_the_belief_node(self._belief_publishers())
        if not self._skills_at_start:
            self._skills_at_start = self._skills.ready()
        if not self._reset.wait_for_service(timeout_sec=10.0):
            raise RecognitionAborted(f'belief node not available ({names.RESET_BELIEF})')
        self._observations.reset()
        # dict(): one atomic copy while input callbacks add on other threads.
        self._rejected_at_reset = collections.Counter(dict(self.health.stats.rejected))
        # The belief node's messages arrive in order, so the first belief at step 0 from
        # now on is the reset's own; the evidence waits skip everything before it.
        self._beliefs.reset_asked()
        self._scenes.reset_asked(track_id)
        response = call_with_retry(self._reset, ResetBelief.Request(track_id=track_id), 10.0)
        if response is None or not response.success:
            self._scenes.reset_refused()
            raise RecognitionAborted('belief reset failed: '
                                     f'{response.message if response else "no answer"}')

    def wait_for_belief(self, predicate, timeout_s):
        return self._beliefs.wait(predicate, timeout_s,
                                  lambda: rclpy.ok(context=self.context))

    def belief_restarted(self):
        return self._beliefs.take_restart()

    def observations_since_reset(self):
        health = self._belief_health
        report = belief_node_report(None, 0.0) if health is None else \
            belief_node_report(health[0], time.monotonic() - health[1], names.ASPECT_OBSERVATION)
        own = [f'{n} {topic} {kind}' for (topic, kind), n in
               (collections.Counter(dict(self.health.stats.rejected))
                - self._rejected_at_reset).items()]
        rejected = f'; the planner rejected {", ".join(own)}' if own else ''
        return f'{self._observations.describe()}{rejected}; {report}'

    def latest_belief(self):
        return self._beliefs.latest()

    def cancel_requested(self):
        return self._goal_handle.is_cancel_requested

    def _belief_publishers(self):
        """{endpoint gid: (node namespace, node name)} of the publishers of the belief."""
        topic = names.absolute(names.BELIEF, self.get_namespace())
        return {bytes(info.endpoint_gid): (info.node_namespace, info.node_name)
                for info in self.get_publishers_info_by_topic(topic)}

    def missing_nodes(self):
        # DDS notices a killed process when its lease expires (~20 s), so a node is seen
        # gone some seconds after it died; the runner asks again before every decision.
        # A respawned belief node can appear before the dead one is seen gone: a belief
        # publisher of the belief node's name that the episode has not met counts as the
        # old one lost (once). Other nodes may publish beliefs too (a test, a bag replay);
        # they are neither the belief node nor its loss. The ROS graph can list an
        # endpoint (nameless at first) well after its messages flow, so a first sighting
        # is no respawn.
        missing = []
        own = of_the_belief_node(self._belief_publishers())
        new = own - self._known_belief_publishers if self._known_belief_publishers else set()
        self._known_belief_publishers |= own
        if not own or new:
            missing.append(BELIEF_NODE)
        if self._observation_sub.get_publisher_count() == 0:
            missing.append(f'aspect observations ({names.ASPECT_OBSERVATION})')
        # Only servers the episode started with: a graph may run a subset of the skills.
        ready = self._skills.ready()
        skills = [skill for skill in self._skills_at_start if skill not in ready]
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
        response = call_with_retry(self._feasibility,
                                   CheckFeasibility.Request(actions=list(ACTIONS)), 10.0)
        if response is None:
            self.get_logger().warning('feasibility service did not answer; assuming feasible')
            return {}
        return {a: (ok, reason) for a, ok, reason in
                zip(response.actions, response.feasible, response.reasons)}

    def run_skill(self, action, track_id=''):
        # The skills act on the cube in front of the robot: their goals carry no track.
        return self._skills.run(action, self._param('skill_timeout'), self.cancel_requested)

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

    def publish_feedback(self, belief, decision, actions_taken, track_id=''):
        self._goal_handle.publish_feedback(Recognize.Feedback(
            belief=belief, chosen_action=decision.action,
            expected_information_gain=expected_gain(decision), actions_taken=actions_taken,
            chosen_track_id=track_id))

    def publish_executed(self, action, sequence, success, reason, duration, track_id=''):
        msg = ExecutedAction(action=action, sequence=sequence, success=success, reason=reason,
                             duration=duration, track_id=track_id)
        msg.header.stamp = self.get_clock().now().to_msg()
        self._executed_pub.publish(msg)

    def _publish_markers(self):
        belief = self._beliefs.latest()
        self._markers_pub.publish(belief_markers(belief, self._cube_pose,
                                                 self.get_clock().now().to_msg(),
                                                 base_frame=self._base_frame))


def main(args=None):
    # Multi-threaded: the Recognize loop blocks while skill results and beliefs arrive.
    return run_node('planner', PlannerNode, args, config_errors=(ModelFileError,),
                    make_executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == '__main__':
    sys.exit(main())
