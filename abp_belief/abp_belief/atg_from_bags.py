"""ATG experience from recorded episodes of a known object (issue 13, item 2, second source).

Plain NumPy and the `rosbags` library, no rclpy. A real robot does not see the cube's
state; it sees aspects. Given the object a bag holds (a labels file: bag -> model name), the
states before and after each executed action are inferred from the bag's aspect
observations and turned into weighted transitions (`atg_learning.Experience`) that the
survey learner pools and estimates as it does the survey's (`atg_learning.learn`).

**Reading** (`read_episode`). Per bag: ``abp/aspect_observation`` (the best hypothesis,
as the belief node uses it), ``abp/executed_action`` and, when the bag has it (simulated
runs only), ``abp/sim/ground_truth`` for checking. Topics match in any namespace. Times are
the messages' header stamps. The abp_msgs definitions are registered from the .msg files
(`abp_common.bag_types`, shared with abp_bringup's recorder and player).

**Segments.** An executed action's stamp is its end; ``stamp - duration`` its start. The
cube is in one state between two actions: segment k holds the observations stamped after
action k ended and before action k+1 started (segment 0: before the first action).
Frames taken while an action runs show the cube (or the view) in motion and are not
used. Frames of one unchanged view are not independent evidence (the belief node
corrects once per action for this reason), so a segment's log-likelihood is the sum over
its frames scaled to at most `views_per_segment` observations' worth (a tempered
product: the geometric mean of the frames' likelihoods, to that power).

**Smoothing** (`infer_episode`). An HMM over the object's 48 states, one step per
executed action, uniform initial state. Transition of a successful action a:
``(1 - broad) * T_a + broad * B_a``, T_a the current table of the object's mass variant
(the model set's: hand-written, or a learned file), B_a a broad neighbourhood (manual
actions: no change, quarter and half rolls about the horizontal axes, each with yaw 0 or
+-45 deg, and T_a's support; ORBIT: any yaw with the same up face; plus 10 % uniform over
all 48), so that the observations can disagree with the table. A failed action (success
false: the belief node skips its prediction; not an ATG outcome, and not counted) still
may have moved the cube (a base that did not settle after most of an orbit):
``0.5 identity + 0.3 (the successful kernel) + 0.2 uniform``. An unknown action name or a
new episode in the same bag (sequence restarts) is a uniform kernel (the chain restarts).
Forward-backward gives the posterior of each segment's state and, per successful action,
xi(s, s') = p(state before = s, state after = s' | all observations of the episode).

**Experience.** Every successful action adds xi as fractional transitions (action, mass
of the object, s, s', weight xi(s, s')), entries below `min_weight` dropped and the rest
renormalised, so one action is one trial however ambiguous its states were; an
ambiguous inference is spread over its candidates by posterior, not dropped.
"""

from __future__ import annotations

import csv
import functools
import os
import pathlib
import time
from dataclasses import dataclass, field

import numpy as np

from abp_common import bag_types, names

from . import atg_learning, cube
from .cube import ACTIONS, NUM_MASS_VARIANTS, ORBIT_STEPS, STATES_PER_MODEL
from .modelset import ModelSet

_NS = STATES_PER_MODEL
DEFAULT_BROAD = 0.25
DEFAULT_VIEWS_PER_SEGMENT = 2.0
DEFAULT_MIN_WEIGHT = 1e-4
FAILED_MIX = (0.5, 0.3, 0.2)          # identity, successful kernel, uniform
BROAD_UNIFORM = 0.1                   # share of the broad kernel spread over all 48 states


class BagLearningError(ValueError):
    """A labels file, bag or label that cannot be learned from; the message says which."""


# -- labels ---------------------------------------------------------------------------------
def load_labels(path) -> list[tuple[str, str]]:
    """[(bag path, object name)] from a labels file; relative bag paths are relative to it.

    YAML: a mapping ``bag: object``, a list of ``{bag: ..., object: ...}``, or either under
    a top-level ``bags:`` key. CSV (``.csv``): rows ``bag,object``; a first row
    ``bag,object`` is a header. Lists and CSV may repeat a bag."""
    path = pathlib.Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise BagLearningError(f'{path}: cannot read the labels file ({exc})') from None
    rows: list[tuple[str, str]] = []
    if path.suffix.lower() == '.csv':
        for row in csv.reader(line for line in text.splitlines()
                              if line.strip() and not line.lstrip().startswith('#')):
            row = [c.strip() for c in row]
            if len(row) != 2:
                raise BagLearningError(f'{path}: expected rows "bag,object", got {row}')
            if not rows and row[0].lower() == 'bag':
                continue
            rows.append((row[0], row[1]))
    else:
        import yaml
        try:
            doc = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise BagLearningError(f'{path}: not YAML ({exc})') from None
        if isinstance(doc, dict) and set(doc) == {'bags'}:
            doc = doc['bags']
        if isinstance(doc, dict):
            rows = [(str(k), str(v)) for k, v in doc.items()]
        elif isinstance(doc, list):
            for item in doc:
                if not (isinstance(item, dict) and 'bag' in item and 'object' in item):
                    raise BagLearningError(f'{path}: list items need bag and object, got '
                                           f'{item!r}')
                rows.append((str(item['bag']), str(item['object'])))
        else:
            raise BagLearningError(f'{path}: expected a mapping bag -> object or a list')
    if not rows:
        raise BagLearningError(f'{path}: no bags listed')
    base = path.resolve().parent
    return [(os.fspath(base / bag), obj) for bag, obj in rows]


# -- reading bags ---------------------------------------------------------------------------
def typestore():
    """Jazzy's standard types plus every abp_msgs message (abp_common.bag_types)."""
    try:
        return bag_types.typestore()
    except FileNotFoundError as error:
        raise BagLearningError(str(error)) from None


def _which(topic: str) -> str | None:
    for key, name in (('obs', names.ASPECT_OBSERVATION), ('act', names.EXECUTED_ACTION),
                      ('truth', names.GROUND_TRUTH)):
        if topic == '/' + name or topic.endswith('/' + name):
            return key
    return None


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


@dataclass
class Episode:
    """The recognition evidence of one bag (times in ns, header stamps)."""

    obs_stamp: np.ndarray                 # (n,) observations with a hypothesis
    obs_z: np.ndarray                     # (n, 4) best hypothesis (type, s0, s1, s2)
    act_end: np.ndarray                   # (K,) executed actions, in time order
    act_start: np.ndarray                 # (K,) end - duration
    act_index: np.ndarray                 # (K,) index in ACTIONS, -1 unknown
    act_success: np.ndarray               # (K,) bool
    act_sequence: np.ndarray              # (K,) sequence number in the episode
    truth_stamp: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    truth_state: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    truth_object: str | None = None
    path: str | None = None
    # The world's count of manual actions (a push, or a grasp that rose), per truth message.
    truth_manual: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self):
        self.obs_stamp = np.asarray(self.obs_stamp, dtype=np.int64).reshape(-1)
        self.obs_z = np.asarray(self.obs_z, dtype=np.int64).reshape(-1, 4)
        for name in ('act_end', 'act_start', 'act_index', 'act_sequence', 'truth_stamp',
                     'truth_state', 'truth_manual'):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.int64).reshape(-1))
        self.act_success = np.asarray(self.act_success, dtype=bool).reshape(-1)

    @property
    def num_actions(self) -> int:
        return int(self.act_end.size)

    def segment_of_observations(self) -> np.ndarray:
        """(n,) segment index of each observation (0..K), -1 while an action runs."""
        k = np.searchsorted(self.act_end, self.obs_stamp, side='right')   # actions ended
        nxt = np.minimum(k, self.num_actions - 1)
        running = (k < self.num_actions) & (self.obs_stamp > self.act_start[nxt]) \
            if self.num_actions else np.zeros(self.obs_stamp.shape, bool)
        return np.where(running, -1, k)

    def true_transitions(self) -> np.ndarray:
        """(K, 2) ground-truth state at each action's start and after its end (-1 unknown):
        the last truth stamped at or before the start, the first at or after the end."""
        return self._around_actions(self.truth_state)

    def world_actions(self) -> np.ndarray:
        """(K,) manual actions the world counted during each action: 0 for a PUSH, LIFT or
        FLIP whose hands never touched the cube or let go of it before it rose; -1
        unknown (no truth, or bags without the count)."""
        if self.truth_manual.size != self.truth_stamp.size:
            return np.full(self.num_actions, -1, dtype=np.int64)
        around = self._around_actions(self.truth_manual)
        return np.where((around >= 0).all(axis=1), around[:, 1] - around[:, 0], -1)

    def _around_actions(self, values) -> np.ndarray:
        """(K, 2) `values` of the last truth at or before each action's start and the first
        at or after its end (-1 where there is none)."""
        out = np.full((self.num_actions, 2), -1, dtype=np.int64)
        if self.truth_stamp.size == 0:
            return out
        i = np.searchsorted(self.truth_stamp, self.act_start, side='right') - 1
        j = np.searchsorted(self.truth_stamp, self.act_end, side='left')
        out[:, 0] = np.where(i >= 0, values[np.maximum(i, 0)], -1)
        ok = j < self.truth_stamp.size
        out[:, 1] = np.where(ok, values[np.minimum(j, self.truth_stamp.size - 1)], -1)
        return out


def read_episode(path) -> Episode:
    """The observations, executed actions and (if recorded) ground truth of a bag."""
    from rosbags.highlevel import AnyReader
    path = pathlib.Path(path)
    if not path.exists():
        raise BagLearningError(f'bag {path} does not exist')
    store = typestore()
    obs_t, obs_z, acts, truth = [], [], [], []
    truth_object = None
    try:
        # Read with the definitions the bag was recorded with (abp_msgs may have gained
        # fields since); a bag without them with the current ones.
        with AnyReader([path], default_typestore=store) as reader:
            wanted = [c for c in reader.connections if _which(c.topic)]
            for connection, _, data in reader.messages(connections=wanted):
                kind = _which(connection.topic)
                msg = reader.deserialize(data, connection.msgtype)
                if kind == 'obs':
                    if not msg.hypotheses:
                        continue
                    best = msg.hypotheses[0]
                    slots = [int(s) for s in best.slots]
                    if int(best.aspect_type) == 2:
                        slots[2] = -1
                    obs_t.append(_ns(msg.header.stamp))
                    obs_z.append((int(best.aspect_type), *slots))
                elif kind == 'act':
                    end = _ns(msg.header.stamp)
                    acts.append((end, end - _ns(msg.duration),
                                 ACTIONS.index(msg.action) if msg.action in ACTIONS else -1,
                                 bool(msg.success), int(msg.sequence)))
                else:
                    truth.append((_ns(msg.header.stamp), int(msg.state),
                                  int(msg.manual_actions)))
                    truth_object = str(msg.object_id)
    except BagLearningError:
        raise
    except Exception as exc:  # rosbags raises several types for unreadable bags
        raise BagLearningError(f'cannot read bag {path}: {exc}') from exc
    acts.sort()
    truth.sort()
    order = np.argsort(np.asarray(obs_t, dtype=np.int64), kind='stable')
    a = np.asarray(acts, dtype=np.int64).reshape(-1, 5)
    t = np.asarray(truth, dtype=np.int64).reshape(-1, 3)
    return Episode(np.asarray(obs_t, np.int64)[order],
                   np.asarray(obs_z, np.int64).reshape(-1, 4)[order],
                   a[:, 0], np.minimum(a[:, 1], a[:, 0]), a[:, 2], a[:, 3].astype(bool),
                   a[:, 4], t[:, 0], t[:, 1], truth_object, os.fspath(path), t[:, 2])


# -- the object's HMM -------------------------------------------------------------------------
def object_model(model_set: ModelSet, name: str) -> ModelSet:
    """A one-model set of the object `name` (looked up in `model_set`, else parsed from the
    name ``c<t0>-..-<t5>/<mass>``), with `model_set`'s tag set, observation model and
    transition tables."""
    if name in model_set.names:
        i = model_set.model_index(name)
        faces, mass = model_set.faces[i], int(model_set.mass[i])
    else:
        try:
            tags, mass_name = name.split('/')
            if not tags.startswith('c'):
                raise ValueError
            faces = [int(t) for t in tags[1:].split('-')]
            mass = cube.MASS_NAMES.index(mass_name)
        except ValueError:
            raise BagLearningError(f'object {name!r} is not in the model set and not a model '
                                   "name like 'c0-3-2-4-6-5/m+z'") from None
    try:
        return ModelSet([faces], [mass], model_set.n_tags, names=[name],
                        cube_size=model_set.cube_size, feature_sigma=model_set.feature_sigma,
                        transition_params=model_set.transition_params,
                        observation_params=model_set.observation_params,
                        outcome_tables=(model_set.outcome_states, model_set.outcome_probs))
    except ValueError as exc:
        raise BagLearningError(f'object {name!r}: {exc}') from None


@functools.lru_cache(maxsize=1)
def _broad_support() -> np.ndarray:
    """(8, 48, 48) bool: the broad neighbourhood of each action (module doc)."""
    wide = atg_learning.neighbourhood('wide')
    up = np.arange(_NS) // cube.NUM_YAWS
    same_up = up[:, None] == up[None, :]
    return np.stack([same_up if a in ORBIT_STEPS else wide for a in ACTIONS])


def kernels(table: np.ndarray, mass: int, broad: float = DEFAULT_BROAD):
    """(success, failed) kernels, each (8, 48, 48), of mass variant `mass` (module doc)."""
    t = np.asarray(table)[:, mass]
    support = _broad_support() | (t > 0)
    b = support / support.sum(axis=2, keepdims=True)
    b = (1.0 - BROAD_UNIFORM) * b + BROAD_UNIFORM / _NS
    ok = (1.0 - broad) * t + broad * b
    w_id, w_ok, w_uni = FAILED_MIX
    failed = w_id * np.eye(_NS)[None] + w_ok * ok + w_uni / _NS
    return ok, failed


def segment_log_likelihood(episode: Episode, model: ModelSet,
                           views_per_segment: float = DEFAULT_VIEWS_PER_SEGMENT):
    """(K + 1, 48) tempered log p(observations of segment k | state), and (K + 1,) frames."""
    k1 = episode.num_actions + 1
    seg = episode.segment_of_observations()
    keep = seg >= 0
    loglik = np.zeros((k1, _NS))
    frames = np.bincount(seg[keep], minlength=k1).astype(np.float64)
    if keep.any():
        zs, inverse = np.unique(episode.obs_z[keep], axis=0, return_inverse=True)
        per_z = np.empty((len(zs), _NS))
        for i, z in enumerate(zs):
            try:
                lik = model.observation.likelihood(tuple(int(v) for v in z))
            except ValueError:                           # a tag outside the tag set
                lik = np.ones(model.num_aspects)
            per_z[i] = np.log(lik[model.node_aspect])
        np.add.at(loglik, seg[keep], per_z[inverse.reshape(-1)])
        scale = np.where(frames > 0, np.minimum(1.0, views_per_segment /
                                                np.maximum(frames, 1.0)), 0.0)
        loglik *= scale[:, None]
    return loglik, frames


@dataclass
class EpisodeInference:
    """Smoothed states of one episode."""

    name: str                       # the object
    mass: int
    gamma: np.ndarray               # (K + 1, 48) p(state of segment k | all observations)
    xi: np.ndarray                  # (K, 48, 48) p(before, after | all) per action
    action: np.ndarray              # (K,) action index (-1 unknown)
    counted: np.ndarray             # (K,) True: a successful action, an ATG outcome
    frames: np.ndarray              # (K + 1,) observations per segment
    log_evidence: float
    episode: Episode | None = None

    def map_transitions(self) -> np.ndarray:
        """(K, 2) MAP (before, after) pair of each action."""
        flat = self.xi.reshape(len(self.xi), _NS * _NS).argmax(axis=1)
        return np.stack(np.divmod(flat, _NS), axis=1)


def infer_episode(episode: Episode, model: ModelSet, table: np.ndarray | None = None,
                  broad: float = DEFAULT_BROAD,
                  views_per_segment: float = DEFAULT_VIEWS_PER_SEGMENT) -> EpisodeInference:
    """Forward-backward over the object's 48 states (module doc). `model`: a one-model set
    (`object_model`); `table`: (8, 7, 48, 48) current table, default `model`'s."""
    if table is None:
        table = _dense(model)
    mass = int(model.mass[0])
    ok, failed = kernels(table, mass, broad)
    n_act = episode.num_actions
    loglik, frames = segment_log_likelihood(episode, model, views_per_segment)
    emit = np.exp(loglik - loglik.max(axis=1, keepdims=True))
    a = episode.act_index
    new_episode = np.zeros(n_act, dtype=bool)
    new_episode[1:] = episode.act_sequence[1:] <= episode.act_sequence[:-1]
    known = a >= 0
    trans = np.full((n_act, _NS, _NS), 1.0 / _NS)
    use_ok = known & episode.act_success & ~new_episode
    use_failed = known & ~episode.act_success & ~new_episode
    trans[use_ok] = ok[a[use_ok]]
    trans[use_failed] = failed[a[use_failed]]
    # Forward (normalised) and backward (normalised) messages.
    alpha = np.empty((n_act + 1, _NS))
    scale = np.empty(n_act + 1)
    f = emit[0] / _NS
    scale[0] = f.sum()
    alpha[0] = f / scale[0]
    for k in range(n_act):
        f = (alpha[k] @ trans[k]) * emit[k + 1]
        scale[k + 1] = f.sum()
        alpha[k + 1] = f / scale[k + 1]
    beta = np.ones((n_act + 1, _NS))
    for k in range(n_act - 1, -1, -1):
        b = trans[k] @ (emit[k + 1] * beta[k + 1])
        beta[k] = b / scale[k + 1]
    gamma = alpha * beta
    gamma /= gamma.sum(axis=1, keepdims=True)
    xi = alpha[:-1, :, None] * trans * (emit[1:] * beta[1:])[:, None, :]
    xi /= np.maximum(xi.sum(axis=(1, 2), keepdims=True), 1e-300)
    log_evidence = float(np.log(scale).sum() + loglik.max(axis=1).sum())
    return EpisodeInference(model.names[0], mass, gamma, xi, a.copy(), use_ok, frames,
                            log_evidence, episode)


def _dense(model: ModelSet) -> np.ndarray:
    return atg_learning.dense_table(model.outcome_states, model.outcome_probs)


def experience_from_inferences(inferences, min_weight: float = DEFAULT_MIN_WEIGHT,
                               source: dict | None = None) -> atg_learning.Experience:
    """Fractional transitions of every counted action (module doc)."""
    parts = []
    for inf in inferences:
        for k in np.flatnonzero(inf.counted):
            xi = np.where(inf.xi[k] >= min_weight, inf.xi[k], 0.0)
            total = xi.sum()
            if not total > 0:
                continue
            s, s2 = np.nonzero(xi)
            w = xi[s, s2] / total
            parts.append(np.stack([np.full(s.size, inf.action[k]), np.full(s.size, inf.mass),
                                   s, s2]).T.astype(np.float64))
            parts[-1] = np.column_stack([parts[-1], w])
    data = np.concatenate(parts) if parts else np.zeros((0, 5))
    return atg_learning.Experience(data[:, 0], data[:, 1], data[:, 2], data[:, 3], data[:, 4],
                                   source=dict(source or {}))


def experience_from_bags(labels, model_set: ModelSet, table: np.ndarray | None = None,
                         broad: float = DEFAULT_BROAD,
                         views_per_segment: float = DEFAULT_VIEWS_PER_SEGMENT,
                         min_weight: float = DEFAULT_MIN_WEIGHT):
    """(Experience, [EpisodeInference]) of the bags of a labels file (path, or a list of
    (bag, object) pairs). `table`: the current (8, 7, 48, 48) table, default `model_set`'s."""
    t0 = time.perf_counter()
    labels_path = None
    if isinstance(labels, (str, os.PathLike)):
        labels_path = os.fspath(labels)
        labels = load_labels(labels)
    if table is None:
        table = atg_learning.dense_table(model_set.outcome_states, model_set.outcome_probs)
    if table.shape != (len(ACTIONS), NUM_MASS_VARIANTS, _NS, _NS):
        raise BagLearningError(f'table must have shape (8, 7, 48, 48), got {table.shape}')
    models: dict[str, ModelSet] = {}
    inferences = []
    for bag, name in labels:
        if name not in models:
            models[name] = object_model(model_set, name)
        episode = read_episode(bag)
        inferences.append(infer_episode(episode, models[name], table, broad,
                                        views_per_segment))
    source = dict(kind='bags', path=labels_path, bags=len(labels),
                  objects=sorted(models), broad=broad, views_per_segment=views_per_segment,
                  actions=int(sum(i.counted.sum() for i in inferences)),
                  failed_actions=int(sum((~i.counted & (i.action >= 0)).sum()
                                         for i in inferences)),
                  read_infer_s=round(time.perf_counter() - t0, 3))
    experience = experience_from_inferences(inferences, min_weight, source)
    experience.source['transitions'] = len(experience)
    return experience, inferences


def truth_agreement(inferences) -> dict:
    """Checks against the recorded ground truth (simulated bags): per counted action with a
    known true pair, whether the MAP before/after states match, and the posterior mass on
    the true pair. Also the bags whose ground-truth object differs from the label."""
    rows = []
    mismatch = []
    for inf in inferences:
        ep = inf.episode
        if ep is None or ep.truth_state.size == 0:
            continue
        if ep.truth_object is not None and ep.truth_object != inf.name:
            mismatch.append(ep.path)
        true = ep.true_transitions()
        guess = inf.map_transitions()
        for k in np.flatnonzero(inf.counted & (true >= 0).all(axis=1)):
            s, s2 = true[k]
            rows.append((bool(guess[k, 0] == s), bool(guess[k, 1] == s2),
                         float(inf.xi[k, s, s2])))
    if not rows:
        return dict(actions=0, label_mismatch=mismatch)
    r = np.array(rows)
    return dict(actions=len(rows), map_before=float(r[:, 0].mean()),
                map_after=float(r[:, 1].mean()), map_pair=float((r[:, 0] * r[:, 1]).mean()),
                mass_on_true_pair=float(r[:, 2].mean()),
                min_mass_on_true_pair=float(r[:, 2].min()), label_mismatch=mismatch)


__all__ = ['BagLearningError', 'DEFAULT_BROAD', 'DEFAULT_MIN_WEIGHT',
           'DEFAULT_VIEWS_PER_SEGMENT', 'Episode', 'EpisodeInference', 'experience_from_bags',
           'experience_from_inferences', 'infer_episode', 'kernels', 'load_labels',
           'object_model', 'read_episode', 'segment_log_likelihood', 'truth_agreement',
           'typestore']
