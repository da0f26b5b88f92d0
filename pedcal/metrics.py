"""The papers' accuracy figures.

Calibration (Kimoto et al., Tables I and II):
- sensor position RMS: root mean square over sensors of the position error against the truth,
  per axis (x, y, z) and combined (the 3-D error), in mm; orientation error is the geodesic angle
  between the estimated and true rotations, in degrees.
- head tracking RMS: the robot's observations recomputed with the given extrinsics
  (p_world = T_given · p_sensor, with p_sensor undone from the installed extrinsics) against the
  robot's head at the same instants: the true head (truth_robot.csv) when the log has it, else the
  AMCL head (robot.csv) as the paper did.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from pedcal import frames
from pedcal.calib.common import robot_head_at
from pedcal.errors import warnings_at_caller
from pedcal.model import Log, SensorNetwork, rows_by_code, sensor_codes
from pedcal.options import require

# Extra top-level key of a calibrated YAML: the tracker latency the calibration estimated (s).
# Observation stamps are that much later than the instant the head was where it was seen.
LATENCY_KEY = "tracker_latency_s"
# ... and each sensor's clock offset about it with its sigma ({sensor: s}; pedcal.calib.clocks).
CLOCK_OFFSET_KEY = "clock_offset_s"
SIGMA_CLOCK_OFFSET_KEY = "sigma_clock_offset_s"
SIGMA_LATENCY_KEY = "sigma_tracker_latency_s"


def sensor_time_correction_s(extra: dict, sensors: np.ndarray, latency_s: float) -> np.ndarray:
    """What to subtract from each observation's stamp (``sensors``: its sensor id) under a
    calibrated YAML's top-level ``extra``: the tracker latency plus the sensor's clock offset."""
    table = {str(k): float(v) for k, v in (extra.get(CLOCK_OFFSET_KEY) or {}).items()}
    if not table:
        return np.full(len(sensors), latency_s)
    return latency_s + np.array([table.get(str(s), 0.0) for s in sensors], float)


# Extra top-level key of a calibrated YAML: the radius (m) of the head dome the calibration
# modelled. A tracker sees the point of the dome that faces it; the head top is that point moved
# r along the viewing ray (to the dome centre) and r up. Absent or 0: points are taken as seen.
HEAD_RADIUS_KEY = "head_radius_m"
# Extra top-level mapping of a calibrated YAML: the head-point model the calibration estimated.
# The tracker's head point is the head top moved ``vertical_offset_m`` up (negative: below the
# top), then ``ray_shift_m`` along the viewing ray toward the sensor (a dome of radius r:
# vertical offset -r, ray shift r), ``horizontal_shift_m`` horizontally toward it and
# ``curvature_m`` x cos^2(the sensor's elevation) up, with their sigmas.
HEAD_MODEL_KEY = "head_model"
# Extra top-level mapping: the joint covariance (m^2) of all sensors' positions, world axes,
# {sensors: [ids], matrix: 3n x 3n}; the per-sensor sigma are the square roots of its diagonal.
JOINT_COV_KEY = "position_covariance_m2"
# Extra top-level mapping: residuals against the noise model, per sensor, and the sensors whose
# residuals the model does not explain (their sigma widened by that ratio).
MISMATCH_KEY = "model_mismatch"
# Extra top-level mappings of the factor graph's YAML: AMCL's error model it estimated (white and
# wandering std, correlation time, jumps left out) and the sensors' noise it estimated from the
# log (depth floor and growth with range, lateral); information for the reader, not applied.
AMCL_MODEL_KEY = "amcl_error_model"
NOISE_KEY = "observation_noise"
# Extra top-level mapping of the factor graph's YAML when the log has wheel odometry: its distance
# scale and heading drifts (per metre, per second) as calibrated against AMCL and corrected in the
# graph against what the sensors saw, with the graph's sigma; information, not applied.
ODOMETRY_MODEL_KEY = "odometry_model"


def network_sigma_split(extrinsics: SensorNetwork) -> dict | None:
    """The sensors' position uncertainty split as the benches split their error: per world axis
    (m) the std of the network's common position (the mean of its ok sensors' positions: what
    every sensor shares, AMCL's error averaged over the run among it, and the head point's
    height) and the root of the mean over those sensors of the variance of each one's departure
    from that mean, from the calibrated file's joint covariance (``position_covariance_m2``).
    With C_ij the 3 x 3 blocks of the k ok sensors, the common covariance is sum_ij C_ij / k^2 and
    a departure's variances the diagonal of C_ii - (sum_j C_ij + sum_j C_ji) / k + the common one,
    diag C_ii - 2 diag sum_j C_ij / k + the common variances (C is symmetric); the two squares add
    up to the mean of the sensors' own variances. Returns {"common_m": [x, y, z], "relative_rms_m":
    [x, y, z], "sensors": k, "ids": [the k sensors]}, or None without a joint covariance or an ok
    sensor: one of the covariance's sensors with status ok or none given in ``extrinsics`` (a
    sensor left at its installed pose would count its prior; one the network lacks is not
    counted; a sensor outside the covariance is in neither part)."""
    cov = extrinsics.extra.get(JOINT_COV_KEY)
    if not isinstance(cov, dict) or "sensors" not in cov or "matrix" not in cov:
        return None
    ids = [str(i) for i in cov["sensors"]]
    n = len(ids)
    M = np.asarray(cov["matrix"], float)
    if M.shape != (3 * n, 3 * n):
        raise ValueError(f"{JOINT_COV_KEY}: a {M.shape} matrix for {n} sensors, expected {3 * n} x {3 * n}")
    status = {s.id: s.status for s in extrinsics}
    ok = np.array([i for i, sid in enumerate(ids) if sid in status and status[sid] in (None, "ok")], int)
    if not len(ok):
        return None
    k = len(ok)
    C = M.reshape(n, 3, n, 3)[ok][:, :, ok, :]                   # (k, 3, k, 3): the ok sensors' blocks
    var_common = np.einsum("iaja->a", C) / k ** 2                # diag of sum_ij C_ij / k^2
    own = np.einsum("iaia->ia", C)                                # diag C_ii, per sensor
    row = np.einsum("iaja->ia", C)                                # diag sum_j C_ij, per sensor
    var_rest = np.clip(np.mean(own - 2.0 * row / k, axis=0) + var_common, 0.0, None)
    var_common = np.clip(var_common, 0.0, None)
    return {"common_m": np.sqrt(var_common).tolist(), "relative_rms_m": np.sqrt(var_rest).tolist(), "sensors": k,
            "ids": [ids[i] for i in ok]}


def head_model_of(extrinsics: SensorNetwork) -> tuple[float, float, float, float]:
    """(vertical offset, ray shift, horizontal shift, curvature), m, of the head point an
    extrinsics file carries: its ``head_model``, else a dome of ``head_radius_m`` (older
    files), else the head top itself."""
    hm = extrinsics.extra.get(HEAD_MODEL_KEY)
    if isinstance(hm, dict):
        return tuple(float(hm.get(k, 0.0) or 0.0)
                     for k in ("vertical_offset_m", "ray_shift_m", "horizontal_shift_m", "curvature_m"))
    r = float(extrinsics.extra.get(HEAD_RADIUS_KEY, 0.0) or 0.0)
    return -r, r, 0.0, 0.0


@dataclass
class PositionRMS:
    """Root mean square over sensors of the position error (mm): per world axis and in 3-D."""

    x: float
    y: float
    z: float
    combined: float

    @property
    def horizontal(self) -> float:
        """sqrt(x^2 + y^2): the RMS of the horizontal error."""
        return float(np.hypot(self.x, self.y))

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class SensorError:
    id: str
    position_error_mm: list[float]      # estimated - true, world axes
    position_error_norm_mm: float
    orientation_error_deg: float
    head_rms_mm: float | None
    head_observations: int


@dataclass
class EvaluationResult:
    sensor_position_rms_mm: PositionRMS | None
    orientation_rms_deg: float | None
    head_tracking_rms_mm: float | None
    head_reference: str                           # truth_robot | robot (AMCL)
    head_observations: int
    robot_rows: str                               # how the robot's observations were picked
    sensors: list[SensorError] = field(default_factory=list)
    missing_sensors: list[str] = field(default_factory=list)      # in the log, not in the extrinsics
    # in the extrinsics, not in the log's sensors.yaml (a file of another site, sensors renamed): not scored
    foreign_sensors: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """The figures as nested plain values (``pedcal evaluate --json``); ``to_dataframe()``
        gives the per-sensor part as a table."""
        return asdict(self)

    def to_dataframe(self) -> pd.DataFrame:
        """One row per scored sensor, indexed by id: ``error_x_mm``, ``error_y_mm``, ``error_z_mm``
        (estimated - true, world axes), ``position_error_norm_mm``, ``orientation_error_deg``,
        ``head_rms_mm`` (NaN without head observations) and ``head_observations``."""
        rows = [{"id": s.id, **dict(zip(("error_x_mm", "error_y_mm", "error_z_mm"), map(float, s.position_error_mm),
                                        strict=True)),
                 "position_error_norm_mm": s.position_error_norm_mm, "orientation_error_deg": s.orientation_error_deg,
                 "head_rms_mm": np.nan if s.head_rms_mm is None else s.head_rms_mm,
                 "head_observations": s.head_observations} for s in self.sensors]
        columns = ["id", "error_x_mm", "error_y_mm", "error_z_mm", "position_error_norm_mm", "orientation_error_deg",
                   "head_rms_mm", "head_observations"]
        return pd.DataFrame(rows, columns=columns).set_index("id")

    def format_table(self) -> str:
        out = []
        if self.sensor_position_rms_mm is not None:
            r = self.sensor_position_rms_mm
            out.append(f"sensor position RMS (mm): x {r.x:.2f}  y {r.y:.2f}  z {r.z:.2f}  "
                       f"combined {r.combined:.2f}")
            out.append(f"orientation RMS (deg):    {self.orientation_rms_deg:.3f}")
        if self.head_tracking_rms_mm is not None:
            out.append(f"head tracking RMS (mm):   {self.head_tracking_rms_mm:.2f}  "
                       f"(against {self.head_reference}, {self.head_observations} observations; "
                       f"robot rows from {self.robot_rows})")
        out.append(f"{'sensor':>8s} {'pos err (mm)':>14s} {'orient (deg)':>13s} {'head RMS (mm)':>14s} {'obs':>6s}")
        for s in self.sensors:
            head = "-" if s.head_rms_mm is None else f"{s.head_rms_mm:.1f}"
            out.append(f"{s.id:>8s} {s.position_error_norm_mm:14.1f} {s.orientation_error_deg:13.3f} "
                       f"{head:>14s} {s.head_observations:6d}")
        if self.missing_sensors:
            out.append(f"not in the extrinsics file (not scored): {id_listing(self.missing_sensors)}")
        if self.foreign_sensors:
            out.append(f"not in the log's sensors.yaml (not scored): {id_listing(self.foreign_sensors)}")
        return "\n".join(out)


def id_listing(ids: list[str], first: int = 10) -> str:
    """Sensor ids on one line: the first ``first``, then how many in all (a file of another site
    can name hundreds); the whole list is in the result (``to_dict``)."""
    return ", ".join(ids[:first]) + (f", ... ({len(ids)} in all)" if len(ids) > first else "")


def robot_rows(log: Log) -> tuple[np.ndarray, str]:
    """Mask of the robot's observations: from truth_observations.csv when present, else picked
    out by pedcal's association."""
    if log.truth_observations is not None:
        who = log.truth_observations.set_index("row")["who"].astype(str)
        mask = np.zeros(len(log.observations), dtype=bool)
        rows = who.index[who == "robot"].to_numpy(int)
        mask[rows] = True
        return mask, "truth_observations"
    from pedcal.calib.association import associate_robot

    return associate_robot(log).is_robot, "association"


def amcl_run_mean_error_m(log: Log) -> np.ndarray | None:
    """AMCL's position error averaged over the log's run (world x, y, m), from truth_robot.csv
    (None without it): the error every calibration anchored to AMCL shares, which no
    calibration from this log can remove."""
    if log.truth_robot is None or log.robot is None or not len(log.robot):
        return None
    t = log.robot["t"].to_numpy(float)
    truth = robot_truth_xy(log, t)
    return (log.robot[["x", "y"]].to_numpy(float) - truth).mean(axis=0)


def robot_truth_xy(log: Log, t: np.ndarray) -> np.ndarray:
    """The robot base's true (x, y) at times ``t`` (linear in truth_robot.csv)."""
    from pedcal.calib.common import interpolate_pose2

    return interpolate_pose2(log.truth_robot, t)[:, :2]


def reproject_observations(log: Log, extrinsics: SensorNetwork, mask: np.ndarray | None = None) -> np.ndarray:
    """World head points of the observations recomputed with ``extrinsics`` (NaN for sensors the
    extrinsics do not name), with the head-point model the extrinsics file carries (each
    sensor's own horizontal shift, ``per_sensor_shift_m``, where it names one)."""
    from pedcal.calib.headpoint import horizontal_distance, own_shift, shift_at

    vertical_m, ray_m, horizontal_m, curvature_m = head_model_of(extrinsics)
    hm = extrinsics.extra.get(HEAD_MODEL_KEY)
    profile = hm.get("horizontal_profile") if isinstance(hm, dict) else None
    own_shifts = (hm.get("per_sensor_shift_m") if isinstance(hm, dict) else None) or {}
    p_sensor = log.observation_points_sensor()
    sensor_col = log.observations["sensor"].astype(str).to_numpy()
    out = np.full_like(p_sensor, np.nan)
    for s in extrinsics:
        m = sensor_col == s.id
        if mask is not None:
            m &= mask
        if m.any():
            p = p_sensor[m]
            # the head point moved back horizontally, down by the curvature and along the ray by
            # the shifts, then up by minus the offset: the top
            if profile is not None:        # the shift against horizontal distance (pedcal.calib.headpoint)
                toward = frames.toward_sensor_horizontal(p, s.R_world_sensor)
                # and this sensor's own departure from it, where one was kept (the shared shift at d_0 is shift_m[0])
                own = own_shift(profile, s.id)
                p = p - (shift_at(profile, horizontal_distance(p, toward)) + own)[:, None] * toward
            else:
                # the shared shift, or this sensor's own where the calibration estimated one
                own_m = float(own_shifts.get(s.id, horizontal_m))
                if own_m:
                    p = p - own_m * frames.toward_sensor_horizontal(p, s.R_world_sensor)
            if curvature_m:
                p = p - curvature_m * frames.up_by_cos2_elevation(p, s.R_world_sensor)
            p = p + ray_m * p / np.linalg.norm(p, axis=1, keepdims=True)
            out[m] = s.to_world(p) - np.array([0.0, 0.0, vertical_m])
    return out


@warnings_at_caller
def evaluate(log: Log, extrinsics: SensorNetwork) -> EvaluationResult:
    """The papers' figures of ``extrinsics`` on ``log`` (see the module docstring)."""
    require(log, "log", Log, "a pedcal.Log (pedcal.read_log(PATH))")
    require(extrinsics, "extrinsics", SensorNetwork, "a pedcal.SensorNetwork (pedcal.read_sensors_yaml(PATH))")
    # sets of ids: a network's look-up rebuilds its index on a miss (it cannot tell an absent id
    # from one added since), so a miss per sensor would be quadratic
    log_ids, extrinsics_ids = set(log.sensors.ids), set(extrinsics.ids)
    missing = [sid for sid in log.sensors.ids if sid not in extrinsics_ids]
    foreign = [s.id for s in extrinsics if s.id not in log_ids]
    per_sensor: dict[str, dict] = {}

    pos_rms = orient_rms = None
    if log.truth is not None:
        errs, angs = [], []
        truth_ids = set(log.truth.ids)
        for s in extrinsics:
            if s.id not in truth_ids:
                continue
            true = log.truth[s.id]
            e_mm = 1000.0 * (s.position_m - true.position_m)
            ang = frames.rotation_angle_deg(true.R_world_sensor, s.R_world_sensor)
            errs.append(e_mm)
            angs.append(ang)
            per_sensor[s.id] = dict(position_error_mm=e_mm.tolist(),
                                    position_error_norm_mm=float(np.linalg.norm(e_mm)),
                                    orientation_error_deg=ang)
        if errs:
            E = np.array(errs)
            pos_rms = PositionRMS(*(float(np.sqrt(np.mean(E[:, k] ** 2))) for k in range(3)),
                                  combined=float(np.sqrt(np.mean(np.sum(E ** 2, axis=1)))))
            orient_rms = float(np.sqrt(np.mean(np.square(angs))))

    mask, how = robot_rows(log)
    latency_s = float(extrinsics.extra.get(LATENCY_KEY, 0.0) or 0.0)
    head_rms = None
    n_head = 0
    sensor_col = log.observations["sensor"].astype(str).to_numpy()
    if mask.any():
        p_world = reproject_observations(log, extrinsics, mask)
        # the tracker latency plus each sensor's own clock offset (pedcal.calib.clocks)
        t = log.observations["t"].to_numpy(float) - sensor_time_correction_s(extrinsics.extra, sensor_col, latency_s)
        use = mask & np.isfinite(p_world[:, 0])
        reference = "truth_robot" if log.truth_robot is not None else "robot (AMCL)"
        head = np.full_like(p_world, np.nan)
        head[use] = robot_head_at(log, t[use], truth=log.truth_robot is not None)
        d2 = np.sum((p_world - head) ** 2, axis=1)
        n_head = int(use.sum())
        if n_head:
            head_rms = float(1000.0 * np.sqrt(np.mean(d2[use])))
        # each sensor's rows from the column's codes (not a comparison of every row per sensor)
        codes, names = sensor_codes(log.observations["sensor"])
        rows_of = dict(zip(names.tolist(), rows_by_code(codes, len(names)), strict=True))
        for s in extrinsics:
            if s.id not in log_ids:       # another site's sensor: listed in foreign_sensors, not scored
                continue
            rows = rows_of.get(s.id, np.zeros(0, np.int64))
            rows = rows[use[rows]]
            per_sensor.setdefault(s.id, dict(position_error_mm=[np.nan] * 3, position_error_norm_mm=np.nan,
                                             orientation_error_deg=np.nan))
            per_sensor[s.id]["head_rms_mm"] = float(1000.0 * np.sqrt(np.mean(d2[rows]))) if len(rows) else None
            per_sensor[s.id]["head_observations"] = int(len(rows))
    else:
        reference = "none: no robot observations"

    sensors = [SensorError(id=sid, head_rms_mm=v.get("head_rms_mm"), head_observations=v.get("head_observations", 0),
                           position_error_mm=v["position_error_mm"],
                           position_error_norm_mm=v["position_error_norm_mm"],
                           orientation_error_deg=v["orientation_error_deg"])
               for sid, v in per_sensor.items()]
    return EvaluationResult(sensor_position_rms_mm=pos_rms, orientation_rms_deg=orient_rms,
                            head_tracking_rms_mm=head_rms, head_reference=reference,
                            head_observations=n_head, robot_rows=how, sensors=sensors,
                            missing_sensors=missing, foreign_sensors=foreign)


# --- the reported sigma's honesty over many logs -------------------------------------------------
# A calibration's sensors share much of their error (AMCL's error over the run, the head point's
# model), so a log is one draw of it, not one per sensor: a share pooled over the sensors of a
# few logs is as uncertain as those few draws. The figures below take the log as the unit of
# resampling.

# fewer logs than this get no interval: a bootstrap over one or two logs only repeats them
MIN_LOGS_FOR_INTERVAL = 3


def _rows(a) -> np.ndarray:
    """``a`` as a float array of rows (n, axes): a flat one is one axis."""
    a = np.asarray(a, float)
    return a[:, None] if a.ndim == 1 else a


def within_sigma_share(ratios: np.ndarray, k: float = 1.0) -> np.ndarray:
    """Per axis, the share (0-1) of ``ratios`` (n, axes): |error| / sigma, inf for a miss (a sensor
    not calibrated, without a sigma or left out) that are <= ``k``; NaN for an axis with no rows.
    A miss counts in the denominator and never within."""
    r = _rows(ratios)
    if not len(r):
        return np.full(r.shape[1], np.nan)
    # a miss (inf) and NaN compare False: outside, in the denominator
    return np.mean(r <= k, axis=0)


def sigma_ratio_rms(ratios: np.ndarray) -> np.ndarray:
    """Per axis, the root mean square of the finite |error| / sigma ``ratios`` (n, axes): 1 when
    the sigma is honest, below 1 when it is too wide (which the share within 1 sigma alone would
    reward), above 1 when it is too narrow. Misses (inf, NaN) are left out (the share within
    sigma counts them); NaN for an axis with no finite ratio."""
    r = _rows(ratios)
    out = np.full(r.shape[1], np.nan)
    for a in range(r.shape[1]):
        col = r[np.isfinite(r[:, a]), a]
        if len(col):
            out[a] = float(np.sqrt(np.mean(col ** 2)))
    return out


@dataclass
class ClusteredFigure:
    """A figure pooled over the sensors of many logs, per axis, with its percentile interval
    from a bootstrap over the logs (each resample draws logs with replacement and pools all of
    their sensors): ``estimate``, ``low``, ``high`` (axes,), over ``logs`` logs and ``rows``
    sensors, at confidence ``level``; ``misses`` of the rows hold a non-finite value (of
    |error| / sigma ratios: the sensors missed, which :func:`sigma_ratio_rms` leaves out, so a
    method may look honest by dropping sensors: print the count beside it)."""

    estimate: np.ndarray
    low: np.ndarray
    high: np.ndarray
    logs: int
    rows: int
    level: float
    misses: int = 0


def log_bootstrap(per_log: list[np.ndarray], statistic, n_boot: int = 2000, seed: int = 0,
                  level: float = 0.9) -> ClusteredFigure:
    """``statistic`` (a function of the pooled (n, axes) rows, giving (axes,)) of the rows of
    ``per_log`` (one (n_i, axes) array per log) with its ``level`` percentile interval from
    ``n_boot`` resamples of the logs with replacement (seeded by ``seed``): the interval a
    share of a few logs' sensors deserves, their errors being shared within a log. Logs without
    rows are kept as logs (their resample adds nothing). NaN statistics of a resample (no rows)
    are left out of the percentiles. With one log the interval is the point. Rows with a
    non-finite value are counted (``misses``)."""
    blocks = [_rows(b) for b in per_log]
    if not blocks:
        raise ValueError("log_bootstrap needs at least one log")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    axes = max(b.shape[1] for b in blocks)
    blocks = [b if len(b) else np.zeros((0, axes)) for b in blocks]
    pooled = np.concatenate(blocks)
    estimate = np.asarray(statistic(pooled), float)
    rng = np.random.default_rng(seed)
    draws = np.array([np.asarray(statistic(np.concatenate([blocks[i] for i in pick])), float)
                      for pick in rng.integers(0, len(blocks), (n_boot, len(blocks)))]).reshape(n_boot, -1)
    tail = 100 * (1.0 - level) / 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # an axis NaN in every resample
        low = np.nanpercentile(draws, tail, axis=0)
        high = np.nanpercentile(draws, 100 - tail, axis=0)
    misses = int(np.sum(~np.all(np.isfinite(pooled), axis=1)))
    return ClusteredFigure(estimate=estimate, low=low, high=high, logs=len(blocks), rows=len(pooled), level=level,
                           misses=misses)


def sigma_honesty(per_log_ratios: list[np.ndarray], n_boot: int = 2000, seed: int = 0,
                  level: float = 0.9) -> tuple[ClusteredFigure, ClusteredFigure]:
    """(share within 1 sigma, error / sigma RMS) per axis of the |error| / sigma ratios of many
    logs (one (n_i, axes) array per log, inf for a miss), each with its interval from a
    bootstrap over the logs (:func:`log_bootstrap`, the same resamples for both)."""
    return (log_bootstrap(per_log_ratios, within_sigma_share, n_boot, seed, level),
            log_bootstrap(per_log_ratios, sigma_ratio_rms, n_boot, seed, level))


def format_clustered(fig: ClusteredFigure, scale: float = 1.0, digits: int = 0, unit: str = "logs") -> str:
    """'a [lo-hi] / b [lo-hi] / ...' per axis, each value times ``scale``; with fewer than
    MIN_LOGS_FOR_INTERVAL logs (``unit`` names them) the estimates alone, 'a / b / ... (N logs: no
    interval)': a bootstrap over one or two logs only repeats them, a width of nothing."""
    def f(v):
        return "-" if not np.isfinite(v) else f"{scale * v:.{digits}f}"

    if fig.logs < MIN_LOGS_FOR_INTERVAL:
        return " / ".join(f(e) for e in fig.estimate) + f" ({fig.logs} {unit}: no interval)"
    return " / ".join(f"{f(e)} [{f(lo)}-{f(hi)}]" for e, lo, hi in zip(fig.estimate, fig.low, fig.high, strict=True))
