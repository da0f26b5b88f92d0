"""The factor graph and the grid search on zoo logs whose pedestrians are real recorded crowds:
each recording the simulator knows (ATC, ETH/UCY's hotel, THOR; ``pedcal.sim.walkers.RECORDINGS``,
read from the shared data folder) as the walkers the ceiling sensors see besides the robot,
in each scenario and seed, with the nuisance zoo drawn from the seed
(``simulate_logs(scenario, seed, vary_nuisances="zoo", walkers=recording)``).

    nice -n 5 .venv/bin/python benchmarks/bench_realwalk.py \
        [--recordings atc eth_ucy thor] [--scenarios paper corridor cross] [--seeds 2] [--first-seed 0]
        [--jobs 1] [--recipe KEY=VALUE ...]     # graph recipe fields for the factor graph
        [--by-scenario]                         # rows pooling each scenario over the recordings
        [--save FILE] [--from-results FILE]     # keep the per-log results; print an earlier run's

Per recording and scenario, over the seeds: the sensors' horizontal position RMS (mm, on the
evaluation log, ``pedcal.metrics.evaluate``) of the factor graph and of the grid search and their
ratio, and the share (%) of the factor graph's per-axis errors (x, y, z world axes, every sensor
of every seed) within 1 reported sigma (a sensor not calibrated or without a sigma counts as a
miss; the grid search reports no sigma) and, beside it, per axis the RMS of the finite
error / sigma ratios (1 when the sigma is honest, below 1 when it is too wide, which the share
within 1 sigma alone would reward), each with its 90 % interval from a bootstrap over the seeds
(seeded; ``pedcal.metrics.sigma_honesty``; a seed's zoo and AMCL error every recording's log of
it shares, much of it across scenarios, and the sensors of a log share it: a figure of few seeds
is uncertain however many sensors it pools; "logs (seeds)" counts both; "sensors (missed)" counts
the graph's sensors the ratios pool and, in brackets, those it missed, which the RMS leaves out:
a method that drops sensors shows it there); a last row pools every log, and with
``--by-scenario`` rows pool each scenario over the recordings. Then the graph's calibrate()
CPU time (s, time.process_time) summed, and the load average at the start and the end. A
recording missing from the shared data folder is said and skipped (the simulator would fall back
to built-in walkers).
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_factorgraph_nuisances import by_seed, recipe_overrides, sigma_ratios  # noqa: E402

from pedcal.calib import calibrate  # noqa: E402
from pedcal.metrics import evaluate, format_clustered, sigma_honesty  # noqa: E402
from pedcal.sim import simulate_logs  # noqa: E402
from pedcal.sim.walkers import RECORDINGS, SHARED_DATA  # noqa: E402


def error_sigma_ratios(ev, network) -> np.ndarray:
    """(n_sensors, 3) each sensor's |error| on each world axis over its reported sigma (a miss,
    :func:`bench_factorgraph_nuisances.sigma_ratios`, is inf)."""
    return sigma_ratios(network, [s.id for s in ev.sensors],
                        [np.asarray(s.position_error_mm, float) / 1000.0 for s in ev.sensors],
                        missing=len(ev.missing_sensors))


def run_one(recording: str, scenario: str, seed: int, recipe: dict | None = None) -> dict:
    warnings.simplefilter("ignore")
    sim = simulate_logs(scenario, seed=seed, vary_nuisances="zoo", walkers=recording)
    out = dict(recording=recording, scenario=scenario, seed=seed)
    for method in ("factorgraph", "gridsearch"):
        c0 = time.process_time()
        res = calibrate(sim.calib, method=method, **((recipe or {}) if method == "factorgraph" else {}))
        cpu = time.process_time() - c0
        ev = evaluate(sim.eval, res.network)
        E = np.array([s.position_error_mm for s in ev.sensors], float).reshape(-1, 3)
        E = E[np.all(np.isfinite(E), axis=1)]
        out[method] = dict(sq_xy=np.sum(E[:, :2] ** 2, axis=1), cpu_s=cpu)
        if method == "factorgraph":
            out["ratios"] = error_sigma_ratios(ev, res.network)
    return out


def _row(name: str, runs: list[dict]) -> str:
    rms = {m: float(np.sqrt(np.mean(np.concatenate([r[m]["sq_xy"] for r in runs])))) for m in
           ("factorgraph", "gridsearch")}
    # the RMS of the finite ratios per axis (a miss is counted by the share within 1 sigma),
    # resampled by seed: a seed's logs share its zoo draw and AMCL's error whatever the
    # recording (the walkers change the people seen, not the robot's draws), and much of that
    # error across scenarios
    within, ratio_rms = sigma_honesty(by_seed(runs))
    return (f"| {name} | {len(runs)} ({within.logs}) | {within.rows} ({within.misses}) | "
            f"{rms['factorgraph']:.1f} | {rms['gridsearch']:.1f} | {rms['factorgraph'] / rms['gridsearch']:.2f} | "
            f"{format_clustered(within, 100, unit='seeds')} | {format_clustered(ratio_rms, digits=2, unit='seeds')} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recordings", nargs="+", default=list(RECORDINGS), choices=list(RECORDINGS))
    ap.add_argument("--scenarios", nargs="+", default=["paper", "corridor", "cross"])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--recipe", nargs="+", default=[], metavar="KEY=VALUE",
                    help="graph recipe fields for the factor graph (head_profile_consider=false)")
    ap.add_argument("--by-scenario", action="store_true", help="rows pooling each scenario over the recordings")
    ap.add_argument("--save", default=None, metavar="FILE", help="write the per-log results (pickle)")
    ap.add_argument("--from-results", default=None, metavar="FILE",
                    help="print the table of an earlier run's --save FILE without running")
    args = ap.parse_args()
    if args.from_results:
        with open(args.from_results, "rb") as fh:
            saved = pickle.load(fh)
        print(saved["title"] + f" (from {args.from_results})")
        print_table(saved["results"], saved["recordings"], saved["scenarios"], args.by_scenario)
        return
    recipe = recipe_overrides(args.recipe, ap)
    recordings = []
    for rec in args.recordings:
        if (SHARED_DATA / RECORDINGS[rec]).is_file():
            recordings.append(rec)
        else:
            print(f"{rec}: {SHARED_DATA / RECORDINGS[rec]} not found, skipped", file=sys.stderr)
    if not recordings:
        ap.error(f"none of the recordings is under {SHARED_DATA}")
    load0 = os.getloadavg()[0]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    tasks = [(rec, sc, s, recipe) for rec in recordings for sc in args.scenarios for s in seeds]
    with ProcessPoolExecutor(args.jobs) as ex:
        results = list(ex.map(run_one, *zip(*tasks, strict=True)))
    title = (f"recorded walkers x scenarios x {args.seeds} seeds (first {args.first_seed}), --vary-nuisances zoo"
             + (f", recipe {' '.join(args.recipe)}" if args.recipe else ""))
    if args.save:
        with open(args.save, "wb") as fh:
            pickle.dump(dict(title=title, results=results, recordings=recordings, scenarios=args.scenarios), fh)
    print(title)
    print_table(results, recordings, args.scenarios, args.by_scenario)
    cpu = sum(r["factorgraph"]["cpu_s"] for r in results)
    print(f"graph calibrate() CPU {cpu:.0f} s over {len(results)} logs; load average at the start {load0:.1f}, "
          f"at the end {os.getloadavg()[0]:.1f}")


def print_table(results: list[dict], recordings: list[str], scenarios: list[str], by_scenario: bool) -> None:
    """The table: a row per recording and scenario, per scenario (``by_scenario``), all pooled."""
    print("| recording / scenario | logs (seeds) | graph's sensors (missed) | graph xy RMS (mm) | "
          "grid search xy RMS (mm) | graph / grid | "
          "graph within 1 sigma x / y / z (%) [90 % over seeds] | "
          "graph error / sigma RMS x / y / z [90 % over seeds] |")
    print("|---|---|---|---|---|---|---|---|")
    for rec in recordings:
        for sc in scenarios:
            print(_row(f"{rec} / {sc}", [r for r in results if r["recording"] == rec and r["scenario"] == sc]))
    if by_scenario:
        for sc in scenarios:
            print(_row(f"all / {sc}", [r for r in results if r["scenario"] == sc]))
    print(_row("all", results))


if __name__ == "__main__":
    main()
