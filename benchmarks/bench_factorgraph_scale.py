"""How the factor graph's time and memory grow with the network: synthetic installations of up to
1000 ceiling sensors and ~400 000 robot observations, generated directly (not through the full
simulator): sensors on a 1.5 m grid 2.6 m up, pitched 50 deg, looking along +-x / +-y; a robot
driving a lawnmower of lanes 0.5 m apart at 1 m/s; AMCL at 5 Hz with an OU error (5 cm, 20 s);
exact odometry at 20 Hz; each sensor reporting the head at 40 Hz within 1.2 m of its look-at point
(1 cm noise); installed extrinsics off by 0.2 m / 3 deg. The robot's observations are given
(no association); the closed form initializes; latency, people and the head dome are off. Every
sensor's clock offset is estimated (the default recipe): above its ``clock_offsets_joint_max``
(200) sensors as variables of the linear system, each one's sigma given the robot's path.

    nice -n 5 .venv/bin/python benchmarks/bench_factorgraph_scale.py [--sizes 10,40,160,500,1000] [--blas-threads 1]

Each size runs in its own process, so its peak resident memory (ru_maxrss) is its own, with BLAS
on ``--blas-threads`` threads (1 by default: a multi-threaded OpenBLAS's idle threads spin while
they wait, and on a busy shared machine that spinning counts as CPU time, several times the work
of the small dense blocks here; ``bench_factorgraph_stages.py`` splits the time by stage). Prints
sensors, observations, robot poses, calibrate() wall and CPU time (s; time.process_time, which a
busy neighbour on a shared machine does not inflate), peak RSS (MB), the minor page faults of the
calibration (thousands: each a fresh 4 KB page the kernel zeroes, a share of the system CPU time
that large temporary arrays cost), and the growth exponents of
time and memory against the number of observations (least-squares slope in log-log), with the
machine's load average at the start and the end.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
import warnings

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from pedcal.model import Log, Meta, SensorExtrinsics, SensorNetwork
from pedcal.sim.robot import ou_process

HEAD = np.array([0.0, 0.0, 1.35])


def synthetic_log(n_sensors: int, seed: int = 0) -> Log:
    rng = np.random.default_rng(seed)
    cols = int(np.ceil(np.sqrt(n_sensors * 1.6)))
    rows = int(np.ceil(n_sensors / cols))
    spacing, pitch = 1.5, 50.0
    look = (2.6 - HEAD[2]) / np.tan(np.radians(pitch))
    truth, installed, centres = [], [], []
    for k in range(n_sensors):
        r, c = divmod(k, cols)
        yaw = 90.0 * rng.integers(0, 4)
        centre = np.array([1.0 + spacing * c, 1.0 + spacing * r])
        pos = np.r_[centre - look * np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))]), 2.6]
        s = SensorExtrinsics(f"s{k:04d}", pos, [yaw, pitch, 0.0])
        truth.append(s)
        installed.append(SensorExtrinsics(s.id, pos + rng.normal(0, 0.2, 3) * [1, 1, 0.3],
                                          s.ypr_deg + rng.normal(0, 3.0, 3)))
        centres.append(centre)
    truth, installed, centres = SensorNetwork(truth), SensorNetwork(installed), np.array(centres)
    # lawnmower along x, lanes 0.5 m apart, 1 m/s
    x0, x1 = 0.0, 2.0 + spacing * (cols - 1)
    lanes = np.arange(0.0, 2.0 + spacing * (rows - 1) + 1e-9, 0.5)
    wp = np.concatenate([[[x0, y], [x1, y]] if i % 2 == 0 else [[x1, y], [x0, y]] for i, y in enumerate(lanes)])
    seg = np.linalg.norm(np.diff(wp, axis=0), axis=1)
    s_wp = np.r_[0.0, np.cumsum(seg)]
    t = np.arange(0.0, s_wp[-1], 1.0 / 40.0)
    xy = np.column_stack([np.interp(t, s_wp, wp[:, 0]), np.interp(t, s_wp, wp[:, 1])])
    d = np.gradient(xy, axis=0)
    yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    truth_robot = pd.DataFrame({"t": t, "x": xy[:, 0], "y": xy[:, 1], "yaw": yaw})
    odo = truth_robot.iloc[::4].reset_index(drop=True)                    # exact, 10 Hz
    ta = t[::8]                                                           # AMCL at 5 Hz
    n = len(ta)
    amcl = pd.DataFrame({"t": ta, "x": xy[::8, 0] + ou_process(rng, n, 0.2, 0.05, 20.0),
                         "y": xy[::8, 1] + ou_process(rng, n, 0.2, 0.05, 20.0),
                         "yaw": yaw[::8] + ou_process(rng, n, 0.2, np.radians(1.0), 20.0),
                         "cov_xx": 0.05 ** 2, "cov_xy": 0.0, "cov_xyaw": 0.0, "cov_yy": 0.05 ** 2,
                         "cov_yyaw": 0.0, "cov_yawyaw": np.radians(1.0) ** 2})
    head = np.column_stack([xy, np.full(len(t), HEAD[2])])
    near = cKDTree(xy).query_ball_point(centres, r=1.2)
    parts = []
    for s_true, s_inst, idx in zip(truth, installed, near, strict=True):
        idx = np.asarray(idx, int)
        if len(idx) == 0:
            continue
        p_s = s_true.to_sensor(head[idx]) + rng.normal(0, 0.01, (len(idx), 3))
        p_w = s_inst.to_world(p_s)
        parts.append(pd.DataFrame({"t": t[idx], "sensor": s_true.id, "track": "1",
                                   "x": p_w[:, 0], "y": p_w[:, 1], "z": p_w[:, 2]}))
    obs = pd.concat(parts, ignore_index=True).sort_values("t", kind="stable").reset_index(drop=True)
    return Log(sensors=installed, robot=amcl, observations=obs, odometry=odo, meta=Meta(HEAD.copy()),
               truth=truth, truth_robot=truth_robot)


def run_one(n_sensors: int) -> dict:
    from pedcal.calib.factorgraph import calibrate_factorgraph

    log = synthetic_log(n_sensors)
    warnings.simplefilter("ignore")
    faults0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    t0, c0 = time.perf_counter(), time.process_time()
    res = calibrate_factorgraph(log, is_robot=np.ones(len(log.observations), bool), estimate_latency=False,
                                people=False, head_radius_m=0.0)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults0
    err = np.array([s.position_m - log.truth[s.id].position_m for s in res.network])
    sigma = np.array([s.sigma_position_m for s in res.network])
    # (an error or a sigma alone rewards failure: the share of sensors within their sigma, per axis)
    within = 100.0 * np.mean(np.abs(err[:, :2]) <= sigma[:, :2], axis=0)
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return dict(sensors=n_sensors, observations=len(log.observations), poses=int(len(log.robot)),
                time_s=elapsed, cpu_s=cpu, peak_rss_mb=rss_mb, minor_faults=faults, build_s=res.diagnostics.build_s,
                optimize_s=res.diagnostics.optimize_s, rms_mm=float(1000 * np.sqrt(np.mean(np.sum(err ** 2, axis=1)))),
                sigma_xy_mm=[float(v) for v in 1000 * np.median(sigma[:, :2], axis=0)],
                within_xy_pct=[float(v) for v in within])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="10,40,160,500,1000")
    ap.add_argument("--blas-threads", type=int, default=1, help="BLAS threads of each size's process")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(run_one(args.one)))
        return
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(args.blas_threads)
    out = []
    print(f"BLAS threads: {args.blas_threads}; load average at the start {os.getloadavg()[0]:.1f}")
    print(f"{'sensors':>8s} {'observations':>13s} {'AMCL poses':>11s} {'time (s)':>9s} {'CPU (s)':>8s} {'build':>7s} "
          f"{'optimize':>9s} {'peak RSS (MB)':>14s} {'page faults (k)':>16s} {'RMS (mm)':>9s} "
          f"{'median sigma x, y (mm)':>23s} "
          f"{'within 1 sigma x, y (%)':>24s}")
    for n in (int(v) for v in args.sizes.split(",")):
        r = json.loads(subprocess.run([sys.executable, __file__, "--one", str(n)], capture_output=True, text=True,
                                      check=True, env=env).stdout.strip().splitlines()[-1])
        out.append(r)
        print(f"{r['sensors']:8d} {r['observations']:13d} {r['poses']:11d} {r['time_s']:9.2f} {r['cpu_s']:8.2f} "
              f"{r['build_s']:7.2f} "
              f"{r['optimize_s']:9.2f} {r['peak_rss_mb']:14.0f} {r['minor_faults'] / 1000:16.0f} {r['rms_mm']:9.1f} "
              f"{r['sigma_xy_mm'][0]:15.1f}, {r['sigma_xy_mm'][1]:6.1f} "
              f"{r['within_xy_pct'][0]:16.0f}, {r['within_xy_pct'][1]:6.0f}", flush=True)
    if len(out) >= 2:
        n_obs = np.log([r["observations"] for r in out])
        slope_t = np.polyfit(n_obs, np.log([r["time_s"] for r in out]), 1)[0]
        slope_c = np.polyfit(n_obs, np.log([r["cpu_s"] for r in out]), 1)[0]
        slope_m = np.polyfit(n_obs, np.log([r["peak_rss_mb"] for r in out]), 1)[0]
        print(f"growth exponent vs observations: time {slope_t:.2f} (CPU {slope_c:.2f}), peak RSS {slope_m:.2f}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
