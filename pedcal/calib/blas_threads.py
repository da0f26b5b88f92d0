"""The BLAS libraries' thread count, set for a stretch of code and restored after.

The factor graph's dense products (a few tens of columns: the profile's sensitivities, the clock
offsets' block scores) are too small for OpenBLAS's threads to pay: they spin waiting more than
they compute. On the paper scenario with OpenBLAS's default threads (two cores, busy) the solve
took 1.5 s of CPU and 2.3 s of wall time against 0.72 s and 1.07 s on one thread, and its results
are the same either way (the small products are not split across threads in a way that changes
their sums: 0.0 difference measured). ``OPENBLAS_NUM_THREADS`` does this for a whole process
before NumPy loads; :func:`limited` does it at run time, for the libraries already loaded.

The OpenBLAS libraries are found among the process's mapped files (``/proc/self/maps``; NumPy's
and SciPy's wheels each carry their own, with prefixed symbols); elsewhere, or with another BLAS,
nothing is changed.
"""

from __future__ import annotations

import ctypes
import threading
from contextlib import contextmanager

# (set, get) symbol pairs of OpenBLAS builds: plain, 64-bit integer, and the scipy-openblas wheels'
_SYMBOLS = (("openblas_set_num_threads", "openblas_get_num_threads"),
            ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
            ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
            ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"))

_FOUND: dict = {}
# (the blocks open now, and the counts saved by the first of them: calibrations run side by side
# in threads, or one inside another, restore the counts when the last of them ends, not the first)
_LOCK = threading.Lock()
_OPEN = {"depth": 0, "saved": []}


def _controls() -> list:
    """(set, get) functions of every OpenBLAS mapped into the process, looked up once per library."""
    try:
        with open("/proc/self/maps") as f:
            # (address, permissions, offset, device, inode, then the path, which may hold spaces)
            paths = sorted({parts[5].strip() for parts in (line.split(maxsplit=5) for line in f)
                            if len(parts) == 6 and "openblas" in parts[5].lower() and ".so" in parts[5]})
    except OSError:
        return []
    out = []
    for path in paths:
        if path not in _FOUND:
            found = None
            try:
                lib = ctypes.CDLL(path)
                for set_name, get_name in _SYMBOLS:
                    if hasattr(lib, set_name) and hasattr(lib, get_name):
                        found = (getattr(lib, set_name), getattr(lib, get_name))
                        found[1].restype = ctypes.c_int
                        break
            except OSError:
                found = None
            _FOUND[path] = found
        if _FOUND[path] is not None:
            out.append(_FOUND[path])
    return out


@contextmanager
def limited(threads: int = 1):
    """Inside the block, every loaded OpenBLAS runs at most ``threads`` threads; each one's
    count before it is restored after (also on an exception). Blocks open at once (one inside
    another, or in several threads) share the limit of the first: the counts come back when the
    last one ends."""
    with _LOCK:
        if _OPEN["depth"] == 0:
            for set_threads, get_threads in _controls():
                before = int(get_threads())
                if before > threads:
                    set_threads(threads)
                    _OPEN["saved"].append((set_threads, before))
        _OPEN["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _OPEN["depth"] -= 1
            if _OPEN["depth"] == 0:
                for set_threads, before in _OPEN["saved"]:
                    set_threads(before)
                _OPEN["saved"] = []


def current() -> list[int]:
    """The thread count of every loaded OpenBLAS (empty when none is found)."""
    return [int(get()) for _, get in _controls()]


__all__ = ["limited", "current"]
