"""Atomic output: write to a temporary file beside the target, then rename over it.

A crash or a bad input never leaves a half-written output file. The temporary file's name
carries the writer's process id (``.NAME.PID.XXXX.tmp``); one left behind by a process that was
killed (SIGKILL cannot be caught) is removed by the next write to the same target, while the
temporaries of writers still running (concurrent runs) are left alone.

``atomic_dir`` does the same for a folder of outputs (``follow -o``, ``report --out``): the files
are written into a temporary sibling folder that then takes the target's place by rename, so the
folder changes all at once or not at all.

``check_output`` is the pre-flight of a command's ``-o``: an output that is a directory when a
file is expected (or the reverse), lies under a file, is not writable, is a device, FIFO or socket
(never replaced: ``-o /dev/null`` as root would replace the system's), or is or lies inside one of
the command's inputs is refused before any work is done. A disk that fills up while writing is a
one-line error naming the output; the old output stays as it was.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import stat
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
    """Remove ``.NAME.PID.*.tmp`` files (``.tmpdir`` / ``.old`` folders of ``atomic_dir``) beside
    ``target`` whose writing process is gone."""
    target = Path(target)
    pattern = re.compile(rf"^\.{re.escape(target.name)}\.(\d+)\.[^.]+\.(tmp|tmpdir|old)$")
    removed = []
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = pattern.match(p.name)
        if m and not _pid_alive(int(m.group(1))):
            with contextlib.suppress(OSError):
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink()
                removed.append(p)
    return removed


SPECIAL_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                 (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


def special_kind(path: str | Path) -> str | None:
    """What ``path`` is when it exists and is neither a regular file nor a directory (a symbolic
    link is followed): "a character device", "a FIFO (named pipe)", ...; None otherwise."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    return next((what for test, what in SPECIAL_KINDS if test(mode)), None)


def refuse_special_output(target: str | Path) -> None:
    kind = special_kind(target)
    if kind is not None:
        raise PedcalInputError(f"is {kind}, not a regular file or folder: pedcal never replaces one; "
                               "choose another output path", path=target)


# Errors of a write that has started: the device filled up, a quota, a file-size limit.
_SPACE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def _is_space_error(e: BaseException) -> bool:
    # pyarrow and some C writers raise OSError without errno, their text carrying strerror
    return isinstance(e, OSError) and (e.errno in _SPACE_ERRNOS or "No space left on device" in str(e)
                                       or "Disk quota exceeded" in str(e))


def _os_error(e: OSError, target: Path) -> PedcalInputError:
    if _is_space_error(e) and e.errno not in _SPACE_ERRNOS:
        e = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    what = {errno.EACCES: "permission denied", errno.EPERM: "permission denied",
            errno.EROFS: "read-only file system", errno.ENOSPC: "no space left on the device",
            errno.EISDIR: "is a directory, expected a file path",
            errno.ENOTDIR: "a parent of this path is a file, not a directory",
            errno.EDQUOT: "disk quota exceeded", errno.EFBIG: "file too large for the file system"}.get(
        e.errno, e.strerror or str(e))
    if e.errno in _SPACE_ERRNOS:
        what += " (the previous output, if any, is unchanged)"
    return PedcalInputError(f"cannot write output: {what}", path=target)


@contextlib.contextmanager
def atomic_path(target: str | Path):
    """Yield a temporary path in the target's directory; on success rename it to ``target``.

    An output that cannot be written (a directory, under a file, no permission) raises
    PedcalInputError naming it."""
    target = Path(target)
    refuse_special_output(target)
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
        try:
            yield tmp
        except OSError as e:
            if _is_space_error(e):
                raise _os_error(e, target) from None
            raise
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


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one step (Linux renameat2 RENAME_EXCHANGE); False where the
    system or the file system does not offer it."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


@contextlib.contextmanager
def atomic_dir(target: str | Path):
    """Yield a temporary folder beside ``target`` holding a copy of its present files; on success
    it takes ``target``'s place (one exchange of names where the system offers it, else two renames),
    so a reader sees the old folder or the new one, never a mix. On an error or an interrupt the
    temporary folder is removed and ``target`` is as it was."""
    target = Path(target)
    refuse_special_output(target)
    if target.exists() and not target.is_dir():
        raise PedcalInputError("is a file, expected a directory", path=target)
    parent = target.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(target)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".tmpdir", dir=parent))
    except (FileExistsError, NotADirectoryError):
        raise PedcalInputError("a parent of this path is a file, not a directory", path=target) from None
    except OSError as e:
        raise _os_error(e, target) from None
    old = None
    try:
        try:
            os.chmod(tmp, 0o777 & ~_umask())
            if target.is_dir():          # files of the folder the command does not rewrite are kept
                shutil.copytree(target, tmp, symlinks=True, dirs_exist_ok=True)
            yield tmp
        except OSError as e:
            if _is_space_error(e):
                raise _os_error(e, target) from None
            raise
        try:
            if not target.exists():
                os.rename(tmp, target)
            elif _exchange(tmp, target):
                old = tmp                # now holds the previous contents
            else:
                old = parent / f"{tmp.name[:-len('.tmpdir')]}.old"
                os.rename(target, old)
                try:
                    os.rename(tmp, target)
                except OSError:
                    os.rename(old, target)
                    old = None
                    raise
        except OSError as e:
            raise _os_error(e, target) from None
    finally:
        for p in {tmp, old} - {None}:
            if p.exists() and p != target:
                shutil.rmtree(p, ignore_errors=True)


def _inside(path: Path, other: Path) -> bool:
    return path == other or other in path.parents


def check_output(target: str | Path, *, inputs=(), directory: bool = False) -> Path:
    """Pre-flight of an output path, before any work: raises PedcalInputError when ``target``

    - is or lies inside one of ``inputs`` (files or directories the same command reads),
    - is a directory while a file is expected (``directory=False``), or a file while a directory is,
    - lies under an existing file, or its nearest existing folder is not writable,
    - is a device, FIFO or socket (never replaced).
    """
    target = Path(target)
    refuse_special_output(target)
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
