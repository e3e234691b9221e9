"""ROS 2 wiring of the Bayes filter: the `belief` node.

Subscribes:  /abp/aspect_observation (abp_msgs/AspectObservation)
             /abp/executed_action    (abp_msgs/ExecutedAction)
Publishes:   /abp/belief             (abp_msgs/Belief, transient local: late joiners get the latest)
Services:    /abp/reset_belief       (abp_msgs/ResetBelief)

The science lives in `abp_belief.filter` / `abp_belief.modelset`; this module only
converts messages and parameters.
"""

import array
import collections
import sys

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy

from abp_msgs.msg import AspectNodeBelief, AspectObservation, Belief, ExecutedAction
from abp_msgs.srv import ResetBelief

from . import io as model_io
from .cube import ACTIONS, STATES_PER_MODEL
from .filter import BeliefFilter, BeliefUpdateError
from .model_set_params import (
    MODEL_SET_PARAMETERS,
    declare_model_set_parameters,
    integer_range,
    load_model_set,
    probability_range,
)
from .node_main import run_node

LATCHED = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                     durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
# Deep enough that a replay or a busy machine does not overwrite unread inputs.
OBSERVATION_QUEUE_DEPTH = 100
INPUTS = QoSProfile(depth=OBSERVATION_QUEUE_DEPTH, reliability=QoSReliabilityPolicy.RELIABLE)


class BeliefNode(Node):
    def __init__(self):
        super().__init__("belief")
        self._declare_parameters()
        self.model_set = load_model_set(self)
        self.filter = BeliefFilter(self.model_set)
        self.model_set_id = model_io.fingerprint(self.model_set)
        self.step = 0
        # Correct once per action cycle: frames of one unchanged view are not
        # independent evidence, so after a correction further observations wait
        # for the next executed action (or a reset).
        self._awaiting_observation = True
        # Frames taken before the last action ended show the old state: skip them.
        self._earliest_observation_ns = 0
        # Observations and executed actions come on two topics, whose relative order
        # DDS does not keep. Frames stamped after the last action that arrive while
        # no correction is due wait here, in case the next action's message arrives
        # after the frames that already show its outcome.
        self._early_observations = collections.deque(maxlen=OBSERVATION_QUEUE_DEPTH)
        self._belief_pub = self.create_publisher(Belief, "/abp/belief", LATCHED)
        self.create_subscription(AspectObservation, "/abp/aspect_observation",
                                 self._on_observation, INPUTS)
        self.create_subscription(ExecutedAction, "/abp/executed_action",
                                 self._on_executed_action, INPUTS)
        self.create_service(ResetBelief, "/abp/reset_belief", self._on_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"belief over {self.model_set.num_models} models "
            f"({self.model_set.num_nodes} aspect nodes, {len(self.model_set.aspects)} aspects)")
        self._publish_belief()

    # -- parameters ---------------------------------------------------------------
    def _declare_parameters(self):
        declare_model_set_parameters(self)
        self.declare_parameter("top_k", 10, ParameterDescriptor(
            description="Number of objects and aspect nodes listed in /abp/belief.",
            integer_range=integer_range(1, 1000)))
        self.declare_parameter("node_floor", 1e-12, ParameterDescriptor(
            description="Nodes below this fraction of the most probable node are left out "
            "of the sparse belief in /abp/belief (the planner plans on the rest).",
            floating_point_range=probability_range(1e-3)))
        self.declare_parameter("correct_once_per_action", True, ParameterDescriptor(
            description="Use only the first observation after each executed action (true), "
            "or every observation message (false)."))

    def _param(self, name):
        return self.get_parameter(name).value

    def _on_set_parameters(self, params):
        for param in params:
            if param.name in MODEL_SET_PARAMETERS:
                return SetParametersResult(
                    successful=False,
                    reason=f"{param.name} defines the model set; restart the node to change it")
        return SetParametersResult(successful=True)

    # -- callbacks ----------------------------------------------------------------
    def _on_observation(self, msg: AspectObservation):
        if not msg.hypotheses:
            self.get_logger().debug("observation without aspect hypotheses: nothing to correct")
            return
        stamp_ns = _stamp_ns(msg.header.stamp)
        if stamp_ns < self._earliest_observation_ns:
            return
        if self._param("correct_once_per_action") and not self._awaiting_observation:
            self._early_observations.append((stamp_ns, msg))
            return
        self._correct(msg)

    def _correct(self, msg: AspectObservation):
        best = msg.hypotheses[0]
        z = (int(best.aspect_type), *(int(s) for s in best.slots))
        if z[0] == 2:
            z = (*z[:3], -1)
        try:
            self.filter.correct(z)
        except (ValueError, BeliefUpdateError) as error:
            self.get_logger().warning(f"observation {z} ignored: {error}")
            return
        self._awaiting_observation = False
        self.step += 1
        self._publish_belief(msg.header.stamp)

    def _on_executed_action(self, msg: ExecutedAction):
        self._earliest_observation_ns = _stamp_ns(msg.header.stamp)
        early = sorted((m for m in self._early_observations
                        if m[0] >= self._earliest_observation_ns), key=lambda m: m[0])
        self._early_observations.clear()
        if msg.action not in ACTIONS:
            self.get_logger().warning(
                f"executed action {msg.action!r} is unknown (expected one of "
                f"{', '.join(ACTIONS)}); belief not predicted")
            return
        self._awaiting_observation = True
        if not msg.success:
            # The skill did not run to completion: the cube was not acted on as modelled.
            self.get_logger().info(f"{msg.action} failed ({msg.reason}); no prediction step")
        else:
            self.filter.predict(msg.action)
            self.step += 1
            self._publish_belief(msg.header.stamp)
        # The first frame of the new state may have overtaken this message.
        for _, observation in early:
            self._correct(observation)
            if not self._awaiting_observation:
                break

    def _on_reset(self, request, response):
        prior = np.asarray(request.model_prior, dtype=np.float64)
        try:
            self.filter = BeliefFilter(self.model_set, prior if prior.size else None)
        except ValueError as error:
            response.success = False
            response.message = f"reset refused: {error}"
            return response
        self.step = 0
        self._awaiting_observation = True
        self._earliest_observation_ns = 0
        self._early_observations.clear()
        self._publish_belief()
        response.success = True
        response.message = f"belief reset over {self.model_set.num_models} models"
        return response

    # -- output -------------------------------------------------------------------
    def _publish_belief(self, stamp=None):
        top_k = self._param("top_k")
        marginal = self.filter.object_marginal()
        order = np.argsort(-marginal, kind="stable")[:top_k]
        msg = Belief()
        msg.header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        msg.step = self.step
        msg.object_ids = [self.model_set.names[i] for i in order]
        msg.probabilities = marginal[order].tolist()
        msg.total_models = self.model_set.num_models
        msg.entropy = self.filter.entropy()
        node_count = min(top_k, self.filter.belief.size)
        top_nodes = np.argpartition(-self.filter.belief, node_count - 1)[:node_count]
        top_nodes = top_nodes[np.argsort(-self.filter.belief[top_nodes], kind="stable")]
        for node in top_nodes:
            model, state = divmod(int(node), STATES_PER_MODEL)
            msg.top_nodes.append(AspectNodeBelief(
                model_index=model, object_id=self.model_set.names[model], state=state,
                probability=float(self.filter.belief[node])))
        floor = self._param("node_floor")
        live = np.flatnonzero(self.filter.belief >= floor * self.filter.belief.max())
        # array.array from raw bytes: far faster than Python lists for 70k-node beliefs.
        msg.node_indices = array.array("I", live.astype(np.uint32).tobytes())
        msg.node_probabilities = array.array("d", self.filter.belief[live].tobytes())
        msg.node_floor = floor
        msg.model_set_id = self.model_set_id
        self._belief_pub.publish(msg)


def _stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def main(args=None):
    return run_node("belief", BeliefNode, args, config_errors=(model_io.ModelFileError,))


if __name__ == "__main__":
    sys.exit(main())
