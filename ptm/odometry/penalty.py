"""The landmark-density penalty Pen of the odometry likelihood (docs/model.md §3.3; paper eq. 11-12).

Distinct places are assumed not to lie close together. For a partition T and the positions t_i of the
detections,

    Pen_T(P) = sum over pairs i < j in different sets of f(|t_i - t_j|),
    f(d) = P_max (1 - d / D)^3 for d < D, else 0,

a cubic that reaches 0 at d = D with zero slope and zero curvature, so that Newton steps see a smooth
function. :func:`landmark_penalty` evaluates it for many states at once (the importance samples);
:class:`DetectionPenalty` knows which pairs of one run's detections a partition's penalty can count;
:class:`PairPenalty` gives the value, gradient and Hessian over a fixed set of pairs (the Newton search
for the penalised mode, :mod:`ptm.odometry.proposal`).

    >>> positions = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]])     # 1 m and 5 m from the first
    >>> pairs = (np.array([0, 0]), np.array([1, 2]))
    >>> float(landmark_penalty(positions, pairs, penalty_radius=2.0, max_penalty=100.0))   # 100 (1 - 1/2)^3
    12.5
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.spatial.distance

from ..pose_graph import poses_from_vector

__all__ = ["landmark_penalty", "DetectionPenalty", "PairPenalty"]


def landmark_penalty(positions, pairs, penalty_radius: float, max_penalty: float) -> np.ndarray:
    """Pen = sum over ``pairs`` (i, j) of f(|t_i - t_j|) for positions of shape (..., N, 2) (eq. 11-12).

    The caller passes the pairs in different sets (and may leave out pairs that
    cannot come within the radius: they contribute exactly 0).
    """
    first, second = pairs
    x, y = positions[..., 0], positions[..., 1]  # gathered per coordinate: 2-4 times faster than (..., P, 2)
    across, along = x[..., first] - x[..., second], y[..., first] - y[..., second]
    closeness = np.maximum(1.0 - np.sqrt(across * across + along * along) / penalty_radius, 0.0)
    return max_penalty * np.sum(closeness * closeness * closeness, axis=-1)


class DetectionPenalty:
    """Pen over the N detections of one run: its pairs i < j (``first``, ``second``, in the order of
    ``numpy.triu_indices`` and of ``scipy.spatial.distance.pdist``) and those that a partition's penalty counts.

    Pose 0 is fixed at the origin, so the states are the (d,) vectors of poses 1..N-1.
    """

    def __init__(self, n: int, penalty_radius: float, max_penalty: float):
        self.n = n
        self.penalty_radius, self.max_penalty = penalty_radius, max_penalty
        self.first, self.second = np.triu_indices(n, k=1)

    def close_pairs(self, distance, labels) -> np.ndarray:
        """Indices (into ``pdist`` order) of the pairs of different sets closer than the radius, for the
        pairwise ``distance`` of the detections' positions (``pdist`` order) and the partition's ``labels``."""
        near = np.flatnonzero(distance < self.penalty_radius)
        return near[labels[self.first[near]] != labels[self.second[near]]]

    def at(self, x, labels) -> "PairPenalty":
        """Pen over the positions of detections 1..N-1 (rows 0..N-2; detection 0 is the origin, row -1),
        counting the pairs of different sets within the radius at the state ``x``."""
        near = self.close_pairs(scipy.spatial.distance.pdist(poses_from_vector(x)[:, :2]), labels)
        return PairPenalty((self.first[near] - 1, self.second[near] - 1), self.n - 1, self.penalty_radius,
                           self.max_penalty)

    def of_states(self, states, offsets, centre, labels, centre_distance) -> np.ndarray:
        """Pen of every sample (``states``: (S, d), their ``offsets`` from the ``centre`` P*: (d, S);
        ``centre_distance``: the pairwise distances at P*); pairs that no sample can bring within the radius
        are skipped exactly."""
        if self.max_penalty == 0.0 or self.n < 2:
            return np.zeros(len(states))
        reach = np.zeros(self.n)
        reach[1:] = np.sqrt(np.max(offsets[0::3] ** 2 + offsets[1::3] ** 2, axis=1))
        # triangle inequality: |t_i^s - t_j^s| >= |t_i* - t_j*| - reach_i - reach_j
        near = np.flatnonzero(centre_distance < self.penalty_radius + 2.0 * reach.max())
        first, second = self.first[near], self.second[near]
        may_touch = ((labels[first] != labels[second])
                     & (centre_distance[near] - reach[first] - reach[second] < self.penalty_radius))
        pairs = (first[may_touch], second[may_touch])
        return landmark_penalty(poses_from_vector(states)[..., :2], pairs, self.penalty_radius, self.max_penalty)


class PairPenalty:
    """Pen(t) = sum over ``pairs`` (i, j) of rows of the positions t (m, 2) of f(|t_i - t_j|) (row -1: pose 0
    at the origin), and its derivatives; the pairs' index arithmetic is done once, for the many evaluations
    of one Newton search."""

    def __init__(self, pairs, rows: int, penalty_radius: float, max_penalty: float):
        self.first, self.second = pairs
        self.rows = rows
        self.penalty_radius, self.max_penalty = penalty_radius, max_penalty
        padded_rows = rows + 1  # the origin appended
        first, second = self.first % padded_rows, self.second % padded_rows
        # entries summed in the order of np.add.at over the first then the second rows (so bit for bit
        # its sums): the gradient's (row, axis), the Hessian's (row, axis, row, axis) of each pair's block
        self._gradient_entries = (2 * np.concatenate([first, second])[:, None] + np.arange(2)).ravel()
        block_rows, block_cols = (np.concatenate([first, second, first, second]),
                                  np.concatenate([first, second, second, first]))
        axis_rows, axis_cols = np.divmod(np.arange(4), 2)
        self._hessian_entries = (((2 * block_rows[:, None] + axis_rows) * padded_rows + block_cols[:, None]) * 2
                                 + axis_cols).ravel()

    def _separations(self, positions):
        padded = np.concatenate([positions, np.zeros((1, 2))])  # row -1: the origin
        separation = padded[self.first] - padded[self.second]
        distances = np.hypot(separation[:, 0], separation[:, 1])
        closeness = np.clip(1.0 - distances / self.penalty_radius, 0.0, None)
        return separation, distances, closeness

    def __call__(self, positions) -> float:
        """Pen of the positions t (m, 2)."""
        return self.max_penalty * float(np.sum(self._separations(positions)[2] ** 3))

    def derivatives(self, positions, sparse: bool = False):
        """Pen, its gradient (2m,) and the positive semi-definite part of its Hessian (2m, 2m): per pair
        f''(d) u u^T, without the tangential part f'(d)/d (I - u u^T), which is negative (as Gauss-Newton
        leaves out residual curvature). With ``sparse`` the Hessian is a ``scipy.sparse.coo_matrix``
        (duplicate entries to be summed)."""
        separation, distances, closeness = self._separations(positions)
        value = self.max_penalty * float(np.sum(closeness**3))
        units = separation / np.where(distances > 0.0, distances, np.inf)[:, None]
        slope = -3.0 * self.max_penalty / self.penalty_radius * closeness**2  # f'(d)
        curvature = 6.0 * self.max_penalty / self.penalty_radius**2 * closeness  # f''(d) >= 0
        pulls = slope[:, None] * units
        padded_size = 2 * (self.rows + 1)
        gradient = np.bincount(self._gradient_entries, weights=np.concatenate([pulls, -pulls]).ravel(),
                               minlength=padded_size)
        blocks = curvature[:, None, None] * units[:, :, None] * units[:, None, :]
        entries = np.concatenate([blocks, blocks, -blocks, -blocks]).ravel()
        size = 2 * self.rows
        if sparse:  # the entries' flat indices into the padded matrix, without the origin's rows and columns
            rows, cols = np.divmod(self._hessian_entries, padded_size)
            kept = (rows < size) & (cols < size)
            return value, gradient[:size], scipy.sparse.coo_matrix((entries[kept], (rows[kept], cols[kept])),
                                                                   shape=(size, size))
        hessian = np.bincount(self._hessian_entries, weights=entries,
                              minlength=padded_size**2).reshape(padded_size, padded_size)
        return value, gradient[:size], hessian[:size, :size]
