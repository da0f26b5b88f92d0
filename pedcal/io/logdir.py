"""Log directories, format version 1 (docs/LOG_FORMAT.md): reading with validation, writing atomically.

Every table may be ``<name>.csv`` or ``<name>.parquet`` (not both). Column order is free and
extra columns are ignored. Observations keep file order (truth_observations.csv refers to their
0-based data rows); the pose tables (robot, odometry, truth_robot) are returned sorted by time.
Errors name the file, the 0-based data row and the column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import PedcalInputError
from pedcal.io.atomic import atomic_path, write_text_atomic
from pedcal.io.sensors_yaml import (
    dump_yaml,
    flow_vector,
    load_yaml_file,
    read_sensors_yaml,
    read_vector,
    write_sensors_yaml,
)
from pedcal.model import (
    OBSERVATION_COLUMNS,
    ODOMETRY_COLUMNS,
    ROBOT_COLUMNS,
    TRUTH_OBSERVATION_COLUMNS,
    TRUTH_ROBOT_COLUMNS,
    Log,
    Meta,
    SensorNetwork,
)

TABLE_FORMATS = ("csv", "parquet")
VARIANCE_COLUMNS = ("cov_xx", "cov_yy", "cov_yawyaw")
# Table name -> (columns, text columns); every other column is a float.
TABLES = {
    "robot": (ROBOT_COLUMNS, ()),
    "observations": (OBSERVATION_COLUMNS, ("sensor", "track")),
    "odometry": (ODOMETRY_COLUMNS, ()),
    "truth_robot": (TRUTH_ROBOT_COLUMNS, ()),
    "truth_observations": (TRUTH_OBSERVATION_COLUMNS, ("who",)),
}
INTEGER_COLUMNS = {"row"}


# ------------------------------------------------------------------------------------ table reading
def find_table(directory: Path, name: str, *, required: bool) -> Path | None:
    """The one file holding table ``name`` in ``directory`` (.csv or .parquet)."""
    found = [directory / f"{name}.{ext}" for ext in TABLE_FORMATS if (directory / f"{name}.{ext}").is_file()]
    if len(found) > 1:
        raise PedcalInputError(f"both {found[0].name} and {found[1].name} exist; keep one of them",
                               path=found[0])
    if not found:
        if required:
            raise PedcalInputError(f"required file missing (expected {name}.csv or {name}.parquet)",
                                   path=directory / f"{name}.csv")
        return None
    return found[0]


def _raw_table(path: Path) -> pd.DataFrame:
    try:
        if path.suffix == ".parquet":
            return pd.read_parquet(path, engine="pyarrow")
        # Everything as text first, so a bad cell can be located and floats parse exactly.
        return pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        return pd.DataFrame()
    except (pd.errors.ParserError, UnicodeDecodeError, OSError, ValueError) as e:
        raise PedcalInputError(f"cannot read table: {e}", path=path) from None


def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def parse_float_column(values: pd.Series, path: Path, column: str) -> np.ndarray:
    """Finite floats; the first empty, NaN, infinite or non-numeric cell is reported by row."""
    if pd.api.types.is_numeric_dtype(values.dtype) and not pd.api.types.is_bool_dtype(values.dtype):
        out = values.to_numpy(dtype=float, na_value=np.nan)
    else:
        try:   # fast path: every cell parses (Python's correctly rounded float(), so CSV round trips exactly)
            out = values.to_numpy(dtype=object).astype(float)
        except (ValueError, TypeError):
            out = _locate_bad_number(values, path, column)
    if not np.isfinite(out).all():
        row = _first_bad(~np.isfinite(out))
        raise PedcalInputError(f"expected a finite number, got {out[row]}", path=path, row=row, column=column)
    return out


def _locate_bad_number(values: pd.Series, path: Path, column: str) -> np.ndarray:
    """Slow path of parse_float_column: find and report the first cell that is not a number."""
    text = values.astype(object).where(values.notna(), "").astype(str).str.strip()
    empty = (text == "").to_numpy()
    if empty.any():
        row = _first_bad(empty)
        raise PedcalInputError("empty cell, expected a number", path=path, row=row, column=column)
    out = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
    bad = np.isnan(out) & ~text.str.lower().isin(["nan", "+nan", "-nan"]).to_numpy()
    if bad.any():
        row = _first_bad(bad)
        raise PedcalInputError(f"expected a number, got {text.iloc[row]!r}", path=path, row=row,
                               column=column)
    return out


def parse_text_column(values: pd.Series, path: Path, column: str) -> pd.Series:
    """Non-empty strings (ints such as track 3 or sensor 1 become "3", "1")."""
    missing = values.isna().to_numpy()
    text = values.astype(object).where(~missing, "")
    if pd.api.types.is_float_dtype(values.dtype):   # a Parquet column of whole numbers stored as float
        text = pd.Series(["" if m else str(int(v)) if float(v).is_integer() else repr(float(v))
                          for v, m in zip(values, missing, strict=True)], index=values.index, dtype=object)
    text = text.astype(str).str.strip()
    empty = (text == "").to_numpy() | missing
    if empty.any():
        raise PedcalInputError("empty cell, expected an id", path=path, row=_first_bad(empty), column=column)
    return text.astype(str)


def read_table(path: Path, columns: tuple[str, ...], text_columns: tuple[str, ...] = (),
               *, required: bool = True) -> pd.DataFrame:
    """Read one table with exactly ``columns`` (in that order) and validated cell types."""
    raw = _raw_table(path)
    raw.columns = [str(c).strip() for c in raw.columns]
    missing = [c for c in columns if c not in raw.columns]
    if missing:
        raise PedcalInputError(f"missing required column(s) {', '.join(missing)}; "
                               f"expected {', '.join(columns)}, found {', '.join(raw.columns) or 'none'}",
                               path=path, column=missing[0])
    if required and len(raw) == 0:
        raise PedcalInputError("table has no data rows", path=path)
    out = {}
    for c in columns:
        if c in text_columns:
            out[c] = parse_text_column(raw[c], path, c)
        else:
            v = parse_float_column(raw[c], path, c)
            if c in INTEGER_COLUMNS:
                if (v != np.round(v)).any():
                    row = _first_bad(v != np.round(v))
                    raise PedcalInputError(f"expected an integer, got {v[row]}", path=path, row=row, column=c)
                v = v.astype(np.int64)
            out[c] = v
    return pd.DataFrame(out, index=pd.RangeIndex(len(raw)))


# ---------------------------------------------------------------------------------------- checks
def check_unique_times(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """Pose tables: no repeated ``t``; returned sorted by time (stable)."""
    dup = df["t"].duplicated().to_numpy()
    if dup.any():
        row = _first_bad(dup)
        first = int(np.flatnonzero(df["t"].to_numpy() == df["t"].iloc[row])[0])
        raise PedcalInputError(f"time {df['t'].iloc[row]!r} repeats row {first}; each pose needs its own t",
                               path=path, row=row, column="t")
    return df.sort_values("t", kind="stable").reset_index(drop=True)


def check_variances(df: pd.DataFrame, path: Path) -> None:
    for c in VARIANCE_COLUMNS:
        neg = df[c].to_numpy() < 0
        if neg.any():
            row = _first_bad(neg)
            raise PedcalInputError(f"negative variance {df[c].iloc[row]!r}, expected >= 0", path=path,
                                   row=row, column=c)


def check_track_clocks(obs: pd.DataFrame, path: Path) -> None:
    """Within one (sensor, track), in file order, t strictly increases."""
    dt = obs.groupby(["sensor", "track"], sort=False)["t"].diff().to_numpy()
    back = dt <= 0   # NaN (first row of a track) compares False
    if back.any():
        row = _first_bad(back)
        s, k = obs["sensor"].iloc[row], obs["track"].iloc[row]
        raise PedcalInputError(f"time {obs['t'].iloc[row]!r} of sensor '{s}' track '{k}' does not increase "
                               f"(that track's previous row is {obs['t'].iloc[row] - dt[row]!r}); "
                               "within a track t must strictly increase in file order",
                               path=path, row=row, column="t")


def check_known_sensors(obs: pd.DataFrame, network: SensorNetwork, path: Path, yaml_path: Path) -> None:
    unknown = ~obs["sensor"].isin(network.ids).to_numpy()
    if unknown.any():
        row = _first_bad(unknown)
        raise PedcalInputError(f"unknown sensor id '{obs['sensor'].iloc[row]}' (not in {yaml_path.name}: "
                               f"{', '.join(network.ids)})", path=path, row=row, column="sensor")


def check_truth_rows(truth_obs: pd.DataFrame, n_observations: int, path: Path) -> None:
    rows = truth_obs["row"].to_numpy()
    bad = (rows < 0) | (rows >= n_observations)
    if bad.any():
        r = _first_bad(bad)
        raise PedcalInputError(f"row {rows[r]} out of range: observations has {n_observations} data rows "
                               f"(0..{n_observations - 1})", path=path, row=r, column="row")
    dup = truth_obs["row"].duplicated().to_numpy()
    if dup.any():
        r = _first_bad(dup)
        raise PedcalInputError(f"observation row {rows[r]} is labelled twice", path=path, row=r, column="row")


# ---------------------------------------------------------------------------------------- meta.yaml
def read_meta(path: Path) -> Meta:
    data, _ = load_yaml_file(path)
    if data is None:
        return Meta()
    if not isinstance(data, dict):
        raise PedcalInputError("expected a mapping (head_offset: [x, y, z], notes...)", path=path)
    notes = {k: v for k, v in data.items() if k != "head_offset"}
    if data.get("head_offset") is None:
        return Meta(notes=notes)
    return Meta(head_offset_m=read_vector(data["head_offset"], 3, "head_offset", path), notes=notes)


def meta_yaml_text(meta: Meta) -> str:
    data = {"head_offset": flow_vector(meta.head_offset_m)}
    data.update({k: v for k, v in meta.notes.items() if k != "head_offset"})
    return dump_yaml(data)


# ---------------------------------------------------------------------------------------- log dirs
def read_log(path: str | Path) -> Log:
    """Read and validate a log directory (LOG_FORMAT.md). Bad input raises PedcalInputError."""
    directory = Path(path)
    if not directory.is_dir():
        raise PedcalInputError("log directory not found" if not directory.exists() else
                               "expected a log directory (sensors.yaml, robot.csv, observations.csv)",
                               path=directory)
    sensors_path = directory / "sensors.yaml"
    if not sensors_path.is_file():
        raise PedcalInputError("required file missing", path=sensors_path)
    sensors = read_sensors_yaml(sensors_path)

    def table(name: str, required: bool) -> tuple[pd.DataFrame | None, Path | None]:
        p = find_table(directory, name, required=required)
        if p is None:
            return None, None
        columns, text_columns = TABLES[name]
        return read_table(p, columns, text_columns, required=required), p

    robot, robot_path = table("robot", True)
    check_variances(robot, robot_path)
    robot = check_unique_times(robot, robot_path)

    obs, obs_path = table("observations", True)
    check_known_sensors(obs, sensors, obs_path, sensors_path)
    check_track_clocks(obs, obs_path)

    odometry, odo_path = table("odometry", False)
    if odometry is not None:
        odometry = check_unique_times(odometry, odo_path)
    truth_robot, truth_robot_path = table("truth_robot", False)
    if truth_robot is not None:
        truth_robot = check_unique_times(truth_robot, truth_robot_path)
    truth_obs, truth_obs_path = table("truth_observations", False)
    if truth_obs is not None:
        check_truth_rows(truth_obs, len(obs), truth_obs_path)

    meta_path = directory / "meta.yaml"
    meta = read_meta(meta_path) if meta_path.is_file() else Meta()
    truth_path = directory / "truth.yaml"
    truth = read_sensors_yaml(truth_path) if truth_path.is_file() else None
    return Log(sensors=sensors, robot=robot, observations=obs, odometry=odometry, meta=meta, truth=truth,
               truth_robot=truth_robot, truth_observations=truth_obs, path=directory)


def table_for_writing(df: pd.DataFrame, name: str) -> pd.DataFrame:
    """The format's columns first (text columns as str), then any extra columns the caller added."""
    columns, text_columns = TABLES[name]
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{name} table lacks column(s) {', '.join(missing)} (LOG_FORMAT.md)")
    out = df[list(columns) + [c for c in df.columns if c not in columns]].reset_index(drop=True)
    out = out.astype({c: str for c in text_columns})
    return out.astype({c: float for c in columns if c not in text_columns and c not in INTEGER_COLUMNS})


def write_table(df: pd.DataFrame, path: Path) -> Path:
    """One table, atomically; CSV floats use the shortest exact representation (round trip exact)."""
    with atomic_path(path) as tmp:
        if path.suffix == ".parquet":
            df.to_parquet(tmp, engine="pyarrow", index=False)
        else:
            df.to_csv(tmp, index=False, lineterminator="\n")
    return path


def write_log(log: Log, path: str | Path, fmt: str = "csv") -> dict[str, Path]:
    """Write ``log`` as a log directory; tables as ``fmt`` (csv or parquet). Returns name -> file.

    Each file is written atomically. A table file of the other format, or of an optional table the
    log does not hold, is removed so that the directory reads back as exactly this log.
    """
    if fmt not in TABLE_FORMATS:
        raise ValueError(f"fmt must be one of {TABLE_FORMATS}, got {fmt!r}")
    directory = Path(path)
    directory.mkdir(parents=True, exist_ok=True)
    tables = {"robot": log.robot, "observations": log.observations, "odometry": log.odometry,
              "truth_robot": log.truth_robot, "truth_observations": log.truth_observations}
    written: dict[str, Path] = {}
    written["sensors"] = write_sensors_yaml(log.sensors, directory / "sensors.yaml")
    for name, df in tables.items():
        if df is not None:
            written[name] = write_table(table_for_writing(df, name), directory / f"{name}.{fmt}")
    meta_path = directory / "meta.yaml"
    write_text_atomic(meta_path, meta_yaml_text(log.meta if log.meta is not None else Meta()))
    written["meta"] = meta_path
    if log.truth is not None:
        written["truth"] = write_sensors_yaml(log.truth, directory / "truth.yaml")
    # Stale files last, once everything new is in place.
    for name in tables:
        for ext in TABLE_FORMATS:
            p = directory / f"{name}.{ext}"
            if p.exists() and written.get(name) != p:
                p.unlink()
    if log.truth is None and (directory / "truth.yaml").exists():
        (directory / "truth.yaml").unlink()
    return written
