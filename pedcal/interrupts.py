"""Ctrl-C on the command line: one line and exit code 130, whenever it comes.

``install()`` (run by the command line's first import, and by ``main``) makes SIGINT raise
SystemExit(130) after printing ``interrupted``: a SystemExit passes every ``except Exception`` of
the work, runs the ``finally`` blocks that remove temporary outputs (pedcal.io.atomic), and is no
traceback, also while the first modules are being imported; a process started with SIGINT ignored
keeps ignoring it. A Ctrl-C whose handler runs where Python cannot raise (a weak reference's
callback, a finalizer: the exception is "ignored" and printed with a traceback, the work goes on)
is not lost: the unraisable hook installed beside the handler swallows that SystemExit and sets an
alarm a millisecond on, which the same handler answers in ordinary code.

``command_ended()`` (the command line's ``main``, at its end) ignores a Ctrl-C while the
interpreter shuts down: the command's own exit code stands.

``children_ignore()`` starts helper processes (Dask workers) with SIGINT
ignored: the terminal sends Ctrl-C to the whole process group, and the parent alone answers it,
by shutting its workers down.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys

EXIT_INTERRUPTED = 130


_announced = False        # "interrupted" is printed once, however often the handler must run
_logging_disabled = None  # logging's disable level before the handler silenced it (for ``restore``)


def _on_sigint(signum, frame):
    global _announced, _logging_disabled
    signal.signal(signal.SIGINT, signal.SIG_IGN)       # a second Ctrl-C does not interrupt the clean-up
    if _logging_disabled is None:
        _logging_disabled = logging.root.manager.disable
    logging.disable(logging.CRITICAL)     # the shutdown's own messages (Dask killing its workers) are noise now
    if not _announced:
        _announced = True
        try:
            print("interrupted", file=sys.stderr, flush=True)
        except (OSError, ValueError):
            pass
    raise SystemExit(EXIT_INTERRUPTED)


def _on_unraisable(unraisable) -> None:
    """Our SystemExit raised where it cannot propagate (a weakref callback, ``__del__``): the same
    handler fired again by a SIGALRM a millisecond on, to answer outside; anything else goes to the
    hook before us."""
    exc = unraisable.exc_value
    if isinstance(exc, SystemExit) and exc.code == EXIT_INTERRUPTED and _announced:
        # not SIGINT now: its handler would run inside this hook (Python checks a signal sent to itself
        # at once), and be ignored again; an alarm a millisecond on finds ordinary code running
        # (a plain try: no Python frame of a context manager runs after the alarm is set)
        global _previous_alarm
        try:
            previous = signal.signal(signal.SIGALRM, _on_sigint)
            if previous is not _on_sigint and previous is not None:    # (None: set from C, not ours to give back)
                _previous_alarm = previous
            signal.setitimer(signal.ITIMER_REAL, 0.001)
        except (ValueError, OSError, AttributeError):      # (main thread only; POSIX only)
            pass
        return
    _previous_unraisablehook(unraisable)


_previous_unraisablehook = sys.unraisablehook
_NO_ALARM = object()
_previous_alarm = _NO_ALARM    # SIGALRM's handler before the hook took it (``restore`` gives it back)


def caused_by_interrupt(error: BaseException) -> bool:
    """``error`` was raised because of the SystemExit of a Ctrl-C (``_on_sigint``): somewhere in its
    chain of causes (an extension module's initialization turns it into ImportError)."""
    seen = set()
    e = error
    while e is not None and id(e) not in seen:
        if isinstance(e, SystemExit) and e.code == EXIT_INTERRUPTED:
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def install():
    """SIGINT -> one line and SystemExit(130); returns the previous handler (for ``restore``)."""
    try:
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:   # started with Ctrl-C ignored (nohup, a background job)
            return None
        previous = signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:           # not the main thread: leave the interpreter's handling alone
        return None
    global _previous_unraisablehook
    if sys.unraisablehook is not _on_unraisable:
        _previous_unraisablehook = sys.unraisablehook
        sys.unraisablehook = _on_unraisable
    return previous


def restore(previous) -> None:
    """The SIGINT handler and unraisable hook as before ``install``; a caller that lives on after
    a Ctrl-C (``main`` called from Python) gets its logging back and its next Ctrl-C announced."""
    global _announced, _logging_disabled, _previous_alarm
    with contextlib.suppress(ValueError, OSError, AttributeError):      # (main thread only; POSIX only)
        if signal.getsignal(signal.SIGALRM) is _on_sigint:       # the hook's alarm cancelled, its handler given back
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            if _previous_alarm is not _NO_ALARM:
                signal.signal(signal.SIGALRM, _previous_alarm)
    _previous_alarm = _NO_ALARM
    _announced = False
    if _logging_disabled is not None:
        logging.disable(_logging_disabled)
        _logging_disabled = None
    if previous is not None:
        with contextlib.suppress(ValueError):
            signal.signal(signal.SIGINT, previous)
        if sys.unraisablehook is _on_unraisable:
            sys.unraisablehook = _previous_unraisablehook


def command_ended() -> None:
    """The command line's work is over (its outputs written, its exit code set): a Ctrl-C from now
    on, while the interpreter shuts down, is ignored. The handler would not run there (the
    interpreter's finalization gives SIGINT its default back, which ended the process by the
    signal, its outputs complete, without a word); the command's own code stands instead. A Ctrl-C
    that came before, whose handler ran in a finalizer and left the hook's alarm pending, ends the
    command here (130, as announced): the alarm, left to the shutdown, would kill the process."""
    with contextlib.suppress(ValueError):        # (main thread only)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if signal.getsignal(signal.SIGALRM) is _on_sigint:     # the hook's alarm, still pending
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            raise SystemExit(EXIT_INTERRUPTED)


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


def running_the_command_line() -> bool:
    """This process is ``python -m pedcal.cli`` or the ``pedcal`` script (not a library user)."""
    import os

    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    return getattr(spec, "name", None) == "pedcal.cli" or os.path.basename(sys.argv[0] if sys.argv else "") in (
        "pedcal", "pedcal.exe")


# The command line imports this module before anything heavy, so that a Ctrl-C while the rest loads
# is already one line; a library user's SIGINT handling is left alone.
if running_the_command_line():
    install()
