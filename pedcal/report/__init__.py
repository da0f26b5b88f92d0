"""Accuracy reports: scenarios x seeds x methods against the papers' tables, with figures.

- ``run_report(...)``: run the sweep (serially or on Dask), save the raw results, build the report;
- ``build_report(results_dir)``: rebuild ``report.md`` and its figures from saved results alone;
- ``compare_extrinsics(log, [A.yaml, B.yaml], out)``: compare calibrations on a user's own log.
"""

from __future__ import annotations

from pathlib import Path

from pedcal.errors import PedcalInputError
from pedcal.report.build import SECTIONS, ReportContext, build_report, register_section
from pedcal.report.compare import compare_extrinsics
from pedcal.report.results import SweepResults, load_results, results_from_cases, save_results
from pedcal.report.sweep import (
    DEFAULT_FOLLOW_SCENES,
    DEFAULT_FOLLOW_SEEDS,
    DEFAULT_FOLLOW_TRACKERS,
    DEFAULT_SCENARIOS,
    DEFAULT_SEEDS,
    METHOD_ORDER,
    SweepConfig,
    check_follow,
    check_methods,
    parse_scenarios,
    run_follow_case,
    run_sweep,
)


def run_report(scenarios=DEFAULT_SCENARIOS, seeds: int = DEFAULT_SEEDS, methods=METHOD_ORDER,
               out: str | Path = "reports/default", *, scheduler: str | None = None, workers: int | None = None,
               serial: bool = False, progress: bool = True, follow_scenes=DEFAULT_FOLLOW_SCENES,
               follow_trackers=DEFAULT_FOLLOW_TRACKERS, follow_seeds: int = DEFAULT_FOLLOW_SEEDS) -> Path:
    """Run ``scenarios`` (names, or ``NAME:SEEDS`` for a scenario's own seed count) x seeds
    0..seeds-1 x ``methods``, and, when ``follow_seeds`` > 0, the following scenes x trackers x
    seeds 0..follow_seeds-1 (``pedcal follow``); save the results into ``out`` and build
    ``out/report.md``. Returns the report's path."""
    if follow_seeds < 0:
        raise PedcalInputError(f"--follow-seeds {follow_seeds}: expected 0 or more")
    scenes, trackers = check_follow(follow_scenes, follow_trackers)
    config = SweepConfig(scenarios=parse_scenarios(scenarios, seeds), methods=check_methods(methods),
                         seeds=seeds, out=str(out), follow_scenes=scenes, follow_trackers=trackers,
                         follow_seeds=follow_seeds)
    cases = run_sweep(config, scheduler=scheduler, workers=workers, serial=serial, progress=progress)
    calib_cases = [c for c in cases if "scenario" in c]
    timings = {c["scenario"]: {} for c in calib_cases}
    for c in calib_cases:
        timings[c["scenario"]][str(c["seed"])] = c["timings"]
    save_results(results_from_cases(config, cases), out, timings={"solve_time_s": timings})
    return build_report(out)


def rerun_tracking(results_dir: str | Path, *, progress: bool = True) -> Path:
    """Run the saved sweep's following part again (its scenes x trackers x seeds, serially), replace
    the tracking table of the results in ``results_dir`` (the calibration tables are kept as they
    are) and rebuild the report. Returns the report's path."""
    import logging

    results = load_results(results_dir)
    cfg = results.config
    if cfg.follow_seeds < 1:
        raise PedcalInputError("these results hold no following part (--follow-seeds 0)", path=results_dir)
    check_follow(cfg.follow_scenes, cfg.follow_trackers)
    cases = []
    for k, (scene, seed) in enumerate(cfg.follow_cases(), 1):
        cases.append(run_follow_case(scene, seed, list(cfg.follow_trackers)))
        if progress:
            logging.getLogger(__name__).info(f"report: following {k}/{len(cfg.follow_cases())} ({scene} seed {seed})",
                                             extra={"progress": (k, len(cfg.follow_cases()))})
    results.tracking = results_from_cases(cfg, cases).tracking
    save_results(results, results_dir)
    return build_report(results_dir)


__all__ = ["run_report", "rerun_tracking", "build_report",
           "compare_extrinsics", "register_section", "SECTIONS", "ReportContext",
           "SweepConfig", "SweepResults", "load_results", "save_results", "results_from_cases", "run_sweep",
           "parse_scenarios", "check_methods"]
