"""The odometry noise fit recovers the simulator's noise parameters from raw against reference increments."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ptm.se2 import dead_reckoning

from ptm_bench.logs.carmen import SHIPPED_LOGS, CarmenLog, read_carmen, shipped_log
from ptm_bench.logs.noise_fit import (ON_THE_SPOT, SIGNIFICANT, NoiseFit, calibrate_on_drive, corrected_increments,
                                      fit_noise, motion_components, split_calibration_drive, systematic_errors,
                                      systematic_sigmas)
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
    on_the_spot = np.array([[-0.002, 0.003, 0.10], [0.5, 0.05, 0.05]])  # uncorrected, a turn's jitter stays put
    np.testing.assert_allclose(corrected_increments(on_the_spot, 0.0, 0.0), on_the_spot, atol=1e-12)


def test_a_calibration_drive_leaves_the_spread_between_its_errors_and_the_rest_of_the_run():
    """With a drive, the systematic sigmas are how far each stretch of the drive's length misses the rest of its
    log (root mean square over every stretch of every log), not the spread between robots; the alphas do not
    depend on it."""
    logs = [_synthetic_log(OdometryNoise(scale_sigma=0.02, drift_sigma=0.02), seed, steps=800) for seed in (4, 5)]
    between_robots, driven = fit_noise(logs), fit_noise(logs, calibration_drive=100.0)
    differences = []
    for log in logs:
        _, trans, _ = motion_components(log.reference_increments())
        ends = [log.scan_at_path_length(metres) for metres in np.arange(100.0, log.path_length(), 100.0)]
        whole = np.array(systematic_errors(log))
        for start, stop in zip([0] + ends[:-1], ends):
            drive = log.segment(start, stop + 1)
            stretch, weight = np.array(systematic_errors(drive)), np.sum(trans[start:stop] ** 2)
            rest = (whole * np.sum(trans ** 2) - stretch * weight) / (np.sum(trans ** 2) - weight)
            differences.append(stretch - rest)
    assert len(differences) >= 10
    np.testing.assert_allclose([driven.model.scale_sigma, driven.model.drift_sigma],
                               np.sqrt(np.mean(np.square(differences), axis=0)))
    assert driven.model.drift_sigma < 0.2 * between_robots.model.drift_sigma  # one robot's drift is steady
    assert driven.model.alpha1 == between_robots.model.alpha1 and driven.calibration_drive == 100.0
    with pytest.raises(ValueError, match="shorter than 5000 m"):
        fit_noise(logs, calibration_drive=5000.0)


def test_a_drive_takes_out_only_what_it_tells_from_zero_and_the_rows_carry_the_rest():
    """A drift more than SIGNIFICANT sigmas from zero is taken out and the rows keep sigma; one within is left
    in, and the rows carry it: sqrt(d^2 + sigma^2). (Before: whatever the drive measured was taken out.)"""
    log = _synthetic_log(OdometryNoise(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, scale_sigma=0.0,
                                       drift_sigma=0.0), 6, steps=100)
    noise = NoiseFit(OdometryNoise(scale_sigma=0.01, drift_sigma=0.002), 0.05, 0.02, {"other": {}}, 25.0, 4.5)
    for drift in (0.004, 0.02):  # 2 and 10 sigmas
        drifting = replace(log, raw_increments=corrected_increments(log.raw_increments, 0.0, -drift))
        calibration = calibrate_on_drive(noise, drifting)
        assert calibration.heading_drift == pytest.approx(drift, rel=1e-6) and calibration.scale_applied == 0.0
        if drift > SIGNIFICANT * 0.002:
            assert calibration.drift_applied == calibration.heading_drift
            assert calibration.noise.model.drift_sigma == pytest.approx(0.002)
        else:
            assert calibration.drift_applied == 0.0
            assert calibration.noise.model.drift_sigma == pytest.approx(np.hypot(drift, 0.002), rel=1e-6)
        assert calibration.noise.model.scale_sigma == pytest.approx(0.01, abs=1e-6)


def test_a_drive_noisier_than_the_fit_widens_the_rows_and_a_quieter_one_does_not_narrow_them():
    """The drive's rows' mean normalised error under the fit multiplies the rows' covariances where above 1."""
    noisy = _synthetic_log(OdometryNoise(alpha1=0.05, alpha2=0.02, alpha3=0.05, alpha4=0.02, scale_sigma=0.0,
                                         drift_sigma=0.0), 7, steps=200)
    tight = NoiseFit(OdometryNoise(alpha1=0.005, alpha2=0.002, alpha3=0.005, alpha4=0.002, scale_sigma=0.0,
                                   drift_sigma=0.0), 0.001, 0.001, {"other": {}}, 25.0, 4.5)
    calibration = calibrate_on_drive(tight, noisy)
    assert calibration.noise_level > 10.0
    corrected = corrected_increments(noisy.raw_increments, calibration.scale_applied, calibration.drift_applied)
    _, at_the_fit = calibration.noise.row_covariances(corrected, [0, 50, 120])
    np.testing.assert_allclose(calibration.row_covariances(noisy.raw_increments, [0, 50, 120])[1],
                               calibration.noise_level * at_the_fit)
    wide = replace(tight, model=replace(tight.model, alpha1=0.5, alpha2=0.2, alpha3=0.5, alpha4=0.2))
    assert calibrate_on_drive(wide, noisy).noise_level == 1.0


@pytest.fixture(scope="module")
def shipped():
    return {name: read_carmen(shipped_log(name)) for name in SHIPPED_LOGS}


def test_on_every_shipped_log_the_drive_never_makes_dead_reckoning_worse_than_none(shipped):
    """Leave-one-out: the sigmas from the three other logs, the first 25 m of the log as its drive. Taking out
    whatever the drive measured made Acapulco's dead-reckoned rest 40.8 m RMS off the reference against 2.0 m
    uncorrected; with the rule no log's is worse, and Intel's and FHW's, whose drifts are real, are better."""
    gains = {}
    for name, log in shipped.items():
        scale_sigma, drift_sigma = systematic_sigmas([other for key, other in shipped.items() if key != name], 25.0)
        noise = NoiseFit(OdometryNoise(scale_sigma=scale_sigma, drift_sigma=drift_sigma), 0.05, 0.02, {}, 25.0, 4.5)
        drive, rest = split_calibration_drive(log, 25.0)
        calibration = calibrate_on_drive(noise, drive)

        def off(increments):
            poses = dead_reckoning(increments, start=rest.reference[0])
            return np.sqrt(np.mean(np.sum((poses[:, :2] - rest.reference[:, :2]) ** 2, axis=1)))

        corrected = corrected_increments(rest.raw_increments, calibration.scale_applied, calibration.drift_applied)
        gains[name] = off(corrected) / off(rest.raw_increments)
    assert all(gain <= 1.0 for gain in gains.values()), gains
    assert gains["intel"] < 0.6 and gains["fhw"] < 0.6


def test_a_fit_without_noise_in_a_component_is_refused_naming_its_logs():
    """Raw odometry that repeats the reference fits no noise at all: rows with a singular covariance."""
    exact = _synthetic_log(OdometryNoise(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, scale_sigma=0.0,
                                         drift_sigma=0.0), 8, steps=200)
    with pytest.raises(ValueError, match="fitted on sim8 is degenerate: no noise in heading"):
        fit_noise([exact], window=3.0)
    without_travel_noise = OdometryNoise(alpha3=0.0, alpha4=0.0)
    with pytest.raises(ValueError, match="fitted on aces, fhw is degenerate: no noise in the direction of travel"):
        NoiseFit(without_travel_noise, 0.0, 0.01, {"fhw": {}, "aces": {}})
    with pytest.raises(ValueError, match="degenerate: floor_theta = nan"):
        NoiseFit(OdometryNoise(), 0.01, float("nan"), {"aces": {}})
