"""Nuisance parameters that enter the measurements, estimated by their profile likelihood on the
factor graph linearized at its solution.

A nuisance theta (the head point's shift toward the sensor along the ray, its horizontal shift)
changes what the observation factors measure, not the graph's structure. Linearized at the
solution x*, the whitened residual is ``r(dx, dtheta) = A dx - b - B dtheta``: A and b are GTSAM's
linearization (``GaussianFactorGraph``, rows whitened), B the change of b with theta, a finite
difference of the observation block alone (:func:`pedcal.calib.graph.observation_block`).
Minimizing over dx for each dtheta, the profile, leaves

    dx(dtheta) = z0 + Z dtheta,   z0 = N^-1 A^T b,   Z = N^-1 A^T B,   N = A^T A,
    r_p(dtheta) = rho0 + M dtheta,   rho0 = A z0 - b,   M = A Z - B,

so the profile error 1/2 |r_p|^2 (GTSAM's error, chi^2 / 2) is quadratic in dtheta with gradient
M^T rho0 and Hessian M^T M, to which theta's prior adds. A and b come from GTSAM's linearization
(``GaussianFactorGraph.sparseJacobian_``), B's column j from the observation block rebuilt at
theta + h e_j; the k + 1 solves with N share one sparse factorization (CHOLMOD's supernodal
Cholesky of A^T A from A, :mod:`pedcal.calib.cholmod`, in a COLAMD order of the graph computed
once and kept across steps), a chord step's single solve takes one of its own. The Hessian's
inverse is theta's covariance, and Z carries it into every variable: the marginal over theta,
not the conditional at its estimate. z0 is the Gauss-Newton step at theta itself, which also
settles directions Levenberg-Marquardt barely moves along (a flat gauge held by weak priors only).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.sparse as sps
from scipy.sparse import _sparsetools


@dataclass
class Nuisance:
    """One nuisance parameter: its name (a keyword of the observation block's ``theta``), the
    prior's mean and sigma, and the finite-difference step of its profile (same unit)."""

    name: str
    prior_mean: float
    prior_sigma: float
    step: float


@dataclass
class Columns:
    """The linear system's columns: the variables in key order (GTSAM's order of
    ``sparseJacobian_`` and ``VectorValues.vector``), each ``dim`` wide from ``offset``."""

    keys: list[int]
    offset: dict[int, int]
    dim: dict[int, int]
    n: int

    @classmethod
    def of(cls, values: gtsam.Values) -> Columns:
        dims = values.dims()
        keys = sorted(dims)
        offset, n = {}, 0
        for k in keys:
            offset[k] = n
            n += int(dims[k])
        return cls(keys=keys, offset=offset, dim={k: int(dims[k]) for k in keys}, n=n)

    def _table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The keys (uint64), each one's first column and width (int64), in key order: worked
        out once and kept (the lookups of :meth:`index`, :meth:`spans`, fill_reducing_order)."""
        table = self.__dict__.get("_layout")
        if table is None:
            table = self.__dict__["_layout"] = (np.array(self.keys, np.uint64),
                                                np.array([self.offset[k] for k in self.keys], np.int64),
                                                np.array([self.dim[k] for k in self.keys], np.int64))
        return table

    def spans(self) -> tuple[list[int], list[int]]:
        """Each variable's first column and the column after its last, in key order (lists)."""
        _, starts, dims = self._table()
        return starts.tolist(), (starts + dims).tolist()

    def index(self, keys) -> np.ndarray:
        """Column indices of ``keys``' variables, concatenated."""
        keys = np.asarray(keys, np.uint64).reshape(-1)
        if len(keys) > 16:
            # many keys (a linearized graph's): looked up in the sorted key array, not one by one
            table = self._table()
            at = np.minimum(np.searchsorted(table[0], keys), len(table[0]) - 1)
            if len(table[0]) == 0 or np.any(table[0][at] != keys):
                raise KeyError(int(keys[np.flatnonzero(table[0][at] != keys)[0]]) if len(table[0]) else int(keys[0]))
            starts, dims = table[1][at], table[2][at]
        else:
            starts = np.array([self.offset[int(k)] for k in keys], np.int64)
            dims = np.array([self.dim[int(k)] for k in keys], np.int64)
        if not len(starts):
            return np.zeros(0, np.int64)
        # arange per key in one pass: each key's run starts at its offset
        first = np.cumsum(dims) - dims
        return np.repeat(starts - first, dims) + np.arange(int(dims.sum()))


def sparse_system(gfg: gtsam.GaussianFactorGraph, cols: Columns) -> tuple[sps.csr_matrix, np.ndarray]:
    """(A, b) of a linearized graph with the columns of ``cols`` (its own keys may be a subset)."""
    if gfg.size() == 0:
        return sps.csr_matrix((0, cols.n)), np.zeros(0)
    ijs = gfg.sparseJacobian_()          # 3 x entries, (row, column, value), 1-based, b as a last column
    m = int(ijs[0].max()) if ijs.shape[1] else 0      # (1-based: the row count)
    own = np.sort(np.asarray(gfg.keyVector(), np.uint64))
    # the graph's own columns (1-based, its keys in order) -> the system's, b's column -> cols.n
    local = cols.index(own)
    index_dtype = np.int32 if max(ijs.shape[1], cols.n + 1) < 2 ** 31 else np.int64     # (scipy's own choice)
    column = np.empty(len(local) + 2, index_dtype)
    column[0], column[1:-1], column[-1] = -1, local, cols.n
    # (compact arrays of the kept entries, the 3 x entries array dropped once they are taken: it and
    # its copies were the peak memory of a large graph's linearization; no copy of its values first)
    j = column[ijs[1].astype(np.int32)]
    i = ijs[0].astype(np.int32 if m < 2 ** 31 else np.int64)
    i -= 1
    rhs = j == cols.n
    b = np.bincount(i[rhs], weights=ijs[2][rhs], minlength=m)
    keep = ~rhs
    v = ijs[2][keep]
    del ijs, rhs
    i, j = i[keep], j[keep]
    del keep
    # (GTSAM lists a factor's entries variable by variable, so its rows are not in order: COO, made
    # CSR by scipy's own conversion into arrays of the final size, then its entries' columns put in
    # order in each row and duplicates summed, as csr_matrix((v, (i, j))) does)
    indptr = np.empty(m + 1, index_dtype)
    indices, data = np.empty(len(v), index_dtype), np.empty(len(v))
    _sparsetools.coo_tocsr(m, cols.n, len(v), i, j, v, indptr, indices, data)
    del i, j, v
    A = sps.csr_matrix((data, indices, indptr), shape=(m, cols.n), copy=False)
    A.sum_duplicates()
    return A, b


def fill_reducing_order(gfg, cols: Columns) -> np.ndarray:
    """A fill-reducing order of the system's columns: GTSAM's COLAMD ordering of the linearized
    graph's variables (``gfg``, a GaussianFactorGraph), or a given ``gtsam.Ordering`` of them
    (the nonlinear graph's COLAMD, :func:`pedcal.calib.graph.optimize_graph`'s: the same
    structure), each variable's columns together. It depends on the graph's structure alone, so
    one order serves every factorization of the same graph (the profile's steps)."""
    ordering = gfg if isinstance(gfg, gtsam.Ordering) else gtsam.Ordering.ColamdGaussianFactorGraph(gfg)
    keys = np.fromiter((ordering.at(i) for i in range(ordering.size())), np.uint64, ordering.size())
    own = cols._table()[0]
    keys = keys[np.isin(keys, own)]                    # (the system's variables only, in the order's sequence)
    missing = np.setdiff1d(own, keys)                  # variables no factor touches, last (sorted)
    return cols.index(np.r_[keys, missing])


def release_free_memory() -> None:
    """The C heap's free pages handed back to the system (glibc's ``malloc_trim``), before a
    large factorization: the linearizations and the solve before it free hundreds of MB in blocks
    that the allocator otherwise keeps resident, and the process's peak memory would be those on
    top of the factor's. Nothing where the C library has no ``malloc_trim``."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


def _malloc_trim():
    """glibc's ``malloc_trim`` (looked up once), or None."""
    if "trim" not in _MALLOC:
        try:
            import ctypes

            _MALLOC["trim"] = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _MALLOC["trim"] = None
    return _MALLOC["trim"]


_MALLOC: dict = {}

# the free memory is handed back before factorizing a system of at least this many entries in A
# (~12 MB; its factor is several times that); below, the pages taken back cost more than the
# peak they would spare (paper scene: a fraction of a factorization's milliseconds). Above, they
# cost too: the allocations after it fault the pages in again; a larger value trades the memory back
RELEASE_BEFORE_ENTRIES = 1_000_000


def ordered_normal_matrix(A: sps.spmatrix, order: np.ndarray) -> tuple[sps.csc_matrix, np.ndarray]:
    """The normal matrix A^T A with its columns in the fill-reducing ``order``
    (:func:`fill_reducing_order`), CSC: A's columns are renumbered into the order (its values
    shared, not copied), so that the normal matrix is formed permuted, no permuted copies of it.
    Returns (it, each column of A's position in it)."""
    from pedcal.calib.cholmod import renumbered

    A = sps.csr_matrix(A)
    indices, position = renumbered(A.indices, np.asarray(order, np.int64))
    A_ordered = sps.csr_matrix((A.data, indices, A.indptr), shape=A.shape)
    return (A_ordered.T @ A_ordered).tocsc(), position


def _superlu_normal_solver(A: sps.csr_matrix, order: np.ndarray | None = None):
    """The normal equations by SuperLU's LU of the formed A^T A, no pivoting (it is positive
    definite: the graph's priors hold every variable), in the fill-reducing ``order`` or SuperLU's
    minimum-degree one: where CHOLMOD cannot be loaded (:mod:`pedcal.calib.cholmod`)."""
    import scipy.sparse.linalg as spla

    if order is None:
        N, position = (A.T @ A).tocsc(), None
    else:
        N, position = ordered_normal_matrix(A, order)
    try:
        lu = spla.splu(N, permc_spec="MMD_AT_PLUS_A" if order is None else "NATURAL", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
    except RuntimeError as e:          # SuperLU: "Factor is exactly singular"
        raise np.linalg.LinAlgError(f"the normal matrix is not positive definite (a variable no factor holds): "
                                    f"{e}") from e

    def solve(y):
        y = np.asarray(y, float)
        return lu.solve(y) if order is None else lu.solve(y[order])[position]
    solve.factor_entries = int(lu.L.nnz)   # (L's, as CHOLMOD's counts: U mirrors it)
    return solve


def _normal_solver(A: sps.csr_matrix, order: np.ndarray | None = None):
    """A solver of the normal equations A^T A x = y: one sparse Cholesky factorization of A^T A
    from A itself (:class:`pedcal.calib.cholmod.NormalCholesky`, CHOLMOD's supernodal, its
    symbolic analysis reused by the next factorization of the same graph), in the fill-reducing
    column ``order`` (:func:`fill_reducing_order`) or, without one, CHOLMOD's own. Many
    right-hand sides go to it at once; where CHOLMOD cannot be loaded, SuperLU's LU
    (:func:`_superlu_normal_solver`). Its ``factor_entries``: the values stored in the factor,
    what holding it costs."""
    from pedcal.calib import cholmod

    if A.nnz >= RELEASE_BEFORE_ENTRIES:
        release_free_memory()
    if not cholmod.available():
        return _superlu_normal_solver(A, order)
    chol = cholmod.NormalCholesky(A, order)

    def solve(y):
        return chol.solve(y)
    solve.factor_entries = chol.factor_entries
    return solve


# A full profile step keeps its factorization for the chord steps that follow it up to this many
# values stored in L (CHOLMOD's supernodes, their padding included; 8 bytes each: 40 MB); a
# larger one is dropped with the step's solves, and a chord step takes a fresh one (the peak
# memory of a large graph is not raised)
KEEP_FACTOR_ENTRIES = 5_000_000


# a chord step's z0 by conjugate gradients to this relative residual: from the nearby factorization
# (residual ~5e-2) each iteration gains ~5x; at 1e-6 the calibration moves against 1e-10's by at
# most 3.7e-9 m (a sensor's position; median of the runs' largest 6e-10 m) and its sigmas by at
# most 1.6e-8 relative (paper, sparse, corridor, cross and the L-shaped hall, seeds 0-3, the
# factor graph's default recipe), with 7-9 preconditioner solves instead of 12-13
CHORD_RTOL = 1e-6


def _near_solve(A: sps.csr_matrix, y: np.ndarray, solve_near, rtol: float = CHORD_RTOL,
                max_iterations: int = 30) -> np.ndarray | None:
    """x with A^T A x = y by conjugate gradients on the normal equations preconditioned with
    ``solve_near`` (:func:`_normal_solver` of a nearby point's system, the same graph: its
    normal matrix differs by the Jacobians' change over a small step, so a few iterations
    converge), to a residual |y - A^T A x| <= ``rtol`` |y|; None without ``solve_near`` or
    when ``max_iterations`` do not reach it."""
    if solve_near is None:
        return None
    y = np.asarray(y, float)
    target = rtol * np.linalg.norm(y)
    x = solve_near(y)
    r = y - A.T @ (A @ x)
    z = solve_near(r)
    p, rz = z, float(r @ z)
    for _ in range(max_iterations + 1):
        if np.linalg.norm(r) <= target:
            return x
        Ap = A @ p
        pq = float(Ap @ Ap)
        if not pq > 0.0:
            return None
        alpha = rz / pq
        x = x + alpha * p
        r = r - alpha * (A.T @ Ap)
        z = solve_near(r)
        rz_next = float(r @ z)
        p, rz = z + (rz_next / rz) * p, rz_next
    return None


@dataclass
class LocalProfile:
    """Nuisances each entering the rows of one variable alone (a sensor's clock offset, its own
    robot observations): nuisance i's step ``dtheta[i]`` (the joint Gauss-Newton step's, exact),
    and from its own profile with everything but its variable held its variance ``variance[i]``
    (the local Hessian's inverse), its variable's ``columns[i]`` and sensitivity ``Z[i]``
    (tangent per unit of the nuisance, that variable alone): their coupling through the other
    variables (a sensor's offset through the robot's path it shares with others) is left out of
    the sigma."""

    dtheta: np.ndarray
    variance: np.ndarray
    Z: np.ndarray
    columns: np.ndarray


@dataclass
class ProfileStep:
    """One profile of the nuisances at a linearization point: the Newton step ``dtheta`` of the
    (quadratic) profile, its Hessian (chi^2 / 2 units: theta's information), the Gauss-Newton step
    ``z0`` of the variables at theta and their sensitivity ``Z`` (n x k, tangent per unit of
    theta), both in the columns of ``cols``."""

    dtheta: np.ndarray
    hessian: np.ndarray
    z0: np.ndarray
    Z: np.ndarray
    cols: Columns
    order: np.ndarray | None = None   # the fill-reducing column order its factorization used
    # the system's A (fixed, observation, plain rows) and the right-hand side's change with
    # theta B (same rows, k columns, sparse): the profile residual's change M = A Z - B
    A: sps.csr_matrix | None = None
    B: sps.csc_matrix | None = None
    local: LocalProfile | None = None   # the nuisances profiled locally (``profile_step``'s ``local``)
    rho0: np.ndarray | None = None      # the profile residual at theta (A's rows), of a full step

    def local_step(self) -> np.ndarray:
        """The local nuisances' step at this step's ``dtheta`` (of a step with ``local``): the
        joint Gauss-Newton optimum's rows of z0 + Z dtheta beyond the variables' (``cols.n``)."""
        n = self.cols.n
        return self.z0[n:] + self.Z[n:] @ self.dtheta

    def select(self, keep: np.ndarray) -> ProfileStep:
        """The step restricted to the nuisances ``keep`` (their Hessian's rows and columns, Z's
        and B's columns; dtheta as it was: the caller takes its own)."""
        out = ProfileStep(dtheta=self.dtheta[keep], hessian=self.hessian[np.ix_(keep, keep)], z0=self.z0,
                          Z=self.Z[:, keep], cols=self.cols, order=self.order, A=self.A,
                          B=None if self.B is None else self.B[:, keep], local=self.local, rho0=self.rho0)
        if "_normal_solve" in self.__dict__:      # (the same system: its factorization serves both)
            out.__dict__["_normal_solve"] = self.__dict__["_normal_solve"]
        return out

    @property
    def covariance(self) -> np.ndarray:
        """theta's covariance, the Hessian's inverse (kept: read once per nuisance and step)."""
        cached = self.__dict__.get("_covariance")
        if cached is None or cached[0] is not self.hessian:
            cached = self.__dict__["_covariance"] = (self.hessian, np.linalg.inv(self.hessian))
        return cached[1]


def _factor_rows(graph: gtsam.NonlinearFactorGraph) -> np.ndarray:
    """Start row of every factor of ``graph`` in its linearization, and the end. Kept per graph
    object while it lives and keeps its size (the profile's steps take the same observation block
    again; asking each of 60 000 factors its dimension took 0.1 s a step): a block is rebuilt, not
    edited in place, when the nuisances move."""
    hit = _FACTOR_ROWS.get(id(graph))
    if hit is not None and hit[0]() is graph and len(hit[1]) == graph.size() + 1:
        return hit[1]
    rows = np.r_[0, np.cumsum([graph.at(i).dim() for i in range(graph.size())])].astype(np.int64)
    try:
        key = id(graph)
        _FACTOR_ROWS[key] = (weakref.ref(graph, lambda _, k=key: _FACTOR_ROWS.pop(k, None)), rows)
    except TypeError:               # (no weak reference to it: not kept)
        pass
    return rows


_FACTOR_ROWS: dict = {}


def sqrt_weights(reweighted_norm: np.ndarray, kernel: str, k: float) -> np.ndarray | None:
    """Square roots of robust weights from the norms of GTSAM's reweighted whitened residuals
    (sqrt(w(e)) e per factor), for kernels where that map can be undone: Huber (w = 1 up to k,
    then k / e, so sqrt(w) e = sqrt(k e)), Cauchy (w = 1 / (1 + e^2 / k^2), so (sqrt(w) e)^2 =
    e^2 w and w = 1 - (sqrt(w) e)^2 / k^2) and none; None otherwise (Tukey's is not one-to-one)."""
    b = np.asarray(reweighted_norm, float)
    kernel = kernel.lower()
    if kernel == "none":
        return np.ones(len(b))
    if kernel == "huber":
        return np.where(b <= k, 1.0, k / np.maximum(b, 1e-300))
    if kernel == "cauchy":
        return np.sqrt(np.clip(1.0 - (b / k) ** 2, 1e-12, 1.0))
    return None


def takes_chord(previous: ProfileStep | None, local) -> bool:
    """Whether :func:`profile_step` given ``previous`` and ``local`` (and its ``residuals``) takes a
    chord step (the previous full step's Hessian and sensitivities, this point's gradient from
    this point's B): with a previous step that kept its system, and no local nuisances (with them
    every step is a full one: the system they join changes with their B)."""
    return previous is not None and previous.A is not None and (local is None or len(local) == 0)


def profile_step(fixed: gtsam.NonlinearFactorGraph, observations, values: gtsam.Values, theta: np.ndarray,
                 nuisances: list[Nuisance], cols: Columns | None = None, obs0=None,
                 kernel: tuple[str, float] = ("none", 0.0), plain_leading: int = 0,
                 plain=None, previous: ProfileStep | None = None,
                 order: np.ndarray | None = None, residuals=None, footprint: dict | None = None,
                 local: np.ndarray | None = None, factor_rows: np.ndarray | None = None,
                 obs_linear=None) -> ProfileStep:
    """The profile of ``nuisances`` at ``theta`` around ``values``. ``fixed``: the factors theta
    does not enter; ``observations(theta, sigma_scale)``: the factors it enters, built at that
    theta with their robust kernels (``sigma_scale`` None) or with each factor's sigmas scaled
    instead; ``obs0``: those factors at ``theta`` when already built. B is taken with each
    factor's robust weight w frozen at ``theta`` (the weights of GTSAM's linearization, which A
    carries: the factors built with sigmas / sqrt(w) and no kernel), so the profile's gradient is
    exactly the robust error's, sum w e de/dtheta. The weights come from the linearization itself
    (:func:`sqrt_weights`, ``kernel`` = (name, k) of the observation factors, the first
    ``plain_leading`` of which have no kernel), or, for a kernel that cannot be undone, from the
    factors built once more without it.

    ``plain``: optionally ``(indices, residuals(theta), linear())``, factors without a robust
    kernel that only the nuisances at ``indices`` enter (the odometry, whose calibration they
    correct): B's columns of those nuisances are taken from these factors alone, the
    observations' for the others. ``residuals(theta)`` is their linearization's right-hand side
    at ``values`` (:class:`pedcal.calib.graph.MotionRhs`), ``linear()`` their linearization at
    ``values`` and ``theta`` as (A, b) in ``cols`` (:meth:`pedcal.calib.graph.MotionRhs.linearized`);
    no factors are built, so ``order`` must be given with it (the first step's order is
    computed from GTSAM's linearized blocks).

    ``previous``: a step taken at a nearby point (the one before, a few of theta's sigma away):
    its Hessian and sensitivity Z are kept and only the variables' step z0 and the gradient (B's
    finite differences at this point) are taken here (a chord step of Newton's method: one solve
    instead of k + 1). Only with ``residuals`` (a gradient from the previous step's B settled
    elsewhere than the profile's optimum).

    ``order``: the fill-reducing column order of an earlier step on the same graph (its
    ``order``), so that the ordering is computed once per graph, not once per step.

    ``residuals(theta, sigma_scale)``: optionally, the right-hand side b of the observation
    factors' linearization at ``values`` (b = -whitened error, sigmas scaled, no kernel) computed
    without building them (:class:`pedcal.calib.graph.ObservationRhs`): B's columns are then
    its differences at theta + h and theta under the same weights, and ``observations`` is
    called for nothing but ``obs0`` when that is not given. ``footprint``: optionally, per
    nuisance index, the observation factors (indices in the block) it alone enters, such as a
    sensor's clock offset its own observations: nuisances whose footprints do not overlap are
    moved together in one ``residuals`` call, each taking the difference on its own factors'
    rows (a column grouping of the finite differences; the rows outside every footprint of a
    group are checked to stay put, else its nuisances are taken one by one).

    ``local``: optionally (m, d) column indices, one row per each of the last m ``nuisances``:
    nuisances that enter the rows of that one variable alone (a sensor's clock offset, its own
    robot observations; their ``footprint`` given). The others are profiled exactly, these held;
    they join the variables as m more columns of the sparse system (one factorization, their
    step the joint Gauss-Newton step's: the profile's optimum), the others are profiled over
    them, and each one's sigma comes from its own profile with every other variable held
    (:class:`LocalProfile`, :func:`_local_profile`): d x d solves instead of m more right-hand
    sides through the whole graph and an m x m Hessian. The step's ``dtheta``, ``hessian`` and
    ``Z`` are the others' (z0 and Z with m rows more, the local nuisances' joint step and
    sensitivity after the variables': :meth:`ProfileStep.local_step`); ``local`` carries these.

    ``factor_rows``: optionally, the start row of each observation factor in the block's
    linearization and the end (:meth:`pedcal.calib.graph.ObservationRhs.factor_rows`), which is
    otherwise asked of each factor (taken only when its end is the block's row count).

    ``obs_linear()``: optionally, the observation factors' linearization at ``values`` as (A, b)
    in ``cols`` (:meth:`pedcal.calib.graph.ObservationRhs.linearized`: no factors made), taken
    instead of ``obs0``'s, which may then be None; not asked when the first step's order is
    computed here (from the linearized blocks).

    M = A Z - B (rows x k) is never formed: with N Z = A^T B, M^T M = B^T B - (A^T B)^T Z and
    M^T r = Z^T A^T r - B^T r."""
    cols = cols or Columns.of(values)
    k = len(nuisances)
    m_local = 0 if local is None else len(local)
    k_exact = k - m_local                 # the nuisances profiled exactly lead
    chord = residuals is not None and takes_chord(previous, local)
    plain_idx, plain_residuals, plain_linear = plain if plain is not None else ((), None, None)
    # the blocks linearized one at a time, each graph dropped once in its (A, b) (its dense
    # Jacobian blocks are a few times A's size), but for the first step's fill-reducing order
    need_order = order is None or len(order) != cols.n
    assert plain is None or not need_order, "plain factors are not built: the order must be given"
    lin = gtsam.GaussianFactorGraph() if need_order else None

    def linear(graph):
        g = graph.linearize(values)
        if lin is not None:
            lin.push_back(g)
        return sparse_system(g, cols)

    A_f, b_f = linear(fixed)
    if obs_linear is not None and lin is None:
        A_o, b_o0 = obs_linear()
    else:
        obs0 = obs0 if obs0 is not None else observations(theta, None)
        A_o, b_o0 = linear(obs0)
    if plain is not None:
        A_p, b_p0 = plain_linear()
    else:
        A_p, b_p0 = sps.csr_matrix((0, cols.n)), np.zeros(0)
    mean = np.array([nu.prior_mean for nu in nuisances[:k_exact]])
    info = np.diag([1.0 / nu.prior_sigma ** 2 for nu in nuisances[:k_exact]])
    # the k + 1 solves share the normal matrix N = A^T A (the systems differ in right-hand sides
    # only): one sparse factorization, then z0 = N^-1 A^T b and Z = N^-1 A^T B
    if need_order:
        order = fill_reducing_order(lin, cols)
        lin = None
    n_f = A_f.shape[0]
    n_rows = n_f + A_o.shape[0] + A_p.shape[0]
    if m_local:
        # (stacked into the joint system below, with the local nuisances' columns: no stacked
        # copy of A first, 60 MB at 1000 sensors)
        A, blocks = None, [A_f, A_o, A_p]
    else:
        A, blocks = sps.vstack([A_f, A_o, A_p], format="csr"), None
    A_f = A_o = A_p = None
    b = np.r_[b_f, b_o0, b_p0]
    if chord:
        # z0 alone: by conjugate gradients preconditioned with the full step's factorization (a
        # nearby point's normal matrix), a fresh factorization only should they not converge
        y = A.T @ b
        z0 = _near_solve(A, y, previous.__dict__.get("_normal_solve"))
        if z0 is None:
            z0 = _normal_solver(A, order)(y)
        rho0 = A @ z0 - b
    elif not m_local:
        solve = _normal_solver(A, order)
    theta = np.asarray(theta, float)
    # each factor's robust weight at theta (GTSAM reweights a factor's rows by sqrt(w))
    given = (factor_rows is not None and (obs0 is None or len(factor_rows) == obs0.size() + 1)
             and factor_rows[-1] == len(b_o0))
    rows = (np.asarray(factor_rows, np.int64) if given
            else _factor_rows(obs0 if obs0 is not None else observations(theta, None)))
    n_rob = np.sqrt(np.add.reduceat(b_o0 ** 2, rows[:-1])) if len(b_o0) else np.zeros(0)
    sqrt_w = sqrt_weights(n_rob, *kernel)
    if sqrt_w is None:
        b_plain0 = (residuals(theta, np.ones(len(rows) - 1)) if residuals is not None else
                    sparse_system(observations(theta, np.ones(len(rows) - 1)).linearize(values), cols)[1])
        n_plain = np.sqrt(np.add.reduceat(b_plain0 ** 2, rows[:-1])) if len(b_o0) else np.zeros(0)
        sqrt_w = np.where(n_plain > 1e-12, n_rob / np.maximum(n_plain, 1e-300), 1.0)
    sqrt_w[:plain_leading] = 1.0
    if residuals is not None:
        # no factors are built: the weights exact, and b at theta under them the reference
        scale = 1.0 / np.maximum(sqrt_w, 1e-12)
        b_ref = residuals(theta, scale)
    else:
        # quantized to 0.1 % so that factors of equal range and weight share a noise model
        scale = np.exp(np.round(np.log(1.0 / np.maximum(sqrt_w, 1e-12)) / 1e-3) * 1e-3)
        b_ref = b_o0
    # B's columns as (rows, values) of the observation and plain blocks: the factors at theta + h
    # with the weights frozen (sigmas / sqrt(w), no kernel) have A's rows and the right-hand side
    # b0 + h B_j
    columns: list = [(np.zeros(0, np.int64), np.zeros(0))] * k
    moved = [j for j in range(k) if j not in plain_idx]
    b_p_ref = plain_residuals(theta) if len(plain_idx) else b_p0
    for j in plain_idx:
        th = np.array(theta, float)
        th[j] += nuisances[j].step
        d = (plain_residuals(th) - b_p_ref) / nuisances[j].step
        columns[j] = (np.flatnonzero(d) + len(b_o0), d[d != 0.0])
    if residuals is not None:
        for group in _disjoint_groups(moved, footprint or {}):
            th = np.array(theta, float)
            for j in group:
                th[j] += nuisances[j].step
            d = residuals(th, scale) - b_ref
            if len(group) > 1:
                # the group's rows at once, nuisance by nuisance (each one's factors' rows in its
                # footprint's order): one pass for all its nuisances, not one per nuisance
                own, member = _group_rows([footprint[j] for j in group], rows)
                outside = np.ones(len(d), bool)
                outside[own] = False
                if np.any(d[outside] != 0.0):        # a footprint was wrong: one by one
                    for j in group:
                        th = np.array(theta, float)
                        th[j] += nuisances[j].step
                        dj = (residuals(th, scale) - b_ref) / nuisances[j].step
                        columns[j] = (np.flatnonzero(dj), dj[dj != 0.0])
                    continue
                dj = d[own] / np.array([nuisances[j].step for j in group])[member]
                nonzero = dj != 0.0
                own, dj = own[nonzero], dj[nonzero]
                bounds = np.searchsorted(member[nonzero], np.arange(len(group) + 1))
                for g, j in enumerate(group):
                    columns[j] = (own[bounds[g]:bounds[g + 1]], dj[bounds[g]:bounds[g + 1]])
            else:
                dj = d / nuisances[group[0]].step
                columns[group[0]] = (np.flatnonzero(dj != 0.0), dj[dj != 0.0])
    else:
        for j in moved:
            th = np.array(theta, float)
            th[j] += nuisances[j].step
            d = (sparse_system(observations(th, scale).linearize(values), cols)[1] - b_ref) / nuisances[j].step
            columns[j] = (np.flatnonzero(d), d[d != 0.0])
    lengths = [len(c[0]) for c in columns]
    B = sps.csc_matrix((np.concatenate([c[1] for c in columns]) if k else np.zeros(0),
                        (n_f + np.concatenate([c[0] for c in columns]).astype(np.int64) if k else np.zeros(0, int),
                         np.repeat(np.arange(k), lengths))), shape=(n_rows, k))
    if chord:
        # the gradient exact, -B^T rho0 with this point's B and weights (A^T rho0 = 0 at z0): the
        # chord's fixed point is the profile's optimum; only the Hessian is the full step's
        grad = -(B.T @ rho0) + info @ (theta[:k_exact] - mean)
        return ProfileStep(dtheta=-np.linalg.solve(previous.hessian, grad), hessian=previous.hessian, z0=z0,
                           Z=previous.Z, cols=cols, order=order, A=previous.A, B=B)
    columns = None                # (B holds them: 10 MB at 1000 sensors, not kept through the factorization)
    B, B_local = B[:, :k_exact], B[:, k_exact:]
    local_cols = None
    if m_local:
        # the local nuisances join the variables: columns -B_local (r = A dx - b - B dtheta) and
        # their priors' rows; the joint Gauss-Newton step moves them with the variables (the
        # profile's optimum, exactly), and the exact nuisances are profiled over them too
        local_cols = np.asarray(local, np.int64)
        sigma = np.array([nu.prior_sigma for nu in nuisances[k_exact:]])
        mean_l = np.array([nu.prior_mean for nu in nuisances[k_exact:]])
        n = cols.n
        prior = sps.csr_matrix((1.0 / sigma, (np.arange(m_local), n + np.arange(m_local))),
                               shape=(m_local, n + m_local))
        A_joint = _joint_system(blocks, -B_local, prior)
        blocks = None             # (A_joint holds them: its first n columns, its prior rows zero there)
        b_joint = np.r_[b, -(theta[k_exact:] - mean_l) / sigma]
        B_joint = sps.vstack([B, sps.csc_matrix((m_local, k_exact))], format="csc")
        solve = _normal_solver(A_joint, _with_local_columns(order, local_cols, n))
        z_joint, Z_joint, AtB = _gauss_newton_and_sensitivity(solve, A_joint, b_joint, B_joint)
        rho0 = A_joint @ z_joint - b_joint
        solve = None              # (its factors, the step's largest memory, freed before the local profiles)
        BtB = np.asarray((B.T @ B).todense()).reshape(k_exact, k_exact)
        MtM = BtB - AtB.T @ Z_joint
        step = ProfileStep(dtheta=np.zeros(k_exact), hessian=0.5 * (MtM + MtM.T) + info, z0=z_joint, Z=Z_joint,
                           cols=cols, order=order, A=A_joint, B=B_joint)
    else:
        z0, Z, AtB = _gauss_newton_and_sensitivity(solve, A, b, B)
        rho0 = A @ z0 - b
        # the profile residual r_p = rho0 + M dtheta, M = A Z - B, by its products with N Z = A^T B
        BtB = np.asarray((B.T @ B).todense()).reshape(k_exact, k_exact)
        MtM = BtB - AtB.T @ Z
        step = ProfileStep(dtheta=np.zeros(k_exact), hessian=0.5 * (MtM + MtM.T) + info, z0=z0, Z=Z, cols=cols,
                           order=order, A=A, B=B)
        if solve.factor_entries <= KEEP_FACTOR_ENTRIES:
            # (kept for a chord step's solve: below this size the factor's memory is small)
            step.__dict__["_normal_solve"] = solve
    grad = _residual_change_t(step, rho0) + info @ (theta[:k_exact] - mean)
    step.dtheta = -np.linalg.solve(step.hessian, grad)
    step.rho0 = rho0
    if m_local:
        # the local nuisances' step: the joint optimum's at the exact ones' step; their sigma and
        # their sensors' sensitivity from their own profiles (the path held)
        step.local = _local_profile(step.A, sps.vstack([B_local, sps.csc_matrix((m_local, m_local))], format="csc"),
                                    local_cols, nuisances[k_exact:])
        # (z0 and Z keep their rows beyond the variables', the local nuisances': a selection that
        # drops or maps exact nuisances after this step, the curvature or the head profile's
        # shape, maps them alike, and the local step is the joint optimum's at the kept ones')
        step.local.dtheta = step.local_step()
        # (no chord step follows one with local nuisances: its system, the largest memory it holds, goes)
        step.A = step.B = None
    return step


# the profile's right-hand sides are solved this many at a time: the solver's dense copies of
# them (permuted in, solved, permuted back) stay a few MB rather than several n x k arrays (160
# sensors' clock offsets and head shift departures profiled exactly: k ~ 330, 80 MB each, the
# step's peak memory); CHOLMOD's supernodal solve is as fast per column from a few dozen on
SOLVE_COLUMNS = 32


def _gauss_newton_and_sensitivity(solve, A: sps.csr_matrix, b: np.ndarray,
                                  B: sps.csc_matrix) -> tuple[np.ndarray, np.ndarray, sps.csc_matrix]:
    """z0 = N^-1 A^T b and Z = N^-1 A^T B (n x k) with the normal matrix's ``solve``
    (:func:`_normal_solver`), the k + 1 right-hand sides a chunk of SOLVE_COLUMNS at a time:
    (z0, Z, A^T B sparse, each of its columns a nuisance's footprint on the variables)."""
    AtB = sps.csc_matrix(A.T @ B)
    n, k = AtB.shape
    z0, Z = np.empty(n), np.empty((n, k))
    for lo in range(0, k + 1, SOLVE_COLUMNS):          # (column 0: A^T b, column j: A^T B's j - 1)
        hi = min(lo + SOLVE_COLUMNS, k + 1)
        first = int(lo == 0)
        rhs = np.empty((n, hi - lo), order="F")      # (column-major: the solver's layout, not copied into it)
        if first:
            rhs[:, 0] = A.T @ b
        rhs[:, first:] = AtB[:, lo + first - 1:hi - 1].toarray()
        out = np.asarray(solve(rhs)).reshape(n, hi - lo)
        if first:
            z0[:] = out[:, 0]
        Z[:, lo + first - 1:hi - 1] = out[:, first:]
    return z0, Z, AtB


def _joint_system(A, C: sps.spmatrix, prior: sps.csr_matrix) -> sps.csr_matrix:
    """[[A, C], [prior]] in CSR, assembled row by row from A's and C's CSR arrays (no COO round
    trip: A has millions of entries): each row's A entries, then its C entries (columns n + j).
    ``A``: one matrix, or a list of row blocks stacked in order (no stacked copy of them first)."""
    blocks = [sps.csr_matrix(a) for a in (A if isinstance(A, (list, tuple)) else [A])]
    C = sps.csr_matrix(C)
    n = blocks[0].shape[1]
    m = sum(a.shape[0] for a in blocks)
    count_a = np.concatenate([np.diff(a.indptr) for a in blocks])
    count_c = np.diff(C.indptr)
    indptr = np.r_[0, np.cumsum(count_a + count_c)]
    nnz = int(indptr[-1])
    indices = np.empty(nnz + prior.nnz, np.int32 if max(nnz + prior.nnz, n + C.shape[1]) < 2 ** 31 else np.int64)
    data = np.empty(nnz + prior.nnz)
    row = 0
    for a in blocks:
        rows = slice(row, row + a.shape[0])
        start, c_first, c_end = int(indptr[row]), int(C.indptr[row]), int(C.indptr[row + a.shape[0]])
        row += a.shape[0]
        if c_first == c_end:
            # rows without C entries (the fixed factors'): the block's arrays in one piece
            indices[start:start + a.nnz], data[start:start + a.nnz] = a.indices, a.data
            continue
        # destination of each of the block's A entries: its own index in the block shifted by the
        # block's C entries of the rows before its row (C's: by the block's A entries of the rows
        # up to and including its row), from the block's first entry on (per block, not over all
        # of A: index arrays of a block's size, not of millions of entries)
        dtype = indptr.dtype
        at = np.repeat((C.indptr[rows] - c_first).astype(dtype), np.diff(a.indptr))
        at += np.arange(start, start + a.nnz, dtype=dtype)
        indices[at], data[at] = a.indices, a.data
        at = np.repeat(a.indptr[1:].astype(dtype), count_c[rows])
        at += np.arange(start, start + c_end - c_first, dtype=dtype)
        indices[at], data[at] = C.indices[c_first:c_end] + n, C.data[c_first:c_end]
    prior = sps.csr_matrix(prior)
    indices[nnz:], data[nnz:] = prior.indices, prior.data
    indptr = np.r_[indptr, nnz + prior.indptr[1:]]
    return sps.csr_matrix((data, indices, indptr), shape=(m + prior.shape[0], n + C.shape[1]))


def _with_local_columns(order: np.ndarray, local_cols: np.ndarray, n: int) -> np.ndarray:
    """The fill-reducing ``order`` of n columns with column n + i (local nuisance i) placed just
    before the first of its variable's ``local_cols[i]``: it touches that variable's rows alone, so
    it adds one column to that variable's clique and no fill elsewhere."""
    position = np.empty(n, np.int64)
    position[order] = np.arange(n)
    key = np.r_[2 * np.arange(n), 2 * position[local_cols].min(axis=1) - 1]
    return np.r_[order, n + np.arange(len(local_cols))][np.argsort(key, kind="stable")]


def _local_profile(A: sps.csr_matrix, B: sps.csc_matrix, columns: np.ndarray,
                   nuisances: list[Nuisance]) -> LocalProfile:
    """Each nuisance i's (B's column i, nonzero on its own rows) variance and sensitivity in its
    own profile, with only its own variable (``columns[i]``, d wide) free and every other held:
    with A_i = A's columns of that variable and N_i = A_i^T A_i (all its rows: its priors too),
    Z_i = N_i^-1 A_i^T B_i, M_i = A_i Z_i - B_i and the Hessian M_i^T M_i = B_i^T B_i - (A_i^T
    B_i) . Z_i plus the prior's information (:func:`profile_step`'s module docstring with k = 1
    and the variables reduced to one). All m at once: batched d x d solves. (``dtheta`` is left
    at 0 for the caller.)"""
    m, d = columns.shape
    # the distinct variables (a sensor's clock offset and its own shift departure share its pose)
    # and each nuisance's among them: each variable's columns taken once (scipy's column
    # selection: no copy of all of A), its N_i formed once
    variables, of = np.unique(columns, axis=0, return_inverse=True)
    of = of.reshape(-1)
    A_l = sps.csr_matrix(A)[:, variables.ravel()].tocsc()
    G = (A_l.T @ A_l).tocoo()
    own = G.row // d == G.col // d
    N = np.zeros((len(variables), d, d))
    N[G.row[own] // d, G.row[own] % d, G.col[own] % d] = G.data[own]
    C = (A_l.T @ B).tocoo()                                # A_i^T B_i: column i's own variable's rows
    own = C.row // d == of[C.col]
    AtB = np.zeros((m, d))
    AtB[C.col[own], C.row[own] % d] = C.data[own]
    Z = np.linalg.solve(N[of], AtB[:, :, None])[:, :, 0]
    prior_info = np.array([1.0 / nu.prior_sigma ** 2 for nu in nuisances])
    hessian = np.asarray(B.multiply(B).sum(axis=0)).ravel() - np.einsum("id,id->i", AtB, Z) + prior_info
    return LocalProfile(dtheta=np.zeros(m), variance=1.0 / hessian, Z=Z, columns=columns)


def _residual_change_t(step: ProfileStep, r: np.ndarray) -> np.ndarray:
    """M^T r for the step's M = A Z - B (never formed): Z^T (A^T r) - B^T r."""
    return step.Z.T @ (step.A.T @ r) - step.B.T @ r


def _group_rows(footprints: list, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The system rows of each footprint's factors (``rows``: each factor's first row, and the
    end), each footprint's factors in its order, the footprints concatenated in theirs; and for
    each row the index of its footprint (at least one footprint)."""
    factors = [np.asarray(f, np.int64).reshape(-1) for f in footprints]
    all_factors = np.concatenate(factors)
    starts = rows[all_factors]
    lengths = rows[all_factors + 1] - starts
    first = np.cumsum(lengths) - lengths              # each factor's first place among the rows returned
    own = np.repeat(starts - first, lengths) + np.arange(int(lengths.sum()))
    member = np.repeat(np.repeat(np.arange(len(factors)), [len(f) for f in factors]), lengths)
    return own, member


def _disjoint_groups(indices: list[int], footprint: dict) -> list[list[int]]:
    """``indices`` in groups whose footprints do not overlap (greedy, in order); an index without
    a footprint is a group of its own."""
    groups, used = [], []
    for j in indices:
        if j not in footprint:
            groups.append([j])
            used.append(None)
            continue
        mine = set(np.asarray(footprint[j]).tolist())
        for g, u in zip(groups, used, strict=True):
            if u is not None and not (u & mine):
                g.append(j)
                u |= mine
                break
        else:
            groups.append([j])
            used.append(mine)
    return groups


# GTSAM's eliminations of a linearized graph (a Gauss-Newton iteration's, the joint marginal's
# partial one) run sequentially (Cholesky, one variable at a time) up to this many variables,
# multifrontally (dense frontal blocks) above. One Gauss-Newton iteration at the final point, the
# same COLAMD ordering, one BLAS thread, CPU ms, fastest of 7 (of 3 at 1000 sensors): paper seed 0
# (2076 variables) 19.1 sequentially against 22.3 multifrontally, corridor seed 1 (2532) 26.0
# against 30.1, 40 synthetic sensors (1365) 16.4 against 18.9, 160 (4959) 86.6 against 91.8, 1000
# (29 181) 743-803 against 734-736; the joint marginal of the sensors, paper 19.3-19.9 against
# 22.1-22.9, 160 synthetic sensors 177-181 against 183-188
SEQUENTIAL_MAX_VARIABLES = 10_000


def linear_solver(n_variables: int) -> str:
    """GTSAM's linear solver for a graph of ``n_variables`` (SEQUENTIAL_MAX_VARIABLES)."""
    return "SEQUENTIAL_CHOLESKY" if n_variables <= SEQUENTIAL_MAX_VARIABLES else "MULTIFRONTAL_CHOLESKY"


def joint_marginal_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int]) -> np.ndarray:
    """The joint covariance of the variables ``keys`` (their tangents, in the order given) at
    ``values``: every other variable eliminated by GTSAM's partial elimination (in a COLAMD order
    with the kept ones constrained last; sequential or multifrontal by the graph's size,
    :func:`linear_solver`), the Schur complement it leaves on the kept ones (their marginal
    information) inverted by Cholesky. Equal to ``gtsam.Marginals(...).jointMarginalCovariance(keys)``
    and, for hundreds of sensors, several times faster (500 sensors: 13 s -> 3 s)."""
    from scipy.linalg import cho_factor, cho_solve

    gfg = graph.linearize(values)
    kept = set(keys)
    full = gtsam.Ordering.ColamdConstrainedLastGaussianFactorGraph(gfg, gtsam.KeyVector(keys))
    others = gtsam.Ordering([k for k in map(full.at, range(full.size())) if k not in kept])
    if linear_solver(values.size()) == "SEQUENTIAL_CHOLESKY":
        _, rest = gfg.eliminatePartialSequential(others)
    else:
        _, rest = gfg.eliminatePartialMultifrontal(others)
    info, _ = rest.hessian()                 # columns: the kept keys in key order
    dims = values.dims()
    order = sorted(int(k) for k in rest.keyVector())
    offset = np.r_[0, np.cumsum([dims[k] for k in order])]
    at = {k: offset[i] for i, k in enumerate(order)}
    idx = np.concatenate([np.arange(at[k], at[k] + dims[k]) for k in keys])
    info = info[np.ix_(idx, idx)]
    return cho_solve(cho_factor(0.5 * (info + info.T)), np.eye(len(idx)))


def retract_flat(values: gtsam.Values, delta: np.ndarray, cols: Columns) -> gtsam.Values:
    """``values`` moved by the tangent vector ``delta`` laid out in ``cols``."""
    vv = gtsam.VectorValues()
    insert = vv.insert
    for key, start, end in zip(cols.keys, *cols.spans(), strict=True):
        insert(key, delta[start:end])
    return values.retract(vv)


def gauss_newton_step(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
    """``values`` after one Gauss-Newton step on ``graph`` (exact along directions the graph is
    quadratic in, such as a gauge held by priors alone)."""
    return values.retract(graph.linearize(values).optimize())


def steps_to_come_below(u: np.ndarray, rate: float | None, tolerance: float) -> bool | None:
    """Whether the steps still to come of an iteration contracting at ``rate`` are all below
    ``tolerance``: with theta = ``rate`` (this step's length over the last one's, each in its
    variables' sigmas, as the caller measures it), the geometric series theta / (1 - theta) of
    this step ``u``, component by component (the stopping rule of simplified Newton iterations,
    Hairer & Wanner, Solving ODEs II, IV.8). None where there is no contraction to measure: no
    rate (no last step, one of other variables or of length 0), a step no shorter than the last
    (``rate`` >= 1), or a step or rate that is not a number."""
    u = np.abs(np.asarray(u, float))
    if rate is None or not rate < 1.0 or np.isnan(u).any():
        return None
    return bool(np.all(rate / (1.0 - rate) * u <= tolerance))


__all__ = ["Nuisance", "Columns", "linear_solver", "ProfileStep", "LocalProfile", "profile_step", "sparse_system",
           "gauss_newton_step", "retract_flat", "sqrt_weights", "joint_marginal_covariance", "fill_reducing_order",
           "steps_to_come_below"]
