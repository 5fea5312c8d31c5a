"""Noisy odometry: the rotation-translation-rotation motion model, systematic error, covariance (docs/model.md §5).

Every control step the true planar motion ``prev_T_curr`` is decomposed as
``rot1`` (turn towards the new position), ``trans`` (drive) and ``rot2`` (turn
to the new heading) -- the odometry motion model of Thrun, Burgard and Fox,
*Probabilistic Robotics*, Table 5.6 -- and perturbed with zero-mean Gaussian
noise whose *standard deviations* are (all scaled by the noise level S)

    sd(rot1)  = S (alpha1 |rot1| + alpha2 trans)
    sd(trans) = S (alpha3 trans  + alpha4 (|rot1| + |rot2|))
    sd(rot2)  = S (alpha1 |rot2| + alpha2 trans)

plus two systematic errors drawn once per run: a translation-scale error
``s ~ N(0, (S scale_sigma)^2)`` (trans' = (1 + s) trans) and a heading drift
``d ~ N(0, (S drift_sigma)^2)`` radians per metre (rot2' gains d trans). The
noisy increment is composed on SE(2), so error accumulates along the run.

The covariance of each dataset row (motion between two detections, in the
frame of the earlier one) is propagated step by step with the linearised model
on the state (dx, dy, dtheta, s, d): the systematic parameters start each row
at their prior variance, so each row's covariance is its marginal (rows share
s and d, a correlation a per-row covariance cannot carry). A floor of
``COVARIANCE_FLOOR`` on the diagonal keeps it positive definite at S = 0.

    >>> import numpy as np
    >>> true_poses = np.column_stack([np.linspace(0.0, 30.0, 301), np.zeros(301), np.zeros(301)])  # 30 m straight
    >>> steps = sample_odometry(true_poses, OdometryNoise().scaled(1.0), np.random.default_rng(0))
    >>> rows, covariances = detection_odometry(steps, [0, 120, 300])
    >>> rows.shape, covariances.shape
    ((2, 3), (2, 3, 3))
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from ptm.se2 import compose, dead_reckoning, relative_pose, wrap_angle  # the one SE(2) module

__all__ = [
    "COVARIANCE_FLOOR",
    "OdometryNoise",
    "OdometrySteps",
    "decompose",
    "detection_odometry",
    "sample_odometry",
]

COVARIANCE_FLOOR = 1e-10  # added to each variance: (1e-5 m)^2 and (1e-5 rad)^2


@dataclass(frozen=True)
class OdometryNoise:
    """Noise parameters of the odometry (standard-deviation form) and the overall level S."""

    alpha1: float = 0.05  # rad of rotation noise per rad turned
    alpha2: float = 0.005  # rad of rotation noise per metre driven
    alpha3: float = 0.02  # m of translation noise per metre driven
    alpha4: float = 0.005  # m of translation noise per rad turned
    scale_sigma: float = 0.01  # sd of the per-run translation-scale error (fraction)
    drift_sigma: float = 0.0005  # sd of the per-run heading drift [rad/m]
    level: float = 1.0  # S: multiplies every standard deviation above

    def __post_init__(self):
        for name, value in asdict(self).items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ValueError(f"odometry noise {name} must be a finite number, got {value!r}")
            if value < 0:
                raise ValueError(f"odometry noise {name} must be >= 0, got {value!r}")

    def scaled(self, level: float) -> "OdometryNoise":
        """The same model at noise level ``level``."""
        if isinstance(level, bool) or not isinstance(level, (int, float)) or not np.isfinite(level) or level < 0:
            raise ValueError(f"noise must be a finite number >= 0, got {level!r}")
        return replace(self, level=float(level))

    def step_sigmas(self, rot1, trans, rot2) -> np.ndarray:
        """(T, 3) standard deviations of (rot1, trans, rot2) for each step."""
        rot1, trans, rot2 = np.abs(rot1), np.abs(trans), np.abs(rot2)
        return self.level * np.stack(
            [
                self.alpha1 * rot1 + self.alpha2 * trans,
                self.alpha3 * trans + self.alpha4 * (rot1 + rot2),
                self.alpha1 * rot2 + self.alpha2 * trans,
            ],
            axis=-1,
        )

    def as_meta(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class OdometrySteps:
    """Per-control-step odometry of one run."""

    increments: np.ndarray  # (T, 3) measured prev_T_curr as (dx, dy, dtheta)
    sigmas: np.ndarray  # (T, 3) sd of (rot1, trans, rot2) used for each step
    scale_error: float  # the run's drawn translation-scale error s
    heading_drift: float  # the run's drawn heading drift d [rad/m]
    model: OdometryNoise
    #: (rot1, trans, rot2) of every increment, where the caller decomposed them otherwise than :func:`decompose`
    #: (real logs: turns on the spot and reversing, :func:`ptm_bench.logs.noise_fit.motion_components`); None:
    #: :func:`decompose`. The covariance propagation differentiates the increments in these components.
    motion: tuple | None = None


def decompose(increments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rot1, trans, rot2) of (T, 3) increments ``prev_T_curr``; rot1 = 0 for a turn on the spot."""
    increments = np.asarray(increments, dtype=float)
    trans = np.hypot(increments[:, 0], increments[:, 1])
    rot1 = np.where(trans > 1e-12, np.arctan2(increments[:, 1], increments[:, 0]), 0.0)
    rot2 = wrap_angle(increments[:, 2] - rot1)
    return rot1, trans, rot2


def _from_rtr(rot1, trans, rot2) -> np.ndarray:
    return np.stack([trans * np.cos(rot1), trans * np.sin(rot1), rot1 + rot2], axis=-1)


def sample_odometry(true_poses, model: OdometryNoise, rng: np.random.Generator) -> OdometrySteps:
    """Measured per-step increments for a true trajectory (T+1, 3) under ``model``."""
    true_poses = np.asarray(true_poses, dtype=float)
    if true_poses.ndim != 2 or true_poses.shape[1] != 3 or len(true_poses) < 2:
        raise ValueError(f"true_poses must have shape (T+1, 3) with T >= 1, got {true_poses.shape}")
    rot1, trans, rot2 = decompose(relative_pose(true_poses[:-1], true_poses[1:]))
    scale_error = model.level * model.scale_sigma * rng.standard_normal()
    heading_drift = model.level * model.drift_sigma * rng.standard_normal()
    sigmas = model.step_sigmas(rot1, trans, rot2)
    noise = sigmas * rng.standard_normal(sigmas.shape)
    measured = _from_rtr(rot1 + noise[:, 0], trans * (1.0 + scale_error) + noise[:, 1],
                         rot2 + heading_drift * trans + noise[:, 2])
    return OdometrySteps(measured, sigmas, float(scale_error), float(heading_drift), model)


def detection_odometry(steps: OdometrySteps, detection_steps) -> tuple[np.ndarray, np.ndarray]:
    """Odometry rows (K-1, 3) and their covariances (K-1, 3, 3) between consecutive detection steps.

    Row k is the measured motion from the pose at step ``detection_steps[k-1]``
    to the pose at ``detection_steps[k]``, in the frame of the earlier pose.
    """
    indices = np.asarray(detection_steps, dtype=int)
    in_run = len(indices) == 0 or (indices[0] >= 0 and indices[-1] <= len(steps.increments))
    if indices.ndim != 1 or np.any(np.diff(indices) <= 0) or not in_run:
        raise ValueError("detection_steps must be strictly increasing step indices within the run")
    odometry_poses = dead_reckoning(steps.increments)
    rows = relative_pose(odometry_poses[indices[:-1]], odometry_poses[indices[1:]])
    covariances = np.array([_row_covariance(steps, start, stop) for start, stop in zip(indices[:-1], indices[1:])])
    return rows, covariances.reshape(len(rows), 3, 3)


def _row_covariance(steps: OdometrySteps, start: int, stop: int) -> np.ndarray:
    """Linearised covariance of the composed increments ``start..stop-1`` (state dx, dy, dtheta, s, d)."""
    model = steps.model
    covariance = np.zeros((5, 5))
    covariance[3, 3] = (model.level * model.scale_sigma) ** 2
    covariance[4, 4] = (model.level * model.drift_sigma) ** 2
    rot1, trans, _ = (decompose(steps.increments[start:stop]) if steps.motion is None
                      else (component[start:stop] for component in steps.motion))
    pose = np.zeros(3)
    transition = np.eye(5)
    noise_map = np.zeros((5, 3))
    for k, increment in enumerate(steps.increments[start:stop]):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        rotate = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        # d(increment)/d(rot1, trans, rot2) at the measured values
        cr, sr = np.cos(rot1[k]), np.sin(rot1[k])
        increment_jacobian = np.array([[-trans[k] * sr, cr, 0.0], [trans[k] * cr, sr, 0.0], [1.0, 0.0, 1.0]])
        transition[:3, :3] = [[1.0, 0.0, -s * increment[0] - c * increment[1]],
                              [0.0, 1.0, c * increment[0] - s * increment[1]], [0.0, 0.0, 1.0]]
        step_map = rotate @ increment_jacobian
        # trans' = (1 + s) trans and rot2' = rot2 + d trans: derivatives trans along the trans and rot2 columns
        transition[:3, 3] = step_map[:, 1] * trans[k]
        transition[:3, 4] = step_map[:, 2] * trans[k]
        noise_map[:3] = step_map
        step_covariance = np.diag(steps.sigmas[start + k] ** 2)
        covariance = transition @ covariance @ transition.T + noise_map @ step_covariance @ noise_map.T
        pose = compose(pose, increment)
    return covariance[:3, :3] + COVARIANCE_FLOOR * np.eye(3)
