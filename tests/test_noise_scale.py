"""The odometry noise scale integrated out with the topology (docs/model.md §3.3, "Noise scale").

A scale s multiplies every covariance of the pose graph; with s ~ IG(a, b) the Laplace part of log P(O | T)
is integrated in closed form, and the importance-sampling correction is taken at the conditional mode
s_hat = (b + E*) / (a + k + 1). The data are simulated from the model itself with every covariance
TRUE_SCALE = 4 times the model's (sigma 2 times): odometry rows composed in the frame of the earlier
detection, each detection of a place of n_S drawn round it with variance 4 sigma_T^2 / n_S per axis (the
tie's own Gaussian). Then E*/4 ~ Gamma(N - M) for the true partition (measured over 150 seeds: mean 2.84,
sd 1.66 for k = 3; 16.2, 4.3 for k = 17).

Measured on the N = 5 run the exactness tests use (there and back between two places 5 m apart, seed 1,
entropy 1.3 nats): TV between the MCMC histogram and the enumeration 0.016 at seed 7 (seeds 5-9: 0.016-0.043;
bound 0.06, that of tests/test_sampler.py); between the plug-in (s = 1) and the marginal posterior 0.206; the
truth's mass 0.396 plug-in, 0.583 marginal; E[s | data] 2.11. The sampler runs without delayed acceptance:
screened by the cheap terms, which hold the tie normaliser's reward for every merge, its acceptance rate is
1.4 % here, with the scale plugged in as well as integrated out, and 4 x 3 000 steps do not mix (TV 0.09-0.15).
On the square driven ten times (N = 41, k = 37 ties) the truth's conditional has mean 3.75-4.38 over seeds 0-3.
"""

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.stats

import ptm
import ptm.recorder
from ptm.moves import GibbsReassign, SplitMerge
from ptm.pose_graph import PoseGraph, odometry_sqrt_information
from ptm.se2 import relative_pose, wrap_angle

TRUE_SCALE = 4.0
MODEL = dict(sigma_xy=0.1, sigma_theta=0.03, sigma_topology=0.3, penalty_radius=2.0, max_penalty=0.0,
             n_importance=50, seed=0)
#: TV bound of the MCMC histogram against the enumeration (four chains of 3 000 kept steps): that of
#: tests/test_sampler.py, above the 0.016-0.043 measured over five seeds.
TOLERANCE = 0.06


def loop_run(n, places, seed, scale=TRUE_SCALE, side=5.0):
    """``n`` detections driven round a regular polygon of ``places`` corners ``side`` m apart (2: there and
    back), simulated from the model with every covariance ``scale`` times ``MODEL``'s."""
    rng = np.random.default_rng(seed)
    angles = np.arange(places) * 2.0 * np.pi / places
    corners = side / (2.0 * np.sin(np.pi / places)) * np.column_stack([np.cos(angles), np.sin(angles)])
    labels = np.arange(n) % places
    spread = np.sqrt(scale / np.bincount(labels)[labels]) * MODEL["sigma_topology"]
    positions = corners[labels] + rng.normal(0.0, 1.0, (n, 2)) * spread[:, None]
    headings = wrap_angle(angles[labels] + np.pi / 2 + np.pi / places + rng.normal(0.0, 0.2, n))
    poses = np.column_stack([positions, headings])
    sigmas = np.sqrt(scale) * np.array([MODEL["sigma_xy"], MODEL["sigma_xy"], MODEL["sigma_theta"]])
    odometry = relative_pose(poses[:-1], poses[1:]) + rng.normal(0.0, sigmas, (n - 1, 3))
    return ptm.Dataset(odometry=odometry, labels=labels)


def marginal_model(prior=None, normalised_ties=True, **settings):
    return ptm.OdometryModel(**{**MODEL, **settings}, noise_scale_prior=prior or ptm.NoiseScalePrior.wide(),
                             normalised_ties=normalised_ties)


def normaliser(dataset):
    return ptm.TieNormaliser.from_dead_reckoning(dataset, MODEL["sigma_topology"], margin=1.0)


@pytest.fixture(scope="module")
def shuttle():
    """The N = 5 run there and back, and its exact posteriors with the scale plugged in (s = 1) and integrated
    out: the marginal term is rebound from the plug-in one, so each partition is fitted once."""
    dataset = loop_run(5, places=2, seed=1)
    plug_in = ptm.OdometryModel(**MODEL).bind(dataset)
    marginal = plug_in.rebind(marginal_model())
    posteriors = [ptm.Posterior(dataset, ptm.PoissonPrior(2.0), [term, normaliser(dataset)])
                  for term in (plug_in, marginal)]
    return dataset, posteriors, [ptm.exact_posterior(posterior) for posterior in posteriors]


# -- the closed form ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("normalised_ties", [True, False], ids=["normalised", "paper_ties"])
def test_the_closed_form_is_the_integral_over_the_scale(normalised_ties):
    # log int IG(s) L_Laplace(T, s) ds by quadrature, L_Laplace(T, s) from a fit of the graph whose covariances
    # are s times the model's (from dead reckoning), with the rows' Gaussian normaliser -(d/2) log s and, with
    # normalised ties, the TieNormaliser's change at sigma_T sqrt(s)
    dataset = loop_run(5, places=2, seed=1)
    labels = dataset.labels
    prior = ptm.NoiseScalePrior(2.0, 3.0)
    term = marginal_model(prior, normalised_ties).bind(dataset)
    dimension = 3 * (dataset.n - 1)
    sqrt_information = odometry_sqrt_information(np.broadcast_to(
        np.diag([MODEL["sigma_xy"] ** 2, MODEL["sigma_xy"] ** 2, MODEL["sigma_theta"] ** 2]), (dataset.n - 1, 3, 3)))
    ties = normaliser(dataset)
    partition = ptm.Partition.from_labels(labels)

    def laplace(scale):
        graph = PoseGraph(dataset.odometry, sqrt_information / math.sqrt(scale),
                          MODEL["sigma_topology"] * math.sqrt(scale))
        fit = graph.fit(graph.dead_reckoning(), labels)
        assert fit.converged
        value = -fit.energy + 0.5 * dimension * math.log(2.0 * math.pi) - 0.5 * fit.factor.log_det()
        value -= 0.5 * dimension * math.log(scale)
        if normalised_ties:
            value += ptm.TieNormaliser(ties.area, ties.sigma_topology * math.sqrt(scale)).log_likelihood(partition)
            value -= ties.log_likelihood(partition)
        return value

    closed_form = term.evaluate(labels).laplace
    density = scipy.stats.invgamma(prior.shape, scale=prior.scale)

    def integrand(log_scale):
        scale = math.exp(log_scale)
        return math.exp(log_scale + density.logpdf(scale) + laplace(scale) - closed_form)

    integral, error = scipy.integrate.quad(integrand, -6.0, 14.0, epsabs=1e-10, epsrel=1e-9, limit=100)
    assert math.log(integral) == pytest.approx(0.0, abs=1e-6)


def test_without_ties_or_penalty_the_scale_changes_nothing():
    # all distinct: E* = 0 and k = 0, so the scale's integral is 1 and the importance estimate exact
    dataset = loop_run(5, places=2, seed=1)
    labels = np.arange(5)
    marginal = marginal_model().bind(dataset).evaluate(labels)
    plug_in = ptm.OdometryModel(**MODEL).bind(dataset).evaluate(labels)
    assert marginal.log_likelihood == pytest.approx(plug_in.log_likelihood, abs=1e-9)
    assert marginal.log_likelihood == pytest.approx(marginal.laplace, abs=1e-9)


@pytest.mark.parametrize("labels", [[0, 1, 0, 1, 0], [0, 1, 0, 1, 2]], ids=["truth", "revisit_split"])
def test_the_importance_correction_is_taken_at_the_conditional_mode(labels):
    # IS / Laplace of the marginal term = that of the model whose sigmas are sqrt(s_hat) times the model's, with
    # the same seed: the same draws, the graph scaled; the split revisit draws from the penalty's mixture
    dataset = loop_run(5, places=2, seed=1)
    settings = dict(max_penalty=5.0)
    prior = ptm.NoiseScalePrior.wide()
    term = marginal_model(prior, **settings).bind(dataset)
    evaluation = term.evaluate(labels)
    ties = 5 - (max(labels) + 1)
    scale = (prior.scale + term.fit(np.array(labels)).energy) / (prior.shape + ties + 1.0)
    scaled = ptm.OdometryModel(**{**MODEL, **settings, "sigma_xy": MODEL["sigma_xy"] * math.sqrt(scale),
                                  "sigma_theta": MODEL["sigma_theta"] * math.sqrt(scale),
                                  "sigma_topology": MODEL["sigma_topology"] * math.sqrt(scale)}).bind(dataset)
    reference = scaled.evaluate(labels)
    assert evaluation.log_likelihood - evaluation.laplace == pytest.approx(
        reference.log_likelihood - reference.laplace, abs=1e-6)
    assert evaluation.ess == pytest.approx(reference.ess, rel=1e-6)
    assert (evaluation.penalty_shift > 0.0) == (labels[-1] == 2)


# -- the posterior ------------------------------------------------------------------------------------------------


def test_enumeration_and_sampling_agree_with_the_scale_integrated_out(shuttle, monkeypatch):
    monkeypatch.setattr(ptm.recorder, "RENORMALISE_COVERAGE", math.inf)  # judge the visits (tests/test_sampler.py)
    _, (_, posterior), (_, exact) = shuttle
    sampled = ptm.mcmc(posterior, 3_000, burn_in=500, seed=7, chains=4, start="dispersed", max_doublings=0,
                       moves=[GibbsReassign(), SplitMerge()], delayed_acceptance=False)
    assert ptm.total_variation(sampled, exact) < TOLERANCE
    assert posterior.diagnostics()["odometry"]["evaluations"] == len(exact)  # every value from the memo


def test_negative_control_the_plugged_in_scale_is_another_posterior(shuttle):
    _, _, (plug_in, marginal) = shuttle
    assert ptm.total_variation(plug_in, marginal) > 3 * TOLERANCE


def test_every_value_respects_the_bound_exact_enumeration_skips_by(shuttle):
    _, (plug_in, marginal), _ = shuttle
    term = marginal.global_terms[0]
    bound = term.log_likelihood_upper_bound()
    assert bound > plug_in.global_terms[0].log_likelihood_upper_bound()
    partitions = ptm.exact_posterior(plug_in).partitions
    values = [term.log_likelihood(labels) for labels in partitions]
    assert max(values) <= bound
    # the bound of the partitions of M places: at most the one over all, and every value of M places below it
    places = partitions.max(axis=1) + 1
    by_places = [term.log_likelihood_upper_bound(m) for m in range(1, marginal.n + 1)]
    assert max(by_places) == pytest.approx(bound) and min(by_places) < bound - 1.0
    assert all(value <= by_places[m - 1] for value, m in zip(values, places))



def test_the_scale_is_learned_from_the_loop_closures(shuttle):
    dataset, (_, posterior), (plug_in, marginal) = shuttle
    assert marginal.probability(dataset.labels) > plug_in.probability(dataset.labels) + 0.1
    scale = ptm.noise_scale_posterior(marginal, posterior)
    # three ties carry little: within a factor 2 of the truth, and above the calibrated 1
    assert TRUE_SCALE / 2.0 < scale.mean < TRUE_SCALE * 2.0
    assert not scale.in_prior_tail
    # a square driven ten times (k = 37 ties): the truth's conditional concentrates round 4
    long_run = loop_run(41, places=4, seed=0)
    long_posterior = ptm.Posterior(long_run, ptm.PoissonPrior(4.0), [marginal_model(), normaliser(long_run)])
    truth = ptm.PTM([long_run.labels], [1.0], "exact")
    learned = ptm.noise_scale_posterior(truth, long_posterior, quantiles=(0.025, 0.975))
    assert learned.mean == pytest.approx(TRUE_SCALE, rel=0.25)
    assert 1.0 < learned.quantiles[0.025] < TRUE_SCALE < learned.quantiles[0.975]
    assert not learned.in_prior_tail


def test_a_prior_that_excludes_the_datas_scale_is_flagged():
    long_run = loop_run(41, places=4, seed=0)
    truth = ptm.PTM([long_run.labels], [1.0], "exact")
    narrow = ptm.NoiseScalePrior(50.0, 51.0)  # mode 1, sd 0.15: the calibration taken as all but certain
    posterior = ptm.Posterior(long_run, ptm.PoissonPrior(4.0), [marginal_model(narrow), normaliser(long_run)])
    report = ptm.noise_scale_posterior(truth, posterior)
    assert report.in_prior_tail and report.prior_tail_mass < 0.01
    assert report.quantiles[0.5] > 2.0  # pulled up by the data, and not trusted


def test_the_mixture_is_the_weighted_sum_of_the_conditionals():
    prior = ptm.NoiseScalePrior(2.0, 3.0)

    class Term:
        noise_scale_prior, n = prior, 2

        @staticmethod
        def noise_scale_conditional(labels):
            return prior.conditional(energy=4.0 * labels[1], ties=1 - labels[1])

    class Posterior:
        terms = [Term]

    result = ptm.PTM([[0, 0], [0, 1]], [0.25, 0.75], "exact")
    report = ptm.noise_scale_posterior(result, Posterior, quantiles=(0.3,))
    first, second = scipy.stats.invgamma(3.0, scale=3.0), scipy.stats.invgamma(2.0, scale=7.0)
    assert report.mean == pytest.approx(0.25 * first.mean() + 0.75 * second.mean())
    assert 0.25 * first.cdf(report.quantiles[0.3]) + 0.75 * second.cdf(report.quantiles[0.3]) == pytest.approx(0.3)


# -- what is refused ----------------------------------------------------------------------------------------------


def test_the_model_says_how_the_scale_enters_the_ties():
    with pytest.raises(TypeError, match="normalised_ties"):
        ptm.OdometryModel(noise_scale_prior=ptm.NoiseScalePrior.wide())
    with pytest.raises(ValueError, match="normalised_ties"):
        ptm.OdometryModel(normalised_ties=True)
    with pytest.raises(TypeError, match="noise_scale_prior"):
        ptm.OdometryModel(noise_scale_prior=(2.0, 3.0), normalised_ties=True)
    with pytest.raises(ValueError, match="shape"):
        ptm.NoiseScalePrior(0.0, 1.0)


@pytest.mark.parametrize("normalised_ties, normalisers, message", [
    (True, 0, "exactly one ptm.TieNormaliser"),
    (True, 2, "exactly one ptm.TieNormaliser"),
    (False, 1, "normalised_ties=True"),
], ids=["declared_but_missing", "counted_twice", "undeclared"])
def test_the_posterior_refuses_a_tie_normaliser_the_model_was_not_told_of(normalised_ties, normalisers, message):
    dataset = loop_run(4, places=2, seed=0)
    models = [marginal_model(normalised_ties=normalised_ties)] + [normaliser(dataset)] * normalisers
    with pytest.raises(ValueError, match=message):
        ptm.Posterior(dataset, ptm.PoissonPrior(2.0), models)


def test_the_posterior_refuses_a_tie_normaliser_of_another_sigma():
    dataset = loop_run(4, places=2, seed=0)
    other = ptm.TieNormaliser(100.0, 2.0 * MODEL["sigma_topology"])
    with pytest.raises(ValueError, match="sigma_topology"):
        ptm.Posterior(dataset, ptm.PoissonPrior(2.0), [marginal_model(), other])


def test_a_scale_posterior_needs_a_term_with_a_prior():
    dataset = loop_run(4, places=2, seed=0)
    posterior = ptm.Posterior(dataset, ptm.PoissonPrior(2.0), [ptm.OdometryModel(**MODEL)])
    truth = ptm.PTM([dataset.labels], [1.0], "exact")
    with pytest.raises(ValueError, match="noise_scale_prior"):
        ptm.noise_scale_posterior(truth, posterior)
    with pytest.raises(TypeError, match="result"):
        ptm.noise_scale_posterior([dataset.labels], posterior)
    with pytest.raises(ValueError, match="quantiles"):
        ptm.noise_scale_posterior(truth, posterior, quantiles=(0.5, 1.0))
