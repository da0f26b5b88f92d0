"""Can any estimator reach a horizontal sensor RMS of 12 mm on the nuisance zoo's logs? The
factor graph and the grid search against the Cramér-Rao bound taken under the noise each log was
truly generated with (pedcal.calib.crlb: ``simulator_noise``, ``sensor_position_crlb``).

    nice -n 5 .venv/bin/python benchmarks/bench_bound.py [--scenarios paper sparse corridor cross lhall] \
        [--seeds 4] [--first-seed 0] [--jobs 1] [--limit-mm 12] [--verbose] \
        [--off FAMILY ...] [--known FAMILY ...]

Per log (``simulate_logs(scenario, seed, vary_nuisances="zoo")``, calibrated on the calibration
log, scored on the evaluation log, pedcal.metrics.evaluate), horizontal only (mm):

- graph / grid: the factor graph's and the grid search's RMS over sensors of the horizontal
  position error, sqrt(mean_i (e_x,i^2 + e_y,i^2));
- bound: the Cramér-Rao bound's horizontal RMS, sqrt(mean_i (var_x,i + var_y,i)) (the root of the
  mean over sensors of the bound on each sensor's horizontal mean square error): robot
  observations only, the head point, latency and clock offsets known, AMCL's true error process
  (the OU's std and correlation time, or white) and its heading error known, depth and lateral
  noise as simulated or below (pedcal.calib.crlb's docstring says which way each departure moves
  it: all down but people's sightings left out, which raises the rest);
- bound, heading as the graph: the same with AMCL's heading error at its true std, held as the
  graph holds it (white, inflated to an OU mean's information), which raises the bound: the
  truth's lies between the two;
- common / rest: the same split into the sensors' mean horizontal error (the network's common
  shift: its norm for an estimate, sqrt(trace) of its covariance for the bound) and the RMS of each
  sensor's departure from it (squares add up to the total's);
- genie common: the bound on the common shift with everything but AMCL's run-mean error known,
  1 / (1^T Sigma^-1 1) per axis under AMCL's true error covariance (common_shift_variance_m2);
- P(<= limit): the probability that an efficient estimator (Gaussian errors of exactly the
  bound's joint covariance) meets the limit on a log like this one;
- graph / bound: the efficiency ratio (1: efficient; below 1 on one log is chance, or bias);
- AMCL run-mean error: the norm of AMCL's position error averaged over the calibration run (the
  truth's draw of what every calibration anchored to AMCL shares); over logs, its RMS over the
  bound's common part says how large the draws were (about 1.03 for an unbiased draw: the bound's
  common part is the best linear estimate's of that mean, the run mean a plain average of it,
  1.025 on the zoo's paper seed 0); the graph's common part less it (RMS over
  logs): the common error the graph adds to AMCL's own. The logs of one seed share AMCL's error
  draw across scenarios (the same stream, routes of similar length), so 20 seeds are about 20
  draws of it, not 100.

Controlled experiments: ``--off FAMILY ...`` switches zoo families off in the simulator, every
other draw of the seed left as it was (pedcal.sim.nuisances.switch_off: head, clock, latency,
jumps, mounts, odometry, depth); ``--known FAMILY ...`` (head, clock, latency; each switched off
too) gives the factor graph that family's truth (the head top itself, one shared clock, no
latency: KNOWN_RECIPE). How much of the graph's rest over the bound's a family's switching off
closes is what that family costs (the bound itself changes only where the family enters it:
mounts, depth, AMCL's jumps).

Summaries per scenario, per AMCL family (white, correlated, jumps, relocalization) and pooled:
means over logs of the per-log figures, the share of logs whose bound exceeds the limit, the
expected share of logs an efficient estimator meets it on (mean of P), how many logs the graph
meets it on, and the efficiency as RMS over logs of the graph's over that of the bound (total,
common and rest), besides: the bound's rest with AMCL's heading held as the graph holds it and
the graph's rest over it (RMS over logs), the median over logs of the graph's rest over the
bound's (one failed log does not set it), and the share of the graph's per-axis errors (x, y,
every sensor of every log) within its 1-sigma.

``--xgen-results DIR [DIR ...]`` adds the held-out generator's logs of earlier
``benchmarks/bench_xgen.py --out DIR`` runs (their results.jsonl and logs): the factor graph's and the
grid search's horizontal RMS as bench_xgen scored them, and the genie bound on the common shift
under the generator's true AMCL process (xgen.json): an OU of std sigma_along along the room's
long axis and sigma_cross across it, correlation time tau_xy, its white jitter and jumps taken as
known (both lower the bound), so per axis of the room 1 / (1^T Sigma^-1 1). Only the single-room
layouts (rooms, corridor, openhall) with an OU error are bounded: the generator turns the OU's
axes from one wing of the L-shaped hall to the other (a turn that shows the error's components,
which a fixed-axes bound would not hold), and its random-walk error resets at times the log does
not give. The whole bound is at least this (total^2 = common^2 + rest^2).

What the bound means: it bounds UNBIASED estimators' mean square error; a bound above 12 mm says
no unbiased estimator reaches 12 mm in root mean square over such logs, not that none can on a
single log (P(<= limit) says how often an efficient one would). It is a valid lower bound with
the nuisances known (knowing more can only lower it), except for people's shared sightings, which
it leaves out: they carry information on the sensors' relative positions (the rest), none on the
common shift.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.sim.nuisances import OFF_FAMILIES

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_factorgraph_nuisances import sigma_ratios  # noqa: E402


def horizontal_split_mm(E_xy_m: np.ndarray) -> tuple[float, float, float]:
    """(RMS over sensors, norm of the mean, RMS of the departures from the mean) of horizontal
    errors (n, 2) in m, as mm; the first squared is the sum of the others squared."""
    E = np.asarray(E_xy_m, float)
    m = E.mean(axis=0)
    return (float(1000 * np.sqrt(np.mean(np.sum(E ** 2, axis=1)))), float(1000 * np.linalg.norm(m)),
            float(1000 * np.sqrt(np.mean(np.sum((E - m) ** 2, axis=1)))))


# --known FAMILY: the factor graph given that nuisance's truth, for logs with it switched off
# (--off FAMILY) in the simulator: recipe fields
KNOWN_RECIPE = {
    # the head top itself: no head model estimated, no per-sensor shift, curvature or profile
    "head": dict(estimate_head_model=False, head_radius_m=0.0, estimate_head_horizontal_shift=False,
                 head_shift_per_sensor_sigma_m=0.0, head_curvature="off", head_profile_consider=False),
    "clock": dict(clock_offsets=False),      # one shared clock
    "latency": dict(estimate_latency=False),  # no latency
}


def run_one(scenario: str, seed: int, limit_mm: float = 12.0, off: tuple = (), known: tuple = ()) -> dict:
    import dataclasses

    from pedcal.calib import calibrate
    from pedcal.calib.crlb import (
        KNOWN_HEADING_SIGMA_RAD,
        common_shift_variance_m2,
        sensor_position_crlb,
        simulator_noise,
    )
    from pedcal.calib.recipe import GraphRecipe
    from pedcal.metrics import amcl_run_mean_error_m, evaluate
    from pedcal.sim import simulate_logs
    from pedcal.sim.nuisances import switch_off, vary, zoo_families
    from pedcal.sim.scenario import load_scenario

    warnings.simplefilter("ignore")
    if off:
        # the seed's zoo draw with the families switched off, everything else as drawn
        sc = switch_off(vary(load_scenario(scenario).resolve(seed=seed), zoo=True), off)
        sim = simulate_logs(sc, seed=seed)
    else:
        sim = simulate_logs(scenario, seed=seed, vary_nuisances="zoo")
    recipe = dataclasses.replace(GraphRecipe(), **{k: v for f in known for k, v in KNOWN_RECIPE[f].items()})
    log = sim.calib
    amcl_mean_m = amcl_run_mean_error_m(log)
    out = dict(scenario=scenario, seed=seed, family=zoo_families(sim.scenario)["amcl"], sensors=len(log.truth),
               amcl_mean_mm=float(1000 * np.linalg.norm(amcl_mean_m)))
    for method in ("factorgraph", "gridsearch"):
        c0 = time.process_time()
        res = calibrate(log, method=method, **(dict(graph=recipe) if method == "factorgraph" and known else {}))
        cpu = time.process_time() - c0
        ev = evaluate(sim.eval, res.network)
        E = np.array([s.position_error_mm[:2] for s in ev.sensors]) / 1000.0
        out[method] = dict(zip(("xy", "common", "rest"), horizontal_split_mm(E), strict=True), cpu_s=cpu,
                           common_less_amcl=float(1000 * np.linalg.norm(E.mean(axis=0) - amcl_mean_m)))
        if method == "factorgraph":
            # |error| / sigma per world axis x, y of every sensor (inf: a miss)
            out[method]["z_xy"] = sigma_ratios(res.network, [s.id for s in ev.sensors],
                                               [np.asarray(s.position_error_mm[:2]) / 1000.0 for s in ev.sensors],
                                               missing=len(ev.missing_sensors)).tolist()
    rec, model, sigma_yaw = simulator_noise(sim.scenario)
    c0 = time.process_time()
    t = log.robot["t"].to_numpy(float)
    genie = float(1000 * np.sqrt(2.0 * common_shift_variance_m2(t, model)))
    for key, yaw in (("bound", KNOWN_HEADING_SIGMA_RAD), ("bound_heading", sigma_yaw)):
        bound = sensor_position_crlb(log, rec, amcl_model=model, amcl_sigma_yaw_rad=yaw, joint=True)
        common, rest = bound.horizontal_split_mm()
        out[key] = dict(xy=bound.horizontal_rms_bound_mm, common=common, rest=rest, genie_common=genie,
                        p_within=bound.share_within_mm(limit_mm, seed=seed))
    out["bound"]["cpu_s"] = time.process_time() - c0
    return out


LOG_HEADER = ("| log | AMCL | sensors | graph xy (common / rest) | grid xy | bound xy (common / rest) | "
              "bound xy, heading as the graph | genie common | P(efficient <= limit) | graph / bound | "
              "CPU graph / grid / bounds (s) |")


def log_row(r: dict) -> str:
    f, b = r["factorgraph"], r["bound"]
    return (f"| {r['scenario']} {r['seed']} | {r['family']} | {r['sensors']} | {f['xy']:.1f} ({f['common']:.1f} / "
            f"{f['rest']:.1f}) | {r['gridsearch']['xy']:.1f} | {b['xy']:.1f} ({b['common']:.1f} / {b['rest']:.1f}) | "
            f"{r['bound_heading']['xy']:.1f} | {b['genie_common']:.1f} | {100 * b['p_within']:.0f} % | "
            f"{f['xy'] / b['xy']:.2f} | {f['cpu_s']:.1f} / {r['gridsearch']['cpu_s']:.1f} / {b['cpu_s']:.1f} |")


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def summary_row(name: str, rs: list[dict], limit_mm: float) -> str:
    g = lambda m, k: np.array([r[m][k] for r in rs])  # noqa: E731
    fg, gs, b = g("factorgraph", "xy"), g("gridsearch", "xy"), g("bound", "xy")
    eff = " / ".join(f"{_rms(g('factorgraph', k)) / _rms(g('bound', k)):.2f}" for k in ("xy", "common", "rest"))
    bh = g("bound_heading", "xy")
    z = np.concatenate([np.asarray(r["factorgraph"]["z_xy"]).reshape(-1, 2) for r in rs])
    within = ", ".join(f"{100 * np.mean(z[:, a] <= 1.0):.0f}" for a in (0, 1))
    return (f"| {name} | {len(rs)} | {fg.mean():.1f} | {gs.mean():.1f} | {b.mean():.1f} | {bh.mean():.1f} | "
            f"{g('bound', 'common').mean():.1f} / {g('bound', 'rest').mean():.1f} | "
            f"{g('bound', 'genie_common').mean():.1f} | "
            f"{g('factorgraph', 'common').mean():.1f} / {g('factorgraph', 'rest').mean():.1f} | "
            f"{np.mean([r['amcl_mean_mm'] for r in rs]):.1f} | "
            f"{_rms([r['amcl_mean_mm'] for r in rs]) / _rms(g('bound', 'common')):.2f} | "
            f"{_rms(g('factorgraph', 'common_less_amcl')):.1f} | "
            f"{100 * np.mean(b > limit_mm):.0f} | {100 * g('bound', 'p_within').mean():.0f} "
            f"({100 * g('bound_heading', 'p_within').mean():.0f}) | "
            f"{int(np.sum(fg <= limit_mm))} | {int(np.sum(fg <= 0.35 * gs))} | {eff} | "
            f"{g('bound_heading', 'rest').mean():.1f} | "
            f"{_rms(g('factorgraph', 'rest')) / _rms(g('bound_heading', 'rest')):.2f} | "
            f"{np.median(g('factorgraph', 'rest') / g('bound', 'rest')):.2f} | {within} |")


SINGLE_ROOM = ("rooms", "corridor", "openhall")


def xgen_common_bound_m2(log_dir: Path) -> np.ndarray | None:
    """The genie bound's 2 x 2 covariance (m^2, in the room's axes: along, across) of the common
    shift of an xgen log (module docstring), None where it is not bounded here."""
    from pedcal.calib.amcl_model import AmclErrorModel
    from pedcal.calib.crlb import common_shift_variance_m2

    info = json.loads((log_dir / "xgen.json").read_text())
    amcl = info["amcl"]
    if amcl["kind"] != "ou" or info["family"] not in SINGLE_ROOM:
        return None
    t = pd.read_csv(log_dir / "robot.csv")["t"].to_numpy(float)
    var = [common_shift_variance_m2(t, AmclErrorModel(white_sigma_m=0.0, correlated_sigma_m=amcl[k],
                                                      correlation_s=amcl["tau_xy_s"]))
           for k in ("sigma_along_m", "sigma_cross_m")]
    return np.diag(var)


def xgen_rows(results_dir: Path, limit_mm: float) -> list[dict]:
    """Per log of a bench_xgen run: the graph's and the grid search's horizontal RMS (every
    sensor, as bench_xgen scores it), AMCL's run-mean error, and the genie common-shift bound
    with the probability that an efficient estimator's common shift alone is within the limit
    (an upper bound on that of its whole error: NaN where not bounded)."""
    from pedcal.calib.crlb import share_rms_within_mm

    rows = [json.loads(line) for line in (results_dir / "results.jsonl").read_text().splitlines() if line]
    out = {}
    for r in rows:
        if r["method"] not in ("factorgraph", "gridsearch") or not r.get("sensors"):
            continue
        key = (r["family"], r["seed"])
        d = out.setdefault(key, dict(family=r["family"], seed=r["seed"], amcl_mean_mm=r["amcl_mean_mm"]))
        d[r["method"]] = 1000 * float(np.sqrt(np.mean([x["dx"] ** 2 + x["dy"] ** 2 for x in r["sensors"]])))
    for (family, seed), d in out.items():
        C = xgen_common_bound_m2(results_dir / f"{family}-{seed}" / "log")
        if C is None:
            d["common_bound_mm"] = d["p_within"] = float("nan")
            continue
        d["common_bound_mm"] = 1000 * float(np.sqrt(np.trace(C)))
        d["p_within"] = share_rms_within_mm(C, limit_mm, draws=20000, seed=seed)
    return list(out.values())


def print_xgen(rows: list[dict], limit_mm: float) -> None:
    lim = f"{limit_mm:g} mm"
    print("\nheld-out generator (xgen), horizontal, mm: the genie bound on the common shift (single-room OU logs)\n")
    print(f"| log | graph xy | grid xy | AMCL run-mean error | common-shift bound | "
          f"P(efficient common <= {lim}) |")
    print("|---|---|---|---|---|---|")
    for d in rows:
        print(f"| {d['family']} {d['seed']} | {d.get('factorgraph', np.nan):.1f} | {d.get('gridsearch', np.nan):.1f} | "
              f"{d['amcl_mean_mm']:.1f} | {d['common_bound_mm']:.1f} | {100 * d['p_within']:.0f} % |")
    b = np.array([d["common_bound_mm"] for d in rows])
    ok = np.isfinite(b)
    fg = np.array([d.get("factorgraph", np.nan) for d in rows])
    print(f"\n{len(rows)} logs, {int(ok.sum())} bounded: common-shift bound mean {np.mean(b[ok]):.1f} mm, "
          f"> {lim} on {int(np.sum(b[ok] > limit_mm))}; an efficient estimator's common shift within {lim} on "
          f"{100 * np.mean([d['p_within'] for d in rows if np.isfinite(d['p_within'])]):.0f} % of them (expected); "
          f"graph xy mean {np.nanmean(fg):.1f} mm over all {len(rows)} logs, {np.nanmean(fg[ok]):.1f} over the "
          f"bounded, "
          f"<= {lim} on {int(np.sum(fg <= limit_mm))}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["paper", "sparse", "corridor", "cross", "lhall"])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--limit-mm", type=float, default=12.0)
    ap.add_argument("--verbose", action="store_true", help="one line per log")
    ap.add_argument("--xgen-results", type=Path, nargs="+", default=None, metavar="DIR",
                    help="also bound the held-out generator's logs of earlier bench_xgen.py --out DIR runs")
    ap.add_argument("--xgen-only", action="store_true", help="with --xgen-results: no zoo logs")
    ap.add_argument("--off", nargs="+", default=[], choices=OFF_FAMILIES, metavar="FAMILY",
                    help=f"switch these zoo families off in the simulator (pedcal.sim.nuisances.switch_off): "
                         f"{', '.join(OFF_FAMILIES)}")
    ap.add_argument("--known", nargs="+", default=[], choices=sorted(KNOWN_RECIPE), metavar="FAMILY",
                    help="give the factor graph these families' truth (with --off the same family: "
                         f"{', '.join(sorted(KNOWN_RECIPE))})")
    args = ap.parse_args()
    if set(args.known) - set(args.off):
        ap.error("--known FAMILY needs --off FAMILY too (the truth the graph is given is the switched-off one)")
    if args.xgen_results is not None:
        print_xgen([row for d in args.xgen_results for row in xgen_rows(d, args.limit_mm)], args.limit_mm)
        if args.xgen_only:
            return
    tasks = [(sc, s, args.limit_mm, tuple(args.off), tuple(args.known)) for sc in args.scenarios
             for s in range(args.first_seed, args.first_seed + args.seeds)]
    if args.verbose:
        print(LOG_HEADER.replace("limit", f"{args.limit_mm:g} mm") + "\n" + "|---" * 11 + "|", flush=True)
    w0 = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.jobs) as ex:
        for r in ex.map(run_one, *zip(*tasks, strict=True)):
            results.append(r)
            if args.verbose:
                print(log_row(r), flush=True)
    wall = time.perf_counter() - w0
    lim = f"{args.limit_mm:g} mm"
    print(f"{len(args.scenarios)} scenarios x {args.seeds} seeds (first {args.first_seed}), --vary-nuisances zoo"
          f"{'; off: ' + ' '.join(args.off) if args.off else ''}"
          f"{'; known: ' + ' '.join(args.known) if args.known else ''}; "
          f"wall {wall:.0f} s with {args.jobs} jobs, load {os.getloadavg()[0]:.2f} at the end")
    print("\nhorizontal, mm; means over logs (efficiency: RMS over logs of the graph's over the bound's)\n")
    print(f"| group | logs | graph xy | grid xy | bound xy | bound xy, heading as the graph | bound common / rest | "
          f"genie common | graph common / rest | AMCL run-mean error | AMCL run-mean / bound common (RMS) | "
          f"graph common less AMCL run mean (RMS) | bound > {lim} (% of logs) | "
          f"efficient <= {lim} (expected % of logs; heading as the graph) | "
          f"graph <= {lim} (logs) | graph <= 0.35x grid (logs) | graph / bound: xy / common / rest | "
          f"bound rest, heading as the graph | graph / that bound: rest | graph / bound rest (median over logs) | "
          f"graph within 1 sigma x, y (%) |")
    print("|---" * 21 + "|")
    groups = defaultdict(list)
    for r in results:
        groups[r["scenario"]].append(r)
    for r in results:
        groups[f"AMCL {r['family']}"].append(r)
    for name, rs in groups.items():
        print(summary_row(name, rs, args.limit_mm))
    print(summary_row("pooled", results, args.limit_mm))


if __name__ == "__main__":
    main()
