"""The odometry likelihood log P(O | T): a Laplace fit, then importance sampling (docs/model.md §3.3; paper eq. 3
and 11-14).

For a partition T,

    log P(O | T) = log integral exp(-E(P) - Pen(P)) dP,

with E the pose-graph energy of :mod:`ptm.pose_graph` (odometry distortion plus the topology ties, both in
the 1/2 r^T Sigma^-1 r convention) and Pen the landmark-density penalty over the pairs of detections in
different sets. The integral is evaluated in three steps:

1. the Laplace fit Q = N(P*, H^-1) of E, with P* the lower of the minima reached from two starts that depend
   on the partition alone, so that the value does not depend on what was evaluated before;
2. importance sampling from Q, its draws placed in the increments between consecutive detections
   (erratum E12), and where the penalty acts at P*, from a defensive mixture of Q and the Laplace fit of
   exp(-E - Pen) (erratum E10);
3. common random numbers drawn once per bound term, so that the estimate is a deterministic function of the
   partition, memoised per partition.

One module per concept:

* :mod:`~ptm.odometry.model` -- :class:`OdometryModel`, the parameters; ``bind(dataset)`` gives the term;
* :mod:`~ptm.odometry.term` -- :class:`OdometryTerm`, the memoised value, its diagnostics and its screen;
* :mod:`~ptm.odometry.covariance_range` -- the standard deviations it can compute with, relative to the
  odometry's scale;
* :mod:`~ptm.odometry.laplace` -- which minimum is P* (step 1);
* :mod:`~ptm.odometry.growth` -- a term one detection longer starts its fits from the shorter run's modes;
* :mod:`~ptm.odometry.importance` -- the estimator and its Monte-Carlo error (steps 2-3);
* :mod:`~ptm.odometry.increments` -- where the draws are placed;
* :mod:`~ptm.odometry.proposal` -- the penalised mode and the mixture proposal;
* :mod:`~ptm.odometry.penalty` -- the penalty Pen (eq. 11-12);
* :mod:`~ptm.odometry.noise_scale` -- the prior of one scale of every covariance, integrated out with the
  topology where the model has one, and its posterior given a PTM;
* :mod:`~ptm.odometry.surrogate` -- :class:`OdometrySurrogate`, the screen that predicts a move's change of
  the odometry terms from the map estimate of the current partition (docs/model.md §3.4).

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> noise = np.random.default_rng(0).normal(0.0, [0.05, 0.05, 0.02], (4, 3))
    >>> steps = np.tile([2.0, 0.0, np.pi / 2], (4, 1)) + noise
    >>> model = OdometryModel(sigma_xy=0.05, sigma_theta=0.02, sigma_topology=0.1,     # a 2 m square driven once
    ...                       penalty_radius=1.0, max_penalty=100.0, n_importance=100, seed=0)
    >>> posterior = Posterior(Dataset(odometry=steps), PoissonPrior(4.0), [model])
    >>> posterior.log_prob([0, 1, 2, 3, 0]) > posterior.log_prob([0, 1, 2, 3, 4])       # the loop closes
    True
"""

from .importance import OdometryEvaluation
from .increments import compose_linearised_increments, linearised_increment_offsets
from .model import OdometryModel
from .noise_scale import NoiseScalePosterior, NoiseScalePrior, noise_scale_posterior
from .penalty import landmark_penalty
from .proposal import PenalisedMode
from .surrogate import ConditionedMap, MapEstimate, OdometrySurrogate
from .term import OdometryTerm

__all__ = ["OdometryModel", "OdometryTerm", "OdometryEvaluation", "OdometrySurrogate", "MapEstimate",
           "ConditionedMap", "PenalisedMode", "landmark_penalty", "compose_linearised_increments",
           "linearised_increment_offsets", "NoiseScalePrior", "NoiseScalePosterior", "noise_scale_posterior"]
