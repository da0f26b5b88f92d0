"""Speed of Kimoto et al.'s grid search at the paper's resolution (+-60 deg at 0.01 deg, +-1000 mm at
5 mm), and evidence that it is the exhaustive search's optimum.

    .venv/bin/python benchmarks/bench_gridsearch.py [--repeats 5] [--no-brute] [--no-sim]

1. A paper-like sensor (2.6 m up, pitch 45 deg) with 1000 noisy pairs: time per stage and total,
   and the exhaustive search of the same stages where it is affordable (pitch/roll on a +-5 deg
   window, 1001^2 cells; yaw over all 12001 values; x/y over all 401^2 cells), compared cell for cell.
2. The simulator's paper scenario (seed 0), calibration log with the truth association: time per
   sensor and in total, and the error against the true extrinsics.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pedcal import frames
from pedcal.calib import gridsearch as gs
from pedcal.model import SensorExtrinsics


def paper_like_pairs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    truth = SensorExtrinsics("bench", [1.0, 2.0, 2.6], [30.0, 45.0, 1.5])
    axis = truth.R_world_sensor[:, 0]
    centre = truth.position_m + (1.35 - truth.position_m[2]) / axis[2] * axis
    head = np.column_stack([centre[:2] + rng.uniform(-1.3, 1.3, (n, 2)), np.full(n, 1.35)])
    p_sensor = truth.to_sensor(head) + rng.normal(0.0, 0.01, (n, 3))          # sensor noise 1 cm
    amcl_head = head + np.column_stack([rng.normal(0.0, 0.05, (n, 2)), np.zeros(n)])  # AMCL 5 cm
    initial = SensorExtrinsics("bench", truth.position_m + [0.3, -0.25, 0.1], truth.ypr_deg + [6.0, -5.0, 4.0])
    return truth, p_sensor, amcl_head, initial


def bench_sensor(repeats: int, brute: bool) -> None:
    truth, p, head, initial = paper_like_pairs(1000, seed=0)
    times, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = gs.grid_search_sensor(p, head, initial)
        times.append(time.perf_counter() - t0)
    print(f"paper-like sensor, N = {len(p)} pairs, paper resolution: grid search "
          f"{1000 * np.median(times):.1f} ms median of {repeats} (min {1000 * min(times):.1f} ms)")
    print("  stages (last run, ms): " + ", ".join(f"{k} {1000 * v:.1f}" for k, v in res.timings_s.items()))
    est = res.extrinsics
    print(f"  error vs truth: position {1000 * np.linalg.norm(est.position_m - truth.position_m):.1f} mm, "
          f"rotation {frames.rotation_angle_deg(est.R_world_sensor, truth.R_world_sensor):.3f} deg")
    if not brute:
        return

    # Pitch/roll: the fast search and the exhaustive one on a +-5 deg window around the same centre.
    centre = SensorExtrinsics("bench", initial.position_m, [initial.ypr_deg[0], *est.ypr_deg[1:]])
    grids = gs._Grids(centre, 5.0, 0.01, 1.0, 0.005)
    t0 = time.perf_counter()
    zdev_fast, ip_f, ir_f = gs._zdev_fast(p, head[:, 2], grids, gs._Progress(False, ""))
    t_fast = time.perf_counter() - t0
    n_roll = len(grids.roll)
    tz = grids.z[grids.kz0]
    t0 = time.perf_counter()
    zdev_brute, k = gs._brute_argmin(
        len(grids.pitch) * n_roll,
        lambda f: gs._zdev_cells(p, head[:, 2], tz, grids.pitch, grids.roll, f // n_roll, f % n_roll), len(p))
    t_brute = time.perf_counter() - t0
    cells = len(grids.pitch) * n_roll
    print(f"  pitch/roll on +-5 deg ({cells} cells): fast {1000 * t_fast:.1f} ms, exhaustive {t_brute:.1f} s "
          f"(full 12001^2 grid extrapolated: {t_brute * 12001 ** 2 / cells / 3600:.1f} h); "
          f"same cell: {(ip_f, ir_f) == divmod(k, n_roll) and zdev_fast == zdev_brute}")

    # Yaw and x/y over the paper's full ranges, after the fast pitch/roll.
    grids = gs._Grids(initial, 60.0, 0.01, 1.0, 0.005)
    ip, ir = res.index["pitch"] + len(grids.pitch) // 2, res.index["roll"] + len(grids.roll) // 2
    q = gs._rotate_pitch_roll(p, grids.pitch, grids.roll, ip, ir)
    t_xy = initial.position_m[:2]
    t0 = time.perf_counter()
    fast_yaw = gs._xydev_fast(q, head[:, :2], t_xy, grids.yaw)
    t_fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    brute_yaw = gs._brute_argmin(len(grids.yaw), lambda f: gs._xydev_cells(q, head[:, :2], t_xy, grids.yaw, f),
                                 len(p))
    t_brute = time.perf_counter() - t0
    print(f"  yaw over 12001 values: fast {1000 * t_fast:.2f} ms, exhaustive {1000 * t_brute:.0f} ms; "
          f"same cell: {fast_yaw == brute_yaw}")
    iy = res.index["yaw"] + len(grids.yaw) // 2
    sy, cy = grids.yaw.sin[iy], grids.yaw.cos[iy]
    r_xy = np.column_stack([cy * q[:, 0] - sy * q[:, 1], sy * q[:, 0] + cy * q[:, 1]])
    ny = len(grids.y)
    t0 = time.perf_counter()
    fast_xy = gs._xydist_branch_and_bound(r_xy, head[:, :2], grids.x, grids.y, 0.005)
    t_fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    v, k = gs._brute_argmin(len(grids.x) * ny,
                            lambda f: gs._xydist_cells(r_xy, head[:, :2], grids.x, grids.y, f // ny, f % ny), len(p))
    t_brute = time.perf_counter() - t0
    print(f"  x/y over 401^2 cells: fast {1000 * t_fast:.1f} ms, exhaustive {t_brute:.1f} s; "
          f"same cell: {fast_xy == (v, k // ny, k % ny)}")


def bench_paper_scenario() -> None:
    try:
        from pedcal.sim import simulate_logs
    except ImportError as exc:
        print(f"paper scenario skipped: {exc}")
        return
    from pedcal.calib.gridsearch import calibrate_gridsearch

    t0 = time.perf_counter()
    log = simulate_logs("paper", seed=0).calib
    print(f"paper scenario (seed 0) simulated in {time.perf_counter() - t0:.1f} s: {len(log.sensors)} sensors, "
          f"{len(log.observations)} observations")
    tr = log.truth_observations
    mask = np.zeros(len(log.observations), dtype=bool)
    mask[tr.loc[tr["who"] == "robot", "row"].to_numpy()] = True
    res = calibrate_gridsearch(log, is_robot=mask)
    diag = res.diagnostics.sensors
    errs = []
    for s in res.network:
        line = f"  {s.id:>6s} {s.status:10s} obs {s.observations:5d}"
        if s.id in diag:
            t = sum(diag[s.id].timings_s.values())
            true = log.truth[s.id]
            dp = 1000 * np.linalg.norm(s.position_m - true.position_m)
            da = frames.rotation_angle_deg(s.R_world_sensor, true.R_world_sensor)
            errs.append(dp)
            line += f"  {1000 * t:7.1f} ms  position error {dp:6.1f} mm  rotation error {da:5.2f} deg"
        print(line)
    n_run = len(diag)
    print(f"  total {res.runtime_s:.2f} s for {len(res.network)} sensors ({n_run} searched); "
          f"position RMS {np.sqrt(np.mean(np.square(errs))):.1f} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-brute", action="store_true", help="skip the exhaustive comparisons")
    ap.add_argument("--no-sim", action="store_true", help="skip the simulated paper scenario")
    args = ap.parse_args()
    bench_sensor(args.repeats, brute=not args.no_brute)
    if not args.no_sim:
        bench_paper_scenario()


if __name__ == "__main__":
    main()
