"""The factor graph and the grid search on zoo logs whose pedestrians are real recorded crowds:
each recording the simulator knows (ATC, ETH/UCY's hotel, THOR; ``pedcal.sim.walkers.RECORDINGS``,
read from the shared data folder) as the walkers the ceiling sensors see besides the robot,
in each scenario and seed, with the nuisance zoo drawn from the seed
(``simulate_logs(scenario, seed, vary_nuisances="zoo", walkers=recording)``).

    nice -n 5 .venv/bin/python benchmarks/bench_realwalk.py \
        [--recordings atc eth_ucy thor] [--scenarios paper corridor cross] [--seeds 2] [--first-seed 0]
        [--jobs 1] [--recipe KEY=VALUE ...]     # graph recipe fields for the factor graph
        [--by-scenario] [--by-seed]             # rows pooling each scenario / each seed
        [--save FILE] [--from-results FILE ...] # keep the per-log results; print earlier runs' pooled

Per recording and scenario, over the seeds: the sensors' horizontal position RMS (mm, on the
evaluation log, ``pedcal.metrics.evaluate``) of the factor graph and of the grid search, each with
the sensors it left out of that RMS in brackets (not evaluated, or without a finite error: the
RMS alone would reward a miss; '?' for runs saved before they were counted), and their
ratio, and the share (%) of the factor graph's per-axis errors (x, y, z world axes, every sensor
of every seed) within 1 reported sigma (a sensor not calibrated or without a sigma counts as a
miss; the grid search reports no sigma) and, beside it, per axis the RMS of the finite
error / sigma ratios (1 when the sigma is honest, below 1 when it is too wide, which the share
within 1 sigma alone would reward), each with its 90 % interval from a bootstrap over the seeds
(seeded; ``pedcal.metrics.sigma_honesty``; a seed's zoo and AMCL error every recording's log of
it shares, much of it across scenarios, and the sensors of a log share it: a figure of few seeds
is uncertain however many sensors it pools; "logs (seeds)" counts both; "sensors (missed)" counts
the graph's sensors the ratios pool and, in brackets, those it missed, which the RMS leaves out:
a method that drops sensors shows it there); a last row pools every log (a row without logs, as
when saved runs pooled do not cover every recording and scenario, is left out), and with
``--by-scenario`` rows pool each scenario over the recordings, with ``--by-seed`` each seed over
the recordings and scenarios (a seed is one draw of what every sensor of its logs shares).
Beside them, per axis x / y: the RMS of the horizontal error over its sigma split into the
sensors' mean (the network's common shift, each log one value) and each sensor's departure from
it (``bench_factorgraph_nuisances.shared_and_rest_z``, from the joint position covariance), and
AMCL's true run-mean error over the exact std of an OU mean with the simulator's own parameters
(2 sigma^2 tau / T (1 - tau / T (1 - e^-T/tau))): the truth's own draw of what anchors the network
to the map, whatever the graph (1 in RMS over many seeds; logs whose AMCL family is
``correlated`` only: a relocalization's or a jump's offset adds to the run mean beyond the OU,
and the graph moves those back), one value per scenario and seed: the recordings' logs of it
share its AMCL draw, so "(draws)" counts independent draws, not logs. A shared part over its
sigma that follows the truth's draw is the draw, not the sigma. Then the graph's calibrate()
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

from bench_factorgraph_nuisances import (  # noqa: E402
    by_seed,
    error_sigma_ratios,
    missed_text,
    pooled_text,
    recipe_overrides,
    shared_rest_parts,
)

from pedcal.calib import calibrate  # noqa: E402
from pedcal.calib.amcl_model import AmclErrorModel  # noqa: E402
from pedcal.metrics import (  # noqa: E402
    amcl_run_mean_error_m,
    evaluate,
    format_clustered,
    sigma_honesty,
    sigma_ratio_rms,
)
from pedcal.sim import simulate_logs  # noqa: E402
from pedcal.sim.nuisances import zoo_families  # noqa: E402
from pedcal.sim.walkers import RECORDINGS, SHARED_DATA  # noqa: E402


def amcl_truth_z(run_mean_m, amcl_sigma_m: float, amcl_tau_s: float, duration_s: float) -> np.ndarray:
    """(2,) AMCL's true run-mean error (world x, y, m) over the exact std per axis of the mean of
    an Ornstein-Uhlenbeck process of std ``amcl_sigma_m`` and correlation time ``amcl_tau_s``
    over ``duration_s`` (:meth:`AmclErrorModel.floor_sigma_m`): N(0, 1) per axis over the
    simulator's draws of such a process, whatever the calibration."""
    return np.asarray(run_mean_m, float) / AmclErrorModel(0.0, amcl_sigma_m, amcl_tau_s).floor_sigma_m(duration_s)


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
        # the sensors the RMS leaves out: not evaluated at all, or without a finite error
        out[method] = dict(sq_xy=np.sum(E[:, :2] ** 2, axis=1), cpu_s=cpu,
                           missed=len(ev.missing_sensors) + len(ev.sensors) - len(E))
        if method == "factorgraph":
            out["ratios"] = error_sigma_ratios(ev, res.network)
            z_shared, z_rest = shared_rest_parts(ev, res.network, res.position_covariance_m2)
            out["z_shared"], out["z_rest"] = z_shared, z_rest.reshape(-1, 2)
    t = sim.calib.robot["t"].to_numpy(float)
    sc = sim.scenario
    out["amcl_family"] = zoo_families(sc)["amcl"]
    out["amcl_truth_z"] = (amcl_truth_z(amcl_run_mean_error_m(sim.calib), sc.amcl_sigma_m, sc.amcl_tau_s,
                                        float(t.max() - t.min()))
                           if out["amcl_family"] == "correlated" else np.full(2, np.nan))
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
            f"{rms['factorgraph']:.1f} ({missed_text(runs, 'factorgraph')}) | "
            f"{rms['gridsearch']:.1f} ({missed_text(runs, 'gridsearch')}) | "
            f"{rms['factorgraph'] / rms['gridsearch']:.2f} | "
            f"{format_clustered(within, 100, unit='seeds')} | {format_clustered(ratio_rms, digits=2, unit='seeds')} | "
            f"{shared_rest_text(runs)} | {truth_z_text(runs)} |")


def _rms_xy(z: np.ndarray) -> str:
    """'x / y': :func:`pedcal.metrics.sigma_ratio_rms` of the (n, 2) ratios ``z``."""
    return " / ".join(f"{v:.2f}" for v in sigma_ratio_rms(z))


def shared_rest_text(runs: list[dict]) -> str:
    """'x / y ; x / y (n of N logs)': the RMS over ``runs`` of the shared part over its sigma (one
    value per log) and of the rest (one per sensor), per horizontal axis, with the logs pooled (a
    log with fewer than 2 calibrated sensors or no finite joint covariance has none:
    :func:`bench_factorgraph_nuisances.pooled_text`); '-' for runs saved without them."""
    if not all("z_shared" in r for r in runs):
        return "-"
    zs = np.array([r["z_shared"] for r in runs if len(r["z_shared"])]).reshape(-1, 2)
    zr = np.concatenate([r["z_rest"] for r in runs]).reshape(-1, 2)
    return f"{_rms_xy(zs) if len(zs) else '-'} ; {_rms_xy(zr) if len(zr) else '-'} {pooled_text(runs)}"


def truth_z_text(runs: list[dict]) -> str:
    """'x / y (n)': the RMS over ``runs`` of AMCL's true run mean over its exact OU std
    (:func:`amcl_truth_z`), one value per (scenario, seed): the recordings' logs of a scenario and
    seed share its AMCL draw (the walkers change the people seen, not the robot's path), so n
    counts independent draws, not logs (family ``correlated`` only); '-' without any."""
    draws = {}
    for r in runs:
        if "amcl_truth_z" in r:
            draws.setdefault((r["scenario"], r["seed"]), r["amcl_truth_z"])
    z = np.array(list(draws.values()), float).reshape(-1, 2)
    z = z[np.all(np.isfinite(z), axis=1)]
    return f"{_rms_xy(z)} ({len(z)})" if len(z) else "-"


def load_results(paths: list[str]) -> dict:
    """Several runs' ``--save`` files pooled: their logs together (the recordings and scenarios in
    the order first seen, the titles joined). A log ((recording, scenario, seed)) in two of the
    files is an error: pooling it twice would count one draw as two."""
    results, recordings, scenarios, titles, seen = [], [], [], [], {}
    for path in paths:
        with open(path, "rb") as fh:
            saved = pickle.load(fh)
        for r in saved["results"]:
            key = (r["recording"], r["scenario"], r["seed"])
            if key in seen:
                raise ValueError(f"{path}: log {key} is also in {seen[key]}")
            seen[key] = path
            results.append(r)
        recordings += [x for x in saved["recordings"] if x not in recordings]
        scenarios += [x for x in saved["scenarios"] if x not in scenarios]
        titles.append(saved["title"])
    return dict(title=" + ".join(titles), results=results, recordings=recordings, scenarios=scenarios)


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
    ap.add_argument("--by-seed", action="store_true", help="rows pooling each seed over the recordings and scenarios")
    ap.add_argument("--save", default=None, metavar="FILE", help="write the per-log results (pickle)")
    ap.add_argument("--from-results", default=None, nargs="+", metavar="FILE",
                    help="print the table of earlier runs' --save FILEs (pooled; disjoint logs) without running")
    args = ap.parse_args()
    if args.from_results:
        try:
            saved = load_results(args.from_results)
        except (OSError, ValueError, pickle.UnpicklingError, KeyError) as exc:
            ap.error(f"--from-results: {exc}")
        print(saved["title"] + f" (from {' '.join(args.from_results)})")
        print_table(saved["results"], saved["recordings"], saved["scenarios"], args.by_scenario, args.by_seed)
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
    print_table(results, recordings, args.scenarios, args.by_scenario, args.by_seed)
    cpu = sum(r["factorgraph"]["cpu_s"] for r in results)
    print(f"graph calibrate() CPU {cpu:.0f} s over {len(results)} logs; load average at the start {load0:.1f}, "
          f"at the end {os.getloadavg()[0]:.1f}")


def print_table(results: list[dict], recordings: list[str], scenarios: list[str], by_scenario: bool,
                by_seed: bool = False) -> None:
    """The table: a row per recording and scenario, per scenario (``by_scenario``), per seed
    (``by_seed``), all pooled."""
    print("| recording / scenario | logs (seeds) | graph's sensors (missed) | graph xy RMS (mm) (missed) | "
          "grid search xy RMS (mm) (missed) | graph / grid | "
          "graph within 1 sigma x / y / z (%) [90 % over seeds] | "
          "graph error / sigma RMS x / y / z [90 % over seeds] | "
          "graph error / sigma RMS, shared x / y ; rest x / y | "
          "AMCL's true run mean / exact OU std RMS x / y (draws) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = [(f"{rec} / {sc}", [r for r in results if r["recording"] == rec and r["scenario"] == sc])
            for rec in recordings for sc in scenarios]
    if by_scenario:
        rows += [(f"all / {sc}", [r for r in results if r["scenario"] == sc]) for sc in scenarios]
    if by_seed:
        rows += [(f"seed {seed}", [r for r in results if r["seed"] == seed])
                 for seed in sorted({r["seed"] for r in results})]
    rows.append(("all", results))
    # (saved runs pooled need not cover every recording x scenario: a row without logs is left out)
    for name, runs in rows:
        if runs:
            print(_row(name, runs))


if __name__ == "__main__":
    main()
