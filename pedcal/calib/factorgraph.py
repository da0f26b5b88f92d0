"""pedcal's estimator, the batch solve: the factor graph of :mod:`pedcal.calib.graph` solved over
the whole log, with what the graph does not hold as variables estimated around it:

1. a first solve (a few Levenberg-Marquardt iterations) under the assumed AMCL model and the
   sensors' noise estimated from consecutive observations;
2. the head point's shifts toward the sensor (along the ray, horizontally) by their profile on
   the linearized graph (:mod:`pedcal.calib.profile`, :func:`_estimate_nuisances`), roughly;
3. AMCL's error model (white and wandering std, correlation time, jumps left out) from the
   residuals of AMCL against what each sensor saw (:mod:`pedcal.calib.amcl_model`); shared
   sightings the solution contradicts dropped; the graph rebuilt and solved again, unless the
   profile's steps (joint Gauss-Newton steps of the variables) follow and the model left the
   robot's motion unchanged;
4. the shifts again, to a tenth of their sigma, and with wheel odometry the corrections of its
   calibration (scale, heading drift per metre and per second) with them, their covariance
   carried into the sensors';
5. the residuals checked against the noise model, per sensor, the sigma widened where they
   exceed it (:func:`model_check`), and the joint covariance of all sensors' positions and the
   head model written to the calibrated YAML (:func:`_posterior`).

The graph's variables and factors are described in :mod:`pedcal.calib.graph`, whose names are
re-exported here.
"""

from __future__ import annotations

import copy
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from pedcal.calib import blas_threads, readback
from pedcal.calib.amcl_model import FLOOR_MODES, estimate_model, jumps_moved_back, reported_sigma_m
from pedcal.calib.clocks import CLUSTER_S as CLOCK_CLUSTER_S
from pedcal.calib.clocks import PREFIX as CLOCK_PREFIX
from pedcal.calib.clocks import clock_nuisances, is_clock_nuisance, record_clocks, widen_for_overdispersion
from pedcal.calib.common import (
    CalibrationResult,
    FactorGraphDiagnostics,
    GraphKeys,
    HeadModel,
    ModelMismatch,
    ray_basis,
)
from pedcal.calib.graph import (  # noqa: F401 (re-exported: the graph layer's public names)
    BLOCKS,
    GRAPHS_DIR,
    ODOMETRY_NUISANCES,
    A,
    FactorGraphProblem,
    GraphParts,
    GraphRecipe,
    H,
    L,
    MotionRhs,
    ObservationRhs,
    S,
    X,
    _amcl_block,
    _log,
    _network_from_result,
    amcl_cov_body,
    amcl_white_sigma,
    build_graph,
    build_parts,
    calibrate_odometry,
    finish_network,
    head_frame,
    merged_noise_factors,
    motion_block,
    observability,
    observation_block,
    observation_block_terms,
    observation_graph,
    observation_sigmas,
    observation_terms,
    optimize_graph,
    pose_arrays,
    prepare,
    rebuild_parts,
    rotation_sigma_deg,
    sensor_sigma_world,
    set_amcl_model,
)
from pedcal.calib.headpoint import SENSOR_PREFIX as SHIFT_PREFIX
from pedcal.calib.headpoint import (
    considered_nuisances,
    considered_rms,
    estimate_departure_spread,
    head_depth_note,
    head_profile_nuisances,
    is_head_profile,
    is_sensor_shift,
    leave_out,
    record_head_profile,
    row_clusters,
    row_sensors,
    select_head_profile,
    sensor_shift_nuisances,
)
from pedcal.calib.keys import symbol_parts, symbols
from pedcal.calib.marginals import marginal_covariances
from pedcal.calib.profile import (
    Columns,
    Nuisance,
    fill_reducing_order,
    joint_marginal_covariance,
    profile_step,
    retract_flat,
    sparse_system,
    steps_to_come_below,
)
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.frames import toward_sensor_horizontal
from pedcal.metrics import LATENCY_KEY
from pedcal.model import Log, SensorNetwork


def calibrate_factorgraph(log: Log, *, progress: bool = False, graph: str | Path | GraphRecipe | None = None,
                          is_robot: np.ndarray | None = None, online: bool = False,
                          init_network: SensorNetwork | None = None, **recipe_overrides) -> CalibrationResult:
    """Calibrate with pedcal's factor graph. ``graph`` names a recipe in graphs/ or a TOML path;
    keyword overrides set recipe fields by name. (BLAS on one thread throughout: its products
    here are too small for threads to pay, :mod:`pedcal.calib.blas_threads`.)"""
    with blas_threads.limited(1):
        return _calibrate_factorgraph(log, progress=progress, graph=graph, is_robot=is_robot, online=online,
                                      init_network=init_network, **recipe_overrides)


def _calibrate_factorgraph(log: Log, *, progress: bool, graph, is_robot, online: bool, init_network,
                           **recipe_overrides) -> CalibrationResult:
    t0 = time.perf_counter()
    recipe = graph if isinstance(graph, GraphRecipe) else GraphRecipe.load(graph or "default")
    recipe = copy.copy(recipe)
    for k, v in recipe_overrides.items():
        if not hasattr(recipe, k):
            raise ValueError(f"unknown graph recipe field '{k}'")
        setattr(recipe, k, v)
    if not (recipe.robot or recipe.people):
        raise PedcalInputError("the graph recipe uses neither the robot nor people: nothing observes the sensors")
    if recipe.amcl_reported_floor not in FLOOR_MODES:
        raise PedcalInputError(f"amcl_reported_floor must be {', '.join(FLOOR_MODES)}, got "
                               f"{recipe.amcl_reported_floor!r}", column="amcl_reported_floor")
    if recipe.head_curvature not in ("off", "on", "auto", "widen"):
        raise PedcalInputError(f"head_curvature must be off, on, auto or widen, got {recipe.head_curvature!r}",
                               column="head_curvature")
    if recipe.ceiling_height_m > 0.0 and recipe.sensor_height_sigma_m <= 0.0:
        raise PedcalInputError("a ceiling height needs its sigma (sensor_height_sigma_m > 0)",
                               column="sensor_height_sigma_m")
    n_jumps, amcl_steps = 0, None
    if recipe.robot and recipe.amcl_jumps_moved_back and len(log.robot):
        moved, n_jumps, amcl_steps = jumps_moved_back(log, recipe.amcl_jump_threshold, recipe.amcl_min_jump_m)
        # (the steps of a track left as it was are the assumed AMCL model's, at the same
        # threshold: not looked for again; a moved track's are)
        amcl_steps, log = amcl_steps if moved is log else None, moved
        if n_jumps:
            _log(progress, f"{n_jumps} relocalization jumps in AMCL's track: their estimates moved back by the "
                           "jumps' steps")
    if online:
        from pedcal.calib.online import calibrate_online

        return calibrate_online(log, recipe=recipe, is_robot=is_robot, progress=progress)

    prob = prepare(log, recipe, is_robot=is_robot, progress=progress, init_network=init_network,
                   amcl_steps=amcl_steps)
    prob.amcl_jumps_moved_back = n_jumps
    t_build = time.perf_counter()
    parts = build_parts(log, prob)
    fg = parts.graph()
    t_build = time.perf_counter() - t_build
    _log(progress, f"optimizing {fg.size()} factors over {parts.values.size()} variables")
    t_opt = time.perf_counter()
    resolve = recipe.estimate_amcl_model and recipe.amcl and recipe.robot
    # a first solve that the AMCL model's re-solve continues: a few iterations are enough for the
    # residuals the model is estimated from (to 0.1 % of the error, 1 % with the nuisances
    # profiled: the first profile step, a joint Gauss-Newton step of the variables, follows before
    # them, and at 0.1 % the 1000-sensor graph took one iteration more, 0.6 s, for changes below
    # 0.05 mm).
    # It alone also stops on the predicted remainder (``predicted_stop``): its point feeds AMCL's
    # residuals and one rough profile step, and the graph is solved again under the model. The
    # two other solves the profile's steps follow (this call when AMCL's model is not estimated,
    # and the re-solve after the model changed the robot's motion) give the point the final
    # profile loop starts from; the rule was measured on this one only, and they keep LM's test
    profiled = _profiled(recipe)
    result, iterations = optimize_graph(fg, parts.values, recipe, max_iterations=10 if resolve else None,
                                        gauss_newton_step=not profiled,
                                        relative_error_tol=(1e-2 if profiled else 1e-3) if resolve else None,
                                        ordering=parts.colamd(), predicted_stop=profiled and resolve)
    if progress:        # (the errors cost two passes over the graph: not when nobody reads them)
        _log(progress, f"converged in {iterations} iterations, error {fg.error(parts.values):.1f} -> "
                       f"{fg.error(result):.1f}")
    # (before AMCL's model is estimated, a rough head model is enough: it keeps a wrong one from
    # leaving per-sensor offsets in the residuals that look like a wandering AMCL; the profile is
    # nearly quadratic, so one Newton step from the prior lands within about a sigma)
    # (the AMCL model's re-solve rebuilds the graph: this pass's graph at its result is not built)
    shifts = _estimate_nuisances(log, prob, parts, result, progress, max_steps=1 if resolve else None,
                                 tolerance=0.5 if resolve else 0.1, curvature=not resolve, odometry=not resolve,
                                 final_graph=not resolve)
    if resolve:
        # AMCL's error model from the residuals of a solution with the head model estimated (a
        # wrong head model leaves per-sensor offsets that look like a wandering AMCL), then the
        # head model again under it
        if shifts is not None:
            result = shifts.result
        # (the first pass's graph and nuisances are not held through the re-solve: at 1000 sensors
        # they are 70 MB of the peak)
        fg = shifts = None
        parts, result, more = _reestimate_amcl(log, prob, parts, result, progress, gauss_newton_step=not profiled)
        iterations += more
        shifts = _estimate_nuisances(log, prob, parts, result, progress, odometry=True)
    if shifts is not None:
        fg, result = shifts.graph, shifts.result
        sd = 1000 * np.sqrt(np.diag(shifts.cov))
        _log(progress, f"head point shift toward the sensor: {1000 * prob.ray_shift_m:.1f} +- {sd[0]:.1f} mm "
                       f"along the ray, {1000 * prob.horizontal_shift_m:.1f} mm horizontally, curvature "
                       f"{1000 * prob.curvature_m:.1f} mm ({shifts.solves} profile steps)")
    else:
        fg = parts.graph()
    t_opt = time.perf_counter() - t_opt
    cov_body, cov_given, joint_pos, head_model, mismatch = _posterior(log, prob, _held_graph(log, prob, parts, fg),
                                                                      result, shifts)
    record_head_profile(head_model, prob, shifts)
    cov_world: dict[str, np.ndarray] = {}
    network = _network_from_result(log, prob, fg, result, progress, cov_out=cov_world, cov_body=cov_body,
                                   cov_given=cov_given)
    mask = finish_network(log, prob, network, head_model=head_model, joint_position_cov=joint_pos,
                          mismatch=mismatch)
    record_clocks(network, prob, shifts)
    latency_s = float(network.extra.get(LATENCY_KEY, prob.latency_s))   # with the clock offsets' mean
    diagnostics = FactorGraphDiagnostics(recipe=recipe.name, tracker_latency_s=latency_s, iterations=iterations,
                                         factors=fg.size(), build_s=t_build, optimize_s=t_opt,
                                         variables=result.size(), shared_people=len(prob.people),
                                         odometry_model=prob.odometry_estimates, position_covariance_m2=cov_world,
                                         head_model=head_model, model_mismatch=mismatch,
                                         amcl_error_model=prob.amcl_model, observation_noise=prob.noise_estimate or {})
    return CalibrationResult(network=network, method="factorgraph", runtime_s=time.perf_counter() - t0,
                             is_robot=mask, diagnostics=diagnostics, graph=fg, values=result,
                             keys=graph_keys(prob, result), position_covariance_m2=joint_pos)


def amcl_residuals(log: Log, prob: FactorGraphProblem, result: gtsam.Values) -> tuple[np.ndarray, np.ndarray, list]:
    """AMCL's residuals at its estimates that have a pose variable: (times of all estimates,
    (N, 2) AMCL's head frame minus the solved robot's, world xy, NaN without a pose variable,
    and per sensor (rows, (n, 2)): AMCL's head minus the head top that sensor saw there, mapped
    to the world with its solved pose and the head model, averaged per estimate). A sensor's own
    position error is the same in all of its residuals."""
    amcl = log.robot.sort_values("t", kind="stable")
    t = amcl["t"].to_numpy(float)
    times = prob.pose_times
    k = np.clip(np.searchsorted(times, t), 0, max(len(times) - 1, 0))
    has = times[k] == t
    head_m = np.asarray(log.meta.head_offset_m, float)
    c, s_ = np.cos(amcl["yaw"].to_numpy(float)), np.sin(amcl["yaw"].to_numpy(float))
    z_xy = np.column_stack([amcl["x"].to_numpy(float) + c * head_m[0] - s_ * head_m[1],
                            amcl["y"].to_numpy(float) + s_ * head_m[0] + c * head_m[1]])
    x_xy = pose_arrays(result, symbols("x", range(len(times))))[1][:, :2].reshape(len(times), 2)
    res = np.full((len(t), 2), np.nan)
    res[has] = z_xy[has] - x_xy[k[has]]
    # pose index -> AMCL row (where the pose sits on an AMCL stamp)
    row_of_pose = np.full(len(times), -1)
    row_of_pose[k[has]] = np.flatnonzero(has)
    use = prob.fac_key_index < len(times)
    p = prob.head_points_sensor()
    with np.errstate(divide="ignore", invalid="ignore"):
        p = p * (1.0 + prob.ray_shift_m / np.linalg.norm(p, axis=1))[:, None]    # the head top, sensor frame
    # (a point at the sensor's own origin, a tracker's placeholder, has no ray to shift along: left out)
    finite = np.isfinite(p).all(axis=1)
    n_sensors = len(prob.sensor_ids)
    # each sensor's sightings mapped with its own pose, then all of them averaged per (sensor,
    # estimate) in one pass (the sums taken in the same order as one sensor at a time)
    sensor_of, rows_of, d_of = [], [], []
    for i, m in _groups(np.where(use, prob.fac_sensor_index, n_sensors), n_sensors):
        rows = row_of_pose[prob.fac_key_index[m]]
        keep = (rows >= 0) & finite[m]
        rows = rows[keep]
        if not len(rows):
            continue
        T = result.atPose3(S(i))
        seen = (p[m][keep] @ T.rotation().matrix().T + T.translation())[:, :2]
        sensor_of.append(np.full(len(rows), i, np.int64))
        rows_of.append(rows)
        d_of.append(z_xy[rows] - seen)
    per_sensor = [(np.zeros(0, int), np.zeros((0, 2))) for _ in range(n_sensors)]
    if sensor_of:
        sensor_all, rows_all, d = np.concatenate(sensor_of), np.concatenate(rows_of), np.concatenate(d_of)
        u, inv = np.unique(sensor_all * np.int64(len(t) + 1) + rows_all, return_inverse=True)
        inv = np.asarray(inv).ravel()
        mean = np.column_stack([np.bincount(inv, d[:, c], minlength=len(u)) for c in (0, 1)])
        mean /= np.bincount(inv, minlength=len(u))[:, None]
        owner, row = np.divmod(u, np.int64(len(t) + 1))
        cuts = np.searchsorted(owner, np.arange(n_sensors + 1))
        for i in np.flatnonzero(np.diff(cuts)).tolist():
            per_sensor[i] = (row[cuts[i]:cuts[i + 1]], mean[cuts[i]:cuts[i + 1]])
    return t, res, per_sensor


def residual_noise_m2(prob: FactorGraphProblem, result: gtsam.Values) -> float:
    """The sensors' own noise in AMCL's residuals (:func:`amcl_residuals`): each robot-observation
    factor's point, its noise's covariance in the sensor frame (the recipe's range sigma along the
    ray, its lateral one across: :func:`pedcal.calib.recipe.observation_sigmas`) over its count,
    times the variance factor of that many correlated reports' mean
    (:func:`pedcal.calib.graph.merged_noise_factors`), turned into the world with the sensor's
    solved rotation; its horizontal variance per axis, averaged over the factors (m^2; 0 without
    any)."""
    use = np.flatnonzero(prob.fac_key_index < len(prob.pose_times))
    if not len(use):
        return 0.0
    p = prob.fac_p_sensor[use]
    r = np.linalg.norm(p, axis=1)
    count = np.asarray(prob.fac_count[use], float)
    # (a merged factor's mean of correlated reports: its variance factor, graph.merged_noise_factors)
    g_lateral, g_depth = merged_noise_factors(prob.noise_estimate, count)
    var_lateral = prob.recipe.lateral_sigma_m ** 2 * g_lateral / count
    var_range = observation_sigmas(prob.recipe, r)[:, 2] ** 2 * g_depth / count
    R = np.stack([result.atPose3(S(i)).rotation().matrix() for i in range(len(prob.sensor_ids))])
    v = np.einsum("nij,nj->ni", R[prob.fac_sensor_index[use]], p / np.maximum(r, 1e-9)[:, None])
    # the world covariance lateral^2 I + (range^2 - lateral^2) v v^T; its xy trace over two axes
    xy = 0.5 * (2.0 * var_lateral + (var_range - var_lateral) * (v[:, 0] ** 2 + v[:, 1] ** 2))
    return float(np.mean(xy))


def _reestimate_amcl(log: Log, prob: FactorGraphProblem, parts: GraphParts, result: gtsam.Values, progress: bool,
                     gauss_newton_step: bool = True):
    """AMCL's error model estimated from the first solve's residuals (pedcal.calib.amcl_model),
    the graph rebuilt with it and solved again from the first solution (``parts``: the first
    graph's, whose sensors' priors and unchanged motion block are kept), or, with
    ``gauss_newton_step`` False and the robot's motion unchanged by the model, left at the first
    solution for the nuisances' profile steps to solve. Returns (parts, result, iterations)."""
    rec = prob.recipe
    t, res, per_sensor = amcl_residuals(log, prob, result)
    ok = np.isfinite(res[:, 0])
    model = estimate_model(t, per_sensor, prob.amcl_model,
                           prior_sigma_m=reported_sigma_m(log.robot), noise_m2=residual_noise_m2(prob, result),
                           jump_threshold=rec.amcl_jump_threshold, min_jump_m=rec.amcl_min_jump_m,
                           floor=rec.amcl_reported_floor)
    if model is prob.amcl_model:
        warnings.warn("too few AMCL estimates while a sensor saw the robot to estimate AMCL's error model; the "
                      "recipe's (correlation time, white share of the reported covariance) is kept",
                      DegenerateDataWarning, stacklevel=3)
        return build_parts(log, prob), result, 0
    _log(progress, f"AMCL error: white {1000 * model.white_sigma_m:.1f} mm, wandering "
                   f"{1000 * model.correlated_sigma_m:.1f} mm over {model.correlation_s:.1f} s; {model.jumps} jumps "
                   f"({model.excluded_s:.1f} s) left out")
    rotations = {sid: result.atPose3(S(i)).rotation().matrix() for i, sid in enumerate(prob.sensor_ids)}
    motion_changed = set_amcl_model(log, prob, model, rotations=rotations)
    # the re-solve is left to the nuisances' profile steps, Gauss-Newton steps of the variables
    # (``gauss_newton_step`` False), unless the robot's motion changed with the model (AMCL's
    # jumps left out where it stands in for odometry: every observation carried again), which
    # moves the data, not the noise alone, and Levenberg-Marquardt solves again first
    resolve = gauss_newton_step or motion_changed
    # shared sightings the solution contradicts (two sensors' views of "one" person far apart:
    # a wrong match) hold nothing but a flat robust cost between the two views, which the
    # solver crawls along; they are left out
    bad = people_misfit(prob, result) > rec.people_misfit_sigma
    if bad.any():
        _log(progress, f"{int(bad.sum())} of {len(bad)} shared person sightings contradict the solution "
                       f"(beyond {rec.people_misfit_sigma:.0f} sigma); left out")
        prob.people = [p for p, b in zip(prob.people, bad, strict=True) if not b]
        result = people_renumbered(result, np.flatnonzero(~bad))
    # the variables at the first solution, but the AMCL error's nodes (new with the model: below);
    # the sensors' priors and an unchanged motion block kept from the first graph
    # (without a re-solve, the nuisances' profile builds the observation block at these values first)
    parts = rebuild_parts(log, prob, parts, result, observations=resolve)
    values = parts.values
    # the error process's nodes start at its share of AMCL's mean residual near them (the node
    # F = X Z^-1 is minus the residual): c^2 / (c^2 + w^2 / n) of it for n estimates; its height at
    # the head model's
    keep = ok & ~(model.excluded if model.excluded is not None else np.zeros(len(t), bool))
    nodes = prob.amcl_node_times
    if keep.sum() >= 2 and len(nodes):
        z = result.atPose3(H(0)).translation()[2] if result.exists(H(0)) else 0.0
        node = np.clip(np.round((t[keep] - nodes[0]) / max(nodes[1] - nodes[0], 1e-9) if len(nodes) > 1
                                else np.zeros(int(keep.sum()))).astype(int), 0, len(nodes) - 1)
        n = np.bincount(node, minlength=len(nodes))
        mean = np.column_stack([np.bincount(node, res[keep, c], minlength=len(nodes)) for c in (0, 1)])
        mean /= np.maximum(n, 1)[:, None]
        c2, w2 = model.correlated_sigma_m ** 2, model.white_sigma_m ** 2
        share = np.where(n > 0, c2 / (c2 + w2 / np.maximum(n, 1)), 0.0)
        start = np.column_stack([-share * mean[:, 0], -share * mean[:, 1], np.full(len(nodes), z)])
        no_turn, exists, update = gtsam.Rot3(), values.exists, values.update
        # (the Pose3 overload named: GTSAM's binding otherwise tries nine others first)
        for key, xyz in zip(symbols("a", range(len(nodes))).tolist(), start, strict=True):
            if exists(key):
                update(key, pose3=gtsam.Pose3(no_turn, xyz))
    if not resolve:
        # Gauss-Newton steps follow, those of the nuisances' profile (each a joint step of the
        # variables, from a point one such step already settled under the first model): they
        # solve the rebuilt graph, converging quadratically this close, and no iteration of its
        # own goes before them (LM's two iterations to 0.1 % of the error were 1.3 s of 1000
        # sensors' 17 s; without them, the zoo logs' sensors moved by at most 1 mm, their RMS by
        # less than 0.1 mm)
        return parts, values, 0
    # (when Gauss-Newton steps follow, those of the nuisances' profile, LM stops at 0.1 % of the
    # error: they finish what it leaves)
    result, iterations = optimize_graph(parts.graph(), values, rec, gauss_newton_step=gauss_newton_step,
                                        relative_error_tol=None if gauss_newton_step else 1e-3,
                                        ordering=parts.colamd())
    return parts, result, iterations


def people_renumbered(values: gtsam.Values, kept: np.ndarray) -> gtsam.Values:
    """``values`` with the people's variables renumbered after some sightings were left out:
    ``L(m)`` holds what ``L(kept[m])`` held (the others' variables are dropped; every other
    variable is copied as it is)."""
    out = gtsam.Values(values)
    keys = np.asarray(values.keys(), np.uint64)
    for key in keys[symbol_parts(keys)[0] == np.uint64(ord("l"))].tolist():
        out.erase(key)
    for m, j in enumerate(kept):
        if values.exists(L(int(j))):
            out.insert(L(m), values.atPoint3(L(int(j))))
    return out


def people_misfit(prob: FactorGraphProblem, result: gtsam.Values) -> np.ndarray:
    """Per shared sighting, the largest whitened residual (bearing and range, in sigmas) of its
    sensors' views of the solved person; inf for a sighting without its variable."""
    rec = prob.recipe
    idx = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    out = np.full(len(prob.people), np.inf)
    for m, (_, seen) in enumerate(prob.people):
        if not result.exists(L(m)):
            continue
        worst = 0.0
        for sid, p in seen:
            T = result.atPose3(S(idx[sid]))
            p = p - prob.horizontal_shift_m * toward_sensor_horizontal(p[None, :], T.rotation().matrix())[0]
            q = T.transformTo(result.atPoint3(L(m)))
            r_meas = float(np.linalg.norm(p))
            sig = observation_sigmas(rec, np.array([r_meas]))[0]
            angle = np.arccos(np.clip(np.dot(q, p) / (np.linalg.norm(q) * r_meas), -1.0, 1.0))
            worst = max(worst, np.hypot(angle / sig[0], (np.linalg.norm(q) - r_meas - prob.ray_shift_m) / sig[2]))
        out[m] = worst
    return out


@dataclass
class _Nuisances:
    graph: gtsam.NonlinearFactorGraph | None     # (None when not asked for: ``final_graph``)
    result: gtsam.Values
    cov: np.ndarray               # (k, k) covariance of the nuisances (in ``names`` order, their units squared)
    sensitivity: np.ndarray       # (6 n_sensors + 6, k) d(sensor pose tangents, h(0) tangent)/d(nuisance), per unit
    solves: int
    names: list = field(default_factory=list)
    # nuisances profiled each on its own variable (pedcal.calib.profile.LocalProfile), the last of
    # ``names``: cov holds their variances on its diagonal, ``sensitivity`` has no columns for
    # them; (their sensor indices (m,), their sensors' sensitivity (m, 6))
    local: tuple | None = None
    # a curvature the data show but the recipe does not estimate: (would-be value m, the
    # sensors' (and h(0)'s) sensitivity to it, chi^2)
    unmodelled: tuple | None = None
    # the shift against distance held at 0 but not known (pedcal.calib.headpoint.considered_nuisances):
    # (how far it may be from 0 given the data and the curvature's hold, m
    # (pedcal.calib.headpoint.considered_rms), the
    # sensors' (and h(0)'s) error per unit of it)
    considered: tuple | None = None
    # ``graph``'s COLAMD ordering (the parts', computed for the solve): the marginals' elimination order
    ordering: gtsam.Ordering | None = None


def _shown(name: str, value: float) -> str:
    """A nuisance's value in the unit it is read in: mm, % or deg per metre or second."""
    if name.endswith("_rad_per_m"):
        return f"{np.degrees(value):+.4f} deg/m"
    if name.endswith("_rad_per_s"):
        return f"{np.degrees(value):+.5f} deg/s"
    if name.endswith("_correction"):
        return f"{100 * value:+.3f} %"
    return f"{1000 * value:+.2f} mm"


def _profiled(rec: GraphRecipe) -> bool:
    """Whether the recipe estimates the nuisances by their profile (each step a Gauss-Newton step)."""
    return bool(rec.estimate_head_model and rec.head_ray_shift_sigma_m > 0.0 and rec.robot)


def _sensor_of(name: str) -> str:
    """The sensor id of a per-sensor nuisance's name (a clock offset, a head shift departure)."""
    return name[len(SHIFT_PREFIX):] if is_sensor_shift(name) else name[len(CLOCK_PREFIX):]


# at most this many profile steps: each one's gradient exact, they reach the profile's optimum,
# within a few steps where the profile is nearly quadratic; where the robust kernel's frozen
# weights overstate its curvature (an offset the data hardly hold, Huber's down-weighted factors
# pulling it) the steps shrink slowly and more are taken, extrapolated
MAX_PROFILE_STEPS = 20


def _estimate_nuisances(log: Log, prob: FactorGraphProblem, parts, result, progress: bool = False,
                        max_steps: int | None = None, tolerance: float = 0.1, curvature: bool = True,
                        odometry: bool = False, final_graph: bool = True) -> _Nuisances | None:
    """The nuisances that enter the measurements, by their profile likelihood on the linearized
    graph (pedcal.calib.profile): the head point's shift toward the sensor along the ray (a range
    offset of every observation; a dome's radius), horizontally (a point pulled toward the sensor
    whatever the viewing angle), its height's curvature with the viewing angle
    (``head_curvature``: on, off, or auto: kept when the first step's profile finds it at
    ``head_curvature_select_chi2`` or more, a significance test of chi^2 with one degree of
    freedom; widen: never kept, its would-be move carried in the sensors' covariance from
    ``head_curvature_widen_chi2``) and, with ``odometry`` and wheel odometry in the graph, the
    corrections of the odometry's calibration (scale, heading drift per metre and per second;
    the motion block rebuilt for them). Each step moves the nuisances by the profile's Newton
    (or chord) step and the variables by the linearized optimum there, until the step is below
    ``tolerance`` times their sigma (at most ``max_steps`` steps). Their covariance is the
    profile's inverse Hessian and the variables' sensitivity to them carries it into the
    sensors' covariance: the marginal over the nuisances, not the conditional. ``parts`` gets
    the observation and motion blocks at the final values, and the result its graph, unless
    ``final_graph`` is False (a pass whose graph the caller rebuilds: the observation block is
    left empty unless something made it, the result's graph None); ``curvature=False`` leaves the
    curvature out (a first, rough pass).

    Above ``clock_offsets_joint_max`` per-sensor clock offsets, they join the linear system as
    variables (their step the joint Gauss-Newton step's, as exact as the profile's), and each
    one's sigma comes from its own profile with every other variable held
    (:func:`pedcal.calib.profile._local_profile`): its sensor's pose free, the robot's path
    fixed, which many sensors pin down; their coupling through the path is left out of their
    sigma and of the sensors' covariance, and the cost stays linear in the sensors (one d x d
    solve each, not a right-hand side through the whole graph)."""
    rec = prob.recipe
    if not _profiled(rec):
        return None
    # each sensor's clock offset (pedcal.calib.clocks), first: it sets the head's velocity at ``result``,
    # which the observation terms' clock-shift regressors read (read after them, the first step of a second
    # pass would take A, b and the robust weights at the pass before's velocity, its B at this one's)
    clocks = clock_nuisances(prob, result)
    # the observation block's terms at the solution the steps are linearized at (the block ``parts``
    # holds was built before the solve, its noise ranges read elsewhere: its A and b would be whitened
    # unlike the right-hand sides' B, which ObservationRhs reads at the points ``result`` predicts);
    # its factors are made when asked for (``block()``: the selection of the head profile, an ordering
    # not kept whose block was not held, people, the final graph), the steps take its linearization
    # from the terms (ObservationRhs.linearized): the factors of a block nobody asks for (60 000 at
    # 1000 sensors, 0.14 s a block) are not made
    block_terms = observation_terms(log, prob, result)
    built, motion_fresh = None, True

    def block() -> gtsam.NonlinearFactorGraph:
        """The observation block of ``block_terms``, made on the first call for them."""
        nonlocal built
        if built is not block_terms:
            parts.blocks["observations"], built = observation_graph(prob, block_terms), block_terms
        return parts.blocks["observations"]

    def motion() -> gtsam.NonlinearFactorGraph:
        """The odometry's block at the problem's present corrections, made when they moved."""
        nonlocal motion_fresh
        if not motion_fresh:
            parts.blocks["motion"], motion_fresh = motion_block(log, prob), True
        return parts.blocks["motion"]
    nuis = [Nuisance("ray_shift_m", rec.head_radius_m, rec.head_ray_shift_sigma_m, rec.head_ray_shift_step_m)]
    if rec.estimate_head_horizontal_shift and rec.head_horizontal_shift_sigma_m > 0.0:
        nuis.append(Nuisance("horizontal_shift_m", 0.0, rec.head_horizontal_shift_sigma_m, rec.head_ray_shift_step_m))
    odo = odometry and rec.estimate_odometry_errors and rec.odometry and prob.odometry is not None
    if odo:
        # odometry's systematic errors left by its calibration, about the calibration (the curvature,
        # which _select_curvature may drop, stays last)
        nuis += [Nuisance("odometry_scale_correction", 0.0, rec.odometry_scale_sigma, 1e-3),
                 Nuisance("odometry_drift_rad_per_m", 0.0, np.radians(rec.odometry_drift_sigma_deg_per_m), 1e-4),
                 Nuisance("odometry_drift_rad_per_s", 0.0, np.radians(rec.odometry_drift_sigma_deg_per_s), 1e-5)]
    local_nuis = clocks if len(clocks) > rec.clock_offsets_joint_max else []
    if local_nuis:
        _log(progress, f"{len(clocks)} sensors' clock offsets (more than {rec.clock_offsets_joint_max}): each "
                       "fitted with the path, its sigma on its own given the path (their coupling through it left out)")
    else:
        nuis += clocks
    profile_nuis = head_profile_nuisances(prob)   # the horizontal shift against distance (pedcal.calib.headpoint)
    nuis += profile_nuis
    # each sensor's own departure of the horizontal shift (a random effect; with many sensors
    # fitted with the path like the clock offsets)
    if local_nuis:
        local_nuis = local_nuis + sensor_shift_nuisances(prob)
    else:
        nuis += sensor_shift_nuisances(prob)
    # (the shift against distance is chosen among its shapes; the random effect's departures are
    # no candidates, and without a profile there is nothing to choose: no rows labelled for it)
    select_profile = bool(profile_nuis)
    select = curvature and rec.head_curvature in ("auto", "widen")
    # (the spread's estimate, used or only reported; not in the rough first pass, whose head model
    # only serves AMCL's model)
    spread = curvature and rec.head_shift_per_sensor_sigma_m > 0.0
    unmodelled = None
    considered = considered_nuisances(prob)    # (before the curvature, which stays last)
    nuis += considered
    consider_s = None
    if curvature and rec.head_curvature in ("on", "auto", "widen") and rec.head_curvature_sigma_m > 0.0:
        nuis.append(Nuisance("curvature_m", 0.0, rec.head_curvature_sigma_m, rec.head_ray_shift_step_m))
    fixed = gtsam.NonlinearFactorGraph()
    for name in BLOCKS:
        if name != "observations" and not (odo and name == "motion"):
            fixed.push_back(parts.blocks[name])
    cols = Columns.of(result)
    kernel = (rec.robust_kernel, rec.robust_k)
    prior_factors = int(result.exists(H(0)) and rec.amcl)      # the head offset's prior leads the block
    step, full_step, reference = None, None, None
    local_names = [n.name for n in local_nuis]
    index = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    local_sensors = np.array([index[_sensor_of(n)] for n in local_names], np.int64)
    own_shift = np.array([is_sensor_shift(n) for n in local_names], bool)
    # (each local nuisance's sensor's columns, one row each: looked up together, not one sensor at a time)
    local_cols = (cols.index([S(int(i)) for i in local_sensors]).reshape(len(local_sensors), -1) if local_nuis
                  else None)
    # (the last step in sigmas, its nuisances' names: with local nuisances, every step has them,
    # the whole step, theirs too)
    previous_u, previous_names, slow, extrapolated = None, None, False, False
    max_steps = MAX_PROFILE_STEPS if max_steps is None else max_steps       # (read when called: tests set it)
    for n_step in range(1, max_steps + 1):
        names = [n.name for n in nuis]
        theta = np.array([getattr(prob, n) for n in names], float)
        theta_local = np.array([getattr(prob, n) for n in local_names], float)
        every = tuple(names + local_names)          # the exact nuisances first, then the local ones
        # the shifts enter the measurements linearly, so after a step of a few sigma the
        # sensitivities barely change: a chord step (the last full step's Hessian and
        # sensitivities, this point's gradient) costs one solve, not k + 1
        chord = step is not None and np.all(np.abs(step.dtheta) <= 3.0 * np.sqrt(np.diag(step.covariance)))
        chord = chord and not slow      # (a slow one: the next step's Hessian taken afresh)
        # (a chord step takes B's finite differences too: its gradient, -B^T rho0, is exact only with
        # this point's B and robust weights; with the full step's, the chord settled elsewhere than
        # the profile's optimum)
        plain = None
        if odo:
            motion_rhs = MotionRhs(log, prob, result)
            plain = ([j for j, n in enumerate(names) if n in ODOMETRY_NUISANCES],
                     lambda th, f=motion_rhs, nm=every: f(dict(zip(nm, th, strict=True))),
                     # (the block's linearization made in numpy: it is not rebuilt between steps)
                     lambda f=motion_rhs: f.linearized(cols))
        # B's columns in numpy, no factors rebuilt (what the block read at ``result`` taken from it)
        rhs = ObservationRhs(log, prob, result, terms=block_terms)
        # a sensor's clock offset enters its own robot observations alone (pedcal.calib.clocks),
        # and so does its own departure of the horizontal shift
        footprint = {j: rhs.robot_factors(index[_sensor_of(n)]) for j, n in enumerate(every)
                     if (is_clock_nuisance(n) or is_sensor_shift(n)) and _sensor_of(n) in index}
        if step is None and parts.ordering is None and parts.blocks["observations"].size() == 0:
            # (the whole graph's COLAMD ordering is computed with it; a held block, of the same
            # structure, serves as well)
            block()
        step = profile_step(fixed, lambda th, scale, r=result, nm=every: observation_block(
            log, prob, r, theta=dict(zip(nm, th, strict=True)), sigma_scale=scale), result,
            np.r_[theta, theta_local], nuis + local_nuis, cols, kernel=kernel,
            plain_leading=prior_factors, plain=plain, previous=full_step if chord else None,
            # (the first step's fill-reducing order: the graph's COLAMD ordering, the solver's)
            order=fill_reducing_order(parts.colamd(), cols) if step is None else step.order,
            residuals=lambda th, scale, f=rhs, nm=every: f(dict(zip(nm, th, strict=True)), scale),
            footprint=footprint, local=local_cols, factor_rows=rhs.factor_rows(),
            # (the block's linearization made from its terms; GTSAM's where they cannot make it)
            obs_linear=lambda f=rhs: _linearized(f, cols, block))
        if not chord:
            full_step = step
        if considered and not chord:
            # the shift against distance, held at 0: out of the estimate, its sensitivity kept
            with_line, line_j = step, names.index(considered[0].name)
            step, consider_s = leave_out(step, line_j)
            consider_sd = considered_rms(with_line, line_j)    # its prior's sigma, as the data leave it
            nuis = [n for n in nuis if n.name != considered[0].name]
            considered = []
            names = [n.name for n in nuis]
            theta = np.array([getattr(prob, n) for n in names], float)
            full_step = step
        if select and "curvature_m" in names:
            select = False
            full = step
            step, nuis, chi2 = _select_curvature(step, nuis, rec.head_curvature_select_chi2,
                                                 estimate=rec.head_curvature == "auto")
            kept = len(nuis) == len(names)
            if not kept and chi2 >= rec.head_curvature_widen_chi2:
                unmodelled = _unmodelled_curvature(full, chi2)
            if not kept and consider_s is not None:
                # (the curvature held at 0 as well takes up none of the line's move)
                consider_s = leave_out(with_line, line_j, held=(len(with_line.hessian) - 1,))[1]
                consider_sd = considered_rms(with_line, line_j, held=(len(with_line.hessian) - 1,))
            _log(progress, f"head point curvature: chi^2 {chi2:.1f} -> "
                           + ("estimated" if kept else "its share widens the sigma" if unmodelled else "left out"))
            names = [n.name for n in nuis]
            theta = np.array([getattr(prob, n) for n in names], float)
            full_step = step
        if select_profile and not chord:
            select_profile = False
            local = step.local
            # the rows of the profile's system: the fixed blocks', the observations', the motion's
            graphs = [fixed, block()] + ([motion()] if odo else [])
            n_rows = 0 if step.rho0 is None else len(step.rho0)
            step, nuis, compared = select_head_profile(prob, step, nuis, folds=row_sensors(graphs, n_rows),
                                                       clusters=row_clusters(graphs, prob.pose_times, n_rows))
            # (the offsets fitted with the path keep the joint step taken before the head profile's
            # choice; the next step's joint solve settles them under it)
            step.local = local
            _log(progress, f"head point shift against distance: {compared}")
            names, full_step = [n.name for n in nuis], step
            theta = np.array([getattr(prob, n) for n in names], float)
        if spread and not chord:
            # the departures' prior sigma from the data (pedcal.calib.headpoint), once per solve
            spread = False
            step, nuis, spread_rec = estimate_departure_spread(prob, step, nuis, theta,
                                                               use=rec.head_shift_per_sensor_sigma_estimate)
            prob.departure_spread = spread_rec
            _log(progress, f"head point spread between the sensors' trackers: {spread_rec}")
        if not chord:       # the residuals the clock offsets' overdispersion is taken from (pedcal.calib.clocks)
            reference = (step, theta.copy()) if step.rho0 is not None else None
        # converged when the steps still to come are below ``tolerance`` sigma: with this step's
        # ratio theta to the last one (a contraction's rate), their geometric series,
        # theta / (1 - theta) of this step (the stopping rule of simplified Newton iterations,
        # Hairer & Wanner, Solving ODEs II, IV.8). A step along the last one and not much shorter
        # is a slow, linear, convergence (the robust kernel's weights, frozen in each
        # linearization, overstate the curvature of the factors it down-weights; a chord step's
        # Hessian is older still): it is extrapolated by 1 / (1 - theta) (at most 4x), theta then
        # its projection on the last step, and the next step's Hessian is taken afresh. Without a
        # last step to compare with (the first, or the one after an extrapolation, which is no
        # measure of the contraction) the step itself is the test, but not right after an
        # extrapolation; so it is for steps that swap sides of the optimum (the reweighting's
        # factors crossing the kernel's threshold and back), whose optimum lies within the step.
        u = step.dtheta / np.sqrt(np.diag(step.covariance))
        slow, rate, cos = False, None, 0.0
        same = previous_names == names
        if previous_u is not None and same and step.local is None:
            nu, npv = float(np.linalg.norm(u)), float(np.linalg.norm(previous_u))
            if npv > 0.0:
                rate = nu / npv
                cos = float(u @ previous_u) / (nu * npv) if nu > 0.0 else 0.0
                slow = cos > 0.9 and cos * rate > 0.3
                if slow:
                    rate = cos * rate
        if rate is not None and cos >= 0.0:
            converged = steps_to_come_below(u, rate, tolerance) is True
        elif rate is not None:      # (steps that swap sides of the optimum: it lies within this one)
            converged = bool(np.all(np.abs(u) <= tolerance))
        else:
            converged = not (n_step > 1 and extrapolated) and bool(np.all(np.abs(u) <= tolerance))
        extrapolated = slow and not converged and rate < 1.0
        if extrapolated:
            step.dtheta = step.dtheta * min(1.0 / (1.0 - rate), 4.0)
        previous_names = names
        if step.local is None:
            previous_u = None if extrapolated else u
        theta = theta + step.dtheta
        _log(progress, f"profile step {n_step}: " + ", ".join(
            f"{n} {_shown(n, v)} (step {_shown(n, d)}, sigma {_shown(n, s)})" for n, v, d, s in
            zip(names, theta, step.dtheta, np.sqrt(np.diag(step.covariance)), strict=True)))
        for name, v in zip(names, theta, strict=True):
            setattr(prob, name, float(v))
        motion_fresh = not odo          # (the odometry's block at the new corrections made when asked for)
        # the variables at the linearized optimum for the new shifts: z0 + Z dtheta
        delta = step.z0 + step.Z @ step.dtheta
        if step.local is not None:
            # (their step is the joint optimum's at the exact nuisances' step, after a selection
            # that dropped one, the curvature or the head profile's knots, at the kept ones')
            loc = step.local
            loc.dtheta = step.local_step()
            theta_local = theta_local + loc.dtheta
            for name, v in zip(local_names, theta_local, strict=True):
                setattr(prob, name, float(v))
            ratio = np.abs(loc.dtheta) / np.sqrt(loc.variance)
            # the same stopping rule on the whole step, the exact nuisances' and these (in their
            # sigmas), with its rate from the step before (every step with them a full one, none
            # extrapolated): the steps still to come, theta / (1 - theta) of this one, below
            # ``tolerance``; without a step to compare with, or not contracting, the step itself
            u_all = np.r_[u, loc.dtheta / np.sqrt(loc.variance)]
            before = np.linalg.norm(previous_u) if previous_u is not None and same else 0.0
            to_come = steps_to_come_below(u_all, np.linalg.norm(u_all) / before if before > 0.0 else None, tolerance)
            converged = to_come if to_come is not None else converged and bool(np.all(ratio <= tolerance))
            previous_u = u_all
            for kind, unit, mine in (("clock offsets", "ms", ~own_shift), ("head shift departures", "mm", own_shift)):
                if mine.any():
                    _log(progress, f"  {int(mine.sum())} {kind} (sigma per sensor given the path): median "
                                   f"{1000 * np.median(np.abs(theta_local[mine])):.1f} {unit}, median sigma "
                                   f"{1000 * np.median(np.sqrt(loc.variance[mine])):.1f} {unit}, largest step "
                                   f"{ratio[mine].max():.2f} sigma")
        result = retract_flat(result, delta, cols)
        if final_graph or not (converged or n_step == max_steps):
            block_terms = observation_terms(log, prob, result)
        if converged:
            break
    else:
        if max_steps > 1:
            _log(progress, f"profile steps stopped at {max_steps} before converging (last step above "
                           f"{tolerance} sigma)")
    if not np.all(np.linalg.eigvalsh(step.hessian) > 0.0):
        warnings.warn("the head point's shifts toward the sensor are not determined by the data (flat "
                      "profile); their prior is kept", DegenerateDataWarning, stacklevel=3)
    keys = [S(i) for i in range(len(prob.sensor_ids))] + ([H(0)] if result.exists(H(0)) else [])
    sens = step.Z[cols.index(keys)]
    cov, local = step.covariance, None
    if step.local is None and final_graph:
        # each clock offset's sigma widened by its residuals' scatter over time blocks (pedcal.calib.clocks;
        # not on a rough pass whose covariance the caller drops)
        cov, phi = widen_for_overdispersion(reference, nuis, np.array([getattr(prob, n) for n in names]), cov,
                                            prob.pose_times, prob.amcl_node_times)
        if np.isfinite(phi).any():
            _log(progress, f"clock offsets' overdispersion over {CLOCK_CLUSTER_S:.0f} s blocks: median "
                           f"{np.nanmedian(phi):.2f}, largest {np.nanmax(phi):.2f} (their sigma widened by its root)")
    if step.local is not None:
        k = len(names)
        cov = np.zeros((k + len(local_names),) * 2)
        cov[:k, :k] = step.covariance
        cov[np.arange(k, len(cov)), np.arange(k, len(cov))] = step.local.variance
        local = (local_sensors, step.local.Z)
    motion()
    if final_graph:
        block()
    elif built is not block_terms:
        # (a pass whose graph the caller rebuilds: the block left empty, not made)
        parts.blocks["observations"] = gtsam.NonlinearFactorGraph()
    return _Nuisances(parts.graph() if final_graph else None, result, cov, sens, n_step, names=names + local_names,
                       local=local,
                       unmodelled=None if unmodelled is None else (unmodelled[0], unmodelled[1][cols.index(keys)],
                                                                    unmodelled[2]),
                       considered=None if consider_s is None else (consider_sd, consider_s[cols.index(keys)]),
                       ordering=parts.colamd() if final_graph else None)


def _linearized(rhs: ObservationRhs, cols, block):
    """The observation block of ``rhs``'s terms linearized at ``rhs.values`` (those the terms were
    read at) as (A, b) in ``cols``: made from the terms (:meth:`ObservationRhs.linearized`), else
    GTSAM's linearization of ``block()`` (made of the same terms)."""
    made = rhs.linearized(cols)
    return made if made is not None else sparse_system(block().linearize(rhs.values), cols)


def _unmodelled_curvature(step, chi2: float):
    """What a head point curving with the viewing angle that the graph does not estimate would
    move: (the curvature the profile would give it, m, the variables' sensitivity to it (n,),
    chi^2), from a profile step that held it at 0."""
    H = step.hessian
    g = -H @ step.dtheta
    k = len(g) - 1
    cov = np.linalg.inv(H)
    dc = float(-(cov @ g)[k])            # its Newton step with the others re-optimized
    return dc, step.Z[:, k], chi2


def _select_curvature(step, nuis: list[Nuisance], threshold_chi2: float, estimate: bool = True):
    """The profile step with the head point's curvature (the last nuisance, at 0) kept when its
    chi^2 (the profile's decrease from estimating it, the others re-optimized) reaches
    ``threshold_chi2`` and ``estimate``, else the step of the others alone (its rows and
    columns dropped). Returns (step, nuisances, chi^2)."""
    H = step.hessian
    g = -H @ step.dtheta
    o = np.arange(len(nuis) - 1)
    chi2 = float(g @ np.linalg.solve(H, g) - g[o] @ np.linalg.solve(H[np.ix_(o, o)], g[o]))
    if estimate and chi2 >= threshold_chi2:
        return step, nuis, chi2
    reduced = step.select(o)
    reduced.dtheta = -np.linalg.solve(H[np.ix_(o, o)], g[o])
    return reduced, nuis[:-1], chi2


def robot_residuals(prob: FactorGraphProblem, result: gtsam.Values) -> np.ndarray:
    """(N, 3) normalized residuals of the robot observations at ``result``: two bearing
    components (across the ray, over the lateral sigma) and the range (over its sigma), each
    N(0, 1) if the noise model of the graph holds."""
    rec = prob.recipe
    n_pose = len(prob.pose_times)
    use = prob.fac_key_index < n_pose
    if not (rec.robot and use.any()):
        return np.zeros((0, 3))
    xk = pose_arrays(result, symbols("x", range(n_pose)))[1]
    idx = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    si = np.array([idx[s] for s in prob.fac_sensor[use]])
    R = np.stack([result.atPose3(S(i)).rotation().matrix() for i in range(len(prob.sensor_ids))])[si]
    t = np.stack([result.atPose3(S(i)).translation() for i in range(len(prob.sensor_ids))])[si]
    p_pred = np.einsum("nji,nj->ni", R, xk[prob.fac_key_index[use]] - t)
    p_meas = prob.head_points_sensor()[use]
    r_meas = np.linalg.norm(p_meas, axis=1)
    u = p_meas / r_meas[:, None]
    r_pred = np.linalg.norm(p_pred, axis=1)
    b1, b2 = ray_basis(u)
    u_pred = p_pred / r_pred[:, None]
    # one report's sigmas at the range as observed, over sqrt of the merged count, times the root
    # of the variance factor of that many correlated reports' mean (graph.merged_noise_factors)
    count = prob.fac_count[use]
    g_lateral, g_depth = merged_noise_factors(prob.noise_estimate, count)
    sig = (observation_sigmas(rec, np.linalg.norm(prob.fac_p_sensor[use], axis=1)) / np.sqrt(count)[:, None]
           * np.sqrt(np.column_stack([g_lateral, g_lateral, g_depth])))
    return np.column_stack([np.sum(u_pred * b1, axis=1) / sig[:, 0], np.sum(u_pred * b2, axis=1) / sig[:, 1],
                            (r_pred - r_meas - prob.ray_shift_m) / sig[:, 2]])


def _groups(index: np.ndarray, n: int):
    """(i, rows where index == i) for i in range(n), by one sort."""
    order = np.argsort(index, kind="stable")
    bounds = np.searchsorted(index[order], np.arange(n + 1))
    for i in range(n):
        yield i, order[bounds[i]:bounds[i + 1]]


def group_medians(values: np.ndarray, index: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """((n, k) each group's column medians, (n,) its row count) of ``values`` (m, k) grouped by
    ``index`` (m,) in 0..n-1, by one sort for every group, each median what ``np.median(values[rows],
    axis=0)`` gives to the bit (the middle value, or the two middle ones' sum over 2; NaN in a
    column with a NaN, and for a group without rows)."""
    values = np.asarray(values, float)
    values = values[:, None] if values.ndim == 1 else values
    index = np.asarray(index, np.int64)
    count = np.bincount(index, minlength=n)[:n] if len(index) else np.zeros(n, np.int64)
    start = np.r_[0, np.cumsum(count)[:-1]]
    lo, hi = start + np.maximum(count - 1, 0) // 2, start + count // 2
    out = np.full((n, values.shape[1]), np.nan)
    has = count > 0
    for c in range(values.shape[1]):
        col = values[:, c]
        v = col[np.lexsort((col, index))]          # (each group's rows in order, NaN last)
        if not len(v):
            continue
        a, b = v[lo[has]], v[hi[has]]
        out[has, c] = np.where(lo[has] == hi[has], a, (a + b) / 2.0)
        nan = np.bincount(index, np.isnan(col), minlength=n)[:n] > 0
        out[nan, c] = np.nan
    return out, count


def model_check(prob: FactorGraphProblem, result: gtsam.Values, threshold: float = 1.5) -> ModelMismatch:
    """Residuals against the noise model, per sensor: the robust variance ratio (median of the
    squared normalized residuals over the chi-square(1) median 0.455, averaged over the three
    components; 1 when the model holds, robust to the mis-associations the kernel rejects, not
    to a bias), and the sensors whose ratio exceeds ``threshold``."""
    z = robot_residuals(prob, result)
    rec = prob.recipe
    n_pose = len(prob.pose_times)
    sensor_i = prob.fac_sensor_index[prob.fac_key_index < n_pose] if rec.robot else np.zeros(0, int)
    med, count = group_medians(z ** 2, sensor_i, len(prob.sensor_ids))
    ratio = {prob.sensor_ids[i]: float(np.mean(med[i]) / 0.4549) for i in np.flatnonzero(count >= 10).tolist()}
    bad = {sid: r for sid, r in ratio.items() if r > threshold}
    return ModelMismatch(variance_ratio=ratio, threshold=threshold, sensors=sorted(bad),
                         misfit=(f"{len(bad)} of {len(ratio)} sensors' residuals exceed the noise model: "
                                 + ", ".join(f"{sid} x{np.sqrt(r):.2f} sigma" for sid, r in sorted(bad.items()))
                                 if bad else ""))


def _held_graph(log: Log, prob: FactorGraphProblem, parts: GraphParts, fg):
    """The graph the sensors' covariance is read from: ``fg`` itself, or, where AMCL's model was
    solved with the data's wandering part and holds the one AMCL's reported std allows beside it
    (recipe ``amcl_reported_floor = "consider"``: :meth:`AmclErrorModel.held`), ``fg`` with its
    AMCL block built under the held one (the same nodes and keys). The residuals cannot show
    AMCL's error averaged over a sensor's view (the sensor's pose absorbs it), so the data's
    wander may be too small; the estimate takes the data's weights, the sigma the held model's
    (about what the graph solved under "hold" would report for the same data: read at the other
    solution, with the nuisances' shares from the solved model). The sensors' marginals from it
    also decide which directions the data leave unconstrained (:func:`_posterior`'s given
    covariance, pedcal.calib.readback), so a sensor barely seen may be reset to its installed
    pose along a direction the solved graph alone would have kept."""
    held = prob.amcl_model.held() if prob.amcl_model is not None and prob.recipe.amcl else None
    if held is None or not len(prob.pose_times):
        return fg
    solved, prob.amcl_model = prob.amcl_model, held
    try:
        block = gtsam.NonlinearFactorGraph()
        _amcl_block(block, gtsam.Values(), log, prob, prob.pose_times)
    finally:
        prob.amcl_model = solved
    return parts.graph(amcl=block)


def _posterior(log: Log, prob: FactorGraphProblem, fg, result, shifts: _Nuisances | None):
    """The sensors' covariance: the joint marginal of every sensor pose (and the head model's
    vertical offset) from the graph, plus the ray shift's share (its sigma times the sensors'
    sensitivity), each sensor's rows widened by the square root of its residuals' variance ratio
    where that exceeds 1. Returns (per-sensor body covariance, the graph's own per-sensor marginal
    given the nuisances (what the data constrain), the joint world-axes position covariance, the
    head model, the model check)."""
    rec = prob.recipe
    n = len(prob.sensor_ids)
    keys = [S(i) for i in range(n)] + ([H(0)] if result.exists(H(0)) else [])
    has_h = result.exists(H(0))
    joint = n <= readback.JOINT_COV_MAX_SENSORS
    if joint:
        C = joint_marginal_covariance(fg, result, keys)
        blocks = [C[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(len(keys))]
    else:
        # hundreds of sensors: each one's marginal (a dense joint inverse would take minutes), by
        # selected inversion of one sparse factorization (GTSAM's Marginals re-eliminates a
        # key's whole clique for each key: quadratic in the sensors)
        # (the graph's COLAMD ordering that the solve computed: ``fg`` is the profile's graph or its
        # held copy (_held_graph), of the same variables; marginal_covariances checks them)
        ordering = shifts.ordering if shifts is not None else None
        blocks = marginal_covariances(fg, result, keys, ordering=ordering)
    # (what the data constrain is read from the graph's own marginal, given the nuisances: their
    # shares below widen a sensor's sigma, they do not make a direction unconstrained)
    cov_given = {sid: blocks[i].copy() for i, sid in enumerate(prob.sensor_ids)}   # (views of C: copied)
    extra = []                                 # (sensitivity (6 len(keys),), k x k covariance) terms
    if shifts is not None:
        k = shifts.sensitivity.shape[1]
        extra.append((shifts.sensitivity, shifts.cov[:k, :k]))
        if shifts.local is not None:
            # each locally fitted offset's share of its own sensor alone: Z_i sigma_i^2 Z_i^T
            sensor, Z_local = shifts.local
            var = np.diag(shifts.cov)[k:]
            share = var[:, None, None] * Z_local[:, :, None] * Z_local[:, None, :]
            for i, s in zip(sensor, share, strict=True):
                blocks[i] = blocks[i] + s
                if joint:
                    C[6 * i:6 * i + 6, 6 * i:6 * i + 6] += s
        if shifts.unmodelled is not None:
            # the model does not fit: the sensors widened by the move the misfit's own fix would make
            dc, sens_c, _ = shifts.unmodelled
            extra.append((sens_c[:, None], np.array([[dc ** 2]])))
        if shifts.considered is not None:
            # the shift against distance held at 0, its prior carried (a consider parameter): under
            # a wandering AMCL the path's scale follows the views' radial scale, which it sets
            sd, sens_s = shifts.considered
            extra.append((sens_s[:, None], np.array([[sd ** 2]])))
    for sens, cov in extra:
        sens = sens[:6 * len(keys)]
        if joint:
            C = C + sens @ cov @ sens.T
        blocks = [b + sens[6 * i:6 * i + 6] @ cov @ sens[6 * i:6 * i + 6].T for i, b in enumerate(blocks)]
    check = model_check(prob, result)
    if shifts is not None and shifts.unmodelled is not None:
        dc, _, chi2 = shifts.unmodelled
        check.head_model_misfit = (f"the head point's height curves with the viewing angle (chi^2 {chi2:.0f}, "
                                   f"{1000 * dc:+.0f} mm x cos^2(elevation)), which the head model leaves out; the "
                                   "sensors' sigma carries what estimating it would move them by "
                                   "(head_curvature = \"auto\" estimates it)")
        check.misfit = "; ".join(m for m in (check.misfit, check.head_model_misfit) if m)
    scale = np.array([np.sqrt(max(1.0, check.variance_ratio.get(sid, 1.0))) for sid in prob.sensor_ids])
    cov_body = {sid: blocks[i] * scale[i] ** 2 for i, sid in enumerate(prob.sensor_ids)}
    joint_pos = None
    if joint:
        # world-axes positions: each sensor's translation block rotated by its R, widened by its scale
        R = np.stack([result.atPose3(S(i)).rotation().matrix() for i in range(n)])
        Ct = C[:6 * n, :6 * n].reshape(n, 6, n, 6)[:, 3:, :, 3:] * np.outer(scale, scale)[:, None, :, None]
        joint_pos = np.einsum("iab,ibjc,jdc->iajd", R, Ct, R).reshape(3 * n, 3 * n)
    if rec.sensor_height_sigma_m > 0.0:
        reference = "ceiling height" if rec.ceiling_height_m > 0.0 else "installed sensor heights"
    else:
        reference = "none"
    head = HeadModel(vertical_offset_m=-rec.head_radius_m, ray_shift_m=prob.ray_shift_m,
                     horizontal_shift_m=prob.horizontal_shift_m, curvature_m=prob.curvature_m,
                     height_reference=reference, estimated=bool(rec.estimate_head_model))
    if has_h:
        head.vertical_offset_m = float(-rec.head_radius_m + result.atPose3(H(0)).translation()[2])
        head.sigma_vertical_offset_m = float(np.sqrt(blocks[n][5, 5]))
    if shifts is not None:
        for name, sd in zip(shifts.names, np.sqrt(np.diag(shifts.cov)), strict=True):
            if name in ODOMETRY_NUISANCES:
                _record_odometry_correction(prob.odometry_estimates, name, getattr(prob, name), float(sd))
            elif not (is_clock_nuisance(name) or is_head_profile(name)):
                setattr(head, "sigma_" + name, float(sd))
    if has_h and reference == "none":
        head.note = (HEAD_HEIGHT_DEGENERACY + " Its prior is a dome's (offset = -shift) give or take "
                        f"{1000 * rec.head_vertical_sigma_m:.0f} mm, a sigma the sensors' heights carry, "
                        "shared by all of them.")
        warnings.warn("the head point's vertical offset cannot be told from the sensors' common height by "
                      "the robot alone: the sensors' vertical sigma carries its prior "
                      f"({1000 * rec.head_vertical_sigma_m:.0f} mm). {head_depth_note(rec.head_vertical_sigma_m)} "
                      "(A height reference: --sensor-height-sigma or --ceiling-height.)",
                      DegenerateDataWarning, stacklevel=3)
    return cov_body, cov_given, joint_pos, head, check


def _record_odometry_correction(est: dict, name: str, value: float, sigma: float) -> None:
    """The calibration's estimate in ``est`` (pedcal.calib.graph.calibrate_odometry's keys) with
    the graph's correction applied, and the correction's sigma beside it."""
    if name == "odometry_scale_correction":
        base = est.get("scale", 1.0)
        est["scale"], est["sigma_scale"] = base * (1.0 + value), base * sigma
    else:
        key = "yaw_drift_deg_per_m" if name.endswith("_per_m") else "yaw_drift_deg_per_s"
        est[key] = est.get(key, 0.0) + float(np.degrees(value))
        est["sigma_" + key] = float(np.degrees(sigma))
    est["source"] = "calibrated against AMCL, corrected in the graph"


def _count_held(values: gtsam.Values, char: str, n: int) -> int:
    """How many of the symbols ``char``(0) .. ``char``(n - 1) ``values`` holds."""
    chars, index = symbol_parts(np.asarray(values.keys(), np.uint64))
    return int(np.count_nonzero((chars == np.uint64(ord(char))) & (index < np.uint64(max(n, 0)))))


def graph_keys(prob: FactorGraphProblem, result: gtsam.Values) -> GraphKeys:
    """Which symbol of the solved graph is which variable (CalibrationResult.keys)."""
    # (the values' keys read once, not one lookup per pose)
    n_pose = _count_held(result, "x", len(prob.pose_times))
    n_amcl = _count_held(result, "a", len(prob.amcl_node_times))
    people = [m for m in range(len(prob.people)) if result.exists(L(m))]
    return GraphKeys(sensors={sid: S(i) for i, sid in enumerate(prob.sensor_ids)},
                     robot_poses=symbols("x", range(n_pose)).tolist(), robot_pose_times=prob.pose_times[:n_pose],
                     amcl_errors=symbols("a", range(n_amcl)).tolist(), amcl_error_times=prob.amcl_node_times[:n_amcl],
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
