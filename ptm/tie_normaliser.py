"""The normaliser of the topology ties: landmarks spread over an area (docs/model.md §3.3, "A property worth knowing").

The odometry likelihood (paper eq. 3) ties the detections of one set with
exp(-sum_{i<j in S} |t_i - t_j|^2 / (2 sigma_T^2)), a density of their
positions that is not normalised, as in the paper. Then no merge can raise
P(O | T), and odometry alone leans to "every detection its own place". A
proper prior on the positions puts each place's landmark uniformly on an
area A and its detections around it as the tie says. Integrating out where
the detections of a set S of n lie relative to their mean (the tie is a
Gaussian of variance sigma_T^2 / n along each of the 2(n - 1) centred
directions; the mean carries a Jacobian n) gives

    Z_n = n (2 pi sigma_T^2 / n)^(n - 1),      p(t_S | T) = exp(-ties_S) / (A Z_n),

and compared with n separate landmarks (A^-n) a set of n gains

    log c(S) = (n - 1) log(A n / (2 pi sigma_T^2)) - log n                     (per set)

on top of the unnormalised tie already in the odometry energy. c depends on
the set's size only, so :class:`TieNormaliser` is a decomposable term, scored
with the prior and appearance (the cheap part of the posterior), and
``Posterior(dataset, prior, [odometry_model, TieNormaliser(area, sigma_T)])``
is the odometry model with a normalised landmark prior. It is not the
paper's model; the library offers it as an option (the harness adds it by
default, ``odometry.tie_normaliser``). A comes from what a user knows
(the size of the building) or from the run itself without labels
(:meth:`TieNormaliser.from_dead_reckoning`: the bounding box of the
dead-reckoned detections). :class:`DeadReckonedTieNormaliser` is that rule
as an unbound model: each dataset it is bound to gets the area of its own
dead-reckoned detections, so the online mapper, which binds its models anew
to the detections so far, uses the area the robot has covered so far.

The normaliser rewards a merge by about (n - 1) log(A / (2 pi sigma_T^2)),
7-8 nats a pair on a 40 m grid at sigma_T = 0.53 m, that only the odometry
term's ties take back: it is the normaliser of *their* density and means
nothing without them. So it declares ``completes_global_term``, and what
scores the cheap terms alone (the samplers' warm-up before the odometry
surrogate joins, the placement of a new detection in an incremental start)
leaves it out (:meth:`ptm.Posterior.standalone_block_score`).

    >>> normaliser = TieNormaliser(area=1600.0, sigma_topology=2.0)
    >>> round(normaliser.block_log_likelihood((3,)), 3), round(normaliser.block_log_likelihood((0, 6)), 3)
    (0.0, 4.154)
    >>> from ptm import Dataset
    >>> DeadReckonedTieNormaliser(sigma_topology=2.0, margin=1.0).bind(Dataset(odometry=[[38.0, 0.0, 1.5708]]))
    TieNormaliser(area=80, sigma_topology=2)
"""

from __future__ import annotations

import math

import numpy as np

from ._validation import positive
from .se2 import dead_reckoning

__all__ = ["DeadReckonedTieNormaliser", "TieNormaliser"]


class TieNormaliser:
    """The per-set normaliser log c(S) of the odometry model's ties, for landmarks uniform on ``area`` [m^2]."""

    name = "tie_normaliser"
    #: It normalises the odometry term's ties: scores without the global terms leave it out.
    completes_global_term = True

    def __init__(self, area: float, sigma_topology: float):
        self.area = positive("area", area)
        self.sigma_topology = positive("sigma_topology", sigma_topology)

    @classmethod
    def from_dead_reckoning(cls, dataset, sigma_topology: float, margin: float) -> "TieNormaliser":
        """A from the scored run itself: its dead-reckoned detections' bounding box, ``margin`` [m] added on
        every side (for example the detection radius). No labels are read. A single detection (no odometry
        rows) spans the margin's square."""
        if dataset.odometry is None and dataset.n != 1:
            raise ValueError("TieNormaliser.from_dead_reckoning needs a dataset with odometry")
        margin = _margin(margin)
        positions = np.zeros((1, 2)) if dataset.odometry is None else dead_reckoning(dataset.odometry)[:, :2]
        extent = np.ptp(positions, axis=0) + 2.0 * margin
        area = float(np.prod(extent))
        if area <= 0.0:
            raise ValueError("the dead-reckoned detections span no area; give a margin > 0")
        return cls(area, sigma_topology)

    def bind(self, dataset) -> "TieNormaliser":
        """The term for ``dataset``: the same object (it depends on the set sizes only)."""
        return self

    def block_log_likelihood(self, block) -> float:
        """log c(S) = (n - 1) log(A n / (2 pi sigma_T^2)) - log n for a set of n detections."""
        size = len(block)
        if size < 1:
            raise ValueError("a set has at least one detection")
        return (size - 1) * math.log(self.area * size / (2.0 * math.pi * self.sigma_topology ** 2)) - math.log(size)

    def log_likelihood(self, partition) -> float:
        """Sum of :meth:`block_log_likelihood` over the partition's sets."""
        return sum(self.block_log_likelihood(block) for block in partition.blocks)

    def __repr__(self) -> str:
        return f"TieNormaliser(area={self.area:g}, sigma_topology={self.sigma_topology:g})"


class DeadReckonedTieNormaliser:
    """The unbound :class:`TieNormaliser` whose area is that of the detections it is bound to
    (:meth:`TieNormaliser.from_dead_reckoning` with ``margin`` [m], for example the detection radius)."""

    name = TieNormaliser.name
    completes_global_term = True

    def __init__(self, sigma_topology: float, margin: float):
        self.sigma_topology = positive("sigma_topology", sigma_topology)
        self.margin = _margin(margin)

    def bind(self, dataset) -> TieNormaliser:
        """The normaliser for ``dataset``'s dead-reckoned detections."""
        return TieNormaliser.from_dead_reckoning(dataset, self.sigma_topology, self.margin)

    def __repr__(self) -> str:
        return f"DeadReckonedTieNormaliser(sigma_topology={self.sigma_topology:g}, margin={self.margin:g})"


def _margin(margin) -> float:
    margin = float(margin)
    if not math.isfinite(margin) or margin < 0.0:
        raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
    return margin
