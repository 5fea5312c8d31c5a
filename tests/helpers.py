"""Shared builders for the tests: small posteriors with exactly enumerable targets."""

import numpy as np

import ptm

TRUE_LABELS_8 = np.array([0, 1, 2, 0, 1, 2, 0, 1])
PLACE_SIGNATURES = np.array([[0.30, 0.10], [0.25, 0.15], [0.40, 0.05]])


def prior_only_posterior(n: int = 6, rate: float = 2.0) -> ptm.Posterior:
    return ptm.Posterior(ptm.Dataset(labels=np.zeros(n, dtype=int)), ptm.PoissonPrior(rate))


def appearance_posterior(n: int = 8, noise: float = 0.02, seed: int = 0) -> ptm.Posterior:
    """Three places with nearby signatures: a posterior spread over many partitions (entropy ~2 nats)."""
    rng = np.random.default_rng(seed)
    labels = TRUE_LABELS_8[:n]
    signatures = PLACE_SIGNATURES[labels] + rng.normal(0.0, noise, size=(n, 2))
    dataset = ptm.Dataset(signatures=signatures, labels=labels)
    model = ptm.AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2.0 * noise ** 2)
    return ptm.Posterior(dataset, ptm.PoissonPrior(3.0), [model])
