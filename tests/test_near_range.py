"""Near-range people cut by the field of view (``pedcal.detect.near_range``)."""

from __future__ import annotations

import numpy as np
import pytest

from pedcal.detect.near_range import (
    EDGE_ROWS,
    TRUNCATED_MAX_RANGE_M,
    edge_flags,
    fov_cut,
    sensor_views,
)
from pedcal.sim.lidar import LIDAR_PRESETS, Mount, fx8_pair_mounts

FX8 = LIDAR_PRESETS["fx8"]


def ray_point(view, azimuth_deg: float, elevation_deg: float, range_m: float) -> np.ndarray:
    """The base-frame point at ``range_m`` along a ray of ``view`` (angles in its own frame)."""
    a, e = np.radians(azimuth_deg) + view.yaw_rad, np.radians(elevation_deg)
    return np.asarray(view.xyz_m) + range_m * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def column(x_m: float, width_m: float, depth_m: float, view, n: int = 21) -> np.ndarray:
    """Points on the front face and one side of a box standing at ``x_m`` ahead of the sensor,
    filling its field of view from the bottom row to the top row."""
    ys = np.linspace(-width_m / 2, width_m / 2, n)
    xs = x_m + np.linspace(0.0, depth_m, 5)
    pts = []
    for y in ys:
        for xx in (xs[0], xs[-1]) if abs(y) == width_m / 2 else (xs[0],):
            r = np.hypot(xx - view.xyz_m[0], y - view.xyz_m[1])
            for el in np.linspace(view.bottom_rad, view.top_rad, 31):
                pts.append([xx, y, view.xyz_m[2] + r * np.tan(el)])
    return np.array(pts)


def box_dims(pts: np.ndarray) -> tuple[float, float]:
    return float(np.ptp(pts[:, 1])), float(np.ptp(pts[:, 0]))


def test_sensor_views_of_the_fx8_pair():
    views = sensor_views(FX8, fx8_pair_mounts())
    assert len(views) == 2
    for v, m in zip(views, fx8_pair_mounts(), strict=True):
        assert v.xyz_m == (m.x_m, m.y_m, m.z_m)
        assert v.yaw_rad == pytest.approx(np.radians(m.yaw_deg))
        assert v.top_rad == pytest.approx(np.radians(25.0)) and v.bottom_rad == pytest.approx(np.radians(-25.0))
        assert v.half_azimuth_rad == pytest.approx(np.radians(30.0))
        assert v.row_step_rad == pytest.approx(np.radians(50.0 / 60))


def test_sensor_views_refuse_tilted_mounts_and_beam_tables():
    with pytest.raises(ValueError, match="pitched or rolled"):
        sensor_views(FX8, (Mount(0.0, 0.0, 1.0, 0.0, 5.0),))
    with pytest.raises(ValueError, match="beam table"):
        sensor_views(LIDAR_PRESETS["vlp16"], (Mount(),))


def test_edge_flags_by_elevation_and_azimuth():
    (v,) = sensor_views(FX8, (Mount(0.0, 0.0, 1.0),))
    step = np.degrees(v.row_step_rad)
    pts = np.array([ray_point(v, 10.0, 25.0, 0.6),  # the top row
                    ray_point(v, 10.0, 25.0 - (EDGE_ROWS - 0.1) * step, 0.6),  # within EDGE_ROWS rows of it
                    ray_point(v, 10.0, 25.0 - (EDGE_ROWS + 0.1) * step, 0.6),  # just beyond
                    ray_point(v, -20.0, -25.0, 0.9),  # the bottom row
                    ray_point(v, 0.0, 0.0, 0.9),  # the middle
                    ray_point(v, 35.0, 25.0, 0.6)])  # at the top's elevation, outside the azimuth field
    top, bottom = edge_flags(pts, (v,))
    assert top.tolist() == [True, True, False, False, False, False]
    assert bottom.tolist() == [False, False, False, True, False, False]


def test_a_person_sized_column_filling_the_view_is_cut():
    (v,) = sensor_views(FX8, (Mount(0.0, 0.0, 1.0),))
    pts = column(0.5, 0.45, 0.25, v)
    w, d = box_dims(pts)
    assert fov_cut(pts, np.arange(len(pts)), w, d, np.pi / 2, (v,))


@pytest.mark.parametrize("case", ["pole", "board", "wall", "far", "low", "top_corner_only", "hanging"])
def test_what_is_not_a_cut_column(case):
    """Too narrow (a pole), too flat (a board face-on), too wide (a wall), too far, not reaching the
    top edge (a chair, a box), reaching it over less than half its width, or not reaching the
    bottom edge (a sign or a lamp hanging from above)."""
    (v,) = sensor_views(FX8, (Mount(0.0, 0.0, 1.0),))
    pts = {"pole": column(0.5, 0.06, 0.06, v), "board": column(0.5, 0.5, 0.02, v), "wall": column(0.5, 1.0, 0.3, v),
           "far": column(TRUNCATED_MAX_RANGE_M + 0.1, 0.45, 0.25, v), "low": column(0.5, 0.45, 0.25, v),
           "top_corner_only": column(0.5, 0.45, 0.25, v), "hanging": column(0.5, 0.45, 0.25, v)}[case]
    if case == "low":  # a box 0.9 m high: below the top edge at that range (1 + 0.5 tan 25 deg = 1.23 m)
        pts = pts[pts[:, 2] <= 0.9]
    if case == "top_corner_only":  # its top is a slope: only the left quarter reaches the top edge
        keep = (pts[:, 2] < 1.15) | (pts[:, 1] > 0.45 / 4)
        pts = pts[keep]
    if case == "hanging":  # from 1.1 m up: the top edge, never the bottom one
        pts = pts[pts[:, 2] >= 1.1]
    w, d = box_dims(pts)
    assert not fov_cut(pts, np.arange(len(pts)), w, d, np.pi / 2, (v,))


def test_fov_cut_of_an_empty_cluster_is_false():
    (v,) = sensor_views(FX8, (Mount(0.0, 0.0, 1.0),))
    assert not fov_cut(np.zeros((0, 4)), np.zeros(0, int), 0.45, 0.25, 0.0, (v,))
