"""Topological detections from a recorded log: places on the reference trajectory, the simulator's detector.

A log (:mod:`ptm_bench.logs.carmen`) becomes a ``ptm.Dataset`` (docs/model.md
§2.2) with ground truth taken from its reference trajectory:

* **Places** (:func:`choose_places`, deterministic): walk the reference
  positions of the scans in time order; the first scan's position is place
  0, and every scan farther than ``place_spacing`` from all places chosen so
  far becomes the next place at its position. Places are therefore more than
  the spacing apart, and every scan is within the spacing of one.
* **Detections**: the simulator's detector
  (:func:`ptm_bench.simulation.detector.detect`) on the reference poses of the
  scans: a visit is a maximal run of scans within ``detection_radius`` of a
  place, and it fires once, at the scan closest to the place (no misses, no
  false detections). The radius may be at most half the spacing, so that no
  scan is within the radius of two places.
* **Ground truth**: each detection's label is its place id; its true pose is
  the reference pose of its scan.
* **Calibration drive**: the robot's systematic odometry errors (translation
  scale, heading drift) and its noise level are measured on the log's first
  ``calibration_drive`` metres, reference against raw odometry, as a
  roboticist calibrates a robot before mapping; nothing is detected there,
  so no label and no pose of a scored detection comes from it
  (:func:`ptm_bench.logs.noise_fit.calibrate_on_drive`).
* **Odometry**: row k is the *raw* odometry from detection k-1 to detection k,
  composed from the raw increments of the scans between them with the
  drive's systematic errors taken out where the drive measured them
  distinguishably from zero; its covariance is propagated through the scans
  with a noise model fitted on *other* logs
  (:func:`ptm_bench.logs.noise_fit.fit_noise`: the simulator's linearised
  propagation through the scans, plus the fitted floor once), whose
  systematic part is the error the drive leaves, times the drive's noise
  level where the robot is noisier than those logs.
* **Appearance** (optional, beyond the paper): the laser scan at the
  detection, clipped to ``LASER_CLIP`` metres (farther returns and
  "no return" readings say little in corridors) and scaled to [0, 1], reduced
  by ``ptm.features.fourier_signature`` to the magnitudes of its first K
  Fourier coefficients. The front laser sees 180 degrees only, so a place
  passed in opposite directions looks different: the measured aliasing AUC
  (``meta["aliasing_auc"]``) says how much it still separates places.

    >>> log = read_carmen(shipped_log("aces"))
    >>> others = [read_carmen(shipped_log(name)) for name in ("intel", "fhw", "acapulco")]
    >>> dataset = log_dataset(log, fit_noise(others, calibration_drive=25.0), place_spacing=4.5, detection_radius=1.5)
    >>> dataset.n, len(set(dataset.labels)), round(dataset.meta["path_length"]), dataset.meta["calibration_drive"]["scans"]
    (53, 41, 298, 40)
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

import ptm
from ptm.features import fourier_signature

from ptm_bench.logs.carmen import SHIPPED_LOGS, CarmenLog, read_carmen, resolve_log, shipped_log
from ptm_bench.logs.noise_fit import NoiseFit, calibrate_on_drive, fit_noise, log_name, split_calibration_drive
from ptm_bench.simulation.aliasing import signature_auc
from ptm_bench.simulation.detector import detect

__all__ = ["DEFAULT_CALIBRATION_DRIVE", "DEFAULT_DETECTION_RADIUS", "DEFAULT_PLACE_SPACING", "IMPORTER_VERSION",
           "LASER_CLIP", "choose_places", "import_carmen", "laser_signature", "log_dataset"]

#: Defaults that give 50-150 detections on each shipped log (Intel 73, ACES 53, FHW 73, Acapulco 113).
DEFAULT_PLACE_SPACING = 4.5  # [m]
DEFAULT_DETECTION_RADIUS = 1.5  # [m]
#: [m] of each log that calibrate its robot's odometry (ptm_bench.logs.noise_fit): its drift is then known to
#: 0.002-0.004 rad/m, against a spread of 0.037 rad/m between the shipped robots.
DEFAULT_CALIBRATION_DRIVE = 25.0
LASER_CLIP = 10.0  # [m] laser ranges beyond this are clipped before the signature
IMPORTER_VERSION = "ptm_bench.logs.detections/3"


def choose_places(reference, place_spacing: float) -> dict[int, tuple[float, float]]:
    """Places on a reference trajectory (T, >=2): greedy in time order, more than ``place_spacing`` apart."""
    if not place_spacing > 0:
        raise ValueError(f"place_spacing must be positive, got {place_spacing!r}")
    positions = np.asarray(reference, dtype=float)[:, :2]
    chosen = [positions[0]]
    for position in positions[1:]:
        if np.min(np.linalg.norm(np.asarray(chosen) - position, axis=1)) > place_spacing:
            chosen.append(position)
    return {index: (float(x), float(y)) for index, (x, y) in enumerate(chosen)}


def _places(log: CarmenLog, place_spacing: float) -> dict[int, tuple[float, float]]:
    """:func:`choose_places` on the log's reference; ``ValueError`` when they are fewer than two."""
    places = choose_places(log.reference, place_spacing)
    if len(places) < 2:
        raise ValueError(f"place_spacing {place_spacing:g} m yields {len(places)} place on {log_name(log)} "
                         f"(path {log.path_length():.0f} m scored); a topology needs at least two: "
                         "choose a smaller spacing")
    return places


def laser_signature(ranges, k: int = 5) -> np.ndarray:
    """The first ``k`` Fourier magnitudes of a scan's ranges clipped to ``LASER_CLIP`` and scaled to [0, 1]."""
    profile = np.clip(np.asarray(ranges, dtype=float), 0.0, LASER_CLIP) / LASER_CLIP
    return fourier_signature(profile[None, :], k=k)


def log_dataset(log: CarmenLog, noise: NoiseFit, place_spacing: float = DEFAULT_PLACE_SPACING,
                detection_radius: float = DEFAULT_DETECTION_RADIUS, signature_k: int | None = 5) -> ptm.Dataset:
    """The dataset of one log: detections at closest approach to places on its reference trajectory.

    With a ``noise.calibration_drive``, the log's first that many metres calibrate its robot's systematic
    errors (their reference against their raw odometry), which are taken out of the raw odometry of the
    rest, and only the rest is scored: places, detections and labels come from it alone.
    """
    if log.reference is None:
        raise ValueError(f"{log.source}: the log has no reference trajectory (no corrected poses, no TRUEPOS lines), "
                         "so its detections would have no ground truth")
    if not place_spacing > 0:
        raise ValueError(f"place_spacing must be positive, got {place_spacing!r}")
    if not detection_radius > 0:
        raise ValueError(f"detection_radius must be positive, got {detection_radius!r}")
    if detection_radius > place_spacing / 2:
        raise ValueError(f"detection_radius {detection_radius:g} m exceeds half the place_spacing "
                         f"{place_spacing:g} m: a scan could be within the radius of two places")
    name = log_name(log)
    if name in noise.per_log:
        raise ValueError(f"the odometry noise model was fitted on {name} itself; fit it on other logs")
    scored, first_scan, drive, rows_noise = log, 0, None, noise
    if noise.calibration_drive:
        calibration, scored = split_calibration_drive(log, noise.calibration_drive)
        rows_noise = calibrate_on_drive(noise, calibration)
        first_scan = calibration.n_scans - 1
        drive = {"metres": noise.calibration_drive, "scans": calibration.n_scans, **rows_noise.as_meta()}
    places = _places(scored, place_spacing)
    # The detector draws only for misses and false detections, which are off: the generator is never used.
    detections = detect(scored.reference, places, detection_radius, rng=np.random.default_rng(0))
    scans = np.array([detection.step for detection in detections])
    labels = np.array([detection.place_id for detection in detections])
    rows, covariances = rows_noise.row_covariances(scored.raw_increments, scans)
    signatures = None
    if signature_k:
        signatures = np.array([laser_signature(scored.ranges[scan], signature_k) for scan in scans])
    meta = {
        "source": "carmen log",
        "world": name,
        "log": Path(log.source).name,
        "log_sha256": hashlib.sha256(Path(log.source).read_bytes()).hexdigest() if Path(log.source).is_file() else None,
        "log_form": log.form,
        "reference": "GMapping's corrected poses" if log.form == "corrected" else "TRUEPOS lines",
        "importer_version": IMPORTER_VERSION,
        "place_spacing": float(place_spacing),
        "detection_radius": float(detection_radius),
        "calibration_drive": drive,
        "places": {str(place_id): [round(x, 4), round(y, 4)] for place_id, (x, y) in places.items()},
        "scans": [int(first_scan + scan) for scan in scans],
        "scan_lines": [int(scored.lines[scan]) for scan in scans],
        "timestamps": [float(scored.timestamps[scan]) for scan in scans],
        "path_length": round(scored.path_length(), 3),
        "n_scans": log.n_scans,
        "time_reversals": log.time_reversals,
        "odometry_noise": noise.as_meta(),
        "laser_clip": LASER_CLIP if signature_k else None,
        "aliasing_auc": float(signature_auc(signatures, labels)) if signatures is not None else float("nan"),
    }
    return ptm.Dataset(odometry=rows, odometry_cov=covariances, signatures=signatures, labels=labels,
                       true_poses=scored.reference[scans], meta=meta)


def import_carmen(log, place_spacing: float = DEFAULT_PLACE_SPACING,
                  detection_radius: float = DEFAULT_DETECTION_RADIUS, calibration=None,
                  signature_k: int | None = 5, calibration_drive: float = DEFAULT_CALIBRATION_DRIVE) -> ptm.Dataset:
    """Read a log (a shipped log's name or a path) and make its dataset, the noise fitted on other logs.

    ``calibration`` lists the logs (names or paths) to fit the odometry noise
    on; by default the shipped logs other than this one. ``calibration_drive``
    [m]: the log's first metres that calibrate its robot's systematic errors
    and are not scored (0: none; the other logs' spread of them instead).
    """
    path = resolve_log(log)
    carmen_log = read_carmen(path)
    name = log_name(carmen_log)
    if calibration is None:
        calibration = [other for other in SHIPPED_LOGS if shipped_log(other).name != path.name]
    calibration_logs = [read_carmen(resolve_log(other)) for other in calibration]
    if any(Path(other.source).resolve() == path.resolve() or log_name(other) == name for other in calibration_logs):
        raise ValueError(f"the calibration logs include {name} itself; the noise model must come from other logs")
    if carmen_log.reference is not None:
        _places(carmen_log, place_spacing)  # a spacing that leaves fewer than two places is named before the fit
    try:
        noise = fit_noise(calibration_logs, calibration_drive, window=place_spacing)  # rows span about the spacing
    except ValueError as error:
        raise ValueError(f"{name}: {error}") from None
    return log_dataset(carmen_log, noise, place_spacing, detection_radius, signature_k)
