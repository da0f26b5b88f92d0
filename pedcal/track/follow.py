"""Run a tracker on a simulated following episode and score it (``pedcal follow``).

:func:`run_follow` plays an episode of :mod:`pedcal.sim.follow` frame by frame: sensing from the
robot's true pose, the tracker's step, the robot's controller on the tracker's output. Every frame is
logged; :func:`follow_metrics` scores the target's identity on that log and :func:`mot_metrics`
scores all people (CLEAR MOT, through ``motmetrics``).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from pedcal.io.atomic import atomic_path, write_text_atomic
from pedcal.sim.follow import (
    FRAME_HZ,
    Episode,
    Planner,
    RobotController,
    Sensing,
    in_field_of_view,
    make_episode,
    people_episode,
    to_robot,
)
from pedcal.track.types import TrackerOutput

MATCH_DISTANCE_M = 0.5
METRIC_KEYS = ("frames", "target_correct_fraction", "id_switches", "lost_episodes", "searching_episodes",
               "searching_frames", "mean_reacquire_s", "max_reacquire_s", "followed_to_end",
               "lost_position_error_m", "mota", "motp", "idf1")


def match_people(people_xy_m: np.ndarray, tracks_xy_m: np.ndarray, max_m: float = MATCH_DISTANCE_M
                 ) -> list[tuple[int, int]]:
    """One-to-one (person, track) pairs minimizing the summed distance, pairs within ``max_m`` only."""
    if len(people_xy_m) == 0 or len(tracks_xy_m) == 0:
        return []
    d = np.linalg.norm(people_xy_m[:, None, :] - tracks_xy_m[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.where(d <= max_m, d, 1e6))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if d[r, c] <= max_m]


def _runs(mask: np.ndarray) -> int:
    """Number of maximal runs of True."""
    m = np.asarray(mask, bool)
    return int(np.sum(m[1:] & ~m[:-1]) + (m[0] if len(m) else 0))


def follow_metrics(log: pd.DataFrame, target_id: str) -> dict:
    """The target's identity metrics of a per-frame log (columns ``t``, ``target_visible``,
    ``state``, ``target_track_id``, ``claimed_person``, ``target_x/y``, ``est_target_x/y``).

    ``claimed_person`` is the person the tracker's target track is matched to in that frame: the
    confirmed tracks are assigned one to one to all people present (visible or not; Hungarian on the
    distance, pairs within 0.5 m); None when the tracker names no target or its track matches nobody.

    - ``target_correct_fraction``: over the frames from the tracker's first choice of a target on, the
      share of frames where, with the target in view (in the field of view, not occluded), the
      claimed person is the target; and with the target out of sight, the claimed person is not
      somebody else (claiming nobody, or a track still sitting on the hidden target, is correct).
      0 when the tracker never chooses a target.
    - holding the target: the claimed person is the target, or the target is out of sight, the
      tracker claims nobody and keeps the track id it last held the target with (a coasting filter).
    - a loss is a frame not holding the target after a frame holding it; ``lost_episodes`` counts
      them; the reacquire time is from the loss frame to the next frame holding the target
      (``mean_reacquire_s``, ``max_reacquire_s`` over the losses recovered; None if none).
    - ``id_switches``: changes of the claimed person between consecutive frames that claim someone.
    - ``searching_episodes`` / ``searching_frames``: runs and frames in the tracker state "Searching".
    - ``followed_to_end``: holding the target in the last frame.
    - ``lost_position_error_m``: median distance of the tracker's target estimate from the truth over
      the frames (after the first choice) with the target out of sight; None if there are none.
    """
    n = len(log)
    tid = log["target_track_id"].to_numpy()
    has_tid = ~pd.isna(tid)
    claimed = log["claimed_person"].to_numpy(dtype=object)
    claimed_none = pd.isna(claimed)
    visible = log["target_visible"].to_numpy(bool)
    t = log["t"].to_numpy(float)
    is_target = np.array([c == target_id for c in claimed], bool) & ~claimed_none
    started = np.cumsum(has_tid) > 0
    correct = np.where(visible, is_target, claimed_none | is_target)
    holding = np.zeros(n, bool)
    last_id = None
    for k in range(n):
        if is_target[k]:
            holding[k], last_id = True, tid[k]
        elif not visible[k] and claimed_none[k] and has_tid[k] and tid[k] == last_id:
            holding[k] = True
    losses = np.flatnonzero(holding[:-1] & ~holding[1:]) + 1
    reacq = []
    for k in losses:
        nxt = np.flatnonzero(holding[k:])
        if len(nxt):
            reacq.append(float(t[k + nxt[0]] - t[k]))
    seq = [c for c in claimed[~claimed_none]]
    switches = int(sum(a != b for a, b in zip(seq[:-1], seq[1:], strict=True)))
    searching = log["state"].to_numpy(dtype=object) == "Searching"
    hidden = started & ~visible & log["est_target_x"].notna().to_numpy() & log["target_x"].notna().to_numpy()
    err = np.hypot(log["est_target_x"].to_numpy(float) - log["target_x"].to_numpy(float),
                   log["est_target_y"].to_numpy(float) - log["target_y"].to_numpy(float))
    return {
        "frames": int(n),
        "target_correct_fraction": float(correct[started].mean()) if started.any() else 0.0,
        "id_switches": switches,
        "lost_episodes": int(len(losses)),
        "searching_episodes": _runs(searching),
        "searching_frames": int(searching.sum()),
        "mean_reacquire_s": float(np.mean(reacq)) if reacq else None,
        "max_reacquire_s": float(np.max(reacq)) if reacq else None,
        "followed_to_end": bool(holding[-1]) if n else False,
        "lost_position_error_m": float(np.median(err[hidden])) if hidden.any() else None,
    }


class MotAccumulator:
    """CLEAR MOT over all people in the field of view (``motmetrics``, Euclidean distance, 0.5 m)."""

    def __init__(self):
        import motmetrics as mm

        self.mm = mm
        self.acc = mm.MOTAccumulator(auto_id=True)

    def update(self, gt_ids: list[int], gt_xy_m: np.ndarray, hyp_ids: list[int], hyp_xy_m: np.ndarray) -> None:
        d = np.linalg.norm(gt_xy_m.reshape(-1, 1, 2) - hyp_xy_m.reshape(1, -1, 2), axis=2)
        self.acc.update(gt_ids, hyp_ids, np.where(d <= MATCH_DISTANCE_M, d, np.nan))

    def summary(self) -> dict:
        res = self.mm.metrics.create().compute(self.acc, metrics=["mota", "motp", "idf1"], name="all")
        out = {}
        for k in ("mota", "motp", "idf1"):
            v = float(res[k].iloc[0])
            out[k] = None if not np.isfinite(v) else v
        return out


@dataclass
class FollowResult:
    """Metrics (``METRIC_KEYS``) and the per-frame log of one run."""

    scenario: str
    tracker: str
    seed: int
    metrics: dict
    log: pd.DataFrame = field(repr=False)
    notes: str = ""

    def to_dict(self) -> dict:
        return {k: self.metrics[k] for k in METRIC_KEYS}

    def format_table(self) -> str:
        rows = [f"follow {self.scenario} (tracker {self.tracker}, seed {self.seed})"]
        for k in METRIC_KEYS:
            v = self.metrics[k]
            rows.append(f"  {k:<24} {'-' if v is None else (f'{v:.3f}' if isinstance(v, float) else v)}")
        return "\n".join(rows)

    def save(self, out_dir: str | Path) -> tuple[Path, Path]:
        """``follow.json`` (metrics and run description) and ``follow_log.parquet``, atomically."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        j = out / "follow.json"
        write_text_atomic(j, json.dumps({"scenario": self.scenario, "tracker": self.tracker, "seed": self.seed,
                                         "notes": self.notes, **self.to_dict()}, indent=2) + "\n")
        p = out / "follow_log.parquet"
        with atomic_path(p) as tmp:
            self.log.to_parquet(tmp, index=False)
        return j, p


def _make_tracker(name: str, episode: Episode):
    from pedcal.track.tracker import make_tracker

    if name == "lidar-only":  # the operator points the target out at the start
        return make_tracker(name, initial_target_xy_world_m=episode.walker(episode.target_id).at(0.0))
    if name == "factorgraph":
        return make_tracker(name, occupancy=episode.occupancy)
    return make_tracker(name)


def run_episode(episode: Episode, tracker: str = "paper", seed: int = 0, progress: bool = False) -> FollowResult:
    """Play ``episode`` with the tracker named ``tracker`` (see ``make_tracker``) and score it."""
    rng = np.random.default_rng(seed)
    trk = _make_tracker(tracker, episode)
    sensing = Sensing(episode.occupancy, rng)
    ctrl = RobotController()
    planner = Planner(episode.occupancy) if episode.occupancy is not None else None
    pose = np.asarray(episode.robot_pose0, dtype=float).copy()
    stopped = True
    mot = MotAccumulator()
    rows = []
    person_index = {w.person_id: i for i, w in enumerate(episode.walkers)}  # motmetrics takes numeric ids
    n_frames = int(np.floor(episode.duration_s * FRAME_HZ)) + 1
    for k in range(n_frames):
        t = k / FRAME_HZ
        people = episode.people_at(t)
        ids = [w.person_id for w, _ in people]
        xy = np.array([p for _, p in people]).reshape(-1, 2)
        target_xy = next((p for w, p in people if w.person_id == episode.target_id), None)
        frame, vis = sensing.frame(t, pose, people, target_xy, stopped)
        out: TrackerOutput = trk.step(frame)
        tr_ids = [e.track_id for e in out.tracks]
        tr_xy = np.array([e.xy_world_m for e in out.tracks]).reshape(-1, 2)
        pairs = match_people(xy, tr_xy)
        person_of_track = {tr_ids[c]: ids[r] for r, c in pairs}
        in_fov = in_field_of_view(to_robot(tr_xy, pose)) if len(tr_xy) else np.zeros(0, bool)
        mot.update([person_index[i] for i, v in zip(ids, vis, strict=True) if v], xy[vis],
                   [i for i, f in zip(tr_ids, in_fov, strict=True) if f], tr_xy[in_fov])
        est_t = out.target_xy_world_m
        tvis = bool(vis[ids.index(episode.target_id)]) if target_xy is not None else False
        rows.append({"t": t, "robot_x": pose[0], "robot_y": pose[1], "robot_yaw": pose[2],
                     "est_x": frame.pose_world_robot[0], "est_y": frame.pose_world_robot[1],
                     "est_yaw": frame.pose_world_robot[2],
                     "target_x": np.nan if target_xy is None else target_xy[0],
                     "target_y": np.nan if target_xy is None else target_xy[1],
                     "target_visible": tvis, "n_detections": len(frame.detections), "n_espar": len(frame.espar),
                     "state": out.state, "target_track_id": out.target_track_id,
                     "claimed_person": person_of_track.get(out.target_track_id),
                     "est_target_x": np.nan if est_t is None else float(est_t[0]),
                     "est_target_y": np.nan if est_t is None else float(est_t[1]),
                     "stop_robot": bool(out.stop_robot)})
        v, w = ctrl.command(np.asarray(frame.pose_world_robot, float), out, planner)
        pose, stopped = ctrl.step(pose, v, w, 1.0 / FRAME_HZ, episode.occupancy)
        if progress and (k % 40 == 0 or k == n_frames - 1):
            logging.getLogger(__name__).info(f"follow {episode.name}: frame {k + 1}/{n_frames} t={t:.1f}s "
                                             f"state={out.state}", extra={"progress": (k + 1, n_frames)})
    log = pd.DataFrame(rows)
    log["target_track_id"] = log["target_track_id"].astype("Int64")
    log["claimed_person"] = log["claimed_person"].astype(object)
    metrics = {**follow_metrics(log, episode.target_id), **mot.summary()}
    return FollowResult(episode.name, tracker, seed, metrics, log, episode.notes)


def run_follow(scenario: str | None = "passing", tracker: str = "paper", seed: int = 0, people_csv=None,
               target_id: str | None = None, progress: bool = False) -> FollowResult:
    """Run the scenario ``scenario`` (``pedcal.sim.follow.SCENARIOS``), or, with ``people_csv`` (a
    ``t, person, x, y`` file or such a DataFrame), those trajectories with ``target_id`` carrying
    the transmitter."""
    if isinstance(people_csv, pd.DataFrame):
        from pedcal.errors import PedcalInputError

        if target_id is None:
            raise PedcalInputError("a people table needs target_id (the person carrying the transmitter)")
        return run_episode(people_episode(people_csv, str(target_id)), tracker, seed, progress)
    if people_csv is not None:
        from pedcal.io.preflight import check_follow_people

        episode = people_episode(check_follow_people(people_csv, target_id), str(target_id), people_csv)
    else:
        episode = make_episode(scenario or "passing", seed)
    return run_episode(episode, tracker, seed, progress)


__all__ = ["METRIC_KEYS", "MATCH_DISTANCE_M", "FollowResult", "follow_metrics", "match_people", "MotAccumulator",
           "run_episode", "run_follow"]
