"""ROS 2 wiring of the aspect matcher (paper Alg. 2): the `aspect_matcher` node.

Subscribes:  abp/tag_detections    (abp_msgs/TagDetectionArray, poses in base_frame)
Publishes:   abp/aspect_observation (abp_msgs/AspectObservation: features and ranked
             aspect hypotheses, stamped like the detections)

Topic names are relative (abp_common.names). The model set is chosen by the same
parameters as the belief node (abp_belief.model_set_config.MODEL_SET_SPECS), so both
agree on the aspects; the matcher's own are `node_parameters.MATCHER_SPECS`. The science
lives in `abp_perception.matcher`. Detections that are not in `base_frame` (the detector
had no joint states yet) are skipped: the view frame needs the robot base's position.
Malformed arrays (oversized, stamps from the past or the future) and single detections
that are malformed (non-finite pose or covariance, a zero quaternion, a tag id outside
the model set) are rejected, counted in /diagnostics and logged at most once per few
seconds per kind (`abp_common.health`); an array whose every detection was rejected
publishes nothing.
"""

import sys

import numpy as np
from geometry_msgs.msg import Point, Vector3
from rcl_interfaces.msg import SetParametersResult

from abp_belief.model_file import ModelFileError
from abp_belief.model_set_config import (
    MODEL_SET_PARAMETERS,
    MODEL_SET_SPECS,
    model_set_from_values,
)
from abp_common import input_checks, names, qos
from abp_common.health import NodeHealth
from abp_common.input_checks import Rejected
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_description.frames import quaternion_from_rotation, rotation_from_quaternion
from abp_description.robot_profile import load_profile
from abp_msgs.msg import AspectHypothesis, AspectObservation, Feature, TagDetectionArray

from .matcher import AspectMatcher, normal_sigma_of
from .matcher import Feature as MatchFeature
from .node_parameters import MATCHER_PARAMETERS, MATCHER_SPECS, matcher_options

MAX_DETECTIONS = input_checks.MAX_FEATURES


class AspectMatcherNode(ManagedNode):
    """Configure loads the model set and builds the matcher; activate opens the topics."""

    def __init__(self):
        super().__init__('aspect_matcher')

    def configure(self):
        values = declare_all(self, MODEL_SET_SPECS + MATCHER_SPECS)
        # The same parameters as the belief node, so both see the same aspects.
        self.model_set = model_set_from_values(values)
        self.base_frame = values['base_frame'] or load_profile(values['robot_profile']).frames.base
        self._config = {name: values[name] for name in MATCHER_PARAMETERS}
        self.matcher = self._build_matcher(self._config)
        self.health = NodeHealth(self)
        self._stamps = self.health.stamp_check()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f'matching against {len(self.model_set.aspects)} aspects of '
            f'{self.model_set.num_models} models (n_tags={self.model_set.n_tags})')

    def activate(self):
        self._pub = self.create_publisher(AspectObservation, names.ASPECT_OBSERVATION,
                                          qos.RELIABLE)
        self.health.subscribe(TagDetectionArray, names.TAG_DETECTIONS, self._on_detections,
                              qos.RELIABLE)

    # -- parameters ---------------------------------------------------------------
    def _build_matcher(self, config):
        return AspectMatcher(self.model_set, **matcher_options(config))

    def _on_set_parameters(self, params):
        changes = {}
        for param in params:
            if param.name in MODEL_SET_PARAMETERS:
                return SetParametersResult(
                    successful=False,
                    reason=f'{param.name} defines the model set; restart the node to change it')
            if param.name in MATCHER_PARAMETERS:
                changes[param.name] = param.value
        if changes:
            config = dict(self._config, **changes)
            try:
                matcher = self._build_matcher(config)
            except ValueError as error:
                return SetParametersResult(successful=False, reason=str(error))
            self._config, self.matcher = config, matcher
        return SetParametersResult(successful=True)

    # -- callbacks ----------------------------------------------------------------
    def _on_detections(self, msg: TagDetectionArray):
        """Raises input_checks.Rejected for a malformed array (NodeHealth counts it)."""
        if msg.header.frame_id != self.base_frame:
            raise Rejected('frame', f'tag detections in frame {msg.header.frame_id!r}, need '
                                    f'{self.base_frame!r} (does the detector get '
                                    f'{self.resolve_topic_name(names.JOINT_STATES)}?)')
        input_checks.at_most('detections', len(msg.detections), MAX_DETECTIONS)
        self._stamps.check(msg.header.stamp, self.health.now_ns())
        self._stamps.taken(msg.header.stamp)
        features = []
        for det in msg.detections:
            try:
                features.append(self._feature(det, self.model_set.n_tags))
            except Rejected as rejected:
                self.health.reject(names.TAG_DETECTIONS, rejected.kind,
                                   f'tag {det.id} skipped: {rejected.detail}')
        if msg.detections and not features:
            return
        with self.health.timed():
            result = self.matcher.match(features)
        if result.ignored_ids:
            self.get_logger().debug(f'ignored tag ids outside the model set: '
                                    f'{result.ignored_ids}')
        self._pub.publish(self._to_msg(msg.header, features, result))

    @staticmethod
    def _feature(det, n_tags):
        """The matcher's feature of one detection; Rejected when it is malformed."""
        if not 0 <= det.id < n_tags:
            raise Rejected('unknown_id', f'tag id {det.id} is not in the model set '
                                         f'(0..{n_tags - 1})')
        p = det.pose.pose
        input_checks.pose('pose', p)
        input_checks.finite('pose covariance', det.pose.covariance)
        input_checks.finite('confidence', (det.confidence,))
        rot = rotation_from_quaternion(p.orientation.x, p.orientation.y, p.orientation.z,
                                       p.orientation.w)
        cov6 = np.asarray(det.pose.covariance, dtype=np.float64).reshape(6, 6)
        return MatchFeature(int(det.id), np.array([p.position.x, p.position.y, p.position.z]),
                            cov6[:3, :3].copy(), rot[:, 2].copy(), float(det.confidence),
                            normal_sigma_of(cov6))

    @staticmethod
    def _to_msg(header, features, result):
        out = AspectObservation()
        out.header = header
        for f in features:
            msg = Feature(type=int(f.tag_id))
            msg.position = Point(x=float(f.position[0]), y=float(f.position[1]),
                                 z=float(f.position[2]))
            msg.position_covariance = [float(v) for v in f.covariance.ravel()]
            msg.normal = Vector3(x=float(f.normal[0]), y=float(f.normal[1]),
                                 z=float(f.normal[2]))
            out.features.append(msg)
        for h in result.hypotheses:
            msg = AspectHypothesis()
            msg.aspect_type = int(h.aspect_type)
            msg.slots = [int(s) for s in h.slots]
            msg.support = float(h.support)
            msg.score = float(h.score)
            pose = msg.object_pose.pose
            pose.position = Point(x=float(h.position[0]), y=float(h.position[1]),
                                  z=float(h.position[2]))
            qx, qy, qz, qw = quaternion_from_rotation(h.rotation)
            pose.orientation.x, pose.orientation.y = float(qx), float(qy)
            pose.orientation.z, pose.orientation.w = float(qz), float(qw)
            msg.object_pose.covariance = [float(v) for v in h.covariance.ravel()]
            msg.feature_indices = [int(i) for i in h.feature_indices]
            out.hypotheses.append(msg)
        return out


def main(args=None):
    return run_node('aspect_matcher', AspectMatcherNode, args, config_errors=(ModelFileError,))


if __name__ == '__main__':
    sys.exit(main())
