"""Sparse Cholesky factorization of a normal matrix A^T A straight from A: CHOLMOD's supernodal
factorization (SuiteSparse), reached through ``ctypes``.

CHOLMOD factorizes F F^T of an unsymmetric F, so F = A^T, which is A's CSR arrays read as CSC:
A^T A is never formed (scipy's product of a 177 000-column system took 0.3-0.45 s and ~90 MB),
and the supernodal factorization runs on dense BLAS-3 blocks: 0.4 s where SuperLU's LU of the
formed matrix took 1.0 s (1000 synthetic sensors). The symbolic analysis (the elimination tree,
the supernodes, their row patterns) depends on A's pattern and the column order alone; it is
kept (without its values) for the next factorization of the same pattern, as the profile's steps
are of the same graph. The numeric factorization is CHOLMOD's supernodal one of the permuted
matrices it needs, made here from A's arrays (one renumbering and one transpose, where
cholmod_factorize takes two transposes of its own: 0.03-0.04 s and 23 000 page faults less per
factorization of 1000 sensors' system, the same factor bit for bit). Many right-hand sides are
solved together (dense blocks).

The library is the one cvxopt's wheels carry (its BLAS calls bound to the wheel's OpenBLAS, not
its ATLAS: the dynamic linker's bindings, ``LD_DEBUG=bindings``), loaded
after cvxopt's own module, which brings its dependencies into the process; else the system's
``libcholmod`` (Debian's libcholmod3), of a major version in LAYOUT_MAJOR_VERSIONS; where none
is found, :func:`pedcal.calib.profile._normal_solver` takes SuperLU's LU of the formed normal
matrix instead (the same solution, slower on large graphs). Only CHOLMOD's stable public structures are
spelled out (``cholmod_sparse``, ``cholmod_dense``, the head of ``cholmod_factor``); its
``cholmod_common`` is an opaque buffer its own ``cholmod_start`` fills.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import logging
import os
import threading

import numpy as np
import scipy.sparse as sps

# cholmod_sparse / cholmod_dense codes (cholmod_core.h)
_INT, _REAL, _DOUBLE = 0, 1, 0
_SOLVE_A = 0          # CHOLMOD_A: solve A x = b (here F F^T x = b, the permutation applied inside)
_PATTERN = 0          # CHOLMOD_PATTERN: a factor without values (its symbolic analysis)
_NATURAL = 0          # CHOLMOD_NATURAL (a factor's ordering): its columns as they are, L->Perm not applied


class _Sparse(ctypes.Structure):
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("nz", ctypes.c_void_p), ("x", ctypes.c_void_p),
                ("z", ctypes.c_void_p), ("stype", ctypes.c_int), ("itype", ctypes.c_int), ("xtype", ctypes.c_int),
                ("dtype", ctypes.c_int), ("sorted", ctypes.c_int), ("packed", ctypes.c_int)]


class _Dense(ctypes.Structure):
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("d", ctypes.c_size_t), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p), ("xtype", ctypes.c_int),
                ("dtype", ctypes.c_int)]


class _FactorHead(ctypes.Structure):
    # the leading fields of cholmod_factor: n, the first column that failed (minor = n when none),
    # and, of a supernodal one, the size of its values (xsize, supernodes' padding included)
    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t), ("Perm", ctypes.c_void_p),
                ("ColCount", ctypes.c_void_p), ("IPerm", ctypes.c_void_p), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("nz", ctypes.c_void_p), ("next", ctypes.c_void_p), ("prev", ctypes.c_void_p),
                ("nsuper", ctypes.c_size_t), ("ssize", ctypes.c_size_t), ("xsize", ctypes.c_size_t),
                ("maxcsize", ctypes.c_size_t), ("maxesize", ctypes.c_size_t), ("super", ctypes.c_void_p),
                ("pi", ctypes.c_void_p), ("px", ctypes.c_void_p), ("s", ctypes.c_void_p), ("ordering", ctypes.c_int),
                ("is_ll", ctypes.c_int), ("is_super", ctypes.c_int)]


# the CHOLMOD major versions whose cholmod_sparse, cholmod_dense and cholmod_factor head are the
# ones spelled out below (3: cvxopt 1.3's wheels and Debian 12's libcholmod3, where they were
# tested; 4 shares 3's layout); another is not loaded (the normal equations go to SuperLU)
LAYOUT_MAJOR_VERSIONS = (3, 4)

# cholmod_common's size differs by version (~2-4 KB); its buffer is made far larger
_COMMON_BYTES = 1 << 16
# cholmod_common's fields set here, by byte offset (CHOLMOD 3-5's layout): `print` (messages on
# stderr: set to 0), `nmethods` (0: CHOLMOD tries a given order and its own COLAMD and keeps the
# sparser factor; 1: the given order alone, what the first of its `method` entries says by
# default, an analysis 0.15 s faster on 1000 sensors' system, where COLAMD was no sparser),
# `supernodal` (CHOLMOD_AUTO: a simplicial LL^T where the factor's flops per entry are below
# `supernodal_switch`, 40, as on the paper scene's system; CHOLMOD_SUPERNODAL: supernodal always,
# its dense blocks BLAS-3: the paper scene's factorization 13 -> 8 ms, the same factor to
# rounding). Written only when the fields around them hold the defaults cholmod_start gives them
# (the relaxation parameters, the print level, the supernodal switch, the methods' parameters and
# orderings): the offsets checked
_SUPERNODAL_SWITCH_OFFSET, _SUPERNODAL_OFFSET = 40, 48
_AUTO, _SUPERNODAL = 1, 2                      # CHOLMOD_AUTO (the default), CHOLMOD_SUPERNODAL
_PRINT_OFFSET = 144
_NMETHODS_OFFSET = 168
_METHOD_OFFSET, _METHOD_BYTES = 184, 168       # cholmod_method_struct: 9 doubles, 5 size_t, 6 ints, 4 size_t
_GIVEN = 1                                     # CHOLMOD_GIVEN, the default's first method (then AMD, METIS)


def _library_paths():
    """The candidate libraries in turn: cvxopt's wheel's, then the system's. A generator: the
    system's is looked for (ctypes.util.find_library runs ldconfig, gcc and ld, tens of ms) only
    when the wheel's cannot be loaded."""
    try:
        import cvxopt.cholmod  # noqa: F401  (loads the libraries CHOLMOD's needs from the wheel)

        root = os.path.dirname(os.path.dirname(cvxopt.cholmod.__file__))
        for pattern in ("cvxopt.libs/libcholmod*.so*", "cvxopt/.dylibs/libcholmod*.dylib"):
            yield from sorted(glob.glob(os.path.join(root, pattern)))
    except ImportError:
        pass
    system = ctypes.util.find_library("cholmod")
    if system:
        yield system


def _int(raw: bytes, offset: int) -> int:
    return int(np.frombuffer(raw, np.int32, 1, offset)[0])


class _Library:
    """CHOLMOD's functions and one ``cholmod_common`` (its workspace: calls are serialized)."""

    def __init__(self):
        lib, errors = None, []
        for path in _library_paths():
            try:
                lib = ctypes.CDLL(path)
                break
            except OSError as e:
                errors.append(f"{path}: {e}")
        if lib is None:
            raise ImportError("CHOLMOD (SuiteSparse) was not found: install the package's dependencies "
                              "(cvxopt's wheel carries it; or the system's libcholmod)"
                              + (f" ({'; '.join(errors)})" if errors else ""))
        sp, fp, vp = ctypes.POINTER(_Sparse), ctypes.c_void_p, ctypes.c_void_p
        common = ctypes.c_char_p
        lib.cholmod_start.argtypes = [common]
        lib.cholmod_analyze_p.argtypes = [sp, vp, vp, ctypes.c_size_t, common]
        lib.cholmod_analyze_p.restype = fp
        lib.cholmod_factorize.argtypes = [sp, fp, common]
        # (the supernodal numeric factorization of matrices already permuted: cholmod_factorize's
        # own step after its two transposes, public in CHOLMOD's Supernodal module)
        self.super_numeric = getattr(lib, "cholmod_super_numeric", None)
        if self.super_numeric is not None:
            self.super_numeric.argtypes = [sp, sp, ctypes.POINTER(ctypes.c_double * 2), fp, common]
        lib.cholmod_solve.argtypes = [ctypes.c_int, fp, ctypes.POINTER(_Dense), common]
        lib.cholmod_solve.restype = ctypes.POINTER(_Dense)
        lib.cholmod_free_dense.argtypes = [ctypes.POINTER(ctypes.POINTER(_Dense)), common]
        lib.cholmod_free_factor.argtypes = [ctypes.POINTER(fp), common]
        lib.cholmod_change_factor.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                              fp, common]
        version = (ctypes.c_int * 3)()
        try:
            lib.cholmod_version(version)
        except AttributeError:                         # (before CHOLMOD 3: no cholmod_version)
            version[0] = 0
        self.version = tuple(version)
        if self.version[0] not in LAYOUT_MAJOR_VERSIONS:
            raise ImportError(f"CHOLMOD {'.'.join(map(str, self.version))} at {path}: its structures are spelled "
                              f"out here for major versions {LAYOUT_MAJOR_VERSIONS} only")
        self.lib = lib
        self.common = ctypes.create_string_buffer(_COMMON_BYTES)
        if not lib.cholmod_start(self.common):
            raise ImportError("CHOLMOD did not start")
        raw = self.common.raw
        method = _METHOD_OFFSET
        # (supernodal switch 40, CHOLMOD_AUTO; relaxation 0.8 / 0.1 / 0.05 and 4 / 16 / 48, print
        # 3; no methods chosen; the first method's prune_dense 10, nd_oksep 1, nd_small 200 and the
        # orderings GIVEN, AMD, METIS)
        self.defaults = (np.frombuffer(raw, np.float64, 3, 80).tolist() == [0.8, 0.1, 0.05]
                         and np.frombuffer(raw, np.uint64, 3, 104).tolist() == [4, 16, 48]
                         and np.frombuffer(raw, np.float64, 1, _SUPERNODAL_SWITCH_OFFSET)[0] == 40.0
                         and _int(raw, _SUPERNODAL_OFFSET) == _AUTO
                         and _int(raw, _PRINT_OFFSET) == 3 and _int(raw, _NMETHODS_OFFSET) == 0
                         and np.frombuffer(raw, np.float64, 1, method + 16)[0] == 10.0
                         and np.frombuffer(raw, np.float64, 1, method + 32)[0] == 1.0
                         and np.frombuffer(raw, np.uint64, 1, method + 72)[0] == 200
                         and [_int(raw, method + 132 + i * _METHOD_BYTES) for i in range(3)] == [_GIVEN, 2, 3])
        if self.defaults:
            self._set_int(_PRINT_OFFSET, 0)
            self._set_int(_SUPERNODAL_OFFSET, _SUPERNODAL)
        self.lock = threading.RLock()

    def _set_int(self, offset: int, value: int) -> None:
        ctypes.memmove(ctypes.addressof(self.common) + offset, ctypes.byref(ctypes.c_int(value)), 4)

    def given_order_only(self, given: bool) -> None:
        """A given order taken as it is (one method), or CHOLMOD's default choice."""
        if self.defaults:
            self._set_int(_NMETHODS_OFFSET, 1 if given else 0)

    def free_factor(self, factor) -> None:
        if factor:
            handle = ctypes.c_void_p(factor)
            with self.lock:
                self.lib.cholmod_free_factor(ctypes.byref(handle), self.common)


_LIBRARY: list = []


_MISSING: list = []


def library() -> _Library:
    """CHOLMOD, loaded on first use (ImportError when it is nowhere, or of another layout: the
    first failure is kept and raised again, not retried on every call)."""
    if _MISSING:
        raise _MISSING[0]
    if not _LIBRARY:
        try:
            _LIBRARY.append(_Library())
        except ImportError as e:
            _MISSING.append(e)
            logging.getLogger("pedcal").info("the normal equations go to SuperLU: %s", e)
            raise
    return _LIBRARY[0]


def available() -> bool:
    """Whether CHOLMOD can be loaded."""
    try:
        library()
    except ImportError:
        return False
    return True


class _Analyses:
    """The symbolic analysis of the last factorization let go of (its values freed), with the
    pattern and order it was made for: taken by the next factorization of the same, freed by
    one of another."""

    def __init__(self):
        self.kept = None

    def give(self, factor, key) -> None:
        lib = library()
        head = _FactorHead.from_address(factor)
        # (under the library's lock, an RLock: two threads' factorizations never take or free the
        # same kept analysis)
        with lib.lock:
            # numeric -> symbolic, supernodal or simplicial as it was (without the defaults
            # recognized, CHOLMOD factorizes small systems simplicially, LDL^T): the values (the
            # factor's memory) freed, the analysis kept
            ok = lib.lib.cholmod_change_factor(_PATTERN, head.is_ll, head.is_super, 1, 1, factor, lib.common)
            new = (factor, key) if ok else None      # (made before the swap: a collection it triggers may call give)
            old, self.kept = self.kept, new
            if not ok:
                lib.free_factor(factor)
            if old is not None:
                lib.free_factor(old[0])

    def take(self, key):
        lib = library()
        with lib.lock:
            kept, self.kept = self.kept, None
            if kept is None:
                return None
            factor, kept_key = kept
            if _same_key(kept_key, key):
                return factor
            lib.free_factor(factor)
            return None


def _same_key(a, b) -> bool:
    # (np.array_equal is False for arrays of different shapes)
    return len(a) == len(b) and a[0] == b[0] and all(np.array_equal(x, y) for x, y in zip(a[1:], b[1:], strict=True))


_ANALYSES = _Analyses()


def renumbered(indices: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A sparse matrix's column ``indices`` renumbered into the column ``order`` (column
    ``order[k]`` becomes column k), and each column's position in the order; both of the
    indices' integer type."""
    position = np.empty(len(order), indices.dtype)
    position[order] = np.arange(len(order), dtype=indices.dtype)
    return position[indices], position


def _super_numeric(lib: _Library, n: int, m: int, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray,
                   head: _FactorHead, factor) -> int:
    """The supernodal factorization L L^T = S S^T of the analysed ``factor`` (its supernodes, and
    its column order P: the given order, postordered by the analysis), from S = P A^T and its
    transpose S^T = A P^T, both made here from the CSR arrays (int32) of A, m x n: cholmod_factorize
    makes them by two transposes of its own, through A(P, :)^T (1000 sensors' system: 4.9 million
    entries, each transpose a scattered pass with its own copy). S^T's columns list their rows in
    order, as CHOLMOD's transpose does, so that each entry of S S^T is summed in the same order:
    the same factor, bit for bit. S's columns may list their rows in any order (CHOLMOD scatters
    them)."""
    perm = np.ctypeslib.as_array(ctypes.cast(head.Perm, ctypes.POINTER(ctypes.c_int32)), shape=(n,))
    s_rows, _ = renumbered(indices, perm)     # S = P A^T: A's rows as its columns, the variables renumbered
    s_transposed = sps.csr_matrix((data, s_rows, indptr), shape=(m, n)).tocsc()    # S^T = A P^T, CSC
    t_indptr = np.ascontiguousarray(s_transposed.indptr, np.int32)
    t_indices = np.ascontiguousarray(s_transposed.indices, np.int32)
    t_data = np.ascontiguousarray(s_transposed.data, np.float64)
    S = _Sparse(n, m, len(data), indptr.ctypes.data, s_rows.ctypes.data, None, data.ctypes.data,
                None, 0, _INT, _REAL, _DOUBLE, 0, 1)
    S_t = _Sparse(m, n, len(data), t_indptr.ctypes.data, t_indices.ctypes.data, None, t_data.ctypes.data,
                  None, 0, _INT, _REAL, _DOUBLE, 1, 1)
    beta = (ctypes.c_double * 2)(0.0, 0.0)
    return lib.super_numeric(ctypes.byref(S), ctypes.byref(S_t), ctypes.byref(beta), factor, lib.common)


class NormalCholesky:
    """CHOLMOD's supernodal Cholesky factorization L L^T = P A^T A P^T of a normal matrix, from A
    itself (CSR, its columns the variables), in the fill-reducing column ``order`` (P; without
    one, CHOLMOD's own: COLAMD). A^T A must be positive definite: a column nothing holds is a
    LinAlgError naming the first failing one. ``solve(y)`` takes one right-hand side or many
    (columns); ``factor_entries``: the values stored in L (supernodes' padding included, 8 bytes
    each), what holding the factorization costs."""

    def __init__(self, A: sps.spmatrix, order: np.ndarray | None = None):
        lib = library()
        A = sps.csr_matrix(A)
        if not A.has_canonical_format:        # (CHOLMOD's analysis rejects repeated entries: summed, on a copy)
            A = A.copy()
            A.sum_duplicates()
        index = np.int32
        if A.nnz >= 2 ** 31 or max(A.shape) >= 2 ** 31:
            raise ValueError(f"a system of {A.shape} with {A.nnz} entries is beyond 32-bit indices")
        # A's CSR arrays as F = A^T in CSC (CHOLMOD reads them in place, while it analyzes and factorizes)
        indptr = np.ascontiguousarray(A.indptr, index)
        indices = np.ascontiguousarray(A.indices, index)
        data = np.ascontiguousarray(A.data, np.float64)
        n, m = A.shape[1], A.shape[0]
        self.n = n
        F = _Sparse(n, m, A.nnz, indptr.ctypes.data, indices.ctypes.data, None, data.ctypes.data,
                    None, 0, _INT, _REAL, _DOUBLE, int(A.has_sorted_indices), 1)
        perm = None if order is None else np.ascontiguousarray(order, index)
        if perm is not None and (perm.shape != (n,) or not np.array_equal(np.sort(perm), np.arange(n))):
            raise ValueError(f"the column order must be a permutation of the {n} columns")
        # (copies: the caller's arrays may be A's own, and a pattern edited in place would match
        # the analysis kept for the old one)
        key = (n, indptr.copy(), indices.copy()) + (() if perm is None else (perm.copy(),))
        factor = _ANALYSES.take(key)
        with lib.lock:
            if factor is None:
                lib.given_order_only(perm is not None)
                factor = lib.lib.cholmod_analyze_p(ctypes.byref(F), None if perm is None else perm.ctypes.data,
                                                   None, 0, lib.common)
                if not factor:
                    raise MemoryError(f"CHOLMOD's analysis of a {n}-column normal matrix failed (memory, "
                                      f"size or an invalid matrix)")
            self._factor, self._key = factor, key
            head = _FactorHead.from_address(factor)
            # (a natural ordering is factorized unpermuted by cholmod_factorize, which then reads
            # no L->Perm: left to it, as _super_numeric applies L->Perm)
            if head.is_super and head.ordering != _NATURAL and lib.super_numeric is not None:
                ok = _super_numeric(lib, n, m, indptr, indices, data, head, factor)
            else:
                ok = lib.lib.cholmod_factorize(ctypes.byref(F), factor, lib.common)
        # (not positive definite is CHOLMOD's warning, not a failure: the factor's ``minor`` says
        # where; a failed call is memory or size)
        if not ok:
            raise MemoryError(f"CHOLMOD's factorization of a {n}-column normal matrix failed (memory or size)")
        head = _FactorHead.from_address(factor)
        if head.minor < head.n:
            raise np.linalg.LinAlgError("the normal matrix is not positive definite (a variable no factor holds): "
                                        f"the factorization failed at its {int(head.minor)}th column in the "
                                        "elimination order")
        self.factor_entries = int(head.xsize if head.is_super else head.nzmax)

    def solve(self, y) -> np.ndarray:
        """x with A^T A x = y (y of n rows, one column or many)."""
        y = np.asarray(y, float)
        if y.shape[0] != self.n:
            raise ValueError(f"a right-hand side of {y.shape[0]} rows for {self.n} columns")
        if y.size == 0:           # no column, or no right-hand side (before the reshape, which 0 rows cannot take)
            return np.zeros(y.shape)
        Y = np.asfortranarray(y.reshape(self.n, -1))
        k = Y.shape[1]
        B = _Dense(self.n, k, self.n * k, self.n, Y.ctypes.data, None, _REAL, _DOUBLE)
        lib = library()
        with lib.lock:
            X = lib.lib.cholmod_solve(_SOLVE_A, self._factor, ctypes.byref(B), lib.common)
            if not X:
                raise MemoryError("CHOLMOD's solve failed")
            try:
                # (CHOLMOD's column-major n x k: copied as it lies, k x n, and returned transposed,
                # a column-major view, not transposed in the copy)
                x = np.ctypeslib.as_array(ctypes.cast(X.contents.x, ctypes.POINTER(ctypes.c_double)),
                                          shape=(k, self.n)).copy()
            finally:
                lib.lib.cholmod_free_dense(ctypes.byref(X), lib.common)
        return x.T.reshape(y.shape)

    def __del__(self):
        factor, self._factor = getattr(self, "_factor", None), None
        if factor and _LIBRARY:
            # the analysis goes back for the next factorization of the same pattern
            _ANALYSES.give(factor, self._key)


__all__ = ["NormalCholesky", "available", "library", "renumbered"]
