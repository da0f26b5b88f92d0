"""Reading an input file defensively: only a regular file is read (a FIFO would block forever,
``/dev/zero`` would fill memory, a socket or a device is no file of data), and never more bytes
than the format can sensibly hold. Every text reader of pedcal (YAML, TOML, JSON labels) and the
table readers share this check.
"""

from __future__ import annotations

from pathlib import Path

from pedcal.errors import PedcalInputError
from pedcal.io.atomic import special_kind

# sensors.yaml of 10 000 sensors is ~2 MB, a graph recipe or a label file a few kB.
MAX_TEXT_BYTES = 64 * 1024 ** 2


def regular_file(path: str | Path, what: str = "file") -> Path:
    """``path`` as a Path when it is a regular file (a symbolic link to one is followed); a missing
    path, a directory, a device, FIFO or socket raise PedcalInputError naming it."""
    path = Path(path)
    if path.is_dir():
        raise PedcalInputError(f"is a directory, expected a {what}", path=path)
    kind = special_kind(path)
    if kind is not None:
        raise PedcalInputError(f"is {kind}, expected a regular {what} (pedcal reads only regular files)", path=path)
    if not path.is_file():
        raise PedcalInputError(f"{what} not found", path=path)
    return path


def read_bytes_capped(path: str | Path, what: str = "file", max_bytes: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``; larger files, unreadable ones and the
    checks of ``regular_file`` raise PedcalInputError naming the file."""
    path = regular_file(path, what)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except PermissionError:
        raise PedcalInputError("cannot read: permission denied", path=path) from None
    except OSError as e:
        raise PedcalInputError(f"cannot read: {e.strerror or e}", path=path) from None
    if len(data) > max_bytes:
        raise PedcalInputError(f"larger than {max_bytes / 1024 ** 2:g} MB, more than a {what} holds "
                               "(a wrong file?)", path=path)
    return data
