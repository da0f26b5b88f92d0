"""The head point's shift against distance (pedcal.calib.headpoint) on the simulator's head models:
the factor graph's horizontal sensor RMS with the constant shift (``head_profile = "off"``) and
with the profile chosen by each criterion, per head family, over seeds.

    nice -n 5 .venv/bin/python benchmarks/bench_head_profile.py [--seeds 20] [--scenarios paper sparse]
        [--families shift ramp saturate zoo per-sensor] [--modes off cv bic cv+sensors] [--duration 200]

Modes: a ``head_profile`` value, ``+sensors`` adding each sensor's own departure
(``head_profile_per_sensor``). Families: ``shift`` a constant shift toward the sensor, ``ramp``
one fading to nothing with horizontal distance, ``saturate`` one growing to its size and
staying, each of 2-6 cm over 1-3 m, linear, exponential or smooth, drawn per seed; ``zoo`` the simulator's nuisance zoo
(``vary_nuisances="zoo"``: any head model, per sensor half the time, with the other families'
nuisances); ``per-sensor`` the zoo's draw with a head model drawn for every sensor. Per family:
mean and median xy RMS (mm) per mode, the mean difference to ``off`` with its standard error, the
worst log's difference, the mean xy RMS less each log's mean horizontal error (what the sensors
share, such as AMCL's mean error: the network's shape) and the models chosen. CPU seconds of the
calibrations at the end.
"""

from __future__ import annotations

import argparse
import logging
import time
import warnings
from collections import Counter, defaultdict

import numpy as np

from pedcal.calib import calibrate
from pedcal.sim import simulate_logs
from pedcal.sim.nuisances import RAMP_SHAPES, vary
from pedcal.sim.scenario import load_scenario


class _Chosen(logging.Handler):
    """Keeps the head profile's choice from the calibration's progress log."""

    def __init__(self):
        super().__init__()
        self.chosen: list[str] = []

    def emit(self, record):
        msg = record.getMessage()
        if "against distance:" in msg and "'chosen': '" in msg:
            self.chosen.append(msg.split("'chosen': '")[1].split("'")[0].split("@")[0])


def _simulate(scenario: str, family: str, seed: int, duration_s: float):
    if family == "per-sensor":      # the zoo's draw with a head model drawn for each sensor
        sc = vary(load_scenario(scenario).resolve(seed=seed, duration_s=duration_s), zoo=True)
        return simulate_logs(sc.resolve(per_sensor_head=True), seed=seed)
    return simulate_logs(scenario, seed=seed, duration_s=duration_s, **_overrides(family, seed))


def _overrides(family: str, seed: int) -> dict:
    if family == "zoo":
        return {"vary_nuisances": "zoo"}
    rng = np.random.default_rng([seed, 0x4EAD])
    return {"head_point": family, "head_shift_m": float(rng.uniform(0.02, 0.06)),
            "head_ramp_m": float(rng.uniform(1.0, 3.0)), "head_ramp_shape": str(rng.choice(RAMP_SHAPES))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--scenarios", nargs="+", default=["paper"])
    ap.add_argument("--families", nargs="+", default=["shift", "ramp", "saturate", "zoo"])
    ap.add_argument("--modes", nargs="+", default=["off", "cv", "bic"])
    ap.add_argument("--duration", type=float, default=200.0)
    args = ap.parse_args()
    handler = _Chosen()
    logger = logging.getLogger("pedcal")
    logger.setLevel(logging.INFO)
    logger.addHandler(handler)
    logger.propagate = False
    cpu = defaultdict(float)
    for scenario in args.scenarios:
        for family in args.families:
            xy, xy_shape = defaultdict(list), defaultdict(list)
            chosen = defaultdict(Counter)
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                sim = _simulate(scenario, family, seed, args.duration)
                for mode in args.modes:
                    handler.chosen.clear()
                    t = time.process_time()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        # (the shared shift's shapes compared alone: without each sensor's own
                        # departure as a random effect, which the selected departures replace)
                        res = calibrate(sim.calib, method="factorgraph", head_profile=mode.split("+")[0],
                                        head_profile_per_sensor=mode.endswith("+sensors"),
                                        head_shift_per_sensor_sigma_m=0.0, progress=True)
                    cpu[mode] += time.process_time() - t
                    E = np.array([res.network[s].position_m - sim.calib.truth[s].position_m
                                  for s in sim.calib.sensors.ids])
                    xy[mode].append(1000 * np.sqrt(np.mean(np.sum(E[:, :2] ** 2, axis=1))))
                    shape = E[:, :2] - E[:, :2].mean(axis=0)
                    xy_shape[mode].append(1000 * np.sqrt(np.mean(np.sum(shape ** 2, axis=1))))
                    chosen[mode][handler.chosen[-1] if handler.chosen else "-"] += 1
            print(f"{scenario} / {family}: {args.seeds} seeds from {args.first_seed}")
            ref = np.array(xy["off"]) if "off" in xy else None
            for mode in args.modes:
                v = np.array(xy[mode])
                line = f"  {mode:5s} xy mean {v.mean():5.1f} median {np.median(v):5.1f} mm"
                if ref is not None and mode != "off":
                    d = v - ref
                    line += (f" | vs off {d.mean():+5.1f} +- {d.std(ddof=1) / np.sqrt(len(d)):.1f} mm, worst "
                             f"{d.max():+5.1f}, better on {int(np.sum(d < 0))}/{len(d)}")
                line += f" | less shared shift {np.mean(xy_shape[mode]):5.1f} | chosen {dict(chosen[mode])}"
                print(line, flush=True)
    print("CPU s per calibration: " + ", ".join(
        f"{m} {cpu[m] / (args.seeds * len(args.families) * len(args.scenarios)):.2f}" for m in args.modes))


if __name__ == "__main__":
    main()
