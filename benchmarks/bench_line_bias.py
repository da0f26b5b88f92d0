"""The estimated line's bias (``head_profile = "linear"``: the head point's horizontal shift toward
the sensor rising by a slope from the first to the last knot of horizontal distance) where the
head point is the blob's top, its true line 0: every nuisance off but AMCL's wandering error
(correlated, 5 cm, 1 deg) and mixed mounting heights (2.6-4.5 m), with the observation noise
off, on (depth 1.5e-3 r^2 doubled past 3.5 m, lateral 1 cm) or in part, to tell the bias's
sources apart: ``depth`` (the depth noise alone), ``depth-flat`` (alone and not doubled past
3.5 m, the recipe's model still doubling it), ``lateral`` (the lateral noise alone).

    nice -n 5 .venv/bin/python benchmarks/bench_line_bias.py [--seeds 10] [--scenario corridor]
        [--noise off on depth depth-flat lateral] [--recipe key=value ...]

Per seed and mean +- standard error over seeds: the line's estimate (its rise per metre of
horizontal distance between the end knots, mm/m) and the network's stretch along x (the
least-squares slope of the sensors' x error against their true x, mm/m). CPU seconds of the
calibrations at the end.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from bench_factorgraph_nuisances import recipe_overrides

from pedcal.calib import calibrate
from pedcal.metrics import HEAD_MODEL_KEY
from pedcal.sim import simulate_logs

SETUP = dict(noise_free=True, amcl_error="correlated", amcl_sigma_m=0.05, amcl_sigma_yaw_deg=1.0,
             sensor_height_range_m=[2.6, 4.5])
NOISE = {"off": {}, "on": dict(depth_noise_k_per_m=1.5e-3, lateral_noise_m=0.01, far_noise_factor=2.0),
         "depth": dict(depth_noise_k_per_m=1.5e-3, far_noise_factor=2.0),
         "depth-flat": dict(depth_noise_k_per_m=1.5e-3, far_noise_factor=1.0),
         "lateral": dict(lateral_noise_m=0.01)}


def stretch_m_per_m(truth, network) -> float:
    """The least-squares slope of the calibrated sensors' x error against their true x (m/m)."""
    ids = [i for i in network.ids if network[i].status == "ok"]
    err_x = np.array([network[i].position_m[0] - truth[i].position_m[0] for i in ids])
    x = np.array([truth[i].position_m[0] for i in ids])
    return float(np.sum((x - x.mean()) * err_x) / np.sum((x - x.mean()) ** 2))


def line_m_per_m(network) -> float:
    """The estimated shift's rise per metre between the profile's end knots (m/m; NaN without one)."""
    hm = network.extra.get(HEAD_MODEL_KEY)
    profile = hm.get("horizontal_profile") if isinstance(hm, dict) else None
    if not profile:
        return float("nan")
    d, s = np.asarray(profile["distance_m"], float), np.asarray(profile["shift_m"], float)
    return float((s[-1] - s[0]) / (d[-1] - d[0]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--scenario", default="corridor")
    ap.add_argument("--noise", nargs="+", choices=list(NOISE), default=["off", "on"])
    ap.add_argument("--recipe", nargs="*", default=[], metavar="KEY=VALUE",
                    help="graph recipe fields besides head_profile=linear")
    args = ap.parse_args()
    overrides = {"head_profile": "linear", **recipe_overrides(args.recipe, ap)}
    cpu = 0.0
    for noise in args.noise:
        lines, stretches = [], []
        for seed in range(args.seeds):
            sim = simulate_logs(args.scenario, seed=seed, **SETUP, **NOISE[noise])
            t0 = time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = calibrate(sim.calib, method="factorgraph", **overrides)
            cpu += time.process_time() - t0
            lines.append(1000 * line_m_per_m(res.network))
            stretches.append(1000 * stretch_m_per_m(sim.calib.truth, res.network))
            print(f"  noise {noise} seed {seed:2d}: line {lines[-1]:+6.2f} mm/m, stretch {stretches[-1]:+6.2f} mm/m",
                  flush=True)
        se = np.sqrt(len(lines))
        print(f"{args.scenario}, observation noise {noise}, {args.seeds} seeds: line {np.mean(lines):+.2f} +- "
              f"{np.std(lines, ddof=1) / se:.2f} mm/m, stretch {np.mean(stretches):+.2f} +- "
              f"{np.std(stretches, ddof=1) / se:.2f} mm/m")
    print(f"calibrations: {cpu:.1f} s CPU")


if __name__ == "__main__":
    main()
