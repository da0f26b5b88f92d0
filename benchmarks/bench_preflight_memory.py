"""The calibration pre-flight's memory estimate (pedcal.io.preflight) beside the measured peak RSS
growth of a factor-graph calibration, on the simulated sparse log driven K times in a row (times
shifted), so the estimate can be checked to stay an upper figure as the span grows.

    nice -n 10 .venv/bin/python benchmarks/bench_preflight_memory.py [K ...]   (default 1 4)

Each K runs in its own process (peak RSS never goes down).
"""

from __future__ import annotations

import resource
import subprocess
import sys
import tempfile
import time

import pandas as pd


def one(log_dir: str, k: int) -> None:
    from pedcal.calib import calibrate
    from pedcal.io import read_log
    from pedcal.io.preflight import calibration_memory_bytes

    log = read_log(log_dir)
    span = log.robot.t.max() - log.robot.t.min() + 1.0

    def repeat(df):
        return None if df is None else pd.concat([df.assign(t=df.t + i * span) for i in range(k)], ignore_index=True)

    log.robot, log.odometry = repeat(log.robot), repeat(log.odometry)
    log.observations = pd.concat([log.observations.assign(t=log.observations.t + i * span,
                                                          track=log.observations.track + f"#{i}")
                                  for i in range(k)], ignore_index=True)
    log.truth_observations = log.truth_robot = None
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    w, c = time.perf_counter(), time.process_time()
    calibrate(log)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(f"{k:3d} {len(log.robot):7d} {calibration_memory_bytes(log) / 1e6:12.0f} {(peak - base) / 1e3:14.0f} "
          f"{time.perf_counter() - w:7.1f} {time.process_time() - c:6.1f}")


def main(ks: list[int]) -> None:
    from pedcal.sim import simulate

    with tempfile.TemporaryDirectory() as tmp:
        simulate("sparse", tmp, seed=0, progress=False)
        print(f"{'K':>3s} {'poses':>7s} {'estimate_MB':>12s} {'rss_growth_MB':>14s} {'wall_s':>7s} {'cpu_s':>6s}")
        for k in ks:
            subprocess.run([sys.executable, __file__, "--one", f"{tmp}/calib", str(k)], check=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--one":
        one(sys.argv[2], int(sys.argv[3]))
    else:
        main([int(a) for a in sys.argv[1:]] or [1, 4])
