"""Recorded pedestrian datasets -> people trajectories ``t, person, x, y`` (s, id, m, m).

Readers for the layouts in ``shared/data`` (README.md there): ATC (Brščić et al. 2013), ETH/UCY
and THÖR. Rows keep file order; ``person`` is text. Bad cells raise PedcalInputError naming the
file, the 0-based data row and the column.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import PedcalInputError, show
from pedcal.io.inputs import header_cells, not_utf8_error, refuse_repeated_columns, regular_file
from pedcal.io.logdir import is_parquet, parse_float_column, parse_text_column
from pedcal.io.people import read_people_csv, validate_people
from pedcal.model import PEOPLE_COLUMNS
from pedcal.options import require_path

ATC_COLUMNS = ("time_unix_s", "person_id", "x", "y", "velocity", "motion_angle")
ETH_UCY_COLUMNS = ("frame", "ped_id", "x", "y")
THOR_COLUMNS = ("time", "person_id", "x", "y", "velocity", "motion_angle")
KINDS = ("atc", "eth_ucy", "thor", "people")

# ETH/UCY as vendored for trajectory prediction: annotations at 2.5 fps, frame numbers step 10,
# so t = frame / 25. The biwi_eth file is the exception: its frames were renumbered by linear
# interpolation of the original annotation, which stepped 6 frames per 0.4 s (frames 780, 786, ...;
# the positions at a shared frame number are identical), so there t = frame * 0.4 / 6 = frame / 15.
# With /25 its median walking speed comes out at 2.45 m/s, with /15 at 1.47 m/s.
# The rate is known only for the recordings named here; a file of another name (a renamed copy,
# another recording) needs the rate given (--fps): guessing 25 would replay biwi_eth 1.67x too fast.
ETH_UCY_FRAMES_PER_S = 25.0
ETH_UCY_FRAMES_PER_S_BY_NAME = {"biwi_eth": 15.0, **{name: ETH_UCY_FRAMES_PER_S for name in (
    "biwi_hotel", "crowds_zara01", "crowds_zara02", "crowds_zara03", "students001", "students003", "uni_examples")}}
ADVICE_NOT_UTF8 = "a binary file, or a file saved in another encoding"
# Positions larger than this (in absolute value) cannot be metres in one building: millimetres.
MAX_PLAUSIBLE_M = 1000.0


def _read_text_table(path: Path, columns: tuple[str, ...], sep: str, header: bool) -> pd.DataFrame:
    regular_file(path, "pedestrian file")
    try:
        raw = pd.read_csv(path, sep=sep, header=0 if header else None, dtype=str, keep_default_na=False,
                          skipinitialspace=True, engine="python" if sep == r"\s+" else "c")
    except pd.errors.EmptyDataError:
        raise PedcalInputError("empty file, expected pedestrian rows", path=path) from None
    except UnicodeDecodeError as e:     # its offset is within the parser's buffer: find the byte in the file
        raise not_utf8_error(path, e, ADVICE_NOT_UTF8) from None
    except PermissionError:
        raise PedcalInputError("cannot read: permission denied", path=path) from None
    except (pd.errors.ParserError, OSError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise PedcalInputError(f"cannot read: {show(first, 160)[1:-1]}", path=path) from None
    if header:
        raw.columns = [str(c).strip() for c in raw.columns]
        names = [c.strip() for c in header_cells(path)]     # (a headed layout is comma-separated: THÖR)
        refuse_repeated_columns(names, columns[:4], path)
        missing = [c for c in columns[:4] if c not in raw.columns]
        if missing:
            raise PedcalInputError(f"missing column(s) {', '.join(missing)}; expected header "
                                   f"{','.join(columns)}", path=path, column=missing[0])
    else:
        if raw.shape[1] < 4:
            raise PedcalInputError(f"expected {len(columns)} columns ({', '.join(columns)}), found "
                                   f"{raw.shape[1]}", path=path)
        raw = raw.iloc[:, : len(columns)]
        raw.columns = list(columns[: raw.shape[1]])
    if len(raw) == 0:
        raise PedcalInputError("no data rows", path=path)
    return raw


def _people(path: Path, raw: pd.DataFrame, t_col: str, id_col: str, *, t_scale: float = 1.0,
            xy_scale: float = 1.0) -> pd.DataFrame:
    ids = pd.Series(parse_float_column(raw[id_col], path, id_col), index=raw.index)
    return pd.DataFrame({
        "t": parse_float_column(raw[t_col], path, t_col) * t_scale,
        "person": parse_text_column(ids, path, id_col).to_numpy(),
        "x": parse_float_column(raw["x"], path, "x") * xy_scale,
        "y": parse_float_column(raw["y"], path, "y") * xy_scale,
    }, columns=list(PEOPLE_COLUMNS))


def _metres_scale(path: Path, raw: pd.DataFrame) -> float:
    xy = np.abs(np.column_stack([parse_float_column(raw[c], path, c) for c in ("x", "y")]))
    return 1e-3 if np.median(xy) > MAX_PLAUSIBLE_M else 1.0


def read_atc(path: str | Path) -> pd.DataFrame:
    """ATC shopping-centre tracks: CSV without header (time_unix_s, person_id, x, y, velocity,
    motion_angle). The original ATC release gives x, y in millimetres; the copy in shared/data is
    already in metres (|x| < 50, velocity column ~1 m/s). Millimetres are recognised by magnitude
    (positions beyond 1 km) and converted to metres."""
    path = Path(path)
    raw = _read_text_table(path, ATC_COLUMNS, ",", header=False)
    return _people(path, raw, "time_unix_s", "person_id", xy_scale=_metres_scale(path, raw))


def eth_ucy_frames_per_s(path: Path, frames_per_s: float | None = None) -> float:
    """The frame rate: ``frames_per_s`` when given, else the rate of the recording the file name
    identifies (ETH_UCY_FRAMES_PER_S_BY_NAME); an unknown name without a rate is an input error."""
    if frames_per_s is not None:
        fps = float(frames_per_s)
        if not (np.isfinite(fps) and fps > 0):
            raise PedcalInputError(f"frame rate must be a positive number, got {frames_per_s!r}", path=path)
        return fps
    if path.stem not in ETH_UCY_FRAMES_PER_S_BY_NAME:
        raise PedcalInputError(f"frame-numbered (ETH/UCY) file whose name does not identify the recording "
                               f"(known: {', '.join(sorted(ETH_UCY_FRAMES_PER_S_BY_NAME))}); give its frame rate "
                               "with --fps (frames per second of the frame numbers): pedcal import-people FILE --fps "
                               "F -o people.csv, then follow --people people.csv", path=path)
    return ETH_UCY_FRAMES_PER_S_BY_NAME[path.stem]


def read_eth_ucy(path: str | Path, frames_per_s: float | None = None) -> pd.DataFrame:
    """ETH/UCY TSV ``frame ped_id x y`` (metres). t = frame / frames_per_s: given, or known from the
    file name (25, 15 for biwi_eth: see ETH_UCY_FRAMES_PER_S_BY_NAME)."""
    path = Path(path)
    raw = _read_text_table(path, ETH_UCY_COLUMNS, r"\s+", header=False)
    people = _people(path, raw, "frame", "ped_id")          # cell errors first, then the rate
    people["t"] = people["t"] * (1.0 / eth_ucy_frames_per_s(path, frames_per_s))
    return people


def _has_header(path: Path) -> bool:
    first = _first_line(path)
    return bool(first) and not re.fullmatch(r"[\s,;\t0-9eE.+\-]*", first)


def _first_line(path: Path) -> str:
    regular_file(path, "pedestrian file")
    try:
        with path.open("rb") as f:
            head = f.read(4096)
        try:
            head.decode("utf-8")
        except UnicodeDecodeError as e:
            if e.start < len(head) - 4:     # not a character cut at the 4 KB boundary
                raise not_utf8_error(path, e, ADVICE_NOT_UTF8) from None
        if b"\x00" in head:
            raise PedcalInputError("not a text file (NUL bytes): expected pedestrian rows", path=path)
        with path.open("r", encoding="utf-8-sig", errors="replace") as f:     # a BOM is no character of the line
            for line in f:
                if line.strip():
                    return line.strip()
    except PermissionError:
        raise PedcalInputError("cannot read: permission denied", path=path) from None
    return ""


def read_thor(path: str | Path) -> pd.DataFrame:
    """THÖR CSV ``time, person_id, x, y, velocity, motion_angle`` (s, id, m, m, m/s, rad), with or
    without the header line."""
    path = Path(path)
    raw = _read_text_table(path, THOR_COLUMNS, ",", header=_has_header(path))
    return _people(path, raw, "time", "person_id")


def detect_kind(path: str | Path) -> str:
    """Recognise a file's layout from its content: a header naming ``person`` (people CSV) or
    ``person_id`` (THÖR); whitespace-separated 4 columns (ETH/UCY); comma-separated 6 columns with
    unix times (ATC) or times from zero (THÖR without header)."""
    path = Path(path)
    first = _first_line(path)
    if not first:
        raise PedcalInputError("empty file, expected pedestrian rows", path=path)
    if _has_header(path):
        try:        # read as the table will be: quoted names, a BOM
            names = [c.strip() for c in header_cells(path)]
        except (pd.errors.ParserError, ValueError) as e:
            raise PedcalInputError(f"cannot read the header {show(first, 80)}: "
                                   f"{show(str(e).strip() or type(e).__name__, 120)[1:-1]}", path=path) from None
        if set(PEOPLE_COLUMNS) <= set(names):
            return "people"
        if set(THOR_COLUMNS[:4]) <= set(names):
            return "thor"
        raise PedcalInputError(f"unrecognised header {show(first, 80)}; expected {','.join(PEOPLE_COLUMNS)} or "
                               f"{','.join(THOR_COLUMNS)}", path=path)
    if "," not in first and len(first.split()) == 4:
        return "eth_ucy"
    fields = first.split(",")
    if len(fields) == 6:
        try:
            t0 = float(fields[0])
        except ValueError:
            t0 = None
        if t0 is not None:
            return "atc" if t0 > 1e8 else "thor"
    raise PedcalInputError(f"cannot tell the layout from the first line {show(first, 80)}; pass kind= one of "
                           f"{', '.join(KINDS)}", path=path)


def read_pedestrians(path: str | Path, kind: str = "auto", fps: float | None = None) -> pd.DataFrame:
    """Read any supported recording into ``t, person, x, y``; ``kind`` is auto, atc, eth_ucy, thor
    or people (pedcal's own CSV). ``fps``: the frame rate of a frame-numbered (ETH/UCY) file,
    needed when its name does not identify the recording; the other layouts carry seconds."""
    path = require_path(path, "path")
    if kind == "auto":          # a people table import-people wrote as Parquet, or a text layout to sniff
        kind = "people" if is_parquet(path) else detect_kind(path)
    readers = {"atc": read_atc, "eth_ucy": read_eth_ucy, "thor": read_thor, "people": read_people_csv}
    if kind not in readers:
        raise PedcalInputError(f"unknown kind {kind!r}, expected auto or one of {', '.join(KINDS)}", path=path)
    if kind == "eth_ucy":
        return validate_people(read_eth_ucy(path, frames_per_s=fps), path)
    if fps is not None:
        raise PedcalInputError(f"--fps applies to frame-numbered (ETH/UCY) files; this {kind} file's times are "
                               "in seconds", path=path)
    return validate_people(readers[kind](path), path)
