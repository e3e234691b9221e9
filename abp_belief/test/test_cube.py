import numpy as np
import pytest

from abp_belief import cube


def test_cube_group_is_the_24_proper_rotations_identity_first():
    group = cube.CUBE_ROTATIONS
    assert group.shape == (24, 3, 3)
    assert np.allclose(group[0], np.eye(3))
    assert np.allclose(np.linalg.det(group), 1.0)
    flat = {tuple(q.astype(int).ravel()) for q in group}
    assert len(flat) == 24


def test_r_up_takes_each_face_to_top():
    for f in range(6):
        assert np.allclose(cube.R_UP[f] @ cube.FACE_NORMALS[f], [0, 0, 1])


def test_states_are_48_distinct_rotations_and_even_ones_are_the_cube_group():
    rots = cube.STATE_ROTATIONS
    assert len({tuple(np.round(r, 6).ravel()) for r in rots}) == 48
    even = {tuple(np.round(r, 6).ravel()) for r in rots[cube.STATE_YAW % 2 == 0]}
    assert even == {tuple(np.round(q, 6).ravel()) for q in cube.CUBE_ROTATIONS}
    for s in range(48):
        assert cube.state_from_rotation(rots[s]) == s
        assert cube.STATE_TOP_FACE[s] == s // 8


def test_view_frame_is_right_handed_and_plus_y_is_robot_right():
    # y = z x x; robot looks along -x, so its right is (-x) x z = +y.
    assert np.allclose(np.cross([0, 0, 1], [1, 0, 0]), [0, 1, 0])
    assert np.allclose(np.cross([-1, 0, 0], [0, 0, 1]), [0, 1, 0])


def test_aspect_types_follow_yaw_parity():
    tags = [10, 11, 12, 13, 14, 15]
    for s in range(48):
        key = cube.aspect_of(tags, s)
        assert key[0] == (2 if s % 2 == 0 else 3)
        assert key[1] == tags[s // 8]
        if key[0] == 2:
            assert key[3] == -1
        assert len(set(key[1:1 + key[0]])) == key[0]


def test_identity_state_aspects():
    tags = [0, 1, 2, 3, 4, 5]             # +x -x +y -y +z -z
    up_z = 8 * 4
    assert cube.aspect_of(tags, up_z) == (2, 4, 0, -1)            # top +z, front +x
    # Rotated +45 deg: the +x face moves to the robot's right, -y to its left.
    assert cube.aspect_of(tags, up_z + 1) == (3, 4, 0, 3)


def test_mirror_cubes_have_different_aspects():
    cube_a = [0, 1, 2, 3, 4, 5]
    mirror = [0, 1, 3, 2, 4, 5]           # +y and -y swapped: the mirror image
    assert not np.array_equal(cube.canonical_faces(cube_a), cube.canonical_faces(mirror))
    aspects_a = {cube.aspect_of(cube_a, s) for s in range(48)}
    aspects_m = {cube.aspect_of(mirror, s) for s in range(48)}
    # Same adjacency -> same (top, front) pairs; chirality shows only in the 3-feature slots.
    assert {a for a in aspects_a if a[0] == 2} == {a for a in aspects_m if a[0] == 2}
    assert {a for a in aspects_a if a[0] == 3} != {a for a in aspects_m if a[0] == 3}
    assert not ({a for a in aspects_a if a[0] == 3} & {a for a in aspects_m if a[0] == 3})


def test_canonical_faces_is_lexmin_over_rotations():
    rng = np.random.default_rng(0)
    for _ in range(20):
        faces = rng.permutation(9)[:6]
        canon = cube.canonical_faces(faces)
        rotated = faces[cube.ROTATION_FACE_SOURCE]
        assert tuple(canon) == min(tuple(r) for r in rotated)
        assert tuple(cube.canonical_faces(rotated[rng.integers(24)])) == tuple(canon)


def test_action_index_and_n_tags_validation():
    assert cube.action_index('FLIP') == 7
    assert cube.action_index(5) == 5
    with pytest.raises(ValueError, match='unknown action'):
        cube.action_index('JUMP')
    with pytest.raises(ValueError, match='out of range'):
        cube.action_index(8)
    for bad in (5, 51, 0, -1):
        with pytest.raises(ValueError, match='6..50'):
            cube.check_n_tags(bad)


def test_aspect_feature_geometry(robot):
    row2 = int(np.flatnonzero(robot.aspects[:, 0] == 2)[0])
    row3 = int(np.flatnonzero(robot.aspects[:, 0] == 3)[0])
    h = robot.cube_size
    pos2 = robot.aspect_feature_positions(row2)
    assert np.allclose(pos2, [[0, 0, h / 2], [h / 2, 0, 0]])
    pos3 = robot.aspect_feature_positions(row3)
    assert pos3.shape == (3, 3)
    assert pos3[1, 1] > 0 > pos3[2, 1]                     # plus_y on the robot's right
    assert np.allclose(np.linalg.norm(pos3, axis=1), h / 2)
    pairs = robot.aspect_pair_gaussians(row3)
    assert pairs.slots.tolist() == [[0, 1], [0, 2], [1, 2]]
    assert pairs.tags.tolist() == [[robot.aspects[row3, 1 + i], robot.aspects[row3, 1 + j]]
                                   for i, j in pairs.slots]
    assert np.allclose(pairs.mean, h / np.sqrt(2))
    assert np.allclose(pairs.sigma, 0.005)
    assert len(robot.aspect_pair_gaussians(row2).mean) == 1
