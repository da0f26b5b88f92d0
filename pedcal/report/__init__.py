"""Accuracy reports: scenarios x seeds x methods against the papers' tables, with figures.

- ``run_report(...)``: run the sweep (serially or on Dask), save the raw results, build the report;
- ``build_report(results_dir)``: rebuild ``report.md`` and its figures from saved results alone;
- ``compare_extrinsics(log, [A.yaml, B.yaml], out)``: compare calibrations on a user's own log.
"""

from __future__ import annotations

from pathlib import Path

from pedcal.report.build import SECTIONS, ReportContext, build_report, register_section
from pedcal.report.compare import compare_extrinsics
from pedcal.report.results import SweepResults, load_results, results_from_cases, save_results
from pedcal.report.sweep import (
    DEFAULT_SCENARIOS,
    DEFAULT_SEEDS,
    METHOD_ORDER,
    SweepConfig,
    check_methods,
    parse_scenarios,
    run_sweep,
)


def run_report(scenarios=DEFAULT_SCENARIOS, seeds: int = DEFAULT_SEEDS, methods=METHOD_ORDER,
               out: str | Path = "reports/default", *, scheduler: str | None = None, workers: int | None = None,
               serial: bool = False, progress: bool = True) -> Path:
    """Run ``scenarios`` (names, or ``NAME:SEEDS`` for a scenario's own seed count) x seeds
    0..seeds-1 x ``methods``, save the results into ``out`` and build ``out/report.md``.
    Returns the report's path."""
    config = SweepConfig(scenarios=parse_scenarios(scenarios, seeds), methods=check_methods(methods),
                         seeds=seeds, out=str(out))
    cases = run_sweep(config, scheduler=scheduler, workers=workers, serial=serial, progress=progress)
    timings = {c["scenario"]: {} for c in cases}
    for c in cases:
        timings[c["scenario"]][str(c["seed"])] = c["timings"]
    save_results(results_from_cases(config, cases), out, timings={"solve_time_s": timings})
    return build_report(out)


__all__ = ["run_report", "build_report", "compare_extrinsics", "register_section", "SECTIONS", "ReportContext",
           "SweepConfig", "SweepResults", "load_results", "save_results", "results_from_cases", "run_sweep",
           "parse_scenarios", "check_methods"]
