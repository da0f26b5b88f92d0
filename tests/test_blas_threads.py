"""The BLAS thread count set for a stretch of code and restored after (pedcal.calib.blas_threads)."""

import numpy as np
import pytest

from pedcal.calib import blas_threads


@pytest.fixture
def two_threads():
    """Every loaded BLAS at two threads for the test, its own counts restored after: the counts
    it takes (a serial build, as cvxopt's wheel carries, stays at 1), at least one of them 2."""
    np.ones((4, 4)) @ np.ones((4, 4))            # (NumPy's BLAS loaded)
    if not blas_threads.current():
        pytest.skip("no BLAS found in this process")
    with blas_threads.limited(2):
        counts = blas_threads.current()
        assert max(counts) == 2
        yield counts


def test_inside_the_block_every_openblas_runs_one_thread_and_after_it_its_count_is_back(two_threads):
    with blas_threads.limited(1):
        assert all(n == 1 for n in blas_threads.current())
    assert blas_threads.current() == two_threads


def test_an_exception_inside_the_block_restores_the_count_too(two_threads):
    with pytest.raises(RuntimeError), blas_threads.limited(1):
        raise RuntimeError("inside")
    assert blas_threads.current() == two_threads


def test_nested_blocks_restore_the_count_when_the_outer_one_ends(two_threads):
    with blas_threads.limited(1):
        with blas_threads.limited(1):
            assert all(n == 1 for n in blas_threads.current())
        assert all(n == 1 for n in blas_threads.current())     # (the outer block still runs)
    assert blas_threads.current() == two_threads


def test_the_factor_graph_calibrates_on_one_blas_thread(two_threads, monkeypatch):
    import pedcal.calib.factorgraph as fgmod

    seen = []
    monkeypatch.setattr(fgmod, "_calibrate_factorgraph",
                        lambda log, **kw: seen.append(blas_threads.current()) or "done")
    assert fgmod.calibrate_factorgraph(None) == "done"
    assert seen and all(n == 1 for n in seen[0])
    assert blas_threads.current() == two_threads
