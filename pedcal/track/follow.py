"""Run a tracker on a simulated following episode and score it (``pedcal follow``).

:func:`run_follow` plays an episode of :mod:`pedcal.sim.follow` frame by frame: sensing from the
robot's true pose, the tracker's step, the robot's controller on the tracker's output. Every frame is
logged; :func:`follow_metrics` scores the target's identity on that log and :func:`mot_metrics`
scores all people (CLEAR MOT, through ``motmetrics``).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from pedcal.follow_types import TrackerOutput
from pedcal.io.atomic import atomic_path, write_text_atomic
from pedcal.sim.follow import (
    FOLLOW_DISTANCE_M,
    FRAME_HZ,
    PERSON_RADIUS_M,
    ROBOT_RADIUS_M,
    TARGET_PERSON_M,
    Episode,
    Planner,
    RobotController,
    in_field_of_view,
    make_episode,
    people_episode,
    to_robot,
    to_world,
)

MATCH_DISTANCE_M = TARGET_PERSON_M   # a track matches a person this close (the simulator's target pick alike)
HIDDEN_HOLD_M = 1.0  # a hidden target counts as held while the tracker's estimate is this close to it
NEAR_M = 3.0  # the robot is "near" the target within this distance


@dataclass(frozen=True)
class FollowMetrics:
    """How well one run followed its target (:func:`follow_metrics`) and tracked everyone (CLEAR MOT).

    Every target figure counts the frames from the tracker's first choice of a target to the end of
    the episode (the *scored frames*). A frame is *with the target* when the person the tracker's
    target track is matched to (``claimed_person``) is the target, or when the target is out of
    sight and the tracker's estimate of it is within ``HIDDEN_HOLD_M`` (1 m) of the truth. A frame
    where the robot lost the target, whether it claims somebody else or nobody, is never with it.
    """

    frames: int
    """Frames in the episode (4 Hz)."""
    with_target_fraction: float
    """The headline: the share of scored frames with the target (0 when no target is ever chosen)."""
    near_fraction: float
    """The share of scored frames with the robot within ``NEAR_M`` (3 m) of the target."""
    median_distance_m: float | None
    """Median robot-to-target distance over the scored frames with the target present."""
    followed_to_end: bool
    """The last frame is with the target."""
    id_switches: int
    """Changes of the claimed person between consecutive frames that claim somebody."""
    lost_episodes: int
    """Frames not with the target right after a frame with it (losses)."""
    mean_reacquire_s: float | None
    """Mean time from a loss to the next frame with the target; a loss never recovered counts until
    the episode's end. None when there is no loss."""
    max_reacquire_s: float | None
    """The longest of those times; None when there is no loss."""
    unrecovered_losses: int
    """Losses after which the target was never with the tracker again (0 or 1)."""
    searching_episodes: int
    """Runs of frames in the tracker state "Searching"."""
    searching_frames: int
    """Frames in the tracker state "Searching"."""
    lost_position_error_m: float | None
    """Median distance of the tracker's target estimate from the truth over the scored frames with
    the target out of sight (frames without an estimate left out); None if there are none."""
    robot_contacts: int | None = None
    """Contacts of the robot's making: runs of consecutive frames in which the robot's disc
    (``ROBOT_RADIUS_M``) overlaps a person's (``PERSON_RADIUS_M``) after a step of its own that began
    or deepened the overlap (it ends nearer the person than standing still would have left it); a
    person walking into a waiting robot is not one (:func:`robot_contact_frames`). None when the log
    holds no contact columns."""
    contacts_per_min: float | None = None
    """``robot_contacts`` per minute of the episode."""
    contact_frame_fraction: float | None = None
    """The share of all frames with a contact of the robot's making."""
    min_clearance_m: float | None = None
    """The least gap between the robot's disc and a person's over the episode (m; negative: they
    overlapped, whoever's doing); None when nobody was ever present."""
    mota: float | None = None
    """CLEAR MOT accuracy over every person in the field of view (``motmetrics``, 0.5 m)."""
    motp: float | None = None
    """CLEAR MOT precision (mean distance of matches, m)."""
    idf1: float | None = None
    """Identity F1 over every person in the field of view."""

    def to_dict(self) -> dict:
        """The metrics in field order (plain Python numbers, None for undefined)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict) -> FollowMetrics:
        return cls(**{f.name: d[f.name] for f in fields(cls) if f.name in d})


METRIC_KEYS = tuple(f.name for f in fields(FollowMetrics))


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


def with_target_frames(log: pd.DataFrame, target_id: str) -> np.ndarray:
    """Per frame of a follow log: the claimed person is the target, or the target is out of sight and
    the tracker's estimate of it is within ``HIDDEN_HOLD_M`` of the truth (``FollowMetrics``)."""
    claimed = log["claimed_person"].to_numpy(dtype=object)
    is_target = np.array([c is not None and not pd.isna(c) and c == target_id for c in claimed], bool)
    visible = log["target_visible"].to_numpy(bool)
    err = np.hypot(log["est_target_x"].to_numpy(float) - log["target_x"].to_numpy(float),
                   log["est_target_y"].to_numpy(float) - log["target_y"].to_numpy(float))
    with np.errstate(invalid="ignore"):
        hidden_held = ~visible & (err <= HIDDEN_HOLD_M)  # NaN (no estimate, target absent) is not held
    return is_target | hidden_held


HELD_BACK_SPEED_MPS = 0.1  # the robot "stands" below this speed over a frame
HELD_BACK_S = (5.0, 2.0)  # held back: standing at least 2 s of the last 5 s, farther than it follows from


def lost_frames(log: pd.DataFrame, target_id: str) -> tuple[np.ndarray, np.ndarray]:
    """(scored, lost) masks of a follow log's frames: scored from the tracker's first choice of a
    target to the end, lost where scored and not with the target (``with_target_frames``)."""
    scored = np.cumsum(log["target_track_id"].notna().to_numpy()) > 0
    return scored, scored & ~with_target_frames(log, target_id)


def loss_causes(log: pd.DataFrame, target_id: str) -> dict[str, int]:
    """Why the scored frames of a follow log that are not with the target (``with_target_frames``)
    are not: ``in_view``, the target in the robot's view and the tracker claiming somebody else or
    nobody; ``held_back``, the target out of view after the robot stood (below
    ``HELD_BACK_SPEED_MPS``) for at least ``HELD_BACK_S[1]`` s of the last ``HELD_BACK_S[0]`` s while
    farther from the target than ``FOLLOW_DISTANCE_M`` + 0.4 m (people in its way); ``out_of_view``,
    the rest (hidden behind people or walls, out of the field of view). Frame counts."""
    _, lost = lost_frames(log, target_id)
    robot = log[["robot_x", "robot_y"]].to_numpy(float)
    speed = np.r_[0.0, np.linalg.norm(np.diff(robot, axis=0), axis=1) * FRAME_HZ]
    dist = np.linalg.norm(robot - log[["target_x", "target_y"]].to_numpy(float), axis=1)
    with np.errstate(invalid="ignore"):
        standing = (speed < HELD_BACK_SPEED_MPS) & (dist > FOLLOW_DISTANCE_M + 0.4)
    window, least = int(round(HELD_BACK_S[0] * FRAME_HZ)), int(round(HELD_BACK_S[1] * FRAME_HZ))
    c = np.r_[0, np.cumsum(standing)]
    k = np.arange(len(log))
    held_back = c[k + 1] - c[np.maximum(k + 1 - window, 0)] >= least
    visible = log["target_visible"].to_numpy(bool)
    return {"in_view": int((lost & visible).sum()), "held_back": int((lost & ~visible & held_back).sum()),
            "out_of_view": int((lost & ~visible & ~held_back).sum())}


def robot_contact_frames(robot_xy_m: np.ndarray, people_xy_m: np.ndarray, robot_radius_m: float = ROBOT_RADIUS_M,
                         person_radius_m: float = PERSON_RADIUS_M) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of robot positions (N, 2) and people positions (N, P, 2; NaN where a person is
    absent): the least gap between the robot's disc and a person's (m, NaN with nobody present), and
    whether the robot's own step into that frame began or deepened an overlap with somebody (the
    overlap there, and the robot nearer that person than at its previous position; never in the
    first frame)."""
    r = np.asarray(robot_xy_m, float).reshape(-1, 2)
    p = np.asarray(people_xy_m, float).reshape(len(r), -1, 2)
    touch = robot_radius_m + person_radius_m
    d = np.linalg.norm(p - r[:, None, :], axis=2)  # (N, P), NaN for absent people
    with np.errstate(invalid="ignore"):
        gap = np.nanmin(np.where(np.isnan(d), np.inf, d), axis=1) - touch if p.shape[1] else np.full(len(r), np.inf)
        gap = np.where(np.isfinite(gap), gap, np.nan)
        caused = np.zeros(len(r), bool)
        if len(r) > 1:
            d_stay = np.linalg.norm(p[1:] - r[:-1, None, :], axis=2)  # had the robot not moved
            caused[1:] = ((d[1:] < touch) & (d[1:] < d_stay)).any(axis=1)
    return gap, caused


def contact_metrics(log: pd.DataFrame) -> dict:
    """``robot_contacts``, ``contacts_per_min``, ``contact_frame_fraction`` and ``min_clearance_m``
    from a log's ``robot_contact`` (bool) and ``clearance_m`` columns (:func:`robot_contact_frames`);
    all None when it has none."""
    keys = ("robot_contacts", "contacts_per_min", "contact_frame_fraction", "min_clearance_m")
    if not {"robot_contact", "clearance_m"} <= set(log.columns) or len(log) == 0:
        return dict.fromkeys(keys)
    caused = log["robot_contact"].to_numpy(bool)
    t = log["t"].to_numpy(float)
    minutes = (t[-1] - t[0] + (t[1] - t[0] if len(t) > 1 else 1.0 / FRAME_HZ)) / 60.0
    gap = log["clearance_m"].to_numpy(float)
    n = _runs(caused)
    return dict(zip(keys, (n, n / minutes, float(caused.mean()),
                           float(np.nanmin(gap)) if np.isfinite(gap).any() else None), strict=True))


def follow_metrics(log: pd.DataFrame, target_id: str) -> dict:
    """The target figures of :class:`FollowMetrics` (all but CLEAR MOT) from a per-frame log with
    columns ``t``, ``robot_x/y``, ``target_visible``, ``state``, ``target_track_id``,
    ``claimed_person``, ``target_x/y`` (NaN when the target is absent) and ``est_target_x/y``, and
    the contact figures from ``robot_contact`` and ``clearance_m`` where it has them.

    ``claimed_person`` is the person the tracker's target track is matched to in that frame: the
    confirmed tracks are assigned one to one to all people present (visible or not; Hungarian on the
    distance, pairs within 0.5 m); None when the tracker names no target or its track matches nobody.
    """
    n = len(log)
    tid = log["target_track_id"].to_numpy()
    claimed = log["claimed_person"].to_numpy(dtype=object)
    claimed_none = pd.isna(claimed)
    t = log["t"].to_numpy(float)
    scored = np.cumsum(~pd.isna(tid)) > 0  # from the first choice of a target to the end
    held = with_target_frames(log, target_id)
    sc_held = held[scored]
    first = int(np.argmax(scored)) if scored.any() else n
    losses = np.flatnonzero(held[first:-1] & ~held[first + 1:]) + first + 1
    reacq, unrecovered = [], 0
    for k in losses:
        nxt = np.flatnonzero(held[k:])
        if len(nxt):
            reacq.append(float(t[k + nxt[0]] - t[k]))
        else:
            reacq.append(float(t[-1] - t[k] + (t[1] - t[0] if n > 1 else 0.0)))  # censored at the end
            unrecovered += 1
    seq = list(claimed[scored & ~claimed_none])
    switches = int(sum(a != b for a, b in zip(seq[:-1], seq[1:], strict=True)))
    searching = log["state"].to_numpy(dtype=object) == "Searching"
    visible = log["target_visible"].to_numpy(bool)
    txy = log[["target_x", "target_y"]].to_numpy(float)
    dist = np.hypot(*(log[["robot_x", "robot_y"]].to_numpy(float) - txy).T)
    present = scored & np.isfinite(dist)
    err = np.hypot(log["est_target_x"].to_numpy(float) - txy[:, 0], log["est_target_y"].to_numpy(float) - txy[:, 1])
    hidden = scored & ~visible & np.isfinite(err)
    return {
        "frames": int(n),
        "with_target_fraction": float(sc_held.mean()) if scored.any() else 0.0,
        "near_fraction": float(np.mean(present[scored] & (np.nan_to_num(dist[scored], nan=np.inf) <= NEAR_M)))
        if scored.any() else 0.0,
        "median_distance_m": float(np.median(dist[present])) if present.any() else None,
        "followed_to_end": bool(held[-1] and scored[-1]) if n else False,
        "id_switches": switches,
        "lost_episodes": int(len(losses)),
        "mean_reacquire_s": float(np.mean(reacq)) if reacq else None,
        "max_reacquire_s": float(np.max(reacq)) if reacq else None,
        "unrecovered_losses": unrecovered,
        "searching_episodes": _runs(searching),
        "searching_frames": int(searching.sum()),
        "lost_position_error_m": float(np.median(err[hidden])) if hidden.any() else None,
        **contact_metrics(log),
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
    """The metrics and the per-frame log of one run."""

    scenario: str
    tracker: str
    seed: int
    metrics: FollowMetrics
    log: pd.DataFrame = field(repr=False)
    notes: str = ""
    target_id: str = "target"
    sensing: str = "ideal"  # "ideal" (the abstract detection model) or "lidar:PRESET" (LIDAR and detector)

    def to_dict(self) -> dict:
        return self.metrics.to_dict()

    def to_dataframe(self) -> pd.DataFrame:
        """The per-frame log (one row per frame; the columns of ``follow_log.parquet``)."""
        return self.log.copy()

    def format_table(self) -> str:
        rows = [f"follow {self.scenario} (tracker {self.tracker}, seed {self.seed}, target {self.target_id}, "
                f"sensing {self.sensing})"]
        for k, v in self.to_dict().items():
            rows.append(f"  {k:<24} {'-' if v is None else (f'{v:.3f}' if isinstance(v, float) else v)}")
        rows.append(f"  with_target_fraction: frames, from the first choice of a target on, where the claimed "
                    f"person is the target or the hidden target's estimate is within {HIDDEN_HOLD_M:g} m")
        return "\n".join(rows)

    def save(self, out_dir: str | Path) -> tuple[Path, Path]:
        """``follow.json`` (metrics and run description) and ``follow_log.parquet``, atomically."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        j = out / "follow.json"
        write_text_atomic(j, json.dumps({"scenario": self.scenario, "tracker": self.tracker, "seed": self.seed,
                                         "target": self.target_id, "sensing": self.sensing, "notes": self.notes,
                                         **self.to_dict()},
                                        indent=2) + "\n")
        p = out / "follow_log.parquet"
        with atomic_path(p) as tmp:
            self.log.to_parquet(tmp, index=False)
        return j, p


def _make_tracker(name: str, episode: Episode):
    from pedcal.track.trackers import make_tracker

    if name == "lidar-only":  # the operator points the target out at the start
        return make_tracker(name, initial_target_xy_world_m=episode.walker(episode.target_id).at(0.0))
    if name == "factorgraph":
        return make_tracker(name, occupancy=episode.occupancy)
    return make_tracker(name)


def perceived_people(episode: Episode, t_s: float, pose_true: np.ndarray, pose_est: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Everyone present at ``t_s`` as the robot perceives them: positions (N, 2) and velocities over
    the last frame (N, 2; zero for somebody who just appeared), where they are relative to the
    robot put in the frame of its estimated pose (recorded walkers do not react to the robot, so
    it must avoid all of them)."""
    people = episode.people_at(t_s)
    xy = np.array([p for _, p in people]).reshape(-1, 2)
    before = [w.at(t_s - 1.0 / FRAME_HZ) for w, _ in people]
    vel = np.array([(p - b) * FRAME_HZ if b is not None else np.zeros(2)
                    for (_, p), b in zip(people, before, strict=True)]).reshape(-1, 2)
    dyaw = float(pose_est[2] - pose_true[2])
    c, s = np.cos(dyaw), np.sin(dyaw)
    return to_world(to_robot(xy, pose_true), pose_est), vel @ np.array([[c, s], [-s, c]])


def run_episode(episode: Episode, tracker: str = "paper", seed: int = 0, progress: bool = False,
                sensing: str = "ideal", lidar: str | None = None) -> FollowResult:
    """Play ``episode`` with the tracker named ``tracker`` (see ``make_tracker``) and score it.

    ``sensing``: ``"ideal"``, the abstract detection model (``pedcal.sim.follow.Sensing``), or
    ``"lidar"``, the simulated LIDAR ``lidar`` (a ``LIDAR_PRESETS`` or ``SENSORS`` name, the FX8 pair by default)
    and the shipped detector every frame (``pedcal.sim.follow_lidar.LidarSensing``)."""
    from pedcal.sim.follow_lidar import DEFAULT_LIDAR, check_sensing, lidar_preset, make_sensing

    check_sensing(sensing, lidar)
    rng = np.random.default_rng(seed)
    if episode.crowd is not None:  # simulated walkers who react to the robot start on their plans
        episode.crowd.reset()
    trk = _make_tracker(tracker, episode)
    sense = make_sensing(sensing, episode, rng, lidar)
    sensing_name = "ideal" if sensing == "ideal" else f"lidar:{lidar_preset(lidar or DEFAULT_LIDAR)}"
    ctrl = RobotController(v_max_mps=episode.robot_max_speed_mps)
    planner = Planner(episode.occupancy) if episode.occupancy is not None else None
    pose = np.asarray(episode.robot_pose0, dtype=float).copy()
    stopped = True
    mot = MotAccumulator()
    rows = []
    person_index = {w.person_id: i for i, w in enumerate(episode.walkers)}  # motmetrics takes numeric ids
    n_frames = int(np.floor(episode.duration_s * FRAME_HZ)) + 1
    everyone_xy = np.full((n_frames, len(episode.walkers), 2), np.nan)  # for the contact figures
    robot_v = np.zeros(2)  # the robot's velocity over the last frame (world frame, m/s)
    for k in range(n_frames):
        t = k / FRAME_HZ
        if episode.crowd is not None:  # they see the robot where it is now and step around it
            episode.crowd.react(t, pose[:2], robot_v)
        people = episode.people_at(t)
        ids = [w.person_id for w, _ in people]
        xy = np.array([p for _, p in people]).reshape(-1, 2)
        everyone_xy[k, [person_index[i] for i in ids]] = xy
        target_xy = next((p for w, p in people if w.person_id == episode.target_id), None)
        frame, vis = sense.frame(t, pose, people, target_xy, stopped)
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
        v, w = ctrl.command(np.asarray(frame.pose_world_robot, float), out, planner,
                            *perceived_people(episode, t, pose, frame.pose_world_robot))
        pose_before = pose
        pose, stopped = ctrl.step(pose, v, w, 1.0 / FRAME_HZ, episode.occupancy)
        robot_v = (pose[:2] - pose_before[:2]) * FRAME_HZ
        if progress and (k % 40 == 0 or k == n_frames - 1):
            logging.getLogger(__name__).info(f"follow {episode.name}: frame {k + 1}/{n_frames} t={t:.1f}s "
                                             f"state={out.state}", extra={"progress": (k + 1, n_frames)})
    log = pd.DataFrame(rows)
    log["clearance_m"], log["robot_contact"] = robot_contact_frames(log[["robot_x", "robot_y"]].to_numpy(float),
                                                                    everyone_xy)
    log["target_track_id"] = log["target_track_id"].astype("Int64")
    log["claimed_person"] = log["claimed_person"].astype(object)
    if getattr(sense, "frame_stats", None):  # the LIDAR's per-frame figures (times, target found)
        log = log.join(pd.DataFrame(sense.frame_stats).drop(columns="t_s").add_prefix("lidar_"))
    metrics = FollowMetrics(**follow_metrics(log, episode.target_id), **mot.summary())
    return FollowResult(episode.name, tracker, seed, metrics, log, episode.notes, episode.target_id, sensing_name)


def read_people(path: str | Path) -> pd.DataFrame:
    """A people table (``t, person, x, y``) from a people CSV or any recording
    ``pedcal.io.pedestrians.read_pedestrians`` recognises (ATC, ETH/UCY, THOR)."""
    from pedcal.io.pedestrians import read_pedestrians

    return read_pedestrians(path)


def run_follow(scenario: str | None = "passing", tracker: str = "factorgraph", seed: int = 0, people_csv=None,
               target_id: str | None = None, progress: bool = False,
               density_per_10m2: float | None = None, sensing: str = "ideal",
               lidar: str | None = None) -> FollowResult:
    """Run the scenario ``scenario`` (``pedcal.sim.follow.SCENARIOS``; ``density_per_10m2`` sets the
    crowd scene's people per 10 m^2), or, with ``people_csv`` (a ``t, person, x, y`` file, a
    recording or such a DataFrame), those trajectories with ``target_id`` carrying the transmitter;
    ``sensing`` and ``lidar`` as :func:`run_episode`'s."""
    from pedcal.io.preflight import check_follow_people
    from pedcal.options import check
    from pedcal.sim.follow_lidar import check_sensing

    check(seed=seed, density_per_10m2=density_per_10m2)
    check_sensing(sensing, lidar)
    if isinstance(people_csv, pd.DataFrame):
        from pedcal.errors import PedcalInputError

        if target_id is None:
            raise PedcalInputError("a people table needs target_id (the person carrying the transmitter)")
        return run_episode(people_episode(check_follow_people(people_csv, target_id), str(target_id)), tracker,
                           seed, progress, sensing, lidar)
    if people_csv is not None:

        episode = people_episode(check_follow_people(people_csv, target_id), str(target_id), people_csv)
    else:
        episode = make_episode(scenario or "passing", seed, density_per_10m2)
    return run_episode(episode, tracker, seed, progress, sensing, lidar)


__all__ = ["METRIC_KEYS", "MATCH_DISTANCE_M", "HIDDEN_HOLD_M", "NEAR_M", "FollowMetrics", "FollowResult",
           "follow_metrics", "with_target_frames", "lost_frames", "loss_causes", "robot_contact_frames",
           "contact_metrics", "perceived_people", "match_people", "MotAccumulator",
           "run_episode", "run_follow", "read_people"]
