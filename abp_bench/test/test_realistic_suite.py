"""The realistic-conditions suite (abp_bench.realistic_suite): its frames and its report."""

import cv2
import numpy as np

from abp_bench import perception_benchmark, realistic_suite


def test_fake_tags_are_no_dictionary_tags():
    deg = realistic_suite.Degrader(640, 480, seed=1)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
                                       cv2.aruco.DetectorParameters())
    canvas = np.full((480, 640), 128, np.uint8)
    for k, cells in enumerate(deg.fakes[:12]):
        tag = cv2.resize(cells, (96, 96), interpolation=cv2.INTER_NEAREST)
        tag = cv2.copyMakeBorder(tag, 16, 16, 16, 16, cv2.BORDER_CONSTANT, value=255)
        r, c = divmod(k, 4)
        canvas[r * 150 + 10:r * 150 + 138, c * 150 + 10:c * 150 + 138] = tag
    corners, ids, rejected = detector.detectMarkers(canvas)
    assert ids is None
    assert len(rejected) >= 12             # they are tag-like: ArUco looked at them


def test_background_is_replaced_only_around_the_cube(full_models):
    from abp_bench.scenes import SceneGenerator
    gen = SceneGenerator(seed=2)
    deg = realistic_suite.Degrader(gen.width, gen.height, seed=2)
    rng = np.random.default_rng(2)
    gray, scene, poly = realistic_suite.render_frame(gen, full_models, rng, deg, 'clutter', 1.0)
    assert poly is None and gray.shape == (gen.height, gen.width)
    # Inside a cube tag (away from its edges) the frame keeps the tag's own pixels: the
    # black border cells are dark whatever the background.
    tag = next(t for t in scene.tags if t.on_cube and t.in_image and t.cos_view > 0.6)
    centre = tag.corners_px.mean(axis=0)
    border = centre + 0.85 * (tag.corners_px[0] - centre)
    assert gray[int(round(border[1])), int(round(border[0]))] < 60
    # Outside the cube (the frame's corners, far from it) the background is the clutter,
    # not the renderer's uniform floor and wall.
    plain = realistic_suite.render_frame(gen, full_models, np.random.default_rng(2), deg,
                                         'plain', 1.0)[0]
    corner = (slice(0, 60), slice(0, 60))
    assert gray[corner].std() > 3 * plain[corner].std()


def test_suite_runs_and_reports_every_condition_against_opencv(capsys):
    assert perception_benchmark.main(['--suite', 'realistic', '--realistic-frames', '2',
                                      '--seed', '3']) == 0
    out = capsys.readouterr().out
    assert out.startswith('## Perception under realistic conditions (issue 16)')
    for cond in realistic_suite.CONDITIONS:
        assert f'| {cond} |' in out
    for heading in ('### By condition', '### By distance', '### By viewing angle',
                    '### Rotation error of tags on cubes', '### Region search',
                    '### Aspect top-1', '### Between full-frame passes'):
        assert heading in out


def test_moved_frame_corners_map_back_to_the_original_frame():
    rng = np.random.default_rng(0)
    gray = np.zeros((480, 640), np.uint8)
    gray[200:260, 300:360] = 255
    moved, affine = realistic_suite.moved_frame(gray, rng)
    square = np.array([[299.5, 199.5], [359.5, 199.5], [359.5, 259.5], [299.5, 259.5]])
    there = square @ affine[:, :2].T + affine[:, 2]
    assert 0.1 < np.abs(there - square).max() < 2.0 + 320 * np.radians(0.3) + 1e-9
    np.testing.assert_allclose(realistic_suite.unmoved(there, affine), square, atol=1e-9)
    inside = np.round(there.mean(axis=0)).astype(int)
    assert moved[inside[1], inside[0]] == 255


def test_update_doc_keeps_the_two_perception_sections_apart(tmp_path):
    doc = tmp_path / 'BENCHMARKS.md'
    doc.write_text('# Benchmarks\n\n## Perception\n\nstandard\n\n## Planner\n\nplanner\n')
    perception_benchmark.update_doc(doc, '## Perception under realistic conditions (issue 16)'
                                    '\n\nrealistic v1\n',
                                    heading='Perception under realistic conditions')
    perception_benchmark.update_doc(doc, '## Perception under realistic conditions (issue 16)'
                                    '\n\nrealistic v2\n',
                                    heading='Perception under realistic conditions')
    perception_benchmark.update_doc(doc, '## Perception\n\nstandard v2\n')
    text = doc.read_text()
    assert 'standard v2' in text and 'realistic v2' in text and 'planner' in text
    assert 'realistic v1' not in text and '\nstandard\n' not in text
    assert text.count('## Perception under realistic conditions') == 1


def test_aspect_verdict_tells_a_missed_tag_from_a_wrong_one():
    truth = (3, 1, 6, 5)
    assert realistic_suite.aspect_verdict(None, truth) == 'none'
    assert realistic_suite.aspect_verdict((3, 1, 6, 5), truth) == 'top-1'
    assert realistic_suite.aspect_verdict((3, 1, 6, -1), truth) == 'partial'
    assert realistic_suite.aspect_verdict((3, -1, 6, -1), truth) == 'partial'
    assert realistic_suite.aspect_verdict((3, 1, 5, 6), truth) == 'wrong'    # mirrored
    assert realistic_suite.aspect_verdict((2, 1, 6, -1), truth) == 'wrong'   # wrong type
    assert realistic_suite.aspect_verdict((3, 1, 4, -1), truth) == 'wrong'   # wrong tag
