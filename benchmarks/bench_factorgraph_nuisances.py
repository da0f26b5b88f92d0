"""The factor graph against the grid search on logs whose nuisance models it does not assume:
every seed draws its head-point model, AMCL error, odometry, latency and depth noise from the
simulator's zoo (``simulate_logs(..., vary_nuisances=True)``, ``pedcal simulate --vary-nuisances``);
with ``--zoo`` also the zoo's further families (head points that ramp or saturate with distance,
one per sensor, that sink as heads are seen from the side, per-sensor clocks, mixed heights and
wall mounts, relocalizations:
``--vary-nuisances zoo``), and the figures split by family.

    nice -n 10 .venv/bin/python benchmarks/bench_factorgraph_nuisances.py \
        [--scenarios paper sparse corridor cross] [--seeds 20] [--first-seed 0] [--jobs 1] [--zoo] [--verbose]
        [--recipe KEY=VALUE ...]     # graph recipe fields, e.g. head_shift_per_sensor_sigma_m=0
        [--only FAMILY=VALUE ...]    # with --zoo: only seeds whose zoo drew these, e.g. head=top
        [--off FAMILY ...]           # those seeds' logs with these nuisances switched off (paired)
        [--save FILE] [--from-results FILE]   # keep the per-log results; print an earlier run's

Per scenario (means over seeds): sensor position RMS of the factor graph and of the grid search
(3-D and horizontal, mm; evaluated on the evaluation log, pedcal.metrics.evaluate), each with the
sensors it missed in brackets (not evaluated, or without a finite error: left out of its RMS,
which alone would reward a miss; '?' for runs saved before they were counted), their ratio;
the norm of AMCL's error averaged over the calibration run (the error every calibration anchored
to AMCL shares, from the simulator's truth) and each method's horizontal RMS with it taken out,
and with the best common 2-D rigid transform of the whole network taken out (Kabsch: the
network's internal geometry apart from its anchoring to AMCL, which that transform holds);
the fraction of per-axis errors (x, y, z world axes, every sensor of every seed) within 1 and 2
reported sigma; the RMS of the horizontal errors over their sigma, split into what the sensors
share (their mean, whose sigma the joint covariance gives) and the rest (1 when the sigma is
right); the head-model error: over the robot's sightings in the calibration run, the RMS of
(estimated - simulated) head-point offset from the head top, after removing the mean vertical
part (which the robot cannot tell from the sensors' heights), its RMS over seeds and its worst
seed, and the RMS of that mean vertical part; the factor graph's calibrate() wall and CPU time;
the worst log's horizontal RMS and graph / grid ratio, and how many logs meet <= 12 mm and
<= 0.35x the grid search horizontally. With ``--zoo``, per family of each nuisance (head, clock,
mounts, AMCL, tracker noise, robot stops, head sink):
logs, horizontal RMS mean and worst (the graph's sensors missed beside it), graph /
grid (the grid search's sensors missed beside it), and the per-sensor clock
offsets' error about their mean (RMS) and the share within 1 and 2 sigma (the sigma's honesty per
family is in the table below).
On the L-shaped hall, each wing's mean error along x and y over its sigma (the wings share no
view: the robot's path and AMCL join them).

The sigma's honesty, per scenario, all pooled and (with ``--zoo``) per family: the share of
per-axis errors within 1 sigma and the RMS of |error| / sigma (1 when honest; below 1 a sigma
too wide, which the share alone would reward), x, y, z, each with its 90 % interval from a
bootstrap over the seeds (seeded; ``pedcal.metrics.sigma_honesty``): a log's sensors share one
draw of AMCL's error and of the head point, and a seed's logs in every scenario share its zoo
draw and much of AMCL's, so a figure of few seeds is uncertain however many sensors it pools,
and the interval says how much (none is claimed below 3 seeds); beside them the sensors pooled
and, in brackets, those missed (not calibrated, without a sigma or left out: outside any sigma
for the share, left out of the RMS, so a method that drops sensors shows it there). Beside it,
per group: AMCL's run-mean error (the truth) against the graph's AMCL model's sigma of it, and
the error over sigma of the sensors' common error and of the rest; and the network's stretch
along x and y (mm/m, :func:`stretch_fit`) against its sigma.
"""

from __future__ import annotations

import argparse
import pickle
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from pedcal.calib import calibrate
from pedcal.calib.common import interpolate_pose2
from pedcal.metrics import (
    CLOCK_OFFSET_KEY,
    SIGMA_CLOCK_OFFSET_KEY,
    amcl_run_mean_error_m,
    evaluate,
    format_clustered,
    robot_rows,
    sigma_honesty,
    sigma_ratio_rms,
    within_sigma_share,
)
from pedcal.sim import load_scenario, simulate_logs
from pedcal.sim.nuisances import (
    HEAD_KINDS,
    OFF_FAMILIES,
    head_model_truth,
    head_point,
    sensor_clocks,
    sensor_head_models,
    switch_off,
    vary,
    zoo_families,
)
from pedcal.sim.scenario import CHOICES

# Each family pedcal.sim.nuisances.zoo_families names, with the values the zoo can draw for it
# (--only FAMILY=VALUE, the figures split by family): the head point the same for every sensor
# (any kind) or one per sensor; AMCL's classic draws or the zoo's relocalizations; the tracker's
# noise white or correlated frame to frame.
ZOO_FAMILY_VALUES = {"head": ("per-sensor", *HEAD_KINDS), "clock": ("shared", "offsets", "skew"),
                     "mounts": ("ceiling", "mixed", "wall"), "amcl": (*CHOICES["amcl_error"], "relocalization"),
                     "tracker noise": ("white", "correlated"), "robot stops": ("none", "stops"),
                     "head sink": ("none", "sinks")}


def head_model_error_mm(sim, head) -> tuple[float, float]:
    """(RMS of the head-point offset error with its mean vertical part removed, that mean
    vertical part), mm, over the robot's sightings of the calibration log."""
    log, sc = sim.calib, sim.scenario
    mask, _ = robot_rows(log)
    sensors = log.observations["sensor"].astype(str).to_numpy()[mask]
    index = {sid: k for k, sid in enumerate(log.truth.ids)}
    k_sensor = np.array([index[sid] for sid in sensors], dtype=int)
    offset, _ = sensor_clocks(sc, len(log.truth))
    t = log.observations["t"].to_numpy(float)[mask] - sc.latency_s - offset[k_sensor]
    pose = interpolate_pose2(log.truth_robot, t)
    off = np.asarray(sc.head_offset_m, float)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    top = np.column_stack([pose[:, 0] + c * off[0] - s * off[1], pose[:, 1] + s * off[0] + c * off[1],
                           np.full(len(t), off[2])])
    sensor_pos = np.stack([log.truth[sid].position_m for sid in sensors])
    true_off = np.zeros_like(top)
    for k, model in enumerate(sensor_head_models(sc, len(log.truth))):
        mine = k_sensor == k
        true_off[mine] = head_point(top[mine], sensor_pos[mine], model) - top[mine]
    q = top + np.array([0.0, 0.0, head.vertical_offset_m])
    u = sensor_pos - q
    u_h = np.column_stack([u[:, :2], np.zeros(len(u))])
    u_h /= np.maximum(np.linalg.norm(u_h, axis=1, keepdims=True), 1e-9)
    cos2 = np.sum(u[:, :2] ** 2, axis=1) / np.sum(u ** 2, axis=1)
    est_off = (q - top + head.ray_shift_m * u / np.linalg.norm(u, axis=1, keepdims=True)
               + head.horizontal_shift_m * u_h + head.curvature_m * cos2[:, None] * np.array([0.0, 0.0, 1.0]))
    d = est_off - true_off
    dz = float(d[:, 2].mean())
    d[:, 2] -= dz
    return float(1000 * np.sqrt(np.mean(np.sum(d ** 2, axis=1)))), 1000 * dz


def finite_rms(x: np.ndarray) -> float:
    """The RMS of the finite values of ``x`` (a miss, NaN, is counted by the shares within sigma
    instead); NaN without any."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")


def clock_offset_errors(sim, network) -> tuple[np.ndarray, np.ndarray]:
    """Each estimated clock offset's error (s) about the offsets' mean, the truth's taken about
    its own mean, and that error over its sigma; empty when the log has no clock offset (a
    calibration that estimates none gets a NaN miss for every sensor).
    A skewed clock's offset is taken at the mean time of its sensor's robot sightings in the
    calibration run, what a constant offset fitted to them estimates (the simulator stamps
    offset + skew x (t - start); at 50 ppm, a sensor that saw the robot a minute from the run's
    middle is 3 ms off the middle's offset)."""
    log = sim.calib
    offset, skew_ppm = sensor_clocks(sim.scenario, len(log.truth))
    mask, _ = robot_rows(log)
    t_obs = log.observations["t"].to_numpy(float)[mask]
    sensor_obs = log.observations["sensor"].astype(str).to_numpy()[mask]
    t = log.robot["t"].to_numpy(float)
    for k, sid in enumerate(log.truth.ids):
        mine = sensor_obs == sid
        t_seen = float(t_obs[mine].mean()) if mine.any() else 0.5 * (t.min() + t.max())
        offset[k] += 1e-6 * skew_ppm[k] * (t_seen - sim.scenario.start_time_s)
    est, sigma = network.extra.get(CLOCK_OFFSET_KEY) or {}, network.extra.get(SIGMA_CLOCK_OFFSET_KEY) or {}
    if not np.any(offset):
        return np.zeros(0), np.zeros(0)
    # every sensor of the truth: one whose offset was not estimated is a NaN error, a miss (never
    # within any sigma, left out of the error RMS), so that a method does not look better for
    # dropping the clocks it cannot fit; the truth is taken about its mean over the estimated ones
    ids = list(sim.calib.truth.ids)
    est_s = np.array([est.get(sid, np.nan) for sid in ids], float)
    known = np.isfinite(est_s)
    err = est_s - (offset - (offset[known].mean() if known.any() else 0.0))
    # (an offset without its sigma is a miss: NaN, never within any sigma)
    return err / np.maximum([sigma.get(sid, np.nan) for sid in ids], 1e-9), err


def wing_z(sim, network, joint_cov_m2: np.ndarray | None) -> dict:
    """On the L-shaped hall, each wing's mean error along x and y over its sigma (from the joint
    position covariance): {"x wing": (z_x, z_y), "y wing": (z_x, z_y)}; empty on other layouts.
    The two wings share no view, so what joins them is the robot's path and AMCL."""
    sc = sim.scenario
    if sc.layout != "lhall" or joint_cov_m2 is None:
        return {}
    ids = list(network.ids)
    E = np.array([network[sid].position_m - sim.calib.truth[sid].position_m for sid in ids])
    in_y_wing = np.array([sim.calib.truth[sid].position_m[0] > sc.area_m[0] - sc.corridor_width_m - 0.5
                          for sid in ids])
    out = {}
    for name, m in (("x wing", ~in_y_wing), ("y wing", in_y_wing)):
        z = []
        for axis in (0, 1):
            w = np.zeros(3 * len(ids))
            w[3 * np.flatnonzero(m) + axis] = 1.0 / m.sum()
            z.append(float(E[m, axis].mean() / np.sqrt(w @ joint_cov_m2 @ w)))
        out[name] = tuple(z)
    return out


def rigid_residual_rms_mm(est_xy: np.ndarray, true_xy: np.ndarray) -> float:
    """RMS (mm) of the horizontal errors left after the best common 2-D rigid transform (a turn
    and a shift, least squares) of the estimated network onto the truth: the network's internal
    geometry apart from its anchoring to the map (which the transform takes up). The Kabsch
    solution: the turn from the SVD of the centred cross-covariance, a reflection excluded."""
    est, true = np.asarray(est_xy, float), np.asarray(true_xy, float)
    if len(est) < 2:
        return float("nan")
    a, b = est - est.mean(axis=0), true - true.mean(axis=0)
    U, _, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, d]) @ U.T             # R a ~ b
    return float(1000 * np.sqrt(np.mean(np.sum((a @ R.T - b) ** 2, axis=1))))


def _xy_block(joint_cov_m2: np.ndarray, rows) -> np.ndarray:
    """The x and y rows and columns of the joint position covariance (3 N, 3 N) for the sensors at
    ``rows`` of the network, in that order, x and y per sensor: (2 n, 2 n)."""
    idx = (3 * np.asarray(rows, int)[:, None] + [0, 1]).ravel()
    return joint_cov_m2[np.ix_(idx, idx)]


def _ls_fit(E_xy_m: np.ndarray, joint_cov_m2: np.ndarray | None, A: np.ndarray,
            rows) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal errors ``E`` (n, 2) fitted by least squares by the columns of ``A`` (2 n, k,
    x and y per sensor): the coefficients L e (L = pinv(A)) and their sigma sqrt(diag(L C L^T)),
    C the joint position covariance's block of the sensors at ``rows`` (:func:`_xy_block`); NaN
    sigma without the covariance."""
    L = np.linalg.pinv(A)
    coef = L @ np.asarray(E_xy_m, float).ravel()
    if joint_cov_m2 is None:
        return coef, np.full(len(coef), np.nan)
    return coef, np.sqrt(np.diag(L @ _xy_block(joint_cov_m2, rows) @ L.T))


def projected_z(E_xy_m: np.ndarray, joint_cov_m2: np.ndarray, A: np.ndarray,
                rows) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal errors ``E`` (n, 2) split into the motions of the network that ``A`` (2 n, k)
    spans (least squares, x and y per sensor: :func:`_ls_fit`) and the rest, each over its sigma
    from the joint position covariance (3 N, 3 N, the network's N sensors): (k,) and (2 n,)
    ratios, N(0, 1) when the covariance is right. ``rows`` (n,): each error's sensor's position
    in the network (the covariance's 3x3 block), so that the caller may leave sensors out (not
    calibrated: the prior's sigma would drown the shared motion; without an error)."""
    coef, sigma = _ls_fit(E_xy_m, joint_cov_m2, A, rows)
    C = _xy_block(joint_cov_m2, rows)
    R = np.eye(2 * len(E_xy_m)) - A @ np.linalg.pinv(A)
    return coef / sigma, (R @ E_xy_m.ravel()) / np.sqrt(np.diag(R @ C @ R.T))


def shared_and_rest_z(E_xy_m: np.ndarray, joint_cov_m2: np.ndarray | None, rows) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal errors split into what the sensors share (their mean, x and y) and the rest
    (each sensor's departure from it), each over its sigma (:func:`projected_z`; ``rows`` the
    sensors' positions in the network). Empty without the joint covariance."""
    n = len(E_xy_m)
    if joint_cov_m2 is None or n < 2:
        return np.zeros(0), np.zeros(0)
    return projected_z(E_xy_m, joint_cov_m2, np.kron(np.ones((n, 1)), np.eye(2)), rows)


def error_sigma_ratios(ev, network) -> np.ndarray:
    """(n_sensors + missing, 3) each sensor's |error| on each world axis over its reported sigma
    (:func:`sigma_ratios`: a miss is inf), from an evaluation ``ev`` of ``network``."""
    return sigma_ratios(network, [s.id for s in ev.sensors],
                        [np.asarray(s.position_error_mm, float) / 1000.0 for s in ev.sensors],
                        missing=len(ev.missing_sensors))


def calibrated_with_error(ev, network) -> tuple[list, list[int]]:
    """The evaluated sensors ``network`` calibrated (status ok) whose error is finite, and each
    one's row in the network (its place in the joint covariance)."""
    row_of = {sid: r for r, sid in enumerate(network.ids)}
    kept = [s for s in ev.sensors
            if (network[s.id].status or "ok") == "ok" and np.all(np.isfinite(s.position_error_mm))]
    return kept, [row_of[s.id] for s in kept]


def shared_rest_parts(ev, network, joint_cov_m2) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shared_and_rest_z` over the sensors :func:`calibrated_with_error` keeps: (2,) their
    mean horizontal error over its sigma and each one's departure over its (flat, x y per
    sensor); empty without the joint covariance or with fewer than 2."""
    kept, rows = calibrated_with_error(ev, network)
    return shared_and_rest_z(np.array([s.position_error_mm[:2] for s in kept], float).reshape(-1, 2) / 1000.0,
                             joint_cov_m2, rows)


def stretch_fit(E_xy_m: np.ndarray, true_xy_m: np.ndarray, joint_cov_m2: np.ndarray | None,
                rows) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal errors ``E`` (n, 2) fitted (least squares) by a common shift and a stretch
    along each axis about the sensors' middle, e_x = c_x + s_x (x - mean x), e_y likewise: the
    coefficients (c_x, c_y in m; s_x, s_y in m/m) and their sigma from the joint position
    covariance (``rows``: each sensor's place in it, as in :func:`projected_z`); NaN sigma
    without the covariance. A head point whose shift toward the sensor changes with distance
    scales each view radially, which shows as a stretch."""
    n = len(E_xy_m)
    d = np.asarray(true_xy_m, float) - np.mean(true_xy_m, axis=0)
    A = np.zeros((2 * n, 4))
    A[0::2, 0] = A[1::2, 1] = 1.0
    A[0::2, 2], A[1::2, 3] = d[:, 0], d[:, 1]
    return _ls_fit(E_xy_m, joint_cov_m2, A, rows)


def sigma_ratios(network, ids, abs_err_m: np.ndarray, missing: int = 0, axes: int = 3) -> np.ndarray:
    """(len(ids) + missing, axes) each sensor's |error| over its reported sigma per world axis
    (the first ``axes`` of x, y, z: ``abs_err_m`` is (n, axes)); inf for a miss, not a padding: a
    sensor not calibrated (status not ok: its sigma the prior's, wide enough to hold any error),
    without a sigma or an error, or left out of the result altogether (``missing`` of them)."""
    err = np.abs(np.asarray(abs_err_m, float)).reshape(len(ids), axes)
    k = axes
    out = np.full((len(ids) + missing, k), np.inf)
    for r, sid in enumerate(ids):
        ext = network[sid]
        if ext.sigma_position_m is not None and (ext.status or "ok") == "ok" and np.all(np.isfinite(err[r])):
            out[r] = err[r] / np.asarray(ext.sigma_position_m, float)[:k]
    return out


def run_one(scenario: str, seed: int, zoo: bool = False, recipe: dict | None = None, off: tuple = ()) -> dict:
    warnings.simplefilter("ignore")
    # the seed's draw (simulate_logs(..., vary_nuisances=True or "zoo")) with the ``off`` families
    # made ideal, every other draw as it was (paired); without ``off`` the draw itself
    sc = switch_off(vary(load_scenario(scenario).resolve(seed=seed), zoo=zoo), off)
    sim = simulate_logs(sc, seed=seed)
    out = dict(scenario=scenario, seed=seed, nuisances=head_model_truth(sim.scenario),
               families=zoo_families(sim.scenario),
               amcl=sim.scenario.amcl_error, odometry=sim.scenario.odometry, latency_s=sim.scenario.latency_s,
               depth=sim.scenario.depth_noise_model,
               amcl_mean_xy_mm=float(1000 * np.linalg.norm(amcl_run_mean_error_m(sim.calib))))
    for method in ("factorgraph", "gridsearch"):
        w0, c0 = time.perf_counter(), time.process_time()
        res = calibrate(sim.calib, method=method, **((recipe or {}) if method == "factorgraph" else {}))
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        ev = evaluate(sim.eval, res.network)
        finite = [s.id for s in ev.sensors if np.all(np.isfinite(s.position_error_mm))]
        E = np.array([s.position_error_mm for s in ev.sensors if np.all(np.isfinite(s.position_error_mm))])
        # the horizontal error less what every sensor shares with AMCL's run average (which no
        # calibration anchored to AMCL can remove): what the method itself controls
        rel = E[:, :2] - 1000 * amcl_run_mean_error_m(sim.calib)
        out[method] = dict(rms_mm=float(np.sqrt(np.mean(np.sum(E ** 2, axis=1)))),
                           rms_xy_mm=float(np.sqrt(np.mean(np.sum(E[:, :2] ** 2, axis=1)))),
                           rms_rel_mm=float(np.sqrt(np.mean(np.sum(rel ** 2, axis=1)))),
                           rms_rigid_mm=rigid_residual_rms_mm(
                               np.array([res.network[sid].position_m[:2] for sid in finite]),
                               np.array([sim.eval.truth[sid].position_m[:2] for sid in finite])),
                           wall_s=wall, cpu_s=cpu,
                           # sensors left out of the RMS: not in the extrinsics, or without a finite error
                           missed=len(ev.missing_sensors) + len(ev.sensors) - len(finite))
        if method == "factorgraph":
            out["ratios"] = error_sigma_ratios(ev, res.network)
            # signed errors and sigma (m, world axes) for a diagnosis from --save's file
            out["error_m"] = np.array([s.position_error_mm for s in ev.sensors], float).reshape(-1, 3) / 1000.0
            out["sigma_m"] = np.array([res.network[s.id].sigma_position_m if res.network[s.id].sigma_position_m
                                       is not None else [np.nan] * 3 for s in ev.sensors], float).reshape(-1, 3)
            out["amcl_mean_m"] = amcl_run_mean_error_m(sim.calib)
            out["ids"] = [s.id for s in ev.sensors]
            out["true_m"] = np.array([sim.eval.truth[s.id].position_m for s in ev.sensors], float).reshape(-1, 3)
            model = res.diagnostics.amcl_error_model
            if model is not None:
                t = sim.calib.robot["t"].to_numpy(float)
                out["amcl_model"] = dict(white_m=model.white_sigma_m, correlated_m=model.correlated_sigma_m,
                                         correlation_s=model.correlation_s, source=model.source,
                                         # (the model the sigma is read with: the held one, where it holds one)
                                         floor_m=(model.held() or model).floor_sigma_m(float(t.max() - t.min())),
                                         duration_s=float(t.max() - t.min()))
            # only calibrated sensors with an error, each with its own block of the covariance
            out["z_shared"], out["z_rest"] = shared_rest_parts(ev, res.network, res.position_covariance_m2)
            kept, rows = calibrated_with_error(ev, res.network)
            if res.position_covariance_m2 is not None and len(kept) >= 3:
                out["stretch"] = stretch_fit(np.array([s.position_error_mm[:2] for s in kept]) / 1000.0,
                                             np.array([sim.eval.truth[s.id].position_m[:2] for s in kept]),
                                             res.position_covariance_m2, rows)
            out["head_shape_mm"], out["head_dz_mm"] = head_model_error_mm(sim, res.diagnostics.head_model)
            out["mismatch"] = len(res.diagnostics.model_mismatch.sensors)
            out["clock_z"], out["clock_err_s"] = clock_offset_errors(sim, res.network)
            out["wings"] = wing_z(sim, res.network, res.position_covariance_m2)
    return out


def recipe_overrides(items: list[str], ap: argparse.ArgumentParser) -> dict:
    """KEY=VALUE items as graph recipe fields, each value read as its field's default's type."""
    from pedcal.calib.recipe import GraphRecipe

    defaults, out = GraphRecipe(), {}
    for item in items:
        key, _, value = item.partition("=")
        if not hasattr(defaults, key):
            ap.error(f"--recipe {item}: no graph recipe field '{key}'")
        default = getattr(defaults, key)
        try:
            if isinstance(default, bool):
                if value not in ("true", "false"):
                    raise ValueError(value)
                out[key] = value == "true"
            else:
                out[key] = type(default)(value)
        except ValueError:
            ap.error(f"--recipe {item}: '{key}' takes a {type(default).__name__}")
    return out


def family_filter(items: list[str], ap: argparse.ArgumentParser) -> dict:
    """FAMILY=VALUE items (--only) as {family: value}, each family one of zoo_families' and each
    value one the zoo can draw for it (:data:`ZOO_FAMILY_VALUES`): a value it never draws is
    refused here, before any seed is drawn."""
    out = {}
    for item in items:
        family, _, value = item.partition("=")
        if family not in ZOO_FAMILY_VALUES or not value:
            ap.error(f"--only {item}: expected FAMILY=VALUE with FAMILY one of {', '.join(ZOO_FAMILY_VALUES)}")
        if value not in ZOO_FAMILY_VALUES[family]:
            ap.error(f"--only {item}: the zoo draws {family} as one of {', '.join(ZOO_FAMILY_VALUES[family])}")
        out[family] = value
    return out


def seeds_with(scenario: str, only: dict, first: int, count: int, limit: int = 5000) -> list[int]:
    """The first ``count`` seeds from ``first`` whose zoo draw (scenario resolved, no log
    simulated) falls in every family of ``only``; an error when ``limit`` seeds hold fewer."""
    base, out = load_scenario(scenario), []
    for seed in range(first, first + limit):
        if len(out) == count:
            break
        families = zoo_families(vary(base.resolve(seed=seed), zoo=True))
        if all(families[f] == v for f, v in only.items()):
            out.append(seed)
    if len(out) < count:
        raise SystemExit(f"{scenario}: only {len(out)} of seeds {first}..{first + limit - 1} draw {only}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["paper", "sparse", "corridor", "cross"])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--verbose", action="store_true", help="one line per seed")
    ap.add_argument("--zoo", action="store_true", help="--vary-nuisances zoo, figures split by family")
    ap.add_argument("--recipe", nargs="+", default=[], metavar="KEY=VALUE",
                    help="graph recipe fields for the factor graph, each of its field's type (a number, "
                         "true or false, a word: head_profile=linear)")
    ap.add_argument("--only", nargs="+", default=[], metavar="FAMILY=VALUE",
                    help="with --zoo: per scenario the first --seeds seeds from --first-seed whose zoo draws "
                         "these families (head=top, amcl=correlated, mounts=wall, clock=skew, ...)")
    ap.add_argument("--off", nargs="+", default=[], choices=OFF_FAMILIES,
                    help="switch these nuisance families off in each seed's draw, every other draw kept "
                         "(pedcal.sim.nuisances.switch_off): the same logs without them")
    ap.add_argument("--save", default=None, metavar="FILE", help="write the per-log results (pickle)")
    ap.add_argument("--from-results", default=None, metavar="FILE",
                    help="print the tables of an earlier run's --save FILE without running")
    args = ap.parse_args()
    if args.from_results:
        with open(args.from_results, "rb") as fh:
            saved = pickle.load(fh)
        print(saved["title"] + f" (from {args.from_results})")
        print_all(saved["results"], saved["zoo"], args.verbose)
        return
    recipe = recipe_overrides(args.recipe, ap)
    only = family_filter(args.only, ap)
    if only and not args.zoo:
        ap.error("--only selects zoo families: give --zoo")
    seeds = {sc: (seeds_with(sc, only, args.first_seed, args.seeds) if only
                  else list(range(args.first_seed, args.first_seed + args.seeds))) for sc in args.scenarios}
    tasks = [(sc, s, args.zoo, recipe, tuple(args.off)) for sc in args.scenarios for s in seeds[sc]]
    with ProcessPoolExecutor(args.jobs) as ex:
        results = list(ex.map(run_one, *zip(*tasks, strict=True)))
    title = (f"{len(args.scenarios)} scenarios x {args.seeds} seeds (first {args.first_seed}), "
             f"--vary-nuisances{' zoo' if args.zoo else ''}"
             + (f", only {' '.join(args.only)}" if args.only else "")
             + (f", recipe {' '.join(args.recipe)}" if args.recipe else "")
             + (f", off {' '.join(args.off)}" if args.off else ""))
    if args.save:
        with open(args.save, "wb") as fh:
            pickle.dump(dict(title=title, results=results, zoo=args.zoo), fh)
    print(title)
    print_all(results, args.zoo, args.verbose)


def print_all(results: list[dict], zoo: bool, verbose: bool = False) -> None:
    """Every table of a run's per-log results."""
    scenarios = list(dict.fromkeys(r["scenario"] for r in results))
    print("| scenario | graph RMS 3-D / xy (mm; sensors missed) | grid search 3-D / xy (mm; missed) | "
          "graph / grid (xy) | "
          "AMCL run-mean error xy (mm) | graph / grid xy less AMCL's run mean (mm) | "
          "graph / grid xy less the best common rigid 2-D transform (mm) | within 1 sigma x,y,z (%) | "
          "within 2 sigma x,y,z (%) | error / sigma RMS, shared / rest (xy) | head model shape RMS / worst, "
          "mean dz (mm) | graph solve wall / CPU (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for sc in scenarios:
        rs = [r for r in results if r["scenario"] == sc]
        if verbose:
            for r in rs:
                print(f"  seed {r['seed']:3d} graph {r['factorgraph']['rms_mm']:6.1f}"
                      f" grid {r['gridsearch']['rms_mm']:6.1f}"
                      f"  head {r['head_shape_mm']:5.1f} dz {r['head_dz_mm']:+6.1f}  mismatch {r['mismatch']}"
                      f"  | {r['nuisances']}, AMCL {r['amcl']}, odometry {r['odometry']}, "
                      f"latency {r['latency_s']:.2f}, depth {r['depth']}, {r['families']}")
        g = np.mean([r["factorgraph"]["rms_mm"] for r in rs])
        gxy = np.mean([r["factorgraph"]["rms_xy_mm"] for r in rs])
        b = np.mean([r["gridsearch"]["rms_mm"] for r in rs])
        bxy = np.mean([r["gridsearch"]["rms_xy_mm"] for r in rs])
        ratios = np.concatenate([r["ratios"] for r in rs])
        w1, w2 = 100 * within_sigma_share(ratios, 1.0), 100 * within_sigma_share(ratios, 2.0)
        z_text = _z_text(rs)
        shape = np.sqrt(np.mean([r["head_shape_mm"] ** 2 for r in rs]))
        worst = np.max([r["head_shape_mm"] for r in rs])
        floor = np.mean([r["amcl_mean_xy_mm"] for r in rs])
        grel = np.mean([r["factorgraph"]["rms_rel_mm"] for r in rs])
        brel = np.mean([r["gridsearch"]["rms_rel_mm"] for r in rs])
        grig = np.mean([r["factorgraph"]["rms_rigid_mm"] for r in rs])
        brig = np.mean([r["gridsearch"]["rms_rigid_mm"] for r in rs])
        dz = np.sqrt(np.mean([r["head_dz_mm"] ** 2 for r in rs]))
        wall = np.mean([r["factorgraph"]["wall_s"] for r in rs])
        cpu = np.mean([r["factorgraph"]["cpu_s"] for r in rs])
        print(f"| {sc} | {g:.1f} / {gxy:.1f} ({missed_text(rs, 'factorgraph')}) | "
              f"{b:.1f} / {bxy:.1f} ({missed_text(rs, 'gridsearch')}) | {g / b:.2f} ({gxy / bxy:.2f}) | {floor:.1f} | "
              f"{grel:.1f} / {brel:.1f} | {grig:.1f} / {brig:.1f} | "
              f"{w1[0]:.0f}, {w1[1]:.0f}, {w1[2]:.0f} | {w2[0]:.0f}, {w2[1]:.0f}, {w2[2]:.0f} | {z_text} | "
              f"{shape:.1f} / {worst:.1f}, {dz:.1f} | {wall:.2f} / {cpu:.2f} |")
    print_targets(results)
    print_wings(results)
    groups = [(sc, [r for r in results if r["scenario"] == sc]) for sc in scenarios] + [("all", results)]
    if zoo:
        print_families(results)
        groups += family_groups(results)
    print_honesty(groups)
    print_shared(groups)
    print_stretch(groups)


def missed_text(rs: list[dict], method: str) -> str:
    """The sensors ``method`` left out of its RMS over the logs ``rs`` (a miss is no error to
    average, so the RMS alone would reward it); '?' for results saved before they were counted."""
    counts = [r[method].get("missed") for r in rs]
    return "?" if None in counts else str(sum(counts))


def pooled_text(rs: list[dict]) -> str:
    """'(n of N logs)': how many of the logs ``rs`` have a finite shared part (at least 2
    calibrated sensors and a joint covariance); the others are not in the shared / rest RMS, and
    the count shows it instead of a figure over fewer logs than the row's."""
    n = sum(bool(len(r["z_shared"])) and bool(np.all(np.isfinite(r["z_shared"]))) for r in rs)
    return f"({n} of {len(rs)} logs)"


def _z_text(rs: list[dict]) -> str:
    """'shared / rest (n of N logs)': the RMS over ``rs``'s sensors of the horizontal error over
    its sigma, split into the sensors' mean and the departures from it (:func:`shared_and_rest_z`),
    with the logs pooled (:func:`pooled_text`); '-' without."""
    zs = np.concatenate([r["z_shared"] for r in rs])
    zr = np.concatenate([r["z_rest"] for r in rs])
    if not len(zs):
        return f"- {pooled_text(rs)}"
    # (pedcal.metrics.sigma_ratio_rms: a ratio that is not finite, a sigma of 0, is left out)
    return (f"{sigma_ratio_rms(zs.reshape(-1, 1))[0]:.2f} / {sigma_ratio_rms(zr.reshape(-1, 1))[0]:.2f} "
            f"{pooled_text(rs)}")


def _xy(r: dict) -> tuple[float, float]:
    return r["factorgraph"]["rms_xy_mm"], r["factorgraph"]["rms_xy_mm"] / r["gridsearch"]["rms_xy_mm"]


def print_targets(results: list[dict]) -> None:
    """Per scenario: the worst log's horizontal RMS and graph / grid ratio, and how many logs
    meet <= 12 mm and <= 0.35x the grid search horizontally."""
    print("\n| scenario | logs | worst xy RMS (mm) | worst graph / grid xy | logs <= 12 mm xy | logs <= 0.35x grid |")
    print("|---|---|---|---|---|---|")
    for sc in dict.fromkeys(r["scenario"] for r in results):
        xy = np.array([_xy(r) for r in results if r["scenario"] == sc])
        print(f"| {sc} | {len(xy)} | {xy[:, 0].max():.1f} | {xy[:, 1].max():.2f} | {int(np.sum(xy[:, 0] <= 12.0))} | "
              f"{int(np.sum(xy[:, 1] <= 0.35))} |")


def print_wings(results: list[dict]) -> None:
    """The L-shaped hall's wings: each one's mean error along x and y over its sigma, mean and
    RMS over the logs (0 and 1 when the sigma is right)."""
    rs = [r for r in results if r.get("wings")]
    if not rs:
        return
    print("\n| wing (L-shaped hall) | logs | mean error / sigma along x: mean, RMS | along y: mean, RMS |")
    print("|---|---|---|---|")
    for wing in ("x wing", "y wing"):
        z = np.array([r["wings"][wing] for r in rs])
        print(f"| {wing} | {len(z)} | {z[:, 0].mean():+.2f}, {np.sqrt(np.mean(z[:, 0] ** 2)):.2f} | "
              f"{z[:, 1].mean():+.2f}, {np.sqrt(np.mean(z[:, 1] ** 2)):.2f} |")


def family_groups(results: list[dict]) -> list[tuple[str, list[dict]]]:
    """The logs grouped by the family each zoo nuisance fell in (all scenarios pooled)."""
    return [(f"{family}: {value}", [r for r in results if r["families"][family] == value])
            for family in ZOO_FAMILY_VALUES
            for value in sorted({r["families"][family] for r in results})]


def print_families(results: list[dict]) -> None:
    """The figures split by the family each zoo nuisance fell in (all scenarios pooled); the
    sigma's honesty per family is in :func:`print_honesty`'s table."""
    print("\n| family | logs | graph xy RMS mean / worst (mm) (missed) | graph / grid xy (grid's missed) | "
          "clock offsets: error RMS (ms), within 1 / 2 sigma (%) |")
    print("|---|---|---|---|---|")
    for name, rs in family_groups(results):
        xy = np.array([_xy(r) for r in rs])
        z = np.concatenate([r.get("clock_z", np.zeros(0)) for r in rs])
        err = np.concatenate([r.get("clock_err_s", np.zeros(0)) for r in rs])
        clock = (f"{finite_rms(1000 * err):.1f}, {100 * np.mean(np.abs(z) <= 1):.0f} / "
                 f"{100 * np.mean(np.abs(z) <= 2):.0f}" if len(z) else "-")
        print(f"| {name} | {len(rs)} | {xy[:, 0].mean():.1f} / {xy[:, 0].max():.1f} "
              f"({missed_text(rs, 'factorgraph')}) | "
              f"{xy[:, 1].mean():.2f} ({missed_text(rs, 'gridsearch')}) | {clock} |")


def print_shared(groups: list[tuple[str, list[dict]]]) -> None:
    """Per group of logs, where the horizontal error's overconfidence lies: the RMS over the
    logs of AMCL's run-mean error (the simulator's truth; x, y pooled, mm) beside the graph's
    own estimate of its spread (the median over the logs of its AMCL model's run-mean sigma,
    ``AmclErrorModel.floor_sigma_m``, of the held model where it holds one: the one the sigma is
    read with), the sensors' mean error (RMS over the logs, mm), and the
    error over its sigma of that mean (shared) and of the departures from it (rest). A shared
    error/sigma far above 1 with AMCL's draws far above the model's spread is the draws'
    doing, not the sigma's."""
    print("\n| logs of | logs (seeds) | AMCL run-mean error RMS (mm) | graph's AMCL run-mean sigma, median (mm) | "
          "sensors' mean error RMS (mm) | error / sigma RMS, shared / rest (xy) |")
    print("|---|---|---|---|---|---|")
    for name, rs in groups:
        if not rs:
            continue
        amcl = 1000 * np.sqrt(np.mean([np.mean(np.square(r["amcl_mean_m"])) for r in rs
                                       if r.get("amcl_mean_m") is not None]))
        floors = [r["amcl_model"]["floor_m"] for r in rs if r.get("amcl_model")]
        floor = f"{1000 * np.median(floors):.1f}" if floors else "-"
        mean_err = [np.nanmean(r["error_m"][:, :2], axis=0) for r in rs if "error_m" in r]
        mean_text = f"{1000 * np.sqrt(np.mean(np.square(mean_err))):.1f}" if mean_err else "-"
        z_text = _z_text(rs)
        seeds = len({r["seed"] for r in rs})
        print(f"| {name} | {len(rs)} ({seeds}) | {amcl:.1f} | {floor} | {mean_text} | {z_text} |")


def print_stretch(groups: list[tuple[str, list[dict]]]) -> None:
    """Per group of logs, the network's stretch (:func:`stretch_fit`, mm/m along x and y): its
    mean and spread over the logs, the median of its sigma, and the RMS of stretch / sigma (1
    when the covariance holds the stretch the errors show)."""
    rows = [(name, [r["stretch"] for r in rs if r.get("stretch") is not None]) for name, rs in groups]
    rows = [(name, fits) for name, fits in rows if fits]
    if not rows:
        return
    print("\n| logs of | logs | stretch x: mean, sd over logs, median sigma (mm/m) | stretch / sigma RMS x | "
          "stretch y: mean, sd, median sigma (mm/m) | stretch / sigma RMS y |")
    print("|---|---|---|---|---|---|")
    for name, fits in rows:
        coef = 1000 * np.array([c for c, _ in fits])
        sig = 1000 * np.array([s for _, s in fits])
        cells = []
        for k in (2, 3):
            cells.append(f"{coef[:, k].mean():+.1f}, {coef[:, k].std():.1f}, {np.median(sig[:, k]):.1f}")
            cells.append(f"{np.sqrt(np.mean((coef[:, k] / sig[:, k]) ** 2)):.2f}")
        print(f"| {name} | {len(fits)} | " + " | ".join(cells) + " |")


def by_seed(rs: list[dict]) -> list[np.ndarray]:
    """The error / sigma ratios of ``rs`` pooled per seed (in the order the seeds first come): the
    unit of the bootstrap. A seed's logs share its zoo draw in every scenario (the same families,
    head model, clocks; whatever the walkers, benchmarks/bench_realwalk.py) and much of AMCL's
    error (the same random streams along another route: paper, corridor and L-hall of seed 0
    average 45, 28 and 36 mm of it along y), so the scenarios of one seed are not independent
    draws."""
    out: dict[int, list[np.ndarray]] = {}
    for r in rs:
        out.setdefault(r["seed"], []).append(r["ratios"])
    return [np.concatenate(v) for v in out.values()]


def print_honesty(groups: list[tuple[str, list[dict]]]) -> None:
    """Per group of logs: the share of per-axis errors within 1 sigma and the RMS of |error| /
    sigma, x / y / z, each with its 90 % interval from a bootstrap over the group's seeds
    (:func:`by_seed`); beside them the sensors and, in brackets, how many of them were missed
    (a ratio not finite: not calibrated, without a sigma or left out), which the share counts
    as outside and the RMS leaves out."""
    print("\n| logs of | logs (seeds) | sensors (missed) | within 1 sigma x / y / z (%) [90 % over seeds] | "
          "error / sigma RMS x / y / z [90 % over seeds] |")
    print("|---|---|---|---|---|")
    for name, rs in groups:
        if not rs:
            continue
        within, rms = sigma_honesty(by_seed(rs))
        print(f"| {name} | {len(rs)} ({within.logs}) | {within.rows} ({within.misses}) | "
              f"{format_clustered(within, 100, unit='seeds')} | {format_clustered(rms, digits=2, unit='seeds')} |")


if __name__ == "__main__":
    main()
