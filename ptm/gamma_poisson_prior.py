"""The occupancy prior with an uncertain rate: the Poisson rate itself Gamma-distributed (docs/model.md §3.1,
"Uncertain rate").

:class:`ptm.PoissonPrior` plugs in one rate lambda, the number of landmarks a world is expected to have. A rate
calibrated on other floors or robots is a guess, so here lambda ~ Gamma(shape a, mean ``rate``) and is
integrated out: the number of landmarks L is then negative binomial, and

    P(T) = sum_{L >= M} NB(L; a, rate) L! / (L - M)! L^(-N),
    log term(L) = lgamma(L + a) - lgamma(a) - lgamma(L - M + 1) + a log(b / (1 + b)) - L log(1 + b) - N log L

with b = a / rate (the L! of the urn model cancels the one of the negative binomial). The terms are log-concave
in L for every a > 0 (the second difference of lgamma(L + a) - lgamma(L - M + 1) is negative and the rest is
concave or linear), so the series is summed exactly over the window around its one mode where terms lie within
``_DEPTH`` nats of the top. As ``shape`` grows the prior tends to ``PoissonPrior(rate)``.

The data update the rate through M alone: given L, lambda ~ Gamma(a + L, b + 1), so E[lambda | T] =
(a + E[L | N, M]) / (b + 1) (:meth:`GammaPoissonPrior.rate_posterior`), and the rate's posterior given the data
is the mixture of these over the posterior's place counts (:meth:`GammaPoissonPrior.rate_posterior_of`).

    >>> from ptm import PoissonPrior
    >>> wide, plug_in = GammaPoissonPrior(rate=6.0, shape=2.0), PoissonPrior(6.0)
    >>> bool(wide.log_prob(n=9, m=1) > plug_in.log_prob(n=9, m=1))    # a wider rate: more room for few places
    True
    >>> round(GammaPoissonPrior.with_expected_places(n=9, places=6.0, shape=2.0).expected_places(9), 6)
    6.0
"""

from __future__ import annotations

import math
from functools import lru_cache

from typing import TYPE_CHECKING

import numpy as np
from scipy import optimize, stats
from scipy.special import digamma, gammaln, logsumexp

from ._validation import count, positive

if TYPE_CHECKING:
    from .result import PTM

__all__ = ["GammaPoissonPrior", "MAX_SCALE"]

#: [nats] the series is summed over every L whose term is within this of the largest.
_DEPTH = 60.0
#: The largest rate / shape (the Gamma's scale) accepted: the window of terms is about _DEPTH x that long.
MAX_SCALE = 1e5
#: :meth:`GammaPoissonPrior.table` sums every M on one grid up to this many terms.
_TABLE_CELLS = 4_000_000


class GammaPoissonPrior:
    """Prior P(T) from a negative-binomial number of landmarks: Poisson with a Gamma(``shape``) rate of mean ``rate``.

    ``shape`` sets how well the rate is known: its coefficient of variation is 1 / sqrt(shape) (shape 2: the
    central 95 % of rates spans 0.12-2.8 x ``rate``).
    """

    def __init__(self, rate: float, shape: float):
        self.rate = positive("rate", rate)
        self.shape = positive("shape", shape)
        if self.rate / self.shape > MAX_SCALE:
            raise ValueError(f"rate / shape must be at most MAX_SCALE = {MAX_SCALE:g} (the terms to sum grow with it), "
                             f"got rate={rate!r}, shape={shape!r}")
        self._b = self.shape / self.rate
        self._window = lru_cache(maxsize=None)(self._terms)

    def log_prob(self, n: int, m: int) -> float:
        """log P(T) for any partition of ``n`` detections into ``m`` places."""
        n = count("n (the number of detections)", n, 1)
        if not 1 <= m <= n:
            raise ValueError(f"a partition of n={n} detections has 1 <= m <= n places, got m={m}")
        _, terms = self._window(n, int(m))
        return float(logsumexp(terms))

    def table(self, n: int) -> np.ndarray:
        """Array whose entry ``m`` is log P(T) for M = m of ``n`` detections (entry 0 is -inf).

        Every M on one grid L = 1 .. the upper end of the widest row's window, where that grid has at most
        ``_TABLE_CELLS`` entries; a row whose last term is not ``_DEPTH`` nats below its top, or a larger grid,
        is summed by :meth:`log_prob`.
        """
        n = count("n (the number of detections)", n, 1)
        values = np.full(n, math.nan)
        last = max(self._window(n, 1)[0][-1], self._window(n, n)[0][-1])
        if n * last <= _TABLE_CELLS:
            counts = np.arange(1, int(last) + 1)
            # log term(L) = common(L) - lgamma(L - M + 1): one vector and a table of log factorials
            common = self._log_term(counts, n, 1)  # lgamma(L - 1 + 1) = lgamma(L) is taken back below
            common += gammaln(counts.astype(float))
            excess = counts[None, :] - np.arange(1, n + 1)[:, None]  # L - M
            log_factorials = gammaln(np.arange(1.0, last + 1.0))
            terms = np.where(excess >= 0, common[None, :] - log_factorials[np.maximum(excess, 0)], -math.inf)
            top = terms.max(axis=1)
            held = terms[:, -1] < top - _DEPTH
            values[held] = top[held] + np.log(np.exp(terms[held] - top[held, None]).sum(axis=1))
        for m in np.flatnonzero(np.isnan(values)) + 1:
            values[m - 1] = self.log_prob(n, int(m))
        return np.concatenate([[-math.inf], values])

    def rate_posterior(self, n: int, m: int) -> tuple[float, float]:
        """Mean and standard deviation of the rate given a partition of ``n`` detections into ``m`` places."""
        n = count("n (the number of detections)", n, 1)
        counts, terms = self._window(n, int(m))
        weights = np.exp(terms - terms.max())
        weights /= weights.sum()
        shape = self.shape + counts  # lambda | L ~ Gamma(a + L, b + 1)
        mean = float(weights @ shape) / (self._b + 1.0)
        second = float(weights @ (shape * (shape + 1.0))) / (self._b + 1.0) ** 2
        return mean, math.sqrt(max(second - mean**2, 0.0))

    def rate_posterior_of(self, result: PTM) -> tuple[float, float]:
        """Mean and standard deviation of the rate given the data, from a PTM's probabilities (Rao-Blackwellised:
        the mixture over its topologies of :meth:`rate_posterior`)."""
        n = len(result.partitions[0])
        means, sds, probabilities = [], [], np.asarray(result.probabilities, dtype=float)
        for partition in result.partitions:
            mean, sd = self.rate_posterior(n, len(set(partition)))
            means.append(mean)
            sds.append(sd)
        means, sds = np.array(means), np.array(sds)
        mean = float(probabilities @ means)
        second = float(probabilities @ (sds**2 + means**2))
        return mean, math.sqrt(max(second - mean**2, 0.0))

    def expected_places(self, n: int) -> float:
        """E[M | N = ``n``]: the number of distinct places the prior expects ``n`` detections to visit."""
        n = count("n (the number of detections)", n, 1)
        distribution = stats.nbinom(self.shape, self._b / (1.0 + self._b))
        counts = np.arange(1.0, distribution.isf(1e-18) + 2.0)
        occupied = -counts * np.expm1(n * np.log1p(-1.0 / np.maximum(counts, 2.0)))
        occupied[counts == 1.0] = 1.0
        weights = distribution.pmf(counts)
        return float(weights @ occupied / weights.sum())

    @classmethod
    def with_expected_places(cls, n: int, places: float, shape: float) -> "GammaPoissonPrior":
        """The prior of ``shape`` whose expected number of visited places for ``n`` detections is ``places``."""
        n = count("n (the number of detections)", n, 1)
        places = float(places)
        if not 1.0 < places < n:
            raise ValueError(f"expected places must lie strictly between 1 and n={n}, got {places!r}")

        def excess(log_rate):
            return cls(math.exp(log_rate), shape).expected_places(n) - places

        low, high = math.log(places) - 1.0, math.log(places) + 1.0
        while excess(low) > 0.0:
            low -= 2.0
        while excess(high) < 0.0:
            limit = math.log(MAX_SCALE * float(shape))
            if high >= limit:
                raise ValueError(f"{places:g} expected places of n={n} need a rate / shape above MAX_SCALE = "
                                 f"{MAX_SCALE:g}")
            high = min(high + 2.0, limit)
        return cls(math.exp(optimize.brentq(excess, low, high, xtol=1e-12, rtol=1e-12)), shape)

    def _log_term(self, counts, n: int, m) -> np.ndarray:
        counts = np.asarray(counts, dtype=float)
        a, b = self.shape, self._b
        return (gammaln(counts + a) - gammaln(a) - gammaln(counts - m + 1.0) + a * math.log(b / (1.0 + b))
                - counts * math.log1p(b) - n * np.log(counts))

    def _terms(self, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
        """The counts L of the window around the series' mode and their log terms."""
        def slope(count):  # d/dL of the log term, decreasing in L
            return digamma(count + self.shape) - digamma(count - m + 1.0) - math.log1p(self._b) - n / count

        mode = float(m)
        if slope(mode) > 0.0:
            high = 2.0 * mode
            while slope(high) > 0.0:
                high *= 2.0
            mode = optimize.brentq(slope, mode, high, xtol=1e-9)
        top = float(self._log_term(mode, n, m))

        def below(count):
            return float(self._log_term(count, n, m)) - (top - _DEPTH)

        low = float(m)
        if below(low) < 0.0:
            low = optimize.brentq(below, low, mode)
        high, step = mode + 1.0, max(1.0, mode)
        while below(high) >= 0.0:
            high += step
            step *= 2.0
        high = optimize.brentq(below, mode, high)
        counts = np.arange(math.floor(low), math.ceil(high) + 1, dtype=float)
        counts = counts[counts >= m]
        return counts, self._log_term(counts, n, m)

    def __repr__(self) -> str:
        return f"GammaPoissonPrior(rate={self.rate:g}, shape={self.shape:g})"
