"""The Markdown report, built from saved results alone (``results.load_results``).

A report is a list of *section builders*: functions ``section(ctx) -> str`` that return a
Markdown fragment (possibly empty) and save their figures through ``ctx.figure``. ``SECTIONS``
is the default list; another part of pedcal adds its own section from its own saved results with
``register_section`` (or passes ``sections=`` to ``build_report``), reading them from
``ctx.results_dir``.

Numbers are printed with fixed formats and the figures carry no dates, so building twice from
the same results gives the same bytes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.demo import PAPER
from pedcal.io.atomic import write_text_atomic
from pedcal.metrics import within_sigma_share
from pedcal.report import figures
from pedcal.report.results import SweepResults, load_results

FIG_DIR = "figures"
TABLE_TITLES = {"paper": "Table I (Kimoto et al.): the paper's 10-sensor installation",
                "sparse": "Table II (Kimoto et al.): 5 non-overlapping sensors"}
SIGMA_LEVELS = ((1, 68.27), (2, 95.45), (3, 99.73))


@dataclass
class ReportContext:
    results: SweepResults
    results_dir: Path
    out_dir: Path
    saved_figures: list[str] = field(default_factory=list)

    @property
    def methods(self) -> list[str]:
        return list(self.results.config.methods)

    @property
    def scenarios(self) -> list[str]:
        return [name for name, _ in self.results.config.scenarios]

    def figure(self, fig, name: str, alt: str) -> str:
        """Save ``fig`` as ``figures/NAME.png`` beside the report; returns the Markdown image."""
        figures.save_png(fig, self.out_dir / FIG_DIR / f"{name}.png")
        self.saved_figures.append(name)
        return f"![{alt}]({FIG_DIR}/{name}.png)"


Section = Callable[[ReportContext], str]


# ------------------------------------------------------------------------------------ statistics
def stats(values) -> dict:
    """mean, sample standard deviation (ddof=1), min, max and count of the finite values."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return dict(mean=np.nan, std=np.nan, min=np.nan, max=np.nan, n=0)
    return dict(mean=float(v.mean()), std=float(v.std(ddof=1)) if len(v) > 1 else np.nan,
                min=float(v.min()), max=float(v.max()), n=len(v))


def fmt(x: float, digits: int = 1) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def fmt_stats(s: dict, digits: int = 1) -> str:
    if s["n"] == 0:
        return "–"
    out = fmt(s["mean"], digits) + (f" ± {fmt(s['std'], digits)}" if np.isfinite(s["std"]) else "")
    return out + f" ({fmt(s['min'], digits)}–{fmt(s['max'], digits)})" if s["n"] > 1 else out


def accuracy_table(results: SweepResults, scenario: str) -> pd.DataFrame:
    """Per method: statistics over seeds of the sensor position RMS and the head tracking RMS
    (mm), the published figures, and the sensors' status counts over all seeds."""
    runs = results.runs[results.runs["scenario"] == scenario]
    sensors = results.sensors[(results.sensors["scenario"] == scenario) & (results.sensors["status"] == "ok")]
    # sensor position RMS per seed over the sensors the method calibrated (status ok) only
    ok_rms = sensors.groupby(["method", "seed"])["err_mm"].apply(lambda e: float(np.sqrt(np.mean(e ** 2))))
    paper = PAPER.get(scenario, {})
    rows = []
    for m in results.config.methods:
        r = runs[runs["method"] == m]
        pub = paper.get(m, (None, None))
        rows.append(dict(method=m, sensor=stats(r["sensor_rms_mm"]), head=stats(r["head_rms_mm"]),
                         sensor_ok=stats(ok_rms[m].to_numpy() if m in ok_rms.index.get_level_values(0) else []),
                         orientation=stats(r["orientation_rms_deg"]),
                         paper_sensor=pub[0], paper_head=pub[1], seeds=len(r),
                         ok=int(r["ok"].sum()), degenerate=int(r["degenerate"].sum()),
                         no_data=int(r["no_data"].sum())))
    return pd.DataFrame(rows)


def sigma_consistency(results: SweepResults, scenario: str) -> pd.DataFrame:
    """Per method reporting a sigma: the fraction of per-axis position errors within k reported
    sigma (k = 1, 2, 3) and the median |error| / sigma, over all seeds and sensors. A sensor the
    method did not calibrate (status not ok: no data, its installed pose, a degenerate sensor whose
    sigma is its prior's, wide enough to hold any error) or gave no finite sigma is a miss
    (``missed`` of the ``axes``): in the denominator, never within, above the median's every
    ratio, so that a method does not look consistent by dropping the sensors it fails."""
    sig_cols = ["sigma_x_mm", "sigma_y_mm", "sigma_z_mm"]
    s = results.sensors[results.sensors["scenario"] == scenario]
    rows = []
    for m in results.config.methods:
        # whether the method reports a sigma is decided over all its rows (every scenario): a
        # method that gave up on every sensor of this scenario still shows its misses and 0 %
        every = results.sensors.loc[results.sensors["method"] == m, sig_cols].to_numpy(float)
        if not (np.isfinite(every) & (every > 0)).any():    # the method reports no sigma
            continue
        d = s[s["method"] == m]
        err = d[["err_x_mm", "err_y_mm", "err_z_mm"]].to_numpy(float)
        sig = d[sig_cols].to_numpy(float)
        calibrated = (d["status"] == "ok").to_numpy()
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(err) / sig
        z[~np.isfinite(z) | ~(np.isfinite(sig) & (sig > 0)) | ~calibrated[:, None]] = np.inf
        z = z.ravel()
        rows.append(dict(method=m, axes=int(z.size), missed=int(np.isinf(z).sum()),
                         median_ratio=float(np.median(z)),
                         **{f"within_{k}": float(within_sigma_share(z, k)[0]) for k, _ in SIGMA_LEVELS}))
    return pd.DataFrame(rows)


# -------------------------------------------------------------------------------------- sections
def header_section(ctx: ReportContext) -> str:
    cfg = ctx.results.config
    seeds = ", ".join(f"{name}: {n} seed{'s' if n > 1 else ''} (0–{n - 1})" for name, n in cfg.scenarios)
    return "\n".join([
        "# pedcal calibration report",
        "",
        "Regenerate everything in this directory (results, figures, this file) with:",
        "",
        "```sh",
        cfg.command(),
        "```",
        "",
        f"and rebuild this file and its figures from the saved results alone with "
        f"`pedcal report --from-results {cfg.out}`.",
        "",
        f"Scenarios and seeds: {seeds}. Methods: {', '.join(cfg.methods)}. Each seed simulates a calibration "
        "log and an evaluation log (the same route driven again with independent noise); every method "
        "calibrates on the calibration log and is scored on the evaluation log: sensor position RMS "
        "against the true extrinsics, head tracking RMS of the robot's observations recomputed with the "
        "calibrated extrinsics against the robot's true head (`pedcal.metrics.evaluate`). Figures are "
        "mean ± sample standard deviation over seeds (min–max in brackets). The published figures are "
        "Kimoto et al.'s, measured on their real installation; ours are simulated (`datasets/`).",
        "",
        "Raw results: `results.json` and `runs.parquet` / `sensors.parquet` (per scenario, seed, method "
        "and sensor: errors, reported sigma, status), `heads.parquet` / `robot.parquet` (head tracks of "
        "each scenario's first seed). Solve times vary from run to run, so they are kept apart in "
        "`timings.json`, which this report does not read.",
    ])


def accuracy_section(ctx: ReportContext) -> str:
    out = ["## Accuracy against the papers' tables"]
    for sc in ctx.scenarios:
        tab = accuracy_table(ctx.results, sc)
        n = int(tab["seeds"].max()) if len(tab) else 0
        title = TABLE_TITLES.get(sc, f"Scenario `{sc}`")
        out += ["", f"### {title}", "", f"`{sc}` scenario, {n} seeds.", "",
                "| method | sensor position RMS (mm) | published | head tracking RMS (mm) | published "
                "| orientation RMS (deg) | sensors ok / degenerate / no data (all seeds) "
                "| sensor position RMS, ok sensors only (mm) |",
                "|---|---|---|---|---|---|---|---|"]
        for r in tab.itertuples():
            ok_only = "–" if r.method == "installed" else fmt_stats(r.sensor_ok)
            out.append(f"| {r.method} | {fmt_stats(r.sensor)} | {fmt(r.paper_sensor, 2)} | {fmt_stats(r.head)} "
                       f"| {fmt(r.paper_head, 2)} | {fmt(r.orientation['mean'], 2)} "
                       f"| {'–' if r.method == 'installed' else f'{r.ok} / {r.degenerate} / {r.no_data}'} "
                       f"| {ok_only} |")
    out += ["", "`installed` is the hand-measured extrinsics the log came with; `published` is empty where "
            "the paper gives no figure (closed form and factor graph are pedcal's; the paper has no head "
            "tracking figure for the 5-sensor experiment). The sensor position RMS counts every sensor a "
            "method returned, whatever its status: a sensor a method could not calibrate keeps what the "
            "method returned for it (the installed pose for the factor graph's no-data sensors); a sensor "
            "the method left out of its extrinsics is counted in `no data` only. The last column counts only the "
            "sensors the method marked ok, per seed; its spread shows how much of a method's error comes from "
            "sensors it knew it could not calibrate."]
    return "\n".join(out)


def association_section(ctx: ReportContext) -> str:
    runs = ctx.results.runs
    out = ["## Picking out the robot", "",
           "Precision / recall of the observations each method used as the robot's (against the simulator's "
           "labels), mean over seeds; estimated tracker latency where the method estimates one "
           "(simulated: about 0.1 s).", "",
           "| scenario | method | precision | recall | latency (s) |", "|---|---|---|---|---|"]
    rows = 0
    for sc in ctx.scenarios:
        for m in ctx.methods:
            r = runs[(runs["scenario"] == sc) & (runs["method"] == m)]
            p, rc, lat = (stats(r[c])["mean"] for c in ("assoc_precision", "assoc_recall", "latency_s"))
            if np.isfinite(p) or np.isfinite(lat):
                out.append(f"| {sc} | {m} | {fmt(p, 3)} | {fmt(rc, 3)} | {fmt(lat, 3)} |")
                rows += 1
    return "\n".join(out) if rows else ""


def per_sensor_section(ctx: ReportContext) -> str:
    out = ["## Per-sensor errors", "",
           "Mean position error of each sensor over seeds (log scale); the black dash on a bar is the mean "
           "3-D 1σ the method reported (√(σx² + σy² + σz²)), for methods that report one: a consistent "
           "method's bar reaches about its dash."]
    return "\n".join(out + _scenario_figures(ctx, figures.per_sensor_bars, "per_sensor",
                                              "position error per sensor, mean over seeds"))


def _scenario_figures(ctx: ReportContext, make, name: str, title: str) -> list[str]:
    """One figure per scenario of ``make(sensors_of_scenario, methods, title)``."""
    out = []
    for sc in ctx.scenarios:
        s = ctx.results.sensors[ctx.results.sensors["scenario"] == sc]
        out += ["", ctx.figure(make(s, ctx.methods, f"{sc}: {title}"), f"{name}_{sc}", f"{title}, {sc}")]
    return out


def trajectory_section(ctx: ReportContext) -> str:
    heads, robot = ctx.results.heads, ctx.results.robot
    if heads.empty:
        return ""
    out = ["## Head trajectories (cf. Kimoto et al., Figs. 5 and 6)", "",
           "The robot's observations on the evaluation log of each scenario's first seed, recomputed with "
           "each method's extrinsics (coloured points), over the robot's true head path (grey); triangles "
           "are the sensors' true positions, arrows their viewing directions."]
    for sc in ctx.scenarios:
        h, r = heads[heads["scenario"] == sc], robot[robot["scenario"] == sc]
        if h.empty:
            continue
        seed = int(h["seed"].iloc[0])
        s = ctx.results.sensors
        s = s[(s["scenario"] == sc) & (s["seed"] == seed)]
        fig = figures.head_trajectories(h, r, s, ctx.methods, f"{sc}, seed {seed}: calibrated head tracks")
        out += ["", ctx.figure(fig, f"trajectories_{sc}", f"head trajectories, {sc}")]
    return "\n".join(out)


def histogram_section(ctx: ReportContext) -> str:
    out = ["## Error distributions", "", "Per-sensor position errors over all seeds (log-spaced bins)."]
    return "\n".join(out + _scenario_figures(ctx, figures.error_histograms, "histogram",
                                              "sensor position errors, all seeds"))


def floorplan_section(ctx: ReportContext) -> str:
    out = ["## Reported uncertainty on the floor plan", "",
           "First seed of each scenario: each sensor's position error (arrow from the true position) and the "
           "1σ ellipse in x and y the method reported around its estimate, both magnified by the stated "
           "factor. The calibrated files carry per-axis sigmas only, so the ellipses are axis-aligned."]
    n = 0
    for sc in ctx.scenarios:
        s = ctx.results.sensors[ctx.results.sensors["scenario"] == sc]
        seed = int(s["seed"].min())
        fig = figures.covariance_floorplan(s[s["seed"] == seed], ctx.methods,
                                           f"{sc}, seed {seed}: errors and reported 1σ")
        if fig is not None:
            out += ["", ctx.figure(fig, f"floorplan_{sc}", f"covariance floor plan, {sc}")]
            n += 1
    return "\n".join(out) if n else ""


def consistency_section(ctx: ReportContext) -> str:
    out = ["## Consistency of the reported sigma", "",
           "Fraction of per-axis position errors (x, y, z of every sensor, every seed) within "
           "k times the sigma the method reported. A consistent sigma gives 68.3 / 95.4 / 99.7 %; "
           "less means the method is over-confident. A sensor the method did not calibrate (status not ok) or "
           "left without a sigma is missed: counted among the axes, never within.", "",
           "| scenario | method | axes (missed) | within 1σ (68.3 %) | within 2σ (95.4 %) | within 3σ (99.7 %) "
           "| median \\|e\\|/σ (0.67) |",
           "|---|---|---|---|---|---|---|"]
    rows = 0
    for sc in ctx.scenarios:
        for r in sigma_consistency(ctx.results, sc).itertuples():
            out.append(f"| {sc} | {r.method} | {r.axes} ({r.missed}) | {100 * r.within_1:.1f} % "
                       f"| {100 * r.within_2:.1f} % | {100 * r.within_3:.1f} % | {r.median_ratio:.2f} |")
            rows += 1
    return "\n".join(out) if rows else ""


def crlb_table(results: SweepResults, scenario: str) -> pd.DataFrame:
    """Per calibration method: the sensor position RMS over the Cramér-Rao bound on it
    (sqrt of the mean trace of the bound), over the sensors with status ok, per seed; and the
    median ratio of the reported per-axis sigma to the bound's."""
    b = results.bounds
    if b.empty:
        return pd.DataFrame()
    s = results.sensors[(results.sensors["scenario"] == scenario) & (results.sensors["status"] == "ok")]
    d = s.merge(b, on=["scenario", "seed", "sensor"], how="inner")
    rows = []
    for m in results.config.methods:
        dm = d[d["method"] == m]
        if dm.empty:
            continue
        per_seed = dm.groupby("seed").apply(
            lambda g: np.sqrt(np.mean(g["err_mm"] ** 2)) / np.sqrt(np.mean(g["crlb_3d_mm"] ** 2)),
            include_groups=False)
        sig = dm[["sigma_x_mm", "sigma_y_mm", "sigma_z_mm"]].to_numpy(float)
        bound = dm[["crlb_x_mm", "crlb_y_mm", "crlb_z_mm"]].to_numpy(float)
        r = (sig / bound).ravel()
        r = r[np.isfinite(r)]
        rows.append(dict(method=m, ratio=stats(per_seed.to_numpy(float)),
                         bound_mm=stats(dm.groupby("seed")["crlb_3d_mm"].apply(
                             lambda v: np.sqrt(np.mean(v ** 2))).to_numpy(float)),
                         sigma_ratio=float(np.median(r)) if len(r) else np.nan, sensors=len(dm)))
    return pd.DataFrame(rows)


def crlb_section(ctx: ReportContext) -> str:
    if ctx.results.bounds.empty:
        return ""
    out = ["## Against the Cramér-Rao bound", "",
           "`pedcal.calib.crlb`: the bound on each sensor's position covariance from the calibration log, "
           "for the robot's observations with the factor graph's noise models taken as the truth (people and "
           "outliers left out, odometry's systematic errors known: slightly optimistic). *RMS / bound* is a "
           "method's sensor position RMS over sqrt(mean trace of the bound), over the sensors it reports ok, "
           "per seed (1 = efficient); *σ / bound* is the median ratio of the reported per-axis sigma to the "
           "bound's (below 1 claims more than the data hold).", "",
           "| scenario | method | sensors (all seeds) | bound, RMS (mm) | RMS / bound | σ / bound |",
           "|---|---|---|---|---|---|"]
    for sc in ctx.scenarios:
        for r in crlb_table(ctx.results, sc).itertuples():
            if r.method == "installed":
                continue
            out.append(f"| {sc} | {r.method} | {r.sensors} | {fmt(r.bound_mm['mean'])} | {fmt_stats(r.ratio, 2)} "
                       f"| {fmt(r.sigma_ratio, 2)} |")
    return "\n".join(out)


TRACKING_STAT_KEYS = ("with_target_fraction", "near_fraction", "id_switches", "lost_episodes", "searching_frames",
                      "mean_reacquire_s", "max_reacquire_s", "followed_to_end", "lost_position_error_m", "mota",
                      "idf1")


def tracking_table(results: SweepResults) -> pd.DataFrame:
    """Per following scene and tracker: statistics over seeds of the ``pedcal follow`` metrics."""
    t = results.tracking
    rows = []
    for scene in results.config.follow_scenes:
        for tracker in results.config.follow_trackers:
            d = t[(t["scene"] == scene) & (t["tracker"] == tracker)]
            if d.empty:
                continue
            rows.append(dict(scene=scene, tracker=tracker, seeds=len(d),
                             **{k: stats(d[k].astype(float)) for k in TRACKING_STAT_KEYS}))
    return pd.DataFrame(rows)


def tracking_section(ctx: ReportContext) -> str:
    if ctx.results.tracking.empty:
        return ""
    if "with_target_fraction" not in ctx.results.tracking.columns:
        return ("## Following a specific person\n\nThese results hold the older following metrics; rerun "
                "`pedcal report` for the tracking tables.")
    tab = tracking_table(ctx.results)
    cfg = ctx.results.config
    out = ["## Following a specific person", "",
           f"`pedcal follow` on the simulated scenes ({', '.join(cfg.follow_scenes)}), seeds 0–{cfg.follow_seeds - 1}, "
           "for each tracker: `paper` (Misu and Miura's Kalman filters, appearance, ESPAR target probability, "
           "four states and existence grid), `lidar-only` (the same filters without the antenna) and "
           "`factorgraph` (pedcal's recovery: fixed-lag smoother of ESPAR bearings with a grid belief). "
           "*with target* is `with_target_fraction` (mean over seeds, worst seed in brackets): over the frames "
           "from the tracker's first choice of a target to the end, the share where the person it claims is the "
           "target, or the target is out of sight and its estimate is within 1 m of the truth; frames where the "
           "robot lost the target count as failures. *near* is the share of those frames with the robot within "
           "3 m of the target. *reacquire* is the time from losing the target to holding it again (mean of the "
           "per-seed means, a loss never recovered counting until the end; worst per-seed maximum); "
           "*lost error* is the median error of the target estimate while the target is out of sight; "
           "*to end* is the share of seeds where the robot held the target in the last frame. MOTA and IDF1 are "
           "CLEAR MOT over every person in the field of view (`motmetrics`, 0.5 m). A dash: no such event. "
           "The real recordings, each long-present person as the target, are `pedcal follow-bench`'s.", "",
           "| scene | tracker | with target | near | id switches | lost episodes | searching frames | reacquire (s) "
           "| lost error (m) | to end | MOTA | IDF1 |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in tab.itertuples():
        wf = r.with_target_fraction
        out.append(f"| {r.scene} | {r.tracker} | {fmt(wf['mean'], 3)} ({fmt(wf['min'], 3)}) "
                   f"| {fmt(r.near_fraction['mean'], 3)} "
                   f"| {fmt(r.id_switches['mean'], 1)} | {fmt(r.lost_episodes['mean'], 1)} "
                   f"| {fmt(r.searching_frames['mean'], 1)} "
                   f"| {fmt(r.mean_reacquire_s['mean'], 2)} ({fmt(r.max_reacquire_s['max'], 2)}) "
                   f"| {fmt(r.lost_position_error_m['mean'], 2)} | {fmt(r.followed_to_end['mean'], 2)} "
                   f"| {fmt(r.mota['mean'], 3)} | {fmt(r.idf1['mean'], 3)} |")
    return "\n".join(out)


SECTIONS: list[Section] = [header_section, accuracy_section, per_sensor_section, trajectory_section,
                           histogram_section, floorplan_section, consistency_section, crlb_section,
                           association_section, tracking_section]


def register_section(section: Section) -> Section:
    """Append ``section`` to the default report (usable as a decorator)."""
    SECTIONS.append(section)
    return section


def build_report(results_dir: str | Path, out_dir: str | Path | None = None,
                 sections: list[Section] | None = None) -> Path:
    """Write ``report.md`` and its figures (default: into ``results_dir``) from the saved results
    in ``results_dir``; nothing is recomputed. Returns the report's path."""
    results_dir = Path(results_dir)
    results = load_results(results_dir)
    out_dir = Path(out_dir) if out_dir is not None else results_dir
    ctx = ReportContext(results=results, results_dir=results_dir, out_dir=out_dir)
    parts = [text for section in (SECTIONS if sections is None else sections) if (text := section(ctx))]
    path = out_dir / "report.md"
    write_text_atomic(path, "\n\n".join(parts) + "\n")
    return path
