"""Model-set files: a versioned, checksummed .npz (no pickle).

Layout: one ``header`` member (UTF-8 JSON as uint8) plus the arrays in ARRAY_SPECS.
The header holds the format name and version, n_tags, counts, parameters, each
array's dtype and shape and the SHA-256 of the arrays. Transition matrices are
rebuilt from the stored outcome tables; aspects are re-derived from the faces and
must match the stored ones.

Version 2 (learned ATGs, issue 13) adds, optionally, ``outcome_counts`` (the experience
behind each edge of a learned table, the shape of ``outcome_states``) and a ``learning``
header entry (how the tables were learned; null for hand-written ones). Version 1 files
are still read (no counts). The header's sha256 covers every stored array; `fingerprint`
(the model-set id the nodes publish) covers the version-1 arrays only, i.e. what the
models predict, not the experience behind it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import zipfile
import zlib

import numpy as np

from .cube import ACTIONS, NUM_MASS_VARIANTS, STATES_PER_MODEL, check_n_tags
from .modelset import ModelSet, ObservationParams, TransitionParams

FORMAT_NAME = 'abp_belief.modelset'
FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (1, 2)
_ZIP_MAGIC = b'PK\x03\x04'

# name -> (dtype, shape template); symbols M (models), N (nodes), A (aspects), K (outcomes).
ARRAY_SPECS = {
    'faces': ('int16', ('M', 6)),
    'mass': ('int8', ('M',)),
    'visual_id': ('int32', ('M',)),
    'names': ('unicode', ('M',)),
    'node_aspect': ('int32', ('N',)),
    'aspects': ('int16', ('A', 4)),
    'outcome_states': ('int16', (len(ACTIONS), NUM_MASS_VARIANTS, STATES_PER_MODEL, 'K')),
    'outcome_probs': ('float64', (len(ACTIONS), NUM_MASS_VARIANTS, STATES_PER_MODEL, 'K')),
}
# Version 2: stored when present (learned tables).
OPTIONAL_ARRAY_SPECS = {
    'outcome_counts': ('float64', (len(ACTIONS), NUM_MASS_VARIANTS, STATES_PER_MODEL, 'K')),
}


class ModelFileError(Exception):
    """A model-set file is missing, corrupt, inconsistent or of an unsupported format."""


def _arrays_of(model_set: ModelSet) -> dict[str, np.ndarray]:
    arrays = {
        'faces': model_set.faces,
        'mass': model_set.mass,
        'visual_id': model_set.visual_id,
        'names': np.array(model_set.names, dtype=str),
        'node_aspect': model_set.node_aspect,
        'aspects': model_set.aspects,
        'outcome_states': model_set.outcome_states,
        'outcome_probs': model_set.outcome_probs,
    }
    if getattr(model_set, 'outcome_counts', None) is not None:
        arrays['outcome_counts'] = np.asarray(model_set.outcome_counts, dtype=np.float64)
    return arrays


def arrays_sha256(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 over (name, dtype, shape, bytes) of each array in ARRAY_SPECS order, then of
    each OPTIONAL_ARRAY_SPECS array present in `arrays`."""
    digest = hashlib.sha256()
    for name in list(ARRAY_SPECS) + [n for n in OPTIONAL_ARRAY_SPECS if n in arrays]:
        arr = np.ascontiguousarray(arrays[name])
        digest.update(f'{name}|{arr.dtype.str}|{arr.shape}|'.encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()


def fingerprint(model_set: ModelSet) -> str:
    """sha256 identifying a model set's content: its version-1 arrays (for a hand-written
    set the same as stored in its file header; learned counts are not part of it)."""
    arrays = _arrays_of(model_set)
    return arrays_sha256({name: arrays[name] for name in ARRAY_SPECS})


def make_header(model_set: ModelSet, arrays: dict[str, np.ndarray]) -> dict:
    return {
        'format': FORMAT_NAME,
        'version': FORMAT_VERSION,
        'n_tags': model_set.n_tags,
        'num_models': model_set.num_models,
        'num_visual_cubes': model_set.num_visual_cubes,
        'num_nodes': model_set.num_nodes,
        'num_aspects': model_set.num_aspects,
        'cube_size': model_set.cube_size,
        'feature_sigma': model_set.feature_sigma,
        'transition_params': dataclasses.asdict(model_set.transition_params),
        'observation_params': dataclasses.asdict(model_set.observation_params),
        'learning': getattr(model_set, 'learning', None),
        'arrays': {name: {'dtype': arr.dtype.str, 'shape': list(arr.shape)}
                   for name, arr in arrays.items()},
        'sha256': arrays_sha256(arrays),
    }


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def write_npz(path, header: dict, arrays: dict[str, np.ndarray]):
    """Write header + arrays atomically (temp file, then rename)."""
    path = os.fspath(path)
    tmp = f'{path}.tmp{os.getpid()}'
    text = json.dumps(header, sort_keys=True, default=_json_default)
    members = {'header': np.frombuffer(text.encode(), np.uint8)}
    members.update(arrays)
    try:
        with open(tmp, 'wb') as fh:
            np.savez_compressed(fh, **members)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def save(model_set: ModelSet, path):
    """Write `model_set` to `path` (exact name; no suffix is added)."""
    arrays = _arrays_of(model_set)
    write_npz(path, make_header(model_set, arrays), arrays)


def _read_members(path: str) -> dict[str, np.ndarray]:
    try:
        with open(path, 'rb') as fh:
            magic = fh.read(4)
    except FileNotFoundError:
        raise ModelFileError(f'{path}: no such file') from None
    except OSError as exc:
        raise ModelFileError(f'{path}: cannot read: {exc.strerror or exc}') from None
    if magic != _ZIP_MAGIC:
        raise ModelFileError(f'{path}: not a model-set file (no .npz/zip signature)')
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError) as exc:
        raise ModelFileError(f'{path}: truncated or corrupt model-set file ({exc})') from None


def _read_header(path: str, members: dict) -> dict:
    if 'header' not in members:
        raise ModelFileError(f"{path}: no 'header' member; not a {FORMAT_NAME} file")
    raw = members['header']
    try:
        header = json.loads(raw.astype(np.uint8).tobytes().decode('utf-8'))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ModelFileError(f'{path}: header is not valid JSON ({exc})') from None
    if not isinstance(header, dict) or header.get('format') != FORMAT_NAME:
        found = header.get('format') if isinstance(header, dict) else None
        raise ModelFileError(f'{path}: wrong format {found!r} (expected {FORMAT_NAME!r})')
    version = header.get('version')
    if version not in SUPPORTED_VERSIONS:
        raise ModelFileError(f'{path}: unsupported format version {version!r} '
                             f'(this reader supports {list(SUPPORTED_VERSIONS)})')
    for key in ('n_tags', 'num_models', 'num_nodes', 'num_aspects', 'sha256', 'cube_size',
                'feature_sigma', 'transition_params', 'observation_params'):
        if key not in header:
            raise ModelFileError(f"{path}: header lacks '{key}'")
    return header


def _check_arrays(path: str, header: dict, members: dict) -> dict[str, np.ndarray]:
    arrays = {}
    try:
        dims = {'M': int(header['num_models']), 'N': int(header['num_nodes']),
                'A': int(header['num_aspects'])}
    except (TypeError, ValueError):
        raise ModelFileError(f'{path}: header counts are not integers') from None
    if dims['N'] != dims['M'] * STATES_PER_MODEL:
        raise ModelFileError(f"{path}: num_nodes {dims['N']} != 48 * num_models {dims['M']}")
    specs = dict(ARRAY_SPECS)
    if header['version'] >= 2:
        listed = header.get('arrays') or {}
        specs.update({name: spec for name, spec in OPTIONAL_ARRAY_SPECS.items()
                      if name in members or name in listed})
    for name, (dtype, template) in specs.items():
        if name not in members:
            raise ModelFileError(f"{path}: missing array '{name}'")
        arr = members[name]
        if dtype == 'unicode':
            if arr.dtype.kind != 'U':
                raise ModelFileError(f"{path}: array '{name}' has dtype {arr.dtype}, expected str")
        elif arr.dtype != np.dtype(dtype):
            raise ModelFileError(f"{path}: array '{name}' has dtype {arr.dtype}, expected {dtype}")
        if 'K' in template and arr.ndim == len(template):
            dims.setdefault('K', arr.shape[-1])
        expected = tuple(dims.get(d, -1) if isinstance(d, str) else d for d in template)
        if arr.shape != expected:
            raise ModelFileError(f"{path}: array '{name}' has shape {arr.shape}, "
                                 f"expected {expected}")
        arrays[name] = arr
    digest = arrays_sha256(arrays)
    if digest != header['sha256']:
        raise ModelFileError(f"{path}: checksum mismatch (arrays modified or corrupt): "
                             f"header {str(header['sha256'])[:16]}..., data {digest[:16]}...")
    return arrays


def _check_ranges(path: str, n_tags: int, arrays: dict[str, np.ndarray]):
    faces = arrays['faces']
    if faces.size and (faces.min() < 0 or faces.max() >= n_tags):
        raise ModelFileError(f'{path}: tag ids out of range 0..{n_tags - 1} '
                             f'(found {faces.min()}..{faces.max()})')
    mass = arrays['mass']
    if mass.size and (mass.min() < 0 or mass.max() >= NUM_MASS_VARIANTS):
        raise ModelFileError(f'{path}: mass indices out of range 0..{NUM_MASS_VARIANTS - 1}')
    states = arrays['outcome_states']
    if states.min() < 0 or states.max() >= STATES_PER_MODEL:
        raise ModelFileError(f'{path}: outcome_states out of range 0..{STATES_PER_MODEL - 1}')
    probs = arrays['outcome_probs']
    if not np.isfinite(probs).all() or probs.min() < 0 \
            or not np.allclose(probs.sum(axis=3), 1.0, atol=1e-9):
        raise ModelFileError(f'{path}: outcome_probs are not distributions (>= 0, sum 1)')
    counts = arrays.get('outcome_counts')
    if counts is not None and (not np.isfinite(counts).all() or counts.min() < 0):
        raise ModelFileError(f'{path}: outcome_counts must be finite and >= 0')


def load(path) -> ModelSet:
    """Read a model set written by `save`; raises ModelFileError naming file and problem."""
    path = os.fspath(path)
    members = _read_members(path)
    header = _read_header(path, members)
    try:
        n_tags = check_n_tags(header['n_tags'])
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f'{path}: bad n_tags in header ({exc})') from None
    arrays = _check_arrays(path, header, members)
    _check_ranges(path, n_tags, arrays)
    try:
        model_set = ModelSet(
            arrays['faces'], arrays['mass'], n_tags, names=arrays['names'].tolist(),
            cube_size=float(header['cube_size']), feature_sigma=float(header['feature_sigma']),
            transition_params=TransitionParams(**header['transition_params']),
            observation_params=ObservationParams(**header['observation_params']),
            outcome_tables=(arrays['outcome_states'], arrays['outcome_probs']),
            outcome_counts=arrays.get('outcome_counts'), learning=header.get('learning'))
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f'{path}: invalid model set ({exc})') from None
    for name in ('visual_id', 'node_aspect', 'aspects'):
        if not np.array_equal(getattr(model_set, name), arrays[name]):
            raise ModelFileError(f"{path}: stored '{name}' is inconsistent with the faces")
    return model_set
