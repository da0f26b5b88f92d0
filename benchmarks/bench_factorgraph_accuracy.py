"""Accuracy of the factor graph (and the baselines) over many seeds of a simulated scenario, the
honesty of its reported sigma, and its efficiency against the Cramér-Rao bound.

    .venv/bin/python benchmarks/bench_factorgraph_accuracy.py [--scenario paper] [--seeds 20]
        [--first-seed 0] [--methods factorgraph|all|m1,m2] [--crlb] [--companion 0.2]
        [--swap 0.2] [--repeats 1] [--set key=value ...]

Per seed: ``simulate_logs(scenario, seed)``, calibrate the calibration log, evaluate on the
evaluation log (the same route driven again, pedcal.metrics.evaluate): sensor position RMS (3-D,
mm; also over the sensors the method reports with status ok only), head tracking RMS (mm),
calibrate() time (s; the minimum over --repeats, the machine is shared). For the factor graph
also:

- sigma coverage, per axis: the fraction of sensor-axis errors (x, y, z in world axes, every
  sensor of every seed) within k reported sigma, k = 1, 2, 3 (a Gaussian gives 68.3 / 95.4 /
  99.7 %); and in 3-D: the fraction of sensors whose error e has e^T C^-1 e (C the reported
  world-axes position covariance) below the chi2(3) quantiles of the same probabilities;
- the AMCL floor: the RMS of the calibration run's mean AMCL position error (the one link of
  the rigid sensors + trajectory structure to the map; no estimator can know it), and the head
  RMS of two references on the evaluation log: the true extrinsics (the trackers' own noise) and
  the true extrinsics moved by the calibration run's mean AMCL error (what a calibration that
  knew everything but that unknowable mean would give);
- with --crlb, the Cramér-Rao bound (pedcal.calib.crlb.sensor_position_crlb) and RMS / bound.

``--companion F`` sets the scenario's companion_fraction (a pedestrian walking beside the robot
for a fraction F of the run); ``--swap F`` sets companion_swap_fraction (the trackers report a
companion beside the robot instead of the robot for a share F of its sightings, in swaps of a few
seconds through the run); ``--set key=value`` any other scenario parameter.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from scipy.stats import chi2

from pedcal.calib import calibrate
from pedcal.calib.common import interpolate_pose2
from pedcal.metrics import evaluate
from pedcal.sim import simulate_logs

ALL = ("installed", "alternative", "gridsearch", "closedform", "factorgraph")
PROBS = (0.6827, 0.9545, 0.9973)


def amcl_floor_mm(log) -> float:
    """|mean AMCL position error| over the run (mm)."""
    t = log.robot["t"].to_numpy(float)
    true = interpolate_pose2(log.truth_robot, t)
    e = log.robot[["x", "y"]].to_numpy(float) - true[:, :2]
    return float(1000.0 * np.linalg.norm(e.mean(axis=0)))


def ok_rms_mm(ev, network) -> float:
    """3-D sensor position RMS (mm) over the sensors ``network`` reports with status ok (NaN if none)."""
    e = [s.position_error_norm_mm for s in ev.sensors
         if s.id in network and network[s.id].status in (None, "ok") and np.isfinite(s.position_error_norm_mm)]
    return float(np.sqrt(np.mean(np.square(e)))) if e else float("nan")


def reference_head_rms_mm(sim) -> tuple[float, float]:
    """Head RMS on the evaluation log (true latency and head radius) of the true extrinsics, and of
    the true extrinsics moved by the calibration run's mean AMCL position error."""
    from pedcal.metrics import HEAD_RADIUS_KEY, LATENCY_KEY

    c = sim.calib
    t = c.robot["t"].to_numpy(float)
    shift = np.r_[(c.robot[["x", "y"]].to_numpy(float) - interpolate_pose2(c.truth_robot, t)[:, :2]).mean(0), 0]
    out = []
    for d in (np.zeros(3), shift):
        net = sim.eval.truth.copy()
        for s in net:
            s.position_m = s.position_m + d
        net.extra.update({LATENCY_KEY: sim.scenario.latency_s, HEAD_RADIUS_KEY: sim.scenario.head_radius_m})
        out.append(evaluate(sim.eval, net).head_tracking_rms_mm)
    return out[0], out[1]


def coverage(ev, res):
    """(per-axis |e| / sigma, 3-D Mahalanobis d^2) for every sensor the graph calibrated."""
    cov = getattr(res.diagnostics, "position_covariance_m2", {})
    ratios, d2 = [], []
    for s in ev.sensors:
        ext = res.network[s.id]
        if ext.status != "ok" or ext.sigma_position_m is None:
            continue
        e = np.asarray(s.position_error_mm) / 1000.0
        ratios.extend(np.abs(e) / np.asarray(ext.sigma_position_m))
        if s.id in cov:
            d2.append(float(e @ np.linalg.solve(cov[s.id], e)))
    return ratios, d2


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--methods", default="factorgraph")
    ap.add_argument("--crlb", action="store_true")
    ap.add_argument("--companion", type=float, default=None)
    ap.add_argument("--swap", type=float, default=None)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    methods = ALL if args.methods == "all" else tuple(args.methods.split(","))
    overrides = {}
    for kv in args.set:
        k, v = kv.split("=", 1)
        overrides[k] = float(v)
    if args.companion is not None:
        overrides["companion_fraction"] = args.companion
    if args.swap is not None:
        overrides["companion_swap_fraction"] = args.swap
    warnings.simplefilter("ignore")

    rows = {m: [] for m in methods}
    ratios, d2, floors, bounds, replaced, references = [], [], [], [], [], []
    print(f"{args.scenario}, seeds {args.first_seed}..{args.first_seed + args.seeds - 1}, overrides {overrides}")
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        sim = simulate_logs(args.scenario, seed=seed, **overrides)
        line = [f"seed {seed:3d}"]
        floors.append(amcl_floor_mm(sim.calib))
        references.append(reference_head_rms_mm(sim))
        for m in methods:
            if m == "installed":
                network, runtime, res = sim.calib.sensors, 0.0, None
            else:
                runtime = np.inf
                for _ in range(args.repeats):
                    t0 = time.perf_counter()
                    res = calibrate(sim.calib, method=m)
                    runtime = min(runtime, time.perf_counter() - t0)
                network = res.network
            ev = evaluate(sim.eval, network)
            rows[m].append((ev.sensor_position_rms_mm.combined, ev.head_tracking_rms_mm, runtime,
                            ok_rms_mm(ev, network)))
            line.append(f"{m} {rows[m][-1][0]:6.1f} (ok {rows[m][-1][3]:6.1f}) / {rows[m][-1][1]:6.1f} mm "
                        f"{runtime:5.2f} s")
            if m == "factorgraph":
                r, d = coverage(ev, res)
                ratios.extend(r)
                d2.extend(d)
        line.append(f"AMCL floor {floors[-1]:5.1f} mm, head true ext. {references[-1][0]:5.1f} "
                    f"+ AMCL mean {references[-1][1]:5.1f} mm")
        who = sim.calib.truth_observations["who"].astype(str)
        if (who == "companion").any():
            replaced.append(float((who == "companion").sum() / who.isin(["robot", "companion"]).sum()))
            line.append(f"companion {100 * replaced[-1]:4.1f}% of the robot's")
        if args.crlb:
            from pedcal.calib.crlb import sensor_position_crlb

            bounds.append(sensor_position_crlb(sim.calib).rms_bound_mm)
            line.append(f"CRLB {bounds[-1]:5.1f} mm")
        print("  ".join(line), flush=True)

    print(f"\nmean over {args.seeds} seeds (sensor RMS / head RMS mm, time s; RMS over seeds in brackets)")
    for m in methods:
        a = np.array(rows[m])
        print(f"  {m:12s} sensor {a[:, 0].mean():7.1f} [{np.sqrt(np.mean(a[:, 0] ** 2)):6.1f}] "
              f"ok-only {np.nanmean(a[:, 3]):7.1f}  "
              f"head {a[:, 1].mean():7.1f}  time mean {a[:, 2].mean():6.2f} min {a[:, 2].min():6.2f} "
              f"max {a[:, 2].max():6.2f}")
    print(f"  AMCL floor (|mean AMCL error| of the calibration run): mean {np.mean(floors):.1f} mm")
    ref = np.array(references)
    print(f"  head RMS references: true extrinsics {ref[:, 0].mean():.1f} mm, true extrinsics moved by the "
          f"run's mean AMCL error {ref[:, 1].mean():.1f} mm")
    if replaced:
        print(f"  companion rows among the robot's (robot + companion): mean {100 * np.mean(replaced):.1f}%")
    if "factorgraph" in methods and "gridsearch" in methods:
        fg, gs = np.array(rows["factorgraph"])[:, 0], np.array(rows["gridsearch"])[:, 0]
        print(f"  factor graph / grid search sensor RMS: {fg.mean() / gs.mean():.3f} (ratio of means)")
    if ratios:
        r, d = np.array(ratios), np.array(d2)
        per_axis = " ".join(f"{100 * np.mean(r <= k):.1f}%" for k in (1, 2, 3))
        maha = " ".join(f"{100 * np.mean(d <= chi2.ppf(p, 3)):.1f}%" for p in PROBS)
        print(f"  sigma coverage per axis within 1/2/3 sigma ({len(r)} sensor-axes): {per_axis}"
              f"   (Gaussian 68.3% 95.4% 99.7%)")
        print(f"  sigma coverage 3-D Mahalanobis below chi2(3) at 68.3/95.4/99.7% ({len(d)} sensors): {maha}")
    if bounds:
        fg = np.array(rows["factorgraph"])[:, 0] if "factorgraph" in methods else None
        print(f"  CRLB sqrt(mean trace): mean {np.mean(bounds):.1f} mm"
              + ("" if fg is None else f"; factor graph RMS / CRLB: mean of ratios "
                 f"{np.mean(fg / np.array(bounds)):.3f}, RMS over seeds / RMS bound "
                 f"{np.sqrt(np.mean(fg ** 2)) / np.sqrt(np.mean(np.square(bounds))):.3f}"))


if __name__ == "__main__":
    main()
