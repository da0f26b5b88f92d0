"""Perception in the following loop: step times and with-target, ``--sensing lidar`` against ``ideal``.

    .venv/bin/python benchmarks/bench_follow_lidar.py timing [--people 5 15 30] [--seeds 1] [--lidar fx8]
    .venv/bin/python benchmarks/bench_follow_lidar.py compare [--densities 0.5 1 2] [--seeds 3]
                                                      [--trackers paper factorgraph] [--out DIR]
    .venv/bin/python benchmarks/bench_follow_lidar.py report --crowd DIR --ideal DIR --lidar DIR
    .venv/bin/python benchmarks/bench_follow_lidar.py near [--distances 0.8 1 1.2 1.5 2 3] [--frames 12]
    .venv/bin/python benchmarks/bench_follow_lidar.py losses --people FILE --targets ID [ID ...]

``timing`` plays the crowd scene with N people (the target and N - 1 walkers) with the LIDAR in the
loop and the factor-graph tracker, and prints per frame (4 Hz) the median and 90th percentile of the
raycast (scene build and ``render``), the detector, the tracker's step and their sum, wall and CPU
(``time.process_time``) time, and the people within the LIDAR's reach.

``compare`` runs each crowd density (and ``--scenes`` scripted scene) x seed x tracker with both
sensing modes on the same episode and prints (and with ``--out`` writes ``crowd.csv`` and
``crowd_frames.csv.gz``, the LIDAR runs' follow logs) the with-target fractions side by side, and,
with the LIDAR, how often the detector found the target within 5 m and its detections near nobody
(false) per frame.

``near`` counts the frames in which the detector finds a lone person walking ahead at each distance,
first seen there and after the robot closed in from 1 m farther (the near-range hold).

``losses`` plays recorded targets with both sensing modes and counts, with the LIDAR, why frames lack
the target: out of sight, missed by the detector nearer than 1.1 m or farther, or detected.

``report`` turns ``compare``'s folder and two ``pedcal follow-bench`` folders (``--sensing ideal`` and
``lidar``, same recordings, trackers and seeds) into markdown tables, pairing the bench's episodes.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.sim.follow import FRAME_HZ, Planner, RobotController, crowd_episode, make_episode
from pedcal.sim.follow_lidar import LidarSensing
from pedcal.track.follow import _make_tracker, run_episode

CLOSE_IN_FRAMES = 4  # near: frames the robot follows 1 m farther before closing in


def timing(people: list[int], seeds: int, lidar: str, tracker: str) -> None:
    print(f"per frame, ms (median / 90th percentile); lidar {lidar}, tracker {tracker}, {seeds} seed(s), "
          "crowd scene; the machine was shared")
    print(f"{'people':>6} {'frames':>6} {'in reach':>8} {'raycast':>13} {'detect':>13} {'track':>13} "
          f"{'step':>13} {'step cpu':>13}")
    for n in people:
        rows = []
        for seed in range(seeds):
            ep = crowd_episode(np.random.default_rng(seed), n_walkers=n - 1)
            rng = np.random.default_rng(seed)
            trk = _make_tracker(tracker, ep)
            sense = LidarSensing(ep, rng, lidar)
            ctrl = RobotController(v_max_mps=ep.robot_max_speed_mps)
            planner = Planner(ep.occupancy) if ep.occupancy is not None else None
            pose, stopped = np.asarray(ep.robot_pose0, float).copy(), True
            robot_v = np.zeros(2)  # the robot's velocity over the last frame (world frame, m/s)
            for k in range(int(np.floor(ep.duration_s * FRAME_HZ)) + 1):
                t = k / FRAME_HZ
                ep.crowd.react(t, pose[:2], robot_v)  # the walkers step around the robot, as in run_episode
                people_t = ep.people_at(t)
                target = next((p for w, p in people_t if w.person_id == ep.target_id), None)
                c0, w0 = time.process_time(), time.perf_counter()
                frame, _ = sense.frame(t, pose, people_t, target, stopped)
                w1 = time.perf_counter()
                out = trk.step(frame)
                w2, c2 = time.perf_counter(), time.process_time()
                st = sense.frame_stats[-1]
                rows.append(dict(raycast=st["raycast_s"], detect=st["detect_s"], track=w2 - w1, step=w2 - w0,
                                 cpu=c2 - c0, reach=st["people_in_range"]))
                v, w = ctrl.command(np.asarray(frame.pose_world_robot, float), out, planner)
                pose_before = pose
                pose, stopped = ctrl.step(pose, v, w, 1.0 / FRAME_HZ, ep.occupancy)
                robot_v = (pose[:2] - pose_before[:2]) * FRAME_HZ
        d = pd.DataFrame(rows)

        def q(col, d=d):
            return f"{1e3 * d[col].median():6.1f} /{1e3 * d[col].quantile(0.9):6.1f}"

        print(f"{n:>6} {len(d):>6} {d['reach'].mean():>8.1f} {q('raycast')} {q('detect')} {q('track')} "
              f"{q('step')} {q('cpu')}", flush=True)


def compare(densities: list[float], seeds: int, trackers: list[str], lidar: str, out: Path | None,
            scenes: tuple[str, ...] = ()) -> None:
    rows, frames = [], []
    cases = [(sc, sc, None) for sc in scenes] + [(f"crowd@{d:g}", "crowd", d) for d in densities]
    print(f"{'scene':>10} {'seed':>4} {'tracker':<12} {'ideal':>6} {'lidar':>6} {'diff':>6} {'det/frame':>9} "
          f"{'target found':>12} {'false/frame':>11} {'s lidar':>7}")
    for label, scene, dens in cases:
        for seed in range(seeds):
            for tr in trackers:
                res = {}
                for sensing in ("ideal", "lidar"):
                    ep = make_episode(scene, seed, dens)
                    t0 = time.perf_counter()
                    r = run_episode(ep, tr, seed, sensing=sensing, lidar=lidar if sensing == "lidar" else None)
                    if sensing == "lidar":
                        st = r.log.assign(scene=label, density=dens, seed=seed, tracker=tr)
                        frames.append(st.drop(columns=["claimed_person"]))
                    res[sensing] = (r, time.perf_counter() - t0)
                wi, wl = (res[s][0].metrics.with_target_fraction for s in ("ideal", "lidar"))
                found = st["lidar_target_detected"][st["lidar_target_range_m"] <= 5.0].mean()
                rows.append(dict(scene=label, density=dens, seed=seed, tracker=tr, ideal=wi, lidar=wl, diff=wl - wi,
                                 ideal_det_per_frame=res["ideal"][0].log["n_detections"].mean(),
                                 lidar_det_per_frame=res["lidar"][0].log["n_detections"].mean(),
                                 target_found_within_5m=found,
                                 false_per_frame=st["lidar_false_detections"].mean(), lidar_wall_s=res["lidar"][1]))
                print(f"{label:>10} {seed:>4} {tr:<12} {wi:>6.3f} {wl:>6.3f} {wl - wi:>+6.3f} "
                      f"{rows[-1]['lidar_det_per_frame']:>9.2f} {found:>12.3f} {rows[-1]['false_per_frame']:>11.3f} "
                      f"{res['lidar'][1]:>7.1f}", flush=True)
    d = pd.DataFrame(rows)
    print("\nmedian with-target per scene and tracker (ideal / lidar):")
    for (label, tr), g in d.groupby(["scene", "tracker"], sort=False):
        print(f"  {label} {tr:<12} {g['ideal'].median():.3f} / {g['lidar'].median():.3f} "
              f"(mean difference {g['diff'].mean():+.3f})")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        d.to_csv(out / "crowd.csv", index=False)
        pd.concat(frames).to_csv(out / "crowd_frames.csv.gz", index=False)


def near(distances: list[float], frames: int, lidar: str) -> None:
    """How often the detector finds a lone person walking ahead at a fixed distance from the robot
    (the robot following at the person's 1 m/s, no walls nor clutter): first seen at that distance
    (the classifier alone), and after the robot closed in from 1 m farther (``CLOSE_IN_FRAMES``
    frames 1 m farther, one 0.5 m farther, not counted): near-range detections held by the person
    detected before (``LidarSensing.held_columns``)."""
    from pedcal.sim.follow import Episode, route_walker

    print(f"lone walker ahead, {frames} frames each, lidar {lidar}")
    for dist in distances:
        found = []
        for lead in (0, CLOSE_IN_FRAMES + 1):
            w = route_walker("p", [[dist, 0.0], [dist + 60.0, 0.0]], 1.0)
            ep = Episode("near", [w], "p", np.zeros(3), (frames + lead) / FRAME_HZ, None)
            sense = LidarSensing(ep, np.random.default_rng(1), lidar, clutter_per_10m2=0.0)
            for k in range(frames + lead):
                t = k / FRAME_HZ
                back_m = 0.0 if k >= lead else (1.0 if k < lead - 1 else 0.5)
                sense.frame(t, np.array([t * 1.0 - back_m, 0.0, 0.0]), ep.people_at(t), w.at(t), False)
            st = sense.frame_stats[lead:]
            found.append((sum(s["target_detected"] for s in st), sum(s["near_rule"] for s in st)))
        (cold, _), (warm, rule) = found
        print(f"  {dist:4.1f} m: found in {cold} of {frames} frames first seen there, {warm} of {frames} after "
              f"closing in ({rule} by the near-range hold)", flush=True)


NEAR_M = 1.1  # losses: nearer than this (robot to target centre) the FX8 pair sees a slab of torso


def lidar_loss_causes(log: pd.DataFrame, target_id: str) -> dict:
    """Why the frames of a LIDAR run's follow log lack the target (``with_target_frames`` false,
    from the tracker's first choice on): the target out of sight (``target_visible`` false), in
    sight but missed by the detector nearer than ``NEAR_M`` or farther, or detected (the tracker's
    doing); and the detector's hits in sight, near and far, its false detections per frame and the
    frames the robot spent nearer than ``NEAR_M``."""
    from pedcal.track.follow import lost_frames, with_target_frames

    held = with_target_frames(log, target_id)
    scored, lost = lost_frames(log, target_id)
    vis = log["target_visible"].to_numpy(bool)
    near = log["lidar_target_range_m"].to_numpy(float) < NEAR_M
    det = log["lidar_target_detected"].to_numpy(bool)
    return dict(frames=int(scored.sum()), with_target=float(held[scored].mean()), near_frames=int((vis & near).sum()),
                found_near=int((vis & near & det).sum()), far_frames=int((vis & ~near).sum()),
                found_far=int((vis & ~near & det).sum()), lost=int(lost.sum()), lost_hidden=int((lost & ~vis).sum()),
                lost_missed_near=int((lost & vis & near & ~det).sum()),
                lost_missed_far=int((lost & vis & ~near & ~det).sum()), lost_detected=int((lost & vis & det).sum()),
                false_per_frame=float(log["lidar_false_detections"].mean()),
                held_near=int(log.get("lidar_near_rule", pd.Series(0, index=log.index)).sum()))


def losses(people: Path, targets: list[str], tracker: str, seed: int, lidar: str) -> None:
    """``lidar_loss_causes`` of each target's episode with the LIDAR, beside its with-target with the
    abstract model (same episode, tracker and seed)."""
    from pedcal.sim.follow import people_episode
    from pedcal.track.follow import read_people

    table = read_people(people)
    rows = []
    for t in targets:
        ideal = run_episode(people_episode(table, t, people), tracker, seed).metrics.with_target_fraction
        r = run_episode(people_episode(table, t, people), tracker, seed, sensing="lidar", lidar=lidar)
        rows.append(dict(target=t, ideal=ideal, **lidar_loss_causes(r.log, t)))
        print(pd.DataFrame(rows[-1:]).round(3).to_string(index=False, header=len(rows) == 1), flush=True)
    d = pd.DataFrame(rows)
    tot = d.drop(columns=["target", "ideal", "with_target", "false_per_frame"]).sum()
    print(f"all: {tot['lost']} frames without the target: {tot['lost_missed_near']} missed nearer than {NEAR_M} m, "
          f"{tot['lost_hidden']} out of sight, {tot['lost_missed_far']} missed farther, {tot['lost_detected']} "
          f"detected (the tracker's); detector found the target in sight in {tot['found_near']} of "
          f"{tot['near_frames']} frames nearer than {NEAR_M} m, {tot['found_far']} of {tot['far_frames']} farther; "
          f"{(d['false_per_frame'] * d['frames']).sum() / d['frames'].sum():.4f} false detections per frame")


def report(crowd: Path, ideal: Path, lidar: Path) -> str:
    """Markdown tables of with-target, ideal against LIDAR sensing: the crowd scene (``compare``'s
    ``crowd.csv``) and the real recordings (two ``pedcal follow-bench`` folders, paired by episode)."""
    c = pd.read_csv(crowd / "crowd.csv")
    if "scene" not in c:  # written before the scripted scenes could be compared
        c["scene"] = [f"crowd@{v:g}" for v in c["density"]]
    out = ["| scene (crowd@people per 10 m²) | tracker | seeds | ideal median | LIDAR median | mean LIDAR − ideal "
           "| largest difference | LIDAR false detections / frame |", "|---|---|---|---|---|---|---|---|"]
    for (label, tr), g in c.groupby(["scene", "tracker"], sort=False):
        big = g["diff"].iloc[int(np.argmax(np.abs(g["diff"].to_numpy())))]
        out.append(f"| {label} | {tr} | {len(g)} | {g['ideal'].median():.3f} | {g['lidar'].median():.3f} "
                   f"| {g['diff'].mean():+.3f} | {big:+.3f} | {g['false_per_frame'].mean():.3f} |")
    key = ["recording", "target", "tracker", "seed"]
    e = pd.read_parquet(ideal / "episodes.parquet").merge(pd.read_parquet(lidar / "episodes.parquet"), on=key,
                                                          suffixes=("_ideal", "_lidar"))
    out += ["", "| recording | tracker | episodes | ideal median / p10 | LIDAR median / p10 | mean LIDAR − ideal "
            "| episodes more than 0.05 lower |", "|---|---|---|---|---|---|---|"]
    for (rec, tr), g in e.groupby(["recording", "tracker"], sort=False):
        wi, wl = g["with_target_fraction_ideal"], g["with_target_fraction_lidar"]
        out.append(f"| {rec} | {tr} | {len(g)} | {wi.median():.3f} / {wi.quantile(0.1):.3f} "
                   f"| {wl.median():.3f} / {wl.quantile(0.1):.3f} | {(wl - wi).mean():+.3f} "
                   f"| {int((wl < wi - 0.05).sum())} |")
    return "\n".join(out) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="mode", required=True)
    s = sub.add_parser("timing")
    s.add_argument("--people", nargs="+", type=int, default=[5, 15, 30])
    s.add_argument("--seeds", type=int, default=1)
    s.add_argument("--lidar", default="fx8")
    s.add_argument("--tracker", default="factorgraph")
    s = sub.add_parser("compare")
    s.add_argument("--densities", nargs="*", type=float, default=[0.5, 1.0, 2.0])
    s.add_argument("--scenes", nargs="*", default=[], help="scripted scenes too (passing corner crossing)")
    s.add_argument("--seeds", type=int, default=3)
    s.add_argument("--trackers", nargs="+", default=["paper", "factorgraph"])
    s.add_argument("--lidar", default="fx8")
    s.add_argument("--out", type=Path, default=None)
    s = sub.add_parser("near")
    s.add_argument("--distances", nargs="+", type=float, default=[0.8, 1.0, 1.2, 1.5, 2.0, 3.0])
    s.add_argument("--frames", type=int, default=12)
    s.add_argument("--lidar", default="fx8")
    s = sub.add_parser("losses")
    s.add_argument("--people", type=Path, required=True, help="a recording (pedcal follow --people)")
    s.add_argument("--targets", nargs="+", required=True)
    s.add_argument("--tracker", default="factorgraph")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--lidar", default="fx8")
    s = sub.add_parser("report")
    s.add_argument("--crowd", type=Path, required=True, help="compare's --out folder")
    s.add_argument("--ideal", type=Path, required=True, help="pedcal follow-bench -o folder, --sensing ideal")
    s.add_argument("--lidar", type=Path, required=True, help="the same bench with --sensing lidar")
    args = p.parse_args()
    warnings.simplefilter("ignore")
    if args.mode == "timing":
        timing(args.people, args.seeds, args.lidar, args.tracker)
    elif args.mode == "near":
        near(args.distances, args.frames, args.lidar)
    elif args.mode == "losses":
        losses(args.people, args.targets, args.tracker, args.seed, args.lidar)
    elif args.mode == "report":
        print(report(args.crowd, args.ideal, args.lidar), end="")
    else:
        compare(args.densities, args.seeds, args.trackers, args.lidar, args.out, tuple(args.scenes))


if __name__ == "__main__":
    main()
