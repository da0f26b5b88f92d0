"""Is the sigma of what every sensor shares honest? The network's link to the map is AMCL's error
averaged over the run: a common shift and a common turn of the whole network. One log is one
draw of them, shared by all its sensors, so a per-axis "within 1 sigma" on one log says little
(one 1.3-sigma draw puts every sensor outside); this pools many seeds.

    nice -n 5 .venv/bin/python benchmarks/bench_common_mode.py [--scenarios paper scale40] \
        [--seeds 40] [--first-seed 0] [--jobs 2]

``scale40`` is the 40-sensor site of ``bench_factorgraph_scale.py`` (an exact odometry, AMCL an
OU of 5 cm and 1 deg over 20 s); any other name a simulator scenario with the nuisance zoo.
Per scenario and AMCL family: the sensors' horizontal errors fitted (least squares, about their
centroid) by a common shift and turn, each over its sigma from the joint position covariance
(the same linear map of it), and the rest over its sigma: RMS of these ratios (1 when honest;
over n draws its own spread is about 1 / sqrt(2 n)); the share of per-axis errors within 1 sigma;
and AMCL's true run-mean error over the exact std of an OU mean with the simulator's own
parameters, 2 sigma^2 tau / T (1 - tau / T (1 - e^-T/tau)): the truth's draw, whatever the graph.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_factorgraph_nuisances import projected_z, sigma_ratios  # noqa: E402


def shift_turn_z(E_xy_m: np.ndarray, P_xy_m: np.ndarray, C_m2: np.ndarray, rows):
    """(shift x, y and turn over their sigma (3,), rest over its sigma (2 n,)) of errors ``E``
    (n, 2) at sensors ``P`` (n, 2) under the joint position covariance ``C`` (3 N, 3 N) of the
    network, whose ``rows`` (n,) these sensors are."""
    n = len(E_xy_m)
    c = P_xy_m.mean(axis=0)
    A = np.zeros((2 * n, 3))
    A[0::2, 0] = A[1::2, 1] = 1.0
    A[0::2, 2], A[1::2, 2] = -(P_xy_m[:, 1] - c[1]), P_xy_m[:, 0] - c[0]
    return projected_z(E_xy_m, C_m2, A, rows)


def run_one(scenario: str, seed: int) -> dict:
    from pedcal.calib.amcl_model import AmclErrorModel
    from pedcal.metrics import amcl_run_mean_error_m

    warnings.simplefilter("ignore")
    if scenario.startswith("scale"):
        from bench_factorgraph_scale import synthetic_log

        from pedcal.calib.factorgraph import calibrate_factorgraph

        log = synthetic_log(int(scenario[len("scale"):]), seed)
        res = calibrate_factorgraph(log, is_robot=np.ones(len(log.observations), bool), estimate_latency=False,
                                    people=False, head_radius_m=0.0)
        truth, family, sigma_m, tau_s = log.truth, "correlated", 0.05, 20.0
    else:
        from pedcal.calib import calibrate
        from pedcal.sim import simulate_logs
        from pedcal.sim.nuisances import zoo_families

        sim = simulate_logs(scenario, seed=seed, vary_nuisances="zoo")
        log, truth = sim.calib, sim.eval.truth
        res = calibrate(log, method="factorgraph")
        family, sigma_m, tau_s = zoo_families(sim.scenario)["amcl"], sim.scenario.amcl_sigma_m, sim.scenario.amcl_tau_s
    ids = [s.id for s in res.network]
    P = np.array([truth[i].position_m[:2] for i in ids])
    E = np.array([res.network[i].position_m[:2] for i in ids]) - P
    # only calibrated sensors: one with the prior's sigma would drown the shared motion's
    ok = np.array([(res.network[i].status or "ok") == "ok" for i in ids], bool)
    z_common, z_rest = shift_turn_z(E[ok], P[ok], res.position_covariance_m2, np.flatnonzero(ok))
    t = log.robot["t"].to_numpy(float)
    floor = AmclErrorModel(0.0, sigma_m, tau_s).floor_sigma_m(float(t.max() - t.min()))
    z_truth = amcl_run_mean_error_m(log) / floor if family == "correlated" else np.full(2, np.nan)
    return dict(scenario=scenario, family=family, z_common=z_common, z_rest=z_rest,
                within=sigma_ratios(res.network, ids, E, missing=sum(sid not in res.network for sid in truth.ids),
                                          axes=2) <= 1.0, z_truth=z_truth)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["paper", "scale40"])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args()
    tasks = [(sc, s) for sc in args.scenarios for s in range(args.first_seed, args.first_seed + args.seeds)]
    with ProcessPoolExecutor(args.jobs) as ex:
        results = list(ex.map(run_one, *zip(*tasks, strict=True)))
    groups = defaultdict(list)
    for r in results:
        groups[(r["scenario"], "all")].append(r)
        groups[(r["scenario"], r["family"])].append(r)
    print(f"{args.seeds} seeds (first {args.first_seed}) per scenario")
    print("| scenario | AMCL | logs | shift x, y / sigma RMS | turn / sigma RMS | rest / sigma RMS | "
          "within 1 sigma x, y (%) | AMCL's true run mean / exact OU std, RMS x, y |")
    print("|---|---|---|---|---|---|---|---|")
    rms = lambda a: np.sqrt(np.nanmean(np.square(a), axis=0))  # noqa: E731
    for (sc, fam), rs in groups.items():
        zc = np.array([r["z_common"] for r in rs])
        zr = np.concatenate([r["z_rest"] for r in rs])
        within = 100.0 * np.concatenate([r["within"] for r in rs]).mean(axis=0)
        zt = np.array([r["z_truth"] for r in rs])
        truth = "-" if np.all(np.isnan(zt)) else "{:.2f}, {:.2f}".format(*rms(zt))
        print(f"| {sc} | {fam} | {len(rs)} | {rms(zc[:, 0]):.2f}, {rms(zc[:, 1]):.2f} | {rms(zc[:, 2]):.2f} | "
              f"{rms(zr):.2f} | {within[0]:.0f}, {within[1]:.0f} | {truth} |")


if __name__ == "__main__":
    main()
