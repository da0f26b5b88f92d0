"""Log directories, format version 1 (docs/LOG_FORMAT.md): reading with validation, writing atomically.

Every table may be ``<name>.csv`` or ``<name>.parquet`` (not both). Column order is free and
extra columns are ignored; rows need not be sorted. Observations keep file order
(truth_observations.csv refers to their 0-based data rows); the pose tables (robot, odometry,
truth_robot) are returned sorted by time. Errors name the file, the 0-based data row and the column.

Reading is two steps: the files are read as they are (CSV numerically with ``pd.read_csv``; a column
with a cell that is not a number comes back as text and is located cell by cell), then
:func:`validate` types and checks the tables. ``validate`` is public: a ``Log`` built from a user's
DataFrames gets the same checks and messages, naming the table (``Log.robot``) instead of a file.
"""

from __future__ import annotations

import difflib
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import PedcalInputError, show, warnings_at_caller
from pedcal.io import plausible
from pedcal.io.atomic import atomic_path, write_text_atomic
from pedcal.io.inputs import CsvTable, header_cells, not_utf8_error, refuse_repeated_columns
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
from pedcal.options import require, require_path

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
# The keys meta.yaml defines (LOG_FORMAT.md); any other key is a free-form note.
META_KEYS = ("head_offset",)


# ------------------------------------------------------------------------------------ table reading
def find_table(directory: Path, name: str, *, required: bool) -> Path | None:
    """The one file holding table ``name`` in ``directory`` (.csv or .parquet)."""
    for ext in TABLE_FORMATS:
        if (directory / f"{name}.{ext}").is_dir():
            raise PedcalInputError(f"is a directory, expected the {name} table file", path=directory / f"{name}.{ext}")
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


def _raw_table(path: Path, columns: tuple[str, ...] = (), text_columns: tuple[str, ...] = ()) -> pd.DataFrame:
    """The table as stored. CSV: only ``columns`` (matched after stripping spaces), numbers parsed by
    pandas' C reader (correctly rounded, so CSV round trips exactly), ``text_columns`` as text; a
    column holding a cell that is not a number comes back as text for parse_float_column to locate."""
    try:
        if path.stat().st_size == 0:
            raise pd.errors.EmptyDataError
        if is_parquet(path):
            return pd.read_parquet(path, engine="pyarrow")
        # no NA filter: an empty cell stays "" for the locator; numbers may carry spaces, ids are stripped later
        options = {"na_filter": False}
        names = header_cells(path)
        refuse_repeated_columns([n.strip() for n in names], columns, path)
        wanted = {str(n).strip() for n in columns}
        use = [n for n in names if str(n).strip() in wanted] if columns else None
        if use is not None and len(use) == len(names):
            use = None       # usecols turns off the C reader's parallel conversion: only for extra columns
        dtype = {n: str for n in names if str(n).strip() in text_columns}
        return pd.read_csv(path, usecols=use, dtype=dtype, **options)
    except PedcalInputError:
        raise
    except pd.errors.EmptyDataError:      # no bytes, or only blank lines
        header = f"header {','.join(columns)}" if columns else "a header line"
        expected = (f"a Parquet table with columns {', '.join(columns)}" if is_parquet(path) else
                    f"a CSV with {header}")
        raise PedcalInputError(f"empty file, expected {expected}", path=path) from None
    except UnicodeDecodeError as e:     # its offset is within pandas' buffer: find the byte in the file
        raise not_utf8_error(path, e, "a binary file, or a CSV saved in another encoding") from None
    except PermissionError:
        raise PedcalInputError("cannot read: permission denied", path=path) from None
    except (pd.errors.ParserError, OSError, ValueError, OverflowError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise PedcalInputError(f"cannot read table: {show(first, 160)[1:-1]}", path=path) from None
    except Exception as e:       # pyarrow's errors for a damaged Parquet file
        if type(e).__module__.startswith("pyarrow"):
            raise PedcalInputError(f"cannot read Parquet file: {show(str(e), 160)[1:-1]}", path=path) from None
        raise


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
        raise PedcalInputError(f"expected a finite number, got {show(out[row])}", path=path, row=row, column=column)
    return out


def _locate_bad_number(values: pd.Series, path: Path, column: str) -> np.ndarray:
    """Slow path of parse_float_column: find and report the first cell that is not a number."""
    text = values.astype(object).where(values.notna(), "").astype(str).str.strip()
    empty = (text == "").to_numpy()
    if empty.any():
        row = _first_bad(empty)
        raise PedcalInputError("empty cell, expected a number", path=path, row=row, column=column)
    out = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    bad = np.isnan(out) & ~text.str.lower().isin(["nan", "+nan", "-nan"]).to_numpy()
    if bad.any():
        row = _first_bad(bad)
        raise PedcalInputError(f"expected a number, got {show(text.iloc[row])}", path=path, row=row,
                               column=column)
    return out


def parse_text_column(values: pd.Series, path: Path, column: str) -> pd.Series:
    """Non-empty strings (ints such as track 3 or sensor 1 become "3", "1")."""
    missing = values.isna().to_numpy()
    if values.dtype == _TEXT_DTYPE and not missing.any():
        # already text (a log read from CSV, or validated before): stripped as it is, the same
        # strings without a Python object made per cell (a third of validating 400 000 rows)
        return _stripped_ids(values.str.strip(), missing, path, column)
    text = values.astype(object).where(~missing, "")
    if pd.api.types.is_float_dtype(values.dtype):   # a Parquet column of whole numbers stored as float
        text = pd.Series(["" if m else str(int(v)) if float(v).is_integer() else repr(float(v))
                          for v, m in zip(values, missing, strict=True)], index=values.index, dtype=object)
    return _stripped_ids(text.astype(str).str.strip(), missing, path, column)


# the text columns' dtype once parsed (``astype(str)``: pandas' string dtype)
_TEXT_DTYPE = pd.Series(["a"]).astype(str).dtype


def _stripped_ids(text: pd.Series, missing: np.ndarray, path: Path, column: str) -> pd.Series:
    """``text`` (stripped) as :func:`parse_text_column` returns it; an empty or ``missing`` cell
    raises, naming its row."""
    empty = (text == "").to_numpy() | missing
    if empty.any():
        raise PedcalInputError("empty cell, expected an id", path=path, row=_first_bad(empty), column=column)
    return text.astype(str)


def typed_table(raw: pd.DataFrame, columns: tuple[str, ...], text_columns: tuple[str, ...], where,
                *, required: bool = True) -> pd.DataFrame:
    """``raw`` (a table as read, or a user's DataFrame) with exactly ``columns`` in that order and
    validated cell types; ``where`` (a file, or a table name such as ``Log.robot``) is named in errors.
    Rows are counted by position (0-based), whatever the DataFrame's index."""
    if not isinstance(raw, pd.DataFrame):
        raise PedcalInputError(f"expected a pandas DataFrame with columns {', '.join(columns)}, got "
                               f"{type(raw).__name__}", path=where)
    names = [str(c).strip() for c in raw.columns]
    missing = [c for c in columns if c not in names]
    if missing:
        raise PedcalInputError(f"missing required column(s) {', '.join(missing)}; "
                               f"expected {', '.join(columns)}, found {', '.join(names) or 'none'}",
                               path=where, column=missing[0])
    if required and len(raw) == 0:
        raise PedcalInputError("table has no data rows", path=where)
    refuse_repeated_columns(names, columns, where, in_header=False)    # a DataFrame's (or Parquet file's) columns
    position = {n: i for i, n in reversed(list(enumerate(names)))}   # the first of repeated names
    out = {}
    for c in columns:
        values = raw.iloc[:, position[c]].reset_index(drop=True)
        if c in text_columns:
            out[c] = parse_text_column(values, where, c)
        else:
            v = parse_float_column(values, where, c)
            if c in INTEGER_COLUMNS:
                if (v != np.round(v)).any():
                    row = _first_bad(v != np.round(v))
                    raise PedcalInputError(f"expected an integer, got {show(v[row])}", path=where, row=row, column=c)
                v = v.astype(np.int64)
            out[c] = v
    return pd.DataFrame(out, index=pd.RangeIndex(len(raw)))


def read_table(path: Path, columns: tuple[str, ...], text_columns: tuple[str, ...] = (),
               *, required: bool = True) -> pd.DataFrame:
    """Read one table with exactly ``columns`` (in that order) and validated cell types."""
    path = Path(path)
    if path.is_dir():
        raise PedcalInputError("is a directory, expected a table file", path=path)
    return typed_table(_raw_table(path, columns, text_columns), columns, text_columns, table_source(path),
                       required=required)


def table_source(path: Path) -> CsvTable | Path:
    """``path`` as errors about its rows name it: a CSV table names a row's line, a Parquet one cannot."""
    return path if is_parquet(path) else CsvTable(path)


def is_parquet(path: Path) -> bool:
    """A table file read and written as Parquet: named .parquet, in any case (.PARQUET); any other is CSV."""
    return Path(path).suffix.lower() == ".parquet"


# ---------------------------------------------------------------------------------------- checks
def check_unique_times(df: pd.DataFrame, path) -> pd.DataFrame:
    """Pose tables: no repeated ``t``; returned sorted by time (stable)."""
    dup = df["t"].duplicated().to_numpy()
    if dup.any():
        row = _first_bad(dup)
        first = int(np.flatnonzero(df["t"].to_numpy() == df["t"].iloc[row])[0])
        raise PedcalInputError(f"time {show(df['t'].iloc[row])} repeats row {first}; each pose needs its own t",
                               path=path, row=row, column="t")
    return df.sort_values("t", kind="stable").reset_index(drop=True)


def check_times(df: pd.DataFrame, path) -> None:
    """Seconds (LOG_FORMAT.md): a stamp beyond 1e10 s (the year 2286) is another unit."""
    t = df["t"].to_numpy()
    bad = np.abs(t) > plausible.MAX_ABS_TIME_S
    if bad.any():
        row = _first_bad(bad)
        raise PedcalInputError(f"time {t[row]:.6g} s is implausible (beyond {plausible.MAX_ABS_TIME_S:g} s, the year "
                               f"2286): {plausible.time_unit_hint(t[row])}? times are seconds (LOG_FORMAT.md)",
                               path=path, row=row, column="t")


def check_coordinates(df: pd.DataFrame, columns: tuple[str, ...], path) -> None:
    for c in columns:
        v = df[c].to_numpy()
        bad = np.abs(v) > plausible.MAX_ABS_COORDINATE_M
        if bad.any():
            row = _first_bad(bad)
            raise PedcalInputError(f"coordinate {v[row]:.6g} m is implausible (expected |{c}| <= "
                                   f"{plausible.MAX_ABS_COORDINATE_M:g} m; millimetres, or a corrupted value?)",
                                   path=path, row=row, column=c)


def check_variances(df: pd.DataFrame, path) -> None:
    """The AMCL covariance of every row: variances >= 0 and plausible, the 3x3 matrix positive definite."""
    for c in VARIANCE_COLUMNS:
        v = df[c].to_numpy()
        neg = v < 0
        if neg.any():
            row = _first_bad(neg)
            raise PedcalInputError(f"negative variance {show(v[row])}, expected >= 0", path=path,
                                   row=row, column=c)
        big = v > plausible.MAX_VARIANCE
        if big.any():
            row = _first_bad(big)
            raise PedcalInputError(f"variance {v[row]:.6g} is implausible (expected <= {plausible.MAX_VARIANCE:g} "
                                   "m^2 or rad^2)", path=path, row=row, column=c)
    xx, xy, xyaw, yy, yyaw, aa = (df[c].to_numpy() for c in ROBOT_COLUMNS[4:])
    # Sylvester's criterion on the matrix scaled to unit diagonal (a correlation matrix), so the test
    # does not depend on units: every leading minor > 0.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d = np.sqrt(np.stack([xx, yy, aa]))
        r_xy, r_xa, r_ya = xy / (d[0] * d[1]), xyaw / (d[0] * d[2]), yyaw / (d[1] * d[2])
        minor2 = 1.0 - r_xy ** 2
        minor3 = 1.0 + 2.0 * r_xy * r_xa * r_ya - r_xy ** 2 - r_xa ** 2 - r_ya ** 2
    eps = 1e-12
    not_pd = ~((d > 0).all(axis=0) & (minor2 > eps) & (minor3 > eps))
    if not_pd.any():
        row = _first_bad(not_pd)
        m = np.array([[xx[row], xy[row], xyaw[row]], [xy[row], yy[row], yyaw[row]], [xyaw[row], yyaw[row], aa[row]]])
        eig = ", ".join(f"{e:.3g}" for e in np.linalg.eigvalsh(m))
        raise PedcalInputError(f"the covariance (cov_xx .. cov_yawyaw) is not positive definite (eigenvalues {eig}); "
                               "expected the upper triangle of a positive definite 3x3 matrix (m^2, m rad, rad^2)",
                               path=path, row=row, column="cov_xx")


def check_track_clocks(obs: pd.DataFrame, path) -> None:
    """Rows may come in any order (LOG_FORMAT.md), but one (sensor, track) has one position per instant."""
    dup = obs.duplicated(["sensor", "track", "t"]).to_numpy()
    if dup.any():
        row = _first_bad(dup)
        s, k, t = obs["sensor"].iloc[row], obs["track"].iloc[row], obs["t"].iloc[row]
        first = int(np.flatnonzero((obs["sensor"] == s).to_numpy() & (obs["track"] == k).to_numpy()
                                   & (obs["t"] == t).to_numpy())[0])
        raise PedcalInputError(f"time {show(t)} of sensor {show(s)} track {show(k)} repeats row {first}; a track "
                               "has one position per instant", path=path, row=row, column="t")


def check_known_sensors(obs: pd.DataFrame, network: SensorNetwork, path, yaml_path) -> None:
    unknown = ~obs["sensor"].isin(network.ids).to_numpy()
    if unknown.any():
        row = _first_bad(unknown)
        listed = ", ".join(network.ids[:20]) + (", ..." if len(network) > 20 else "")
        raise PedcalInputError(f"unknown sensor id {show(obs['sensor'].iloc[row])} (not in "
                               f"{Path(str(yaml_path)).name}: {listed})", path=path, row=row, column="sensor")


def check_truth_rows(truth_obs: pd.DataFrame, n_observations: int, path) -> None:
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


def check_clocks_overlap(robot: pd.DataFrame, obs: pd.DataFrame, robot_where, obs_where) -> None:
    """One clock for all files: the observations must fall at least partly within the robot's times."""
    r0, r1 = float(robot["t"].min()), float(robot["t"].max())
    o0, o1 = float(obs["t"].min()), float(obs["t"].max())
    if o1 < r0 or o0 > r1:
        raise PedcalInputError(f"its times {o0:.6g} .. {o1:.6g} s do not overlap the robot's {r0:.6g} .. {r1:.6g} s "
                               f"in {robot_where}; all files share one clock in seconds (LOG_FORMAT.md): is one of "
                               "them in another unit or from another recording?", path=obs_where, column="t")


def check_network(network: SensorNetwork, where) -> None:
    """An in-memory SensorNetwork: finite, plausible positions and angles (files are checked by their reader)."""
    if not isinstance(network, SensorNetwork) or len(network) == 0:
        raise PedcalInputError("expected a SensorNetwork with at least one sensor", path=where)
    for s in network:
        for what, v, lim, unit in (("position", s.position_m, plausible.MAX_ABS_COORDINATE_M, "m"),
                                   ("ypr_deg", s.ypr_deg, plausible.MAX_ABS_ANGLE_DEG, "deg")):
            if not np.isfinite(v).all() or (np.abs(v) > lim).any():
                raise PedcalInputError(f"sensor {show(s.id)} {what} {show(list(map(float, v)), 80)}: expected "
                                       f"finite values within +-{lim:g} {unit}", path=where)


def validate(log: Log, sources: dict | None = None, *, rows_required: bool = True) -> Log:
    """Check a ``Log`` and return it typed: float columns, text ids, pose tables sorted by time.

    The same checks and messages as reading a log directory (which calls this); ``sources`` maps a
    table name to the file it came from, otherwise errors name the table (``Log.robot``, row, column).
    ``rows_required=False`` lets a log without robot poses or observations through (a calibration
    reports what it cannot estimate). Raises PedcalInputError."""
    sources = dict(sources or {})

    def where(name: str):
        return sources.get(name, f"Log.{name}")

    if not isinstance(log, Log):
        raise PedcalInputError(f"expected a pedcal.model.Log, got {type(log).__name__}")
    if "sensors" not in sources:
        check_network(log.sensors, where("sensors"))
    if log.truth is not None and "truth" not in sources:
        check_network(log.truth, where("truth"))
    typed = {}
    for name, (columns, text_columns) in TABLES.items():
        df = getattr(log, name)
        required = rows_required and name in ("robot", "observations")
        if df is None and name in ("robot", "observations"):
            if required:
                raise PedcalInputError(f"the {name} table is required", path=where(name))
            df = pd.DataFrame(columns=list(columns))
        if df is None:
            typed[name] = None
            continue
        typed[name] = typed_table(df, columns, text_columns, where(name), required=required)
        if "t" in columns:
            check_times(typed[name], where(name))
        check_coordinates(typed[name], tuple(c for c in ("x", "y", "z") if c in columns), where(name))
    robot, obs = typed["robot"], typed["observations"]
    check_variances(robot, where("robot"))
    robot = check_unique_times(robot, where("robot"))
    check_known_sensors(obs, log.sensors, where("observations"), where("sensors"))
    check_track_clocks(obs, where("observations"))
    if len(robot) and len(obs):
        check_clocks_overlap(robot, obs, where("robot"), where("observations"))
    for name in ("odometry", "truth_robot"):
        if typed[name] is not None:
            typed[name] = check_unique_times(typed[name], where(name))
    if typed["truth_observations"] is not None:
        check_truth_rows(typed["truth_observations"], len(obs), where("truth_observations"))
    meta = log.meta if log.meta is not None else Meta()
    if "meta" not in sources:
        read_vector(list(np.asarray(meta.head_offset_m, dtype=float).reshape(-1)), 3, "head_offset", where("meta"),
                    max_abs=plausible.MAX_HEAD_OFFSET_M, unit="m")
    # replace(): any other field of the Log is carried over untouched
    return replace(log, robot=robot, observations=obs, odometry=typed["odometry"], meta=meta,
                   truth_robot=typed["truth_robot"], truth_observations=typed["truth_observations"])


# ---------------------------------------------------------------------------------------- meta.yaml
def read_meta(path: Path) -> Meta:
    data, _ = load_yaml_file(path)
    if data is None:
        return Meta()
    if not isinstance(data, dict):
        raise PedcalInputError("expected a mapping (head_offset: [x, y, z], notes...)", path=path)
    notes = {k: v for k, v in data.items() if k not in META_KEYS}
    meta = Meta(notes=notes) if data.get("head_offset") is None else Meta(
        head_offset_m=read_vector(data["head_offset"], 3, "head_offset", path, max_abs=plausible.MAX_HEAD_OFFSET_M,
                                  unit="m"), notes=notes)
    # any other key is a free-form note (LOG_FORMAT.md), unless it is a misspelling of a key the file lacks:
    # a close match only (cutoff 0.85: head_ofset, head_offset_m; not camera_offset or head_offset_source)
    absent = [k for k in META_KEYS if k not in data]
    for key in notes:
        like = difflib.get_close_matches(str(key).lower(), absent, n=1, cutoff=0.85)
        if like:
            offset = ", ".join(f"{v:g}" for v in meta.head_offset_m)
            warnings.warn(f"{path}: key {show(key)} is not one meta.yaml defines and is kept as a note: did you mean "
                          f"{show(like[0])}? (the head offset used is [{offset}] m)", UserWarning, stacklevel=3)
    return meta


def meta_yaml_text(meta: Meta) -> str:
    data = {"head_offset": flow_vector(meta.head_offset_m)}
    data.update({k: v for k, v in meta.notes.items() if k != "head_offset"})
    return dump_yaml(data)


# ---------------------------------------------------------------------------------------- log dirs
@warnings_at_caller
def read_log(path: str | Path) -> Log:
    """Read and validate a log directory (LOG_FORMAT.md). Bad input raises PedcalInputError."""
    directory = require_path(path, "path")
    if not directory.is_dir():
        raise PedcalInputError("log directory not found" if not directory.exists() else
                               "expected a log directory (sensors.yaml, robot.csv, observations.csv)",
                               path=directory)
    sensors_path = directory / "sensors.yaml"
    if not sensors_path.exists():
        raise PedcalInputError("required file missing", path=sensors_path)
    sensors = read_sensors_yaml(sensors_path)
    sources: dict = {"sensors": sensors_path}
    tables: dict = {}
    for name, (columns, text_columns) in TABLES.items():
        p = find_table(directory, name, required=name in ("robot", "observations"))
        tables[name] = None if p is None else _raw_table(p, columns, text_columns)
        if p is not None:          # errors name a CSV row's line too (validate keeps file order until they are checked)
            sources[name] = table_source(p)
    meta_path = directory / "meta.yaml"
    meta = Meta()
    if meta_path.exists():
        meta, sources["meta"] = read_meta(meta_path), meta_path
    truth_path = directory / "truth.yaml"
    truth = None
    if truth_path.exists():
        truth, sources["truth"] = read_sensors_yaml(truth_path), truth_path
    return validate(Log(sensors=sensors, meta=meta, truth=truth, path=directory, **tables), sources)


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
        if is_parquet(path):
            df.to_parquet(tmp, engine="pyarrow", index=False)
        else:
            _write_csv(df, tmp)
    return path


def _whole_float_columns_as_text(df: pd.DataFrame) -> pd.DataFrame:
    """Arrow writes the float 0.0 as "0"; a float column holding only whole numbers (a covariance
    term that is always 0) would then read back as integers with a plain pd.read_csv. Such columns
    are written as "0.0", as pandas writes them."""
    out = None
    for c in df.columns:
        v = df[c].to_numpy()
        if v.dtype.kind != "f" or len(v) == 0 or not (np.isfinite(v).all() and (np.abs(v) < 2.0 ** 53).all()):
            continue
        if (v == np.round(v)).all():
            text = pd.Series(v.astype(np.int64).astype(str), index=df.index) + ".0"
            text[(v == 0) & np.signbit(v)] = "-0.0"
            out = df.copy() if out is None else out
            out[c] = text
    return df if out is None else out


def _write_csv(df: pd.DataFrame, path: Path) -> None:
    """Arrow's CSV writer (shortest exact floats, ~15x faster than DataFrame.to_csv on 2 M rows),
    unquoted as pandas writes it; pandas when a value needs quoting (an id holding a comma) or a
    column is of a type Arrow cannot write."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    df = _whole_float_columns_as_text(df)
    try:
        table = pa.Table.from_pandas(df, preserve_index=False)
        pacsv.write_csv(table, path, pacsv.WriteOptions(quoting_style="none", quoting_header="none"))
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
        df.to_csv(path, index=False, lineterminator="\n")


def write_log(log: Log, path: str | Path, fmt: str = "csv") -> dict[str, Path]:
    """Write ``log`` as a log directory; tables as ``fmt`` (csv or parquet). Returns name -> file.

    Each file is written atomically. A table file of the other format, or of an optional table the
    log does not hold, is removed so that the directory reads back as exactly this log.
    """
    if fmt not in TABLE_FORMATS:
        raise ValueError(f"fmt must be one of {TABLE_FORMATS}, got {fmt!r}")
    require(log, "log", Log, "a pedcal.Log")
    directory = require_path(path, "path")
    validate(log, rows_required=False)    # nothing written of a log that would not read back (NaN, 1e300, ...)
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
