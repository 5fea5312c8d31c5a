"""PTM: probabilistic topological maps.

The posterior over set partitions of N landmark detections ("which detections
were taken at the same place"), from a Poisson-marginalised occupancy prior,
an odometry likelihood and an appearance likelihood (Ranganathan, Menegatti
and Dellaert, IEEE T-RO 2006; see SPEC.md for the corrected equations).

    >>> import ptm
    >>> ds = ptm.Dataset(signatures=signatures)
    >>> post = ptm.Posterior(ds, ptm.PoissonPrior(2.0), [ptm.AppearanceModel(0.1, 1.0, 3.0, 0.01)])
    >>> ptm.mcmc(post, 20_000, seed=0).top(3)
"""

from . import features
from .dataset import Dataset

__all__ = ["Dataset", "features"]
__version__ = "0.1.0"
