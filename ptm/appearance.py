"""Appearance likelihood: conjugate Normal-Inverse-Gamma evidence per set (paper eq. 15-19, docs/model.md §3.2).

Each signature component k of a detection i in set S_j is modelled as

    a_ik ~ N(y_jk, s2_jk),   y_jk ~ N(mu_k, s2_jk / kappa_k),   s2_jk ~ InvGamma(alpha_k, beta_k)

and integrating y and s2 out gives, for a set of n members,

    kappa_n = kappa + n,  alpha_n = alpha + n/2,
    beta_n  = beta + 1/2 [ sum (a - mean)^2 + kappa n (mean - mu)^2 / kappa_n ]
            = beta + 1/2 [ sum (a - mu)^2 - (sum (a - mu))^2 / kappa_n ]
    log p(S, k) = lgamma(alpha_n) - lgamma(alpha) + alpha log beta - alpha_n log beta_n
                  + 1/2 log(kappa / kappa_n) - (n/2) log(2 pi).

log P(A | T) sums this over sets and components. The paper's printed eq. (19)
(exponent alpha + n/2 + 2, per-set constants dropped) is wrong — errata E1 and E2
of docs/model.md — and is offered only as the ablation ``evidence="paper_eq19"``.

Predictive checks (any appearance term, this model or
:class:`ptm.JointAppearanceModel`): the log Bayes factor of a pair "same place"
vs "two places", log p({i, j}) - log p({i}) - log p({j}), and the posterior
predictive of a held-out visit given the other visits of its place. For this
model the predictive of component k given a set of n members is a Student t
with 2 alpha_n degrees of freedom, location mu_n = (kappa mu + n mean) / kappa_n
and squared scale beta_n (kappa_n + 1) / (alpha_n kappa_n), independently per
component; :func:`leave_one_out_pit` returns the probability-integral
transform of every held-out component (uniform if the model is calibrated).

    >>> import numpy as np; from ptm import AppearanceModel, Dataset
    >>> term = AppearanceModel(mu=0.3, kappa=1.0, alpha=3.0, beta=0.01).bind(Dataset(signatures=np.full((3, 2), 0.3)))
    >>> round(term.block_log_likelihood((0, 1, 2)), 3), round(pair_log_bayes_factor(term, 0, 1), 3)
    (10.437, 0.454)
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize
from scipy import stats
from scipy.special import digamma, gammaln

from ._cache import BoundedCache
from ._validation import count, finite_array, instance, positive, positive_array, share
from .appearance_outliers import SHARE_BOUNDS, fit_outlier_model, outlier_log_evidence, outlier_predictive
from .dataset import Dataset
from .partitions import Partition

__all__ = ["AppearanceModel", "IndependentStudentT", "calibration_groups", "inverse_gamma_from_mean_variance",
           "leave_one_out_pit", "pair_log_bayes_factor", "pairwise_log_bayes_factors", "predictive_log_density",
           "predictive_pit"]

EVIDENCE_FORMS = ("corrected", "paper_eq19")
#: The hyperparameters kappa, alpha and beta lie in this range, and |mu| below its top, so that the evidence's
#: products and squares stay floats (alpha = 1.7e308 gave NaN, kappa = 5e-324 probability 0 everywhere).
HYPERPARAMETER_RANGE = (1e-150, 1e150)


def inverse_gamma_from_mean_variance(mean: float, variance: float) -> tuple[float, float]:
    """(alpha, beta) of the inverse gamma with the given mean and variance of s2.

    mean = beta / (alpha - 1) and variance = mean^2 / (alpha - 2), so
    alpha = 2 + mean^2 / variance and beta = mean (alpha - 1). The paper uses
    mean 500 and variance 50.
    """
    mean = positive("mean", mean)
    variance = positive("variance", variance)
    alpha = 2.0 + mean * mean / variance
    return alpha, mean * (alpha - 1.0)


class AppearanceModel:
    """Hyperparameters of the appearance model; ``bind(dataset)`` gives the likelihood term.

    Parameters
    ----------
    mu, kappa, alpha, beta : float or (K,) array
        Prior mean of the true appearance, its precision scale, and the
        inverse-gamma shape and scale of the per-set noise variance.
    evidence : {"corrected", "paper_eq19"}
        The exact NIG evidence (default) or the paper's printed eq. (19), an ablation only.
    outlier_share, outlier_scale, max_outliers
        Visits from unusual standpoints (``ptm.appearance_outliers``, docs/model.md §3.2.2): each visit is,
        with prior probability ``outlier_share``, seen with ``outlier_scale`` x its place's variance in
        every component; a place has at most ``max_outliers`` such visits. ``outlier_share = 0`` (the
        default) is the paper's model.
    """

    def __init__(self, mu, kappa, alpha, beta, evidence: str = "corrected", outlier_share: float = 0.0,
                 outlier_scale: float = 1.0, max_outliers: int = 2):
        self.mu = finite_array("mu", mu)
        if self.mu.ndim > 1:
            raise ValueError(f"mu must be a scalar or a 1-D array, got shape {self.mu.shape}")
        if np.any(np.abs(self.mu) > HYPERPARAMETER_RANGE[1]):
            raise ValueError(f"mu must lie within +-{HYPERPARAMETER_RANGE[1]:g}, got {mu!r}")
        self.kappa = positive_array("kappa", kappa, within=HYPERPARAMETER_RANGE)
        self.alpha = positive_array("alpha", alpha, within=HYPERPARAMETER_RANGE)
        self.beta = positive_array("beta", beta, within=HYPERPARAMETER_RANGE)
        if evidence not in EVIDENCE_FORMS:
            raise ValueError(f"evidence must be one of {EVIDENCE_FORMS}, got {evidence!r}")
        self.evidence = evidence
        self.outlier_share = share("outlier_share", outlier_share)
        if self.outlier_share == 1.0:
            raise ValueError(f"outlier_share must lie in [0, 1), got {outlier_share!r}")
        self.outlier_scale = positive("outlier_scale", outlier_scale, (0.0, HYPERPARAMETER_RANGE[1]))
        if self.outlier_share > 0.0 and self.outlier_scale <= 1.0:
            raise ValueError(f"outlier_scale must exceed 1 when outlier_share > 0, got {outlier_scale!r}")
        self.max_outliers = count("max_outliers", max_outliers, 1)
        if self.outlier_share > 0.0 and evidence != "corrected":
            raise ValueError("outliers (outlier_share > 0) need evidence='corrected'; the printed eq. (19) is "
                             "an ablation of the paper's model only")
        lengths = {name: np.size(value) for name, value in self._hyper().items() if np.ndim(value) == 1}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"hyperparameter arrays have different lengths: {lengths}")

    def _hyper(self) -> dict:
        return {"mu": self.mu, "kappa": self.kappa, "alpha": self.alpha, "beta": self.beta}

    @property
    def outliers(self) -> dict:
        """The outlier settings as constructor keywords (``outlier_share = 0``: none)."""
        return {"outlier_share": self.outlier_share, "outlier_scale": self.outlier_scale,
                "max_outliers": self.max_outliers}

    def bind(self, dataset) -> "AppearanceTerm":
        if dataset.signatures is None:
            raise ValueError("the appearance model needs a dataset with signatures")
        width = dataset.signatures.shape[1]
        for name, value in self._hyper().items():
            if np.ndim(value) == 1 and value.shape[0] != width:
                raise ValueError(f"{name} has length {value.shape[0]} but the signatures have K={width}")
        return AppearanceTerm(self, dataset.signatures)

    @classmethod
    def fit(cls, datasets, evidence: str = "corrected", max_alpha: float = 10.0, outliers: bool = False,
            max_outliers: int = 2, max_outlier_share: float = SHARE_BOUNDS[1]) -> "AppearanceModel":
        """Empirical Bayes: per-component (mu, kappa, alpha, beta) maximising the evidence
        of the ground-truth partitions of labelled calibration datasets.

        With ``outliers=True`` the outlier share and scale (docs/model.md §3.2.2) are fitted
        to the same evidence together with those four, starting from their fit without outliers
        (``ptm.appearance_outliers.fit_outlier_model``), the share at most ``max_outlier_share``.

        ``max_alpha`` bounds the inverse-gamma shape. Unbounded, a few
        calibration runs whose places share one noise level drive alpha to the
        thousands (s2 known exactly); the predictive of a new visit is then
        practically Normal and one unusual visit is split off its place. With
        alpha <= 10 the predictive stays a Student t with <= 20 degrees of freedom.
        Never fit on the data you then score: use separate calibration runs.
        Each component is fitted by L-BFGS-B; a run that reports failure is
        restarted once from where it stopped with the analytic gradient of the
        evidence, and if that fails too the fit raises ``RuntimeError`` naming
        the component and the optimiser's messages.
        """
        max_alpha = positive("max_alpha", max_alpha, HYPERPARAMETER_RANGE)
        if evidence not in EVIDENCE_FORMS:
            raise ValueError(f"evidence must be one of {EVIDENCE_FORMS}, got {evidence!r}")
        groups = calibration_groups(datasets)
        width = groups[0].shape[1]
        fitted = np.array([_fit_component([group[:, k] for group in groups], evidence, max_alpha, component=k)
                           for k in range(width)])
        mu, kappa, alpha, beta = fitted.T
        if not outliers:
            return cls(mu, kappa, alpha, beta, evidence=evidence)
        if evidence != "corrected":
            raise ValueError("outliers=True needs evidence='corrected'")
        mu, kappa, alpha, beta, share, scale = fit_outlier_model(groups, mu, kappa, alpha, beta, max_outliers, max_alpha,
                                                                 max_outlier_share)
        return cls(mu, kappa, alpha, beta, evidence=evidence, outlier_share=share, outlier_scale=scale,
                   max_outliers=max_outliers)

    def __repr__(self) -> str:
        def show(value):
            return f"{float(value):.4g}" if np.ndim(value) == 0 else np.array2string(value, precision=4)

        outliers = (f", outlier_share={self.outlier_share:.4g}, outlier_scale={self.outlier_scale:.4g}, "
                    f"max_outliers={self.max_outliers}") if self.outlier_share > 0 else ""
        return (f"AppearanceModel(mu={show(self.mu)}, kappa={show(self.kappa)}, "
                f"alpha={show(self.alpha)}, beta={show(self.beta)}, evidence={self.evidence!r}{outliers})")


#: Sets whose evidence an :class:`AppearanceTerm` remembers, with the terms it grows into (:meth:`AppearanceTerm.grown`).
SET_MEMO_SIZE = 200_000


class AppearanceTerm:
    """The appearance likelihood bound to one dataset's signatures; decomposes over sets.

    A set's evidence depends on its members' signatures alone, so it is memoised per set, and
    :meth:`grown` binds the model to a run with more detections while keeping what is known.
    """

    name = "appearance"

    def __init__(self, model: AppearanceModel, signatures: np.ndarray, memo: BoundedCache | None = None):
        self.model = model
        self.signatures = signatures
        self._memo = BoundedCache(SET_MEMO_SIZE) if memo is None else memo
        width = signatures.shape[1]
        self._centred = signatures - model.mu
        self._centred_squared = self._centred ** 2
        self._kappa = np.broadcast_to(model.kappa, (width,)).astype(float)
        self._alpha = np.broadcast_to(model.alpha, (width,)).astype(float)
        self._beta = np.broadcast_to(model.beta, (width,)).astype(float)
        self._paper_form = model.evidence == "paper_eq19"
        self._constant_by_size: dict[int, float] = {}

    def _constant(self, n: int) -> float:
        """The part of sum_k log p(S, k) that depends on the set size only."""
        value = self._constant_by_size.get(n)
        if value is None:
            kappa, alpha, beta = self._kappa, self._alpha, self._beta
            if self._paper_form:
                value = float(np.sum(gammaln(alpha + n / 2.0 + 2.0) - 0.5 * np.log(kappa + n)))
            else:
                value = float(np.sum(gammaln(alpha + n / 2.0) - gammaln(alpha) + alpha * np.log(beta)
                                     + 0.5 * np.log(kappa / (kappa + n)))
                              - 0.5 * n * kappa.size * math.log(2.0 * math.pi))
            self._constant_by_size[n] = value
        return value

    def grown(self, dataset) -> "AppearanceTerm":
        """The model bound to ``dataset``, a run whose first detections are this term's (the online mapper's
        next detection), sharing this term's memo of set evidences: those sets' members and signatures are
        the same. ``ValueError`` where ``dataset``'s signatures do not begin with this term's."""
        signatures = dataset.signatures
        n = len(self.signatures)
        if signatures is None or len(signatures) < n or not np.array_equal(signatures[:n], self.signatures):
            raise ValueError("the dataset does not extend this term's run: its first signatures differ or are "
                             "missing; bind the model to it instead (model.bind(dataset))")
        return AppearanceTerm(self.model, signatures, self._memo)

    def block_log_likelihood(self, block) -> float:
        """sum_k log p(S, k) for the set of detections ``block`` (a sorted tuple), memoised."""
        key = tuple(block)
        value = self._memo.get(key)
        if value is None:
            value = self._evidence(key)
            self._memo.put(key, value)
        return value

    def _evidence(self, block) -> float:
        members = list(block)
        n = len(members)
        model = self.model
        if model.outlier_share > 0.0:
            return float(outlier_log_evidence(self._centred[members], self._kappa, self._alpha, self._beta,
                                              model.outlier_share, model.outlier_scale, model.max_outliers))
        if n == 1:
            total = self._centred[members[0]]
            squares = self._centred_squared[members[0]]
        else:
            total = self._centred[members].sum(axis=0)
            squares = self._centred_squared[members].sum(axis=0)
        beta_n = self._beta + 0.5 * (squares - total * total / (self._kappa + n))
        exponent = self._alpha + (n / 2.0 + 2.0 if self._paper_form else n / 2.0)
        return self._constant(n) - float(np.dot(exponent, np.log(beta_n)))

    def log_likelihood(self, partition: Partition) -> float:
        return sum(self.block_log_likelihood(block) for block in partition.blocks)

    def predictive(self, given=()) -> "IndependentStudentT":
        """Posterior predictive of one more visit of the set ``given`` (the prior predictive if empty)."""
        if self._paper_form:
            raise ValueError("evidence='paper_eq19' is not a normalised model and has no predictive; "
                             "use evidence='corrected'")
        members = list(given)
        n = len(members)
        model = self.model
        if model.outlier_share > 0.0:
            return outlier_predictive(self._centred[members], model.mu, self._kappa, self._alpha, self._beta,
                                      model.outlier_share, model.outlier_scale, model.max_outliers)
        total = self._centred[members].sum(axis=0) if n else np.zeros_like(self._kappa)
        squares = self._centred_squared[members].sum(axis=0) if n else np.zeros_like(self._kappa)
        kappa_n = self._kappa + n
        alpha_n = self._alpha + n / 2.0
        beta_n = self._beta + 0.5 * (squares - total * total / kappa_n)
        return IndependentStudentT(dof=2.0 * alpha_n, loc=self.model.mu + total / kappa_n,
                                   scale=np.sqrt(beta_n * (kappa_n + 1.0) / (alpha_n * kappa_n)))


class IndependentStudentT:
    """A product of univariate Student t distributions, one per signature component.

    Parameters
    ----------
    dof, loc, scale : (K,) arrays
        Degrees of freedom, location and scale (not variance) of each component.
    """

    def __init__(self, dof, loc, scale):
        self.dof, self.loc, self.scale = (np.asarray(v, dtype=float) for v in np.broadcast_arrays(dof, loc, scale))

    def logpdf(self, x) -> float:
        """Joint log density of one K-vector (sum of the components' log densities)."""
        return float(np.sum(stats.t.logpdf(np.asarray(x, dtype=float), self.dof, self.loc, self.scale)))

    def marginal_cdf(self, x) -> np.ndarray:
        """Per-component CDF of one K-vector: its probability-integral-transform values."""
        return stats.t.cdf(np.asarray(x, dtype=float), self.dof, self.loc, self.scale)

    def __repr__(self) -> str:
        return f"IndependentStudentT(dof={self.dof}, loc={self.loc}, scale={self.scale})"


# -- predictive checks, for any appearance term ------------------------------------------------------


def pair_log_bayes_factor(term, i: int, j: int) -> float:
    """log p({i, j}) - log p({i}) - log p({j}): > 0 favours "i and j are the same place".

    ``term`` is any bound appearance term (``model.bind(dataset)``) with
    ``block_log_likelihood``: :class:`AppearanceModel` or :class:`ptm.JointAppearanceModel`.
    """
    i, j = _detection(term, i), _detection(term, j)
    if i == j:
        raise ValueError(f"a pair needs two different detections, got i = j = {i}")
    pair = (min(i, j), max(i, j))
    return float(term.block_log_likelihood(pair) - term.block_log_likelihood((i,)) - term.block_log_likelihood((j,)))


def pairwise_log_bayes_factors(term) -> np.ndarray:
    """(N, N) symmetric matrix of :func:`pair_log_bayes_factor`, NaN on the diagonal."""
    n = term.signatures.shape[0]
    singles = np.array([term.block_log_likelihood((i,)) for i in range(n)])
    matrix = np.full((n, n), np.nan)
    for i in range(n):
        for j in range(i + 1, n):
            matrix[i, j] = matrix[j, i] = term.block_log_likelihood((i, j)) - singles[i] - singles[j]
    return matrix


def predictive_log_density(term, held_out: int, given) -> float:
    """log p(a_held_out | a_given): the posterior predictive density of one visit given a set.

    ``given`` may be empty (the prior predictive). Equals
    log p(given + {held_out}) - log p(given) (the chain rule of the evidence).
    """
    held_out, given = _held_out_and_given(term, held_out, given)
    return term.predictive(given).logpdf(term.signatures[held_out])


def predictive_pit(term, held_out: int, given) -> np.ndarray:
    """(K,) probability-integral-transform values of visit ``held_out`` under the predictive given ``given``.

    Component k's value is the marginal predictive CDF at the observed a_k
    (Student t, see the module docstrings); over many held-out visits a
    calibrated model gives values uniform on (0, 1), an overconfident one piles
    them up near 0 and 1.
    """
    held_out, given = _held_out_and_given(term, held_out, given)
    return term.predictive(given).marginal_cdf(term.signatures[held_out])


def leave_one_out_pit(term, labels) -> np.ndarray:
    """(N, K) PIT of every detection given the other visits of its place (ground-truth ``labels``).

    A row is NaN when its detection is the only visit of its place (nothing to
    condition on; those visits test the prior, not the within-place model).
    """
    labels = np.asarray(labels)
    n, width = term.signatures.shape
    if labels.shape != (n,):
        raise ValueError(f"labels must have shape ({n},) to match the term's signatures, got {labels.shape}")
    pit = np.full((n, width), np.nan)
    for block in Partition.from_labels(labels).blocks:
        if len(block) < 2:
            continue
        for held_out in block:
            pit[held_out] = predictive_pit(term, held_out, [i for i in block if i != held_out])
    return pit


def _detection(term, index) -> int:
    n = term.signatures.shape[0]
    if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)) or not 0 <= index < n:
        raise ValueError(f"detection index must be an integer in [0, {n}), got {index!r}")
    return int(index)


def _held_out_and_given(term, held_out, given) -> tuple[int, tuple]:
    held_out = _detection(term, held_out)
    given = tuple(sorted(_detection(term, i) for i in given))
    if held_out in given or len(set(given)) != len(given):
        raise ValueError(f"given must list distinct detections other than held_out={held_out}, got {given}")
    return held_out, given


def calibration_groups(datasets) -> list[np.ndarray]:
    """The signatures of each ground-truth place of labelled calibration datasets (one :class:`ptm.Dataset`
    or any iterable of them), one (n, K) array per place.

    Refuses (``TypeError``) anything but a Dataset or an iterable of Datasets, and (``ValueError``, naming
    the problem) an empty list, a dataset without signatures or labels, datasets of different K, a set
    without a single revisit, and a component that
    is constant over the whole set (its variance would be fitted as zero: a
    model certain that every visit repeats that value exactly).
    """
    try:
        runs = iter([datasets] if isinstance(datasets, Dataset) else datasets)
    except TypeError:
        raise TypeError(f"datasets must be a ptm.Dataset or an iterable of them, got {datasets!r:.60}") from None
    datasets = [instance(f"datasets[{index}]", dataset, Dataset) for index, dataset in enumerate(runs)]
    if not datasets:
        raise ValueError("fit needs at least one labelled dataset")
    groups = []
    for index, dataset in enumerate(datasets):
        if dataset.signatures is None or dataset.labels is None:
            raise ValueError(f"calibration dataset {index} needs signatures and labels")
        for block in Partition.from_labels(dataset.labels).blocks:
            groups.append(dataset.signatures[list(block)])
    widths = {group.shape[1] for group in groups}
    if len(widths) != 1:
        raise ValueError(f"calibration datasets have different signature lengths {sorted(widths)}")
    if all(group.shape[0] == 1 for group in groups):
        raise ValueError("the calibration set has no revisits (every place is visited once): the within-place "
                         "spread cannot be told apart from the spread between places")
    values = np.concatenate(groups)
    centre, spread = values.mean(axis=0), values.std(axis=0)
    for k in range(values.shape[1]):
        if not spread[k] > 1e-12 * max(1.0, abs(centre[k])):
            raise ValueError(f"signature component {k} is constant ({centre[k]:.6g}) over the whole calibration "
                             "set: its variance is degenerate; drop the component or calibrate on varied data")
    return groups


def _component_evidence(params: np.ndarray, groups: list[np.ndarray], evidence: str) -> float:
    """Total log evidence of one component over the calibration groups, params = (mu, log kappa, log alpha,
    log beta): the objective of the fit, through :class:`AppearanceTerm` itself."""
    mu, log_kappa, log_alpha, log_beta = params
    kappa, alpha, beta = math.exp(log_kappa), math.exp(log_alpha), math.exp(log_beta)
    model = AppearanceModel(mu, kappa, alpha, beta, evidence=evidence)
    total = 0.0
    for group in groups:
        term = AppearanceTerm(model, group[:, None])
        total += term.block_log_likelihood(range(group.shape[0]))
    return total


class _ComponentData:
    """One signature component of the calibration places, flattened: ``values``, the place ``group`` of
    each value and the number of visits ``sizes`` of each place."""

    def __init__(self, groups: list[np.ndarray]):
        self.values = np.concatenate(groups)
        self.sizes = np.array([group.size for group in groups], dtype=float)
        self.group = np.repeat(np.arange(len(groups)), [group.size for group in groups])


def _component_evidence_gradient(params: np.ndarray, data: _ComponentData, evidence: str) -> tuple[float, np.ndarray]:
    """:func:`_component_evidence` (vectorised over the places) and its analytic gradient in
    params = (mu, log kappa, log alpha, log beta), for the fit's restart.

    With d = a - mu, T = sum d and Q = sum d^2 per place, beta_n = beta + (Q - T^2 / kappa_n) / 2,
    so d beta_n / d mu = -T kappa / kappa_n and d beta_n / d kappa = T^2 / (2 kappa_n^2).
    """
    mu, log_kappa, log_alpha, log_beta = params
    kappa, alpha, beta = math.exp(log_kappa), math.exp(log_alpha), math.exp(log_beta)
    n = data.sizes
    centred = data.values - mu
    total = np.bincount(data.group, centred, minlength=n.size)
    squares = np.bincount(data.group, centred * centred, minlength=n.size)
    kappa_n = kappa + n
    beta_n = beta + 0.5 * (squares - total * total / kappa_n)
    log_beta_n = np.log(beta_n)
    if evidence == "paper_eq19":  # an ablation: the printed eq. (19), see AppearanceTerm
        shape_n = alpha + n / 2.0 + 2.0
        value = float(np.sum(gammaln(shape_n) - 0.5 * np.log(kappa_n) - shape_n * log_beta_n))
        d_alpha = float(np.sum(digamma(shape_n) - log_beta_n))
        d_beta = float(np.sum(-shape_n / beta_n))
        d_kappa = float(np.sum(-0.5 / kappa_n))
    else:
        shape_n = alpha + n / 2.0
        value = float(np.sum(gammaln(shape_n) - gammaln(alpha) + alpha * log_beta - shape_n * log_beta_n
                             + 0.5 * np.log(kappa / kappa_n) - 0.5 * n * math.log(2.0 * math.pi)))
        d_alpha = float(np.sum(digamma(shape_n) - digamma(alpha) + log_beta - log_beta_n))
        d_beta = float(np.sum(alpha / beta - shape_n / beta_n))
        d_kappa = float(np.sum(0.5 * (1.0 / kappa - 1.0 / kappa_n)))
    pull = shape_n / beta_n  # -d log p / d beta_n
    d_mu = float(np.sum(pull * total * kappa / kappa_n))
    d_kappa -= float(np.sum(pull * 0.5 * total * total / kappa_n**2))
    return value, np.array([d_mu, d_kappa * kappa, d_alpha * alpha, d_beta * beta])


def _fit_component(groups: list[np.ndarray], evidence: str, max_alpha: float,
                   component: int = 0) -> tuple[float, float, float, float]:
    """Maximise the evidence of one component with L-BFGS-B (finite-difference gradient).

    A run that reports failure (in about 2 % of component fits, an abnormal
    line search where the evidence is flat to rounding) is restarted from
    where it stopped with the analytic gradient
    (:func:`_component_evidence_gradient`); if that run fails too,
    ``RuntimeError`` names the component and both messages.
    """
    values = np.concatenate(groups)
    spread = float(np.var(values)) if values.size > 1 else 1.0
    within = [np.var(group) for group in groups if group.size > 1]
    noise = float(np.mean(within)) if within else spread
    noise = max(noise, 1e-12 + 1e-6 * spread, 1e-12)
    start_alpha = min(3.0, max_alpha)
    start = np.array([float(values.mean()), 0.0, math.log(start_alpha), math.log(max(start_alpha - 1.0, 0.5) * noise)])
    bounds = [(None, None), (math.log(1e-4), math.log(1e4)), (math.log(min(0.5, max_alpha)), math.log(max_alpha)),
              (start[3] - 25.0, start[3] + 25.0)]
    result = minimize(lambda p: -_component_evidence(p, groups, evidence), start, method="L-BFGS-B", bounds=bounds)
    attempts = [str(result.message)]
    if not (result.success and np.isfinite(result.fun)):
        data = _ComponentData(groups)

        def objective(params):
            value, gradient = _component_evidence_gradient(params, data, evidence)
            return -value, -gradient

        result = minimize(objective, result.x, jac=True, method="L-BFGS-B", bounds=bounds)
        attempts.append(str(result.message))
        if not (result.success and np.isfinite(result.fun)):
            hint = ""
            if evidence == "paper_eq19" and any(group.size == 1 for group in groups):
                hint = ("; the printed eq. (19) has no maximum when a calibration place is visited once (its "
                        "evidence grows without bound as beta -> 0 with mu at that visit)")
            raise RuntimeError(f"AppearanceModel.fit: the optimiser did not converge for signature component "
                               f"{component} ({'; '.join(attempts)}){hint}")
    mu, log_kappa, log_alpha, log_beta = result.x
    return float(mu), math.exp(log_kappa), math.exp(log_alpha), math.exp(log_beta)
