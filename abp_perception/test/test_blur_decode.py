"""Decoding blurred markers by correlation with blurred codes (issue 16)."""

import cv2
import numpy as np

from abp_perception.blur_decode import blur_kernels, code_matrix, darkness, decode_blurred
from abp_perception.corners import code_table, decode_quads

DICT = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)


def _scene(marker_id, side=26.0, angle_deg=20.0, blur=7, blur_angle=35.0, seed=0):
    """A marker (1-cell white quiet zone) on a grey background, rotated, motion-blurred
    by `blur` px; its true quad (clockwise on screen, ArUco order)."""
    rng = np.random.default_rng(seed)
    card = np.full((80, 80), 200, np.uint8)
    card[10:70, 10:70] = DICT.generateImageMarker(marker_id, 60)
    a = np.radians(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    quad = np.array([80.0, 80.0]) + (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
                                     * side / 2) @ rot.T
    h = cv2.getPerspectiveTransform(np.float32([[10, 10], [70, 10], [70, 70], [10, 70]]),
                                    quad.astype(np.float32))
    img = cv2.warpPerspective(card, h, (160, 160), borderValue=110).astype(np.float32)
    if blur:
        k = np.zeros((blur, blur), np.float32)
        k[blur // 2, :] = 1.0
        k = cv2.warpAffine(k, cv2.getRotationMatrix2D(((blur - 1) / 2, (blur - 1) / 2),
                                                      blur_angle, 1.0), (blur, blur))
        img = cv2.filter2D(img, -1, k / k.sum())
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), quad


def test_code_matrix_matches_the_code_table():
    x, ids, rots = code_matrix(DICT)
    assert x.shape == (4 * 50, 37) and np.all(x[:, -1] == 1)
    table = code_table(DICT)
    cells = x[:, :36].reshape(-1, 6, 6)
    assert np.all(cells[:, 0] == 0) and np.all(cells[:, :, 0] == 0)      # black border
    bits = cells[:, 1:5, 1:5] > 0.5
    packed = (bits.reshape(-1, 16).astype(np.int64) << np.arange(16)).sum(axis=1)
    for p, i, r in zip(packed, ids, rots):
        assert table[int(p)][0] == i
    off, w, kid, k = blur_kernels()
    np.testing.assert_allclose(np.bincount(kid, w, minlength=k), 1.0)


def test_a_blurred_marker_the_bits_misread_is_decoded_with_its_rotation():
    # 20 px markers blurred by 8 px: the bits misread two of them; correlation reads
    # five of six and never a wrong id.
    misread = decoded = 0
    for seed, marker_id in enumerate((3, 17, 29, 41, 8, 22)):
        gray, quad = _scene(marker_id, side=20.0, blur=8, seed=seed)
        bits = decode_quads(gray, quad[None], DICT)[0]
        misread += bits is None or bits[0] != marker_id
        res = decode_blurred(gray, quad[None], DICT)[0]
        if res is None:
            continue
        assert res[0] == marker_id
        # The rotation puts the marker's top-left corner first, as decode_quads does on
        # the sharp image.
        sharp, _ = _scene(marker_id, side=20.0, blur=0, seed=seed)
        assert decode_quads(sharp, quad[None], DICT)[0][1] == res[1]
        decoded += 1
    assert misread >= 2 and decoded >= 5


def test_no_marker_no_decode():
    rng = np.random.default_rng(5)
    gray, quad = _scene(3)
    # A plain region and a random-bit fake tag (not in the dictionary) give nothing.
    plain = np.full_like(gray, 150)
    assert decode_blurred(plain, quad[None], DICT) == [None]
    assert darkness(plain, quad[None], 6)[0] < 1.0
    fake = np.full((80, 80), 200, np.uint8)
    cells = np.zeros((6, 6), np.uint8)
    cells[1:5, 1:5] = (rng.integers(0, 2, (4, 4)) * 255).astype(np.uint8)
    table = code_table(DICT)
    bits = cells[1:5, 1:5] > 127
    assert all(int((np.rot90(bits, t).ravel().astype(np.int64) << np.arange(16)).sum())
               not in table for t in range(4))
    fake[10:70, 10:70] = cv2.resize(cells, (60, 60), interpolation=cv2.INTER_NEAREST)
    h = cv2.getPerspectiveTransform(np.float32([[10, 10], [70, 10], [70, 70], [10, 70]]),
                                    quad.astype(np.float32))
    img = cv2.warpPerspective(fake, h, (160, 160), borderValue=110)
    res = decode_blurred(img, quad[None], DICT)[0]
    assert res is None


def test_square_homographies_match_opencv_and_flag_degenerate_quads():
    from abp_perception.corners import square_homographies
    rng = np.random.default_rng(3)
    square = np.float32([[0, 0], [6, 0], [6, 6], [0, 6]])
    quads = np.array([[[10, 12], [50, 8], [55, 60], [5, 49]],
                      [[100, 100], [140, 104], [138, 150], [96, 144]]], float)
    quads = quads + rng.normal(0, 0.5, quads.shape)
    h = square_homographies(np.concatenate([quads, np.zeros((1, 4, 2))]), 6)
    for k, quad in enumerate(quads):
        np.testing.assert_allclose(
            h[k], cv2.getPerspectiveTransform(square, quad.astype(np.float32)), rtol=1e-5,
            atol=1e-5)
    assert not np.isfinite(h[2]).any()


def test_marker_contrast_tells_markers_from_dark_blobs_and_plain_texture():
    from abp_perception.blur_decode import marker_contrast
    gray, quad = _scene(17, side=26.0, blur=0)
    frame, bits = marker_contrast(gray, quad[None], 6)
    assert frame[0] > 60 and bits[0] > 60
    # A uniformly dark square in the marker's place: a frame, but no bits.
    blob = np.full_like(gray, 200)
    cv2.fillConvexPoly(blob, np.round(quad).astype(np.int32), 40)
    frame, bits = marker_contrast(blob, quad[None], 6)
    assert frame[0] > 60 and bits[0] < 15
    # Random texture: no dark frame against a brighter quiet zone.
    noise = np.random.default_rng(6).integers(0, 256, gray.shape).astype(np.uint8)
    noise = cv2.GaussianBlur(noise, (0, 0), 4.0)
    frame, _ = marker_contrast(noise, quad[None], 6)
    assert frame[0] < 15
    assert [a.shape for a in marker_contrast(gray, np.zeros((0, 4, 2)), 6)] == [(0,), (0,)]
