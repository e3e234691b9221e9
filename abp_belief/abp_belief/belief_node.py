"""ROS 2 wiring of the Bayes filter: the `belief` node.

Subscribes:  abp/aspect_observation (abp_msgs/AspectObservation)
             abp/executed_action    (abp_msgs/ExecutedAction)
Publishes:   abp/belief             (abp_msgs/Belief, latched: late joiners get the latest)
Services:    abp/reset_belief       (abp_msgs/ResetBelief)

(Names are relative: /abp/... without a namespace.) Inputs are checked before they reach
the evidence gate (`abp_common.input_checks`, and the model set's observation check): a
malformed observation or an unknown action is rejected, counted in /diagnostics
(`abp_common.health`) and logged at most once per few seconds per kind. The science lives in
`abp_belief.filter` / `abp_belief.modelset`, the choice of which observation corrects
in `abp_belief.evidence_gate`; this module only converts messages and parameters.
"""

import array
import sys

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.time import Time

from abp_common import input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_description.robot_profile import load_profile
from abp_msgs.msg import AspectNodeBelief, AspectObservation, Belief, ExecutedAction
from abp_msgs.srv import ResetBelief

from .belief_config import BELIEF_SPECS, BELIEF_STEP_KEY, EVIDENCE_GATE_KEY
from .cube import ACTIONS, STATES_PER_MODEL
from .evidence_gate import HELD_OBSERVATIONS, EvidenceGate
from .filter import BeliefFilter, BeliefUpdateError
from .model_file import ModelFileError, fingerprint
from .model_set_config import MODEL_SET_PARAMETERS, MODEL_SET_SPECS, model_set_from_values

# Deep enough that a replay or a busy machine does not overwrite unread inputs.
INPUTS = qos.reliable(HELD_OBSERVATIONS)


class BeliefNode(ManagedNode):
    """Configure loads the model set and the filter; activate opens the topics and the
    reset service and publishes the prior (abp_common.lifecycle)."""

    def __init__(self):
        super().__init__('belief')

    def configure(self):
        values = declare_all(self, MODEL_SET_SPECS + BELIEF_SPECS)
        self.model_set = model_set_from_values(values)
        self.filter = BeliefFilter(self.model_set)
        self._prior = None               # the last reset's prior (None: uniform)
        self.model_set_id = fingerprint(self.model_set)
        self.step = 0
        self._gate = EvidenceGate(values['correct_once_per_action'])
        base_frame = values['base_frame'] or load_profile(values['robot_profile']).frames.base
        self._frames = ('', base_frame)   # '': the base frame (unset)
        self.health = NodeHealth(self)
        # One stream of time: observations guard the actions' stamps and the reverse.
        self._stamps = self.health.stamp_check()
        self.health.add_values(self._state_values)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self.get_logger().info(
            f'belief over {self.model_set.num_models} models '
            f'({self.model_set.num_nodes} aspect nodes, {len(self.model_set.aspects)} aspects)')

    def activate(self):
        self._belief_pub = self.create_publisher(Belief, names.BELIEF, qos.LATCHED)
        self.health.subscribe(AspectObservation, names.ASPECT_OBSERVATION,
                              self._on_observation, INPUTS)
        self.health.subscribe(ExecutedAction, names.EXECUTED_ACTION,
                              self._on_executed_action, INPUTS)
        self.create_service(ResetBelief, names.RESET_BELIEF, self._on_reset)
        self._publish_belief()

    # -- parameters ---------------------------------------------------------------
    def _param(self, name):
        return self.get_parameter(name).value

    def _on_set_parameters(self, params):
        for param in params:
            if param.name in MODEL_SET_PARAMETERS:
                return SetParametersResult(
                    successful=False,
                    reason=f'{param.name} defines the model set; restart the node to change it')
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, params):
        for param in params:
            if param.name == 'correct_once_per_action':
                self._gate.once_per_action = bool(param.value)

    # -- callbacks ----------------------------------------------------------------
    def _on_observation(self, msg: AspectObservation):
        """Raises input_checks.Rejected for a malformed observation (NodeHealth counts it)."""
        input_checks.aspect_observation(msg, self._frames)
        self._stamps.check(msg.header.stamp, self.health.now_ns())
        if msg.hypotheses:
            z = _observation_of(msg)
            try:
                self.model_set.observation.normalize_observation(z)
            except ValueError as error:
                raise Rejected('out_of_range', str(error)) from None
        self._stamps.taken(msg.header.stamp)
        if not msg.hypotheses:
            self.get_logger().debug('observation without aspect hypotheses: nothing to correct')
            return
        stamp = input_checks.stamp_ns(msg.header.stamp)
        if stamp < self._gate.earliest_stamp_ns:
            self._reset_if_the_clock_went_back()
        with self.health.timed():
            if self._gate.offer(stamp, msg):
                self._correct(msg)

    def _reset_if_the_clock_went_back(self):
        """As tf2 clears its buffer on a jump back in time: a clock that went back before
        the last action's end is a new world (a restarted simulation, a bag played again),
        whose frames would all be dropped as stale until the clock came back there. The
        belief starts again from the prior (its step goes back: the planner re-observes)."""
        now_ns = self.get_clock().now().nanoseconds
        if not self._gate.clock_went_back(now_ns):
            return
        self.get_logger().warning(
            f'the clock went back to {now_ns * 1e-9:.3f} s, before the last action ended '
            f'({self._gate.earliest_stamp_ns * 1e-9:.3f} s): a restarted simulation or a '
            f'bag played again; belief reset at step {self.step}')
        self._restart(self._prior)

    def _correct(self, msg: AspectObservation):
        z = _observation_of(msg)
        try:
            self.filter.correct(z)
        except (ValueError, BeliefUpdateError) as error:
            self.health.reject(names.ASPECT_OBSERVATION, 'no_likelihood',
                               f'observation {z} ignored: {error}')
            return
        self._gate.corrected()
        self.step += 1
        self._publish_belief(msg.header.stamp)

    def _on_executed_action(self, msg: ExecutedAction):
        """Raises input_checks.Rejected for an unknown action or a bad stamp: such a
        message neither predicts nor moves the evidence gate."""
        if msg.action not in ACTIONS:
            shown = msg.action if len(msg.action) <= 40 else msg.action[:40] + '...'
            raise Rejected('unknown_id', f'executed action {shown!r} is unknown (expected one '
                                         f'of {", ".join(ACTIONS)}); belief not predicted')
        self._stamps.check(msg.header.stamp, self.health.now_ns())
        self._stamps.taken(msg.header.stamp)
        early = self._gate.action_executed(input_checks.stamp_ns(msg.header.stamp))
        if not msg.success:
            # The skill did not run to completion: the cube was not acted on as modelled.
            self.get_logger().info(f'{msg.action} failed ({msg.reason}); no prediction step')
        else:
            self.filter.predict(msg.action)
            self.step += 1
            self._publish_belief(msg.header.stamp)
        # The first frame of the new state may have overtaken this message.
        for observation in early:
            self._correct(observation)
            if not self._gate.awaiting_observation:
                break

    def _on_reset(self, request, response):
        prior = np.asarray(request.model_prior, dtype=np.float64)
        step = self.step
        try:
            self._restart(prior if prior.size else None)
        except ValueError as error:
            response.success = False
            response.message = f'reset refused: {error}'
            return response
        self.get_logger().info(f'belief reset at step {step} (a new episode)')
        response.success = True
        response.message = f'belief reset over {self.model_set.num_models} models'
        return response

    def _restart(self, prior):
        """The belief from `prior` (None: uniform), published; raises ValueError for a
        prior the filter refuses, leaving the belief as it was."""
        self.filter = BeliefFilter(self.model_set, prior)
        self._prior = prior
        self.step = 0
        self._gate.reset()
        # Stamped with the newest input taken, not with now: the corrections that follow
        # carry their frames' stamps, which trail the clock by the perception latency, and
        # a reader that compares stamps within the topic must not see it go back.
        # Never after the clock, though: a restarted simulation's clock went back.
        newest = self._stamps.newest_not_after(self.get_clock().now().nanoseconds)
        self._publish_belief(None if newest is None else Time(nanoseconds=newest).to_msg())

    # -- output -------------------------------------------------------------------
    def _state_values(self):
        """The filter's and the evidence gate's state, for /diagnostics."""
        return [(BELIEF_STEP_KEY, self.step), (EVIDENCE_GATE_KEY, self._gate.describe()),
                ('observations dropped as older than the last action',
                 self._gate.dropped_stale)]

    def _publish_belief(self, stamp=None):
        top_k = self._param('top_k')
        belief = self.filter.belief
        marginal = self.filter.object_marginal()
        order = np.argsort(-marginal, kind='stable')[:top_k]
        msg = Belief()
        msg.header.stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        msg.step = self.step
        msg.object_ids = [self.model_set.names[i] for i in order]
        msg.probabilities = marginal[order].tolist()
        msg.total_models = self.model_set.num_models
        msg.entropy = self.filter.entropy()
        node_count = min(top_k, belief.size)
        top_nodes = np.argpartition(-belief, node_count - 1)[:node_count]
        top_nodes = top_nodes[np.argsort(-belief[top_nodes], kind='stable')]
        for node in top_nodes:
            model, state = divmod(int(node), STATES_PER_MODEL)
            msg.top_nodes.append(AspectNodeBelief(
                model_index=model, object_id=self.model_set.names[model], state=state,
                probability=float(belief[node])))
        floor = self._param('node_floor')
        live = np.flatnonzero(belief >= floor * belief.max())
        # array.array from raw bytes: far faster than Python lists for 70k-node beliefs.
        msg.node_indices = array.array('I', live.astype(np.uint32).tobytes())
        msg.node_probabilities = array.array('d', belief[live].tobytes())
        msg.node_floor = floor
        msg.model_set_id = self.model_set_id
        self._belief_pub.publish(msg)


def _observation_of(msg):
    """The observation tuple z = (type, s0, s1, s2) of the best hypothesis."""
    best = msg.hypotheses[0]
    z = (int(best.aspect_type), *(int(s) for s in best.slots))
    return (*z[:3], -1) if z[0] == 2 else z


def main(args=None):
    return run_node('belief', BeliefNode, args, config_errors=(ModelFileError,))


if __name__ == '__main__':
    sys.exit(main())
