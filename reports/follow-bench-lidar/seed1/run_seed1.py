"""Seed 1 of `pedcal follow-bench --trackers paper factorgraph` (the bench's own cases, seed 1 only),
one CSV row per episode, resumable: `python run_seed1.py {ideal|lidar} OUT.csv` from the repository."""
import csv
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd

from pedcal.track.follow_bench import RECORDINGS, bench_cases, run_case

sensing, out = sys.argv[1], Path(sys.argv[2])
cases, tables, _ = bench_cases(Path("../shared/data"), list(RECORDINGS), ["paper", "factorgraph"], 2, 45.0, None)
done = set()
if os.path.exists(out):
    d = pd.read_csv(out, dtype={"target": str})
    done = set(zip(d.recording, d.target, d.tracker, strict=True))
cases = [replace(c, sensing=sensing, lidar=None) for c in cases
         if c.seed == 1 and (c.recording, str(c.target), c.tracker) not in done]
t0, c0 = time.perf_counter(), time.process_time()
with open(out, "a", newline="") as f:
    w = csv.writer(f)
    if not done:
        w.writerow(["recording", "target", "tracker", "seed", "with_target_fraction"])
    for k, c in enumerate(cases, 1):
        r = run_case(c, tables[c.recording])
        w.writerow([c.recording, c.target, c.tracker, c.seed, r.to_dict()["with_target_fraction"]])
        f.flush()
        print(k, len(cases), c.recording, c.target, c.tracker, f"{time.perf_counter() - t0:.0f} s", file=sys.stderr)
print(f"{len(cases)} episodes, {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU",
      file=sys.stderr)
