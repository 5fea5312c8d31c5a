"""The odometry term of the pose-graph energy: SE(2) relative-pose residuals and their derivatives.

Implements the odometry part of the energy of docs/model.md §3.3 (paper
eq. 3, 13). The variables are the poses p_i = (x_i, y_i, theta_i) of
detections 1..N-1 flattened into one state vector of d = 3(N-1) numbers;
pose 0 is fixed at the origin (the gauge). Step k contributes

    1/2 r_k^T Sigma_k^-1 r_k,    r_k = (p_{k-1}^-1 o p_k) - o_k

(:func:`ptm.se2.relative_pose` of the two poses minus the measured odometry
row, the angle wrapped), so ``odometry_cov``, given in the frame of the
earlier detection, whitens it directly. :class:`StepFrames` holds each
step's rotation and relative translation once, and gives the residuals, the
analytic Jacobians and the residual-weighted second derivatives from them.

    >>> import numpy as np
    >>> poses = poses_from_vector(np.array([1.0, 0.0, np.pi / 2, 1.0, 1.0, np.pi]))
    >>> odometry_residuals(poses, np.array([[1.0, 0.0, np.pi / 2], [1.0, 0.0, np.pi / 2]])).round(12) + 0.0
    array([[0., 0., 0.],
           [0., 0., 0.]])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..se2 import wrap_angle

__all__ = [
    "StepFrames",
    "StepInformation",
    "odometry_sqrt_information",
    "odometry_residuals",
    "odometry_jacobian_blocks",
    "odometry_second_order_blocks",
    "poses_from_vector",
]


def odometry_sqrt_information(covariances) -> np.ndarray:
    """Per-step whitening matrices U_k with U_k^T U_k = Sigma_k^-1 (shape (N-1, 3, 3)).

    Raises ``ValueError`` naming the step when a covariance is not symmetric
    positive definite (its Cholesky factorisation fails).
    """
    covariances = np.asarray(covariances, dtype=float)
    if covariances.ndim != 3 or covariances.shape[1:] != (3, 3):
        raise ValueError(f"odometry_cov must have shape (N-1, 3, 3), got {covariances.shape}")
    if not np.all(np.isfinite(covariances)):
        raise ValueError("odometry_cov contains non-finite values")
    if not np.allclose(covariances, np.swapaxes(covariances, 1, 2), rtol=1e-9, atol=1e-12):
        raise ValueError("odometry_cov is not symmetric")
    try:
        lower = np.linalg.cholesky(covariances)
    except np.linalg.LinAlgError:
        eigenvalues = np.linalg.eigvalsh(covariances).min(axis=1)
        step = int(np.argmin(eigenvalues))
        raise ValueError(
            f"odometry_cov[{step}] is not positive definite (smallest eigenvalue {eigenvalues[step]:.3g})"
        ) from None
    identity = np.broadcast_to(np.eye(3), covariances.shape)
    return np.linalg.solve(lower, identity)  # U_k = L_k^-1, so U_k^T U_k = Sigma_k^-1


def poses_from_vector(x) -> np.ndarray:
    """Prepend the fixed origin pose: (..., 3(N-1)) state vectors -> (..., N, 3) poses."""
    x = np.asarray(x, dtype=float)
    poses = x.reshape(*x.shape[:-1], -1, 3)
    origin = np.zeros((*x.shape[:-1], 1, 3))
    return np.concatenate([origin, poses], axis=-2)


@dataclass(frozen=True)
class StepFrames:
    """Each step's starting frame: cos and sin of the earlier pose's heading, the later pose's position
    (u, v) in that frame and the heading change ``turn``, each of shape (..., N-1).

    (u, v, wrap(turn)) is :func:`ptm.se2.relative_pose` of consecutive poses;
    the rotation is kept because the Jacobians need it.
    """

    cos: np.ndarray
    sin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    turn: np.ndarray

    @classmethod
    def of(cls, poses) -> "StepFrames":
        """The frames of consecutive poses of shape (..., N, 3)."""
        previous = poses[..., :-1, :]
        cos, sin = np.cos(previous[..., 2]), np.sin(previous[..., 2])
        step = poses[..., 1:, :] - previous
        dx, dy, turn = step[..., 0], step[..., 1], step[..., 2]
        return cls(cos, sin, cos * dx + sin * dy, -sin * dx + cos * dy, turn)

    def residuals(self, odometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The three components of r_k = (p_{k-1}^-1 o p_k) - o_k, each of shape (..., N-1).

        The angle residual is wrapped to (-pi, pi] (the energy is even in it, so
        the end point does not matter).
        """
        return self.u - odometry[:, 0], self.v - odometry[:, 1], wrap_angle(self.turn - odometry[:, 2])

    def jacobian_blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """dr_k/dp_{k-1} and dr_k/dp_k, each of shape (N-1, 3, 3) (see :func:`odometry_jacobian_blocks`)."""
        cos, sin, u, v = self.cos, self.sin, self.u, self.v
        steps = len(cos)
        wrt_current = np.zeros((steps, 3, 3))
        wrt_current[:, 0, 0] = cos
        wrt_current[:, 0, 1] = sin
        wrt_current[:, 1, 0] = -sin
        wrt_current[:, 1, 1] = cos
        wrt_current[:, 2, 2] = 1.0
        wrt_previous = -wrt_current
        wrt_previous[:, 0, 2] = v
        wrt_previous[:, 1, 2] = -u
        return wrt_previous, wrt_current

    def second_order_blocks(self, multipliers) -> tuple[np.ndarray, np.ndarray]:
        """sum_i m_ki d^2 r_ki of each step, shape (N-1, 3, 3) each (see :func:`odometry_second_order_blocks`)."""
        cos, sin, u, v = self.cos, self.sin, self.u, self.v
        m_u, m_v = multipliers[:, 0], multipliers[:, 1]
        theta_x_current = -m_u * sin - m_v * cos
        theta_y_current = m_u * cos - m_v * sin
        wrt_previous = np.zeros((len(cos), 3, 3))
        wrt_previous[:, 2, 2] = -m_u * u - m_v * v
        wrt_previous[:, 2, 0] = wrt_previous[:, 0, 2] = -theta_x_current
        wrt_previous[:, 2, 1] = wrt_previous[:, 1, 2] = -theta_y_current
        between = np.zeros((len(cos), 3, 3))
        between[:, 2, 0] = theta_x_current
        between[:, 2, 1] = theta_y_current
        return wrt_previous, between


class StepInformation:
    """The information matrices Sigma_k^-1 of the odometry steps and the energy they weight residuals with.

    Parameters
    ----------
    sqrt_information : (N-1, 3, 3) array
        Whitening matrices U_k with U_k^T U_k = Sigma_k^-1 (see :func:`odometry_sqrt_information`).
    """

    def __init__(self, sqrt_information):
        self.sqrt_information = np.asarray(sqrt_information, dtype=float)
        self.information = np.swapaxes(self.sqrt_information, 1, 2) @ self.sqrt_information
        # r_k^T W_k r_k = sum_{a<=b} c_kab r_ka r_kb with c_kaa = W_kaa and c_kab = 2 W_kab (zero terms left out)
        self._quadratic_terms = [(a, b, (1.0 if a == b else 2.0) * self.information[:, a, b])
                                 for a in range(3) for b in range(a, 3) if np.any(self.information[:, a, b])]
        terms = self._quadratic_terms
        self._term_components = (np.array([a for a, _, _ in terms], dtype=int),
                                 np.array([b for _, b, _ in terms], dtype=int))
        self._term_coefficients = np.array([c for _, _, c in terms]).reshape(len(terms), len(self.information))

    def energy(self, residuals) -> np.ndarray:
        """1/2 sum_k r_k^T Sigma_k^-1 r_k from the three residual components (each (..., N-1))."""
        if np.ndim(residuals[0]) == 1:  # one state: the terms' dot products in one call (the same ddot each)
            components = np.array(residuals)
            first, second = self._term_components
            return 0.5 * sum(np.vecdot(components[first] * components[second], self._term_coefficients).tolist())
        return 0.5 * sum((residuals[a] * residuals[b]) @ coefficients for a, b, coefficients in self._quadratic_terms)

    def multipliers(self, residuals) -> np.ndarray:
        """m_k = Sigma_k^-1 r_k, shape (N-1, 3), from the three residual components of one state."""
        return np.einsum("kij,kj->ki", self.information, np.ascontiguousarray(np.transpose(residuals)))


def odometry_residuals(poses, odometry) -> np.ndarray:
    """r_k = (p_{k-1}^-1 o p_k) - o_k for poses of shape (..., N, 3); returns (..., N-1, 3).

    The angle residual is wrapped to (-pi, pi].
    """
    return np.stack(StepFrames.of(poses).residuals(odometry), axis=-1)


def odometry_jacobian_blocks(poses) -> tuple[np.ndarray, np.ndarray]:
    """Analytic Jacobians of r_k with respect to p_{k-1} and p_k, each of shape (N-1, 3, 3).

    With R the rotation of p_{k-1} and delta = t_k - t_{k-1} expressed in its
    frame as (u, v): d(u, v)/d t_k = R^T, d(u, v)/d t_{k-1} = -R^T,
    d(u, v)/d theta_{k-1} = (v, -u), and the angle residual has slopes +1 / -1.
    """
    return StepFrames.of(poses).jacobian_blocks()


def odometry_second_order_blocks(poses, multipliers) -> tuple[np.ndarray, np.ndarray]:
    """Residual-weighted second derivatives sum_i m_ki d^2 r_ki of each step, shape (N-1, 3, 3) each.

    ``multipliers`` are m_k = Sigma_k^-1 r_k. Only the translation residual
    (u, v) is non-linear, and only through theta_{k-1}: d^2 u / d theta^2 = -u,
    d^2 v / d theta^2 = -v, d/d theta of d(u, v)/d t_k = ((-sin, cos), (-cos, -sin)),
    and the opposite for t_{k-1}. Returns the (p_{k-1}, p_{k-1}) and the
    (p_{k-1}, p_k) blocks; the (p_k, p_k) block is zero.
    """
    return StepFrames.of(poses).second_order_blocks(multipliers)
