"""The odometry likelihood (docs/model.md §3.3): derivatives, the estimator, the paper's Fig. 10, the sampler.

Datasets are built here with numpy: a robot that drives a square loop and
detects a landmark at every corner, its odometry composed on the SE(2)
manifold with Gaussian noise on each relative-pose row.

    python -m pytest tests/test_odometry.py -q
    python -m pytest tests/test_odometry.py -q -k "finite_differences or penalty_decides"
    python -m pytest tests/test_odometry.py -q -k "mcmc_matches or negative_control"
"""

import functools
import math

import numpy as np
import pytest

import ptm
from ptm.se2 import relative_pose, wrap_angle
from ptm.odometry import landmark_penalty
from ptm.pose_graph import (odometry_jacobian_blocks, odometry_residuals, odometry_second_order_blocks,
                            odometry_sqrt_information, poses_from_vector)

PLACE_SIGNATURES = np.array([[0.30, 0.10], [0.25, 0.15], [0.40, 0.05], [0.32, 0.12]])


def square_loop_dataset(n, side=5.0, sigma_xy=0.1, sigma_theta=0.03, seed=0, signature_noise=None):
    """N detections at the corners of a square driven repeatedly (labels 0,1,2,3,0,1,...)."""
    seeds = np.random.SeedSequence(seed).spawn(2)
    odometry_rng, appearance_rng = (np.random.default_rng(s) for s in seeds)
    corners = np.array([[0.0, 0.0], [side, 0.0], [side, side], [0.0, side]])
    labels = np.arange(n) % 4
    poses = np.column_stack([corners[labels], wrap_angle(labels * np.pi / 2)])
    odometry = relative_pose(poses[:-1], poses[1:])  # previous_T_current
    odometry = odometry + odometry_rng.normal(0.0, [sigma_xy, sigma_xy, sigma_theta], size=odometry.shape)
    signatures = None
    if signature_noise is not None:
        signatures = PLACE_SIGNATURES[labels] + appearance_rng.normal(0.0, signature_noise, size=(n, 2))
    return ptm.Dataset(odometry=odometry, labels=labels, true_poses=poses, signatures=signatures)


def mixed_dataset(n=7):
    """A noisy, aliased loop with odometry and appearance."""
    return square_loop_dataset(n, side=4.0, sigma_xy=0.5, sigma_theta=0.15, seed=1, signature_noise=0.05)


def mixed_posterior_of(dataset, model_seed=0):
    """Odometry + appearance models matched to :func:`mixed_dataset`: a posterior spread over many topologies."""
    appearance = ptm.AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2.0 * 0.05**2)
    odometry = ptm.OdometryModel(0.5, 0.15, 0.5, 3.0, 5.0, n_importance=50, seed=model_seed)
    return ptm.Posterior(dataset, ptm.PoissonPrior(3.0), [appearance, odometry])


def mixed_posterior(n=7, model_seed=0):
    return mixed_posterior_of(mixed_dataset(n), model_seed)


@functools.lru_cache(maxsize=None)
def mixed_target(n=7):
    """:func:`mixed_posterior` and its exact posterior, enumerated once per test session.

    Enumerating fills the posterior's odometry memo with every partition, so
    the samplers that run on this same posterior evaluate nothing new (the
    values are deterministic functions of the partition: common random numbers).
    """
    posterior = mixed_posterior(n)
    return posterior, ptm.exact_posterior(posterior)


# -- derivatives ---------------------------------------------------------------------------------


def test_jacobian_blocks_match_finite_differences():
    rng = np.random.default_rng(3)
    poses = rng.normal(0.0, 2.0, size=(6, 3))
    odometry = rng.normal(0.0, 1.0, size=(5, 3))
    wrt_previous, wrt_current = odometry_jacobian_blocks(poses)
    step = 1e-6
    for k in range(5):
        for coordinate in range(3):
            for pose, analytic in ((k, wrt_previous[k]), (k + 1, wrt_current[k])):
                shifted_up, shifted_down = poses.copy(), poses.copy()
                shifted_up[pose, coordinate] += step
                shifted_down[pose, coordinate] -= step
                numeric = (odometry_residuals(shifted_up, odometry)[k]
                           - odometry_residuals(shifted_down, odometry)[k]) / (2 * step)
                np.testing.assert_allclose(analytic[:, coordinate], numeric, atol=1e-7)


def test_second_order_blocks_match_finite_differences_of_the_jacobian():
    rng = np.random.default_rng(4)
    poses = rng.normal(0.0, 2.0, size=(4, 3))
    multipliers = rng.normal(size=(3, 3))

    def weighted_gradient(p):  # sum_k J_k^T m_k with m fixed, per pose pair (previous, current)
        wrt_previous, wrt_current = odometry_jacobian_blocks(p)
        return (np.einsum("kji,kj->ki", wrt_previous, multipliers),
                np.einsum("kji,kj->ki", wrt_current, multipliers))

    second_previous, second_between = odometry_second_order_blocks(poses, multipliers)
    step = 1e-6
    for k in range(3):
        for coordinate in range(3):
            for pose, analytic_column in ((k, second_previous[k][:, coordinate]),
                                          (k + 1, second_between[k][:, coordinate])):
                up, down = poses.copy(), poses.copy()
                up[pose, coordinate] += step
                down[pose, coordinate] -= step
                numeric = (weighted_gradient(up)[0][k] - weighted_gradient(down)[0][k]) / (2 * step)
                np.testing.assert_allclose(analytic_column, numeric, atol=1e-6)


CORRELATED_COVARIANCE = np.array([[0.02, 0.005, 0.002], [0.005, 0.01, -0.001], [0.002, -0.001, 0.004]])


@pytest.mark.parametrize("covariance", [None, CORRELATED_COVARIANCE], ids=["diagonal", "correlated"])
def test_energy_gradient_and_newton_hessian_match_finite_differences(covariance):
    dataset = square_loop_dataset(6, sigma_xy=0.3, sigma_theta=0.2)
    if covariance is not None:
        dataset = dataset.replace(odometry_cov=np.broadcast_to(covariance, (5, 3, 3)))
    graph = ptm.OdometryModel(0.1, 0.05, 0.3, 2.5, 0.0).bind(dataset).graph
    labels = np.array([0, 1, 2, 3, 0, 1])
    x = graph.dead_reckoning() + np.random.default_rng(5).normal(0.0, 0.3, graph.dimension)
    topology = graph.topology(labels)
    linearisation = graph.linearise(x, topology)
    assert linearisation.energy == graph.energy(x, labels)
    hessian = graph.hessian_matrix(topology, linearisation.gauss_newton + linearisation.second_order).toarray()
    step = 1e-6
    basis = np.eye(graph.dimension)
    numeric_gradient = np.array([(graph.energy(x + step * e, labels) - graph.energy(x - step * e, labels)) / (2 * step)
                                 for e in basis])
    numeric_hessian = np.array([(graph.linearise(x + step * e, topology).gradient
                                 - graph.linearise(x - step * e, topology).gradient) / (2 * step) for e in basis])
    np.testing.assert_allclose(linearisation.gradient, numeric_gradient, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(hessian, numeric_hessian, rtol=1e-6, atol=1e-4)


def test_topology_energy_is_the_pairwise_sum_not_the_star_energy():
    graph = ptm.OdometryModel(0.1, 0.05, 0.7, 2.5, 0.0).bind(square_loop_dataset(9)).graph
    labels = np.array([0, 1, 0, 2, 0, 1, 3, 0, 2])  # pose 0, at the origin, shares a set with 2, 4 and 7
    rng = np.random.default_rng(6)
    centre = rng.normal(0.0, 30.0, graph.dimension)  # far from the origin, where x^T H_T x would cancel
    offsets = rng.normal(0.0, 0.5, size=(graph.dimension, 4))
    states = centre + offsets.T
    positions = poses_from_vector(states)[..., :2]
    pairwise = np.zeros(4)
    for i in range(9):
        for j in range(i + 1, 9):
            if labels[i] == labels[j]:
                pairwise += 0.5 * np.sum((positions[:, i] - positions[:, j]) ** 2, axis=-1) / 0.7**2
    topology = graph.topology(labels)
    np.testing.assert_allclose(topology.energy(states), pairwise, rtol=1e-12)
    np.testing.assert_allclose(topology.energy_around(centre, offsets), pairwise, rtol=1e-12)
    np.testing.assert_allclose(topology @ centre, graph.hessian_matrix(topology, np.zeros((15, 3, 3))) @ centre,
                               rtol=1e-12)
    assert np.all(topology.energy(states) > 0)


def test_penalty_is_the_cubic_of_the_paper():
    positions = np.array([[0.0, 0.0], [0.0, 0.0], [1.5, 0.0], [0.0, 3.0], [10.0, 0.0]])
    pairs = (np.array([0, 0, 0, 0]), np.array([1, 2, 3, 4]))
    # f(0) = P_max, f(D/2) = P_max / 8, f(D) = f(beyond) = 0 with D = 3, P_max = 100
    assert landmark_penalty(positions, pairs, 3.0, 100.0) == pytest.approx(100.0 + 12.5)


@pytest.mark.parametrize("sparse_above", [600, 0], ids=["banded_low_rank", "sparse"])
def test_factors_solve_log_det_and_sample_the_assembled_hessian(sparse_above):
    dataset = square_loop_dataset(9, sigma_xy=0.2, sigma_theta=0.05)
    graph = ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 0.0, sparse_above=sparse_above).bind(dataset).graph
    labels = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0])
    topology = graph.topology(labels)
    linearisation = graph.linearise(graph.dead_reckoning(), topology)
    gradient, gauss_newton = linearisation.gradient, linearisation.gauss_newton
    factor = graph.factorise(topology, gauss_newton)
    hessian = graph.hessian_matrix(topology, gauss_newton).toarray()
    assert factor.log_det() == pytest.approx(np.linalg.slogdet(hessian)[1], rel=1e-12)
    np.testing.assert_allclose(factor.solve(gradient), np.linalg.solve(hessian, gradient), rtol=1e-9, atol=1e-12)
    noise = np.random.default_rng(8).standard_normal((graph.dimension + 9, 40_000))
    offsets, half_quadratic = factor.sample(noise)
    np.testing.assert_allclose(half_quadratic, 0.5 * np.einsum("ds,de,es->s", offsets, hessian, offsets), rtol=1e-9)
    # the sample covariance is H^-1: with 40 000 draws each entry is within ~4 standard errors
    covariance = np.linalg.inv(hessian)
    scale = np.sqrt(np.outer(np.diag(covariance), np.diag(covariance)))
    assert np.max(np.abs(np.cov(offsets) - covariance) / scale) < 4 * np.sqrt(2 / 40_000)


# -- the estimator ---------------------------------------------------------------------------------


def test_all_distinct_without_penalty_equals_the_gaussian_normaliser():
    # Each relative pose is an independent Gaussian with unit-Jacobian change of variables, so
    # log P(O | all distinct) = sum_k 1/2 log det(2 pi Sigma_k) exactly (angle tails aside).
    dataset = square_loop_dataset(6)
    term = ptm.OdometryModel(0.1, 0.03, 0.3, 2.5, 0.0, n_importance=400, seed=1).bind(dataset)
    evaluation = term.evaluate(range(6))
    exact = 5 * 0.5 * math.log((2 * math.pi) ** 3 * 0.1**4 * 0.03**2)
    assert evaluation.laplace == pytest.approx(exact, abs=1e-9)
    assert abs(evaluation.log_likelihood - exact) < 4 * evaluation.standard_error + 1e-9


def test_importance_sampling_agrees_with_laplace_on_a_near_linear_problem():
    # Short steps and a tight heading noise make E nearly quadratic; with no penalty the
    # weights are then nearly constant and the estimate must sit within its Monte-Carlo error.
    dataset = square_loop_dataset(7, side=1.0, sigma_xy=0.02, sigma_theta=0.005, seed=2)
    term = ptm.OdometryModel(0.02, 0.005, 0.05, 0.5, 0.0, n_importance=2000, seed=3).bind(dataset)
    for labels in ([0, 1, 2, 3, 0, 1, 2], [0, 1, 2, 3, 4, 5, 6], [0, 1, 2, 3, 0, 4, 5]):
        evaluation = term.evaluate(labels)
        assert evaluation.standard_error > 0
        assert abs(evaluation.log_likelihood - evaluation.laplace) < 4 * evaluation.standard_error, labels
    # and the loop closure changes the value by far more than that error: the comparison has teeth
    assert abs(term.evaluate([0, 1, 2, 3, 0, 1, 2]).laplace - term.evaluate(range(7)).laplace) > 1.0


def test_the_value_is_a_deterministic_function_of_the_partition():
    dataset = square_loop_dataset(10, sigma_xy=0.2, sigma_theta=0.05)
    model = ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 50.0, n_importance=100, seed=11)
    cold, warm = model.bind(dataset), model.bind(dataset)
    partitions = [[0, 1, 2, 3, 0, 1, 2, 3, 0, 1], list(range(10)), [0, 1, 2, 3, 4, 1, 2, 3, 0, 5],
                  [0, 0, 1, 1, 2, 2, 3, 3, 4, 4], [0, 1, 2, 3, 0, 1, 2, 3, 0, 1]]
    for labels in partitions:  # warm: a term that has evaluated other partitions before
        warm.log_likelihood(labels)
    diagnostics = warm.diagnostics()
    assert diagnostics["cache_hits"] == 1 and diagnostics["evaluations"] == 4  # the last is the first again
    assert diagnostics["cache_hit_rate"] == pytest.approx(1 / 5)
    assert 1.0 <= diagnostics["ess_min"] <= diagnostics["ess_mean"] <= 100
    for labels in partitions:
        fresh = model.bind(dataset)  # cold: a term that has evaluated nothing
        assert warm.log_likelihood(labels) == pytest.approx(fresh.log_likelihood(labels), rel=1e-9)
    assert cold.log_likelihood(partitions[0]) == cold.log_likelihood([5, 6, 7, 8, 5, 6, 7, 8, 5, 6])  # cache hit
    other_seed = ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 50.0, n_importance=100, seed=12).bind(dataset)
    assert other_seed.log_likelihood(partitions[0]) != warm.log_likelihood(partitions[0])


def test_rebound_terms_share_the_fits_and_give_the_values_of_fresh_terms(monkeypatch):
    dataset = square_loop_dataset(10, sigma_xy=0.2, sigma_theta=0.05)
    fits = []
    original_fit = ptm.pose_graph.PoseGraph.fit
    monkeypatch.setattr(ptm.pose_graph.PoseGraph, "fit",
                        lambda graph, start, partition: fits.append(1) or original_fit(graph, start, partition))
    partitions = [[0, 1, 2, 3, 0, 1, 2, 3, 0, 1], list(range(10)), [0, 1, 2, 3, 4, 1, 2, 3, 0, 5],
                  [0, 0, 1, 1, 2, 2, 3, 3, 4, 4], [0, 1, 2, 3, 0, 1, 2, 3, 1, 0]]
    models = [ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 50.0, n_importance=100, seed=11),
              ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 50.0, n_importance=100, seed=12),  # the sampler's settings
              ptm.OdometryModel(0.2, 0.05, 0.3, 3.0, 10.0, n_importance=40, seed=13, cache_size=2)]
    first = models[0].bind(dataset)
    terms = [first, first.rebind(models[1])]
    terms.append(terms[1].rebind(models[2]))  # rebound from a rebound term: still the one memo
    values = [[term.log_likelihood(labels) for labels in partitions] for term in terms]
    assert len(fits) == 2 * len(partitions)  # two starts per partition, once between the three terms
    assert terms[2].evaluate(partitions[0]).iterations == first.evaluate(partitions[0]).iterations
    assert len(fits) == 2 * len(partitions)
    for model, row in zip(models, values):
        fresh = model.bind(dataset)
        assert row == pytest.approx([fresh.log_likelihood(labels) for labels in partitions], rel=1e-12, abs=0)
    assert len(set(row[2] for row in values)) == 3  # and the samplers do differ
    for name, value in (("sigma_xy", 0.3), ("sigma_theta", 0.1), ("sigma_topology", 0.5), ("sparse_above", 3)):
        changed = ptm.OdometryModel(**{"sigma_xy": 0.2, "sigma_theta": 0.05, "sigma_topology": 0.3, name: value})
        with pytest.raises(ValueError, match=name):
            first.rebind(changed)


def test_weighting_the_samples_in_chunks_changes_nothing(monkeypatch):
    dataset = square_loop_dataset(100, sigma_xy=0.2, sigma_theta=0.05)
    model = ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 50.0, n_importance=100, seed=3)
    chunked = model.bind(dataset)
    monkeypatch.setattr(ptm.odometry.importance, "IMPORTANCE_CHUNK_BYTES", 1 << 40)
    whole = model.bind(dataset)
    assert len(chunked.sampler.sample_chunks) > 1 and len(whole.sampler.sample_chunks) == 1
    for labels in (dataset.labels, np.arange(100) % 7):
        first, second = chunked.evaluate(labels), whole.evaluate(labels)
        assert first.log_likelihood == pytest.approx(second.log_likelihood, rel=1e-12)
        assert first.ess == pytest.approx(second.ess, rel=1e-9)


def test_sparse_and_banded_low_rank_linear_algebra_agree():
    dataset = square_loop_dataset(14, sigma_xy=0.2, sigma_theta=0.05)
    labels = [0, 1, 2, 3, 0, 1, 2, 3, 0, 4, 2, 3, 0, 1]
    banded = ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 20.0, n_importance=400, seed=0).bind(dataset)
    sparse = ptm.OdometryModel(0.2, 0.05, 0.3, 2.5, 20.0, n_importance=400, seed=0, sparse_above=0).bind(dataset)
    assert not banded.graph.sparse and sparse.graph.sparse
    first, second = banded.evaluate(labels), sparse.evaluate(labels)
    assert first.laplace == pytest.approx(second.laplace, abs=1e-8)
    # the two factors map the same noise to different samples: equal within Monte-Carlo error
    error = math.hypot(first.standard_error, second.standard_error)
    assert abs(first.log_likelihood - second.log_likelihood) < 4 * error + 1e-6


# -- the paper's Fig. 10 and the sampler ---------------------------------------------------------------


@pytest.mark.slow  # two exact enumerations with odometry (8-30 s each on two busy cores)
@pytest.mark.parametrize("max_penalty, winner", [(100.0, "truth"), (0.0, "all_distinct")])
def test_penalty_decides_between_truth_and_all_distinct(max_penalty, winner):
    dataset = square_loop_dataset(7)
    model = ptm.OdometryModel(0.1, 0.03, 0.3, 3.0, max_penalty, n_importance=100, seed=0)
    exact = ptm.exact_posterior(ptm.Posterior(dataset, ptm.PoissonPrior(3.0), [model]))
    truth, all_distinct = ptm.canonical(dataset.labels), tuple(range(7))
    if winner == "truth":
        assert exact.probability(truth) > 0.9
    else:
        assert exact.map() == all_distinct
        assert exact.probability(all_distinct) > 2 * exact.probability(truth)


# Measured for these chain lengths (seeds 5, 6, 7): TV 0.016-0.028 for the correct target, 0.97 for
# the negative control that drops the odometry term; 0.06 is the bound the core's sampler tests use.
TOLERANCE = 0.06


@pytest.mark.slow  # the first test to ask enumerates the N = 7 target (20-90 s on two busy cores)
def test_mcmc_matches_exact_posterior_with_odometry_and_appearance():
    posterior, exact = mixed_target()
    assert exact.entropy() > 1.5  # a spread-out target, not a single spike
    sampled = ptm.mcmc(posterior, 20_000, burn_in=1_000, seed=5, chains=2)
    assert ptm.total_variation(sampled, exact) < TOLERANCE
    assert sampled.diagnostics["odometry"]["cache_hit_rate"] > 0.9


@pytest.mark.slow
def test_negative_control_without_the_odometry_term_fails_the_same_check():
    posterior, exact = mixed_target()
    appearance_only = ptm.Posterior(posterior.dataset, posterior.prior, posterior.terms[:1])
    sampled = ptm.mcmc(appearance_only, 20_000, burn_in=1_000, seed=5, chains=2)
    assert ptm.total_variation(sampled, exact) > 3 * TOLERANCE


def test_same_seed_gives_the_same_ptm():
    first = ptm.mcmc(mixed_posterior(model_seed=4), 3_000, seed=9, chains=2)
    second = ptm.mcmc(mixed_posterior(model_seed=4), 3_000, seed=9, chains=2)
    assert first.top(10) == second.top(10)
    np.testing.assert_array_equal(first.traces["log_prob"], second.traces["log_prob"])


# -- bad input ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("field, value", [("sigma_xy", 0.0), ("sigma_theta", -1.0), ("sigma_topology", math.nan),
                                          ("penalty_radius", 0.0), ("max_penalty", -1.0), ("n_importance", 0)])
def test_bad_parameters_are_refused_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        ptm.OdometryModel(**{field: value})


def test_a_dataset_without_odometry_is_refused():
    with pytest.raises(ValueError, match="odometry"):
        ptm.OdometryModel().bind(ptm.Dataset(signatures=np.ones((4, 2))))


def test_singular_odometry_covariance_is_refused():
    covariances = np.broadcast_to(np.diag([0.01, 0.01, 0.0]), (3, 3, 3))
    with pytest.raises(ValueError, match=r"odometry_cov\[0\] is not positive definite"):
        odometry_sqrt_information(covariances)


def test_dataset_covariance_replaces_the_default():
    dataset = square_loop_dataset(5)
    with_covariance = dataset.replace(odometry_cov=np.broadcast_to(np.diag([0.04, 0.04, 0.01]), (4, 3, 3)))
    from_parameters = ptm.OdometryModel(0.2, 0.1, 0.3, 2.5, 10.0, seed=2).bind(dataset)
    from_dataset = ptm.OdometryModel(5.0, 5.0, 0.3, 2.5, 10.0, seed=2).bind(with_covariance)
    labels = [0, 1, 2, 3, 0]
    assert from_dataset.log_likelihood(labels) == pytest.approx(from_parameters.log_likelihood(labels), rel=1e-10)


def test_a_fit_that_does_not_converge_is_recorded_not_hidden():
    dataset = square_loop_dataset(8, sigma_xy=0.3, sigma_theta=0.1)
    term = ptm.OdometryModel(0.1, 0.03, 0.3, 2.5, 100.0).bind(dataset)
    term.graph.max_iterations = 1
    value = term.log_likelihood([0] * 8)  # everything at one place: far from dead reckoning
    assert math.isfinite(value)
    assert term.diagnostics()["failures"] == 1


def test_poses_from_vector_fixes_the_first_pose_at_the_origin():
    poses = poses_from_vector(np.arange(6.0))
    np.testing.assert_array_equal(poses, [[0, 0, 0], [0, 1, 2], [3, 4, 5]])


def test_a_single_detection_has_likelihood_one_and_two_detections_work():
    single = ptm.Dataset(odometry=np.zeros((0, 3)), labels=[0])
    assert ptm.OdometryModel().bind(single).log_likelihood([0]) == 0.0
    pair = ptm.Dataset(odometry=[[1.0, 0.0, 0.1]], labels=[0, 0])
    term = ptm.OdometryModel(max_penalty=0.0, n_importance=400).bind(pair)
    evaluation = term.evaluate([0, 1])  # no tie, no penalty: the Gaussian normaliser of one step
    assert evaluation.laplace == pytest.approx(0.5 * math.log((2 * math.pi) ** 3 * 0.1**4 * 0.05**2), abs=1e-9)
    assert math.isfinite(term.log_likelihood([0, 0]))
