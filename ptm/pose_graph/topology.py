"""The topology term of the pose-graph energy: the tie between positions of detections of one place.

Implements the topology part of the energy of docs/model.md §3.3 (paper
eq. 13): for a partition T,

    E_T(P) = 1/2 sum_{S in T} sum_{i<j in S} |t_i - t_j|^2 / sigma_T^2

over the positions t_i = (x_i, y_i) (headings are free). E_T is exactly
quadratic in the state, 1/2 x^T H_T x, and its Hessian H_T is the graph
Laplacian of the cliques of T divided by sigma_T^2: per set S,
(|S| I - 1 1^T) / sigma_T^2, a diagonal minus a rank-one term. So
H_T = diag(star) - U U^T with U one column per set and axis (1/sigma_T on the
members' coordinates), the form the banded + low-rank factor of
:mod:`ptm.pose_graph.factorisation` takes. Pose 0 is fixed at the origin but
still counts in |S|.

    >>> import numpy as np
    >>> topology = TopologyHessian.of(np.array([0, 1, 0]), sigma_topology=1.0)   # pose 2 revisits pose 0
    >>> float(topology.energy(np.array([1.0, 0.0, 0.0, 3.0, 4.0, 0.0])))          # 1/2 |t_2 - t_0|^2
    12.5
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["TopologyHessian", "MemberSums"]


@dataclass(frozen=True)
class MemberSums:
    """U^T as a linear map: column c of U holds ``scale`` on coordinates[starts[c]:starts[c + 1]]."""

    coordinates: np.ndarray
    columns: np.ndarray  # the column of each coordinate entry
    starts: np.ndarray
    scale: float

    def __matmul__(self, matrix) -> np.ndarray:
        if not len(self.starts):
            return np.zeros((0,) + np.shape(matrix)[1:])
        return self.scale * np.add.reduceat(matrix[self.coordinates], self.starts, axis=0)


@dataclass(frozen=True)
class TopologyHessian:
    """H_T = (clique Laplacian of T) / sigma_T^2 on the free x and y coordinates.

    Held as star_diagonal - low_rank low_rank^T (the banded factor's form), and
    as COO entries when first asked for (the sparse factor's). The topology
    energy is the quadratic form 1/2 x^T H_T x (pose 0 sits at the origin, so
    its terms vanish). Build it with :meth:`of`.
    """

    labels: np.ndarray  # the partition, canonical
    star_diagonal: np.ndarray  # (d,): |S| / sigma_T^2 on the members of non-singleton sets
    low_rank: np.ndarray  # (d, r): per set and axis, 1 / sigma_T on the members' coordinates
    low_rank_transpose: MemberSums  # its transpose as sums over members (one entry per coordinate)
    set_sizes: np.ndarray  # (r,): |S| of each column's set, pose 0 included
    origin_in_set: np.ndarray  # (r,): 1 where pose 0 belongs to the column's set

    @classmethod
    def of(cls, labels, sigma_topology: float) -> "TopologyHessian":
        """w (|S| I - 1 1^T), w = 1/sigma_T^2, for every set S with two or more members, on the x and
        y coordinates of its free poses (pose 0 is fixed but still counts in |S|), as a star diagonal
        w |S| minus one column of U per set and axis (1/sigma_T on its members).

        ``labels`` is an (N,) integer array of the partition (canonical or not).
        """
        labels = np.asarray(labels)
        dimension = 3 * (len(labels) - 1)
        counts = np.bincount(labels)
        free_sizes = counts[labels[1:]]
        members = np.flatnonzero(free_sizes > 1)  # free poses of sets with two or more members
        shared = counts > 1  # the sets with columns (each has a free member)
        column_of_label = np.cumsum(shared) - 1
        column_of_set = column_of_label[labels[1:][members]]
        rank = 2 * int(np.count_nonzero(shared))
        coordinates = np.concatenate([3 * members, 3 * members + 1])
        columns = np.concatenate([2 * column_of_set, 2 * column_of_set + 1])
        star_diagonal = np.zeros(dimension)
        star_diagonal[coordinates] = (1.0 / sigma_topology**2) * np.concatenate([free_sizes[members]] * 2)
        low_rank = np.zeros((dimension, rank))
        low_rank[coordinates, columns] = 1.0 / sigma_topology
        order = np.argsort(columns, kind="stable")
        starts = np.searchsorted(columns[order], np.arange(rank))
        set_sizes = np.repeat(counts[shared], 2).astype(float)
        origin_in_set = np.zeros(rank)
        if shared[labels[0]]:
            origin_in_set[2 * column_of_label[labels[0]] + np.arange(2)] = 1.0
        return cls(labels, star_diagonal, low_rank,
                   MemberSums(coordinates[order], columns[order], starts, 1.0 / sigma_topology),
                   set_sizes, origin_in_set)

    def __matmul__(self, vector) -> np.ndarray:
        return self.star_diagonal * vector - self.low_rank @ (self.low_rank_transpose @ vector)

    @cached_property
    def diagonal(self) -> np.ndarray:
        """(d,): each member coordinate's own column of U contributes 1 / sigma_T^2 to U U^T."""
        return np.where(self.star_diagonal > 0.0, self.star_diagonal - self.low_rank_transpose.scale**2, 0.0)

    @cached_property
    def entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """COO (rows, cols, values) without duplicates: w (|S| - 1) on the diagonal of every
        member coordinate and -w between the same coordinate of two members, w = 1/sigma_T^2."""
        labels = self.labels
        sizes = np.bincount(labels)[labels]
        free_labels = labels[1:]
        first, second = np.nonzero((free_labels[:, None] == free_labels[None, :]) & (sizes[1:, None] > 1))
        weight = self.low_rank_transpose.scale**2
        pair_values = np.where(first == second, weight * (sizes[1:][first] - 1.0), -weight)
        return (np.concatenate([3 * first, 3 * first + 1]), np.concatenate([3 * second, 3 * second + 1]),
                np.concatenate([pair_values, pair_values]))

    def energy(self, states) -> np.ndarray:
        """1/2 sum_S sum_{i<j in S} |t_i - t_j|^2 / sigma_T^2 = 1/2 x^T H_T x for states of shape (..., d).

        Evaluated through the exact identity sum_{i<j in S} |t_i - t_j|^2 =
        |S| sum_{i in S} |t_i - mean_S|^2 (not the star energy
        sum |t_i - mean_S|^2, which weights sets differently), with pose 0 (at
        the origin) a member of its set, one coordinate axis at a time, in O(N)
        per state: the quadratic form itself cancels catastrophically far from
        the origin, and a fit compares energies to the last digit.
        """
        members = self.low_rank_transpose
        if not len(members.starts):
            return np.zeros(np.shape(states)[:-1])
        values = states[..., members.coordinates]
        means = np.add.reduceat(values, members.starts, axis=-1) / self.set_sizes
        deviations = values - means[..., members.columns]
        squares = np.add.reduceat(deviations * deviations, members.starts, axis=-1) + self.origin_in_set * means**2
        return 0.5 * members.scale**2 * (squares @ self.set_sizes)

    def energy_around(self, centre, offsets) -> np.ndarray:
        """The topology energy of centre + delta_s for offsets delta_s given as columns (d, S), by
        the exact expansion E_T(c) + (H_T c)^T delta + 1/2 (sum_i star_i delta_i^2 - |U^T delta|^2).

        The quadratic form cancels only on the scale of the offsets, not of the positions.
        """
        projected = self.low_rank_transpose @ offsets
        quadratic = self.star_diagonal @ (offsets * offsets) - np.einsum("rs,rs->s", projected, projected)
        return self.energy(centre) + (self @ centre) @ offsets + 0.5 * quadratic
