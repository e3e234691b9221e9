"""Issue 32's goal on image latency, over real DDS with the real detector node: with 60 ms
of image latency while the head pans at 0.5 rad/s, the cube position error stays <= 1 cm
when the camera pose is taken at the image stamp. The same frames also go to a detector
with the old behaviour (newest joint state), whose error must show the latency: else the
scene would not test anything. Figures: docs/CAMERA.md
(`python -m abp_bench.image_latency_benchmark` prints them too)."""

import pytest

rclpy = pytest.importorskip('rclpy')
if not hasattr(pytest.importorskip('abp_msgs.msg'), 'TagDetectionArray'):
    pytest.skip('abp_msgs is not built: run scripts/bootstrap.sh and source scripts/env.sh',
                allow_module_level=True)

from abp_bench.head_motion_scene import HeadMotion, HeadMotionScene  # noqa: E402
from abp_bench.image_latency_benchmark import (  # noqa: E402
    MODES,
    LatencyPlayer,
    detector_argv,
    detector_executable,
    markdown,
)

LATENCY_S = 0.06
SPEED = 0.5


def test_camera_pose_at_the_image_stamp_keeps_the_cube_within_1_cm(ros_processes, tester,
                                                                   spin):
    for mode in MODES:
        ros_processes.start(detector_argv(detector_executable(), mode))
    node, executor = tester
    player = LatencyPlayer(node, HeadMotionScene(HeadMotion(speed=SPEED)), LATENCY_S,
                           fps=10.0, duration_s=4.0)
    assert spin(executor, player.connected, 60), 'the detectors did not come up'
    player.start()
    assert spin(executor, lambda: player.done, 60)
    last = player.frame_stamps()[-1]
    spin(executor, lambda: all(last in out for out in player.outputs.values()), 10)
    result = player.report()
    print('\n' + markdown(result, LATENCY_S * 1e3, SPEED))

    assert result['image_delay_ms']['min'] >= LATENCY_S * 1e3
    sent = result['frames_sent']
    new, old = result['interpolate'], result['latest']
    # The detectors take frames best-effort: a loaded machine drops some. Enough must
    # come through for the figures to mean something.
    assert new['frames'] >= 0.4 * sent and old['frames'] >= 0.4 * sent, result
    assert new['max_mm'] <= 10.0, result
    # 60 ms at 0.5 rad/s is 30 mrad: ~3 cm at the cube's metre from the head.
    assert old['median_mm'] >= 20.0, result
