"""Observation model p(z | x) of MODEL.md: depends on the node's aspect only."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Above this many aspects the (A, A) table is built on first use only (A = 2048 -> 32 MiB).
EAGER_TABLE_MAX_ASPECTS = 2048


@dataclass(frozen=True)
class ObservationParams:
    p_miss: float = 0.05        # a tag in a slot is not detected -> -1
    p_false: float = 0.02       # a slot reports a wrong tag
    p_type: float = 0.01        # the 2/3-feature geometry is misread

    def __post_init__(self):
        for name in ('p_miss', 'p_false', 'p_type'):
            value = getattr(self, name)
            # Strictly positive: a hard zero would make one bad observation unrecoverable.
            if not (isinstance(value, (int, float)) and 0.0 < float(value) < 1.0):
                raise ValueError(f'ObservationParams.{name} must be in (0, 1), got {value!r}')
        if self.p_miss + self.p_false >= 1.0:
            raise ValueError('ObservationParams: p_miss + p_false must be < 1, got '
                             f'{self.p_miss} + {self.p_false}')


class ObservationModel:
    """p(z | x) for every aspect of a model set; never zero.

    aspect_likelihood[z_row, x_row] = p(z = aspect z_row | a node with aspect x_row).
    """

    def __init__(self, aspects, n_tags: int, params: ObservationParams | None = None):
        self.aspects = np.asarray(aspects, dtype=np.int16)
        if self.aspects.ndim != 2 or self.aspects.shape[1] != 4:
            raise ValueError(f'aspects must have shape (A, 4), got {self.aspects.shape}')
        self.n_tags = int(n_tags)
        self.params = params if params is not None else ObservationParams()
        p = self.params
        self.p_hit = 1.0 - p.p_miss - p.p_false
        self.p_wrong = p.p_false / (self.n_tags - 1)
        self.num_aspects = self.aspects.shape[0]
        self._types = self.aspects[:, 0].astype(np.int64)
        self._slots = self.aspects[:, 1:].astype(np.int64)
        self._row_of_key = {tuple(int(v) for v in row): i for i, row in enumerate(self.aspects)}
        self._table = None
        if self.num_aspects <= EAGER_TABLE_MAX_ASPECTS:
            self._table = self._build_table()

    # -- lookup -----------------------------------------------------------------------------
    def aspect_row(self, key) -> int | None:
        """Row of an aspect key (type, s0, s1, s2) in `aspects`, or None."""
        return self._row_of_key.get(tuple(int(v) for v in key))

    @property
    def aspect_likelihood(self) -> np.ndarray:
        """(A, A) table [z_row, x_row]; built lazily for very large aspect sets."""
        if self._table is None:
            self._table = self._build_table()
        return self._table

    def _build_table(self) -> np.ndarray:
        k_z = np.where(self._types == 3, 3, 2)                        # slots per z aspect
        # Same type: (1 - p_type) p_hit^hits p_wrong^(k - hits); count hits per pair.
        hits = np.zeros((self.num_aspects, self.num_aspects), dtype=np.int8)
        for j in range(3):
            equal = self._slots[:, None, j] == self._slots[None, :, j]
            if j == 2:
                equal &= (k_z == 3)[:, None]
            hits += equal
        lut = np.zeros((4, 4))
        for k in (2, 3):
            h = np.arange(k + 1)
            lut[k, :k + 1] = (1.0 - self.params.p_type) * self.p_hit ** h * self.p_wrong ** (k - h)
        table = lut[k_z[:, None], hits]
        other = self.params.p_type * (1.0 / (self.n_tags + 1)) ** k_z
        same_type = self._types[:, None] == self._types[None, :]
        table = np.where(same_type, table, other[:, None])
        table.flags.writeable = False            # rows are handed out by likelihood()
        return table

    # -- p(z | x) ---------------------------------------------------------------------------
    def normalize_observation(self, z) -> tuple[int, int, int, int]:
        """Validated observation tuple (type, s0, s1, s2); a 3-tuple is a type-2 observation."""
        try:
            values = [int(v) for v in z]
        except (TypeError, ValueError):
            raise ValueError(f'observation must be a tuple of ints (type, s0, s1, s2), got {z!r}')
        if len(values) == 3 and values[0] == 2:
            values.append(-1)
        if len(values) != 4:
            raise ValueError(f'observation must have 4 entries (type, s0, s1, s2), got {z!r}')
        z_type = values[0]
        if z_type not in (2, 3):
            raise ValueError(f'observation type must be 2 or 3, got {z_type} in {z!r}')
        for v in values[1:1 + z_type]:
            if not -1 <= v < self.n_tags:
                raise ValueError(f'observation {z!r}: tag {v} out of range -1..{self.n_tags - 1}')
        if z_type == 2 and values[3] != -1:
            raise ValueError(f'type-2 observation {z!r} must have s2 = -1')
        return tuple(values)

    def likelihood(self, z) -> np.ndarray:
        """p(z | aspect) for every aspect row, (A,); z may hold -1 for missed tags.

        May return a read-only row of the precomputed table: copy before modifying.
        """
        z = self.normalize_observation(z)
        row = self._row_of_key.get(z)
        if row is not None and self._table is not None:
            return self._table[row]
        z_type = z[0]
        k = 3 if z_type == 3 else 2
        same = np.full(self.num_aspects, 1.0 - self.params.p_type)
        for j in range(k):
            if z[1 + j] == -1:
                same *= self.params.p_miss
            else:
                same *= np.where(self._slots[:, j] == z[1 + j], self.p_hit, self.p_wrong)
        other = self.params.p_type * (1.0 / (self.n_tags + 1)) ** k
        return np.where(self._types == z_type, same, other)

    def sample(self, aspect_row, rng: np.random.Generator) -> tuple[int, int, int, int]:
        """A noisy observation of aspect `aspect_row`, drawn exactly from p(z | x)."""
        row = int(aspect_row)
        if not 0 <= row < self.num_aspects:
            raise ValueError(f'aspect row {row} out of range 0..{self.num_aspects - 1}')
        x_type = int(self._types[row])
        if rng.random() < self.params.p_type:
            z_type = 5 - x_type                                        # 2 <-> 3
            k = 3 if z_type == 3 else 2
            slots = [int(v) for v in rng.integers(-1, self.n_tags, size=k)]
        else:
            z_type = x_type
            k = 3 if z_type == 3 else 2
            slots = []
            for j in range(k):
                true_tag = int(self._slots[row, j])
                u = rng.random()
                if u < self.p_hit:
                    slots.append(true_tag)
                elif u < self.p_hit + self.params.p_miss:
                    slots.append(-1)
                else:
                    wrong = int(rng.integers(0, self.n_tags - 1))
                    slots.append(wrong + (wrong >= true_tag))           # uniform over the others
        slots += [-1] * (3 - k)
        return (z_type, *slots)
