"""The odometry model's specification: its parameters, validated once, and ``bind(dataset)`` (docs/model.md §3.3,
"Parameters").

    >>> model = OdometryModel(sigma_xy=0.05, sigma_theta=0.02, sigma_topology=0.1, penalty_radius=1.0)
    >>> model.max_penalty, model.n_importance
    (100.0, 100)
    >>> OdometryModel(n_importance=0)
    Traceback (most recent call last):
    ...
    ValueError: n_importance must be an integer >= 1, got 0
"""

from __future__ import annotations

from .._validation import count, non_negative, positive, seed_sequence
from ..pose_graph import SPARSE_ABOVE_DIMENSION
from .covariance_range import LARGEST_STD
from .noise_scale import NoiseScalePrior
from .term import OdometryTerm

__all__ = ["MAX_IMPORTANCE_SAMPLES", "MAX_PENALTY", "OdometryModel"]

#: The largest ``max_penalty`` [nats]: e^-1e6 already excludes a pair; beyond 1e10 the penalised fit fails.
MAX_PENALTY = 1e6
#: The largest ``n_importance``: the common random numbers take 8 S (4N - 3) bytes (3 GB at N = 100).
MAX_IMPORTANCE_SAMPLES = 10**6


class OdometryModel:
    """Specification of the odometry likelihood; ``bind(dataset)`` gives the term.

    Parameters
    ----------
    sigma_xy, sigma_theta : float
        Per-step odometry standard deviations [m, rad]; the covariance of a step
        is diag(sigma_xy^2, sigma_xy^2, sigma_theta^2) unless the dataset
        carries ``odometry_cov``, which then wins. Binding refuses a step's standard deviations, and
        sigma_topology, outside ``STD_RANGE`` x the odometry's scale (:mod:`ptm.odometry.covariance_range`).
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
    noise_scale_prior : NoiseScalePrior or None
        None: the covariances are taken as calibrated (scale 1). Else the prior of one scale s that multiplies
        every covariance (the rows and sigma_T^2), which the term integrates out (docs/model.md §3.3, "Noise
        scale"); ``normalised_ties`` must then say whether the posterior normalises the ties.
    normalised_ties : bool or None
        With a ``noise_scale_prior`` only: True where the posterior adds a :class:`ptm.TieNormaliser` (this
        term then owns its dependence on s, -(N - M) log s), False for the paper's unnormalised ties. The
        posterior refuses a combination that contradicts it.
    """

    def __init__(self, sigma_xy: float = 0.1, sigma_theta: float = 0.05, sigma_topology: float = 0.3,
                 penalty_radius: float = 2.5, max_penalty: float = 100.0, n_importance: int = 100,
                 seed=0, cache_size: int = 100_000, sparse_above: int = SPARSE_ABOVE_DIMENSION,
                 noise_scale_prior: NoiseScalePrior | None = None, normalised_ties: bool | None = None):
        # lengths are squared: at most LARGEST_STD; the range relative to the odometry is checked on binding
        self.sigma_xy = positive("sigma_xy", sigma_xy, (0.0, LARGEST_STD))
        self.sigma_theta = positive("sigma_theta", sigma_theta, (0.0, LARGEST_STD))
        self.sigma_topology = positive("sigma_topology", sigma_topology, (0.0, LARGEST_STD))
        self.penalty_radius = positive("penalty_radius", penalty_radius, (0.0, LARGEST_STD))
        self.max_penalty = non_negative("max_penalty", max_penalty, (0.0, MAX_PENALTY))
        self.n_importance = count("n_importance", n_importance, 1, MAX_IMPORTANCE_SAMPLES)
        seed_sequence("seed", seed)  # checked here; kept as given
        self.seed = seed
        self.cache_size = count("cache_size", cache_size, 1)
        self.sparse_above = count("sparse_above", sparse_above, 0)
        if noise_scale_prior is not None and not isinstance(noise_scale_prior, NoiseScalePrior):
            raise TypeError(f"noise_scale_prior must be a ptm.odometry.NoiseScalePrior or None, "
                            f"got {noise_scale_prior!r}")
        if noise_scale_prior is None and normalised_ties is not None:
            raise ValueError("normalised_ties says how the noise scale enters the ties; it needs a noise_scale_prior")
        if noise_scale_prior is not None and not isinstance(normalised_ties, bool):
            raise TypeError("with a noise_scale_prior, normalised_ties must be True (the posterior adds a "
                            "ptm.TieNormaliser) or False (the paper's unnormalised ties), "
                            f"got {normalised_ties!r}")
        self.noise_scale_prior = noise_scale_prior
        self.normalised_ties = normalised_ties

    def bind(self, dataset) -> OdometryTerm:
        """The likelihood term of this model for ``dataset`` (which must carry odometry)."""
        return OdometryTerm(self, dataset)

    def __repr__(self) -> str:
        return (f"OdometryModel(sigma_xy={self.sigma_xy}, sigma_theta={self.sigma_theta}, "
                f"sigma_topology={self.sigma_topology}, penalty_radius={self.penalty_radius}, "
                f"max_penalty={self.max_penalty}, n_importance={self.n_importance}, seed={self.seed!r}"
                + ("" if self.noise_scale_prior is None else
                   f", noise_scale_prior={self.noise_scale_prior!r}, normalised_ties={self.normalised_ties}")
                + ")")
