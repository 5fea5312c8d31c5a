"""The joint (Normal-Inverse-Wishart) appearance model (docs/model.md §3.2, "components are not independent").

Evidence checked against independent computations: the chain rule through
scipy's multivariate t (exact identity, rel 1e-10), Monte Carlo over prior
draws (tolerance 4 Monte-Carlo standard errors), and the K = 1 reduction to the
independent NIG model (exact identity, abs 1e-10). The sampler on a
joint-model posterior is held to test_sampler's bound with its harness and
negative control. The empirical-Bayes fit must recover hyperparameters it
generated data from, and refuse degenerate calibration sets by name.
"""

import math

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import approx_fprime
from scipy.special import logsumexp

import ptm
from helpers import PLACE_SIGNATURES, TRUE_LABELS_8
from ptm.appearance_joint import FitParametrisation, PlaceStatistics
from test_sampler import TOLERANCE, SplitMergeWithoutHastingsRatio, total_variation_to_exact, visit_frequencies  # noqa: F401

MU = np.array([0.2, -0.1])
PSI = np.array([[0.09, 0.06], [0.06, 0.08]])
SIGNATURES = np.array([[0.31, -0.05], [0.12, -0.21], [0.45, 0.08], [0.22, -0.02], [0.05, -0.30]])


def joint_term(signatures=SIGNATURES, mu=MU, kappa=0.7, nu=4.5, psi=PSI):
    return ptm.JointAppearanceModel(mu, kappa, nu, psi).bind(ptm.Dataset(signatures=signatures))


def textbook_sequential_log_evidence(signatures, mu, kappa, nu, psi):
    """Sum over members of log t(a_i | a_1..a_{i-1}), by rank-one NIW updates and scipy's multivariate t."""
    width = len(mu)
    total = 0.0
    for a in signatures:
        dof = nu - width + 1.0
        total += stats.multivariate_t.logpdf(a, loc=mu, shape=psi * (kappa + 1.0) / (kappa * dof), df=dof)
        psi = psi + kappa / (kappa + 1.0) * np.outer(a - mu, a - mu)
        mu = (kappa * mu + a) / (kappa + 1.0)
        kappa, nu = kappa + 1.0, nu + 1.0
    return total


@pytest.mark.parametrize("block", [(0,), (1, 3), (0, 2, 4), (0, 1, 2, 3, 4)])
def test_evidence_equals_the_chain_rule_of_predictive_densities(block):
    term = joint_term()
    expected = textbook_sequential_log_evidence(SIGNATURES[list(block)], MU, 0.7, 4.5, PSI)
    assert term.block_log_likelihood(block) == pytest.approx(expected, rel=1e-10)
    # the library's own predictive satisfies the same identity
    chained = sum(ptm.appearance.predictive_log_density(term, block[i], block[:i]) for i in range(len(block)))
    assert chained == pytest.approx(expected, rel=1e-10)


def test_evidence_matches_monte_carlo_over_prior_draws():
    """log mean_s prod_i N(a_i | y_s, Sigma_s) with (y_s, Sigma_s) ~ NIW, K = 2, n = 3.

    Measured: closed form -5.5494, MC -5.5513 with standard error 0.0031 (0.6 SE apart).
    """
    mu, kappa, nu, psi = np.zeros(2), 1.0, 5.0, 2.0 * np.array([[1.0, 0.6], [0.6, 1.0]])
    values = np.array([[0.3, 0.1], [-0.5, -0.2], [0.8, 1.0]])
    rng = np.random.default_rng(2024)
    draws = 400_000
    sigmas = stats.invwishart(df=nu, scale=psi).rvs(size=draws, random_state=rng)
    factors = np.linalg.cholesky(sigmas)
    means = mu + np.einsum("sij,sj->si", factors, rng.standard_normal((draws, 2))) / math.sqrt(kappa)
    whitened = np.linalg.solve(factors[:, None], (values[None, :, :] - means[:, None, :])[..., None])[..., 0]
    log_weights = (-0.5 * np.sum(whitened ** 2, axis=(1, 2)) - 3 * np.sum(np.log(np.diagonal(factors, axis1=1, axis2=2)), axis=1)
                   - 3 * math.log(2 * math.pi))
    estimate = logsumexp(log_weights) - math.log(draws)
    weights = np.exp(log_weights - log_weights.max())
    standard_error = weights.std() / (weights.mean() * math.sqrt(draws))
    closed_form = ptm.JointAppearanceModel(mu, kappa, nu, psi).log_evidence(values)
    assert standard_error < 0.01
    assert abs(closed_form - estimate) < 4 * standard_error


def test_one_component_reduces_to_the_independent_model():
    values = np.array([[0.2], [0.5], [0.1], [0.3], [0.45]])
    dataset = ptm.Dataset(signatures=values)
    mu, kappa, nu, psi = 0.25, 0.5, 3.0, 0.04
    joint = ptm.JointAppearanceModel([mu], kappa, nu, [[psi]]).bind(dataset)
    independent = ptm.AppearanceModel(mu, kappa, nu / 2, psi / 2).bind(dataset)
    for block in [(0,), (1, 4), (0, 2, 3), (0, 1, 2, 3, 4)]:
        assert joint.block_log_likelihood(block) == pytest.approx(independent.block_log_likelihood(block), abs=1e-10)
    for held_out, given in [(2, ()), (2, (0, 1)), (4, (0, 1, 2, 3))]:
        np.testing.assert_allclose(ptm.appearance.predictive_pit(joint, held_out, given),
                                   ptm.appearance.predictive_pit(independent, held_out, given), rtol=1e-10)


def test_independent_models_predictive_obeys_its_chain_rule():
    term = ptm.AppearanceModel(0.1, np.array([0.5, 2.0]), 2.5, 0.03).bind(ptm.Dataset(signatures=SIGNATURES))
    block = (0, 1, 3, 4)
    chained = sum(ptm.appearance.predictive_log_density(term, block[i], block[:i]) for i in range(len(block)))
    assert chained == pytest.approx(term.block_log_likelihood(block), rel=1e-10)


def test_pair_bayes_factor_and_pit_definitions():
    term = joint_term()
    factors = ptm.appearance.pairwise_log_bayes_factors(term)
    expected = term.block_log_likelihood((1, 3)) - term.block_log_likelihood((1,)) - term.block_log_likelihood((3,))
    assert ptm.appearance.pair_log_bayes_factor(term, 3, 1) == pytest.approx(expected, rel=1e-12)
    assert factors[1, 3] == factors[3, 1] == pytest.approx(expected, rel=1e-12)
    assert np.all(np.isnan(np.diag(factors)))
    predictive = term.predictive((0, 2))
    marginal_scale = np.sqrt(np.diag(predictive.shape))
    np.testing.assert_allclose(ptm.appearance.predictive_pit(term, 4, (2, 0)),
                               stats.t.cdf(SIGNATURES[4], predictive.dof, predictive.loc, marginal_scale), rtol=1e-12)
    pit = ptm.appearance.leave_one_out_pit(term, [0, 1, 0, 0, 2])
    assert np.all(np.isnan(pit[[1, 4]])) and np.all((pit[[0, 2, 3]] > 0) & (pit[[0, 2, 3]] < 1))
    np.testing.assert_allclose(pit[3], ptm.appearance.predictive_pit(term, 3, (0, 2)), rtol=1e-12)
    with pytest.raises(ValueError, match="two different detections"):
        ptm.appearance.pair_log_bayes_factor(term, 2, 2)
    with pytest.raises(ValueError, match="held_out"):
        ptm.appearance.predictive_pit(term, 2, (0, 2))
    with pytest.raises(ValueError, match="paper_eq19"):
        ptm.AppearanceModel(0.1, 1.0, 2.5, 0.03, evidence="paper_eq19").bind(
            ptm.Dataset(signatures=SIGNATURES)).predictive((0,))


def draw_from_the_model(rng, mu, kappa, nu, psi, places, visits):
    """A labelled dataset drawn from the NIW model itself."""
    sigmas = stats.invwishart(df=nu, scale=psi).rvs(size=places, random_state=rng)
    labels = np.repeat(np.arange(places), visits)
    rows = [rng.multivariate_normal(rng.multivariate_normal(mu, sigma / kappa), sigma, size=visits) for sigma in sigmas]
    return ptm.Dataset(signatures=np.concatenate(rows), labels=labels)


def test_held_out_pit_is_uniform_under_the_model():
    """One held-out visit per place given the others: exactly Uniform(0, 1) when the data follow the model."""
    rng = np.random.default_rng(5)
    mu, kappa, nu, psi = MU, 0.2, 4.0, PSI
    dataset = draw_from_the_model(rng, mu, kappa, nu, psi, places=400, visits=3)
    term = ptm.JointAppearanceModel(mu, kappa, nu, psi).bind(dataset)
    pit = np.array([ptm.appearance.predictive_pit(term, 3 * p + 2, (3 * p, 3 * p + 1)) for p in range(400)])
    for k in range(2):
        assert stats.kstest(pit[:, k], "uniform").pvalue > 0.01
    # negative control: psi 16x too small, an overconfident predictive (measured KS p 7e-6 and 1e-6,
    # 27 % of PIT values in the outer 10 %; the right model: p 0.76 and 0.84, 9 %)
    wrong = ptm.JointAppearanceModel(mu, kappa, nu, psi / 16.0).bind(dataset)
    pit_wrong = np.array([ptm.appearance.predictive_pit(wrong, 3 * p + 2, (3 * p, 3 * p + 1)) for p in range(400)])
    for k in range(2):
        assert stats.kstest(pit_wrong[:, k], "uniform").pvalue < 1e-4
    assert np.mean((pit_wrong < 0.05) | (pit_wrong > 0.95)) > 0.2


# -- the sampler on a joint-model posterior ------------------------------------------------------


def joint_posterior(n: int = 8, seed: int = 0) -> ptm.Posterior:
    """test_sampler's three nearby places, noise moved by one latent factor (within-place correlation 0.95)."""
    rng = np.random.default_rng(seed)
    labels = TRUE_LABELS_8[:n]
    covariance = 0.02 ** 2 * np.array([[1.0, 0.95], [0.95, 1.0]])
    signatures = PLACE_SIGNATURES[labels] + rng.multivariate_normal(np.zeros(2), covariance, size=n)
    model = ptm.JointAppearanceModel(mu=[0.3, 0.1], kappa=0.05, nu=2.5, psi=0.5 * covariance)
    return ptm.Posterior(ptm.Dataset(signatures=signatures, labels=labels), ptm.PoissonPrior(3.0), [model])


def test_joint_posterior_is_spread_out_and_memoised():
    posterior = joint_posterior()
    exact = ptm.exact_posterior(posterior)
    assert exact.entropy() > 1.4  # measured 1.60 nats, top partition 0.43: the TV check below has teeth
    partition = ptm.Partition.from_labels(TRUE_LABELS_8)
    assert posterior.log_likelihoods(partition)["appearance"] == pytest.approx(
        sum(posterior.block_score(block) for block in partition.blocks))


def test_sampler_matches_exact_posterior_with_the_joint_model():
    # measured TV 0.015, 0.021, 0.019 over seeds 7, 8, 9 (default moves); bound shared with test_sampler
    assert total_variation_to_exact(joint_posterior(), "default", seed=7) < TOLERANCE


def test_negative_control_fails_with_the_joint_model():
    # measured TV 0.249 and 0.245 (seeds 7, 8) with the Hastings ratio dropped: > 3 x 0.06
    assert total_variation_to_exact(joint_posterior(), [SplitMergeWithoutHastingsRatio()], seed=7) > 3 * TOLERANCE


# -- empirical Bayes ------------------------------------------------------------------------------------


def test_fit_gradient_matches_finite_differences():
    rng = np.random.default_rng(3)
    dataset = draw_from_the_model(rng, MU, 0.3, 5.0, PSI, places=20, visits=3)
    groups = [dataset.signatures[list(block)] for block in ptm.Partition.from_labels(dataset.labels).blocks]
    data = PlaceStatistics(groups)
    for correlation in (None, np.array([[1.0, 0.4], [0.4, 1.0]])):
        parametrisation = FitParametrisation(2, correlation)
        theta = parametrisation.pack(MU + 0.05, 0.5, 6.0, PSI if correlation is None else np.diag(np.diag(PSI)))
        analytic = parametrisation.objective(theta, data, 1.0)[1]
        numeric = approx_fprime(theta, lambda t: parametrisation.objective(t, data, 1.0)[0], 1e-7)
        np.testing.assert_allclose(analytic, numeric, rtol=1e-4, atol=1e-4)


def test_fit_refuses_an_optimiser_that_never_converges(monkeypatch):
    import ptm.appearance_joint

    real = ptm.appearance_joint.minimize

    def failing(*args, **kwargs):  # every run stops early and says so
        result = real(*args, **{**kwargs, "options": {"maxiter": 2}})
        result.success, result.message = False, "STOP: TOTAL NO. OF ITERATIONS REACHED LIMIT (simulated)"
        return result

    monkeypatch.setattr(ptm.appearance_joint, "minimize", failing)
    dataset = draw_from_the_model(np.random.default_rng(3), MU, 0.3, 5.0, PSI, places=20, visits=3)
    with pytest.raises(RuntimeError, match="did not converge.*ITERATIONS"):
        ptm.JointAppearanceModel.fit([dataset])


def test_fit_recovers_known_hyperparameters():
    """Correlation 0.9 between two components; 4 runs x 60 places x 4 visits drawn from the model.

    Measured: nu 6.65 (true 7), kappa 0.046 (0.05), E[Sigma] correlation 0.903,
    standard deviations +2.4 % and +2.2 %, mu within 0.0023.
    """
    rng = np.random.default_rng(11)
    sd, rho, nu, kappa = np.array([0.02, 0.03]), 0.9, 7.0, 0.05
    mu = np.array([0.3, 0.1])
    mean_sigma = np.outer(sd, sd) * np.array([[1.0, rho], [rho, 1.0]])
    psi = (nu - 3.0) * mean_sigma
    datasets = [draw_from_the_model(rng, mu, kappa, nu, psi, places=60, visits=4) for _ in range(4)]
    model = ptm.JointAppearanceModel.fit(datasets)
    assert model.shrinkage == 0.0 and model.fit_info["at_bounds"] == []
    fitted_sigma = model.psi / (model.nu - 3.0)
    fitted_sd = np.sqrt(np.diag(fitted_sigma))
    assert fitted_sigma[0, 1] / np.prod(fitted_sd) == pytest.approx(rho, abs=0.03)
    np.testing.assert_allclose(fitted_sd, sd, rtol=0.12)
    assert model.nu == pytest.approx(nu, rel=0.25)
    assert model.kappa == pytest.approx(kappa, rel=0.35)
    np.testing.assert_allclose(model.mu, mu, atol=0.01)


def test_joint_model_beats_the_independent_one_on_correlated_data():
    """One latent factor moves both components (correlation 0.97); spreads differ between places (nu = 5).

    Both models fitted on two calibration runs, scored on a held-out run.
    Measured (seed 21): log evidence of the true partition: joint 826.8,
    generating model 829.5, independent 585.5; different-place pairs whose
    Bayes factor favours "same place": joint 11.4 %, independent 28.9 %.
    """
    rng = np.random.default_rng(21)
    mean_sigma = np.outer([0.02, 0.03], [0.02, 0.03]) * np.array([[1.0, 0.97], [0.97, 1.0]])
    truth = (np.array([0.3, 0.1]), 0.05, 5.0, 2.0 * mean_sigma)  # mu, kappa, nu, psi
    calibration = [draw_from_the_model(rng, *truth, places=30, visits=4) for _ in range(2)]
    held_out = draw_from_the_model(rng, *truth, places=40, visits=4)
    partition = ptm.Partition.from_labels(held_out.labels)
    different_places = np.triu(held_out.labels[:, None] != held_out.labels[None, :], 1)

    def score(model):
        term = model.bind(held_out)
        return term.log_likelihood(partition), np.mean(ptm.appearance.pairwise_log_bayes_factors(term)[different_places] > 0)

    joint_evidence, joint_false_merges = score(ptm.JointAppearanceModel.fit(calibration))
    independent_evidence, independent_false_merges = score(ptm.AppearanceModel.fit(calibration))
    true_evidence, _ = score(ptm.JointAppearanceModel(*truth))
    assert abs(joint_evidence - true_evidence) < 10.0
    assert joint_evidence > independent_evidence + 100.0
    assert joint_false_merges < 0.6 * independent_false_merges


def test_too_few_revisits_are_shrunk_towards_the_diagonal_or_refused():
    rng = np.random.default_rng(1)
    labels = np.array([0, 0, 1, 1, 2, 2, 3, 4, 5])  # 3 within-place degrees of freedom < K(K+1)/2 = 15
    dataset = ptm.Dataset(signatures=rng.normal(0.3, 0.05, size=(9, 5)), labels=labels)
    model = ptm.JointAppearanceModel.fit(dataset)
    assert 0.0 < model.shrinkage <= 1.0
    assert model.fit_info["covariance_parameters"] == 5 and model.fit_info["within_place_dof"] == 3
    assert np.linalg.eigvalsh(model.psi)[0] > 0
    with pytest.raises(ValueError, match="too few revisits"):
        ptm.JointAppearanceModel.fit(dataset, shrinkage=0.0)
    with pytest.raises(ValueError, match="no revisits"):
        ptm.JointAppearanceModel.fit(dataset.replace(labels=np.arange(9)))
    with pytest.raises(ValueError, match="at least K \\+ 1"):
        ptm.JointAppearanceModel.fit(ptm.Dataset(signatures=dataset.signatures[:4], labels=[0, 0, 1, 1]))


def test_explicit_shrinkage_fixes_the_correlation_shape():
    rng = np.random.default_rng(4)
    dataset = draw_from_the_model(rng, MU, 0.3, 6.0, PSI, places=30, visits=3)
    model = ptm.JointAppearanceModel.fit(dataset, shrinkage=1.0)
    assert model.shrinkage == 1.0 and model.psi[0, 1] == 0.0


def test_degenerate_calibration_sets_are_refused_by_name():
    rng = np.random.default_rng(2)
    signatures = rng.normal(0.3, 0.05, size=(12, 3))
    labels = np.repeat(np.arange(4), 3)
    constant = signatures.copy()
    constant[:, 1] = 0.7
    with pytest.raises(ValueError, match="component 1 is constant"):
        ptm.JointAppearanceModel.fit(ptm.Dataset(signatures=constant, labels=labels))
    dependent = signatures.copy()
    dependent[:, 2] = 2.0 * dependent[:, 0] - dependent[:, 1]
    with pytest.raises(ValueError, match="linearly dependent"):
        ptm.JointAppearanceModel.fit(ptm.Dataset(signatures=dependent, labels=labels))
    with pytest.raises(ValueError, match="signatures"):  # non-finite values stop at the Dataset boundary
        ptm.Dataset(signatures=np.where(np.eye(12, 3) > 0, np.nan, signatures), labels=labels)
    with pytest.raises(ValueError, match="calibration dataset 0 needs signatures and labels"):
        ptm.JointAppearanceModel.fit(ptm.Dataset(signatures=signatures))


@pytest.mark.parametrize("field, kwargs", [
    ("psi must be symmetric", dict(psi=[[1.0, 0.5], [0.4, 1.0]])),
    ("psi must be positive definite", dict(psi=[[1.0, 2.0], [2.0, 1.0]])),
    ("psi must be a square", dict(psi=[1.0, 1.0])),
    ("psi contains a non-finite", dict(psi=[[1.0, np.inf], [np.inf, 1.0]])),
    ("nu must be", dict(nu=0.9)),
    ("nu must be", dict(nu=float("inf"))),
    ("kappa", dict(kappa=0.0)),
    ("mu contains a non-finite", dict(mu=[np.nan, 0.0])),
    ("mu must have length K=2", dict(mu=[0.0, 0.0, 0.0])),
])
def test_bad_hyperparameters_are_refused(field, kwargs):
    arguments = dict(mu=[0.0, 0.0], kappa=1.0, nu=3.0, psi=np.eye(2)) | kwargs
    with pytest.raises(ValueError, match=field):
        ptm.JointAppearanceModel(**arguments)


def test_signature_width_must_match_the_model():
    with pytest.raises(ValueError, match="K=3 components but the model .* has K=2"):
        ptm.JointAppearanceModel([0.0, 0.0], 1.0, 3.0, np.eye(2)).bind(ptm.Dataset(signatures=np.ones((4, 3))))
    with pytest.raises(ValueError, match="needs a dataset with signatures"):
        ptm.JointAppearanceModel([0.0, 0.0], 1.0, 3.0, np.eye(2)).bind(ptm.Dataset(labels=[0, 1]))
