"""People trajectories CSV (LOG_FORMAT.md, "People trajectories"): columns t, person, x, y."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from pedcal.errors import PedcalInputError
from pedcal.io.logdir import check_coordinates, check_times, read_table, typed_table, write_table
from pedcal.model import PEOPLE_COLUMNS
from pedcal.options import require_path


def read_people_csv(path: str | Path) -> pd.DataFrame:
    """Read a people CSV (or .parquet); ``person`` is text; rows keep file order."""
    path = require_path(path, "path")
    if not path.is_file():
        raise PedcalInputError("file not found", path=path)
    if path.is_dir():
        raise PedcalInputError("is a directory, expected a people CSV file", path=path)
    return validate_people(read_table(path, PEOPLE_COLUMNS, ("person",)), path)


def validate_people(people: pd.DataFrame, where="people table") -> pd.DataFrame:
    """A people table typed (``t`` s, ``person`` text, ``x, y`` m) with plausible times (seconds)
    and coordinates; errors name ``where`` (a file or a table), the row and the column."""
    people = typed_table(people, PEOPLE_COLUMNS, ("person",), where)
    check_times(people, where)
    check_coordinates(people, ("x", "y"), where)
    return people


def write_people_csv(df: pd.DataFrame, path: str | Path) -> Path:
    """Write ``t, person, x, y`` (then any extra columns) atomically, floats exact."""
    missing = [c for c in PEOPLE_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"people table lacks column(s) {', '.join(missing)}")
    out = df[list(PEOPLE_COLUMNS) + [c for c in df.columns if c not in PEOPLE_COLUMNS]].reset_index(drop=True)
    out = out.astype({"person": str, "t": float, "x": float, "y": float})
    validate_people(out)           # NaN, 1e300 or nanosecond stamps would not read back
    return write_table(out, Path(path))
