"""Object tracks: which cube each tag detection belongs to, across views (no rclpy).

Several ARcubes share tag ids (every cube of a model set carries tags 0..n-1), so a tag id
does not name a cube: its position does. The aspect matcher node runs, per image:

1. `group_features`: the tags of one image grouped into cubes: tags whose centres lie
   within `link` (default one edge) of each other, transitively, are one cube. Tags on
   adjacent faces of a cube are an edge / sqrt 2 apart, tags of two cubes at least the
   cubes' spacing less an edge (0.2 m in the sim); tag centres come from range and image
   position, which a wrong tilt (a lone tag's IPPE flip) hardly moves, so the grouping
   does not use the normals. A cube's centre is the mean of the centres its tags imply,
   half an edge behind each face (`position - normal * cube_size / 2`: one point for the
   tags of a rigid cube fit). A group of >= 2 tags has a fitted pose (`CubeView.fitted`).
2. `OdomBuffer.pose_at`: the base's odom pose at the image stamp (from /odom), so that the
   cube centres, measured in the base frame, become positions in `odom` that stay put
   while the robot drives around them.
3. `ObjectTracker.update`: the cubes of the image associated with the tracks, by
   distance in `odom` with a gate. A cube with no track within the gate starts a new
   track; a track keeps its id when its cube moved less than the gate (pushed, flipped)
   and when it is out of view (tracks are never dropped; `reset` forgets them all).
   An association that cannot be made with confidence is *reported, not guessed*: a
   cube with two or more tracks within the gate, or a track with two or more cubes of
   the image within the gate, leaves every cube involved unassociated for this image
   (`Association.ambiguous`, counted in `ObjectTracker.ambiguous_count`). The remaining
   one-to-one candidates are taken with `scipy.optimize.linear_sum_assignment` on the
   distances (each is the only candidate of its row and column, so this is the
   assignment; the solver keeps the rule in one place if the gate rule is relaxed).

Track ids are 'cube1', 'cube2', ... in the order the tracks were made.
"""

from __future__ import annotations

from bisect import bisect_left
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from abp_description.frames import wrap_rad

DEFAULT_GATE_M = 0.15   # half the sim's least cube spacing (0.3 m)


@dataclass
class CubeView:
    """One cube in one image: its tags and centre (in the features' frame)."""

    feature_indices: list        # indices into the image's features
    centre: np.ndarray           # (3,) mean implied centre
    rotation: np.ndarray         # (3, 3) axes of its lowest-id tag (z out of that face), as
    #                              rigid_cube's cube frame: that tag's axes at the centre

    @property
    def fitted(self):
        """Two or more tags: the detector fitted one rigid cube to them."""
        return len(self.feature_indices) >= 2


def implied_centres(positions, normals, cube_size):
    """(n, 3) cube centres the tags imply: half an edge behind each face."""
    return np.asarray(positions, float) - np.asarray(normals, float) * (cube_size / 2)


def group_features(features, cube_size, link=None, rotations=None):
    """[CubeView] of the matcher features (`.position`, `.normal`, `.tag_id`) of one
    image: single-linkage groups of tag centres within `link` (default cube_size).
    `rotations`: each tag's (3, 3) orientation (None: a frame about its normal)."""
    n = len(features)
    if n == 0:
        return []
    link = cube_size if link is None else float(link)
    positions = np.array([f.position for f in features], dtype=float)
    centres = implied_centres(positions, [f.normal for f in features], cube_size)
    close = np.linalg.norm(positions[:, None] - positions[None], axis=2) <= link
    label = -np.ones(n, dtype=int)
    groups = []
    for start in range(n):
        if label[start] >= 0:
            continue
        label[start], members, frontier = len(groups), [start], [start]
        while frontier:
            i = frontier.pop()
            for j in np.flatnonzero(close[i] & (label < 0)):
                label[j] = label[start]
                members.append(int(j))
                frontier.append(int(j))
        groups.append(sorted(members))
    views = []
    for members in groups:
        first = min(members, key=lambda i: features[i].tag_id)
        rotation = (np.asarray(rotations[first], float) if rotations is not None
                    else _frame_of(features[first].normal))
        views.append(CubeView(members, centres[members].mean(axis=0), rotation))
    return views


def _frame_of(normal):
    """A rotation whose z axis is `normal` (the tag's own x, y are not in a Feature)."""
    z = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


class OdomBuffer:
    """The last `keep_s` seconds of odom poses (x, y, yaw), looked up at an image stamp."""

    def __init__(self, keep_s=5.0):
        self.keep_ns = int(keep_s * 1e9)
        self._stamps, self._poses = [], []

    def add(self, stamp_ns, x, y, yaw):
        stamp_ns = int(stamp_ns)
        if self._stamps and stamp_ns < self._stamps[-1]:
            self.clear()   # time went back (a restarted simulation, a bag played again)
        self._stamps.append(stamp_ns)
        self._poses.append((float(x), float(y), float(yaw)))
        cut = bisect_left(self._stamps, stamp_ns - self.keep_ns)
        if cut > 100:
            del self._stamps[:cut], self._poses[:cut]

    def clear(self):
        self._stamps, self._poses = [], []

    def pose_at(self, stamp_ns, tolerance_ns):
        """(x, y, yaw) at `stamp_ns`, interpolated between the poses around it, or the
        nearest one within `tolerance_ns`; None when there is none that close."""
        stamps = self._stamps
        if not stamps:
            return None
        i = bisect_left(stamps, int(stamp_ns))
        if i < len(stamps) and stamps[i] == stamp_ns:
            return np.array(self._poses[i])
        if 0 < i < len(stamps):
            t0, t1 = stamps[i - 1], stamps[i]
            if t1 - t0 <= 2 * tolerance_ns:
                a = (stamp_ns - t0) / (t1 - t0)
                p0, p1 = np.array(self._poses[i - 1]), np.array(self._poses[i])
                out = p0 + a * (p1 - p0)
                out[2] = p0[2] + a * wrap_rad(p1[2] - p0[2])
                return out
        near = min((j for j in (i - 1, i) if 0 <= j < len(stamps)),
                   key=lambda j: abs(stamps[j] - stamp_ns))
        if abs(stamps[near] - stamp_ns) <= tolerance_ns:
            return np.array(self._poses[near])
        return None


def base_to_odom(points, base_pose):
    """(n, 3) points of the base frame in odom, the base at planar pose (x, y, yaw)."""
    x, y, yaw = base_pose
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(points, float).reshape(-1, 3) @ rot.T + [x, y, 0.0]


@dataclass
class Track:
    track_id: str
    position: np.ndarray       # (3,) odom, where the cube was last seen
    last_seen_ns: int
    views: int = 1


@dataclass
class Association:
    """One image's cubes against the tracks: `track_ids[i]` is cube i's track id, or ''
    when it was ambiguous (its index is then in `ambiguous`)."""

    track_ids: list
    new_tracks: list = field(default_factory=list)   # ids made by this image
    ambiguous: list = field(default_factory=list)    # indices of the cubes left out
    reasons: list = field(default_factory=list)      # one line per ambiguity


class ObjectTracker:
    """Tracks of cubes in odom (see the module doc)."""

    def __init__(self, gate=DEFAULT_GATE_M):
        if not (np.isfinite(gate) and gate > 0):
            raise ValueError(f'track gate must be > 0 m, got {gate}')
        self.gate = float(gate)
        self.tracks = []
        self.ambiguous_count = 0
        self._made = 0

    def reset(self):
        self.tracks = []
        self._made = 0

    def track(self, track_id):
        return next((t for t in self.tracks if t.track_id == track_id), None)

    def update(self, positions, stamp_ns):
        """Associate the (n, 3) odom positions of one image's cubes; returns Association."""
        positions = np.asarray(positions, float).reshape(-1, 3)
        n, out = len(positions), Association([''] * len(positions))
        if n == 0:
            return out
        if self.tracks:
            known = np.array([t.position for t in self.tracks])
            dist = np.linalg.norm(positions[:, None] - known[None], axis=2)
        else:
            dist = np.zeros((n, 0))
        within = dist <= self.gate
        per_cube, per_track = within.sum(axis=1), within.sum(axis=0)
        blocked = np.zeros(n, dtype=bool)
        for i in np.flatnonzero(per_cube > 1):
            blocked[i] = True
            names = [self.tracks[j].track_id for j in np.flatnonzero(within[i])]
            out.reasons.append(f'cube at {_xy(positions[i])} is within {self.gate:g} m of '
                               f'tracks {", ".join(names)}')
        for j in np.flatnonzero(per_track > 1):
            cubes = np.flatnonzero(within[:, j])
            blocked[cubes] = True
            out.reasons.append(f'track {self.tracks[j].track_id} is within {self.gate:g} m '
                               f'of {len(cubes)} cubes of one image, at '
                               f'{", ".join(_xy(positions[i]) for i in cubes)}')
        candidates = within & ~blocked[:, None]
        if candidates.any():
            cost = np.where(candidates, dist, 1e6)
            for i, j in zip(*linear_sum_assignment(cost)):
                if candidates[i, j]:
                    track = self.tracks[j]
                    track.position, track.last_seen_ns = positions[i].copy(), int(stamp_ns)
                    track.views += 1
                    out.track_ids[i] = track.track_id
        for i in range(n):
            if not out.track_ids[i] and not blocked[i] and per_cube[i] == 0:
                self._made += 1
                track = Track(f'cube{self._made}', positions[i].copy(), int(stamp_ns))
                self.tracks.append(track)
                out.track_ids[i] = track.track_id
                out.new_tracks.append(track.track_id)
        out.ambiguous = [int(i) for i in np.flatnonzero(blocked)]
        self.ambiguous_count += len(out.ambiguous)
        return out


def _xy(p):
    return f'({p[0]:.2f}, {p[1]:.2f}) m'


__all__ = ['DEFAULT_GATE_M', 'Association', 'CubeView', 'ObjectTracker', 'OdomBuffer',
           'Track', 'base_to_odom', 'group_features', 'implied_centres']
