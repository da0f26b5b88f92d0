"""Time of ``pedcal.sim.simulate`` (both logs, written to a temporary directory) and the
observation counts, per scenario, seed 0.

    .venv/bin/python benchmarks/bench_simulate.py [scenario ...]
"""

from __future__ import annotations

import sys
import tempfile
import time

import numpy as np

from pedcal.sim import log_summary, simulate


def main(names: list[str]) -> None:
    print(f"{'scenario':8s} {'sensors':>7s} {'simulate_s':>10s} {'run':>5s} {'obs':>7s} {'robot':>6s} "
          f"{'people':>6s} {'false':>5s} {'dur_s':>6s} {'inst_err_mm':>11s}")
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = simulate(name, tmp, seed=0)
            elapsed = time.perf_counter() - t0
        log = res.calib
        err_mm = 1000 * np.mean([np.linalg.norm(s.position_m - log.truth[s.id].position_m) for s in log.sensors])
        for run, lg in (("calib", res.calib), ("eval", res.eval)):
            s = log_summary(lg)
            print(f"{name:8s} {len(log.sensors):7d} {elapsed:10.2f} {run:>5s} {s['observations']:7d} "
                  f"{s['robot']:6d} {s['pedestrians']:6d} {s['false_tracks']:5d} {s['duration_s']:6.0f} "
                  f"{err_mm:11.0f}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["paper", "sparse", "mall"])
