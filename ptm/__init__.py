"""PTM: probabilistic topological maps.

The posterior over set partitions of N landmark detections ("which detections
were taken at the same place"), from a Poisson-marginalised occupancy prior,
an odometry likelihood and an appearance likelihood (Ranganathan, Menegatti
and Dellaert, IEEE T-RO 2006; docs/model.md gives the equations with the
paper's errata corrected).

    >>> import ptm
    >>> ds = ptm.Dataset(signatures=signatures)
    >>> post = ptm.Posterior(ds, ptm.PoissonPrior(2.0), [ptm.AppearanceModel(0.1, 1.0, 3.0, 0.01)])
    >>> ptm.mcmc(post, 20_000, seed=0).top(3)
"""

from . import features, moves
from .appearance import (AppearanceModel, inverse_gamma_from_mean_variance, leave_one_out_pit, pair_log_bayes_factor,
                         pairwise_log_bayes_factors, predictive_log_density, predictive_pit)
from .appearance_joint import JointAppearanceModel
from .dataset import Dataset
from .exact import exact_posterior
from .odometry import OdometryModel
from .partitions import Partition, bell, canonical, stirling2
from .posterior import Posterior
from .prior import PoissonPrior
from .result import PTM, total_variation
from .sampler import mcmc
from .tempering import tempered_mcmc

__all__ = [
    "AppearanceModel", "JointAppearanceModel", "Dataset", "PTM", "Partition", "PoissonPrior", "Posterior",
    "bell", "canonical", "exact_posterior", "features", "inverse_gamma_from_mean_variance",
    "leave_one_out_pit", "pair_log_bayes_factor", "pairwise_log_bayes_factors", "predictive_log_density",
    "predictive_pit",
    "mcmc", "moves", "stirling2", "tempered_mcmc", "total_variation", "OdometryModel",
]
__version__ = "0.1.0"
