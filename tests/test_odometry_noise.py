"""Odometry motion model: noise-free identity, per-step error statistics, covariance propagation."""

import numpy as np
import pytest

from ptm.se2 import compose, dead_reckoning, relative_pose
from ptm_bench.simulation.odometry_noise import (
    COVARIANCE_FLOOR,
    OdometryNoise,
    OdometrySteps,
    decompose,
    detection_odometry,
    sample_odometry,
)

STEP = np.array([0.05, 0.15, -0.02])  # one control step: rot1 [rad], trans [m], rot2 [rad]


def _trajectory(rot1, trans, rot2):
    """True poses (T+1, 3) from per-step (rot1, trans, rot2)."""
    increments = np.stack([trans * np.cos(rot1), trans * np.sin(rot1), rot1 + rot2], axis=-1)
    return dead_reckoning(increments, start=(1.0, -2.0, 0.4))


def _l_shaped_run(steps=150):
    """Drive 10 m straight, turn 90 degrees while driving, drive on."""
    rot1 = np.zeros(steps)
    turn = np.zeros(steps)
    turn[60:75] = (np.pi / 2) / 15
    return _trajectory(rot1, np.full(steps, 0.1), turn)


def test_compose_and_relative_pose_are_inverse():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    back = compose(a, relative_pose(a, b))
    assert np.allclose(back[:, :2], b[:, :2]) and np.allclose(np.cos(back[:, 2] - b[:, 2]), 1.0)


def test_noise_zero_reproduces_the_truth():
    poses = _l_shaped_run()
    steps = sample_odometry(poses, OdometryNoise().scaled(0.0), np.random.default_rng(1))
    assert steps.scale_error == 0.0 and steps.heading_drift == 0.0
    rows, covariances = detection_odometry(steps, [0, 40, 100, 150])
    assert np.abs(rows - relative_pose(poses[[0, 40, 100]], poses[[40, 100, 150]])).max() < 1e-12
    assert np.allclose(covariances, COVARIANCE_FLOOR * np.eye(3))


def _per_step_errors(model, steps=20_000, seed=3):
    poses = _trajectory(*(np.full(steps, value) for value in STEP))
    measured = sample_odometry(poses, model, np.random.default_rng(seed))
    rot1, trans, rot2 = decompose(measured.increments)
    return np.stack([rot1 - STEP[0], trans - STEP[1], rot2 - STEP[2]], axis=-1)


def _matches_model(errors, model):
    """Mean within 4 standard errors of 0 and each sd within 4% of the configured one."""
    expected = model.step_sigmas(*STEP)
    n = len(errors)
    means_ok = np.all(np.abs(errors.mean(axis=0)) < 4 * expected / np.sqrt(n))
    sds_ok = np.all(np.abs(errors.std(axis=0, ddof=1) / expected - 1) < 0.04)
    return bool(means_ok and sds_ok)


@pytest.mark.parametrize("level", [0.5, 1.0, 3.0])
def test_empirical_per_step_error_matches_the_configured_model(level):
    model = OdometryNoise(scale_sigma=0.0, drift_sigma=0.0).scaled(level)
    errors = _per_step_errors(model)
    assert _matches_model(errors, model)
    # negative control: the same errors do not match a model with a doubled alpha3
    assert not _matches_model(errors, OdometryNoise(alpha3=0.04, scale_sigma=0.0, drift_sigma=0.0).scaled(level))


def test_systematic_errors_are_drawn_per_run_with_the_configured_spread():
    model = OdometryNoise(alpha1=0.0, alpha2=0.0, alpha3=0.0, alpha4=0.0, scale_sigma=0.02, drift_sigma=0.001)
    poses = _trajectory(np.zeros(10), np.full(10, 0.2), np.zeros(10))
    draws = np.array([
        (steps.scale_error, steps.heading_drift, steps.increments[0, 0] / 0.2 - 1, steps.increments[0, 2] / 0.2)
        for steps in (sample_odometry(poses, model, np.random.default_rng(seed)) for seed in range(4000))
    ])
    assert np.allclose(draws[:, 0], draws[:, 2]) and np.allclose(draws[:, 1], draws[:, 3])  # applied as configured
    standard_error = 1 / np.sqrt(2 * len(draws))
    assert abs(draws[:, 0].std() / 0.02 - 1) < 4 * standard_error
    assert abs(draws[:, 1].std() / 0.001 - 1) < 4 * standard_error


def test_propagated_covariance_matches_monte_carlo():
    poses = _l_shaped_run()
    model = OdometryNoise(alpha1=0.1, alpha2=0.01, alpha3=0.05, alpha4=0.01, scale_sigma=0.02, drift_sigma=0.002)
    finals = []
    for seed in range(3000):
        steps = sample_odometry(poses, model, np.random.default_rng(seed))
        finals.append(relative_pose(dead_reckoning(steps.increments)[0], dead_reckoning(steps.increments)[-1]))
    finals = np.array(finals)
    truth = relative_pose(poses[0], poses[-1])
    empirical = np.cov((finals - truth).T)
    _, propagated = detection_odometry(sample_odometry(poses, model.scaled(1.0), np.random.default_rng(0)), [0, 150])
    ratio = np.diag(empirical) / np.diag(propagated[0])
    assert np.all(np.abs(ratio - 1) < 0.12), ratio  # 3000 draws: sd of a variance ratio ~ 2.6%
    correlation = lambda c: c[0, 1] / np.sqrt(c[0, 0] * c[1, 1])  # noqa: E731
    assert correlation(empirical) == pytest.approx(correlation(propagated[0]), abs=0.08)


def test_covariance_scales_with_the_square_of_the_noise_level():
    poses = _l_shaped_run()
    true_increments = relative_pose(poses[:-1], poses[1:])
    rot1, trans, rot2 = decompose(true_increments)
    covariances = []
    for level in (1.0, 2.0):
        model = OdometryNoise().scaled(level)
        steps = OdometrySteps(true_increments, model.step_sigmas(rot1, trans, rot2), 0.0, 0.0, model)
        covariances.append(detection_odometry(steps, [0, 150])[1][0] - COVARIANCE_FLOOR * np.eye(3))
    assert np.allclose(covariances[1], 4 * covariances[0], rtol=1e-9, atol=1e-15)


def test_bad_noise_levels_and_steps_are_rejected():
    with pytest.raises(ValueError, match="noise must be"):
        OdometryNoise().scaled(-0.5)
    with pytest.raises(ValueError, match="alpha3"):
        OdometryNoise(alpha3=-1.0)
    steps = sample_odometry(_l_shaped_run(), OdometryNoise(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="detection_steps"):
        detection_odometry(steps, [0, 50, 40])
