"""How soon a calibration of a log without a single observation says so, for N sensors: the time
until the pre-flight's warning, and the time the whole call then takes (every sensor comes back
with status no-data).

    nice -n 10 .venv/bin/python benchmarks/bench_preflight_no_observations.py [N ...]   (default 100 1000)

Prints wall and CPU time (pedcal's modules imported by a first small call, so the figures are the
calibration's, not the imports').
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np
import pandas as pd


def run(n: int) -> tuple[float, float, float, float]:
    from pedcal.calib import calibrate
    from pedcal.model import OBSERVATION_COLUMNS, Log, SensorExtrinsics, SensorNetwork

    sensors = SensorNetwork([SensorExtrinsics(f"s{i}", [i % 100 * 3.0, i // 100 * 3.0, 2.6], [0, 45, 0])
                             for i in range(n)])
    t = np.arange(0.0, 100.0, 0.5)
    robot = pd.DataFrame({"t": t, "x": 0.1 * t, "y": 0.0, "yaw": 0.0, "cov_xx": 1e-3, "cov_xy": 0.0,
                          "cov_xyaw": 0.0, "cov_yy": 1e-3, "cov_yyaw": 0.0, "cov_yawyaw": 1e-4})
    log = Log(sensors=sensors, robot=robot, observations=pd.DataFrame(columns=list(OBSERVATION_COLUMNS)))
    said = []
    w0, c0 = time.perf_counter(), time.process_time()

    def show(message, *args, **kwargs):
        if "no observations" in str(message) and not said:
            said.append((time.perf_counter() - w0, time.process_time() - c0))

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = show
        calibrate(log)
    return (*said[0], time.perf_counter() - w0, time.process_time() - c0)


def main(sizes: list[int]) -> None:
    run(2)
    for n in sizes:
        warn_wall, warn_cpu, wall, cpu = run(n)
        print(f"{n:6d} sensors: warning after {warn_wall:.2f} s wall / {warn_cpu:.2f} s CPU; whole call "
              f"{wall:.1f} s wall / {cpu:.1f} s CPU")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [100, 1000])
