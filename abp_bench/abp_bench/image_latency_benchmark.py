"""`image_latency_benchmark`: the cube position error of the real tag detector node while
the head pans and images arrive late.

    python -m abp_bench.image_latency_benchmark [--latency-ms 60] [--speed 0.5]
        [--fps 10] [--duration 4] [--json FILE]

A player node publishes /joint_states at 200 Hz, stamped with its clock, with the head
panning at --speed rad/s (`head_motion_scene.HeadMotion`), and camera images rendered for
the joint state at time t (`head_motion_scene.HeadMotionScene`), stamped t but published
--latency-ms later, as a camera driver on a robot delivers them. Two `artag_detector`
processes take the same frames and joint states over DDS: one with
`joint_state_lookup:=latest` (the camera pose at the newest joint state: the detector's
behaviour before issue 32), one with the default `interpolate` (the joint state at the
image stamp). Each detection's cube centre in base_link is compared with the truth.
Prints a Markdown table; the figures go in docs/CAMERA.md.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from abp_description.robot_profile import load_profile

from .head_motion_scene import CUBE_CENTRE, HeadMotionScene, cube_centre_from_tags, error_summary

JOINT_STATE_HZ = 200.0
CAMERA_INFO_EVERY = 10           # joint-state ticks per camera_info
MODES = ('latest', 'interpolate')

BASE_FRAME = load_profile().frames.base   # the default robot's (the detector's default)


def detector_argv(executable, mode):
    """Command line of one detector: own node name and output topic per lookup mode."""
    return [executable, '--ros-args', '-r', f'__node:=artag_detector_{mode}',
            '-r', f'abp/tag_detections:=abp/tag_detections_{mode}',
            '-p', f'joint_state_lookup:={mode}']


def output_topic(mode):
    return f'abp/tag_detections_{mode}'


def detector_executable():
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix('abp_perception'), 'lib', 'abp_perception',
                        'artag_detector')


class LatencyPlayer:
    """Publishes the scene's joint states now and its images `latency_s` after their stamp;
    collects the detectors' outputs (ROS wiring only: the scene is plain)."""

    def __init__(self, node, scene, latency_s=0.06, fps=10.0, duration_s=4.0, lead_s=0.5,
                 modes=MODES):
        from sensor_msgs.msg import CameraInfo, Image, JointState

        from abp_common import names, qos
        from abp_msgs.msg import TagDetectionArray

        self._Image, self._JointState = Image, JointState
        self.node, self.scene = node, scene
        self.latency_ns = int(latency_s * 1e9)
        self.lead_ns = int(lead_s * 1e9)
        period = 1.0 / fps
        # Rendered before the clock starts: publishing must not wait for rendering.
        self.frames = [(int(k * period * 1e9), scene.render(k * period))
                       for k in range(int(round(duration_s * fps)))]
        self.image_pub = node.create_publisher(Image, names.IMAGE, qos.CAMERA_PUBLISHER)
        self.info_pub = node.create_publisher(CameraInfo, names.CAMERA_INFO,
                                              qos.CAMERA_PUBLISHER)
        self.joint_pub = node.create_publisher(JointState, names.JOINT_STATES, qos.RELIABLE)
        self.info = self._camera_info(CameraInfo)
        self.outputs = {mode: {} for mode in modes}
        for mode in modes:
            node.create_subscription(
                TagDetectionArray, output_topic(mode),
                lambda msg, mode=mode: self._on_detections(mode, msg), qos.RELIABLE)
        self.t0_ns = None
        self.next_frame = 0
        self.delays_ms = []          # actual publish time - stamp, per frame
        self._ticks = 0
        self._next_joint_ns = None   # stamp of the next joint state to publish
        self._timer = None

    def _camera_info(self, CameraInfo):
        cam = self.scene.camera
        msg = CameraInfo(width=cam.width, height=cam.height, distortion_model='plumb_bob')
        msg.header.frame_id = cam.frame_id
        msg.k = [float(v) for v in cam.K.ravel()]
        msg.d = [float(v) for v in cam.D]
        msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        msg.p = [cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        return msg

    def connected(self):
        """Every detector subscribes to the inputs and publishes its output."""
        n = len(self.outputs)
        return (self.image_pub.get_subscription_count() >= n
                and self.joint_pub.get_subscription_count() >= n
                and self.info_pub.get_subscription_count() >= n
                and all(self.node.count_publishers(output_topic(m)) >= 1 for m in self.outputs))

    def start(self):
        now = self.node.get_clock().now().nanoseconds
        self.t0_ns = now + self.lead_ns
        self._next_joint_ns = now
        self._timer = self.node.create_timer(1.0 / JOINT_STATE_HZ, self._tick)

    @property
    def done(self):
        return self.next_frame >= len(self.frames)

    def _stamp(self, ns):
        from builtin_interfaces.msg import Time
        return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def _tick(self):
        now = self.node.get_clock().now().nanoseconds
        # Every JOINT_STATE_HZ period of the scene gets its joint state, stamped when it
        # held, however late this timer runs on a loaded machine (a starved timer must
        # not thin out the robot's joint states: that would test this player, not the
        # detector).
        period_ns = int(1e9 / JOINT_STATE_HZ)
        while self._next_joint_ns <= now:
            stamp = self._next_joint_ns
            joints = self._JointState(name=list(self.scene.kin.joint_names),
                                      position=[float(v) for v in
                                                self.scene.joints((stamp - self.t0_ns) * 1e-9)])
            joints.header.stamp = self._stamp(stamp)
            self.joint_pub.publish(joints)
            self._next_joint_ns += period_ns
        if self._ticks % CAMERA_INFO_EVERY == 0:
            self.info_pub.publish(self.info)
        self._ticks += 1
        while not self.done:
            offset_ns, image = self.frames[self.next_frame]
            stamp_ns = self.t0_ns + offset_ns
            if now < stamp_ns + self.latency_ns:
                break
            msg = self._Image(height=image.shape[0], width=image.shape[1], encoding='mono8',
                              step=image.shape[1], data=image.tobytes())
            msg.header.stamp = self._stamp(stamp_ns)
            msg.header.frame_id = self.scene.camera.frame_id
            self.image_pub.publish(msg)
            self.delays_ms.append((now - stamp_ns) * 1e-6)
            self.next_frame += 1
        if self.done and self._timer is not None:
            self._timer.cancel()

    def _on_detections(self, mode, msg):
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.outputs[mode][stamp_ns] = msg

    def frame_stamps(self):
        return [self.t0_ns + offset for offset, _ in self.frames]

    def errors(self, mode):
        """Per-frame cube centre errors (m) of one detector, over the frames it detected."""
        out = []
        for stamp_ns in self.frame_stamps():
            msg = self.outputs[mode].get(stamp_ns)
            if msg is None or msg.header.frame_id != BASE_FRAME:
                continue
            tags = [((d.pose.pose.position.x, d.pose.pose.position.y,
                      d.pose.pose.position.z),
                     (d.pose.pose.orientation.x, d.pose.pose.orientation.y,
                      d.pose.pose.orientation.z, d.pose.pose.orientation.w))
                     for d in msg.detections]
            centre = cube_centre_from_tags(tags)
            if centre is not None:
                out.append(float(np.linalg.norm(centre - CUBE_CENTRE)))
        return out

    def report(self):
        """{mode: error summary} plus the latency the images actually had."""
        result = {mode: error_summary(self.errors(mode)) for mode in self.outputs}
        result['frames_sent'] = len(self.frames)
        result['image_delay_ms'] = {'min': float(np.min(self.delays_ms)),
                                    'median': float(np.median(self.delays_ms))}
        return result


def markdown(result, latency_ms, speed):
    rows = [f'Head pan {speed:g} rad/s, images published {latency_ms:g} ms after their stamp '
            f"(measured: median {result['image_delay_ms']['median']:.1f} ms), "
            f"{result['frames_sent']} frames; cube centre error in the base frame:", '',
            '| camera pose from | frames detected | median mm | p95 mm | max mm |',
            '|---|---|---|---|---|']
    names = {'latest': 'newest joint state (before)', 'interpolate': 'joint state at the '
             'image stamp (now)'}
    for mode in MODES:
        s = result[mode]
        rows.append(f"| {names[mode]} | {s['frames']} | {s['median_mm']:.1f} | "
                    f"{s['p95_mm']:.1f} | {s['max_mm']:.1f} |")
    return '\n'.join(rows)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--latency-ms', type=float, default=60.0)
    parser.add_argument('--speed', type=float, default=0.5, help='head pan speed, rad/s')
    parser.add_argument('--fps', type=float, default=10.0)
    parser.add_argument('--duration', type=float, default=4.0, help='seconds of frames')
    parser.add_argument('--json', help='write the figures to this file')
    args = parser.parse_args(argv)

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from .head_motion_scene import HeadMotion

    scene = HeadMotionScene(HeadMotion(speed=args.speed))
    procs = [subprocess.Popen(detector_argv(detector_executable(), mode)) for mode in MODES]
    rclpy.init()
    node = rclpy.create_node('image_latency_player')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        player = LatencyPlayer(node, scene, args.latency_ms * 1e-3, args.fps, args.duration)
        deadline = time.monotonic() + 60.0
        while not player.connected():
            if time.monotonic() > deadline:
                sys.exit('the detectors did not come up within 60 s')
            executor.spin_once(timeout_sec=0.1)
        player.start()
        while not player.done:
            executor.spin_once(timeout_sec=0.1)
        last = set(player.frame_stamps()[-1:])
        deadline = time.monotonic() + 10.0        # the last frames' detections
        while time.monotonic() < deadline and not all(
                last <= set(out) for out in player.outputs.values()):
            executor.spin_once(timeout_sec=0.1)
        result = player.report()
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.wait(timeout=10)
        node.destroy_node()
        rclpy.try_shutdown()
    print(markdown(result, args.latency_ms, args.speed))
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(result, stream, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
