"""abp_perception: ArUco tag detection and generalised-Hough aspect matching (paper Alg. 2).

Science in plain modules (no rclpy):

- ``detector``: image conversion (no cv_bridge), ArUco detection, IPPE_SQUARE poses,
  covariances, confidences, transforms to the base frame;
- ``corners``: sub-pixel edge-fit corners and bit decoding of a quad;
- ``matcher``: the aspect-based generalised Hough transform (Alg. 2);
- ``geometry``: rotation -> quaternion for the messages;
- ``node_parameters``: the two nodes' parameter tables (abp_common ParamSpec).

ROS wiring: ``artag_detector_node`` and ``aspect_matcher_node``. The rendered test scenes
and the perception benchmark live in ``abp_bench`` (``scenes``, ``perception_benchmark``).
"""
