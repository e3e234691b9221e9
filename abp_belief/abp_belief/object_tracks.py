"""The belief node's per-object bookkeeping (issue 37): one ATG belief per object track.
Plain Python, no rclpy.

The beliefs themselves are a `FactoredBelief` (one row per track); this module keeps,
per track, what the single-object node kept once: its evidence gate (which observation
corrects, `evidence_gate`), its step count (corrections and predictions since its reset),
the actions done on it, and where and when it was last seen. An observation or an
executed action names its track; the empty track id is the single object in front of
the robot, as before tracks existed, so a one-cube graph that never names a track gets
exactly the single-object numbers.

Tracks are made by their first observation with an aspect hypothesis, or by the first
action done on them, starting from the prior; at most `max_tracks` are kept (a further
one is refused with `TrackLimitError`). Resetting one track puts it back to the prior;
resetting all forgets every track (a new scene).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .evidence_gate import EvidenceGate
from .factored_belief import FactoredBelief, UnknownObjectError
from .filter import BeliefFilter

# Longer ids are refused: no tracker names a cube with more (and each id is in every
# /abp/beliefs message).
MAX_TRACK_ID_LENGTH = 64


class TrackLimitError(ValueError):
    """A new track would exceed the bound on the number of tracks."""


@dataclass(eq=False)
class ObjectTrack:
    """One object's bookkeeping; its belief is the FactoredBelief row of `track_id`."""
    track_id: str
    gate: EvidenceGate
    step: int = 0               # corrections and predictions since its (re)start
    actions_taken: int = 0      # successful executed actions since its (re)start
    pose: object = None         # cube pose of its latest observation with a fit (opaque)
    pose_frame: str = ''
    pose_stamp: object = None   # stamp of that observation (opaque)
    seen_ns: int | None = None  # stamp of its latest observation that saw it
    stamp: object = None        # stamp of its latest belief update (opaque)


class ObjectTracks:
    """The factored belief and every track's bookkeeping."""

    def __init__(self, model_set, max_tracks, once_per_action=True, prior=None):
        self.model_set = model_set
        self.max_tracks = int(max_tracks)
        self._once_per_action = bool(once_per_action)
        self.newest_seen_ns = None   # stamp of the latest observation (the latest image)
        self._dropped_stale_forgotten = 0
        self.tracks: dict[str, ObjectTrack] = {}
        self.last_updated: ObjectTrack | None = None   # what /abp/belief carries
        self.restart(prior)

    # -- the set of tracks --------------------------------------------------------------
    def restart(self, prior=None):
        """Forget every track; new ones start from `prior` (per-model weights; None:
        uniform). Raises ValueError for a bad prior, changing nothing."""
        belief = FactoredBelief(self.model_set, prior=prior)
        self.prior = BeliefFilter(self.model_set, prior).belief
        self.belief = belief
        self._dropped_stale_forgotten += sum(t.gate.dropped_stale for t in self.tracks.values())
        self.tracks = {}
        self.last_updated = None
        self.newest_seen_ns = None

    def __len__(self):
        return len(self.tracks)

    def __contains__(self, track_id):
        return track_id in self.tracks

    def get(self, track_id) -> ObjectTrack:
        """The track `track_id`; UnknownObjectError (a KeyError) names the known ones."""
        try:
            return self.tracks[track_id]
        except KeyError:
            known = ', '.join(repr(t) for t in self.tracks) or 'none'
            raise UnknownObjectError(f'no object track {track_id!r} (tracks: {known})') \
                from None

    def track(self, track_id, create=True) -> ObjectTrack | None:
        """The track `track_id`, made with the prior when new and `create` (else None).
        Raises ValueError for an id too long, TrackLimitError beyond `max_tracks`."""
        if len(track_id) > MAX_TRACK_ID_LENGTH:
            raise ValueError(f'track id of {len(track_id)} characters (at most '
                             f'{MAX_TRACK_ID_LENGTH})')
        if track_id in self.tracks or not create:
            return self.tracks.get(track_id)
        if len(self.tracks) >= self.max_tracks:
            raise TrackLimitError(
                f'new object track {track_id!r} refused: already {len(self.tracks)} tracks '
                f'(max_tracks {self.max_tracks}); reset the belief (all, or a track) to '
                'make room')
        self.belief.add_object(track_id)
        track = ObjectTrack(track_id, EvidenceGate(self._once_per_action))
        self.tracks[track_id] = track
        return track

    @property
    def once_per_action(self):
        return self._once_per_action

    @once_per_action.setter
    def once_per_action(self, value):
        self._once_per_action = bool(value)
        for track in self.tracks.values():
            track.gate.once_per_action = self._once_per_action

    # -- evidence ---------------------------------------------------------------------
    def observed(self, track, stamp_ns, seen, pose=None, frame='', stamp=None):
        """An observation stamped `stamp_ns` came in (after every other: observations
        arrive in the order of their images, and a clock that went back must not leave the
        latest image in the past); it saw `track` (None: no track) when `seen`, with the
        cube pose `pose` (None: no fit) in `frame`."""
        self.newest_seen_ns = stamp_ns
        if track is None or not seen:
            return
        track.seen_ns = stamp_ns
        if pose is not None:
            track.pose, track.pose_frame, track.pose_stamp = pose, frame, stamp

    def visible(self, track) -> bool:
        """Seen in the latest observation's image (its stamp)."""
        return track.seen_ns is not None and track.seen_ns == self.newest_seen_ns

    def correct(self, track, z, stamp=None):
        """Correct `track`'s belief on z (its gate has let it through). Raises ValueError
        or BeliefUpdateError, changing nothing."""
        self.belief.correct(track.track_id, z)
        track.gate.corrected()
        self._updated(track, stamp)

    def executed(self, track, stamp_ns, action, success, stamp=None):
        """An action ended at `stamp_ns` on `track`; predicts through it when `success`.
        Returns the observations of the track held by its gate that were stamped after
        the action ended (the caller corrects with them in turn, oldest first, while the
        gate awaits an observation)."""
        early = track.gate.action_executed(stamp_ns)
        if success:
            self.belief.predict(track.track_id, action)
            track.actions_taken += 1
            self._updated(track, stamp)
        return early

    def reset(self, track_id, prior=None, stamp=None):
        """Back to the prior (`prior`: per-model weights; None: uniform) for one track.
        Raises UnknownObjectError, or ValueError for a bad prior, changing nothing."""
        track = self.get(track_id)
        self.belief.reset(track_id, prior=_uniform(self.model_set) if prior is None
                          else prior)
        track.gate.reset()
        track.step, track.actions_taken, track.stamp = 0, 0, stamp
        self.last_updated = track

    def _updated(self, track, stamp):
        track.step += 1
        track.stamp = stamp
        self.last_updated = track

    # -- read-outs --------------------------------------------------------------------
    def node_belief(self, track) -> np.ndarray:
        return self.belief.belief(track.track_id)

    def version(self, track) -> int:
        return self.belief.version(track.track_id)

    @property
    def dropped_stale(self):
        """Observations dropped as older than their track's last action, since the start."""
        return self._dropped_stale_forgotten + sum(
            t.gate.dropped_stale for t in self.tracks.values())

    def describe_gate(self):
        """The gate line of the track last updated (a fresh gate's before any)."""
        gate = self.last_updated.gate if self.last_updated else EvidenceGate(
            self._once_per_action)
        return gate.describe()


def _uniform(model_set):
    return np.ones(model_set.num_models)


__all__ = ['MAX_TRACK_ID_LENGTH', 'ObjectTrack', 'ObjectTracks', 'TrackLimitError',
           'UnknownObjectError']
