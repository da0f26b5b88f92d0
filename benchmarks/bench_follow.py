"""Following benchmark: the trackers over the scripted episodes, the walker scenes and crowd densities.

    .venv/bin/python benchmarks/bench_follow.py [--scenarios passing corner crossing crowd recorded]
                                                [--densities 0.5 1 2] [--trackers paper lidar-only factorgraph]
                                                [--seeds 5]

Prints one row per scenario (``crowd@D``: the crowd scene at D people per 10 m^2) x tracker over the
seeds: median, 10th percentile and minimum of ``with_target_fraction`` (frames holding the target; a
robot that lost it scores those frames as failures), mean ``near_fraction`` (robot within 3 m),
id switches, losses, mean reacquire time (a loss never recovered counts until the end), followed to
the end, MOTA, IDF1, robot-caused contacts per minute and the share of frames with one (over all
the seeds' frames), the least clearance between the robot's disc and a person's, why the frames
without the target are (``pedcal.track.follow.loss_causes``, as shares of all the seeds' frames: the
target in view but not held, out of view after the robot was held back by people in its way, out of
view otherwise), and wall and CPU seconds per run. The real recordings are ``pedcal follow-bench``'s.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from pedcal.track.follow import loss_causes, run_follow


def cases(scenarios: list[str], densities: list[float]) -> list[tuple[str, str, float | None]]:
    """(label, scene, density) for each scenario, then the crowd scene at each density."""
    return [(sc, sc, None) for sc in scenarios] + [(f"crowd@{d:g}", "crowd", d) for d in densities]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", nargs="*", default=["passing", "corner", "crossing", "crowd", "recorded"],
                   help="scripted and walker scenes (none: only the crowd densities)")
    p.add_argument("--densities", nargs="*", type=float, default=[0.5, 1.0, 2.0],
                   help="crowd densities (people per 10 m^2) to add")
    p.add_argument("--trackers", nargs="+", default=["paper", "lidar-only", "factorgraph"])
    p.add_argument("--seeds", type=int, default=5)
    args = p.parse_args()
    warnings.simplefilter("ignore")
    print(f"{'scenario':<10} {'tracker':<12} {'seeds':>5} {'with_med':>8} {'p10':>6} {'min':>6} {'near':>6} "
          f"{'switch':>7} {'lost':>5} {'reacq_s':>8} {'to_end':>7} {'mota':>6} {'idf1':>6} {'cont/min':>8} "
          f"{'cont_fr%':>8} {'clear_m':>7} {'view%':>6} {'back%':>6} {'hid%':>6} {'s/run':>6} {'cpu/run':>7}")
    for label, sc, dens in cases(args.scenarios, args.densities):
        for tr in args.trackers:
            rows, causes, t0, c0 = [], [], time.perf_counter(), time.process_time()
            for seed in range(args.seeds):
                res = run_follow(sc, tracker=tr, seed=seed, density_per_10m2=dens)
                rows.append(res.to_dict())
                causes.append(loss_causes(res.log, res.target_id))
            dt = (time.perf_counter() - t0) / args.seeds
            dc = (time.process_time() - c0) / args.seeds

            def mean(key, rows=rows):
                v = [r[key] for r in rows if r[key] is not None]
                return float(np.mean(v)) if v else float("nan")

            w = [r["with_target_fraction"] for r in rows]
            frames = np.array([r["frames"] for r in rows], float)
            contacts = sum(r["robot_contacts"] for r in rows)
            contact_frames = np.sum([r["contact_frame_fraction"] for r in rows] * frames) / frames.sum()
            clear = min((r["min_clearance_m"] for r in rows if r["min_clearance_m"] is not None), default=np.nan)
            cause = {k: 100 * sum(c[k] for c in causes) / frames.sum() for k in ("in_view", "held_back", "out_of_view")}
            print(f"{label:<10} {tr:<12} {args.seeds:>5} {np.median(w):>8.3f} {np.percentile(w, 10):>6.3f} "
                  f"{np.min(w):>6.3f} {mean('near_fraction'):>6.3f} {mean('id_switches'):>7.2f} "
                  f"{mean('lost_episodes'):>5.2f} {mean('mean_reacquire_s'):>8.2f} {mean('followed_to_end'):>7.2f} "
                  f"{mean('mota'):>6.3f} {mean('idf1'):>6.3f} {contacts / (frames.sum() / 4.0 / 60.0):>8.2f} "
                  f"{100 * contact_frames:>8.2f} {clear:>7.2f} {cause['in_view']:>6.1f} {cause['held_back']:>6.1f} "
                  f"{cause['out_of_view']:>6.1f} {dt:>6.2f} {dc:>7.2f}", flush=True)


if __name__ == "__main__":
    main()
