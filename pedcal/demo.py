"""The main job on the built-in default: simulate a scenario, calibrate its calibration log with
every method, evaluate each on the evaluation log (the same route driven again), print the table;
then the same over several seeds, as mean and spread (one seed draws one AMCL error averaged over
the run, which every calibration anchored to AMCL shares and which can put any method ahead).

Results are saved (``OUT/results.json`` and one calibrated YAML per method of the first seed) and
the tables are built from them.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from pedcal.io.atomic import write_text_atomic

PAPER = {  # Kimoto et al., Tables I and II: sensor position RMS, head tracking RMS (mm)
    "paper": {"alternative": (346.96, 694.04), "gridsearch": (100.17, 135.29)},
    "sparse": {"alternative": (379.53, None), "gridsearch": (115.91, None)},
}
METHOD_ORDER = ("installed", "alternative", "gridsearch", "closedform", "factorgraph")


def calibrate_scored(sim, method: str):
    """``method``'s extrinsics for ``sim.calib`` ("installed": the log's own), its solve time (s) and,
    when the method picks the robot's observations, their precision/recall against the simulator's
    labels. Shared by the demo and the report's sweep."""
    from pedcal.calib import calibrate
    from pedcal.calib.association import score_association

    if method == "installed":
        return sim.calib.sensors, 0.0, None
    res = calibrate(sim.calib, method=method, progress=False)
    assoc = score_association(sim.calib, res.is_robot) if res.is_robot is not None else None
    return res.network, res.runtime_s, assoc


def run_methods(sim, out_dir: Path | None, progress: bool = True) -> dict:
    """Calibrate ``sim.calib`` with every method, evaluate on ``sim.eval``; returns the results
    (and writes each method's calibrated YAML into ``out_dir`` unless it is None).
    ``sensor_position_rms_less_amcl_mm``: the horizontal RMS with AMCL's error averaged over the
    calibration run (the simulator's truth) taken out of every sensor's error, the part a
    calibration anchored to AMCL controls."""
    import numpy as np

    from pedcal.io import write_sensors_yaml
    from pedcal.metrics import amcl_run_mean_error_m, evaluate

    shared_mm = amcl_run_mean_error_m(sim.calib)
    results = {}
    for method in METHOD_ORDER:
        if progress:
            logging.getLogger(__name__).info(f"[demo] {method} ...")
        network, runtime, assoc = calibrate_scored(sim, method)
        if method != "installed" and out_dir is not None:
            write_sensors_yaml(network, out_dir / f"calibrated_{method}.yaml")
        ev = evaluate(sim.eval, network)
        less = float("nan")
        if shared_mm is not None:
            E = np.array([s.position_error_mm[:2] for s in ev.sensors], float) - 1000.0 * shared_mm
            less = float(np.sqrt(np.nanmean(np.sum(E ** 2, axis=1))))
        results[method] = dict(sensor_position_rms_mm=ev.sensor_position_rms_mm.combined,
                               sensor_position_rms_xy_mm=ev.sensor_position_rms_mm.horizontal,
                               sensor_position_rms_less_amcl_mm=less,
                               orientation_rms_deg=ev.orientation_rms_deg,
                               head_tracking_rms_mm=ev.head_tracking_rms_mm, runtime_s=runtime,
                               association=assoc,
                               statuses={s.id: s.status for s in network if s.status})
    return results


def format_results(results: dict, scenario: str) -> str:
    paper = PAPER.get(scenario, {})
    lines = [f"{'method':<12s} {'sensor pos RMS 3-D / xy / xy less AMCL (mm)':>43s} {'orient RMS (deg)':>17s} "
             f"{'head RMS (mm)':>14s} {'assoc P/R':>11s} {'time (s)':>9s}   paper: sensor / head (mm)"]
    for method in METHOD_ORDER:
        if method not in results:
            continue
        r = results[method]
        a = r.get("association")
        assoc = f"{a['precision']:.3f}/{a['recall']:.3f}" if a else "-"
        pp = paper.get(method)
        ptxt = "" if not pp else f"{pp[0]:.2f} / {pp[1]:.2f}" if pp[1] else f"{pp[0]:.2f} / -"
        pos = (f"{r['sensor_position_rms_mm']:.1f} / {r['sensor_position_rms_xy_mm']:.1f} / "
               f"{r['sensor_position_rms_less_amcl_mm']:.1f}")
        lines.append(f"{method:<12s} {pos:>43s} {r['orientation_rms_deg']:17.3f} "
                     f"{r['head_tracking_rms_mm']:14.1f} {assoc:>11s} {r['runtime_s']:9.2f}   {ptxt}")
    return "\n".join(lines)


SUMMARY_KEYS = ("sensor_position_rms_mm", "sensor_position_rms_xy_mm", "sensor_position_rms_less_amcl_mm",
                "runtime_s")


def summarize_seeds(per_seed: list[dict]) -> dict:
    """Per method and figure (SUMMARY_KEYS), the mean and the sample standard deviation (ddof 1;
    0 for one seed) over the seeds' results (each as :func:`run_methods` returns them)."""
    import numpy as np

    out = {}
    for method in METHOD_ORDER:
        rows = [r[method] for r in per_seed if method in r]
        if not rows:
            continue
        out[method] = {}
        for key in SUMMARY_KEYS:
            v = np.array([row[key] for row in rows], float)
            out[method][key] = {"mean": float(np.mean(v)), "std": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0}
    return out


def format_summary(summary: dict, scenario: str, seeds: list[int]) -> str:
    lines = [f"{scenario} scenario over seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} seeds), mean +- standard "
             "deviation over the seeds:",
             f"{'method':<12s} {'sensor pos RMS 3-D (mm)':>24s} {'xy (mm)':>15s} {'xy less AMCL (mm)':>18s} "
             f"{'time (s)':>13s}"]
    for method in METHOD_ORDER:
        if method not in summary:
            continue
        cells = [f"{summary[method][k]['mean']:.1f} +- {summary[method][k]['std']:.1f}" for k in SUMMARY_KEYS[:3]]
        t = summary[method]["runtime_s"]
        lines.append(f"{method:<12s} {cells[0]:>24s} {cells[1]:>15s} {cells[2]:>18s} "
                     f"{t['mean']:>6.2f} +- {t['std']:.2f}")
    return "\n".join(lines)


def run_demo(out_dir: Path, seed: int = 0, scenario: str = "paper", seeds: int = 4) -> int:
    """The demo: ``seed``'s table (its logs and calibrated YAMLs written to ``out_dir``), then the
    methods over ``seeds`` seeds from ``seed`` on (the others simulated in memory)."""
    import warnings

    from pedcal.errors import DegenerateDataWarning
    from pedcal.metrics import amcl_run_mean_error_m
    from pedcal.sim import simulate, simulate_logs

    if seeds < 1:
        from pedcal.errors import PedcalInputError

        raise PedcalInputError(f"--seeds must be at least 1, got {seeds}")
    out_dir = Path(out_dir)
    sim = simulate(scenario, out_dir, seed=seed, progress=True)
    print(sim.summary())
    results = run_methods(sim, out_dir)
    print(f"\n{scenario} scenario, seed {seed}: calibrated on {out_dir / 'calib'}, evaluated on {out_dir / 'eval'}")
    print(format_results(results, scenario))
    floor = amcl_run_mean_error_m(sim.calib)
    if floor is not None:
        print(f"AMCL's own error averaged over the calibration run (simulator's truth): x {1000 * floor[0]:+.1f}, "
              f"y {1000 * floor[1]:+.1f} mm; every calibration anchored to AMCL shares it, and 'xy less AMCL' "
              "takes it out. The vertical part of the factor graph's error is the head point's unknown height "
              "unless a height reference is given (pedcal calibrate --sensor-height-sigma / --ceiling-height)")
    per_seed, seed_list = [results], list(range(seed, seed + seeds))
    for s in seed_list[1:]:
        logging.getLogger(__name__).info(f"[demo] seed {s} ...")
        with warnings.catch_warnings():     # the first seed's warnings were shown; the others' repeat them
            warnings.simplefilter("ignore", DegenerateDataWarning)
            per_seed.append(run_methods(simulate_logs(scenario, seed=s), None, progress=False))
    summary = summarize_seeds(per_seed)
    if seeds > 1:
        print()
        print(format_summary(summary, scenario, seed_list))
        print("(one seed's table above is one draw; benchmarks/bench_factorgraph_nuisances.py averages over "
              "more seeds and nuisance models)")
    write_text_atomic(out_dir / "results.json", json.dumps(
        {"scenario": scenario, "seed": seed, "evaluated_on": "eval log", "results": results,
         "seeds": seed_list, "over_seeds": summary, "per_seed": per_seed}, indent=2))
    print(f"\nsaved: {out_dir / 'results.json'}")
    return 0
