"""Detections from a recorded log: deterministic places, closest-approach detections, raw odometry rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import ptm
from ptm.se2 import dead_reckoning, relative_pose

from ptm_bench.logs.carmen import SHIPPED_LOGS, CarmenLog
from ptm_bench.logs.detections import IMPORTER_VERSION, choose_places, import_carmen, log_dataset
from ptm_bench.logs.noise_fit import NoiseFit
from ptm_bench.logs.row_error import row_normalised_error
from ptm_bench.simulation.odometry_noise import OdometryNoise

REAL_LOGS = Path(__file__).resolve().parent.parent / "data" / "real_logs"

NOISE = NoiseFit(model=OdometryNoise(), floor_xy=0.01, floor_theta=0.005, per_log={"other": {}})


def _square_log(laps: int = 2, side: float = 10.0, step: float = 0.5, drift: float = 0.0) -> CarmenLog:
    """A square of 10 m sides driven ``laps`` times; the raw odometry turns 1 % more than the reference and
    drifts ``drift`` rad per metre."""
    per_side = int(side / step)
    one_side = [[step, 0.0, 0.0]] * (per_side - 1) + [[step, 0.0, np.pi / 2]]
    reference_steps = np.array(one_side * 4 * laps)
    reference = dead_reckoning(reference_steps)
    raw = reference_steps * [1.0, 1.0, 1.01] + [0.0, 0.0, drift * step]
    n = len(reference)
    return CarmenLog(source="square.log", form="plain", timestamps=np.arange(n, dtype=float),
                     ranges=tuple(np.full(180, 3.0 + (k % 40) / 10) for k in range(n)), scan_poses=reference,
                     raw_increments=raw, reference=reference, lines=np.arange(1, n + 1))


def test_places_are_greedy_in_time_order_and_spaced():
    line = np.column_stack([np.linspace(0, 20, 41), np.zeros(41)])
    places = choose_places(line, 5.0)
    assert places == {0: (0.0, 0.0), 1: (5.5, 0.0), 2: (11.0, 0.0), 3: (16.5, 0.0)}


def test_dataset_of_a_square_driven_twice():
    log = _square_log()
    dataset = log_dataset(log, NOISE, place_spacing=5.0, detection_radius=1.0)
    assert isinstance(dataset, ptm.Dataset)
    places = len(dataset.meta["places"])
    assert places == 6 and dataset.n == 2 * places + 1  # every place once per lap, and the start again at the end
    np.testing.assert_array_equal(dataset.labels, list(range(6)) * 2 + [0])
    scans = np.array(dataset.meta["scans"])
    np.testing.assert_allclose(dataset.true_poses, log.reference[scans])
    raw_poses = dead_reckoning(log.raw_increments)
    np.testing.assert_allclose(dataset.odometry, relative_pose(raw_poses[scans[:-1]], raw_poses[scans[1:]]), atol=1e-12)
    assert dataset.odometry_cov.shape == (dataset.n - 1, 3, 3)
    assert dataset.signatures.shape == (dataset.n, 5)
    assert dataset.meta["detection_radius"] == 1.0 and dataset.meta["odometry_noise"]["fitted_on"] == ["other"]


@pytest.mark.parametrize("spacing, radius, message", [
    (60.0, 1.0, r"place_spacing 60 m yields 1 place"),
    (5.0, 3.0, r"detection_radius 3 m exceeds half the place_spacing"),
    (-1.0, 0.1, r"place_spacing must be positive"),
])
def test_bad_parameters_are_refused(spacing, radius, message):
    with pytest.raises(ValueError, match=message):
        log_dataset(_square_log(laps=1), NOISE, place_spacing=spacing, detection_radius=radius)


def test_noise_fitted_on_the_log_itself_is_refused():
    own = NoiseFit(model=OdometryNoise(), floor_xy=0.01, floor_theta=0.005, per_log={"square": {}})
    with pytest.raises(ValueError, match="fitted on square itself"):
        log_dataset(_square_log(), own)
    with pytest.raises(ValueError, match="include aces itself"):
        import_carmen("aces", calibration=["fhw", "aces"])


def test_a_calibration_drive_takes_the_robots_drift_out_and_is_not_scored():
    """The first metres calibrate the heading drift, which the rows then no longer have; no detection is
    made on the drive, and its scans' labels and poses are not in the dataset."""
    log = _square_log(laps=3, drift=0.02)
    noise = NoiseFit(model=OdometryNoise(), floor_xy=0.01, floor_theta=0.005, per_log={"other": {}},
                     calibration_drive=20.0)
    raw_dataset, driven = log_dataset(log, NOISE, 5.0, 1.0), log_dataset(log, noise, 5.0, 1.0)
    drive = driven.meta["calibration_drive"]
    assert drive["metres"] == 20.0 and drive["scans"] == 41 and drive["heading_drift"] == pytest.approx(0.02, abs=2e-3)
    assert min(driven.meta["scans"]) >= drive["scans"] - 1 and driven.n < raw_dataset.n
    scans = np.array(driven.meta["scans"])
    raw_poses = dead_reckoning(log.raw_increments)
    reference_turns = relative_pose(log.reference[scans[:-1]], log.reference[scans[1:]])[:, 2]
    raw_turns = relative_pose(raw_poses[scans[:-1]], raw_poses[scans[1:]])[:, 2]
    assert np.abs(driven.odometry[:, 2] - reference_turns).max() < 0.25 * np.abs(raw_turns - reference_turns).max()
    np.testing.assert_allclose(driven.true_poses, log.reference[scans])
    with pytest.raises(ValueError, match="leaves nothing"):
        log_dataset(_square_log(laps=1), NoiseFit(OdometryNoise(), 0.01, 0.005, {"other": {}}, 39.9), 5.0, 1.0)


def test_shipped_log_defaults():
    """ACES with the defaults: 53 detections of 41 places after a 25 m calibration drive; the noise comes
    from the three other logs, whose drives leave a drift of a few mrad/m (their robots' drifts differ by 37)."""
    dataset = import_carmen("aces")
    assert dataset.n == 53 and len(set(dataset.labels)) == 41
    noise = dataset.meta["odometry_noise"]
    assert noise["fitted_on"] == ["acapulco", "fhw", "intel"] and noise["calibration_drive"] == 25.0
    assert noise["drift_sigma"] < 0.01 < max(abs(entry["heading_drift"]) for entry in noise["per_log"].values())
    assert np.all(np.linalg.eigvalsh(dataset.odometry_cov) > 0)


def test_the_row_normalised_error_is_one_where_the_covariances_are_right():
    """mean r^T Sigma^-1 r / 3 of the rows against the true poses: 4 with covariances 4 times too tight."""
    true_poses = dead_reckoning(np.array([[1.0, 0.0, 0.1], [1.0, 0.0, -0.2]]))
    rows = relative_pose(true_poses[:-1], true_poses[1:]) - [[0.2, 0.0, 0.1], [0.0, -0.2, 0.1]]
    right = np.array([np.diag([0.04, 0.04, 0.01])] * 2)  # each row's error is one sd in two of its components
    dataset = ptm.Dataset(odometry=rows, odometry_cov=right, true_poses=true_poses)
    assert row_normalised_error(dataset) == pytest.approx(2.0 / 3.0)
    assert row_normalised_error(dataset.replace(odometry_cov=right / 4.0)) == pytest.approx(8.0 / 3.0)
    with pytest.raises(ValueError, match="needs a dataset with odometry, odometry_cov and true_poses"):
        row_normalised_error(ptm.Dataset(odometry=rows, odometry_cov=right))


@pytest.mark.parametrize("name", SHIPPED_LOGS)
def test_the_committed_real_log_datasets_are_the_importers_and_their_rows_fit_their_covariances(name):
    """Each committed dataset (noise fitted on the three other logs) comes from this importer, and its rows'
    normalised error lies within [0.5, 2] (importer 2: Intel's 4.17, its robot noisier than the others)."""
    dataset = ptm.Dataset.load(REAL_LOGS / f"{name}.npz")
    assert dataset.meta["importer_version"] == IMPORTER_VERSION
    assert name not in dataset.meta["odometry_noise"]["fitted_on"]
    assert 0.5 <= row_normalised_error(dataset) <= 2.0


def test_a_degenerate_noise_fit_is_an_error_naming_the_log(tmp_path):
    """A calibration log whose raw odometry repeats its reference fits no noise: the import names both logs."""
    poses = dead_reckoning(np.tile([[1.0, 0.0, 0.3], [1.0, 0.0, -0.2]], (30, 1)))
    lines = []
    for k, (x, y, theta) in enumerate(poses):
        pose = f"{x:.6f} {y:.6f} {theta:.6f}"
        lines += [f"ODOM {pose} 0 0 0 {k}.0 host {k}.0", f"TRUEPOS {pose} {pose} {k}.0 host {k}.0",
                  f"FLASER 2 1.0 2.0 {pose} {pose} {k}.5 host {k}.5"]
    exact = tmp_path / "exact.log"
    exact.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="aces: the odometry noise fitted on exact is degenerate: no noise in heading"):
        import_carmen("aces", calibration=[exact], calibration_drive=0.0)
