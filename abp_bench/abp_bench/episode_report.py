"""`episode_report BAG --out FILE.png`: what the robot saw and believed, action by action,
from a bag of a recognition episode (`scripts/start_graph.sh --record DIR
--record-images`). Plain module (no rclpy): the bag is read with `rosbags` through
`abp_bringup.bag`; the picture is drawn by `episode_figure`.

One row per step: first the view the first decision was made from, then per executed
action (`/abp/executed_action`, with the planner's expected information gain from
`/abp/plan`) the first camera frame recorded after it, with the tags detected in that
frame (`/abp/tag_detections`: corners and ids), and the belief's top candidates
(`/abp/belief`) before the next action; the last row is the result (the last belief, the
actions taken, and the ground truth where the bag has `/abp/sim/ground_truth`). A bag
without images (the recorder's default) still gets its report: the detected corners are
drawn on a blank frame. A bag with several episodes (action sequence numbers that start
again) gets one picture per episode: FILE-1.png, FILE-2.png, ...

Times are the bag's receive times (one clock for every topic); a frame and its
detections are matched by the image's header stamp. Only the sparse topics are read
whole; frames, detections, camera_info and ground truth are read in time windows (the
MCAP chunk index), so a bag of a gigabyte of frames is not read through.
"""

import argparse
import bisect
import pathlib
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from rosbags.highlevel import AnyReader

from abp_bringup.bag import (
    BagError,
    deserialize,
    graph_name,
    typestore,
)
from abp_common import names

TOP_CANDIDATES = 5
DEFAULT_SIZE = (640, 480)
DETECTION_WINDOW_NS = 5_000_000_000   # a frame's detections arrive within this after it
THUMBNAIL_WIDTH = 320          # frames are shrunk to this width: the picture stays small

@dataclass
class Tag:
    tag_id: int
    corners: np.ndarray            # (4, 2) px of the full-size frame, ArUco order


@dataclass
class Step:
    """One row of the report: the start view (action '') or one executed action."""

    time_ns: int
    action: str = ''
    sequence: int = 0
    success: bool = True
    reason: str = ''
    duration_s: float = 0.0
    expected_gain: float = float('nan')
    image: np.ndarray | None = None       # RGB or grey thumbnail
    image_scale: float = 1.0              # thumbnail px per frame px
    frame_ns: int = -1                    # receive time of the frame shown
    tags: list = field(default_factory=list)
    detections_found: bool = False        # a detection message was matched to this step
    candidates: list = field(default_factory=list)    # [(object id, probability)]
    entropy: float = float('nan')
    belief_step: int = -1


@dataclass
class Episode:
    steps: list
    final_candidates: list
    final_entropy: float
    truth: str = ''
    image_size: tuple = DEFAULT_SIZE
    has_images: bool = False
    bag: str = ''

    @property
    def actions(self):
        return [s for s in self.steps if s.action]


def stamp_ns(header):
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _candidates(belief, k=TOP_CANDIDATES):
    return [(str(n), float(p)) for n, p in zip(belief.object_ids[:k], belief.probabilities[:k])]


def _last_before(times, items, t_ns):
    """The last item whose time is <= t_ns (times sorted), or None."""
    i = bisect.bisect_right(times, t_ns)
    return items[i - 1] if i else None


class _Bag:
    """An open bag read by graph topic name. The sparse topics (actions, plans, beliefs)
    are read whole; the dense ones (frames, detections, camera_info, ground truth) only
    in time windows, which rosbags seeks to by the MCAP chunk index instead of reading
    (and decompressing) the gigabyte of frames around them."""

    SPARSE = (names.EXECUTED_ACTION, names.PLAN, names.BELIEF)

    def __init__(self, reader, store):
        self.reader, self.store = reader, store
        self.connections = {}
        for connection in reader.connections:
            name = graph_name(connection.topic)
            if name:
                self.connections.setdefault(name, []).append(connection)
        self.sparse = {name: self.read(name) for name in self.SPARSE}

    def read(self, name, start=None, stop=None, first_only=False):
        """[(receive time, message)] of graph topic `name` in [start, stop)."""
        connections = self.connections.get(name)
        if not connections:
            return []
        out = []
        for connection, t_ns, data in self.reader.messages(connections=connections,
                                                           start=start, stop=stop):
            out.append((t_ns, deserialize(self.store, data, connection.msgtype)))
            if first_only:
                break
        return out

    def last_before(self, name, until_ns, window_ns=10_000_000_000):
        """The last message of `name` received before until_ns (looked for in the last
        `window_ns` first: a latched topic may have only one, long before)."""
        found = self.read(name, max(0, until_ns - window_ns), until_ns) or \
            self.read(name, None, until_ns)
        return found[-1][1] if found else None

    def times(self, name):
        return [t for t, _ in self.sparse[name]]

    def msgs(self, name):
        return [m for _, m in self.sparse[name]]


def split_episodes(actions):
    """Lists of (time_ns, ExecutedAction): a new episode where the sequence starts again."""
    episodes, current, last = [], [], None
    for t_ns, msg in actions:
        if current and last is not None and msg.sequence <= last:
            episodes.append(current)
            current = []
        current.append((t_ns, msg))
        last = msg.sequence
    if current:
        episodes.append(current)
    return episodes


def _fill_belief(step, belief_times, beliefs, until_ns):
    belief = _last_before(belief_times, beliefs, until_ns)
    if belief is not None:
        step.candidates = _candidates(belief)
        step.entropy = float(belief.entropy)
        step.belief_step = int(belief.step)


def build_episodes(rec, path=''):
    """The Episode(s) of an open `_Bag`, without frames (see attach_images)."""
    belief_times, beliefs = rec.times(names.BELIEF), rec.msgs(names.BELIEF)
    plan_times, plans = rec.times(names.PLAN), rec.msgs(names.PLAN)
    actions = rec.sparse[names.EXECUTED_ACTION]
    if not actions and not beliefs:
        raise BagError(f'bag {path} has no {names.EXECUTED_ACTION} and no {names.BELIEF}: '
                       'not a recording of a recognition episode')
    end_ns = max([t for t, _ in actions] + belief_times + plan_times)
    info = rec.last_before(names.CAMERA_INFO, end_ns + 1)
    size = (int(info.width), int(info.height)) if info is not None and info.width \
        else DEFAULT_SIZE
    # A belief whose step does not grow was reset (a new Recognize goal).
    resets = [t for i, t in enumerate(belief_times)
              if i and beliefs[i].step <= beliefs[i - 1].step]
    groups = split_episodes(actions) or [[]]
    episodes = []
    for k, group in enumerate(groups):
        first_ns = group[0][0] if group else end_ns
        # The start view: the first decision of this episode was made from it.
        start_ns = next((t for t in plan_times if t <= first_ns and
                         (k == 0 or t > groups[k - 1][-1][0])), first_ns)
        next_group_ns = groups[k + 1][0][0] if k + 1 < len(groups) else None
        steps = [Step(time_ns=start_ns)]
        for t_ns, msg in group:
            step = Step(time_ns=t_ns, action=str(msg.action), sequence=int(msg.sequence),
                        success=bool(msg.success), reason=str(msg.reason),
                        duration_s=msg.duration.sec + 1e-9 * msg.duration.nanosec)
            plan = _last_before(plan_times, plans, t_ns)
            if plan is not None and plan.action == step.action:
                step.expected_gain = float(plan.expected_information_gain)
            steps.append(step)
        # Each row's belief: the last one before the next action; for the last row, the
        # last one before the belief is reset for the next episode (or the bag ends).
        last_ns = steps[-1].time_ns
        reset_ns = next((t for t in resets if t > last_ns), None)
        episode_end = min(t for t in (reset_ns, next_group_ns, end_ns + 1) if t is not None)
        for i, step in enumerate(steps):
            until = steps[i + 1].time_ns - 1 if i + 1 < len(steps) else episode_end - 1
            _fill_belief(step, belief_times, beliefs, until)
        last = steps[-1]
        truth = rec.last_before(names.GROUND_TRUTH, episode_end)
        episodes.append(Episode(steps=steps, final_candidates=last.candidates,
                                final_entropy=last.entropy,
                                truth=str(truth.object_id) if truth is not None else '',
                                image_size=size, bag=str(path)))
    return episodes


def _detections_near(rec, t_ns, stamp=None):
    """The tag detection array of the frame stamped `stamp` (received within
    DETECTION_WINDOW_NS after t_ns, the frame's time), else the first one received at or
    after t_ns."""
    if stamp is not None:
        for _, msg in rec.read(names.TAG_DETECTIONS, t_ns, t_ns + DETECTION_WINDOW_NS):
            if stamp_ns(msg.header) == stamp:
                return msg
    found = rec.read(names.TAG_DETECTIONS, t_ns, first_only=True)
    return found[0][1] if found else None


def _tags_of(msg):
    return [Tag(int(d.id), np.array([[c.x, c.y] for c in d.corners], dtype=np.float64))
            for d in msg.detections]


def image_to_display(msg, width=THUMBNAIL_WIDTH):
    """(thumbnail RGB or grey uint8, scale) of a rosbags sensor_msgs/Image."""
    import cv2

    from abp_perception.image_encodings import image_to_gray
    h, w, enc = int(msg.height), int(msg.width), str(msg.encoding)
    data = np.asarray(msg.data, dtype=np.uint8)
    channels = {'bgr8': 3, 'rgb8': 3, 'bgra8': 4, 'rgba8': 4}.get(enc)
    if channels:
        rows = data.reshape(h, int(msg.step))[:, :w * channels].reshape(h, w, channels)
        image = rows[..., :3]
        if enc.startswith('bgr'):
            image = image[..., ::-1]
    else:
        image = image_to_gray(enc, h, w, msg.step, data, bool(msg.is_bigendian))
    scale = min(1.0, width / float(w))
    if scale < 1.0:
        image = cv2.resize(np.ascontiguousarray(image), (width, int(round(h * scale))),
                           interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(image), scale


def attach_images(rec, episodes):
    """Give each step the first frame received at or after its time (only those frames
    are read and deserialized) and the tags detected in it."""
    steps = [s for e in episodes for s in e.steps]
    frames = {}                               # frame time -> (thumbnail, scale, stamp)
    for step in steps:
        found = rec.read(names.IMAGE, step.time_ns, first_only=True)
        if not found:
            continue
        frame_ns, msg = found[0]
        if frame_ns not in frames:
            frames[frame_ns] = (*image_to_display(msg), stamp_ns(msg.header))
        step.image, step.image_scale, stamp = frames[frame_ns]
        step.frame_ns = frame_ns
        det = _detections_near(rec, frame_ns, stamp)
        if det is not None:
            step.tags, step.detections_found = _tags_of(det), True
    for episode in episodes:
        episode.has_images = any(s.image is not None for s in episode.steps)
    for step in steps:                     # no frame after it: the detections then
        if step.image is None:
            det = _detections_near(rec, step.time_ns)
            if det is not None:
                step.tags, step.detections_found = _tags_of(det), True
    return episodes


def load_episodes(path):
    """Every Episode of the bag at `path`, with frames and detections."""
    path = pathlib.Path(path)
    if not path.exists():
        raise BagError(f'bag {path} does not exist')
    try:
        store = typestore()
        with AnyReader([path], default_typestore=store) as reader:
            # The bag's own definitions: abp_msgs may have gained fields since.
            rec = _Bag(reader, reader.typestore)
            return attach_images(rec, build_episodes(rec, path))
    except BagError:
        raise
    except Exception as error:  # rosbags raises several types for unreadable bags
        raise BagError(f'cannot read bag {path}: {error}') from error


def output_paths(out, count):
    out = pathlib.Path(out)
    if count == 1:
        return [out]
    return [out.with_name(f'{out.stem}-{k + 1}{out.suffix}') for k in range(count)]


def write_reports(bag, out, dpi=None):
    """Draw every episode of `bag` to `out` (FILE-k.png when several); returns the paths."""
    from .episode_figure import DEFAULT_DPI, draw_episode
    episodes = load_episodes(bag)
    paths = output_paths(out, len(episodes))
    for episode, path in zip(episodes, paths):
        draw_episode(episode, path, dpi=dpi or DEFAULT_DPI)
    return paths, episodes


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog='episode_report', description='One PNG per recognition episode of a bag: per '
        'action the camera frame with the detected tags, the action and the top '
        'candidates of the belief, then the result.')
    parser.add_argument('bag', help='rosbag2 folder (scripts/start_graph.sh --record DIR '
                        '--record-images)')
    parser.add_argument('--out', required=True, help='PNG to write (FILE-k.png for each '
                        'episode when the bag has several)')
    parser.add_argument('--dpi', type=int, default=0, help='resolution (default 60)')
    args = parser.parse_args(argv)
    start = time.monotonic()
    try:
        paths, episodes = write_reports(args.bag, args.out, args.dpi)
    except BagError as error:
        print(f'[episode_report] error: {error}', file=sys.stderr)
        return 2
    for path, episode in zip(paths, episodes):
        note = '' if episode.has_images else ' (no camera images in the bag: tags on blank ' \
            'frames; record them with start_graph.sh --record-images)'
        print(f'[episode_report] {path}: {len(episode.actions)} actions{note}')
    print(f'[episode_report] done in {time.monotonic() - start:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
