"""A site that outgrows one solve: floors of ceiling sensors, each driven by the robot in its own
run (the synthetic installations of ``bench_factorgraph_scale.py``, one seed per floor, sensor ids
prefixed by the floor), calibrated run by run with pedcal.calib.site.calibrate_site: in parallel
on a local Dask cluster (or the scheduler at ``--scheduler``) and, unless ``--no-serial``, serially
in this process for comparison.

    nice -n 10 .venv/bin/python benchmarks/bench_factorgraph_site.py [--floors 10]
        [--sensors-per-floor 500] [--workers 2] [--scheduler ADDR] [--no-serial]

The defaults make a 5000-sensor site. Prints per run the solve's wall and CPU time (in its
worker), the site's wall time in parallel and serially, the speed-up, and each floor's sensor
position RMS against the truth. The robot's observations are found by the association (as for a
real run).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_factorgraph_scale import synthetic_log  # noqa: E402

from pedcal.calib.site import calibrate_site  # noqa: E402
from pedcal.io import read_sensors_yaml, write_log  # noqa: E402
from pedcal.model import SensorNetwork  # noqa: E402

OPTIONS = dict(estimate_latency=False, people=False, head_radius_m=0.0)   # as bench_factorgraph_scale


def floor_log(floor: int, n_sensors: int):
    """Floor ``floor``'s run: its own installation and drive, its sensors named fFF_sNNNN."""
    log = synthetic_log(n_sensors, seed=floor)
    prefix = f"f{floor:02d}_"
    out = copy.copy(log)
    out.sensors = SensorNetwork([dataclasses.replace(s, id=prefix + s.id) for s in log.sensors])
    out.truth = SensorNetwork([dataclasses.replace(s, id=prefix + s.id) for s in log.truth])
    out.observations = log.observations.assign(sensor=prefix + log.observations["sensor"].astype(str))
    return out


def rms_mm(output: str, truth: SensorNetwork) -> float:
    net = read_sensors_yaml(output)
    err = [np.linalg.norm(s.position_m - truth[s.id].position_m) for s in net]
    return float(1000 * np.sqrt(np.mean(np.square(err))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--floors", type=int, default=10)
    ap.add_argument("--sensors-per-floor", type=int, default=500)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    ap.add_argument("--no-serial", action="store_true", help="skip the serial comparison")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory(prefix="pedcal-site-") as tmp:
        root = Path(tmp)
        runs, truth = [], {}
        for f in range(args.floors):
            log = floor_log(f, args.sensors_per_floor)
            write_log(log, root / f"floor{f:02d}")
            runs.append(root / f"floor{f:02d}")
            truth[f"floor{f:02d}"] = log.truth
        n_sensors = sum(len(read_sensors_yaml(r / "sensors.yaml")) for r in runs)
        print(f"site: {args.floors} floors x {args.sensors_per_floor} sensors = {n_sensors} sensors")
        w0 = time.perf_counter()
        par = calibrate_site(runs, root / "parallel", scheduler=args.scheduler, workers=args.workers, **OPTIONS)
        wall_par = time.perf_counter() - w0
        wall_ser = None
        if not args.no_serial:
            w0 = time.perf_counter()
            calibrate_site(runs, root / "serial", serial=True, **OPTIONS)
            wall_ser = time.perf_counter() - w0
        print(f"{'run':>8s} {'solve wall (s)':>15s} {'solve CPU (s)':>14s} {'RMS (mm)':>9s}")
        for r in par:
            print(f"{r['run']:>8s} {r['solve_wall_s']:15.2f} {r['solve_cpu_s']:14.2f} "
                  f"{rms_mm(r['output'], truth[r['run']]):9.1f}")
        cpu = sum(r["solve_cpu_s"] for r in par)
        where = args.scheduler or f"a local cluster of {args.workers} workers"
        print(f"site on {where}: {wall_par:.1f} s wall (solves' CPU summed {cpu:.1f} s)")
        if wall_ser is not None:
            print(f"serially in one process: {wall_ser:.1f} s wall; speed-up {wall_ser / wall_par:.2f}x")


if __name__ == "__main__":
    main()
