"""Following benchmark: the trackers over the scripted episodes and the walker scenes, several seeds.

    .venv/bin/python benchmarks/bench_follow.py [--scenarios passing corner crossing crowd recorded]
                                                [--trackers paper lidar-only] [--seeds 5]

Prints one row per scenario x tracker with the means over seeds (target_correct_fraction, id switches,
losses, reacquire time, followed to the end, MOTA, IDF1) and the seconds per run.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from pedcal.track.follow import run_follow


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", nargs="+", default=["passing", "corner", "crossing", "crowd", "recorded"])
    p.add_argument("--trackers", nargs="+", default=["paper", "lidar-only"])
    p.add_argument("--seeds", type=int, default=5)
    args = p.parse_args()
    warnings.simplefilter("ignore")
    print(f"{'scenario':<10} {'tracker':<12} {'seeds':>5} {'correct':>8} {'min':>6} {'switch':>7} {'lost':>5} "
          f"{'reacq_s':>8} {'to_end':>7} {'mota':>6} {'idf1':>6} {'s/run':>6}")
    for sc in args.scenarios:
        for tr in args.trackers:
            rows, t0 = [], time.perf_counter()
            for seed in range(args.seeds):
                rows.append(run_follow(sc, tracker=tr, seed=seed).to_dict())
            dt = (time.perf_counter() - t0) / args.seeds

            def mean(key, rows=rows):
                v = [r[key] for r in rows if r[key] is not None]
                return float(np.mean(v)) if v else float("nan")

            cf = [r["target_correct_fraction"] for r in rows]
            print(f"{sc:<10} {tr:<12} {args.seeds:>5} {np.mean(cf):>8.3f} {np.min(cf):>6.3f} "
                  f"{mean('id_switches'):>7.2f} {mean('lost_episodes'):>5.2f} {mean('max_reacquire_s'):>8.2f} "
                  f"{mean('followed_to_end'):>7.2f} {mean('mota'):>6.3f} {mean('idf1'):>6.3f} {dt:>6.2f}")


if __name__ == "__main__":
    main()
