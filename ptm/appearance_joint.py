"""Joint appearance likelihood: Normal-Inverse-Wishart evidence of the K-vector per set (docs/model.md §3.2).

Beyond the paper. The paper's model (eq. 15-19, :mod:`ptm.appearance`) treats
the K signature components as independent; on the simulator one latent factor
(the robot's position inside the detection radius) moves several components
together and the within-place spread differs several-fold between places, so
that model is overconfident. Here the whole vector a_i of a detection in set S_j is

    a_i ~ N(y_j, Sigma_j),   y_j ~ N(mu, Sigma_j / kappa),   Sigma_j ~ InvWishart(nu, Psi)

(E[Sigma] = Psi / (nu - K - 1)). With n members, mean abar and scatter
S = sum (a_i - abar)(a_i - abar)^T, integrating y and Sigma out gives (docs/model.md §3.2)

    kappa_n = kappa + n,   nu_n = nu + n,
    Psi_n = Psi + S + kappa n / kappa_n (abar - mu)(abar - mu)^T
          = Psi + sum d_i d_i^T - (sum d_i)(sum d_i)^T / kappa_n,      d_i = a_i - mu
    log p(S) = -(n K / 2) log pi + log Gamma_K(nu_n / 2) - log Gamma_K(nu / 2)
               + (nu / 2) log|Psi| - (nu_n / 2) log|Psi_n| + (K / 2) log(kappa / kappa_n).

With K = 1 this is the paper's (corrected) NIG evidence with alpha = nu / 2 and
beta = Psi / 2. The posterior predictive of one more visit of S is a
multivariate Student t with nu_n - K + 1 degrees of freedom, location
mu_n = (kappa mu + n abar) / kappa_n and shape matrix
Psi_n (kappa_n + 1) / (kappa_n (nu_n - K + 1)); its one-dimensional marginals give
the PIT values of :func:`ptm.appearance.predictive_pit`.

    >>> from ptm import Dataset, JointAppearanceModel
    >>> from ptm.appearance import pair_log_bayes_factor
    >>> model = JointAppearanceModel(mu=[0.3, 0.1], kappa=0.1, nu=5.0, psi=[[4e-4, 3e-4], [3e-4, 4e-4]])
    >>> term = model.bind(Dataset(signatures=[[0.31, 0.11], [0.29, 0.09], [0.40, 0.02]]))
    >>> round(pair_log_bayes_factor(term, 0, 1), 2), round(pair_log_bayes_factor(term, 0, 2), 2)
    (0.55, -5.35)

Fit on labelled calibration runs (never the run you score):
``JointAppearanceModel.fit([run_a, run_b])``; then use it like any model:
``Posterior(dataset, PoissonPrior(3.0), [model])``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats
from scipy.optimize import minimize
from scipy.special import digamma, multigammaln

from ._validation import finite_array, number, positive
from .appearance import HYPERPARAMETER_RANGE, calibration_groups
from .partitions import Partition

__all__ = ["JointAppearanceModel", "JointAppearanceTerm", "MultivariateStudentT", "PlaceStatistics", "FitParametrisation"]

_LOG_PI = math.log(math.pi)


class JointAppearanceModel:
    """Normal-Inverse-Wishart hyperparameters of the appearance K-vector; ``bind(dataset)`` gives the term.

    Parameters
    ----------
    mu : (K,) array (a scalar is broadcast to K)
        Prior mean of a place's true signature.
    kappa : float > 0
        How many visits' worth of information the prior mean carries.
    nu : float > K - 1
        Inverse-Wishart degrees of freedom: small nu lets the within-place
        covariance differ strongly from place to place.
    psi : (K, K) symmetric positive definite array
        Inverse-Wishart scale; E[Sigma] = psi / (nu - K - 1) when nu > K + 1.

    ``shrinkage`` and ``fit_info`` are set by :meth:`fit` (None otherwise).
    """

    def __init__(self, mu, kappa, nu, psi):
        psi = finite_array("psi", psi)
        if psi.ndim != 2 or psi.shape[0] != psi.shape[1] or psi.shape[0] < 1:
            raise ValueError(f"psi must be a square (K, K) matrix, got shape {psi.shape}")
        width = psi.shape[0]
        if not np.allclose(psi, psi.T, rtol=1e-10, atol=1e-14 * np.max(np.abs(psi))):
            raise ValueError("psi must be symmetric")
        try:
            np.linalg.cholesky(psi)
        except np.linalg.LinAlgError:
            raise ValueError(f"psi must be positive definite; its eigenvalues are {np.linalg.eigvalsh(psi)}") from None
        mu = finite_array("mu", mu)
        if mu.ndim == 0:
            mu = np.full(width, float(mu))
        if mu.shape != (width,):
            raise ValueError(f"mu must have length K={width} (the size of psi), got shape {mu.shape}")
        if np.any(np.abs(mu) > HYPERPARAMETER_RANGE[1]):
            raise ValueError(f"mu must lie within +-{HYPERPARAMETER_RANGE[1]:g}, got {mu!r}")
        nu_value = number("nu", nu)
        if not width - 1 < nu_value <= HYPERPARAMETER_RANGE[1]:
            raise ValueError(f"nu must be a finite number > K - 1 = {width - 1} and at most "
                             f"{HYPERPARAMETER_RANGE[1]:g}, got {nu!r}")
        nu = nu_value
        self.mu = mu
        self.kappa = positive("kappa", kappa, HYPERPARAMETER_RANGE)
        self.nu = nu
        self.psi = 0.5 * (psi + psi.T)
        self.shrinkage: float | None = None
        self.fit_info: dict | None = None

    @property
    def k(self) -> int:
        """Length K of the signature vector."""
        return self.mu.shape[0]

    def bind(self, dataset) -> "JointAppearanceTerm":
        if dataset.signatures is None:
            raise ValueError("the appearance model needs a dataset with signatures")
        width = dataset.signatures.shape[1]
        if width != self.k:
            raise ValueError(f"signatures have K={width} components but the model (mu, psi) has K={self.k}")
        return JointAppearanceTerm(self, dataset.signatures)

    def log_evidence(self, signatures) -> float:
        """log p(S) of one set given as an (n, K) array of its signatures (n >= 0)."""
        signatures = finite_array("signatures", signatures, ndim=2)
        if signatures.shape[1] != self.k:
            raise ValueError(f"signatures have K={signatures.shape[1]} components, the model has K={self.k}")
        if signatures.shape[0] == 0:
            return 0.0
        return JointAppearanceTerm(self, signatures).block_log_likelihood(range(signatures.shape[0]))

    @classmethod
    def fit(cls, datasets, shrinkage="auto", max_dof: float = 20.0) -> "JointAppearanceModel":
        """Empirical Bayes: (mu, kappa, nu, psi) maximising the summed evidence of the
        ground-truth partitions of labelled calibration datasets.

        The fit runs on signatures standardised per component (the model is
        affine-equivariant: mu and psi transform back exactly, kappa and nu are
        unchanged), with L-BFGS-B and the analytic gradient over mu, log kappa,
        log(nu - K + 1) and psi.

        Parameters
        ----------
        datasets : Dataset or list of Dataset
            With ``signatures`` and ``labels``. Never the data you then score.
        shrinkage : "auto" or float in [0, 1]
            How psi is parametrised. With lambda = 0, psi is free (its Cholesky
            factor, log diagonal): K (K + 1) / 2 covariance parameters. With
            lambda > 0, psi = D R_lambda D with free per-component scales D and
            the correlation fixed to R_lambda = (1 - lambda) R + lambda I, R the
            pooled within-place correlation of the calibration set (shrunk
            towards the diagonal). "auto" takes lambda = 0 when the calibration
            set has at least K (K + 1) / 2 within-place degrees of freedom
            (sum over places of visits - 1), and otherwise the Ledoit-Wolf
            intensity of R towards I. The lambda used is ``model.shrinkage``.
        max_dof : float
            Upper bound on nu - K + 1, the prior predictive's degrees of freedom
            (as ``AppearanceModel.fit``'s max_alpha: unbounded, calibration
            places sharing one noise level drive nu to infinity, and the
            predictive of a new visit becomes overconfident).

        Raises
        ------
        ValueError
            No labelled dataset, no place visited twice, a signature component
            constant over the calibration set (named), linearly dependent
            components, too few degrees of freedom for ``shrinkage=0``.
        RuntimeError
            The optimiser did not converge (after one restart from where it stopped).
        """
        max_dof = positive("max_dof", max_dof, HYPERPARAMETER_RANGE)
        groups = calibration_groups(datasets)
        return _fit(cls, groups, shrinkage, max_dof)

    def __repr__(self) -> str:
        return (f"JointAppearanceModel(mu={np.array2string(self.mu, precision=4)}, kappa={self.kappa:.4g}, "
                f"nu={self.nu:.4g}, psi={np.array2string(self.psi, precision=4)})")


class JointAppearanceTerm:
    """The joint appearance likelihood bound to one dataset's signatures; decomposes over sets."""

    name = "appearance"

    def __init__(self, model: JointAppearanceModel, signatures: np.ndarray):
        self.model = model
        self.signatures = signatures
        self._width = model.k
        self._centred = signatures - model.mu
        self._outer = self._centred[:, :, None] * self._centred[:, None, :]
        self._psi = model.psi
        self._half_nu_log_det_psi = 0.5 * model.nu * _log_det(model.psi)
        self._constant_by_size: dict[int, float] = {}

    def _constant(self, n: int) -> float:
        """The part of log p(S) that depends on the set size only."""
        value = self._constant_by_size.get(n)
        if value is None:
            model, width = self.model, self._width
            value = (-0.5 * n * width * _LOG_PI + multigammaln(0.5 * (model.nu + n), width)
                     - multigammaln(0.5 * model.nu, width) + self._half_nu_log_det_psi
                     + 0.5 * width * math.log(model.kappa / (model.kappa + n)))
            self._constant_by_size[n] = value
        return value

    def _posterior_scale(self, members: list) -> tuple[int, np.ndarray, np.ndarray]:
        """(n, sum of d_i, Psi_n) for the set ``members``."""
        n = len(members)
        if n == 0:
            return 0, np.zeros(self._width), self._psi
        if n == 1:
            total, squares = self._centred[members[0]], self._outer[members[0]]
        else:
            total, squares = self._centred[members].sum(axis=0), self._outer[members].sum(axis=0)
        return n, total, self._psi + squares - np.outer(total, total) / (self.model.kappa + n)

    def block_log_likelihood(self, block) -> float:
        """log p(S) for the set of detections ``block``."""
        n, _, psi_n = self._posterior_scale(list(block))
        return float(self._constant(n) - 0.5 * (self.model.nu + n) * _log_det(psi_n))

    def log_likelihood(self, partition: Partition) -> float:
        return sum(self.block_log_likelihood(block) for block in partition.blocks)

    def predictive(self, given=()) -> "MultivariateStudentT":
        """Posterior predictive of one more visit of the set ``given`` (the prior predictive if empty)."""
        n, total, psi_n = self._posterior_scale(list(given))
        kappa_n = self.model.kappa + n
        dof = self.model.nu + n - self._width + 1.0
        return MultivariateStudentT(dof=dof, loc=self.model.mu + total / kappa_n,
                                    shape=psi_n * (kappa_n + 1.0) / (kappa_n * dof))


class MultivariateStudentT:
    """Multivariate Student t: ``dof`` degrees of freedom, location ``loc``, shape matrix ``shape``
    (a thin wrapper of :data:`scipy.stats.multivariate_t` with the per-component marginal CDFs)."""

    def __init__(self, dof: float, loc, shape):
        self.dof = float(dof)
        self.loc = np.asarray(loc, dtype=float)
        self.shape = np.asarray(shape, dtype=float)

    def logpdf(self, x) -> float:
        """Log density of one K-vector (:data:`scipy.stats.multivariate_t`)."""
        return float(stats.multivariate_t(self.loc, self.shape, df=self.dof).logpdf(np.asarray(x, dtype=float)))

    def marginal_cdf(self, x) -> np.ndarray:
        """Per-component marginal CDF of one K-vector: its probability-integral-transform values.

        Each marginal of a multivariate t is a univariate t with the same
        degrees of freedom, location loc_k and scale sqrt(shape_kk).
        """
        return stats.t.cdf(np.asarray(x, dtype=float), self.dof, self.loc, np.sqrt(np.diag(self.shape)))

    def __repr__(self) -> str:
        return f"MultivariateStudentT(dof={self.dof:.4g}, loc={self.loc}, shape={self.shape})"


def _log_det(matrix: np.ndarray) -> float:
    try:
        cholesky = np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        raise ValueError("a posterior scale matrix Psi_n is not positive definite: psi is too badly "
                         "conditioned for these signatures (rescale them, or refit)") from None
    return 2.0 * float(np.sum(np.log(np.diag(cholesky))))


# -- empirical Bayes -------------------------------------------------------------------------------


class PlaceStatistics:
    """Per-place sufficient statistics of (standardised) calibration signatures, stacked for the vectorised
    evidence of :meth:`JointAppearanceModel.fit`: visit counts ``n`` (G,), means ``mean`` (G, K), scatter
    matrices ``scatter`` (G, K, K), the pooled ``deviations`` from the place means and their degrees of
    freedom ``dof`` = sum (n - 1).

    Parameters
    ----------
    groups : list of (n_g, K) arrays
        The signatures of each calibration place (:func:`ptm.appearance.calibration_groups`).
    """

    def __init__(self, groups: list[np.ndarray]):
        self.n = np.array([group.shape[0] for group in groups], dtype=float)
        self.mean = np.array([group.mean(axis=0) for group in groups])
        deviations = [group - group.mean(axis=0) for group in groups]
        self.scatter = np.array([d.T @ d for d in deviations])
        self.deviations = np.concatenate(deviations)
        self.width = self.mean.shape[1]
        self.dof = int(np.sum(self.n - 1.0))
        self.constant = float(np.sum(-0.5 * self.n * self.width * _LOG_PI))


def _evidence_and_gradient(mu, kappa, nu, psi, data: PlaceStatistics):
    """Summed log evidence of the places and its gradient in (mu, kappa, nu, psi)."""
    width, n = data.width, data.n
    d = data.mean - mu
    c = kappa * n / (kappa + n)
    psi_n = psi + data.scatter + c[:, None, None] * d[:, :, None] * d[:, None, :]
    chol_n = np.linalg.cholesky(psi_n)
    log_det_n = 2.0 * np.sum(np.log(np.diagonal(chol_n, axis1=1, axis2=2)), axis=1)
    log_det = 2.0 * float(np.sum(np.log(np.diag(np.linalg.cholesky(psi)))))
    nu_n = nu + n
    value = (data.constant + float(np.sum(multigammaln(0.5 * nu_n, width))) - n.size * multigammaln(0.5 * nu, width)
             + 0.5 * nu * log_det * n.size - float(np.dot(0.5 * nu_n, log_det_n))
             + 0.5 * width * float(np.sum(np.log(kappa / (kappa + n)))))
    inv_n = np.linalg.inv(psi_n)
    inv_n = 0.5 * (inv_n + np.transpose(inv_n, (0, 2, 1)))
    inv_d = np.einsum("gij,gj->gi", inv_n, d)
    grad_mu = np.sum((nu_n * c)[:, None] * inv_d, axis=0)
    quad = np.einsum("gi,gi->g", d, inv_d)
    grad_kappa = float(np.sum(-0.5 * nu_n * (n / (kappa + n)) ** 2 * quad + 0.5 * width * (1.0 / kappa - 1.0 / (kappa + n))))
    half = 0.5 * np.arange(width)
    grad_nu = float(0.5 * np.sum(digamma(0.5 * nu_n[:, None] - half)) - 0.5 * n.size * np.sum(digamma(0.5 * nu - half))
                    + 0.5 * n.size * log_det - 0.5 * np.sum(log_det_n))
    inv = np.linalg.inv(psi)
    grad_psi = 0.5 * nu * n.size * 0.5 * (inv + inv.T) - np.einsum("g,gij->ij", 0.5 * nu_n, inv_n)
    return value, grad_mu, grad_kappa, grad_nu, grad_psi


class FitParametrisation:
    """Unconstrained vector theta <-> (mu, kappa, nu, psi) for the optimiser of :meth:`JointAppearanceModel.fit`,
    with the chain rule for the gradient.

    theta = (mu, log kappa, log(nu - K + 1), psi parameters): with ``correlation`` None the psi
    parameters are the lower triangle of its Cholesky factor (log on the diagonal); with a fixed
    correlation matrix R they are the log scales D of psi = D R D.
    :meth:`objective` is the negative summed log evidence times ``weight`` and its gradient in theta.
    """

    def __init__(self, width: int, correlation: np.ndarray | None):
        self.width = width
        self.correlation = correlation  # None: free Cholesky factor; else psi = D R D
        self.rows, self.cols = np.tril_indices(width)
        self.diagonal = self.rows == self.cols
        self.n_psi = width if correlation is not None else self.rows.size

    def unpack(self, theta):
        """(mu, kappa, nu, psi, extra): extra is the Cholesky factor of psi, or the scales D."""
        width = self.width
        mu = theta[:width]
        kappa = math.exp(theta[width])
        nu = width - 1.0 + math.exp(theta[width + 1])
        psi_params = theta[width + 2:]
        if self.correlation is not None:
            scales = np.exp(psi_params)
            return mu, kappa, nu, scales[:, None] * self.correlation * scales[None, :], scales
        factor = np.zeros((width, width))
        factor[self.rows, self.cols] = np.where(self.diagonal, np.exp(psi_params), psi_params)
        return mu, kappa, nu, factor @ factor.T, factor

    def pack(self, mu, kappa, nu, psi) -> np.ndarray:
        """theta of (mu, kappa, nu, psi); with a fixed correlation only the diagonal of psi is kept."""
        if self.correlation is not None:
            psi_params = 0.5 * np.log(np.diag(psi))
        else:
            factor = np.linalg.cholesky(psi)
            psi_params = np.where(self.diagonal, np.log(np.abs(factor[self.rows, self.cols]) + 1e-300),
                                  factor[self.rows, self.cols])
        return np.concatenate([mu, [math.log(kappa), math.log(nu - self.width + 1.0)], psi_params])

    def objective(self, theta, data: PlaceStatistics, weight: float):
        """(-weight * log evidence, its gradient in theta); (inf, 0) where psi_n is not positive definite."""
        mu, kappa, nu, psi, extra = self.unpack(theta)
        try:
            value, g_mu, g_kappa, g_nu, g_psi = _evidence_and_gradient(mu, kappa, nu, psi, data)
        except np.linalg.LinAlgError:
            return math.inf, np.zeros_like(theta)
        if self.correlation is not None:
            g_params = 2.0 * np.sum(g_psi * psi, axis=1)
        else:
            g_factor = 2.0 * g_psi @ extra
            g_params = np.where(self.diagonal, g_factor[self.rows, self.cols] * extra[self.rows, self.cols],
                                g_factor[self.rows, self.cols])
        gradient = np.concatenate([g_mu, [g_kappa * kappa, g_nu * (nu - self.width + 1.0)], g_params])
        return -value * weight, -gradient * weight


def _standardise(groups: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-component centre and scale of the calibration set; refuse linearly dependent components."""
    values = np.concatenate(groups)
    if values.shape[0] < values.shape[1] + 1:
        raise ValueError(f"the calibration set has {values.shape[0]} signatures for K={values.shape[1]} components: "
                         f"at least K + 1 are needed to span the signature space")
    centre, scale = values.mean(axis=0), values.std(axis=0)  # calibration_groups refused constant components
    standard = (values - centre) / scale
    eigenvalues, eigenvectors = np.linalg.eigh(standard.T @ standard / values.shape[0])
    if eigenvalues[0] < 1e-10 * eigenvalues[-1]:
        involved = [k for k in np.argsort(-np.abs(eigenvectors[:, 0])) if abs(eigenvectors[k, 0]) > 1e-3]
        raise ValueError(f"signature components {sorted(int(k) for k in involved)} are linearly dependent over the "
                         "calibration set: their joint covariance is singular; drop one of them")
    return centre, scale


def _ledoit_wolf_correlation(data: PlaceStatistics) -> tuple[np.ndarray, float]:
    """Pooled within-place correlation R and the Ledoit-Wolf (2004) intensity of shrinking it towards I."""
    sd = np.sqrt(np.sum(data.deviations ** 2, axis=0) / data.dof)
    sd = np.where(sd > 0, sd, 1.0)
    z = data.deviations / sd
    correlation = z.T @ z / data.dof
    np.fill_diagonal(correlation, 1.0)
    distance = float(np.sum((correlation - np.eye(data.width)) ** 2))
    if distance == 0.0:
        return correlation, 1.0
    spread = float(np.sum((z[:, :, None] * z[:, None, :] - correlation) ** 2)) / data.dof ** 2
    return correlation, min(1.0, spread / distance)


def _fit(cls, groups, shrinkage, max_dof: float) -> JointAppearanceModel:
    width = groups[0].shape[1]
    centre, scale = _standardise(groups)
    data = PlaceStatistics([(group - centre) / scale for group in groups])
    n_covariance = width * (width + 1) // 2
    if isinstance(shrinkage, str):
        if shrinkage != "auto":
            raise ValueError(f"shrinkage must be 'auto' or a number in [0, 1], got {shrinkage!r}")
        lam = None if data.dof >= n_covariance else "ledoit_wolf"
    else:
        lam = float(shrinkage)
        if not 0.0 <= lam <= 1.0:
            raise ValueError(f"shrinkage must be 'auto' or a number in [0, 1], got {shrinkage!r}")
        if lam == 0.0:
            if data.dof < n_covariance:
                raise ValueError(
                    f"too few revisits to fit a full covariance: the calibration set has {data.dof} within-place "
                    f"degrees of freedom (sum over places of visits - 1) for K(K+1)/2 = {n_covariance} covariance "
                    "parameters; use shrinkage='auto' (Ledoit-Wolf towards the diagonal) or more calibration runs")
            lam = None
    correlation = None
    if lam is not None:
        pooled, intensity = _ledoit_wolf_correlation(data)
        lam = intensity if lam == "ledoit_wolf" else lam
        correlation = (1.0 - lam) * pooled + lam * np.eye(width)
        try:
            np.linalg.cholesky(correlation)
        except np.linalg.LinAlgError:
            raise ValueError(f"the shrunk within-place correlation (shrinkage {lam:.3g}) is singular; "
                             "use a larger shrinkage or more calibration runs") from None
    parametrisation = FitParametrisation(width, correlation)

    # start: mu at the mean of place means, psi = (nu - K - 1) x pooled within-place covariance
    within = np.diag(np.maximum(np.sum(data.deviations ** 2, axis=0) / data.dof, 1e-3))
    if correlation is not None:
        within = np.sqrt(within) @ correlation @ np.sqrt(within)
    elif data.dof >= n_covariance:
        pooled = data.deviations.T @ data.deviations / data.dof
        within = 0.5 * (pooled + within) if np.linalg.eigvalsh(pooled)[0] <= 1e-6 else pooled
    nu0 = width - 1.0 + min(4.0, max_dof)
    mu0 = data.mean.mean(axis=0)
    between = float(np.trace(np.cov(data.mean.T))) if data.n.size > 1 else 1.0
    kappa0 = float(np.clip(np.trace(within) / max(between, 1e-3 * np.trace(within)), 1e-3, 1e3))
    start = parametrisation.pack(mu0, kappa0, nu0, max(nu0 - width - 1.0, 0.5) * within)
    bounds = ([(None, None)] * width + [(math.log(1e-4), math.log(1e4)), (math.log(1e-2), math.log(max_dof))]
              + [((None, None) if not diagonal else (value - 25.0, value + 25.0))
                 for diagonal, value in zip(np.ones(width, bool) if correlation is not None else parametrisation.diagonal,
                                            start[width + 2:])])
    weight = 1.0 / float(np.sum(data.n))
    attempts = []
    theta = start
    for _ in range(2):  # one restart from where a failed run stopped
        result = minimize(parametrisation.objective, theta, args=(data, weight), jac=True, method="L-BFGS-B",
                          bounds=bounds, options={"maxiter": 5000})
        attempts.append(str(result.message))
        theta = result.x
        if result.success and np.isfinite(result.fun):
            break
    else:
        raise RuntimeError(f"JointAppearanceModel.fit: the optimiser did not converge ({'; '.join(attempts)}); "
                           "check the calibration data, or pass a larger shrinkage")
    mu_s, kappa, nu, psi_s, _ = parametrisation.unpack(theta)
    model = cls(centre + scale * mu_s, kappa, nu, scale[:, None] * psi_s * scale[None, :])
    model.shrinkage = 0.0 if lam is None else float(lam)
    at_bounds = [name for name, index in (("kappa", width), ("nu", width + 1))
                 if any(b is not None and abs(theta[index] - b) < 1e-8 for b in bounds[index])]
    model.fit_info = {
        "places": int(data.n.size), "signatures": int(np.sum(data.n)), "within_place_dof": data.dof,
        "covariance_parameters": n_covariance if lam is None else width,
        "log_evidence": float(-result.fun / weight - np.sum(data.n) * np.sum(np.log(scale))),
        "optimiser": attempts, "iterations": int(result.nit), "at_bounds": at_bounds,
    }
    return model
