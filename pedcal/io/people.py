"""People trajectories CSV (LOG_FORMAT.md, "People trajectories"): columns t, person, x, y."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from pedcal.errors import PedcalInputError
from pedcal.io.logdir import read_table, write_table
from pedcal.model import PEOPLE_COLUMNS


def read_people_csv(path: str | Path) -> pd.DataFrame:
    """Read a people CSV (or .parquet); ``person`` is text; rows keep file order."""
    path = Path(path)
    if not path.is_file():
        raise PedcalInputError("file not found", path=path)
    return read_table(path, PEOPLE_COLUMNS, ("person",))


def write_people_csv(df: pd.DataFrame, path: str | Path) -> Path:
    """Write ``t, person, x, y`` (then any extra columns) atomically, floats exact."""
    missing = [c for c in PEOPLE_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"people table lacks column(s) {', '.join(missing)}")
    out = df[list(PEOPLE_COLUMNS) + [c for c in df.columns if c not in PEOPLE_COLUMNS]].reset_index(drop=True)
    out = out.astype({"person": str, "t": float, "x": float, "y": float})
    return write_table(out, Path(path))
