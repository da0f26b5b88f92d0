"""Shared pieces of every calibration method: the result type and robot-head interpolation."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from pedcal.model import Log, SensorNetwork


@dataclass
class CalibrationResult:
    """What a calibration method returns. ``network`` has the calibrated schema of
    LOG_FORMAT.md (status, observations, sigma where the method gives one)."""

    network: SensorNetwork
    method: str
    runtime_s: float = 0.0
    # Boolean mask over the rows of log.observations: True where the method used the row as
    # an observation of the robot (None when the method does not pick out the robot).
    is_robot: np.ndarray | None = None
    diagnostics: dict = field(default_factory=dict)

    def summary(self) -> str:
        lines = [f"method {self.method}: {len(self.network)} sensors in {self.runtime_s:.2f} s"]
        for s in self.network:
            sig = ""
            if s.sigma_position_m is not None:
                sig = "  sigma " + " ".join(f"{1000 * v:.1f}" for v in s.sigma_position_m) + " mm"
            extra = f" unobservable: {', '.join(s.unobservable)}" if s.unobservable else ""
            lines.append(f"  {s.id:>8s} {s.status or '':10s} obs {s.observations or 0:6d}"
                         f"  pos {np.array2string(s.position_m, precision=3)}"
                         f"  ypr {np.array2string(s.ypr_deg, precision=2)}{sig}{extra}")
        return "\n".join(lines)


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.elapsed_s = time.perf_counter() - self.t0


def interpolate_pose2(track: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """Robot base (x, y, yaw) at times ``t`` by linear interpolation of a t/x/y/yaw table,
    yaw unwrapped before interpolating. Times outside the table are clamped to its ends."""
    track = track.sort_values("t")
    tt = track["t"].to_numpy(float)
    x = np.interp(t, tt, track["x"].to_numpy(float))
    y = np.interp(t, tt, track["y"].to_numpy(float))
    yaw = np.interp(t, tt, np.unwrap(track["yaw"].to_numpy(float)))
    return np.column_stack([x, y, yaw])


def head_world(pose2: np.ndarray, head_offset_m) -> np.ndarray:
    """World position of the robot's head top for base poses (N, 3) [x, y, yaw]."""
    off = np.asarray(head_offset_m, dtype=float)
    c, s = np.cos(pose2[:, 2]), np.sin(pose2[:, 2])
    return np.column_stack([pose2[:, 0] + c * off[0] - s * off[1],
                            pose2[:, 1] + s * off[0] + c * off[1],
                            np.full(len(pose2), off[2])])


def head_interpolator(log: Log, *, truth: bool = False):
    """t -> the robot's head top in the world (N, 3), from robot.csv (AMCL) or, with
    ``truth=True``, from truth_robot.csv. AMCL's estimates come at a few Hz: on a turn a straight
    chord between them is off by centimetres, so robot.csv is interpolated with a cubic spline
    (x, y and unwrapped yaw; one row per time stamp). truth_robot.csv is dense and the simulator
    interpolates it linearly, so it is read the same way. Times outside the table are clamped to
    its ends."""
    track = log.truth_robot if truth else log.robot
    if track is None:
        raise ValueError("the log has no truth_robot.csv" if truth else "the log has no robot.csv")
    track = track.groupby("t", sort=True)[["x", "y", "yaw"]].mean()
    tt = track.index.to_numpy(float)
    xy_yaw = np.column_stack([track["x"].to_numpy(float), track["y"].to_numpy(float),
                              np.unwrap(track["yaw"].to_numpy(float))])
    spline = CubicSpline(tt, xy_yaw, axis=0) if len(tt) >= 4 and not truth else None
    head_offset_m = log.meta.head_offset_m

    def head_at(t):
        t = np.clip(np.asarray(t, float), tt[0], tt[-1])
        if spline is None:
            pose2 = np.column_stack([np.interp(t, tt, xy_yaw[:, i]) for i in range(3)])
        else:
            pose2 = spline(t)
        return head_world(np.atleast_2d(pose2), head_offset_m)

    return head_at


def robot_head_at(log: Log, t: np.ndarray, *, truth: bool = False) -> np.ndarray:
    """The robot's head top in the world at times ``t`` (see :func:`head_interpolator`)."""
    return head_interpolator(log, truth=truth)(t)
