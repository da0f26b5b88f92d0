"""The BLAS libraries' thread count, limited for a stretch of code and restored after.

The factor graph's dense products (a few tens of columns: the profile's sensitivities, the clock
offsets' block scores) are too small for OpenBLAS's threads to pay: they spin waiting more than
they compute. On the paper scenario with OpenBLAS's default threads (two cores, busy) the solve
took 1.5 s of CPU and 2.3 s of wall time against 0.72 s and 1.07 s on one thread, and its results
are the same either way (0.0 difference measured). ``OPENBLAS_NUM_THREADS`` does this for a whole
process before NumPy loads; :func:`limited` does it at run time, for the libraries already loaded,
through threadpoolctl (which finds NumPy's and SciPy's own BLAS builds, whatever their vendor).

Blocks in several Python threads at once (calibrations on a threaded scheduler): OpenBLAS's pool
is one per process, and threadpoolctl lets the first thread that limits it control it until its
block ends; the others' limits and restores do nothing, so no block leaves the process's BLAS
changed after it, at worst a block that outlives the controlling one runs threaded.
"""

from __future__ import annotations

from functools import cache

from threadpoolctl import ThreadpoolController


@cache
def _controller() -> ThreadpoolController:
    """The BLAS libraries loaded at the first call (NumPy's and SciPy's, which pedcal.calib imports
    before it calibrates), looked up once: the look-up walks the process's libraries (~6 ms)."""
    return ThreadpoolController()


def limited(threads: int = 1):
    """A context in which every loaded BLAS runs ``threads`` threads; each one's count before it is
    restored after (also on an exception)."""
    return _controller().limit(limits=threads, user_api="blas")


def current() -> list[int]:
    """The thread count of every loaded BLAS (empty when none is found)."""
    return [int(lib.num_threads) for lib in _controller().select(user_api="blas").lib_controllers]


__all__ = ["limited", "current"]
