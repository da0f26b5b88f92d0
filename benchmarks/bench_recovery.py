"""Speed of one recovery step of the factor-graph tracker: grid belief + fixed-lag smoother.

Run: .venv/bin/python benchmarks/bench_recovery.py [--steps N] [--map PATH.yaml]
     .venv/bin/python benchmarks/bench_recovery.py --compare [--seeds N] [--scenes passing,corner,...]

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
    cpu0 = time.process_time()
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
    cpu_ms = 1e3 * (time.process_time() - cpu0) / steps   # the whole loop, simulation included
    t_grid, t_smoother = np.array(t_grid) * 1e3, np.array(t_smoother) * 1e3
    total = t_grid + t_smoother
    return {"cells": grid.belief.size, "readings_per_step": float(np.mean(n_readings)), "cpu_per_step_ms": cpu_ms,
            **{f"{name}_{stat}_ms": float(f(v)) for name, v in (("grid", t_grid), ("smoother", t_smoother),
                                                                ("step", total))
               for stat, f in (("median", np.median), ("p90", lambda a: np.percentile(a, 90)))}}


TRACKER_NAMES = ("paper", "factorgraph", "lidar-only")


def compare(scenes: list[str], n_seeds: int) -> None:
    """``run_follow`` on every scene x seed x tracker; per scene (and all): mean with_target_fraction,
    mean of the runs' mean reacquire times, the largest reacquire time, median lost_position_error_m,
    searching frames, losses, and runs that lost the target and did not end holding it."""
    import warnings

    from pedcal.track.follow import run_follow

    runs: dict[tuple[str, str], list[dict]] = {}
    for scene in scenes:
        for name in TRACKER_NAMES:
            for seed in range(n_seeds):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    m = run_follow(scene, tracker=name, seed=seed).to_dict()
                runs.setdefault((scene, name), []).append(m)
                runs.setdefault(("all", name), []).append(m)

    def fmt(v) -> str:
        return "n/a" if v is None else f"{v:.2f}"

    print(f"{'scene':9s} {'tracker':12s} {'runs':>4s} {'with_tgt':>8s} {'reacq_mean_s':>12s} {'reacq_max_s':>11s} "
          f"{'lost_err_m':>10s} {'searching':>9s} {'losses':>6s} {'unrecovered':>11s}")
    for scene in [*scenes, "all"]:
        for name in TRACKER_NAMES:
            ms = runs[(scene, name)]
            reacq = [m["mean_reacquire_s"] for m in ms if m["mean_reacquire_s"] is not None]
            reacq_max = [m["max_reacquire_s"] for m in ms if m["max_reacquire_s"] is not None]
            lost_err = [m["lost_position_error_m"] for m in ms if m["lost_position_error_m"] is not None]
            unrecovered = sum(m["unrecovered_losses"] for m in ms)
            print(f"{scene:9s} {name:12s} {len(ms):4d} {np.mean([m['with_target_fraction'] for m in ms]):8.3f} "
                  f"{fmt(np.mean(reacq) if reacq else None):>12s} {fmt(max(reacq_max) if reacq_max else None):>11s} "
                  f"{fmt(np.median(lost_err) if lost_err else None):>10s} "
                  f"{sum(m['searching_frames'] for m in ms):9d} {sum(m['lost_episodes'] for m in ms):6d} "
                  f"{unrecovered:11d}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--map", type=Path, default=TURTLEBOT_MAP if TURTLEBOT_MAP.is_file() else None)
    ap.add_argument("--compare", action="store_true", help="tracker comparison on the follow scenes instead")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--scenes", default="passing,corner,crossing,recorded")
    args = ap.parse_args()
    if args.compare:
        compare(args.scenes.split(","), args.seeds)
        return
    r = bench(args.steps, args.map)
    print(f"map: {args.map or 'none (empty window)'}; {r['cells']} cells; "
          f"{r['readings_per_step']:.2f} ESPAR readings per step; {args.steps} steps")
    for name in ("grid", "smoother", "step"):
        print(f"{name:9s} median {r[f'{name}_median_ms']:6.2f} ms   p90 {r[f'{name}_p90_ms']:6.2f} ms")
    print(f"CPU per step (the loop, simulation included): {r['cpu_per_step_ms']:.2f} ms")


if __name__ == "__main__":
    main()
