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


def test_nested_blocks_restore_the_count_when_the_outer_one_ends(two_threads):
    with blas_threads.limited(1):
        with blas_threads.limited(1):
            assert all(n == 1 for n in blas_threads.current())
        assert all(n == 1 for n in blas_threads.current())     # (the outer block still runs)
    assert all(n == 2 for n in blas_threads.current())


def test_blocks_in_two_threads_restore_the_count_when_the_last_one_ends(two_threads):
    import threading

    inside, release = threading.Event(), threading.Event()

    def other():
        with blas_threads.limited(1):
            inside.set()
            release.wait(10.0)

    worker = threading.Thread(target=other)
    worker.start()
    assert inside.wait(10.0)
    with blas_threads.limited(1):
        assert all(n == 1 for n in blas_threads.current())
    assert all(n == 1 for n in blas_threads.current())         # (the other thread's block still runs)
    release.set()
    worker.join(10.0)
    assert all(n == 2 for n in blas_threads.current())


def test_the_factor_graph_calibrates_on_one_blas_thread(two_threads, monkeypatch):
    import pedcal.calib.factorgraph as fgmod

    seen = []
    monkeypatch.setattr(fgmod, "_calibrate_factorgraph",
                        lambda log, **kw: seen.append(blas_threads.current()) or "done")
    assert fgmod.calibrate_factorgraph(None) == "done"
    assert seen and all(n == 1 for n in seen[0])
    assert all(n == 2 for n in blas_threads.current())
