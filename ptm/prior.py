"""The Poisson-marginalised occupancy prior over partitions (paper eq. 8-9, docs/model.md §3.1).

With L landmarks, N detections fall into them like balls into urns:
P(T | L) = L! / (L - M)! * L^(-N) for a partition T with M sets. With a
Poisson(rate) prior on L (conditioned on L >= M),

    log P(T) = -rate + log sum_{L=M}^inf  L^(-N) rate^L / (L - M)!

which depends on (N, M) only and is evaluated in log space, as
M log rate + log E[(K + M)^-N] with K = L - M ~ Poisson(rate): to about 1e-14
and in milliseconds for any rate in ``RATE_RANGE`` = [1e-300, 1e15] (others are
refused: beyond, its terms lose their accuracy, and the value becomes NaN).
Summed over all partitions of N detections it equals 1 - exp(-rate) = P(L >= 1).

The rate counts landmarks, visited or not; the number of *visited* places,
M, is smaller. With L landmarks, N detections occupy on average
L (1 - (1 - 1/L)^N) of them, so E[M | N] = E[L (1 - (1 - 1/L)^N) | L >= 1]
(:meth:`PoissonPrior.expected_places`), and :meth:`PoissonPrior.with_expected_places`
finds the rate for which that expectation is a given number of places.

    >>> prior = PoissonPrior(rate=3.0)
    >>> prior.log_prob(n=5, m=2)            # doctest: +ELLIPSIS
    -3.79...
    >>> round(PoissonPrior(rate=6.0).expected_places(n=9), 2)
    4.58
    >>> round(PoissonPrior.with_expected_places(n=9, places=6.0).rate, 2)
    10.25
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import integrate, optimize, stats
from scipy.special import digamma, gammaln, logsumexp

from ._validation import positive

__all__ = ["RATE_RANGE", "PoissonPrior"]

#: The rates allowed: the sum's terms keep their accuracy up to 1e15 (at 1e16 the value was NaN, at 1e50 it hung),
#: and below 1e-300 log rate and 1 / rate leave the floats (a subnormal rate gave NaN).
RATE_RANGE = (1e-300, 1e15)

_CHUNK = 256
_DEPTH = 60.0  # [nats] each part of the sum is taken until its terms are this far below its top
_MAX_TERMS = 200_000  # a bump wider than this is integrated instead of summed term by term
_TABLE_CELLS = 4_000_000  # PoissonPrior.table sums every M on one grid up to this many terms


class PoissonPrior:
    """Prior P(T) from a Poisson(``rate``) number of landmarks in the world."""

    def __init__(self, rate: float):
        self.rate = positive("rate", rate, RATE_RANGE)
        self._log_prob = lru_cache(maxsize=None)(self._compute)

    def log_prob(self, n: int, m: int) -> float:
        """log P(T) for any partition of ``n`` detections into ``m`` places."""
        if not 1 <= m <= n:
            raise ValueError(f"a partition of n={n} detections has 1 <= m <= n places, got m={m}")
        return self._log_prob(int(n), int(m))

    def expected_places(self, n: int) -> float:
        """E[M | N = ``n``]: the number of distinct places the prior expects ``n`` detections to visit."""
        n = _detections(n)
        spread = 40.0 * math.sqrt(self.rate) + 40.0  # the Poisson mass beyond this is below 1e-300
        counts = np.arange(max(1, math.floor(self.rate - spread)), math.ceil(self.rate + spread) + 1, dtype=float)
        occupied = -counts * np.expm1(n * np.log1p(-1.0 / np.maximum(counts, 2.0)))
        occupied[counts == 1.0] = 1.0
        weights = stats.poisson.pmf(counts, self.rate)
        return float(weights @ occupied / weights.sum())

    @classmethod
    def with_expected_places(cls, n: int, places: float) -> "PoissonPrior":
        """The prior whose expected number of visited places for ``n`` detections is ``places`` (1 < places < n)."""
        n = _detections(n)
        places = float(places)
        if not 1.0 < places < n:
            raise ValueError(f"expected places must lie strictly between 1 and n={n} (the prior's limits as the rate "
                             f"goes to 0 and to infinity), got {places!r}")

        def excess(log_rate):
            return cls(math.exp(log_rate)).expected_places(n) - places

        low, high = math.log(places) - 1.0, math.log(places) + 1.0
        while excess(low) > 0.0:
            low -= 2.0
        while excess(high) < 0.0:
            high += 2.0
        return cls(math.exp(optimize.brentq(excess, low, high, xtol=1e-12, rtol=1e-12)))

    def table(self, n: int) -> np.ndarray:
        """Array whose entry ``m`` is log P(T) for M = m of ``n`` detections (entry 0 is -inf).

        Every M at once where one grid of k holds the whole sum: k = 0..K with K = rate + 40 sqrt(rate) + 40,
        beyond which each term is below the one before by a factor rate / (k + 1) < 1, so a row whose term at
        K is _DEPTH nats below its top has a tail of relative size below 1e-24. A row that is not (or a grid
        wider than _TABLE_CELLS entries, for a large rate or n) is computed by :meth:`log_prob`. About 50x
        faster than one :meth:`log_prob` per M for n = 100 (the online mapper builds a table per detection).
        """
        n = _detections(n)
        places = np.arange(1, n + 1, dtype=float)
        values = np.full(n, math.nan)
        last = math.ceil(self.rate + 40.0 * math.sqrt(self.rate) + 40.0)
        if n * (last + 1) <= _TABLE_CELLS:
            counts = np.arange(last + 1, dtype=float)
            terms = _log_poisson(counts, self.rate)[None, :] - n * np.log(counts[None, :] + places[:, None])
            held = terms[:, -1] < terms.max(axis=1) - _DEPTH
            values[held] = places[held] * math.log(self.rate) + logsumexp(terms[held], axis=1)
        for m in np.flatnonzero(np.isnan(values)) + 1:
            values[m - 1] = self.log_prob(n, int(m))
        return np.concatenate([[-math.inf], values])

    def _compute(self, n: int, m: int) -> float:
        # With K = L - M ~ Poisson(rate):  log P(T) = M log rate + log E[(K + M)^-N],
        # a sum over k >= 0 of exp(h(k)), h(k) = log Poisson(k; rate) - N log(k + M).
        # h is not log-concave: it can fall from k = 0, rise to a bump near k = rate - N and fall
        # again (N = 3000, M = 5, rate = e^11), so a scan that stops once terms fall is wrong.
        # Every local maximum of h but the last lies below k = M - 2 ((k + M) h'(k) is convex there,
        # concave beyond). The sum is taken in two parts: the terms from k = 0 until they are _DEPTH nats below
        # the top, and the last bump of h around its top k* (the last zero of h') to _DEPTH nats down
        # on either side, summed term by term or, when wider than _MAX_TERMS terms, integrated (the
        # terms are smooth on that scale, so sum and integral agree far below double precision). The
        # skipped valley has fewer than k* < rate + 2 terms, each _DEPTH nats below the top: a relative
        # error below 1e-14 for any rate up to 1e15. Cost: milliseconds, whatever the rate.
        rate = self.rate
        peak = _last_peak(n, m, rate)
        parts = []  # log of each part's sum
        head_end = _MAX_TERMS if peak is None else int(math.floor(_edge(n, m, rate, peak, -1.0)))
        top = -math.inf if peak is None else float(_log_terms(np.array([peak]), n, m, rate)[0])
        head, best = [], -math.inf
        start = 0
        while start < head_end:
            counts = np.arange(start, min(start + _CHUNK, head_end), dtype=float)
            terms = _log_terms(counts, n, m, rate)
            head.append(terms)
            best = max(best, float(terms.max()))
            # Past k = M - 2, h has no local maximum before the bump, so every term up to the bump's edge is
            # below this one or below the edge: stop once this one is negligible.
            negligible = terms[-1] < max(best, top) - _DEPTH
            if counts[-1] >= m - 2 and negligible and (peak is not None or terms[-1] < terms[0]):
                break
            start += _CHUNK
        if head:
            parts.append(float(logsumexp(np.concatenate(head))))
        if peak is not None:
            low = max(head_end, 0)
            high = math.ceil(_edge(n, m, rate, peak, +1.0))
            if high - low <= _MAX_TERMS:
                parts.append(float(logsumexp(_log_terms(np.arange(low, high + 1, dtype=float), n, m, rate))))
            else:
                def relative_term(x):
                    return math.exp(float(_log_terms(np.array([x]), n, m, rate, peak)[0]) - top)

                area, _ = integrate.quad(relative_term, low - peak, high - peak, points=[0.0], epsabs=0.0,
                                         epsrel=1e-11, limit=200)
                parts.append(top + math.log(area))
        return m * math.log(rate) + float(logsumexp(parts))

    def __repr__(self) -> str:
        return f"PoissonPrior(rate={self.rate:g})"


def _detections(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n (the number of detections) must be a positive integer, got {n!r}")
    return int(n)


def _log_terms(k: np.ndarray, n: int, m: int, rate: float, base: float = 0.0) -> np.ndarray:
    """h(base + k) = log Poisson(base + k; rate) - N log(base + k + M), accurate for k and rate up to 1e15 and beyond.

    ``base``: a large origin (a peak near the rate) from which ``k`` is a small offset, so that a smooth
    function of ``k`` stays smooth where base + k itself would be rounded to 1/8 (near 1e15).
    """
    return _log_poisson(k, rate, base) - n * np.log(base + k + m)


def _log_poisson(offset: np.ndarray, rate: float, base: float = 0.0) -> np.ndarray:
    # Loader's form, -log(2 pi k)/2 - stirlerr(k) - rate * D(k / rate): no difference of large numbers, so the
    # terms near k = rate = 1e12 keep ~1e-12 absolute accuracy (k log rate - lgamma(k + 1) - rate loses 1e-3).
    offset = np.asarray(offset, dtype=float)
    k = base + offset
    safe = np.maximum(k, 1.0)
    relative = np.where(k >= 1.0, ((base - rate) + offset) / rate, (safe - rate) / rate)
    # (1 + d) log(1 + d) - d; near d = 0 by its series (sum over j >= 2 of (-d)^j / (j (j - 1))): the closed
    # form there is a difference of two numbers of size d, which times a rate of 1e15 is noise of 1e-7
    near = np.abs(relative) < 0.01
    d = np.where(near, relative, 0.0)
    series = sum((-d) ** j / (j * (j - 1)) for j in range(2, 12))
    far = np.where(near, 0.0, relative)
    deviance = rate * np.where(near, series, (1.0 + far) * np.log1p(far) - far)
    small = safe < 100.0
    stirling_error = np.where(small, gammaln(np.where(small, safe, 1.0) + 1.0) - (safe + 0.5) * np.log(safe) + safe
                              - 0.5 * math.log(2.0 * math.pi), 1.0 / (12.0 * safe) - 1.0 / (360.0 * safe ** 3))
    value = -0.5 * np.log(2.0 * math.pi * safe) - stirling_error - deviance
    return np.where(k < 1.0, k * math.log(rate) - gammaln(k + 1.0) - rate, value)


def _slope_sign(k: float, n: int, m: int, rate: float) -> float:
    """(k + M) h'(k), whose sign is that of h'(k): (k + M)(log rate - digamma(k + 1)) - N."""
    return (k + m) * (math.log(rate) - float(digamma(k + 1.0))) - n


def _last_peak(n: int, m: int, rate: float) -> float | None:
    """Where h has its last local maximum away from k = 0 (None: h only falls)."""
    # (k + M) h'(k) is concave for k >= M - 2 and negative beyond k = rate + 1: its largest zero is the peak.
    upper = rate + 2.0
    lower = max(0.0, m - 2.0)
    top = lower  # with M - 2 beyond rate + 2, (k + M) h'(k) < 0 on all of its concave part
    if lower < upper:
        top = float(optimize.minimize_scalar(lambda k: -_slope_sign(k, n, m, rate), bounds=(lower, upper),
                                             method="bounded", options={"xatol": 1e-9 * upper}).x)
    if _slope_sign(top, n, m, rate) <= 0.0:
        if _slope_sign(0.0, n, m, rate) <= 0.0:
            return None
        top = 0.0
    return float(optimize.brentq(_slope_sign, top, upper, args=(n, m, rate), xtol=1e-9))


def _edge(n: int, m: int, rate: float, peak: float, direction: float) -> float:
    """The k on one side of ``peak`` where h is _DEPTH nats below its top (0 on the left if it never gets there)."""
    top = float(_log_terms(np.array([peak]), n, m, rate)[0])

    def below(k):
        return float(_log_terms(np.array([k]), n, m, rate)[0]) - (top - _DEPTH)

    step = max(1.0, math.sqrt(max(peak, 1.0)))
    if direction < 0:
        if peak <= 0.0 or below(0.0) >= 0.0:
            return 0.0
        far = peak
        while far > 0.0:
            far = max(0.0, far - step)
            if below(far) < 0.0:
                break
            step *= 2.0
        return float(optimize.brentq(below, far, peak))
    far = peak
    while True:
        far += step
        if below(far) < 0.0:
            return float(optimize.brentq(below, peak, far))
        step *= 2.0
