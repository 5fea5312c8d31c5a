"""The chordal relaxation of the pose graph: headings for the start of a Laplace fit, from one linear solve.

The start of the fit that defines P* (docs/model.md §3.3, "Which minimum is P*"). The energy E of a
partition is non-linear only through the headings: given them, the odometry residuals are linear in the
positions and the ties are quadratic. The relaxation (the chordal initialisation of pose-graph SLAM:
Martinec & Pajdla 2007; Carlone et al., ICRA 2015) replaces each heading theta_j by the unconstrained
2-vector q_j = (cos theta_j, sin theta_j), so that every term becomes linear in (t_j, q_j):

    rotation of step k:     w_theta,k (q_k - R(o_k^theta) q_{k-1})
    translation of step k:  w_xy,k (t_k - t_{k-1} - [[c, -s], [s, c]]_{k-1} o_k^xy),   (c, s) = q_{k-1}
    tie of S in T:          (t_i - t_j) / sigma_T   for i < j in S

with isotropic weights w_xy,k = sqrt(mean of the translation information's diagonal) and w_theta,k =
sqrt(Sigma_k^-1 [theta, theta]); pose 0 is fixed at q_0 = (1, 0), t_0 = 0. The least-squares solution is one
sparse solve of 4(N-1) unknowns, and theta_j = atan2(q_j). Where the loops of T are consistent the
relaxation is nearly tight, so the headings it gives already bend the dead-reckoned drift the way the
closures ask; from dead reckoning, a Newton fit spends most of its iterations doing that, and on a long run
it can stop in a basin hundreds of nats above the minimum reached from here.

    >>> import numpy as np
    >>> from ptm.pose_graph import PoseGraph, odometry_sqrt_information
    >>> odometry = np.array([[2.0, 0.0, 1.4]] + [[2.0, 0.0, np.pi / 2]] * 3)      # a square, the first turn 0.17 short
    >>> graph = PoseGraph(odometry, odometry_sqrt_information(np.diag([0.01, 0.01, 0.0025])[None].repeat(4, 0)), 0.1)
    >>> labels = [0, 1, 2, 3, 0]                                                  # the loop closes
    >>> chordal_headings(odometry, graph.information, graph.topology(labels)).round(2)   # dead reckoning: 1.4 ... 6.11
    array([1.42, 3.01, 4.58, 6.15])
    >>> starts = (graph.dead_reckoning(), graph.chordal_start(labels))
    >>> [round(float(graph.energy(start, labels)), 2) for start in starts]
    [5.82, 0.85]
    >>> round(float(graph.fit(graph.chordal_start(labels), labels).energy), 2)  # the minimum
    0.84
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from .topology import TopologyHessian

__all__ = ["chordal_headings"]


def chordal_headings(odometry, information, topology: TopologyHessian) -> np.ndarray:
    """The headings theta_1..theta_{N-1} of the chordal relaxation's least-squares solution (module
    docstring), each within pi of its dead-reckoned value.

    ``odometry`` is (N-1, 3), ``information`` the per-step Sigma_k^-1, (N-1, 3, 3).
    """
    odometry = np.asarray(odometry, dtype=float)
    steps = len(odometry)
    translation_weight = np.sqrt(0.5 * (information[:, 0, 0] + information[:, 1, 1]))
    rotation_weight = np.sqrt(information[:, 2, 2])
    dx, dy, turn = odometry.T
    cos_turn, sin_turn = np.cos(turn), np.sin(turn)
    # rows 4k .. 4k+3 (x, y, c, s of step k+1); unknowns 4j .. 4j+3 = (x_j, y_j, c_j, s_j) of pose j = 0..N-1
    earlier, later = 4 * np.arange(steps), 4 * np.arange(1, steps + 1)
    entries = [  # (row offset, column of the later pose or the earlier one, offset, coefficient / weight)
        (0, later, 0, 1.0), (0, earlier, 0, -1.0), (0, earlier, 2, -dx), (0, earlier, 3, dy),
        (1, later, 1, 1.0), (1, earlier, 1, -1.0), (1, earlier, 2, -dy), (1, earlier, 3, -dx),
        (2, later, 2, 1.0), (2, earlier, 2, -cos_turn), (2, earlier, 3, sin_turn),
        (3, later, 3, 1.0), (3, earlier, 2, -sin_turn), (3, earlier, 3, -cos_turn),
    ]
    weights = (translation_weight, translation_weight, rotation_weight, rotation_weight)
    rows = np.concatenate([np.arange(steps) * 4 + offset for offset, *_ in entries])
    cols = np.concatenate([pose + coordinate for _, pose, coordinate, _ in entries])
    values = np.concatenate([weights[offset] * np.broadcast_to(coefficient, steps)
                             for offset, _, _, coefficient in entries])
    design = scipy.sparse.csc_matrix((values, (rows, cols)), shape=(4 * steps, 4 * (steps + 1)))
    free = design[:, 4:]
    target = -design[:, 2].toarray().ravel()  # pose 0's fixed q_0 = (1, 0) moved to the right-hand side
    # the ties: the clique Laplacian of T / sigma_T^2 on the positions (the state's x, y -> the unknowns' x, y)
    tie_rows, tie_cols, tie_values = topology.entries
    normal = (free.T @ free + scipy.sparse.csc_matrix(
        (tie_values, (_unknown_index(tie_rows), _unknown_index(tie_cols))), shape=(4 * steps, 4 * steps)))
    solution = scipy.sparse.linalg.spsolve(normal.tocsc(), free.T @ target).reshape(steps, 4)
    headings = np.arctan2(solution[:, 3], solution[:, 2])
    dead_reckoned = np.cumsum(turn)
    return dead_reckoned + np.angle(np.exp(1j * (headings - dead_reckoned)))


def _unknown_index(state_index) -> np.ndarray:
    """The relaxation's unknown of a state coordinate x or y: pose j's 3(j-1) + a -> 4(j-1) + a."""
    return 4 * (state_index // 3) + state_index % 3
