"""The simulator's odometry noise model fitted to real robots: raw increments against a reference trajectory.

The model is the one that generates the simulator's odometry
(:mod:`ptm_bench.simulation.odometry_noise`, docs/model.md §5): each scan's
motion is (rot1, trans, rot2), measured with standard deviations

    sd(rot1)  = alpha1 |rot1| + alpha2 trans
    sd(trans) = alpha3 trans  + alpha4 (|rot1| + |rot2|)
    sd(rot2)  = alpha1 |rot2| + alpha2 trans

plus, per run, a translation-scale error s (trans' = (1 + s) trans) and a
heading drift d [rad/m] (rot2' = rot2 + d trans). New here: a *floor*, an
independent error of sd ``floor_xy`` on dx and dy and ``floor_theta`` on
dtheta added once per increment, which absorbs the reference's own jitter
(GMapping's scan matching) and the logs' quantisation. It does not
accumulate along the odometry: a dataset row composed of many scans gets the
floor once (:meth:`NoiseFit.row_covariances`).

**Fit.** For each log, s and d are least-squares slopes of the translation
error and the heading error on the reference translation. The alphas and
floors are maximum-likelihood estimates over all scans of all logs, with
each log's own s and d removed: the residual u_k - m_k of the raw
increment u_k against its mean m_k (the reference increment with s and d
applied), in (dx, dy, dtheta), is Normal with covariance
J diag(sd^2) J^T + diag(floor_xy^2, floor_xy^2, floor_theta^2), J the Jacobian
of (dx, dy, dtheta) in (rot1, trans, rot2) at the reference.
The systematic sigmas ``scale_sigma`` and ``drift_sigma`` are the root mean
squares of the logs' s and d (the spread of the systematic errors between
robots). A dataset's odometry covariances come from a fit on *other* logs
(:func:`fit_noise` of those logs), never on the log itself.

    >>> from ptm_bench.logs.carmen import read_carmen, shipped_log
    >>> fit = fit_noise([read_carmen(shipped_log(name)) for name in ("aces", "fhw", "acapulco")])
    >>> 0.0 < fit.model.alpha1 < 1.0 and 0.0 < fit.floor_xy < 0.1
    True
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from ptm.se2 import wrap_angle

from ptm_bench.logs.carmen import CarmenLog
from ptm_bench.simulation.odometry_noise import OdometryNoise, OdometrySteps, decompose, detection_odometry

__all__ = ["NoiseFit", "fit_noise", "log_name", "systematic_errors"]

_JITTER = 1e-10  # on the variances of the fit's likelihood: keeps the covariance regular at any parameters


@dataclass(frozen=True)
class NoiseFit:
    """A fitted odometry noise model: the simulator's parameters, the floors, and what each log contributed."""

    model: OdometryNoise  # alpha1..alpha4, scale_sigma, drift_sigma (level 1)
    floor_xy: float  # [m] sd of the independent error on dx and dy of every increment
    floor_theta: float  # [rad] sd of the independent error on dtheta of every increment
    per_log: dict = field(default_factory=dict)  # log name -> {"scans", "scale_error", "heading_drift"}

    def steps(self, increments) -> OdometrySteps:
        """The raw increments with the standard deviations of their (rot1, trans, rot2), without the floor."""
        increments = np.asarray(increments, dtype=float).reshape(-1, 3)
        return OdometrySteps(increments, self.model.step_sigmas(*decompose(increments)), 0.0, 0.0, self.model)

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
                "fitted_on": sorted(self.per_log), "per_log": self.per_log}


def log_name(log: CarmenLog) -> str:
    """A log's short name: its file name without ``-corrected`` and the ``.log(.gz)`` suffixes."""
    name = Path(log.source).name
    for suffix in (".gz", ".log", "-corrected"):
        name = name.removesuffix(suffix)
    return name


def systematic_errors(log: CarmenLog) -> tuple[float, float]:
    """(s, d): the log's translation-scale error and heading drift [rad/m] against its reference."""
    raw, reference = log.raw_increments, log.reference_increments()
    _, raw_trans, _ = decompose(raw)
    _, trans, _ = decompose(reference)
    travelled = float(trans @ trans)
    if travelled <= 0.0:
        raise ValueError(f"{log.source}: the reference never moves; no odometry noise can be fitted")
    scale = float((raw_trans - trans) @ trans) / travelled
    drift = float(wrap_angle(raw[:, 2] - reference[:, 2]) @ trans) / travelled
    return scale, drift


def _residuals(log: CarmenLog, scale: float, drift: float):
    """Residuals (T, 3) of the raw increments against the reference with the log's systematic errors applied."""
    reference = log.reference_increments()
    rot1, trans, rot2 = decompose(reference)
    mean_trans = (1.0 + scale) * trans
    mean = np.stack([mean_trans * np.cos(rot1), mean_trans * np.sin(rot1), rot1 + rot2 + drift * trans], axis=-1)
    residual = log.raw_increments - mean
    residual[:, 2] = wrap_angle(residual[:, 2])
    return residual, (rot1, trans, rot2)


def fit_noise(logs) -> NoiseFit:
    """Maximum-likelihood alphas and floors over ``logs`` (each needs a reference), systematic sigmas from their spread."""
    logs = list(logs)
    if not logs:
        raise ValueError("fitting the odometry noise needs at least one log with a reference trajectory")
    per_log, residuals, motions = {}, [], []
    for log in logs:
        scale, drift = systematic_errors(log)
        residual, motion = _residuals(log, scale, drift)
        residuals.append(residual)
        motions.append(np.stack(motion, axis=-1))
        per_log[log_name(log)] = {"scans": log.n_scans, "scale_error": round(scale, 6), "heading_drift": round(drift, 6)}
    residual = np.concatenate(residuals)
    rot1_signed, trans, rot2 = np.concatenate(motions).T
    rot1, rot2 = np.abs(rot1_signed), np.abs(rot2)

    # The entries of J diag(sd^2) J^T, written out: a batched 3 x 3 solve would take ten times as long.
    cos, sin = np.cos(rot1_signed), np.sin(rot1_signed)
    x, y, theta = residual.T

    def negative_log_likelihood(log_params):
        a1, a2, a3, a4, f_xy, f_theta = np.exp(log_params)
        v1 = (a1 * rot1 + a2 * trans) ** 2
        v2 = (a3 * trans + a4 * (rot1 + rot2)) ** 2
        v3 = (a1 * rot2 + a2 * trans) ** 2
        tv1 = trans * v1
        cxx = trans * sin * sin * tv1 + cos * cos * v2 + f_xy ** 2 + _JITTER
        cyy = trans * cos * cos * tv1 + sin * sin * v2 + f_xy ** 2 + _JITTER
        cxy = cos * sin * (v2 - trans * tv1)
        cxt, cyt, ctt = -sin * tv1, cos * tv1, v1 + v3 + f_theta ** 2 + _JITTER
        # cofactors of the symmetric 3 x 3 matrix [[cxx, cxy, cxt], [cxy, cyy, cyt], [cxt, cyt, ctt]]
        k00, k01, k02 = cyy * ctt - cyt * cyt, cxt * cyt - cxy * ctt, cxy * cyt - cxt * cyy
        k11, k12, k22 = cxx * ctt - cxt * cxt, cxy * cxt - cxx * cyt, cxx * cyy - cxy * cxy
        det = cxx * k00 + cxy * k01 + cxt * k02
        quadratic = (k00 * x * x + k11 * y * y + k22 * theta * theta
                     + 2.0 * (k01 * x * y + k02 * x * theta + k12 * y * theta)) / det
        return 0.5 * float(np.sum(np.log(det)) + np.sum(quadratic))

    start = np.log([0.05, 0.005, 0.02, 0.005, 0.01, 0.01])  # the simulator's alphas, centimetre floors
    result = minimize(negative_log_likelihood, start, method="L-BFGS-B", bounds=[(-16.0, 2.0)] * 6)
    if not np.isfinite(result.fun):
        raise ValueError(f"odometry noise fit failed on {sorted(per_log)}: {result.message}")
    a1, a2, a3, a4, f_xy, f_theta = (float(value) for value in np.exp(result.x))
    scales = np.array([entry["scale_error"] for entry in per_log.values()])
    drifts = np.array([entry["heading_drift"] for entry in per_log.values()])
    model = OdometryNoise(alpha1=a1, alpha2=a2, alpha3=a3, alpha4=a4,
                          scale_sigma=float(np.sqrt(np.mean(scales ** 2))),
                          drift_sigma=float(np.sqrt(np.mean(drifts ** 2))), level=1.0)
    return NoiseFit(model=model, floor_xy=f_xy, floor_theta=f_theta, per_log=per_log)
