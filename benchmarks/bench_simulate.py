"""Time of ``pedcal.sim.simulate`` (both logs, written to a temporary directory) and the
observation counts, per scenario, seed 0.

    .venv/bin/python benchmarks/bench_simulate.py [scenario ...]
"""

from __future__ import annotations

import sys
import tempfile
import time

import numpy as np

from pedcal.sim import load_scenario, log_summary, networks, simulate

N_SEEDS = 60


def installed_error_mm(name: str, seed: int) -> float:
    """Mean distance between installed and true sensor positions (mm)."""
    true_net, installed = networks(load_scenario(name).resolve(seed=seed))
    return 1000 * float(np.mean([np.linalg.norm(s.position_m - true_net[s.id].position_m) for s in installed]))


def main(names: list[str]) -> None:
    print(f"{'scenario':8s} {'sensors':>7s} {'simulate_s':>10s} {'run':>5s} {'obs':>7s} {'robot':>6s} "
          f"{'people':>6s} {'false':>5s} {'dur_s':>6s} {'inst_err_mm':>11s}")
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = simulate(name, tmp, seed=0)
            elapsed = time.perf_counter() - t0
        log = res.calib
        err_mm = installed_error_mm(name, 0)
        for run, lg in (("calib", res.calib), ("eval", res.eval)):
            s = log_summary(lg)
            print(f"{name:8s} {len(log.sensors):7d} {elapsed:10.2f} {run:>5s} {s['observations']:7d} "
                  f"{s['robot']:6d} {s['pedestrians']:6d} {s['false_tracks']:5d} {s['duration_s']:6.0f} "
                  f"{err_mm:11.0f}")
    for name in names:
        errs = [installed_error_mm(name, seed) for seed in range(N_SEEDS)]
        print(f"{name}: installed mean sensor position error over seeds 0-{N_SEEDS - 1}: "
              f"{np.mean(errs):.0f} mm (10th-90th percentile {np.percentile(errs, 10):.0f}-"
              f"{np.percentile(errs, 90):.0f} mm)")


if __name__ == "__main__":
    main(sys.argv[1:] or ["paper", "sparse", "mall"])
