"""ROS 2 wiring of the aspect matcher (paper Alg. 2): the `aspect_matcher` node.

Subscribes:  /abp/tag_detections    (abp_msgs/TagDetectionArray, poses in base_frame)
Publishes:   /abp/aspect_observation (abp_msgs/AspectObservation: features and ranked
             aspect hypotheses, stamped like the detections)

The model set is chosen by the same parameters as the belief node (model_file,
model_set, model_set_size, n_tags, seed), so both agree on the aspects. The science
lives in `abp_perception.matcher`. Detections that are not in `base_frame` (the
detector had no joint states yet) are skipped with a throttled warning: the view frame
needs the robot base's position.
"""

import sys

import numpy as np
from geometry_msgs.msg import Point, Vector3
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.qos import QoSProfile, QoSReliabilityPolicy

from abp_belief.io import ModelFileError
from abp_belief.model_set_params import (
    MODEL_SET_PARAMETERS,
    declare_model_set_parameters,
    load_model_set,
)
from abp_belief.node_main import run_node
from abp_msgs.msg import AspectHypothesis, AspectObservation, Feature, TagDetectionArray

from .geometry import quaternion_to_rotation, rotation_to_quaternion
from .matcher import AspectMatcher, normal_sigma_of
from .matcher import Feature as MatchFeature

RELIABLE = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)
THROTTLE_S = 5.0
MATCHER_PARAMETERS = ("voxel_size", "peak_radius", "orientation_sigma_deg", "min_pair_score",
                      "min_support", "max_hypotheses", "distance_samples")


def _range(low, high):
    return [FloatingPointRange(from_value=low, to_value=high, step=0.0)]


def _int_range(low, high):
    return [IntegerRange(from_value=low, to_value=high, step=1)]


class AspectMatcherNode(Node):
    def __init__(self):
        super().__init__("aspect_matcher")
        self._declare_parameters()
        # The same parameters as the belief node, so both see the same aspects.
        self.model_set = load_model_set(self)
        self.base_frame = self._param("base_frame")
        self._config = {name: self._param(name) for name in MATCHER_PARAMETERS}
        self.matcher = self._build_matcher(self._config)
        self._pub = self.create_publisher(AspectObservation, "/abp/aspect_observation",
                                          RELIABLE)
        self.create_subscription(TagDetectionArray, "/abp/tag_detections", self._on_detections,
                                 RELIABLE)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"matching against {len(self.model_set.aspects)} aspects of "
            f"{self.model_set.num_models} models (n_tags={self.model_set.n_tags})")

    # -- parameters ---------------------------------------------------------------
    def _declare_parameters(self):
        def declare(name, default, description, **extra):
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, **extra))

        declare_model_set_parameters(self)
        declare("base_frame", "base_link", "Frame the detections must be in (robot base; "
                "its origin defines the view frame).", read_only=True)
        declare("voxel_size", 0.0, "Hough accumulator voxel, m; 0 = cube_size / 4.",
                floating_point_range=_range(0.0, 1.0))
        declare("peak_radius", 0.0, "Votes within this distance of a peak support it, m; "
                "0 = cube_size / 2.", floating_point_range=_range(0.0, 1.0))
        declare("orientation_sigma_deg", 15.0, "Tolerance of a vote's rotation against the "
                "view frame, deg.", floating_point_range=_range(1.0, 180.0))
        declare("min_pair_score", 0.05, "Minimum Gaussian-correlation score of a vote.",
                floating_point_range=_range(0.0, 1.0))
        declare("min_support", 0.05, "Minimum support of a reported hypothesis.",
                floating_point_range=_range(0.0, 100.0))
        declare("max_hypotheses", 10, "Hypotheses per observation, best first.",
                integer_range=_int_range(1, 1000))
        declare("distance_samples", 0, "Sample the inter-feature distance Gaussians with "
                "this many samples (paper); 0 = propagate the covariances.",
                integer_range=_int_range(0, 10000))

    def _param(self, name):
        return self.get_parameter(name).value

    def _build_matcher(self, config):
        return AspectMatcher(
            self.model_set,
            voxel_size=config["voxel_size"] or None,
            peak_radius=config["peak_radius"] or None,
            orientation_sigma_deg=config["orientation_sigma_deg"],
            min_pair_score=config["min_pair_score"],
            min_support=config["min_support"],
            max_hypotheses=config["max_hypotheses"],
            distance_samples=config["distance_samples"])

    def _on_set_parameters(self, params):
        changes = {}
        for param in params:
            if param.name in MODEL_SET_PARAMETERS:
                return SetParametersResult(
                    successful=False,
                    reason=f"{param.name} defines the model set; restart the node to change it")
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
        if msg.header.frame_id != self.base_frame:
            self.get_logger().warning(
                f"tag detections in frame {msg.header.frame_id!r}, need {self.base_frame!r} "
                "(does the detector get /joint_states?): skipped",
                throttle_duration_sec=THROTTLE_S)
            return
        features = [self._feature(det) for det in msg.detections]
        result = self.matcher.match(features)
        if result.ignored_ids:
            self.get_logger().debug(f"ignored tag ids outside the model set: "
                                    f"{result.ignored_ids}")
        self._pub.publish(self._to_msg(msg.header, features, result))

    @staticmethod
    def _feature(det):
        p = det.pose.pose
        rot = quaternion_to_rotation(p.orientation.x, p.orientation.y, p.orientation.z,
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
            qx, qy, qz, qw = rotation_to_quaternion(h.rotation)
            pose.orientation.x, pose.orientation.y = float(qx), float(qy)
            pose.orientation.z, pose.orientation.w = float(qz), float(qw)
            msg.object_pose.covariance = [float(v) for v in h.covariance.ravel()]
            msg.feature_indices = [int(i) for i in h.feature_indices]
            out.hypotheses.append(msg)
        return out


def main(args=None):
    return run_node("aspect_matcher", AspectMatcherNode, args, config_errors=(ModelFileError,))


if __name__ == "__main__":
    sys.exit(main())
