"""Speed of one recovery step of the factor-graph tracker: grid belief + fixed-lag smoother.

Run: .venv/bin/python benchmarks/bench_recovery.py [--steps N] [--map PATH.yaml]

A target walks out of the robot's view; the robot drives after it at 0.8 m/s while the target is
out of sight, and every 0.25 s LIDAR frame runs what ``FactorGraphTracker`` runs when the target is
lost: the grid belief's motion step, the LIDAR's negative information (ray casting, two people as
occluders), one antenna likelihood per ESPAR reading (two antennas at 2 Hz), the smoother's
iSAM2 update (window 10 s) and the fused estimate. Prints median and p90 per step of the grid part,
the smoother part and the whole, over the TurtleBot 4 floor map when it is present (a free window
of it), else an empty map.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pedcal.io.maps import read_occupancy_map
from pedcal.sim.espar import EsparParams, EsparSimulator
from pedcal.track.grid_belief import GridBelief
from pedcal.track.recovery import TargetSmoother

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
TURTLEBOT_MAP = SHARED_DATA / "turtlebot4_ros2_bag" / "mac_1st_floor_final.yaml"
START_XY = np.array([6.425, -13.225])      # a free cell of the TurtleBot floor


def bench(steps: int, map_path: Path | None, seed: int = 0) -> dict:
    occ = read_occupancy_map(map_path) if map_path is not None else None
    rng = np.random.default_rng(seed)
    espar = EsparSimulator(EsparParams(), np.random.default_rng(seed + 1))
    grid = GridBelief(occ, START_XY)
    grid.reset_gaussian(START_XY + [1.5, 0.0], 0.5)
    smoother = TargetSmoother()
    cov = np.diag([0.03 ** 2, 0.03 ** 2, np.radians(1.0) ** 2])
    heading = rng.uniform(-np.pi, np.pi)
    target = START_XY + [1.5, 0.0]
    pose = np.array([*START_XY, 0.0])
    t_grid, t_smoother, n_readings = [], [], []
    for k in range(1, steps + 1):
        t = 0.25 * k
        heading += rng.normal(0.0, 0.2)
        target = target + 0.25 * 1.0 * np.array([np.cos(heading), np.sin(heading)])
        rel = target - pose[:2]
        pose[2] = np.arctan2(rel[1], rel[0]) + np.pi / 2           # looking away: target out of view
        pose[:2] += 0.2 * rel / max(np.hypot(*rel), 1e-9)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        R = np.array([[c, -s], [s, c]])
        readings = espar.readings(t - 0.25, t, R.T @ rel)
        people = pose[:2] + R @ rng.uniform([1.0, -2.0], [4.0, 2.0], (2, 2)).T
        t0 = time.perf_counter()
        grid.predict(0.25)
        grid.observe_empty(pose, people.T)
        for r in readings:
            grid.observe_bearing(pose[:2] + R @ r.xy_antenna_robot_m, pose[2] + r.bearing_robot_rad)
        t1 = time.perf_counter()
        seed_xy = grid.estimate()[0] if k == 1 else None
        smoother.add_frame(t, pose, cov, espar=readings, seed_xy_world_m=seed_xy, seed_sigma_m=1.0)
        xy_s, cov_s = smoother.latest()
        t2 = time.perf_counter()
        fused = grid.copy()
        fused.observe_gaussian(xy_s, cov_s)
        xy, _, _ = fused.estimate()
        grid.keep_in_window(xy)
        t3 = time.perf_counter()
        t_grid.append((t1 - t0) + (t3 - t2))
        t_smoother.append(t2 - t1)
        n_readings.append(len(readings))
    t_grid, t_smoother = np.array(t_grid) * 1e3, np.array(t_smoother) * 1e3
    total = t_grid + t_smoother
    return {"cells": grid.belief.size, "readings_per_step": float(np.mean(n_readings)),
            **{f"{name}_{stat}_ms": float(f(v)) for name, v in (("grid", t_grid), ("smoother", t_smoother),
                                                                ("step", total))
               for stat, f in (("median", np.median), ("p90", lambda a: np.percentile(a, 90)))}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--map", type=Path, default=TURTLEBOT_MAP if TURTLEBOT_MAP.is_file() else None)
    args = ap.parse_args()
    r = bench(args.steps, args.map)
    print(f"map: {args.map or 'none (empty window)'}; {r['cells']} cells; "
          f"{r['readings_per_step']:.2f} ESPAR readings per step; {args.steps} steps")
    for name in ("grid", "smoother", "step"):
        print(f"{name:9s} median {r[f'{name}_median_ms']:6.2f} ms   p90 {r[f'{name}_p90_ms']:6.2f} ms")


if __name__ == "__main__":
    main()
