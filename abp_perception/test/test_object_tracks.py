"""Object tracks (abp_perception.object_tracks): grouping one image's tags into cubes,
odom poses at an image stamp, and the association of cubes with tracks across views."""

import numpy as np
import pytest

from abp_perception.matcher import Feature
from abp_perception.object_tracks import (
    ObjectTracker,
    OdomBuffer,
    base_to_odom,
    group_features,
)

EDGE = 0.10


def tag(tag_id, centre, normal):
    """A feature on the face of the cube at `centre` whose outward normal is `normal`."""
    normal = np.asarray(normal, float)
    position = np.asarray(centre, float) + normal * EDGE / 2
    return Feature(tag_id, position, np.eye(3) * 1e-6, normal, 1.0, 0.05)


def test_tags_of_three_cubes_with_the_same_ids_group_by_cube():
    centres = [(0.5, 0.0, 0.05), (0.7, 0.3, 0.05), (0.8, -0.2, 0.05)]
    features = []
    for c in centres:   # every cube shows tag 0 on top and tag 1 in front
        features += [tag(0, c, (0, 0, 1)), tag(1, c, (-1, 0, 0))]
    features.append(tag(2, centres[2], (0, -1, 0)))   # a third face of the last cube
    views = group_features(features, EDGE)
    assert [v.feature_indices for v in views] == [[0, 1], [2, 3], [4, 5, 6]]
    np.testing.assert_allclose([v.centre for v in views], centres, atol=1e-12)
    assert all(v.fitted for v in views)
    lone = group_features([tag(3, centres[0], (0, 0, 1))], EDGE)
    assert len(lone) == 1 and not lone[0].fitted


def test_a_tag_with_a_flipped_normal_stays_with_its_cube():
    """A lone tag's pose can take IPPE's mirrored tilt: its implied centre moves by
    centimetres, its own centre does not; the grouping goes by the tag centres."""
    centre = np.array([0.8, -0.2, 0.05])
    top, front = tag(0, centre, (0, 0, 1)), tag(1, centre, (-1, 0, 0))
    tilted = np.array([-np.cos(np.radians(70)), 0.0, np.sin(np.radians(70))])
    front = Feature(1, front.position, front.covariance, tilted, 1.0, 0.05)
    views = group_features([top, front], EDGE)
    assert len(views) == 1 and views[0].feature_indices == [0, 1]
    assert np.linalg.norm(views[0].centre - centre) < 0.04   # half of its 6 cm error


def test_a_cube_keeps_its_track_across_views_and_a_push_within_the_gate():
    tracker = ObjectTracker(gate=0.15)
    first = tracker.update([[0.5, 0.0, 0.05], [0.7, 0.3, 0.05]], 1)
    assert first.track_ids == ['cube1', 'cube2'] and first.new_tracks == ['cube1', 'cube2']
    # The next view sees them in the other order; cube1 was pushed 6 cm, cube2 flipped
    # (its centre rolled 5 cm towards the robot).
    moved = tracker.update([[0.65, 0.3, 0.05], [0.56, 0.0, 0.05]], 2)
    assert moved.track_ids == ['cube2', 'cube1'] and not moved.new_tracks
    np.testing.assert_allclose(tracker.track('cube1').position, [0.56, 0.0, 0.05])
    # A cube beyond every gate starts a new track.
    third = tracker.update([[1.2, 0.0, 0.05]], 3)
    assert third.track_ids == ['cube3']


def test_a_cube_out_of_view_keeps_its_track():
    tracker = ObjectTracker(gate=0.15)
    tracker.update([[0.5, 0.0, 0.05], [0.7, 0.3, 0.05]], 1)
    only_second = tracker.update([[0.7, 0.31, 0.05]], 2)   # cube1 out of view
    assert only_second.track_ids == ['cube2']
    assert [t.track_id for t in tracker.tracks] == ['cube1', 'cube2']
    back = tracker.update([[0.5, 0.01, 0.05]], 3)
    assert back.track_ids == ['cube1'] and tracker.track('cube1').last_seen_ns == 3


def test_an_ambiguous_association_is_reported_not_guessed():
    tracker = ObjectTracker(gate=0.15)
    tracker.update([[0.5, 0.0, 0.05], [0.7, 0.0, 0.05]], 1)
    # Midway between two tracks, within the gate of both.
    between = tracker.update([[0.6, 0.0, 0.05]], 2)
    assert between.track_ids == [''] and between.ambiguous == [0] and not between.new_tracks
    assert 'cube1' in between.reasons[0] and 'cube2' in between.reasons[0]
    assert tracker.ambiguous_count == 1
    # Two cubes of one image within the gate of one track: neither is associated.
    split = tracker.update([[0.45, 0.0, 0.05], [0.55, 0.05, 0.05], [0.7, 0.0, 0.05]], 3)
    assert split.track_ids == ['', '', 'cube2'] and split.ambiguous == [0, 1]
    assert 'track cube1' in split.reasons[0]
    assert tracker.ambiguous_count == 3
    np.testing.assert_allclose(tracker.track('cube1').position, [0.5, 0.0, 0.05])
    assert len(tracker.tracks) == 2


def test_odom_buffer_interpolates_at_the_image_stamp_and_refuses_a_gap():
    odom = OdomBuffer()
    odom.add(1_000_000_000, 0.0, 0.0, np.pi - 0.1)
    odom.add(1_040_000_000, 0.4, 0.0, -np.pi + 0.1)
    mid = odom.pose_at(1_020_000_000, 50_000_000)
    np.testing.assert_allclose(mid[:2], [0.2, 0.0])
    assert abs(abs(mid[2]) - np.pi) < 1e-9   # through +-pi, not through 0
    np.testing.assert_allclose(odom.pose_at(1_040_000_000, 0), [0.4, 0.0, -np.pi + 0.1])
    assert odom.pose_at(2_000_000_000, 50_000_000) is None
    odom.add(10, 1.0, 1.0, 0.0)   # time went back: the old poses are forgotten
    assert odom.pose_at(1_000_000_000, 50_000_000) is None


def test_base_frame_points_go_to_odom():
    points = base_to_odom([[1.0, 0.0, 0.05]], (2.0, 1.0, np.pi / 2))
    np.testing.assert_allclose(points, [[2.0, 2.0, 0.05]], atol=1e-12)


def test_bad_gate_is_refused():
    with pytest.raises(ValueError, match='gate'):
        ObjectTracker(gate=0.0)
