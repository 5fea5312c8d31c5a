"""Structured factorisations of the pose-graph Hessian: banded + low rank, and general sparse.

The Hessian of the energy of docs/model.md §3.3 at a state is
H = A_odometry + H_T: the odometry part is block-tridiagonal (3 x 3 blocks,
one per pose, coupling consecutive poses), and the topology part
H_T = diag(star) - U U^T (:class:`ptm.pose_graph.TopologyHessian`) is a
diagonal minus a low-rank term with r <= N columns. So H = A - U U^T with A
banded of half-bandwidth 5, whose Cholesky factor costs O(d).
:class:`BandedLowRankFactor` solves with H, gives log det H and draws from
N(0, H^-1) through the Woodbury identity; above ``sparse_above`` variables,
where r^2 d would dominate, :class:`SparseFactor` (SuperLU with a symmetric
ordering and diagonal pivots) is used instead. :class:`HessianLayout` knows
where the 3 x 3 blocks go in either form and assembles them.

    >>> import numpy as np
    >>> from ptm.pose_graph import TopologyHessian
    >>> layout = HessianLayout(poses=2)                          # two free poses: d = 6
    >>> blocks = np.concatenate([np.broadcast_to(2.0 * np.eye(3), (2, 3, 3)), -0.5 * np.eye(3)[None]])
    >>> topology = TopologyHessian.of(np.array([0, 1, 1]), sigma_topology=1.0)
    >>> factor = layout.factorise(topology, blocks, sparse=False)
    >>> dense = layout.matrix(topology, blocks).toarray()
    >>> bool(np.isclose(factor.log_det(), np.linalg.slogdet(dense)[1]))
    True
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from .topology import MemberSums, TopologyHessian

__all__ = ["BandedLowRankFactor", "SparseFactor", "HessianLayout", "BAND_DIAGONAL", "band_indices",
           "tridiagonal_block_indices"]

#: The row of the diagonal in upper band storage of half-bandwidth 5 (two 3x3 blocks minus one).
BAND_DIAGONAL = 5


class HessianLayout:
    """Where the 3 x 3 blocks of a block-tridiagonal Hessian over ``poses`` free poses go, in upper
    band storage and as sparse COO indices; assembles them with the topology Hessian and factorises.

    Blocks come as one array of shape (2 poses - 1, 3, 3): the diagonal blocks
    of the poses, then the blocks (pose k-1, pose k) above the diagonal.
    """

    def __init__(self, poses: int):
        self.poses = int(poses)
        self.dimension = 3 * self.poses
        self._block_rows, self._block_cols = tridiagonal_block_indices(self.poses)
        self._band_rows, self._band_cols, self._band_sources = band_indices(self.poses)
        #: The x and y coordinates of the poses, and where the block entries between two of them go in
        #: :meth:`position_matrix` (the rows and columns among the positions, the index into the values).
        self.positions = np.flatnonzero(np.arange(self.dimension) % 3 != 2)
        between_positions = np.flatnonzero((self._block_rows % 3 != 2) & (self._block_cols % 3 != 2))
        self._position_entries = (_position_index(self._block_rows[between_positions]),
                                  _position_index(self._block_cols[between_positions]), between_positions)

    def factorise(self, topology: TopologyHessian, blocks, added_diagonal=None, sparse: bool = False):
        """Factorise the topology Hessian + the block-tridiagonal blocks (+ a diagonal): a
        :class:`SparseFactor` if ``sparse``, else a :class:`BandedLowRankFactor`.

        Raises ``ValueError`` when the sum is not positive definite.
        """
        if sparse:
            return SparseFactor(self.matrix(topology, blocks, added_diagonal))
        band = np.zeros((6, self.dimension))
        band[self._band_rows, self._band_cols] = blocks.reshape(-1)[self._band_sources]
        band[BAND_DIAGONAL] += topology.star_diagonal
        if added_diagonal is not None:
            band[BAND_DIAGONAL] += added_diagonal
        return BandedLowRankFactor(band, topology.low_rank, topology.low_rank_transpose)

    def matrix(self, topology: TopologyHessian, blocks, added_diagonal=None):
        """The assembled sparse (CSC) matrix: topology Hessian + blocks (+ a diagonal)."""
        topology_rows, topology_cols, topology_values = topology.entries
        values = np.concatenate([self._block_values(blocks), topology_values])
        rows = np.concatenate([self._block_rows, topology_rows])
        cols = np.concatenate([self._block_cols, topology_cols])
        matrix = scipy.sparse.csc_matrix((values, (rows, cols)), shape=(self.dimension, self.dimension))
        if added_diagonal is not None:
            matrix = matrix + scipy.sparse.diags(added_diagonal, format="csc")
        return matrix

    def position_matrix(self, topology: TopologyHessian, blocks):
        """``matrix(topology, blocks)[positions][:, positions]``, the rows and columns of the x and y
        coordinates, assembled directly (the same CSC arrays: every entry is a sum of at most two terms,
        a block's and the topology's, so the order of summation does not matter)."""
        rows, cols, sources = self._position_entries
        topology_rows, topology_cols, topology_values = topology.entries
        values = np.concatenate([self._block_values(blocks)[sources], topology_values])
        rows = np.concatenate([rows, _position_index(topology_rows)])
        cols = np.concatenate([cols, _position_index(topology_cols)])
        return scipy.sparse.csc_matrix((values, (rows, cols)), shape=(len(self.positions),) * 2)

    def _block_values(self, blocks) -> np.ndarray:
        """The entries of the blocks in the order of ``tridiagonal_block_indices``."""
        diagonal, above = blocks[:self.poses], blocks[self.poses:]
        return np.concatenate([diagonal.ravel(), above.ravel(), np.swapaxes(above, 1, 2).ravel()])


class BandedLowRankFactor:
    """H = A - U U^T with A symmetric positive definite of half-bandwidth 5 (upper band storage).

    With A = L L^T (banded Cholesky, L = R^T stored as R in upper band storage:
    OpenBLAS solves with the upper band factor in either direction about 1.5
    times as fast as the transposed solve with a lower one) and W = L^-1 U,
    H = L (I - W W^T) L^T, so
    with K = I - W^T W = L_K L_K^T the Woodbury identity gives

        H^-1 b = L^-T (y + W K^-1 W^T y),    y = L^-1 b,
        log det H = log det A + log det K.

    Only forward substitutions (no back substitutions) build W.

    Raises ``ValueError`` when A or K is not positive definite (then neither is
    H, given A is).
    """

    def __init__(self, band, low_rank, low_rank_transpose: MemberSums):
        # LAPACK is called directly: at N = 100 the scipy.linalg wrappers' checks cost as much as the work
        self.low_rank_transpose = low_rank_transpose
        self.band_factor, info = scipy.linalg.lapack.dpbtrf(band, lower=0)
        if info != 0:
            raise ValueError("the pose-graph Hessian is not positive definite")
        self.dimension = band.shape[1]
        self.whitened_low_rank = self._triangular_solve(low_rank) if low_rank.shape[1] else low_rank  # W = L^-1 U
        capacitance = np.eye(low_rank.shape[1]) - self.whitened_low_rank.T @ self.whitened_low_rank
        self.capacitance_factor, info = scipy.linalg.lapack.dpotrf(capacitance, lower=1)
        if info != 0:
            raise ValueError("the pose-graph Hessian is not positive definite")

    def _triangular_solve(self, rhs, transpose: bool = False) -> np.ndarray:
        """L^-1 rhs = R^-T rhs, or L^-T rhs = R^-1 rhs."""
        solution, info = scipy.linalg.lapack.dtbtrs(self.band_factor, rhs, uplo="U",
                                                    trans="N" if transpose else "T")
        if info != 0:
            raise ValueError(f"banded triangular solve failed (LAPACK info {info})")
        return solution

    def solve(self, rhs) -> np.ndarray:
        whitened = self._triangular_solve(np.reshape(rhs, (self.dimension, -1)))
        if self.capacitance_factor.shape[0]:
            correction, _ = scipy.linalg.lapack.dpotrs(self.capacitance_factor, self.whitened_low_rank.T @ whitened,
                                                       lower=1)
            whitened = whitened + self.whitened_low_rank @ correction
        return self._triangular_solve(whitened, transpose=True).reshape(np.shape(rhs))

    def log_det(self) -> float:
        return 2.0 * float(np.sum(np.log(self.band_factor[BAND_DIAGONAL]))
                           + np.sum(np.log(np.diag(self.capacitance_factor))))

    def sample(self, noise_columns) -> tuple[np.ndarray, np.ndarray]:
        """Offsets delta_s ~ N(0, H^-1) as columns (d, S) from standard normal ``noise_columns``
        (at least d + r rows), and 1/2 delta_s^T H delta_s for each.

        delta = L^-T z with z = eps_1 + W L_K^-T eps_2, whose covariance
        I + W K^-1 W^T = (I - W W^T)^-1 makes Cov(delta) = H^-1; and
        delta^T H delta = |z|^2 - |W^T z|^2 = |z|^2 - |U^T delta|^2.
        """
        rank = self.capacitance_factor.shape[0]
        whitened = noise_columns[: self.dimension]
        if rank:
            coupled, _ = scipy.linalg.lapack.dtrtrs(self.capacitance_factor,
                                                    noise_columns[self.dimension:self.dimension + rank],
                                                    lower=1, trans=1)
            whitened = whitened + self.whitened_low_rank @ coupled
        offsets = self._triangular_solve(whitened, transpose=True)
        quadratic = np.einsum("ds,ds->s", whitened, whitened)
        if rank:
            quadratic -= np.einsum("rs,rs->s", projected := self.low_rank_transpose @ offsets, projected)
        return offsets, 0.5 * quadratic


class SparseFactor:
    """P^T H P = L D L^T of a sparse symmetric positive-definite matrix (SuperLU, diagonal pivots).

    With a symmetric fill-reducing ordering and no off-diagonal pivoting the LU
    factors of an SPD matrix are U = D L^T, so G = P L D^1/2 satisfies G G^T = H,
    and G^-T eps = H^-1 (G eps): one sparse product and one SuperLU solve.
    """

    def __init__(self, matrix):
        self.lu = scipy.sparse.linalg.splu(
            scipy.sparse.csc_matrix(matrix), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
        if not np.array_equal(self.lu.perm_r, self.lu.perm_c):
            raise ValueError("the sparse factorisation pivoted off the diagonal: Hessian not positive definite")
        self.pivots = self.lu.U.diagonal()
        if not np.all(self.pivots > 0.0):
            raise ValueError("the pose-graph Hessian is not positive definite")
        self.lower = self.lu.L.tocsr()

    def solve(self, rhs) -> np.ndarray:
        return self.lu.solve(rhs)

    def log_det(self) -> float:
        return float(np.sum(np.log(self.pivots)))

    def sample(self, noise_columns) -> tuple[np.ndarray, np.ndarray]:
        """Offsets G^-T eps_s ~ N(0, H^-1) as columns (d, S) from the first d rows of standard
        normal ``noise_columns``, and 1/2 delta_s^T H delta_s = 1/2 |eps_s|^2 for each."""
        noise = noise_columns[: len(self.pivots)]
        factor_times_noise = self.lower @ (noise * np.sqrt(self.pivots)[:, None])
        offsets = self.lu.solve(np.ascontiguousarray(factor_times_noise[self.lu.perm_c]))  # (P y)_i = y[perm_c[i]]
        return offsets, 0.5 * np.einsum("ds,ds->s", noise, noise)


class DenseFactor:
    """H = L L^T of a small dense symmetric positive-definite matrix (LAPACK Cholesky), with the interface of
    :class:`SparseFactor`, for sizes where sparse algebra costs more in overhead than it saves.

    Raises ``ValueError`` when the matrix is not positive definite.
    """

    def __init__(self, matrix):
        try:
            self.lower = np.linalg.cholesky(np.asarray(matrix, dtype=float))
        except np.linalg.LinAlgError as error:
            raise ValueError("the matrix is not positive definite") from error

    def solve(self, rhs) -> np.ndarray:
        return scipy.linalg.cho_solve((self.lower, True), rhs)

    def log_det(self) -> float:
        return 2.0 * float(np.sum(np.log(np.diag(self.lower))))

    def sample(self, noise_columns) -> tuple[np.ndarray, np.ndarray]:
        """Offsets L^-T eps_s ~ N(0, H^-1) as columns (d, S) from the first d rows of ``noise_columns``,
        and 1/2 delta_s^T H delta_s = 1/2 |eps_s|^2 for each."""
        noise = noise_columns[: len(self.lower)]
        offsets = scipy.linalg.solve_triangular(self.lower, noise, lower=True, trans="T")
        return offsets, 0.5 * np.einsum("ds,ds->s", noise, noise)


def _position_index(coordinates) -> np.ndarray:
    """The index among the x and y coordinates of the x or y coordinate ``coordinates`` (3i + a -> 2i + a)."""
    return coordinates - coordinates // 3


def band_indices(poses: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the upper triangle of the 3x3 blocks goes in upper band storage (A[i, j] at band[5 + i - j, j]).

    Blocks are laid out as in :class:`ptm.pose_graph.Linearisation` (diagonal blocks, then the
    blocks above the diagonal); returns (band row, band column, index into the
    flattened blocks) for every stored entry. Entries are enumerated in the lower
    triangle, A[j + m, j] for m = 0..5, and stored as their mirror A[j, j + m].
    """
    rows, cols, sources = [], [], []
    for a in range(3):
        for b in range(a + 1):  # diagonal block (i, i): entry (3i + a, 3i + b)
            pose = np.arange(poses)
            rows.append(np.full(poses, a - b))
            cols.append(3 * pose + b)
            sources.append(pose * 9 + 3 * a + b)
        for b in range(3):  # block (i + 1, i) = transpose of the block above: entry (3(i+1) + a, 3i + b)
            pose = np.arange(max(poses - 1, 0))
            rows.append(np.full(len(pose), 3 + a - b))
            cols.append(3 * pose + b)
            sources.append(9 * poses + pose * 9 + 3 * b + a)
    below_diagonal, cols = np.concatenate(rows), np.concatenate(cols)
    return BAND_DIAGONAL - below_diagonal, cols + below_diagonal, np.concatenate(sources)


def tridiagonal_block_indices(poses: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the 3x3 blocks (i,i), (i-1,i), (i,i-1) of a block-tridiagonal matrix."""
    within_rows, within_cols = np.divmod(np.arange(9), 3)

    def block(row_pose, col_pose):
        rows = (3 * row_pose[:, None] + within_rows).ravel()
        cols = (3 * col_pose[:, None] + within_cols).ravel()
        return rows, cols

    everyone = np.arange(poses)
    diagonal = block(everyone, everyone)
    upper = block(everyone[:-1], everyone[1:])
    lower = block(everyone[1:], everyone[:-1])
    return (np.concatenate([diagonal[0], upper[0], lower[0]]),
            np.concatenate([diagonal[1], upper[1], lower[1]]))
