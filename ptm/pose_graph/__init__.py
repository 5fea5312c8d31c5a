"""The pose graph of one topology: SE(2) odometry residuals, topology ties, structured factorisations, Laplace fit.

Implements the energy of docs/model.md §3.3 (paper eq. 3, 13) and step 1 of
its evaluation, the Laplace approximation. The variables are the poses
p_i = (x_i, y_i, theta_i) of detections 1..N-1 flattened into one vector of
d = 3(N-1) numbers; pose 0 is fixed at the origin (the gauge). For a
partition T,

    E(P) = 1/2 sum_k r_k(P)^T Sigma_k^-1 r_k(P)  +  1/2 sum_{S in T} sum_{i<j in S} |t_i - t_j|^2 / sigma_T^2
    r_k  = (p_{k-1}^-1 o p_k) - o_k     (translation in the frame of p_{k-1}, angle wrapped)

One module per concept:

* :mod:`~ptm.pose_graph.residuals` -- the odometry residuals r_k (through
  :mod:`ptm.se2`), their Jacobians and second derivatives;
* :mod:`~ptm.pose_graph.topology` -- the topology tie, exactly quadratic:
  :class:`TopologyHessian`, the clique Laplacian of T / sigma_T^2 as a
  diagonal minus a low-rank term;
* :mod:`~ptm.pose_graph.factorisation` -- H = A - U U^T with A banded
  (half-bandwidth 5): :class:`BandedLowRankFactor` (banded Cholesky and the
  Woodbury identity) and, above ``sparse_above`` variables,
  :class:`SparseFactor` (SuperLU L D L^T);
* :mod:`~ptm.pose_graph.chordal` -- the chordal relaxation, whose headings
  start the fit that defines P* (:func:`chordal_headings`);
* :mod:`~ptm.pose_graph.solver` -- :class:`PoseGraph`, whose
  :meth:`~PoseGraph.fit` finds P* = argmin E by damped Newton steps and
  factorises the Gauss-Newton Hessian there (:class:`LaplaceFit`).

    >>> import numpy as np
    >>> odometry = np.array([[2.0, 0.0, np.pi / 2]] * 3 + [[2.1, 0.0, np.pi / 2]])   # a 2 m square, 10 cm long
    >>> covariances = np.broadcast_to(np.diag([0.01, 0.01, 0.0025]), (4, 3, 3))
    >>> graph = PoseGraph(odometry, odometry_sqrt_information(covariances), sigma_topology=0.3)
    >>> round(float(graph.energy(graph.dead_reckoning(), (0, 1, 2, 3, 0))), 4)    # detection 4 revisits 0
    0.0556
    >>> fit = graph.fit(graph.dead_reckoning(), (0, 1, 2, 3, 0))
    >>> fit.converged, round(fit.energy, 4), round(fit.factor.log_det(), 2)
    (True, 0.0335, 61.84)
"""

from .chordal import chordal_headings
from .factorisation import BandedLowRankFactor, DenseFactor, HessianLayout, SparseFactor
from .residuals import (StepFrames, StepInformation, odometry_jacobian_blocks, odometry_residuals,
                        odometry_second_order_blocks, odometry_sqrt_information, poses_from_vector)
from .solver import SPARSE_ABOVE_DIMENSION, LaplaceFit, Linearisation, PoseGraph
from .topology import MemberSums, TopologyHessian

__all__ = [
    "PoseGraph",
    "LaplaceFit",
    "Linearisation",
    "TopologyHessian",
    "MemberSums",
    "BandedLowRankFactor",
    "SparseFactor",
    "DenseFactor",
    "HessianLayout",
    "StepFrames",
    "StepInformation",
    "SPARSE_ABOVE_DIMENSION",
    "chordal_headings",
    "odometry_sqrt_information",
    "odometry_residuals",
    "odometry_jacobian_blocks",
    "odometry_second_order_blocks",
    "poses_from_vector",
]
