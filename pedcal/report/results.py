"""Saved sweep results: what the report is rebuilt from.

A results directory holds

- ``results.json``: the sweep's configuration (and the command that regenerates it), the per-run
  table (one row per scenario, seed and method) and the per-sensor table as columns and rows
  (floats to 6 decimals, NaN as null);
- ``runs.parquet``, ``sensors.parquet``: the same two tables as Parquet;
- ``heads.parquet``, ``robot.parquet``: the calibrated head tracks of every method and the true
  robot path on the evaluation log of each scenario's first seed (for the trajectory figures);
- ``bounds.parquet``: per scenario, seed and sensor the Cramér-Rao bound of its position;
- ``tracking.parquet``: per following scene, seed and tracker the metrics of ``pedcal follow``
  (also in results.json when the sweep ran the tracking part);
- ``timings.json``: solve times per run. They vary from run to run, so the report never reads
  them and the reproducible files never hold them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from pedcal.errors import PedcalInputError
from pedcal.io.atomic import atomic_path, write_text_atomic
from pedcal.report.sweep import SweepConfig

FORMAT_VERSION = 1
JSON_DECIMALS = 6        # results.json rounds floats (mm, deg, m); the Parquet tables keep every digit
TABLES = ("runs", "sensors", "heads", "robot", "bounds", "tracking")
OPTIONAL_TABLES = ("tracking",)  # absent from results written before the tracking part existed


@dataclass
class SweepResults:
    config: SweepConfig
    runs: pd.DataFrame
    sensors: pd.DataFrame
    heads: pd.DataFrame
    robot: pd.DataFrame
    bounds: pd.DataFrame
    tracking: pd.DataFrame = field(default_factory=pd.DataFrame)  # follow metrics per scene, seed, tracker
    path: Path | None = None


def _clean(v):
    if isinstance(v, float):
        return round(v, JSON_DECIMALS) if math.isfinite(v) else None
    return v


def table_json(df: pd.DataFrame) -> str:
    """A table as ``{"columns": [...], "rows": [[...], ...]}``, one row a line (readable diffs),
    floats rounded to JSON_DECIMALS, NaN as null."""
    rows = [json.dumps([_clean(v) for v in r], allow_nan=False) for r in df.itertuples(index=False, name=None)]
    return ('{"columns": ' + json.dumps(list(map(str, df.columns))) + ',\n "rows": [\n  '
            + ",\n  ".join(rows) + "\n ]}")


def json_text(obj) -> str:
    """Reproducible JSON: sorted keys, fixed indentation, no NaN (null instead)."""
    return json.dumps(obj, indent=1, sort_keys=True, allow_nan=False) + "\n"


def write_parquet_atomic(df: pd.DataFrame, path: Path) -> None:
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, index=False, engine="pyarrow", compression="zstd")


def results_from_cases(config: SweepConfig, cases: list[dict]) -> SweepResults:
    """Tables of the task results of ``run_sweep`` (already in their sorted order)."""
    frames = {name: pd.DataFrame([r for c in cases for r in c.get(name, [])]) for name in TABLES}
    return SweepResults(config=config, **frames)


def save_results(results: SweepResults, out_dir: str | Path, timings: dict | None = None) -> Path:
    """Write the results files (module docstring) into ``out_dir``, each atomically."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in TABLES:
        write_parquet_atomic(getattr(results, name), out_dir / f"{name}.parquet")
    # Keys in sorted order, as json_text writes them.
    write_text_atomic(out_dir / "results.json", "{\n" + ",\n".join([
        '"config": ' + json.dumps(results.config.to_dict(), sort_keys=True),
        f'"format_version": {FORMAT_VERSION}',
        '"runs": ' + table_json(results.runs),
        '"sensors": ' + table_json(results.sensors)]
        + (['"tracking": ' + table_json(results.tracking)] if not results.tracking.empty else [])) + "\n}\n")
    if timings is not None:
        write_text_atomic(out_dir / "timings.json", json_text(timings))
    return out_dir


def load_results(results_dir: str | Path) -> SweepResults:
    """Read a results directory written by ``save_results``."""
    results_dir = Path(results_dir)
    path = results_dir / "results.json"
    if not path.is_file():
        raise PedcalInputError("no results.json: expected a directory written by `pedcal report`", path=results_dir)
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
        config = SweepConfig.from_dict(meta["config"])
    except (ValueError, KeyError, TypeError) as exc:
        raise PedcalInputError(f"not a pedcal report results file ({exc})", path=path) from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise PedcalInputError(f"format_version {meta.get('format_version')!r}, expected {FORMAT_VERSION}", path=path)
    tables = {}
    for name in TABLES:
        p = results_dir / f"{name}.parquet"
        if not p.is_file() and name in OPTIONAL_TABLES:
            tables[name] = pd.DataFrame()
            continue
        if not p.is_file():
            raise PedcalInputError(f"missing {p.name}, which `pedcal report` writes beside results.json", path=p)
        tables[name] = _read_table(p, KEY_COLUMNS.get(name, ()))
    return SweepResults(config=config, path=results_dir, **tables)


# The columns that say which run a row of a results table belongs to (every table save_results
# writes with rows has them).
KEY_COLUMNS = {"runs": ("scenario", "seed", "method"), "sensors": ("scenario", "seed", "method", "sensor"),
               "heads": ("scenario", "seed", "method", "sensor"), "robot": ("scenario", "seed"),
               "bounds": ("scenario", "seed", "sensor")}


def _read_table(path: Path, key_columns: tuple[str, ...]) -> pd.DataFrame:
    """A results table; a damaged file or one without its key columns raises PedcalInputError."""
    import pyarrow as pa  # imported by read_parquet anyway

    try:
        df = pd.read_parquet(path)
    except (OSError, ValueError, pa.ArrowException) as exc:      # every pyarrow error is an ArrowException
        raise PedcalInputError(f"cannot read the Parquet table: {str(exc).splitlines()[0][:160]}", path=path) from None
    missing = [c for c in key_columns if c not in df.columns]
    if len(df) and missing:
        raise PedcalInputError(f"not a table `pedcal report` writes: missing column(s) {', '.join(missing)}",
                               path=path, column=missing[0])
    return df
