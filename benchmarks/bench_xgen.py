"""Held-out exam: pedcal's calibrations on logs from an independent generator (benchmarks/xgen).

The generator shares no code and no modelling choice with pedcal's simulator (see
benchmarks/xgen/README.md); its logs test whether the estimator generalizes. This is an exam, not
a training set: do not tune pedcal to it.

    nice -n 5 .venv/bin/python benchmarks/bench_xgen.py [--seeds 2] [--first-seed 0] \
        [--families rooms lhall corridor openhall] [--methods factorgraph gridsearch] [--out DIR] [--jobs 1]
        [--graph graphs/FILE.toml]
        [--max-time 600]
        [--ideal head head-xy head-z noise clocks amcl people]   # diagnosis: the same worlds without these
        [--head-profiles per-sensor|shared]       # one tracker profile per sensor (default) or per log
        [--from-results DIR]                      # the tables of an earlier run

Per (family, seed) it writes a log into OUT/<family>-<seed>/log, runs ``pedcal calibrate LOG
--method M`` as a subprocess for each method (its CPU time from the child's rusage), and scores
the calibrated YAML against the generator's truth.yaml here, with its own arithmetic:
- xy / z RMS (mm): sqrt of the mean over every sensor of every log of the family (pooled) of the
  squared horizontal / vertical position error; every sensor counts, whatever its status (a
  method that gives up on a sensor keeps its installed pose and is scored on it);
- yaw (deg): RMS of the world-vertical component of the rotation error log(R_est R_true^T);
- within 1 / 2 sigma x, y, z (%): share of per-axis position errors within 1 and 2 of the YAML's
  sigma.position_m; rot: the same for the sensor-frame rotation error log(R_true^T R_est) against
  sigma.rotation_deg when the YAML has it (else against sigma.ypr_deg is not meaningful and '-');
- xy less shared shift: the xy RMS after taking out each log's mean horizontal error over its
  sensors (what they share, such as AMCL's mean error over the run), the network's own shape;
- installed: the installed extrinsics' xy RMS (the start); AMCL: the norm of AMCL's mean error
  over the run (mm), the error any calibration anchored to AMCL shares;
- CPU (s): mean CPU time of one calibrate subprocess (user + sys, includes the import).
Then per method that reports a sigma, the sigma's honesty per family, pooled, per what the
log drew and per sensor mount and head profile: the share within 1 sigma and the RMS of
|error| / sigma (1 when honest, below 1 too wide), x, y, z, each with its 90 % interval from a
bootstrap over the logs (seeded;
``pedcal.metrics.sigma_honesty``: a log's sensors share its AMCL draw, so a share pooled over a
few logs is uncertain however many sensors it holds); a sensor not calibrated is a miss,
counted beside them ("sensors (missed)": outside for the share, left out of the RMS).
Then the network's shape per family and pooled (:func:`network_shape`): each log's horizontal
errors split by least squares into a shared shift, a common turn and a common scale of the whole
network about its sensors' centre, and the rest (mm RMS, pooled over every sensor of the family's
logs), with the scale in mm per m (mean / sd over the logs).
Then each log on its own (:func:`per_log_table`): per method the logs' xy RMS (best / median /
worst) and how many are within 12 mm, and each log's factor graph / grid search ratio and how many
are at or below 0.35x (the calibration issue's per-log targets; a log where either method failed
is left out of the ratio and counted beside it: a target met because the other method failed
would reward the failure).
Then, per method whose YAML holds the sensors' joint covariance, the sigma's honesty split as the
error is (:func:`split_ratios`): each log's shared error (the mean of its ok sensors' errors) over
the common position's sigma, and the RMS of their errors about it over the RMS sigma about it
(``pedcal.metrics.network_sigma_split``), x, y, z, as the RMS over the logs (1 when honest), and
the logs whose horizontal rest exceeds 2 sigma on an axis, named.
Last, per method, how much of each sensor's horizontal error about its log's mean its tracker's
sink would make as the sensor's tilt (:func:`sink_tilts`: the sensor's height above the head
times the slope of a plane fitted to the true sink over its reports): both RMS, their
correlation per axis, the least-squares gain and what is left (:func:`tilt_fit`).
Results are also written to OUT/results.jsonl; the tables are printed per family and pooled.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from xgen import FAMILIES, generate  # noqa: E402
from xgen.generator import HEAD_PROFILE_MODES, IDEAL, rot_world_sensor, tracked_point  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from pedcal.calib.common import robot_head_at  # noqa: E402
from pedcal.io import read_log, read_sensors_yaml  # noqa: E402
from pedcal.metrics import (  # noqa: E402
    format_clustered,
    network_sigma_split,
    robot_rows,
    sigma_honesty,
    sigma_ratio_rms,
    within_sigma_share,
)

# the calibration issue's per-log figures: horizontal RMS within this on every log, and at most
# this fraction of the grid search's on the same log
TARGET_XY_MM = 12.0
TARGET_RATIO = 0.35


def read_network(path: Path) -> dict:
    data = yaml.safe_load(path.read_text())
    out = {}
    for s in data["sensors"]:
        ypr = np.radians(np.asarray(s["ypr_deg"], float))
        sigma = s.get("sigma") or {}
        out[str(s["id"])] = {
            "p": np.asarray(s["position"], float), "R": rot_world_sensor(*ypr),
            "sigma_p": np.asarray(sigma["position_m"], float) if "position_m" in sigma else None,
            "sigma_rot_deg": np.asarray(sigma["rotation_deg"], float) if "rotation_deg" in sigma else None,
            "status": s.get("status", "ok")}
    return out


def score(truth: dict, est: dict, installed: dict | None = None) -> dict:
    """Per-sensor errors of est against truth (every sensor of the truth). A sensor est lacks is
    scored at its installed pose (``installed``), status "missing" and no sigma: a method that
    gives a sensor up is scored on what the user is left with, never dropped. Each row holds the
    sensor's true horizontal position ``true_xy_m`` (map frame, m) for :func:`network_shape`."""
    rows = []
    for sid, t in truth.items():
        e = est.get(sid)
        if e is None:
            e = {**installed[sid], "sigma_p": None, "sigma_rot_deg": None, "status": "missing"}
        d = e["p"] - t["p"]
        yaw_err = Rotation.from_matrix(e["R"] @ t["R"].T).as_rotvec()[2]
        rot_s = Rotation.from_matrix(t["R"].T @ e["R"]).as_rotvec()
        rows.append({"id": sid, "true_xy_m": t["p"][:2].tolist(),
                     "dx": d[0], "dy": d[1], "dz": d[2], "yaw_deg": math.degrees(yaw_err),
                     "rot_deg": np.degrees(rot_s).tolist(),
                     "sigma_p": None if e["sigma_p"] is None else e["sigma_p"].tolist(),
                     "sigma_rot_deg": None if e["sigma_rot_deg"] is None else e["sigma_rot_deg"].tolist(),
                     "status": e["status"]})
    return {"sensors": rows}


def run_calibrate_rusage(log: Path, method: str, out_yaml: Path, graph: Path | None = None) -> dict:
    """pedcal calibrate as a subprocess, with its CPU time from os.wait4's rusage (``graph``: the
    factor graph's recipe file, ``--graph``)."""
    cmd = [sys.executable, "-m", "pedcal.cli", "calibrate", str(log), "-o", str(out_yaml), "--method", method, "-q"]
    if graph is not None and method == "factorgraph":
        cmd += ["--graph", str(graph)]
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    err_path = out_yaml.with_suffix(".stderr.txt")
    t0 = time.perf_counter()
    with open(err_path, "w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    return {"rc": proc.returncode, "wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "stderr": err_path.read_text()[-1500:]}


def one_log(family: str, seed: int, out: Path, methods, max_time_s: float, ideal=(), head_profiles="per-sensor",
            graph: Path | None = None):
    d = out / f"{family}-{seed}"
    log = d / "log"
    info = generate(log, seed, family, max_time_s=max_time_s, ideal=ideal, head_profiles=head_profiles)
    truth = read_network(log / "truth.yaml")
    installed = read_network(log / "sensors.yaml")
    amcl_mean_mm = 1000 * float(np.linalg.norm(info["amcl"]["run_mean_error_m"]))
    base = {"family": family, "seed": seed, "n_sensors": len(truth), "amcl_mean_mm": amcl_mean_mm,
            "duration_s": info["duration_s"], "robot_observations": info["robot_observations"],
            "amcl_kind": info["amcl"]["kind"], "cov_factor": info["amcl"]["reported_sigma_factor"],
            "clock_offsets": info["clock_offsets"], "odometry": info["odometry"] is not None,
            "profiles": sorted({s["profile"]["kind"] for s in info["sensors"]})}
    results = [{**base, "method": "installed", **score(truth, installed), "rc": 0, "cpu_s": 0.0, "wall_s": 0.0}]
    for m in methods:
        y = d / f"{m}.yaml"
        r = run_calibrate_rusage(log, m, y, graph)
        row = {**base, "method": m, **{k: r[k] for k in ("rc", "cpu_s", "wall_s")}}
        if r["rc"] == 0 and y.exists():
            row.update(score(truth, read_network(y), installed))
        else:
            # a calibration that failed leaves the installed poses: scored on them
            row.update(score(truth, {}, installed), failed=True, stderr=r["stderr"])
        results.append(row)
    return results


def _errs(rows):
    """Every sensor's errors of a list of result rows."""
    return [x for r in rows for x in r.get("sensors", [])]


def reports_sigma(rows, method) -> tuple[bool, bool]:
    """Whether ``method`` reports a position sigma and a rotation sigma, decided over all its
    ``rows``: a group of logs where it failed everywhere (no sigma) still shows its coverage (0 %),
    not '-' like a method that reports none."""
    s = _errs(r for r in rows if r["method"] == method)
    return (any(x["sigma_p"] is not None for x in s), any(x["sigma_rot_deg"] is not None for x in s))


def failed_and_not_ok(rows, method) -> tuple[int, int] | None:
    """Over ``method``'s scored rows: its failed logs (a non-zero exit or flagged failed) and its
    sensors not calibrated (status other than ok); None when it has no scored row."""
    rr = [r for r in rows if r["method"] == method and r.get("sensors")]
    if not rr:
        return None
    return (sum(1 for r in rr if r["rc"] != 0 or r.get("failed")),
            sum(1 for x in _errs(rr) if x["status"] != "ok"))


def summarize(rows, method, reports: tuple[bool, bool] | None = None):
    """A method's figures over every log it was run on: a failed log counts at its installed
    poses (:func:`score`), and the sigma's coverage counts a sensor the method did not calibrate
    (status other than ok, or no sigma) as outside. ``reports``: :func:`reports_sigma` over all the
    method's rows (default: over ``rows``), whether its position / rotation coverage is shown."""
    reports = reports_sigma(rows, method) if reports is None else reports
    counts = failed_and_not_ok(rows, method)
    if counts is None:
        return None
    rr = [r for r in rows if r["method"] == method and r.get("sensors")]
    s = _errs(rr)
    dx, dy, dz = (np.array([x[k] for x in s]) for k in ("dx", "dy", "dz"))
    out = {"logs": len(rr), "failed": counts[0], "n": len(s),
           "xy_mm": 1000 * math.sqrt(np.mean(dx ** 2 + dy ** 2)), "z_mm": 1000 * math.sqrt(np.mean(dz ** 2)),
           "xy_rel_mm": 1000 * math.sqrt(np.mean([x["dx_rel"] ** 2 + x["dy_rel"] ** 2 for x in s])),
           "yaw_deg": math.sqrt(np.mean([x["yaw_deg"] ** 2 for x in s])),
           "worst_log_xy_mm": max(log_xy_mm(r) for r in rr),
           "not_ok": counts[1],
           "cpu_s": float(np.mean([r["cpu_s"] for r in rr])), "wall_s": float(np.mean([r["wall_s"] for r in rr]))}
    # (a sensor left at its prior has a sigma wide enough to hold any error: a miss, not evidence)
    if reports[0]:
        ratios = sensor_ratios(s)
        out["cov1"] = (100 * within_sigma_share(ratios, 1.0)).tolist()
        out["cov2"] = (100 * within_sigma_share(ratios, 2.0)).tolist()
    if reports[1]:
        ratios = sensor_ratios(s, "sigma_rot_deg").reshape(-1, 1)        # the three axes pooled
        out["rot1"] = float(100 * within_sigma_share(ratios, 1.0)[0])
        out["rot2"] = float(100 * within_sigma_share(ratios, 2.0)[0])
        # the share alone rewards a sigma that is only wide: its error / sigma RMS is below 1
        out["rot_rms"] = float(sigma_ratio_rms(ratios)[0])
    return out


def sensor_ratios(sensors: list[dict], sigma: str = "sigma_p") -> np.ndarray:
    """(n_sensors, 3) each scored sensor's |error| over its sigma per axis: the position's (x, y,
    z world axes) against ``sigma_p``, or with ``sigma="sigma_rot_deg"`` the rotation's (sensor
    axes) against it; inf for a miss (no sigma, or a status other than ok: a sensor left at its
    prior or not calibrated, whose sigma would hold any error)."""
    out = np.full((len(sensors), 3), np.inf)
    for k, x in enumerate(sensors):
        if x[sigma] is not None and x["status"] == "ok":
            err = [x["dx"], x["dy"], x["dz"]] if sigma == "sigma_p" else x["rot_deg"]
            out[k] = np.abs(err) / np.asarray(x[sigma], float)
    return out


def log_ratios(row) -> np.ndarray:
    """:func:`sensor_ratios` of the position of one result row's sensors."""
    return sensor_ratios(row.get("sensors", []))


def honesty_table(rows, method, groups, title, label="logs of"):
    """The sigma's honesty of ``method`` per group of logs: within 1 sigma and error / sigma
    RMS per axis with their 90 % intervals over the group's logs, beside the sensors and those
    missed (:func:`log_ratios`' inf rows, which the RMS leaves out); '' when it reports no sigma."""
    lines = [f"### {title}", "",
             f"| {label} | logs | sensors (missed) | within 1 sigma x / y / z (%) [90 % over logs] | "
             "error / sigma RMS x / y / z [90 % over logs] |", "|---|---|---|---|---|"]
    any_sigma = False
    for name, g in groups:
        rr = [r for r in g if r["method"] == method and r.get("sensors")]
        if not rr:
            continue
        any_sigma |= any(x["sigma_p"] is not None for r in rr for x in r["sensors"])
        within, rms = sigma_honesty([log_ratios(r) for r in rr])
        lines.append(f"| {name} | {within.logs} | {within.rows} ({within.misses}) | {format_clustered(within, 100)} | "
                     f"{format_clustered(rms, digits=2)} |")
    return "\n".join(lines) if any_sigma else ""


def by_family(rows):
    fams = [f for f in FAMILIES if any(r["family"] == f for r in rows)]
    return [(f, [r for r in rows if r["family"] == f]) for f in fams] + [("pooled", rows)]


def by_log_nuisance(rows):
    """Groups of logs by what the generator drew for the whole log (AMCL, clocks, odometry)."""
    keys = [("AMCL OU", lambda r: r["amcl_kind"] == "ou"), ("AMCL random walk", lambda r: r["amcl_kind"] == "rw"),
            ("AMCL cov honest", lambda r: r["cov_factor"] == 1.0),
            ("AMCL sigma x0.5", lambda r: r["cov_factor"] == 0.5), ("AMCL sigma x2", lambda r: r["cov_factor"] == 2.0),
            ("AMCL jumps", lambda r: r.get("amcl_jumps", 0) > 0),
            ("clock offsets", lambda r: r["clock_offsets"]), ("no clock offsets", lambda r: not r["clock_offsets"]),
            ("odometry", lambda r: r["odometry"]), ("no odometry", lambda r: not r["odometry"])]
    return [(name, [r for r in rows if f(r)]) for name, f in keys if any(f(r) for r in rows)]


def by_sensor(rows, field_name):
    """Groups of sensors (every log's rows kept, their sensors filtered) by a per-sensor field."""
    values = sorted({x[field_name] for r in rows for x in r.get("sensors", []) if field_name in x})
    return [(f"{field_name} {v}", [{**r, "sensors": [x for x in r.get("sensors", []) if x.get(field_name) == v]}
                                   for r in rows]) for v in values]


def shared_shift_removed(row) -> None:
    """Each scored sensor of ``row`` gets its error less the log's shared horizontal shift (what
    anchoring to AMCL's run mean moves all sensors by): dx_rel, dy_rel."""
    scored = row.get("sensors", [])
    if scored:
        mean_xy = np.mean([[x["dx"], x["dy"]] for x in scored], axis=0)
        for x in scored:
            x["dx_rel"], x["dy_rel"] = x["dx"] - mean_xy[0], x["dy"] - mean_xy[1]


# 90-degree rotation in the horizontal plane: J q is q turned by +90 deg (a small turn w moves q by w J q)
_J = np.array([[0.0, -1.0], [1.0, 0.0]])
# below this RMS distance of the sensors from their centre (m) a turn and a scale are not determined
_MIN_SPREAD_M = 1e-6


def network_shape(true_xy_m, err_xy_m) -> dict:
    """One log's horizontal errors split into the network's shared shift, common turn, common
    scale and the rest: the least-squares fit of

        d_i = t + w J q_i + s q_i + r_i

    over the log's scored sensors i (every one, as :func:`score` scores them), where d_i is the
    sensor's horizontal error (estimate less truth, m), q_i its true horizontal position less the
    mean of the log's true positions (m), J the 90-degree rotation [[0, -1], [1, 0]], t the shared
    shift (m), w the common turn (rad, small-angle), s the common scale (dimensionless: the network
    stretched, s > 0, or shrunk about its centre) and r_i the rest.

    As q is centred and J q_i is perpendicular to q_i, the regressors (the two axes of t, J q and
    q, stacked over the sensors) are mutually orthogonal: the fit is t = mean d_i,
    w = sum (J q_i . d_i) / sum |q_i|^2, s = sum (q_i . d_i) / sum |q_i|^2, and the parts' mean
    squares add up to the total's (up to rounding). t is the shared shift that
    :func:`shared_shift_removed` takes out, so "xy less shared shift" is the RMS of turn, scale
    and rest together.

    ``true_xy_m``, ``err_xy_m``: (n, 2). Returns ``n``; ``t_mm`` (2); ``turn_rad``;
    ``scale_mm_per_m`` (1000 s); the RMS over the sensors of each part's contribution in mm:
    ``shift_mm`` (|t|), ``turn_mm`` (|w| times the RMS of |q_i|), ``scale_mm`` (|s| times the same),
    ``rest_mm`` and ``total_mm`` (the RMS of |d_i|). With fewer than 3 sensors (or sensors within
    a micrometre RMS of their centre) the turn and scale are not determined (with 2 they would
    take up every error but the shift): they are NaN and everything not shift is in the rest.
    With no sensor every figure is NaN.

    A sensor the method did not calibrate (status other than ok: missing, or a failed log, scored
    at its installed pose) enters the split like any other, so its installed-pose error leaks into
    the shift, turn and scale as well as the rest (:func:`shape_table` shows how many there were).
    The noise floor: with white errors of sigma per axis at each of n >= 3 sensors, the turn's and
    the scale's expected mean squares are each sigma^2 / n and the rest's 2 (n - 2) sigma^2 / n
    (2 n values less 4 fitted), so their RMS parts are each about rest / sqrt(2 (n - 2)) (about
    rest / 4.2 for 11 sensors); a turn or scale much above that is shared by the network."""
    p = np.asarray(true_xy_m, float).reshape(-1, 2)
    d = np.asarray(err_xy_m, float).reshape(-1, 2)
    if p.shape != d.shape:
        raise ValueError(f"network_shape: {len(p)} true positions for {len(d)} errors")
    n = len(p)
    nan = float("nan")
    if n == 0:
        return {"n": 0, "t_mm": [nan, nan], "turn_rad": nan, "scale_mm_per_m": nan, "shift_mm": nan,
                "turn_mm": nan, "scale_mm": nan, "rest_mm": nan, "total_mm": nan}
    t = d.mean(axis=0)
    q = p - p.mean(axis=0)
    sum_q2 = float(np.sum(q ** 2))
    rest = d - t
    w = s = nan
    if n >= 3 and sum_q2 > n * _MIN_SPREAD_M ** 2:
        jq = q @ _J.T
        w = float(np.sum(jq * d)) / sum_q2
        s = float(np.sum(q * d)) / sum_q2
        rest = rest - w * jq - s * q
    rms_q = math.sqrt(sum_q2 / n)
    return {"n": n, "t_mm": (1000 * t).tolist(), "turn_rad": w, "scale_mm_per_m": 1000 * s,
            "shift_mm": 1000 * float(np.linalg.norm(t)), "turn_mm": 1000 * abs(w) * rms_q,
            "scale_mm": 1000 * abs(s) * rms_q, "rest_mm": 1000 * math.sqrt(np.mean(np.sum(rest ** 2, axis=1))),
            "total_mm": 1000 * math.sqrt(np.mean(np.sum(d ** 2, axis=1)))}


def row_shape(row) -> dict:
    """:func:`network_shape` of one result row's scored sensors, whatever their status (each has
    its true position: :func:`score` writes it, :func:`attach_sensor_info` reads it back from the
    log for an older results.jsonl)."""
    scored = row.get("sensors") or []
    return network_shape([x["true_xy_m"] for x in scored], [[x["dx"], x["dy"]] for x in scored])


SHAPE_PARTS = ("shift", "turn", "scale", "rest")


def pooled_shape(rows) -> dict | None:
    """The shape split of a group of result rows (one method's): each part's RMS pooled over every
    sensor of every log that has it, sqrt(sum_logs n_log ms_log / sum_logs n_log) with ms_log the
    log's mean square of that part (the pooling of the xy RMS); a log whose turn and scale are not
    determined adds 0 to them (its error is in its rest). The scale's mean and sd (ddof 1, NaN
    for one log) over the logs where it is determined (mm per m); ``logs``: how many logs have
    sensors, every one counted (a failed log at its installed poses). None when none has."""
    shapes = [row_shape(r) for r in rows if r.get("sensors")]
    if not shapes:
        return None
    n = np.array([sh["n"] for sh in shapes], float)
    out = {"logs": len(shapes)}
    for part in SHAPE_PARTS:
        ms = np.array([sh[f"{part}_mm"] ** 2 for sh in shapes])
        out[f"{part}_mm"] = math.sqrt(np.sum(n * np.nan_to_num(ms, nan=0.0)) / n.sum())
    scales = np.array([sh["scale_mm_per_m"] for sh in shapes if math.isfinite(sh["scale_mm_per_m"])])
    out["scale_mean_mm_per_m"] = float(np.mean(scales)) if len(scales) else float("nan")
    out["scale_sd_mm_per_m"] = float(np.std(scales, ddof=1)) if len(scales) > 1 else float("nan")
    return out


def shape_table(rows, methods, groups=None, label="family"):
    """Per group (default: per family and pooled) and method, :func:`pooled_shape`: shift / turn /
    scale / rest (mm RMS) and the scale (mm per m) mean / sd over the logs. As in :func:`table`
    (:func:`failed_and_not_ok`, the counts :func:`summarize` gives), "(k failed)" after a method's
    split counts its failed logs and the "not ok" column its sensors not calibrated: both are in
    the split at their installed poses."""
    groups = by_family(rows) if groups is None else groups
    lines = ["### the network's shape: horizontal error split into shared shift, common turn, common scale "
             "and the rest", ""]
    head = (f"| {label} | logs | " + " | ".join(f"{m} shift / turn / scale / rest (mm RMS) | "
                                                f"{m} scale (mm/m) mean / sd over logs" for m in methods)
            + " | not ok |")
    lines += [head, "|" + "---|" * (head.count("|") - 1)]

    def num(v, fmt):
        return "-" if not math.isfinite(v) else format(v, fmt)

    for name, g in groups:
        logs = sum(1 for r in g if r["method"] == "installed" and r.get("sensors"))
        cells = [name, str(logs)]
        counts = {m: failed_and_not_ok(g, m) for m in methods}
        for m in methods:
            x = pooled_shape([r for r in g if r["method"] == m])
            if x is None:
                cells += ["-", "-"]
                continue
            failed = f" ({counts[m][0]} failed)" if counts[m][0] else ""
            cells.append(" / ".join(f"{x[f'{p}_mm']:.1f}" for p in SHAPE_PARTS) + failed)
            cells.append(f"{num(x['scale_mean_mm_per_m'], '+.2f')} / {num(x['scale_sd_mm_per_m'], '.2f')}")
        cells.append(" / ".join("-" if counts[m] is None else str(counts[m][1]) for m in methods))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def attach_sensor_info(rows, out: Path):
    """Each scored sensor gets its mount and head profile (from the log's xgen.json) and, when its
    row lacks it (an older results.jsonl), its true horizontal position (from the log's truth.yaml);
    each row its AMCL jumps."""
    cache = {}
    for r in rows:
        key = (r["family"], r["seed"])
        if key not in cache:
            log = out / f"{r['family']}-{r['seed']}" / "log"
            cache[key] = json.loads((log / "xgen.json").read_text()), read_network(log / "truth.yaml")
        info, truth = cache[key]
        per = {s["id"]: s for s in info["sensors"]}
        r["amcl_jumps"] = len(info["amcl"]["jumps"])
        shared_shift_removed(r)
        for x in r.get("sensors", []):
            x["mount"] = per[x["id"]]["mount"]
            x["profile"] = per[x["id"]]["profile"]["kind"]
            if x.get("true_xy_m") is None:
                x["true_xy_m"] = truth[x["id"]]["p"][:2].tolist()


def sink_tilts(log: Path) -> dict[str, np.ndarray]:
    """Per sensor of an xgen log, the horizontal move (m, world) its tracker's sink would make as
    the sensor's tilt: the true sink (the vertical part of the tracker's point less the head top)
    over the robot observations it made fitted by a plane a + b (x - x_s) + c (y - y_s), times the
    sensor's height above the head, H (b, c) (:func:`plane_slope`: read along the directions the
    reports spread over by 10 cm or more). Turning a sensor by a slope k lowers each point by
    k d along its view and moves every point by k H, which its position takes back (pedcal's
    README, the head point's two parts). The head tops are the truth's at each report's capture
    time (stamp less the latency and the sensor's clock offset); a sensor with fewer than 20
    reports gets none."""
    info = json.loads((log / "xgen.json").read_text())
    truth = read_network(log / "truth.yaml")
    data = read_log(log)
    obs = data.observations[robot_rows(data)[0]]
    head_z = float(data.meta.head_offset_m[2])
    out = {}
    for s in info["sensors"]:
        sid = str(s["id"])
        seen = obs[obs["sensor"].astype(str) == sid]
        if len(seen) < 20:
            continue
        top = robot_head_at(data, seen["t"].to_numpy(float) - info["latency_s"] - s["clock_offset_s"], truth=True)
        p_s = truth[sid]["p"]
        sink = tracked_point(s["profile"], top, p_s)[:, 2] - top[:, 2]
        out[sid] = (p_s[2] - head_z) * plane_slope(top[:, :2], sink)
    return out


MIN_SPREAD_M = 0.1       # a plane's slope is read along directions the points spread over by this (std) or more


def plane_slope(xy_m: np.ndarray, z_m: np.ndarray, min_spread_m: float = MIN_SPREAD_M) -> np.ndarray:
    """The horizontal gradient (2,) of the least-squares plane z = a + g . (xy - mean), read only
    along the principal directions of ``xy_m`` whose std is ``min_spread_m`` or more (0 across a
    line of points: a plane's tilt across it is whatever the fit's rounding makes it)."""
    xy = np.asarray(xy_m, float) - np.mean(xy_m, axis=0)
    z = np.asarray(z_m, float) - np.mean(z_m)
    u, sv, vt = np.linalg.svd(xy, full_matrices=False)
    keep = sv / np.sqrt(max(len(xy), 1)) >= min_spread_m
    return vt[keep].T @ ((u[:, keep].T @ z) / sv[keep])


def tilt_fit(tilt_m: np.ndarray, rest_m: np.ndarray) -> dict:
    """How much of the sensors' horizontal errors about their log's mean (``rest_m``, (n, 2))
    their trackers' sinks' tilts (``tilt_m``, (n, 2), :func:`sink_tilts`) explain: both RMS (mm),
    their correlation per axis, the least-squares gain g of rest = g tilt over both axes, and the
    RMS of rest - g tilt (mm)."""
    tilt, rest = np.asarray(tilt_m, float), np.asarray(rest_m, float)
    gain = float(np.sum(tilt * rest) / max(float(np.sum(tilt * tilt)), 1e-30))

    def rms(v):
        return float(1000 * np.sqrt(np.mean(np.sum(v ** 2, axis=1))))

    corr = [float(np.corrcoef(tilt[:, a], rest[:, a])[0, 1]) if np.std(tilt[:, a]) > 0 and np.std(rest[:, a]) > 0
            else math.nan for a in range(2)]
    return {"sensors": len(tilt), "tilt_mm": rms(tilt), "rest_mm": rms(rest), "corr": corr, "gain": gain,
            "left_mm": rms(rest - gain * tilt)}


def sink_tilt_table(rows, method, out: Path) -> str:
    """Per family and pooled, :func:`tilt_fit` of ``method``'s sensors (every scored sensor of a
    log that calibrated, errors about the log's mean horizontal error) against their trackers'
    sinks' tilts; "" when no log of the method calibrated."""
    per_family: dict[str, list] = {}
    for r in rows:
        if r["method"] != method or r.get("failed") or not r.get("sensors"):
            continue
        tilts = sink_tilts(out / f"{r['family']}-{r['seed']}" / "log")
        e = np.array([[x["dx"], x["dy"]] for x in r["sensors"]])
        rest = e - e.mean(axis=0)
        for x, d in zip(r["sensors"], rest, strict=True):
            if x["id"] in tilts:
                per_family.setdefault(r["family"], []).append((tilts[x["id"]], d))
    if not per_family:
        return ""
    lines = [f"### {method}: each tracker's sink as its sensor's tilt (height above the head x the sink's slope)",
             "", "| family | sensors | tilt RMS (mm) | rest RMS (mm) | correlation x / y | gain "
             "| rest less gain x tilt (mm) |", "|---|---|---|---|---|---|---|"]
    groups = list(per_family.items()) + [("pooled", [p for v in per_family.values() for p in v])]
    for name, pairs in groups:
        f = tilt_fit(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]))
        lines.append(f"| {name} | {f['sensors']} | {f['tilt_mm']:.1f} | {f['rest_mm']:.1f} | "
                     f"{f['corr'][0]:.2f} / {f['corr'][1]:.2f} | {f['gain']:.2f} | {f['left_mm']:.1f} |")
    return "\n".join(lines)


def attach_sigma_split(rows, out: Path) -> None:
    """Each calibration row gets ``sigma_split``: :func:`pedcal.metrics.network_sigma_split` of the
    YAML its method wrote (OUT/FAMILY-SEED/METHOD.yaml), None for a failed run, without the file,
    a joint covariance in it (the grid search writes none) or an ok sensor, and for a file that
    does not read (named on stderr: one bad file leaves the other tables be)."""
    for r in rows:
        if r["method"] == "installed" or "sigma_split" in r:
            continue
        path = out / f"{r['family']}-{r['seed']}" / f"{r['method']}.yaml"
        r["sigma_split"] = None
        if r.get("rc") != 0 or not path.is_file():
            continue
        try:
            r["sigma_split"] = network_sigma_split(read_sensors_yaml(path))
        except (ValueError, OSError) as e:      # (PedcalInputError is a ValueError)
            print(f"{path}: no sigma split ({e})", file=sys.stderr)


def split_ratios(row) -> tuple[np.ndarray, np.ndarray] | None:
    """One row's sigma honesty split as the error is, per axis x, y, z: |t| / the common position's
    sigma, t the mean error of the log's ok sensors, and the RMS of their errors less t over the
    RMS sigma about the common position (the row's ``sigma_split``, over the same ok sensors);
    NaN where a sigma is 0 (the only ok sensor has no rest). None without a split, or when its
    sensors are not the row's ok ones. (The ok sensors alone, where :func:`shared_shift_removed`
    and :func:`network_shape` take every scored sensor, those left at their installed poses too:
    the two tables' shifts and rests differ where a method left a sensor.)"""
    split = row.get("sigma_split")
    ok = [x for x in row.get("sensors") or [] if x.get("status") == "ok"]
    if not split or not ok or sorted(split.get("ids", [])) != sorted(x["id"] for x in ok):
        return None
    e = np.array([[x["dx"], x["dy"], x["dz"]] for x in ok], float)
    t = e.mean(axis=0)
    rest = np.sqrt(np.mean((e - t) ** 2, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        common = np.abs(t) / np.asarray(split["common_m"], float)
        about = rest / np.asarray(split["relative_rms_m"], float)
    return np.where(np.isfinite(common), common, np.nan), np.where(np.isfinite(about), about, np.nan)


def split_honesty_table(rows, method, groups, title, limit: float = 2.0) -> str:
    """Per group, :func:`split_ratios` of ``method``'s rows: the common part's and the rest's
    error / sigma RMS over the logs, x / y / z, and the logs whose horizontal rest is over
    ``limit`` sigma on an axis (named). "" when no row of the method has a split."""
    lines = [f"### {title}", "",
             f"| logs of | logs | common error / sigma RMS x / y / z | rest error / sigma RMS x / y / z | "
             f"logs with a horizontal rest over {limit:g} sigma |", "|---|---|---|---|---|"]
    any_row = False

    def fmt(v):
        return " / ".join("-" if not math.isfinite(x) else f"{x:.2f}" for x in v)

    for name, g in groups:
        got = [(r, split_ratios(r)) for r in g if r["method"] == method]
        got = [(r, x) for r, x in got if x is not None]
        if not got:
            continue
        any_row = True
        common = sigma_ratio_rms(np.array([x[0] for _, x in got]))
        rest = sigma_ratio_rms(np.array([x[1] for _, x in got]))
        over = [f"{r['family']} {r['seed']}" for r, x in got if np.nanmax(np.r_[x[1][:2], 0.0]) > limit]
        lines.append(f"| {name} | {len(got)} | {fmt(common)} | {fmt(rest)} | "
                     f"{len(over)}{' (' + ', '.join(over) + ')' if over else ''} |")
    return "\n".join(lines) if any_row else ""


def rot_rms_text(rms: float) -> str:
    """The rotation's error / sigma RMS for :func:`table`: '-' without a finite ratio."""
    return f"{rms:.2f}" if math.isfinite(rms) else "-"


def table(rows, methods, title, groups=None, label="family"):
    groups = by_family(rows) if groups is None else groups
    groups = [(n, g) for n, g in groups if any(r.get("sensors") for r in g if r["method"] == "installed")]
    lines = [f"### {title}", ""]
    head = (f"| {label} | logs | sensors | installed xy | AMCL mean | " +
            " | ".join(f"{m} xy / xy less shared shift / z (mm), yaw (deg)" for m in methods) +
            (" | graph / grid xy" if {"factorgraph", "gridsearch"} <= set(methods) else "") +
            " | " + " | ".join(f"{m} within 1 sigma x, y, z / rot (%) (rot error / sigma RMS)" for m in methods) +
            " | " + " | ".join(f"{m} within 2 sigma x, y, z / rot (%)" for m in methods) +
            " | worst log xy (mm) | not ok | " + " | ".join(f"{m} CPU / wall (s)" for m in methods) + " |")
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    reports = {m: reports_sigma(rows, m) for m in methods}      # once per method, over every group
    for name, g in groups:
        inst = summarize(g, "installed")
        sm = {m: summarize(g, m, reports[m]) for m in methods}
        amcl = float(np.sqrt(np.mean([r["amcl_mean_mm"] ** 2 for r in g if r["method"] == "installed"])))
        cells = [name, str(inst["logs"]), str(inst["n"]), f"{inst['xy_mm']:.0f}", f"{amcl:.1f}"]
        for m in methods:
            x = sm[m]
            cells.append("failed" if x is None else
                         f"{x['xy_mm']:.1f} / {x['xy_rel_mm']:.1f} / {x['z_mm']:.1f}, {x['yaw_deg']:.2f}"
                         + (f" ({x['failed']} failed)" if x["failed"] else ""))
        if {"factorgraph", "gridsearch"} <= set(methods):
            a, b = sm["factorgraph"], sm["gridsearch"]
            cells.append("-" if a is None or b is None else f"{a['xy_mm'] / b['xy_mm']:.2f}")
        for key, rot in (("cov1", "rot1"), ("cov2", "rot2")):
            for m in methods:
                x = sm[m]
                if x is None or key not in x:
                    cells.append("-")
                else:
                    cells.append(", ".join(f"{v:.0f}" for v in x[key]) + (f" / {x[rot]:.0f}" if rot in x else "")
                                 + (f" (rms {rot_rms_text(x['rot_rms'])})" if rot == "rot1" and rot in x else ""))
        cells.append(" / ".join("-" if sm[m] is None else f"{sm[m]['worst_log_xy_mm']:.0f}" for m in methods))
        cells.append(" / ".join("-" if sm[m] is None else str(sm[m]["not_ok"]) for m in methods))
        for m in methods:
            x = sm[m]
            cells.append("-" if x is None else f"{x['cpu_s']:.1f} / {x['wall_s']:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def log_xy_mm(row) -> float:
    """A log's horizontal RMS over every sensor it scores (a failed log's at the installed poses,
    :func:`score`), mm."""
    return 1000 * math.sqrt(np.mean([x["dx"] ** 2 + x["dy"] ** 2 for x in row["sensors"]]))


def per_log_table(rows, methods, target_mm: float = TARGET_XY_MM, target_ratio: float = TARGET_RATIO,
                  groups=None, label="family") -> str:
    """Each log judged on its own, as the calibration issue's figures are: per method the logs'
    horizontal RMS (best / median / worst) and how many are within ``target_mm`` (a failed log at
    its installed poses, :func:`score`); with both methods, each log's factor graph over grid
    search ratio (best / median / worst) and how many are at or below ``target_ratio``, paired by
    family and seed: a log either method lacks is left out of the ratio (counted in its own
    column), and so is a log where either failed (counted beside the ratio: a ratio met because
    the other method failed would reward the failure); among the logs that meet the ratio, those
    where either method left a sensor not ok are counted beside it too. Two rows of one method
    for one log are refused (a hand-merged results file)."""
    groups = by_family(rows) if groups is None else groups
    both = {"factorgraph", "gridsearch"} <= set(methods)
    head = (f"| {label} | logs | " + " | ".join(f"{m} per-log xy best / median / worst (mm)" for m in methods)
            + " | " + " | ".join(f"{m} logs <= {target_mm:g} mm" for m in methods)
            + (f" | graph / grid per log best / median / worst | logs <= {target_ratio:g}x grid" if both else "")
            + " |")
    lines = [f"### each log on its own (targets: <= {target_mm:g} mm xy on every log"
             + (f", <= {target_ratio:g}x the grid search's)" if both else ")"), "", head,
             "|" + "---|" * (head.count("|") - 1)]
    seen = [(r["family"], r["seed"], r["method"]) for r in rows if r["method"] in methods]
    if len(seen) != len(set(seen)):
        twice = sorted({k for k in seen if seen.count(k) > 1})
        raise ValueError(f"more than one row for (family, seed, method) {twice}: one row per method and log")
    failed = {(r["family"], r["seed"]) for r in rows if r["method"] in methods and (r["rc"] != 0 or r.get("failed"))}
    # logs where a method left a sensor not calibrated (scored where it left it, a no-data sensor at
    # its installed pose): a ratio met there may be the other method's giving up, so it is named
    not_ok = {(r["family"], r["seed"]) for r in rows if r["method"] in methods
              and any(x["status"] != "ok" for x in r.get("sensors") or [])}
    for name, g in groups:
        xy = {m: {(r["family"], r["seed"]): log_xy_mm(r) for r in g if r["method"] == m and r.get("sensors")}
              for m in methods}
        n_logs = len({(r["family"], r["seed"]) for r in g if r["method"] in methods})
        cells = [name, str(n_logs)]
        for m in methods:
            v = np.array(list(xy[m].values()))
            cells.append("-" if not len(v) else f"{v.min():.1f} / {np.median(v):.1f} / {v.max():.1f}")
        cells += [f"{int(np.sum(np.array(list(xy[m].values())) <= target_mm))} of {len(xy[m])}" for m in methods]
        if both:
            both_ran = set(xy["factorgraph"]) & set(xy["gridsearch"])
            keys = sorted(both_ran - failed)
            ratio = np.array([xy["factorgraph"][k] / xy["gridsearch"][k] for k in keys])
            cells.append("-" if not len(ratio) else f"{ratio.min():.2f} / {np.median(ratio):.2f} / {ratio.max():.2f}")
            n_failed = len(both_ran & failed)
            met = {k for k, x in zip(keys, ratio, strict=True) if x <= target_ratio}
            notes = ([f"{len(met & not_ok)} of them with a sensor not ok"] if met & not_ok else []) + \
                ([f"{n_failed} with a failed run left out"] if n_failed else [])
            cells.append(f"{len(met)} of {len(ratio)}" + (f" ({'; '.join(notes)})" if notes else ""))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=FAMILIES)
    ap.add_argument("--methods", nargs="+", default=["factorgraph", "gridsearch"])
    ap.add_argument("--out", type=Path, default=None, help="where logs and results go (default: a temp dir)")
    ap.add_argument("--jobs", type=int, default=1, help="logs calibrated at once")
    ap.add_argument("--max-time", type=float, default=600.0, help="longest drive per log (s)")
    ap.add_argument("--ideal", nargs="+", default=[], choices=IDEAL,
                    help="switch these nuisances off (diagnosis: the same worlds without them)")
    ap.add_argument("--head-profiles", default="per-sensor", choices=HEAD_PROFILE_MODES,
                    help="each tracker its own head-point profile, or one shared by all sensors of a log")
    ap.add_argument("--graph", type=Path, default=None,
                    help="the factor graph's recipe file (pedcal calibrate --graph; default: graphs/default.toml)")
    ap.add_argument("--from-results", type=Path, default=None,
                    help="print the tables of an earlier run's DIR (its results.jsonl and logs) without running")
    args = ap.parse_args(argv)
    if args.from_results is not None:
        rows = [json.loads(line) for line in (args.from_results / "results.jsonl").read_text().splitlines() if line]
        methods = [m for m in args.methods if any(r["method"] == m for r in rows)]
        print_tables(rows, methods, args.from_results, f"from {args.from_results}")
        return 0
    out = args.out or Path(tempfile.mkdtemp(prefix="xgen-bench-"))
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(f, s) for f in args.families for s in range(args.first_seed, args.first_seed + args.seeds)]
    ideal = f", ideal: {' '.join(args.ideal)}" if args.ideal else ""
    ideal += f", head profiles {args.head_profiles}" + (f", graph {args.graph}" if args.graph else "")
    print(f"# xgen held-out exam: {len(jobs)} logs into {out}{ideal}; load {os.getloadavg()[0]:.2f}", flush=True)
    rows = []
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool, open(out / "results.jsonl", "w") as fh:
        futures = [pool.submit(one_log, f, s, out, args.methods, args.max_time, args.ideal, args.head_profiles,
                               args.graph)
                   for f, s in jobs]
        for fut in futures:
            res = fut.result()
            for r in res:
                fh.write(json.dumps(r) + "\n")
                fh.flush()
                if r["method"] != "installed":
                    s = r.get("sensors") or []
                    xy = log_xy_mm(r) if s else float("nan")
                    print(f"{r['family']:>9} seed {r['seed']:>3} {r['method']:>11}: rc {r['rc']} xy {xy:7.1f} mm "
                          f"cpu {r['cpu_s']:.1f} s  ({r['n_sensors']} sensors, AMCL {r['amcl_kind']}, "
                          f"cov x{r['cov_factor']}, clocks {r['clock_offsets']}, odom {r['odometry']})", flush=True)
                    if r["rc"] != 0:
                        print("   " + r.get("stderr", "").strip().replace("\n", "\n   "), flush=True)
            rows += res
    print_tables(rows, args.methods, out, f"seeds {args.first_seed}..{args.first_seed + args.seeds - 1}, "
                                          f"load {os.getloadavg()[0]:.2f} at the end")
    return 0


def print_tables(rows, methods, out: Path, title: str):
    attach_sensor_info(rows, out)
    attach_sigma_split(rows, out)
    print()
    print(table(rows, methods, title))
    print()
    print(per_log_table(rows, methods))
    print()
    print(shape_table(rows, methods))
    print()
    print(table(rows, methods, "by what the log drew (pooled over families)", by_log_nuisance(rows), "logs with"))
    print()
    sensor_groups = by_sensor(rows, "mount") + by_sensor(rows, "profile")
    print(table(rows, methods, "by sensor (pooled over families)", sensor_groups,
                "sensors"))
    for m in methods:
        text = honesty_table(rows, m, by_family(rows) + by_log_nuisance(rows) + sensor_groups,
                             f"{m}: the sigma's honesty, intervals from a bootstrap over the logs")
        if text:
            print()
            print(text)
    for m in methods:
        text = split_honesty_table(rows, m, by_family(rows) + by_log_nuisance(rows),
                                   f"{m}: the sigma's honesty split as the error is: the shared part and each sensor's "
                                   "about it")
        if text:
            print()
            print(text)
    for m in methods:
        text = sink_tilt_table(rows, m, out)
        if text:
            print()
            print(text)


if __name__ == "__main__":
    raise SystemExit(main())
