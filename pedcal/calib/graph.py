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
- AMCL: AMCL reports ``Z_j = E_j · X(t_j)`` where E_j is its error: white per estimate plus a
  slowly wandering Gauss-Markov (Ornstein-Uhlenbeck) process, under the problem's
  :class:`~pedcal.calib.amcl_model.AmclErrorModel` (assumed before the first solve, estimated
  from its residuals after it; estimates it marks as jumps are left out). With ``F_j = E_j^{-1}``
  as the variable ``a(j)``, ``BetweenFactorPose3(a(j), x(k), Z_j)`` has residual
  ``Log(Z_j^{-1} F_j^{-1} X)`` and the white error (plus the process's change since its node)
  as noise. The process on F is the exact AR(1) of an OU process sampled every dn on its
  nodes, a = exp(-dn / tau), written as factors: ``BetweenFactorPose3(a(j), a(j+1), I)`` of
  variance sigma^2 (1 - a^2) / a and zero priors of variance sigma^2 (1 + a) / (1 - a) on inner
  nodes and sigma^2 (1 + a) on the two ends (the sum of these squares is the AR(1)'s exact
  precision). AMCL's heading error cannot be a world-frame rotation (that would swing the
  position about the map origin), so it is a white error per stamp inflated to 2 tau / dt times
  its variance: the information a process of correlation time tau holds about its mean. So the
  graph learns the run-average of AMCL, not its wander: sensors and trajectory are one rigid
  structure tied to the map by the average of all AMCL estimates, an average whose uncertainty
  the error model decides (a white 5 cm: a millimetre over minutes; a wandering one: cm).
- Odometry: ``BetweenFactorPose3`` between consecutive robot poses from the wheel odometry
  after its systematic errors are estimated and removed (:func:`calibrate_odometry`: distance
  scale, heading drift per metre and per second, fitted against AMCL over the whole run) and
  what that fit left corrected (:func:`motion_block`; the corrections are estimated with the
  head point's shifts by their profile, :mod:`pedcal.calib.factorgraph`: a fit against a
  wandering AMCL is off by tenths of a percent, which the graph would otherwise take for the
  robot's true motion, bending the network with a confident sigma). What is left is white per
  step (a random walk growing with sqrt(dt)) plus a small residual scale and heading-drift term;
  without odometry a motion-smoothness factor from AMCL's increments.
- Planarity: roll, pitch and height of the robot are held by the priors of each pose.
- Robot observations: ``BearingRangeFactorPose3(s(i), x(k))`` measuring the sensor-frame head
  point as a bearing and a range, with the head point's shifts taken out: the horizontal one
  (and the curvature, when estimated) subtracted from the point, the one along the ray added to
  the range (``|p| + rho``). A sensor's observations carried to one pose are one factor, their
  mean with sigma / sqrt(n) (:meth:`FactorGraphProblem.merge_observations`). Depth noise is
  ``floor + k r^2`` (doubled past the reliable range) and the lateral noise constant, both
  estimated from consecutive observations (:func:`estimate_observation_noise`) and taken at the
  range as observed; a robust kernel keeps mis-associations (a pedestrian beside the robot)
  from dragging.
- People seen by two sensors at once (matched by
  :func:`pedcal.calib.alternative.match_shared_observations`): ``BearingRangeFactor3D(s(i),
  l(m))`` for each sensor.

Head point. Trackers report different points of a head (the blob's highest point, a dome's point
facing the sensor, the centroid of the head's top, a fitted ellipsoid's centre): the graph takes
the reported point as the head top moved ``vertical_offset`` up, then ``rho`` along the ray toward
the sensor, ``horizontal`` horizontally toward it (a dome of radius r: -r, r, 0) and, optionally,
``curvature`` x cos^2(the sensor's elevation) up. The vertical offset is the variable h(0); a
uniform offset moves every robot observation down alike, which the robot alone cannot tell from
the sensors' common height, so without a height reference (the installed sensor heights or a
ceiling height with their sigma, a prior on each sensor's world height) it is held by its prior
(a dome's: offset = -rho, give or take head_vertical_sigma_m) and its sigma reaches every
sensor's height. The shifts enter the measurements and are estimated by their profile on the
linearized graph (:mod:`pedcal.calib.profile`, :mod:`pedcal.calib.factorgraph`).

Tracker latency is estimated once, by the association's pooled estimator
(:func:`pedcal.calib.association.estimate_latency`: per-sensor rigid fits against the AMCL spline,
minimized over the latency), and written to the calibrated YAML (``tracker_latency_s``). Within
the graph a latency error is mostly absorbed by the trajectory (a few millimetres along the
track), so re-solving for it buys little.
"""

from __future__ import annotations

import copy
import logging
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path

import gtsam
import numpy as np
import pandas as pd

from pedcal import frames
from pedcal.calib.amcl_model import AmclErrorModel, assumed_model
from pedcal.calib.common import HeadModel, ModelMismatch, head_interpolator, head_world, interpolate_pose2
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.frames import toward_sensor_horizontal, wrap_angle_rad
from pedcal.io.sensors_yaml import flow_vector, read_text_file
from pedcal.metrics import (
    AMCL_MODEL_KEY,
    HEAD_MODEL_KEY,
    JOINT_COV_KEY,
    LATENCY_KEY,
    MISMATCH_KEY,
    NOISE_KEY,
    ODOMETRY_MODEL_KEY,
)
from pedcal.model import Log, SensorExtrinsics, SensorNetwork
from pedcal.options import check_recipe_numbers

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
    # the three above estimated from consecutive observations (estimate_observation_noise) unless false
    estimate_observation_noise: bool = True
    # head-point model (module docstring, "Head point"): the prior is a dome of radius
    # head_radius_m (vertical offset -r, ray shift r); both are estimated unless
    # estimate_head_model is false
    head_radius_m: float = 0.05
    estimate_head_model: bool = True
    head_vertical_sigma_m: float = 0.03     # prior sigma of the vertical offset about -ray shift
    head_ray_shift_sigma_m: float = 0.05    # prior sigma of the shift toward the sensor
    head_ray_shift_step_m: float = 0.02     # step of the shifts' profile likelihood
    estimate_head_horizontal_shift: bool = True   # a constant horizontal shift toward the sensor too
    head_horizontal_shift_sigma_m: float = 0.05   # its prior sigma (mean 0)
    # the head point's height curving with the sensor's elevation e, curvature_m x cos^2(e) up
    # (a centroid of the head's top sits lowest seen from straight above or the side): off, on,
    # auto (estimated when its profile chi^2 reaches head_curvature_select_chi2) or widen (the
    # default: not estimated, but when its chi^2 reaches head_curvature_widen_chi2, about two
    # sigma, the misfit is named in model_mismatch and the sensors' covariance carries the move
    # estimating it would make). Over the nuisance zoo's 80 logs without it, the other shifts'
    # model inexactness gave it a chi^2 of 3-54 and estimating it cost 2-5 mm of sensor RMS; the
    # simulated centroid tracker gives 20-145, and with it not widened for below 60 the sensors'
    # errors relative to their mean were 1.5-1.9x their sigma on paper and sparse (40 seeds), 1.0
    # and 1.15x widened from 4.
    head_curvature: str = "widen"
    head_curvature_sigma_m: float = 0.02
    head_curvature_select_chi2: float = 60.0
    head_curvature_widen_chi2: float = 4.0
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
    # AMCL's error model (white std, wandering std and correlation time, jumps) estimated from the
    # residuals of a first solve (pedcal.calib.amcl_model); the three above are its starting point
    estimate_amcl_model: bool = True
    amcl_jump_threshold: float = 5.0   # robust sigmas off the running median: a jump, left out
    amcl_min_jump_m: float = 0.1       # ... and at least this far off
    # robot poses: one per AMCL stamp, gaps longer than this filled
    max_pose_gap_s: float = 0.25
    # odometry: systematic errors estimated and removed, then white noise per sqrt(second)
    # and a residual scale / heading drift
    odometry_calibrate: bool = True
    odometry_white_sigma_m: float = 0.005          # per sqrt(s)
    odometry_white_yaw_sigma_deg: float = 0.25     # per sqrt(s)
    odometry_sigma_per_m: float = 0.003            # residual scale error
    odometry_yaw_sigma_deg_per_m: float = 0.05     # residual heading drift
    # what the calibration left of odometry's systematic errors (scale, heading drift per metre
    # and per second), estimated in the graph against what the sensors saw (a calibration against
    # a wandering AMCL leaves errors the graph would otherwise take as the robot's true motion);
    # prior sigmas of these corrections
    estimate_odometry_errors: bool = True
    odometry_scale_sigma: float = 0.01
    odometry_drift_sigma_deg_per_m: float = 0.1
    odometry_drift_sigma_deg_per_s: float = 0.01
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
    people_misfit_sigma: float = 5.0   # a shared sighting whose views the first solve puts this far apart is dropped
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
            data = tomllib.loads(read_text_file(path, "graph recipe"))   # a regular file, size capped
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
        check_recipe_numbers(flat, cls(), path)
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


def smoothed_increment_var(white_sigma_m: float, dt_s, rate_hz: float, smooth_s: float):
    """Variance (m^2, per axis) of the increment over ``dt_s`` of a white jitter of std
    ``white_sigma_m`` sampled at ``rate_hz`` and smoothed by a Gaussian of ``smooth_s`` seconds
    (:func:`smoothed_track`): the kernel's slope squared summed over the samples,
    white^2 dt^2 / (rate 4 sqrt(pi) s^3), for dt up to about s."""
    return white_sigma_m ** 2 * np.asarray(dt_s, float) ** 2 / (rate_hz * 4.0 * np.sqrt(np.pi) * smooth_s ** 3)


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
    """Noise models of observations, built once per (rounded) range and sigma factor (1 / sqrt of
    the count of merged observations, or a frozen robust weight's 1 / sqrt(w) times it): a few
    hundred C++ objects instead of one per observation, kept across the graph's rebuilds (the
    profile rebuilds the observation block a dozen times per solve)."""

    STEP_M = 0.01
    MAX_MODELS = 50_000

    def __init__(self, recipe: GraphRecipe, robust: bool):
        self.recipe, self.robust, self.cache = recipe, robust, {}

    @classmethod
    def of(cls, recipe: GraphRecipe, robust: bool) -> _NoiseCache:
        """The cache of the recipe's observation noise (and robust kernel, when ``robust``)."""
        key = (recipe.range_sigma_floor_m, recipe.range_sigma_k_per_m, recipe.reliable_range_m, recipe.far_factor,
               recipe.lateral_sigma_m, robust and recipe.robust_kernel, robust and recipe.robust_k)
        cache = _NOISE_CACHES.get(key)
        if cache is None:
            if len(_NOISE_CACHES) > 16:
                _NOISE_CACHES.clear()
            cache = _NOISE_CACHES[key] = cls(recipe, robust)
        return cache

    @classmethod
    def keys(cls, range_m: np.ndarray) -> np.ndarray:
        return np.round(np.asarray(range_m, float) / cls.STEP_M).astype(int)

    def models(self, keys: np.ndarray, factors: np.ndarray) -> list:
        """The models of observations at range keys ``keys`` with sigmas times ``factors``."""
        if len(self.cache) > self.MAX_MODELS:
            self.cache.clear()
        pairs = list(zip(np.asarray(keys, int).tolist(), np.asarray(factors, float).tolist(), strict=True))
        missing = [i for i, p in enumerate(pairs) if p not in self.cache]
        if missing:
            sig = observation_sigmas(self.recipe, np.asarray(keys, float)[missing] * self.STEP_M)
            sig *= np.asarray(factors, float)[missing, None]
            for i, row in zip(missing, sig, strict=True):
                nm = gtsam.noiseModel.Diagonal.Sigmas(row)
                self.cache[pairs[i]] = _robust(self.recipe, nm) if self.robust else nm
        return [self.cache[p] for p in pairs]


_NOISE_CACHES: dict = {}


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
    amcl_model: AmclErrorModel | None = None     # AMCL's error model the graph is built with
    noise_estimate: dict | None = None           # the sensors' noise estimated from the observations
    # derived by carry_observations: latency-corrected instants, the pose each observation is
    # carried to, and the sensor-frame point carried there
    obs_t: np.ndarray | None = None
    obs_key_index: np.ndarray | None = None
    obs_p_sensor: np.ndarray | None = None
    obs_toward_sensor: np.ndarray | None = None   # horizontal unit toward the sensor, sensor frame
    # the graph's robot-observation factors (merge_observations): a sensor's observations carried
    # to one pose are one factor, their mean point with its sigma over sqrt(count)
    fac_sensor: np.ndarray | None = None
    fac_sensor_index: np.ndarray | None = None    # index into sensor_ids
    fac_key_index: np.ndarray | None = None
    fac_p_sensor: np.ndarray | None = None
    fac_toward_sensor: np.ndarray | None = None
    fac_up_cos2: np.ndarray | None = None         # up x cos^2(sensor's elevation), sensor frame
    fac_count: np.ndarray | None = None
    # the head point's shift toward the sensor along the ray and horizontally (m) the graph is
    # built with
    ray_shift_m: float = 0.0
    horizontal_shift_m: float = 0.0
    curvature_m: float = 0.0
    # corrections of the calibrated odometry the graph is built with (motion_block): distance
    # scale (-, 0: none), heading drift per metre driven (rad/m) and per second (rad/s)
    odometry_scale_correction: float = 0.0
    odometry_drift_rad_per_m: float = 0.0
    odometry_drift_rad_per_s: float = 0.0

    def head_points_sensor(self) -> np.ndarray:
        """The robot-observation factors' points (sensor frame) with the horizontal shift toward
        the sensor taken out: the head point moved ray_shift_m along the ray from the offset
        head top."""
        return (self.fac_p_sensor - self.horizontal_shift_m * self.fac_toward_sensor
                - self.curvature_m * self.fac_up_cos2)

    def merge_observations(self, max_sigmas: float = 4.0) -> None:
        """The graph's robot-observation factors: the observations one sensor made of the robot
        carried to one pose predict the same point, so their mean, with the noise's sigma over
        the square root of their count, holds the same information as each of them (the factor
        count drops by the sensors' frame rate over AMCL's). A group in which one observation
        lies beyond ``max_sigmas`` (whitened by the recipe's noise) from the mean of the others
        is left as single observations, for the robust kernel to judge each."""
        n = len(self.obs_key_index)
        sid_index = {sid: i for i, sid in enumerate(self.sensor_ids)}
        sensor_i = np.array([sid_index[s] for s in self.obs_sensor], int)
        _, group, count = np.unique(self.obs_key_index * max(len(self.sensor_ids), 1) + sensor_i,
                                    return_inverse=True, return_counts=True)
        group = np.asarray(group).ravel()
        mean = np.column_stack([np.bincount(group, self.obs_p_sensor[:, c], minlength=len(count))
                                for c in range(3)]) / np.maximum(count, 1)[:, None] if n else np.zeros((0, 3))
        # each observation against the mean of the others in its group, whitened
        c_obs = count[group]
        d = (self.obs_p_sensor - mean[group]) * (c_obs / np.maximum(c_obs - 1, 1))[:, None]
        r = np.linalg.norm(self.obs_p_sensor, axis=1)
        u = self.obs_p_sensor / np.maximum(r, 1e-9)[:, None]
        along = np.sum(d * u, axis=1)
        across = np.linalg.norm(d - along[:, None] * u, axis=1)
        sig = observation_sigmas(self.recipe, r)
        z = np.hypot(along / sig[:, 2], across / (sig[:, 0] * np.maximum(r, 0.3)))
        split = np.zeros(len(count), bool)
        np.logical_or.at(split, group, (z > max_sigmas) & (c_obs > 1))
        # merged groups: one representative observation each (its sensor, pose and rotation)
        rep = np.full(len(count), -1)
        rep[group[::-1]] = np.arange(n)[::-1]
        merged = np.flatnonzero(~split)
        solo = np.flatnonzero(split[group])
        idx = np.r_[rep[merged], solo].astype(int)
        self.fac_sensor = self.obs_sensor[idx]
        self.fac_sensor_index = sensor_i[idx]
        self.fac_key_index = self.obs_key_index[idx]
        self.fac_p_sensor = np.vstack([mean[merged], self.obs_p_sensor[solo]])
        self.fac_count = np.r_[count[merged], np.ones(len(solo), int)]
        self.fac_toward_sensor = toward_sensor_horizontal(self.fac_p_sensor, self._R_obs[idx])
        self.fac_up_cos2 = frames.up_by_cos2_elevation(self.fac_p_sensor, self._R_obs[idx])

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
        self._R_obs = R
        self.merge_observations()


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


BLOCKS = ("sensors", "amcl", "motion", "observations")


@dataclass
class GraphParts:
    """The factor graph in blocks, each a NonlinearFactorGraph (``BLOCKS``, in graph order):
    ``sensors`` (installed priors, height reference), ``amcl`` (AMCL's measurements and its error
    process), ``motion`` (odometry or smoothness) and ``observations`` (the robot's and the shared
    people's, and the head model's prior: everything the head point's shifts enter, rebuilt alone
    by :func:`observation_block` when they change), and the initial values."""

    blocks: dict
    values: gtsam.Values

    def graph(self, **replace) -> gtsam.NonlinearFactorGraph:
        """The whole graph; ``replace`` swaps blocks by name (e.g. ``observations=...``)."""
        g = gtsam.NonlinearFactorGraph()
        for name in BLOCKS:
            g.push_back(replace.get(name, self.blocks[name]))
        return g


def build_graph(log: Log, prob: FactorGraphProblem, *, t_max: float | None = None):
    """Build the factor graph and the initial values (optionally only with data up to t_max)."""
    parts = build_parts(log, prob, t_max=t_max)
    return parts.graph(), parts.values


def _pose_times(prob: FactorGraphProblem, t_max: float | None) -> np.ndarray:
    return prob.pose_times if t_max is None else prob.pose_times[prob.pose_times <= t_max]


def _head_m(log: Log, rec: GraphRecipe) -> np.ndarray:
    """The robot's head frame offset (base frame) the poses are built at: the head top moved
    down by the prior dome's radius (the vertical offset's initial value, see H(0))."""
    return np.asarray(log.meta.head_offset_m, float) - np.array([0.0, 0.0, rec.head_radius_m])


def build_parts(log: Log, prob: FactorGraphProblem, *, t_max: float | None = None) -> GraphParts:
    """The graph's blocks and initial values (optionally only with data up to t_max)."""
    rec = prob.recipe
    values = gtsam.Values()
    blocks = {name: gtsam.NonlinearFactorGraph() for name in BLOCKS}
    head_m = _head_m(log, rec)

    # Sensors: weak prior at the installed extrinsics; a height reference, when given, as a
    # prior on the world height alone (the Pose3 tangent is body-frame: world z is R^T e_z there).
    g = blocks["sensors"]
    sig_rot = np.radians(rec.sensor_prior_sigma_deg)
    sensor_prior = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sig_rot] * 3, [rec.sensor_prior_sigma_m] * 3])
    for i, sid in enumerate(prob.sensor_ids):
        T_inst = log.sensors[sid].T_world_sensor
        g.add(gtsam.PriorFactorPose3(S(i), T_inst, sensor_prior))
        values.insert(S(i), prob.init_sensors[sid])
        if rec.sensor_height_sigma_m > 0.0:
            z_ref = rec.ceiling_height_m if rec.ceiling_height_m > 0.0 else float(T_inst.translation()[2])
            # about the initial pose (close to the solution: the Pose3 logmap couples the
            # horizontal offset into the height by the rotation difference)
            T0 = prob.init_sensors[sid]
            g.add(gtsam.PriorFactorPose3(S(i), _height_reference(T0, z_ref),
                                         _height_noise(T0, rec.sensor_height_sigma_m)))

    times = _pose_times(prob, t_max)
    n_pose = len(times)
    init = initial_track(log, prob, times) if n_pose else np.zeros((0, 3))
    # Robot poses at the initial track; roll, pitch and height held by a planarity prior (AMCL's
    # own factor holds them when it is in the graph).
    planar = gtsam.noiseModel.Diagonal.Sigmas(np.array(
        [np.radians(rec.planar_sigma_deg)] * 2 + [1e3, 1e3, 1e3, rec.head_height_sigma_m]))
    for k in range(n_pose):
        P = head_frame(*init[k], head_m)
        values.insert(X(k), P)
        if not rec.amcl:
            blocks["amcl"].add(gtsam.PriorFactorPose3(X(k), P, planar))
    if rec.amcl and n_pose:
        _amcl_block(blocks["amcl"], values, log, prob, times)
    if n_pose > 1:
        blocks["motion"] = motion_block(log, prob, t_max=t_max)
    blocks["observations"] = observation_block(log, prob, values, t_max=t_max, insert_values=True)
    return GraphParts(blocks=blocks, values=values)


def initial_track(log: Log, prob: FactorGraphProblem, times: np.ndarray, smooth_s: float = 5.0) -> np.ndarray:
    """(N, 3) base poses [x, y, yaw] to start the robot poses from: with odometry, its path
    carried into the map by AMCL's map-from-odometry transform smoothed over ``smooth_s`` (the
    path then has odometry's shape, which its factors expect, and AMCL's place); without it AMCL
    smoothed (when it jitters) or AMCL itself. AMCL's estimates the error model left out as
    jumps are not used."""
    from scipy.ndimage import gaussian_filter1d

    amcl = log.robot.sort_values("t", kind="stable")
    model = prob.amcl_model
    if model is not None and model.excluded is not None:
        amcl = amcl[~model.excluded]
    amcl = amcl.groupby("t", sort=True)[["x", "y", "yaw"]].mean().reset_index()
    if prob.odometry is None or len(amcl) < 2:
        src = prob.smoothed_amcl if prob.smoothed_amcl is not None else amcl
        return interpolate_pose2(src, times)
    t_a = amcl["t"].to_numpy(float)
    odo = interpolate_pose2(prob.odometry, t_a)
    yaw_d = np.unwrap(np.unwrap(amcl["yaw"].to_numpy(float)) - odo[:, 2])
    c, s_ = np.cos(yaw_d), np.sin(yaw_d)
    tx = amcl["x"].to_numpy(float) - (c * odo[:, 0] - s_ * odo[:, 1])
    ty = amcl["y"].to_numpy(float) - (s_ * odo[:, 0] + c * odo[:, 1])
    sig = smooth_s / max(float(np.median(np.diff(t_a))), 1e-3)
    # the transform's components smoothed (the rotation through its sine and cosine)
    tx, ty, c, s_ = (gaussian_filter1d(v, sig, mode="nearest") for v in (tx, ty, c, s_))
    yaw_d = np.arctan2(s_, c)
    o = interpolate_pose2(prob.odometry, times)
    D = np.column_stack([np.interp(times, t_a, tx), np.interp(times, t_a, ty), np.interp(times, t_a, np.unwrap(yaw_d))])
    c, s_ = np.cos(D[:, 2]), np.sin(D[:, 2])
    return np.column_stack([D[:, 0] + c * o[:, 0] - s_ * o[:, 1], D[:, 1] + s_ * o[:, 0] + c * o[:, 1],
                            D[:, 2] + o[:, 2]])


def _amcl_block(graph, values, log: Log, prob: FactorGraphProblem, times: np.ndarray) -> None:
    """AMCL as a measurement with a Gauss-Markov error (module docstring), under the problem's
    AMCL error model (:class:`pedcal.calib.amcl_model.AmclErrorModel`): each estimate tied to the
    nearest node of the error process with its white error and the process's change since the
    node; the process itself as the exact discretization of an Ornstein-Uhlenbeck process on the
    nodes; estimates the model marks as jumps left out."""
    rec = prob.recipe
    head_m = _head_m(log, rec)
    model = prob.amcl_model
    amcl = log.robot.sort_values("t", kind="stable")
    amcl_t = amcl["t"].to_numpy(float)
    n_pose = len(times)
    cov = amcl[["cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"]].to_numpy(float)
    k_of = np.searchsorted(times, amcl_t)
    use = (k_of < n_pose) & (times[np.minimum(k_of, n_pose - 1)] == amcl_t)
    if model.excluded is not None:
        use &= ~model.excluded
    use = np.flatnonzero(use)
    dt_amcl = float(np.median(np.diff(amcl_t))) if len(amcl_t) > 1 else 1.0
    nodes = prob.amcl_node_times
    dn = float(nodes[1] - nodes[0]) if len(nodes) > 1 else 1.0
    node_of = np.clip(np.round((amcl_t[use] - nodes[0]) / dn).astype(int), 0, len(nodes) - 1)
    tiny = np.radians(0.05)
    tau = max(model.correlation_s, 1e-3)
    sig_c = max(model.correlated_sigma_m, 1e-4)
    yaw_a = amcl["yaw"].to_numpy(float)[use]
    x_a, y_a = amcl["x"].to_numpy(float)[use], amcl["y"].to_numpy(float)[use]
    # AMCL's covariance in the body frame (amcl_cov_body); the slow error is a world-frame
    # translation (F is held to a pure translation), the white error stays here; the heading error
    # is white, inflated to the information of an OU mean (2 tau / dt).
    C3 = np.stack([np.stack([cov[use, 0], cov[use, 1], cov[use, 2]], -1),
                   np.stack([cov[use, 1], cov[use, 3], cov[use, 4]], -1),
                   np.stack([cov[use, 2], cov[use, 4], cov[use, 5]], -1)], -2)
    f = model.reported_white_fraction
    scale = np.array([1.0, 1.0, np.sqrt(max(1.0, 2.0 * tau / dt_amcl)), f, f, 1.0])
    Cb = amcl_cov_body(C3, yaw_a) * np.outer(scale, scale)
    Cb[:, 0, 0] = Cb[:, 1, 1] = tiny ** 2
    # white error (the model's share of the reported covariance and its own std) and the OU's
    # change since the node (exact: sigma^2 (1 - exp(-2 |dt| / tau)))
    drift_var = sig_c ** 2 * (1.0 - np.exp(-2.0 * np.abs(amcl_t[use] - nodes[node_of]) / tau))
    Cb[:, 3:5, 3:5] += (model.white_sigma_m ** 2 + drift_var)[:, None, None] * np.eye(2)
    Cb[:, 5, 5] = 1e-6
    for n, j in enumerate(use):
        Z = head_frame(x_a[n], y_a[n], yaw_a[n], head_m)
        graph.add(gtsam.BetweenFactorPose3(A(int(node_of[n])), X(int(k_of[j])), Z,
                                           gtsam.noiseModel.Gaussian.Covariance(Cb[n])))
    # The error process on its nodes: the exact AR(1) of an OU process sampled every dn,
    # a = exp(-dn / tau), written as increments and per-node priors (module docstring).
    a = float(np.exp(-dn / tau))
    free_z = rec.estimate_head_model
    z_sig = 1e2 if free_z else 1e-3

    def sig6(s_xy: float, s_z: float):
        return gtsam.noiseModel.Diagonal.Sigmas(np.array([tiny, tiny, 1e-4, s_xy, s_xy, s_z]))

    n_nodes = int(node_of.max()) + 1 if len(use) else 0
    if n_nodes == 1:
        priors = [sig6(sig_c, z_sig)]
    else:
        inner = sig6(sig_c * np.sqrt((1.0 + a) / max(1.0 - a, 1e-12)), z_sig)
        priors = [inner] * n_nodes
    q = sig6(sig_c * np.sqrt((1.0 - a * a) / max(a, 1e-12)), 1e-3)
    if free_z and n_nodes:
        # The head point's vertical offset from its initial value (-head_radius_m) is the height
        # of the variable h (its prior is in the observation block: it depends on the ray shift):
        # every AMCL error node's height is tied to it, so every robot pose, and with it every
        # head point the sensors see, moves up or down with it alike.
        values.insert(H(0), gtsam.Pose3())
        tie = gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, 1.0, 1e3, 1e3, 1e-4]))
    for m in range(n_nodes):
        values.insert(A(m), gtsam.Pose3())
        graph.add(gtsam.PriorFactorPose3(A(m), gtsam.Pose3(), priors[m]))
        if m and a > 1e-9:
            graph.add(gtsam.BetweenFactorPose3(A(m - 1), A(m), gtsam.Pose3(), q))
        if free_z:
            graph.add(gtsam.BetweenFactorPose3(H(0), A(m), gtsam.Pose3(), tie))


ODOMETRY_NUISANCES = ("odometry_scale_correction", "odometry_drift_rad_per_m", "odometry_drift_rad_per_s")


def motion_block(log: Log, prob: FactorGraphProblem, *, t_max: float | None = None,
                 theta: dict | None = None) -> gtsam.NonlinearFactorGraph:
    """Odometry (or smoothness) between consecutive robot poses. With odometry, each increment is
    the calibrated odometry's (body frame: forward, left, turn) with the problem's corrections
    applied, ``theta`` overriding them by name (``ODOMETRY_NUISANCES``): distance times
    (1 + scale correction), turn minus the drift per metre times the distance and per second
    times the interval."""
    rec = prob.recipe
    graph = gtsam.NonlinearFactorGraph()
    times = _pose_times(prob, t_max)
    n_pose = len(times)
    if n_pose < 2:
        return graph
    head_m = _head_m(log, rec)
    dt = np.diff(times)
    if rec.odometry and prob.odometry is not None:
        theta = theta or {}
        scale, drift_m, drift_s = (float(theta.get(k, getattr(prob, k))) for k in ODOMETRY_NUISANCES)
        src = interpolate_pose2(prob.odometry, times)
        c, s_ = np.cos(src[:-1, 2]), np.sin(src[:-1, 2])
        d = np.diff(src[:, :2], axis=0)
        fwd, left = c * d[:, 0] + s_ * d[:, 1], -s_ * d[:, 0] + c * d[:, 1]
        dist = np.hypot(fwd, left)
        turn = wrap_angle_rad(np.diff(src[:, 2])) - drift_m * dist - drift_s * dt
        fwd, left = (1.0 + scale) * fwd, (1.0 + scale) * left
        st = np.sqrt(rec.odometry_white_sigma_m ** 2 * dt + (rec.odometry_sigma_per_m * dist) ** 2) + 1e-4
        sy = np.sqrt(np.radians(rec.odometry_white_yaw_sigma_deg) ** 2 * dt
                     + (np.radians(rec.odometry_yaw_sigma_deg_per_m) * dist) ** 2) + 1e-5
        # the head frame's increment H^-1 B H (B the base's, H the head offset h): the turn, and the
        # base's translation plus the head offset carried round the turn, (Rz(turn) - I) h
        c, s_ = np.cos(turn), np.sin(turn)
        tx = fwd + (c - 1.0) * head_m[0] - s_ * head_m[1]
        ty = left + s_ * head_m[0] + (c - 1.0) * head_m[1]
        steps = [gtsam.Pose3(gtsam.Rot3.Yaw(turn[k]), np.array([tx[k], ty[k], 0.0])) for k in range(n_pose - 1)]
    elif rec.smoothness:
        amcl = log.robot.sort_values("t")
        src = interpolate_pose2(amcl if prob.smoothed_amcl is None else prob.smoothed_amcl, times)
        # AMCL's short-term increments: error grows with dt, plus AMCL's white jitter at both ends
        white = amcl_white_sigma(log.robot)
        jitter_var = 2.0 * white ** 2
        if prob.smoothed_amcl is not None:
            # the smoothed increments' errors are alike over the kernel's 2 s / dt steps, so each
            # counts that many times
            rate = 1.0 / max(float(np.median(np.diff(np.unique(log.robot["t"].to_numpy(float))))), 1e-3)
            jitter_var = (smoothed_increment_var(white, dt, rate, rec.amcl_smooth_s)
                          * np.maximum(2.0 * rec.amcl_smooth_s / dt, 1.0))
        st = np.sqrt((rec.smoothness_sigma_mps * dt) ** 2 + jitter_var) + 1e-3
        sy = np.radians(2.0) * dt + 1e-4
        P = [head_frame(*src[k], head_m) for k in range(n_pose)]
        steps = [P[k].between(P[k + 1]) for k in range(n_pose - 1)]
    else:
        return graph
    # one noise model per distinct (turn, translation) sigma, rounded to 0.1 %
    q = np.round(np.log(np.column_stack([sy, st])) / 1e-3).astype(np.int64)
    uniq, inverse = np.unique(q, axis=0, return_inverse=True)
    models = [gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, a, b, b, 1e-3]))
              for a, b in np.exp(uniq * 1e-3)]
    inverse = np.asarray(inverse).ravel()
    for k in range(n_pose - 1):
        graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), steps[k], models[inverse[k]]))
    return graph


def observation_block(log: Log, prob: FactorGraphProblem, values: gtsam.Values | None = None, *,
                      t_max: float | None = None, insert_values: bool = False,
                      theta: dict | None = None, robust: bool = True,
                      sigma_scale: np.ndarray | None = None) -> gtsam.NonlinearFactorGraph:
    """The factors the head point's shifts enter: the prior of the head point's vertical offset
    (a dome's: offset = -ray shift), the robot observations carried to their pose variables
    (FactorGraphProblem.carry_observations) and the people seen by two or more sensors at once,
    in this order. ``theta`` overrides the problem's shifts by name (``ray_shift_m``,
    ``horizontal_shift_m``) without changing it; ``robust=False`` leaves the robust kernel out;
    ``sigma_scale`` (one per factor, in order) multiplies each factor's sigmas instead of a
    kernel (a robust weight w frozen: 1 / sqrt(w); models are shared between equal scales);
    ``insert_values`` puts the people's initial positions into ``values``."""
    rec = prob.recipe
    theta = theta or {}
    rho = float(theta.get("ray_shift_m", prob.ray_shift_m))
    hs = float(theta.get("horizontal_shift_m", prob.horizontal_shift_m))
    cv = float(theta.get("curvature_m", prob.curvature_m))
    graph = gtsam.NonlinearFactorGraph()
    n_pose = len(_pose_times(prob, t_max))
    cache = _NoiseCache.of(rec, robust=robust and sigma_scale is None)
    factor = 0           # index of the next factor (into sigma_scale)

    def noises(range_m: np.ndarray, count: np.ndarray | None = None) -> list:
        """Noise models of observations at these ranges, each the mean of ``count``: shared
        cached ones, robust, or with each factor's sigmas scaled instead."""
        nonlocal factor
        count = np.ones(len(range_m), int) if count is None else np.asarray(count, int)
        scale = 1.0 / np.sqrt(count)
        if sigma_scale is not None:
            scale = scale * np.asarray(sigma_scale[factor:factor + len(range_m)], float)
            factor += len(range_m)
        pairs, inverse = np.unique(np.column_stack([cache.keys(range_m), scale]), axis=0, return_inverse=True)
        models = cache.models(pairs[:, 0], pairs[:, 1])
        return [models[i] for i in inverse.ravel()]

    if rec.amcl and rec.estimate_head_model and values is not None and values.exists(H(0)):
        # prior: the point lies on a dome, offset = -shift (a blob's top: both 0; a dome's
        # facing point: -r and r), give or take head_vertical_sigma_m; h's height is the
        # offset minus the initial -head_radius_m of the robot poses
        tiny = np.radians(0.05)
        h_prior = gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, rec.head_radius_m - rho]))
        sig = np.array([tiny, tiny, tiny, 1e-4, 1e-4, rec.head_vertical_sigma_m])
        if sigma_scale is not None:
            sig = sig * sigma_scale[factor]
            factor += 1
        graph.add(gtsam.PriorFactorPose3(H(0), h_prior, gtsam.noiseModel.Diagonal.Sigmas(sig)))
    sid_index = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    if rec.robot:
        use = np.flatnonzero(prob.fac_key_index < n_pose)
        p_obs = prob.fac_p_sensor[use] - hs * prob.fac_toward_sensor[use] - cv * prob.fac_up_cos2[use]
        rng_m = np.linalg.norm(p_obs, axis=1)
        keys = [S(sid_index[s]) for s in prob.fac_sensor[use]]
        pose = prob.fac_key_index[use]
        # noise from the range as observed, not as shifted: sigmas that moved with the shifts would
        # reward shifts that shrink them (a least-squares fit is no likelihood when its weights
        # depend on the parameters), a bias along the shifts' nearly degenerate combination
        for n, nm in enumerate(noises(np.linalg.norm(prob.fac_p_sensor[use], axis=1), prob.fac_count[use])):
            graph.add(gtsam.BearingRangeFactorPose3(keys[n], X(int(pose[n])), gtsam.Unit3(p_obs[n]),
                                                   rng_m[n] + rho, nm))
    if rec.people:
        seen_keys, seen_p, seen_m, seen_r = [], [], [], []
        for m, (t, seen) in enumerate(prob.people):
            if t_max is not None and t > t_max:
                continue
            pts = []
            for sid, p in seen:
                R0 = prob.init_sensors[sid].rotation().matrix()
                seen_r.append(float(np.linalg.norm(p)))
                p = (p - hs * toward_sensor_horizontal(p[None, :], R0)[0]
                     - cv * frames.up_by_cos2_elevation(p[None, :], R0)[0])
                seen_keys.append(S(sid_index[sid]))
                seen_p.append(p)
                seen_m.append(m)
                pts.append(prob.init_sensors[sid].transformFrom(p * (1.0 + rho / float(np.linalg.norm(p)))))
            if insert_values:
                values.insert(L(m), np.mean(pts, axis=0))
        if seen_p:
            seen_p = np.asarray(seen_p)
            r = np.linalg.norm(seen_p, axis=1)
            for n, nm in enumerate(noises(np.asarray(seen_r))):
                graph.add(gtsam.BearingRangeFactor3D(seen_keys[n], L(seen_m[n]), gtsam.Unit3(seen_p[n]),
                                                     r[n] + rho, nm))
    return graph


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
        import importlib

        from pedcal.calib import METHODS

        opts = dict(is_robot=is_robot) if recipe.init == "gridsearch" else dict(is_robot=is_robot,
                                                                                latency_s=latency_s)
        module, func = METHODS[recipe.init]      # the method itself: the log is validated already
        with warnings.catch_warnings():     # the graph reports degenerate sensors itself
            warnings.simplefilter("ignore", DegenerateDataWarning)
            res = getattr(importlib.import_module(module), func)(log, progress=progress, **opts)
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
    set_amcl_model(log, prob, assumed_model(log.robot, recipe), carry=False)
    prob.carry_observations({sid: T.rotation().matrix() for sid, T in init.items()})
    if recipe.estimate_observation_noise and recipe.robot:
        noise = estimate_observation_noise(log, prob)
        if noise is None:
            warnings.warn("too few pairs of consecutive robot observations to estimate the sensors' noise; the "
                          "recipe's depth and lateral noise are assumed", DegenerateDataWarning, stacklevel=3)
        else:
            prob.recipe = copy.copy(recipe)
            for k in ("range_sigma_floor_m", "range_sigma_k_per_m", "lateral_sigma_m"):
                setattr(prob.recipe, k, noise[k])
            prob.noise_estimate = noise
            prob.merge_observations()           # judged against the estimated noise
            _log(progress, f"observation noise from {noise['pairs']} pairs of consecutive observations: depth "
                           f"{1000 * noise['range_sigma_floor_m']:.1f} mm + {1000 * noise['range_sigma_k_per_m']:.2f} "
                           f"mm/m^2 x r^2, lateral {1000 * noise['lateral_sigma_m']:.1f} mm")
    if recipe.people:
        net = SensorNetwork([SensorExtrinsics.from_pose3(sid, init[sid]) for sid in log.sensors.ids],
                            frame=log.sensors.frame)
        prob.people = _shared_people(log, is_robot, recipe, net)
    _log(progress, f"{len(rows)} robot observations, {len(pose_times)} robot poses, "
                   f"{len(prob.people)} shared person sightings")
    return prob


def estimate_observation_noise(log: Log, prob: FactorGraphProblem, max_gap_s: float = 0.25,
                               min_pairs: int = 100) -> dict | None:
    """The sensors' noise from the robot's observations themselves, without any fit: two
    consecutive observations of one track (at most ``max_gap_s`` apart), the later carried back
    to the earlier's instant by the robot's motion, differ by the two observations' noise alone.
    Half the robust variance of that difference along the ray gives the depth noise, binned by
    range and fitted by ``floor + k r^2`` (times ``far_factor`` past ``reliable_range_m``, as the
    graph models it); across the ray, the lateral noise (with the latency jitter times the
    robot's speed in it). A tracker that smooths its output makes consecutive reports alike and
    this an underestimate, which the model check after the solve sees (a variance ratio above 1)
    and widens the sigma for. Returns the recipe's three noise fields and the number of pairs, or
    None with fewer than ``min_pairs`` pairs."""
    rec = prob.recipe
    rows = prob.rows_used
    if rows is None or len(rows) < 2:
        return None
    track = log.observations["track"].astype(str).to_numpy()[rows]
    order = np.lexsort((prob.obs_t, track, prob.obs_sensor))
    s_o, tr_o, t_o = prob.obs_sensor[order], track[order], prob.obs_t[order]
    dt = np.diff(t_o)
    nxt = (s_o[1:] == s_o[:-1]) & (tr_o[1:] == tr_o[:-1]) & (dt > 0.0) & (dt <= max_gap_s)
    i, j = order[:-1][nxt], order[1:][nxt]
    if len(i) < min_pairs:
        return None
    R = np.stack([prob.init_sensors[sid].rotation().matrix() for sid in prob.obs_sensor[i]])
    disp = prob.motion.displacement(prob.obs_t[j], prob.obs_t[i])
    p_i = prob.obs_p_raw[i]
    d = prob.obs_p_raw[j] + np.einsum("nji,nj->ni", R, disp) - p_i
    r = np.linalg.norm(p_i, axis=1)
    u = p_i / r[:, None]
    along = np.sum(d * u, axis=1)
    a = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    b1 = np.cross(u, a)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = np.cross(u, b1)

    def robust_sigma(x):
        return 1.4826 * float(np.median(np.abs(x - np.median(x)))) / np.sqrt(2.0)     # one observation's

    lateral = float(np.sqrt(0.5 * (robust_sigma(np.sum(d * b1, axis=1)) ** 2
                                   + robust_sigma(np.sum(d * b2, axis=1)) ** 2)))
    edges = np.quantile(r, np.linspace(0.0, 1.0, 7))
    r_bin, s_bin, n_bin = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (r >= lo) & (r <= hi)
        if m.sum() >= 20:
            r_bin.append(float(np.median(r[m])))
            s_bin.append(robust_sigma(along[m]) / (rec.far_factor if np.median(r[m]) > rec.reliable_range_m else 1.0))
            n_bin.append(int(m.sum()))
    if len(r_bin) < 2:
        return None
    r_bin, s_bin, w = np.array(r_bin), np.array(s_bin), np.sqrt(np.array(n_bin, float))
    M = np.column_stack([np.ones(len(r_bin)), r_bin ** 2])
    floor, k = np.linalg.lstsq(M * w[:, None], s_bin * w, rcond=None)[0]
    if k < 0.0:
        floor, k = float(np.average(s_bin, weights=w)), 0.0
    return {"range_sigma_floor_m": float(max(floor, 1e-3)), "range_sigma_k_per_m": float(k),
            "lateral_sigma_m": float(max(lateral, 1e-3)), "pairs": int(len(i))}


def set_amcl_model(log: Log, prob: FactorGraphProblem, model: AmclErrorModel, *, carry: bool = True,
                   rotations: dict[str, np.ndarray] | None = None) -> None:
    """Build the graph with AMCL's error ``model`` from now on: the error process's nodes spaced
    for its correlation time and, when the model leaves estimates out as jumps and AMCL stands in
    for odometry, the robot's short-term motion from AMCL without them (observations carried
    again, with ``rotations``, the current R_world_sensor per sensor, when ``carry``)."""
    rec = prob.recipe
    t_a = np.unique(log.robot["t"].to_numpy(float))
    period = float(np.median(np.diff(t_a))) if len(t_a) > 1 else rec.amcl_node_spacing_s
    dn = model.node_spacing_s(period, rec.amcl_node_spacing_s)
    prob.amcl_node_times = t_a[0] + dn * np.arange(int(np.round((t_a[-1] - t_a[0]) / dn)) + 1)
    prob.amcl_model = model
    if model.excluded is None or prob.odometry is not None:
        return
    clean = copy.copy(log)
    clean.robot = log.robot.sort_values("t", kind="stable")[~model.excluded]
    if prob.smoothed_amcl is not None:
        prob.smoothed_amcl = smoothed_track(clean.robot, rec.amcl_smooth_s)
        prob.motion = _RobotMotion(clean, prob.smoothed_amcl)
    else:
        prob.motion = _RobotMotion(clean, None)
    if carry:
        prob.carry_observations(rotations or {sid: T.rotation().matrix() for sid, T in prob.init_sensors.items()})


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


def optimize_graph(fg, values, recipe: GraphRecipe, max_iterations: int | None = None,
                   gauss_newton_step: bool = True, relative_error_tol: float | None = None):
    """Levenberg-Marquardt from ``values``, then, with the head model's vertical offset free, one
    Gauss-Newton step (unless ``gauss_newton_step`` is False: the caller's next step is one, as
    every profile step of the nuisances is); (result, iterations). A common vertical shift of all variables changes no
    measurement factor then, only the priors (the offset's, the sensors' installed heights, a
    height reference): a flat direction LM barely moves along before its relative-error test
    stops it, so the solution would sit wherever the initial values put it. The error is quadratic
    along it, and a Gauss-Newton step goes to its optimum."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(recipe.max_iterations if max_iterations is None else max_iterations)
    params.setRelativeErrorTol(recipe.relative_error_tol if relative_error_tol is None else relative_error_tol)
    # the robot's chain of poses eliminates faster sequentially, in one COLAMD ordering computed
    # once (the graph's structure does not change between iterations): ~20 % per iteration
    params.setLinearSolverType("SEQUENTIAL_CHOLESKY")
    params.setOrdering(gtsam.Ordering.ColamdGaussianFactorGraph(fg.linearize(values)))
    opt = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    result = opt.optimize()
    if gauss_newton_step and result.exists(H(0)):
        result = result.retract(fg.linearize(result).optimize())
    return result, opt.iterations()


# Above this many sensors the joint position covariance (3n x 3n) is not computed (each sensor's
# marginal is): at 1000 sensors it would be 9 M numbers, about 100 MB of text, and a dense inverse
# of 6000 x 6000 takes a minute.
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
    elif len(prob.sensor_ids) > JOINT_COV_MAX_SENSORS:
        logging.getLogger(__name__).warning(
            f"the joint covariance of {len(prob.sensor_ids)} sensors' positions ({3 * len(prob.sensor_ids)} x "
            f"{3 * len(prob.sensor_ids)}) is not computed above {JOINT_COV_MAX_SENSORS} sensors (each sensor's "
            "marginal is); CalibrationResult.marginals().jointMarginalCovariance(keys) gives any part of it")
    if prob.amcl_model is not None and prob.recipe.amcl:
        network.extra[AMCL_MODEL_KEY] = prob.amcl_model.to_dict()
    if prob.odometry is not None and prob.odometry_estimates:
        network.extra[ODOMETRY_MODEL_KEY] = {k: (round(v, 6) if isinstance(v, float) else v)
                                             for k, v in prob.odometry_estimates.items()}
    if prob.noise_estimate:
        network.extra[NOISE_KEY] = {k: (round(v, 6) if isinstance(v, float) else v)
                                    for k, v in prob.noise_estimate.items()}
    if mismatch is not None:
        ratios = {k: round(v, 3) for k, v in mismatch.variance_ratio.items()}
        network.extra[MISMATCH_KEY] = {"sensors": mismatch.sensors, "threshold": mismatch.threshold,
                                       "variance_ratio": ratios, "misfit": mismatch.misfit}
        if mismatch.head_model_misfit:
            network.extra[MISMATCH_KEY]["head_model"] = mismatch.head_model_misfit
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
