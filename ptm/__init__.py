"""PTM: probabilistic topological maps.

The posterior over set partitions of N landmark detections ("which detections
were taken at the same place"), from a Poisson-marginalised occupancy prior,
an odometry likelihood and an appearance likelihood (Ranganathan, Menegatti
and Dellaert, IEEE T-RO 2006; docs/model.md gives the equations with the
paper's errata corrected).

    >>> import numpy as np
    >>> import ptm
    >>> signatures = np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]])   # places A, B, A, B
    >>> model = ptm.AppearanceModel(mu=0.3, kappa=0.05, alpha=3.0, beta=2e-4)
    >>> post = ptm.Posterior(ptm.Dataset(signatures=signatures), ptm.PoissonPrior(2.0), [model])
    >>> ptm.exact_posterior(post).map(), ptm.mcmc(post, 2_000, seed=0).map()
    ((0, 1, 0, 1), (0, 1, 0, 1))
"""

from . import diagnostics, export, features, moves
from .appearance import AppearanceModel
from .appearance_joint import JointAppearanceModel
from .dataset import Dataset
from .exact import exact_posterior
from .gamma_poisson_prior import GammaPoissonPrior
from .odometry import NoiseScalePrior, OdometryModel, noise_scale_posterior
from .online import OnlineMapper
from .partitions import Partition, bell, canonical
from .posterior import Posterior
from .prior import PoissonPrior
from .result import PTM, total_variation
from .sampler import SamplerOptions, mcmc
from .tempering import tempered_mcmc
from .tie_normaliser import DeadReckonedTieNormaliser, TieNormaliser

__all__ = [
    "Dataset", "PTM", "Partition", "PoissonPrior", "GammaPoissonPrior", "Posterior", "AppearanceModel", "JointAppearanceModel",
    "OdometryModel", "TieNormaliser", "DeadReckonedTieNormaliser", "OnlineMapper", "SamplerOptions", "mcmc",
    "NoiseScalePrior", "noise_scale_posterior",
    "tempered_mcmc", "exact_posterior", "total_variation", "canonical", "bell",
    "diagnostics", "export", "features", "moves",
]
__version__ = "0.1.0"
