"""The ``odometry`` section of ``ptm-bench speed``: cost of the odometry likelihood (docs/model.md §3.3).

Measures, on synthetic routes (a robot visiting about N/3 places on a 5 m
grid in random order, odometry composed on SE(2) with noise):

* the median wall (and process CPU) time of one log P(O | T) evaluation on a cache miss
  (Laplace fit from the history-free starts of docs/model.md §3.3, plus importance
  sampling with ``n_importance = 100``) at N = 10, 50, 100, 200, for
  partitions one Gibbs move away from the truth, as a sampler proposes them, with the
  weights' mean ESS and Monte-Carlo standard error;
* the odometry cache hit rate, the number of evaluations and the MH steps per second of one
  chain of the default moves with odometry + appearance at N = 50, from the truth, with plain
  and with delayed acceptance (docs/model.md §3.4).

    $ ptm-bench speed --section odometry
    $ ptm-bench speed --section odometry --scale 0.2   # quicker, noisier
"""

from __future__ import annotations

import time

import numpy as np

import ptm
from ptm.se2 import relative_pose, wrap_angle

EVALUATION_SIZES = (10, 50, 100, 200)
CHAIN_SIZE = 50
N_IMPORTANCE = 100


def synthetic_route_dataset(n: int, seed: int = 0, spacing: float = 5.0) -> ptm.Dataset:
    """N detections of a robot touring about N/3 grid places in random order, with appearance."""
    route_rng, odometry_rng, appearance_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    places = max(2, n // 3)
    side = int(np.ceil(np.sqrt(places)))
    grid = spacing * np.array([(i % side, i // side) for i in range(places)], dtype=float)
    labels = np.concatenate([[0], route_rng.integers(0, places, size=n - 1)])
    repeats = np.flatnonzero(labels[1:] == labels[:-1]) + 1
    labels[repeats] = (labels[repeats] + 1) % places  # the robot moves between detections
    positions = grid[labels]
    headings = np.zeros(n)
    headings[1:] = np.arctan2(*(positions[1:] - positions[:-1]).T[::-1])
    poses = np.column_stack([positions, wrap_angle(headings)])
    odometry = relative_pose(poses[:-1], poses[1:])
    odometry += odometry_rng.normal(0.0, [0.1, 0.1, 0.02], size=odometry.shape)
    place_signatures = appearance_rng.uniform(0.05, 0.5, size=(places, 5))
    signatures = np.abs(place_signatures[labels] + appearance_rng.normal(0.0, 0.01, size=(n, 5)))
    return ptm.Dataset(odometry=odometry, signatures=signatures, labels=labels, true_poses=poses)


def odometry_model(seed: int = 0) -> ptm.OdometryModel:
    """The benchmark's model."""
    return ptm.OdometryModel(sigma_xy=0.1, sigma_theta=0.02, sigma_topology=0.3, penalty_radius=2.5,
                             max_penalty=100.0, n_importance=N_IMPORTANCE, seed=seed)


def neighbouring_partitions(labels, count: int, rng) -> list[np.ndarray]:
    """``count`` partitions, each the truth with one detection moved to another (or a new) place."""
    out = []
    for _ in range(count):
        moved = np.array(labels)
        moved[rng.integers(len(moved))] = rng.integers(moved.max() + 2)
        out.append(moved)
    return out


def odometry_rows(args) -> list[dict]:
    rows = []
    evaluations = max(10, int(60 * args.scale))
    for n in EVALUATION_SIZES:
        dataset = synthetic_route_dataset(n)
        term = odometry_model().bind(dataset)
        wall, cpu = [], []
        term.evaluate(dataset.labels)  # the chain's current state
        for labels in neighbouring_partitions(dataset.labels, evaluations, np.random.default_rng(n)):
            started_wall, started_cpu = time.perf_counter(), time.process_time()
            term.evaluate(labels)
            wall.append(time.perf_counter() - started_wall)
            cpu.append(time.process_time() - started_cpu)
        diagnostics = term.diagnostics()
        rows += [
            {"section": "odometry", "metric": "evaluation_median_ms_cache_miss", "n": n,
             "value": 1e3 * float(np.median(wall)), "unit": "ms"},
            {"section": "odometry", "metric": "evaluation_median_cpu_ms_cache_miss", "n": n,
             "value": 1e3 * float(np.median(cpu)), "unit": "ms (process CPU)"},
            {"section": "odometry", "metric": "importance_ess_mean", "n": n,
             "value": diagnostics["ess_mean"], "unit": f"of {N_IMPORTANCE}"},
            {"section": "odometry", "metric": "mc_standard_error_mean", "n": n,
             "value": diagnostics["mc_standard_error_mean"], "unit": "nats"},
            {"section": "odometry", "metric": "newton_iterations_mean", "n": n,
             "value": diagnostics["lm_iterations_mean"], "unit": "iterations"},
            {"section": "odometry", "metric": "factorisations_mean", "n": n,
             "value": diagnostics["factorisations_mean"], "unit": "per evaluation"},
        ]
    steps = max(500, int(5_000 * args.scale))
    dataset = synthetic_route_dataset(CHAIN_SIZE)
    appearance = ptm.AppearanceModel(mu=0.25, kappa=0.1, alpha=3.0, beta=2.0 * 0.01**2)
    for name in ("plain", "delayed_acceptance"):
        posterior = ptm.Posterior(dataset, ptm.PoissonPrior(rate=CHAIN_SIZE / 3), [appearance, odometry_model()])
        started = time.perf_counter()
        result = ptm.mcmc(posterior, steps, seed=1, chains=1, start=dataset.labels, burn_in=0, max_doublings=0,
                          moves="default", delayed_acceptance=name != "plain")
        rate = steps / (time.perf_counter() - started)
        odometry = result.diagnostics["odometry"]
        rows += [
            {"section": "odometry", "metric": f"mh_steps_per_s_odometry_appearance_{name}", "n": CHAIN_SIZE,
             "value": rate, "unit": "steps/s"},
            {"section": "odometry", "metric": f"cache_hit_rate_{name}", "n": CHAIN_SIZE,
             "value": odometry["cache_hit_rate"], "unit": "fraction"},
            {"section": "odometry", "metric": f"evaluations_{name}", "n": CHAIN_SIZE,
             "value": odometry["evaluations"], "unit": f"of {steps} steps"},
        ]
    return rows
