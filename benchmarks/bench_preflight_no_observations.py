"""How soon a calibration of a log without a single observation is refused, for N sensors (the
pre-flight says so before the solver sets up any sensor).

    nice -n 10 .venv/bin/python benchmarks/bench_preflight_no_observations.py [N ...]   (default 100 10000)

Prints wall and CPU time of the refused call (pedcal's modules already imported, so the figure is
the check's, not the imports').
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pandas as pd


def main(sizes: list[int]) -> None:
    from pedcal.calib import calibrate
    from pedcal.errors import PedcalInputError
    from pedcal.model import OBSERVATION_COLUMNS, Log, SensorExtrinsics, SensorNetwork

    for n in sizes:
        sensors = SensorNetwork([SensorExtrinsics(f"s{i}", [i % 100 * 3.0, i // 100 * 3.0, 2.6], [0, 45, 0])
                                 for i in range(n)])
        t = np.arange(0.0, 100.0, 0.5)
        robot = pd.DataFrame({"t": t, "x": 0.1 * t, "y": 0.0, "yaw": 0.0, "cov_xx": 1e-3, "cov_xy": 0.0,
                              "cov_xyaw": 0.0, "cov_yy": 1e-3, "cov_yyaw": 0.0, "cov_yawyaw": 1e-4})
        log = Log(sensors=sensors, robot=robot, observations=pd.DataFrame(columns=list(OBSERVATION_COLUMNS)))
        w0, c0 = time.perf_counter(), time.process_time()
        try:
            calibrate(log)
            outcome = "calibrated"
        except PedcalInputError as e:
            outcome = f"refused: {e}"
        print(f"{n:6d} sensors: {time.perf_counter() - w0:.2f} s wall, {time.process_time() - c0:.2f} s CPU; "
              f"{outcome[:100]}")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [100, 10000])
