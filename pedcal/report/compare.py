"""Compare calibrations (extrinsics files) on a user's own log: a table and figures.

Each file is scored with ``pedcal.metrics.evaluate``: against the true extrinsics and the true
robot path when the log has them (truth.yaml, truth_robot.csv), otherwise the head tracking RMS of
the robot's observations recomputed with each file against the robot's AMCL head (robot.csv), as
Kimoto et al. did. The log's installed extrinsics (sensors.yaml) are scored beside them.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.io.atomic import write_text_atomic
from pedcal.report import figures
from pedcal.report.build import FIG_DIR, fmt
from pedcal.report.results import json_text
from pedcal.report.sweep import MAX_HEAD_POINTS, head_track_records, robot_path_records, thin_mask


def _labels(paths: list[Path]) -> list[str]:
    """File stems, or the paths as given when two files share a stem."""
    stems = [p.stem for p in paths]
    return [s if stems.count(s) == 1 and s != "installed" else str(p) for s, p in zip(stems, paths, strict=True)]


def compare_extrinsics(log_path, extrinsics, out_dir: str | Path | None = None,
                       *, progress: bool = True) -> Path:
    """Score each extrinsics file (and the installed extrinsics) on the log at ``log_path``;
    write ``report.md``, ``results.json`` and figures into ``out_dir`` (default:
    ``report-<log name>``). Returns the report's path.

    ``log_path`` may be a :class:`pedcal.model.Log` in memory; ``extrinsics`` a list of YAML paths
    and/or SensorNetworks, or a mapping {label: path or SensorNetwork}."""
    from pedcal.errors import PedcalInputError
    from pedcal.io import read_log, read_sensors_yaml
    from pedcal.metrics import evaluate, robot_rows
    from pedcal.model import Log, SensorNetwork

    given_log = log_path if isinstance(log_path, Log) else None
    log_path = Path(log_path) if given_log is None else Path(given_log.path or "log")
    names = list(extrinsics) if isinstance(extrinsics, dict) else None
    items = list(extrinsics.values()) if names is not None else list(extrinsics)
    paths = [Path(f"extrinsics{i + 1}") if isinstance(p, SensorNetwork) else Path(p) for i, p in enumerate(items)]
    if not paths:
        raise PedcalInputError("give at least one --extrinsics file to compare on the log", path=log_path)
    out_dir = Path(out_dir) if out_dir is not None else Path(f"report-{log_path.resolve().name}")
    networks = [p if isinstance(p, SensorNetwork) else read_sensors_yaml(p) for p in items]  # a bad file names it
    log = given_log if given_log is not None else read_log(log_path)
    labels = ["installed", *(map(str, names) if names is not None else _labels(paths))]
    networks = [log.sensors, *networks]
    files = ["sensors.yaml (in the log)", *("(in memory)" if isinstance(p, SensorNetwork) else str(p) for p in items)]

    has_truth, has_truth_robot = log.truth is not None, log.truth_robot is not None
    mask, how = robot_rows(log)
    keep = thin_mask(mask, MAX_HEAD_POINTS)
    summary, per_sensor, heads = [], [], []
    for label, net, file in zip(labels, networks, files, strict=True):
        if progress:
            logging.getLogger(__name__).info(f"report: scoring {label}")
        ev = evaluate(log, net)
        summary.append(dict(label=label, file=file,
                            sensor_rms_mm=None if ev.sensor_position_rms_mm is None
                            else ev.sensor_position_rms_mm.combined,
                            orientation_rms_deg=ev.orientation_rms_deg, head_rms_mm=ev.head_tracking_rms_mm,
                            head_reference=ev.head_reference, head_observations=ev.head_observations,
                            statuses={s.id: s.status for s in net if s.status},
                            missing_sensors=ev.missing_sensors))
        per_sensor += [dict(label=label, sensor=e.id, position_error_mm=e.position_error_norm_mm,
                            orientation_error_deg=e.orientation_error_deg, head_rms_mm=e.head_rms_mm,
                            head_observations=e.head_observations) for e in ev.sensors]
        heads += head_track_records(log, net, keep, method=label)

    ref = log.truth if has_truth else log.sensors
    sensors_df = pd.DataFrame([dict(sensor=s.id, true_x_m=s.position_m[0], true_y_m=s.position_m[1],
                                    true_yaw_deg=s.ypr_deg[0]) for s in ref])
    robot_df = pd.DataFrame(robot_path_records(log, truth=has_truth_robot))
    reference = "the robot's true head path" if has_truth_robot else "the robot's AMCL head path (robot.csv)"

    command = " ".join(["pedcal report", str(log_path), *(f"--extrinsics {p}" for p in paths), f"--out {out_dir}"])
    lines = ["# pedcal calibration comparison", "", "Regenerate with:", "", "```sh", command, "```", "",
             f"Log: `{log_path}` ({len(log.observations)} observations, {len(log.sensors)} sensors). "
             f"Robot observations picked out by {how}; head tracking RMS against {reference}"
             + ("; sensor errors against truth.yaml." if has_truth else
                "; the log has no truth.yaml, so sensor position errors cannot be scored."),
             "", "| extrinsics | file | sensor position RMS (mm) | orientation RMS (deg) | head tracking RMS (mm) "
             "| head observations | sensors not ok |", "|---|---|---|---|---|---|---|"]
    for r in summary:
        bad = [f"{k}: {v}" for k, v in sorted(r["statuses"].items()) if v != "ok"]
        bad += [f"{k}: missing" for k in r["missing_sensors"]]
        lines.append(f"| {r['label']} | `{r['file']}` | {fmt(_f(r['sensor_rms_mm']))} "
                     f"| {fmt(_f(r['orientation_rms_deg']), 3)} | {fmt(_f(r['head_rms_mm']))} "
                     f"| {r['head_observations']} | {', '.join(bad) or '–'} |")
    ps = pd.DataFrame(per_sensor)
    lines += ["", "## Per sensor", "", "Head tracking RMS (mm)" + (" / position error (mm)" if has_truth else "")
              + " of each sensor.", "", "| sensor | " + " | ".join(labels) + " |",
              "|---|" + "---|" * len(labels)]
    for sid in sorted(ps["sensor"].unique()):
        cells = []
        for lab in labels:
            r = ps[(ps["sensor"] == sid) & (ps["label"] == lab)]
            if r.empty:
                cells.append("–")
                continue
            c = fmt(_f(r["head_rms_mm"].iloc[0]))
            cells.append(c + (f" / {fmt(_f(r['position_error_mm'].iloc[0]))}" if has_truth else ""))
        lines.append(f"| {sid} | " + " | ".join(cells) + " |")

    fig_lines = []
    if ps["head_rms_mm"].notna().any():
        figures.save_png(figures.head_rms_bars(ps, "head tracking RMS per sensor"),
                         out_dir / FIG_DIR / "head_rms_per_sensor.png")
        fig_lines.append(f"![head tracking RMS per sensor]({FIG_DIR}/head_rms_per_sensor.png)")
    if heads:
        fig = figures.head_trajectories(pd.DataFrame(heads), robot_df, sensors_df, labels,
                                        "robot's head computed with each calibration", ref_label=reference,
                                        sensor_label="sensor (" + ("true" if has_truth else "installed")
                                        + " position, arrow: view)")
        figures.save_png(fig, out_dir / FIG_DIR / "trajectories.png")
        fig_lines.append(f"![head trajectories]({FIG_DIR}/trajectories.png)")
    if fig_lines:
        lines += ["", "## Figures", "", "Triangles: the sensors' " + ("true" if has_truth else "installed")
                  + " positions and viewing directions."]
        for line in fig_lines:
            lines += ["", line]
    write_text_atomic(out_dir / "results.json", json_text({"command": command, "summary": _clean(summary),
                                                            "sensors": _clean(per_sensor)}))
    path = out_dir / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def _f(x) -> float:
    return np.nan if x is None else float(x)


def _clean(obj):
    """JSON-safe copy: NaN -> None, numpy scalars -> Python."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj
