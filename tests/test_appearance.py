"""The appearance evidence (docs/model.md §3.2) against direct numerical integration of the model."""

import math

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.optimize import OptimizeResult

from helpers import appearance_posterior
from ptm import AppearanceModel, Dataset, Partition
from ptm.appearance import inverse_gamma_from_mean_variance


def numerical_evidence(values, mu, kappa, alpha, beta):
    """log of the double integral over y and s2 of IG(s2) N(y; mu, s2/kappa) prod N(a; y, s2).

    Trapezoid rule on a dense grid: log s2 on a wide range (Jacobian s2), and for
    each s2 a y grid spanning +-12 standard deviations of where the integrand lives.
    """
    values = np.asarray(values, dtype=float)
    log_variance = np.linspace(-14.0, 6.0, 4001)
    variance = np.exp(log_variance)[:, None]
    centre = (kappa * mu + values.sum()) / (kappa + values.size)
    half_width = 12.0 * np.sqrt(variance / (kappa + values.size))
    y = centre + half_width * np.linspace(-1.0, 1.0, 801)[None, :]
    log_density = (stats.invgamma.logpdf(variance, alpha, scale=beta)
                   + stats.norm.logpdf(y, mu, np.sqrt(variance / kappa))
                   + stats.norm.logpdf(values[None, None, :], y[:, :, None], np.sqrt(variance)[:, :, None]).sum(axis=2))
    over_y = integrate.trapezoid(np.exp(log_density), y, axis=1)
    return math.log(integrate.trapezoid(over_y * variance[:, 0], log_variance))


@pytest.mark.parametrize("values", [[0.9], [0.9, 1.1], [0.7, 1.2, 1.4], [1.5, 1.6, 1.4, 1.55]])
def test_evidence_matches_numerical_integration(values):
    mu, kappa, alpha, beta = 1.0, 0.5, 2.5, 0.1
    term = AppearanceModel(mu, kappa, alpha, beta).bind(Dataset(signatures=np.array(values)[:, None]))
    closed_form = term.block_log_likelihood(tuple(range(len(values))))
    assert closed_form == pytest.approx(numerical_evidence(values, mu, kappa, alpha, beta), abs=1e-5)


def test_papers_printed_formula_is_a_different_function():
    values = np.array([[0.7], [1.2], [1.4]])
    dataset = Dataset(signatures=values)
    corrected = AppearanceModel(1.0, 0.5, 2.5, 0.1).bind(dataset)
    printed = AppearanceModel(1.0, 0.5, 2.5, 0.1, evidence="paper_eq19").bind(dataset)
    merged, split = Partition.from_labels([0, 0, 0]), Partition.from_labels([0, 1, 1])
    corrected_ratio = corrected.log_likelihood(merged) - corrected.log_likelihood(split)
    printed_ratio = printed.log_likelihood(merged) - printed.log_likelihood(split)
    assert abs(corrected_ratio - printed_ratio) > 0.1


def test_components_are_independent_and_hyperparameters_broadcast():
    rng = np.random.default_rng(3)
    signatures = rng.uniform(0.1, 0.5, size=(5, 3))
    kappa = np.array([0.2, 0.5, 1.0])
    full = AppearanceModel(0.3, kappa, 3.0, 0.01).bind(Dataset(signatures=signatures))
    block = (0, 2, 3)
    per_component = sum(
        AppearanceModel(0.3, kappa[k], 3.0, 0.01).bind(Dataset(signatures=signatures[:, [k]])).block_log_likelihood(block)
        for k in range(3))
    assert full.block_log_likelihood(block) == pytest.approx(per_component, rel=1e-12)


def test_inverse_gamma_from_mean_and_variance():
    alpha, beta = inverse_gamma_from_mean_variance(500.0, 50.0)
    distribution = stats.invgamma(alpha, scale=beta)
    assert distribution.mean() == pytest.approx(500.0, rel=1e-10)
    assert distribution.var() == pytest.approx(50.0, rel=1e-8)


def test_empirical_bayes_fit_recovers_the_generating_noise_level():
    rng = np.random.default_rng(11)
    noise, spread = 0.02, 0.15
    datasets = []
    for _ in range(4):
        labels = np.repeat(np.arange(8), 4)
        centres = rng.normal(0.3, spread, size=(8, 2))
        datasets.append(Dataset(signatures=centres[labels] + rng.normal(0, noise, size=(32, 2)), labels=labels))
    model = AppearanceModel.fit(datasets)
    implied_noise_variance = model.beta / (model.alpha - 1.0)  # prior mean of s2
    assert np.all(np.abs(np.sqrt(implied_noise_variance) / noise - 1.0) < 0.35)
    assert np.all(np.abs(model.mu - 0.3) < 0.1)


@pytest.mark.parametrize("field, kwargs", [
    ("kappa", dict(mu=0.0, kappa=0.0, alpha=1.0, beta=1.0)),
    ("alpha", dict(mu=0.0, kappa=1.0, alpha=-1.0, beta=1.0)),
    ("beta", dict(mu=0.0, kappa=1.0, alpha=1.0, beta=float("inf"))),
    ("mu", dict(mu=float("nan"), kappa=1.0, alpha=1.0, beta=1.0)),
])
def test_bad_hyperparameters_are_refused(field, kwargs):
    with pytest.raises(ValueError, match=field):
        AppearanceModel(**kwargs)


def test_hyperparameter_length_must_match_signatures():
    with pytest.raises(ValueError, match="K=5"):
        AppearanceModel(0.0, np.ones(3), 1.0, 1.0).bind(Dataset(signatures=np.ones((4, 5))))
    with pytest.raises(ValueError, match="evidence"):
        AppearanceModel(0.0, 1.0, 1.0, 1.0, evidence="eq19")


def test_fit_refuses_a_component_that_never_varies():
    rng = np.random.default_rng(0)
    signatures = np.column_stack([rng.normal(size=6), np.full(6, 0.3)])
    calibration = Dataset(signatures=signatures, labels=np.array([0, 1, 0, 1, 2, 2]))
    with pytest.raises(ValueError, match="signature component 1 is constant"):
        AppearanceModel.fit([calibration])


def test_fit_refuses_calibration_runs_without_a_revisit():
    calibration = Dataset(signatures=np.random.default_rng(0).normal(size=(6, 2)), labels=np.arange(6))
    with pytest.raises(ValueError, match="no revisits"):
        AppearanceModel.fit([calibration])


def calibration_runs(seed=11):
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(3):
        labels = np.repeat(np.arange(6), 3)
        centres = rng.normal(0.3, 0.15, size=(6, 2))
        runs.append(Dataset(signatures=centres[labels] + rng.normal(0, 0.02, size=(18, 2)), labels=labels))
    return runs


def failing_optimiser(monkeypatch, calls_failing):
    """Make the fit's L-BFGS-B runs number 0 .. calls_failing - 1 stop at once, where they started, reporting failure."""
    import ptm.appearance

    real, calls = ptm.appearance.minimize, []

    def minimize(fun, x0, **kwargs):
        calls.append(kwargs.get("jac", False))
        if len(calls) > calls_failing:
            return real(fun, x0, **kwargs)
        value = fun(x0)
        return OptimizeResult(x=np.asarray(x0, dtype=float), fun=value[0] if kwargs.get("jac") else value,
                              success=False, message="ABNORMAL: (simulated)")

    monkeypatch.setattr(ptm.appearance, "minimize", minimize)
    return calls


def test_a_failed_fit_is_restarted_with_the_analytic_gradient(monkeypatch):
    # the restart starts from scratch here (the failed run did not move): it must find the same maximum as the
    # usual finite-difference run, which it can only do with a right gradient of the evidence
    expected = AppearanceModel.fit(calibration_runs())
    calls = failing_optimiser(monkeypatch, calls_failing=1)
    model = AppearanceModel.fit(calibration_runs())
    assert calls == [False, True, False]  # component 0: failed, restarted with the gradient; component 1: ok
    for name in ("mu", "kappa", "alpha", "beta"):
        np.testing.assert_allclose(getattr(model, name), getattr(expected, name), rtol=1e-5, err_msg=name)


def test_a_fit_that_fails_twice_is_refused_by_component(monkeypatch):
    failing_optimiser(monkeypatch, calls_failing=2)
    with pytest.raises(RuntimeError, match=r"did not converge for signature component 0 \(ABNORMAL.*; ABNORMAL"):
        AppearanceModel.fit(calibration_runs())


def test_a_grown_term_scores_as_a_fresh_one_and_keeps_what_it_memoised():
    """The online mapper's next detection: the term grown into the longer run gives every set the value a
    fresh binding gives, and the sets of the shorter run are answered from its memo."""
    longer = appearance_posterior(8).dataset
    shorter = Dataset(signatures=longer.signatures[:6])
    model = AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2e-4)
    term = model.bind(shorter)
    seen = [(0, 3), (1, 4), (2, 5), (0, 1, 2)]
    for block in seen:
        term.block_log_likelihood(block)
    grown, fresh = term.grown(longer), model.bind(longer)
    for block in seen + [(0, 3, 6), (1, 4, 7), (7,)]:
        assert grown.block_log_likelihood(block) == fresh.block_log_likelihood(block)
    assert grown._memo is term._memo and term._memo.hits == len(seen)


def test_growing_into_another_run_is_refused():
    longer = appearance_posterior(8).dataset
    term = AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2e-4).bind(longer)
    other = Dataset(signatures=longer.signatures[::-1].copy())
    with pytest.raises(ValueError, match="does not extend this term's run"):
        term.grown(other)
    with pytest.raises(ValueError, match="does not extend this term's run"):
        term.grown(Dataset(signatures=longer.signatures[:4]))
