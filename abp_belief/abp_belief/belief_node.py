"""ROS 2 wiring of the Bayes filter: the `belief` node.

Subscribes:  abp/aspect_observation (abp_msgs/AspectObservation)
             abp/executed_action    (abp_msgs/ExecutedAction)
Publishes:   abp/belief             (abp_msgs/Belief, latched: late joiners get the latest)
             abp/beliefs            (abp_msgs/SceneBelief, latched)
Services:    abp/reset_belief       (abp_msgs/ResetBelief)

One ATG belief per object track (issue 37, docs/MULTI_OBJECT.md): an observation or an
executed action names its track (`track_id`), and corrects or predicts that object's
belief only; the empty track id is the single object of a one-cube scene. Each track
has its own evidence gate and step count (`abp_belief.object_tracks`). /abp/beliefs
carries every object's belief at each update; /abp/belief the belief of the object
updated last (with one object: the single-object belief, as before tracks). The pose of
an object is its latest observation's `cube_pose`, in that observation's frame (the
node has no tf; an empty frame is written as the base frame).

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
from abp_msgs.msg import (
    AspectNodeBelief,
    AspectObservation,
    Belief,
    ExecutedAction,
    ObjectBelief,
    SceneBelief,
)
from abp_msgs.srv import ResetBelief

from .belief_config import BELIEF_SPECS, BELIEF_STEP_KEY, EVIDENCE_GATE_KEY
from .cube import ACTIONS, STATES_PER_MODEL
from .evidence_gate import HELD_OBSERVATIONS
from .filter import BeliefUpdateError, entropy_bits
from .model_file import ModelFileError, fingerprint
from .model_set_config import MODEL_SET_PARAMETERS, MODEL_SET_SPECS, model_set_from_values
from .object_tracks import ObjectTracks, TrackLimitError, UnknownObjectError

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
        self.tracks = ObjectTracks(self.model_set, values['max_tracks'],
                                   values['correct_once_per_action'])
        self._prior = None               # the last reset's prior (None: uniform)
        self.model_set_id = fingerprint(self.model_set)
        self._messages = {}   # track id -> ((belief version, top_k, floor), its Belief)
        base_frame = values['base_frame'] or load_profile(values['robot_profile']).frames.base
        self._base_frame = base_frame
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
        self._scene_pub = self.create_publisher(SceneBelief, names.BELIEFS, qos.LATCHED)
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
                self.tracks.once_per_action = bool(param.value)
            elif param.name == 'max_tracks':
                self.tracks.max_tracks = int(param.value)   # tracks beyond it are kept

    # -- callbacks ----------------------------------------------------------------
    def _on_observation(self, msg: AspectObservation):
        """Raises input_checks.Rejected for a malformed observation (NodeHealth counts it)."""
        input_checks.aspect_observation(msg, self._frames)
        input_checks.pose('cube pose', msg.cube_pose)
        self._stamps.check(msg.header.stamp, self.health.now_ns())
        if msg.hypotheses:
            z = _observation_of(msg)
            try:
                self.model_set.observation.normalize_observation(z)
            except ValueError as error:
                raise Rejected('out_of_range', str(error)) from None
        # Only an observation with something to correct makes a new track.
        track = self._track(msg.track_id, create=bool(msg.hypotheses))
        self._stamps.taken(msg.header.stamp)
        stamp_ns = input_checks.stamp_ns(msg.header.stamp)
        if msg.hypotheses and stamp_ns < track.gate.earliest_stamp_ns \
                and self._reset_if_the_clock_went_back(track):
            track = self._track(msg.track_id, create=True)   # in the new world
        self.tracks.observed(track, stamp_ns, seen=bool(msg.hypotheses or msg.features),
                             pose=_fitted_pose(msg.cube_pose),
                             frame=msg.header.frame_id or self._base_frame,
                             stamp=msg.header.stamp)
        if not msg.hypotheses:
            self.get_logger().debug('observation without aspect hypotheses: nothing to correct')
            return
        with self.health.timed():
            if track.gate.offer(stamp_ns, msg):
                self._correct(track, msg)

    def _reset_if_the_clock_went_back(self, track):
        """As tf2 clears its buffer on a jump back in time: a clock that went back before
        the end of the last action on the observed track is a new world (a restarted
        simulation, a bag played again), whose frames would all be dropped as stale until
        the clock came back there. Every object's belief starts again from the prior, the
        tracks are forgotten (their steps go back: the planner re-observes). True if so."""
        now_ns = self.get_clock().now().nanoseconds
        if not track.gate.clock_went_back(now_ns):
            return False
        on = f' on track {track.track_id!r}' if track.track_id else ''
        self.get_logger().warning(
            f'the clock went back to {now_ns * 1e-9:.3f} s, before the last action{on} '
            f'ended ({track.gate.earliest_stamp_ns * 1e-9:.3f} s): a restarted simulation '
            f'or a bag played again; belief reset at step {track.step}')
        self._restart(self._prior)
        return True

    def _track(self, track_id, create):
        """The object track named by an input (None: unknown and not `create`); Rejected
        for an id too long or a new track beyond max_tracks."""
        try:
            return self.tracks.track(track_id, create)
        except TrackLimitError as error:
            raise Rejected('too_many_tracks', str(error)) from None
        except ValueError as error:
            raise Rejected('oversized', str(error)) from None

    def _correct(self, track, msg: AspectObservation):
        z = _observation_of(msg)
        try:
            self.tracks.correct(track, z, msg.header.stamp)
        except (ValueError, BeliefUpdateError) as error:
            self.health.reject(names.ASPECT_OBSERVATION, 'no_likelihood',
                               f'observation {z} ignored: {error}')
            return
        self._publish_belief(msg.header.stamp)

    def _on_executed_action(self, msg: ExecutedAction):
        """Raises input_checks.Rejected for an unknown action or a bad stamp: such a
        message neither predicts nor moves the evidence gate."""
        if msg.action not in ACTIONS:
            shown = msg.action if len(msg.action) <= 40 else msg.action[:40] + '...'
            raise Rejected('unknown_id', f'executed action {shown!r} is unknown (expected one '
                                         f'of {", ".join(ACTIONS)}); belief not predicted')
        self._stamps.check(msg.header.stamp, self.health.now_ns())
        # An action on a cube not seen yet starts its track: its gate must date the
        # frames (older ones show the cube before the action).
        track = self._track(msg.track_id, create=True)
        self._stamps.taken(msg.header.stamp)
        # The skill did not run to completion (no success): the cube was not acted on as
        # modelled, so no prediction.
        early = self.tracks.executed(track, input_checks.stamp_ns(msg.header.stamp),
                                     msg.action, msg.success, msg.header.stamp)
        if not msg.success:
            on = f' on track {track.track_id!r}' if track.track_id else ''
            self.get_logger().info(f'{msg.action}{on} failed ({msg.reason}); no prediction '
                                   'step')
        else:
            self._publish_belief(msg.header.stamp)
        # The first frame of the new state may have overtaken this message.
        for observation in early:
            self._correct(track, observation)
            if not track.gate.awaiting_observation:
                break

    def _on_reset(self, request, response):
        prior = np.asarray(request.model_prior, dtype=np.float64)
        prior = prior if prior.size else None
        track_id = request.track_id
        step = self.tracks.last_updated.step if self.tracks.last_updated else 0
        try:
            if track_id:
                step = self.tracks.get(track_id).step
                self.tracks.reset(track_id, prior, self._reset_stamp())
                self._publish_belief(self._reset_stamp())
            else:
                self._restart(prior)   # a new scene: every track is forgotten
        except UnknownObjectError as error:
            response.success = False
            response.message = f'reset refused: {error.args[0]}'
            return response
        except ValueError as error:
            response.success = False
            response.message = f'reset refused: {error}'
            return response
        what = f'belief of track {track_id!r}' if track_id else 'belief'
        self.get_logger().info(f'{what} reset at step {step} (a new episode)')
        response.success = True
        response.message = f'{what} reset over {self.model_set.num_models} models'
        return response

    def _restart(self, prior):
        """Every track forgotten, new ones from `prior` (None: uniform), published; raises
        ValueError for a prior the filter refuses, leaving the beliefs as they were."""
        self.tracks.restart(prior)
        self._prior = prior
        self._messages.clear()   # new tracks count their versions from 0
        self._publish_belief(self._reset_stamp())

    def _reset_stamp(self):
        """Stamp of a reset belief: the newest input taken, not now. The corrections that
        follow carry their frames' stamps, which trail the clock by the perception latency,
        and a reader that compares stamps within the topic must not see it go back. Never
        after the clock, though: a restarted simulation's clock went back."""
        newest = self._stamps.newest_not_after(self.get_clock().now().nanoseconds)
        return None if newest is None else Time(nanoseconds=newest).to_msg()

    # -- output -------------------------------------------------------------------
    def _state_values(self):
        """The filter's and the evidence gate's state, for /diagnostics."""
        last = self.tracks.last_updated
        return [(BELIEF_STEP_KEY, last.step if last else 0),
                (EVIDENCE_GATE_KEY, self.tracks.describe_gate()),
                ('observations dropped as older than the last action',
                 self.tracks.dropped_stale),
                ('object tracks', f'{len(self.tracks)} (at most {self.tracks.max_tracks})')]

    def _publish_belief(self, stamp=None):
        """/abp/belief (the object updated last; the prior before any) and /abp/beliefs."""
        stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        last = self.tracks.last_updated
        if last is None:
            self._belief_pub.publish(self._belief_message(self.tracks.prior, 0, stamp))
        else:
            self._belief_pub.publish(self._object_message(last))
        scene = SceneBelief(model_set_id=self.model_set_id)
        scene.header.stamp = stamp
        for track in self.tracks.tracks.values():
            entry = ObjectBelief(track_id=track.track_id, actions_taken=track.actions_taken,
                                 visible=self.tracks.visible(track),
                                 belief=self._object_message(track))
            if track.pose is not None:
                entry.pose.pose = track.pose
                entry.pose.header.frame_id = track.pose_frame
                entry.pose.header.stamp = track.pose_stamp
            scene.objects.append(entry)
        self._scene_pub.publish(scene)

    def _object_message(self, track):
        """The track's Belief message, made again only when its belief changed."""
        key = (self.tracks.version(track), self._param('top_k'), self._param('node_floor'))
        cached = self._messages.get(track.track_id)
        if cached is None or cached[0] != key:
            stamp = track.stamp if track.stamp is not None else \
                self.get_clock().now().to_msg()
            cached = (key, self._belief_message(self.tracks.node_belief(track), track.step,
                                                stamp))
            self._messages[track.track_id] = cached
        return cached[1]

    def _belief_message(self, belief, step, stamp):
        top_k = self._param('top_k')
        marginal = belief.reshape(self.model_set.num_models, STATES_PER_MODEL).sum(axis=1)
        order = np.argsort(-marginal, kind='stable')[:top_k]
        msg = Belief()
        msg.header.stamp = stamp
        msg.step = step
        msg.object_ids = [self.model_set.names[i] for i in order]
        msg.probabilities = marginal[order].tolist()
        msg.total_models = self.model_set.num_models
        msg.entropy = entropy_bits(marginal)
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
        return msg


def _observation_of(msg):
    """The observation tuple z = (type, s0, s1, s2) of the best hypothesis."""
    best = msg.hypotheses[0]
    z = (int(best.aspect_type), *(int(s) for s in best.slots))
    return (*z[:3], -1) if z[0] == 2 else z


def _fitted_pose(pose):
    """The observation's cube pose, or None when no fit was possible (all zero with an
    identity orientation, AspectObservation.msg)."""
    p, o = pose.position, pose.orientation
    if (p.x, p.y, p.z, o.x, o.y, o.z, o.w) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0):
        return None
    return pose


def main(args=None):
    return run_node('belief', BeliefNode, args, config_errors=(ModelFileError,))


if __name__ == '__main__':
    sys.exit(main())
