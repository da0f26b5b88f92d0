"""pedcal's estimator, the batch solve: the factor graph of :mod:`pedcal.calib.graph` solved once
over the whole log, with what the graph does not hold as factors estimated around it:

- the head point's shifts toward the sensor (along the ray: a range offset of every
  observation; horizontally) by their profile likelihood, their covariance carried into the
  sensors' (:func:`_estimate_head_shifts`);
- the residuals checked against the noise model, per sensor, the sigma widened where they
  exceed it (:func:`model_check`);
- the joint covariance of all sensors' positions and the head model, written to the
  calibrated YAML (:func:`_posterior`).

The graph's variables and factors are described in :mod:`pedcal.calib.graph`, whose names are
re-exported here.
"""

from __future__ import annotations

import copy
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from pedcal.calib.common import CalibrationResult, FactorGraphDiagnostics, GraphKeys, HeadModel, ModelMismatch
from pedcal.calib.graph import (  # noqa: F401 (re-exported: the graph layer's public names)
    GRAPHS_DIR,
    A,
    FactorGraphProblem,
    GraphRecipe,
    H,
    L,
    S,
    X,
    _log,
    _network_from_result,
    amcl_cov_body,
    amcl_white_sigma,
    build_graph,
    calibrate_odometry,
    finish_network,
    head_frame,
    observability,
    observation_sigmas,
    optimize_graph,
    prepare,
    rotation_sigma_deg,
    sensor_sigma_world,
)
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.model import Log, SensorNetwork


def calibrate_factorgraph(log: Log, *, progress: bool = False, graph: str | Path | GraphRecipe | None = None,
                          is_robot: np.ndarray | None = None, online: bool = False,
                          init_network: SensorNetwork | None = None, **recipe_overrides) -> CalibrationResult:
    """Calibrate with pedcal's factor graph. ``graph`` names a recipe in graphs/ or a TOML path;
    keyword overrides set recipe fields by name."""
    t0 = time.perf_counter()
    recipe = graph if isinstance(graph, GraphRecipe) else GraphRecipe.load(graph or "default")
    recipe = copy.copy(recipe)
    for k, v in recipe_overrides.items():
        if not hasattr(recipe, k):
            raise ValueError(f"unknown graph recipe field '{k}'")
        setattr(recipe, k, v)
    if not (recipe.robot or recipe.people):
        raise PedcalInputError("the graph recipe uses neither the robot nor people: nothing observes the sensors")
    if recipe.ceiling_height_m > 0.0 and recipe.sensor_height_sigma_m <= 0.0:
        raise PedcalInputError("a ceiling height needs its sigma (sensor_height_sigma_m > 0)",
                               column="sensor_height_sigma_m")
    if online:
        from pedcal.calib.online import calibrate_online

        return calibrate_online(log, recipe=recipe, is_robot=is_robot, progress=progress)

    prob = prepare(log, recipe, is_robot=is_robot, progress=progress, init_network=init_network)
    t_build = time.perf_counter()
    fg, values = build_graph(log, prob)
    t_build = time.perf_counter() - t_build
    _log(progress, f"optimizing {fg.size()} factors over {values.size()} variables")
    t_opt = time.perf_counter()
    result, iterations = optimize_graph(fg, values, recipe)
    _log(progress, f"converged in {iterations} iterations, error {fg.error(values):.1f} -> {fg.error(result):.1f}")
    shifts = _estimate_head_shifts(log, prob, fg, result)
    if shifts is not None:
        fg, result = shifts.graph, shifts.result
        sd = 1000 * np.sqrt(np.diag(shifts.cov))
        _log(progress, f"head point shift toward the sensor: {1000 * prob.ray_shift_m:.1f} +- {sd[0]:.1f} mm "
                       f"along the ray, {1000 * prob.horizontal_shift_m:.1f} mm horizontally "
                       f"({shifts.solves} solves)")
    t_opt = time.perf_counter() - t_opt
    cov_body, joint_pos, head_model, mismatch = _posterior(log, prob, fg, result, shifts)
    cov_world: dict[str, np.ndarray] = {}
    network = _network_from_result(log, prob, fg, result, progress, cov_out=cov_world, cov_body=cov_body)
    mask = finish_network(log, prob, network, head_model=head_model, joint_position_cov=joint_pos,
                          mismatch=mismatch)
    diagnostics = FactorGraphDiagnostics(recipe=recipe.name, latency_s=prob.latency_s, iterations=iterations,
                                         factors=fg.size(), build_s=t_build, optimize_s=t_opt,
                                         variables=values.size(), shared_people=len(prob.people),
                                         odometry=prob.odometry_estimates, position_cov_world_m2=cov_world,
                                         head_model=head_model, model_mismatch=mismatch)
    return CalibrationResult(network=network, method="factorgraph", runtime_s=time.perf_counter() - t0,
                             is_robot=mask, diagnostics=diagnostics, graph=fg, values=result,
                             keys=graph_keys(prob, result), position_covariance_m2=joint_pos)


@dataclass
class _HeadShifts:
    graph: gtsam.NonlinearFactorGraph
    result: gtsam.Values
    cov: np.ndarray               # (k, k) covariance of the shifts (ray, then horizontal), m^2
    sensitivity: np.ndarray       # (6 n_sensors, k) d(sensor pose tangent)/d(shift), per metre
    solves: int


def _set_shifts(prob: FactorGraphProblem, theta: np.ndarray) -> None:
    prob.ray_shift_m = float(theta[0])
    if len(theta) > 1:
        prob.horizontal_shift_m = float(theta[1])


def _shift_prior(rec: GraphRecipe, theta: np.ndarray) -> float:
    """The shifts' prior as a graph error (chi^2 / 2): the ray shift about head_radius_m, the
    horizontal one about 0."""
    e = 0.5 * ((theta[0] - rec.head_radius_m) / rec.head_ray_shift_sigma_m) ** 2
    if len(theta) > 1:
        e += 0.5 * (theta[1] / rec.head_horizontal_shift_sigma_m) ** 2
    return float(e)


def _solve_at(log: Log, prob: FactorGraphProblem, theta: np.ndarray, start: gtsam.Values,
              max_iterations: int | None = None):
    """The graph rebuilt with the head point's shifts ``theta`` (toward the sensor along the ray,
    then horizontally), solved from ``start`` (at most ``max_iterations`` LM steps: a probe near a
    converged solution needs one or two); returns (graph, result, profile error incl. the
    shifts' prior)."""
    rec = prob.recipe
    _set_shifts(prob, theta)
    fg, values = build_graph(log, prob)
    values.update(start)
    if max_iterations is not None:
        rec = copy.copy(rec)
        rec.max_iterations = max_iterations
    result, _ = optimize_graph(fg, values, rec)
    return fg, result, fg.error(result) + _shift_prior(rec, theta)


def _sensor_tangents(prob: FactorGraphProblem, result: gtsam.Values, ref: gtsam.Values) -> np.ndarray:
    return np.concatenate([ref.atPose3(S(i)).localCoordinates(result.atPose3(S(i)))
                           for i in range(len(prob.sensor_ids))])


def _estimate_head_shifts(log: Log, prob: FactorGraphProblem, fg, result) -> _HeadShifts | None:
    """The head point's shift toward the sensor along the ray (a range offset of every
    observation; a dome's radius) and, unless the recipe leaves it out, horizontally (a point
    pulled toward the sensor whatever the viewing angle), by their profile likelihood: the
    graph's optimal error at theta +- h on each axis and at theta + h (1, 1), a quadratic through
    them (Gauss-Newton on the profile), repeated once if a step reached 4 h. Their covariance is
    the inverse of the quadratic's Hessian (error = chi^2 / 2), and the sensors' sensitivity to
    them (central differences of the solutions) carries it into the sensors' covariance: the
    marginal over the shifts, not the conditional."""
    rec = prob.recipe
    if not (rec.estimate_head_model and rec.head_ray_shift_sigma_m > 0.0):
        return None
    k = 2 if rec.estimate_head_horizontal_shift and rec.head_horizontal_shift_sigma_m > 0.0 else 1
    h = rec.head_ray_shift_step_m
    theta = np.array([prob.ray_shift_m, prob.horizontal_shift_m][:k])
    e0 = fg.error(result) + _shift_prior(rec, theta)
    n6 = 6 * len(prob.sensor_ids)
    solves = 0
    for _ in range(2):
        g, Hm, sens = np.zeros(k), np.zeros((k, k)), np.zeros((n6, k))
        e_plus = np.zeros(k)
        for j in range(k):
            d = h * np.eye(k)[j]
            _, r_plus, e_plus[j] = _solve_at(log, prob, theta + d, result, max_iterations=2)
            _, r_minus, e_minus = _solve_at(log, prob, theta - d, result, max_iterations=2)
            g[j] = (e_plus[j] - e_minus) / (2.0 * h)
            Hm[j, j] = (e_plus[j] + e_minus - 2.0 * e0) / h ** 2
            sens[:, j] = (_sensor_tangents(prob, r_plus, result) - _sensor_tangents(prob, r_minus, result)) / (2 * h)
            solves += 2
        if k == 2:
            _, _, e_pp = _solve_at(log, prob, theta + h, result, max_iterations=2)
            Hm[0, 1] = Hm[1, 0] = (e_pp - e_plus[0] - e_plus[1] + e0) / h ** 2
            solves += 1
        if not np.all(np.linalg.eigvalsh(Hm) > 0.0):
            warnings.warn("the head point's shifts toward the sensor are not determined by the data (flat "
                          "profile); their prior is kept", DegenerateDataWarning, stacklevel=3)
            fg, result, _ = _solve_at(log, prob, theta, result)
            prior_sd = [rec.head_ray_shift_sigma_m, rec.head_horizontal_shift_sigma_m][:k]
            return _HeadShifts(fg, result, np.diag(np.square(prior_sd)), np.zeros((n6, k)), solves + 1)
        step = np.clip(-np.linalg.solve(Hm, g), -5.0 * h, 5.0 * h)
        theta = theta + step
        fg, result, e0 = _solve_at(log, prob, theta, result)
        solves += 1
        if np.max(np.abs(step)) < 4.0 * h:     # the profile is close to quadratic: one fit is enough
            break
    return _HeadShifts(fg, result, np.linalg.inv(Hm), sens, solves)


def robot_residuals(prob: FactorGraphProblem, result: gtsam.Values) -> np.ndarray:
    """(N, 3) normalized residuals of the robot observations at ``result``: two bearing
    components (across the ray, over the lateral sigma) and the range (over its sigma), each
    N(0, 1) if the noise model of the graph holds."""
    rec = prob.recipe
    n_pose = len(prob.pose_times)
    use = prob.obs_key_index < n_pose
    if not (rec.robot and use.any()):
        return np.zeros((0, 3))
    xk = np.array([result.atPose3(X(k)).translation() for k in range(n_pose)])
    idx = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    si = np.array([idx[s] for s in prob.obs_sensor[use]])
    R = np.stack([result.atPose3(S(i)).rotation().matrix() for i in range(len(prob.sensor_ids))])[si]
    t = np.stack([result.atPose3(S(i)).translation() for i in range(len(prob.sensor_ids))])[si]
    p_pred = np.einsum("nji,nj->ni", R, xk[prob.obs_key_index[use]] - t)
    p_meas = prob.head_points_sensor()[use]
    r_meas = np.linalg.norm(p_meas, axis=1)
    u = p_meas / r_meas[:, None]
    r_pred = np.linalg.norm(p_pred, axis=1)
    a = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    b1 = np.cross(u, a)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = np.cross(u, b1)
    u_pred = p_pred / r_pred[:, None]
    sig = observation_sigmas(rec, r_meas)
    return np.column_stack([np.sum(u_pred * b1, axis=1) / sig[:, 0], np.sum(u_pred * b2, axis=1) / sig[:, 1],
                            (r_pred - r_meas - prob.ray_shift_m) / sig[:, 2]])


def model_check(prob: FactorGraphProblem, result: gtsam.Values, threshold: float = 1.5) -> ModelMismatch:
    """Residuals against the noise model, per sensor: the robust variance ratio (median of the
    squared normalized residuals over the chi-square(1) median 0.455, averaged over the three
    components; 1 when the model holds, robust to the mis-associations the kernel rejects, not
    to a bias), and the sensors whose ratio exceeds ``threshold``."""
    z = robot_residuals(prob, result)
    rec = prob.recipe
    n_pose = len(prob.pose_times)
    sensors = prob.obs_sensor[prob.obs_key_index < n_pose] if rec.robot else np.zeros(0, str)
    ratio = {}
    for sid in prob.sensor_ids:
        m = sensors == sid
        if m.sum() >= 10:
            ratio[sid] = float(np.mean(np.median(z[m] ** 2, axis=0)) / 0.4549)
    bad = {sid: r for sid, r in ratio.items() if r > threshold}
    return ModelMismatch(variance_ratio=ratio, threshold=threshold, sensors=sorted(bad),
                         misfit=(f"{len(bad)} of {len(ratio)} sensors' residuals exceed the noise model: "
                                 + ", ".join(f"{sid} x{np.sqrt(r):.2f} sigma" for sid, r in sorted(bad.items()))
                                 if bad else ""))


def _posterior(log: Log, prob: FactorGraphProblem, fg, result, shifts: _HeadShifts | None):
    """The sensors' covariance: the joint marginal of every sensor pose (and the head model's
    vertical offset) from the graph, plus the ray shift's share (its sigma times the sensors'
    sensitivity), each sensor's rows widened by the square root of its residuals' variance ratio
    where that exceeds 1. Returns (per-sensor body covariance, the joint world-axes position
    covariance, the head model, the model check)."""
    rec = prob.recipe
    n = len(prob.sensor_ids)
    keys = [S(i) for i in range(n)]
    has_h = result.exists(H(0))
    marginals = gtsam.Marginals(fg, result)
    kv = gtsam.KeyVector(keys + ([H(0)] if has_h else []))
    C = marginals.jointMarginalCovariance(kv).fullMatrix()
    C_s = C[:6 * n, :6 * n].copy()
    if shifts is not None:
        C_s += shifts.sensitivity @ shifts.cov @ shifts.sensitivity.T
    check = model_check(prob, result)
    scale = np.ones(6 * n)
    for i, sid in enumerate(prob.sensor_ids):
        scale[6 * i:6 * i + 6] = np.sqrt(max(1.0, check.variance_ratio.get(sid, 1.0)))
    C_s = C_s * np.outer(scale, scale)
    cov_body = {sid: C_s[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i, sid in enumerate(prob.sensor_ids)}
    Rb = np.zeros((3 * n, 6 * n))
    for i in range(n):
        Rb[3 * i:3 * i + 3, 6 * i + 3:6 * i + 6] = result.atPose3(S(i)).rotation().matrix()
    joint_pos = Rb @ C_s @ Rb.T
    if rec.sensor_height_sigma_m > 0.0:
        reference = "ceiling height" if rec.ceiling_height_m > 0.0 else "installed sensor heights"
    else:
        reference = "none"
    head = HeadModel(vertical_offset_m=-rec.head_radius_m, ray_shift_m=prob.ray_shift_m,
                     horizontal_shift_m=prob.horizontal_shift_m, height_reference=reference,
                     estimated=bool(rec.estimate_head_model))
    if has_h:
        head.vertical_offset_m = float(-rec.head_radius_m + result.atPose3(H(0)).translation()[2])
        head.sigma_vertical_offset_m = float(np.sqrt(C[6 * n + 5, 6 * n + 5]))
    if shifts is not None:
        sd = np.sqrt(np.diag(shifts.cov))
        head.sigma_ray_shift_m = float(sd[0])
        if len(sd) > 1:
            head.sigma_horizontal_shift_m = float(sd[1])
    if has_h and reference == "none":
        head.note = (HEAD_HEIGHT_DEGENERACY + " Its prior is a dome's (offset = -shift) give or take "
                        f"{1000 * rec.head_vertical_sigma_m:.0f} mm, a sigma the sensors' heights carry, "
                        "shared by all of them.")
        warnings.warn("the head point's vertical offset cannot be told from the sensors' common height by "
                      "the robot alone: the sensors' vertical sigma carries its prior "
                      f"({1000 * rec.head_vertical_sigma_m:.0f} mm); give a height reference "
                      "(--sensor-height-sigma or --ceiling-height)", DegenerateDataWarning, stacklevel=3)
    return cov_body, joint_pos, head, check


def graph_keys(prob: FactorGraphProblem, result: gtsam.Values) -> GraphKeys:
    """Which symbol of the solved graph is which variable (CalibrationResult.keys)."""
    n_pose = sum(1 for k in range(len(prob.pose_times)) if result.exists(X(k)))
    n_amcl = sum(1 for k in range(len(prob.amcl_node_times)) if result.exists(A(k)))
    people = [m for m in range(len(prob.people)) if result.exists(L(m))]
    return GraphKeys(sensors={sid: S(i) for i, sid in enumerate(prob.sensor_ids)},
                     robot_poses=[X(k) for k in range(n_pose)], robot_pose_times=prob.pose_times[:n_pose],
                     amcl_errors=[A(k) for k in range(n_amcl)], amcl_error_times=prob.amcl_node_times[:n_amcl],
                     people=[L(m) for m in people], people_times=np.array([prob.people[m][0] for m in people]),
                     head_model=H(0) if result.exists(H(0)) else None)


HEAD_HEIGHT_DEGENERACY = ("A head point uniformly lower than the head top moves every robot observation down "
                          "alike, which the robot alone cannot tell from the sensors' heights: the vertical "
                          "offset is held by its prior unless a height reference is given.")




__all__ = ["calibrate_factorgraph", "model_check", "graph_keys", "robot_residuals", "HEAD_HEIGHT_DEGENERACY",
           "GraphRecipe",
           "FactorGraphProblem", "build_graph", "prepare", "optimize_graph", "sensor_sigma_world", "amcl_cov_body",
           "amcl_white_sigma", "observability", "observation_sigmas", "rotation_sigma_deg", "calibrate_odometry",
           "head_frame", "finish_network", "GRAPHS_DIR", "S", "X", "A", "L", "H"]
