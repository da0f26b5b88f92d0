"""Time per frame of the trackers with 20 people in view (target: <= 20 ms per frame at 30 people).

Twenty people walk at constant velocity around a robot standing at the origin; every frame (4 Hz)
carries their detections (50 mm noise, per-person reflectance histograms) and the antennas'
readings of the target (``EsparSimulator``, 2 Hz per antenna). The paper tracker's Searching state
(the existence grid) is timed on its own, per grid update of one frame's readings.

    .venv/bin/python benchmarks/bench_tracking.py [--people 20] [--frames 400] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pedcal.follow_types import FollowFrame, PersonDetection
from pedcal.sim.espar import EsparParams, EsparSimulator
from pedcal.track.existence_grid import ExistenceGrid
from pedcal.track.trackers import make_tracker

DT_S = 0.25
N_BINS = 16


def frames(n_people: int, n_frames: int, seed: int) -> list[FollowFrame]:
    rng = np.random.default_rng(seed)
    start = rng.uniform(-6, 6, (n_people, 2))
    start[0] = [2.0, 0.0]
    vel = rng.normal(0, 0.5, (n_people, 2))
    hists = rng.dirichlet(np.ones(N_BINS), n_people)
    sim = EsparSimulator(EsparParams(), np.random.default_rng(seed + 1))
    out = []
    for k in range(1, n_frames + 1):
        t = k * DT_S
        # Walk inside a 12 m square, bouncing off its sides.
        xy = np.abs(np.mod(start + vel * t + 6, 24) - 12) - 6
        dets = tuple(PersonDetection(xy[i] + rng.normal(0, 0.05, 2), 1.7, 0.9,
                                     np.clip(hists[i] + rng.normal(0, 0.01, N_BINS), 0, None))
                     for i in range(n_people))
        out.append(FollowFrame(t, np.zeros(3), np.diag([1e-4, 1e-4, 1e-5]), dets,
                               sim.readings(t - DT_S, t, xy[0]), False))
    return out


def time_tracker(name: str, fs: list[FollowFrame]) -> tuple[np.ndarray, np.ndarray]:
    """Wall and CPU milliseconds of each frame's step (the CPU figure is what a shared machine's
    other jobs cannot inflate)."""
    tracker = make_tracker(name)
    ms, cpu = np.empty(len(fs)), np.empty(len(fs))
    for i, f in enumerate(fs):
        t0, c0 = time.perf_counter(), time.process_time()
        tracker.step(f)
        ms[i], cpu[i] = 1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)
    return ms, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--people", type=int, default=20)
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    fs = frames(a.people, a.frames, a.seed)
    print(f"{a.people} people, {a.frames} frames at {1 / DT_S:.0f} Hz (seed {a.seed})")
    for name in ("paper", "lidar-only", "factorgraph"):
        ms, cpu = (a[10:] for a in time_tracker(name, fs))  # after the filters are confirmed
        print(f"  {name:11s} per frame: median {np.median(ms):.2f} ms, p90 {np.percentile(ms, 90):.2f} ms, "
              f"max {ms.max():.2f} ms wall; CPU median {np.median(cpu):.2f} ms, p90 {np.percentile(cpu, 90):.2f} ms")
    grid = ExistenceGrid(np.zeros(2), half_size_m=8.0, cell_m=0.25)
    readings = [f.espar for f in fs if f.espar]
    ms = np.empty(len(readings))
    for i, r in enumerate(readings):
        t0 = time.perf_counter()
        grid.add(r, np.zeros(3))
        ms[i] = 1e3 * (time.perf_counter() - t0)
    print(f"  existence grid ({grid.shape[0]}x{grid.shape[1]} cells) per frame's readings: "
          f"median {np.median(ms):.2f} ms, p90 {np.percentile(ms, 90):.2f} ms")


if __name__ == "__main__":
    main()
