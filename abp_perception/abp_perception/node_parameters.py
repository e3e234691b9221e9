"""Parameter tables of the two perception nodes (ROS-free; the nodes declare them with
`abp_common.parameters.declare_all`).

`CAMERA_SPECS`: the `camera` node (frames from a device, video file or folder).
`DETECTOR_SPECS`: the `artag_detector` node; `DETECTOR_PARAMETERS` are the ones a running
detector is rebuilt from when they change. `MATCHER_SPECS`: the `aspect_matcher` node,
after the model-set parameters it shares with the belief node
(`abp_belief.model_set_config.MODEL_SET_SPECS`); `MATCHER_PARAMETERS` can change at run
time.
"""

from abp_common.param_spec import (
    BOOL,
    DOUBLE,
    DOUBLE_ARRAY,
    INT,
    STRING,
    STRING_ARRAY,
    ParamSpec,
)
from abp_description.robot_profile import PROFILE_SPEC

from .detector import DICTIONARY_NAMES

IMAGE_TRANSPORTS = ('raw', 'compressed')
# How the camera pose is timed: the joint state at the image stamp, or the newest one.
JOINT_STATE_LOOKUPS = ('interpolate', 'latest')

CAMERA_ENCODINGS = ('bgr8', 'mono8')

CAMERA_SPECS = (
    ParamSpec('source', STRING, '', 'Where frames come from: a V4L2 device (/dev/video0, or '
              'its index 0), a video file, or a folder of images played in sorted name '
              'order (frame_source.open_frame_source).', read_only=True),
    ParamSpec('calibration_file', STRING, '', 'Camera calibration YAML (camera_calibration '
              '/ camera_info_manager format) published as camera/camera_info; its image size '
              "must be the frames'. Empty: camera_info with the frame size only (no "
              'intrinsics: the tag detector then refuses the frames).', read_only=True),
    ParamSpec('rate', DOUBLE, 10.0, 'Frames published per second (a file or folder is '
              'played at this rate, whatever it was recorded at).', (0.1, 240.0),
              read_only=True),
    ParamSpec('frame_id', STRING, '', 'header.frame_id of the images and camera_info (the '
              "tag detector maps it with frame_map). Empty: the robot profile's camera "
              'optical frame.', read_only=True),
    PROFILE_SPEC,
    ParamSpec('encoding', STRING, 'bgr8', 'Encoding of camera/image_raw.', read_only=True,
              choices=CAMERA_ENCODINGS),
    ParamSpec('loop', BOOL, False, 'Play a video file or folder again from the start at its '
              'end (else publishing stops there).', read_only=True),
    ParamSpec('publish_compressed', BOOL, False, 'Also publish JPEG frames on '
              "camera/image_raw/compressed (image_transport's compressed transport).",
              read_only=True),
    ParamSpec('jpeg_quality', INT, 90, 'JPEG quality of the compressed frames.', (1, 100),
              read_only=True),
    ParamSpec('image_width', INT, 0, 'Capture width asked of a device, px (0: its default; '
              'with image_height).', (0, 10000), read_only=True),
    ParamSpec('image_height', INT, 0, 'Capture height asked of a device, px (0: its '
              'default; with image_width).', (0, 10000), read_only=True),
)

DETECTOR_SPECS = (
    ParamSpec('dictionary', STRING, 'DICT_4X4_50', 'ArUco dictionary (OpenCV name).',
              read_only=True, choices=DICTIONARY_NAMES),
    ParamSpec('image_transport', STRING, 'raw', "'raw': sensor_msgs/Image on camera/image_raw;"
              " 'compressed': sensor_msgs/CompressedImage (JPEG or PNG, image_transport's "
              'compressed convention) on camera/image_raw/compressed.', read_only=True,
              choices=IMAGE_TRANSPORTS),
    ParamSpec('marker_size', DOUBLE, 0.08, "Edge of a tag's black square, m.", (0.005, 2.0)),
    ParamSpec('cube_size', DOUBLE, 0.10, 'Edge of the ARcubes, m: tags on adjacent faces '
              '(centres cube_size / sqrt 2 apart) are fitted as one rigid cube and published '
              'with the poses it implies; 0 = per-tag poses only.', (0.0, 5.0)),
    PROFILE_SPEC,
    ParamSpec('base_frame', STRING, '', 'Frame of the published poses (robot base). Empty: '
              "the robot profile's base frame.", read_only=True),
    ParamSpec('camera_frame', STRING, '',
              'URDF frame of the camera, used for images and camera_info without a frame_id. '
              "Empty: the robot profile's camera optical frame.", read_only=True),
    ParamSpec('frame_map', STRING_ARRAY, None, "Camera driver frames as URDF frames: "
              "'driver_frame:urdf_frame' entries, e.g. "
              "['camera_color_optical_frame:<the URDF's optical frame>']. A frame_id neither "
              'mapped nor in the URDF is refused (camera_model.FrameMap).', read_only=True),
    ParamSpec('fixed_camera_pose', DOUBLE_ARRAY, None, 'A camera that does not move (no '
              'robot): [x, y, z, roll, pitch, yaw] (m, deg) of the camera body (x forward, '
              'y left, z up; positive pitch looks down) in base_frame, used for every image '
              'whatever its frame_id, instead of joint_states. [] = from joint_states.',
              read_only=True),
    ParamSpec('image_is_rectified', BOOL, False, 'true: the images are rectified (an '
              "image_proc 'image_rect' topic): intrinsics from camera_info's P (left 3x3), "
              'its D ignored, poses rotated back by R; false: raw images, K and D.',
              read_only=True),
    ParamSpec('joint_state_lookup', STRING, 'interpolate', "Camera pose from the joint "
              "state at the image stamp ('interpolate': linear between the buffered "
              "joint_states around it) or from the newest joint state ('latest': for "
              'senders whose stamps cannot be trusted; wrong while the head moves).',
              read_only=True, choices=JOINT_STATE_LOOKUPS),
    ParamSpec('joint_state_buffer_s', DOUBLE, 2.0, 'Seconds of joint_states kept for '
              'the lookup at image stamps (longer than the latency of the images).',
              (0.1, 60.0), read_only=True),
    ParamSpec('joint_state_tolerance_s', DOUBLE, 0.02, 'An image waits for the joint '
              'state that reaches its stamp until the next image comes; then, stamped up '
              'to this long after the newest (or before the oldest) buffered joint state, '
              'it takes that state, and further out it is refused (joint_state_stamp), s.',
              (0.0, 1.0), read_only=True),
    ParamSpec('urdf_file', STRING, '', "URDF for the kinematics; empty = the robot "
              "profile's.", read_only=True),
    ParamSpec('corner_sigma_px', DOUBLE, 0.08, 'Base corner noise of the covariance model, px.',
              (0.001, 10.0)),
    ParamSpec('max_reprojection_error', DOUBLE, 2.0, 'Drop poses with a larger RMS '
              'reprojection error, px (tags up to max_reprojection_error / '
              'max_reprojection_fraction px across; larger ones: the fraction).',
              (0.01, 100.0)),
    ParamSpec('max_reprojection_fraction', DOUBLE, 0.04, 'The RMS reprojection gate of a '
              'large tag as a fraction of its apparent side: max(max_reprojection_error, '
              'this * side px); 0 = max_reprojection_error alone.', (0.0, 0.5)),
    ParamSpec('min_side_px', DOUBLE, 6.0, 'Drop tags smaller than this in the image, px.',
              (1.0, 1000.0)),
    ParamSpec('refine_corners', BOOL, True, 'Edge-fit sub-pixel corners (else OpenCV SUBPIX).'),
    ParamSpec('second_pass', BOOL, True, 'Decode candidates that ArUco rejected, after '
              'refining.'),
    ParamSpec('face_search', BOOL, True, 'Decode the tags predicted on the cube faces next '
              'to found tags, also when blurred (needs cube_size > 0; detector.TagDetector).'),
    ParamSpec('face_search_budget_ms', DOUBLE, 30.0, 'CPU time per frame the face search '
              'and tracking may spend decoding blurred tags by correlation: a quad is tried '
              'only while its expected cost fits (~4 ms for DICT_4X4_50, ~34 ms for '
              'DICT_APRILTAG_36h11); 0 = bit decoding only.', (0.0, 1000.0)),
    ParamSpec('full_frame_every', INT, 5, 'Search the whole image every this many frames '
              '(and after a frame without tags); in between only around the last tags '
              '(detector.RegionSearch). 1 = always the whole image.', (1, 10000)),
    ParamSpec('track_tags', BOOL, True, 'Between full-frame searches, first look for the '
              "last frame's tags where they were (optical flow, edge fit, decode: no ArUco "
              'pass); ArUco searches around them only when one is lost '
              '(detector.RegionSearch).'),
)
DETECTOR_PARAMETERS = ('marker_size', 'cube_size', 'corner_sigma_px', 'max_reprojection_error',
                       'max_reprojection_fraction', 'min_side_px', 'refine_corners',
                       'second_pass', 'face_search', 'face_search_budget_ms')

MATCHER_SPECS = (
    ParamSpec('base_frame', STRING, '', 'Frame the detections must be in (robot base; its '
              "origin defines the view frame). Empty: the robot profile's base frame.",
              read_only=True),
    PROFILE_SPEC,
    ParamSpec('voxel_size', DOUBLE, 0.0, 'Hough accumulator voxel, m; 0 = cube_size / 4.',
              (0.0, 1.0)),
    ParamSpec('peak_radius', DOUBLE, 0.0, 'Votes within this distance of a peak support it, '
              'm; 0 = cube_size / 2.', (0.0, 1.0)),
    ParamSpec('orientation_sigma_deg', DOUBLE, 15.0, "Tolerance of a vote's rotation against "
              'the view frame, deg.', (1.0, 180.0)),
    ParamSpec('min_pair_score', DOUBLE, 0.05, 'Minimum Gaussian-correlation score of a vote.',
              (0.0, 1.0)),
    ParamSpec('min_support', DOUBLE, 0.05, 'Minimum support of a reported hypothesis.',
              (0.0, 100.0)),
    ParamSpec('max_hypotheses', INT, 10, 'Hypotheses per observation, best first.', (1, 1000)),
    ParamSpec('distance_samples', INT, 0, 'Sample the inter-feature distance Gaussians with '
              'this many samples (paper); 0 = propagate the covariances.', (0, 10000)),
    # Object tracks (docs/MULTI_OBJECT.md; abp_perception.object_tracks).
    ParamSpec('multi_object', BOOL, False, 'Several cubes in view: group the tags of an image '
              'into cubes, track the cubes in odom (needs /odom) and publish one '
              'AspectObservation per cube with its track_id and cube_pose. false: one '
              'observation per image with every tag, track_id empty (one cube).',
              read_only=True),
    ParamSpec('track_gate', DOUBLE, 0.15, 'multi_object: a cube seen within this distance '
              '(odom, m) of a track is that track; further away it starts a new one; within '
              'it of two tracks (or two cubes of one track) it is ambiguous: reported, not '
              'associated. Keep it under half the least cube spacing, above a push.',
              (0.01, 2.0), read_only=True),
    ParamSpec('odom_tolerance_s', DOUBLE, 0.05, 'multi_object: an image needs an /odom pose '
              'within this time of its stamp (else its tags are skipped, counted).',
              (0.0, 10.0), read_only=True),
)
MATCHER_PARAMETERS = tuple(p.name for p in MATCHER_SPECS if not p.read_only)


def matcher_options(values):
    """AspectMatcher keyword arguments from {name: value} of MATCHER_SPECS (0 = derive
    the voxel size and peak radius from the cube size)."""
    return dict(voxel_size=values['voxel_size'] or None,
                peak_radius=values['peak_radius'] or None,
                orientation_sigma_deg=values['orientation_sigma_deg'],
                min_pair_score=values['min_pair_score'], min_support=values['min_support'],
                max_hypotheses=values['max_hypotheses'],
                distance_samples=values['distance_samples'])


__all__ = ['CAMERA_ENCODINGS', 'CAMERA_SPECS', 'DETECTOR_PARAMETERS', 'DETECTOR_SPECS',
           'IMAGE_TRANSPORTS', 'JOINT_STATE_LOOKUPS', 'MATCHER_PARAMETERS', 'MATCHER_SPECS',
           'matcher_options']
