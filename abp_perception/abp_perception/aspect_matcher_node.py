"""ROS 2 wiring of the aspect matcher (paper Alg. 2): the `aspect_matcher` node.

Subscribes:  abp/tag_detections    (abp_msgs/TagDetectionArray, poses in base_frame)
             odom                  (nav_msgs/Odometry; with multi_object only)
Publishes:   abp/aspect_observation (abp_msgs/AspectObservation: features and ranked
             aspect hypotheses, stamped like the detections)

With `multi_object` (several cubes in view) the tags of an image are grouped into cubes
and associated with object tracks in odom (`abp_perception.object_tracks`); each cube
gets its own observation, with its `track_id` and `cube_pose` (its centre in base_frame
and the axes of its lowest-id tag; all zero with an identity orientation for a lone tag).
An ambiguous cube is left out of that image (logged, counted in /diagnostics); an image
without tags, or without an odom pose within `odom_tolerance_s`, publishes nothing.
Without it (the default) every image gives one observation with every tag and an empty
track_id, as for one cube.

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
from geometry_msgs.msg import Point, Pose, Vector3
from nav_msgs.msg import Odometry
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
from abp_description.frames import (
    quaternion_from_rotation,
    rotation_from_quaternion,
    yaw_of_quaternion,
)
from abp_description.robot_profile import load_profile
from abp_msgs.msg import AspectHypothesis, AspectObservation, Feature, TagDetectionArray

from .matcher import AspectMatcher, normal_sigma_of
from .matcher import Feature as MatchFeature
from .node_parameters import MATCHER_PARAMETERS, MATCHER_SPECS, matcher_options
from .object_tracks import ObjectTracker, OdomBuffer, base_to_odom, group_features

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
        self.multi_object = bool(values['multi_object'])
        if self.multi_object:
            self.tracker = ObjectTracker(values['track_gate'])
            self._odom = OdomBuffer()
            self._odom_tolerance_ns = int(values['odom_tolerance_s'] * 1e9)
            self.health.add_values(lambda: [
                ('object tracks', len(self.tracker.tracks)),
                ('ambiguous cube associations (left out)', self.tracker.ambiguous_count)])
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f'matching against {len(self.model_set.aspects)} aspects of '
            f'{self.model_set.num_models} models (n_tags={self.model_set.n_tags})')

    def activate(self):
        self._pub = self.create_publisher(AspectObservation, names.ASPECT_OBSERVATION,
                                          qos.RELIABLE)
        self.health.subscribe(TagDetectionArray, names.TAG_DETECTIONS, self._on_detections,
                              qos.RELIABLE)
        if self.multi_object:
            self.health.subscribe(Odometry, names.ODOM, self._on_odom, qos.RELIABLE)

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
        features, rotations = [], []
        for det in msg.detections:
            try:
                features.append(self._feature(det, self.model_set.n_tags))
            except Rejected as rejected:
                self.health.reject(names.TAG_DETECTIONS, rejected.kind,
                                   f'tag {det.id} skipped: {rejected.detail}')
                continue
            o = det.pose.pose.orientation
            rotations.append(rotation_from_quaternion(o.x, o.y, o.z, o.w))
        if msg.detections and not features:
            return
        if self.multi_object:
            self._publish_per_cube(msg.header, features, rotations)
            return
        with self.health.timed():
            result = self.matcher.match(features)
        if result.ignored_ids:
            self.get_logger().debug(f'ignored tag ids outside the model set: '
                                    f'{result.ignored_ids}')
        self._pub.publish(self._to_msg(msg.header, features, result))

    def _on_odom(self, msg: Odometry):
        p = msg.pose.pose
        input_checks.pose('odom pose', p)
        o = p.orientation
        self._odom.add(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec,
                       p.position.x, p.position.y, yaw_of_quaternion(o.x, o.y, o.z, o.w))

    def _publish_per_cube(self, header, features, rotations):
        """One observation per cube of the image, with its track (module doc)."""
        if not features:
            return
        stamp_ns = header.stamp.sec * 10**9 + header.stamp.nanosec
        base_pose = self._odom.pose_at(stamp_ns, self._odom_tolerance_ns)
        if base_pose is None:
            raise Rejected('no_odom', f'no {self.resolve_topic_name(names.ODOM)} pose within '
                                      f'{self._odom_tolerance_ns * 1e-9:g} s of the image: '
                                      'its cubes cannot be placed in odom')
        views = group_features(features, self.model_set.cube_size, rotations=rotations)
        association = self.tracker.update(base_to_odom([v.centre for v in views], base_pose),
                                          stamp_ns)
        for reason in association.reasons:
            self.get_logger().warning(f'ambiguous cube association, left out: {reason}',
                                      throttle_duration_sec=2.0)
        for track_id in association.new_tracks:
            self.get_logger().info(f'new object track {track_id}')
        for view, track_id in zip(views, association.track_ids):
            if not track_id:
                continue
            own = [features[i] for i in view.feature_indices]
            with self.health.timed():
                result = self.matcher.match(own)
            out = self._to_msg(header, own, result)
            out.track_id = track_id
            if view.fitted:
                out.cube_pose = _pose(view.centre, view.rotation)
            self._pub.publish(out)

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


def _pose(position, rotation):
    qx, qy, qz, qw = quaternion_from_rotation(rotation)
    pose = Pose()
    pose.position = Point(x=float(position[0]), y=float(position[1]), z=float(position[2]))
    pose.orientation.x, pose.orientation.y = float(qx), float(qy)
    pose.orientation.z, pose.orientation.w = float(qz), float(qw)
    return pose


def main(args=None):
    return run_node('aspect_matcher', AspectMatcherNode, args, config_errors=(ModelFileError,))


if __name__ == '__main__':
    sys.exit(main())
