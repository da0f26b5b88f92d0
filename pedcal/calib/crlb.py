"""Cramér-Rao lower bound of the sensor positions on simulated data.

For Gaussian measurement models the Fisher information of the factor graph is its Gauss-Newton
information matrix J^T Sigma^-1 J, with J the Jacobian of every factor's measurement function
evaluated at the TRUE values of all variables (the measured values do not enter it). Inverting it
and keeping a sensor's block gives the bound on the covariance of any unbiased estimate of that
sensor's pose: its world-axes position block is what :func:`sensor_position_crlb` returns.

Assumptions (state them with any figure):
- the graph recipe's noise models are the true ones (the default recipe's are close to the
  simulator's: depth k r^2, lateral ~1 cm, AMCL an OU process of the reported std and the
  recipe's correlation time, odometry white per sqrt(s) after its systematic errors are removed);
  pass a recipe to state others;
- odometry's systematic errors (scale, heading drift) are known: the bound is for the
  calibrated odometry, so it is slightly optimistic;
- the robot's observations are the true ones (truth_observations.csv), the robust kernel is off
  (no outliers), and people's shared observations are left out: the bound is the robot's.
- The world-axes position block comes from GTSAM's body-frame Pose3 marginal, rotated by the
  true orientation (:func:`pedcal.calib.graph.sensor_sigma_world`).

The figure of merit reported with an estimate is RMS / sqrt(mean trace): an efficient estimator
scores about 1 (its 3-D position error has mean square trace(CRLB) per sensor).

Under the simulator's own noise (:func:`simulator_noise`, ``amcl_model`` and ``amcl_sigma_yaw_rad``
of :func:`sensor_position_crlb`) the bound is taken under the model a simulated log was truly
generated with, as far as the graph can hold it, every departure but two on the side that lowers
the bound: AMCL's position error the simulator's Ornstein-Uhlenbeck process (its std and
correlation time; a node of the process at every estimate, the AR(1)'s exact precision at the
run's two ends too) or its white error; its jumps known (the estimates carry the OU error alone:
a genie's knowledge); depth noise k r^2 (a linear model's under a chord of it), lateral noise
without the latency jitter, odometry's white noise with its systematic errors known; the
latency, clock offsets and head point known (knowing a nuisance can only lower the bound; the
head point a point, without the recipe's dome). The departures upward:

- people are left out (``people=True`` adds the shared sightings the estimator's graph matches:
  5 on the zoo's paper seed 2, none on cross seed 2, changing the bound by under 0.01 mm; an
  ideal estimator could also use a walker's track across the gaps between views): they carry
  information on the sensors' relative positions (the rest beside the common shift), none on the
  network's common shift (people carry nothing of the map);
- AMCL's heading error (an OU process too) the graph can only hold as white noise inflated to the
  information an OU holds about its mean (2 tau / dt times its variance): that matches the OU's
  spectrum at frequency 0 and lies above it elsewhere, so it raises the bound; with the heading
  error known instead (``amcl_sigma_yaw_rad=KNOWN_HEADING_SIGMA_RAD``) the bound is a lower one
  again, and the truth's lies between the two (they differ in the rest: 7.1 against 3.8 mm on the
  zoo's paper seed 0, 24.6 against 18.7 on lhall seed 4; in the common shift by under 2 %).

- two of the graph's own constants (pedcal.calib.graph): the robot's roll and pitch tied to 0 at
  0.05 deg where the simulated robot is exactly planar (at 0.0005 deg the rest part fell 8 % on
  the zoo's paper seed 0, 2 % on lhall seed 4), and 0.1 mm added to the odometry's translation
  sigma (about 5 % of the simulated 2 mm a step; the rest part ~2 % high). The common shift moves
  by under 0.2 %; the rest part's bound is high by about these shares, so the graph's rest over
  the bound understates the gap as much.

It bounds unbiased estimators: a biased one (a prior pulling toward the installed poses, say) can
do better on some logs and worse on others. The graph's installed-pose prior (sensor_prior_sigma_m)
is in the information, as a Bayesian bound would have it; at the simulator's 0.24 m per sensor
instead of the recipe's 0.5 m the common shift's bound drops by 1.7-3 % (the zoo's paper seed 0,
corridor 2, cross 3).

:func:`common_shift_variance_m2` is the bound on the sensors' mean horizontal position (the
network's common shift) with everything else known: AMCL's run-mean error is the only link of the
rigid sensors + trajectory structure to the map, so that mean is known no better than a constant
under AMCL's error process, whose best linear unbiased estimate has variance 1 / (1^T Sigma^-1 1).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import gtsam
import numpy as np

from pedcal.calib.amcl_model import AmclErrorModel, amcl_period_s
from pedcal.calib.common import interpolate_pose2
from pedcal.calib.graph import (
    A,
    GraphRecipe,
    S,
    X,
    build_graph,
    head_frame,
    prepare,
    sensor_sigma_world,
    set_amcl_model,
)
from pedcal.deprecation import renamed_fields
from pedcal.errors import PedcalInputError
from pedcal.model import Log


@renamed_fields(position_cov_world_m2="position_covariance_m2")
@dataclass
class CRLBResult:
    """Per sensor the bound on the world-axes position covariance (m^2)."""

    position_covariance_m2: dict[str, np.ndarray]
    recipe: str
    # with joint=True: the joint world-axes position covariance of every sensor (3 n x 3 n, x y z
    # per sensor in the order of ``position_covariance_m2``)
    joint_position_covariance_m2: np.ndarray | None = None

    @property
    def rms_bound_mm(self) -> float:
        """sqrt of the mean over sensors of trace(CRLB): the bound on the RMS 3-D position error."""
        return float(1000.0 * np.sqrt(np.mean([np.trace(c) for c in self.position_covariance_m2.values()])))

    def sigma_mm(self, sensor_id: str) -> np.ndarray:
        return 1000.0 * np.sqrt(np.diag(self.position_covariance_m2[sensor_id]))

    def efficiency_ratio(self, position_rms_mm: float) -> float:
        """An estimate's RMS sensor position error over the bound (1 = efficient)."""
        return float(position_rms_mm / self.rms_bound_mm)

    @property
    def horizontal_rms_bound_mm(self) -> float:
        """sqrt of the mean over sensors of var_x + var_y: the bound on the RMS over sensors of
        the horizontal position error (its root mean square over logs)."""
        return float(1000.0 * np.sqrt(np.mean([c[0, 0] + c[1, 1] for c in self.position_covariance_m2.values()])))

    def horizontal_split_mm(self) -> tuple[float, float]:
        """(common, rest) of the horizontal bound (needs ``joint``): the bound on the norm of the
        sensors' mean horizontal error (the network's common shift), sqrt(trace) of its 2 x 2
        covariance, and on the RMS of each sensor's departure from that mean. Their squares add
        up to :attr:`horizontal_rms_bound_mm` squared (the mean over sensors of |e_i|^2 is
        |mean e|^2 plus the mean of |e_i - mean e|^2)."""
        C = self.horizontal_joint_m2()
        n = len(C) // 2
        mean_op = np.kron(np.ones((1, n)) / n, np.eye(2))
        common = float(np.trace(mean_op @ C @ mean_op.T))
        rest = float(np.trace(C) / n) - common
        return 1000.0 * np.sqrt(common), 1000.0 * np.sqrt(max(rest, 0.0))

    def horizontal_joint_m2(self) -> np.ndarray:
        """The joint covariance of every sensor's horizontal position (2 n x 2 n, x y per sensor)."""
        if self.joint_position_covariance_m2 is None:
            raise ValueError("the joint covariance was not computed (sensor_position_crlb(..., joint=True))")
        n = len(self.position_covariance_m2)
        idx = np.array([3 * i + a for i in range(n) for a in (0, 1)])
        return self.joint_position_covariance_m2[np.ix_(idx, idx)]

    def share_within_mm(self, limit_mm: float, draws: int = 4000, seed: int = 0) -> float:
        """The probability that an efficient estimator (Gaussian errors of exactly this joint
        covariance) has a horizontal RMS over sensors of at most ``limit_mm`` on a log like this
        one (:func:`share_rms_within_mm` of :meth:`horizontal_joint_m2`)."""
        return share_rms_within_mm(self.horizontal_joint_m2(), limit_mm, draws=draws, seed=seed)


def share_rms_within_mm(C_m2: np.ndarray, limit_mm: float, draws: int = 4000, seed: int = 0) -> float:
    """The share of ``draws`` seeded Gaussian draws of horizontal errors with the (2 n x 2 n, x y
    per sensor) covariance ``C_m2`` whose RMS over the n sensors is at most ``limit_mm`` (n = 1:
    the probability that a 2-D error of covariance C lies within the limit)."""
    C_m2 = np.asarray(C_m2, float)
    if C_m2.ndim != 2 or C_m2.shape[0] != C_m2.shape[1] or C_m2.shape[0] % 2:
        raise ValueError(f"a horizontal covariance is 2 n x 2 n, got {C_m2.shape}")
    rng = np.random.default_rng(seed)
    # the RMS over sensors is the error vector's norm, which C's eigenvectors (orthonormal)
    # leave as it is: a draw's squared norm is sum_i w_i z_i^2
    w = np.maximum(np.linalg.eigvalsh(C_m2), 0.0)
    z = rng.standard_normal((draws, len(w)))
    rms_mm = 1000.0 * np.sqrt((z ** 2 @ w) / (len(w) // 2))
    return float(np.mean(rms_mm <= limit_mm))


def true_values(log: Log, prob, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
    """``values`` with every sensor, robot pose and AMCL error set to the truth of ``log``."""
    rec = prob.recipe
    out = gtsam.Values(values)
    head_m = np.asarray(log.meta.head_offset_m, float) - np.array([0.0, 0.0, rec.head_radius_m])
    for i, sid in enumerate(prob.sensor_ids):
        out.update(S(i), log.truth[sid].T_world_sensor)
    true_pose = interpolate_pose2(log.truth_robot, prob.pose_times)
    X_true = [head_frame(*true_pose[k], head_m) for k in range(len(prob.pose_times))]
    for k, P in enumerate(X_true):
        if out.exists(X(k)):
            out.update(X(k), P)
    # AMCL error variables: BetweenFactorPose3(a(j), x(k), Z_j) predicts Z = F^-1 X with F a pure
    # world translation, so at the truth F = X_true.t - Z.t
    for n in range(graph.size()):
        f = graph.at(n)
        keys = f.keys()
        if len(keys) == 2 and chr(gtsam.Symbol(keys[0]).chr()) == "a" and chr(gtsam.Symbol(keys[1]).chr()) == "x":
            Z = f.measured()
            d = X_true[gtsam.Symbol(keys[1]).index()].translation() - Z.translation()
            out.update(keys[0], gtsam.Pose3(gtsam.Rot3(), np.array([d[0], d[1], 0.0])))
    return out


def sensor_position_crlb(log: Log, recipe: str | GraphRecipe | None = None, *,
                         is_robot: np.ndarray | None = None, amcl_model: AmclErrorModel | None = None,
                         amcl_sigma_yaw_rad: float | None = None, joint: bool = False,
                         people: bool = False) -> CRLBResult:
    """The Cramér-Rao bound of every sensor's position (module docstring) for a simulated log
    (it needs truth.yaml, truth_robot.csv and, unless ``is_robot`` is given,
    truth_observations.csv).

    ``amcl_model``: AMCL's true error model (white std, OU std and correlation time; a white
    error: correlated 0), in place of the one the recipe assumes from AMCL's reported covariance,
    with ``amcl_sigma_yaw_rad`` its heading error's std (white, inflated to an OU mean's
    information over ``amcl_model.correlation_s``, as the graph holds it); the process then gets
    a node at every AMCL estimate and its exact ends (module docstring). ``joint``: keep the
    joint covariance of every sensor's position too (:meth:`CRLBResult.horizontal_split_mm`).
    ``people``: with the people's shared sightings the graph matches (at their initial points)."""
    if log.truth is None or log.truth_robot is None:
        raise PedcalInputError("the Cramér-Rao bound needs the truth (truth.yaml and truth_robot.csv), "
                               "which the log lacks", path=log.path)
    rec = recipe if isinstance(recipe, GraphRecipe) else GraphRecipe.load(recipe or "default")
    rec = copy.copy(rec)
    rec.people, rec.robust_kernel = people, "none"
    rec.estimate_head_model = False     # the bound for a known head point
    rec.estimate_observation_noise = False   # ... and the recipe's noise model
    if amcl_model is not None:
        log = _with_true_amcl_covariance(log, amcl_sigma_yaw_rad)
        # a node of the error process at every estimate: the process held exactly, not through
        # each estimate's change since its node
        t_a = np.unique(log.robot["t"].to_numpy(float))
        rec.amcl_node_spacing_s = amcl_period_s(t_a, rec.amcl_node_spacing_s)
        rec.amcl_change_per_span = False
    if is_robot is None:
        if log.truth_observations is None:
            raise PedcalInputError("the Cramér-Rao bound needs truth_observations.csv (which rows are the "
                                   "robot) or an is_robot mask", path=log.path)
        is_robot = np.zeros(len(log.observations), bool)
        to = log.truth_observations
        is_robot[to["row"].to_numpy(int)[to["who"].astype(str).to_numpy() == "robot"]] = True
    prob = prepare(log, rec, is_robot=is_robot, init_network=log.truth)
    if amcl_model is not None:
        set_amcl_model(log, prob, amcl_model, carry=False)
    graph, values = build_graph(log, prob)
    if amcl_model is not None:
        _exact_ou_ends(graph, values, amcl_model, prob)
    truth = true_values(log, prob, graph, values)
    marginals = gtsam.Marginals(graph, truth)
    cov = {}
    for i, sid in enumerate(prob.sensor_ids):
        cov[sid], _, _ = sensor_sigma_world(truth.atPose3(S(i)), marginals.marginalCovariance(S(i)))
    joint_cov = None
    if joint:
        keys = gtsam.KeyVector([S(i) for i in range(len(prob.sensor_ids))])
        J = marginals.jointMarginalCovariance(keys)
        n = len(prob.sensor_ids)
        joint_cov = np.zeros((3 * n, 3 * n))
        R = [truth.atPose3(S(i)).rotation().matrix() for i in range(n)]
        for i in range(n):
            for j in range(n):
                # the Pose3 tangent's translation is in the body frame: world = R_i t_i
                joint_cov[3 * i:3 * i + 3, 3 * j:3 * j + 3] = R[i] @ J.at(S(i), S(j))[3:, 3:] @ R[j].T
    return CRLBResult(position_covariance_m2=cov, recipe=rec.name, joint_position_covariance_m2=joint_cov)


def _with_true_amcl_covariance(log: Log, sigma_yaw_rad: float | None) -> Log:
    """``log`` with AMCL's covariance columns set to what the truth holds: no position part (the
    graph takes AMCL's position error from the error model, none of it from the reported
    covariance) and the heading error's true variance (unchanged when None)."""
    out = copy.copy(log)
    out.robot = log.robot.copy()
    for c in ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw"):
        out.robot[c] = 0.0
    if sigma_yaw_rad is not None:
        out.robot["cov_yawyaw"] = float(sigma_yaw_rad) ** 2
    return out


def _exact_ou_ends(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, model: AmclErrorModel,
                   prob) -> None:
    """Add to the AMCL error process's first and last node the precision the graph leaves out
    there (pedcal.calib.amcl_model.ar1_factor_sigmas: a / (sigma^2 (1 + a))), so that the nodes
    hold the stationary AR(1)'s exact precision."""
    nodes = [k for k in values.keys() if chr(gtsam.Symbol(k).chr()) == "a"]
    if len(nodes) < 2 or model.correlated_sigma_m <= 0.0:
        return
    dn = float(prob.amcl_node_times[1] - prob.amcl_node_times[0])
    a = float(np.exp(-dn / max(model.correlation_s, 1e-3)))
    if a <= 1e-9:
        return
    s_end = model.correlated_sigma_m * np.sqrt((1.0 + a) / a)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e3, 1e3, 1e3, s_end, s_end, 1e3]))
    idx = sorted(gtsam.Symbol(k).index() for k in nodes)
    for m in (idx[0], idx[-1]):
        graph.add(gtsam.PriorFactorPose3(A(m), gtsam.Pose3(), noise))


# AMCL's heading std (rad) that makes its heading error as good as known (the bound changes by
# under 0.01 % between 1e-5 and 1e-7)
KNOWN_HEADING_SIGMA_RAD = 1e-6

# AMCL's white std the bound gives an error process without one (m): the process with a node at
# every estimate would otherwise tie each pose to its node exactly (a singular noise model); a
# millimetre beside the simulator's 5 cm process raises the bound by 0.001 % (against 0.1 mm, on
# the zoo's paper seed 0)
MIN_WHITE_M = 1e-3


def simulator_noise(sc) -> tuple[GraphRecipe, AmclErrorModel, float]:
    """The noise a log of the simulator's scenario ``sc`` (a :class:`pedcal.sim.scenario.Scenario`,
    its nuisances drawn) was generated with, as the bound's (recipe, AMCL error model, AMCL
    heading std in rad), for :func:`sensor_position_crlb`. Where the graph cannot hold the truth
    the model is the less noisy side of it, so the bound stays a lower one:

    - depth: ``quadratic`` k r^2 exactly (no floor); ``linear`` 2.5 k r under the chord of it
      through the shortest and the longest range (floor + k' r^2 <= 2.5 k r between them); the far
      factor beyond the reliable range as simulated;
    - lateral: the simulator's std across the ray, without the latency jitter's share;
    - odometry: its white noise per step as a random walk per sqrt(s), its systematic errors known
      (no residual scale or drift); a log without odometry keeps the graph's smoothness factor
      from AMCL's increments, a prior on the path that uses AMCL a second time (more information
      than the log holds: lower);
    - AMCL: ``white`` a white error of amcl_sigma_m; ``correlated`` and ``jumps`` the OU process of
      amcl_sigma_m and amcl_tau_s (the jumps known), with MIN_WHITE_M of white error; the heading
      error's std amcl_sigma_yaw_deg, which the graph holds as white noise, inflated for an OU
      (module docstring: that raises the bound; pass KNOWN_HEADING_SIGMA_RAD instead for a
      lower one)."""
    rec = GraphRecipe(name="simulator truth")
    # the head point a point, not the recipe's dome (whose ray shift raised the rest part ~1 %)
    rec.head_radius_m = 0.0
    k = sc.depth_noise_k_per_m
    if sc.depth_noise_model == "linear":
        c, r1, r2 = 2.5 * k, sc.min_range_m, sc.max_range_m
        rec.range_sigma_k_per_m, rec.range_sigma_floor_m = c / (r1 + r2), c * r1 * r2 / (r1 + r2)
    else:
        rec.range_sigma_k_per_m, rec.range_sigma_floor_m = k, 0.0
    rec.far_factor, rec.reliable_range_m = sc.far_noise_factor, sc.reliable_range_m
    rec.lateral_sigma_m = sc.lateral_noise_m
    rate = sc.truth_rate_hz
    rec.odometry_white_sigma_m = sc.odom_noise_m * np.sqrt(rate)
    rec.odometry_white_yaw_sigma_deg = sc.odom_noise_yaw_deg * np.sqrt(rate)
    rec.odometry_sigma_per_m = rec.odometry_yaw_sigma_deg_per_m = 0.0
    if sc.amcl_error == "white":
        model = AmclErrorModel(white_sigma_m=sc.amcl_sigma_m, correlated_sigma_m=0.0, correlation_s=1e-3)
    else:
        model = AmclErrorModel(white_sigma_m=MIN_WHITE_M, correlated_sigma_m=sc.amcl_sigma_m,
                               correlation_s=sc.amcl_tau_s)
    model.source = "simulator truth"
    return rec, model, float(np.radians(sc.amcl_sigma_yaw_deg))


def common_shift_variance_m2(t_s: np.ndarray, model: AmclErrorModel) -> float:
    """Per axis, the variance (m^2) of the best linear unbiased estimate of a constant seen
    through AMCL's error at the times ``t_s``: 1 / (1^T Sigma^-1 1), Sigma the error's
    covariance, sigma_c^2 exp(-|t_i - t_j| / tau) + sigma_w^2 on the diagonal (module docstring).
    The bound on the network's common shift along one axis when everything else is known."""
    t = np.unique(np.asarray(t_s, float))    # (one look per time: a repeated stamp is no new draw)
    n = len(t)
    if n == 0:
        return float("inf")
    Sigma = np.eye(n) * model.white_sigma_m ** 2
    if model.correlated_sigma_m > 0.0:
        Sigma += model.correlated_sigma_m ** 2 * np.exp(-np.abs(t[:, None] - t[None, :])
                                                        / max(model.correlation_s, 1e-9))
    x = np.linalg.solve(Sigma, np.ones(n))
    return float(1.0 / np.sum(x))


__all__ = ["sensor_position_crlb", "CRLBResult", "true_values", "common_shift_variance_m2",
           "simulator_noise", "MIN_WHITE_M", "KNOWN_HEADING_SIGMA_RAD"]
