"""Plausibility bounds of the log format's values (LOG_FORMAT.md: seconds, metres, radians in CSV,
degrees in YAML). A value beyond them is a unit mistake or a corrupted file, refused with the
unit in the message before it can overflow a solver or size an allocation.
"""

from __future__ import annotations

import numpy as np

# Positions: metres in one map frame. 1000 km covers any building, campus or UTM-sized map frame.
MAX_ABS_COORDINATE_M = 1.0e6
# Times: seconds, unix times or from 0. 1e10 s is the year 2286: larger stamps are milli-, micro- or
# nanoseconds.
MAX_ABS_TIME_S = 1.0e10
# Variances of a pose covariance (m^2, rad^2): a standard deviation beyond 1 km or 1000 rad says
# nothing a solver can use and overflows its information matrix.
MAX_VARIANCE = 1.0e6
# Tracker latency of a calibrated YAML (s) and the head dome radius it modelled (m).
MAX_ABS_LATENCY_S = 60.0
MAX_HEAD_RADIUS_M = 1.0
# Head offset of meta.yaml (m): the top of a robot's head in its base frame.
MAX_HEAD_OFFSET_M = 10.0
# A sensors YAML whose every angle lies within +-2 pi (and not all zero) was written in radians:
# ceiling sensors look down by tens of degrees.
RADIANS_LIMIT = 2.0 * np.pi


def time_unit_hint(t_s: float) -> str:
    """What a too-large time stamp probably is (unix times in s are ~1.7e9)."""
    a = abs(t_s)
    if a > 1e17:
        return "unix nanoseconds"
    if a > 1e14:
        return "unix microseconds, or nanoseconds"
    return "milliseconds, microseconds or nanoseconds"


def angles_look_like_radians(ypr_deg: np.ndarray) -> bool:
    """``ypr_deg`` (N, 3) of one file: every angle within +-2 pi, and some angle not a whole number
    of degrees (a sensor tilted by 5 degrees, written as 5, is not taken for radians)."""
    a = np.abs(np.asarray(ypr_deg, dtype=float))
    return a.size > 0 and bool(a.max() <= RADIANS_LIMIT) and bool((a != np.round(a)).any())
# Angles of a sensors YAML (degrees): beyond two turns is a corrupted value.
MAX_ABS_ANGLE_DEG = 720.0
