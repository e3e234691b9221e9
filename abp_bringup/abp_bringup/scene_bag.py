"""Every object's belief from a bag (issue 37): the belief node's /abp/beliefs
(abp_msgs/SceneBelief) as recorded, read back with the `rosbags` library (no rclpy).

Each SceneBelief holds one ObjectBelief per object track; its Belief carries the node
belief sparse (every node at or above `node_floor` times the most probable one), which
`dense_belief` puts back into the full (models x 48) vector, zero below the floor, as
the belief node had it. `scene_beliefs(bag)` yields every recorded scene in time order;
`object_beliefs(bag)` is the last one: the belief of every object at the end of the bag.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from abp_belief.cube import STATES_PER_MODEL
from abp_common import names

from .bag import BagError, bag_topics, deserialize, read_bag, typestore

SCENE_BELIEF = 'abp_msgs/msg/SceneBelief'


@dataclass(frozen=True)
class RecordedObject:
    """One object's belief as the bag holds it."""
    track_id: str
    step: int                 # its belief's step (updates since its reset)
    stamp_ns: int             # stamp of its belief's latest update
    actions_taken: int
    visible: bool
    frame_id: str             # frame of `position` ('' when never fitted)
    position: tuple           # cube centre (x, y, z) of its latest fitted observation
    model_set_id: str
    belief: np.ndarray        # dense node belief, zero below the publisher's node floor

    def object_marginal(self) -> np.ndarray:
        return self.belief.reshape(-1, STATES_PER_MODEL).sum(axis=1)


def dense_belief(belief) -> np.ndarray:
    """The full node belief of an abp_msgs/Belief (rclpy or rosbags message)."""
    out = np.zeros(int(belief.total_models) * STATES_PER_MODEL)
    indices = np.asarray(belief.node_indices, dtype=np.int64)
    if indices.size and indices.max() >= out.size:
        raise BagError(f'belief node index {indices.max()} beyond its {belief.total_models} '
                       'models')
    out[indices] = np.asarray(belief.node_probabilities, dtype=np.float64)
    return out


def recorded_objects(scene) -> dict[str, RecordedObject]:
    """{track id: RecordedObject} of one SceneBelief message, in the order of its tracks."""
    objects = {}
    for entry in scene.objects:
        b, p = entry.belief, entry.pose
        objects[entry.track_id] = RecordedObject(
            track_id=entry.track_id, step=int(b.step),
            stamp_ns=int(b.header.stamp.sec) * 1_000_000_000 + int(b.header.stamp.nanosec),
            actions_taken=int(entry.actions_taken), visible=bool(entry.visible),
            frame_id=p.header.frame_id,
            position=(p.pose.position.x, p.pose.position.y, p.pose.position.z),
            model_set_id=scene.model_set_id, belief=dense_belief(b))
    return objects


def scene_topic(path, namespace='') -> str:
    """The bag's SceneBelief topic (/abp/beliefs under `namespace`); BagError if absent."""
    topic = names.absolute(names.BELIEFS, namespace)
    topics = bag_topics(path)
    if topics.get(topic) != SCENE_BELIEF:
        raise BagError(f'bag {path} has no {topic} ({SCENE_BELIEF}); it has '
                       f"{', '.join(sorted(topics)) or 'no topics'}")
    return topic


def scene_beliefs(path, namespace='') -> Iterator[tuple[int, dict[str, RecordedObject]]]:
    """(receive time ns, {track id: RecordedObject}) of every recorded SceneBelief."""
    store = typestore()
    for _, msgtype, timestamp, data in read_bag(path, [scene_topic(path, namespace)]):
        yield timestamp, recorded_objects(deserialize(store, data, msgtype))


def object_beliefs(path, namespace='') -> dict[str, RecordedObject]:
    """Every object's belief at the end of the bag (its last SceneBelief)."""
    last = None
    for _, objects in scene_beliefs(path, namespace):
        last = objects
    if last is None:
        raise BagError(f'bag {path} holds no message on '
                       f'{names.absolute(names.BELIEFS, namespace)}')
    return last


__all__ = ['RecordedObject', 'dense_belief', 'object_beliefs', 'recorded_objects',
           'scene_beliefs', 'scene_topic']
