"""Every real recording as a following test bench (``pedcal follow-bench``).

Each person of a recording present at least ``min_duration_s`` (45 s by default) carries the
transmitter in turn; the robot follows them among the recording's other people
(``pedcal.sim.follow.people_episode``) with each tracker and seed. The bench reports, per
recording and tracker, the distribution of ``with_target_fraction`` (median, 10th percentile,
worst episode), the other target figures, the command that replays the worst episode and a plot
of it: robot path, target path, and who the tracker claimed when.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.io.atomic import atomic_path, write_text_atomic
from pedcal.options import check
from pedcal.sim.follow import FRAME_HZ
from pedcal.track.follow import METRIC_KEYS, FollowResult, read_people, run_episode

log = logging.getLogger(__name__)

# The shared real recordings (ATC, ETH, HOTEL, ZARA, THOR), relative to the data folder.
RECORDINGS = ("atc/atc-1024-9_test.csv", "atc/atc-1024-10_test.csv", "eth_ucy/biwi_eth.txt",
              "eth_ucy/biwi_hotel.txt", "eth_ucy/crowds_zara01.txt", "thor/exp-1-run-2.csv")
DEFAULT_TRACKERS = ("paper", "lidar-only", "factorgraph")
MIN_DURATION_S = 45.0


@dataclass(frozen=True)
class BenchCase:
    """One episode of the bench: a recording, its target, a tracker and a seed."""

    recording: str  # path relative to the data folder
    path: Path
    target: str
    duration_s: float
    tracker: str
    seed: int
    sensing: str = "ideal"  # "ideal" or "lidar" (``run_episode``'s)
    lidar: str | None = None  # with "lidar": the LIDAR preset (default the FX8 pair)

    def replay_command(self, out_dir: str = "replay") -> str:
        """The command that plays this episode again and saves its log."""
        sensing = "" if self.sensing == "ideal" else f" --sensing {self.sensing}" + \
            (f" --lidar {self.lidar}" if self.lidar else "")
        return (f"pedcal follow --people {self.path.as_posix()} --target {self.target} --tracker {self.tracker} "
                f"--seed {self.seed}{sensing} -o {out_dir}")


def eligible_targets(people: pd.DataFrame, min_duration_s: float = MIN_DURATION_S,
                     max_targets: int | None = None) -> pd.DataFrame:
    """The people present at least ``min_duration_s`` (``candidate_targets``), the longest first,
    at most ``max_targets`` of them."""
    from pedcal.sim.follow import candidate_targets

    c = candidate_targets(people, min_duration_s)
    return c if max_targets is None else c.head(max_targets)


def bench_cases(data_dir: Path, files=RECORDINGS, trackers=DEFAULT_TRACKERS, seeds: int = 3,
                min_duration_s: float = MIN_DURATION_S, max_targets: int | None = None
                ) -> tuple[list[BenchCase], dict[str, pd.DataFrame], pd.DataFrame]:
    """The bench's episodes; the people table of each recording; one row per recording with its
    people, eligible targets and the longest presence (for recordings without eligible targets)."""
    cases, tables, rows = [], {}, []
    for rec in files:
        path = Path(data_dir) / rec
        if not path.is_file():
            raise PedcalInputError("recording not found under the data folder", path=path)
        people = read_people(path)
        tables[rec] = people
        targets = eligible_targets(people, min_duration_s, max_targets)
        longest = float(people.groupby("person")["t"].agg(lambda t: t.max() - t.min()).max())
        rows.append(dict(recording=rec, people=int(people["person"].nunique()), eligible=len(targets),
                         longest_s=longest))
        for r in targets.itertuples():
            for tracker in trackers:
                for seed in range(seeds):
                    cases.append(BenchCase(rec, path, str(r.person), float(r.duration_s), tracker, seed))
    return cases, tables, pd.DataFrame(rows)


def run_case(case: BenchCase, people: pd.DataFrame) -> FollowResult:
    from pedcal.sim.follow import people_episode

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_episode(people_episode(people, case.target, case.path), case.tracker, case.seed,
                           sensing=case.sensing, lidar=case.lidar)


def summarize(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per recording and tracker: episodes, median, 10th percentile and minimum of
    ``with_target_fraction``; median ``near_fraction``; share followed to the end; mean of the
    episodes' mean reacquire times; robot-caused contacts (their number, per minute and the share
    of frames with one, over all the episodes' frames) and the least clearance of any episode; the
    worst episode (lowest ``with_target_fraction``)."""
    rows = []
    for (rec, tracker), d in episodes.groupby(["recording", "tracker"], sort=False):
        w = d["with_target_fraction"].to_numpy(float)
        worst = d.iloc[int(np.argmin(w))]
        reacq = d["mean_reacquire_s"].astype(float)
        frames = d["frames"].to_numpy(float)
        contact_frames = float(np.sum(d["contact_frame_fraction"].to_numpy(float) * frames) / frames.sum())
        rows.append(dict(recording=rec, tracker=tracker, episodes=len(d), targets=d["target"].nunique(),
                         median=float(np.median(w)), p10=float(np.percentile(w, 10)), worst=float(w.min()),
                         near_median=float(d["near_fraction"].median()),
                         to_end=float(d["followed_to_end"].astype(float).mean()),
                         id_switches=float(d["id_switches"].mean()),
                         mean_reacquire_s=float(reacq.mean()) if reacq.notna().any() else None,
                         robot_contacts=int(d["robot_contacts"].sum()),
                         contacts_per_min=float(d["robot_contacts"].sum() / (frames.sum() / FRAME_HZ / 60.0)),
                         contact_frames=contact_frames, min_clearance_m=float(d["min_clearance_m"].min()),
                         worst_target=str(worst["target"]), worst_seed=int(worst["seed"]),
                         worst_command=str(worst["replay"])))
    return pd.DataFrame(rows)


def plot_episode(res: FollowResult, title: str):
    """Robot path, target path and, along the target path, who the tracker claimed: the target
    (green), somebody else (red), nobody while the hidden target's estimate is within 1 m (blue
    crosses), nobody otherwise (grey)."""
    from pedcal.plotting import new_figure
    from pedcal.track.follow import with_target_frames

    log = res.log
    fig = new_figure(9.0, 4.5)
    ax, ax_t = fig.subplots(1, 2, width_ratios=[1.2, 1.0])
    ax.plot(log["target_x"], log["target_y"], color="0.3", lw=1, label="target")
    ax.plot(log["robot_x"], log["robot_y"], color="#1f77b4", lw=1.5, label="robot")
    claimed = log["claimed_person"].to_numpy(dtype=object)
    is_t = np.array([c == res.target_id for c in claimed], bool)
    other = ~pd.isna(claimed) & ~is_t
    held = with_target_frames(log, res.target_id)
    kinds = [(is_t, "#2ca02c", "o", "claims the target"), (other, "#d62728", "o", "claims somebody else"),
             (held & ~is_t, "#17becf", "x", "hidden target held (< 1 m)"),
             (~is_t & ~other & ~held, "0.6", ".", "lost")]
    for mask, col, mk, lab in kinds:
        if mask.any():
            ax.scatter(log["target_x"][mask], log["target_y"][mask], s=9, color=col, marker=mk, label=lab, zorder=3)
    ax.scatter([log["robot_x"].iloc[0]], [log["robot_y"].iloc[0]], marker="s", color="#1f77b4", zorder=4)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=7, loc="best")
    t = log["t"].to_numpy(float)
    dist = np.hypot(log["robot_x"] - log["target_x"], log["robot_y"] - log["target_y"])
    ax_t.plot(t, dist, color="#1f77b4", lw=1, label="robot to target (m)")
    for mask, col, _, _lab in kinds:
        ax_t.scatter(t[mask], np.full(mask.sum(), -0.4), s=6, color=col, marker="|")
    ax_t.axhline(3.0, color="0.7", lw=0.8, ls="--")
    ax_t.set_xlabel("t (s)")
    ax_t.set_ylabel("robot to target (m); bar: claimed")
    ax.set_title(title, fontsize=8)
    return fig


def _fmt(v, nd=3) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{nd}f}"


def bench_markdown(summary: pd.DataFrame, recordings: pd.DataFrame, config: dict) -> str:
    out = ["# Following on every real recording", "",
           f"`{config['command']}`", "",
           f"Each person present at least {config['min_duration_s']:g} s is the target in turn, seeds "
           f"0–{config['seeds'] - 1}. *with target* is `with_target_fraction`: over the frames from the first "
           "choice of a target to the end, the share where the claimed person is the target or the target is "
           "out of sight and the tracker's estimate of it is within 1 m (a robot that lost the target scores "
           "those frames as failures). *near* is the median share of frames with the robot within 3 m of the "
           "target; *reacquire* the mean of the episodes' mean reacquire times (a loss never recovered counts "
           "until the end). *contacts*: the robot's disc overlapping a person's after a step of its own that began "
           "or deepened the overlap (a person walking into a waiting robot is not one), per minute and as the "
           "share of all frames; *clearance* the least gap between the robot's disc and a person's in any "
           "episode (negative: they overlapped, whoever's doing).", "",
           "| recording | people | eligible targets | longest presence (s) |", "|---|---|---|---|"]
    for r in recordings.itertuples():
        out.append(f"| {r.recording} | {r.people} | {r.eligible} | {r.longest_s:.1f} |")
    out += ["", "| recording | tracker | episodes | median | p10 | worst | near | to end | id switches "
            "| reacquire (s) | contacts / min | contact frames | clearance (m) | worst episode |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary.itertuples():
        fig = f"figures/worst_{_slug(r.recording)}_{r.tracker}.png"
        out.append(f"| {r.recording} | {r.tracker} | {r.episodes} | {r.median:.3f} | {r.p10:.3f} | {r.worst:.3f} "
                   f"| {r.near_median:.3f} | {r.to_end:.2f} | {r.id_switches:.1f} | {_fmt(r.mean_reacquire_s, 2)} "
                   f"| {r.contacts_per_min:.2f} | {100 * r.contact_frames:.2f} % | {_fmt(r.min_clearance_m, 2)} "
                   f"| [{r.worst_target} seed {r.worst_seed}]({fig}): `{r.worst_command}` |")
    return "\n".join(out) + "\n"


def _slug(rec: str) -> str:
    return Path(rec).stem.replace("-", "_")


def run_follow_bench(data_dir: str | Path | None = None, out_dir: str | Path = "follow-bench", *,
                     trackers=None, seeds: int = 3, min_duration_s: float = MIN_DURATION_S,
                     max_targets: int | None = None, files=None, progress: bool = True,
                     sensing: str = "ideal", lidar: str | None = None) -> Path:
    """Run the bench and write ``episodes.parquet`` (one row per episode: metrics and replay
    command), ``summary.csv``, ``bench.md`` and the worst episodes' plots under ``figures/``, all
    atomically. Returns the path of ``bench.md``. ``sensing`` / ``lidar``: the detections of every
    episode (``run_episode``'s: the abstract model, or the simulated LIDAR and the detector)."""
    from dataclasses import replace

    from pedcal.plotting import save_png
    from pedcal.sim.follow_lidar import check_sensing
    from pedcal.sim.walkers import SHARED_DATA
    from pedcal.track.trackers import TRACKERS

    check_sensing(sensing, lidar)
    data_dir = Path(data_dir) if data_dir is not None else SHARED_DATA
    if not data_dir.is_dir():
        raise PedcalInputError("recordings folder not found (give --data-dir)", path=data_dir)
    trackers = list(trackers or DEFAULT_TRACKERS)
    for name in trackers:
        if name not in TRACKERS:
            raise PedcalInputError(f"--trackers: unknown tracker {name!r}; expected one of {', '.join(TRACKERS)}")
    check(seeds=seeds, min_duration_s=min_duration_s, max_targets=max_targets)   # pedcal.options' domains
    if seeds < 1:
        raise PedcalInputError(f"--seeds {seeds}: expected at least 1")
    files = list(files or RECORDINGS)
    cases, tables, recordings = bench_cases(data_dir, files, trackers, seeds, min_duration_s, max_targets)
    cases = [replace(c, sensing=sensing, lidar=lidar) for c in cases]
    if not cases:       # an empty bench is written, but not in silence
        warnings.warn(f"no episode to run: no person is present for --min-duration {min_duration_s:g} s in any "
                      "recording (longest: " + ", ".join(f"{r.recording} {r.longest_s:.1f} s"
                                                         for r in recordings.itertuples()) + ")",
                      DegenerateDataWarning, stacklevel=2)
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    rows, worst = [], {}
    t0, cpu0 = time.perf_counter(), time.process_time()
    for k, case in enumerate(cases, 1):
        res = run_case(case, tables[case.recording])
        m = res.to_dict()
        rows.append(dict(recording=case.recording, target=case.target, duration_s=case.duration_s,
                         tracker=case.tracker, seed=case.seed, sensing=res.sensing, **m,
                         replay=case.replay_command()))
        key = (case.recording, case.tracker)
        if key not in worst or m["with_target_fraction"] < worst[key][0]:
            worst[key] = (m["with_target_fraction"], res, case)
        if progress:
            log.info(f"follow-bench {k}/{len(cases)}: {case.recording} target {case.target} {case.tracker} "
                     f"seed {case.seed}: with_target {m['with_target_fraction']:.3f} "
                     f"({time.perf_counter() - t0:.0f} s)", extra={"progress": (k, len(cases))})
    episodes = pd.DataFrame(rows, columns=["recording", "target", "duration_s", "tracker", "seed", "sensing",
                                           *METRIC_KEYS, "replay"])
    summary = summarize(episodes) if len(episodes) else pd.DataFrame()
    for (rec, tracker), (_, res, case) in worst.items():
        fig = plot_episode(res, f"{rec}, target {case.target}, {tracker}, seed {case.seed}: "
                                f"with_target {res.metrics.with_target_fraction:.3f}")
        save_png(fig, out / "figures" / f"worst_{_slug(rec)}_{tracker}.png")
    with atomic_path(out / "episodes.parquet") as tmp:
        episodes.to_parquet(tmp, index=False)
    with atomic_path(out / "summary.csv") as tmp:
        summary.to_csv(tmp, index=False)
    cmd = (f"pedcal follow-bench --files {' '.join(files)} --trackers {' '.join(trackers)} --seeds {seeds} "
           f"--min-duration {min_duration_s:g}" + (f" --max-targets {max_targets}" if max_targets else "")
           + ("" if sensing == "ideal" else f" --sensing {sensing}" + (f" --lidar {lidar}" if lidar else ""))
           + f" -o {out.as_posix()}")
    md = bench_markdown(summary, recordings, dict(command=cmd, min_duration_s=min_duration_s, seeds=seeds))
    path = out / "bench.md"
    write_text_atomic(path, md)
    if progress:
        log.info(f"follow-bench: {len(cases)} episodes in {time.perf_counter() - t0:.0f} s wall, "
                 f"{time.process_time() - cpu0:.0f} s CPU")
    return path


__all__ = ["RECORDINGS", "BenchCase", "bench_cases", "eligible_targets", "run_case", "summarize", "plot_episode",
           "run_follow_bench"]
