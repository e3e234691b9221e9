"""The renderer benchmark runs (tiny size) and prints its median."""

import cv2

from abp_bench import render_benchmark


def test_render_benchmark_prints_the_median(capsys):
    threads = cv2.getNumThreads()
    try:
        assert render_benchmark.main(['--frames', '4', '--encoding', 'bgr8']) == 0
    finally:
        cv2.setNumThreads(threads)
    assert 'median' in capsys.readouterr().out
