import json

import numpy as np
import pytest

from abp_belief import model_file, modelset, population

ObservationParams, TransitionParams = modelset.ObservationParams, modelset.TransitionParams


@pytest.fixture(scope='module')
def small():
    return population.robot_set(seed=2, transition_params=TransitionParams(p_fail_flip=0.2),
                                observation_params=ObservationParams(p_miss=0.1),
                                cube_size=0.08, feature_sigma=0.004)


@pytest.fixture
def saved(small, tmp_path):
    path = tmp_path / 'robot.npz'
    model_file.save(small, path)
    return path


def _members(path):
    with np.load(path, allow_pickle=False) as npz:
        members = {k: npz[k] for k in npz.files}
    header = json.loads(members.pop('header').tobytes())
    return header, members


def _rewrite(path, header, arrays, rehash=True):
    if rehash:
        header['sha256'] = model_file.arrays_sha256(arrays)
    model_file.write_npz(path, header, arrays)


def test_round_trip_is_identical(small, saved):
    loaded = model_file.load(saved)
    for name in ('faces', 'mass', 'visual_id', 'node_aspect', 'aspects', 'outcome_states',
                 'outcome_probs'):
        a, b = getattr(small, name), getattr(loaded, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert loaded.names == small.names
    assert loaded.n_tags == small.n_tags
    assert loaded.transition_params == small.transition_params
    assert loaded.observation_params == small.observation_params
    assert loaded.cube_size == 0.08 and loaded.feature_sigma == 0.004
    for name, matrix in small.transitions.items():
        assert (matrix != loaded.transitions[name]).nnz == 0
    assert np.array_equal(small.observation.aspect_likelihood,
                          loaded.observation.aspect_likelihood)
    assert saved.exists() and not list(saved.parent.glob('*.tmp*'))


def test_full_set_round_trip(full7, tmp_path):
    path = tmp_path / 'full.models'                      # any suffix; nothing is appended
    model_file.save(full7, path)
    loaded = model_file.load(path)
    assert loaded.num_models == 1470 and np.array_equal(loaded.node_aspect, full7.node_aspect)


def _expect(path, *fragments):
    with pytest.raises(model_file.ModelFileError) as info:
        model_file.load(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_missing_file(tmp_path):
    _expect(tmp_path / 'nope.npz', 'no such file')


def test_not_an_npz(tmp_path):
    path = tmp_path / 'text.npz'
    path.write_text('hello, I am not a model set')
    _expect(path, 'not a model-set file')


def test_truncated(saved):
    data = saved.read_bytes()
    saved.write_bytes(data[: len(data) // 2])
    _expect(saved, 'truncated or corrupt')


def test_corrupted_bytes(saved):
    data = bytearray(saved.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 64] = bytes(64)
    saved.write_bytes(bytes(data))
    with pytest.raises(model_file.ModelFileError, match='robot.npz'):
        model_file.load(saved)


def test_wrong_format_name(saved):
    header, arrays = _members(saved)
    header['format'] = 'something.else'
    _rewrite(saved, header, arrays)
    _expect(saved, 'wrong format', 'something.else')


def test_missing_header(saved, tmp_path):
    _, arrays = _members(saved)
    with open(saved, 'wb') as fh:
        np.savez(fh, **arrays)
    _expect(saved, "no 'header'")


def test_unsupported_version(saved):
    header, arrays = _members(saved)
    header['version'] = model_file.FORMAT_VERSION + 1
    _rewrite(saved, header, arrays)
    _expect(saved, 'unsupported format version', str(model_file.FORMAT_VERSION + 1))


def test_checksum_mismatch(saved):
    header, arrays = _members(saved)
    arrays['outcome_probs'] = arrays['outcome_probs'].copy()
    arrays['outcome_probs'][5, 0, 0, :2] = arrays['outcome_probs'][5, 0, 0, 1::-1]
    _rewrite(saved, header, arrays, rehash=False)
    _expect(saved, 'checksum mismatch')


def test_shape_mismatch(saved):
    header, arrays = _members(saved)
    arrays['node_aspect'] = arrays['node_aspect'][:-48]
    _rewrite(saved, header, arrays)
    _expect(saved, 'node_aspect', 'shape')
    header, arrays = _members(saved)
    arrays['faces'] = arrays['faces'][:, :5]
    _rewrite(saved, header, arrays)
    _expect(saved, 'faces', 'shape')


def test_wrong_dtype(saved):
    header, arrays = _members(saved)
    arrays['faces'] = arrays['faces'].astype(np.float32)
    _rewrite(saved, header, arrays)
    _expect(saved, 'faces', 'dtype')


def test_missing_array(saved):
    header, arrays = _members(saved)
    del arrays['aspects']
    with open(saved, 'wb') as fh:
        members = {'header': np.frombuffer(json.dumps(header).encode(), np.uint8)}
        np.savez(fh, **members, **arrays)
    _expect(saved, "missing array 'aspects'")


def test_out_of_range_tags(saved):
    header, arrays = _members(saved)
    arrays['faces'] = arrays['faces'].copy()
    arrays['faces'][3, 2] = 9
    _rewrite(saved, header, arrays)
    _expect(saved, 'tag ids out of range', '0..6')


def test_bad_n_tags_in_header(saved):
    header, arrays = _members(saved)
    header['n_tags'] = 99
    _rewrite(saved, header, arrays)
    _expect(saved, 'n_tags', '6..50')


def test_inconsistent_aspects(saved):
    header, arrays = _members(saved)
    arrays['node_aspect'] = arrays['node_aspect'].copy()
    arrays['node_aspect'][[0, 1]] = arrays['node_aspect'][[1, 0]]
    _rewrite(saved, header, arrays)
    _expect(saved, 'node_aspect', 'inconsistent')


def test_probabilities_not_distributions(saved):
    header, arrays = _members(saved)
    arrays['outcome_probs'] = arrays['outcome_probs'] * 1.5
    _rewrite(saved, header, arrays)
    _expect(saved, 'outcome_probs')
