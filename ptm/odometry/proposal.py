"""The importance proposal where the penalty acts: a defensive mixture with the penalised mode (docs/model.md
§3.3, step 2, "Defensive mixture when the penalty is active"; erratum E10).

Where a pair of detections in different sets is closer than the penalty radius at P*, the integrand's mass
sits where Pen pushes the pair apart, in the tail of the Laplace proposal Q = N(P*, H^-1), and Q alone gives
heavy-tailed weights. The proposal is then the mixture alpha_0 Q + alpha_1 Q_1, where Q_1 is the Laplace fit
of exp(-E - Pen) over all poses (:func:`penalised_mode`):

    P-dagger = argmin (E + Pen),   H-dagger = the Hessian of E + Pen used by the search, at P-dagger,

searched from P* (so a function of the partition alone) by Newton steps on the Gauss-Newton Hessian of E
plus the positive semi-definite part of Pen's, with backtracking. Each component draws in the increments
around its centre (:mod:`ptm.odometry.increments`); a state's density under a component is that of its
offset from the component's centre, since the maps have unit Jacobian. Half the samples come from each
(stratified, Q first), weighted by the balance heuristic (:func:`mixture_log_weights`):

    log w_s = -E(P_s) - Pen(P_s) - log( alpha_0 Q(P_s) + alpha_1 Q_1(P_s) ).

Why all poses: a partition that splits a revisit off its place has the split detection within centimetres
of its former place-mates at P*, and the integrand's mass lies where the odometry has stretched to carry it
a metre or more away, every heading on the way adjusted; a fit over the penalised positions alone, with the
other poses following linearly, cannot follow the headings. Why the positive semi-definite part of Pen's
Hessian: the exact one's tangential part is negative and can leave H-dagger barely positive definite, with
draws hundreds of metres long along its flat direction.

    >>> from scipy.spatial.distance import pdist
    >>> from ptm import Dataset, OdometryModel
    >>> from ptm.pose_graph import poses_from_vector
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))                     # a 2 m square driven once
    >>> term = OdometryModel(0.05, 0.02, 0.1, penalty_radius=1.0, max_penalty=100.0).bind(Dataset(odometry=steps))
    >>> labels = np.array([0, 1, 2, 3, 4])                                  # detection 4 is back at 0, called new
    >>> fit = term.fit(labels)
    >>> distance = pdist(poses_from_vector(fit.x)[:, :2])
    >>> mode = penalised_mode(term.graph, fit, labels, distance, term.sampler.penalty, n_importance=100)
    >>> bool(mode.shift > 1.0), np.exp(mode.log_alphas).tolist()              # half the samples from each
    (True, [0.5, 0.5])
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.special import logsumexp

from ..pose_graph import DenseFactor, LaplaceFit, PoseGraph, SparseFactor
from .increments import compose_linearised_increments, linearised_increment_offsets
from .penalty import DetectionPenalty

__all__ = ["PenalisedMode", "penalised_mode", "mixture_log_weights", "component_shares"]

#: Iterations of the search for argmin (E + Pen), and the Newton decrement [nats] below which it stops: the
#: centre of a proposal needs no more (and it converges only linearly on the Gauss-Newton Hessian).
PENALISED_MODE_ITERATIONS = 100
PENALISED_MODE_TOLERANCE = 1e-3
#: Up to this many variables d the penalised mode's Hessians are dense (LAPACK), above it sparse (SuperLU):
#: on small graphs building the sparse matrices costs more than the dense algebra.
DENSE_MODE_DIMENSION = 150
#: Share of the samples the defensive component N(P*, H^-1) keeps when the penalty component is used.
DEFENSIVE_SHARE = 0.5


@dataclass(frozen=True)
class PenalisedMode:
    """The mixture proposal: q_0 = the Laplace Gaussian at P* and q_1 = the one at P-dagger = argmin (E + Pen),
    each a Gaussian in the increments around its centre."""

    centres: tuple  # (P*, P-dagger), (d,) each
    factors: tuple  # (the fit's factor of H, a DenseFactor or SparseFactor of H-dagger)
    hessians: tuple  # (d, d): H at P* (the Gauss-Newton Hessian of E, sparse) and H-dagger (dense or sparse)
    log_norms: np.ndarray  # (2,): d/2 log 2 pi - 1/2 log det H_c
    log_alphas: np.ndarray  # (2,): the share of the samples each component draws
    components: tuple  # slices of the samples of each component
    shift: float  # the offset of P-dagger from P* in the metric of H (its "distance" in standard deviations)


def component_shares(n_importance: int) -> tuple[list, tuple]:
    """The samples of the two mixture components: their counts and slices (the defensive one first)."""
    counts = [n_importance - int(n_importance * (1.0 - DEFENSIVE_SHARE)), int(n_importance * (1.0 - DEFENSIVE_SHARE))]
    bounds = np.cumsum([0] + counts)
    return counts, tuple(slice(bounds[c], bounds[c + 1]) for c in range(len(counts)))


def penalised_mode(graph: PoseGraph, fit: LaplaceFit, labels, centre_distance, penalty: DetectionPenalty,
                   n_importance: int) -> PenalisedMode | None:
    """The mixture proposal of the partition ``labels`` whose Laplace fit is ``fit`` (``centre_distance``: the
    detections' pairwise distances at P*, ``pdist`` order), or None when no pair of different sets is within
    the penalty radius at P* or the penalty does not move the mode (then Q alone is the proposal).

    The search stops when the Newton decrement is below ``PENALISED_MODE_TOLERANCE``; the pairs counted are
    those of different sets within the radius at each iterate. H-dagger is at least the Gauss-Newton Hessian
    of E, so never flatter than E allows. The Hessians are dense up to ``DENSE_MODE_DIMENSION`` variables,
    sparse (SuperLU) above.
    """
    if penalty.max_penalty == 0.0 or graph.n < 2 or not len(penalty.close_pairs(centre_distance, labels)):
        return None
    positions = graph.layout.positions  # the x and y entries of the state, detection by detection
    dimension = graph.dimension

    def penalised(x):  # (E + Pen at x, its Linearisation of E, the pairs' penalty there)
        linearisation = graph.linearise(x, fit.topology)
        pair_penalty = penalty.at(x, labels)
        return linearisation.energy + pair_penalty(x[positions].reshape(-1, 2)), linearisation, pair_penalty

    dense = dimension <= DENSE_MODE_DIMENSION
    factorise = DenseFactor if dense else SparseFactor

    def hessian(linearisation, pair_penalty):  # the Hessian (Pen's positive semi-definite part) and the gradient
        _, gradient, penalty_hessian = pair_penalty.derivatives(linearisation.x[positions].reshape(-1, 2),
                                                                sparse=not dense)
        matrix = graph.hessian_matrix(fit.topology, linearisation.gauss_newton)
        if dense:
            matrix = matrix.toarray()
            matrix[np.ix_(positions, positions)] += penalty_hessian
        else:
            matrix = matrix + scipy.sparse.csc_matrix(
                (penalty_hessian.data, (positions[penalty_hessian.row], positions[penalty_hessian.col])),
                shape=(dimension, dimension))
        full_gradient = linearisation.gradient.copy()
        full_gradient[positions] += gradient
        return matrix, full_gradient

    x = fit.x
    value, linearisation, pair_penalty = penalised(x)
    for _ in range(PENALISED_MODE_ITERATIONS):
        matrix, gradient = hessian(linearisation, pair_penalty)
        factor = factorise(matrix)
        step = -factor.solve(gradient)
        slope = float(gradient @ step)
        if -0.5 * slope < PENALISED_MODE_TOLERANCE:
            break
        length = 1.0
        while length > 1e-10:
            candidate = penalised(x + length * step)
            if candidate[0] <= value + 1e-4 * length * slope:
                break
            length *= 0.5
        else:
            break
        x = x + length * step
        value, linearisation, pair_penalty = candidate
    else:  # out of iterations after a step: the Hessian at the last iterate
        matrix, _ = hessian(linearisation, pair_penalty)
        factor = factorise(matrix)
    centre_hessian = graph.hessian_matrix(fit.topology, graph.linearise(fit.x, fit.topology).gauss_newton)
    offset = linearised_increment_offsets(fit.x, x[None, :])[:, 0]
    shift = math.sqrt(max(float(offset @ (centre_hessian @ offset)), 0.0))
    if shift < 1e-9:  # the penalty does not move the mode
        return None
    counts, components = component_shares(n_importance)
    half_log_two_pi = 0.5 * dimension * math.log(2.0 * math.pi)
    return PenalisedMode(
        centres=(fit.x, x), factors=(fit.factor, factor), hessians=(centre_hessian, matrix),
        log_norms=np.array([half_log_two_pi - 0.5 * f.log_det() for f in (fit.factor, factor)]),
        log_alphas=np.log(np.array(counts) / sum(counts)), components=components, shift=shift)


def mixture_log_weights(graph: PoseGraph, fit: LaplaceFit, mode: PenalisedMode, labels, centre_distance,
                        penalty: DetectionPenalty, noise_columns, chunk: slice) -> np.ndarray:
    """log w = -E - Pen - log(alpha_0 q_0 + alpha_1 q_1) for the samples of ``chunk``, each component drawing
    its samples from its columns of the common random numbers ``noise_columns`` (d + N, S)."""
    states = []
    for centre, component, factor in zip(mode.centres, mode.components, mode.factors):
        columns = slice(max(chunk.start, component.start), min(chunk.stop, component.stop))
        if columns.start < columns.stop:
            offsets, _ = factor.sample(np.asfortranarray(noise_columns[:, columns]))
            states.append(compose_linearised_increments(centre, offsets))
    states = np.concatenate(states)
    log_densities = []
    for centre, matrix, log_norm, log_alpha in zip(mode.centres, mode.hessians, mode.log_norms, mode.log_alphas):
        offsets = linearised_increment_offsets(centre, states)
        log_densities.append(log_alpha - log_norm - 0.5 * np.einsum("ds,ds->s", offsets, matrix @ offsets))
    from_centre = states.T - fit.x[:, None]
    return (-graph.energies_around(fit, from_centre)
            - penalty.of_states(states, from_centre, fit.x, labels, centre_distance)
            - logsumexp(log_densities, axis=0))
