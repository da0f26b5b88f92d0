"""People too near for the classifier: clusters cut by the field of view's top and bottom edges.

A LIDAR with a narrow vertical field of view (the FX8: 50 deg, at 1 m on the robot) sees a person
nearer than about 1.1 m only between its field of view's edges: a slab of torso and hips, 0.5-1.5 m
above the floor, with neither head nor legs. The classifier, which scores a cluster's shape, has
little to go on and scores most such slabs low (a lone person 0.8 m ahead of the FX8 pair: found in
2 of 40 frames, ``benchmarks/bench_follow_lidar.py near``). What the scan does show is that the
object goes on above and below what the sensor can see: its points reach both edges of the field of
view (``fov_cut``), across its width, and it is a person's width and depth (``TRUNCATED_WIDTH_M``,
``TRUNCATED_MIN_DEPTH_M``). Objects lower than the sensor (chairs, boxes, trolleys, low plants)
never reach the top edge; poles and coat stands are too narrow, sign boards and walls seen face-on
too flat, walls too wide. A pillar of a person's width, or a tall plant, does pass: the rule alone
cannot tell those from a person, so the following loop (``pedcal.sim.follow_lidar``) takes such a
column as a person only inside the gate of a person it detected a moment before (a common
tracking-by-detection practice: a weak detection is kept where a track predicts one).

A point is at an edge when its elevation in the frame of a sensor whose azimuth field of view holds
it lies within ``EDGE_ROWS`` ray rows of that sensor's top (bottom) row. Range noise moves a return
along its ray, so it does not move it off its row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EDGE_ROWS = 1.5  # a point within this many rows of the top (bottom) row is at the edge
EDGE_SHARE = 0.5  # the points at the top edge span at least this share of the cluster's width
TRUNCATED_WIDTH_M = (0.25, 0.9)  # a torso with its arms, seen from any side
TRUNCATED_MIN_DEPTH_M = 0.08  # thicker than a board or a wall seen face-on
TRUNCATED_MAX_RANGE_M = 1.5  # from the sensor, horizontally: beyond it the field of view holds a person whole


@dataclass(frozen=True)
class SensorView:
    """One sensor's field of view on the robot: its position (base frame, m), yaw (rad), the
    azimuth half-width, the elevations of its top and bottom ray rows and its row step (rad).
    Only level sensors (no pitch nor roll) are described this way."""

    xyz_m: tuple[float, float, float]
    yaw_rad: float
    half_azimuth_rad: float
    top_rad: float
    bottom_rad: float
    row_step_rad: float


def sensor_views(lidar, mounts) -> tuple[SensorView, ...]:
    """The ``SensorView`` of each of ``mounts`` carrying the ``pedcal.sim.lidar.LidarModel``
    ``lidar`` (a grid of rays: its ``fov_vertical_deg`` around ``vertical_center_deg``). A pitched
    or rolled mount, or a beam table, raises ValueError: its edges are not at one elevation."""
    if getattr(lidar, "elevations_deg", None) is not None:
        raise ValueError("sensor_views: a LIDAR with a beam table has no regular top and bottom rows")
    out = []
    for m in mounts:
        if m.pitch_deg != 0.0 or m.roll_deg != 0.0:
            raise ValueError(f"sensor_views: the mount {m} is pitched or rolled; only level sensors are described")
        half_v = np.radians(lidar.fov_vertical_deg) / 2
        centre = np.radians(lidar.vertical_center_deg)
        out.append(SensorView((m.x_m, m.y_m, m.z_m), float(np.radians(m.yaw_deg)),
                              float(np.radians(lidar.fov_horizontal_deg) / 2), float(centre + half_v),
                              float(centre - half_v),
                              float(np.radians(lidar.fov_vertical_deg) / max(lidar.n_vertical - 1, 1))))
    return tuple(out)


def edge_flags(points_xyz: np.ndarray, views: tuple[SensorView, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(at_top, at_bottom): whether each point (N, 3, base frame) lies within ``EDGE_ROWS`` rows of
    the top (bottom) row of a sensor whose azimuth field of view holds it."""
    p = np.asarray(points_xyz, dtype=float)[:, :3]
    top = np.zeros(len(p), dtype=bool)
    bottom = np.zeros(len(p), dtype=bool)
    for v in views:
        d = p - np.asarray(v.xyz_m)
        az = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - v.yaw_rad)))
        inside = np.abs(az) <= v.half_azimuth_rad + 1e-9
        el = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1]))
        tol = EDGE_ROWS * v.row_step_rad
        top |= inside & (el >= v.top_rad - tol)
        bottom |= inside & (el <= v.bottom_rad + tol)
    return top, bottom


def fov_cut(points_xyz: np.ndarray, idx: np.ndarray, width_m: float, depth_m: float, yaw_rad: float,
            views: tuple[SensorView, ...], at_top: np.ndarray | None = None,
            at_bottom: np.ndarray | None = None) -> bool:
    """Whether the cluster ``idx`` (row indices of ``points_xyz``, its box ``width_m`` x ``depth_m``,
    the width along ``yaw_rad``) is a person-sized column cut by the field of view: within
    ``TRUNCATED_MAX_RANGE_M`` of a sensor, of a person's width and depth, with points at the bottom
    edge and points at the top edge spanning ``EDGE_SHARE`` of its width (``edge_flags``, computed
    here unless given for the whole frame)."""
    if not (TRUNCATED_WIDTH_M[0] <= width_m <= TRUNCATED_WIDTH_M[1] and depth_m >= TRUNCATED_MIN_DEPTH_M):
        return False
    p = np.asarray(points_xyz, dtype=float)[idx, :3]
    if not len(p):
        return False
    centre = p[:, :2].mean(axis=0)
    if min(np.hypot(*(centre - np.asarray(v.xyz_m[:2]))) for v in views) > TRUNCATED_MAX_RANGE_M:
        return False
    if at_top is None or at_bottom is None:
        at_top, at_bottom = edge_flags(p, views)
    else:
        at_top, at_bottom = at_top[idx], at_bottom[idx]
    if not at_top.any() or not at_bottom.any():
        return False
    along = p[at_top, :2] @ np.array([np.cos(yaw_rad), np.sin(yaw_rad)])
    return bool(np.ptp(along) >= EDGE_SHARE * width_m)


__all__ = ["SensorView", "sensor_views", "edge_flags", "fov_cut", "EDGE_ROWS", "EDGE_SHARE", "TRUNCATED_WIDTH_M",
           "TRUNCATED_MIN_DEPTH_M", "TRUNCATED_MAX_RANGE_M"]
