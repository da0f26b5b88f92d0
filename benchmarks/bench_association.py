"""Speed and quality of picking out the robot's observations, and of the closed-form fit.

Run: .venv/bin/python benchmarks/bench_association.py [scenario ...]   (default: paper sparse mall)
Prints, per simulated scenario (seed 0, default nuisances): observations, sensors, association
time, precision/recall against the truth, the estimated tracker latency, and the closed-form
sensor position RMS against the true extrinsics.
"""

import sys
import time
import warnings

from pedcal.calib.association import associate_robot, score_association
from pedcal.calib.closedform import calibrate_closedform
from pedcal.errors import DegenerateDataWarning
from pedcal.metrics import evaluate
from pedcal.sim import simulate_logs


def main(scenarios):
    print(f"{'scenario':>9s} {'obs':>7s} {'sensors':>7s} {'assoc s':>8s} {'precision':>9s} {'recall':>7s} "
          f"{'latency s':>9s} {'closed-form pos RMS mm':>23s} {'degenerate/no-data':>18s}")
    for name in scenarios:
        log = simulate_logs(name, seed=0).calib
        t0 = time.perf_counter()
        assoc = associate_robot(log)
        assoc_s = time.perf_counter() - t0
        score = score_association(log, assoc.is_robot)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DegenerateDataWarning)
            cf = calibrate_closedform(log, is_robot=assoc.is_robot, latency_s=assoc.latency_s)
        rms = evaluate(log, cf.network).sensor_position_rms_mm.combined
        unusable = sum(s.status != "ok" for s in cf.network)
        print(f"{name:>9s} {len(log.observations):7d} {len(log.sensors):7d} {assoc_s:8.2f} "
              f"{score['precision']:9.4f} {score['recall']:7.4f} {assoc.latency_s:9.3f} {rms:23.1f} "
              f"{unusable:18d}")


if __name__ == "__main__":
    main(sys.argv[1:] or ["paper", "sparse", "mall"])
