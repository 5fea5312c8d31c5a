"""The odometry noise fit recovers the simulator's noise parameters from raw against reference increments."""

from __future__ import annotations

import numpy as np
import pytest

from ptm.se2 import dead_reckoning

from ptm_bench.logs.carmen import CarmenLog
from ptm_bench.logs.noise_fit import fit_noise, systematic_errors
from ptm_bench.simulation.odometry_noise import OdometryNoise, sample_odometry


def _synthetic_log(noise: OdometryNoise, seed: int, steps: int = 3000) -> CarmenLog:
    rng = np.random.default_rng(seed)
    motion = np.column_stack([rng.uniform(0.3, 1.0, steps), rng.normal(0, 0.05, steps), rng.normal(0, 0.4, steps)])
    reference = dead_reckoning(motion)
    raw = sample_odometry(reference, noise, rng)
    n = len(reference)
    return CarmenLog(source=f"sim{seed}.log", form="plain", timestamps=np.arange(n, dtype=float), ranges=(),
                     scan_poses=reference, raw_increments=raw.increments, reference=reference, lines=np.arange(n))


def test_fit_recovers_alphas_and_systematic_errors():
    truth = OdometryNoise(alpha1=0.3, alpha2=0.01, alpha3=0.04, alpha4=0.01, scale_sigma=0.02, drift_sigma=0.01)
    logs = [_synthetic_log(truth, seed) for seed in (0, 1)]
    fit = fit_noise(logs)
    assert fit.model.alpha1 == pytest.approx(0.3, rel=0.1)
    assert fit.model.alpha3 == pytest.approx(0.04, rel=0.15)
    assert fit.floor_xy < 0.01 and fit.floor_theta < 0.01  # no floor in the simulated noise
    scale, drift = systematic_errors(logs[0])
    assert fit.per_log["sim0"] == {"scans": 3001, "scale_error": round(scale, 6), "heading_drift": round(drift, 6)}
    assert fit.model.scale_sigma == pytest.approx(np.sqrt(np.mean([entry["scale_error"] ** 2 for entry in fit.per_log.values()])))
    rows, covariances = fit.row_covariances(logs[0].raw_increments, [0, 10, 25])
    assert rows.shape == (2, 3) and np.all(np.linalg.eigvalsh(covariances) > 0)


def test_fit_needs_a_log():
    with pytest.raises(ValueError, match="at least one log"):
        fit_noise([])
