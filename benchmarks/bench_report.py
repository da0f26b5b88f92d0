"""Time of a report sweep, serial and on a local Dask cluster, and of rebuilding the report
from saved results.

    .venv/bin/python benchmarks/bench_report.py [scenario] [seeds] [workers]

Defaults: sparse, 4 seeds, 2 workers, methods installed, gridsearch, closedform, factorgraph.
"""

from __future__ import annotations

import sys
import tempfile
import time

from pedcal.report import SweepConfig, build_report, results_from_cases, run_sweep, save_results
from pedcal.report.results import TABLES


def main(scenario: str = "sparse", seeds: int = 4, workers: int = 2) -> None:
    config = SweepConfig(scenarios=[(scenario, seeds)], methods=["installed", "gridsearch", "closedform",
                                                                  "factorgraph"], seeds=seeds)
    t0 = time.perf_counter()
    serial = run_sweep(config, serial=True, progress=False)
    t_serial = time.perf_counter() - t0
    t0 = time.perf_counter()
    parallel = run_sweep(config, workers=workers, progress=False)
    t_dask = time.perf_counter() - t0
    a, b = results_from_cases(config, serial), results_from_cases(config, parallel)
    same = all(getattr(a, k).equals(getattr(b, k)) for k in TABLES)
    with tempfile.TemporaryDirectory() as tmp:
        save_results(results_from_cases(config, serial), tmp)
        t0 = time.perf_counter()
        build_report(tmp)
        t_build = time.perf_counter() - t0
    print(f"{'scenario':8s} {'seeds':>5s} {'serial_s':>8s} {'dask_s':>7s} {'workers':>7s} {'equal':>5s} "
          f"{'build_s':>7s}")
    print(f"{scenario:8s} {seeds:5d} {t_serial:8.1f} {t_dask:7.1f} {workers:7d} {str(same):>5s} {t_build:7.1f}")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0] if a else "sparse", int(a[1]) if len(a) > 1 else 4, int(a[2]) if len(a) > 2 else 2)
