"""Bayes filter over aspect nodes (paper III-C).

predict:  bel-(x') = sum_x p(x' | x, a) bel(x)     (one CSR mat-vec with T^T)
correct:  bel(x)   = eta p(z | x) bel-(x)          (p(z | x) gathered via node_aspect)
marginal: bel(o)   = sum over the 48 states of o

A *failed* executed action (the skill reports it did not run / aborted before
touching the cube) is the caller's business: do not call predict for it. The
ATG's own failure outcomes model actions that ran but did not have the nominal
effect.
"""

from __future__ import annotations

import numpy as np

from .cube import STATES_PER_MODEL, action_index
from .modelset import ModelSet


class BeliefUpdateError(FloatingPointError):
    """The observation update cannot be normalised (total likelihood is 0 or not finite)."""


class BeliefFilter:
    def __init__(self, model_set: ModelSet, prior=None):
        self.model_set = model_set
        m = model_set.num_models
        if prior is None:
            prior_models = np.full(m, 1.0 / m)
        else:
            prior_models = np.asarray(prior, dtype=np.float64).reshape(-1)
            if prior_models.shape != (m,):
                raise ValueError(f'prior must have shape ({m},) (one weight per model), '
                                 f'got {np.shape(prior)}')
            if not np.isfinite(prior_models).all() or prior_models.min() < 0 \
                    or prior_models.sum() <= 0:
                raise ValueError('prior must be finite, >= 0 and not all zero')
            prior_models = prior_models / prior_models.sum()
        # Unknown initial state: the prior is spread evenly over each model's 48 states.
        self._prior = np.repeat(prior_models / STATES_PER_MODEL, STATES_PER_MODEL)
        self.belief = self._prior.copy()
        self._likelihood_buffer = np.empty(model_set.num_nodes)

    def reset(self):
        self.belief = self._prior.copy()

    def predict(self, action):
        """Propagate through an executed action (name or index)."""
        self.belief = predict_belief(self.model_set, action, self.belief)

    def correct(self, z) -> float:
        """Condition on observation z = (type, s0, s1, s2); returns p(z | history).

        Raises BeliefUpdateError (belief unchanged) if the update cannot be normalised;
        with the strictly positive observation model this only happens for corrupt input.
        """
        self.belief, total = correct_belief(self.model_set, z, self.belief,
                                            likelihood_buffer=self._likelihood_buffer)
        return total

    def object_marginal(self) -> np.ndarray:
        return self.belief.reshape(self.model_set.num_models, STATES_PER_MODEL).sum(axis=1)

    def state_marginal(self) -> np.ndarray:
        """(M, 48) belief per model and state (a view on the belief)."""
        return self.belief.reshape(self.model_set.num_models, STATES_PER_MODEL)

    def entropy(self) -> float:
        """Entropy of the object marginal, in bits."""
        return entropy_bits(self.object_marginal())

    def most_likely_model(self) -> tuple[int, float]:
        marginal = self.object_marginal()
        best = int(np.argmax(marginal))
        return best, float(marginal[best])


def predict_belief(model_set: ModelSet, action, belief: np.ndarray) -> np.ndarray:
    """``bel⁻ = Tᵀ bel`` through an executed action (name or index): a new array.

    ``belief`` is one (N,) node belief or a (K, N) stack of K beliefs over the same
    model set (all K predicted through the same action with one CSR product)."""
    transpose = model_set.transition_transpose(action_index(action))
    if belief.ndim == 1:
        predicted = transpose @ belief
        # Rows of T sum to 1, so this only removes round-off drift.
        predicted /= predicted.sum()
        return predicted
    predicted = np.ascontiguousarray((transpose @ belief.T).T)
    predicted /= predicted.sum(axis=1, keepdims=True)
    return predicted


def correct_belief(model_set: ModelSet, z, belief: np.ndarray, likelihood_buffer=None
                   ) -> tuple[np.ndarray, float]:
    """``(η p(z | x) bel⁻, p(z | history))`` for one (N,) belief and observation z: a new
    array. Raises BeliefUpdateError if the update cannot be normalised."""
    lik_aspect = model_set.observation.likelihood(z)
    lik = np.take(lik_aspect, model_set.node_aspect, out=likelihood_buffer)
    posterior = lik * belief
    total = posterior.sum()
    if not (np.isfinite(total) and total > 0.0):
        raise BeliefUpdateError(f'observation {tuple(z)} has total likelihood {total} '
                                'under the current belief; belief left unchanged')
    posterior /= total
    return posterior, float(total)


def correct_beliefs(model_set: ModelSet, observations, beliefs: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The (K, N) stack ``beliefs`` each conditioned on its own observation (K of them,
    e.g. the cubes of one camera view), in one gather and one product: (posteriors,
    totals). Raises BeliefUpdateError (nothing changed) if any row cannot be normalised."""
    if len(observations) != beliefs.shape[0]:
        raise ValueError(f'{len(observations)} observations for {beliefs.shape[0]} beliefs')
    lik_aspect = np.array([model_set.observation.likelihood(z) for z in observations])
    posterior = np.take(lik_aspect, model_set.node_aspect, axis=1)
    posterior *= beliefs
    totals = posterior.sum(axis=1)
    bad = ~(np.isfinite(totals) & (totals > 0.0))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise BeliefUpdateError(f'observation {tuple(observations[k])} has total likelihood '
                                f'{totals[k]} under belief {k}; beliefs left unchanged')
    posterior /= totals[:, None]
    return posterior, totals


def entropy_bits(p) -> float:
    """Shannon entropy (bits) of a non-negative vector, normalised here (the planner's
    lookahead passes unnormalised masses); zero entries contribute 0."""
    p = np.asarray(p, dtype=np.float64)
    nz = p[p > 0.0] / p.sum()
    return float(-(nz * np.log2(nz)).sum())
