"""The Laplace fit of docs/model.md §3.3 on large graphs: convergence, history-free values, an independent oracle.

* An oracle that shares no code with :mod:`ptm.pose_graph`: the energy, its
  residuals and their Jacobian written out densely here with numpy, minimised
  by plain Levenberg-Marquardt Gauss-Newton; energies and log det H of the
  Gauss-Newton Hessian agree with the solver to 1e-6 nats on the true
  partition of a 107-detection corridor grid.
* The odometry log-likelihood is a function of the partition: the same
  partitions evaluated after different histories (fresh terms, warm terms
  that saw other partitions first, in other orders) agree to 1e-9 relative,
  on a graph where the energy does have several minima.
* Failed fits are recorded per partition and never give NaN.

    python -m pytest tests/test_pose_graph_oracle.py -q
"""

import math
from pathlib import Path

import numpy as np
import pytest

import ptm

SIGMA_XY, SIGMA_THETA, SIGMA_TOPOLOGY = 0.2, 0.1, 0.3


def wrap(angle):
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def corridor_grid_dataset(n, side=10, spacing=3.0, seed=0):
    """N detections of a robot walking the junctions of a side x side corridor grid (one detection per
    junction reached, half the time straight on), its odometry the true relative poses plus Gaussian noise."""
    walk_rng, odometry_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    cell, heading, cells = np.array([0, 0]), np.array([1, 0]), [np.array([0, 0])]
    while len(cells) < n:
        options = [np.array(d) for d in ([1, 0], [-1, 0], [0, 1], [0, -1])
                   if np.all((0 <= cell + d) & (cell + d < side))]
        straight = [d for d in options if np.array_equal(d, heading)]
        heading = straight[0] if straight and walk_rng.random() < 0.5 else options[walk_rng.integers(len(options))]
        cell = cell + heading
        cells.append(cell)
    cells = np.array(cells)
    headings = np.concatenate([[0.0], np.arctan2(*(cells[1:] - cells[:-1]).T[::-1])])
    poses = np.column_stack([spacing * cells, wrap(headings)])
    odometry = relative_poses(poses[:-1], poses[1:])
    odometry += odometry_rng.normal(0.0, [SIGMA_XY, SIGMA_XY, SIGMA_THETA], size=odometry.shape)
    return ptm.Dataset(odometry=odometry, labels=cells[:, 0] * side + cells[:, 1], true_poses=poses)


def relative_poses(frames, poses):
    """Each of ``poses`` (M, 3) in the frame of the matching row of ``frames``, its heading wrapped."""
    cos, sin = np.cos(frames[:, 2]), np.sin(frames[:, 2])
    delta = poses[:, :2] - frames[:, :2]
    return np.column_stack([cos * delta[:, 0] + sin * delta[:, 1], -sin * delta[:, 0] + cos * delta[:, 1],
                            wrap(poses[:, 2] - frames[:, 2])])


def model(seed=0):
    return ptm.OdometryModel(SIGMA_XY, SIGMA_THETA, SIGMA_TOPOLOGY, 2.5, 100.0, n_importance=100, seed=seed)


# -- the oracle: dense residuals, Jacobian and Gauss-Newton, written from docs/model.md §3.3 alone ---------


def oracle_residuals(x, odometry, labels, covariances=None, sigma_topology=SIGMA_TOPOLOGY):
    """Whitened residuals (odometry rows, then one 2-vector per tied pair) and their dense Jacobian; each row
    whitened by its covariance's inverse Cholesky factor where ``covariances`` are given."""
    n = len(odometry) + 1
    poses = np.vstack([np.zeros(3), x.reshape(n - 1, 3)])
    whitens = (np.tile(np.diag([1.0 / SIGMA_XY, 1.0 / SIGMA_XY, 1.0 / SIGMA_THETA]), (n - 1, 1, 1))
               if covariances is None else np.linalg.cholesky(np.linalg.inv(covariances)).transpose(0, 2, 1))
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n) if labels[i] == labels[j]]
    residuals = np.zeros(3 * (n - 1) + 2 * len(pairs))
    jacobian = np.zeros((len(residuals), 3 * (n - 1)))

    def columns(pose):  # pose 0 is fixed at the origin: no columns
        return slice(3 * (pose - 1), 3 * pose) if pose > 0 else None

    for k in range(1, n):
        theta = poses[k - 1, 2]
        rotation_t = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
        u, v = rotation_t @ (poses[k, :2] - poses[k - 1, :2])
        raw = np.array([u - odometry[k - 1, 0], v - odometry[k - 1, 1],
                        wrap(poses[k, 2] - theta - odometry[k - 1, 2])])
        row = slice(3 * (k - 1), 3 * k)
        whiten = whitens[k - 1]
        residuals[row] = whiten @ raw
        current = np.zeros((3, 3))
        current[:2, :2], current[2, 2] = rotation_t, 1.0
        jacobian[row, columns(k)] = whiten @ current
        if k > 1:
            previous = np.zeros((3, 3))
            previous[:2, :2], previous[:2, 2], previous[2, 2] = -rotation_t, [v, -u], -1.0
            jacobian[row, columns(k - 1)] = whiten @ previous
    for q, (i, j) in enumerate(pairs):
        row = slice(3 * (n - 1) + 2 * q, 3 * (n - 1) + 2 * q + 2)
        residuals[row] = (poses[i, :2] - poses[j, :2]) / sigma_topology
        for pose, sign in ((i, 1.0), (j, -1.0)):
            if pose > 0:
                jacobian[row, 3 * (pose - 1):3 * (pose - 1) + 2] = sign * np.eye(2) / sigma_topology
    return residuals, jacobian


def oracle_fit(odometry, labels, covariances=None, sigma_topology=SIGMA_TOPOLOGY, start=None):
    """Levenberg-Marquardt Gauss-Newton from ``start`` (the free poses flattened; dead reckoning if None) to
    |step| < 1e-12; (energy, log det J^T J, x)."""
    n = len(odometry) + 1
    poses = [np.zeros(3)]
    for row in odometry:  # dead reckoning, composed here
        x, y, theta = poses[-1]
        poses.append([x + np.cos(theta) * row[0] - np.sin(theta) * row[1],
                      y + np.sin(theta) * row[0] + np.cos(theta) * row[1], wrap(theta + row[2])])
    x = np.array(poses[1:]).ravel() if start is None else np.asarray(start, dtype=float)
    residuals, jacobian = oracle_residuals(x, odometry, labels, covariances, sigma_topology)
    energy, damping = 0.5 * residuals @ residuals, 1e-3
    for _ in range(500):
        hessian, gradient = jacobian.T @ jacobian, jacobian.T @ residuals
        step = -np.linalg.solve(hessian + damping * np.diag(np.diag(hessian)), gradient)
        new_residuals, new_jacobian = oracle_residuals(x + step, odometry, labels, covariances, sigma_topology)
        new_energy = 0.5 * new_residuals @ new_residuals
        if new_energy <= energy:
            x, residuals, jacobian, energy, damping = x + step, new_residuals, new_jacobian, new_energy, damping / 3
            if np.max(np.abs(step)) < 1e-12:
                break
        else:
            damping *= 4
    else:
        raise AssertionError("the oracle did not converge")
    sign, log_det = np.linalg.slogdet(jacobian.T @ jacobian)
    assert sign > 0 and n > 1
    return energy, log_det, x


def test_energy_and_laplace_value_agree_with_a_dense_oracle_on_a_107_detection_grid():
    dataset = corridor_grid_dataset(107, seed=0)
    term = model().bind(dataset)
    energy, log_det, x = oracle_fit(dataset.odometry, dataset.labels)
    fit = term.fit(ptm.canonical(dataset.labels))
    assert fit.converged
    assert fit.energy == pytest.approx(energy, abs=1e-6)
    assert fit.factor.log_det() == pytest.approx(log_det, abs=1e-6)
    laplace = -energy + 0.5 * len(x) * math.log(2 * math.pi) - 0.5 * log_det
    assert term.evaluate(dataset.labels).laplace == pytest.approx(laplace, abs=1e-6)
    difference = (fit.x - x).reshape(-1, 3)
    difference[:, 2] = wrap(difference[:, 2])  # headings are defined modulo 2 pi (the residual wraps)
    np.testing.assert_allclose(difference, 0.0, atol=1e-6)
    # both solvers fitted an energy with loop closures in it: far from dead reckoning's zero odometry energy
    assert energy > 10.0


@pytest.mark.parametrize("n, seed", [(107, 0), (178, 1)])
def test_the_fit_of_the_true_partition_converges_on_large_grids(n, seed):
    dataset = corridor_grid_dataset(n, seed=seed)
    graph = model().bind(dataset).graph
    for start in (graph.dead_reckoning(), graph.chordal_start(dataset.labels)):
        fit = graph.fit(start, dataset.labels)
        assert fit.converged and fit.failure == ""
        assert fit.iterations < 60  # measured: 10-26 (the cap is 200)


def test_the_chordal_headings_are_exact_where_the_odometry_is():
    # Noise-free odometry of a 60-detection grid walk with its loops closed: every relaxed residual is zero at
    # the true poses, so the relaxation's least-squares solution is theirs and its headings are exact.
    dataset = corridor_grid_dataset(60, seed=4)
    poses = dataset.true_poses
    exact = relative_poses(poses[:-1], poses[1:])
    graph = model().bind(ptm.Dataset(odometry=exact)).graph
    headings = ptm.pose_graph.chordal_headings(exact, graph.information, graph.topology(dataset.labels))
    np.testing.assert_allclose(wrap(headings - poses[1:, 2]), 0.0, atol=1e-9)
    # with noise the relaxation is no longer exact, but it is closer to the truth than dead reckoning
    noisy = model().bind(dataset).graph
    relaxed = ptm.pose_graph.chordal_headings(dataset.odometry, noisy.information, noisy.topology(dataset.labels))
    dead_reckoned = noisy.dead_reckoning()[2::3]
    assert np.abs(wrap(relaxed - poses[1:, 2])).mean() < np.abs(wrap(dead_reckoned - poses[1:, 2])).mean()


def in_frame_of_the_first(poses):
    """The free poses 1..N-1 of ``poses`` (N, 3) in the frame of pose 0, flattened: a state vector."""
    return relative_poses(np.broadcast_to(poses[0], poses[1:].shape), poses[1:]).ravel()


def test_the_chordal_start_reaches_the_minimum_that_dead_reckoning_misses_on_a_208_detection_run():
    # A simulated 14 x 14 corridor grid (208 detections of 113 places). Its dead-reckoned heading drifts so far
    # that a fit of the true partition from dead reckoning, with or without its positions moved to their optimum
    # given the dead-reckoned headings, ends in a minimum hundreds of nats above the one near the true poses;
    # the chordal relaxation's headings start the fit in the right basin, and the term's fit is that one.
    recorded = np.load(Path(__file__).parent / "data" / "grid208_odometry.npz")
    dataset = ptm.Dataset(odometry=recorded["odometry"], odometry_cov=recorded["odometry_cov"])
    labels, sigma_topology = recorded["labels"], float(recorded["sigma_topology"])
    energy, log_det, _ = oracle_fit(dataset.odometry, labels, dataset.odometry_cov, sigma_topology,
                                    start=in_frame_of_the_first(recorded["true_poses"]))
    term = ptm.OdometryModel(0.1, 0.05, sigma_topology, float(recorded["penalty_radius"]), 100.0).bind(dataset)
    fit = term.fit(labels)
    assert fit.converged
    assert fit.energy == pytest.approx(energy, abs=1e-6)
    assert fit.factor.log_det() == pytest.approx(log_det, abs=1e-6)
    # the negative controls: the fits from dead reckoning alone (measured: 862 nats above, both)
    graph, topology = term.graph, term.graph.topology(labels)
    for start in (graph.dead_reckoning(), graph.positions_given_headings(graph.dead_reckoning(), topology)):
        missed = graph.fit(start, topology)
        assert missed.converged and missed.energy > energy + 500.0


def test_the_fit_converges_where_the_trajectory_can_bend_almost_freely():
    # The first 70 detections of a simulated 10 x 10 corridor grid: long legs between places with per-step
    # covariances up to 1.8 m^2, held by ties of sigma_T = 2 m, so the Hessian's smallest eigenvalue is 4e-10
    # of its largest. Without the solver's line search the damping cuts the Newton steps along that bend to
    # nothing, and the fit runs out of iterations short of the minimum.
    recorded = np.load(Path(__file__).parent / "data" / "grid70_odometry.npz")
    dataset = ptm.Dataset(odometry=recorded["odometry"], odometry_cov=recorded["odometry_cov"])
    labels, sigma_topology = recorded["labels"], float(recorded["sigma_topology"])
    term = ptm.OdometryModel(SIGMA_XY, SIGMA_THETA, sigma_topology, float(recorded["penalty_radius"]), 100.0,
                             n_importance=100, seed=0).bind(dataset)
    energy, log_det, _ = oracle_fit(dataset.odometry, labels, dataset.odometry_cov, sigma_topology)
    topology = term.graph.topology(labels)
    for start in term.fitter.starts(topology):
        fit = term.graph.fit(start, topology)
        assert fit.converged and fit.failure == ""
        assert fit.iterations < 100  # measured: 49 and 50
        assert fit.energy == pytest.approx(energy, abs=1e-6)
        assert fit.factor.log_det() == pytest.approx(log_det, abs=1e-6)


# -- the value is a function of the partition ---------------------------------------------------------------


def test_the_value_of_a_partition_does_not_depend_on_what_was_evaluated_before():
    dataset = corridor_grid_dataset(60, seed=3)
    n, rng = dataset.n, np.random.default_rng(0)
    truth = ptm.canonical(dataset.labels)
    one_off = np.array(truth)
    one_off[[17, 41]] = one_off.max() + 1
    partitions = [truth, tuple(one_off), tuple(np.arange(n) % 7), tuple(rng.integers(0, 12, n)),
                  tuple(rng.integers(0, 25, n)), tuple(np.arange(n) // 2), tuple(range(n))]
    fresh = [model().bind(dataset).evaluate(labels).log_likelihood for labels in partitions]
    histories = [list(range(len(partitions))), list(range(len(partitions)))[::-1],
                 list(rng.permutation(len(partitions)))]
    for history in histories:
        term = model().bind(dataset)
        for extra in rng.integers(0, 30, size=(3, n)):  # some other partitions first
            term.evaluate(extra)
        for index in history:
            value = term.evaluate(partitions[index]).log_likelihood
            assert value == pytest.approx(fresh[index], rel=1e-9, abs=0.0), (history, index)
    # the test has teeth: the energy has several minima here, and a start from another partition's optimum
    # (what a warm start did) reaches a different one for some of these partitions
    term = model().bind(dataset)
    optima = [term.fit(labels) for labels in partitions]
    gaps = [abs(term.graph.fit(other.x, labels).energy - fit.energy)
            for labels, fit in zip(partitions, optima) for other in optima]
    assert max(gaps) > 1.0


# -- failures -------------------------------------------------------------------------------------------------


def test_a_non_finite_energy_ends_the_fit_at_once_and_is_marked():
    dataset = corridor_grid_dataset(20, seed=2)
    graph = model().bind(dataset).graph
    start = graph.dead_reckoning()
    start[4] = np.nan
    fit = graph.fit(start, dataset.labels)
    assert not fit.converged and fit.factor is None and "non-finite" in fit.failure


def test_failed_fits_are_listed_per_partition_and_never_give_nan():
    dataset = corridor_grid_dataset(20, seed=2)
    term = model().bind(dataset)
    term.graph.max_iterations = 1
    labels = [0] * 20  # everything at one place: far from either start
    value = term.log_likelihood(labels)
    assert math.isfinite(value)  # the documented fallback: the Gaussian at the last iterate
    diagnostics = term.diagnostics()
    assert diagnostics["failures"] == 1 and diagnostics["failures_minus_inf"] == 0
    [failed] = diagnostics["failed_partitions"]
    assert failed["labels"] == labels and "iterations" in failed["reason"] and "last iterate" in failed["fallback"]


def test_the_damping_falls_geometrically_never_from_1e_3_straight_to_0(monkeypatch):
    dataset = corridor_grid_dataset(60, seed=3)
    graph = model().bind(dataset).graph
    used = []  # the damping of each damped factorisation (0: undamped), in order
    factorise = graph.factorise

    def recording(topology, blocks, added_diagonal=None):
        if added_diagonal is not None:
            used.append(float(np.median(added_diagonal / recording.scale)))
        return factorise(topology, blocks, added_diagonal)

    linearise = ptm.pose_graph.solver.Linearisation.damping_scale.func

    def scale(self):  # remember the scale the damping multiplies, to read lambda back
        recording.scale = linearise(self)
        return recording.scale

    monkeypatch.setattr(ptm.pose_graph.solver.Linearisation, "damping_scale", property(scale))
    monkeypatch.setattr(graph, "factorise", recording)
    fits = [graph.fit(graph.dead_reckoning(), labels)
            for labels in np.random.default_rng(1).integers(0, 8, size=(4, dataset.n))]
    assert all(fit.converged for fit in fits)
    assert len(used) > 20  # the implausible partitions needed damping
    falls = [(before, after) for before, after in zip(used, used[1:]) if after < before]
    assert falls and all(after >= before / 3.0 * (1 - 1e-12) for before, after in falls)
    assert min(used) >= 1e-6 * (1 - 1e-12)  # below that it is dropped (an undamped factorisation)


def test_a_fit_without_a_usable_hessian_gives_minus_infinity_not_nan(monkeypatch):
    dataset = corridor_grid_dataset(20, seed=2)
    term = model().bind(dataset)
    nowhere = np.full(term.dimension, np.nan)
    monkeypatch.setattr(term.fitter, "starts", lambda topology: (nowhere, nowhere))
    assert term.log_likelihood(dataset.labels) == -math.inf
    diagnostics = term.diagnostics()
    assert diagnostics["failures"] == diagnostics["failures_minus_inf"] == 1
    assert diagnostics["failed_partitions"][0]["fallback"] == "-inf"
