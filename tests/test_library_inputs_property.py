"""Property-based tests of the library's entry points (issue 47): any argument works or is refused by name.

``ptm.mcmc``, ``ptm.tempered_mcmc``, ``ptm.exact_posterior``, ``ptm.OdometryModel`` (and its binding),
``ptm.AppearanceModel`` and its ``fit``, ``ptm.JointAppearanceModel.fit``, ``ptm.PoissonPrior`` and the
``ptm.OnlineMapper`` constructor take values of the wrong type, non-finite and extreme values. The only outcomes
are a result that holds up (probabilities summing to one, finite log-probabilities) or the documented error: a
``TypeError`` for a value of the wrong type, a ``ValueError`` for a bad value, naming the argument
(``ptm._validation``). Never an OverflowError, AttributeError or MemoryError from deep inside, never a hang.
Datasets have N <= 5 and runs a few samples, so that every accepted value is cheap.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ptm

FEW = settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])

#: Values of any type, non-finite and extreme, but never an accepted count large enough to take long (a burn-in
#: of 1e9 would be a valid, slow request): whole numbers are small or beyond every documented limit.
anything = st.one_of(
    st.none(), st.booleans(), st.text(max_size=3), st.just(object()), st.lists(st.integers(0, 3), max_size=3),
    st.integers(-3, 6), st.integers(10 ** 13, 2 ** 70), st.integers(-(2 ** 70), -1),
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 0.5, 2.0, -1.0, 1e-300, 5e-324, 1e13, 1e300,
                     1.7976931348623157e308, np.float64(3.0), np.int64(2), np.array(2.0), np.array([1.0, 2.0])]),
)
positive_numbers = st.one_of(anything, st.floats(1e-320, 1e308), st.floats(0.01, 10.0))


def refused_by_name(error: Exception, *names: str) -> bool:
    return isinstance(error, (TypeError, ValueError)) and any(name in str(error) for name in names)


def appearance_posterior(n: int = 4) -> ptm.Posterior:
    signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04], [0.30, 0.12]])[:n]
    return ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(2.0),
                         [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)])


SQUARE = np.tile([2.0, 0.0, np.pi / 2], (4, 1)) + [0.03, -0.02, 0.01]  # a 2 m square, back at the start
ODOMETRY_POSTERIOR = ptm.Posterior(ptm.Dataset(odometry=SQUARE[:2]), ptm.PoissonPrior(2.0),
                                   [ptm.OdometryModel(sigma_topology=0.1, penalty_radius=1.0, n_importance=20)])
APPEARANCE_POSTERIOR = appearance_posterior()


def holds_up(result: ptm.PTM) -> None:
    assert isinstance(result, ptm.PTM) and result.probabilities.sum() == pytest.approx(1.0)
    assert np.all(np.isfinite(result.probabilities)) and np.all(result.probabilities >= 0.0)


# -- the samplers -----------------------------------------------------------------------------------------------

SAMPLER_FIELDS = ["posterior", "n_samples", "seed", "burn_in", "thin", "chains", "max_doublings", "unscreened_share",
                  "delayed_acceptance", "start", "moves"]


@FEW
@given(st.sampled_from(["mcmc", "tempered_mcmc"]), st.sampled_from(SAMPLER_FIELDS + ["temperatures", "swap_interval"]),
       anything)
def test_a_sampler_takes_any_argument_or_refuses_it_by_name(sampler, field, value):
    if sampler == "mcmc" and field in ("temperatures", "swap_interval"):
        field = "seed"
    arguments = {"posterior": APPEARANCE_POSTERIOR, "n_samples": 4, "seed": 0, "chains": 1, "max_doublings": 0,
                 "burn_in": 2}
    if sampler == "tempered_mcmc":
        arguments["temperatures"] = (1.0, 0.5)
    arguments[field] = value
    try:
        result = getattr(ptm, sampler)(arguments.pop("posterior"), arguments.pop("n_samples"), **arguments)
    except Exception as error:  # noqa: BLE001 -- the property is about which exceptions occur
        assert refused_by_name(error, field), f"{field}={value!r}: {type(error).__name__}: {error}"
        return
    holds_up(result)


@FEW
@given(st.sampled_from(["posterior", "max_n", "skip", "max_global_evaluations"]), anything,
       st.sampled_from(["appearance", "odometry"]))
def test_exact_posterior_takes_any_argument_or_refuses_it_by_name(field, value, terms):
    arguments = {"posterior": APPEARANCE_POSTERIOR if terms == "appearance" else ODOMETRY_POSTERIOR, field: value}
    try:
        result = ptm.exact_posterior(**arguments)
    except Exception as error:  # noqa: BLE001
        assert refused_by_name(error, field), f"{field}={value!r}: {type(error).__name__}: {error}"
        return
    holds_up(result)
    assert len(result) == ptm.bell(arguments["posterior"].n) or "skipped_mass_bound" in result.diagnostics


# -- the models -----------------------------------------------------------------------------------------------------

ODOMETRY_FIELDS = ["sigma_xy", "sigma_theta", "sigma_topology", "penalty_radius", "max_penalty", "n_importance", "seed",
                   "cache_size", "sparse_above"]


@settings(FEW, max_examples=60)
@given(st.sampled_from(ODOMETRY_FIELDS), positive_numbers)
def test_an_odometry_model_takes_any_parameter_or_refuses_it_by_name(field, value):
    try:
        term = ptm.OdometryModel(**{"n_importance": 20, field: value}).bind(ptm.Dataset(odometry=SQUARE[:3]))
        values = [term.log_likelihood(labels) for labels in ([0, 1, 2, 0], [0, 1, 2, 3], [0, 0, 0, 0])]
    except Exception as error:  # noqa: BLE001
        assert refused_by_name(error, field), f"{field}={value!r}: {type(error).__name__}: {error}"
        return
    assert all(v < math.inf and not math.isnan(v) for v in values)
    assert max(values) <= term.log_likelihood_upper_bound() + 1.0


@settings(FEW, max_examples=60)
@given(st.lists(st.floats(-330.0, 330.0), min_size=4, max_size=4), st.floats(-3.0, 3.0))
def test_odometry_covariances_of_any_scale_give_a_sound_likelihood_or_are_refused_by_row(exponents, stretch):
    with np.errstate(over="ignore", invalid="ignore"):  # an infinite or NaN row is the Dataset's to refuse
        covariances = np.power(10.0, np.array(exponents))[:, None, None] * np.diag([1.0, 1.0, 10.0 ** stretch])
    try:
        dataset = ptm.Dataset(odometry=SQUARE, odometry_cov=covariances)
    except ValueError:
        return  # the Dataset's own checks (not positive definite: an eigenvalue rounded to 0)
    try:
        term = ptm.OdometryModel(sigma_topology=0.1, penalty_radius=1.0, n_importance=20).bind(dataset)
    except ValueError as error:
        assert "odometry_cov[" in str(error) and "STD_RANGE" in str(error)
        return
    try:
        values = [term.log_likelihood(labels) for labels in ([0, 1, 2, 3, 0], [0, 1, 2, 3, 4], [0, 0, 1, 1, 0])]
    except ValueError as error:  # rows of very different scales: the Hessian cannot be factorised
        assert "not positive definite" in str(error)
        return
    assert all(v < math.inf and not math.isnan(v) for v in values)
    assert max(values) <= term.log_likelihood_upper_bound() + 1.0  # at 1e-300 x I it was +1.5e253


def closing_the_loop(scale: float) -> float:
    """log P(O | the loop closed) - log P(O | all distinct) of the square with every row's covariance scale x I."""
    dataset = ptm.Dataset(odometry=SQUARE, odometry_cov=np.tile(scale * np.eye(3), (4, 1, 1)))
    term = ptm.OdometryModel(sigma_topology=0.1, penalty_radius=1.0, n_importance=20).bind(dataset)
    return term.log_likelihood([0, 1, 2, 3, 0]) - term.log_likelihood([0, 1, 2, 3, 4])


PRECISE_LIMIT = closing_the_loop(1e-12)  # odometry this precise pins the poses: smaller scales change nothing


@FEW
@given(st.floats(-330.0, -10.0))
def test_precise_odometry_gives_its_limit_or_is_refused_by_row(exponent):
    try:
        ratio = closing_the_loop(10.0 ** exponent)
    except ValueError as error:  # beyond STD_RANGE, or (10^-324 = 0) not positive definite
        assert "odometry_cov[0]" in str(error)
        return
    assert ratio == pytest.approx(PRECISE_LIMIT, abs=0.05)  # was 0 (every partition alike) from 1e-50 on


APPEARANCE_FIELDS = ["mu", "kappa", "alpha", "beta", "outlier_share", "outlier_scale", "max_outliers"]


@FEW
@given(st.sampled_from(APPEARANCE_FIELDS), positive_numbers)
def test_an_appearance_model_takes_any_hyperparameter_or_refuses_it_by_name(field, value):
    arguments = {"mu": 0.3, "kappa": 0.05, "alpha": 3.0, "beta": 2e-4, field: value}
    try:
        posterior = ptm.Posterior(APPEARANCE_POSTERIOR.dataset, ptm.PoissonPrior(2.0),
                                  [ptm.AppearanceModel(**arguments)])
        values = [posterior.log_prob(labels) for labels in ([0, 1, 0, 1], [0, 0, 0, 0], [0, 1, 2, 3])]
    except Exception as error:  # noqa: BLE001
        assert refused_by_name(error, field), f"{field}={value!r}: {type(error).__name__}: {error}"
        return
    assert all(math.isfinite(v) for v in values)


def labelled_run(seed: int) -> ptm.Dataset:
    rng = np.random.default_rng(seed)
    labels = np.array([0, 1, 0, 1, 2])
    return ptm.Dataset(signatures=rng.normal(0.0, 1.0, (3, 2))[labels] + rng.normal(0.0, 0.1, (5, 2)), labels=labels)


calibrations = st.one_of(
    anything,
    st.just(labelled_run(0)),
    st.lists(st.sampled_from([labelled_run(0), labelled_run(1), ptm.Dataset(signatures=np.ones((3, 2)))]),
             max_size=2).flatmap(lambda runs: st.sampled_from([runs, tuple(runs), iter(runs), {"a": runs}])),
)


@FEW
@given(st.sampled_from([ptm.AppearanceModel, ptm.JointAppearanceModel]), calibrations)
def test_a_fit_takes_any_calibration_or_refuses_it_by_name(model, datasets):
    try:
        fitted = model.fit(datasets)
    except Exception as error:  # noqa: BLE001
        assert refused_by_name(error, "datasets", "dataset", "revisits", "constant", "K + 1"), \
            f"{datasets!r}: {type(error).__name__}: {error}"
        return
    assert isinstance(fitted, model)


@FEW
@given(positive_numbers)
def test_a_poisson_prior_takes_any_rate_or_refuses_it_by_name(rate):
    try:
        prior = ptm.PoissonPrior(rate)
        values = [prior.log_prob(5, m) for m in range(1, 6)]
    except Exception as error:  # noqa: BLE001
        assert refused_by_name(error, "rate"), f"rate={rate!r}: {type(error).__name__}: {error}"
        return
    assert all(math.isfinite(v) and v <= 0.0 for v in values)


ONLINE_FIELDS = ["prior", "models", "particles", "rejuvenation_steps", "resample_below", "screen", "seed",
                 "reallocation_window", "blas_threads"]


@FEW
@given(st.sampled_from(ONLINE_FIELDS), anything)
def test_an_online_mapper_takes_any_setting_or_refuses_it_by_name(field, value):
    arguments = {"prior": ptm.PoissonPrior(2.0), "models": [ptm.AppearanceModel(0.3, 0.05, 3.0, 2e-4)], field: value}
    try:
        ptm.OnlineMapper(**arguments)
    except Exception as error:  # noqa: BLE001
        assert refused_by_name(error, field, "model"), f"{field}={value!r}: {type(error).__name__}: {error}"
