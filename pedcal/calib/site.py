"""Sites that outgrow one solve: a building of many floors, or several buildings, each driven by
the robot in its own runs, is a set of independent calibration problems (no sensor is seen in two
runs, no factor joins two graphs), so each run's log is calibrated on its own and the runs in
parallel: serially, on a local Dask cluster of worker processes, or on the Dask scheduler at an
address (the one ``pedcal report --scheduler ADDR`` uses), where each worker reads its run's log
directory and writes its calibrated YAML itself (no log or graph crosses the network).

A sensor seen in two runs ties their graphs together; :func:`calibrate_site` refuses such a site
rather than calibrate one sensor twice (calibrate those runs as one log instead).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

from pedcal.errors import PedcalInputError


def _calibrate_run(log_dir: str, out_path: str, method: str, options: dict) -> dict:
    """One run: its log read, calibrated and the calibrated YAML written (atomically); a summary
    back (the run's name, sensors and their statuses, the solve's wall and CPU time)."""
    import warnings

    from pedcal.calib import calibrate
    from pedcal.errors import DegenerateDataWarning
    from pedcal.io import read_log, write_sensors_yaml

    log = read_log(log_dir)
    w0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DegenerateDataWarning)
        res = calibrate(log, method=method, **options)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    write_sensors_yaml(res.network, out_path)
    return {"run": Path(log_dir).name, "log": str(log_dir), "output": str(out_path), "method": method,
            "sensors": {s.id: s.status for s in res.network}, "solve_wall_s": wall, "solve_cpu_s": cpu,
            "warnings": [str(w.message) for w in caught]}


def _sensor_ids(log_dir: Path) -> list[str]:
    from pedcal.io import read_sensors_yaml

    return [s.id for s in read_sensors_yaml(log_dir / "sensors.yaml")]


def calibrate_site(log_dirs, out_dir: str | Path, *, method: str = "factorgraph", scheduler: str | None = None,
                   workers: int | None = None, serial: bool = False, progress: bool = False,
                   **options) -> list[dict]:
    """Calibrate every run of a site (``log_dirs``: one log directory per run, whose sensors no
    other run holds) into ``out_dir``/RUN.yaml (RUN: the log directory's name), each run on its
    own: serially (``serial``), on the Dask scheduler at ``scheduler`` or on a local cluster of
    ``workers`` processes (default: the cores present), one thread each. ``options`` go to
    :func:`pedcal.calib.calibrate` for every run. Returns one summary per run (as
    ``_calibrate_run``), in the order given.

    Refused before any work: no run, two runs of one name, a run without a log directory, or a
    sensor id in two runs (their graphs are one problem)."""
    dirs = [Path(d) for d in log_dirs]
    if not dirs:
        raise PedcalInputError("no run to calibrate: give one log directory per run")
    names = [d.name for d in dirs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise PedcalInputError(f"two runs named {', '.join(dup)}: each run's calibrated YAML is named after its "
                               "log directory, so run names must differ")
    owner: dict[str, str] = {}
    for d in dirs:
        if not (d / "sensors.yaml").is_file():
            raise PedcalInputError("expected a log directory (sensors.yaml, robot.csv, observations.csv)", path=d)
        for sid in _sensor_ids(d):
            if sid in owner:
                raise PedcalInputError(f"sensor {sid} is in run {owner[sid]} and run {d.name}: the two runs' graphs "
                                       "share it, so they are one problem; calibrate them as one log", path=d)
            owner[sid] = d.name
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tasks = [(str(d), str(out_dir / f"{d.name}.yaml"), method, dict(options)) for d in dirs]
    log = logging.getLogger(__name__)
    if serial:
        done = []
        for k, task in enumerate(tasks, 1):
            done.append(_calibrate_run(*task))
            if progress:
                log.info(f"site: {k}/{len(tasks)} runs calibrated ({done[-1]['run']})")
        return done
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=":0")
    try:
        with Client(scheduler or cluster) as client:
            futures = {client.submit(_calibrate_run, *task, key=f"pedcal-site-{Path(task[0]).name}",
                                     pure=False): i for i, task in enumerate(tasks)}
            done = [None] * len(tasks)
            for k, fut in enumerate(as_completed(list(futures)), 1):
                done[futures[fut]] = fut.result()
                if progress:
                    log.info(f"site: {k}/{len(tasks)} runs calibrated ({done[futures[fut]]['run']})")
    finally:
        if cluster is not None:
            cluster.close()
    return done


__all__ = ["calibrate_site"]
