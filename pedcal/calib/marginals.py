"""Marginal covariances of a few variables of a large linearized graph, by selected inversion of
its Bayes tree: the graph eliminated once by GTSAM's multifrontal Cholesky (in a COLAMD order),
and the blocks of the covariance Y = N^-1 (N = R^T R, the normal matrix) computed top-down over
the cliques that hold a requested variable and their ancestors (Takahashi's recurrences).

A clique's conditional holds its frontal variables F given its separator S (the variables of
its parent clique it depends on): R_FF x_F + S_FS x_S = d, R_FF upper triangular. Then, with
W = R_FF^-1 S_FS,

    Y_FS = -W Y_SS,   Y_FF = R_FF^-1 R_FF^-T - Y_FS W^T,

where S lies inside the parent clique (a Bayes tree's running intersection), so each clique
needs its parent's dense block of Y over the parent's frontal and separator variables, nothing
else. The cost is that of the ancestors' cliques: for the sensors of a large installation (near
the tree's root, the robot's path below them), a fraction of the elimination, where GTSAM's
per-key marginal re-eliminates its clique's path to the root for each key (quadratic in the
sensors), and a sparse LU of the normal matrix takes twice the work of the Cholesky.
"""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.linalg import solve_triangular


def tree_marginal_blocks(tree: gtsam.GaussianBayesTree, dims: dict[int, int], keys: list[int]) -> list[np.ndarray]:
    """Each of ``keys``' marginal covariance block (its tangent's, dims[key] square) from the
    Bayes tree ``tree`` of a linearized graph, by the recurrences of the module docstring over
    the cliques holding a key and their ancestors. The conditionals must be whitened (a graph
    without constrained noise models): a ValueError otherwise."""
    keys = [int(k) for k in keys]
    # the cliques to visit (by their first frontal key): those holding a key, up to the roots
    children: dict[int, list[int]] = {}
    conditional: dict[int, gtsam.GaussianConditional] = {}
    roots = []
    for key in dict.fromkeys(keys):
        clique, child = tree[key], None
        while True:
            cond = clique.conditional()
            first = cond.firstFrontalKey()
            new = first not in conditional
            if new:
                conditional[first], children[first] = cond, []
            if child is not None:
                children[first].append(child)
            if not new:
                break
            if clique.isRoot():
                roots.append(first)
                break
            clique, child = clique.parent(), first
    wanted = set(keys)
    found: dict[int, np.ndarray] = {}
    # Y over a visited clique's variables (frontal then separator) and each one's offset in it,
    # kept until its children took their separators' blocks
    Y_clique: dict[int, tuple[np.ndarray, dict[int, int]]] = {}
    pending = {first: len(c) for first, c in children.items()}
    stack = [(first, None) for first in roots]
    while stack:
        first, parent = stack.pop()
        cond = conditional.pop(first)
        model = cond.get_model()
        if model is not None and not np.allclose(model.sigmas(), 1.0):
            raise ValueError("a conditional carries a noise model (a constrained factor's): R and S are not whitened")
        variables = list(cond.keys())
        offset = np.r_[0, np.cumsum([dims[k] for k in variables])].astype(np.int64)
        R = cond.R()
        w = R.shape[0]
        n_frontal = int(np.searchsorted(offset, w))
        R_inv = solve_triangular(R, np.eye(w), lower=False)
        size = int(offset[-1])
        Y = np.empty((size, size))
        Y_FF = R_inv @ R_inv.T
        if size > w:
            Y_parent, at = Y_clique[parent]
            sep = variables[n_frontal:]
            idx = np.concatenate([np.arange(at[k], at[k] + dims[k]) for k in sep])
            Y_SS = Y_parent[np.ix_(idx, idx)]
            pending[parent] -= 1
            if not pending[parent]:
                del Y_clique[parent]
            W = R_inv @ cond.S()
            Y_FS = -W @ Y_SS
            Y_FF = Y_FF - Y_FS @ W.T
            Y[w:, w:] = Y_SS
            Y[:w, w:] = Y_FS
            Y[w:, :w] = Y_FS.T
        Y[:w, :w] = 0.5 * (Y_FF + Y_FF.T)
        for k, o in zip(variables[:n_frontal], offset[:n_frontal], strict=True):
            if k in wanted:
                found[k] = Y[o:o + dims[k], o:o + dims[k]].copy()
        if children[first]:
            Y_clique[first] = (Y, {k: int(o) for k, o in zip(variables, offset[:-1], strict=True)})
            stack.extend((child, first) for child in children[first])
    return [found[k] for k in keys]


def marginal_covariances(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int],
                         ordering: gtsam.Ordering | None = None) -> list[np.ndarray]:
    """Each variable of ``keys``' marginal covariance (its tangent's, as
    ``gtsam.Marginals(graph, values).marginalCovariance(key)``) at ``values``: the graph
    linearized and eliminated once (GTSAM's multifrontal Cholesky, COLAMD order), the keys'
    blocks taken by selected inversion of the Bayes tree (:func:`tree_marginal_blocks`). A
    variable of ``values`` that no factor holds (or a system GTSAM cannot eliminate) is a
    LinAlgError, as the normal matrix is then singular; GTSAM's Marginals should a conditional
    carry a noise model (a constrained factor's: :func:`tree_marginal_blocks` refuses it).
    ``ordering``: ``graph``'s COLAMD ordering when already computed (``graph.orderingCOLAMD()``,
    the same as of its linearization), else (or when it is not of the graph's variables) computed here."""
    gfg = graph.linearize(values)
    held = set(gfg.keyVector())
    free = [k for k in values.keys() if k not in held]
    if free:
        raise np.linalg.LinAlgError(f"the normal matrix is singular: {gtsam.DefaultKeyFormatter(free[0])} is a "
                                    "variable no factor holds")
    if ordering is not None and (ordering.size() != len(held)
                                 or {ordering.at(i) for i in range(ordering.size())} != held):
        ordering = None                     # (not exactly this graph's variables, once each: its own computed)
    try:
        tree = gfg.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(gfg) if ordering is None
                                         else ordering)
    except RuntimeError as e:               # (GTSAM's indeterminant system: a direction nothing holds)
        raise np.linalg.LinAlgError(f"the normal matrix is singular (a variable no factor holds): {e}") from e
    del gfg
    try:
        return tree_marginal_blocks(tree, {int(k): int(d) for k, d in values.dims().items()}, keys)
    except ValueError:
        marginals = gtsam.Marginals(graph, values)
        return [marginals.marginalCovariance(k) for k in keys]


__all__ = ["tree_marginal_blocks", "marginal_covariances"]
