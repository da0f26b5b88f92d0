"""Online calibration's cost per new pass of the robot under a sensor: the factor graph of a
simulated scenario (``pedcal simulate paper --seed 0``, in memory) fed to iSAM2 in time order with
the parameters of ``pedcal calibrate --online`` (pedcal.calib.online), one update each time a
pass ends, holding everything released since the update before (that pass's observations, the
robot's poses, odometry and AMCL since then).

    nice -n 10 .venv/bin/python benchmarks/bench_factorgraph_online.py [--scenario paper] [--seed 0]
        [--gap-s 1.0]

A pass: a sensor's observations of the robot at pose times no more than ``--gap-s`` apart. Prints
the number of updates, the factors per update and the wall and CPU time (time.process_time: the
machine may be shared) of ``ISAM2.update`` per update (median, 90th percentile, largest), and of
the same update followed by the sensors' estimates (calculateEstimate of their poses).
"""

from __future__ import annotations

import argparse
import time
import warnings

import gtsam
import numpy as np

from pedcal.calib.graph import GraphRecipe, S, build_graph, prepare
from pedcal.calib.online import _factor_times, factors_until, isam2_params


def pass_ends(prob, gap_s: float) -> np.ndarray:
    """The time each pass of the robot under a sensor ends (sorted)."""
    t = prob.pose_times[prob.fac_key_index]
    ends = []
    for i in range(len(prob.sensor_ids)):
        ts = np.sort(t[prob.fac_sensor_index == i])
        if len(ts):
            breaks = np.flatnonzero(np.diff(ts) > gap_s)
            ends.extend(ts[np.r_[breaks, len(ts) - 1]])
    return np.unique(ends)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gap-s", type=float, default=1.0)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    from pedcal.sim import simulate_logs

    log = simulate_logs(args.scenario, seed=args.seed).calib
    prob = prepare(log, GraphRecipe.load("default"))
    graph, values = build_graph(log, prob)
    ft = _factor_times(graph, prob)
    order = np.argsort(ft, kind="stable")
    isam = gtsam.ISAM2(isam2_params())               # as pedcal.calib.online
    added: set[int] = set()
    pos, rows = 0, []
    sensor_keys = [S(i) for i in range(len(prob.sensor_ids))]
    for edge in np.r_[pass_ends(prob, args.gap_s), np.inf]:
        new_graph, new_values, pos = factors_until(graph, values, order, ft, pos, edge, added)
        if new_graph.size() == 0:
            continue
        w0, c0 = time.perf_counter(), time.process_time()
        isam.update(new_graph, new_values)
        w1, c1 = time.perf_counter(), time.process_time()
        for key in sensor_keys:
            isam.calculateEstimatePose3(key)
        rows.append((new_graph.size(), w1 - w0, c1 - c0, time.perf_counter() - w0, time.process_time() - c0))
    r = np.array(rows[1:])          # the first update holds everything before the first pass
    ms = 1000.0 * r[:, 1:]
    print(f"{args.scenario} seed {args.seed}: {len(prob.sensor_ids)} sensors, {graph.size()} factors, "
          f"{len(r)} updates (one per pass of the robot under a sensor), {np.median(r[:, 0]):.0f} factors "
          f"per update (median; largest {r[:, 0].max():.0f})")
    for j, what in enumerate(["ISAM2.update wall", "ISAM2.update CPU", "update + sensor estimates wall",
                              "update + sensor estimates CPU"]):
        print(f"  {what:32s} median {np.median(ms[:, j]):6.1f} ms, 90th percentile "
              f"{np.percentile(ms[:, j], 90):6.1f} ms, largest {ms[:, j].max():6.1f} ms")


if __name__ == "__main__":
    main()
