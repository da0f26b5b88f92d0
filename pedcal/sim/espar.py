"""Seeded simulator of the ESPAR direction-finding antennas of Misu and Miura (Sec. 4.3).

An ESPAR antenna reports which of its 12 directions (30 deg apart) receives the target's
transmitter most strongly. The simulator draws, for every reading, the true bearing of the
transmitter seen from the antenna plus Gaussian noise (``sigma_deg``) and quantizes it to the
nearest direction; with probability ``multipath_prob`` the reading instead points to a uniformly
random direction (a reflection). Two antennas on the robot (eq. 10 multiplies their likelihoods)
each report at ``rate_hz``, the second half a period after the first.

Frames: ``robot`` is the robot's base frame (x forward, y left, metres); bearings are radians,
counter-clockwise from the robot's x axis, in [-pi, pi). Direction k of an antenna points at
bearing ``k * 2 pi / n_directions`` in the antenna's frame, which is the robot frame turned by the
antenna's ``yaw`` (0 for both default mounts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedcal.follow_types import EsparReading
from pedcal.frames import wrap_angle_rad


@dataclass(frozen=True)
class EsparParams:
    """The antennas' model; the defaults are the paper's hardware with a plausible noise level."""

    n_directions: int = 12  # directions 360 / n apart
    sigma_deg: float = 20.0  # noise of the true bearing before quantization
    multipath_prob: float = 0.1  # a reading points to a uniformly random direction
    rate_hz: float = 2.0  # readings per second per antenna
    max_range_m: float = 15.0  # no reading when the transmitter is farther from the antenna
    antenna_xy_robot_m: tuple[tuple[float, float], ...] = ((0.0, 0.15), (0.0, -0.15))
    antenna_yaw_robot_rad: tuple[float, ...] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.n_directions < 2:
            raise ValueError(f"n_directions must be >= 2, got {self.n_directions}")
        if self.sigma_deg < 0 or not 0.0 <= self.multipath_prob <= 1.0 or self.rate_hz <= 0:
            raise ValueError("sigma_deg >= 0, 0 <= multipath_prob <= 1 and rate_hz > 0 are required")
        if len(self.antenna_xy_robot_m) != len(self.antenna_yaw_robot_rad):
            raise ValueError("antenna_xy_robot_m and antenna_yaw_robot_rad must list the same antennas")

    @property
    def spacing_rad(self) -> float:
        return 2.0 * np.pi / self.n_directions

    @property
    def n_antennas(self) -> int:
        return len(self.antenna_xy_robot_m)


def quantized_directions(bearing_antenna_rad: np.ndarray, params: EsparParams,
                         rng: np.random.Generator) -> np.ndarray:
    """Direction indices (0..n-1) read for true bearings in the antenna's frame: Gaussian noise,
    quantization to the nearest direction, and multipath replacing a reading by a uniform one.
    Vectorized over any shape of bearings."""
    a = np.asarray(bearing_antenna_rad, dtype=float)
    noisy = a + rng.normal(0.0, np.radians(params.sigma_deg), a.shape)
    k = np.mod(np.rint(noisy / params.spacing_rad).astype(np.int64), params.n_directions)
    multipath = rng.random(a.shape) < params.multipath_prob
    return np.where(multipath, rng.integers(0, params.n_directions, a.shape), k)


def reading_times(t_prev_s: float, t_s: float, params: EsparParams, antenna: int) -> np.ndarray:
    """The times in (t_prev_s, t_s] at which ``antenna`` reports: every 1/rate_hz seconds, the
    antennas staggered evenly over one period."""
    period = 1.0 / params.rate_hz
    phase = period * antenna / params.n_antennas
    n0 = np.floor((t_prev_s - phase) / period) + 1
    n1 = np.floor((t_s - phase) / period)
    return phase + period * np.arange(n0, n1 + 1)


class EsparSimulator:
    """Readings of the robot's antennas for a transmitter at a known place in the robot frame."""

    def __init__(self, params: EsparParams | None = None, rng: np.random.Generator | None = None):
        self.params = params if params is not None else EsparParams()
        self.rng = rng if rng is not None else np.random.default_rng(0)

    def readings(self, t_prev_s: float, t_s: float,
                 target_xy_robot_m: np.ndarray | None) -> tuple[EsparReading, ...]:
        """The readings due in (t_prev_s, t_s], in time order, all taken with the target at
        ``target_xy_robot_m`` (None or out of ``max_range_m``: that antenna reports nothing)."""
        p = self.params
        if target_xy_robot_m is None:
            return ()
        xy = np.asarray(target_xy_robot_m, dtype=float).reshape(2)
        due = []
        for a, (mount, yaw) in enumerate(zip(p.antenna_xy_robot_m, p.antenna_yaw_robot_rad, strict=True)):
            mount = np.asarray(mount, dtype=float)
            d = xy - mount
            if np.hypot(*d) > p.max_range_m:
                continue
            t = reading_times(t_prev_s, t_s, p, a)
            if len(t) == 0:
                continue
            bearing_antenna = wrap_angle_rad(np.arctan2(d[1], d[0]) - yaw)
            k = quantized_directions(np.full(len(t), bearing_antenna), p, self.rng)
            due += [(float(ti), a, int(ki), mount) for ti, ki in zip(t, k, strict=True)]
        due.sort(key=lambda r: (r[0], r[1]))
        return tuple(EsparReading(antenna=a, direction_index=k,
                                  bearing_robot_rad=float(wrap_angle_rad(k * p.spacing_rad
                                                                          + p.antenna_yaw_robot_rad[a])),
                                  xy_antenna_robot_m=mount.copy())
                     for _, a, k, mount in due)


__all__ = ["EsparParams", "EsparSimulator", "quantized_directions", "reading_times"]
