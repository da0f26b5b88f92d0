"""Robot and head paths as TUM trajectory files, so ``evo`` (evo_ape / evo_rpe tum ...) can score them.

TUM format: one pose per line, ``timestamp tx ty tz qx qy qz qw`` (s, m, unit quaternion), comment
lines start with ``#``; times strictly increase.

:func:`write_tum` writes, from a log:

- ``robot.tum``: robot.csv, the localization's base path (z = 0, yaw about z)
- ``head.tum``: the robot's head top from robot.csv and meta.yaml's head offset (what the ceiling
  sensors should see)
- ``truth_robot.tum``, ``truth_head.tum``: the same from truth_robot.csv, when the log has it
- ``head_<label>.tum``: the robot's head as the ceiling sensors saw it, recomputed with each
  extrinsics given (and ``head_installed.tum`` with the log's sensors.yaml), as ``pedcal evaluate``
  scores it: the head-point model of the extrinsics file undone (``head_model``) and its tracker
  latency applied, each point stamped at the observation's time minus ``tracker_latency_s`` and
  its sensor's ``clock_offset_s`` (the instant the head was there under that calibration; the
  file's header comment states the latency). Head points carry the
  identity orientation ``0 0 0 1`` (a point has none); observations at the same time are averaged.

evo pairs two paths' poses whose stamps differ by at most ``--t_max_diff`` (default 0.01 s). The
observed head paths are at the trackers' stamps, the reference at its own rate (truth_head.tum:
the simulator's truth rate, 20 Hz; head.tum: AMCL's), so pass half the reference's period
(``evo_ape tum truth_head.tum head_X.tum --t_max_diff 0.025``) to pair every observation with its
nearest reference pose; with the default, 10 ms of every 50 ms pair.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pedcal.errors import warnings_at_caller
from pedcal.io.atomic import write_text_atomic
from pedcal.model import Log, SensorNetwork


def tum_text(t: np.ndarray, xyz: np.ndarray, q_xyzw: np.ndarray | None = None, comment: str = "") -> str:
    """TUM lines, rows sorted by time; ``q_xyzw`` None -> identity."""
    t = np.asarray(t, float)
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)) if q_xyzw is None else np.asarray(q_xyzw, float)
    order = np.argsort(t, kind="stable")
    rows = np.column_stack([t, xyz, q])[order]
    head = f"# {comment}\n# timestamp tx ty tz qx qy qz qw\n" if comment else "# timestamp tx ty tz qx qy qz qw\n"
    return head + "".join(" ".join(repr(float(v)) for v in r) + "\n" for r in rows)


def read_tum(path: str | Path) -> pd.DataFrame:
    """A TUM file -> columns t, x, y, z, qx, qy, qz, qw."""
    return pd.DataFrame(np.loadtxt(path, comments="#", ndmin=2),
                        columns=["t", "x", "y", "z", "qx", "qy", "qz", "qw"])


def _base_path(track: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    track = track.groupby("t", sort=True)[["x", "y", "yaw"]].first().reset_index()
    xyz = np.column_stack([track["x"], track["y"], np.zeros(len(track))])
    return track["t"].to_numpy(float), xyz, Rotation.from_euler("z", track["yaw"].to_numpy(float)[:, None]).as_quat()


def _label(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", text)


@warnings_at_caller
def write_tum(log: Log, out_dir: str | Path, extrinsics: dict[str, SensorNetwork] | None = None) -> dict[str, Path]:
    """Write the TUM files of the module docstring into ``out_dir`` (atomically); returns
    {name: path}. ``extrinsics``: {label: SensorNetwork} to recompute the observed head path with."""
    from pedcal.calib.common import head_world
    from pedcal.metrics import (
        CLOCK_OFFSET_KEY,
        LATENCY_KEY,
        reproject_observations,
        robot_rows,
        sensor_time_correction_s,
    )

    out_dir = Path(out_dir)
    written: dict[str, Path] = {}

    def put(name: str, t, xyz, q=None, comment: str = "") -> None:
        p = out_dir / f"{name}.tum"
        write_text_atomic(p, tum_text(t, xyz, q, comment))
        written[name] = p

    for prefix, track in (("", log.robot), ("truth_", log.truth_robot)):
        if track is None:
            continue
        t, xyz, q = _base_path(track)
        put(f"{prefix}robot", t, xyz, q, f"{prefix}robot base path (map frame)")
        pose2 = np.column_stack([xyz[:, :2], Rotation.from_quat(q).as_euler("ZYX")[:, 0]])
        put(f"{prefix}head", t, head_world(pose2, log.meta.head_offset_m),
            comment=f"{prefix}robot head top, head offset {list(map(float, log.meta.head_offset_m))}")
    networks = {"installed": log.sensors, **(extrinsics or {})}
    if len(log.observations):
        mask, how = robot_rows(log)
        if not mask.any():
            logging.getLogger(__name__).warning("no observation of the robot found: no observed head path written")
            return written
        t_stamp = log.observations["t"].to_numpy(float)[mask]
        sensors = log.observations["sensor"].astype(str).to_numpy()[mask]
        for label, net in networks.items():
            # at the instant the head was there: less the tracker latency and each sensor's clock
            # offset a calibration estimated (none for the installed extrinsics)
            t_obs = t_stamp - sensor_time_correction_s(net.extra, sensors,
                                                       float(net.extra.get(LATENCY_KEY, 0.0) or 0.0))
            pts = reproject_observations(log, net, mask)[mask]
            ok = np.isfinite(pts).all(axis=1)
            if not ok.any():
                continue
            latency_s = float(net.extra.get(LATENCY_KEY, 0.0) or 0.0)     # as pedcal evaluate applies it
            mean = pd.DataFrame(pts[ok], columns=["x", "y", "z"]).groupby(t_obs[ok], sort=True).mean()
            put(f"head_{_label(label)}", mean.index.to_numpy(float), mean.to_numpy(float),
                comment=f"robot head seen by the ceiling sensors with the {label} extrinsics (rows by {how}), "
                        f"stamped at the observation time minus the tracker latency {latency_s!r} s"
                        + (" and each sensor's clock offset" if net.extra.get(CLOCK_OFFSET_KEY) else ""))
    return written
