"""The Poisson-marginalised occupancy prior over partitions (paper eq. 8-9, SPEC §3.1).

With L landmarks, N detections fall into them like balls into urns:
P(T | L) = L! / (L - M)! * L^(-N) for a partition T with M sets. With a
Poisson(rate) prior on L (conditioned on L >= M),

    log P(T) = -rate + log sum_{L=M}^inf  L^(-N) rate^L / (L - M)!

which depends on (N, M) only and is evaluated in log space. Summed over all
partitions of N detections it equals 1 - exp(-rate) = P(L >= 1).

    >>> prior = PoissonPrior(rate=3.0)
    >>> prior.log_prob(n=5, m=2)            # doctest: +ELLIPSIS
    -3.79...
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.special import gammaln, logsumexp

from ._validation import positive

__all__ = ["PoissonPrior"]

_RELATIVE_TOLERANCE = 1e-16
_CHUNK = 256


class PoissonPrior:
    """Prior P(T) from a Poisson(``rate``) number of landmarks in the world."""

    def __init__(self, rate: float):
        self.rate = positive("rate", rate)
        self._log_prob = lru_cache(maxsize=None)(self._compute)

    def log_prob(self, n: int, m: int) -> float:
        """log P(T) for any partition of ``n`` detections into ``m`` places."""
        if not 1 <= m <= n:
            raise ValueError(f"a partition of n={n} detections has 1 <= m <= n places, got m={m}")
        return self._log_prob(int(n), int(m))

    def table(self, n: int) -> np.ndarray:
        """Array whose entry ``m`` is log P(T) for M = m (entry 0 is -inf)."""
        return np.array([-math.inf] + [self.log_prob(n, m) for m in range(1, n + 1)])

    def _compute(self, n: int, m: int) -> float:
        log_rate = math.log(self.rate)
        # Terms f(L) = -N log L + L log rate - lgamma(L - M + 1) are log-concave in L:
        # sum chunks until past the mode and the newest term is negligible.
        parts = []
        start = m
        best = -math.inf
        while True:
            counts = np.arange(start, start + _CHUNK, dtype=float)
            terms = -n * np.log(counts) + counts * log_rate - gammaln(counts - m + 1.0)
            parts.append(terms)
            best = max(best, float(terms.max()))
            if terms[-1] < terms[-2] and terms[-1] - best < math.log(_RELATIVE_TOLERANCE) - 10.0:
                break
            start += _CHUNK
        return -self.rate + float(logsumexp(np.concatenate(parts)))

    def __repr__(self) -> str:
        return f"PoissonPrior(rate={self.rate:g})"
