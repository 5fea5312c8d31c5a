"""The GTSAM Pose2 graph shared by the ``gnc`` and ``dcs`` peers (docs/model.md §3.3, §6).

The graph is the posterior's energy with every candidate as a tie: a prior
pins pose 0 (the gauge), odometry row k is a ``BetweenFactorPose2`` from pose
k-1 to pose k with the row's covariance (:class:`~ptm_bench.evaluation.peers.noise.PeerNoise`),
and candidate (i, j) says "i and j are one place": a ``BetweenFactorPose2``
whose position noise is the tie sigma sigma_T per axis and whose heading is
free (sigma :data:`FREE_HEADING_SIGMA` rad).

GTSAM's Pose2 between-factor measures the relative pose through the Pose2
logarithm, whose translation part is V(dtheta)^-1 times the position of j in
i's frame: it equals |t_j - t_i| only when the relative heading dtheta matches
the measured one. A tie therefore measures the relative heading the dead
reckoning gives (theta_j - theta_i); the optimiser's heading corrections
delta scale the position residual by delta / (2 sin(delta / 2)) (2 % at
0.5 rad of correction), where the posterior's tie (docs/model.md §3.3) is
|t_i - t_j| exactly.

GTSAM is the optional extra ``ptm[peers]``, imported when a graph is first built.

    >>> import numpy as np, ptm
    >>> from ptm_bench.evaluation.peers.noise import PeerNoise
    >>> dataset = ptm.Dataset(odometry=np.tile([1.0, 0.0, np.pi / 2], (4, 1)))     # a 1 m square, closed
    >>> graph = tie_graph(dataset, PeerNoise(0.1, 0.05, 0.3), np.array([[0, 4]]))
    >>> graph.graph.size(), graph.known_inliers
    (6, [0, 1, 2, 3, 4])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ptm.se2 import dead_reckoning, wrap_angle

__all__ = ["FREE_HEADING_SIGMA", "INSTALL_HINT", "PRIOR_SIGMA", "TieGraph", "import_gtsam", "tie_chi2", "tie_graph"]

#: Heading sigma [rad] of a tie: the wrapped heading residual (at most pi) then weighs at most (pi / 1e3)^2.
FREE_HEADING_SIGMA = 1e3
#: Sigma of the prior that pins pose 0 at the origin (the gauge; docs/model.md §3.3 fixes it exactly).
PRIOR_SIGMA = 1e-6

INSTALL_HINT = 'the robust pose-graph peers need GTSAM: pip install "ptm[peers]"'


def import_gtsam():
    """The ``gtsam`` module, or an ``ImportError`` of one line naming the extra to install."""
    try:
        import gtsam
    except ImportError:
        raise ImportError(INSTALL_HINT) from None
    return gtsam


@dataclass
class TieGraph:
    """A Pose2 factor graph: ``graph`` (prior, odometry, then one factor per candidate), ``initial`` (dead
    reckoning), ``known_inliers`` (the prior's and the odometry's factor indices), ``ties`` (the candidates'
    factors without a robust loss, for their residuals)."""

    graph: object
    initial: object
    known_inliers: list
    ties: list


def tie_graph(dataset, noise, pairs, robust=None) -> TieGraph:
    """The graph of ``dataset`` with a tie per candidate pair; ``robust`` (an m-estimator) wraps the ties' noise."""
    gtsam = import_gtsam()
    poses = dead_reckoning(dataset.odometry)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(0.0, 0.0, 0.0), gtsam.noiseModel.Isotropic.Sigma(3, PRIOR_SIGMA)))
    for step, (row, covariance) in enumerate(zip(dataset.odometry, noise.step_covariances(dataset)), start=1):
        graph.add(gtsam.BetweenFactorPose2(step - 1, step, gtsam.Pose2(*row),
                                           gtsam.noiseModel.Gaussian.Covariance(covariance)))
    tie_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([noise.sigma_tie, noise.sigma_tie, FREE_HEADING_SIGMA]))
    model = tie_noise if robust is None else gtsam.noiseModel.Robust.Create(robust, tie_noise)
    ties = []
    for first, second in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
        heading = float(wrap_angle(poses[second, 2] - poses[first, 2]))
        measured = gtsam.Pose2(0.0, 0.0, heading)
        ties.append(gtsam.BetweenFactorPose2(int(first), int(second), measured, tie_noise))
        graph.add(gtsam.BetweenFactorPose2(int(first), int(second), measured, model))
    initial = gtsam.Values()
    for index, (x, y, theta) in enumerate(poses):
        initial.insert(index, gtsam.Pose2(float(x), float(y), float(wrap_angle(theta))))
    return TieGraph(graph, initial, list(range(dataset.n)), ties)


def tie_chi2(graph: TieGraph, values) -> np.ndarray:
    """(P,) squared Mahalanobis distance of each tie at ``values`` (twice its Gaussian factor error)."""
    return np.array([2.0 * factor.error(values) for factor in graph.ties])
