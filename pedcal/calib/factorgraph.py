"""pedcal's estimator: one GTSAM factor graph of the ceiling sensors, the robot's poses and people.

Variables
- ``s(i)``: ``Pose3`` T_world_sensor of every ceiling sensor, with a weak prior at the installed
  (hand-measured) extrinsics.
- ``x(k)``: ``Pose3`` of the robot's head frame (the base pose lifted to the head's dome centre)
  at every instant something was observed or localized: AMCL stamps and the (latency-corrected)
  instants of the robot's observations.
- ``a(j)``: ``Pose3`` of AMCL's error at AMCL stamp j (world frame, inverted: see below).
- ``l(m)``: ``Point3`` of a person's head seen by two or more sensors at once.

Factors (all GTSAM built-in C++ factors)
- AMCL: AMCL reports ``Z_j = E_j · X(t_j)`` where E_j is a slowly wandering world-frame error, a
  Gauss-Markov process (AMCL's particle cloud drifts over tens of seconds; it is not white).
  With ``F_j = E_j^{-1}`` as the variable ``a(j)``, ``BetweenFactorPose3(a(j), x(k), Z_j)`` has
  residual ``Log(Z_j^{-1} F_j^{-1} X)``. The process on F is the discretized Ornstein-Uhlenbeck
  prior: ``BetweenFactorPose3(a(j), a(j+1), I)`` with variance q = 2 sigma^2 dt / tau and a zero
  prior per node with variance 2 sigma^2 tau / dt (the precision operator of an OU process of
  stationary std sigma and correlation time tau). sigma comes from AMCL's reported covariance.
  So the graph learns the run-average of AMCL, not its wander.
- Odometry: ``BetweenFactorPose3`` between consecutive robot poses from the interpolated wheel
  odometry, noise growing with the distance travelled (scale error, yaw drift); without
  odometry a motion-smoothness factor from AMCL's short-term increments.
- Planarity: roll, pitch and height of the robot are held by the priors of each pose.
- Robot observations: ``BearingRangeFactorPose3(s(i), x(k))`` measuring the sensor-frame head
  point as a bearing and a range; the visible head top is the point of the head dome that faces
  the sensor, so the bearing is that of the dome centre and the range is ``|p| + r_head``. Depth
  noise grows with range squared; a robust kernel keeps mis-associations from dragging.
- People seen by two sensors at once: ``BearingRangeFactor3D(s(i), l(m))`` for each sensor.

Tracker latency is estimated, not assumed zero: the rigid fit residual of every sensor's pairs
is minimized over a latency grid before the graph is built (a 1-D search), and the estimate is
written to the calibrated YAML (``tracker_latency_s``).
"""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path

import gtsam
import numpy as np

from pedcal import frames
from pedcal.calib.closedform import fit_rigid
from pedcal.calib.common import CalibrationResult, head_world, interpolate_pose2
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.metrics import HEAD_RADIUS_KEY, LATENCY_KEY
from pedcal.model import Log, SensorExtrinsics, SensorNetwork

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

S = gtsam.symbol_shorthand.S
X = gtsam.symbol_shorthand.X
A = gtsam.symbol_shorthand.A
L = gtsam.symbol_shorthand.L

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
    # depth sensor model: sigma_range = floor + k r^2, lateral sigma of the head-top extraction
    range_sigma_floor_m: float = 0.01
    range_sigma_k_per_m: float = 1.5e-3
    lateral_sigma_m: float = 0.015
    head_radius_m: float = 0.1      # dome radius of the robot's head (visible top faces the sensor)
    robust_kernel: str = "huber"    # huber | cauchy | tukey | none
    robust_k: float = 1.345
    # AMCL error process
    amcl_correlation_s: float = 15.0
    amcl_white_fraction: float = 0.2   # share of AMCL's reported std that is white, per stamp
    # odometry noise
    odometry_sigma_per_m: float = 0.02
    odometry_yaw_sigma_deg_per_m: float = 1.0
    # Wheel odometry errors are systematic (wheel radius, gyro bias), not independent per step:
    # each step's noise is inflated so that over this distance the accumulated sigma equals
    # the per-metre figures above (the information of one independent stretch per length).
    odometry_correlation_m: float = 5.0
    smoothness_sigma_mps: float = 0.05
    # robot planarity
    planar_sigma_deg: float = 0.5
    head_height_sigma_m: float = 0.02
    # tracker latency search
    estimate_latency: bool = True
    latency_min_s: float = -0.1
    latency_max_s: float = 0.5
    latency_step_s: float = 0.005
    # people association for shared observations
    people_gate_m: float = 0.5
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
        print(f"[factorgraph] {msg}", file=sys.stderr, flush=True)


def _robust(recipe: GraphRecipe, base):
    k = recipe.robust_kernel.lower()
    if k == "none":
        return base
    est = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
           "tukey": gtsam.noiseModel.mEstimator.Tukey}.get(k)
    if est is None:
        raise PedcalInputError(f"unknown robust kernel '{recipe.robust_kernel}'", column="robust_kernel")
    return gtsam.noiseModel.Robust.Create(est.Create(recipe.robust_k), base)


def rigid_fit(p_sensor: np.ndarray, p_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The closed form's rigid fit p_world ~ R p_sensor + t, with its rms residual (m)."""
    R, t = fit_rigid(p_sensor, p_world)
    res = p_world - (p_sensor @ R.T + t)
    return R, t, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))


def pose2_to_pose3(x: float, y: float, yaw: float, z: float = 0.0) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([x, y, z]))


def head_frame(x: float, y: float, yaw: float, head_m: np.ndarray) -> gtsam.Pose3:
    """The robot's head frame: the base pose (x, y, yaw) composed with the head offset
    ``head_m`` (base frame; its z is the dome centre's height)."""
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([x, y, 0.0])).compose(
        gtsam.Pose3(gtsam.Rot3(), np.asarray(head_m, float)))


def amcl_cov_body(cov_world: np.ndarray, yaw: float) -> np.ndarray:
    """AMCL's (x, y, yaw) world covariance as a Pose3 tangent covariance [rx, ry, rz, tx, ty, tz]
    in the body frame (GTSAM's convention), without the roll/pitch/z blocks."""
    c, s = np.cos(yaw), np.sin(yaw)
    Rt = np.array([[c, s], [-s, c]])           # world -> body for xy
    out = np.zeros((6, 6))
    out[2, 2] = cov_world[2, 2]
    out[3:5, 3:5] = Rt @ cov_world[:2, :2] @ Rt.T
    cross = Rt @ cov_world[:2, 2]
    out[3:5, 2] = cross
    out[2, 3:5] = cross
    return out


# ------------------------------------------------------------------------------- latency + init
def estimate_latency(p_sensor, t_obs, sensor_ids, log: Log, recipe: GraphRecipe):
    """Tracker latency (s) minimizing the summed per-sensor rigid-fit residual of the robot's
    pairs over a grid of latencies; returns (latency_s, curve)."""
    grid = np.arange(recipe.latency_min_s, recipe.latency_max_s + 1e-12, recipe.latency_step_s)
    groups = [np.flatnonzero(sensor_ids == sid) for sid in np.unique(sensor_ids)]
    groups = [g for g in groups if len(g) >= 6]
    cost = np.zeros(len(grid))
    for n, lat in enumerate(grid):
        head = head_world(interpolate_pose2(log.robot, t_obs - lat), log.meta.head_offset_m)
        for g in groups:
            _, _, rms = rigid_fit(p_sensor[g], head[g])
            cost[n] += rms ** 2 * len(g)
    i = int(np.argmin(cost))
    if 0 < i < len(grid) - 1:            # parabolic refinement between grid points
        c0, c1, c2 = cost[i - 1], cost[i], cost[i + 1]
        den = c0 - 2 * c1 + c2
        off = 0.5 * (c0 - c2) / den if den > 0 else 0.0
        return float(grid[i] + off * recipe.latency_step_s), (grid, cost)
    return float(grid[i]), (grid, cost)


# ----------------------------------------------------------------------------------- the solver
@dataclass
class FactorGraphProblem:
    """Everything the graph needs, derived once from a log (kept for the online mode and tests)."""

    recipe: GraphRecipe
    latency_s: float
    sensor_ids: list[str]
    obs_sensor: np.ndarray          # sensor id per robot observation
    obs_p_sensor: np.ndarray        # (N, 3) measured head points in the sensor frame
    obs_t: np.ndarray               # latency-corrected instants
    obs_key_index: np.ndarray       # index into pose_times per observation
    pose_times: np.ndarray          # times of the robot pose variables
    init_sensors: dict[str, gtsam.Pose3]
    people: list = field(default_factory=list)   # [(t, [(sensor, p_sensor), ...]), ...]
    rows_used: np.ndarray | None = None


def _observation_noise(recipe: GraphRecipe, range_m: float):
    sig_r = recipe.range_sigma_floor_m + recipe.range_sigma_k_per_m * range_m ** 2
    sig_b = recipe.lateral_sigma_m / max(range_m, 0.3)
    return gtsam.noiseModel.Diagonal.Sigmas(np.array([sig_b, sig_b, sig_r]))


def build_graph(log: Log, prob: FactorGraphProblem, *, t_max: float | None = None):
    """Build the factor graph and the initial values (optionally only with data up to t_max)."""
    rec = prob.recipe
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    head_m = np.asarray(log.meta.head_offset_m, float) - np.array([0.0, 0.0, rec.head_radius_m])

    # Sensors: weak prior at the installed extrinsics.
    sig_rot = np.radians(rec.sensor_prior_sigma_deg)
    sensor_prior = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sig_rot] * 3, [rec.sensor_prior_sigma_m] * 3])
    for i, sid in enumerate(prob.sensor_ids):
        graph.add(gtsam.PriorFactorPose3(S(i), log.sensors[sid].T_world_sensor, sensor_prior))
        values.insert(S(i), prob.init_sensors[sid])

    times = prob.pose_times if t_max is None else prob.pose_times[prob.pose_times <= t_max]
    n_pose = len(times)
    amcl = log.robot.sort_values("t")
    amcl_t = amcl["t"].to_numpy(float)
    base = interpolate_pose2(amcl, times)
    # Robot pose variables, initialized on AMCL, with planarity priors (roll, pitch, height).
    planar = gtsam.noiseModel.Diagonal.Sigmas(np.array(
        [np.radians(rec.planar_sigma_deg)] * 2 + [1e3, 1e3, 1e3, rec.head_height_sigma_m]))
    for k in range(n_pose):
        P = head_frame(*base[k], head_m)
        values.insert(X(k), P)
        graph.add(gtsam.PriorFactorPose3(X(k), P, planar))

    # AMCL as a measurement with a Gauss-Markov error (module docstring).
    key_of_time = {float(t): k for k, t in enumerate(times)}
    if rec.amcl:
        cov = amcl[["cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"]].to_numpy(float)
        sig_xy = np.sqrt(np.median(0.5 * (cov[:, 0] + cov[:, 3])))
        sig_xy = max(sig_xy, 1e-3)
        tau = rec.amcl_correlation_s
        use = amcl_t <= (times[-1] if n_pose else -np.inf)
        j_prev, t_prev = None, None
        tiny = [np.radians(0.05)] * 2
        dt_amcl = float(np.median(np.diff(amcl_t))) if len(amcl_t) > 1 else 1.0
        for j in np.flatnonzero(use):
            k = key_of_time.get(float(amcl_t[j]))
            if k is None:
                continue
            row = amcl.iloc[j]
            C = np.array([[cov[j, 0], cov[j, 1], cov[j, 2]], [cov[j, 1], cov[j, 3], cov[j, 4]],
                          [cov[j, 2], cov[j, 4], cov[j, 5]]])
            # The slow error is a world-frame translation (F is held to a pure translation), so
            # AMCL's heading error is treated as white, inflated to the information of one
            # independent reading per correlation time.
            Cb = amcl_cov_body(C, row["yaw"])
            Cb[3:5, 3:5] *= rec.amcl_white_fraction ** 2
            Cb[2, 3:5] = Cb[3:5, 2] = 0.0
            Cb[2, 2] *= max(1.0, tau / dt_amcl)
            Cb[0, 0] = Cb[1, 1] = tiny[0] ** 2
            Cb[5, 5] = 1e-6
            Z = head_frame(row["x"], row["y"], row["yaw"], head_m)
            graph.add(gtsam.BetweenFactorPose3(A(j), X(k), Z, gtsam.noiseModel.Gaussian.Covariance(Cb)))
            values.insert(A(j), gtsam.Pose3())
            dt = dt_amcl if t_prev is None else max(amcl_t[j] - t_prev, 1e-3)
            # discretized OU prior on the error process (module docstring)
            sp = np.sqrt(2.0 * tau / dt)
            prior = gtsam.noiseModel.Diagonal.Sigmas(np.r_[tiny, 1e-4, sig_xy * sp, sig_xy * sp, 1e-3])
            graph.add(gtsam.PriorFactorPose3(A(j), gtsam.Pose3(), prior))
            if j_prev is not None:
                sq = np.sqrt(2.0 * dt / tau)
                q = gtsam.noiseModel.Diagonal.Sigmas(np.r_[tiny, 1e-4, sig_xy * sq, sig_xy * sq, 1e-3])
                graph.add(gtsam.BetweenFactorPose3(A(j_prev), A(j), gtsam.Pose3(), q))
            j_prev, t_prev = j, amcl_t[j]

    # Odometry (or smoothness) between consecutive robot poses.
    if n_pose > 1:
        if rec.odometry and log.odometry is not None and len(log.odometry) > 1:
            odo = interpolate_pose2(log.odometry, times)
            sig_per_m, yaw_per_m, floor = rec.odometry_sigma_per_m, np.radians(rec.odometry_yaw_sigma_deg_per_m), 1e-3
            src = odo
        elif rec.smoothness:
            src = base
            sig_per_m, yaw_per_m, floor = 0.0, 0.0, 0.0
        else:
            src = None
        if src is not None:
            for k in range(n_pose - 1):
                P0 = head_frame(*src[k], head_m)
                P1 = head_frame(*src[k + 1], head_m)
                d = float(np.hypot(*(src[k + 1, :2] - src[k, :2])))
                dt = times[k + 1] - times[k]
                if sig_per_m > 0:
                    # sigma over a stretch of length Lc is sig_per_m * Lc when every step of
                    # length d carries sig_per_m * sqrt(Lc * d) (see odometry_correlation_m)
                    lc = rec.odometry_correlation_m
                    st = sig_per_m * np.sqrt(lc * d) + floor
                    sy = yaw_per_m * np.sqrt(lc * d) + np.radians(0.05) * dt + 1e-4
                else:   # smoothness: AMCL's short-term increments, error grows with sqrt(dt)
                    st = rec.smoothness_sigma_mps * dt + 1e-3
                    sy = np.radians(2.0) * dt + 1e-4
                nm = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, sy, st, st, 1e-3]))
                graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), P0.between(P1), nm))

    # Robot observations.
    sid_index = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    if rec.robot:
        for n in range(len(prob.obs_t)):
            k = int(prob.obs_key_index[n])
            if k >= n_pose:
                continue
            p = prob.obs_p_sensor[n]
            r = float(np.linalg.norm(p))
            nm = _robust(rec, _observation_noise(rec, r))
            graph.add(gtsam.BearingRangeFactorPose3(S(sid_index[prob.obs_sensor[n]]), X(k), gtsam.Unit3(p),
                                                   r + rec.head_radius_m, nm))

    # People seen by two or more sensors at once.
    if rec.people:
        for m, (t, seen) in enumerate(prob.people):
            if t_max is not None and t > t_max:
                continue
            pts = []
            for sid, p in seen:
                r = float(np.linalg.norm(p))
                nm = _robust(rec, _observation_noise(rec, r))
                graph.add(gtsam.BearingRangeFactor3D(S(sid_index[sid]), L(m), gtsam.Unit3(p), r, nm))
                pts.append(prob.init_sensors[sid].transformFrom(p))
            values.insert(L(m), np.mean(pts, axis=0))
    return graph, values


def prepare(log: Log, recipe: GraphRecipe, is_robot: np.ndarray | None = None, progress: bool = False,
            init_network: SensorNetwork | None = None) -> FactorGraphProblem:
    """Association, latency, initial values and the people's shared observations."""
    if is_robot is None:
        from pedcal.calib.association import associate_robot

        _log(progress, "picking out the robot's observations")
        is_robot = associate_robot(log).is_robot
    is_robot = np.asarray(is_robot, bool)
    obs = log.observations
    p_all = log.observation_points_sensor()
    sensor_col = obs["sensor"].astype(str).to_numpy()
    t_all = obs["t"].to_numpy(float)
    rows = np.flatnonzero(is_robot)
    t_lo, t_hi = log.robot["t"].min(), log.robot["t"].max()
    rows = rows[(t_all[rows] >= t_lo) & (t_all[rows] <= t_hi)]
    p_sensor, t_obs, sids = p_all[rows], t_all[rows], sensor_col[rows]
    latency = 0.0
    if recipe.estimate_latency and len(rows) >= 12:
        latency, _ = estimate_latency(p_sensor, t_obs, sids, log, recipe)
        _log(progress, f"tracker latency estimated at {1000 * latency:.0f} ms")
    t_corr = t_obs - latency

    # Initial sensor poses.
    init = {}
    if init_network is not None:
        init = {s.id: s.T_world_sensor for s in init_network}
    elif recipe.init == "gridsearch":
        from pedcal.calib.gridsearch import calibrate_gridsearch

        res = calibrate_gridsearch(log, is_robot=is_robot, progress=progress)
        init = {s.id: s.T_world_sensor for s in res.network}
    elif recipe.init == "closedform":
        head = head_world(interpolate_pose2(log.robot, t_corr), log.meta.head_offset_m)
        for sid in log.sensors.ids:
            g = sids == sid
            if g.sum() >= 6 and np.linalg.matrix_rank(p_sensor[g] - p_sensor[g].mean(0), tol=0.05) == 3:
                R, t, _ = rigid_fit(p_sensor[g], head[g])
                init[sid] = gtsam.Pose3(gtsam.Rot3(R), t)
    for s in log.sensors:
        init.setdefault(s.id, s.T_world_sensor)

    amcl_t = log.robot["t"].to_numpy(float)
    pose_times, inv = np.unique(np.concatenate([amcl_t, np.round(t_corr, 4)]), return_inverse=True)
    obs_key_index = inv[len(amcl_t):]
    people = _shared_people(log, is_robot, recipe, p_all, init) if recipe.people else []
    _log(progress, f"{len(rows)} robot observations, {len(pose_times)} robot poses, "
                   f"{len(people)} shared person sightings")
    return FactorGraphProblem(recipe=recipe, latency_s=latency, sensor_ids=log.sensors.ids,
                              obs_sensor=sids, obs_p_sensor=p_sensor, obs_t=t_corr,
                              obs_key_index=obs_key_index, pose_times=pose_times, init_sensors=init,
                              people=people, rows_used=rows)


def _shared_people(log: Log, is_robot, recipe: GraphRecipe, p_all, init) -> list:
    """Instants where two sensors see the same (non-robot) person: tracks of different sensors,
    interpolated to a common time grid, whose heads (with the initial extrinsics) agree within
    the gate for the whole overlap. Returns [(t, [(sensor, p_sensor), ...]), ...]."""
    obs = log.observations
    keep = ~np.asarray(is_robot, bool)
    if keep.sum() == 0:
        return []
    sensor_col = obs["sensor"].astype(str).to_numpy()
    track_col = obs["track"].astype(str).to_numpy()
    t_all = obs["t"].to_numpy(float)
    tracks = {}
    for key in sorted(set(zip(sensor_col[keep], track_col[keep], strict=True))):
        m = keep & (sensor_col == key[0]) & (track_col == key[1])
        idx = np.flatnonzero(m)
        idx = idx[np.argsort(t_all[idx])]
        if len(idx) < 4:
            continue
        T = init[key[0]]
        pw = p_all[idx] @ T.rotation().matrix().T + T.translation()
        tracks[key] = (t_all[idx], p_all[idx], pw)
    keys = list(tracks)
    out = []
    dt = recipe.people_sample_s
    for a in range(len(keys)):
        for b in range(a + 1, len(keys)):
            ka, kb = keys[a], keys[b]
            if ka[0] == kb[0]:
                continue
            ta, pa, wa = tracks[ka]
            tb, pb, wb = tracks[kb]
            lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
            if hi - lo < 1.0:
                continue
            grid = np.arange(lo, hi, dt)
            wa_i = np.column_stack([np.interp(grid, ta, wa[:, c]) for c in range(3)])
            wb_i = np.column_stack([np.interp(grid, tb, wb[:, c]) for c in range(3)])
            d = np.linalg.norm((wa_i - wb_i)[:, :2], axis=1)
            if np.median(d) > recipe.people_gate_m or np.max(d) > 2 * recipe.people_gate_m:
                continue
            pa_i = np.column_stack([np.interp(grid, ta, pa[:, c]) for c in range(3)])
            pb_i = np.column_stack([np.interp(grid, tb, pb[:, c]) for c in range(3)])
            for n, t in enumerate(grid):
                out.append((float(t), [(ka[0], pa_i[n]), (kb[0], pb_i[n])]))
    return out


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


def calibrate_factorgraph(log: Log, *, progress: bool = False, graph: str | Path | GraphRecipe | None = None,
                          is_robot: np.ndarray | None = None, online: bool = False,
                          init_network: SensorNetwork | None = None, **recipe_overrides) -> CalibrationResult:
    """Calibrate with pedcal's factor graph. ``graph`` names a recipe in graphs/ or a TOML path;
    keyword overrides set recipe fields by name."""
    t0 = time.perf_counter()
    recipe = graph if isinstance(graph, GraphRecipe) else GraphRecipe.load(graph or "default")
    for k, v in recipe_overrides.items():
        if not hasattr(recipe, k):
            raise ValueError(f"unknown graph recipe field '{k}'")
        setattr(recipe, k, v)
    if not (recipe.robot or recipe.people):
        raise PedcalInputError("the graph recipe uses neither the robot nor people: nothing observes the sensors")
    if online:
        from pedcal.calib.online import calibrate_online

        return calibrate_online(log, recipe=recipe, is_robot=is_robot, progress=progress)

    prob = prepare(log, recipe, is_robot=is_robot, progress=progress, init_network=init_network)
    fg, values = build_graph(log, prob)
    _log(progress, f"optimizing {fg.size()} factors over {values.size()} variables")
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(recipe.max_iterations)
    params.setRelativeErrorTol(recipe.relative_error_tol)
    t_opt = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    result = opt.optimize()
    t_opt = time.perf_counter() - t_opt
    _log(progress, f"converged in {opt.iterations()} iterations, "
                   f"error {fg.error(values):.1f} -> {fg.error(result):.1f}")
    network = _network_from_result(log, prob, fg, result, progress)
    mask = finish_network(log, prob, network)
    return CalibrationResult(network=network, method="factorgraph", runtime_s=time.perf_counter() - t0,
                             is_robot=mask, diagnostics=dict(recipe=recipe.name, latency_s=prob.latency_s,
                                                             iterations=opt.iterations(), factors=fg.size(),
                                                             optimize_s=t_opt,
                                                             variables=values.size(),
                                                             shared_people=len(prob.people)))


def finish_network(log: Log, prob: FactorGraphProblem, network: SensorNetwork) -> np.ndarray:
    """Record the tracker model the graph used (latency, head dome) in the calibrated network and
    return the mask of the observations used as the robot's."""
    network.extra[LATENCY_KEY] = round(prob.latency_s, 4)
    network.extra[HEAD_RADIUS_KEY] = prob.recipe.head_radius_m
    mask = np.zeros(len(log.observations), bool)
    mask[prob.rows_used] = True
    return mask


def _network_from_result(log: Log, prob: FactorGraphProblem, fg, result, progress: bool,
                         marginals: gtsam.Marginals | None = None) -> SensorNetwork:
    rec = prob.recipe
    if marginals is None:
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
        cov = marginals.marginalCovariance(S(i))
        if n_obs + people_count[sid] == 0:
            warnings.warn(f"sensor {sid}: no observation of the robot or of shared people; "
                          "its installed pose is kept", DegenerateDataWarning, stacklevel=2)
            _, sp, sy = sensor_sigma_world(installed.T_world_sensor, cov)
            out.append(SensorExtrinsics(sid, installed.position_m, installed.ypr_deg, sigma_position_m=sp,
                                        sigma_ypr_deg=sy, observations=0, status="no-data"))
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
        _, sp, sy = sensor_sigma_world(T, cov)
        out.append(SensorExtrinsics.from_pose3(sid, T, sigma_position_m=sp, sigma_ypr_deg=sy,
                                               observations=n_obs, status=status,
                                               unobservable=names or None))
    return SensorNetwork(out, frame=log.sensors.frame)
