"""A simulated person and camera for the operator graph: the `scripted_operator` node
(scripts/start_graph.sh --operator scripted; docs/OPERATOR.md, "Scripted operator").

It stands in for the two things outside the operator graph: the camera and the person.
The `operator_skills` node runs exactly as with a person: its `terminal` is a pty that
this node holds the other end of. This node reads the requests there as a person reads
them (their words), carries each one out on the cube of a MuJoCo world with a fixed
camera and no robot (`operator_world`; the outcome from the hidden cube's mass by the ATG
table, `scripted_operator`), and types `d`. So the whole person path is what is tested:
the words, the terminal, the answers, the timeout.

At start (before configure: the operator_skills node opens its terminal when the manager
configures it, maybe at the same moment as this node) it opens a pty and makes
`terminal_link` a symbolic link to its slave end; start_graph.sh waits for the link.

Publishes:  camera/image_raw, camera/camera_info (abp_common.qos.CAMERA_PUBLISHER) at
            `camera_rate` Hz of wall time, stamped with the node's clock when the frame is
            taken (after an action, only frames taken after the cube was placed show it);
            /abp/sim/ground_truth (abp_msgs/SimGroundTruth, latched; TESTS AND BENCHMARKS
            ONLY): the hidden cube, its pose and state, at start and after every action.

Threads: the executor; a world thread that owns MuJoCo (its GL context is the thread's):
renders frames and carries out the actions the terminal thread hands it; a terminal
thread that reads the pty and answers.
"""

import os
import queue
import select
import sys
import termios
import threading
import time
import traceback
from dataclasses import replace

import numpy as np
import rclpy
from sensor_msgs.msg import CameraInfo, Image

from abp_belief.model_set_config import POPULATION_SPECS, TRANSITION_RULES_SPEC
from abp_common import names, qos
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.param_spec import (
    BOOL,
    DOUBLE,
    DOUBLE_ARRAY,
    INT,
    STRING,
    ParamSpec,
    probability,
)
from abp_common.parameters import declare_all
from abp_description import camera_intrinsics
from abp_description.robot_profile import PROFILE_SPEC, load_profile
from abp_msgs.msg import SimGroundTruth

from . import sim_messages
from .config import DICTIONARY_SPEC, check_dictionary
from .scenario import choose_hidden_model
from .scripted_operator import PromptReader, RequestUnclear, ScriptedPerson, parse_request

SEED_RANGE = (0, 2**31 - 1)
TERMINAL_SPEC = ParamSpec(
    'terminal_link', STRING, '', 'Path of a symbolic link this node makes to the slave end '
    "of its pty, at start: the operator_skills node's `terminal` (required).",
    read_only=True)
SCRIPTED_SPECS = (
    *POPULATION_SPECS, TRANSITION_RULES_SPEC, PROFILE_SPEC,
    replace(DICTIONARY_SPEC, read_only=True),
    ParamSpec('model_index', INT, -1, 'Index of the hidden model in the model set; -1 = drawn '
              'with cube_seed.', (-1, 10**7), read_only=True),
    ParamSpec('cube_seed', INT, 0, 'Seed of the random choice of the hidden model.',
              SEED_RANGE, read_only=True),
    ParamSpec('camera_pose', DOUBLE_ARRAY, [0.0, 0.0, 0.4, 0.0, 45.0, 0.0], 'Where the camera '
              'stands: [x, y, z, roll, pitch, yaw] (m, deg) of the camera body (x forward, z '
              "up, positive pitch looks down) in the profile's base frame: the detector's "
              'fixed_camera_pose.',
              read_only=True),
    ParamSpec('cube_up_face', INT, 4, 'Body face up at the start (0:+x 1:-x 2:+y 3:-y 4:+z '
              '5:-z).', (0, 5), read_only=True),
    ParamSpec('cube_yaw', DOUBLE, 0.0, 'Cube yaw at the start, deg.', (-360.0, 360.0),
              read_only=True),
    ParamSpec('camera_rate', DOUBLE, 5.0, 'Camera frames per second of wall time.',
              (0.5, 30.0), read_only=True),
    ParamSpec('camera_encoding', STRING, 'mono8', 'Image encoding.',
              choices=('mono8', 'bgr8'), read_only=True),
    probability('wrong_action_fraction', 0.0, 'Share of the requests the person carries out '
                'as another action (drawn evenly from the other seven ATG actions), and '
                'answers done all the same.'),
    ParamSpec('operator_seed', INT, 0, "Seed of the person's draws (wrong actions, the "
              "table's split outcomes, how exactly the cube is set down), with the hidden "
              'model index.', SEED_RANGE,
              read_only=True),
    ParamSpec('silent', BOOL, False, 'Read the requests but never answer (tests the '
              "operator_skills node's skill_timeout)."),
    ParamSpec('answer_delay', DOUBLE, 0.5, 'Wall seconds from a request to the answer after '
              'the cube was moved (frames of the new pose go out meanwhile).', (0.0, 60.0)),
    ParamSpec('yaw_jitter_deg', DOUBLE, 2.0, 'Standard deviation of the yaw a set-down cube '
              'is left with off its ideal pose, deg (clipped to +-10).', (0.0, 10.0)),
    ParamSpec('push_reach', DOUBLE, 0.2, 'A pushed cube farther than this from its start '
              '(m) is slid straight back to its mark, to stay in view.', (0.05, 1.0)),
)


def open_pty_link(link):
    """(master fd, slave fd) of a new pty without echo, with `link` pointing at its slave
    (replaced atomically if it exists)."""
    master, slave = os.openpty()
    attrs = termios.tcgetattr(slave)
    attrs[3] &= ~(termios.ECHO | termios.ECHONL)
    termios.tcsetattr(slave, termios.TCSANOW, attrs)
    temporary = f'{link}.{os.getpid()}'
    os.symlink(os.ttyname(slave), temporary)
    os.replace(temporary, link)
    return master, slave


class ScriptedOperatorNode(ManagedNode):
    """Construction opens the pty; configure builds the world; activate starts the world
    and terminal threads."""

    def __init__(self, **kwargs):
        super().__init__('scripted_operator', **kwargs)
        link = declare_all(self, (TERMINAL_SPEC,))['terminal_link']
        if not link:
            raise ValueError('parameter terminal_link: give the path of the pty link for the '
                             "operator_skills node's terminal")
        self.link = os.path.abspath(link)
        self.master, self.slave = open_pty_link(self.link)
        self._stop = threading.Event()
        self._threads = []
        self.world = None
        self.failed = False      # the world thread failed: exit code 1

    def configure(self):
        from .operator_world import OperatorWorld  # MuJoCo (EGL) only once configured
        from .worlds import check_rendering

        v = self._values = declare_all(self, SCRIPTED_SPECS)
        check_rendering()  # no EGL: a configuration error with the fix, not a traceback
        # The frame the detector gives poses in (its base_frame default): the truth's too.
        self.base_frame = load_profile(v['robot_profile']).frames.base
        self.hidden = choose_hidden_model(
            (), 0, v['model_set'], v['model_set_size'], v['n_tags'], v['seed'],
            v['model_file'], v['model_index'], v['cube_seed'])
        check_dictionary(v['dictionary'], self.hidden.face_tags, ())
        self.world = OperatorWorld(self.hidden, v['camera_pose'], up_face=v['cube_up_face'],
                                   yaw_deg=v['cube_yaw'], dictionary=v['dictionary'])
        self.person = ScriptedPerson(
            # Seeded with the cube too: episodes of a benchmark (one seed, one cube each)
            # do not repeat one pattern of wrong actions.
            self.hidden.mass_index,
            np.random.default_rng([v['operator_seed'], self.hidden.model_index + 1, 35]),
            v['transition_rules'], v['wrong_action_fraction'], v['yaw_jitter_deg'],
            v['push_reach'])
        intrinsics = camera_intrinsics()
        self.camera_info = sim_messages.camera_info(intrinsics)
        self.frame_id = intrinsics.frame_id
        self.last_outcome = ''
        self.get_logger().info(
            f'scripted operator: hidden cube {self.hidden.object_id} (model_index '
            f'{self.hidden.model_index}) at {np.round(self.world.home_xy, 3).tolist()} m, '
            f'camera {list(v["camera_pose"])}, {v["transition_rules"]} table, wrong actions '
            f'{v["wrong_action_fraction"]:.0%}{", SILENT" if v["silent"] else ""}; its '
            f'terminal {self.link} -> {os.ttyname(self.slave)}')

    def activate(self):
        self._image_pub = self.create_publisher(Image, names.IMAGE, qos.CAMERA_PUBLISHER)
        self._info_pub = self.create_publisher(CameraInfo, names.CAMERA_INFO,
                                               qos.CAMERA_PUBLISHER)
        self._gt_pub = self.create_publisher(SimGroundTruth, names.GROUND_TRUTH, qos.LATCHED)
        self._requests = queue.Queue()
        self._stop.clear()
        self._threads = [threading.Thread(target=self._world_loop, name='world', daemon=True),
                         threading.Thread(target=self._terminal_loop, name='terminal',
                                          daemon=True)]
        for thread in self._threads:
            thread.start()

    def deactivate(self):
        self.stop()

    def stop(self):
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=3.0)
        self._threads = []

    # -- the world thread: frames and actions --------------------------------------------
    def _world_loop(self):
        period = 1.0 / self._values['camera_rate']
        encoding = self._values['camera_encoding']
        next_frame = time.monotonic()
        try:
            self._publish_truth()
            while not self._stop.is_set():
                try:
                    request, done_event, result = self._requests.get(
                        timeout=max(0.0, next_frame - time.monotonic()))
                except queue.Empty:
                    pass
                else:
                    result.append(self.person.carry_out(request, self.world))
                    self.last_outcome = str(result[0])
                    self._publish_truth()
                    done_event.set()
                    next_frame = time.monotonic()   # a frame of the new pose at once
                    continue
                stamp = self.get_clock().now().to_msg()   # taken now, rendered below
                img = self.world.render(encoding)
                msg = Image(height=img.shape[0], width=img.shape[1], encoding=encoding,
                            step=int(img.strides[0]), is_bigendian=0)
                msg.header.stamp, msg.header.frame_id = stamp, self.frame_id
                msg.data = img.tobytes()
                self.camera_info.header.stamp = stamp
                self._image_pub.publish(msg)
                self._info_pub.publish(self.camera_info)
                next_frame += period
                if next_frame < time.monotonic():
                    next_frame = time.monotonic() + period   # slow renderer: no backlog
        except Exception:  # noqa: BLE001
            if self._stop.is_set() or not self.context.ok():
                return          # shutting down: the publishers' context is gone
            self.failed = True
            self.get_logger().error('world thread failed:\n' + traceback.format_exc())
            rclpy.try_shutdown(context=self.context)
        finally:
            self.world.close()

    def _publish_truth(self):
        world, hidden = self.world, self.hidden
        pose = world.cube_pose()
        up, yaw = world.discrete_state()
        msg = SimGroundTruth()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.base_frame
        msg.object_id, msg.model_index = hidden.object_id, int(hidden.model_index)
        msg.face_tags = [int(t) for t in hidden.face_tags]
        msg.mass_index = int(hidden.mass_index)
        msg.cube_pose = sim_messages.pose(pose[:3, 3], pose[:3, :3])
        msg.base_pose = sim_messages.pose([0.0, 0.0, 0.0], np.eye(3))
        msg.state, msg.up_face, msg.yaw_step = 8 * up + yaw, up, yaw
        msg.manual_actions = self.person.actions
        msg.last_outcome = self.last_outcome
        self._gt_pub.publish(msg)

    # -- the terminal thread: read, act, answer ------------------------------------------
    def _terminal_loop(self):
        reader = PromptReader()
        log = self.get_logger()
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.2)
            if not ready:
                continue
            try:
                text = os.read(self.master, 4096).decode('utf-8', errors='replace')
            except OSError:    # EIO: nobody holds the slave end (never here: we hold it)
                time.sleep(0.2)
                continue
            for title, words in reader.feed(text):
                if self.get_parameter('silent').value:
                    log.info(f'asked {title}: staying silent (parameter silent)')
                    continue
                try:
                    request = parse_request(title, words)
                except RequestUnclear as unclear:
                    log.warning(f'cannot do {title}: {unclear}')
                    self._type(f'n {unclear}\n')
                    continue
                done_event, result = threading.Event(), []
                self._requests.put((request, done_event, result))
                while not done_event.wait(0.2):
                    if self._stop.is_set():
                        return
                log.info(f'did {result[0]}')
                if self._stop.wait(self.get_parameter('answer_delay').value):
                    return
                self._type('d\n')

    def _type(self, text):
        os.write(self.master, text.encode())


def main(args=None):
    def on_exit(node):
        node.stop()
        try:
            if os.path.islink(node.link) and os.readlink(node.link) == os.ttyname(node.slave):
                os.unlink(node.link)
        except OSError:
            pass

    failed = []
    code = run_node('scripted_operator', ScriptedOperatorNode, args,
                    on_exit=lambda node: (on_exit(node), failed.append(node.failed)))
    return 1 if any(failed) else code


if __name__ == '__main__':
    sys.exit(main())
