"""Ctrl-C on the command line: one line and exit code 130, whenever it comes.

``install()`` (the command line calls it first) makes SIGINT raise SystemExit(130) after printing
``interrupted``: a SystemExit passes every ``except Exception`` of the work, runs the ``finally``
blocks that remove temporary outputs (pedcal.io.atomic), and is no traceback, also while the
first modules are being imported. ``children_ignore()`` starts helper processes (Dask workers)
with SIGINT ignored: the terminal sends Ctrl-C to the whole process group, and the parent alone
answers it, by shutting its workers down.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys

EXIT_INTERRUPTED = 130


def _on_sigint(signum, frame):
    signal.signal(signal.SIGINT, signal.SIG_IGN)       # a second Ctrl-C does not interrupt the clean-up
    logging.disable(logging.CRITICAL)     # the shutdown's own messages (Dask killing its workers) are noise now
    try:
        print("interrupted", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
    raise SystemExit(EXIT_INTERRUPTED)


def install():
    """SIGINT -> one line and SystemExit(130); returns the previous handler (for ``restore``)."""
    try:
        return signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:           # not the main thread: leave the interpreter's handling alone
        return None


def restore(previous) -> None:
    if previous is not None:
        with contextlib.suppress(ValueError):
            signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def children_ignore():
    """Processes started inside inherit SIGINT ignored (kept across exec: CPython installs its
    KeyboardInterrupt handler only where SIGINT is at its default)."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
