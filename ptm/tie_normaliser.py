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
(:meth:`TieNormaliser.from_dead_reckoning`). :class:`DeadReckonedTieNormaliser`
is that rule as an unbound model: each dataset it is bound to gets the area
of its own dead-reckoned detections, so the online mapper, which binds its
models anew to the detections so far, uses the area the robot has covered so far.

Which area: landmarks are where the robot can detect them, within the
detector's radius of its route, and a building's corridors fill little of the
box around them. The rule ``"route"`` (the default, :func:`route_area`) is the
area within ``margin`` of the dead-reckoned route through the detections: 421
m^2 on a simulated ``office`` run whose dead-reckoned detections span a box of
2 164 m^2, 644 m^2 against 2 259 m^2 on ACES (the shipped dataset). Taking the
box as A (``"bounding_box"``, the rule until 2026-12-04) makes a chance
coincidence of two distinct places four or five times less likely than it is,
and rewards every merge by log 4-5 = 1.5 nats too much: on ACES the online
map so scored merged 41 places into 32, with 62 nats more of that reward than
the truth's. Dead reckoning draws a corridor driven twice as two, so the
route's area can be up to that much larger than the building's (Intel: 653
m^2 against 339 m^2 along its reference), which errs towards the box.

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
    >>> two_detections = Dataset(odometry=[[38.0, 0.0, 1.5708]])          # 38 m apart: a capsule, or a box
    >>> DeadReckonedTieNormaliser(2.0, margin=1.0, area_rule="bounding_box").bind(two_detections)
    TieNormaliser(area=80, sigma_topology=2)
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

__all__ = ["AREA_RULES", "DeadReckonedTieNormaliser", "TieNormaliser", "route_area"]

#: How :meth:`TieNormaliser.from_dead_reckoning` measures the landmarks' area.
AREA_RULES = ("route", "bounding_box")
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
    def from_dead_reckoning(cls, dataset, sigma_topology: float, margin: float,
                            area_rule: str = "route") -> "TieNormaliser":
        """A from the scored run itself, ``margin`` [m] for example the detection radius; no labels are read.
        ``area_rule``: ``"route"``, the area within ``margin`` of the dead-reckoned route through the
        detections (:func:`route_area`), or ``"bounding_box"``, their bounding box with ``margin`` added on
        every side. A single detection (no odometry rows) spans the margin's disc or square."""
        if area_rule not in AREA_RULES:
            raise ValueError(f"area_rule must be one of {AREA_RULES}, got {area_rule!r}")
        if dataset.odometry is None and dataset.n != 1:
            raise ValueError("TieNormaliser.from_dead_reckoning needs a dataset with odometry")
        margin = _margin(margin)
        positions = np.zeros((1, 2)) if dataset.odometry is None else dead_reckoning(dataset.odometry)[:, :2]
        if area_rule == "route":
            area = route_area(positions, margin)
        else:
            area = float(np.prod(np.ptp(positions, axis=0) + 2.0 * margin))
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
    (:meth:`TieNormaliser.from_dead_reckoning` with ``margin`` [m], for example the detection radius, and
    ``area_rule``)."""

    name = TieNormaliser.name
    completes_global_term = True

    def __init__(self, sigma_topology: float, margin: float, area_rule: str = "route"):
        self.sigma_topology = positive("sigma_topology", sigma_topology)
        self.margin = _margin(margin)
        if area_rule not in AREA_RULES:
            raise ValueError(f"area_rule must be one of {AREA_RULES}, got {area_rule!r}")
        self.area_rule = area_rule

    def bind(self, dataset) -> TieNormaliser:
        """The normaliser for ``dataset``'s dead-reckoned detections."""
        return TieNormaliser.from_dead_reckoning(dataset, self.sigma_topology, self.margin, self.area_rule)

    def __repr__(self) -> str:
        return (f"DeadReckonedTieNormaliser(sigma_topology={self.sigma_topology:g}, margin={self.margin:g}, "
                f"area_rule={self.area_rule!r})")


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
