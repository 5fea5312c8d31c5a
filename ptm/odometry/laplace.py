"""Which minimum is P*: the Laplace fit that defines log P(O | T) (docs/model.md §3.3, step 1, "Which minimum is
P*").

The energy E_T of a partition is non-convex in the headings, and implausible partitions have several local
minima. A fit warm-started from the previous partition's optimum would make the value of a partition depend
on the chain's history, so P* is defined from the partition alone: the fit (:meth:`ptm.pose_graph.PoseGraph.fit`)
runs from two fixed starts, each a function of the partition, and the converged minimum of lower energy counts
(the first on a tie). The starts are

* the chordal relaxation's headings with their optimal positions
  (:meth:`ptm.pose_graph.PoseGraph.chordal_start`): where the partition's loops are consistent the relaxation
  is nearly tight, so its headings already bend the dead-reckoned drift the way the closures ask, which a
  Newton fit from dead reckoning may not manage on a long run (it can stop in a basin hundreds of nats above);
* dead reckoning, for the partitions whose loops the relaxation reconciles badly.

The chosen minimum is the better of two starts, not necessarily the global one. A fit that does not converge
keeps its last iterate; the caller records it (:class:`ptm.odometry.OdometryTerm`). A term grown from a run
one detection shorter first tries the shorter run's mode with the new leaf composed on
(:mod:`ptm.odometry.growth`).

    >>> from ptm import Dataset, OdometryModel
    >>> steps = np.array([[2.0, 0.0, 1.4]] + [[2.0, 0.0, np.pi / 2]] * 3)   # a square, the first turn 0.17 short
    >>> term = OdometryModel(0.1, 0.05, sigma_topology=0.1).bind(Dataset(odometry=steps))
    >>> fitter = LaplaceFitter(term.graph)
    >>> labels = np.array([0, 1, 2, 3, 0])                                    # the loop closes
    >>> [round(float(term.graph.energy(start, labels)), 2) for start in fitter.starts(term.graph.topology(labels))]
    [0.85, 5.82]
    >>> fit = fitter.fit(labels)
    >>> fit.converged, round(float(fit.energy), 2)
    (True, 0.84)
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..pose_graph import LaplaceFit, PoseGraph, TopologyHessian
from .growth import ShorterRun

__all__ = ["LaplaceFitter"]


class LaplaceFitter:
    """Fits P* of any partition of one pose graph from the history-free :meth:`starts`.

    ``shorter`` (a :class:`~ptm.odometry.growth.ShorterRun`, or None) holds the modes of the run one detection
    shorter where the term was grown from it; ``from_shorter_run`` counts the fits polished from them.
    """

    def __init__(self, graph: PoseGraph, shorter: ShorterRun | None = None):
        self.graph = graph
        self.shorter = shorter
        self.from_shorter_run = 0
        self._dead_reckoning = graph.dead_reckoning()

    def starts(self, topology: TopologyHessian) -> tuple[np.ndarray, ...]:
        """The starts of the fit of ``topology``: the chordal relaxation's headings with their optimal positions,
        then dead reckoning."""
        return self.graph.chordal_start(topology), self._dead_reckoning

    def fit(self, labels) -> LaplaceFit:
        """The Laplace fit of the partition ``labels``: of the minima reached from :meth:`starts`, the converged
        one of lowest energy (the first on a tie), with the iterations and factorisations of both fits; where
        the shorter run offers a start and the fit from it converges, that fit."""
        labels = np.asarray(labels)
        topology = self.graph.topology(labels)
        start = self.shorter.start(labels) if self.shorter is not None else None
        if start is not None:
            polished = self.graph.fit(start, topology)
            if polished.converged:
                self.from_shorter_run += 1
                return polished
        fits = [self.graph.fit(start, topology) for start in self.starts(topology)]
        usable = [fit for fit in fits if fit.factor is not None] or fits[:1]
        best = min(usable, key=lambda fit: (not fit.converged, fit.energy))
        iterations = sum(fit.iterations for fit in fits)
        factorisations = sum(fit.factorisations for fit in fits)
        return dataclasses.replace(best, iterations=iterations, factorisations=factorisations)
