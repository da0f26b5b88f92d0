"""The BLAS thread count set for a stretch of code and restored after (pedcal.calib.blas_threads)."""

import numpy as np
import pytest

from pedcal.calib import blas_threads


def _set_all(n: int) -> None:
    for set_threads, _ in blas_threads._controls():
        set_threads(n)


@pytest.fixture
def two_threads():
    """Every loaded OpenBLAS at two threads for the test, its own counts restored after."""
    np.ones((4, 4)) @ np.ones((4, 4))            # (NumPy's OpenBLAS loaded and mapped)
    before = blas_threads.current()
    if not before:
        pytest.skip("no OpenBLAS found in this process")
    _set_all(2)
    yield
    for (set_threads, _), n in zip(blas_threads._controls(), before, strict=True):
        set_threads(n)


def test_inside_the_block_every_openblas_runs_one_thread_and_after_it_its_count_is_back(two_threads):
    assert all(n == 2 for n in blas_threads.current())
    with blas_threads.limited(1):
        assert all(n == 1 for n in blas_threads.current())
    assert all(n == 2 for n in blas_threads.current())


def test_an_exception_inside_the_block_restores_the_count_too(two_threads):
    with pytest.raises(RuntimeError), blas_threads.limited(1):
        raise RuntimeError("inside")
    assert all(n == 2 for n in blas_threads.current())


def test_a_count_already_at_or_below_the_limit_is_left_as_it_is(two_threads):
    with blas_threads.limited(3):
        assert all(n == 2 for n in blas_threads.current())
    assert all(n == 2 for n in blas_threads.current())
