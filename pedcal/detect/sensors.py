"""Which sensor produced a cloud, where it sits, and the density the detector expects.

The classifier was trained on LIDARs whose rays are 0.2-1.2 deg apart (``pedcal.detect.train``).
A depth camera's rays are ~0.09 deg apart: a person 2 m away is 40,000+ points, far outside
anything the classifier saw, and the cluster features (point counts, histograms) mean something
else. ``normalize_density`` thins such a cloud with a voxel grid whose size grows with range,
``range x tan(TARGET_STEP_DEG)``, so a person's point pattern resembles the trained sensors'
at every distance. A cloud whose rays are already at least ``THIN_BELOW_DEG`` apart in both
directions is left alone (the spinning and solid-state LIDARs, the FX8).

The ray spacing is known for the named sensors (``SENSORS``) and estimated otherwise: the median,
over points, of the angle subtended at the sensor (the cloud's origin) by the 4th nearest
neighbour. A scan line's neighbours lie along it, so a spinning LIDAR's fine azimuth step alone
does not count as dense; a camera's grid is dense in both directions.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from pedcal.errors import PedcalInputError
from pedcal.frames import world_from_sensor

TARGET_STEP_DEG = 0.5  # the densest trained LIDAR (solid_dense) has 0.44 x 0.56 deg
THIN_BELOW_DEG = 0.3  # clouds denser than this in both directions are thinned
RANGE_BAND_M = 0.5  # voxel sizes are constant within bands of this width


# name -> (pedcal.sim.lidar preset it resembles, (azimuth, elevation) ray step, deg)
SENSORS: dict[str, tuple[str, tuple[float, float]]] = {
    "fx8": ("fx8", (60.0 / 96, 50.0 / 60)),
    "depth-camera": ("depth_camera", (58.0 / 639, 45.0 / 479)),
    "vlp16": ("vlp16", (0.2, 2.0)),
    "vlp32c": ("vlp32c", (0.2, 1.0 / 3.0)),  # 1/3 deg between its beams about the horizon
    "os1-32": ("spin32", (360.0 / 1024, 40.0 / 31)),
    "os1-64": ("os1_64", (360.0 / 2048, 45.0 / 63)),
    "os1-128": ("os1_128", (360.0 / 1024, 45.0 / 127)),
    "hdl32": ("hdl32", (0.2, 1.33)),
    "hdl64": ("hdl64", (0.18, 0.42)),
    "pandar40": ("pandar40", (0.2, 1.0 / 3.0)),  # 1/3 deg between its beams about the horizon
    "realsense-d435": ("realsense_d435", (87.0 / 847, 58.0 / 479)),
    "depth-vga-wide": ("depth_vga_wide", (87.0 / 639, 58.0 / 479)),
    "solid-dense": ("solid_dense", (70.0 / 159, 55.0 / 99)),
    "sparse-tof": ("sparse_tof", (60.0 / 63, 45.0 / 39)),
}


def sensor_names() -> list[str]:
    return sorted(SENSORS)


def angular_step_deg(points: np.ndarray, sample: int = 4000, seed: int = 0) -> float:
    """Estimated ray spacing (deg) of a cloud seen from its origin: the median angle to the 4th
    nearest neighbour over a seeded sample of points."""
    xyz = points[:, :3]
    if len(xyz) < 10:
        return float("inf")
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    pick = xyz[rng.choice(len(xyz), min(sample, len(xyz)), replace=False)]
    d, _ = cKDTree(xyz).query(pick, k=5)
    r = np.linalg.norm(pick, axis=1)
    ok = np.isfinite(d[:, 4]) & (r > 0.1)
    return float(np.median(np.degrees(d[ok, 4] / r[ok]))) if ok.any() else float("inf")


def needs_thinning(points: np.ndarray, sensor: str | None = None) -> bool:
    if sensor is not None:
        return max(SENSORS[sensor][1]) < THIN_BELOW_DEG
    return angular_step_deg(points) < THIN_BELOW_DEG


def normalize_density(points: np.ndarray, sensor: str | None = None) -> np.ndarray:
    """The cloud thinned to ~TARGET_STEP_DEG between points when its sensor is denser (see the
    module docstring); unchanged otherwise. Ranges are from the cloud's origin (the sensor).
    Each voxel's points are averaged (open3d ``voxel_down_sample``), intensity with them."""
    if sensor is not None and sensor not in SENSORS:
        raise PedcalInputError(f"unknown sensor {sensor!r}; expected one of {', '.join(sensor_names())}",
                               column="sensor")
    if len(points) == 0 or not needs_thinning(points, sensor):
        return points
    r = np.linalg.norm(points[:, :3], axis=1)
    band = np.floor(r / RANGE_BAND_M).astype(np.int64)
    out = []
    for b in np.unique(band):
        sel = points[band == b]
        voxel_m = (b + 0.5) * RANGE_BAND_M * np.tan(np.radians(TARGET_STEP_DEG))
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sel[:, :3]))
        pc.colors = o3d.utility.Vector3dVector(np.repeat(sel[:, 3:4], 3, axis=1))
        down = pc.voxel_down_sample(max(voxel_m, 1e-3))
        out.append(np.column_stack([np.asarray(down.points), np.asarray(down.colors)[:, 0]]))
    return np.vstack(out)


def parse_sensor_pose(text: str) -> tuple[np.ndarray, np.ndarray]:
    """``x,y,z,roll,pitch,yaw`` (m, deg) -> (position_m, ypr_deg) of the sensor in the base frame
    (z = 0 on the floor, pedcal.frames' convention: positive pitch looks down)."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != 6 or not np.isfinite(vals).all():
        raise PedcalInputError(f"--sensor-pose {text!r}: expected six numbers x,y,z,roll,pitch,yaw "
                               "(metres, degrees)", column="sensor-pose")
    x, y, z, roll, pitch, yaw = vals
    return np.array([x, y, z]), np.array([yaw, pitch, roll])


def to_base_frame(points: np.ndarray, position_m, ypr_deg) -> np.ndarray:
    """Points of the sensor frame in the base frame (z = 0 on the floor): p = R p_sensor + t."""
    out = points.copy()
    out[:, :3] = world_from_sensor(points[:, :3], position_m, ypr_deg)
    return out
