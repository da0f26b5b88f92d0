"""Atomic output: write to a temporary file beside the target, then rename over it.

A crash or a bad input never leaves a half-written output file. The temporary file's name
carries the writer's process id (``.NAME.PID.XXXX.tmp``); one left behind by a process that was
killed (SIGKILL cannot be caught) is removed by the next write to the same target, while the
temporaries of writers still running (concurrent runs) are left alone.

``check_output`` is the pre-flight of a command's ``-o``: an output that is a directory when a
file is expected (or the reverse), lies under a file, is not writable, or is or lies inside one of
the command's inputs is refused before any work is done.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import tempfile
from pathlib import Path

from pedcal.errors import PedcalInputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:      # alive, another user's
        return True
    return True


def remove_stale_temporaries(target: str | Path) -> list[Path]:
    """Remove ``.NAME.PID.*.tmp`` files beside ``target`` whose writing process is gone."""
    target = Path(target)
    pattern = re.compile(rf"^\.{re.escape(target.name)}\.(\d+)\.[^.]+\.tmp$")
    removed = []
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = pattern.match(p.name)
        if m and not _pid_alive(int(m.group(1))):
            with contextlib.suppress(OSError):
                p.unlink()
                removed.append(p)
    return removed


def _os_error(e: OSError, target: Path) -> PedcalInputError:
    what = {errno.EACCES: "permission denied", errno.EPERM: "permission denied",
            errno.EROFS: "read-only file system", errno.ENOSPC: "no space left on the device",
            errno.EISDIR: "is a directory, expected a file path",
            errno.ENOTDIR: "a parent of this path is a file, not a directory"}.get(e.errno, e.strerror or str(e))
    return PedcalInputError(f"cannot write output: {what}", path=target)


@contextlib.contextmanager
def atomic_path(target: str | Path):
    """Yield a temporary path in the target's directory; on success rename it to ``target``.

    An output that cannot be written (a directory, under a file, no permission) raises
    PedcalInputError naming it."""
    target = Path(target)
    if target.is_dir():
        raise PedcalInputError("is a directory, expected a file path", path=target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(target)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".tmp", dir=target.parent)
    except (FileExistsError, NotADirectoryError):
        raise PedcalInputError("a parent of this path is a file, not a directory", path=target) from None
    except OSError as e:
        raise _os_error(e, target) from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        # mkstemp creates the file owner-only (0600); give it the mode a plain open() would.
        if tmp.exists():
            os.chmod(tmp, 0o666 & ~_umask())
        try:
            os.replace(tmp, target)
        except OSError as e:
            raise _os_error(e, target) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text_atomic(target: str | Path, text: str) -> None:
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _inside(path: Path, other: Path) -> bool:
    return path == other or other in path.parents


def check_output(target: str | Path, *, inputs=(), directory: bool = False) -> Path:
    """Pre-flight of an output path, before any work: raises PedcalInputError when ``target``

    - is or lies inside one of ``inputs`` (files or directories the same command reads),
    - is a directory while a file is expected (``directory=False``), or a file while a directory is,
    - lies under an existing file, or its nearest existing folder is not writable.
    """
    target = Path(target)
    resolved = target.resolve()
    for inp in inputs:
        if inp is None:
            continue
        src = Path(inp).resolve()
        if _inside(resolved, src):
            what = "is" if resolved == src else "lies inside"
            raise PedcalInputError(f"output {what} the input {inp} of this command; choose an output "
                                   "outside the inputs (nothing was written)", path=target)
    if target.exists():
        if directory and not target.is_dir():
            raise PedcalInputError("is a file, expected a directory", path=target)
        if not directory and target.is_dir():
            raise PedcalInputError("is a directory, expected a file path", path=target)
    parent = resolved if directory else resolved.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise PedcalInputError(f"cannot write output: {parent} is a file, not a directory", path=target)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PedcalInputError(f"cannot write output: permission denied in {parent}", path=target)
    return target
