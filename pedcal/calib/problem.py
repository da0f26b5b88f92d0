"""What the factor graph is built from, derived once from a log (:func:`prepare`): the robot's
observations (associated, latency-corrected, carried to the pose grid and merged per pose),
the initial sensor poses, the calibrated odometry, the sensors' noise estimated from the
observations themselves and the people seen by two sensors at once, in a
:class:`FactorGraphProblem`."""

from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, field

import gtsam
import numpy as np
import pandas as pd

from pedcal import frames
from pedcal.calib.amcl_model import AmclErrorModel, amcl_period_s, amcl_white_sigma, assumed_model
from pedcal.calib.clocks import clock_shift_sensor
from pedcal.calib.common import head_interpolator, ray_basis
from pedcal.calib.headpoint import head_profile_shift_sensor
from pedcal.calib.motion import RobotMotion, calibrate_odometry, smoothed_track
from pedcal.calib.recipe import GraphRecipe, _log, observation_sigmas
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.frames import toward_sensor_horizontal
from pedcal.model import Log, SensorExtrinsics, SensorNetwork, sensor_codes


def factorized(names: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(each row's code, the distinct names in order of first appearance) of ``names``, flattened:
    hashed, not sorted (sorting 400 000 id strings took longer than the rest)."""
    return pd.factorize(np.asarray(names).ravel(), use_na_sentinel=False)


def per_row(names: np.ndarray, value_of, shape: tuple = (), codes: tuple | None = None) -> np.ndarray:
    """``value_of(name)`` for every row of ``names``, stacked; each distinct name's value computed
    once (hundreds of sensors over hundreds of thousands of observations). ``shape``: one value's
    shape, for no rows; ``codes``: :func:`factorized` ``names`` when the caller has them."""
    if not len(names):
        return np.zeros((0,) + tuple(shape))
    inverse, uniq = factorized(names) if codes is None else codes
    return np.stack([np.asarray(value_of(n)) for n in uniq])[inverse]


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
    motion: RobotMotion
    odometry: pd.DataFrame | None = None     # calibrated wheel odometry (odometry frame)
    odometry_estimates: dict = field(default_factory=dict)
    smoothed_amcl: pd.DataFrame | None = None    # AMCL smoothed, when it stands in for odometry
    amcl_jumps_moved_back: int = 0    # relocalization jumps moved back by their steps (amcl_model.jumps_moved_back)
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
    # the spread of the sensors' own departures of the head point (headpoint.estimate_departure_spread's
    # record, None without departures), for the head model's note
    departure_spread: dict | None = None
    # corrections of the calibrated odometry the graph is built with (motion_block): distance
    # scale (-, 0: none), heading drift per metre driven (rad/m) and per second (rad/s)
    odometry_scale_correction: float = 0.0
    odometry_drift_rad_per_m: float = 0.0
    odometry_drift_rad_per_s: float = 0.0

    def head_points_sensor(self) -> np.ndarray:
        """The robot-observation factors' points (sensor frame) with the horizontal shift toward
        the sensor and each sensor's clock offset (pedcal.calib.clocks) taken out: the head
        point moved ray_shift_m along the ray from the offset head top."""
        return (self.fac_p_sensor - self.horizontal_shift_m * self.fac_toward_sensor
                - self.curvature_m * self.fac_up_cos2
                + clock_shift_sensor(self, {}, np.arange(len(self.fac_p_sensor)))    # each sensor's clock
                + head_profile_shift_sensor(self, {}, np.arange(len(self.fac_p_sensor))))   # shift vs distance

    def obs_sensor_codes(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`factorized` ``obs_sensor``, computed once per array (carrying, merging and the
        noise estimate each group the observations by sensor)."""
        hit = self.__dict__.get("_obs_sensor_codes")
        if hit is not None and hit[0] is self.obs_sensor:
            return hit[1]
        codes = factorized(self.obs_sensor)
        self.__dict__["_obs_sensor_codes"] = (self.obs_sensor, codes)
        return codes

    def merge_observations(self, max_sigmas: float = 4.0) -> None:
        """The graph's robot-observation factors: the observations one sensor made of the robot
        carried to one pose predict the same point, so their mean, with the noise's sigma over
        the square root of their count, holds the same information as each of them (the factor
        count drops by the sensors' frame rate over AMCL's). A group in which one observation
        lies beyond ``max_sigmas`` (whitened by the recipe's noise) from the mean of the others
        is left as single observations, for the robust kernel to judge each."""
        n = len(self.obs_key_index)
        sid_index = {sid: i for i, sid in enumerate(self.sensor_ids)}
        sensor_i = per_row(self.obs_sensor, sid_index.get, codes=self.obs_sensor_codes()).astype(int)
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
        # (each factor's sensor's rotation, looked up per factor: not kept per observation)
        R = per_row(self.fac_sensor, self._rotations.get, (3, 3))
        self.fac_toward_sensor = toward_sensor_horizontal(self.fac_p_sensor, R)
        self.fac_up_cos2 = frames.up_by_cos2_elevation(self.fac_p_sensor, R)

    def carry_observations(self, rotations: dict[str, np.ndarray]) -> None:
        """Carry every robot observation to its nearest pose variable: the head seen at
        t = stamp - latency is the head at the pose's time t_k minus the robot's motion from t
        to t_k, p_sensor(t_k) = p_sensor(t) + R_world_sensor^T (h(t_k) - h(t)). ``rotations``:
        current R_world_sensor per sensor (an error of a degree moves a point carried a few
        centimetres by under a millimetre). Then the factors merged (:meth:`merge_observations`)."""
        self.obs_t = self.obs_t_raw - self.latency_s
        tk = self.pose_times
        i = np.clip(np.searchsorted(tk, self.obs_t), 1, max(len(tk) - 1, 1))
        if len(tk) > 1:
            i = np.where(np.abs(tk[i - 1] - self.obs_t) <= np.abs(tk[i] - self.obs_t), i - 1, i)
        else:
            i = np.zeros(len(self.obs_t), int)
        self.obs_key_index = i
        disp = self.motion.displacement(self.obs_t, tk, to_index=i) if len(self.obs_t) else np.zeros((0, 3))
        R = per_row(self.obs_sensor, rotations.get, (3, 3), codes=self.obs_sensor_codes())
        self.obs_p_sensor = self.obs_p_raw + np.einsum("nji,nj->ni", R, disp)
        del R              # (27 MB at 400 000 observations; merge_observations looks them up per factor)
        self._rotations = dict(rotations)
        self.merge_observations()


def _pose_grid(amcl_t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """The AMCL stamps, with gaps longer than ``max_gap_s`` filled evenly."""
    t = np.unique(amcl_t)
    gaps = np.diff(t)
    fill = [np.linspace(a, b, int(np.ceil((b - a) / max_gap_s)) + 1)[1:-1]
            for a, b, g in zip(t[:-1], t[1:], gaps, strict=True) if g > max_gap_s]
    return np.unique(np.concatenate([t, *fill])) if fill else t



def _shared_people(log: Log, is_robot: np.ndarray, recipe: GraphRecipe, network: SensorNetwork,
                   points_sensor: np.ndarray | None = None) -> list:
    """Instants where two sensors see the same person, matched by the alternative's
    shared-observation matcher on tracks that hold no robot observation (``is_robot``; all of
    them when the graph leaves the robot's poses out and the robot is one more person).
    ``points_sensor``: ``log.observation_points_sensor()`` when the caller has it.
    Returns [(t, [(sensor, p_sensor), ...]), ...]."""
    from pedcal.calib.alternative import build_tracks, match_shared_observations

    tracks = {sid: [tr for tr in trs if not is_robot[tr.rows].any()]
              for sid, trs in build_tracks(log, points_sensor).items()}
    report = match_shared_observations(tracks, network, sample_period_s=recipe.people_sample_s)
    out = []
    for m in report.matches:
        for n in range(len(m.t)):
            out.append((float(m.t[n]), [(m.sensor_i, m.p_i_sensor[n]), (m.sensor_j, m.p_j_sensor[n])]))
    return sorted(out, key=lambda x: x[0])


def _initial_sensors(log: Log, recipe: GraphRecipe, is_robot, latency_s, progress,
                     init_network: SensorNetwork | None, *, points_sensor: np.ndarray | None = None,
                     head_at) -> dict[str, gtsam.Pose3]:
    """The sensors' initial poses: ``init_network``'s, or the recipe's initializer's, the installed
    ones where it has none. ``points_sensor``: ``log.observation_points_sensor()``, which the
    closed form reads too, and ``head_at`` :func:`pedcal.calib.common.head_interpolator` of ``log``
    (the association's or prepare's), which the closed form takes rather than making its own."""
    if init_network is not None:
        init = {s.id: s.T_world_sensor for s in init_network}
    elif recipe.init in ("gridsearch", "closedform") and recipe.robot:
        import importlib

        from pedcal.calib import METHODS

        opts = dict(is_robot=is_robot) if recipe.init == "gridsearch" else dict(is_robot=is_robot,
                                                                                latency_s=latency_s,
                                                                                points_sensor=points_sensor,
                                                                                head_at=head_at)
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
            init_network: SensorNetwork | None = None, amcl_steps: np.ndarray | None = None) -> FactorGraphProblem:
    """Association, latency, odometry calibration, initial values, the pose grid, the robot's
    observations carried to it, and the people's shared observations. ``amcl_steps``: the
    relocalization jumps' mask of ``log.robot`` at the recipe's threshold when the caller found
    it (:func:`pedcal.calib.amcl_model.jumps_moved_back`), for the assumed AMCL model."""
    from pedcal.calib.association import associate_robot, estimate_latency

    latency = None
    # (the head points in each sensor's frame, read once: the association, the initializer and
    # the shared people's tracks take them too; so is AMCL's head spline, the association's or made
    # here, for the latency, the closed form and the robot's motion)
    p_all = log.observation_points_sensor()
    head_at = None
    if not recipe.robot:
        # Without the robot's observations the robot is one more unlocalized person, as in the
        # alternative (SNAPCAT-3D): its tracks are shared sightings like anyone's, and no
        # association or latency is needed (a latency common to all sensors cancels between two).
        is_robot, latency = np.zeros(len(log.observations), bool), 0.0
    elif is_robot is None:
        _log(progress, "picking out the robot's observations")
        assoc = associate_robot(log, p_sensor=p_all)
        is_robot, latency, head_at = assoc.is_robot, assoc.latency_s, assoc.head_at
    if head_at is None:
        head_at = head_interpolator(log)
    is_robot = np.asarray(is_robot, bool)
    if not recipe.estimate_latency:
        latency = 0.0
    elif latency is None:
        latency = (estimate_latency(log, is_robot, max_latency_s=recipe.latency_max_s, p_sensor=p_all,
                                    head_at=head_at) if is_robot.sum() >= 12 else 0.0)
    _log(progress, f"tracker latency from the association: {1000 * latency:.0f} ms")
    obs = log.observations
    # (each row's sensor by the column's codes: the names of the rows used taken from them, no
    # Python string made per row, and their codes kept for the grouping by sensor)
    sensor_code, sensor_names = sensor_codes(obs["sensor"])
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
    init = _initial_sensors(log, recipe, is_robot, latency, progress, init_network, points_sensor=p_all,
                            head_at=head_at)
    # robot poses only when something observes them (people-only graphs hold the sensors alone)
    pose_times = _pose_grid(amcl_t, recipe.max_pose_gap_s) if recipe.robot else np.zeros(0)
    prob = FactorGraphProblem(recipe=recipe, latency_s=float(latency), sensor_ids=log.sensors.ids,
                              ray_shift_m=recipe.head_radius_m,
                              obs_sensor=sensor_names[sensor_code[rows]], obs_p_raw=p_all[rows],
                              obs_t_raw=t_all[rows],
                              pose_times=pose_times, init_sensors=init,
                              motion=RobotMotion(log, odometry if odometry is not None else smooth,
                                                 head_at=head_at),
                              odometry=odometry, smoothed_amcl=smooth,
                              odometry_estimates=odo_est, rows_used=rows)
    set_amcl_model(log, prob, assumed_model(log.robot, recipe, steps=amcl_steps), carry=False)
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
            _log(progress, f"observation noise from {noise['pairs']} pairs of consecutive observations: depth "
                           f"{1000 * noise['range_sigma_floor_m']:.1f} mm + {1000 * noise['range_sigma_k_per_m']:.2f} "
                           f"mm/m^2 x r^2, lateral {1000 * noise['lateral_sigma_m']:.1f} mm")
    # (the observations' factors merged against the noise estimated, when it is)
    prob.carry_observations({sid: T.rotation().matrix() for sid, T in init.items()})
    if recipe.people:
        net = SensorNetwork([SensorExtrinsics.from_pose3(sid, init[sid]) for sid in log.sensors.ids],
                            frame=log.sensors.frame)
        prob.people = _shared_people(log, is_robot, recipe, net, points_sensor=p_all)
    _log(progress, f"{len(rows)} robot observations, {len(pose_times)} robot poses, "
                   f"{len(prob.people)} shared person sightings")
    return prob


MAX_NOISE_RHO = 0.9          # a frame-to-frame correlation of the tracker's noise beyond this is taken as this
STILL_M = 0.005              # the robot's head moving less than this between two reports: standing still
STILL_MARGIN_S = 0.5         # ... and as little from this long before them to as long after
NOISE_LAGS = 6               # the tracker noise's correlation fitted to reports 1 .. this many frames apart


def estimate_observation_noise(log: Log, prob: FactorGraphProblem, max_gap_s: float = 0.25,
                               min_pairs: int = 100) -> dict | None:
    """The sensors' noise from the robot's observations themselves, without any fit: two
    consecutive observations of one track (at most ``max_gap_s`` apart), the later carried back
    to the earlier's instant by the robot's motion, differ by the two observations' noise alone.
    Half the robust variance of that difference along the ray gives the depth noise, binned by
    range and fitted by ``floor + k r^2`` (times ``far_factor`` past ``reliable_range_m``, as the
    graph models it); across the ray, the lateral noise (with the latency jitter times the
    robot's speed in it). A tracker that smooths its output makes consecutive reports alike: the
    noise's correlation from one frame to the next (an AR(1)'s rho, capped at MAX_NOISE_RHO) is
    fitted to the variances of reports 1..NOISE_LAGS frames apart taken while the robot stood
    still, and each frame's noise is one frame's difference's over sqrt(1 - rho); the graph's
    factors are widened for the correlation (:func:`pedcal.calib.graph.noise_correlation_factor`).
    Returns the recipe's three noise fields, the number of pairs, ``frame_correlation`` (along the
    ray, across it), ``still_pairs`` (pairs of consecutive reports of a still robot it was read
    from; 0: rho taken as 0) and ``frame_period_s`` (the median time between consecutive
    reports), or None with fewer than ``min_pairs`` pairs. ``prob``'s observations need not be carried yet
    (their instants, stamp - latency, are taken here)."""
    rec = prob.recipe
    rows = prob.rows_used
    if rows is None or len(rows) < 2:
        return None
    obs_t = prob.obs_t_raw - prob.latency_s
    # (the tracks and sensors by integer codes: a sort of 400 000 id strings took longer than the
    # rest; the track column's codes by its values' texts, as association numbers them: an object
    # column's 1, 1.0 and True are distinct tracks, no Python string made per row otherwise)
    track = sensor_codes(log.observations["track"])[0][rows].astype(np.int64)
    sensor, sensor_ids = prob.obs_sensor_codes()
    # by sensor, then track, then time: (sensor, track) as one key, an order the same as three keys'
    order = np.lexsort((obs_t, sensor.astype(np.int64) * (int(track.max(initial=0)) + 1) + track))
    s_o, tr_o, t_o = sensor[order], track[order], obs_t[order]
    dt = np.diff(t_o)
    same = (s_o[1:] == s_o[:-1]) & (tr_o[1:] == tr_o[:-1])
    nxt = same & (dt > 0.0) & (dt <= max_gap_s)
    i, j = order[:-1][nxt], order[1:][nxt]
    if len(i) < min_pairs:
        return None
    R_sensor = np.stack([prob.init_sensors[sid].rotation().matrix() for sid in sensor_ids])

    def differences(i, j):
        """(along, lateral 1, lateral 2, range, the robot's move) of observation j carried back to
        i's instant, less i, and the length of the head's move carried (m)."""
        disp = prob.motion.displacement(obs_t, obs_t, from_index=j, to_index=i)
        p_i = prob.obs_p_raw[i]
        d = prob.obs_p_raw[j] + np.einsum("nji,nj->ni", R_sensor[sensor[i]], disp) - p_i
        r = np.linalg.norm(p_i, axis=1)
        u = p_i / r[:, None]
        b1, b2 = ray_basis(u)
        return np.sum(d * u, axis=1), np.sum(d * b1, axis=1), np.sum(d * b2, axis=1), r, np.linalg.norm(disp, axis=1)

    def robust_sigma(x):
        return 1.4826 * float(np.median(np.abs(x - np.median(x)))) / np.sqrt(2.0)     # one observation's

    one_frame = differences(i, j)
    along, l1, l2, r, _ = one_frame
    # a tracker that smooths its output (a filter's track, correlated frame to frame: rho at one
    # frame) makes consecutive reports alike: for an AR(1) the difference of reports k frames
    # apart has variance 2 s^2 (1 - rho^k), one frame's 2 s^2 (1 - rho), so s^2 = one frame's /
    # (1 - rho). rho fitted to those variances at k = 1..NOISE_LAGS (_fit_frame_correlation),
    # from reports of a track taken while the robot stood still (its head moving less than
    # STILL_M over them and for STILL_MARGIN_S before and after: a sensor's clock off by a tenth of
    # a second stamps a report of the robot slowing to a stop as still): the robot's motion
    # carried between reports adds its own error, larger the further apart, which would read as a
    # correlation (0.5-0.9 on simulated white noise). 0 when the robot stood too little
    # (fewer than ``min_pairs`` such pairs one frame apart)
    lag_along, lag_lateral, lag_pairs = [], [], []
    # (each report's robot still for STILL_MARGIN_S before it and after it, taken once)
    still_before = np.linalg.norm(prob.motion.displacement(obs_t - STILL_MARGIN_S, obs_t), axis=1) < STILL_M
    still_after = np.linalg.norm(prob.motion.displacement(obs_t, obs_t + STILL_MARGIN_S), axis=1) < STILL_M
    n_o = len(order)
    run = np.ones(n_o, bool)
    for k in range(1, NOISE_LAGS + 1):
        if n_o <= k:
            break
        run = run[:-1] & same[k - 1:]             # reports o[q] .. o[q + k] of one sensor's track
        span = t_o[k:] - t_o[:-k]
        pair = run & (span > 0.0) & (span <= k * max_gap_s)
        a, b = order[:-k][pair], order[k:][pair]
        # (one frame apart these are the pairs the noise's level is read from: their differences kept)
        al, la1, la2, _, move = one_frame if k == 1 else differences(a, b)
        still = (move < STILL_M) & still_before[a] & still_after[b]
        if still.sum() < 30:
            break
        lag_along.append(robust_sigma(al[still]) ** 2)
        lag_lateral.append(0.5 * (robust_sigma(la1[still]) ** 2 + robust_sigma(la2[still]) ** 2))
        lag_pairs.append(int(still.sum()))
    rho_along = rho_lateral = 0.0
    read = len(lag_pairs) >= 2 and lag_pairs[0] >= min_pairs
    if read:
        rho_along = _fit_frame_correlation(np.array(lag_along), np.array(lag_pairs))
        rho_lateral = _fit_frame_correlation(np.array(lag_lateral), np.array(lag_pairs))
    lateral = float(np.sqrt(0.5 * (robust_sigma(l1) ** 2 + robust_sigma(l2) ** 2) / (1.0 - rho_lateral)))
    edges = np.quantile(r, np.linspace(0.0, 1.0, 7))
    r_bin, s_bin, n_bin = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (r >= lo) & (r <= hi)
        if m.sum() >= 20:
            r_bin.append(float(np.median(r[m])))
            s_bin.append(robust_sigma(along[m]) / np.sqrt(1.0 - rho_along)
                         / (rec.far_factor if np.median(r[m]) > rec.reliable_range_m else 1.0))
            n_bin.append(int(m.sum()))
    if len(r_bin) < 2:
        return None
    r_bin, s_bin, w = np.array(r_bin), np.array(s_bin), np.sqrt(np.array(n_bin, float))
    M = np.column_stack([np.ones(len(r_bin)), r_bin ** 2])
    floor, k = np.linalg.lstsq(M * w[:, None], s_bin * w, rcond=None)[0]
    if k < 0.0:
        floor, k = float(np.average(s_bin, weights=w)), 0.0
    return {"range_sigma_floor_m": float(max(floor, 1e-3)), "range_sigma_k_per_m": float(k),
            "lateral_sigma_m": float(max(lateral, 1e-3)), "pairs": int(len(i)),
            "frame_correlation": {"along": round(rho_along, 4), "lateral": round(rho_lateral, 4)},
            "still_pairs": int(lag_pairs[0]) if read else 0,
            "frame_period_s": round(float(np.median(dt[nxt])), 6)}


def _fit_frame_correlation(var_m2: np.ndarray, pairs: np.ndarray) -> float:
    """The AR(1) coefficient rho of a tracker's noise from half the variances ``var_m2`` of reports
    k = 1, 2, ... frames apart (s^2 (1 - rho^k)), by least squares in their relative errors (each
    weighed by its pairs), s^2 in closed form at each rho of a grid 0 .. MAX_NOISE_RHO (0.005
    apart); 0 where the variances do not grow with k (white noise)."""
    k = np.arange(1, len(var_m2) + 1, dtype=float)
    w = pairs / np.maximum(var_m2, 1e-30) ** 2
    best, best_cost = 0.0, np.inf
    for rho in np.arange(0.0, MAX_NOISE_RHO + 1e-9, 0.005):
        g = 1.0 - rho ** k
        s2 = float(np.sum(w * g * var_m2) / np.sum(w * g * g))
        cost = float(np.sum(w * (var_m2 - s2 * g) ** 2))
        if cost < best_cost:
            best, best_cost = float(rho), cost
    return best


def set_amcl_model(log: Log, prob: FactorGraphProblem, model: AmclErrorModel, *, carry: bool = True,
                   rotations: dict[str, np.ndarray] | None = None) -> bool:
    """Build the graph with AMCL's error ``model`` from now on: the error process's nodes spaced
    for its correlation time and, when the model leaves estimates out as jumps and AMCL stands in
    for odometry, the robot's short-term motion from AMCL without them (observations carried
    again, with ``rotations``, the current R_world_sensor per sensor, when ``carry``). Returns
    whether the robot's motion changed (the observations then carried again, or to be)."""
    rec = prob.recipe
    t_a = np.unique(log.robot["t"].to_numpy(float))
    dn = model.node_spacing_s(amcl_period_s(t_a, rec.amcl_node_spacing_s), rec.amcl_node_spacing_s)
    prob.amcl_node_times = t_a[0] + dn * np.arange(int(np.round((t_a[-1] - t_a[0]) / dn)) + 1)
    prob.amcl_model = model
    if model.excluded is None or prob.odometry is not None:
        return False
    clean = copy.copy(log)
    clean.robot = log.robot.sort_values("t", kind="stable")[~model.excluded]
    if prob.smoothed_amcl is not None:
        prob.smoothed_amcl = smoothed_track(clean.robot, rec.amcl_smooth_s)
        prob.motion = RobotMotion(clean, prob.smoothed_amcl)
    else:
        prob.motion = RobotMotion(clean, None)
    if carry:
        prob.carry_observations(rotations or {sid: T.rotation().matrix() for sid, T in prob.init_sensors.items()})
    return True



__all__ = ["FactorGraphProblem", "prepare", "estimate_observation_noise", "set_amcl_model"]
