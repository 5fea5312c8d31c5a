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
paper's model; the library offers it as an option, which the harness always
adds. A comes from what a user knows (the size of the building) or from the
run itself without labels (:meth:`TieNormaliser.from_dead_reckoning`). :class:`DeadReckonedTieNormaliser`
is that rule as an unbound model: each dataset it is bound to gets the area
of its own dead-reckoned detections, so the online mapper, which binds its
models anew to the detections so far, uses the area the robot has covered so far.

Which area (docs/model.md §3.3, "Which area"): landmarks are where the robot
can detect them, within the detector's radius of its route, and a building's
corridors fill a fraction of the box around them. So A is the area within
``margin`` of the dead-reckoned route through the detections
(:func:`route_area`). The box around them would make a chance coincidence of
two distinct places seem several times less likely than it is, and reward
every merge by the log of that factor. Dead reckoning draws a corridor driven
twice as two, so the route's area can exceed the building's, an error towards
the box's.

The normaliser rewards a merge by about (n - 1) log(A / (2 pi sigma_T^2)),
several nats a pair, that only the odometry term's ties take back: it is the
normaliser of *their* density and means nothing without them. So it declares
``completes_global_term``, and what scores the cheap terms alone (the
placement of a new detection in an incremental start) leaves it out
(:meth:`ptm.Posterior.standalone_block_score`).

    >>> normaliser = TieNormaliser(area=1600.0, sigma_topology=2.0)
    >>> round(normaliser.block_log_likelihood((3,)), 3), round(normaliser.block_log_likelihood((0, 6)), 3)
    (0.0, 4.154)
    >>> from ptm import Dataset
    >>> two_detections = Dataset(odometry=[[38.0, 0.0, 1.5708]])          # 38 m apart: a capsule
    >>> DeadReckonedTieNormaliser(sigma_topology=2.0, margin=1.0).bind(two_detections)   # 2 x 38 + pi
    TieNormaliser(area=79.25, sigma_topology=2)
"""

from __future__ import annotations

import math

import numpy as np
import scipy.ndimage
import scipy.spatial

from ._validation import positive
from .se2 import dead_reckoning

__all__ = ["DeadReckonedTieNormaliser", "TieNormaliser", "route_area"]

#: Raster cells per ``margin`` with which :func:`route_area` counts (within 4 % of a disc's area, 2 % of a
#: capsule's or a ring's), and the most cells it uses (coarser above).
ROUTE_CELLS_PER_MARGIN = 8
ROUTE_MAX_CELLS = 4_000_000
#: Half a raster cell's diagonal (sqrt(2) / 2 = 0.707) and a margin for rounding, in cells: how far a cell's
#: distance to the nearest visited cell can lie from its distance to the route (:func:`route_area`).
ROUTE_RASTER_SLACK = 0.75


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
        """A from the scored run itself: the area within ``margin`` [m], for example the detection radius, of
        the dead-reckoned route through the detections (:func:`route_area`); no labels are read. A single
        detection (no odometry rows) spans the margin's disc."""
        if dataset.odometry is None and dataset.n != 1:
            raise ValueError("TieNormaliser.from_dead_reckoning needs a dataset with odometry")
        margin = _margin(margin)
        positions = np.zeros((1, 2)) if dataset.odometry is None else dead_reckoning(dataset.odometry)[:, :2]
        area = route_area(positions, margin)
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
    (:meth:`TieNormaliser.from_dead_reckoning` with ``margin`` [m], for example the detection radius): the
    online mapper, which binds its models anew to the detections so far, uses the area covered so far."""

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


def route_area(positions, margin: float) -> float:
    """The area [m^2] within ``margin`` of the polyline through ``positions`` (N, 2), in order: the corridor a
    robot driving from one to the next sweeps with a detector of radius ``margin``.

    Counted on a raster of ``ROUTE_CELLS_PER_MARGIN`` cells per margin (coarser where that would exceed
    ``ROUTE_MAX_CELLS``): a cell counts when its centre lies within ``margin`` of the route, sampled every
    half cell (a k-d tree; a straight route's distance is then exact to 1 mm in a metre); a distance
    transform to the cells the route visits settles every cell but those within ``ROUTE_RASTER_SLACK`` cells
    of the margin, which the k-d tree decides.
    One point is a disc.

        >>> round(route_area([[0.0, 0.0], [10.0, 0.0]], 1.0) / (20.0 + np.pi), 2)   # a capsule: 2 x 10 + pi
        1.0
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    margin = _margin(margin)
    if margin == 0.0:
        return 0.0
    extent = np.ptp(positions, axis=0) + 2.0 * margin
    cell = max(margin / ROUTE_CELLS_PER_MARGIN, math.sqrt(float(np.prod(extent + 1.0)) / ROUTE_MAX_CELLS))
    origin = positions.min(axis=0) - margin - 2.0 * cell
    shape = tuple(np.ceil((extent + 4.0 * cell) / cell).astype(int) + 1)
    lengths = np.hypot(*np.diff(positions, axis=0).T)
    route = np.concatenate([positions[:1]] + [
        start + np.outer(np.linspace(0.0, 1.0, int(math.ceil(2.0 * length / cell)) + 1)[1:], stop - start)
        for start, stop, length in zip(positions[:-1], positions[1:], lengths)])
    off_route = np.ones(shape, dtype=bool)
    visited = np.floor((route - origin) / cell).astype(int)
    off_route[visited[:, 0], visited[:, 1]] = False
    # A cell's distance to the nearest visited cell is within half a cell's diagonal of its distance to the
    # route's samples (each sample lies in a visited cell), so only the band where the two could fall on
    # either side of the margin needs the k-d tree.
    raster_distance = scipy.ndimage.distance_transform_edt(off_route, sampling=cell)
    slack = ROUTE_RASTER_SLACK * cell
    inside = np.count_nonzero(raster_distance < margin - slack)
    band = np.argwhere((raster_distance >= margin - slack) & (raster_distance <= margin + slack))
    distances, _ = scipy.spatial.cKDTree(route).query(origin + (band + 0.5) * cell)
    return float(inside + np.count_nonzero(distances <= margin)) * cell * cell


def _margin(margin) -> float:
    margin = float(margin)
    if not math.isfinite(margin) or margin < 0.0:
        raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
    return margin
