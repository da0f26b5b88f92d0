"""Marginal covariances of a few variables of a large linearized graph, by sparse selected
inversion: the entries of the inverse normal matrix on the pattern of its Cholesky factor
(Takahashi's recurrences), computed top-down over the factor's supernodes and only for the
supernodes a requested variable lies in and their ancestors.

With the normal matrix N = A^T A = L D L^T (L unit lower triangular, in a fill-reducing order)
and Y = N^-1, a supernode J (columns with a common structure S below them: L_JJ unit lower, L_SJ
dense) gives, from the block rows J of L^T Y = D^-1 L^-1 (lower triangular),

    Y_SJ = -Y_SS W,   Y_JJ = L_JJ^-T D_J^-1 L_JJ^-1 - W^T Y_SJ,   W = L_SJ L_JJ^-1,

where Y_SS lies inside the parent supernode's clique (S is a clique of the filled graph), so each
supernode needs its parent's dense block of Y over the parent's columns and structure, nothing
else. A variable's columns form a clique, so its block lies in the clique of the supernode of its
first column. The cost is that of factorizing the ancestors' cliques: for the sensors of a large
installation (near the elimination tree's root, the robot's path below them), a fraction of the
factorization, where one marginal per variable through a Bayes tree re-eliminates its whole
clique each time.
"""

from __future__ import annotations

import gtsam
import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.linalg import solve_triangular

from pedcal.calib.profile import Columns, fill_reducing_order, normal_lu, ordered_normal_matrix, sparse_system


def ldl_factor(A: sps.spmatrix, order: np.ndarray) -> tuple[sps.csc_matrix, np.ndarray, np.ndarray]:
    """The factorization N = A^T A = P^T L D L^T P in the fill-reducing column ``order``
    (:func:`pedcal.calib.profile.fill_reducing_order`): (L unit lower triangular, CSC, sorted rows,
    its diagonal stored; D's diagonal; each column of A's position in L). SuperLU without
    pivoting (N is positive definite), whose U is D L^T."""
    N, position = ordered_normal_matrix(A, order)
    return ldl_of_lu(normal_lu(N), position)


def ldl_of_lu(lu, position: np.ndarray) -> tuple[sps.csc_matrix, np.ndarray, np.ndarray]:
    """:func:`ldl_factor` from SuperLU's factorization of the normal matrix formed in its order
    (:func:`pedcal.calib.profile.normal_lu`), ``position`` each of the system's columns' in it."""
    if not np.array_equal(lu.perm_r, lu.perm_c):
        raise np.linalg.LinAlgError("the normal matrix's LU factorization pivoted: it is not positive definite")
    d = lu.U.diagonal()                 # (U's copy dropped at once: the peak memory is here)
    L = lu.L.tocsc()
    L.sort_indices()
    if not np.all(d > 0.0):
        raise np.linalg.LinAlgError("the normal matrix is not positive definite (a variable no factor holds)")
    return L, d, lu.perm_c[position]


def _supernodes(L: sps.csc_matrix) -> tuple[np.ndarray, np.ndarray]:
    """Fundamental supernodes of L's pattern: (first column of each and the end, supernode of
    each column). Column j + 1 joins j's when it is j's parent in the elimination tree (L's first
    row below j's diagonal) with one fewer row: their structures are then nested and equal."""
    n = L.shape[1]
    count = np.diff(L.indptr)
    below = np.full(n, -1, np.int64)
    has = count > 1
    below[has] = L.indices[L.indptr[:-1][has] + 1]
    joins = (below[:-1] == np.arange(1, n)) & (count[:-1] == count[1:] + 1)
    first = np.r_[0, np.flatnonzero(~joins) + 1, n].astype(np.int64)
    of = np.repeat(np.arange(len(first) - 1), np.diff(first))
    return first, of


def selected_inverse_blocks(L: sps.csc_matrix, d: np.ndarray, blocks: list[np.ndarray]) -> list[np.ndarray]:
    """The blocks Y[b, b] of Y = (L D L^T)^-1 for each array of column indices b in ``blocks``, by
    Takahashi's recurrences (module docstring) over the supernodes that hold a block and their
    ancestors; None for a block that is no clique of L's pattern (columns no fill joins, such as
    a variable held by diagonal priors alone: :func:`inverse_columns` gives those)."""
    first, of = _supernodes(L)
    Lp, Li, Lx = L.indptr, L.indices, L.data
    m = len(first) - 1
    clique = [Li[Lp[first[s]]:Lp[first[s] + 1]] for s in range(m)]     # the supernode's columns, then S
    width = np.diff(first)
    parent = np.array([of[c[w]] if len(c) > w else -1 for c, w in zip(clique, width, strict=True)], np.int64)
    # which supernodes to visit: those holding a block's first column, and their ancestors
    blocks = [np.sort(np.asarray(b, np.int64)) for b in blocks]
    owner = np.array([of[b[0]] for b in blocks], np.int64)
    wanted = np.zeros(m, bool)
    for s in np.unique(owner):
        while s >= 0 and not wanted[s]:
            wanted[s] = True
            s = parent[s]
    children = [[] for _ in range(m)]
    for s in np.flatnonzero(wanted):
        if parent[s] >= 0:
            children[parent[s]].append(s)
    pending = np.array([len(c) for c in children])
    by_owner: dict[int, list[int]] = {}
    for i, s in enumerate(owner):
        by_owner.setdefault(int(s), []).append(i)
    out: list[np.ndarray | None] = [None] * len(blocks)
    Y_clique: dict[int, np.ndarray] = {}     # Y over a visited supernode's clique, until its children took theirs
    stack = [s for s in np.flatnonzero(wanted) if parent[s] < 0]
    while stack:
        s = int(stack.pop())
        f, w = int(first[s]), int(width[s])
        C = clique[s]
        size = len(C)
        # L's columns of the supernode, dense (size x w): column f + i holds rows C[i:]
        Ls = np.zeros((size, w))
        for i in range(w):
            Ls[i:, i] = Lx[Lp[f + i]:Lp[f + i + 1]]
        L_JJ, L_SJ = Ls[:w], Ls[w:]
        L_inv = solve_triangular(L_JJ, np.eye(w), lower=True, unit_diagonal=True)
        Y = np.empty((size, size))
        Y_JJ = (L_inv.T / d[f:f + w]) @ L_inv
        if size > w:
            p = int(parent[s])
            P = clique[p]
            idx = np.searchsorted(P, C[w:])
            if np.any(idx >= len(P)) or np.any(P[np.minimum(idx, len(P) - 1)] != C[w:]):
                raise ValueError("L's pattern is not a filled graph's (a supernode's structure outside its "
                                 "parent's clique)")
            Y_SS = Y_clique[p][np.ix_(idx, idx)]
            pending[p] -= 1
            if not pending[p]:
                del Y_clique[p]
            Wt = solve_triangular(L_JJ, L_SJ.T, trans="T", lower=True, unit_diagonal=True)   # W^T, w x |S|
            Y_SJ = -Y_SS @ Wt.T
            Y_JJ = Y_JJ - Wt @ Y_SJ
            Y[w:, w:] = Y_SS
            Y[w:, :w] = Y_SJ
            Y[:w, w:] = Y_SJ.T
        Y[:w, :w] = 0.5 * (Y_JJ + Y_JJ.T)
        for i in by_owner.get(s, ()):
            at = np.minimum(np.searchsorted(C, blocks[i]), size - 1)
            if np.array_equal(C[at], blocks[i]):
                out[i] = Y[np.ix_(at, at)]
        if pending[s]:
            Y_clique[s] = Y
            stack.extend(children[s])
    return out


def inverse_columns(L: sps.csc_matrix, d: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Y's ``columns`` (n x len(columns)) by triangular solves: Y e = L^-T D^-1 L^-1 e."""
    E = np.zeros((L.shape[0], len(columns)))
    E[columns, np.arange(len(columns))] = 1.0
    w = spla.spsolve_triangular(L, E, lower=True, unit_diagonal=True)
    return spla.spsolve_triangular(L.T.tocsr(), w / d[:, None], lower=False, unit_diagonal=True)


def marginal_covariances(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int]) -> list[np.ndarray]:
    """Each variable of ``keys``' marginal covariance (its tangent's, as
    ``gtsam.Marginals(graph, values).marginalCovariance(key)``) at ``values``: the graph
    linearized, its normal matrix factorized once in GTSAM's COLAMD order and the keys' blocks
    of its inverse taken by selected inversion (:func:`selected_inverse_blocks`); GTSAM's
    Marginals should the factor's pattern not be a filled graph's (an entry SuperLU dropped)."""
    gfg = graph.linearize(values)
    cols = Columns.of(values)
    A, _ = sparse_system(gfg, cols)
    order = fill_reducing_order(gfg, cols)
    del gfg
    N, position = ordered_normal_matrix(A, order)
    del A                     # (A's and N's memory freed before the factor's copies, the peak)
    lu = normal_lu(N)
    del N
    L, d, position = ldl_of_lu(lu, position)
    del lu
    blocks = [position[cols.index([k])] for k in keys]
    # (a block's columns sorted in L's order; back to the key's own tangent order)
    try:
        out = selected_inverse_blocks(L, d, blocks)
    except ValueError:
        marginals = gtsam.Marginals(graph, values)
        return [marginals.marginalCovariance(k) for k in keys]
    result = []
    for b, Y in zip(blocks, out, strict=True):
        if Y is None:
            result.append(inverse_columns(L, d, b)[b])
            continue
        back = np.argsort(np.argsort(b))
        result.append(Y[np.ix_(back, back)])
    return result


__all__ = ["ldl_factor", "ldl_of_lu", "selected_inverse_blocks", "inverse_columns", "marginal_covariances"]
