"""Errors a user can cause. The CLI turns these into a message and exit code 2."""

from __future__ import annotations

import functools
import reprlib
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

F = TypeVar("F", bound=Callable)


class PedcalInputError(ValueError):
    """Bad input: names the file, and where known the row and column, and what was expected.

    ``row`` is the 0-based data row (the header is not counted), as in truth_observations.csv.
    Where ``path`` can tell the row's line in the file (a CSV table, pedcal.io.inputs.CsvTable,
    has ``line_of_row``), ``line`` is that 1-based line and the message says "row 8 (line 10)".
    """

    def __init__(self, message: str, *, path: str | Path | None = None, row: int | None = None,
                 column: str | None = None):
        self.path = None if path is None else str(path)
        self.row = row
        self.column = column
        line_of_row = getattr(path, "line_of_row", None)
        self.line = None if row is None or line_of_row is None else line_of_row(row)
        where = []
        if self.path is not None:
            where.append(self.path)
        if row is not None:
            where.append(f"row {row}" if self.line is None else f"row {row} (line {self.line})")
        if column is not None:
            where.append(f"column '{column}'")
        self.detail = message
        super().__init__(f"{': '.join([', '.join(where), message]) if where else message}")


class DegenerateDataWarning(UserWarning):
    """The data leave something unestimable; the message says what."""


def warnings_at_caller(func: F) -> F:
    """Decorate a public entry point: the warnings raised while it runs are re-raised at the line
    that called it (under the caller's warning filters), not at the line inside pedcal that found
    the problem, so ``-W error`` and per-module filters work on the user's script."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = func(*args, **kwargs)
        for w in caught:
            warnings.warn(w.message, w.category, stacklevel=2)
        return result

    return wrapper  # type: ignore[return-value]


def show(value, limit: int = 40) -> str:
    """A value as a message quotes it: plain numbers (never ``np.float64(...)``), text quoted and
    cut to ``limit`` characters with unprintable characters escaped (a binary file's bytes are
    not dumped into a message). A list, tuple, dict or set is shown item by item, each item so
    (``[0, 'abc', nan]``, not the quoted text of its Python form), within reprlib's bounds: two
    levels, 6 items of a list, 4 of a dict, items cut to 20 characters, None as None, and the whole cut
    to ``4 * limit`` characters (a YAML alias bomb, a nest of long strings, prints small)."""
    import numbers

    if isinstance(value, bool):
        return str(value)
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))
    if isinstance(value, _CONTAINERS):
        text = _Brief(min(limit, 20)).repr(value)
        return text if len(text) <= 4 * limit else text[: 4 * limit] + "..."
    text = value.decode("latin-1") if isinstance(value, bytes) else str(value)
    escaped = text.encode("unicode_escape").decode("ascii").replace("'", "\\'")
    cut = len(escaped) > limit
    return f"'{escaped[:limit]}'" + ("..." if cut else "")


_CONTAINERS = (list, tuple, dict, set, frozenset)


class _Brief(reprlib.Repr):
    """reprlib's bounded rendering of containers, with every item that is no container by ``show``."""

    def __init__(self, item_limit: int):
        super().__init__()
        self.maxlevel, self.maxlist, self.maxtuple, self.maxdict, self.maxset = 2, 6, 6, 4, 6
        self.maxfrozenset = 6
        self.item_limit = item_limit

    def repr1(self, x, level):
        if isinstance(x, _CONTAINERS):
            return super().repr1(x, level)
        if x is None:       # a YAML null, not the text 'None'
            return "None"
        return show(x, self.item_limit)
