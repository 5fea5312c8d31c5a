"""The simulator's odometry noise model fitted to real robots: raw increments against a reference trajectory.

The model is the one that generates the simulator's odometry
(:mod:`ptm_bench.simulation.odometry_noise`, docs/model.md §5): each scan's
motion is (rot1, trans, rot2), measured with standard deviations

    sd(rot1)  = alpha1 |rot1| + alpha2 |trans|
    sd(trans) = alpha3 |trans| + alpha4 (|rot1| + |rot2|)
    sd(rot2)  = alpha1 |rot2| + alpha2 |trans|

plus, per run, a translation-scale error s (trans' = (1 + s) trans) and a
heading drift d [rad/m] (rot2' = rot2 + d trans). New here: a *floor*, an
independent error of sd ``floor_xy`` on dx and dy and ``floor_theta`` on
dtheta added once per increment, which absorbs the reference's own jitter
(GMapping's scan matching) and the logs' quantisation. It does not
accumulate along the odometry: a dataset row composed of many scans gets the
floor once (:meth:`NoiseFit.row_covariances`).

**Turns on the spot and reversing** (:func:`motion_components`). A real robot
turns on the spot, where a scan moves it a few millimetres in no particular
direction, and backs up. Read literally, such a scan's rot1 (the direction of
travel) is anything up to pi and rot2 nearly its opposite, and alpha1 |rot1|
charges a heading error for a turn the robot never made: on ACES one row
composed of 17 such scans got a heading sd of 0.8 rad, and the pose graph
folded the route there. As in AMCL's odometry model, a scan that moves less
than ``ON_THE_SPOT`` is a pure turn (rot1 = 0), and one whose direction of
travel points backwards is a reverse (rot1 turned by pi, trans negative).

**Fit.** For each log, s and d are least-squares slopes of the translation
error and the heading error on the reference translation. The alphas and
floors are maximum-likelihood estimates over all logs, with each log's own s
and d removed, of the raw odometry composed over consecutive windows of
``window`` metres of the reference (the importer's: the place spacing, the
length of a dataset row): each window's error is Normal with the covariance a
dataset row gets, the per-scan noise propagated through the window plus the
floor once (:func:`_window_statistics`). Scan by scan (``window = 0``) the
reference's own error gets in the way: GMapping's heading jitters most where
the robot turns, by an error that the next scan takes back, and a per-scan
fit reads it as odometry noise that accumulates. Over the four shipped logs
it gave alpha1 = 0.089 rad per rad turned, and the rows' heading errors were
3 to 15 times smaller in variance than their covariances said (composed over
10 to 30 scans); over 4.5 m windows alpha1 is 0.015, and 9 and 20 m windows
give 0.015 and 0.014.

**Systematic errors: a robot calibrates its odometry.** s and d are properties
of one robot (its wheels), steady over a run (Intel's heading drift is -0.056
to -0.058 rad/m in each quarter of its log) and different between robots
(-0.062 to +0.013 rad/m over the four shipped logs). A robot's own s and d
are what a roboticist measures before mapping (UMBmark); here they come
from a *calibration drive*, the first ``calibration_drive`` metres of the
scored log itself, whose reference the importer reads and whose scans it
scores no detection on (:func:`calibrate_on_drive`). How far a drive of that
length misses the rest of its run is ``scale_sigma`` and ``drift_sigma``: the
root mean square, over every consecutive stretch of that length of the
*other* logs, of the difference between the stretch's s and d and those of
the rest of its log (:func:`fit_noise`; 25 m: 0.007 and 0.005-0.007 rad/m).
A drive's s or d is taken out of the odometry only when it lies more than
``SIGNIFICANT`` = 3 of those sigmas from zero; the rows' covariances then
carry what is left, sqrt((measured - taken out)^2 + sigma^2). Taking out
whatever a drive measured made dead reckoning worse than none: Acapulco's
drive measures -0.0028 rad/m where the rest of its run drifts -0.0002, and
corrected by it the dead-reckoned rest is 40.8 m RMS off the reference
against 2.0 m uncorrected (30 of its 31 stretches of 25 m, each taken as
the drive, do the same). With the rule, no shipped log's drive makes it
worse, and 4 of the 77 stretches do, by at most 15 %.
Without a drive (``calibration_drive = 0``) the sigmas are the spread of the
logs' own s and d, the spread between robots, and the per-row covariance,
which cannot carry the correlation of one d over all rows, charges every
row that spread: 0.037 rad/m over the three logs other than ACES, Intel's
drift among them, a heading sd of 0.19 rad on a 5 m row of a robot that
drifts 0.006 rad/m. A dataset's odometry covariances come from a fit on
*other* logs (:func:`fit_noise` of those logs), never on the log itself.

**A robot's noise level.** Alphas and floors fitted on other robots fit a
robot as noisy as those: fitted on the three others, Intel's rows were 3.8
times too tight (the mean normalised error of :mod:`ptm_bench.logs.row_error`,
1 where right), the other logs' 0.56-1.05. The drive's own rows (consecutive
``window`` metres) show it: Intel's are 4.5 times too tight. Where a drive's
mean normalised error is above 1 it multiplies the rows' covariances
(Intel's rows then 0.85); below 1 it is not used: five rows cannot tell a
quiet robot from a quiet stretch (one log's 25 m stretches range over a
factor of 5 to 10), and rows too narrow make the posterior confidently
wrong where rows too wide cost it power. A fit with no noise in a component
(heading, or the direction of travel) is refused, naming its logs.

    >>> from ptm_bench.logs.carmen import read_carmen, shipped_log
    >>> fit = fit_noise([read_carmen(shipped_log(name)) for name in ("aces", "fhw", "acapulco")], 25.0)
    >>> 0.0 < fit.model.alpha1 < 1.0 and 0.0 < fit.floor_xy < 0.1 and fit.model.drift_sigma < 0.01
    True
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from ptm.se2 import compose, relative_pose, wrap_angle

from ptm_bench.logs.carmen import CarmenLog
from ptm_bench.logs.row_error import normalised_errors
from ptm_bench.simulation.odometry_noise import OdometryNoise, OdometrySteps, decompose, detection_odometry

__all__ = ["ON_THE_SPOT", "SIGNIFICANT", "DriveCalibration", "NoiseFit", "calibrate_on_drive", "corrected_increments",
           "fit_noise", "log_name", "motion_components", "split_calibration_drive", "systematic_errors",
           "systematic_sigmas"]

#: [m] A scan that moves the robot less than this is a turn on the spot: its direction of travel is noise.
ON_THE_SPOT = 0.01
#: A noise parameter at most this (m or rad, per m or rad) is none: the fit's lower bound is e^-16 = 1e-7.
NO_NOISE = 1e-6
#: A calibration drive's s or d is taken out of the odometry when it is this many sigmas from zero.
SIGNIFICANT = 3.0
_JITTER = 1e-10  # on the variances of the fit's likelihood: keeps the covariance regular at any parameters


@dataclass(frozen=True)
class NoiseFit:
    """A fitted odometry noise model: the simulator's parameters, the floors, and what each log contributed."""

    model: OdometryNoise  # alpha1..alpha4, scale_sigma, drift_sigma (level 1): what is left after the drive
    floor_xy: float  # [m] sd of the independent error on dx and dy of every increment
    floor_theta: float  # [rad] sd of the independent error on dtheta of every increment
    per_log: dict = field(default_factory=dict)  # log name -> {"scans", "scale_error", "heading_drift", ...}
    calibration_drive: float = 0.0  # [m] of each scored log that calibrate its robot's s and d (0: none)
    window: float = 0.0  # [m] of the reference over which the raw odometry was compared (0: each scan)

    def __post_init__(self):
        """``ValueError`` naming the logs it was fitted on where the model has a component without noise: a
        row's covariance would be singular, and the pose graph would hold the odometry exact there."""
        fitted_on = ", ".join(sorted(self.per_log)) or "no log"
        floors = {"floor_xy": self.floor_xy, "floor_theta": self.floor_theta}
        for name, value in floors.items():
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"the odometry noise fitted on {fitted_on} is degenerate: {name} = {value!r}")
        model = self.model
        for component, (*alphas, floor) in {"heading": ("alpha1", "alpha2", "floor_theta"),
                                             "the direction of travel": ("alpha3", "alpha4", "floor_xy")}.items():
            if max(getattr(model, alpha) for alpha in alphas) <= NO_NOISE and floors[floor] <= NO_NOISE:
                raise ValueError(f"the odometry noise fitted on {fitted_on} is degenerate: no noise in {component} "
                                 f"({', '.join(alphas)} and {floor} all at most {NO_NOISE:g}); does the raw odometry "
                                 "repeat the reference?")

    def steps(self, increments) -> OdometrySteps:
        """The raw increments with the standard deviations of their (rot1, trans, rot2), without the floor."""
        increments = np.asarray(increments, dtype=float).reshape(-1, 3)
        motion = motion_components(increments)
        return OdometrySteps(increments, self.model.step_sigmas(*motion), 0.0, 0.0, self.model, motion=motion)

    def row_covariances(self, increments, scans) -> tuple[np.ndarray, np.ndarray]:
        """Rows (K-1, 3) composed of the raw increments between consecutive ``scans``, and their covariances.

        The simulator's linearised propagation of the per-scan noise and of the
        systematic errors, plus the floor once per row.
        """
        rows, covariances = detection_odometry(self.steps(increments), scans)
        floor = np.diag([self.floor_xy ** 2, self.floor_xy ** 2, self.floor_theta ** 2])
        return rows, covariances + floor

    def as_meta(self) -> dict:
        model = self.model.as_meta()
        model.pop("level")
        return {**{key: round(float(value), 6) for key, value in model.items()},
                "floor_xy": round(self.floor_xy, 6), "floor_theta": round(self.floor_theta, 6),
                "calibration_drive": self.calibration_drive, "window": self.window, "fitted_on": sorted(self.per_log), "per_log": self.per_log}


def log_name(log: CarmenLog) -> str:
    """A log's short name: its file name without ``-corrected`` and the ``.log(.gz)`` suffixes."""
    name = Path(log.source).name
    for suffix in (".gz", ".log", "-corrected"):
        name = name.removesuffix(suffix)
    return name


def motion_components(increments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rot1, trans, rot2) of increments (T, 3) for a robot that turns on the spot and reverses.

    Where the robot moved less than ``ON_THE_SPOT``, rot1 = 0 and the whole turn is rot2; where it moved
    backwards (its direction of travel more than pi/2 off its heading) rot1 is that direction turned by pi
    and trans is negative. The increment is (trans cos rot1, trans sin rot1, rot1 + rot2) either way.
    """
    increments = np.asarray(increments, dtype=float).reshape(-1, 3)
    rot1, trans, _ = decompose(increments)
    rot1 = np.where(trans < ON_THE_SPOT, 0.0, rot1)
    reverse = np.abs(rot1) > np.pi / 2
    rot1 = np.where(reverse, wrap_angle(rot1 - np.pi), rot1)
    trans = np.where(reverse, -trans, trans)
    return rot1, trans, wrap_angle(increments[:, 2] - rot1)


def corrected_increments(increments, scale: float, drift: float) -> np.ndarray:
    """The increments (T, 3) with a robot's systematic errors taken out: their translation divided by 1 + s,
    their turn less d times the corrected distance (signed: a reverse drifts back). At s = d = 0, unchanged."""
    increments = np.asarray(increments, dtype=float).reshape(-1, 3)
    _, trans, _ = motion_components(increments)
    return np.column_stack([increments[:, :2] / (1.0 + scale),
                            wrap_angle(increments[:, 2] - drift * trans / (1.0 + scale))])


@dataclass(frozen=True)
class DriveCalibration:
    """What a log's calibration drive measured of its robot, and what the importer takes from it."""

    scale_error: float  # s measured on the drive
    heading_drift: float  # d [rad/m] measured on the drive
    scale_applied: float  # taken out of the odometry: s where significant, else 0
    drift_applied: float  # taken out of the odometry: d where significant, else 0
    noise_level: float  # >= 1: the drive's rows' mean normalised error under the fit; multiplies the rows' covariances
    noise: NoiseFit  # the rows' noise model: the fit, its systematic sigmas what the drive leaves

    def row_covariances(self, increments, scans) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`NoiseFit.row_covariances` of the increments with (s, d) taken out, at the drive's noise level."""
        increments = corrected_increments(increments, self.scale_applied, self.drift_applied)
        rows, covariances = self.noise.row_covariances(increments, scans)
        return rows, self.noise_level * covariances

    def as_meta(self) -> dict:
        return {"scale_error": round(self.scale_error, 6), "heading_drift": round(self.heading_drift, 6),
                "scale_applied": round(self.scale_applied, 6), "drift_applied": round(self.drift_applied, 6),
                "noise_level": round(self.noise_level, 4), "rows_scale_sigma": round(self.noise.model.scale_sigma, 6),
                "rows_drift_sigma": round(self.noise.model.drift_sigma, 6)}


def calibrate_on_drive(noise: NoiseFit, drive: CarmenLog) -> DriveCalibration:
    """A robot's calibration drive against the noise fitted on other logs: its (s, d) and its noise level.

    Each of s and d is taken out of the odometry when it lies more than ``SIGNIFICANT`` of the fit's sigmas
    (how far a drive misses the rest of its run on the other logs) from zero, and left in otherwise; the rows'
    systematic sigmas become the root mean square error left, sqrt((measured - taken out)^2 + sigma^2). The
    drive's own rows (consecutive ``noise.window`` metres) then give the noise level, the mean of their
    normalised errors (:func:`ptm_bench.logs.row_error.normalised_errors`), where it is above 1: a robot
    noisier than those the noise was fitted on widens its rows; a quieter drive does not narrow them.
    """
    scale, drift = systematic_errors(drive)
    sigmas = noise.model.scale_sigma, noise.model.drift_sigma
    applied = [value if abs(value) > SIGNIFICANT * sigma else 0.0 for value, sigma in zip((scale, drift), sigmas)]
    left = [float(np.hypot(value - taken, sigma)) for value, taken, sigma in zip((scale, drift), applied, sigmas)]
    rows_noise = replace(noise, model=replace(noise.model, scale_sigma=left[0], drift_sigma=left[1]))
    _, trans, _ = motion_components(drive.reference_increments())
    scans = [members[0] for members in _consecutive(np.abs(trans), noise.window)]
    level = 1.0
    if len(scans) > 1:
        rows, covariances = rows_noise.row_covariances(corrected_increments(drive.raw_increments, *applied), scans)
        reference = relative_pose(drive.reference[scans[:-1]], drive.reference[scans[1:]])
        level = max(1.0, float(np.mean(normalised_errors(rows, covariances, reference))))
    return DriveCalibration(scale, drift, applied[0], applied[1], level, rows_noise)


def split_calibration_drive(log: CarmenLog, metres: float) -> tuple[CarmenLog, CarmenLog]:
    """The first ``metres`` of a log (its calibration drive) and the rest, sharing the scan between them."""
    if not metres > 0:
        raise ValueError(f"calibration_drive must be positive, got {metres!r}")
    boundary = log.scan_at_path_length(metres)
    if boundary >= log.n_scans - 1:
        raise ValueError(f"calibration_drive {metres:g} m leaves nothing of {log.source} "
                         f"(path {log.path_length():.0f} m) to score")
    return log.segment(0, boundary + 1), log.segment(boundary, log.n_scans)


def systematic_errors(log: CarmenLog) -> tuple[float, float]:
    """(s, d): the log's translation-scale error and heading drift [rad/m] against its reference."""
    travelled, scale, drift = _systematic_sums(log).sum(axis=1)
    if travelled <= 0.0:
        raise ValueError(f"{log.source}: the reference never moves; no odometry noise can be fitted")
    return float(scale / travelled), float(drift / travelled)


def _systematic_sums(log: CarmenLog) -> np.ndarray:
    """(3, T) per increment: trans^2, (raw trans - trans) trans and the heading error times trans, trans the
    reference's; s and d are the least-squares slopes of their sums over a stretch (:func:`systematic_errors`)."""
    raw, reference = log.raw_increments, log.reference_increments()
    _, raw_trans, _ = motion_components(raw)
    _, trans, _ = motion_components(reference)
    return np.stack([trans * trans, (raw_trans - trans) * trans, wrap_angle(raw[:, 2] - reference[:, 2]) * trans])


def systematic_sigmas(logs, calibration_drive: float) -> tuple[float, float]:
    """(scale_sigma, drift_sigma) of logs: with a ``calibration_drive`` [m], how far the s and d of a drive that
    long miss those of the rest of its run (root mean square over every consecutive stretch of that length of
    every log, :func:`_drive_misses`); without one (0), the spread (root mean square) of the logs' own s and d."""
    logs = list(logs)
    if calibration_drive:
        misses = np.concatenate([_drive_misses(log, calibration_drive) for log in logs])
    else:
        misses = np.array([systematic_errors(log) for log in logs]).reshape(-1, 2)
    if not len(misses):
        raise ValueError(f"the logs {sorted(log_name(log) for log in logs)} are shorter than {calibration_drive:g} m, "
                         "one calibration drive and some of the run beside it")
    scale_sigma, drift_sigma = np.sqrt(np.mean(np.square(misses), axis=0))
    return float(scale_sigma), float(drift_sigma)


def _drive_misses(log: CarmenLog, metres: float) -> np.ndarray:
    """(k, 2): how far the (s, d) of each of the log's consecutive stretches of ``metres`` (a last, shorter one
    left out) miss those of the rest of the log, as a calibration drive of that length would."""
    sums = _systematic_sums(log)
    _, trans, _ = motion_components(log.reference_increments())
    total = sums.sum(axis=1)
    misses = []
    for members in _consecutive(np.abs(trans), metres)[:-1]:
        stretch = sums[:, members].sum(axis=1)
        rest = total - stretch
        if stretch[0] > 0.0 and rest[0] > 0.0:
            misses.append(stretch[1:] / stretch[0] - rest[1:] / rest[0])
    return np.array(misses).reshape(-1, 2)


def _consecutive(distance, metres: float) -> list[np.ndarray]:
    """The increments (their indices) in consecutive stretches of ``metres`` of travelled ``distance`` (each
    increment its own stretch at 0), the last one possibly shorter."""
    travelled = np.cumsum(distance) - distance  # along the path when each increment starts
    stretch_of = np.arange(len(distance)) if metres == 0 else np.floor(travelled / metres).astype(int)
    return np.split(np.arange(len(distance)), np.flatnonzero(np.diff(stretch_of)) + 1)


def _window_statistics(log: CarmenLog, scale: float, drift: float, window: float):
    """The raw odometry over consecutive windows of ``window`` metres of the reference (each scan its own
    window at 0; a last, shorter window left out), against the reference with the log's s and d applied:
    residuals (W, 3) of the composed motion (x, y in the window's first frame, heading wrapped), and the
    pieces (W, 6, 3, 3) of their covariance, one per product of alphas in ``_MONOMIALS``.

    The propagation is the linearised one of the dataset rows (:func:`ptm_bench.simulation.odometry_noise.
    detection_odometry`): e_k = F_k e_(k-1) + N_k n_k for the error of the pose after scan k, F_k moving the
    later position with an error of heading and N_k mapping the noise of (rot1, trans, rot2) into the window's
    frame, so the window's error is sum_k (F_K ... F_(k+1)) N_k n_k; each noise variance is a sum of products
    of two alphas (sd = alpha1 |rot1| + alpha2 |trans| ...).
    """
    rot1, trans, rot2 = motion_components(log.reference_increments())
    mean_trans = (1.0 + scale) * trans
    mean = np.stack([mean_trans * np.cos(rot1), mean_trans * np.sin(rot1), rot1 + rot2 + drift * trans], axis=-1)
    turn1, distance, turn2 = np.abs(rot1), np.abs(trans), np.abs(rot2)
    # variance coefficients (increments, noise component, monomial): alpha1^2, alpha1 alpha2, alpha2^2, ...
    coefficients = np.zeros((len(trans), 3, len(_MONOMIALS)))
    coefficients[:, 0, :3] = np.stack([turn1 ** 2, 2.0 * turn1 * distance, distance ** 2], axis=-1)
    coefficients[:, 1, 3:] = np.stack([distance ** 2, 2.0 * distance * (turn1 + turn2), (turn1 + turn2) ** 2], axis=-1)
    coefficients[:, 2, :3] = np.stack([turn2 ** 2, 2.0 * turn2 * distance, distance ** 2], axis=-1)
    windows = _consecutive(distance, window)
    residuals, pieces = [], []
    for members in windows if window == 0 else windows[:-1]:
        raw_end, mean_end = np.zeros(3), np.zeros(3)
        maps, transitions = [], []
        for k in members:
            c, s = np.cos(mean_end[2]), np.sin(mean_end[2])
            jacobian = np.array([[-trans[k] * np.sin(rot1[k]), np.cos(rot1[k]), 0.0],
                                 [trans[k] * np.cos(rot1[k]), np.sin(rot1[k]), 0.0], [1.0, 0.0, 1.0]])
            maps.append(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ jacobian)
            dx, dy = mean[k, 0], mean[k, 1]
            transitions.append(np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]]))
            raw_end, mean_end = compose(raw_end, log.raw_increments[k]), compose(mean_end, mean[k])
        piece, later = np.zeros((len(_MONOMIALS), 3, 3)), np.eye(3)
        for k, step_map, transition in zip(members[::-1], maps[::-1], transitions[::-1]):
            columns = later @ step_map  # the window's error per unit noise of (rot1, trans, rot2) at scan k
            piece += np.einsum("jm,aj,bj->mab", coefficients[k], columns, columns)
            later = later @ transition
        residual = raw_end - mean_end
        residual[2] = wrap_angle(residual[2])
        residuals.append(residual)
        pieces.append(piece)
    return np.array(residuals).reshape(-1, 3), np.array(pieces).reshape(-1, len(_MONOMIALS), 3, 3)


#: The products of alphas in the variances of (rot1, trans, rot2) (``_window_statistics``).
_MONOMIALS = ((0, 0), (0, 1), (1, 1), (2, 2), (2, 3), (3, 3))


def fit_noise(logs, calibration_drive: float = 0.0, window: float = 0.0) -> NoiseFit:
    """Maximum-likelihood alphas and floors over ``logs`` (each needs a reference), and the systematic sigmas
    of :func:`systematic_sigmas`.

    The likelihood is that of the raw odometry composed over consecutive ``window`` metres of the reference
    (0: every scan on its own), each window's error Normal with the propagated covariance plus the floor
    once, as a dataset row's (:func:`_window_statistics`).
    """
    logs = list(logs)
    if not logs:
        raise ValueError("fitting the odometry noise needs at least one log with a reference trajectory")
    if not calibration_drive >= 0:
        raise ValueError(f"calibration_drive must be >= 0 metres, got {calibration_drive!r}")
    if not window >= 0:
        raise ValueError(f"window must be >= 0 metres, got {window!r}")
    scale_sigma, drift_sigma = systematic_sigmas(logs, calibration_drive)
    per_log, residuals, pieces = {}, [], []
    for log in logs:
        scale, drift = systematic_errors(log)
        log_residuals, log_pieces = _window_statistics(log, scale, drift, window)
        residuals.append(log_residuals)
        pieces.append(log_pieces)
        per_log[log_name(log)] = {"scans": log.n_scans, "scale_error": round(scale, 6),
                                  "heading_drift": round(drift, 6)}
    residual, piece = np.concatenate(residuals), np.concatenate(pieces)
    if not len(residual):
        raise ValueError(f"the logs {sorted(per_log)} are shorter than one window of {window:g} m")
    first, second = np.array(_MONOMIALS).T

    def negative_log_likelihood(log_params):
        parameters = np.exp(log_params)
        alphas, floors = parameters[:4], parameters[[4, 4, 5]]
        covariance = np.einsum("m,wmab->wab", alphas[first] * alphas[second], piece)
        covariance += np.diag(floors ** 2 + _JITTER)
        factor = np.linalg.cholesky(covariance)
        whitened = np.linalg.solve(factor, residual[:, :, None])[:, :, 0]
        log_det = 2.0 * np.log(np.diagonal(factor, axis1=1, axis2=2)).sum()
        return 0.5 * float(log_det + np.sum(whitened ** 2))

    start = np.log([0.05, 0.005, 0.02, 0.005, 0.01, 0.01])  # the simulator's alphas, centimetre floors
    result = minimize(negative_log_likelihood, start, method="L-BFGS-B", bounds=[(-16.0, 2.0)] * 6)
    if not np.isfinite(result.fun):
        raise ValueError(f"odometry noise fit failed on {sorted(per_log)}: {result.message}")
    a1, a2, a3, a4, f_xy, f_theta = (float(value) for value in np.exp(result.x))
    model = OdometryNoise(alpha1=a1, alpha2=a2, alpha3=a3, alpha4=a4, scale_sigma=scale_sigma,
                          drift_sigma=drift_sigma, level=1.0)
    return NoiseFit(model=model, floor_xy=f_xy, floor_theta=f_theta, per_log=per_log,
                    calibration_drive=float(calibration_drive), window=float(window))
