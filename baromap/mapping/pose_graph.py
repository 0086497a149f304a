"""A 2D pose graph and its robust sparse least-squares optimisation.

Why hand-rolled Gauss-Newton over ``scipy.optimize.least_squares`` or gtsam: a pose graph's
normal matrix is block-sparse and well suited to a direct sparse solve (SuperLU on the 3x3
block structure, minimum-degree ordering), which converges in a handful of iterations;
least_squares with a sparse Jacobian only offers an iterative trust-region solver (LSMR) that
needs many inner iterations on the long, weakly connected chains a corridor run produces.
gtsam's iSAM2 was measured on a graph of the 46-minute run's size (3000 nodes, 700 closures
spanning 200 nodes each): 7 s of incremental updates, where this solver, called only when a
closure moves the graph, needs a fraction of that; a 35 MB binary dependency does not earn
its place for that.

Nodes and edges live in arrays that grow by doubling, so adding one costs nothing like
re-stacking the whole graph.

Robustness: an edge may carry a kernel. Iteratively reweighted least squares gives an edge
with squared Mahalanobis error ``chi2`` the Cauchy weight ``1 / (1 + chi2 / c^2)``, so a wrong
loop closure that disagrees with the rest of the graph by many sigmas pulls with almost no
force and cannot bend the map, while consistent edges keep their full weight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import structlog
from scipy import sparse
from scipy.sparse import csgraph
from scipy.sparse import linalg as sparse_linalg

from baromap.arrays import FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.errors import MappingError

log = structlog.get_logger(__name__)


#: Stiffness that holds the anchor node in place (the gauge freedom of a pose graph).
ANCHOR_INFORMATION = 1e9
#: Median of a chi-square of three degrees of freedom: the squared Mahalanobis error that an
#: edge whose information is its real error has, in the median.
CHI2_3_MEDIAN = 2.3660


@dataclass(slots=True)
class Edge:
    """Measured motion ``z`` from node ``i`` to node ``j`` (in i's frame)."""

    i: int
    j: int
    z: FloatArray
    information: FloatArray
    kind: str = "odometry"  # odometry | match | loop | ride
    robust_c: float | None = None  # Cauchy scale in sigmas; None = plain least squares


def _grow(array: npt.NDArray[np.generic], needed: int) -> npt.NDArray[np.generic]:
    if needed <= len(array):
        return array
    bigger = np.zeros((max(needed, 2 * len(array)), *array.shape[1:]), dtype=array.dtype)
    bigger[: len(array)] = array
    return bigger


class PoseGraph:
    """Poses (x, y, theta) and the relative-motion edges between them."""

    def __init__(self) -> None:
        self._poses: FloatArray = np.zeros((64, 3))
        self._n = 0
        self._i: IntArray = np.zeros(64, dtype=np.int64)
        self._j: IntArray = np.zeros(64, dtype=np.int64)
        self._z: FloatArray = np.zeros((64, 3))
        self._info: FloatArray = np.zeros((64, 3, 3))
        self._robust: FloatArray = np.zeros(64)
        self._kinds: list[str] = []
        self._m = 0
        # unary priors: a measured pose of one node
        self._prior_node: IntArray = np.zeros(0, dtype=np.int64)
        self._prior_pose: FloatArray = np.zeros((0, 3))
        self._prior_info: FloatArray = np.zeros((0, 3, 3))

    def __len__(self) -> int:
        return self._n

    @property
    def poses(self) -> FloatArray:
        """The current estimate (a view: writing a row moves that node)."""
        return self._poses[: self._n]

    @property
    def edge_count(self) -> int:
        return self._m

    @property
    def edges(self) -> list[Edge]:
        """The edges as objects (built on demand; the graph keeps arrays)."""
        return [
            Edge(
                int(self._i[k]),
                int(self._j[k]),
                self._z[k].copy(),
                self._info[k].copy(),
                self._kinds[k],
                None if not np.isfinite(self._robust[k]) else float(self._robust[k]),
            )
            for k in range(self._m)
        ]

    def kinds(self) -> list[str]:
        return list(self._kinds)

    def add_node(self, pose: npt.ArrayLike) -> int:
        self._poses = _grow(self._poses, self._n + 1)  # type: ignore[assignment]
        self._poses[self._n] = np.asarray(pose, dtype=np.float64).reshape(3)
        self._n += 1
        return self._n - 1

    def add_edge(self, edge: Edge) -> int:
        if not (0 <= edge.i < self._n and 0 <= edge.j < self._n):
            raise MappingError(f"edge {edge.i}->{edge.j} refers to a missing node")
        m = self._m + 1
        self._i = _grow(self._i, m)  # type: ignore[assignment]
        self._j = _grow(self._j, m)  # type: ignore[assignment]
        self._z = _grow(self._z, m)  # type: ignore[assignment]
        self._info = _grow(self._info, m)  # type: ignore[assignment]
        self._robust = _grow(self._robust, m)  # type: ignore[assignment]
        k = self._m
        self._i[k], self._j[k] = edge.i, edge.j
        self._z[k] = edge.z
        self._info[k] = edge.information
        self._robust[k] = np.inf if edge.robust_c is None else edge.robust_c
        self._kinds.append(edge.kind)
        self._m = m
        return k

    def set_priors(self, nodes: IntArray, poses: FloatArray, information: FloatArray) -> None:
        """Measured poses of some nodes, in the graph's frame, with their information (in the
        graph's frame too); replaces any earlier priors."""
        nodes = np.asarray(nodes, dtype=np.int64)
        if len(nodes) and (nodes.min() < 0 or nodes.max() >= self._n):
            raise MappingError("a prior refers to a missing node")
        self._prior_node = nodes
        self._prior_pose = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        # the error of a prior is expressed in the measured pose's frame
        c, s = np.cos(self._prior_pose[:, 2]), np.sin(self._prior_pose[:, 2])
        rot = np.zeros((len(nodes), 3, 3))
        rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = c, -s, s, c
        rot[:, 2, 2] = 1.0
        info = np.asarray(information, dtype=np.float64).reshape(-1, 3, 3)
        self._prior_info = np.einsum("mki,mkl,mlj->mij", rot, info, rot)

    def parts(self, left_out: npt.NDArray[np.bool_] | None = None) -> IntArray:
        """The connected part of the graph each node is in, by the edges not ``left_out``
        (a mask over the edges): nodes of different parts are placed against each other
        only by the edges left out. Parts are numbered in the order of their first node, so
        node 0's is part 0."""
        keep = np.ones(self._m, dtype=bool) if left_out is None else ~np.asarray(left_out)
        if keep.shape != (self._m,):
            raise MappingError(f"a mask of {keep.shape} over {self._m} edges")
        i, j = self._i[: self._m][keep], self._j[: self._m][keep]
        adjacency = sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(self._n, self._n))
        _, labels = csgraph.connected_components(adjacency, directed=False)
        # renumbered by first node, whatever order scipy gives
        _, first = np.unique(labels, return_index=True)
        rank = np.empty(len(first), dtype=np.int64)
        rank[np.argsort(first)] = np.arange(len(first))
        parts: IntArray = rank[labels]
        return parts

    def edge_errors(
        self, poses: FloatArray | None = None, edges: IntArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Error vectors (M, 3) and squared Mahalanobis norms (M,) of all edges, or of the
        edges numbered ``edges``."""
        poses = self.poses if poses is None else poses
        sel = np.arange(self._m) if edges is None else np.asarray(edges, dtype=np.int64)
        if len(sel) == 0:
            return np.zeros((0, 3)), np.zeros(0)
        i, j = self._i[sel], self._j[sel]
        err = se2.between(self._z[sel], se2.between(poses[i], poses[j]))
        chi2 = np.einsum("mi,mij,mj->m", err, self._info[sel], err)
        return err, chi2

    def scatter(self, kind: str) -> tuple[int, float]:
        """How the edges of one kind scatter against the current estimate, as a factor on the
        covariance they claim: the median of their squared Mahalanobis errors over that of a
        chi-square of three degrees of freedom (1 when their information is their real error,
        0.1 when they err a tenth of the variance they claim). The median, so the few wrong
        edges a kind holds do not count. Returns (number of edges, factor)."""
        sel = self._of_kind(kind)
        if len(sel) == 0:
            return 0, 1.0
        _, chi2 = self.edge_errors(edges=sel)
        return len(sel), float(np.median(chi2)) / CHI2_3_MEDIAN

    def scale_information(self, kind: str, factor: float) -> None:
        """Multiply the information of every edge of one kind by ``factor``."""
        self._info[self._of_kind(kind)] *= factor

    def _of_kind(self, kind: str) -> IntArray:
        return np.flatnonzero(np.array([k == kind for k in self._kinds], dtype=bool))

    def optimize(
        self, iterations: int = 20, anchor: int | None = 0, tolerance: float = 1e-5
    ) -> int:
        """Robust Gauss-Newton in place; returns the iterations used. ``anchor`` is held where
        it stands (a graph of relative edges alone has no frame of its own); None when priors
        in the graph's frame fix the frame (see :meth:`set_priors`)."""
        n, m = self._n, self._m
        if n < 2 or m == 0:
            return 0
        i, j = self._i[:m], self._j[:m]
        z, info, robust = self._z[:m], self._info[:m], self._robust[:m]
        structure = _BlockStructure(i, j, n)
        cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
        poses = self.poses.copy()
        used = 0
        for used in range(1, iterations + 1):  # noqa: B007 - the count is returned
            pi, pj = poses[i], poses[j]
            ci, si = np.cos(pi[:, 2]), np.sin(pi[:, 2])
            dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
            # local = R_i^T d ; e_xy = R_z^T (local - t_z)
            lx = ci * dx + si * dy
            ly = -si * dx + ci * dy
            ex = cz * (lx - z[:, 0]) + sz * (ly - z[:, 1])
            ey = -sz * (lx - z[:, 0]) + cz * (ly - z[:, 1])
            et = se2.wrap(pj[:, 2] - pi[:, 2] - z[:, 2])
            err = np.stack([ex, ey, et], axis=1)
            chi2 = np.matmul(err[:, None, :], np.matmul(info, err[:, :, None]))[:, 0, 0]
            weight = np.where(np.isfinite(robust), 1.0 / (1.0 + chi2 / robust**2), 1.0)
            # B = d e / d x_j ; A = d e / d x_i
            a11, a12 = cz * ci - sz * si, cz * si + sz * ci
            a21, a22 = -sz * ci - cz * si, -sz * si + cz * ci
            dex_dt = cz * ly - sz * lx
            dey_dt = -sz * ly - cz * lx
            jac_j = np.zeros((m, 3, 3))
            jac_j[:, 0, 0], jac_j[:, 0, 1] = a11, a12
            jac_j[:, 1, 0], jac_j[:, 1, 1] = a21, a22
            jac_j[:, 2, 2] = 1.0
            jac_i = -jac_j
            jac_i[:, 0, 2], jac_i[:, 1, 2] = dex_dt, dey_dt
            w_info = info * weight[:, None, None]
            wa = np.matmul(w_info, jac_i)  # Omega A
            wb = np.matmul(w_info, jac_j)  # Omega B
            jit, jjt = jac_i.transpose(0, 2, 1), jac_j.transpose(0, 2, 1)
            blocks = np.concatenate(
                [
                    np.matmul(jit, wa),  # A^T Omega A  (i, i)
                    np.matmul(jjt, wb),  # B^T Omega B  (j, j)
                    np.matmul(jit, wb),  # A^T Omega B  (i, j)
                    np.matmul(jjt, wa),  # B^T Omega A  (j, i)
                ]
            )
            grad = np.zeros((n, 3))
            np.add.at(grad, i, np.matmul(wa.transpose(0, 2, 1), err[:, :, None])[:, :, 0])
            np.add.at(grad, j, np.matmul(wb.transpose(0, 2, 1), err[:, :, None])[:, :, 0])
            extra = np.zeros((n, 3, 3))
            if len(self._prior_node):
                self._add_priors(poses, extra, grad)
            h = structure.matrix(blocks, anchor, extra)
            try:
                factor = _factorize(h)
                delta = factor.solve(-grad.ravel())
            except RuntimeError:  # singular: a node without any edge
                delta = np.full(3 * n, np.nan)
            if not np.all(np.isfinite(delta)):
                log.warning("pose graph solve failed", nodes=n, edges=m)
                break
            step = delta.reshape(n, 3)
            poses += step
            poses[:, 2] = se2.wrap(poses[:, 2])
            if np.abs(step).max() < tolerance:
                break
        self._poses[:n] = poses
        return used

    def _add_priors(self, poses: FloatArray, diag: FloatArray, grad: FloatArray) -> None:
        """Priors' Gauss-Newton terms into the diagonal blocks and the gradient."""
        node, y, info = self._prior_node, self._prior_pose, self._prior_info
        x = poses[node]
        c, s = np.cos(y[:, 2]), np.sin(y[:, 2])
        dx, dy = x[:, 0] - y[:, 0], x[:, 1] - y[:, 1]
        err = np.stack([c * dx + s * dy, -s * dx + c * dy, se2.wrap(x[:, 2] - y[:, 2])], 1)
        jac = np.zeros((len(node), 3, 3))
        jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1] = c, s, -s, c
        jac[:, 2, 2] = 1.0
        weighted = np.einsum("mkl,mlc->mkc", info, jac)
        np.add.at(diag, node, np.einsum("mki,mkc->mic", jac, weighted))
        np.add.at(grad, node, np.einsum("mki,mk->mi", weighted, err))


def _factorize(h: sparse.csc_matrix) -> sparse_linalg.SuperLU:
    """LU of the normal matrix, which is symmetric positive definite (a sum of J^T W J with
    positive weights, a regulariser on every diagonal block and the anchor's stiff prior).

    A minimum-degree ordering on A + A^T keeps the fill-in of loop closures down (5x faster
    than the default COLAMD here), and since the matrix is positive definite its diagonal
    pivots are as safe as they are for a Cholesky factor: no pivot search (the default
    threshold 1 lets SuperLU swap rows, which spoils the symmetric ordering and costs five
    times the time on the 46-minute run's graph of 1,800 nodes and 550 closures).
    """
    return sparse_linalg.splu(
        h,
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )


class _BlockStructure:
    """The 3x3-block sparsity of a graph's normal matrix, computed once per optimisation so
    each iteration only sums block values into place, straight into the compressed-column
    arrays the solver takes."""

    def __init__(self, i: IntArray, j: IntArray, n: int) -> None:
        diag = np.arange(n, dtype=np.int64)
        rows = np.concatenate([i, j, i, j, diag])
        cols = np.concatenate([i, j, j, i, diag])
        # blocks sorted by (block column, block row): the order of a CSC matrix's columns
        keys, inverse = np.unique(cols * n + rows, return_inverse=True)
        inverse = inverse.reshape(-1)
        self.n = n
        self.blocks = len(keys)
        block_col, block_row = keys // n, keys % n
        per_col = np.bincount(block_col, minlength=n)  # blocks in each block column
        # each block column becomes three scalar columns of 3 * per_col entries each
        col_start = np.concatenate([[0], np.cumsum(3 * per_col)[:-1]])
        first_block = np.concatenate([[0], np.cumsum(per_col)[:-1]])
        # entry (block b, r, c) sits in scalar column 3 * block_col + c, at position
        # 3 * (b - first block of the column) + r within it
        b = np.arange(self.blocks)
        within = 3 * (b - first_block[block_col])
        r, c = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")  # (3, 3)
        position = (
            3 * col_start[block_col][:, None, None]
            + c[None] * (3 * per_col[block_col])[:, None, None]
            + within[:, None, None]
            + r[None]
        )
        # slot of each summed (block, r, c) value in the CSC data array
        self.slot = position.reshape(-1)
        self.row_index = np.empty(9 * self.blocks, dtype=np.int32)
        self.row_index[self.slot] = (3 * block_row[:, None, None] + r[None]).reshape(-1)
        self.indptr = np.concatenate([[0], np.cumsum(np.repeat(3 * per_col, 3))]).astype(np.int32)
        # summing block values: one bincount over (block, entry) slots
        self.entry = (9 * inverse[:, None] + np.arange(9)[None, :]).reshape(-1)

    def matrix(
        self, edge_blocks: FloatArray, anchor: int | None, extra: FloatArray
    ) -> sparse.csc_matrix:
        n = self.n
        # every node's diagonal block gets a tiny regulariser, the anchor a stiff prior
        diag = extra + np.eye(3) * 1e-9
        if anchor is not None:
            diag[anchor] += np.eye(3) * ANCHOR_INFORMATION
        values = np.concatenate([edge_blocks, diag]).reshape(-1)
        summed = np.bincount(self.entry, weights=values, minlength=9 * self.blocks)
        data = np.empty(9 * self.blocks)
        data[self.slot] = summed
        return sparse.csc_matrix((data, self.row_index, self.indptr), shape=(3 * n, 3 * n))
