"""`episode_report`: the picture of an episode from a rosbag2 bag.

A committed bag (bags/mujoco, recorded without images) through the installed command;
and a generated 10-action bag with camera frames (real rosbag2 MCAP written with the
repo's BagWriter; messages built by rosidl and serialized by rclpy, as the recorder
stores what DDS delivers), where each row must show the first frame received after its
action, the tags detected in that very frame (matched by stamp, not a neighbour's) and
the last belief before the next action. The time to draw the 10-action episode is
printed (a measurement, bounded only loosely)."""

import os
import pathlib
import subprocess
import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
ament_index = pytest.importorskip('ament_index_python.packages')

from builtin_interfaces.msg import Duration, Time  # noqa: E402
from geometry_msgs.msg import Point32  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from abp_bench.episode_report import load_episodes, write_reports  # noqa: E402
from abp_bringup.bag import BagWriter, graph_topics  # noqa: E402
from abp_msgs.msg import (  # noqa: E402
    Belief,
    ExecutedAction,
    PlanStep,
    SimGroundTruth,
    TagDetection,
    TagDetectionArray,
)

REPO = pathlib.Path(__file__).resolve().parents[2]
MUJOCO_BAG = REPO / 'bags' / 'mujoco' / 'robot-seed0-twin-m-x'
T0 = 1_000_000_000_000          # ns: the generated episode's start
FRAME_PERIOD = 500_000_000      # 2 Hz camera
ACTION_PERIOD = 3_000_000_000
W, H = 640, 480
ACTIONS = ('ORBIT_P45', 'PUSH', 'LIFT', 'FLIP', 'ORBIT_M90', 'ORBIT_180', 'PUSH',
           'ORBIT_M45', 'FLIP', 'LIFT')
DICTIONARY = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)


def executable(name):
    prefix = ament_index.get_package_prefix('abp_bench')
    return os.path.join(prefix, 'lib', 'abp_bench', name)


def stamp(t_ns):
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def frame_tags(i):
    """Tag ids and corner arrays drawn in frame i."""
    ids = (i % 7, (i + 3) % 7)
    corners = []
    for k in range(2):
        x, y = 150 + 250 * k + 3 * (i % 10), 180
        corners.append(np.array([[x, y], [x + 80, y], [x + 80, y + 80], [x, y + 80]], float))
    return ids, corners


def frame_image(i):
    image = np.full((H, W), 200, np.uint8)
    for tag_id, c in zip(*frame_tags(i)):
        x, y = int(c[0, 0]), int(c[0, 1])
        image[y:y + 80, x:x + 80] = cv2.aruco.generateImageMarker(DICTIONARY, tag_id, 80)
    return image


def action_time(k, first_ns=T0):
    # Between two frames: the frame shown must be the next one.
    return first_ns + (k + 1) * ACTION_PERIOD - FRAME_PERIOD // 4


def write_episode_bag(path, n_actions=10, episodes=1):
    """A recorded-looking bag: frames, their detections (received 50 ms later, so a
    neighbour frame's detections sit close by), camera_info, plans, executed actions,
    beliefs after each prediction and correction, and the ground truth."""
    topics = graph_topics(images=True)
    writer = BagWriter(path, topics, add_all=True)
    messages = []                                  # (t_ns, topic, msg)
    span = (n_actions + 1) * ACTION_PERIOD
    end = T0 + episodes * span
    for i, t in enumerate(range(T0, end, FRAME_PERIOD)):
        img = frame_image(i)
        msg = Image(height=H, width=W, encoding='mono8', step=W, data=img.tobytes())
        msg.header.stamp, msg.header.frame_id = stamp(t), 'camera_optical_frame'
        messages.append((t, '/camera/image_raw', msg))
        info = CameraInfo(width=W, height=H)
        info.header.stamp = stamp(t)
        messages.append((t, '/camera/camera_info', info))
        dets = TagDetectionArray(camera_frame_id='camera_optical_frame')
        dets.header.stamp, dets.header.frame_id = stamp(t), 'base_link'
        for tag_id, c in zip(*frame_tags(i)):
            dets.detections.append(TagDetection(
                id=tag_id, corners=[Point32(x=float(x), y=float(y)) for x, y in c]))
        messages.append((t + 50_000_000, '/abp/tag_detections', dets))
    truth = SimGroundTruth(object_id='m9')
    messages.append((T0, '/abp/sim/ground_truth', truth))
    step = 0
    for e in range(episodes):
        first = T0 + e * span
        messages.append((first + 100, '/abp/belief', belief(step, 0)))
        for k in range(n_actions):
            t = action_time(k, first)
            plan = PlanStep(action=ACTIONS[k], expected_information_gain=0.1 * k,
                            planner_mode='cost')
            messages.append((t - 2_500_000_000, '/abp/plan', plan))
            done = ExecutedAction(action=ACTIONS[k], sequence=k + 1, success=k != 3,
                                  reason='' if k != 3 else 'arm tracking',
                                  duration=Duration(sec=2, nanosec=500_000_000))
            done.header.stamp = stamp(t)
            messages.append((t, '/abp/executed_action', done))
            step += 1
            messages.append((t + 300_000_000, '/abp/belief', belief(step, k)))
            step += 1
            messages.append((t + 1_000_000_000, '/abp/belief', belief(step, k + 1)))
    for t, topic, msg in sorted(messages, key=lambda m: m[0]):
        if not writer.added(topic):
            writer.add_topic(topic)
        writer.write(topic, t, serialize_message(msg))
    writer.close()
    return path


def belief(step, leader):
    """A belief whose top candidate is m<leader>, more certain as the episode goes."""
    p = min(0.95, 0.2 + 0.08 * leader)
    others = [f'm{j}' for j in range(10) if j != leader][:4]
    return Belief(step=step, object_ids=[f'm{leader}', *others],
                  probabilities=[p] + [(1 - p) / 4] * 4, total_models=30,
                  entropy=float(5.0 - 0.4 * leader))


def test_a_committed_bag_without_images_through_the_command(tmp_path):
    out = tmp_path / 'mujoco.png'
    result = subprocess.run([executable('episode_report'), str(MUJOCO_BAG), '--out', str(out)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert f'{out}: 6 actions (no camera images in the bag' in result.stdout
    picture = cv2.imread(str(out))
    # A title, the start row, 6 action rows and the result: 8 rows of 2.1 in at 60 dpi.
    assert picture is not None and picture.shape[0] > 8 * 2.1 * 60 * 0.95
    episode, = load_episodes(MUJOCO_BAG)
    # bags/README.md: the actions and the hidden cube of this episode.
    assert [s.action for s in episode.actions] == ['ORBIT_M45', 'ORBIT_M90', 'ORBIT_M45',
                                                   'LIFT', 'PUSH', 'FLIP']
    assert episode.truth == 'c0-5-1-2-4-6/m-x'
    assert episode.final_candidates[0][0] == 'c0-5-1-2-4-6/m-x'


def test_a_missing_bag_is_a_clear_error(tmp_path):
    result = subprocess.run([executable('episode_report'), str(tmp_path / 'nope'), '--out',
                             str(tmp_path / 'x.png')], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    assert f"error: bag {tmp_path / 'nope'} does not exist" in result.stderr


def test_a_ten_action_episode_with_frames(tmp_path):
    bag = write_episode_bag(tmp_path / 'ep')
    start = time.monotonic()
    paths, episodes = write_reports(bag, tmp_path / 'ep.png')
    seconds = time.monotonic() - start
    print(f'\nepisode_report: 10-action episode with frames drawn in {seconds:.2f} s')
    assert seconds < 60.0                     # loose: the goal is 10 s, measured above
    assert paths == [tmp_path / 'ep.png'] and paths[0].stat().st_size > 10_000
    episode, = episodes
    assert episode.has_images and episode.truth == 'm9'
    assert [s.action for s in episode.actions] == list(ACTIONS)
    assert len(episode.steps) == 11
    for k, step in enumerate(episode.actions):
        t = action_time(k)
        frame = -(-(t - T0) // FRAME_PERIOD)          # the first frame at or after it
        assert step.frame_ns == T0 + frame * FRAME_PERIOD
        ids, corners = frame_tags(frame)
        assert sorted(tag.tag_id for tag in step.tags) == sorted(ids)
        np.testing.assert_allclose(step.tags[0].corners, corners[0])
        assert step.image.shape == (240, 320)         # the thumbnail of the 640x480 frame
        assert step.candidates[0][0] == f'm{k + 1}'    # the belief before the next action
        assert step.expected_gain == pytest.approx(0.1 * k)
        assert step.success == (k != 3)
    assert episode.steps[0].candidates[0][0] == 'm0'
    assert episode.final_candidates[0] == ('m10', pytest.approx(0.95))
    assert episode.actions[3].reason == 'arm tracking'


def test_one_picture_per_episode(tmp_path):
    bag = write_episode_bag(tmp_path / 'two', n_actions=2, episodes=2)
    paths, episodes = write_reports(bag, tmp_path / 'two.png')
    assert paths == [tmp_path / 'two-1.png', tmp_path / 'two-2.png']
    assert all(p.exists() for p in paths)
    assert [len(e.actions) for e in episodes] == [2, 2]
    # The first episode's last row shows the belief before the second episode began.
    assert episodes[0].final_candidates[0][0] == 'm2'
