"""The local ground (``pedcal.detect.ground``) on every labelled real frame in ../shared/data:
how far the bottom of each labelled car and pedestrian box lies from the ground estimated under
it, and how long the estimate takes.

Run: .venv/bin/python benchmarks/bench_ground.py [--data ../shared/data] [--max-range 60] [--repeats 7]

Accuracy: for every ``Pedestrian`` and ``Car`` box (``psr.position`` = centre, ``psr.scale`` = full
size) within ``--max-range`` m of the sensor, box bottom (centre z - height / 2) minus the ground
height at the box centre; per dataset the median and worst |difference| and the share within
0.2 m, for ``estimate_ground`` and, as the baseline, the lowest point of each 1 m cell with a
5 x 5-cell neighbourhood's minimum standing in for cells more than 0.3 m above it (pedcal's floor
before ``pedcal.detect.ground``). Frames without labels (``kitti_pedestrian``) print the ground
found under the sensor and the warnings. Speed: the median wall-clock and CPU time of
``estimate_ground`` and of ``ground_referenced`` (estimate and subtraction) on the largest frame
(a 100k-point Argoverse 2 sweep of two VLP-32C) and on a KITTI HDL-64E frame.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from pedcal.detect.ground import estimate_ground, ground_referenced
from pedcal.detect.pointcloud_io import read_point_cloud
from pedcal.detect.real_eval import read_boxes

DATASETS = (("KITTI HDL-64E (lidar_people_train)", "lidar_people_train/kitti_*.pcd"),
            ("Argoverse 2, two VLP-32C (lidar_people_train)", "lidar_people_train/av2_*.pcd"),
            ("SUSTech (sustech_points)", "sustech_points/*.pcd"),
            ("KITTI crops (kitti_pedestrian)", "kitti_pedestrian/*.bin"))


def lowest_per_cell(points: np.ndarray, cell_m: float = 1.0, max_step_m: float = 0.3, window_cells: int = 5):
    """The baseline: a ground height function of xy from the lowest point of each cell."""
    origin = points[:, :2].min(axis=0)
    ij = np.floor((points[:, :2] - origin) / cell_m).astype(np.int64)
    z_min = np.full(tuple(ij.max(axis=0) + 1), np.inf)
    np.minimum.at(z_min, (ij[:, 0], ij[:, 1]), points[:, 2])
    filled = np.isfinite(z_min)
    nb_min = ndimage.minimum_filter(z_min, size=window_cells, mode="nearest")
    ground = np.where(z_min > nb_min + max_step_m, nb_min, z_min)
    _, (ri, ci) = ndimage.distance_transform_edt(~filled, return_indices=True)
    ground = ground[ri, ci]
    return lambda xy: ndimage.map_coordinates(ground, ((xy - origin) / cell_m - 0.5).T, order=1, mode="nearest")


def accuracy(data: Path, max_range_m: float) -> None:
    print(f"box bottom - ground under the box centre, Pedestrian and Car boxes within {max_range_m:g} m")
    print(f"{'dataset':46} {'boxes':>5}  {'method':18} {'median |d|':>10} {'worst |d|':>9} {'<= 0.2 m':>8}")
    for name, pattern in DATASETS:
        diffs = {"local ground": [], "lowest per 1 m cell": []}
        for cloud in sorted(data.glob(pattern)):
            pts = read_point_cloud(cloud)
            est = estimate_ground(pts, warn=False)
            label = cloud.with_suffix(".json")
            if not label.is_file():
                print(f"  {cloud.name}: no labels; ground {-est.sensor_height_m:+.2f} m from the sensor"
                      + "".join(f"; warning: {w}" for w in est.warnings))
                continue
            boxes = [b for b in read_boxes(label) if b["type"] in ("Pedestrian", "Car")
                     and np.hypot(b["cx"], b["cy"]) <= max_range_m]
            if not boxes:
                continue
            xy = np.array([[b["cx"], b["cy"]] for b in boxes])
            bottom = np.array([b["cz"] - b["height"] / 2 for b in boxes])
            diffs["local ground"].append(bottom - est.height_at(xy))
            diffs["lowest per 1 m cell"].append(bottom - lowest_per_cell(pts)(xy))
        for method, d in diffs.items():
            if d:
                d = np.abs(np.concatenate(d))
                print(f"{name:46} {len(d):5d}  {method:18} {np.median(d):10.3f} {d.max():9.2f} "
                      f"{np.mean(d <= 0.2):8.2f}")


def speed(data: Path, repeats: int) -> None:
    frames = sorted(data.glob("lidar_people_train/*.pcd"))
    if not frames:
        return
    sizes = {f: len(read_point_cloud(f)) for f in frames}
    picks = [max(frames, key=sizes.get)] + [f for f in frames if f.name.startswith("kitti")][:1]
    for f in picks:
        pts = read_point_cloud(f)
        for fn in (estimate_ground, ground_referenced):
            fn(pts, warn=False)  # warm up
            wall, cpu = [], []
            for _ in range(repeats):
                c0, t0 = time.process_time(), time.perf_counter()
                fn(pts, warn=False)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            print(f"{fn.__name__:18} {f.name}: {len(pts)} points, median {1e3 * np.median(wall):.1f} ms wall, "
                  f"{1e3 * np.median(cpu):.1f} ms CPU ({repeats} runs)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data")
    ap.add_argument("--max-range", type=float, default=60.0)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    accuracy(args.data, args.max_range)
    speed(args.data, args.repeats)


if __name__ == "__main__":
    main()
