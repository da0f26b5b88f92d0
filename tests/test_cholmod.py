"""CHOLMOD's factorization of a normal matrix from A (pedcal.calib.cholmod)."""

import gc

import numpy as np
import pytest
import scipy.sparse as sps

import pedcal.calib.cholmod as cholmod
from pedcal.calib.cholmod import NormalCholesky


def _system(m: int, n: int, seed: int) -> sps.csr_matrix:
    # random rows plus an identity block: A^T A positive definite
    return (sps.random(m, n, density=0.1, random_state=seed, format="csr")
            + sps.vstack([sps.eye(n), sps.csr_matrix((m - n, n))])).tocsr()


def test_solves_the_normal_equations_in_any_order_one_or_many_columns():
    rng = np.random.default_rng(0)
    A = _system(200, 60, 1)
    N = (A.T @ A).toarray()
    Y = rng.normal(size=(60, 7))
    for order in (None, np.arange(60), rng.permutation(60)):
        chol = NormalCholesky(A, order)
        X = chol.solve(Y)
        assert X.shape == (60, 7)
        assert np.abs(N @ X - Y).max() < 1e-10 * np.abs(Y).max()
        x = chol.solve(Y[:, 2])
        assert x.shape == (60,) and np.abs(x - X[:, 2]).max() < 1e-12 * np.abs(X).max()
        assert chol.solve(np.zeros((60, 0))).shape == (60, 0)
    # the factor's stored values: at least the lower triangle of N's, at most a dense n x n block
    assert np.count_nonzero(np.tril(N)) <= NormalCholesky(A).factor_entries <= 60 * 60


def test_unsorted_and_empty_rows_and_64_bit_indices():
    # A's CSR rows in any order of columns, rows with no entry, int64 index arrays: the same solution
    rng = np.random.default_rng(1)
    A = _system(120, 40, 2)
    A = sps.vstack([A, sps.csr_matrix((5, 40))], format="csr")
    y = rng.normal(size=40)
    want = np.linalg.solve((A.T @ A).toarray(), y)
    perm = [rng.permutation(np.arange(A.indptr[r], A.indptr[r + 1])) for r in range(A.shape[0])]
    scrambled = sps.csr_matrix((A.data[np.concatenate(perm)], A.indices[np.concatenate(perm)].astype(np.int64),
                                A.indptr.astype(np.int64)), shape=A.shape)
    assert not scrambled.has_sorted_indices
    got = NormalCholesky(scrambled, rng.permutation(40)).solve(y)
    assert np.abs(got - want).max() < 1e-10 * np.abs(want).max()


def test_a_column_nothing_holds_is_a_linalg_error(capfd):
    A = sps.csr_matrix(np.array([[1.0, 0.0, 2.0], [0.0, 0.0, 1.0], [3.0, 0.0, 0.0]]))
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        NormalCholesky(A, np.arange(3))
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        NormalCholesky(A)
    # the error is ours alone: CHOLMOD's own messages are off (its print level 0)
    out, err = capfd.readouterr()
    assert "CHOLMOD" not in out and "CHOLMOD" not in err


def test_the_librarys_workspace_layout_is_the_one_spelled_out():
    # the fields written by offset (the print level, the number of ordering methods) sit among
    # cholmod_start's defaults where they are looked for: with another layout they would not be
    # written, and a given order would be compared with CHOLMOD's own (slower, still right)
    assert cholmod.library().defaults


def test_bad_order_and_right_hand_side_are_value_errors():
    A = _system(30, 10, 3)
    with pytest.raises(ValueError, match="permutation of the 10 columns"):
        NormalCholesky(A, np.r_[0, 0, np.arange(2, 10)])
    with pytest.raises(ValueError, match="permutation of the 10 columns"):
        NormalCholesky(A, np.arange(9))
    with pytest.raises(ValueError, match="11 rows for 10 columns"):
        NormalCholesky(A).solve(np.ones(11))


def test_no_column_or_no_right_hand_side_solves_to_zeros_of_its_shape():
    # a system of no variables (rows or none) factorizes; its solve of one, several or no
    # right-hand sides is empty, as a system's solve of no right-hand side is
    for rows in (5, 0):
        chol = NormalCholesky(sps.csr_matrix((rows, 0)))
        assert chol.n == 0
        for shape in ((0,), (0, 3), (0, 0)):
            x = chol.solve(np.zeros(shape))
            assert x.shape == shape and x.dtype == float
        with pytest.raises(ValueError, match="1 rows for 0 columns"):
            chol.solve(np.ones(1))
    x = NormalCholesky(_system(30, 10, 3)).solve(np.zeros((10, 0)))
    assert x.shape == (10, 0)


def test_the_analysis_is_reused_for_the_same_pattern_and_order_only(monkeypatch):
    # a factorization of the same pattern and order after the last one was let go of takes its
    # symbolic analysis; another order, another pattern, or one still held make their own; the
    # solves are the new values' every time
    lib = cholmod.library()
    analyses = []
    real = lib.lib

    class Counting:
        def __getattr__(self, name):
            return getattr(real, name)

        def cholmod_analyze_p(self, *args):
            analyses.append(1)
            return real.cholmod_analyze_p(*args)

    monkeypatch.setattr(lib, "lib", Counting())
    monkeypatch.setattr(cholmod, "_ANALYSES", cholmod._Analyses())
    rng = np.random.default_rng(7)
    n = 30
    A0 = _system(90, n, 4)
    order = rng.permutation(n)
    y = rng.normal(size=(n, 3))

    def check(A, order):
        x = NormalCholesky(A, order).solve(y)
        assert np.abs((A.T @ A) @ x - y).max() < 1e-10 * np.abs(y).max()
        gc.collect()

    check(A0, order)
    assert len(analyses) == 1
    A1 = A0.copy()
    A1.data = A1.data * (1.0 + 0.1 * rng.standard_normal(A1.nnz))       # the same pattern, new values
    check(A1, order)
    assert len(analyses) == 1
    check(A1, rng.permutation(n))                                        # another order
    assert len(analyses) == 2
    check(A1, None)                                                      # CHOLMOD's own order
    assert len(analyses) == 3
    A2 = sps.vstack([A1, sps.csr_matrix(([1.0, 1.0], ([0, 0], [0, n - 1])), shape=(1, n))], format="csr")
    check(A2, None)                                                      # another pattern
    assert len(analyses) == 4
    held = NormalCholesky(A2)                                            # still held: not shared
    check(A2, None)
    assert len(analyses) == 5
    assert np.abs((A2.T @ A2) @ held.solve(y) - y).max() < 1e-10 * np.abs(y).max()
    del held
    gc.collect()
    # the same row lengths, one entry moved to another column: another pattern
    A3 = A2.copy()
    row = int(np.flatnonzero(np.diff(A3.indptr) > 0)[0])
    cols = set(A3.indices[A3.indptr[row]:A3.indptr[row + 1]].tolist())
    A3.indices[A3.indptr[row]] = min(set(range(n)) - cols)
    A3.sort_indices()
    check(A3, None)
    assert len(analyses) == 6
    # a pattern edited in place after its factorization (the caller's own arrays): not the kept one
    A4 = A0.copy()
    check(A4, order)
    before = len(analyses)
    r = int(np.flatnonzero(np.diff(A4.indptr) > 1)[0])
    lo = A4.indptr[r]
    A4.indices[lo:A4.indptr[r + 1]] = sorted(set(range(n)) - set(A4.indices[lo:A4.indptr[r + 1]].tolist()))[
        :A4.indptr[r + 1] - lo]
    A4.has_sorted_indices = False
    A4.sort_indices()
    check(A4, order)
    assert len(analyses) == before + 1


def test_a_large_system_is_factorized_in_supernodes_and_in_the_given_order():
    # the production path: a supernodal factor (its analysis reused as such), taken in the given
    # order (CHOLMOD's nmethods written where it is: with it unwritten or written elsewhere, CHOLMOD
    # compares the order with its own and may keep its own)
    rng = np.random.default_rng(11)
    # a 30 x 30 grid's differences and a prior on each node: a random order of its nodes fills
    # its factor far beyond what CHOLMOD's own orders leave
    g = 30
    D = sps.diags([-np.ones(g - 1), np.ones(g - 1)], [0, 1], shape=(g - 1, g))
    I_g = sps.eye(g)
    A = sps.vstack([sps.kron(I_g, D), sps.kron(D, I_g), 0.1 * sps.eye(g * g)], format="csr")
    n = g * g
    order = rng.permutation(n)
    chol = NormalCholesky(A, order)
    head = cholmod._FactorHead.from_address(chol._factor)
    assert head.is_super == 1 and head.ordering == 1      # CHOLMOD_GIVEN
    y = rng.normal(size=(n, 2))
    assert np.abs((A.T @ A) @ chol.solve(y) - y).max() < 1e-9 * np.abs(y).max()


def test_repeated_entries_are_summed_as_scipy_sums_them():
    rng = np.random.default_rng(12)
    A = _system(120, 40, 8)
    # each entry split in two halves within its row: the same matrix, with repeated entries
    lengths = np.diff(A.indptr)
    row_of = np.repeat(np.arange(A.shape[0]), lengths)
    order_ = np.argsort(np.r_[row_of, row_of], kind="stable")
    indices = np.r_[A.indices, A.indices][order_]
    data = np.r_[A.data / 2, A.data / 2][order_]
    dup = sps.csr_matrix((data, indices, np.r_[0, np.cumsum(2 * lengths)]), shape=A.shape)
    assert not dup.has_canonical_format and dup.nnz == 2 * A.nnz
    y = rng.normal(size=40)
    want = np.linalg.solve((A.T @ A).toarray(), y)
    assert np.abs(NormalCholesky(dup, rng.permutation(40)).solve(y) - want).max() < 1e-10 * np.abs(want).max()


def test_without_cholmod_the_normal_equations_go_to_superlu_with_the_same_solution(monkeypatch):
    from pedcal.calib import profile

    rng = np.random.default_rng(3)
    A = _system(150, 50, 4)
    Y = rng.normal(size=(50, 3))
    order = rng.permutation(50)
    want = {o is None: profile._normal_solver(A, o)(Y) for o in (None, order)}
    monkeypatch.setattr(cholmod, "available", lambda: False)

    def not_here(*args, **kwargs):
        raise AssertionError("CHOLMOD called without it")
    monkeypatch.setattr(cholmod, "NormalCholesky", not_here)
    for o in (None, order):
        got = profile._normal_solver(A, o)(Y)
        assert np.abs(got - want[o is None]).max() < 1e-10 * np.abs(want[o is None]).max()
    singular = sps.csr_matrix(np.array([[1.0, 0.0, 2.0], [0.0, 0.0, 1.0], [3.0, 0.0, 0.0]]))
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        profile._normal_solver(singular, np.arange(3))


def test_a_cholmod_of_another_layout_is_not_loaded_and_the_failure_is_kept(monkeypatch):
    monkeypatch.setattr(cholmod, "_LIBRARY", [])
    monkeypatch.setattr(cholmod, "_MISSING", [])
    monkeypatch.setattr(cholmod, "LAYOUT_MAJOR_VERSIONS", (99,))
    with pytest.raises(ImportError, match="major versions"):
        cholmod.library()
    assert not cholmod.available()
    calls = []
    monkeypatch.setattr(cholmod, "_Library", lambda: calls.append(1))
    assert not cholmod.available() and not calls          # (not loaded again)


def test_the_systems_library_is_looked_for_only_past_the_wheels(monkeypatch):
    """ctypes.util.find_library runs ldconfig, gcc and ld: not while cvxopt's wheel's CHOLMOD loads."""
    import ctypes.util

    looked = []
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: looked.append(name) or "/nowhere/libcholmod.so")
    paths = cholmod._library_paths()
    first = next(paths)
    if "cvxopt" not in first:
        pytest.skip("cvxopt's wheel carries no CHOLMOD here")
    assert looked == []
    assert list(paths)[-1] == "/nowhere/libcholmod.so" and looked == ["cholmod"]    # (then, in turn)


def test_a_small_system_is_factorized_supernodally_with_the_same_solution():
    # below CHOLMOD's own supernodal switch (a factor of few flops per entry: a chain's) the
    # factorization is supernodal all the same (the library's setting), and solves as the dense
    lib = cholmod.library()
    rng = np.random.default_rng(21)
    n = 12
    D = sps.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))
    A = sps.vstack([D, 0.5 * sps.eye(n)], format="csr")
    chol = NormalCholesky(A, rng.permutation(n))
    head = cholmod._FactorHead.from_address(chol._factor)
    assert head.is_super == (1 if lib.defaults else 0)
    y = rng.normal(size=(n, 3))
    want = np.linalg.solve((A.T @ A).toarray(), y)
    assert np.abs(chol.solve(y) - want).max() < 1e-12 * np.abs(want).max()


@pytest.mark.parametrize("given_order", [False, True])
@pytest.mark.parametrize("seed", [31, 32])
def test_the_permuted_matrices_made_here_give_cholmod_factorizes_factor_bit_for_bit(seed, given_order, monkeypatch):
    # the supernodal factorization from S = P A^T and S^T made here (some of A's rows empty; in
    # CHOLMOD's own order or a random one) against cholmod_factorize's own transposes: the same
    # solutions to the last bit, and both the dense solution's (A's rows unsorted are sorted
    # before either runs: see test_unsorted_and_empty_rows_and_64_bit_indices)
    lib = cholmod.library()
    if lib.super_numeric is None or not lib.defaults:
        pytest.skip("this CHOLMOD has no cholmod_super_numeric or its settings are not the defaults")
    rng = np.random.default_rng(seed)
    g = 14
    D = sps.diags([-np.ones(g - 1), np.ones(g - 1)], [0, 1], shape=(g - 1, g))
    I_g = sps.eye(g)
    A = sps.vstack([sps.kron(I_g, D), sps.kron(D, I_g), sps.random(40, g * g, density=0.05, random_state=seed),
                    sps.csr_matrix((3, g * g)), 0.1 * sps.eye(g * g)], format="csr")
    n = g * g
    order = rng.permutation(n) if given_order else None
    y = rng.normal(size=(n, 3))
    calls = []
    made_here = cholmod._super_numeric

    def counted(*args, **kwargs):
        calls.append(1)
        return made_here(*args, **kwargs)

    monkeypatch.setattr(cholmod, "_super_numeric", counted)
    chol = NormalCholesky(A, order)
    assert len(calls) == 1                             # the path made here ran, once
    assert cholmod._FactorHead.from_address(chol._factor).is_super == 1
    x_here = chol.solve(y)
    numeric = lib.super_numeric
    try:
        lib.super_numeric = None                       # cholmod_factorize, its own transposes
        x_cholmod = NormalCholesky(A, order).solve(y)
    finally:
        lib.super_numeric = numeric
    assert len(calls) == 1
    assert np.array_equal(x_here, x_cholmod)
    want = np.linalg.solve((A.T @ A).toarray(), y)
    assert np.abs(x_here - want).max() < 1e-9 * np.abs(want).max()
