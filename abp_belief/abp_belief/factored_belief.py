"""One ATG belief per object (factored, OO-POMDP style; issue 37). No rclpy.

A scene holds K cubes; the joint belief over K objects would grow as |N|^K, so it is
factored: each object (a track id, any hashable) has its own node belief over the one
model population, and an action or observation of object A updates A's belief only.
The objects are independent under this belief: two cubes may be the same model (a lab
may own two copies), as in MOS (Wandzel et al. 2019).

The maths is ``abp_belief.filter``'s (``predict_belief``, ``correct_belief``,
``correct_beliefs``): this module only keeps the K beliefs as rows of one (K, N) array
so that K objects can be updated together (one CSR product predicts several objects
through the same action, one gather corrects the objects of one camera view) and so
that object k's belief is the contiguous row ``beliefs[k]`` the planner reads without
a copy. With one object every number is the single-object ``BeliefFilter``'s.

Each object also carries a version (incremented by every change of its belief): a
planner may cache an object's scores until its version changes.

Relative state. The state of a cube is relative to the robot's view of it (up face and
yaw, docs/MODEL.md). Acting on A leaves B where it lies in the world, so B's state is
kept; when the robot later views B from another bearing, ``shift_yaw(B, steps)`` turns
B's belief by that many 45° steps (a permutation of the yaw, the nominal ORBIT rotation
without its noise; the wiring rounds the bearing change measured in ``odom``).
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable

import numpy as np

from .cube import NUM_YAWS, STATES_PER_MODEL
from .filter import (
    BeliefFilter,
    correct_belief,
    correct_beliefs,
    entropy_bits,
    predict_belief,
)
from .modelset import ModelSet


class UnknownObjectError(KeyError):
    """An update names an object id the belief does not track."""


class FactoredBelief:
    """K independent node beliefs over one model set, keyed by object (track) id."""

    def __init__(self, model_set: ModelSet, object_ids: Iterable[Hashable] = (), prior=None):
        self.model_set = model_set
        # The single-object filter's prior (uniform over models, spread over 48 states,
        # or the given per-model weights, validated there).
        self._prior = BeliefFilter(model_set, prior).belief
        self._ids: list[Hashable] = []
        self._row: dict[Hashable, int] = {}
        self.beliefs = np.empty((0, model_set.num_nodes))
        self._versions: list[int] = []
        self._likelihood_buffer = np.empty(model_set.num_nodes)
        for object_id in object_ids:
            self.add_object(object_id)

    # -- objects ------------------------------------------------------------------------
    @property
    def object_ids(self) -> tuple:
        return tuple(self._ids)

    def __len__(self) -> int:
        return len(self._ids)

    def __contains__(self, object_id) -> bool:
        return object_id in self._row

    def add_object(self, object_id: Hashable, prior=None) -> None:
        """Track a new object, starting from the prior (or per-model weights ``prior``)."""
        if object_id in self._row:
            raise ValueError(f'object {object_id!r} is already tracked')
        start = self._prior if prior is None else BeliefFilter(self.model_set, prior).belief
        self._row[object_id] = len(self._ids)
        self._ids.append(object_id)
        self.beliefs = np.concatenate([self.beliefs, start[None, :]])
        self._versions.append(0)

    def remove_object(self, object_id: Hashable) -> None:
        k = self._index(object_id)
        self.beliefs = np.delete(self.beliefs, k, axis=0)
        del self._ids[k], self._versions[k]
        self._row = {oid: i for i, oid in enumerate(self._ids)}

    def reset(self, object_id: Hashable | None = None, prior=None) -> None:
        """Back to the prior: one object, or every object (None); ``prior``: per-model
        weights to start from instead of the belief's own prior (validated first)."""
        rows = range(len(self._ids)) if object_id is None else [self._index(object_id)]
        start = self._prior if prior is None else BeliefFilter(self.model_set, prior).belief
        for k in rows:
            self.beliefs[k] = start
            self._versions[k] += 1

    def _index(self, object_id) -> int:
        try:
            return self._row[object_id]
        except KeyError:
            raise UnknownObjectError(
                f'object {object_id!r} is not tracked (tracked: {self._ids})') from None

    def belief(self, object_id) -> np.ndarray:
        """Object's (N,) node belief: a read-only view on its row, valid until the next
        update (as ``BeliefFilter.belief``, an update may replace the array)."""
        view = self.beliefs[self._index(object_id)]
        view.flags.writeable = False
        return view

    def version(self, object_id) -> int:
        return self._versions[self._index(object_id)]

    # -- one object -----------------------------------------------------------------------
    def predict(self, object_id, action) -> None:
        """Object ``object_id`` went through the executed action (name or index)."""
        k = self._index(object_id)
        self.beliefs[k] = predict_belief(self.model_set, action, self.beliefs[k])
        self._versions[k] += 1

    def correct(self, object_id, z) -> float:
        """Condition object ``object_id`` on its observation z; returns p(z | history).
        BeliefUpdateError leaves every belief unchanged."""
        k = self._index(object_id)
        posterior, total = correct_belief(self.model_set, z, self.beliefs[k],
                                          likelihood_buffer=self._likelihood_buffer)
        self.beliefs[k] = posterior
        self._versions[k] += 1
        return total

    def step(self, object_id, action, z) -> float:
        """Predict through ``action`` then correct on ``z``, for one object."""
        self.predict(object_id, action)
        return self.correct(object_id, z)

    def shift_yaw(self, object_id, steps: int) -> None:
        """The robot now views the object ``steps`` 45° steps around from the last view
        (ORBIT's sign); a permutation of every model's yaws."""
        k = self._index(object_id)
        cube = self.beliefs[k].reshape(-1, STATES_PER_MODEL // NUM_YAWS, NUM_YAWS)
        self.beliefs[k] = np.roll(cube, int(steps), axis=2).reshape(-1)
        self._versions[k] += 1

    # -- several objects at once ------------------------------------------------------------
    def predict_many(self, object_ids, action) -> None:
        """Several objects through the same action, one sparse product."""
        rows = [self._index(o) for o in object_ids]
        self.beliefs[rows] = predict_belief(self.model_set, action, self.beliefs[rows])
        for k in rows:
            self._versions[k] += 1

    def correct_many(self, observations: dict) -> np.ndarray:
        """Each object of ``{object_id: z}`` (e.g. the cubes of one view) on its own
        observation, in one gather; returns the p(z | history) per object, in that order.
        BeliefUpdateError leaves every belief unchanged."""
        rows = [self._index(o) for o in observations]
        every = rows == list(range(len(self._ids)))  # the whole stack: no gather, no scatter
        posterior, totals = correct_beliefs(self.model_set, list(observations.values()),
                                            self.beliefs if every else self.beliefs[rows])
        if every:
            self.beliefs = posterior
        else:
            self.beliefs[rows] = posterior
        for k in rows:
            self._versions[k] += 1
        return totals

    # -- read-outs -------------------------------------------------------------------------
    def object_marginal(self, object_id=None) -> np.ndarray:
        """(M,) model posterior of one object, or (K, M) for every object (None)."""
        m = self.model_set.num_models
        if object_id is None:
            return self.beliefs.reshape(len(self._ids), m, STATES_PER_MODEL).sum(axis=2)
        return self.beliefs[self._index(object_id)].reshape(m, STATES_PER_MODEL).sum(axis=1)

    def most_likely_model(self, object_id) -> tuple[int, float]:
        marginal = self.object_marginal(object_id)
        best = int(np.argmax(marginal))
        return best, float(marginal[best])

    def entropy(self, object_id) -> float:
        """Entropy (bits) of the object's model marginal."""
        return entropy_bits(self.object_marginal(object_id))
