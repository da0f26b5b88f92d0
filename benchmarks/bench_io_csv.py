"""Log table I/O on N rows (default 2 000 000): pedcal's CSV reader (numbers parsed by pandas' C
reader, then validated) against a plain ``pd.read_csv``, the CSV writer (Arrow) against
``DataFrame.to_csv``, and Parquet for reference; robot.csv (10 float columns) and observations.csv
(4 floats, 2 text ids). Wall and CPU seconds (reads: the best of 3); "x plain" are the ratios to
plain ``pd.read_csv`` (which converts columns on several threads), the target is within 2x.

    nice -n 10 .venv/bin/python benchmarks/bench_io_csv.py [N]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.io.logdir import TABLES, read_table, table_for_writing, validate, write_table
from pedcal.model import Log, SensorExtrinsics, SensorNetwork


def timed(fn, repeat: int = 1):
    """Result, wall and CPU seconds (the best of ``repeat`` runs: other jobs on a shared machine
    only ever add time)."""
    best_w = best_c = np.inf
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        best_w, best_c = min(best_w, time.perf_counter() - w), min(best_c, time.process_time() - c)
    return out, best_w, best_c


def tables(n: int, rng: np.random.Generator) -> dict[str, pd.DataFrame]:
    t = 1.7e9 + np.arange(n) * 0.1
    A = rng.normal(0, [0.05, 0.05, 0.02], (n, 3, 3))
    cov = A @ A.transpose(0, 2, 1) + np.diag([1e-4, 1e-4, 1e-5])
    robot = pd.DataFrame({"t": t, "x": rng.normal(0, 10, n), "y": rng.normal(0, 10, n),
                          "yaw": rng.uniform(-np.pi, np.pi, n), "cov_xx": cov[:, 0, 0], "cov_xy": cov[:, 0, 1],
                          "cov_xyaw": cov[:, 0, 2], "cov_yy": cov[:, 1, 1], "cov_yyaw": cov[:, 1, 2],
                          "cov_yawyaw": cov[:, 2, 2]})
    obs = pd.DataFrame({"t": t, "sensor": rng.choice([f"s{i:02d}" for i in range(12)], n),
                        "track": (np.arange(n) // 50).astype(str), "x": rng.normal(0, 10, n),
                        "y": rng.normal(0, 10, n), "z": 1.35 + rng.normal(0, 0.05, n)})
    return {"robot": table_for_writing(robot, "robot"), "observations": table_for_writing(obs, "observations")}


def main(n: int) -> None:
    rng = np.random.default_rng(0)
    data = tables(n, rng)
    print(f"{n} rows; seconds as wall / cpu")
    print(f"{'table':13s} {'op':30s} {'wall_s':>7s} {'cpu_s':>7s} {'x plain wall':>12s} {'x plain cpu':>11s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, df in data.items():
            csv, pq = Path(tmp) / f"{name}.csv", Path(tmp) / f"{name}.parquet"
            columns, text = TABLES[name]
            _, w_old, c_old = timed(lambda df=df, p=Path(tmp) / "old.csv": df.to_csv(p, index=False))
            _, w_new, c_new = timed(lambda df=df, p=csv: write_table(df, p))
            _, w_pq, c_pq = timed(lambda df=df, p=pq: write_table(df, p))
            _, w_plain, c_plain = timed(lambda p=csv, text=text: pd.read_csv(p, dtype={c: str for c in text}), 3)
            back, w_read, c_read = timed(lambda p=csv, columns=columns, text=text: read_table(p, columns, text), 3)
            _, w_rpq, c_rpq = timed(lambda p=pq, columns=columns, text=text: read_table(p, columns, text), 3)
            exact = all(np.array_equal(back[c].to_numpy(), df[c].to_numpy()) if c not in text
                        else back[c].tolist() == df[c].tolist() for c in columns)
            rows = [("write DataFrame.to_csv", w_old, c_old, False), ("write pedcal CSV (Arrow)", w_new, c_new, False),
                    ("write pedcal Parquet", w_pq, c_pq, False), ("read plain pd.read_csv", w_plain, c_plain, True),
                    ("read pedcal read_table CSV", w_read, c_read, True),
                    ("read pedcal read_table Parquet", w_rpq, c_rpq, True)]
            for op, w, c, ratio in rows:
                ratios = f"{w / w_plain:12.2f} {c / c_plain:11.2f}" if ratio else ""
                print(f"{name:13s} {op:30s} {w:7.2f} {c:7.2f} {ratios}")
            print(f"{name:13s} CSV round trip exact: {exact}")
        sensors = SensorNetwork([SensorExtrinsics(f"s{i:02d}", [i, 0, 2.6], [0, 45, 0]) for i in range(12)])
        log = Log(sensors=sensors, robot=data["robot"], observations=data["observations"])
        _, w, c = timed(lambda: validate(log))
        print(f"{'log':13s} {'validate (in-memory Log)':30s} {w:7.2f} {c:7.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2_000_000)
