"""The odometry noise scale s, inferred with the topology instead of plugged in (docs/model.md §3.3, "Noise scale").

One scale s multiplies every covariance of the pose graph: the odometry rows Sigma_k and the tie variance
sigma_T^2 together. The mode P* of E_T/s does not depend on s, so the Laplace value of a partition T with M
sets (d = 3(N - 1) variables, E* = E_T(P*)) is a closed-form function of s. Relative to s = 1,

    log L(T, s) = log L(T, 1) + E* (1 - 1/s) - k log s,     k = N - M with normalised ties, else 0:

-E*/s from the energy, +(d/2) log s from -1/2 log det(H/s), -(d/2) log s from the rows' Gaussian normaliser,
and -(n - 1) log s per set of n from the normalised ties (:class:`ptm.TieNormaliser`; the paper's unnormalised
ties have no normaliser, k = 0). With an inverse-gamma prior s ~ IG(a, b) the integral over s is closed form,

    log int IG(s; a, b) s^-k e^(-E*/s) ds = a log b - lgamma(a) + lgamma(a + k) - (a + k) log(b + E*),

and s given T is IG(a + k, b + E*): the scale is learned from the residuals that T's ties leave.
:class:`NoiseScalePrior` is the prior and that update; :func:`noise_scale_posterior` mixes the conditionals
over the partitions of a PTM (Rao-Blackwellised) and flags a posterior in the prior's tail.

    >>> prior = NoiseScalePrior.wide()                              # median 1, 95 % within [0.25, 11]
    >>> round(prior.quantile(0.5), 6), prior.conditional(energy=12.0, ties=3).shape
    (1.0, 4.5)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from scipy.special import gammaincc, gammainccinv, gammaincinv, gammaln

from .._validation import positive

__all__ = ["NoiseScalePrior", "NoiseScalePosterior", "noise_scale_posterior", "PRIOR_TAIL"]

#: A posterior whose median lies where the prior has less than this mass beyond it is flagged: the prior all
#: but excluded the scale the data ask for (issue 44, "Bad input").
PRIOR_TAIL = 0.01
#: The shape of :meth:`NoiseScalePrior.wide` (a > 1: the mean of s given any partition is finite).
WIDE_SHAPE = 1.5


@dataclass(frozen=True)
class NoiseScalePrior:
    """An inverse-gamma distribution IG(shape a, scale b) of the noise scale s: density b^a / Gamma(a) s^-(a+1)
    e^(-b/s), mode b / (a + 1), mean b / (a - 1) for a > 1."""

    shape: float
    scale: float

    def __post_init__(self):
        object.__setattr__(self, "shape", positive("shape", self.shape))
        object.__setattr__(self, "scale", positive("scale", self.scale))

    @classmethod
    def wide(cls) -> "NoiseScalePrior":
        """Wide and centred on the calibrated scale: shape 1.5 and median 1, so 95 % of the prior lies within
        [0.25, 11.0] (covariances 4 times tighter to 11 times looser than calibrated; 1 % above 21)."""
        return cls(WIDE_SHAPE, float(gammaincinv(WIDE_SHAPE, 0.5)))

    @property
    def mode(self) -> float:
        return self.scale / (self.shape + 1.0)

    @property
    def mean(self) -> float:
        return self.scale / (self.shape - 1.0) if self.shape > 1.0 else math.inf

    def cdf(self, s):
        """P(S <= s)."""
        return gammaincc(self.shape, self.scale / np.asarray(s, dtype=float))

    def quantile(self, q: float) -> float:
        """The s with P(S <= s) = q."""
        return float(self.scale / gammainccinv(self.shape, q))

    def conditional(self, energy: float, ties: int) -> "NoiseScalePrior":
        """s given a partition whose Laplace mode has energy E* (at s = 1) and ``ties`` = k: IG(a + k, b + E*)."""
        return NoiseScalePrior(self.shape + ties, self.scale + energy)

    def log_marginal(self, energy: float, ties: int) -> float:
        """log int IG(s; a, b) s^-k exp(-E*/s) ds = a log b - lgamma(a) + lgamma(a + k) - (a + k) log(b + E*)."""
        a, b = self.shape, self.scale
        return float(a * math.log(b) - gammaln(a) + gammaln(a + ties) - (a + ties) * math.log(b + energy))

    def largest_log_marginal_gain(self, max_ties: int) -> float:
        """max over k = 0 .. max_ties of log int IG(s; a, b) s^-k ds = lgamma(a + k) - lgamma(a) - k log b: how far
        the marginal of a partition can exceed its Laplace value at s = 1 with E* = 0 (convex in k: an end)."""
        return max(0.0, float(gammaln(self.shape + max_ties) - gammaln(self.shape) - max_ties * math.log(self.scale)))


@dataclass(frozen=True)
class NoiseScalePosterior:
    """The posterior of the noise scale s, a mixture of inverse gammas over partitions.

    ``mean`` is E[s | data] (inf where a partition's conditional has shape <= 1); ``quantiles`` maps each probability asked for to its quantile; ``prior`` is the
    prior; ``prior_tail_mass`` is the prior's mass beyond the posterior median (on the side it lies), and
    ``in_prior_tail`` flags it below ``PRIOR_TAIL``: the prior all but excluded the scale the data ask for, so
    it was not wide enough to be trusted (widen it, or calibrate on data like these).
    """

    mean: float
    quantiles: dict
    prior: NoiseScalePrior
    prior_tail_mass: float
    in_prior_tail: bool


def noise_scale_posterior(result, posterior, quantiles=(0.025, 0.5, 0.975)) -> NoiseScalePosterior:
    """The posterior of the noise scale given a PTM ``result`` of ``posterior``: sum_T P(T | data)
    IG(a + k_T, b + E*_T) (Rao-Blackwellised: the conditionals are exact given T, only P(T | data) is sampled).

    ``posterior`` must hold exactly one odometry term with a ``noise_scale_prior``
    (:class:`ptm.OdometryModel`); the conditionals of the partitions are those its evaluations memoised
    (a partition it has not evaluated is fitted). The conditional is that of the Laplace part: the
    importance-sampling correction enters the partitions' probabilities at one scale each (docs/model.md §3.3).
    """
    if not hasattr(result, "partitions") or not hasattr(result, "probabilities"):
        raise TypeError(f"result must be a ptm.PTM, got {type(result).__name__}")
    if not hasattr(posterior, "terms"):
        raise TypeError(f"posterior must be a ptm.Posterior, got {type(posterior).__name__}")
    for q in quantiles:
        if not 0.0 < q < 1.0:
            raise ValueError(f"quantiles must lie in (0, 1), got {q!r}")
    terms = [term for term in posterior.terms if getattr(term, "noise_scale_prior", None) is not None]
    if len(terms) != 1:
        raise ValueError(f"noise_scale_posterior needs a posterior with exactly one odometry term that has a "
                         f"noise_scale_prior, this one has {len(terms)}")
    term = terms[0]
    if result.n != term.n:
        raise ValueError(f"the PTM is over {result.n} detections, the posterior over {term.n}")
    kept = np.flatnonzero(result.probabilities > 0.0)
    weights = result.probabilities[kept] / result.probabilities[kept].sum()
    conditionals = [term.noise_scale_conditional(result.partitions[row]) for row in kept]
    shapes = np.array([c.shape for c in conditionals])
    scales = np.array([c.scale for c in conditionals])
    mean = float(np.sum(weights * scales / (shapes - 1.0))) if np.all(shapes > 1.0) else math.inf
    values = {float(q): _mixture_quantile(weights, shapes, scales, q) for q in quantiles}
    median = _mixture_quantile(weights, shapes, scales, 0.5)
    prior = term.noise_scale_prior
    below = float(prior.cdf(median))
    tail = min(below, 1.0 - below)
    return NoiseScalePosterior(mean, values, prior, tail, tail < PRIOR_TAIL)


def _mixture_quantile(weights, shapes, scales, q: float) -> float:
    """The s with sum_T w_T P(S_T <= s) = q, S_T ~ IG(shape_T, scale_T): a root in log s between the
    components' own quantiles (the mixture's lies between the smallest and the largest)."""
    own = scales / gammainccinv(shapes, q)
    low, high = float(own.min()), float(own.max())
    if high <= low * (1.0 + 1e-12):
        return low

    def excess(log_s):
        return float(np.sum(weights * gammaincc(shapes, scales / math.exp(log_s)))) - q

    return math.exp(scipy.optimize.brentq(excess, math.log(low), math.log(high), xtol=1e-12))
