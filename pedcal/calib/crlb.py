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
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import gtsam
import numpy as np

from pedcal.calib.common import interpolate_pose2
from pedcal.calib.graph import GraphRecipe, S, X, build_graph, head_frame, prepare, sensor_sigma_world
from pedcal.deprecation import renamed_fields
from pedcal.errors import PedcalInputError
from pedcal.model import Log


@renamed_fields(position_cov_world_m2="position_covariance_m2")
@dataclass
class CRLBResult:
    """Per sensor the bound on the world-axes position covariance (m^2)."""

    position_covariance_m2: dict[str, np.ndarray]
    recipe: str

    @property
    def rms_bound_mm(self) -> float:
        """sqrt of the mean over sensors of trace(CRLB): the bound on the RMS 3-D position error."""
        return float(1000.0 * np.sqrt(np.mean([np.trace(c) for c in self.position_covariance_m2.values()])))

    def sigma_mm(self, sensor_id: str) -> np.ndarray:
        return 1000.0 * np.sqrt(np.diag(self.position_covariance_m2[sensor_id]))

    def efficiency_ratio(self, position_rms_mm: float) -> float:
        """An estimate's RMS sensor position error over the bound (1 = efficient)."""
        return float(position_rms_mm / self.rms_bound_mm)


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
                         is_robot: np.ndarray | None = None) -> CRLBResult:
    """The Cramér-Rao bound of every sensor's position (module docstring) for a simulated log
    (it needs truth.yaml, truth_robot.csv and, unless ``is_robot`` is given,
    truth_observations.csv)."""
    if log.truth is None or log.truth_robot is None:
        raise PedcalInputError("the Cramér-Rao bound needs the truth (truth.yaml and truth_robot.csv), "
                               "which the log lacks", path=log.path)
    rec = recipe if isinstance(recipe, GraphRecipe) else GraphRecipe.load(recipe or "default")
    rec = copy.copy(rec)
    rec.people, rec.robust_kernel = False, "none"
    rec.estimate_head_model = False     # the bound for a known head point
    rec.estimate_observation_noise = False   # ... and the recipe's noise model
    if is_robot is None:
        if log.truth_observations is None:
            raise PedcalInputError("the Cramér-Rao bound needs truth_observations.csv (which rows are the "
                                   "robot) or an is_robot mask", path=log.path)
        is_robot = np.zeros(len(log.observations), bool)
        to = log.truth_observations
        is_robot[to["row"].to_numpy(int)[to["who"].astype(str).to_numpy() == "robot"]] = True
    prob = prepare(log, rec, is_robot=is_robot, init_network=log.truth)
    graph, values = build_graph(log, prob)
    truth = true_values(log, prob, graph, values)
    marginals = gtsam.Marginals(graph, truth)
    cov = {}
    for i, sid in enumerate(prob.sensor_ids):
        cov[sid], _, _ = sensor_sigma_world(truth.atPose3(S(i)), marginals.marginalCovariance(S(i)))
    return CRLBResult(position_covariance_m2=cov, recipe=rec.name)


__all__ = ["sensor_position_crlb", "CRLBResult", "true_values"]
