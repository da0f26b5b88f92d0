"""Where the factor graph's time goes, stage by stage: the paper scenario (``pedcal simulate paper
--seed 0``, in memory) and the synthetic installations of ``bench_factorgraph_scale.py``.

    nice -n 10 .venv/bin/python benchmarks/bench_factorgraph_stages.py [--scenario paper] [--seed 0]
        [--sizes 160,500] [--repeats 3]

Each stage's wall and CPU time (time.process_time: the machine may be shared, and CPU time is
what a busy neighbour does not inflate) inside one ``pedcal.calib.calibrate`` call, measured by
wrapping the stage's functions (each stage's own time: the graph build inside a profile step counts
to the graph build): the first import of what ``pedcal calibrate`` loads (in a fresh process), association
(the robot's observations picked out, latency), the initializer (closed form or grid search),
the rest of the preparation (carrying and merging observations, the noise estimate, shared
people), the graph build, Levenberg-Marquardt, the head point's profile steps, the sensors'
covariance (the joint marginal, or each sensor's, and the model check), the network read back
and the rest (AMCL's error model, residuals). The grid search's whole solve is timed beside
the paper scenario's. Repeats: the minimum over them (the machine's noise only adds).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

# stage -> (module, function name) wrapped where the solver looks it up; a stage's time excludes
# the other stages it calls (the graph build inside a profile step counts to the graph build)
STAGES = {
    "association": [("pedcal.calib.association", "associate_robot"), ("pedcal.calib.association", "estimate_latency")],
    "initializer": [("pedcal.calib.problem", "_initial_sensors"), ("pedcal.calib.graph", "_initial_sensors")],
    "preparation (rest)": [("pedcal.calib.factorgraph", "prepare")],
    "graph build": [("pedcal.calib.factorgraph", "build_parts"), ("pedcal.calib.factorgraph", "observation_block"),
                    ("pedcal.calib.factorgraph", "motion_block")],
    "Levenberg-Marquardt": [("pedcal.calib.factorgraph", "optimize_graph")],
    "profile steps": [("pedcal.calib.factorgraph", "profile_step")],
    "sensor covariance": [("pedcal.calib.factorgraph", "_posterior")],
    "network read back": [("pedcal.calib.factorgraph", "_network_from_result")],
}


@contextmanager
def timed_stages(totals: dict):
    """Wrap every stage's functions; ``totals[stage]`` accumulates (wall, cpu) of its calls, less
    the time spent in other wrapped calls inside them."""
    import importlib

    saved, stack = [], []

    def wrap(stage, f):
        def inner(*a, **k):
            stack.append([0.0, 0.0])          # time of wrapped calls inside this one
            w0, c0 = time.perf_counter(), time.process_time()
            try:
                return f(*a, **k)
            finally:
                w, c = time.perf_counter() - w0, time.process_time() - c0
                inner_w, inner_c = stack.pop()
                tw, tc = totals.get(stage, (0.0, 0.0))
                totals[stage] = (tw + w - inner_w, tc + c - inner_c)
                if stack:
                    stack[-1][0] += w
                    stack[-1][1] += c
        return inner

    for stage, targets in STAGES.items():
        for module, name in targets:
            try:
                mod = importlib.import_module(module)
            except ImportError:          # an older layout of the package (a before/after comparison)
                continue
            if hasattr(mod, name):
                saved.append((mod, name, getattr(mod, name)))
                setattr(mod, name, wrap(stage, getattr(mod, name)))
    try:
        yield totals
    finally:
        for mod, name, f in saved:
            setattr(mod, name, f)


def import_time() -> tuple[float, float]:
    """(wall, CPU) of importing what ``pedcal calibrate`` loads, in a fresh process."""
    code = ("import time; w, c = time.perf_counter(), time.process_time(); "
            "from pedcal.calib import calibrate; from pedcal.io import read_log, write_sensors_yaml; "
            "import pedcal.calib.factorgraph; print(time.perf_counter() - w, time.process_time() - c)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    return float(out[0]), float(out[1])


def stages_of(log, repeats: int, **options) -> dict:
    """Per stage the (wall, CPU) of the fastest of ``repeats`` calibrations, plus the total."""
    from pedcal.calib import calibrate

    best = None
    for _ in range(repeats):
        totals: dict = {}
        with timed_stages(totals):
            w0, c0 = time.perf_counter(), time.process_time()
            calibrate(log, method="factorgraph", **options)
            totals["total"] = (time.perf_counter() - w0, time.process_time() - c0)
        if best is None or totals["total"][0] < best["total"][0]:
            best = totals
    staged = [v for k, v in best.items() if k != "total"]
    best["rest"] = (best["total"][0] - sum(w for w, _ in staged), best["total"][1] - sum(c for _, c in staged))
    return best


def solve_time(log, method: str, repeats: int, **options) -> tuple[float, float]:
    from pedcal.calib import calibrate

    runs = []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        calibrate(log, method=method, **options)
        runs.append((time.perf_counter() - w0, time.process_time() - c0))
    return min(runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sizes", default="160,500", help="synthetic installations (sensors), empty for none")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    columns = {}
    iw, ic = import_time()
    from pedcal.sim import simulate_logs

    sim = simulate_logs(args.scenario, seed=args.seed)
    columns[f"{args.scenario} seed {args.seed}"] = stages_of(sim.calib, args.repeats)
    grid = solve_time(sim.calib, "gridsearch", args.repeats)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_factorgraph_scale import synthetic_log

    for n in [int(v) for v in args.sizes.split(",") if v]:
        log = synthetic_log(n)
        columns[f"{n} sensors"] = stages_of(log, 1, is_robot=np.ones(len(log.observations), bool),
                                            estimate_latency=False, people=False, head_radius_m=0.0)
    names = ["import (fresh process)"] + list(STAGES) + ["rest", "total"]
    print("stage wall / CPU (s), " + ", ".join(f"{k}" for k in columns)
          + f"; fastest of {args.repeats} on the scenario, one run per size")
    print("| stage | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for name in names:
        cells = []
        for col in columns.values():
            w, c = (iw, ic) if name.startswith("import") else col.get(name, (0.0, 0.0))
            cells.append(f"{w:.3f} / {c:.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print(f"grid search's whole solve on {args.scenario} seed {args.seed}: {grid[0]:.3f} s wall / {grid[1]:.3f} s CPU")


if __name__ == "__main__":
    main()
