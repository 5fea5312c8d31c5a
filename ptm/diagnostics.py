"""Convergence diagnostics for several chains: split R-hat and effective sample size.

Split R-hat (Gelman et al., Bayesian Data Analysis, 3rd ed., §11.4) compares
the variance between half-chains with the variance within them; values near
1 (below ~1.01-1.05) mean the chains agree. The effective sample size uses
the chains' pooled autocorrelation, summed in pairs until a pair turns
negative (Geyer's initial positive sequence). A trace whose values differ
only by rounding (a chain that never left one topology: its log-probability
is updated incrementally, so it drifts in the last digits) counts as
constant: R-hat 1, every draw effective.

    >>> traces = np.random.default_rng(0).normal(size=(4, 1000))
    >>> round(split_rhat(traces), 2), effective_sample_size(traces) > 3000
    (1.0, True)
"""

from __future__ import annotations

import numpy as np

__all__ = ["split_rhat", "effective_sample_size"]


def _split_halves(traces) -> np.ndarray:
    traces = np.asarray(traces, dtype=float)
    if traces.ndim != 2:
        raise ValueError(f"traces must have shape (chains, samples), got {traces.shape}")
    half = traces.shape[1] // 2
    if half < 2:
        raise ValueError("each chain needs at least 4 samples for split diagnostics")
    return np.concatenate([traces[:, :half], traces[:, -half:]], axis=0)


def _constant(halves) -> bool:
    """True when the values differ by no more than rounding (relative 1e-9)."""
    return float(np.ptp(halves)) <= 1e-9 * max(1.0, float(np.abs(halves).max()))


def split_rhat(traces) -> float:
    """Split potential scale reduction factor of a scalar trace, shape (chains, samples)."""
    halves = _split_halves(traces)
    if _constant(halves):
        return 1.0
    length = halves.shape[1]
    within = halves.var(axis=1, ddof=1).mean()
    between = length * halves.mean(axis=1).var(ddof=1)
    if within == 0.0:  # every half-chain constant, at different values
        return float("inf")
    pooled = (length - 1) / length * within + between / length
    return float(np.sqrt(pooled / within))


def effective_sample_size(traces) -> float:
    """Effective number of independent draws in a scalar trace, shape (chains, samples)."""
    halves = _split_halves(traces)
    chains, length = halves.shape
    if _constant(halves):
        return float(chains * length)
    centred = halves - halves.mean(axis=1, keepdims=True)
    size = 1 << int(np.ceil(np.log2(2 * length)))
    spectrum = np.fft.rfft(centred, n=size, axis=1)
    autocovariance = np.fft.irfft(spectrum * np.conj(spectrum), n=size, axis=1)[:, :length] / length
    within = halves.var(axis=1, ddof=1).mean()
    if within == 0.0:  # every half-chain constant, at different values: nothing mixes
        return float(chains)
    pooled = (length - 1) / length * within + length * halves.mean(axis=1).var(ddof=1) / length
    rho = 1.0 - (within - autocovariance.mean(axis=0)) / pooled
    rho[0] = 1.0
    total = 0.0
    for lag in range(0, length - 1, 2):
        pair = rho[lag] + rho[lag + 1]
        if pair < 0.0:
            break
        total += pair
    tau = max(2.0 * total - 1.0, 1.0 / np.log10(max(chains * length, 10)))
    return float(chains * length / tau)
