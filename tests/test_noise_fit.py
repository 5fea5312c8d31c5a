"""The odometry noise fit recovers the simulator's noise parameters from raw against reference increments."""

from __future__ import annotations

import numpy as np
import pytest

from ptm.se2 import dead_reckoning

from ptm_bench.logs.carmen import CarmenLog
from ptm_bench.logs.noise_fit import (ON_THE_SPOT, corrected_increments, fit_noise, motion_components,
                                      split_calibration_drive, systematic_errors)
from ptm_bench.simulation.odometry_noise import OdometryNoise, decompose, sample_odometry


def _synthetic_log(noise: OdometryNoise, seed: int, steps: int = 3000, turn_jitter: float = 0.0) -> CarmenLog:
    """A random drive whose raw odometry has ``noise``; the reference is the true trajectory, its headings off
    by an error of sd ``turn_jitter`` x the scan's turn that does not accumulate (a scan matcher's)."""
    rng = np.random.default_rng(seed)
    motion = np.column_stack([rng.uniform(0.3, 1.0, steps), rng.normal(0, 0.05, steps), rng.normal(0, 0.4, steps)])
    truth = dead_reckoning(motion)
    raw = sample_odometry(truth, noise, rng)
    reference = truth + np.outer(turn_jitter * np.abs(np.r_[0.0, motion[:, 2]]) * rng.standard_normal(steps + 1),
                                 [0.0, 0.0, 1.0])
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
    scales = [systematic_errors(log)[0] for log in logs]
    assert fit.model.scale_sigma == pytest.approx(np.sqrt(np.mean(np.square(scales))))
    rows, covariances = fit.row_covariances(logs[0].raw_increments, [0, 10, 25])
    assert rows.shape == (2, 3) and np.all(np.linalg.eigvalsh(covariances) > 0)


def test_a_fit_over_windows_sees_the_noise_that_accumulates_not_the_references_jitter():
    """Without jitter, the fit over 3 m windows (the rows' scale) recovers alpha1 as the per-scan fit does.
    With a reference whose heading errs with every turn without accumulating, the per-scan fit reads that
    jitter as odometry noise, alpha1 more than three times too large; compared over windows, the jitter of
    the scans between a window's ends cancels, and alpha1 is at most about twice the truth."""
    truth = OdometryNoise(alpha1=0.02, alpha2=0.005, alpha3=0.03, alpha4=0.01, scale_sigma=0.0, drift_sigma=0.0)
    clean = [_synthetic_log(truth, seed, steps=2000) for seed in (0, 1)]
    assert fit_noise(clean).model.alpha1 == pytest.approx(0.02, rel=0.1)
    windowed = fit_noise(clean, window=3.0)
    assert windowed.model.alpha1 == pytest.approx(0.02, rel=0.1) and windowed.window == 3.0
    jittery = [_synthetic_log(truth, seed, steps=2000, turn_jitter=0.1) for seed in (0, 1)]
    assert fit_noise(jittery).model.alpha1 > 3.0 * 0.02
    assert fit_noise(jittery, window=6.0).model.alpha1 < 2.0 * 0.02
    with pytest.raises(ValueError, match="shorter than one window"):
        fit_noise(clean, window=1e6)


def test_fit_needs_a_log():
    with pytest.raises(ValueError, match="at least one log"):
        fit_noise([])


def test_a_turn_on_the_spot_and_a_reverse_turn_no_further_than_they_do():
    """rot1 of a scan that barely moves is its heading, not the direction of a few millimetres' jitter; a
    step backwards is a reverse, not a half turn: alpha1 |rot1| then charges the turn the robot made."""
    increments = np.array([[-0.002, 0.003, 0.10],   # turning on the spot, jittering back and sideways
                           [-0.30, 0.01, 0.02],     # backing up 30 cm
                           [0.50, 0.05, 0.05]])     # driving on
    rot1, trans, rot2 = motion_components(increments)
    literal_rot1, _, _ = decompose(increments)
    assert abs(literal_rot1[0]) > 2.0 and abs(literal_rot1[1]) > 3.0  # what the literal reading charged
    assert rot1[0] == 0.0 and rot2[0] == pytest.approx(0.10) and abs(trans[0]) < ON_THE_SPOT
    assert trans[1] == pytest.approx(-np.hypot(0.30, 0.01)) and abs(rot1[1]) < 0.05
    np.testing.assert_allclose(rot1[2], np.arctan2(0.05, 0.50))
    recomposed = np.stack([trans * np.cos(rot1), trans * np.sin(rot1), rot1 + rot2], axis=-1)
    np.testing.assert_allclose(recomposed[1:], increments[1:], atol=1e-12)  # a reverse is the same motion
    np.testing.assert_allclose(recomposed[0, 2], increments[0, 2])


def test_corrected_increments_undo_the_systematic_errors():
    """Odometry with a scale error s and a heading drift d (trans' = (1 + s) trans, rot2' = rot2 + d trans),
    corrected with them, is the true motion; driving forwards, the simulator's noise-free odometry is such."""
    noise = OdometryNoise(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, scale_sigma=0.03, drift_sigma=0.02)
    rng = np.random.default_rng(3)
    motion = np.column_stack([rng.uniform(0.1, 1.0, 200), rng.normal(0, 0.02, 200), rng.normal(0, 0.3, 200)])
    measured = sample_odometry(dead_reckoning(motion), noise, rng)
    corrected = corrected_increments(measured.increments, measured.scale_error, measured.heading_drift)
    np.testing.assert_allclose(corrected, motion, atol=1e-9)
    assert np.abs(measured.increments - motion).max() > 1e-3
    backwards = np.array([[-0.5, 0.0, 0.0]])  # a reverse: the drift follows the signed distance
    np.testing.assert_allclose(corrected_increments(backwards * [1.1, 1.0, 1.0] + [0.0, 0.0, -0.5 * 0.02], 0.1, 0.02),
                               backwards, atol=1e-12)


def test_a_calibration_drive_leaves_the_spread_between_its_errors_and_the_rest_of_the_run():
    """With a drive, the systematic sigmas are how far each log's drive misses its rest (root mean square),
    not the spread between robots; the alphas do not depend on it."""
    logs = [_synthetic_log(OdometryNoise(scale_sigma=0.02, drift_sigma=0.02), seed, steps=800) for seed in (4, 5)]
    between_robots, driven = fit_noise(logs), fit_noise(logs, calibration_drive=100.0)
    differences = []
    for log in logs:
        drive, rest = split_calibration_drive(log, 100.0)
        assert drive.n_scans + rest.n_scans == log.n_scans + 1 and drive.path_length() >= 100.0
        differences.append(np.subtract(systematic_errors(rest), systematic_errors(drive)))
    np.testing.assert_allclose([driven.model.scale_sigma, driven.model.drift_sigma],
                               np.sqrt(np.mean(np.square(differences), axis=0)))
    assert driven.model.drift_sigma < 0.2 * between_robots.model.drift_sigma  # one robot's drift is steady
    assert driven.model.alpha1 == between_robots.model.alpha1 and driven.calibration_drive == 100.0
    with pytest.raises(ValueError, match="shorter than 5000 m"):
        fit_noise(logs, calibration_drive=5000.0)
