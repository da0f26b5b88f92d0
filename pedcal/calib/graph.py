"""The graph layer of pedcal's estimator: one GTSAM factor graph of the ceiling sensors, the
robot's poses and people, built from a log (:func:`prepare`, :func:`build_graph`), solved
(:func:`optimize_graph`) and read back into a calibrated network. The batch solver
(:mod:`pedcal.calib.factorgraph`) and the incremental one (:mod:`pedcal.calib.online`) both
build on it.

Variables
- ``s(i)``: ``Pose3`` T_world_sensor of every ceiling sensor, with a weak prior at the installed
  (hand-measured) extrinsics.
- ``x(k)``: ``Pose3`` of the robot's head frame (the base pose lifted to the head point's
  height, the head top plus the vertical offset, "Head point" below) at the AMCL stamps (gaps
  longer than ``max_pose_gap_s`` are filled). An observation made between two stamps is carried
  to the nearest one by the robot's own short-term motion (wheel odometry over at most half a
  stamp period, a few centimetres; without odometry AMCL, smoothed when it jitters), so the
  trajectory has one pose per AMCL stamp, not one per observation: there is nothing for it to
  bend with locally.
- ``a(j)``: ``Pose3`` (a pure world translation) of AMCL's slowly wandering error at stamp j.
- ``l(m)``: ``Point3`` of a person's head seen by two sensors at once.
- ``h(0)``: ``Pose3`` whose height is the head point's vertical offset (from its initial value);
  every AMCL error node's height is tied to it.

Factors (all GTSAM built-in C++ factors)
- AMCL: AMCL reports ``Z_j = E_j · X(t_j)`` where E_j is a slowly wandering world-frame error, a
  Gauss-Markov process (AMCL's particle cloud drifts over tens of seconds; it is not white).
  With ``F_j = E_j^{-1}`` as the variable ``a(j)``, ``BetweenFactorPose3(a(j), x(k), Z_j)`` has
  residual ``Log(Z_j^{-1} F_j^{-1} X)``. The process on F is the discretized Ornstein-Uhlenbeck
  prior: ``BetweenFactorPose3(a(j), a(j+1), I)`` with variance q = 2 sigma^2 dt / tau and a zero
  prior per node with variance 2 sigma^2 tau / dt (the precision operator of an OU process of
  stationary std sigma and correlation time tau). sigma comes from AMCL's reported covariance.
  AMCL's heading error is an OU process as well; it cannot be a world-frame rotation (that
  would swing the position about the map origin), so it is a white error per stamp inflated to
  2 tau / dt times its variance: the information an OU process holds about its mean over a run
  of length T >> tau (variance 2 sigma^2 tau / T). So the graph learns the run-average of AMCL,
  not its wander: sensors and trajectory are one rigid structure tied to the map by the average
  of all AMCL estimates.
- Odometry: ``BetweenFactorPose3`` between consecutive robot poses from the wheel odometry
  after its systematic errors are estimated and removed (:func:`calibrate_odometry`: distance
  scale, heading drift per metre and per second, fitted against AMCL over the whole run). What
  is left is white per step (a random walk growing with sqrt(dt)) plus a small residual scale
  and heading-drift term; without odometry a motion-smoothness factor from AMCL's increments.
- Planarity: roll, pitch and height of the robot are held by the priors of each pose.
- Robot observations: ``BearingRangeFactorPose3(s(i), x(k))`` measuring the sensor-frame head
  point as a bearing and a range, with the head point's shifts taken out: the horizontal one
  subtracted from the point, the one along the ray added to the range (``|p| + rho``). Depth
  noise grows with range squared (doubled past the reliable range); a robust kernel keeps
  mis-associations (a pedestrian beside the robot) from dragging.
- People seen by two sensors at once (matched by
  :func:`pedcal.calib.alternative.match_shared_observations`): ``BearingRangeFactor3D(s(i),
  l(m))`` for each sensor.

Head point. Trackers report different points of a head (the blob's highest point, a dome's point
facing the sensor, the centroid of the head's top, a fitted ellipsoid's centre): the graph takes
the reported point as the head top moved ``vertical_offset`` up, then ``rho`` along the ray toward
the sensor and ``horizontal`` horizontally toward it (a dome of radius r: -r, r, 0). The vertical
offset is the variable h(0); a uniform offset moves every robot observation down alike, which
the robot alone cannot tell from the sensors' common height, so without a height reference (the
installed sensor heights or a ceiling height with their sigma, a prior on each sensor's world
height) it is held by its prior (a dome's: offset = -rho, give or take head_vertical_sigma_m) and
its sigma reaches every sensor's height. rho and the horizontal shift enter the measurements and
are estimated around the graph by their profile likelihood (:mod:`pedcal.calib.factorgraph`).

Tracker latency is estimated once, by the association's pooled estimator
(:func:`pedcal.calib.association.estimate_latency`: per-sensor rigid fits against the AMCL spline,
minimized over the latency), and written to the calibrated YAML (``tracker_latency_s``). Within
the graph a latency error is mostly absorbed by the trajectory (a few millimetres along the
track), so re-solving for it buys little.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path

import gtsam
import numpy as np
import pandas as pd

from pedcal import frames
from pedcal.calib.common import HeadModel, ModelMismatch, head_interpolator, head_world, interpolate_pose2
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.frames import toward_sensor_horizontal
from pedcal.io.sensors_yaml import flow_vector
from pedcal.metrics import HEAD_MODEL_KEY, JOINT_COV_KEY, LATENCY_KEY, MISMATCH_KEY
from pedcal.model import Log, SensorExtrinsics, SensorNetwork

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

S = gtsam.symbol_shorthand.S
X = gtsam.symbol_shorthand.X
A = gtsam.symbol_shorthand.A
L = gtsam.symbol_shorthand.L
H = gtsam.symbol_shorthand.H

GRAPHS_DIR = Path(__file__).resolve().parents[2] / "graphs"


# ------------------------------------------------------------------------------------------ recipe
@dataclass
class GraphRecipe:
    """Which factor families and noise models the graph holds (graphs/*.toml)."""

    name: str = "default"
    description: str = ""
    # factor families
    robot: bool = True              # the robot's observations (sensor -> head)
    odometry: bool = True           # wheel odometry between-factors when odometry.csv exists
    smoothness: bool = True         # motion smoothness when there is no odometry
    people: bool = True             # people seen by two or more sensors at once
    amcl: bool = True               # AMCL poses as a correlated-error measurement
    # sensor prior from the installed extrinsics (how far a hand measurement can be off)
    sensor_prior_sigma_m: float = 0.5
    sensor_prior_sigma_deg: float = 10.0
    # depth sensor model: sigma_range = floor + k r^2 (x far_factor past reliable_range_m),
    # lateral sigma of the head-top extraction (plus the latency jitter times the robot's speed)
    range_sigma_floor_m: float = 0.005
    range_sigma_k_per_m: float = 1.5e-3
    reliable_range_m: float = 3.5
    far_factor: float = 2.0
    lateral_sigma_m: float = 0.012
    # head-point model (module docstring, "Head point"): the prior is a dome of radius
    # head_radius_m (vertical offset -r, ray shift r); both are estimated unless
    # estimate_head_model is false
    head_radius_m: float = 0.05
    estimate_head_model: bool = True
    head_vertical_sigma_m: float = 0.03     # prior sigma of the vertical offset about -ray shift
    head_ray_shift_sigma_m: float = 0.05    # prior sigma of the shift toward the sensor
    head_ray_shift_step_m: float = 0.02     # step of the shifts' profile likelihood
    estimate_head_horizontal_shift: bool = False  # a constant horizontal shift toward the sensor too
    head_horizontal_shift_sigma_m: float = 0.05   # its prior sigma (mean 0)
    # height reference: the installed sensor heights measured to this sigma (0: no reference),
    # or, with ceiling_height_m > 0, every sensor at that height to this sigma
    sensor_height_sigma_m: float = 0.0
    ceiling_height_m: float = 0.0
    robust_kernel: str = "huber"    # huber | cauchy | tukey | none
    robust_k: float = 1.345
    # AMCL error process (std from AMCL's reported covariance)
    amcl_correlation_s: float = 20.0
    amcl_node_spacing_s: float = 1.0   # nodes of the error process (a small fraction of tau)
    amcl_white_fraction: float = 0.2   # share of AMCL's reported std that is white, per stamp
    # robot poses: one per AMCL stamp, gaps longer than this filled
    max_pose_gap_s: float = 0.25
    # odometry: systematic errors estimated and removed, then white noise per sqrt(second)
    # and a residual scale / heading drift
    odometry_calibrate: bool = True
    odometry_white_sigma_m: float = 0.005          # per sqrt(s)
    odometry_white_yaw_sigma_deg: float = 0.25     # per sqrt(s)
    odometry_sigma_per_m: float = 0.003            # residual scale error
    odometry_yaw_sigma_deg_per_m: float = 0.05     # residual heading drift
    smoothness_sigma_mps: float = 0.05
    # without odometry, AMCL jitter above this (m, amcl_white_sigma) makes the short-term motion
    # come from AMCL smoothed over amcl_smooth_s (s)
    amcl_smooth_above_m: float = 0.01
    amcl_smooth_s: float = 0.5
    # robot planarity
    planar_sigma_deg: float = 0.5
    head_height_sigma_m: float = 0.02
    # tracker latency
    estimate_latency: bool = True
    latency_max_s: float = 0.4
    # people association for shared observations (at most one shared point per period)
    people_sample_s: float = 0.5
    # initializer: closedform | gridsearch | installed
    init: str = "closedform"
    max_iterations: int = 50
    relative_error_tol: float = 1e-5

    @classmethod
    def load(cls, path: str | Path) -> GraphRecipe:
        path = Path(path)
        if not path.exists() and not path.suffix and (GRAPHS_DIR / f"{path}.toml").exists():
            path = GRAPHS_DIR / f"{path}.toml"
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise PedcalInputError("graph recipe not found", path=path) from None
        except tomllib.TOMLDecodeError as e:
            raise PedcalInputError(f"not valid TOML: {e}", path=path) from None
        flat = {}
        for k, v in data.items():
            if isinstance(v, dict):       # [sections] are only for readability
                flat.update(v)
            else:
                flat[k] = v
        known = {f.name: f for f in fields(cls)}
        for k, v in flat.items():
            if k not in known:
                raise PedcalInputError(f"unknown key '{k}', expected one of {', '.join(known)}", path=path)
            default = getattr(cls(), k)
            if isinstance(default, bool) != isinstance(v, bool) or (
                    isinstance(default, float) and not isinstance(v, (int, float))):
                raise PedcalInputError(f"key '{k}' must be {type(default).__name__}, got {v!r}", path=path)
        if "name" not in flat:
            flat["name"] = path.stem
        return cls(**flat)


# ---------------------------------------------------------------------------------------- helpers
def _log(progress: bool, msg: str) -> None:
    if progress:
        logging.getLogger(__name__).info(f"[factorgraph] {msg}")


def _robust(recipe: GraphRecipe, base):
    k = recipe.robust_kernel.lower()
    if k == "none":
        return base
    est = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
           "tukey": gtsam.noiseModel.mEstimator.Tukey}.get(k)
    if est is None:
        raise PedcalInputError(f"unknown robust kernel '{recipe.robust_kernel}'", column="robust_kernel")
    return gtsam.noiseModel.Robust.Create(est.Create(recipe.robust_k), base)


def head_frame(x: float, y: float, yaw: float, head_m: np.ndarray) -> gtsam.Pose3:
    """The robot's head frame: the base pose (x, y, yaw) composed with the head offset
    ``head_m`` (base frame; its z is the dome centre's height)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([x + c * head_m[0] - s * head_m[1],
                                                      y + s * head_m[0] + c * head_m[1], head_m[2]]))


def amcl_cov_body(cov_world: np.ndarray, yaw) -> np.ndarray:
    """AMCL's (x, y, yaw) world covariance as a Pose3 tangent covariance [rx, ry, rz, tx, ty, tz]
    in the body frame (GTSAM's convention), without the roll/pitch/z blocks. Vectorized: a
    (N, 3, 3) stack with N yaws gives (N, 6, 6)."""
    C = np.asarray(cov_world, float)
    yaw = np.asarray(yaw, float)
    c, s = np.cos(yaw), np.sin(yaw)
    Rt = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)        # world -> body for xy
    out = np.zeros(C.shape[:-2] + (6, 6))
    out[..., 2, 2] = C[..., 2, 2]
    out[..., 3:5, 3:5] = Rt @ C[..., :2, :2] @ np.swapaxes(Rt, -1, -2)
    cross = (Rt @ C[..., :2, 2:3])[..., 0]
    out[..., 3:5, 2] = cross
    out[..., 2, 3:5] = cross
    return out


def smoothed_track(track: pd.DataFrame, sigma_s: float) -> pd.DataFrame:
    """A t/x/y/yaw table smoothed by a Gaussian of ``sigma_s`` seconds (x, y and unwrapped yaw;
    the samples taken as evenly spaced at their median interval; ends by reflection)."""
    from scipy.ndimage import gaussian_filter1d

    tr = track.groupby("t", sort=True)[["x", "y", "yaw"]].mean()
    t = tr.index.to_numpy(float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    s = max(sigma_s / dt, 1e-6)
    xy_yaw = np.column_stack([tr["x"].to_numpy(float), tr["y"].to_numpy(float), np.unwrap(tr["yaw"].to_numpy(float))])
    out = gaussian_filter1d(xy_yaw, s, axis=0, mode="reflect")
    return pd.DataFrame({"t": t, "x": out[:, 0], "y": out[:, 1], "yaw": out[:, 2]})


def amcl_white_sigma(amcl: pd.DataFrame) -> float:
    """Std (m) of the white part of AMCL's position error, from its own jitter: on a smooth
    trajectory each estimate's departure from the straight line through its two neighbours (in
    time: AMCL publishes irregularly) is a white error times sqrt(1 + a^2 + b^2), a and b the
    neighbours' interpolation weights (the robot's acceleration adds millimetres at AMCL's
    rates; a slowly wandering error adds less). Median absolute deviation, so jumps and turns do
    not count."""
    tr = amcl.groupby("t", sort=True)[["x", "y"]].mean()
    t, p = tr.index.to_numpy(float), tr.to_numpy(float)
    if len(t) < 10:
        return 0.0
    b = ((t[1:-1] - t[:-2]) / (t[2:] - t[:-2]))[:, None]      # weight of the next estimate
    e = (p[1:-1] - ((1.0 - b) * p[:-2] + b * p[2:])) / np.sqrt(1.0 + (1.0 - b) ** 2 + b ** 2)
    mad = np.median(np.abs(e - np.median(e, axis=0)), axis=0)
    return float(1.4826 * np.sqrt(np.mean(mad ** 2)))


def observation_sigmas(recipe: GraphRecipe, range_m: np.ndarray) -> np.ndarray:
    """(N, 3) sigmas [bearing rad, bearing rad, range m] of a head seen at ``range_m``:
    structured-light depth noise grows with range squared (Khoshelham and Elberink 2012),
    doubled past the reliable range; the lateral error is a distance across the ray."""
    r = np.asarray(range_m, float)
    sig_r = recipe.range_sigma_floor_m + recipe.range_sigma_k_per_m * r ** 2
    sig_r = np.where(r > recipe.reliable_range_m, recipe.far_factor * sig_r, sig_r)
    sig_b = recipe.lateral_sigma_m / np.maximum(r, 0.3)
    return np.column_stack([sig_b, sig_b, sig_r])


class _NoiseCache:
    """Noise models of observations, built once per (rounded) range: a few hundred C++ objects
    instead of one per observation."""

    def __init__(self, recipe: GraphRecipe, step_m: float = 0.01):
        self.recipe, self.step_m, self.cache = recipe, step_m, {}

    def keys(self, range_m: np.ndarray) -> np.ndarray:
        return np.round(np.asarray(range_m, float) / self.step_m).astype(int)

    def __call__(self, range_m: float | None = None, key: int | None = None):
        key = int(round(range_m / self.step_m)) if key is None else int(key)
        nm = self.cache.get(key)
        if nm is None:
            sig = observation_sigmas(self.recipe, np.array([key * self.step_m]))[0]
            nm = self.cache[key] = _robust(self.recipe, gtsam.noiseModel.Diagonal.Sigmas(sig))
        return nm


# -------------------------------------------------------------------------------------- odometry
def calibrate_odometry(odometry: pd.DataFrame, amcl: pd.DataFrame, window_s: float = 20.0,
                       amcl_correlation_s: float = 20.0, drift_prior_deg_per_m: float = 2.0,
                       drift_prior_deg_per_s: float = 0.2):
    """Wheel odometry with its systematic errors removed: a heading drift per metre driven and
    per second (wheel-base error, gyro bias) from a least-squares fit of the odometry-minus-AMCL
    heading against distance and time over the whole run, and the distance scale from the
    displacements over ``window_s`` windows (AMCL's wander averages out over many windows).
    At a steady speed distance and time are nearly collinear, so the two drifts are held by a
    weak prior (``drift_prior_*``, far beyond a working odometry's) and the AMCL heading samples
    are weighted as the independent ones they are: one per 2 x ``amcl_correlation_s``.
    Returns (DataFrame t, x, y, yaw in the odometry frame, dict of the estimates)."""
    odo = odometry.sort_values("t")
    t = odo["t"].to_numpy(float)
    xy = odo[["x", "y"]].to_numpy(float)
    yaw = np.unwrap(odo["yaw"].to_numpy(float))
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    d = np.diff(xy, axis=0)
    fwd, left = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    dyaw, dt = np.diff(yaw), np.diff(t)
    dist = np.hypot(fwd, left)
    s_m = np.r_[0.0, np.cumsum(dist)]
    est = dict(scale=1.0, yaw_drift_deg_per_m=0.0, yaw_drift_deg_per_s=0.0)
    at = amcl.sort_values("t")
    ta = at["t"].to_numpy(float)
    inside = (t >= ta[0]) & (t <= ta[-1])
    if inside.sum() >= 10 and t[inside][-1] - t[inside][0] > 2 * window_s:
        yaw_a = np.interp(t[inside], ta, np.unwrap(at["yaw"].to_numpy(float)))
        diff = np.unwrap(yaw[inside] - yaw_a)
        n = int(inside.sum())
        span = t[inside][-1] - t[inside][0]
        sig_yaw = float(np.sqrt(np.median(at["cov_yawyaw"].to_numpy(float)))) if "cov_yawyaw" in at else 0.02
        # weight of one sample: n_eff / n independent samples of AMCL's heading std
        w = np.sqrt(max(span / (2.0 * amcl_correlation_s), 1.0) / n) / max(sig_yaw, 1e-4)
        M = np.column_stack([np.ones(n), s_m[inside], t[inside] - t[inside][0]]) * w
        prior = np.diag([0.0, 1.0 / np.radians(drift_prior_deg_per_m), 1.0 / np.radians(drift_prior_deg_per_s)])
        coef = np.linalg.lstsq(np.vstack([M, prior]), np.r_[diff * w, np.zeros(3)], rcond=None)[0]
        est["yaw_drift_deg_per_m"] = float(np.degrees(coef[1]))
        est["yaw_drift_deg_per_s"] = float(np.degrees(coef[2]))
        dyaw = dyaw - coef[1] * dist - coef[2] * dt
    yaw_c = np.r_[yaw[0], yaw[0] + np.cumsum(dyaw)]
    cc, sc = np.cos(yaw_c[:-1]), np.sin(yaw_c[:-1])
    xy_c = xy[0] + np.r_[np.zeros((1, 2)), np.cumsum(np.column_stack([cc * fwd - sc * left, sc * fwd + cc * left]),
                                                     axis=0)]
    if inside.sum() >= 10:
        edges = np.arange(max(t[0], ta[0]), min(t[-1], ta[-1]), window_s)
        if len(edges) >= 3:
            da = np.diff(np.column_stack([np.interp(edges, ta, at["x"].to_numpy(float)),
                                          np.interp(edges, ta, at["y"].to_numpy(float))]), axis=0)
            do = np.diff(np.column_stack([np.interp(edges, t, xy_c[:, 0]), np.interp(edges, t, xy_c[:, 1])]), axis=0)
            na, no = np.linalg.norm(da, axis=1), np.linalg.norm(do, axis=1)
            if np.sum(no ** 2) > 1.0:        # the robot drove at least a metre per window on average
                est["scale"] = float(np.sum(na * no) / np.sum(no ** 2))
    xy_c = xy_c[0] + est["scale"] * (xy_c - xy_c[0])
    return pd.DataFrame({"t": t, "x": xy_c[:, 0], "y": xy_c[:, 1], "yaw": yaw_c}), est


class _RobotMotion:
    """The robot's short-term motion: where the head moves between two nearby instants, from
    the (calibrated) wheel odometry rotated into the map by AMCL's heading, or from the AMCL
    spline when there is no odometry."""

    def __init__(self, log: Log, odometry: pd.DataFrame | None):
        self.head_offset = np.asarray(log.meta.head_offset_m, float)
        self.amcl_head = head_interpolator(log)
        self.odo = odometry
        if odometry is not None:
            amcl = log.robot.sort_values("t")
            self.ta = amcl["t"].to_numpy(float)
            self.yaw_a = np.unwrap(amcl["yaw"].to_numpy(float))

    def displacement(self, t_from: np.ndarray, t_to: np.ndarray) -> np.ndarray:
        """World displacement (N, 3) of the head top from ``t_from`` to ``t_to``."""
        if self.odo is None:
            return self.amcl_head(t_to) - self.amcl_head(t_from)
        h0 = head_world(interpolate_pose2(self.odo, t_from), self.head_offset)
        h1 = head_world(interpolate_pose2(self.odo, t_to), self.head_offset)
        mid = 0.5 * (t_from + t_to)
        # heading of the map relative to the odometry frame at that time (AMCL minus odometry)
        rot = np.interp(mid, self.ta, self.yaw_a) - interpolate_pose2(self.odo, mid)[:, 2]
        c, s = np.cos(rot), np.sin(rot)
        d = h1 - h0
        return np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]])

    def velocity(self, t: np.ndarray, h: float = 0.02) -> np.ndarray:
        return self.displacement(t - h, t + h) / (2 * h)


# ----------------------------------------------------------------------------------- the solver
@dataclass
class FactorGraphProblem:
    """Everything the graph needs, derived once from a log (kept for the online mode and tests)."""

    recipe: GraphRecipe
    latency_s: float
    sensor_ids: list[str]
    obs_sensor: np.ndarray          # sensor id per robot observation
    obs_p_raw: np.ndarray           # (N, 3) measured head points in the sensor frame
    obs_t_raw: np.ndarray           # observation stamps (s)
    pose_times: np.ndarray          # times of the robot pose variables
    init_sensors: dict[str, gtsam.Pose3]
    motion: _RobotMotion
    odometry: pd.DataFrame | None = None     # calibrated wheel odometry (odometry frame)
    odometry_estimates: dict = field(default_factory=dict)
    smoothed_amcl: pd.DataFrame | None = None    # AMCL smoothed, when it stands in for odometry
    people: list = field(default_factory=list)   # [(t, [(sensor, p_sensor), ...]), ...]
    rows_used: np.ndarray | None = None
    amcl_node_times: np.ndarray | None = None    # times of the AMCL error nodes a(j)
    # derived by carry_observations: latency-corrected instants, the pose each observation is
    # carried to, and the sensor-frame point carried there
    obs_t: np.ndarray | None = None
    obs_key_index: np.ndarray | None = None
    obs_p_sensor: np.ndarray | None = None
    obs_toward_sensor: np.ndarray | None = None   # horizontal unit toward the sensor, sensor frame
    # the head point's shift toward the sensor along the ray and horizontally (m) the graph is
    # built with
    ray_shift_m: float = 0.0
    horizontal_shift_m: float = 0.0

    def head_points_sensor(self) -> np.ndarray:
        """The robot observations (sensor frame) with the horizontal shift toward the sensor
        taken out: the head point moved ray_shift_m along the ray from the offset head top."""
        return self.obs_p_sensor - self.horizontal_shift_m * self.obs_toward_sensor

    def carry_observations(self, rotations: dict[str, np.ndarray]) -> None:
        """Carry every robot observation to its nearest pose variable: the head seen at
        t = stamp - latency is the head at the pose's time t_k minus the robot's motion from t
        to t_k, p_sensor(t_k) = p_sensor(t) + R_world_sensor^T (h(t_k) - h(t)). ``rotations``:
        current R_world_sensor per sensor (an error of a degree moves a point carried a few
        centimetres by under a millimetre)."""
        self.obs_t = self.obs_t_raw - self.latency_s
        tk = self.pose_times
        i = np.clip(np.searchsorted(tk, self.obs_t), 1, max(len(tk) - 1, 1))
        if len(tk) > 1:
            i = np.where(np.abs(tk[i - 1] - self.obs_t) <= np.abs(tk[i] - self.obs_t), i - 1, i)
        else:
            i = np.zeros(len(self.obs_t), int)
        self.obs_key_index = i
        disp = self.motion.displacement(self.obs_t, tk[i]) if len(self.obs_t) else np.zeros((0, 3))
        R = np.stack([rotations[s] for s in self.obs_sensor]) if len(self.obs_t) else np.zeros((0, 3, 3))
        self.obs_p_sensor = self.obs_p_raw + np.einsum("nji,nj->ni", R, disp)
        self.obs_toward_sensor = toward_sensor_horizontal(self.obs_p_sensor, R)


def _pose_grid(amcl_t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """The AMCL stamps, with gaps longer than ``max_gap_s`` filled evenly."""
    t = np.unique(amcl_t)
    gaps = np.diff(t)
    fill = [np.linspace(a, b, int(np.ceil((b - a) / max_gap_s)) + 1)[1:-1]
            for a, b, g in zip(t[:-1], t[1:], gaps, strict=True) if g > max_gap_s]
    return np.unique(np.concatenate([t, *fill])) if fill else t


def _height_reference(T: gtsam.Pose3, z_ref_m: float) -> gtsam.Pose3:
    """``T`` moved to the reference height."""
    t = np.array(T.translation(), float)
    t[2] = z_ref_m
    return gtsam.Pose3(T.rotation(), t)


def _height_noise(T: gtsam.Pose3, sigma_m: float):
    """A Pose3 prior that holds the world height alone to ``sigma_m``: its information in the
    body-frame tangent [rx ry rz tx ty tz] is (R^T e_z)(R^T e_z)^T / sigma^2 on the translation."""
    ez_body = T.rotation().matrix().T @ np.array([0.0, 0.0, 1.0])
    info = np.zeros((6, 6))
    info[3:, 3:] = np.outer(ez_body, ez_body) / sigma_m ** 2
    info += np.eye(6) * 1e-9
    return gtsam.noiseModel.Gaussian.Information(info)


def build_graph(log: Log, prob: FactorGraphProblem, *, t_max: float | None = None):
    """Build the factor graph and the initial values (optionally only with data up to t_max)."""
    rec = prob.recipe
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    head_m = np.asarray(log.meta.head_offset_m, float) - np.array([0.0, 0.0, rec.head_radius_m])

    rho = prob.ray_shift_m
    # Sensors: weak prior at the installed extrinsics; a height reference, when given, as a
    # prior on the world height alone (the Pose3 tangent is body-frame: world z is R^T e_z there).
    sig_rot = np.radians(rec.sensor_prior_sigma_deg)
    sensor_prior = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sig_rot] * 3, [rec.sensor_prior_sigma_m] * 3])
    for i, sid in enumerate(prob.sensor_ids):
        T_inst = log.sensors[sid].T_world_sensor
        graph.add(gtsam.PriorFactorPose3(S(i), T_inst, sensor_prior))
        values.insert(S(i), prob.init_sensors[sid])
        if rec.sensor_height_sigma_m > 0.0:
            z_ref = rec.ceiling_height_m if rec.ceiling_height_m > 0.0 else float(T_inst.translation()[2])
            # about the initial pose (close to the solution: the Pose3 logmap couples the
            # horizontal offset into the height by the rotation difference)
            T0 = prob.init_sensors[sid]
            graph.add(gtsam.PriorFactorPose3(S(i), _height_reference(T0, z_ref),
                                             _height_noise(T0, rec.sensor_height_sigma_m)))

    times = prob.pose_times if t_max is None else prob.pose_times[prob.pose_times <= t_max]
    n_pose = len(times)
    amcl = log.robot.sort_values("t")
    amcl_t = amcl["t"].to_numpy(float)
    spline_head = head_interpolator(log)
    # head frames on the AMCL spline: its position and the spline's heading
    pose_xy = spline_head(times)[:, :2] if n_pose else np.zeros((0, 2))
    base = interpolate_pose2(amcl, times)
    # Robot poses on the AMCL spline; roll, pitch and height held by a planarity prior (AMCL's
    # own factor holds them when it is in the graph).
    planar = gtsam.noiseModel.Diagonal.Sigmas(np.array(
        [np.radians(rec.planar_sigma_deg)] * 2 + [1e3, 1e3, 1e3, rec.head_height_sigma_m]))
    for k in range(n_pose):
        P = gtsam.Pose3(gtsam.Rot3.Yaw(base[k, 2]), np.array([pose_xy[k, 0], pose_xy[k, 1], head_m[2]]))
        values.insert(X(k), P)
        if not rec.amcl:
            graph.add(gtsam.PriorFactorPose3(X(k), P, planar))

    # AMCL as a measurement with a Gauss-Markov error (module docstring). The error process is
    # slow (tau ~ 20 s): its nodes are ``amcl_node_spacing_s`` apart, each stamp tied to the
    # nearest node with the OU's change over that interval (variance 2 sigma^2 |dt| / tau) as
    # extra white noise.
    if rec.amcl and n_pose:
        cov = amcl[["cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"]].to_numpy(float)
        sig_xy = max(float(np.sqrt(np.median(0.5 * (cov[:, 0] + cov[:, 3])))), 1e-3)
        white_var = max(amcl_white_sigma(amcl) ** 2 - rec.amcl_white_fraction ** 2 * sig_xy ** 2, 0.0)
        tau = rec.amcl_correlation_s
        k_of = np.searchsorted(times, amcl_t)
        use = np.flatnonzero((k_of < n_pose) & (times[np.minimum(k_of, n_pose - 1)] == amcl_t))
        dt_amcl = float(np.median(np.diff(amcl_t))) if len(amcl_t) > 1 else 1.0
        nodes = prob.amcl_node_times
        node_of = np.clip(np.round((amcl_t[use] - nodes[0]) / rec.amcl_node_spacing_s).astype(int), 0, len(nodes) - 1)
        tiny = np.radians(0.05)
        yaw_a = amcl["yaw"].to_numpy(float)[use]
        x_a, y_a = amcl["x"].to_numpy(float)[use], amcl["y"].to_numpy(float)[use]
        # AMCL's covariance in the body frame (amcl_cov_body); the slow error is a world-frame
        # translation (F is held to a pure translation), its white share stays here; the heading
        # error is white, inflated to the information of an OU mean (2 tau / dt).
        C3 = np.stack([np.stack([cov[use, 0], cov[use, 1], cov[use, 2]], -1),
                       np.stack([cov[use, 1], cov[use, 3], cov[use, 4]], -1),
                       np.stack([cov[use, 2], cov[use, 4], cov[use, 5]], -1)], -2)
        scale = np.array([1.0, 1.0, np.sqrt(max(1.0, 2.0 * tau / dt_amcl)), rec.amcl_white_fraction,
                          rec.amcl_white_fraction, 1.0])
        Cb = amcl_cov_body(C3, yaw_a) * np.outer(scale, scale)
        Cb[:, 0, 0] = Cb[:, 1, 1] = tiny ** 2
        drift_var = 2.0 * sig_xy ** 2 * np.abs(amcl_t[use] - nodes[node_of]) / tau
        # plus the OU's change since the node and, when AMCL's own jitter shows a white error
        # larger than the recipe's share of the reported one, the excess (amcl_white_sigma)
        Cb[:, 3:5, 3:5] += (drift_var + white_var)[:, None, None] * np.eye(2)
        Cb[:, 5, 5] = 1e-6
        for n, j in enumerate(use):
            Z = head_frame(x_a[n], y_a[n], yaw_a[n], head_m)
            graph.add(gtsam.BetweenFactorPose3(A(int(node_of[n])), X(int(k_of[j])), Z,
                                               gtsam.noiseModel.Gaussian.Covariance(Cb[n])))
        # discretized OU prior on the error process (module docstring)
        dn = rec.amcl_node_spacing_s
        sp, sq = np.sqrt(2.0 * tau / dn), np.sqrt(2.0 * dn / tau)
        # The head point's vertical offset from its prior (-head_radius_m) is the height of the
        # variable h: every AMCL error node's height is tied to it, so every robot pose, and with
        # it every head point the sensors see, moves up or down with it alike.
        free_z = rec.estimate_head_model
        prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([tiny, tiny, 1e-4, sig_xy * sp, sig_xy * sp,
                                                           1e2 if free_z else 1e-3]))
        q = gtsam.noiseModel.Diagonal.Sigmas(np.array([tiny, tiny, 1e-4, sig_xy * sq, sig_xy * sq, 1e-3]))
        n_nodes = int(node_of.max()) + 1 if len(use) else 0
        if free_z and n_nodes:
            # prior: the point lies on a dome, offset = -shift (a blob's top: both 0; a dome's
            # facing point: -r and r), give or take head_vertical_sigma_m; h's height is the
            # offset minus the initial -head_radius_m of the robot poses
            values.insert(H(0), gtsam.Pose3())
            h_prior = gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, rec.head_radius_m - rho]))
            graph.add(gtsam.PriorFactorPose3(H(0), h_prior, gtsam.noiseModel.Diagonal.Sigmas(
                np.array([tiny, tiny, tiny, 1e-4, 1e-4, rec.head_vertical_sigma_m]))))
            tie = gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, 1.0, 1e3, 1e3, 1e-4]))
        for m in range(n_nodes):
            values.insert(A(m), gtsam.Pose3())
            graph.add(gtsam.PriorFactorPose3(A(m), gtsam.Pose3(), prior))
            if m:
                graph.add(gtsam.BetweenFactorPose3(A(m - 1), A(m), gtsam.Pose3(), q))
            if free_z:
                graph.add(gtsam.BetweenFactorPose3(H(0), A(m), gtsam.Pose3(), tie))

    # Odometry (or smoothness) between consecutive robot poses.
    if n_pose > 1:
        src = None
        if rec.odometry and prob.odometry is not None:
            src = interpolate_pose2(prob.odometry, times)
            dt = np.diff(times)
            d = np.hypot(*np.diff(src[:, :2], axis=0).T)
            st = np.sqrt(rec.odometry_white_sigma_m ** 2 * dt + (rec.odometry_sigma_per_m * d) ** 2) + 1e-4
            sy = np.sqrt(np.radians(rec.odometry_white_yaw_sigma_deg) ** 2 * dt
                         + (np.radians(rec.odometry_yaw_sigma_deg_per_m) * d) ** 2) + 1e-5
        elif rec.smoothness:
            src = base if prob.smoothed_amcl is None else interpolate_pose2(prob.smoothed_amcl, times)
            dt = np.diff(times)
            # AMCL's short-term increments: error grows with dt, plus AMCL's white jitter at both ends
            st = np.sqrt((rec.smoothness_sigma_mps * dt) ** 2 + 2.0 * amcl_white_sigma(amcl) ** 2) + 1e-3
            sy = np.radians(2.0) * dt + 1e-4
        if src is not None:
            P = [head_frame(*src[k], head_m) for k in range(n_pose)]
            for k in range(n_pose - 1):
                nm = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, sy[k], st[k], st[k], 1e-3]))
                graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), P[k].between(P[k + 1]), nm))

    # Robot observations, carried to their pose variables (FactorGraphProblem.carry_observations).
    sid_index = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    noise = _NoiseCache(rec)
    if rec.robot:
        p_obs = prob.head_points_sensor()
        rng_m = np.linalg.norm(p_obs, axis=1)
        keys = [S(sid_index[s]) for s in prob.obs_sensor]
        noise_keys = noise.keys(rng_m)
        for n in np.flatnonzero(prob.obs_key_index < n_pose):
            graph.add(gtsam.BearingRangeFactorPose3(keys[n], X(int(prob.obs_key_index[n])),
                                                   gtsam.Unit3(p_obs[n]),
                                                   rng_m[n] + rho, noise(key=noise_keys[n])))

    # People seen by two or more sensors at once (the dome centre of their head).
    if rec.people:
        for m, (t, seen) in enumerate(prob.people):
            if t_max is not None and t > t_max:
                continue
            pts = []
            for sid, p in seen:
                R0 = prob.init_sensors[sid].rotation().matrix()
                p = p - prob.horizontal_shift_m * toward_sensor_horizontal(p[None, :], R0)[0]
                r = float(np.linalg.norm(p))
                graph.add(gtsam.BearingRangeFactor3D(S(sid_index[sid]), L(m), gtsam.Unit3(p),
                                                     r + rho, noise(r)))
                pts.append(prob.init_sensors[sid].transformFrom(p * (1.0 + rho / r)))
            values.insert(L(m), np.mean(pts, axis=0))
    return graph, values


def _shared_people(log: Log, is_robot: np.ndarray, recipe: GraphRecipe, network: SensorNetwork) -> list:
    """Instants where two sensors see the same person, matched by the alternative's
    shared-observation matcher on tracks that hold no robot observation (``is_robot``; all of
    them when the graph leaves the robot's poses out and the robot is one more person).
    Returns [(t, [(sensor, p_sensor), ...]), ...]."""
    from pedcal.calib.alternative import build_tracks, match_shared_observations

    tracks = {sid: [tr for tr in trs if not is_robot[tr.rows].any()] for sid, trs in build_tracks(log).items()}
    report = match_shared_observations(tracks, network, sample_period_s=recipe.people_sample_s)
    out = []
    for m in report.matches:
        for n in range(len(m.t)):
            out.append((float(m.t[n]), [(m.sensor_i, m.p_i_sensor[n]), (m.sensor_j, m.p_j_sensor[n])]))
    return sorted(out, key=lambda x: x[0])


def _initial_sensors(log: Log, recipe: GraphRecipe, is_robot, latency_s, progress,
                     init_network: SensorNetwork | None) -> dict[str, gtsam.Pose3]:
    if init_network is not None:
        init = {s.id: s.T_world_sensor for s in init_network}
    elif recipe.init in ("gridsearch", "closedform") and recipe.robot:
        from pedcal.calib import calibrate

        opts = dict(is_robot=is_robot) if recipe.init == "gridsearch" else dict(is_robot=is_robot,
                                                                                latency_s=latency_s)
        with warnings.catch_warnings():     # the graph reports degenerate sensors itself
            warnings.simplefilter("ignore", DegenerateDataWarning)
            res = calibrate(log, method=recipe.init, progress=progress, **opts)
        init = {s.id: s.T_world_sensor for s in res.network if s.status == "ok"}
    elif recipe.init in ("installed", "gridsearch", "closedform"):   # the latter two need the robot
        init = {}
    else:
        raise PedcalInputError(f"unknown initializer '{recipe.init}', expected closedform, gridsearch or "
                               "installed", column="init")
    for s in log.sensors:
        init.setdefault(s.id, s.T_world_sensor)
    return init


def prepare(log: Log, recipe: GraphRecipe, is_robot: np.ndarray | None = None, progress: bool = False,
            init_network: SensorNetwork | None = None) -> FactorGraphProblem:
    """Association, latency, odometry calibration, initial values, the pose grid, the robot's
    observations carried to it, and the people's shared observations."""
    from pedcal.calib.association import associate_robot, estimate_latency

    latency = None
    if not recipe.robot:
        # Without the robot's observations the robot is one more unlocalized person, as in the
        # alternative (SNAPCAT-3D): its tracks are shared sightings like anyone's, and no
        # association or latency is needed (a latency common to all sensors cancels between two).
        is_robot, latency = np.zeros(len(log.observations), bool), 0.0
    elif is_robot is None:
        _log(progress, "picking out the robot's observations")
        assoc = associate_robot(log)
        is_robot, latency = assoc.is_robot, assoc.latency_s
    is_robot = np.asarray(is_robot, bool)
    if not recipe.estimate_latency:
        latency = 0.0
    elif latency is None:
        latency = estimate_latency(log, is_robot, max_latency_s=recipe.latency_max_s) if is_robot.sum() >= 12 else 0.0
    _log(progress, f"tracker latency from the association: {1000 * latency:.0f} ms")
    obs = log.observations
    p_all = log.observation_points_sensor()
    sensor_col = obs["sensor"].astype(str).to_numpy()
    t_all = obs["t"].to_numpy(float)
    rows = np.flatnonzero(is_robot)
    amcl_t = log.robot["t"].to_numpy(float)
    t_lo, t_hi = amcl_t.min(), amcl_t.max()
    rows = rows[(t_all[rows] - latency >= t_lo) & (t_all[rows] - latency <= t_hi)]

    odometry, odo_est, smooth = None, {}, None
    if recipe.odometry and log.odometry is not None and len(log.odometry) > 1:
        if recipe.odometry_calibrate:
            odometry, odo_est = calibrate_odometry(log.odometry, log.robot,
                                                   amcl_correlation_s=recipe.amcl_correlation_s)
            _log(progress, "odometry: scale {scale:.4f}, heading drift {yaw_drift_deg_per_m:+.3f} deg/m "
                           "{yaw_drift_deg_per_s:+.4f} deg/s".format(**odo_est))
        else:
            odometry = log.odometry.sort_values("t")

    if odometry is None and amcl_white_sigma(log.robot) > recipe.amcl_smooth_above_m:
        # no odometry and a jittery AMCL: the robot's short-term motion (carrying observations to
        # their pose, the smoothness factor) from AMCL smoothed over amcl_smooth_s, not from
        # differences of single estimates that each carry the white error
        smooth = smoothed_track(log.robot, recipe.amcl_smooth_s)
        _log(progress, f"AMCL jitter {1000 * amcl_white_sigma(log.robot):.0f} mm: short-term motion from AMCL "
                       f"smoothed over {recipe.amcl_smooth_s:.1f} s")
    init = _initial_sensors(log, recipe, is_robot, latency, progress, init_network)
    # robot poses only when something observes them (people-only graphs hold the sensors alone)
    pose_times = _pose_grid(amcl_t, recipe.max_pose_gap_s) if recipe.robot else np.zeros(0)
    prob = FactorGraphProblem(recipe=recipe, latency_s=float(latency), sensor_ids=log.sensors.ids,
                              ray_shift_m=recipe.head_radius_m,
                              obs_sensor=sensor_col[rows], obs_p_raw=p_all[rows], obs_t_raw=t_all[rows],
                              pose_times=pose_times, init_sensors=init,
                              motion=_RobotMotion(log, odometry if odometry is not None else smooth),
                              odometry=odometry, smoothed_amcl=smooth,
                              odometry_estimates=odo_est, rows_used=rows)
    t_a = np.unique(amcl_t)
    prob.amcl_node_times = t_a[0] + recipe.amcl_node_spacing_s * np.arange(
        int(np.round((t_a[-1] - t_a[0]) / recipe.amcl_node_spacing_s)) + 1)
    prob.carry_observations({sid: T.rotation().matrix() for sid, T in init.items()})
    if recipe.people:
        net = SensorNetwork([SensorExtrinsics.from_pose3(sid, init[sid]) for sid in log.sensors.ids],
                            frame=log.sensors.frame)
        prob.people = _shared_people(log, is_robot, recipe, net)
    _log(progress, f"{len(rows)} robot observations, {len(pose_times)} robot poses, "
                   f"{len(prob.people)} shared person sightings")
    return prob


def sensor_sigma_world(T: gtsam.Pose3, cov_body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-axes position covariance and 1-sigma of position (m) and ypr (deg) from GTSAM's
    Pose3 marginal (body frame, rotation first)."""
    R = T.rotation().matrix()
    cov_pos_world = R @ cov_body[3:, 3:] @ R.T
    ypr0 = frames.ypr_deg_from_rot(R)
    J = np.zeros((3, 3))
    eps = 1e-6
    for c in range(3):
        w = np.zeros(3)
        w[c] = eps
        d = frames.ypr_deg_from_rot(R @ gtsam.Rot3.Expmap(w).matrix()) - ypr0
        J[:, c] = (d + 180.0) % 360.0 - 180.0
    J /= eps
    cov_ypr = J @ cov_body[:3, :3] @ J.T
    return cov_pos_world, np.sqrt(np.diag(cov_pos_world)), np.sqrt(np.maximum(np.diag(cov_ypr), 0.0))


def rotation_sigma_deg(cov_body: np.ndarray) -> np.ndarray:
    """1-sigma (deg) of a sensor's orientation as a rotation vector in its own frame (about its
    optical axis x, its y and its z), from GTSAM's Pose3 covariance (body frame, rotation
    first): defined at any pitch, unlike yaw/pitch/roll, whose yaw and roll blur together when
    the sensor looks straight down."""
    return np.degrees(np.sqrt(np.maximum(np.diag(cov_body)[:3], 0.0)))


_DIRECTION_NAMES_ROT = ("rotation about world x", "rotation about world y", "yaw")
_DIRECTION_NAMES_POS = ("x", "y", "z")


def observability(T: gtsam.Pose3, cov_body: np.ndarray, recipe: GraphRecipe, threshold: float = 0.5):
    """Directions of a sensor pose the data left unconstrained: eigen-directions of the posterior
    covariance whitened by the installed prior whose variance the data reduced by less than
    ``threshold`` (posterior sigma > threshold x prior sigma). Returns (names, whitened basis)."""
    p = np.r_[[np.radians(recipe.sensor_prior_sigma_deg)] * 3, [recipe.sensor_prior_sigma_m] * 3]
    Cw = cov_body / np.outer(p, p)
    evals, evecs = np.linalg.eigh(0.5 * (Cw + Cw.T))
    bad = evecs[:, evals > threshold ** 2]
    names = []
    R = T.rotation().matrix()
    for v in bad.T:     # whitened: rotation and translation parts are comparable
        if np.linalg.norm(v[:3]) >= np.linalg.norm(v[3:]):
            names.append(_DIRECTION_NAMES_ROT[int(np.argmax(np.abs(R @ v[:3])))])
        else:
            names.append(_DIRECTION_NAMES_POS[int(np.argmax(np.abs(R @ v[3:])))])
    return sorted(set(names)), bad


def optimize_graph(fg, values, recipe: GraphRecipe):
    """Levenberg-Marquardt from ``values``, then the vertical gauge settled; (result, iterations)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(recipe.max_iterations)
    params.setRelativeErrorTol(recipe.relative_error_tol)
    opt = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    result = _settle_vertical_gauge(fg, opt.optimize())
    return result, opt.iterations()


def _shift_up(values: gtsam.Values, dz_m: float) -> gtsam.Values:
    """``values`` with every sensor, robot pose, AMCL error, head model and person moved up."""
    out = gtsam.Values(values)
    up = np.array([0.0, 0.0, dz_m])
    for key in values.keys():
        c = chr(gtsam.Symbol(key).chr())
        if c in "sxah":
            P = values.atPose3(key)
            out.update(key, gtsam.Pose3(P.rotation(), P.translation() + up))
        elif c == "l":
            out.update(key, values.atPoint3(key) + up)
    return out


def _settle_vertical_gauge(fg, result: gtsam.Values, step_m: float = 0.01) -> gtsam.Values:
    """Move everything up or down together to the optimum of the priors. With the head model's
    vertical offset free, a common vertical shift of all variables changes no measurement factor,
    only the priors (the offset's, the sensors' installed heights, a height reference): a flat
    direction LM barely moves along (its damping scales with the Hessian's diagonal), so the
    solution would sit wherever the initial values put it. The error is quadratic along it: one
    parabola through three shifts finds the optimum."""
    if not result.exists(H(0)):
        return result
    e0, ep, em = fg.error(result), fg.error(_shift_up(result, step_m)), fg.error(_shift_up(result, -step_m))
    curv = (ep + em - 2.0 * e0) / step_m ** 2
    if not curv > 0.0:
        return result
    return _shift_up(result, -(ep - em) / (2.0 * step_m) / curv)


# Above this many sensors the joint position covariance (3n x 3n) stays on the CalibrationResult and
# is not written to the YAML: at 1000 sensors it would be 9 M numbers, about 100 MB of text.
JOINT_COV_MAX_SENSORS = 200


def finish_network(log: Log, prob: FactorGraphProblem, network: SensorNetwork, *, head_model: HeadModel | None = None,
                   joint_position_cov: np.ndarray | None = None, mismatch: ModelMismatch | None = None) -> np.ndarray:
    """Record the tracker model the graph used (latency, head-point model with its sigma), the
    joint covariance of the sensors' positions and the model check in the calibrated network and
    return the mask of the observations used as the robot's."""
    network.extra[LATENCY_KEY] = round(prob.latency_s, 4)
    if head_model is None:
        head_model = HeadModel(vertical_offset_m=-prob.recipe.head_radius_m, ray_shift_m=prob.ray_shift_m,
                               estimated=False)
    network.extra[HEAD_MODEL_KEY] = {k: (round(v, 5) if isinstance(v, float) else v)
                                     for k, v in head_model.to_dict().items() if v != ""}
    if joint_position_cov is not None and len(prob.sensor_ids) <= JOINT_COV_MAX_SENSORS:
        network.extra[JOINT_COV_KEY] = {"sensors": list(prob.sensor_ids), "order": "x y z per sensor",
                                        "matrix": [flow_vector([float(f"{v:.4e}") for v in row])
                                                   for row in joint_position_cov]}
    elif joint_position_cov is not None:
        logging.getLogger(__name__).warning(
            f"the joint covariance of {len(prob.sensor_ids)} sensors' positions ({3 * len(prob.sensor_ids)} x "
            f"{3 * len(prob.sensor_ids)}) is not written to the calibrated YAML above {JOINT_COV_MAX_SENSORS} "
            "sensors; it is on CalibrationResult.position_covariance_m2")
    if mismatch is not None:
        ratios = {k: round(v, 3) for k, v in mismatch.variance_ratio.items()}
        network.extra[MISMATCH_KEY] = {"sensors": mismatch.sensors, "threshold": mismatch.threshold,
                                       "variance_ratio": ratios, "misfit": mismatch.misfit}
    mask = np.zeros(len(log.observations), bool)
    mask[prob.rows_used] = True
    return mask


def _network_from_result(log: Log, prob: FactorGraphProblem, fg, result, progress: bool,
                         marginals: gtsam.Marginals | None = None,
                         cov_out: dict | None = None, cov_body: dict | None = None) -> SensorNetwork:
    """The calibrated network from the graph's solution; ``cov_out`` (optional) receives each
    sensor's world-axes position covariance (m^2). ``cov_body``: each sensor's Pose3 covariance
    (body frame, rotation first) when the caller has it, else the graph's marginals."""
    rec = prob.recipe
    if marginals is None and cov_body is None:
        marginals = gtsam.Marginals(fg, result)
    people_count = {sid: 0 for sid in prob.sensor_ids}
    for _, seen in prob.people:
        for sid, _ in seen:
            people_count[sid] += 1
    out = []
    for i, sid in enumerate(prob.sensor_ids):
        installed = log.sensors[sid]
        n_obs = int(np.sum(prob.obs_sensor == sid)) if rec.robot else 0
        T = result.atPose3(S(i))
        cov = cov_body[sid] if cov_body is not None else marginals.marginalCovariance(S(i))
        if n_obs + people_count[sid] == 0:
            warnings.warn(f"sensor {sid}: no observation of the robot or of shared people; "
                          "its installed pose is kept", DegenerateDataWarning, stacklevel=2)
            _, sp, sy = sensor_sigma_world(installed.T_world_sensor, cov)
            out.append(SensorExtrinsics(sid, installed.position_m, installed.ypr_deg, sigma_position_m=sp,
                                        sigma_ypr_deg=sy, sigma_rotation_deg=rotation_sigma_deg(cov),
                                        observations=0, status="no-data"))
            continue
        names, bad = observability(T, cov, rec)
        status = "ok"
        if names:
            status = "degenerate"
            # keep the installed value along the unconstrained directions
            p = np.r_[[np.radians(rec.sensor_prior_sigma_deg)] * 3, [rec.sensor_prior_sigma_m] * 3]
            delta = installed.T_world_sensor.localCoordinates(T) / p
            delta -= bad @ (bad.T @ delta)
            T = installed.T_world_sensor.retract(delta * p)
            warnings.warn(f"sensor {sid}: the data leave {', '.join(names)} unconstrained; the installed "
                          "value is kept there", DegenerateDataWarning, stacklevel=2)
        cov_pos, sp, sy = sensor_sigma_world(T, cov)
        if cov_out is not None:
            cov_out[sid] = cov_pos
        out.append(SensorExtrinsics.from_pose3(sid, T, sigma_position_m=sp, sigma_ypr_deg=sy,
                                               sigma_rotation_deg=rotation_sigma_deg(cov),
                                               observations=n_obs, status=status,
                                               unobservable=names or None))
    return SensorNetwork(out, frame=log.sensors.frame)
