"""Reading an input file defensively: only a regular file is read (a FIFO would block forever,
``/dev/zero`` would fill memory, a socket or a device is no file of data), and never more bytes
than the format can sensibly hold. Every text reader of pedcal (YAML, TOML, JSON labels) and the
table readers share this check.
"""

from __future__ import annotations

import os
from pathlib import Path

from pedcal.errors import PedcalInputError, show
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


def not_utf8_text(path: str | Path, chunk_bytes: int = 1 << 20) -> str | None:
    """Where a text file stops being UTF-8, as a message's words ("byte 0xe9 on line 500, at
    offset 18391"), or None when all of it is (a parser's own decoding error gives an offset within
    its buffer, not the file)."""
    base, line, carry = 0, 1, b""
    with open(path, "rb") as f:
        while True:
            chunk = f.read(chunk_bytes)
            data = carry + chunk
            try:
                data.decode("utf-8")
                good, carry = data, b""
            except UnicodeDecodeError as e:
                if chunk and e.end == len(data) and e.reason == "unexpected end of data":
                    good, carry = data[: e.start], data[e.start:]     # a character cut at the chunk's end
                else:
                    line += data[: e.start].count(b"\n")
                    return f"byte 0x{data[e.start]:02x} on line {line}, at offset {base + e.start}"
            if not chunk:
                return None
            line += good.count(b"\n")
            base += len(good)


def not_utf8_error(path: str | Path, error: UnicodeDecodeError, advice: str) -> PedcalInputError:
    """The error of a text file that is not UTF-8: "not UTF-8 text (byte 0xe9 on line 500, at offset
    18391): ``advice``", the byte located in the file itself (a parser's or the utf-8-sig codec's
    offset is within its buffer, after a BOM), or only the decoding error's byte when the file no
    longer holds one that is not UTF-8."""
    where = not_utf8_text(path) or f"byte 0x{error.object[error.start]:02x}"
    return PedcalInputError(f"not UTF-8 text ({where}): {advice}", path=path)


class CsvTable(os.PathLike):
    """A CSV table's file, for errors: a PedcalInputError given it as ``path`` and a 0-based data
    ``row`` also names the row's line in the file, as pandas read it (one header line, blank lines
    skipped, a quoted cell may span lines). Reads as the path it holds (``str``, ``os.fspath``)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def __fspath__(self) -> str:
        return str(self.path)

    def __str__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"CsvTable({str(self.path)!r})"

    def line_of_row(self, row: int) -> int | None:
        """The 1-based line on which data row ``row`` starts, or None if the file no longer has it."""
        import csv

        record, end = -1, 0                 # record 0 is the header
        try:
            with open(self.path, encoding="utf-8-sig", errors="replace", newline="") as f:
                reader = csv.reader(f)
                for cells in reader:
                    start, end = end + 1, reader.line_num
                    if not cells or (len(cells) == 1 and not cells[0].strip()):
                        continue            # a blank line, which pandas skips
                    record += 1
                    if record == row + 1:
                        return start
        except (OSError, csv.Error):
            return None
        return None


def header_cells(path: str | Path) -> list[str]:
    """A comma-separated table's header as written: the cells of its first non-blank line,
    unstripped, read by pandas as the table itself is read (quotes, a BOM). pandas' own header
    renames a repeated ``x`` to ``x.1``, which would pass unseen."""
    import pandas as pd

    first = pd.read_csv(path, header=None, nrows=1, dtype=str, na_filter=False)
    return [str(n) for n in first.iloc[0]]


def refuse_repeated_columns(names: list[str], columns, path, *, in_header: bool = True) -> None:
    """A column of ``columns`` named twice in ``names`` (as written, stripped: pandas renames a
    CSV header's repeat ``x`` to ``x.1``) raises PedcalInputError naming it: which one is meant?"""
    repeated = [c for c in columns if names.count(c) > 1]
    if repeated:
        raise PedcalInputError(f"column {show(repeated[0])} appears {names.count(repeated[0])} times"
                               f"{' in the header' if in_header else ''}; keep one", path=path, column=repeated[0])


def read_json(path: str | Path, what: str = "JSON file", max_bytes: int = MAX_TEXT_BYTES):
    """A JSON file's value; a file that is no regular file, too large, not UTF-8, not JSON, nested
    beyond the parser's recursion limit or holding an integer of thousands of digits raises
    PedcalInputError naming it."""
    import json

    data = read_bytes_capped(path, what, max_bytes)
    try:
        return json.loads(data.decode("utf-8-sig"))
    except UnicodeDecodeError as e:
        raise not_utf8_error(path, e, f"a binary file, or a {what} saved in another encoding") from None
    except json.JSONDecodeError as e:
        raise PedcalInputError(f"not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}", path=path) from None
    except RecursionError:
        raise PedcalInputError("not a usable JSON file: nested too deeply", path=path) from None
    except ValueError as e:          # an integer beyond Python's digit limit
        raise PedcalInputError(f"not a usable JSON file: {str(e)[:120]}", path=path) from None


def check_records(records: list[dict], path, *, finite=(), positive=()) -> list[dict]:
    """Each record's ``finite`` fields are finite numbers and its ``positive`` fields finite and > 0
    (a box of negative, NaN or infinite size is no box); else PedcalInputError naming the row."""
    import math

    for row, rec in enumerate(records):
        for name in (*finite, *positive):
            v = rec[name]
            if not math.isfinite(v) or (name in positive and v <= 0):
                want = "a finite number > 0" if name in positive else "a finite number"
                raise PedcalInputError(f"{name} = {v!r}: expected {want}", path=path, row=row, column=name)
    return records
