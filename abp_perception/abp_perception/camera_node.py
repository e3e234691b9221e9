"""ROS 2 wiring of a camera without a driver of its own: the `camera` node.

Publishes:   camera/image_raw             (sensor_msgs/Image, bgr8 or mono8)
             camera/image_raw/compressed  (sensor_msgs/CompressedImage, JPEG, format
                                           '<enc>; jpeg compressed <enc>'; with
                                           `publish_compressed`)
             camera/camera_info           (sensor_msgs/CameraInfo from `calibration_file`)
all with `abp_common.qos.CAMERA_PUBLISHER` (as the sim bridge publishes its camera), every
1/`rate` s of the node's clock, stamped with that clock and `frame_id`.

Frames come from a V4L2 device, a video file or a folder of images (`source`; the
plain module `frame_source`), the calibration from a camera_calibration YAML
(`camera_calibration_file`). Configure opens the source and reads its first frame, loads the
calibration and checks that both are of one image size: a missing device, an unreadable
file, an empty folder or a calibration of another size fails configure with the reason
(with autostart: `configuration error: ...`, exit code 2). Parameters:
`node_parameters.CAMERA_SPECS`.
"""

import sys

from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from abp_common import names, qos
from abp_common.health import NodeHealth
from abp_common.lifecycle import ManagedNode
from abp_common.node_runner import run_node
from abp_common.parameters import declare_all
from abp_description.robot_profile import load_profile

from .camera_calibration_file import CalibrationFileError, check_image_size
from .camera_calibration_file import load as load_calibration
from .frame_source import FrameSourceError, jpeg_payload, open_frame_source
from .node_parameters import CAMERA_SPECS

COMPRESSED_SUFFIX = '/compressed'
THROTTLE_S = 5.0


class CameraNode(ManagedNode):
    """Configure opens the source and the calibration; activate starts publishing."""

    def __init__(self, **kwargs):
        super().__init__('camera', **kwargs)
        self.source = None

    def configure(self):
        values = declare_all(self, CAMERA_SPECS)
        self.frame_id = (values['frame_id']
                         or load_profile(values['robot_profile']).frames.camera_optical)
        self.encoding = values['encoding']
        self.period_s = 1.0 / values['rate']
        self.publish_compressed = values['publish_compressed']
        self.jpeg_quality = values['jpeg_quality']
        calibration = (load_calibration(values['calibration_file'])
                       if values['calibration_file'] else None)
        self.source = open_frame_source(values['source'], self.encoding, values['loop'],
                                        values['image_width'], values['image_height'])
        try:
            if calibration is not None:
                check_image_size(calibration, self.source.size,
                                 f'the frames of {self.source.name}')
        except CalibrationFileError:
            self._close_source()
            raise
        self.camera_info = CameraInfo()
        if calibration is not None:
            calibration.fill(self.camera_info)
        else:
            self.camera_info.width, self.camera_info.height = self.source.size
            self.get_logger().warning('no calibration_file: camera_info carries the image '
                                      'size only, and the tag detector needs intrinsics')
        self.camera_info.header.frame_id = self.frame_id
        self.published = 0
        self._ended = False
        self._reported_skips = 0
        self.health = NodeHealth(self)
        self.health.add_values(lambda: [('frames published', self.published),
                                        ('frames not delivered', self.source.failed),
                                        ('files skipped', len(self.source.skipped))])
        self.get_logger().info(
            f'{self.source.describe()} as {self.encoding} at {1.0 / self.period_s:g} Hz '
            f'in frame {self.frame_id}'
            + (f", calibration {values['calibration_file']}" if calibration else '')
            + (', looping' if self.source.loop else '')
            + (', also JPEG compressed' if self.publish_compressed else ''))

    def activate(self):
        self._image_pub = self.create_publisher(Image, names.IMAGE, qos.CAMERA_PUBLISHER)
        self._info_pub = self.create_publisher(CameraInfo, names.CAMERA_INFO,
                                               qos.CAMERA_PUBLISHER)
        self._compressed_pub = (self.create_publisher(
            CompressedImage, names.IMAGE + COMPRESSED_SUFFIX, qos.CAMERA_PUBLISHER)
            if self.publish_compressed else None)
        self.create_timer(self.period_s, self._publish_next)

    def cleanup(self):
        self._close_source()

    def _close_source(self):
        if self.source is not None:
            self.source.close()
            self.source = None

    # -- publishing -------------------------------------------------------------------
    def _publish_next(self):
        if self._ended:
            return
        frame = self.source.read()
        self._report_skipped()
        if frame is None:
            if self.source.kind == 'device':
                self.get_logger().warning(
                    f'{self.source.name} delivered no frame ({self.source.failed} so far)',
                    throttle_duration_sec=THROTTLE_S)
                self.health.fault(f'{self.source.name} delivers no frames')
                return
            self._ended = True
            self.get_logger().info(f'end of {self.source.name}: {self.published} frames '
                                   'published; set loop to play it again')
            return
        self.health.fault(None)
        stamp = self.get_clock().now().to_msg()
        height, width = frame.shape[:2]
        image = Image(height=height, width=width, encoding=self.encoding,
                      step=frame.strides[0], is_bigendian=0)
        image.header.stamp, image.header.frame_id = stamp, self.frame_id
        image.data = frame.tobytes()
        self.camera_info.header.stamp = stamp
        self._info_pub.publish(self.camera_info)
        self._image_pub.publish(image)
        if self._compressed_pub is not None:
            msg = CompressedImage()
            msg.header = image.header
            msg.format, msg.data = jpeg_payload(frame, self.encoding, self.jpeg_quality)
            self._compressed_pub.publish(msg)
        self.published += 1

    def _report_skipped(self):
        skipped = self.source.skipped
        for path, why in skipped[self._reported_skips:]:
            self.get_logger().warning(f'skipped {path}: {why}')
        self._reported_skips = len(skipped)


def main(args=None):
    return run_node('camera', CameraNode, args,
                    config_errors=(FrameSourceError, CalibrationFileError),
                    on_exit=lambda node: node._close_source())


if __name__ == '__main__':
    sys.exit(main())
