"""Visits from unusual standpoints: a per-visit scale mixture for the appearance model (docs/model.md §3.2.2).

The paper's model (``ptm.appearance``) gives every visit of a place the same
within-place variance s2_jk. A robot that passes a place 0.2 m left of its
centre and later 0.2 m right of it sees the place's decor with a parallax
that no single variance describes: most revisits lie close, a few far
(``ptm-bench appearance-check``: 2.5-2.9 % of revisit pairs favoured "two
places" on nested_loops and grids). Here each visit i of a set carries an
indicator z_i: with z_i = 1 (an *outlier* visit, seen from an unusual
standpoint) its variance is ``scale`` x s2_jk in every component at once,

    a_ik ~ N(y_jk, s2_jk / w_i),   w_i = 1 if z_i = 0, 1 / scale if z_i = 1,

and y, s2 are integrated out as in the paper's model. Given z the evidence is
still Normal-Inverse-Gamma, with the visits weighted (m outliers of n):

    kappa_n = kappa + sum w,   alpha_n = alpha + n / 2,
    beta_n  = beta + 1/2 [ sum w d^2 - (sum w d)^2 / kappa_n ],   d = a - mu,
    log p(S, k | z) = lgamma(alpha_n) - lgamma(alpha) + alpha log beta - alpha_n log beta_n
                      + 1/2 log(kappa / kappa_n) - (n / 2) log(2 pi) - (m / 2) log(scale).

The indicators' prior: a place has at most ``max_outliers`` outlier visits,
and among the configurations allowed, P(z | n) is proportional to
share^m (1 - share)^(n - m). The evidence of a set sums over those
configurations (1 + n + n(n-1)/2 of them for the default max_outliers = 2:
O(n^2 K) per set, exact, closed form). For n <= max_outliers this is the
plain i.i.d. mixture; for larger sets the bound keeps the sum polynomial, and
the prior is renormalised per set size, so every set's density is proper.
(The bound makes the model non-projective: the predictive of one more visit
is the conditional of the (n + 1)-visit model, not the ratio of two evidences;
:func:`outlier_predictive` computes that conditional.)

``share`` and ``scale`` are fitted by empirical Bayes together with the
per-component hyperparameters (:func:`fit_outlier_model`).

    >>> import numpy as np
    >>> values = np.array([[0.30], [0.31], [0.38]])
    >>> evidence = lambda share: float(outlier_log_evidence(values - 0.3, np.array([1.0]), np.array([3.0]),
    ...                                                      np.array([2e-4]), share, 9.0, 2))
    >>> evidence(0.1) > evidence(1e-9)   # the far third visit is likelier as an outlier
    True
"""

from __future__ import annotations

import math
from functools import lru_cache
from itertools import combinations

import numpy as np
from scipy import stats
from scipy.optimize import minimize
from scipy.special import digamma, gammaln, logsumexp

__all__ = ["StudentTMixture", "fit_outlier_model", "outlier_configurations", "outlier_log_evidence",
           "outlier_predictive", "stack_evidence_and_gradient"]

#: Where the empirical-Bayes fit may place the outlier share (its upper end is the fit's ``max_share``
#: argument, default 0.5) and the variance scale.
SHARE_BOUNDS = (1e-3, 0.5)
SCALE_BOUNDS = (1.5, 100.0)


@lru_cache(maxsize=256)
def outlier_configurations(n: int, max_outliers: int) -> tuple[np.ndarray, np.ndarray]:
    """(C, n) float masks of the allowed outlier configurations of an n-visit set and (C,) outlier counts.

    The configurations with at most ``max_outliers`` outliers, fewest first.
    """
    masks = [np.zeros(n)]
    for m in range(1, min(n, max_outliers) + 1):
        for chosen in combinations(range(n), m):
            mask = np.zeros(n)
            mask[list(chosen)] = 1.0
            masks.append(mask)
    masks = np.array(masks)
    masks.flags.writeable = False
    counts = masks.sum(axis=1)
    counts.flags.writeable = False
    return masks, counts


def _count_log_masses(n: int, share: float, max_outliers: int) -> tuple[np.ndarray, np.ndarray]:
    """The allowed outlier counts m = 0 .. min(n, max_outliers) of an n-visit set and the logarithms of
    C(n, m) share^m (1 - share)^(n - m), before renormalisation."""
    allowed = np.arange(min(n, max_outliers) + 1)
    return allowed, (gammaln(n + 1) - gammaln(allowed + 1) - gammaln(n - allowed + 1)
                     + allowed * math.log(share) + (n - allowed) * math.log1p(-share))


def _log_prior(n: int, counts: np.ndarray, share: float, max_outliers: int) -> np.ndarray:
    """log P(z | n) of each configuration: share^m (1 - share)^(n - m), renormalised over m <= max_outliers."""
    _, log_masses = _count_log_masses(n, share, max_outliers)
    return counts * math.log(share) + (n - counts) * math.log1p(-share) - logsumexp(log_masses)


def _weighted_posterior(centred: np.ndarray, masks: np.ndarray, kappa, scale: float):
    """kappa_n, the weighted sum of d and of d^2 per configuration and component, each (..., C, K).

    ``centred`` is (..., n, K): one set, or a stack of sets of one size.
    """
    shrink = 1.0 - 1.0 / scale  # w = 1 - shrink z
    total = centred.sum(axis=-2)[..., None, :] - shrink * np.einsum("cn,...nk->...ck", masks, centred)
    squares = (centred ** 2).sum(axis=-2)[..., None, :] - shrink * np.einsum("cn,...nk->...ck", masks, centred ** 2)
    kappa_n = kappa + centred.shape[-2] - shrink * masks.sum(axis=1)[:, None]
    return kappa_n, total, squares


def _log_evidence_given(centred, masks, counts, kappa, alpha, beta, scale) -> np.ndarray:
    """(..., C) log p(S | z) summed over components, for each configuration z."""
    n, width = centred.shape[-2:]
    kappa_n, total, squares = _weighted_posterior(centred, masks, kappa, scale)
    beta_n = beta + 0.5 * (squares - total * total / kappa_n)
    alpha_n = alpha + n / 2.0
    per_component = (gammaln(alpha_n) - gammaln(alpha) + alpha * np.log(beta) - alpha_n * np.log(beta_n)
                     + 0.5 * np.log(kappa / kappa_n))
    return per_component.sum(axis=-1) - 0.5 * n * width * math.log(2.0 * math.pi) - 0.5 * width * counts * math.log(scale)


def outlier_log_evidence(centred, kappa, alpha, beta, share: float, scale: float, max_outliers: int):
    """log p(S): the evidence of a set under the scale mixture, summed over components.

    ``centred`` is the (n, K) array of the set's signatures minus the prior
    mean mu, or a (G, n, K) stack of G sets of one size (then a (G,) array);
    ``kappa``, ``alpha``, ``beta`` are (K,) arrays.
    """
    n = centred.shape[-2]
    masks, counts = outlier_configurations(n, max_outliers)
    return _logsumexp_last(_configuration_log_prior(n, share, max_outliers)
                           + _log_evidence_given(centred, masks, counts, kappa, alpha, beta, scale))


@lru_cache(maxsize=1024)
def _configuration_log_prior(n: int, share: float, max_outliers: int) -> np.ndarray:
    """log P(z | n) of each configuration of :func:`outlier_configurations`, read-only (the set scores' inner
    loop asks for the same few sizes again and again)."""
    log_prior = _log_prior(n, outlier_configurations(n, max_outliers)[1], share, max_outliers)
    log_prior.flags.writeable = False
    return log_prior


def _logsumexp_last(values: np.ndarray) -> np.ndarray:
    """log sum exp over the last axis of finite values: ``scipy.special.logsumexp(values, axis=-1)`` without
    its argument handling, which took four fifths of a set's evidence (about 200 us a call)."""
    largest = values.max(axis=-1)
    return largest + np.log(np.exp(values - largest[..., None]).sum(axis=-1))


class StudentTMixture:
    """A mixture of products of univariate Student t's: the predictive of a visit under the outlier model.

    Parameters
    ----------
    weights : (C,) array summing to 1
    dof, loc, scale : (C, K) arrays
        Each mixture component's degrees of freedom, location and scale per signature component.
    """

    def __init__(self, weights, dof, loc, scale):
        self.weights = np.asarray(weights, dtype=float)
        self.dof, self.loc, self.scale = (np.asarray(v, dtype=float) for v in np.broadcast_arrays(dof, loc, scale))

    def logpdf(self, x) -> float:
        """Joint log density of one K-vector."""
        per_component = stats.t.logpdf(np.asarray(x, dtype=float), self.dof, self.loc, self.scale).sum(axis=1)
        return float(logsumexp(per_component, b=self.weights))

    def marginal_cdf(self, x) -> np.ndarray:
        """(K,) marginal CDF of each component at one K-vector: its probability-integral-transform values."""
        return self.weights @ stats.t.cdf(np.asarray(x, dtype=float), self.dof, self.loc, self.scale)

    def __repr__(self) -> str:
        return f"StudentTMixture({self.weights.size} components, K={self.loc.shape[1]})"


def outlier_predictive(centred_given, mu, kappa, alpha, beta, share: float, scale: float,
                       max_outliers: int) -> StudentTMixture:
    """The predictive of one more visit of a set (n given visits), under the (n + 1)-visit model.

    Each configuration z of the n + 1 visits weighs P(z | n + 1) p(given | z);
    given z the new visit is a Student t with 2 alpha_n degrees of freedom,
    location mu + (sum w d) / kappa_n and squared scale
    beta_n (kappa_n + w_new) / (alpha_n kappa_n w_new), from the given visits' weighted statistics.
    """
    n, width = centred_given.shape
    masks, counts = outlier_configurations(n + 1, max_outliers)
    given_masks, new_is_outlier = masks[:, :n], masks[:, n]
    log_weights = (_log_prior(n + 1, counts, share, max_outliers)
                   + _log_evidence_given(centred_given, given_masks, counts - new_is_outlier, kappa, alpha, beta, scale))
    weights = np.exp(log_weights - logsumexp(log_weights))
    kappa_n, total, squares = _weighted_posterior(centred_given, given_masks, kappa, scale)
    alpha_n = alpha + n / 2.0
    beta_n = beta + 0.5 * (squares - total * total / kappa_n)
    new_weight = (1.0 - (1.0 - 1.0 / scale) * new_is_outlier)[:, None]
    spread = np.sqrt(beta_n * (kappa_n + new_weight) / (alpha_n * kappa_n * new_weight))
    return StudentTMixture(weights, np.broadcast_to(2.0 * alpha_n, spread.shape), mu + total / kappa_n, spread)


def _log_prior_gradient(n: int, counts: np.ndarray, share: float, max_outliers: int) -> np.ndarray:
    """d log P(z | n) / d share of each configuration."""
    allowed, log_masses = _count_log_masses(n, share, max_outliers)

    def slope(m):
        return m / share - (n - m) / (1.0 - share)

    return slope(counts) - np.exp(log_masses - logsumexp(log_masses)) @ slope(allowed)


def stack_evidence_and_gradient(stack, mu, kappa, alpha, beta, share: float, scale: float,
                                max_outliers: int) -> tuple[float, np.ndarray]:
    """The total log evidence of a (G, n, K) stack of sets of one size and its gradient in
    (mu, kappa, alpha, beta, share, scale): a (4K + 2,) array, the objective of :func:`fit_outlier_model`.

    With r the posterior of the configurations of each set, the gradient is
    the r-weighted gradient of log P(z) + log p(S | z). Per component, with
    T, Q the weighted sums of d and d^2 and W = sum w (so kappa_n = kappa + W):
    d beta_n / d mu = -T kappa / kappa_n, d beta_n / d kappa = T^2 / (2 kappa_n^2), and
    d(T, Q, W) / d scale = -(D1, D2, m) / scale^2, D1 and D2 the outliers' sums of d and d^2.
    """
    n, width = stack.shape[-2:]
    masks, counts = outlier_configurations(n, max_outliers)
    centred = stack - mu
    log_joint = (_log_prior(n, counts, share, max_outliers)
                 + _log_evidence_given(centred, masks, counts, kappa, alpha, beta, scale))
    kappa_n, total, squares = _weighted_posterior(centred, masks, kappa, scale)
    beta_n = beta + 0.5 * (squares - total * total / kappa_n)
    alpha_n = alpha + n / 2.0
    per_set = logsumexp(log_joint, axis=-1)
    weight = np.exp(log_joint - per_set[:, None])[..., None]  # (G, C, 1)
    pull = alpha_n / beta_n  # -d log p / d beta_n
    d_mu = pull * total * kappa / kappa_n
    d_kappa = 0.5 * (1.0 / kappa - 1.0 / kappa_n) - pull * total * total / (2.0 * kappa_n ** 2)
    d_alpha = digamma(alpha_n) - digamma(alpha) + np.log(beta) - np.log(beta_n)
    d_beta = alpha / beta - pull
    d_kappa_n = -counts[:, None] / scale ** 2
    d_total = -np.einsum("cn,gnk->gck", masks, centred) / scale ** 2
    d_squares = -np.einsum("cn,gnk->gck", masks, centred ** 2) / scale ** 2
    d_beta_n = 0.5 * (d_squares - 2.0 * total * d_total / kappa_n + total * total * d_kappa_n / kappa_n ** 2)
    d_scale = (-0.5 * d_kappa_n / kappa_n - pull * d_beta_n).sum(axis=-1) - 0.5 * width * counts / scale
    d_share = _log_prior_gradient(n, counts, share, max_outliers)
    gradient = np.concatenate([(weight * part).sum(axis=(0, 1)) for part in (d_mu, d_kappa, d_alpha, d_beta)]
                              + [[(weight[..., 0] * d_share).sum()], [(weight[..., 0] * d_scale).sum()]])
    return float(per_set.sum()), gradient


def fit_outlier_model(groups, mu, kappa, alpha, beta, max_outliers: int, max_alpha: float,
                      max_share: float = SHARE_BOUNDS[1]):
    """Empirical Bayes for the whole model: (mu, kappa, alpha, beta, share, scale) maximising the evidence of
    the calibration places' ``groups`` (each an (n, K) array).

    Starts from the paper model's fit (the per-component ``mu`` ... ``beta`` given) with a share of 0.1 at
    4 x the variance (or ``max_share``, if lower), and moves all 4K + 2 together (L-BFGS-B with the analytic
    gradient of :func:`stack_evidence_and_gradient`, in mu and the logarithms of the rest; alpha <=
    ``max_alpha``, the share between the lower end of :data:`SHARE_BOUNDS` and ``max_share``, the scale within
    :data:`SCALE_BOUNDS`): the paper model's fit alone would keep the variance that the outlier visits
    inflated. ``max_share`` says how rare outlier visits are held to be: the evidence of the calibration runs
    alone puts half the visits there (docs/model.md §3.2.2). Raises ``ValueError`` for a ``max_share``
    outside (the lower bound, 0.5] and ``RuntimeError`` naming the optimiser's message if the fit fails.
    """
    if not SHARE_BOUNDS[0] < max_share <= SHARE_BOUNDS[1]:
        raise ValueError(f"max_share must lie in ({SHARE_BOUNDS[0]:g}, {SHARE_BOUNDS[1]:g}], got {max_share!r}")
    by_size = {}
    for group in groups:
        by_size.setdefault(len(group), []).append(np.asarray(group, dtype=float))
    stacks = [np.stack(sets) for sets in by_size.values()]
    width = stacks[0].shape[-1]

    def negative_evidence(params):
        natural = np.concatenate([params[:width], np.exp(params[width:])])
        mu_, kappa_, alpha_, beta_ = natural[:4 * width].reshape(4, width)
        value, gradient = 0.0, np.zeros_like(params)
        for stack in stacks:
            part, part_gradient = stack_evidence_and_gradient(stack, mu_, kappa_, alpha_, beta_, *natural[4 * width:],
                                                              max_outliers)
            value += part
            gradient += part_gradient
        gradient[width:] *= natural[width:]  # d / d log x = x d / d x
        return -value, -gradient

    start = np.concatenate([mu, np.log(kappa), np.log(alpha), np.log(beta), np.log([min(0.1, max_share), 4.0])])
    bounds = ([(None, None)] * width + [(math.log(1e-4), math.log(1e4))] * width
              + [(math.log(min(0.5, max_alpha)), math.log(max_alpha))] * width
              + [(value - 25.0, value + 25.0) for value in np.log(beta)]
              + [(math.log(SHARE_BOUNDS[0]), math.log(max_share)), tuple(math.log(v) for v in SCALE_BOUNDS)])
    result = minimize(negative_evidence, start, jac=True, method="L-BFGS-B", bounds=bounds)
    if not (result.success and np.isfinite(result.fun)):
        raise RuntimeError(f"AppearanceModel.fit: the outlier model's fit did not converge ({result.message})")
    mu_, log_kappa, log_alpha, log_beta = result.x[:4 * width].reshape(4, width)
    share, scale = np.exp(result.x[4 * width:])
    return mu_, np.exp(log_kappa), np.exp(log_alpha), np.exp(log_beta), float(share), float(scale)
