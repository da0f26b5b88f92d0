"""People trajectories CSV (LOG_FORMAT.md, "People trajectories"): columns t, person, x, y."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import DegenerateDataWarning, PedcalInputError, show
from pedcal.io.inputs import regular_file
from pedcal.io.logdir import check_coordinates, check_times, read_table, table_source, typed_table, write_table
from pedcal.model import PEOPLE_COLUMNS
from pedcal.options import require_path


def read_people_csv(path: str | Path) -> pd.DataFrame:
    """Read a people CSV (or .parquet); ``person`` is text; rows keep file order."""
    path = regular_file(require_path(path, "path"), "people CSV file")
    return validate_people(read_table(path, PEOPLE_COLUMNS, ("person",)), table_source(path))


def validate_people(people: pd.DataFrame, where="people table", *, drop_repeats: bool = True) -> pd.DataFrame:
    """A people table typed (``t`` s, ``person`` text, ``x, y`` m) with plausible times (seconds)
    and coordinates; errors name ``where`` (a file or a table), the row and the column. A person
    placed twice at one time is refused when the places differ (which is the person's?); a row
    repeating an earlier one whole is dropped (``drop_repeats``), a warning counting them."""
    people = typed_table(people, PEOPLE_COLUMNS, ("person",), where)
    check_times(people, where)
    check_coordinates(people, ("x", "y"), where)
    return _repeated_samples(people, where, drop_repeats)


def _repeated_samples(people: pd.DataFrame, where, drop: bool) -> pd.DataFrame:
    at_time = people.duplicated(["person", "t"]).to_numpy()
    if not at_time.any():
        return people
    whole = people.duplicated(list(PEOPLE_COLUMNS)).to_numpy()
    conflict = np.flatnonzero(at_time & ~whole)
    if len(conflict):
        row = int(conflict[0])
        person, t = people["person"].iloc[row], float(people["t"].iloc[row])
        first = int(np.flatnonzero((people["person"] == person).to_numpy() & (people["t"] == t).to_numpy())[0])
        x, y = people["x"].to_numpy(), people["y"].to_numpy()
        raise PedcalInputError(f"person {show(person)} at t = {t!r} s is placed twice, at ({x[first]:g}, {y[first]:g}) "
                               f"in row {first} and ({x[row]:g}, {y[row]:g}) here; keep one", path=where, row=row,
                               column="t")
    if not drop:
        return people
    warnings.warn(f"{where}: {int(whole.sum())} row(s) repeating an earlier row whole (person, t, x, y) dropped "
                  f"(the first: row {int(np.flatnonzero(whole)[0])})", DegenerateDataWarning, stacklevel=3)
    return people[~whole].reset_index(drop=True)


def write_people_csv(df: pd.DataFrame, path: str | Path) -> Path:
    """Write ``t, person, x, y`` (then any extra columns) atomically, floats exact."""
    missing = [c for c in PEOPLE_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"people table lacks column(s) {', '.join(missing)}")
    out = df[list(PEOPLE_COLUMNS) + [c for c in df.columns if c not in PEOPLE_COLUMNS]].reset_index(drop=True)
    out = out.astype({"person": str, "t": float, "x": float, "y": float})
    validate_people(out, drop_repeats=False)   # NaN, 1e300, nanosecond stamps, one person in two places: unreadable
    return write_table(out, Path(path))
