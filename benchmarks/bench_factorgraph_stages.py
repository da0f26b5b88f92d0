"""Where the factor graph's time goes, stage by stage: the paper scenario (``pedcal simulate paper
--seed 0``, in memory) and the synthetic installations of ``bench_factorgraph_scale.py``.

    nice -n 10 .venv/bin/python benchmarks/bench_factorgraph_stages.py [--scenario paper] [--seed 0]
        [--sizes 160,500] [--repeats 3] [--no-command]

Each stage's wall and CPU time (time.process_time: the machine may be shared, and CPU time is
what a busy neighbour does not inflate) inside one ``pedcal.calib.calibrate`` call, measured by
wrapping the stage's functions (each stage's own time: the graph build inside a profile step counts
to the graph build): the first import of what ``pedcal calibrate`` loads (in a fresh process), the
pre-flight (the log validated, the memory estimate), association (the robot's observations
picked out, latency), the initializer (closed form or grid search), the rest of the preparation
(carrying and merging observations, the noise estimate, shared people), the graph build,
Levenberg-Marquardt, the head point's profile steps, the consider parameter (the head shift's
line against distance left out of the estimate, its sensitivity kept), the clock offsets'
overdispersion (their sigma widened by their residuals' scatter over time blocks), the sensors' covariance (the joint
marginal, or each sensor's, and the model check), the network read back, AMCL's error model
(its residuals, the fit, the shared sightings checked), the profile's set-up (the clock offsets,
the right-hand sides' inputs, the retraction after each step), the results (the network
finished, clock offsets and head model recorded, the keys) and the rest. The grid search's whole solve is timed beside
the paper scenario's, with its association (the same function as the factor graph's), the two
methods run in turns. Then, as a new user meets it, the whole ``pedcal calibrate LOG -o OUT
--method M -q`` command of each method on the scenario written to a temporary directory (a fresh
process: imports, reading the log, the solve, the YAML; CPU from the children's rusage), also
without the BLAS thread variables this process was given (``OPENBLAS_NUM_THREADS`` ...: as a
shell that never set them runs it), and the import of what it loads before reading the log; where
``PYTHONDONTWRITEBYTECODE`` is set (every start compiles every module whose ``__pycache__`` copy is
missing or stale, as after an edit or on a fresh checkout), the import and
the command again with the compiled modules kept (a temporary ``PYTHONPYCACHEPREFIX``), as an
installed package runs.
Repeats: the minimum over them (the machine's noise only adds); the load average is printed at
the start and the end.
"""

from __future__ import annotations

import argparse
import os
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
    "pre-flight (validation)": [("pedcal.io.preflight", "check_calibration")],
    "association": [("pedcal.calib.association", "associate_robot"), ("pedcal.calib.association", "estimate_latency")],
    "initializer": [("pedcal.calib.problem", "_initial_sensors"), ("pedcal.calib.graph", "_initial_sensors")],
    "preparation (rest)": [("pedcal.calib.factorgraph", "prepare")],
    "graph build": [("pedcal.calib.factorgraph", "build_parts"), ("pedcal.calib.factorgraph", "rebuild_parts"),
                    ("pedcal.calib.factorgraph", "observation_block"),
                    ("pedcal.calib.factorgraph", "observation_block_terms"),
                    ("pedcal.calib.factorgraph", "observation_graph"),
                    ("pedcal.calib.factorgraph", "motion_block")],
    "Levenberg-Marquardt": [("pedcal.calib.factorgraph", "optimize_graph")],
    "profile steps": [("pedcal.calib.factorgraph", "profile_step")],
    "consider parameter": [("pedcal.calib.factorgraph", "considered_nuisances"),
                           ("pedcal.calib.factorgraph", "leave_out")],
    "clock overdispersion": [("pedcal.calib.factorgraph", "widen_for_overdispersion")],
    "sensor covariance": [("pedcal.calib.factorgraph", "_posterior")],
    "network read back": [("pedcal.calib.factorgraph", "_network_from_result")],
    "AMCL error model": [("pedcal.calib.factorgraph", "amcl_residuals"), ("pedcal.calib.factorgraph", "estimate_model"),
                         ("pedcal.calib.factorgraph", "people_misfit")],
    "profile set-up": [("pedcal.calib.factorgraph", "clock_nuisances"), ("pedcal.calib.factorgraph", "ObservationRhs"),
                       ("pedcal.calib.factorgraph", "MotionRhs"), ("pedcal.calib.factorgraph", "retract_flat")],
    "results": [("pedcal.calib.factorgraph", "finish_network"), ("pedcal.calib.factorgraph", "record_clocks"),
                ("pedcal.calib.factorgraph", "record_head_profile"), ("pedcal.calib.factorgraph", "graph_keys")],
}


@contextmanager
def timed_stages(totals: dict, stages: dict | None = None):
    """Wrap every stage's functions (``stages``, by default :data:`STAGES`); ``totals[stage]``
    accumulates (wall, cpu) of its calls, less the time spent in other wrapped calls inside them."""
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

    for stage, targets in (STAGES if stages is None else stages).items():
        found = False
        for module, name in targets:
            try:
                mod = importlib.import_module(module)
            except ImportError:          # an older layout of the package (a before/after comparison)
                continue
            if hasattr(mod, name):       # (a stage may name where a function lived in either layout)
                found = True
                saved.append((mod, name, getattr(mod, name)))
                setattr(mod, name, wrap(stage, getattr(mod, name)))
        if not found:                    # a misspelt or moved name would read 0 s: said, not hidden
            print(f"warning: stage '{stage}' times nothing ({', '.join(f'{m}.{n}' for m, n in targets)} "
                  "not found)", file=sys.stderr)
    try:
        yield totals
    finally:
        for mod, name, f in saved:
            setattr(mod, name, f)


def _environment(default_blas: bool = False, bytecode: str | None = None) -> dict:
    """This process's environment for a child: without the BLAS thread variables
    (``default_blas``), and with ``bytecode`` a directory Python keeps its compiled modules in
    (``PYTHONPYCACHEPREFIX``, ``PYTHONDONTWRITEBYTECODE`` dropped: as an installed package, whose
    modules are compiled once, runs), else as this process has it."""
    env = {k: v for k, v in os.environ.items() if not (default_blas and k in BLAS_THREAD_VARIABLES)}
    if bytecode is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = bytecode
    return env


def import_time(method: str = "factorgraph", bytecode: str | None = None) -> tuple[float, float]:
    """(wall, CPU) of importing what ``pedcal calibrate --method METHOD`` loads before it reads the
    log, in a fresh process (one run: the caller keeps the fastest of its repeats); ``bytecode``:
    :func:`_environment`'s."""
    code = ("import time; w, c = time.perf_counter(), time.process_time(); import pedcal.cli; "
            "from pedcal.calib import calibrate; from pedcal.io import read_log, write_sensors_yaml; "
            f"import pedcal.calib.{method}; print(time.perf_counter() - w, time.process_time() - c)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env=_environment(bytecode=bytecode)).stdout.split()
    return float(out[0]), float(out[1])


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def command_time(log_dir: Path, method: str, default_blas: bool = False,
                 bytecode: str | None = None) -> tuple[float, float]:
    """(wall, CPU) of the whole ``pedcal calibrate LOG -o OUT --method METHOD -q`` as a new user runs
    it (a fresh process: imports, reading the log, the solve, writing the YAML; CPU the child's
    user + system time), one run; ``default_blas``: without the BLAS thread variables
    (``OPENBLAS_NUM_THREADS`` ...) of this process, at the library's own default, as a shell
    that never set them runs it; ``bytecode``: the modules' compiled code kept there
    (:func:`_environment`)."""
    import resource
    import tempfile

    env = _environment(default_blas, bytecode)
    with tempfile.TemporaryDirectory() as tmp:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "pedcal.cli", "calibrate", str(log_dir), "-o",
                        str(Path(tmp) / f"{method}.yaml"), "--method", method, "-q"],
                       check=True, capture_output=True, env=env)
        wall = time.perf_counter() - w0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _timed_solve(log, method: str, stages: dict | None, **options) -> dict:
    """One ``calibrate`` of ``log`` by ``method`` with the (wall, CPU) of ``stages`` (all of
    STAGES when None) and of the whole solve ("total")."""
    from pedcal.calib import calibrate

    totals: dict = {}
    with timed_stages(totals, stages):
        w0, c0 = time.perf_counter(), time.process_time()
        calibrate(log, method=method, **options)
        totals["total"] = (time.perf_counter() - w0, time.process_time() - c0)
    return totals


def stages_of(log, **options) -> dict:
    """Per stage the (wall, CPU) of one factor-graph calibration, the total, and the rest."""
    out = _timed_solve(log, "factorgraph", None, **options)
    staged = [v for k, v in out.items() if k != "total"]
    out["rest"] = (out["total"][0] - sum(w for w, _ in staged), out["total"][1] - sum(c for _, c in staged))
    return out


def solve_time(log, method: str, **options) -> dict:
    """``method``'s whole solve and, within it, the association's: {"total": (wall, CPU),
    "association": (wall, CPU)}, one run."""
    return _timed_solve(log, method, {"association": STAGES["association"]}, **options)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sizes", default="160,500", help="synthetic installations (sensors), empty for none")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-command", action="store_true", help="skip the whole `pedcal calibrate` commands")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    load0 = os.getloadavg()
    from pedcal.sim import simulate, simulate_logs

    sim = simulate_logs(args.scenario, seed=args.seed)
    # the two methods in turns, so that a change of the machine's load falls on both
    fg, grid = [], []
    for _ in range(args.repeats):
        fg.append(stages_of(sim.calib))
        grid.append(solve_time(sim.calib, "gridsearch"))
    columns = {f"{args.scenario} seed {args.seed}": min(fg, key=lambda t: t["total"][1])}
    grid_best = min(grid, key=lambda t: t["total"][1])
    imports = {m: [] for m in ("factorgraph", "gridsearch")}
    commands = {m: [] for m in ("factorgraph", "gridsearch")}
    default_blas = {m: [] for m in ("factorgraph", "gridsearch")}
    # (with PYTHONDONTWRITEBYTECODE set, as this machine's environment has it, every process compiles
    # every module whose __pycache__ copy is missing or stale (edited sources, a fresh checkout),
    # which an installed package, compiled once, does not:
    # then the import and the command are also timed with the compiled modules kept)
    compiled = {m: ([], []) for m in ("factorgraph", "gridsearch")} if os.environ.get(
        "PYTHONDONTWRITEBYTECODE") else {}
    if not args.no_command:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            simulate(args.scenario, Path(tmp) / "run", seed=args.seed)
            cache = str(Path(tmp) / "bytecode")
            for m in compiled:            # (the first run compiles and keeps: not timed)
                command_time(Path(tmp) / "run" / "calib", m, bytecode=cache)
                import_time(m, bytecode=cache)
            for _ in range(args.repeats):
                for m in imports:
                    imports[m].append(import_time(m))
                    commands[m].append(command_time(Path(tmp) / "run" / "calib", m))
                    default_blas[m].append(command_time(Path(tmp) / "run" / "calib", m, default_blas=True))
                    if m in compiled:
                        compiled[m][0].append(import_time(m, bytecode=cache))
                        compiled[m][1].append(command_time(Path(tmp) / "run" / "calib", m, bytecode=cache))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_factorgraph_scale import synthetic_log

    for n in [int(v) for v in args.sizes.split(",") if v]:
        log = synthetic_log(n)
        columns[f"{n} sensors"] = stages_of(log, is_robot=np.ones(len(log.observations), bool),
                                            estimate_latency=False, people=False, head_radius_m=0.0)
    iw, ic = min(imports["factorgraph"], key=lambda r: r[1]) if imports["factorgraph"] else import_time()
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
    gw, gc = grid_best["total"]
    aw, ac = grid_best.get("association", (0.0, 0.0))
    fw, fc = columns[f"{args.scenario} seed {args.seed}"]["total"]
    print(f"grid search's whole solve on {args.scenario} seed {args.seed}: {gw:.3f} s wall / {gc:.3f} s CPU "
          f"(association {aw:.3f} / {ac:.3f}); factor graph / grid search CPU {fc / gc:.2f}")
    if not args.no_command:
        print(f"\nthe whole `pedcal calibrate LOG -o OUT --method M -q` ({args.scenario} seed {args.seed} written "
              f"by `pedcal simulate`), fastest of {args.repeats} by CPU, wall / CPU (s):")
        blas = ", ".join(f"{k}={os.environ[k]}" for k in BLAS_THREAD_VARIABLES if k in os.environ) or "none set"
        kept = " | import, compiled modules kept | whole command, compiled modules kept" if compiled else ""
        print(f"| method | import (fresh process) | whole command (BLAS threads: {blas}) | whole command, "
              f"BLAS at its default threads{kept} |")
        print("|---|---|---|---|" + "---|---|" * bool(compiled))
        for m in commands:
            cells = [min(imports[m], key=lambda r: r[1]), min(commands[m], key=lambda r: r[1]),
                     min(default_blas[m], key=lambda r: r[1])]
            if m in compiled:
                cells += [min(runs, key=lambda r: r[1]) for runs in compiled[m]]
            print(f"| {m} | " + " | ".join(f"{w:.3f} / {c:.3f}" for w, c in cells) + " |")
        if compiled:
            print("(PYTHONDONTWRITEBYTECODE is set: the first columns compile at each start every module whose "
                  "bytecode is missing or stale)")
    load1 = os.getloadavg()
    print(f"\nload average (1 min) {load0[0]:.1f} at the start, {load1[0]:.1f} at the end (2 cores)")


if __name__ == "__main__":
    main()
