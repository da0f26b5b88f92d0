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
  ``Log(Z_j^{-1} F_j^{-1} X)`` and the white error (plus the process's change since its node;
  with the recipe's ``amcl_change_per_span`` its variance times the number of estimates between
  the same two nodes, those changes being one path, not independent draws,
  :func:`~pedcal.calib.amcl_model.node_drift_variance`) as noise. The process on F is the exact
  AR(1) of an OU process sampled every dn on its nodes, a = exp(-dn / tau), written as factors:
  ``BetweenFactorPose3(a(j), a(j+1), I)`` of variance sigma^2 (1 - a^2) / a and zero priors of
  variance sigma^2 (1 + a) / (1 - a) on every node (the AR(1)'s exact precision but at the two
  ends, where the process is left free: :func:`~pedcal.calib.amcl_model.ar1_factor_sigmas`).
  AMCL's heading error cannot be a world-frame rotation (that would swing the
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
  mean with sigma / sqrt(n) (:meth:`FactorGraphProblem.merge_observations`), widened for a
  tracker whose noise is correlated from frame to frame (:func:`noise_correlation_factor`). Depth noise is
  ``floor + k r^2`` (doubled past the reliable range) and the lateral noise constant, both
  estimated from consecutive observations (:func:`estimate_observation_noise`) and taken at the
  range the variables predict, not the noisy one observed (:class:`Regressors`, as is the
  distance the shift's profile is read at); a robust kernel keeps mis-associations (a
  pedestrian beside the robot) from dragging.
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

from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.sparse as sps

from pedcal import frames
from pedcal.calib.amcl_model import (  # noqa: F401
    AmclErrorModel,
    amcl_cov_body,
    amcl_period_s,
    amcl_white_sigma,
    ar1_factor_sigmas,
    ar1_long_run_factor,
    assumed_model,
    node_drift_variance,
)

# (the graph layer's other names are re-exported from the modules that hold them: F401)
from pedcal.calib.clocks import clock_shift_sensor
from pedcal.calib.common import gaussian_smooth_nearest, head_world, interpolate_pose2, rows_taken
from pedcal.calib.headpoint import head_profile_shift_sensor, horizontal_distance
from pedcal.calib.keys import A, H, L, S, X, symbol_parts, symbols  # noqa: F401 (the graph's keys, re-exported)
from pedcal.calib.motion import (  # noqa: F401
    RobotMotion,
    calibrate_odometry,
    head_frame,
    smoothed_increment_var,
    smoothed_track,
)
from pedcal.calib.problem import (  # noqa: F401
    FactorGraphProblem,
    estimate_observation_noise,
    prepare,
    set_amcl_model,
)
from pedcal.calib.profile import linear_solver, steps_to_come_below
from pedcal.calib.readback import (  # noqa: F401
    JOINT_COV_MAX_SENSORS,
    _network_from_result,
    finish_network,
    observability,
    rotation_sigma_deg,
    sensor_sigma_world,
)
from pedcal.calib.recipe import GRAPHS_DIR, GraphRecipe, _log, observation_sigmas  # noqa: F401
from pedcal.errors import PedcalInputError
from pedcal.frames import toward_sensor_horizontal, wrap_angle_rad
from pedcal.model import Log


def head_frames(pose2: np.ndarray, head_m: np.ndarray) -> list:
    """:func:`~pedcal.calib.motion.head_frame` of every base pose (N, 3) [x, y, yaw]: the head
    offsets turned into the world in one pass, a Pose3 made per row (GTSAM's Rot3.Yaw, as there)."""
    pose2 = np.asarray(pose2, float).reshape(-1, 3)
    t = head_world(pose2, head_m)
    yaw_of, pose3 = gtsam.Rot3.Yaw, gtsam.Pose3
    return [pose3(yaw_of(yaw), row) for yaw, row in zip(pose2[:, 2].tolist(), t, strict=True)]


def pose_arrays(values: gtsam.Values, keys) -> tuple[np.ndarray, np.ndarray]:
    """The rotations (n, 3, 3) and translations (n, 3) of the Pose3 variables ``keys`` of
    ``values``, read in one pass (GTSAM's extractPose3: every Pose3 in key order) instead of one
    lookup per key. A key that is not a Pose3 of ``values`` raises KeyError."""
    keys = np.asarray(keys, np.uint64).ravel()
    if not len(keys):
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    rows = np.asarray(gtsam.utilities.extractPose3(values), float).reshape(-1, 12)
    # the Pose3 keys, in the same (key) order: every key when every variable is a Pose3 (the
    # robot's graph without people), else GTSAM's copy of the Pose3 variables' keys
    have = np.asarray(values.keys(), np.uint64)
    if len(have) != len(rows):
        have = np.asarray(gtsam.utilities.allPose3s(values).keys(), np.uint64)
    at = np.searchsorted(have, keys)
    if np.any(at >= len(have)) or np.any(have[np.minimum(at, len(have) - 1)] != keys):
        missing = keys[(at >= len(have)) | (have[np.minimum(at, len(have) - 1)] != keys)][0]
        raise KeyError(f"no Pose3 {gtsam.Symbol(int(missing)).string()} in the values")
    picked = rows[at]
    # laid out as stacked Rot3.matrix() (column-major blocks) and translations are, so that the
    # products taken of them (einsum, matmul) sum in the same order, to the last digit
    R = np.ascontiguousarray(picked[:, :9].reshape(-1, 3, 3).transpose(0, 2, 1)).transpose(0, 2, 1)
    return R, np.ascontiguousarray(picked[:, 9:])


def _robust(recipe: GraphRecipe, base):
    k = recipe.robust_kernel.lower()
    if k == "none":
        return base
    est = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
           "tukey": gtsam.noiseModel.mEstimator.Tukey}.get(k)
    if est is None:
        raise PedcalInputError(f"unknown robust kernel '{recipe.robust_kernel}'", column="robust_kernel")
    return gtsam.noiseModel.Robust.Create(est.Create(recipe.robust_k), base)



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
    # what the motion block was built from (:func:`_motion_inputs`), for :func:`rebuild_parts`
    motion_inputs: tuple | None = None
    # the whole graph's COLAMD ordering (``graph().orderingCOLAMD()``), once computed: the
    # solver's elimination order, and the profile's fill-reducing order of the same structure
    ordering: gtsam.Ordering | None = None
    # what the graph's structure (its factors' keys, in order) was made from (:func:`_structure`):
    # a rebuild of the same structure keeps the ordering
    structure: tuple | None = None

    def colamd(self) -> gtsam.Ordering:
        """The whole graph's COLAMD ordering, computed on the first call and kept (the blocks
        are rebuilt with the same structure, or the parts built anew)."""
        if self.ordering is None:
            self.ordering = self.graph().orderingCOLAMD()
        return self.ordering

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
        values.insert(S(i), pose3=prob.init_sensors[sid])
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
    # (the Pose3 overload named: GTSAM's binding otherwise tries nine others first, a third of the call)
    insert = values.insert
    for key, P in zip(symbols("x", range(n_pose)).tolist(), head_frames(init, head_m), strict=True):
        insert(key, pose3=P)
        if not rec.amcl:
            blocks["amcl"].add(gtsam.PriorFactorPose3(key, P, planar))
    amcl = _amcl_block(blocks["amcl"], values, log, prob, times) if rec.amcl and n_pose else None
    if n_pose > 1:
        blocks["motion"] = motion_block(log, prob, t_max=t_max)
    # (the regressors read at the measured points: the initial values are no solution)
    blocks["observations"] = observation_block(log, prob, values, t_max=t_max, insert_values=True, predicted=False)
    return GraphParts(blocks=blocks, values=values, motion_inputs=_motion_inputs(prob, t_max),
                      structure=_structure(prob, t_max, amcl))


def _structure(prob: FactorGraphProblem, t_max: float | None, amcl: tuple | None) -> tuple | None:
    """What the whole graph's structure is made from: the AMCL block's (:func:`_amcl_block`), the
    problem's robot-observation factors and recipe (as objects: they are replaced, never changed
    in place), the poses' count, ``t_max`` and whether the motion is odometry's; None (nothing
    kept) with shared people, whose sightings a rebuild may leave out."""
    if prob.people:
        return None
    return (amcl, prob.recipe, prob.fac_sensor_index, prob.fac_key_index, len(_pose_times(prob, t_max)), t_max,
            prob.odometry is None)


def _same_structure(a: tuple | None, b: tuple | None) -> bool:
    """Whether two :func:`_structure` answers are the same: the AMCL block's by value, the
    problem's tables and recipe by identity."""
    if a is None or b is None or len(a) != len(b):
        return False
    (amcl_a, *rest_a), (amcl_b, *rest_b) = a, b
    if (amcl_a is None) != (amcl_b is None):
        return False
    if amcl_a is not None and not (len(amcl_a) == len(amcl_b) and all(
            np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
            for x, y in zip(amcl_a, amcl_b, strict=True))):
        return False
    return all(x is y if isinstance(x, (np.ndarray, GraphRecipe)) else x == y
               for x, y in zip(rest_a, rest_b, strict=True))


def _motion_inputs(prob: FactorGraphProblem, t_max: float | None) -> tuple:
    """What :func:`motion_block` reads of the problem: its tables and times (compared as objects:
    :func:`pedcal.calib.problem.set_amcl_model` replaces them, never changes them in place) and
    the odometry's corrections (by value)."""
    return (prob.odometry, prob.smoothed_amcl, prob.pose_times, prob.recipe, t_max,
            tuple(float(getattr(prob, k)) for k in ODOMETRY_NUISANCES))


def _same_inputs(a: tuple | None, b: tuple) -> bool:
    return a is not None and len(a) == len(b) and all(x is y or (isinstance(x, tuple) and x == y)
                                                      for x, y in zip(a, b, strict=True))


def rebuild_parts(log: Log, prob: FactorGraphProblem, parts: GraphParts, result: gtsam.Values,
                  observations: bool = True) -> GraphParts:
    """The graph once AMCL's error model (:func:`set_amcl_model`) or the shared people changed,
    with its variables at ``result``: what :func:`build_parts` makes, its values then taken from
    ``result`` where it has them, except the AMCL error nodes (at zero, for the caller to set).
    The sensors' priors, and the motion block when its inputs are the ones it was built from,
    are kept from ``parts`` (the same factors, in the same order); the AMCL and observation
    blocks are built anew. The robot poses are not initialized from the track, since ``result``
    holds every one of them (else the whole graph is built again). ``observations=False`` leaves
    the observation block empty, for a caller that builds it at its own values next (the
    people's positions then taken from ``result``, which must hold them all: else it is built)."""
    n_pose = len(prob.pose_times)
    rec = prob.recipe
    # (every sensor and robot pose looked up in the values' keys at once, not one binding call each)
    held = np.isin(np.r_[symbols("s", range(len(prob.sensor_ids))), symbols("x", range(n_pose))],
                   np.asarray(result.keys(), np.uint64))
    if not rec.amcl or not held.all():
        # (without AMCL the planarity priors sit at the initial track, which the model's jumps change)
        new = build_parts(log, prob)
        for key in new.values.keys():
            c = chr(gtsam.Symbol(key).chr())
            if c != "a" and result.exists(key):
                new.values.update(key, result.atPoint3(key) if c == "l" else result.atPose3(key))
        return new
    observations = observations or not all(result.exists(L(m)) for m in range(len(prob.people)))
    # (without the observation block, the people's positions are kept from ``result`` as they are)
    values = _kept_values(result, {"s": len(prob.sensor_ids), "x": n_pose}
                          | ({} if observations else {"l": len(prob.people)}))
    blocks = {"sensors": parts.blocks["sensors"], "amcl": gtsam.NonlinearFactorGraph()}
    amcl = None
    if n_pose:
        amcl = _amcl_block(blocks["amcl"], values, log, prob, prob.pose_times)   # inserts h(0) and the nodes a(j)
        if values.exists(H(0)) and result.exists(H(0)):
            values.update(H(0), pose3=result.atPose3(H(0)))
    inputs = _motion_inputs(prob, None)
    if n_pose > 1:
        blocks["motion"] = (parts.blocks["motion"] if _same_inputs(parts.motion_inputs, inputs)
                            else motion_block(log, prob))
    else:
        blocks["motion"] = gtsam.NonlinearFactorGraph()
    # (the same structure as the graph rebuilt: its COLAMD ordering kept, 0.07 s at 1000 sensors)
    structure = _structure(prob, None, amcl)
    kept = parts.ordering if _same_structure(parts.structure, structure) else None
    if not observations:
        # (the block the caller builds next would replace this one: 0.14 s at 1000 sensors)
        blocks["observations"] = gtsam.NonlinearFactorGraph()
        # (a kept ordering holds for the graph once the caller's block is back: the same structure;
        # with people, _structure gives None and no ordering is kept)
        return GraphParts(blocks=blocks, values=values, motion_inputs=inputs, structure=structure, ordering=kept)
    blocks["observations"] = observation_block(log, prob, values, insert_values=True)
    for m in range(len(prob.people)):
        if values.exists(L(m)) and result.exists(L(m)):
            values.update(L(m), result.atPoint3(L(m)))
    return GraphParts(blocks=blocks, values=values, motion_inputs=inputs, structure=structure, ordering=kept)


def _kept_values(values: gtsam.Values, kept: dict[str, int]) -> gtsam.Values:
    """A copy of ``values`` with only the variables ``c(j)``, ``j < kept[c]`` (by symbol character
    c): one copy and a few erasures, where inserting every pose anew costs GTSAM's Python
    binding ~7 us a key (its overloads tried one by one)."""
    out = gtsam.Values(values)
    keys = np.asarray(values.keys(), np.uint64)
    chars, index = symbol_parts(keys)
    keep = np.zeros(len(keys), bool)
    for c, n in kept.items():
        keep |= (chars == np.uint64(ord(c))) & (index < np.uint64(n))
    for key in keys[~keep].tolist():
        out.erase(key)
    return out


def initial_track(log: Log, prob: FactorGraphProblem, times: np.ndarray, smooth_s: float = 5.0) -> np.ndarray:
    """(N, 3) base poses [x, y, yaw] to start the robot poses from: with odometry, its path
    carried into the map by AMCL's map-from-odometry transform smoothed over ``smooth_s`` (the
    path then has odometry's shape, which its factors expect, and AMCL's place); without it AMCL
    smoothed (when it jitters) or AMCL itself. AMCL's estimates the error model left out as
    jumps are not used."""
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
    sig = smooth_s / max(amcl_period_s(t_a, 1.0), 1e-3)
    # the transform's components smoothed (the rotation through its sine and cosine)
    tx, ty, c, s_ = (gaussian_smooth_nearest(v, sig) for v in (tx, ty, c, s_))
    yaw_d = np.arctan2(s_, c)
    o = interpolate_pose2(prob.odometry, times)
    D = np.column_stack([np.interp(times, t_a, tx), np.interp(times, t_a, ty), np.interp(times, t_a, np.unwrap(yaw_d))])
    c, s_ = np.cos(D[:, 2]), np.sin(D[:, 2])
    return np.column_stack([D[:, 0] + c * o[:, 0] - s_ * o[:, 1], D[:, 1] + s_ * o[:, 0] + c * o[:, 1],
                            D[:, 2] + o[:, 2]])


def _amcl_measurements(log: Log, prob: FactorGraphProblem) -> tuple:
    """AMCL's estimates in time order as the AMCL block reads them: (t, yaw, the six covariance
    columns (n, 6), each estimate's head frame, a Pose3 (:func:`head_frames`)), read
    once per robot table and head frame and kept on the problem: the block is built again under
    AMCL's estimated error model (:func:`rebuild_parts`) from the same estimates."""
    head_m = _head_m(log, prob.recipe)
    hit = prob.__dict__.get("_amcl_measurements")
    if hit is not None and hit[0] is log.robot and np.array_equal(hit[1], head_m):
        return hit[2]
    amcl = log.robot.sort_values("t", kind="stable")
    x, y, yaw = (amcl[c].to_numpy(float) for c in ("x", "y", "yaw"))
    arrays = (amcl["t"].to_numpy(float, copy=True), yaw.copy(),
              amcl[["cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"]].to_numpy(float, copy=True))
    for a in arrays:       # (kept for the rebuild: no caller may write into them)
        a.setflags(write=False)
    read = (*arrays, tuple(head_frames(np.column_stack([x, y, yaw]), head_m)))
    prob.__dict__["_amcl_measurements"] = (log.robot, head_m, read)
    return read


def _amcl_block(graph, values, log: Log, prob: FactorGraphProblem, times: np.ndarray) -> tuple:
    """AMCL as a measurement with a Gauss-Markov error (module docstring), under the problem's
    AMCL error model (:class:`pedcal.calib.amcl_model.AmclErrorModel`): each estimate tied to the
    nearest node of the error process with its white error and the process's change since the
    node; the process itself as the exact discretization of an Ornstein-Uhlenbeck process on the
    nodes; estimates the model marks as jumps left out. Returns what the block's structure is
    made from: (each estimate's pose index, its node, the nodes' count, whether the nodes are
    chained, whether they are tied to h(0))."""
    rec = prob.recipe
    model = prob.amcl_model
    amcl_t, yaw_all, cov, frames = _amcl_measurements(log, prob)
    n_pose = len(times)
    k_of = np.searchsorted(times, amcl_t)
    use = (k_of < n_pose) & (times[np.minimum(k_of, n_pose - 1)] == amcl_t)
    if model.excluded is not None:
        use &= ~model.excluded
    use = np.flatnonzero(use)
    dt_amcl = amcl_period_s(amcl_t, 1.0)
    nodes = prob.amcl_node_times
    dn = float(nodes[1] - nodes[0]) if len(nodes) > 1 else 1.0
    # white error (the model's share of the reported covariance and its own std) and the OU's
    # change since the node, with the recipe's amcl_change_per_span its variance times the
    # estimates sharing the span between two nodes (node_drift_variance: one path, not independent draws)
    node_of, drift_var = node_drift_variance(amcl_t[use], float(nodes[0]) if len(nodes) else 0.0, dn, len(nodes),
                                             max(model.correlated_sigma_m, 1e-4), model.correlation_s,
                                             per_span=rec.amcl_change_per_span)
    tiny = np.radians(0.05)
    tau = max(model.correlation_s, 1e-3)
    sig_c = max(model.correlated_sigma_m, 1e-4)
    yaw_a = yaw_all[use]
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
    Cb[:, 3:5, 3:5] += (model.white_sigma_m ** 2 + drift_var)[:, None, None] * np.eye(2)
    Cb[:, 5, 5] = 1e-6
    between, covariance, add = gtsam.BetweenFactorPose3, gtsam.noiseModel.Gaussian.Covariance, graph.add
    for a_key, x_key, u, C in zip(symbols("a", node_of).tolist(), symbols("x", k_of[use]).tolist(), use.tolist(), Cb,
                                  strict=True):
        add(between(a_key, x_key, frames[u], covariance(C)))
    # The error process on its nodes: the exact AR(1) of an OU process sampled every dn,
    # a = exp(-dn / tau), written as increments and per-node priors (module docstring).
    a = float(np.exp(-dn / tau))
    free_z = rec.estimate_head_model
    z_sig = 1e2 if free_z else 1e-3

    def sig6(s_xy: float, s_z: float):
        return gtsam.noiseModel.Diagonal.Sigmas(np.array([tiny, tiny, 1e-4, s_xy, s_xy, s_z]))

    n_nodes = int(node_of.max()) + 1 if len(use) else 0
    prior_sig, step_sig = ar1_factor_sigmas(sig_c, a, n_nodes)
    by_sigma = {s: sig6(s, z_sig) for s in set(prior_sig.tolist())}      # (one value)
    priors = [by_sigma[s] for s in prior_sig.tolist()]
    q = sig6(min(step_sig, 1e6), 1e-3)
    if free_z and n_nodes:
        # The head point's vertical offset from its initial value (-head_radius_m) is the height
        # of the variable h (its prior is in the observation block: it depends on the ray shift):
        # every AMCL error node's height is tied to it, so every robot pose, and with it every
        # head point the sensors see, moves up or down with it alike.
        values.insert(H(0), pose3=gtsam.Pose3())
        tie = gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, 1.0, 1e3, 1e3, 1e-4]))
    # (one identity Pose3 and the keys made once: the factors keep copies)
    identity, node_keys, h_key = gtsam.Pose3(), symbols("a", range(n_nodes)).tolist(), H(0)
    prior_factor, insert = gtsam.PriorFactorPose3, values.insert
    for m, key in enumerate(node_keys):
        insert(key, pose3=identity)
        add(prior_factor(key, identity, priors[m]))
        if m and a > 1e-9:
            add(between(node_keys[m - 1], key, identity, q))
        if free_z:
            add(between(h_key, key, identity, tie))
    return k_of[use], node_of, n_nodes, a > 1e-9, free_z


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
        turn, tx, ty, sy, st = _odometry_steps(log, prob, times, theta)
        yaw_of, pose3 = gtsam.Rot3.Yaw, gtsam.Pose3
        steps = [pose3(yaw_of(a), t) for a, t in zip(turn.tolist(), np.column_stack([tx, ty, np.zeros(len(tx))]),
                                                       strict=True)]
    elif rec.smoothness:
        amcl = log.robot.sort_values("t")
        src = interpolate_pose2(amcl if prob.smoothed_amcl is None else prob.smoothed_amcl, times)
        # AMCL's short-term increments: error grows with dt, plus AMCL's white jitter at both ends
        white = amcl_white_sigma(log.robot)
        jitter_var = 2.0 * white ** 2
        if prob.smoothed_amcl is not None:
            # the smoothed increments' errors are alike over the kernel's 2 s / dt steps, so each
            # counts that many times
            rate = 1.0 / max(amcl_period_s(np.unique(log.robot["t"].to_numpy(float)), 1.0), 1e-3)
            jitter_var = (smoothed_increment_var(white, dt, rate, rec.amcl_smooth_s)
                          * np.maximum(2.0 * rec.amcl_smooth_s / dt, 1.0))
        st = np.sqrt((rec.smoothness_sigma_mps * dt) ** 2 + jitter_var) + 1e-3
        sy = np.radians(2.0) * dt + 1e-4
        P = head_frames(src, head_m)
        steps = [P[k].between(P[k + 1]) for k in range(n_pose - 1)]
    else:
        return graph
    # one noise model per distinct (turn, translation) sigma, rounded to 0.1 %
    uniq, inverse = unique_rows(_motion_sigma_keys(sy, st))
    models = [gtsam.noiseModel.Diagonal.Sigmas(_motion_sigmas(row[None, :])[0]) for row in uniq]
    between, add = gtsam.BetweenFactorPose3, graph.add
    keys = symbols("x", range(n_pose)).tolist()
    for k0, k1, step, i in zip(keys[:-1], keys[1:], steps, np.asarray(inverse).ravel().tolist(), strict=True):
        add(between(k0, k1, step, models[i]))
    return graph


@dataclass
class ObservationTerms:
    """The observation block's factors as arrays, in the block's order (the head offset's prior,
    then one bearing-range factor per robot observation and per person's sighting): what
    :func:`observation_block` makes GTSAM factors of and :func:`observation_rhs` evaluates in
    numpy. ``noise_range_m`` and ``noise_scale``: the range the sigmas are taken at (predicted:
    :class:`Regressors`) and the factor's scale of them (1 / sqrt of the merged count, times
    ``sigma_scale``)."""

    prior: tuple | None          # (mean Pose3, sigmas (6,)) of h(0)'s prior, or None
    sensor: np.ndarray           # (n,) sensor index of each bearing-range factor
    target: np.ndarray           # (n,) its target's key index: a robot pose k, or a person m
    is_pose: np.ndarray          # (n,) whether the target is a robot pose x(k) (else a person l(m))
    p_sensor: np.ndarray         # (n, 3) the measured head point, sensor frame (its direction)
    range_m: np.ndarray          # (n,) the measured range (|p| plus the ray shift)
    noise_range_m: np.ndarray    # (n,)
    noise_scale: np.ndarray      # (n,)
    robust: bool                 # whether the factors carry the robust kernel
    # what was read at ``values`` (the same whatever theta; :class:`ObservationRhs` reuses it):
    # the robot observations' :class:`Regressors` and predicted points (:func:`predicted_points`,
    # None where they were read at the measured points), the people's sightings
    # (:func:`people_sightings`), and the values, t_max, ray shift, observation keys and people
    # they were read at
    robot_regressors: Regressors | None = None
    robot_points: tuple | None = None
    people_regressors: tuple | None = None
    read_at: tuple | None = None

    def sigmas(self, recipe: GraphRecipe, unscaled: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) each factor's sigmas, as its (cached, range-rounded) GTSAM noise model has them;
        ``unscaled``: :meth:`unscaled_sigmas` when the caller has them (the same ranges)."""
        return (self.unscaled_sigmas(recipe) if unscaled is None else unscaled) * self.noise_scale[:, None]

    def unscaled_sigmas(self, recipe: GraphRecipe) -> np.ndarray:
        """(n, 3) the recipe's sigmas at each factor's rounded noise range, before its scale."""
        return observation_sigmas(recipe, _NoiseCache.keys(self.noise_range_m) * _NoiseCache.STEP_M)


@dataclass
class Regressors:
    """What the observation factors' nuisances are read against, per factor (sensor frame): the
    horizontal unit toward the sensor (the horizontal shift's and each sensor's departure's
    direction), the world's up times cos^2 of the sensor's elevation (the curvature's), the
    horizontal distance (the shift's profile against distance, pedcal.calib.headpoint) and the
    range the noise sigmas are taken at.

    The distance and the noise's range are read at the predicted point, the target's value seen
    from its sensor's (:func:`regressors`), not at the measured one: a regressor read from the
    measurement carries its noise, which the residual carries too (errors in variables: the
    corridor's line at -12.7 mm/m where its truth is 0, README), and a sigma read there weights
    down the observations its noise pushed far (a bias toward short ranges of -2 sigma dsigma/dr,
    millimetres past the reliable range where the sigma doubles). The direction and the
    curvature's cos^2 stay read at the measured point: read at the predicted (or the true) one
    they leave the line +3.8 mm/m off on the same log, a bias the measured direction's errors in
    variables offset, and lose 5 mm on a ramping head point's log (README)."""

    toward_sensor: np.ndarray    # (n, 3) horizontal unit from the point toward the sensor
    up_cos2: np.ndarray          # (n, 3) up x cos^2(the sensor's elevation)
    distance_m: np.ndarray       # (n,) horizontal distance from the sensor to the point
    noise_range_m: np.ndarray    # (n,) the range of the reported point


def measured_regressors(prob: FactorGraphProblem, use: np.ndarray) -> Regressors:
    """The robot-observation factors ``use``'s :class:`Regressors` read at their measured points
    (with the rotations they were carried with): a block's before any values predict them."""
    toward = prob.fac_toward_sensor[use]
    p = prob.fac_p_sensor[use]
    return Regressors(toward_sensor=toward, up_cos2=prob.fac_up_cos2[use], distance_m=horizontal_distance(p, toward),
                      noise_range_m=np.linalg.norm(p, axis=1))


def predicted_points(prob: FactorGraphProblem, values: gtsam.Values | None, sensor: np.ndarray,
                     target: np.ndarray, is_pose: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """The targets seen from their sensors in ``values``, R_s^T (t - t_s) (n, 3), with the sensors'
    rotations R_s (n, 3, 3), for factors from sensors ``sensor`` (indices) to targets ``target``
    (robot poses x(k) when ``is_pose``, else people l(m)); None without ``values`` or when they
    do not hold every one (a block being built, its people's initial positions made from it)."""
    if values is None or not len(sensor):
        return None
    uniq, inv = np.unique(target, return_inverse=True)
    try:
        n_sensors = len(prob.sensor_ids)
        if is_pose:
            # (the sensors and the poses read in one pass over the values)
            R_all, t_all = pose_arrays(values, np.r_[symbols("s", range(n_sensors)), symbols("x", uniq)])
            Rs, ts, t_target = R_all[:n_sensors], t_all[:n_sensors], t_all[n_sensors:]
        elif all(values.exists(L(int(m))) for m in uniq):
            Rs, ts = pose_arrays(values, symbols("s", range(n_sensors)))
            t_target = np.array([values.atPoint3(L(int(m))) for m in uniq], float).reshape(len(uniq), 3)
        else:
            return None
    except KeyError:
        return None
    R = Rs[sensor]
    return np.einsum("nji,nj->ni", R, t_target[np.asarray(inv).ravel()] - ts[sensor]), R


def regressors(prob: FactorGraphProblem, values: gtsam.Values | None, sensor: np.ndarray, target: np.ndarray,
               is_pose: bool, measured: Regressors, predicted: tuple | None = None) -> Regressors:
    """The :class:`Regressors` of factors from sensors ``sensor`` to targets ``target``:
    ``measured`` (read at the measured points) with the distance and the noise's range read at
    the predicted points (:func:`predicted_points`; the noise's range the predicted point's less
    the problem's ray shift, not a profile step's, so that the weights stay put while the
    nuisances' profile moves them), where ``values`` hold them.

    The factors' Jacobians (GTSAM's bearing-range factors, whose measurement is fixed when the
    block is built) leave out the distance's own dependence on the variables: the block is
    rebuilt at every new linearization point (each profile step, pedcal.calib.factorgraph), so
    the solution is the fixed point of sum_i J_i^T W_i r_i = 0 with J_i, W_i and the distance
    functions of the variables alone, an unbiased estimating equation (at the true values r_i is
    the noise, of mean 0, whatever the weights), as the full likelihood's is. The left-out part
    of the Jacobian is the profile's slope against distance (a few percent:
    tests/test_observation_sigmas.py measures it by finite differences), so the covariance read
    from GTSAM's Jacobians is off by as little. ``predicted``: :func:`predicted_points`' answer
    for these factors when the caller has it."""
    got = predicted if predicted is not None else predicted_points(prob, values, sensor, target, is_pose)
    if got is None:
        return measured
    p, R = got
    return Regressors(toward_sensor=measured.toward_sensor, up_cos2=measured.up_cos2,
                      distance_m=horizontal_distance(p, toward_sensor_horizontal(p, R)),
                      noise_range_m=np.maximum(np.linalg.norm(p, axis=1) - float(prob.ray_shift_m), 0.0))


def people_sightings(prob: FactorGraphProblem, values: gtsam.Values | None, t_max: float | None = None):
    """The shared people's sightings up to ``t_max`` as arrays, (sensor index (n,), the point in
    the sensor's frame (n, 3), the person's index (n,), their :class:`Regressors`, read at the
    points ``values`` predict where they hold every person, else at the measured ones), or None
    without any: what does not move with the nuisances, so that a caller evaluating the block
    at many of them (:class:`ObservationRhs`) reads it once."""
    sid_index = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    seen_i, seen_p, seen_m = [], [], []
    for m, (t, seen) in enumerate(prob.people):
        if t_max is not None and t > t_max:
            continue
        for sid, p in seen:
            seen_i.append(sid_index[sid])
            seen_p.append(p)
            seen_m.append(m)
    if not seen_p:
        return None
    seen_i, seen_p, seen_m = np.asarray(seen_i, int), np.asarray(seen_p, float), np.asarray(seen_m, int)
    R0 = np.array([prob.init_sensors[sid].rotation().matrix() for sid in prob.sensor_ids])[seen_i]
    toward = toward_sensor_horizontal(seen_p, R0)
    measured = Regressors(toward_sensor=toward, up_cos2=frames.up_by_cos2_elevation(seen_p, R0),
                          distance_m=horizontal_distance(seen_p, toward), noise_range_m=np.linalg.norm(seen_p, axis=1))
    return seen_i, seen_p, seen_m, regressors(prob, values, seen_i, seen_m, False, measured)


def _frame_correlation(noise_estimate: dict | None) -> dict | None:
    rho = (noise_estimate or {}).get("frame_correlation")
    return rho if rho and any(float(v) > 0.0 for v in rho.values()) else None


def noise_correlation_factor(noise_estimate: dict | None, gap_frames: float = 1.0) -> float:
    """How much wider each observation factor's sigmas are taken than one report's noise for a
    tracker whose noise is correlated from frame to frame (an AR(1) of coefficient rho, the
    noise estimate's ``frame_correlation``: :func:`pedcal.calib.problem.estimate_observation_noise`):
    a long run of such reports holds (1 - rho) / (1 + rho) of the information of as many
    independent ones (the AR(1)'s long-run variance is (1 + rho) / (1 - rho) times one report's),
    and the graph takes its factors as independent. The root of that factor, its mean over the
    depth's and the lateral correlation (the factor scales all three sigmas alike); for factors
    ``gap_frames`` reports apart (people's sightings, one per people_sample_s) rho^gap_frames
    in place of rho; 1 without an estimate or for white noise. The noise itself (the model
    check, AMCL's residuals) is one report's, merged as :func:`merged_variance_factor` says."""
    rho = _frame_correlation(noise_estimate)
    if rho is None:
        return 1.0
    r = [float(rho[k]) ** max(float(gap_frames), 1.0) for k in ("along", "lateral")]
    return float(np.sqrt(np.mean([ar1_long_run_factor(x) for x in r])))


def merged_variance_factor(rho: float, count) -> np.ndarray:
    """g_c: the variance of the mean of ``count`` consecutive reports of an AR(1) noise of
    coefficient ``rho`` over one report's variance / count, 1 + 2 sum_{k<c} (1 - k/c) rho^k =
    (1 + rho) / (1 - rho) - 2 rho (1 - rho^c) / (c (1 - rho)^2): 1 for one report or white noise,
    toward the long-run factor (1 + rho) / (1 - rho) for many."""
    c = np.maximum(np.asarray(count, float), 1.0)
    rho = float(rho)
    if rho <= 0.0:
        return np.ones_like(c)
    return ar1_long_run_factor(rho) - 2.0 * rho * (1.0 - rho ** c) / (c * (1.0 - rho) ** 2)


def merged_noise_factors(noise_estimate: dict | None, count) -> tuple[np.ndarray, np.ndarray]:
    """(lateral, depth) variance factors g_c (:func:`merged_variance_factor`) of factors merging
    ``count`` reports, at the noise estimate's lateral and depth correlations (ones without)."""
    rho = _frame_correlation(noise_estimate) or {"along": 0.0, "lateral": 0.0}
    return merged_variance_factor(rho["lateral"], count), merged_variance_factor(rho["along"], count)


def observation_terms(log: Log, prob: FactorGraphProblem, values: gtsam.Values | None = None, *,
                      t_max: float | None = None, insert_values: bool = False,
                      theta: dict | None = None, robust: bool = True,
                      sigma_scale: np.ndarray | None = None, predicted: bool = True,
                      robot_regressors: Regressors | None = None,
                      people_regressors: tuple | None = None) -> ObservationTerms:
    """The observation block's factors as arrays (:class:`ObservationTerms`; the arguments are
    :func:`observation_block`'s; ``robot_regressors``: the robot observations' :class:`Regressors`
    when already read at ``values``, ``people_regressors`` the people's sightings and theirs
    (:func:`people_sightings`) likewise)."""
    rec = prob.recipe
    robot_points = None
    # (terms given what was read elsewhere did not read it at the values themselves)
    read_at = ((values, t_max, float(prob.ray_shift_m), prob.fac_key_index, prob.people)
               if predicted and not insert_values and robot_regressors is None and people_regressors is None else None)
    theta = theta or {}
    rho = float(theta.get("ray_shift_m", prob.ray_shift_m))
    hs = float(theta.get("horizontal_shift_m", prob.horizontal_shift_m))
    cv = float(theta.get("curvature_m", prob.curvature_m))
    n_pose = len(_pose_times(prob, t_max))
    factor = 0           # index of the next factor (into sigma_scale)
    prior = None
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
        prior = (h_prior, sig)
    sensor, target, is_pose, p_all, r_all, noise_r, noise_count = [], [], [], [], [], [], []
    if rec.robot:
        use = np.flatnonzero(prob.fac_key_index < n_pose)
        # the distance and the noise's range at the predicted point (Regressors), the same
        # whatever theta: sigmas that moved with the shifts would reward
        # shifts that shrink them (a least-squares fit is no likelihood when its weights depend on
        # the parameters), a bias along the shifts' nearly degenerate combination
        if robot_regressors is None:
            robot_points = (predicted_points(prob, values, prob.fac_sensor_index[use], prob.fac_key_index[use], True)
                            if predicted else None)
            robot_regressors = regressors(prob, values if predicted else None, prob.fac_sensor_index[use],
                                          prob.fac_key_index[use], True, measured_regressors(prob, use),
                                          predicted=robot_points)
        reg = robot_regressors
        rows = rows_taken(use, len(prob.fac_key_index))     # (every factor: the tables as they are)
        p_obs = prob.fac_p_sensor[rows] - hs * reg.toward_sensor - cv * reg.up_cos2
        p_obs = p_obs + clock_shift_sensor(prob, theta, use)      # the sensors' own clocks (pedcal.calib.clocks)
        # shift vs distance (pedcal.calib.headpoint)
        p_obs = p_obs + head_profile_shift_sensor(prob, theta, use, reg.toward_sensor, reg.distance_m)
        sensor.append(prob.fac_sensor_index[rows])
        target.append(prob.fac_key_index[rows])
        is_pose.append(np.ones(len(use), bool))
        p_all.append(p_obs)
        r_all.append(np.linalg.norm(p_obs, axis=1) + rho)
        noise_r.append(reg.noise_range_m)
        noise_count.append(np.asarray(prob.fac_count[rows], int))
    if rec.people:
        if people_regressors is None:
            people_regressors = people_sightings(prob, values if predicted and not insert_values else None, t_max)
        seen = people_regressors
        if seen is not None:
            seen_i, seen_p, seen_m, reg = seen
            noise_range = reg.noise_range_m
            seen_p = seen_p - hs * reg.toward_sensor - cv * reg.up_cos2
            if insert_values:
                # each person's initial position: the mean of what the sensors saw, at the installed poses
                pts = np.array([prob.init_sensors[prob.sensor_ids[i]].transformFrom(p * (1.0 + rho / np.linalg.norm(p)))
                                for i, p in zip(seen_i.tolist(), seen_p, strict=True)]).reshape(-1, 3)
                uniq, inv = np.unique(seen_m, return_inverse=True)
                inv = np.asarray(inv).ravel()
                mean = np.column_stack([np.bincount(inv, pts[:, c], minlength=len(uniq))
                                        for c in range(3)]) / np.bincount(inv, minlength=len(uniq))[:, None]
                for m, point in zip(uniq.tolist(), mean, strict=True):
                    values.insert(L(m), point)
            sensor.append(np.asarray(seen_i, int))
            target.append(np.asarray(seen_m, int))
            is_pose.append(np.zeros(len(seen_m), bool))
            p_all.append(seen_p)
            r_all.append(np.linalg.norm(seen_p, axis=1) + rho)
            noise_r.append(noise_range)
            noise_count.append(np.ones(len(seen_m), int))

    def cat(parts, shape=(0,), dtype=float):
        return np.concatenate(parts) if parts else np.zeros(shape, dtype)

    count = cat(noise_count, dtype=int)
    # a filtered tracker's reports hold less than as many independent ones: each factor's sigmas
    # widened by the root of the noise's long-run variance factor (noise_correlation_factor);
    # people's sightings, one per people_sample_s, at the correlation that many reports apart
    scale = noise_correlation_factor(prob.noise_estimate) / np.sqrt(count)
    people_rows = ~cat(is_pose, dtype=bool)
    if people_rows.any() and prob.noise_estimate and prob.noise_estimate.get("frame_period_s"):
        gap = rec.people_sample_s / float(prob.noise_estimate["frame_period_s"])
        scale[people_rows] = noise_correlation_factor(prob.noise_estimate, gap) / np.sqrt(count[people_rows])
    if sigma_scale is not None:
        scale = scale * np.asarray(sigma_scale[factor:factor + len(count)], float)
    return ObservationTerms(prior=prior, sensor=cat(sensor, dtype=int), target=cat(target, dtype=int),
                            is_pose=cat(is_pose, dtype=bool), p_sensor=cat(p_all, (0, 3)), range_m=cat(r_all),
                            noise_range_m=cat(noise_r), noise_scale=scale, robust=robust and sigma_scale is None,
                            robot_regressors=robot_regressors if rec.robot else None, robot_points=robot_points,
                            people_regressors=people_regressors if rec.people else None, read_at=read_at)


def _motion_sigma_keys(sigma_turn: np.ndarray, sigma_translation: np.ndarray) -> np.ndarray:
    """(n, 2) the motion factors' (turn, translation) sigmas rounded to 0.1 % (log / 1e-3, int)."""
    return np.round(np.log(np.column_stack([sigma_turn, sigma_translation])) / 1e-3).astype(np.int64)


def _motion_sigmas(keys: np.ndarray) -> np.ndarray:
    """(n, 6) a motion factor's sigmas [roll pitch yaw x y z] from its rounded keys."""
    a, b = np.exp(np.asarray(keys, float) * 1e-3).T
    tiny = np.full(len(a), 1e-3)
    return np.column_stack([tiny, tiny, a, b, b, tiny])


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(a, axis=0, return_inverse=True)`` of a 2-D array (its distinct rows in
    lexicographic order, and each row's index among them), by one lexsort: several times faster
    than NumPy's, which sorts the rows as opaque records (a block of a few thousand factors
    asked it for its noise models once per build)."""
    a = np.asarray(a)
    if a.ndim != 2 or not len(a):
        uniq, inverse = np.unique(a, axis=0, return_inverse=True)
        return uniq, np.asarray(inverse).ravel()
    order = np.lexsort(a.T[::-1])
    sorted_rows = a[order]
    new = np.r_[True, np.any(sorted_rows[1:] != sorted_rows[:-1], axis=1)]
    inverse = np.empty(len(a), np.int64)
    inverse[order] = np.cumsum(new) - 1
    return sorted_rows[new], inverse


def _odometry_at(prob: FactorGraphProblem, times: np.ndarray) -> np.ndarray:
    """(n, 3) the odometry's pose at ``times``, interpolated once per odometry and times and kept
    on the problem: the motion block and its right-hand side ask again at every profile step,
    with only the corrections (applied after) changed."""
    hit = prob.__dict__.get("_odometry_at_cache")
    if hit is not None and hit[0] is prob.odometry and np.array_equal(hit[1], times):
        return hit[2]
    src = interpolate_pose2(prob.odometry, times)
    src.setflags(write=False)
    prob.__dict__["_odometry_at_cache"] = (prob.odometry, np.array(times, copy=True), src)
    return src


def _odometry_steps(log: Log, prob: FactorGraphProblem, times: np.ndarray, theta: dict | None):
    """The odometry's increments between consecutive poses at ``times`` (the head frame's turn and
    x, y translation) with the problem's corrections, ``theta`` overriding them by name, and
    their sigmas (turn, translation): (turn, tx, ty, sigma_turn, sigma_translation)."""
    rec = prob.recipe
    head_m = _head_m(log, rec)
    dt = np.diff(times)
    theta = theta or {}
    scale, drift_m, drift_s = (float(theta.get(k, getattr(prob, k))) for k in ODOMETRY_NUISANCES)
    src = _odometry_at(prob, times)
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
    return turn, tx, ty, sy, st


def _rot3_log(R: np.ndarray) -> np.ndarray:
    """(n, 3) SO(3) logarithm of rotation matrices (n, 3, 3) (angles below pi)."""
    angle = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    vee = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)
    small = angle < 1e-6
    f = np.where(small, 0.5 + angle ** 2 / 12.0, angle / (2.0 * np.sin(np.where(small, 1.0, angle))))
    return f[:, None] * vee


def pose3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n, 6) GTSAM's Pose3 logarithm [w, u] of poses (R (n, 3, 3), t (n, 3)): w = Log(R) and
    u = V(w)^-1 t = t - w x t / 2 + (1 - theta / (2 tan(theta / 2))) / theta^2 w x (w x t)."""
    w = _rot3_log(R)
    angle = np.linalg.norm(w, axis=1)
    wt = np.cross(w, t)
    big = angle > 1e-4
    a = np.where(big, angle, 1.0)
    c = np.where(big, (1.0 - a / (2.0 * np.tan(0.5 * a))) / a ** 2, 1.0 / 12.0 + angle ** 2 / 720.0)
    return np.column_stack([w, t - 0.5 * wt + c[:, None] * np.cross(w, wt)])


def _hat(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the skew-symmetric matrices of vectors (..., 3): hat(v) x = v x x."""
    W = np.zeros(v.shape[:-1] + (3, 3))
    W[..., 0, 1], W[..., 0, 2], W[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    W[..., 1, 0], W[..., 2, 0], W[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return W


class MotionRhs:
    """The right-hand side b of the odometry block's linearization at fixed ``values`` (b =
    -whitened error, what ``sparse_system(motion_block(..., theta=...).linearize(values))[1]``
    gives), in numpy: a BetweenFactorPose3's error Log(Z^-1 X_k^-1 X_k+1), Z the odometry's
    increment. The poses' increments are taken once, each call re-measures."""

    def __init__(self, log: Log, prob: FactorGraphProblem, values: gtsam.Values, *, t_max: float | None = None):
        self.log, self.prob = log, prob
        self.times = _pose_times(prob, t_max)
        R, t = pose_arrays(values, symbols("x", range(len(self.times))))
        # X_k^-1 X_k+1
        self.R_h = np.einsum("nji,njk->nik", R[:-1], R[1:])
        self.t_h = np.einsum("nji,nj->ni", R[:-1], t[1:] - t[:-1])

    def __call__(self, theta: dict | None) -> np.ndarray:
        if len(self.times) < 2:
            return np.zeros(0)
        err, sigmas = self._errors(theta)
        return (-err / sigmas).ravel()

    def _errors(self, theta: dict | None) -> tuple[np.ndarray, np.ndarray]:
        """(n, 6) each factor's error Log(Z^-1 X_k^-1 X_k+1) and its sigmas, at the corrections
        ``theta`` overrides."""
        turn, tx, ty, sy, st = _odometry_steps(self.log, self.prob, self.times, theta)
        c, s_ = np.cos(turn), np.sin(turn)
        Rz_inv = np.zeros((len(turn), 3, 3))             # Z^-1's rotation, Rz(-turn)
        Rz_inv[:, 0, 0] = Rz_inv[:, 1, 1] = c
        Rz_inv[:, 0, 1], Rz_inv[:, 1, 0] = s_, -s_
        Rz_inv[:, 2, 2] = 1.0
        dt = self.t_h - np.column_stack([tx, ty, np.zeros(len(tx))])
        err = pose3_log(Rz_inv @ self.R_h, np.einsum("nij,nj->ni", Rz_inv, dt))
        return err, _motion_sigmas(_motion_sigma_keys(sy, st))

    def linearized(self, cols) -> tuple:
        """(A, b) of the odometry block at the problem's corrections (``motion_block(log,
        prob)``) linearized at the values, what ``sparse_system(block.linearize(values), cols)``
        gives (``cols``: the system's :class:`pedcal.calib.profile.Columns`), to rounding, in
        numpy without the block: a BetweenFactorPose3's Jacobians are GTSAM's, J (-Ad(T^-1)) and
        J for T = X_k^-1 X_k+1, J the Pose3 Logmap's derivative at its error Log(Z^-1 T)
        (GTSAM's own, ``gtsam.Pose3.LogmapDerivative``), whitened by its sigmas; the entries GTSAM's sparse
        Jacobian leaves out (at most 1e-12) are left out."""
        n = len(self.times) - 1
        if n < 1:
            return sps.csr_matrix((0, cols.n)), np.zeros(0)
        err, sigmas = self._errors(None)
        inv_sigma = 1.0 / sigmas                           # (GTSAM whitens by 1 / sigma)
        # (GTSAM's derivative, one call per factor: its closed form, not a copy of it)
        J = np.stack([gtsam.Pose3.LogmapDerivative(e) for e in err])
        # -Ad(T^-1), T^-1 = (R^T, -R^T t): [[-R^T, 0], [-hat(-R^T t) R^T, -R^T]]
        Rt = self.R_h.transpose(0, 2, 1)
        ad = np.zeros((n, 6, 6))
        ad[:, :3, :3] = ad[:, 3:, 3:] = -Rt
        ad[:, 3:, :3] = _hat(np.einsum("nij,nj->ni", Rt, self.t_h)) @ Rt
        rows = np.concatenate([J @ ad, J], axis=2) * inv_sigma[:, :, None]          # (n, 6, 12)
        x_col = cols.index(symbols("x", range(n + 1))).reshape(n + 1, 6)
        index_dtype = np.int32 if max(72 * n, cols.n) < 2 ** 31 else np.int64
        indices = np.concatenate([np.broadcast_to(x_col[:-1, None, :], (n, 6, 6)),
                                  np.broadcast_to(x_col[1:, None, :], (n, 6, 6))], axis=2).astype(index_dtype)
        keep = np.abs(rows) > 1e-12
        indptr = np.r_[0, np.cumsum(keep.sum(axis=2).ravel())].astype(index_dtype)
        b = (-err * inv_sigma).ravel()
        return sps.csr_matrix((rows[keep], indices[keep], indptr), shape=(6 * n, cols.n)), b


def observation_block(log: Log, prob: FactorGraphProblem, values: gtsam.Values | None = None, *,
                      t_max: float | None = None, insert_values: bool = False,
                      theta: dict | None = None, robust: bool = True,
                      sigma_scale: np.ndarray | None = None, predicted: bool = True) -> gtsam.NonlinearFactorGraph:
    """The factors the head point's shifts enter: the prior of the head point's vertical offset
    (a dome's: offset = -ray shift), the robot observations carried to their pose variables
    (FactorGraphProblem.carry_observations) and the people seen by two or more sensors at once,
    in this order. ``theta`` overrides the problem's shifts by name (``ray_shift_m``,
    ``horizontal_shift_m``) without changing it; ``robust=False`` leaves the robust kernel out;
    ``sigma_scale`` (one per factor, in order) multiplies each factor's sigmas instead of a
    kernel (a robust weight w frozen: 1 / sqrt(w); models are shared between equal scales);
    ``insert_values`` puts the people's initial positions into ``values``. The nuisances'
    regressors and the noise's range are read at the points ``values`` predict (:class:`Regressors`;
    at the measured ones with ``predicted=False``: initial values, no solution yet, can predict a
    point decimetres off)."""
    return observation_block_terms(log, prob, values, t_max=t_max, insert_values=insert_values, theta=theta,
                                   robust=robust, sigma_scale=sigma_scale, predicted=predicted)[0]


def observation_block_terms(log: Log, prob: FactorGraphProblem, values: gtsam.Values | None = None, *,
                            t_max: float | None = None, insert_values: bool = False, theta: dict | None = None,
                            robust: bool = True, sigma_scale: np.ndarray | None = None,
                            predicted: bool = True) -> tuple[gtsam.NonlinearFactorGraph, ObservationTerms]:
    """:func:`observation_block` and the :class:`ObservationTerms` it was made of (what an
    :class:`ObservationRhs` at the same values and shifts reads again otherwise)."""
    terms = observation_terms(log, prob, values, t_max=t_max, insert_values=insert_values, theta=theta,
                              robust=robust, sigma_scale=sigma_scale, predicted=predicted)
    return observation_graph(prob, terms), terms


def _head_prior(terms: ObservationTerms) -> gtsam.PriorFactorPose3:
    """The head offset's prior factor the observation block leads with (``terms.prior``: its
    mean and sigmas)."""
    return gtsam.PriorFactorPose3(H(0), terms.prior[0], gtsam.noiseModel.Diagonal.Sigmas(terms.prior[1]))


def observation_graph(prob: FactorGraphProblem, terms: ObservationTerms) -> gtsam.NonlinearFactorGraph:
    """The observation block's factors made from its :class:`ObservationTerms` (what
    :func:`observation_block_terms` builds)."""
    graph = gtsam.NonlinearFactorGraph()
    if terms.prior is not None:
        graph.add(_head_prior(terms))
    n = len(terms.sensor)
    if not n:
        return graph
    cache = _NoiseCache.of(prob.recipe, robust=terms.robust)
    pairs, inverse = unique_rows(np.column_stack([cache.keys(terms.noise_range_m), terms.noise_scale]))
    models = cache.models(pairs[:, 0], pairs[:, 1])
    # (one pass over plain Python lists: a numpy scalar read per factor and field costs as much
    # as the factor)
    model_table = np.empty(len(models), object)
    model_table[:] = models
    model_of = model_table[np.asarray(inverse).ravel()].tolist()
    is_pose = terms.is_pose.tolist()
    # (the keys made in numpy: S(i), X(k) and L(m) are the symbols' bit patterns)
    s_keys = symbols("s", terms.sensor).tolist()
    t_keys = np.where(terms.is_pose, symbols("x", terms.target), symbols("l", terms.target)).tolist()
    add, unit3 = graph.add, gtsam.Unit3
    to_pose, to_point = gtsam.BearingRangeFactorPose3, gtsam.BearingRangeFactor3D
    # (each bearing made from its three coordinates as floats: the same normalization as from the
    # numpy row, without an array conversion per factor, 0.3 us of the factor's 1.7)
    x, y, z = np.asarray(terms.p_sensor, float).T.tolist()
    for s_key, t_key, px, py, pz, r, pose, model in zip(s_keys, t_keys, x, y, z, terms.range_m.tolist(), is_pose,
                                                        model_of, strict=True):
        add((to_pose if pose else to_point)(s_key, t_key, unit3(px, py, pz), r, model))
    return graph


def _unit3_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GTSAM's tangent basis (b1, b2) of the unit vectors ``n`` (rows): b1 = n x a / |n x a|, a
    the axis of n's smallest component (the first of equal ones), b2 = n x b1."""
    a = np.abs(n)
    first = np.where((a[:, 0] <= a[:, 1]) & (a[:, 0] <= a[:, 2]), 0, np.where(a[:, 1] <= a[:, 2], 1, 2))
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), first] = 1.0
    b1 = np.cross(n, axis)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    return b1, np.cross(n, b1)


class ObservationRhs:
    """The right-hand side b of the observation block's linearization at fixed ``values`` (b =
    -whitened error, each factor's sigmas scaled by ``sigma_scale``, no robust kernel: what
    ``sparse_system(observation_block(..., sigma_scale=scale).linearize(values))[1]`` gives),
    evaluated in numpy: the predictions (each target in its sensor's frame, their directions'
    tangent bases) are made once, each call re-measures. A bearing-range factor's error is
    GTSAM's: -Local_pred(u_meas) for the bearing (Unit3 local coordinates at the predicted
    direction: basis^T (theta / sin theta) (u_meas - cos theta u_pred)), predicted minus measured
    range.

    ``terms``: the block's :class:`ObservationTerms` as :func:`observation_block_terms` made them
    at these ``values`` and ``t_max`` with the problem's present ray shift (what is read at the
    values is taken from them, not read again; other terms raise ValueError; the key does not hold
    the other nuisances the head points were computed with, the horizontal shift, the profile, the
    clock offsets: the caller reads the terms after setting them, as the profile steps do). They are kept
    (``terms``) for :meth:`linearized`; those read here without them lack the robot's predicted
    points, so that :meth:`linearized` leaves such a block to GTSAM."""

    def __init__(self, log: Log, prob: FactorGraphProblem, values: gtsam.Values, *, t_max: float | None = None,
                 terms: ObservationTerms | None = None):
        self.log, self.prob, self.values, self.t_max = log, prob, values, t_max
        if terms is not None:
            at = terms.read_at
            if (at is None or at[0] is not values or at[1] != t_max or at[2] != float(prob.ray_shift_m)
                    or at[3] is not prob.fac_key_index or at[4] is not prob.people):
                raise ValueError("the observation terms were not read at these values, t_max, ray shift, "
                                 "observations and people")
            robot_points = terms.robot_points
            self.robot_regressors, self.people_regressors = terms.robot_regressors, terms.people_regressors
        else:
            use = np.flatnonzero(prob.fac_key_index < len(_pose_times(prob, t_max))) if prob.recipe.robot else None
            # the robot observations' and the people's regressors read once (they do not move with
            # theta), from the points the values predict, which the factors' errors are taken at too
            robot_points = None if use is None else predicted_points(prob, values, prob.fac_sensor_index[use],
                                                                     prob.fac_key_index[use], True)
            self.robot_regressors = None if use is None else regressors(
                prob, values, prob.fac_sensor_index[use], prob.fac_key_index[use], True,
                measured_regressors(prob, use), predicted=robot_points)
            self.people_regressors = people_sightings(prob, values, t_max) if prob.recipe.people else None
            terms = observation_terms(log, prob, values, t_max=t_max, robot_regressors=self.robot_regressors,
                                      people_regressors=self.people_regressors)
        d = np.zeros((len(terms.sensor), 3))
        robot = np.flatnonzero(terms.is_pose)
        people = np.flatnonzero(~terms.is_pose)
        people_points = (predicted_points(prob, values, terms.sensor[people], terms.target[people], False)
                         if len(people) else None)
        if (len(robot) and robot_points is None) or (len(people) and people_points is None):
            raise KeyError("the values do not hold every variable the observation block observes")
        if len(robot):
            d[robot] = robot_points[0]      # (the robot's factors lead, in the order of ``use``)
        if len(people):
            d[people] = people_points[0]
        self.range_pred = np.linalg.norm(d, axis=1)
        self.u_pred = d / np.maximum(self.range_pred, 1e-300)[:, None]
        self.basis = _unit3_basis(self.u_pred)
        self.sensor, self.is_pose = terms.sensor, terms.is_pose
        self.terms = terms            # (read at these values: what :meth:`linearized` is made of)
        # (the noise's ranges do not move with theta: the sigmas before their scales taken once)
        self._unscaled_sigmas = terms.unscaled_sigmas(prob.recipe)
        self.first = int(terms.prior is not None)        # the prior leads the block
        # the robot observations grouped by sensor once (each per-sensor nuisance asks for its own)
        robot = np.flatnonzero(self.is_pose)
        by_sensor = robot[np.argsort(self.sensor[robot], kind="stable")]
        self._robot_by_sensor = by_sensor
        self._robot_cuts = np.searchsorted(self.sensor[by_sensor], np.arange(int(self.sensor.max(initial=-1)) + 2))

    def linearized(self, cols) -> tuple | None:
        """(A, b) of the block :func:`observation_block_terms` builds from :attr:`terms` (the
        block's ObservationTerms, read at these values) linearized at the values, what
        ``sparse_system(block.linearize(values), cols)`` gives (``cols``: the system's
        :class:`pedcal.calib.profile.Columns`), to rounding, in numpy without the block: a
        bearing-range factor's Jacobians are GTSAM's (Pose3::bearing and range to a pose's
        translation, in the predicted direction's Unit3 basis), whitened by its sigmas and, with
        the robust kernel, reweighted by the square root of its weight at the whitened error's
        norm (GTSAM's Robust::WhitenSystem). The head offset's prior, one factor, is GTSAM's. A's
        pattern is GTSAM's sparse Jacobian's: the entries it leaves out (at most 1e-12 in size,
        zeros and near-zeros at these values) are left out too. None where the block
        holds people's sightings or a kernel other than Huber's, Cauchy's or none: the caller
        linearizes the block."""
        from pedcal.calib.profile import sparse_system

        rec, terms = self.prob.recipe, self.terms
        n = len(terms.sensor)
        kernel = rec.robust_kernel.lower() if terms.robust else "none"
        if terms.robot_points is None or not terms.is_pose.all() or kernel not in ("none", "huber", "cauchy"):
            return None
        blocks = []
        if terms.prior is not None:
            prior = gtsam.NonlinearFactorGraph()
            prior.add(_head_prior(terms))
            blocks.append(sparse_system(prior.linearize(self.values), cols))
        if n:
            R_s = terms.robot_points[1]                          # each factor's sensor rotation
            R_x = pose_arrays(self.values, symbols("x", terms.target))[0]
            b1, b2, u = self.basis[0], self.basis[1], self.u_pred
            inv_range = (1.0 / self.range_pred)[:, None]
            # the bearing's rows b_r^T / |q| and the range's u^T times d q: d q / d(sensor tangent
            # [w, v]) = [skew(q), -I] (b_r^T skew(q) / |q| = (b_r x u)^T: -b2, b1), d q / d(the
            # target's tangent v) = R_s^T R_x, nothing for its rotation
            rows_q = np.stack([b1 * inv_range, b2 * inv_range, u], axis=1)
            target = np.matmul(np.matmul(rows_q, R_s.transpose(0, 2, 1)), R_x)
            inv_sigma = 1.0 / terms.sigmas(rec, self._unscaled_sigmas)
            b = -self._errors(terms) * inv_sigma
            # GTSAM's robust weight at the whitened error's norm e (Huber: k / e beyond k; Cauchy:
            # k^2 / (k^2 + e^2)), its root scaling the factor's rows
            e, k = np.linalg.norm(b, axis=1), float(rec.robust_k)
            if kernel == "none":
                w = np.ones(n)
            elif kernel == "huber":
                w = np.where(e <= k, 1.0, k / np.maximum(e, 1e-300))
            else:
                w = k * k / (k * k + e * e)
            w = np.sqrt(w)[:, None]
            b *= w
            scale = inv_sigma * w                               # (n, 3) each row's whitening and weight
            data = np.concatenate([-b2, -rows_q[:, 0], target[:, 0], b1, -rows_q[:, 1], target[:, 1],
                                   -u, target[:, 2]], axis=1)
            data *= np.repeat(scale, [9, 9, 6], axis=1)
            s_col = cols.index(symbols("s", terms.sensor)).reshape(n, 6)
            x_col = cols.index(symbols("x", terms.target)).reshape(n, 6)[:, 3:]
            index_dtype = np.int32 if max(24 * n, cols.n) < 2 ** 31 else np.int64
            indices = np.concatenate([s_col, x_col, s_col, x_col, s_col[:, 3:], x_col], axis=1).astype(index_dtype)
            # (the entries GTSAM's sparse Jacobian leaves out, at most 1e-12: the same pattern)
            keep = np.abs(data) > 1e-12
            counts = np.column_stack([keep[:, :9].sum(axis=1), keep[:, 9:18].sum(axis=1), keep[:, 18:].sum(axis=1)])
            indptr = np.r_[0, np.cumsum(counts.ravel())].astype(index_dtype)
            blocks.append((sps.csr_matrix((data[keep], indices[keep], indptr), shape=(3 * n, cols.n)), b.ravel()))
        if not blocks:
            return sps.csr_matrix((0, cols.n)), np.zeros(0)
        if len(blocks) == 1:
            return blocks[0]
        (A0, b0), (A1, b1_) = blocks            # (the prior's rows first)
        return sps.vstack([A0, A1], format="csr"), np.r_[b0, b1_]

    def factor_rows(self) -> np.ndarray:
        """The start row of every factor of the block in its linearization, and the end: the
        head offset's prior (a Pose3's 6 rows) first when there is one, then 3 rows per
        observation (its bearing's 2 and its range's), as the right-hand side's rows."""
        dims = np.r_[np.full(self.first, 6), np.full(len(self.sensor), 3)]
        return np.r_[0, np.cumsum(dims)].astype(np.int64)

    def robot_factors(self, sensor_index: int) -> np.ndarray:
        """Indices in the block of the robot observations of sensor ``sensor_index`` (in order)."""
        if not 0 <= sensor_index < len(self._robot_cuts) - 1:
            return np.zeros(0, np.int64)
        lo, hi = self._robot_cuts[sensor_index], self._robot_cuts[sensor_index + 1]
        return self.first + self._robot_by_sensor[lo:hi]

    def __call__(self, theta: dict | None, sigma_scale: np.ndarray | None = None) -> np.ndarray:
        terms = observation_terms(self.log, self.prob, self.values, t_max=self.t_max, theta=theta,
                                  sigma_scale=sigma_scale, robot_regressors=self.robot_regressors,
                                  people_regressors=self.people_regressors)
        rows = []
        if terms.prior is not None:
            prior = _head_prior(terms)
            rows.append(-prior.whitenedError(self.values))
        if len(terms.sensor):
            rows.append((-self._errors(terms) / terms.sigmas(self.prob.recipe, self._unscaled_sigmas)).ravel())
        return np.concatenate(rows) if rows else np.zeros(0)

    def _errors(self, terms: ObservationTerms) -> np.ndarray:
        """(n, 3) each factor's unwhitened error for the measurements of ``terms``."""
        u_meas = terms.p_sensor / np.linalg.norm(terms.p_sensor, axis=1, keepdims=True)
        x = np.sum(self.u_pred * u_meas, axis=1)
        # theta / sin(theta) (1 where the directions agree, as GTSAM takes it)
        y = np.where(x > 1.0 - 1e-9, 1.0,
                     np.arccos(np.clip(x, -1.0, 1.0)) / np.sqrt(np.maximum(1.0 - x * x, 1e-300)))
        v = y[:, None] * (u_meas - x[:, None] * self.u_pred)
        return np.column_stack([-np.sum(self.basis[0] * v, axis=1), -np.sum(self.basis[1] * v, axis=1),
                                self.range_pred - terms.range_m])


def optimize_graph(fg, values, recipe: GraphRecipe, max_iterations: int | None = None,
                   gauss_newton_step: bool = True, relative_error_tol: float | None = None,
                   ordering: gtsam.Ordering | None = None, predicted_stop: bool = False):
    """Levenberg-Marquardt from ``values``, then, with the head model's vertical offset free, one
    Gauss-Newton step (unless ``gauss_newton_step`` is False: the caller's next step is one, as
    every profile step of the nuisances is); (result, iterations). A common vertical shift of all variables changes no
    measurement factor then, only the priors (the offset's, the sensors' installed heights, a
    height reference): a flat direction LM barely moves along before its relative-error test
    stops it, so the solution would sit wherever the initial values put it. The error is quadratic
    along it, and a Gauss-Newton step goes to its optimum.

    Levenberg-Marquardt's steps are Gauss-Newton's as long as each one lowers the error (its
    damping starts at 1e-5 and shrinks tenfold on every accepted step: a step within 1e-7 mm of
    the undamped one on these graphs, whose information is at least a weak prior's): so the
    iterations are Gauss-Newton's, without the damped system LM forms (~15 % of an iteration),
    with LM's stopping rule, and the first step that would raise the error is not taken: LM
    goes on from the last point for the iterations left (and from an undamped system GTSAM cannot
    solve: a direction nothing holds, which LM's damping does). ``ordering``: ``fg``'s COLAMD
    ordering when already computed (:meth:`GraphParts.colamd`). ``predicted_stop``: the
    iterations also stop when the decreases still to come are predicted below the tolerance,
    theta / (1 - theta) of this iteration's decrease, theta its ratio to the last one's (a
    linear contraction's geometric series, an upper estimate of Gauss-Newton's quadratic one,
    :func:`pedcal.calib.profile.steps_to_come_below`):
    for a caller whose next step is a Gauss-Newton step of its own, which takes that remainder."""
    max_iterations = recipe.max_iterations if max_iterations is None else max_iterations
    relative_error_tol = recipe.relative_error_tol if relative_error_tol is None else relative_error_tol
    # one COLAMD ordering computed once (the graph's structure does not change between
    # iterations), eliminated sequentially up to SEQUENTIAL_MAX_VARIABLES variables and
    # multifrontally above (pedcal.calib.profile.linear_solver)
    if ordering is None:
        ordering = fg.orderingCOLAMD()      # symbolic: the same order as of its linearization
    solver = linear_solver(values.size())
    gn_params = gtsam.GaussNewtonParams()
    gn_params.setLinearSolverType(solver)
    gn_params.setOrdering(ordering)
    gn = gtsam.GaussNewtonOptimizer(fg, values, gn_params)
    result, error, iterations = values, gn.error(), 0      # (the optimizer's own error at values: not again)
    absolute_tol = gn_params.getAbsoluteErrorTol()
    last_decrease = None
    while iterations < max_iterations:
        try:
            gn.iterate()
            new_error = gn.error()
        except RuntimeError:                  # an indeterminate system (a free direction): LM's damping holds it
            new_error = np.inf
        if not new_error <= error:
            break                             # (a rise, or not a number: LM takes over below)
        # (a copy: the optimizer's values are replaced, not kept, by its next iteration)
        result, iterations = gtsam.Values(gn.values()), iterations + 1
        decrease, error = error - new_error, new_error
        if decrease <= relative_error_tol * (error + decrease) or decrease <= absolute_tol:
            break                             # (LM's convergence test, gtsam.checkConvergence)
        if predicted_stop and last_decrease is not None and steps_to_come_below(
                decrease, decrease / last_decrease, relative_error_tol * error) is True:
            break
        last_decrease = decrease
    else:
        new_error = error
    if new_error > error or not np.isfinite(new_error):
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations - iterations)
        params.setRelativeErrorTol(relative_error_tol)
        params.setLinearSolverType(solver)
        params.setOrdering(ordering)
        opt = gtsam.LevenbergMarquardtOptimizer(fg, result, params)
        result = opt.optimize()
        iterations += opt.iterations()
    if gauss_newton_step and result.exists(H(0)):
        result = result.retract(fg.linearize(result).optimize())
    return result, iterations


# Above this many sensors the joint position covariance (3n x 3n) is not computed (each sensor's

