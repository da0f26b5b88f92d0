"""The domains of pedcal's numeric options, checked once, where a value enters: by argparse for the
command line (``type=options.arg("seed")``) and by the library functions
(``options.check(seed=seed)``), with the same words in both messages.

Every numeric option has a domain (an integer >= 0, a finite number > 0, a number within bounds,
...); a value outside it (``nan``, ``-1``, ``1e300`` where a height is expected) is refused before
any work, instead of switching a limit off, hanging a loop or overflowing a solver. Arguments of a
wrong type (``calibrate(None)``, ``read_log(None)``) get a TypeError naming the argument and what
it expects (``require``).
"""

from __future__ import annotations

import argparse
import math
import numbers
import os
from dataclasses import dataclass
from pathlib import Path

from pedcal.errors import PedcalInputError, show


@dataclass(frozen=True)
class Domain:
    """Numbers of ``kind`` (int or float) within [lo, hi] (``lo_open``: lo excluded), always finite."""

    kind: type
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    unit: str = ""

    def describe(self) -> str:
        what = "an integer" if self.kind is int else "a finite number"
        num = (lambda v: f"{int(v)}") if self.kind is int else (lambda v: f"{v:g}")
        unit = f" {self.unit}" if self.unit else ""
        if self.lo is not None and self.hi is not None:
            op = "<" if self.lo_open else "<="
            return f"{what} with {num(self.lo)} {op} value <= {num(self.hi)}{unit}"
        if self.lo is not None:
            return f"{what} {'>' if self.lo_open else '>='} {num(self.lo)}{unit}"
        if self.hi is not None:
            return f"{what} <= {num(self.hi)}{unit}"
        return what + unit

    def problem(self, value) -> str | None:
        """Why ``value`` (a number) lies outside the domain; None when it lies inside."""
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return "not a number"
        if self.kind is int and not isinstance(value, numbers.Integral):
            return "not an integer"
        v = float(value) if self.kind is float else int(value)
        if self.kind is float and not math.isfinite(v):
            return "not finite"
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            return "too small"
        if self.hi is not None and v > self.hi:
            return "too large"
        return None

    def parse(self, text: str):
        """A command-line value -> the number; ValueError with the domain when it is not one."""
        s = str(text).strip()
        try:
            value = int(s, 10) if self.kind is int else float(s)
        except ValueError:
            raise ValueError(f"{show(text)} is not {self.describe()}") from None
        if self.problem(value) is not None:
            raise ValueError(f"{show(text)} is not {self.describe()}")
        return value


SEED_MAX = 2 ** 32 - 1      # numpy's legacy and SeedSequence-based generators both take this range
# name (the library's keyword; the option is --NAME with '-') -> domain
DOMAINS: dict[str, Domain] = {
    "seed": Domain(int, 0, SEED_MAX),
    "seeds": Domain(int, 1, 100_000),
    "follow_seeds": Domain(int, 0, 100_000),
    "frames": Domain(int, 1, 10_000_000),
    "workers": Domain(int, 1, 4096),
    "max_targets": Domain(int, 1, None),
    "gap_cells": Domain(int, 0, 100),
    "max_memory_gb": Domain(float, 0.0, 1e6, lo_open=True, unit="GB"),
    "max_duration_s": Domain(float, 0.0, 1e9, lo_open=True, unit="s"),
    "min_duration_s": Domain(float, 0.0, 1e9, lo_open=True, unit="s"),
    "max_follow_s": Domain(float, 0.0, 1e9, lo_open=True, unit="s"),
    "min_duration": Domain(float, 0.0, 1e9, lo_open=True, unit="s"),
    "fps": Domain(float, 0.0, 1e6, lo_open=True, unit="frames per second"),
    # a height reference: a sigma below a micrometre is no measurement, above 10 m no reference
    "sensor_height_sigma": Domain(float, 1e-6, 10.0, unit="m"),
    "sensor_height_sigma_m": Domain(float, 1e-6, 10.0, unit="m"),
    # ceiling-mounted depth sensors see the floor over a few metres; 50 m covers any atrium
    "ceiling_height": Domain(float, 0.0, 50.0, lo_open=True, unit="m"),
    "ceiling_height_m": Domain(float, 0.0, 50.0, lo_open=True, unit="m"),
    # the crowd scene's 252 m^2: 0.04 gives its first walker; 20 (2 people per m^2, a dense crowd, 500
    # walkers) takes a minute to simulate, and the time grows faster than the walkers' number
    "density_per_10m2": Domain(float, 0.04, 20.0, unit="people per 10 m^2"),
    "density": Domain(float, 0.04, 20.0, unit="people per 10 m^2"),
    "threshold": Domain(float),
    "cell_size_m": Domain(float, 1e-3, 10.0, unit="m"),
    "pose_sigma": Domain(float, 0.0, 360.0, lo_open=True, unit="(m, deg)"),
    "pose_sigma_m": Domain(float, 0.0, 360.0, lo_open=True, unit="m"),
    "pose_sigma_rad": Domain(float, 0.0, 2.0 * math.pi, lo_open=True, unit="rad"),
    "head_offset": Domain(float, -10.0, 10.0, unit="m"),       # pedcal.io.plausible.MAX_HEAD_OFFSET_M
    "sensor_pose_xyz": Domain(float, -1e6, 1e6, unit="m"),       # pedcal.io.plausible.MAX_ABS_COORDINATE_M
    "sensor_pose_deg": Domain(float, -720.0, 720.0, unit="deg"),  # pedcal.io.plausible.MAX_ABS_ANGLE_DEG
}


def arg(name: str):
    """argparse ``type=`` for the option ``name`` (a key of DOMAINS)."""
    domain = DOMAINS[name]

    def parse(text: str):
        try:
            return domain.parse(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.domain = domain            # the fuzz suite walks the parser's actions by this attribute
    parse.__name__ = name            # argparse names the type in "invalid NAME value"
    return parse


def check(**values):
    """Library side: each keyword's value must lie in its domain (None: the default applies)."""
    for name, value in values.items():
        if value is None:
            continue
        domain = DOMAINS[name]
        if domain.problem(value) is not None:
            raise PedcalInputError(f"{name} = {show(value)}: expected {domain.describe()}")


def check_recipe_numbers(values: dict, defaults, path=None, zero_off=()) -> None:
    """The numbers of a recipe file (``graphs/*.toml``): each finite, >= 0 and within 1e6; a sigma
    (a key naming one) > 0 unless its default is 0 or it is one of ``zero_off``, whose 0 switches
    its factor or random effect off."""
    for key, value in values.items():
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            continue
        off_allowed = key in zero_off or not ("sigma" in key and getattr(defaults, key, 0) != 0)
        domain = Domain(float, 0.0, 1e6, lo_open=not off_allowed)
        if domain.problem(value) is not None:
            raise PedcalInputError(f"key '{key}' = {show(value)}: expected {domain.describe()}"
                                   + ("" if off_allowed else " (a sigma)"), path=path)


def path(text: str) -> Path:
    """argparse ``type=`` of a path: an empty string is not the current folder."""
    if not str(text).strip():
        raise argparse.ArgumentTypeError("an empty path (give a file or folder name)")
    if "\x00" in str(text):
        raise argparse.ArgumentTypeError("a path holding a NUL byte")
    return Path(text)


path.domain = None


def sensor_pose(text: str) -> str:
    """argparse ``type=`` of ``--sensor-pose x,y,z,roll,pitch,yaw`` (m, deg): checked, returned as given."""
    parts = str(text).split(",")
    if len(parts) != 6:
        raise argparse.ArgumentTypeError(f"{show(text)}: expected six numbers x,y,z,roll,pitch,yaw (m, deg)")
    for i, part in enumerate(parts):
        domain = DOMAINS["sensor_pose_xyz" if i < 3 else "sensor_pose_deg"]
        try:
            domain.parse(part)
        except ValueError as e:
            name = ("x", "y", "z", "roll", "pitch", "yaw")[i]
            raise argparse.ArgumentTypeError(f"{name}: {e}") from None
    return text


def scheduler_address(text: str) -> str:
    """argparse ``type=`` of a Dask scheduler address: [tcp://]HOST:PORT with 1 <= PORT <= 65535."""
    s = str(text).strip()
    rest = s.split("://", 1)[1] if "://" in s else s
    host, _, port = rest.rpartition(":")
    ok = bool(host) and port.isdigit() and 1 <= int(port) <= 65535 and not any(c.isspace() for c in host)
    if not ok:
        raise argparse.ArgumentTypeError(f"{show(text)}: expected a scheduler address HOST:PORT (tcp://HOST:PORT), "
                                         "PORT from 1 to 65535")
    return s


def require(value, name: str, expected: type | tuple, what: str):
    """``value`` must be an instance of ``expected``; otherwise a TypeError naming the argument."""
    if not isinstance(value, expected):
        raise TypeError(f"{name} must be {what}, not {type(value).__name__}")
    return value


def require_path(value, name: str):
    """A file or folder argument: str or os.PathLike (not None, not a table or a number)."""
    require(value, name, (str, os.PathLike), "a path (str or pathlib.Path)")
    if not str(value).strip():
        raise PedcalInputError(f"{name}: an empty path")
    return Path(value)
