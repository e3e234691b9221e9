"""Bit decoding of quads (abp_perception.corners): the code table that replaces
``Dictionary.identify`` must answer exactly as identify does without error correction."""

import cv2
import numpy as np
import pytest
from tag_scene import paste_tag

from abp_perception.corners import code_table, decode_quads

DICTIONARIES = ('DICT_4X4_50', 'DICT_5X5_100', 'DICT_6X6_250', 'DICT_7X7_50',
                'DICT_APRILTAG_36h11')


def _patterns(dictionary, rng, random_count=300, markers=12):
    """`markers` markers spread over the dictionary in their four rotations, each with one
    bit flipped too, and random bit patterns (almost none of them a code). Few: identify
    of a pattern it does not find is slow (it is why the table exists)."""
    n = dictionary.markerSize
    out = [rng.integers(0, 2, (n, n)).astype(np.uint8) for _ in range(random_count)]
    for marker in np.linspace(0, dictionary.bytesList.shape[0] - 1, markers).astype(int):
        bits = (dictionary.generateImageMarker(marker, n + 2)[1:-1, 1:-1] > 127)
        for turns in range(4):
            pattern = np.ascontiguousarray(np.rot90(bits, turns)).astype(np.uint8)
            flipped = pattern.copy()
            flipped[rng.integers(n), rng.integers(n)] ^= 1
            out += [pattern, flipped]
    return out


@pytest.mark.parametrize('name', DICTIONARIES)
def test_code_table_answers_as_identify_without_error_correction(name):
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    table = code_table(dictionary)
    assert len(table) == 4 * dictionary.bytesList.shape[0]
    weights = 1 << np.arange(dictionary.markerSize ** 2)
    rng = np.random.default_rng(3)
    found = 0
    for bits in _patterns(dictionary, rng):
        ok, idx, rotation = dictionary.identify(bits, 0.0)
        expected = (int(idx), int(rotation)) if ok else None
        assert table.get(int(bits.ravel().astype(np.int64) @ weights)) == expected
        found += ok
    assert found >= 4 * 12


@pytest.mark.parametrize('rotation', range(4))
def test_decoded_rotation_puts_the_top_left_corner_first(rotation):
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    image = np.full((120, 160), 200, np.uint8)
    corners = paste_tag(image, 11, (80, 60), 48)
    # The same quad with its corners listed from another one: decoding names the shift.
    quad = np.roll(corners, -rotation, axis=0)
    (tag_id, found_rotation), = decode_quads(image, quad[None], dictionary)
    assert tag_id == 11
    np.testing.assert_allclose(np.roll(quad, found_rotation, axis=0), corners)
    assert decode_quads(np.full_like(image, 200), quad[None], dictionary) == [None]
