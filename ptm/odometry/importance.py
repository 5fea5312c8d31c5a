"""The importance-sampling estimate of log P(O | T) around the Laplace fit (docs/model.md §3.3, steps 2-3;
paper eq. 14).

With the Laplace fit Q = N(P*, H^-1) of E (:mod:`ptm.odometry.laplace`), draws delta_s ~ N(0, H^-1) placed in
the increments, P_s = C(u* + K delta_s) (:mod:`ptm.odometry.increments`), are weighted

    log w_s = -E(P_s) - Pen(P_s) + (d/2) log 2 pi - 1/2 log det H + 1/2 delta_s^T H delta_s,
    log P(O | T) = logsumexp_s(log w_s) - log S.

(With a factor H = L L^T and delta_s = L^-T eps_s the last term is the 1/2 |eps_s|^2 of docs/model.md §3.3,
step 2; the structured factors of :mod:`ptm.pose_graph` draw delta_s from d + r normals instead and
evaluate the quadratic form directly.) Where the penalty acts at P*, half the samples come from the
penalised mode instead (:mod:`ptm.odometry.proposal`). The estimate is the mean weight; its Monte-Carlo
standard error is the delta-method se(log mean w) = se(mean w) / mean w with the stratified variance
sum_c n_c var_c(w) / S^2, and the effective sample size is (sum w)^2 / sum w^2.

The standard normals (S x (d + N): d for the poses, up to N more for the low-rank part of the factor) are
drawn once per bound term from the model's seed: common random numbers, so that the estimate is a
deterministic function of the partition and the MCMC target a fixed distribution (step 3).

    >>> from ptm import Dataset, OdometryModel
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1))                     # a 2 m square driven once
    >>> term = OdometryModel(0.05, 0.02, 0.1, penalty_radius=1.0, max_penalty=0.0).bind(Dataset(odometry=steps))
    >>> labels = np.array([0, 1, 2, 3, 4])                                  # no ties and no penalty: exact
    >>> evaluation = term.sampler.estimate(term.fit(labels), labels)
    >>> bool(np.isclose(evaluation.log_likelihood, term.log_likelihood_upper_bound())), round(evaluation.ess, 6)
    (True, 100.0)
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import scipy.spatial.distance
from scipy.special import logsumexp

from ..pose_graph import LaplaceFit, PoseGraph, poses_from_vector
from .increments import compose_linearised_increments
from .penalty import DetectionPenalty
from .proposal import mixture_log_weights, penalised_mode

__all__ = ["ImportanceSampler", "OdometryEvaluation"]

#: Bytes of one importance-sampling temporary (see ``ImportanceSampler.sample_chunks``).
IMPORTANCE_CHUNK_BYTES = 128 * 1024


@dataclass(frozen=True)
class OdometryEvaluation:
    """One uncached evaluation of log P(O | T) and how trustworthy it is."""

    log_likelihood: float  # the importance-sampling estimate
    laplace: float  # -E(P*) + (d/2) log 2 pi - 1/2 log det H (no penalty)
    standard_error: float  # delta-method Monte-Carlo standard error of the estimate [nats], stratified
    ess: float  # effective sample size of the importance weights
    iterations: int  # Newton / Gauss-Newton / Levenberg-Marquardt iterations
    factorisations: int  # Hessian factorisations spent by the fit
    converged: bool
    solution: np.ndarray  # P*, the (d,) state vector of poses 1..N-1
    penalty_shift: float = 0.0  # |P-dagger - P*| in the metric of H (0: no penalty component in the proposal)


class ImportanceSampler:
    """The estimator of log P(O | T) for one pose graph: its common random numbers and its penalty.

    ``noise_columns`` are the common random numbers, (d + N, S) standard normals drawn from ``seed`` (an int
    or a ``numpy.random.SeedSequence``); ``sample_chunks`` the slices of the samples weighted together;
    ``penalty`` the :class:`~ptm.odometry.penalty.DetectionPenalty` of the graph's detections.
    """

    def __init__(self, graph: PoseGraph, n_importance: int, seed, penalty_radius: float, max_penalty: float):
        self.graph = graph
        self.n_importance = n_importance
        n, dimension = graph.n, graph.dimension
        generator = np.random.default_rng(seed if isinstance(seed, np.random.SeedSequence)
                                          else np.random.SeedSequence(seed))
        # d rows for the poses plus up to N for the low-rank part of the factor (one per set and axis)
        noise = generator.standard_normal((n_importance, dimension + n))
        self.noise_columns = np.asfortranarray(noise.T)  # the layout LAPACK's triangular solves take as is
        # Samples are weighted in chunks whose temporaries (S x N x 3 poses and the like) stay under
        # IMPORTANCE_CHUNK_BYTES: glibc hands larger freed blocks back to the operating system by default, and
        # faulting them in again on every evaluation costs a good share of its time.
        chunks = math.ceil(n_importance * 3 * n * 8 / IMPORTANCE_CHUNK_BYTES)
        chunk_size = math.ceil(n_importance / chunks)
        self.sample_chunks = [slice(begin, begin + chunk_size) for begin in range(0, n_importance, chunk_size)]
        self.penalty = DetectionPenalty(n, penalty_radius, max_penalty)

    def on(self, graph: PoseGraph) -> "ImportanceSampler":
        """This sampler, its common random numbers and penalty unchanged, for another pose graph of the same
        odometry: the graph whose covariances are scaled (docs/model.md §3.3, "Noise scale")."""
        if (graph.n, graph.dimension) != (self.graph.n, self.graph.dimension):
            raise ValueError(f"a graph of {graph.n} detections for a sampler of {self.graph.n}")
        sampler = copy.copy(self)
        sampler.graph = graph
        return sampler

    def estimate(self, fit: LaplaceFit, labels) -> OdometryEvaluation:
        """The estimate of log P(O | T) for the partition ``labels`` (an (N,) array) with the Laplace fit
        ``fit`` (which must have a factor), with its standard error and effective sample size."""
        graph = self.graph
        log_proposal_norm = 0.5 * graph.dimension * math.log(2.0 * math.pi) - 0.5 * fit.factor.log_det()
        centre_distance = scipy.spatial.distance.pdist(poses_from_vector(fit.x)[:, :2])
        mode = penalised_mode(graph, fit, labels, centre_distance, self.penalty, self.n_importance)
        if mode is not None:
            log_weights = np.concatenate([
                mixture_log_weights(graph, fit, mode, labels, centre_distance, self.penalty, self.noise_columns,
                                    chunk)
                for chunk in self.sample_chunks])
        else:
            log_weights = log_proposal_norm + np.concatenate([
                self.log_weight_terms(fit, labels, centre_distance, chunk) for chunk in self.sample_chunks])
        # stratified (deterministic allocation) balance-heuristic estimator: the mean of all weights
        estimate = float(logsumexp(log_weights)) - math.log(len(log_weights))
        weights = np.exp(log_weights - float(log_weights.max()))  # scaled weights, for the ESS and the error
        mean = float(weights.mean())
        ess = float(weights.sum() ** 2 / np.sum(weights**2))
        total = len(weights)
        variance = sum((component.stop - component.start) * float(weights[component].var())
                       for component in (mode.components if mode is not None else (slice(0, total),))) / total**2
        standard_error = math.sqrt(variance) / mean  # delta method: se(log I) = se(I) / I
        return OdometryEvaluation(
            log_likelihood=estimate,
            laplace=log_proposal_norm - fit.energy,
            standard_error=standard_error,
            ess=ess,
            iterations=fit.iterations,
            factorisations=fit.factorisations,
            converged=fit.converged,
            solution=fit.x,
            penalty_shift=mode.shift if mode is not None else 0.0,
        )

    def log_weight_terms(self, fit: LaplaceFit, labels, centre_distance, chunk: slice) -> np.ndarray:
        """1/2 delta^T H delta - E(P) - Pen(P) for the samples P = C(u* + K delta) of ``chunk`` drawn from Q
        alone (the log weights less the proposal's normaliser)."""
        offsets, half_quadratic = fit.factor.sample(self.noise_columns[:, chunk])
        states = compose_linearised_increments(fit.x, offsets)
        offsets = states.T - fit.x[:, None]
        return (half_quadratic - self.graph.energies_around(fit, offsets)
                - self.penalty.of_states(states, offsets, fit.x, labels, centre_distance))
