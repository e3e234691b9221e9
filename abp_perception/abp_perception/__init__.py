"""abp_perception: ArUco tag detection and generalised-Hough aspect matching (paper Alg. 2).

Science in plain modules (no rclpy):

- ``detector``: ``TagDetector``, ArUco detection and the second pass over rejected
  contours, the face search and rigid-cube fit wired together;
- ``image_encodings``: Image and CompressedImage payloads to grey (no cv_bridge), the
  image checks;
- ``tag_pose``: IPPE_SQUARE poses, covariances, confidences, the detection types;
- ``region_search``: where to search next frame (``RegionSearch``) and tracking;
- ``face_search``, ``blur_decode``, ``rigid_cube``: tags on a found tag's cube faces,
  blurred-code decoding, one rigid pose per cube;
- ``corners``: sub-pixel edge-fit corners and bit decoding of a quad;
- ``matcher``: the aspect-based generalised Hough transform (Alg. 2);
- ``geometry``: rotation -> quaternion for the messages;
- ``node_parameters``: the two nodes' parameter tables (abp_common ParamSpec).

ROS wiring: ``artag_detector_node`` and ``aspect_matcher_node``. The rendered test scenes
and the perception benchmark live in ``abp_bench`` (``scenes``, ``perception_benchmark``).
"""
