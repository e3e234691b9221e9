"""The belief node's per-object bookkeeping without ROS (abp_belief.object_tracks):

- one track (the empty id, a one-cube scene) gives the single-object filter's numbers and
  step counts, bit for bit;
- an observation or an action of one track leaves every other track as it was, evidence
  gate included;
- resetting one track, an unknown track, every track; the bound on the number of tracks;
- `visible` is "seen in the latest observation's image".
"""

import numpy as np
import pytest

from abp_belief import cube
from abp_belief.factored_belief import UnknownObjectError
from abp_belief.filter import BeliefFilter, BeliefUpdateError
from abp_belief.object_tracks import MAX_TRACK_ID_LENGTH, ObjectTracks, TrackLimitError

SCRIPT = ['ORBIT_P90', 'PUSH', 'FLIP', 'ORBIT_M45', 'LIFT']


def observations_of(model_set, true_model, rng, script=SCRIPT):
    """The observations of a true cube driven through `script` (one before any action)."""
    node = true_model * cube.STATES_PER_MODEL + int(rng.integers(cube.STATES_PER_MODEL))
    out = [model_set.observation.sample(model_set.node_aspect[node], rng)]
    for action in script:
        nxt, probs = model_set.successors(cube.ACTIONS.index(action), [node])
        node = int(rng.choice(nxt[0], p=probs[0]))
        out.append(model_set.observation.sample(model_set.node_aspect[node], rng))
    return out


def test_one_track_is_the_single_object_filter_bit_for_bit(robot):
    tracks = ObjectTracks(robot, max_tracks=4)
    single = BeliefFilter(robot)
    assert np.array_equal(tracks.prior, single.belief) and tracks.last_updated is None
    zs = observations_of(robot, 11, np.random.default_rng(1))
    t = 0
    only = tracks.track('')
    assert tracks.track('') is only and len(tracks) == 1
    assert tracks.track('').gate.offer(t, 'z0')
    tracks.correct(only, zs[0])
    single.correct(zs[0])
    step = 1
    for action, z in zip(SCRIPT, zs[1:]):
        t += 10
        assert tracks.executed(only, t, action, True) == []
        single.predict(action)
        assert np.array_equal(tracks.node_belief(only), single.belief)
        assert tracks.track('').gate.offer(t + 1, z)
        tracks.correct(only, z)
        single.correct(z)
        step += 2
        assert np.array_equal(tracks.node_belief(only), single.belief)
        assert only.step == step and tracks.last_updated is only
    assert only.actions_taken == len(SCRIPT)


def test_an_update_of_one_track_leaves_the_others_alone(robot):
    tracks = ObjectTracks(robot, max_tracks=4)
    a, b = tracks.track('a'), tracks.track('b')
    za = observations_of(robot, 3, np.random.default_rng(2))
    zb = observations_of(robot, 20, np.random.default_rng(3))
    tracks.correct(a, za[0])
    tracks.correct(b, zb[0])
    b_before = tracks.node_belief(b).copy()
    b_gate = (b.gate.awaiting_observation, b.gate.earliest_stamp_ns)
    # A's next frame is held until A's action, which releases it: B is not involved.
    assert not a.gate.offer(50, za[1])
    assert not b.gate.offer(50, zb[1])   # B's own frame waits for B's own action
    early = tracks.executed(a, 40, 'ORBIT_P90', True)
    assert early == [za[1]]
    tracks.correct(a, early[0])
    alone = BeliefFilter(robot)
    alone.correct(za[0])
    alone.predict('ORBIT_P90')
    alone.correct(za[1])
    assert np.array_equal(tracks.node_belief(a), alone.belief)
    assert np.array_equal(tracks.node_belief(b), b_before)
    assert (b.gate.awaiting_observation, b.gate.earliest_stamp_ns) == b_gate
    assert (a.step, a.actions_taken, b.step, b.actions_taken) == (3, 1, 1, 0)
    assert b.gate.held == 1


def test_a_failed_action_dates_the_frames_but_does_not_predict(robot):
    tracks = ObjectTracks(robot, max_tracks=2)
    a = tracks.track('a')
    before = tracks.node_belief(a).copy()
    assert tracks.executed(a, 100, 'LIFT', False) == []
    assert np.array_equal(tracks.node_belief(a), before)
    assert (a.step, a.actions_taken) == (0, 0) and tracks.last_updated is None
    assert not a.gate.offer(99, 'older frame') and tracks.dropped_stale == 1


def test_reset_one_track_unknown_track_and_all(robot):
    tracks = ObjectTracks(robot, max_tracks=4)
    a, b = tracks.track('a'), tracks.track('b')
    z = observations_of(robot, 5, np.random.default_rng(4))
    tracks.correct(a, z[0])
    tracks.executed(a, 10, 'PUSH', True)
    tracks.correct(b, z[0])
    b_before = tracks.node_belief(b).copy()
    tracks.reset('a', stamp='t')
    assert np.array_equal(tracks.node_belief(a), BeliefFilter(robot).belief)
    assert (a.step, a.actions_taken, a.stamp) == (0, 0, 't') and tracks.last_updated is a
    assert a.gate.awaiting_observation and a.gate.earliest_stamp_ns == 0
    assert np.array_equal(tracks.node_belief(b), b_before)
    # With a prior of its own; a bad prior changes nothing.
    weights = np.arange(1.0, robot.num_models + 1)
    tracks.reset('b', prior=weights)
    assert np.array_equal(tracks.node_belief(b), BeliefFilter(robot, weights).belief)
    with pytest.raises(ValueError, match='prior'):
        tracks.reset('a', prior=[1.0, 2.0])
    with pytest.raises(UnknownObjectError, match="no object track 'c' \\(tracks: 'a', 'b'\\)"):
        tracks.reset('c')
    assert list(tracks.tracks) == ['a', 'b']
    with pytest.raises(ValueError, match='prior'):
        tracks.restart(prior=[-1.0] * robot.num_models)
    assert list(tracks.tracks) == ['a', 'b']
    dropped = tracks.dropped_stale
    tracks.restart(prior=weights)
    assert len(tracks) == 0 and tracks.last_updated is None
    assert np.array_equal(tracks.prior, BeliefFilter(robot, weights).belief)
    assert np.array_equal(tracks.node_belief(tracks.track('a')), tracks.prior)
    assert tracks.dropped_stale == dropped


def test_the_number_of_tracks_is_bounded(robot):
    tracks = ObjectTracks(robot, max_tracks=2)
    a = tracks.track('a')
    tracks.track('b')
    with pytest.raises(TrackLimitError, match="new object track 'c' refused: already 2 "
                                              'tracks \\(max_tracks 2\\)'):
        tracks.track('c')
    assert tracks.track('c', create=False) is None and list(tracks.tracks) == ['a', 'b']
    tracks.executed(a, 1, 'FLIP', True)   # the tracks kept still update
    assert a.step == 1
    with pytest.raises(ValueError, match='at most 64'):
        tracks.track('x' * (MAX_TRACK_ID_LENGTH + 1))
    tracks.max_tracks = 3
    tracks.track('c')
    tracks.restart()
    tracks.max_tracks = 1
    tracks.track('d')
    with pytest.raises(TrackLimitError):
        tracks.track('e')


def test_visible_means_seen_in_the_latest_image(robot):
    tracks = ObjectTracks(robot, max_tracks=4)
    a, b = tracks.track('a'), tracks.track('b')
    tracks.observed(a, 100, seen=True, pose='pose a', frame='base_link', stamp='s100')
    tracks.observed(b, 100, seen=True)
    assert tracks.visible(a) and tracks.visible(b)
    assert (a.pose, a.pose_frame, a.pose_stamp) == ('pose a', 'base_link', 's100')
    assert b.pose is None   # no fit: no pose
    tracks.observed(a, 200, seen=True, pose=None)
    assert tracks.visible(a) and not tracks.visible(b)
    assert a.pose == 'pose a'   # a view without a fit keeps the last pose
    tracks.observed(None, 300, seen=False)   # an image without any cube
    assert not tracks.visible(a) and not tracks.visible(b)
    # The latest observation taken is the latest image, also when the clock went back.
    tracks.observed(b, 50, seen=True, pose='new world')
    assert tracks.visible(b) and not tracks.visible(a) and b.pose == 'new world'
    tracks.restart()
    assert tracks.newest_seen_ns is None


def test_a_correction_that_cannot_be_normalised_changes_nothing(robot):
    tracks = ObjectTracks(robot, max_tracks=2)
    a = tracks.track('a')
    before = tracks.node_belief(a).copy()
    with pytest.raises((ValueError, BeliefUpdateError)):
        tracks.correct(a, (3, 42, 1, 2))
    assert np.array_equal(tracks.node_belief(a), before)
    assert a.step == 0 and a.gate.awaiting_observation and tracks.last_updated is None


def test_once_per_action_reaches_every_gate(robot):
    tracks = ObjectTracks(robot, max_tracks=3, once_per_action=True)
    a = tracks.track('a')
    tracks.once_per_action = False
    b = tracks.track('b')
    assert not a.gate.once_per_action and not b.gate.once_per_action
