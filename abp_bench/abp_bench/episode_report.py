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
detections are matched by the image's header stamp.
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
    bag_topics,
    deserialize,
    graph_name,
    read_bag,
    typestore,
)
from abp_common import names

TOP_CANDIDATES = 5
DEFAULT_SIZE = (640, 480)
DETECTION_WINDOW_NS = 5_000_000_000   # a frame's detections arrive within this after it
THUMBNAIL_WIDTH = 320          # frames are shrunk to this width: the picture stays small
TOPICS = (names.EXECUTED_ACTION, names.PLAN, names.BELIEF, names.TAG_DETECTIONS,
          names.GROUND_TRUTH, names.CAMERA_INFO)


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


class _Recorded:
    """The small topics of a bag by graph name, read in one pass and kept serialized:
    [(time_ns, msgtype, bytes)]; `msgs` deserializes (cached), `last` only the last one.
    Tag detections and camera infos come at the camera rate: only those used are
    deserialized."""

    def __init__(self, path, store):
        self.store = store
        topics = bag_topics(path)
        self.by_name = {name: [] for name in TOPICS}
        self.image_topic = next((t for t in topics if graph_name(t) == names.IMAGE), None)
        wanted = {t for t in topics if graph_name(t) in TOPICS}
        for topic, msgtype, t_ns, data in read_bag(path, wanted):
            self.by_name[graph_name(topic)].append((t_ns, msgtype, data))
        self._cache = {}

    def times(self, name):
        return [t for t, _, _ in self.by_name[name]]

    def msg(self, name, index):
        key = (name, index)
        if key not in self._cache:
            _, msgtype, data = self.by_name[name][index]
            self._cache[key] = deserialize(self.store, data, msgtype)
        return self._cache[key]

    def msgs(self, name):
        return [self.msg(name, i) for i in range(len(self.by_name[name]))]

    def timed(self, name):
        return [(t, self.msg(name, i)) for i, t in enumerate(self.times(name))]

    def last(self, name):
        return self.msg(name, len(self.by_name[name]) - 1) if self.by_name[name] else None


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


def build_episodes(path, store=None):
    """The Episode(s) of a bag, without images (see attach_images)."""
    store = store or typestore()
    rec = _Recorded(path, store)
    belief_times, beliefs = rec.times(names.BELIEF), rec.msgs(names.BELIEF)
    plan_times, plans = rec.times(names.PLAN), rec.msgs(names.PLAN)
    truth = rec.last(names.GROUND_TRUTH)
    info = rec.last(names.CAMERA_INFO)
    size = (int(info.width), int(info.height)) if info is not None and info.width \
        else DEFAULT_SIZE
    actions = rec.timed(names.EXECUTED_ACTION)
    if not actions and not beliefs:
        raise BagError(f'bag {path} has no {names.EXECUTED_ACTION} and no {names.BELIEF}: '
                       'not a recording of a recognition episode')
    end_ns = max([t for t, _ in actions] + belief_times + plan_times)
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
        episodes.append(Episode(steps=steps, final_candidates=last.candidates,
                                final_entropy=last.entropy,
                                truth=str(truth.object_id) if truth is not None else '',
                                image_size=size, bag=str(path)))
    return episodes, rec


def _detections_near(rec, t_ns, stamp=None):
    """The tag detection array of the frame stamped `stamp` (received within
    DETECTION_WINDOW_NS after t_ns, the frame's time), else the first one received at or
    after t_ns."""
    times = rec.times(names.TAG_DETECTIONS)
    first = bisect.bisect_left(times, t_ns)
    if first >= len(times):
        return None
    if stamp is not None:
        end = bisect.bisect_right(times, t_ns + DETECTION_WINDOW_NS)
        for i in range(first, end):
            msg = rec.msg(names.TAG_DETECTIONS, i)
            if stamp_ns(msg.header) == stamp:
                return msg
    return rec.msg(names.TAG_DETECTIONS, first)


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


def _first_frame_after(reader, connections, t_ns):
    """(receive time, serialized frame) of the first frame at or after t_ns, or None:
    reading from t_ns seeks by the bag's index instead of reading every frame before."""
    for connection, frame_ns, data in reader.messages(connections=connections, start=t_ns):
        return frame_ns, connection.msgtype, data
    return None


def attach_images(path, episodes, rec, store):
    """Give each step the first frame received at or after its time (only those frames
    are read and deserialized) and the tags detected in it."""
    steps = [s for e in episodes for s in e.steps]
    if rec.image_topic is not None and steps:
        try:
            with AnyReader([pathlib.Path(path)], default_typestore=store) as reader:
                connections = [c for c in reader.connections if c.topic == rec.image_topic]
                frames = {}                   # frame time -> (thumbnail, scale, stamp)
                for step in steps:
                    found = _first_frame_after(reader, connections, step.time_ns)
                    if found is None:
                        continue
                    frame_ns, msgtype, data = found
                    if frame_ns not in frames:
                        msg = deserialize(store, data, msgtype)
                        frames[frame_ns] = (*image_to_display(msg), stamp_ns(msg.header))
                    step.image, step.image_scale, stamp = frames[frame_ns]
                    step.frame_ns = frame_ns
                    det = _detections_near(rec, frame_ns, stamp)
                    if det is not None:
                        step.tags, step.detections_found = _tags_of(det), True
        except Exception as error:  # rosbags raises several types for unreadable bags
            raise BagError(f'cannot read the images of bag {path}: {error}') from error
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
    store = typestore()
    episodes, rec = build_episodes(path, store)
    return attach_images(path, episodes, rec, store)


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
