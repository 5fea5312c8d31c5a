"""The odometry model's specification: its parameters, validated once, and ``bind(dataset)`` (docs/model.md §3.3,
"Parameters").

    >>> model = OdometryModel(sigma_xy=0.05, sigma_theta=0.02, sigma_topology=0.1, penalty_radius=1.0)
    >>> model.max_penalty, model.n_importance
    (100.0, 100)
    >>> OdometryModel(n_importance=0)
    Traceback (most recent call last):
    ...
    ValueError: n_importance must be a positive integer, got 0
"""

from __future__ import annotations

from .._validation import non_negative, positive
from ..pose_graph import SPARSE_ABOVE_DIMENSION
from .term import OdometryTerm

__all__ = ["OdometryModel"]


class OdometryModel:
    """Specification of the odometry likelihood; ``bind(dataset)`` gives the term.

    Parameters
    ----------
    sigma_xy, sigma_theta : float
        Per-step odometry standard deviations [m, rad]; the covariance of a step
        is diag(sigma_xy^2, sigma_xy^2, sigma_theta^2) unless the dataset
        carries ``odometry_cov``, which then wins.
    sigma_topology : float
        Standard deviation [m] of the tie between positions of detections in the same set.
    penalty_radius : float
        D [m]: distinct places closer than this are penalised.
    max_penalty : float
        P_max [nats], the penalty at distance 0; 0 switches the density prior off.
    n_importance : int
        Importance samples S per evaluation.
    seed : int or numpy.random.SeedSequence
        Seed of the common random numbers.
    cache_size : int
        Bound on the per-partition memo.
    sparse_above : int
        Use sparse linear algebra when d = 3(N-1) exceeds this.
    """

    def __init__(self, sigma_xy: float = 0.1, sigma_theta: float = 0.05, sigma_topology: float = 0.3,
                 penalty_radius: float = 2.5, max_penalty: float = 100.0, n_importance: int = 100,
                 seed=0, cache_size: int = 100_000, sparse_above: int = SPARSE_ABOVE_DIMENSION):
        self.sigma_xy = positive("sigma_xy", sigma_xy)
        self.sigma_theta = positive("sigma_theta", sigma_theta)
        self.sigma_topology = positive("sigma_topology", sigma_topology)
        self.penalty_radius = positive("penalty_radius", penalty_radius)
        self.max_penalty = non_negative("max_penalty", max_penalty)
        if int(n_importance) != n_importance or n_importance < 1:
            raise ValueError(f"n_importance must be a positive integer, got {n_importance!r}")
        self.n_importance = int(n_importance)
        self.seed = seed
        self.cache_size = cache_size
        self.sparse_above = int(sparse_above)

    def bind(self, dataset) -> OdometryTerm:
        """The likelihood term of this model for ``dataset`` (which must carry odometry)."""
        return OdometryTerm(self, dataset)

    def __repr__(self) -> str:
        return (f"OdometryModel(sigma_xy={self.sigma_xy}, sigma_theta={self.sigma_theta}, "
                f"sigma_topology={self.sigma_topology}, penalty_radius={self.penalty_radius}, "
                f"max_penalty={self.max_penalty}, n_importance={self.n_importance}, seed={self.seed!r})")
