"""Pre-flight checks: before a command allocates anything, the input is validated and the memory
(or time) it would take is estimated and compared with a stated limit. A log stamped in
nanoseconds, or a person seen once at t = 0 and once at t = 1e7 s, is refused with the figure and
the option that raises the limit, instead of exhausting the machine.
"""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.model import Log
from pedcal.options import check, require, require_path

# The factor graph (pedcal.calib.factorgraph) holds a robot pose at every AMCL stamp with gaps longer
# than 0.25 s filled, and a node of the AMCL error process every 1 s; each costs GTSAM values,
# factors, Jacobians and the elimination's fill-in. Bytes per item are set above the measured peak
# RSS growth: benchmarks/bench_preflight_memory.py prints both (sparse log driven 4 times: 126 MB
# estimated, 45-78 MB measured).
POSE_GAP_S = 0.25
AMCL_NODE_SPACING_S = 1.0
BYTES_PER_POSE = 16_000
BYTES_PER_AMCL_NODE = 4_000
BYTES_PER_OBSERVATION = 1_000
DEFAULT_MAX_MEMORY_GB = 4.0
# A robot that never comes this close (horizontally) to any ceiling sensor cannot be seen by one:
# robot.csv and sensors.yaml are then in different frames or units.
MAX_NEAREST_APPROACH_M = 100.0

# pedcal follow simulates FRAME_HZ frames per second of the target's trajectory.
FOLLOW_FRAME_HZ = 4.0
DEFAULT_MAX_FOLLOW_S = 3600.0

_limits = {"max_memory_gb": DEFAULT_MAX_MEMORY_GB, "max_follow_s": DEFAULT_MAX_FOLLOW_S}


@contextlib.contextmanager
def limits(**values):
    """Set limits (``max_memory_gb``, ``max_follow_s``) for the calls inside; None keeps the default."""
    check(**values)
    old = dict(_limits)
    _limits.update({k: v for k, v in values.items() if v is not None})
    try:
        yield
    finally:
        _limits.clear()
        _limits.update(old)


def calibration_memory_bytes(log: Log) -> float:
    """Upper estimate of the calibration's memory: robot poses (AMCL stamps, gaps filled every
    POSE_GAP_S), AMCL error nodes over the time span, and observations."""
    t = np.unique(log.robot["t"].to_numpy(dtype=float))
    span = float(t[-1] - t[0]) if len(t) else 0.0
    fill = float(np.maximum(np.ceil(np.diff(t) / POSE_GAP_S) - 1.0, 0.0).sum()) if len(t) > 1 else 0.0
    n_pose = len(t) + fill
    n_nodes = span / AMCL_NODE_SPACING_S + 1.0
    return n_pose * BYTES_PER_POSE + n_nodes * BYTES_PER_AMCL_NODE + len(log.observations) * BYTES_PER_OBSERVATION


def check_calibration(log: Log, max_memory_gb: float | None = None) -> Log:
    """Validate ``log`` (pedcal.io.validate) and refuse it when calibrating would need more than
    ``max_memory_gb``; returns the validated log."""
    from pedcal.io.logdir import validate

    require(log, "log", Log, "a pedcal.Log (pedcal.read_log(PATH) reads a log directory)")
    check(max_memory_gb=max_memory_gb)
    log = validate(log, _sources(log), rows_required=False)
    if len(log.observations) == 0:     # said at once, not after the method has set up every sensor
        where = _sources(log).get("observations", "Log.observations")
        warnings.warn(f"{where}: no observations (the table has no rows): none of the {len(log.sensors)} sensors "
                      "can be calibrated; each comes back with status no-data", DegenerateDataWarning, stacklevel=3)
    check_robot_near_sensors(log)
    limit_gb = _limits["max_memory_gb"] if max_memory_gb is None else float(max_memory_gb)
    need = calibration_memory_bytes(log)
    if need > limit_gb * 1e9:
        t = log.robot["t"].to_numpy(dtype=float)
        raise PedcalInputError(
            f"calibrating would need about {need / 1e9:.3g} GB (robot times span {t.max() - t.min():.6g} s, "
            f"{len(t)} poses, gaps filled every {POSE_GAP_S} s); the limit is {limit_gb:g} GB: raise it with "
            "--max-memory-gb (calibrate(..., max_memory_gb=...)) if the span is right, otherwise check the time unit "
            "(seconds)", path=_sources(log).get("robot", "Log.robot"), column="t")
    return log


def check_robot_near_sensors(log: Log) -> None:
    """The robot must pass within MAX_NEAREST_APPROACH_M of some sensor (one map frame, metres)."""
    from scipy.spatial import cKDTree

    if len(log.robot) == 0:
        return
    sensors_xy = np.array([s.position_m[:2] for s in log.sensors])
    robot_xy = log.robot[["x", "y"]].to_numpy(dtype=float)
    dist, _ = cKDTree(sensors_xy).query(robot_xy, k=1)
    row = int(np.argmin(dist))
    if dist[row] > MAX_NEAREST_APPROACH_M:
        sources = _sources(log)
        raise PedcalInputError(
            f"the robot never comes within {MAX_NEAREST_APPROACH_M:g} m of a sensor (nearest approach "
            f"{dist[row]:.6g} m, at x={robot_xy[row, 0]:.6g} m, y={robot_xy[row, 1]:.6g} m; sensors in "
            f"{Path(str(sources.get('sensors', 'Log.sensors'))).name} lie within x {sensors_xy[:, 0].min():.4g} .. "
            f"{sensors_xy[:, 0].max():.4g} m, y {sensors_xy[:, 1].min():.4g} .. {sensors_xy[:, 1].max():.4g} m): "
            "are both in the same map frame and in metres?", path=sources.get("robot", "Log.robot"), column="x")


def _sources(log: Log) -> dict:
    """The files a log read from disk came from, so errors name them."""
    if log.path is None:
        return {}
    directory = Path(log.path)
    out = {"sensors": directory / "sensors.yaml"}
    for name in ("robot", "observations", "odometry", "truth_robot", "truth_observations"):
        for ext in ("csv", "parquet"):
            if (directory / f"{name}.{ext}").is_file():
                out[name] = directory / f"{name}.{ext}"
    return out


def check_follow_people(people_csv, target_id: str | None) -> pd.DataFrame:
    """Read and validate a people file for ``pedcal follow --people`` and refuse a target whose
    trajectory would take more than the frame limit to simulate; returns the people table."""
    from pedcal.io.pedestrians import read_pedestrians

    if target_id is None:
        raise PedcalInputError("--people needs --target (the person carrying the transmitter)",
                               path=None if isinstance(people_csv, pd.DataFrame) else people_csv)
    if isinstance(people_csv, pd.DataFrame):     # a table in memory gets the checks of a file
        from pedcal.io.people import validate_people

        people = validate_people(people_csv)
        people_csv = "people table"
    else:
        people = read_pedestrians(require_path(people_csv, "people_csv"))
    tgt = people["t"].to_numpy(dtype=float)[people["person"].astype(str).to_numpy() == str(target_id)]
    if len(tgt) >= 2:
        span = float(tgt.max() - tgt.min())
        limit = float(_limits["max_follow_s"])
        if span > limit:
            raise PedcalInputError(
                f"target {target_id!r} is seen over {span:.6g} s ({span * FOLLOW_FRAME_HZ:.3g} frames at "
                f"{FOLLOW_FRAME_HZ:g} Hz to simulate); the limit is {limit:g} s: raise it with --max-duration-s if "
                "the span is right, otherwise check the time unit (seconds) and gaps in the trajectory",
                path=people_csv, column="t")
    return people
