"""Point-cloud files for ``pedcal detect``: .pcd / .ply (through open3d) and KITTI .bin.

Every reader returns an (N, 4) float64 array ``x, y, z, intensity`` in the file's frame:

- ``.bin``: KITTI Velodyne layout, little-endian float32 ``x, y, z, intensity`` per point;
- ``.pcd`` / ``.ply``: points through open3d's tensor reader; intensity from a scalar field
  named ``intensity`` (or ``reflectance``, ``scalar_intensity``) when present, else the mean of
  the colour channels (0..1) when the file has colours, else 0.

``floor_referenced`` then puts z = 0 on the floor (see its docstring for how both kinds of file
are told apart).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import open3d as o3d

from pedcal.errors import DegenerateDataWarning, PedcalInputError

SUFFIXES = (".bin", ".pcd", ".ply")
_INTENSITY_FIELDS = ("intensity", "reflectance", "scalar_intensity", "scalar_Intensity")


def read_kitti_bin(path: Path) -> np.ndarray:
    raw = path.read_bytes()
    if len(raw) == 0 or len(raw) % 16:
        raise PedcalInputError(f"a KITTI .bin holds float32 x, y, z, intensity (16 bytes a point); "
                               f"its {len(raw)} bytes are not a positive multiple of 16", path=path)
    return np.frombuffer(raw, dtype="<f4").reshape(-1, 4).astype(float)


def read_open3d(path: Path) -> np.ndarray:
    try:
        pcd = o3d.t.io.read_point_cloud(str(path))
    except RuntimeError as e:
        raise PedcalInputError(f"open3d cannot read it: {e}", path=path) from None
    if "positions" not in pcd.point or len(pcd.point.positions) == 0:
        raise PedcalInputError("no points (a readable .pcd/.ply with x, y, z was expected)", path=path)
    xyz = pcd.point.positions.numpy().astype(float).reshape(-1, 3)
    intensity = np.zeros(len(xyz))
    for name in _INTENSITY_FIELDS:
        if name in pcd.point:
            intensity = pcd.point[name].numpy().astype(float).reshape(len(xyz), -1)[:, 0]
            break
    else:
        if "colors" in pcd.point:
            col = pcd.point.colors.numpy().astype(float)
            if col.max(initial=0.0) > 1.0:  # 8-bit colours
                col = col / 255.0
            intensity = col.mean(axis=1)
    return np.column_stack([xyz, intensity])


def read_point_cloud(path: str | Path) -> np.ndarray:
    """(N, 4) ``x, y, z, intensity`` of a .bin, .pcd or .ply file; PedcalInputError when bad."""
    path = Path(path)
    if not path.is_file():
        raise PedcalInputError("no such point-cloud file", path=path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise PedcalInputError(f"unknown point-cloud type '{suffix}', expected one of {', '.join(SUFFIXES)}",
                               path=path)
    pts = read_kitti_bin(path) if suffix == ".bin" else read_open3d(path)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise PedcalInputError(f"{int(bad.sum())} points hold NaN or infinite values "
                               f"(first at point {int(np.flatnonzero(bad)[0])})", path=path,
                               row=int(np.flatnonzero(bad)[0]))
    return pts


def floor_referenced(points: np.ndarray, *, distance_threshold_m: float = 0.05,
                     seed: int = 0) -> tuple[np.ndarray, float]:
    """The points shifted so that z = 0 on the floor, and the shift that was added to z.

    A cloud whose lowest points (1st percentile of z) lie within 0.1 m of z = 0 and which has no
    points below -0.1 m is taken as already floor-referenced (the simulator's frames, or a crop
    such as KITTI's labelled pedestrian) and returned unchanged. Otherwise (a KITTI scan has z = 0
    at the sensor, the floor some 1.7 m below) the floor is the largest near-horizontal plane
    found by RANSAC (open3d ``segment_plane``) among the lowest 30 % of the points; its height
    under the sensor is subtracted. Without such a plane the 1st percentile of z is taken as
    the floor and a DegenerateDataWarning says so.
    """
    z = points[:, 2]
    z_low = float(np.percentile(z, 1.0))
    if abs(z_low) <= 0.1 and z.min() >= -0.1:
        return points, 0.0
    floor_z = z_low
    low = points[z <= np.percentile(z, 30.0), :3]
    if len(low) >= 3:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(low))
        o3d.utility.random.seed(seed)
        (a, b, c, d), inliers = pc.segment_plane(distance_threshold_m, 3, 200)
        if abs(c) > 0.95 and len(inliers) >= 0.2 * len(low):
            floor_z = float(np.median(low[inliers, 2]))
        else:
            warnings.warn("no horizontal floor plane among the lowest points; the floor is taken at the "
                          f"1st percentile of z ({z_low:.2f} m)", DegenerateDataWarning, stacklevel=2)
    out = points.copy()
    out[:, 2] -= floor_z
    return out, -floor_z
