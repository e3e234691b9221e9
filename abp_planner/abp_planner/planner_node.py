"""ROS 2 wiring of the Active Belief Planner: the `planner` node.

Action server:  /abp/recognize (abp_msgs/Recognize) runs the recognition loop.
Subscribes:     /abp/belief (abp_msgs/Belief, transient local; the sparse node belief
                is what the planner plans on), /abp/aspect_observation (cube pose for markers)
Publishes:      /abp/plan (abp_msgs/PlanStep), /abp/executed_action (abp_msgs/ExecutedAction),
                /abp/markers (visualization_msgs/MarkerArray)
Uses:           /abp/skills/{orbit,push,lift,flip} actions, /abp/skills/check_feasibility,
                /abp/reset_belief

The decision itself is `abp_planner.planner`; this module only moves messages.
"""

import queue
import sys
import threading
import time

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.action import ActionClient, ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.duration import Duration
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
from rclpy.task import Future
from visualization_msgs.msg import MarkerArray

from abp_belief import io as model_io
from abp_belief.cube import ACTIONS
from abp_belief.filter import BeliefFilter
from abp_belief.model_set_params import (
    declare_model_set_parameters,
    integer_range,
    load_model_set,
)
from abp_belief.node_main import run_node
from abp_msgs.action import Flip, Lift, Orbit, Push, Recognize
from abp_msgs.msg import AspectObservation, Belief, ExecutedAction, PlanStep
from abp_msgs.srv import CheckFeasibility, ResetBelief

from .markers import belief_markers
from .planner import PLANNER_NAMES, make_planner

LATCHED = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                     durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)

SKILL_TYPES = {"orbit": Orbit, "push": Push, "lift": Lift, "flip": Flip}
# Planner action name -> (skill on /abp/skills/<skill>, its goal).
SKILLS = {
    "ORBIT_P45": ("orbit", lambda: Orbit.Goal(angle_deg=45.0)),
    "ORBIT_M45": ("orbit", lambda: Orbit.Goal(angle_deg=-45.0)),
    "ORBIT_P90": ("orbit", lambda: Orbit.Goal(angle_deg=90.0)),
    "ORBIT_M90": ("orbit", lambda: Orbit.Goal(angle_deg=-90.0)),
    "ORBIT_180": ("orbit", lambda: Orbit.Goal(angle_deg=180.0)),
    "PUSH": ("push", lambda: Push.Goal(face="front")),
    "LIFT": ("lift", lambda: Lift.Goal()),
    "FLIP": ("flip", lambda: Flip.Goal()),
}


def _float_range(low, high):
    return [FloatingPointRange(from_value=low, to_value=high, step=0.0)]


class RecognitionAborted(Exception):
    """The loop cannot go on (no observation, no feasible action); the reason is the message."""


class PlannerNode(Node):
    def __init__(self):
        super().__init__("planner")
        self._declare_parameters()
        self.model_set = load_model_set(self)
        self.model_set_id = model_io.fingerprint(self.model_set)
        self._group = ReentrantCallbackGroup()
        self._belief_lock = threading.Condition()
        self._belief_msg = None
        self._cube_pose = None
        self._busy = threading.Lock()

        self.create_subscription(Belief, "/abp/belief", self._on_belief, LATCHED,
                                 callback_group=self._group)
        self.create_subscription(AspectObservation, "/abp/aspect_observation",
                                 self._on_observation, RELIABLE, callback_group=self._group)
        self._plan_pub = self.create_publisher(PlanStep, "/abp/plan", RELIABLE)
        self._executed_pub = self.create_publisher(ExecutedAction, "/abp/executed_action",
                                                   RELIABLE)
        self._markers_pub = self.create_publisher(MarkerArray, "/abp/markers", LATCHED)
        # rclpy 7.1's ActionClient registers a request only after sending it, so a reply
        # processed by another executor thread in between is dropped ("Ignoring unexpected
        # goal response", ros2/rclpy#1123): the planner then took a goal the server had
        # accepted and run for a rejection. Requests are therefore made on the executor,
        # in the clients' own mutually exclusive group, where no reply can be taken meanwhile.
        self._skill_group = MutuallyExclusiveCallbackGroup()
        self._skill_clients = {
            name: ActionClient(self, action_type, f"/abp/skills/{name}",
                               callback_group=self._skill_group)
            for name, action_type in SKILL_TYPES.items()
        }
        self._skill_calls = queue.SimpleQueue()
        self._skill_call_trigger = self.create_guard_condition(
            self._make_skill_calls, callback_group=self._skill_group)
        self._feasibility = self.create_client(CheckFeasibility, "/abp/skills/check_feasibility",
                                               callback_group=self._group)
        self._reset = self.create_client(ResetBelief, "/abp/reset_belief",
                                         callback_group=self._group)
        self._server = ActionServer(
            self, Recognize, "/abp/recognize", self._execute,
            goal_callback=self._on_goal, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=self._group)
        self.get_logger().info(
            f"planner ready over {self.model_set.num_models} models "
            f"(mode {self._param('planner_mode')})")

    # -- parameters ---------------------------------------------------------------
    def _declare_parameters(self):
        declare_model_set_parameters(self)

        def declare(name, default, description, **ranges):
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, **ranges))

        declare("planner_mode", "abp", "Default planner: " + ", ".join(PLANNER_NAMES) + ".")
        declare("alpha", 0.1, "Alg. 3 threshold on predicted aspect nodes, relative to the max.",
                floating_point_range=_float_range(0.0, 1.0))
        declare("max_actions", 30, "Default action budget of a Recognize goal.",
                integer_range=integer_range(1, 1000))
        declare("posterior_threshold", 0.95, "Default stopping posterior of a Recognize goal.",
                floating_point_range=_float_range(0.5, 0.999999))
        declare("skill_timeout", 180.0, "Seconds a skill may take before it is cancelled.",
                floating_point_range=_float_range(1.0, 3600.0))
        declare("observation_timeout", 20.0, "Seconds to wait for a fresh observation after "
                "an action before planning on the predicted belief.",
                floating_point_range=_float_range(0.1, 600.0))
        declare("use_feasibility", True, "Ask /abp/skills/check_feasibility before each "
                "decision; infeasible actions fall through to the next best.")
        declare("planner_seed", 0, "Seed of the random planner.",
                integer_range=integer_range(0, 2**31 - 1))
        if self._param("planner_mode") not in PLANNER_NAMES:
            raise ValueError(f"parameter planner_mode must be one of {', '.join(PLANNER_NAMES)}, "
                             f"got {self._param('planner_mode')!r}")

    def _param(self, name):
        return self.get_parameter(name).value

    # -- inputs -------------------------------------------------------------------
    def _on_belief(self, msg: Belief):
        if msg.model_set_id and msg.model_set_id != self.model_set_id:
            self.get_logger().error(
                "belief is over a different model set than the planner's "
                f"({msg.model_set_id[:12]} vs {self.model_set_id[:12]}): give both nodes the "
                "same model-set parameters; belief ignored", throttle_duration_sec=10.0)
            return
        with self._belief_lock:
            self._belief_msg = msg
            self._belief_lock.notify_all()
        self._publish_markers()

    def _on_observation(self, msg: AspectObservation):
        if msg.hypotheses:
            self._cube_pose = (msg.header.frame_id, msg.hypotheses[0].object_pose.pose)
            self._publish_markers()

    def _wait_for_belief(self, predicate, timeout):
        """Block until the latest belief satisfies `predicate`; returns it or None."""
        deadline = time.monotonic() + timeout
        with self._belief_lock:
            while self._belief_msg is None or not predicate(self._belief_msg):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not rclpy.ok(context=self.context):
                    return None
                self._belief_lock.wait(min(remaining, 0.1))
            return self._belief_msg

    def _belief_filter(self, msg):
        belief_filter = BeliefFilter(self.model_set)
        belief = np.zeros(self.model_set.num_nodes)
        belief[np.asarray(msg.node_indices, dtype=np.int64)] = msg.node_probabilities
        belief_filter.belief = belief / belief.sum()
        return belief_filter

    # -- Recognize ----------------------------------------------------------------
    def _on_goal(self, goal):
        mode = goal.planner_mode or self._param("planner_mode")
        if mode not in PLANNER_NAMES:
            self.get_logger().warning(f"Recognize goal rejected: unknown planner mode {mode!r}")
            return GoalResponse.REJECT
        if self._busy.locked():
            self.get_logger().warning("Recognize goal rejected: a recognition is running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle):
        with self._busy:
            return self._recognize(goal_handle)

    def _recognize(self, goal_handle):
        goal = goal_handle.request
        mode = goal.planner_mode or self._param("planner_mode")
        budget = goal.max_actions or self._param("max_actions")
        threshold = goal.posterior_threshold or self._param("posterior_threshold")
        planner = make_planner(mode, self.model_set, alpha=self._param("alpha"),
                               seed=self._param("planner_seed"))
        started = self.get_clock().now()
        actions_taken = 0
        try:
            belief = self._start_episode()
            refused_after_failure = set()
            while True:
                posterior = max(belief.probabilities) if belief.probabilities else 0.0
                if posterior >= threshold:
                    return self._finish(goal_handle, belief, actions_taken, started, True,
                                        f"posterior {posterior:.3f} >= {threshold}")
                if actions_taken >= budget:
                    return self._finish(goal_handle, belief, actions_taken, started, False,
                                        f"action budget of {budget} spent")
                if goal_handle.is_cancel_requested:
                    return self._finish(goal_handle, belief, actions_taken, started, False,
                                        "cancelled", canceled=True)
                decision, feasible = self._decide(planner, belief, refused_after_failure)
                self._publish_plan(mode, decision, feasible)
                feedback = Recognize.Feedback(belief=belief, chosen_action=decision.action,
                                              expected_information_gain=_gain(decision),
                                              actions_taken=actions_taken)
                goal_handle.publish_feedback(feedback)
                self.get_logger().info(
                    f"action {actions_taken + 1}: {decision.action} "
                    f"(IG {_gain(decision):.3f} bits, H {belief.entropy:.3f} bits, top "
                    f"{belief.object_ids[0] if belief.object_ids else '-'} {posterior:.3f})")
                step_before = belief.step
                success, reason, duration = self._run_skill(decision.action, goal_handle)
                actions_taken += 1
                self._publish_executed(decision.action, actions_taken, success, reason, duration)
                if goal_handle.is_cancel_requested:
                    return self._finish(goal_handle, belief, actions_taken, started, False,
                                        "cancelled", canceled=True)
                if success:
                    refused_after_failure.clear()
                    expected_step = step_before + 2  # prediction, then a fresh correction
                else:
                    # Re-plan without the action that just failed, once.
                    self.get_logger().warning(f"{decision.action} failed: {reason}; re-planning")
                    refused_after_failure.add(decision.action)
                    expected_step = step_before + 1  # a fresh correction only
                fresh = self._wait_for_belief(lambda b, s=expected_step: b.step >= s,
                                              self._param("observation_timeout"))
                if fresh is None:
                    self.get_logger().warning(
                        "no fresh observation after the action within "
                        f"{self._param('observation_timeout'):.1f} s; planning on the latest "
                        "belief")
                    fresh = self._wait_for_belief(lambda b: True, 1.0)
                belief = fresh
        except RecognitionAborted as error:
            self.get_logger().error(f"recognition aborted: {error}")
            with self._belief_lock:
                belief = self._belief_msg or Belief()
            return self._finish(goal_handle, belief, actions_taken, started, False, str(error),
                                aborted=True)

    def _start_episode(self):
        """Reset the belief and wait for the first observation of this episode."""
        if not self._reset.wait_for_service(timeout_sec=10.0):
            raise RecognitionAborted("belief node not available (/abp/reset_belief)")
        response = self._call(self._reset, ResetBelief.Request(), 10.0)
        if response is None or not response.success:
            raise RecognitionAborted("belief reset failed: "
                                     f"{response.message if response else 'no answer'}")
        first = self._wait_for_belief(lambda b: b.step >= 1,
                                      self._param("observation_timeout"))
        if first is None:
            raise RecognitionAborted(
                "no observation of the cube within "
                f"{self._param('observation_timeout'):.1f} s (is perception running and the "
                "cube in view?)")
        return first

    def _decide(self, planner, belief, refused_after_failure):
        """The planner's choice among the feasible actions.

        "Nothing feasible" is often transient (the skills have not yet seen a cube
        pose estimate, or the estimate is momentarily stale), so it is re-checked
        for up to observation_timeout before the recognition is aborted.
        """
        belief_filter = self._belief_filter(belief)
        deadline = time.monotonic() + self._param("observation_timeout")
        while True:
            feasible = self._check_feasibility()

            def allowed(action, feasible=feasible):
                return feasible.get(action, (True, ""))[0] and action not in refused_after_failure

            try:
                return planner.choose(belief_filter, feasible=allowed), feasible
            except RuntimeError as error:
                if refused_after_failure:
                    # Every other action is infeasible: allow a retry of the failed one.
                    refused_after_failure.clear()
                    continue
                if time.monotonic() > deadline:
                    reasons = "; ".join(f"{a}: {r}" for a, (ok, r) in feasible.items() if not ok)
                    raise RecognitionAborted(f"{error} ({reasons})") from error
                time.sleep(0.5)

    def _check_feasibility(self):
        if not self._param("use_feasibility"):
            return {}
        if not self._feasibility.wait_for_service(timeout_sec=2.0):
            self.get_logger().warning("feasibility service not available; assuming feasible",
                                      throttle_duration_sec=30.0)
            return {}
        response = self._call(self._feasibility, CheckFeasibility.Request(actions=list(ACTIONS)),
                              10.0)
        if response is None:
            self.get_logger().warning("feasibility service did not answer; assuming feasible")
            return {}
        return {a: (ok, reason) for a, ok, reason in
                zip(response.actions, response.feasible, response.reasons)}

    def _run_skill(self, action, goal_handle):
        """Send the skill goal and wait for its result: (success, reason, duration msg)."""
        skill, make_goal = SKILLS[action]
        client = self._skill_clients[skill]
        timeout = self._param("skill_timeout")
        if not client.wait_for_server(timeout_sec=5.0):
            return False, f"skill server /abp/skills/{skill} not available", Duration().to_msg()
        started = self.get_clock().now()
        send = self._wait_future(self._skill_request(lambda: client.send_goal_async(make_goal())),
                                 10.0)
        if send is None or not send.accepted:
            return False, f"{skill} goal rejected", Duration().to_msg()
        result_future = self._skill_request(send.get_result_async)
        deadline = time.monotonic() + timeout
        while not result_future.done():
            if goal_handle.is_cancel_requested or time.monotonic() > deadline:
                why = "cancelled" if goal_handle.is_cancel_requested else \
                    f"timed out after {timeout:.0f} s"
                self._wait_future(self._skill_request(send.cancel_goal_async), 5.0)
                self._wait_future(result_future, 10.0)
                return False, f"{skill} {why}", (self.get_clock().now() - started).to_msg()
            time.sleep(0.02)
        response = result_future.result()
        if response is None:
            return False, f"{skill} result lost", (self.get_clock().now() - started).to_msg()
        result = response.result
        return bool(result.success), result.reason, result.duration

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
            self.get_logger().error(f"skill request failed: {error}")
        outer.set_result(None if error is not None else done.result())

    def _wait_future(self, future, timeout):
        event = threading.Event()
        future.add_done_callback(lambda _: event.set())
        if not event.wait(timeout):
            return None
        return future.result()

    def _call(self, client, request, timeout):
        return self._wait_future(client.call_async(request), timeout)

    def _publish_plan(self, mode, decision, feasible):
        msg = PlanStep(planner_mode=mode, action=decision.action,
                       expected_information_gain=_gain(decision),
                       planning_time=decision.planning_time_s)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.candidate_actions = list(ACTIONS)
        gains = decision.information_gain
        msg.candidate_information_gains = [float(g) for g in gains] if gains is not None \
            else [float("nan")] * len(ACTIONS)
        msg.candidate_feasible = [feasible.get(a, (True, ""))[0] for a in ACTIONS]
        self._plan_pub.publish(msg)

    def _publish_executed(self, action, sequence, success, reason, duration):
        msg = ExecutedAction(action=action, sequence=sequence, success=success, reason=reason,
                             duration=duration)
        msg.header.stamp = self.get_clock().now().to_msg()
        self._executed_pub.publish(msg)

    def _publish_markers(self):
        with self._belief_lock:
            belief = self._belief_msg
        self._markers_pub.publish(belief_markers(belief, self._cube_pose,
                                                 self.get_clock().now().to_msg()))

    def _finish(self, goal_handle, belief, actions_taken, started, success, reason,
                canceled=False, aborted=False):
        result = Recognize.Result(actions_taken=actions_taken, success=success, reason=reason)
        if belief.object_ids:
            result.object_id = belief.object_ids[0]
            result.posterior = float(belief.probabilities[0])
        result.elapsed = (self.get_clock().now() - started).to_msg()
        if canceled:
            goal_handle.canceled()
        elif aborted:
            goal_handle.abort()
        else:
            goal_handle.succeed()
        self.get_logger().info(
            f"recognition finished: {result.object_id or '-'} ({result.posterior:.3f}) after "
            f"{actions_taken} actions: {reason}")
        return result


def _gain(decision):
    if decision.information_gain is None:
        return float("nan")
    return float(decision.information_gain[decision.action_index])


def main(args=None):
    # Multi-threaded: the Recognize loop blocks while skill results and beliefs arrive.
    return run_node("planner", PlannerNode, args, config_errors=(model_io.ModelFileError,),
                    make_executor=lambda: MultiThreadedExecutor(num_threads=4))


if __name__ == "__main__":
    sys.exit(main())
