"""The calibrated network read back from the solved graph: each sensor's pose with its sigma in
world axes and as rotation angles, the directions the data left unconstrained (kept at the
installed values), and the tracker, AMCL, odometry and noise models recorded beside it."""

from __future__ import annotations

import logging
import warnings

import gtsam
import numpy as np
import pandas as pd

from pedcal.calib.common import HeadModel, ModelMismatch
from pedcal.calib.keys import S
from pedcal.calib.problem import FactorGraphProblem
from pedcal.calib.recipe import GraphRecipe
from pedcal.errors import DegenerateDataWarning
from pedcal.frames import ypr_deg_from_rot
from pedcal.io.sensors_yaml import flow_vector
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


def sensor_sigma_world(T: gtsam.Pose3, cov_body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-axes position covariance and 1-sigma of position (m) and ypr (deg) from GTSAM's
    Pose3 marginal (body frame, rotation first)."""
    cov, sp, sy = sensor_sigmas_world(T.rotation().matrix()[None], np.asarray(cov_body, float)[None])
    return cov[0], sp[0], sy[0]


def sensor_sigmas_world(R: np.ndarray, cov_body: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`sensor_sigma_world` of m sensors at once: their rotations R_world_sensor (m, 3, 3)
    and Pose3 marginals (m, 6, 6) -> world-axes position covariances (m, 3, 3), position and ypr
    sigmas (m, 3). The ypr's Jacobian by a forward difference of 1e-6 rad about each body axis."""
    R, cov_body = np.asarray(R, float), np.asarray(cov_body, float)
    Rt = R.transpose(0, 2, 1)
    cov_pos_world = R @ cov_body[:, 3:, 3:] @ Rt
    ypr0 = ypr_deg_from_rot(R)
    J = np.zeros((len(R), 3, 3))
    eps = 1e-6
    for c in range(3):
        w = np.zeros(3)
        w[c] = eps
        d = ypr_deg_from_rot(R @ gtsam.Rot3.Expmap(w).matrix()) - ypr0
        J[:, :, c] = (d + 180.0) % 360.0 - 180.0
    J /= eps
    cov_ypr = J @ cov_body[:, :3, :3] @ J.transpose(0, 2, 1)
    diag_pos = np.diagonal(cov_pos_world, axis1=1, axis2=2)
    diag_ypr = np.diagonal(cov_ypr, axis1=1, axis2=2)
    # (a variance below 0 by rounding is 0: its sigma 0, not NaN)
    return cov_pos_world, np.sqrt(np.maximum(diag_pos, 0.0)), np.sqrt(np.maximum(diag_ypr, 0.0))


def rotation_sigma_deg(cov_body: np.ndarray) -> np.ndarray:
    """1-sigma (deg) of a sensor's orientation as a rotation vector in its own frame (about its
    optical axis x, its y and its z), from GTSAM's Pose3 covariance (body frame, rotation
    first): defined at any pitch, unlike yaw/pitch/roll, whose yaw and roll blur together when
    the sensor looks straight down."""
    return np.degrees(np.sqrt(np.maximum(np.diag(cov_body)[:3], 0.0)))


_DIRECTION_NAMES_ROT = ("rotation about world x", "rotation about world y", "yaw")
_DIRECTION_NAMES_POS = ("x", "y", "z")


UNCONSTRAINED_THRESHOLD = 0.5   # a direction whose posterior sigma is above this share of its prior's


def _prior_sigmas(recipe: GraphRecipe) -> np.ndarray:
    """(6,) the installed pose's prior sigmas, rotation (rad) first, as a Pose3's tangent."""
    return np.r_[[np.radians(recipe.sensor_prior_sigma_deg)] * 3, [recipe.sensor_prior_sigma_m] * 3]


def observability(T: gtsam.Pose3, cov_body: np.ndarray, recipe: GraphRecipe,
                  threshold: float = UNCONSTRAINED_THRESHOLD):
    """Directions of a sensor pose the data left unconstrained: eigen-directions of the posterior
    covariance whitened by the installed prior whose variance the data reduced by less than
    ``threshold`` (posterior sigma > threshold x prior sigma). Returns (names, whitened basis)."""
    evals, evecs = np.linalg.eigh(_whitened(np.asarray(cov_body, float)[None], recipe))
    return _unconstrained(T.rotation().matrix(), evals[0], evecs[0], threshold)


def _whitened(cov_body: np.ndarray, recipe: GraphRecipe) -> np.ndarray:
    """(m, 6, 6) Pose3 covariances whitened by the installed prior's sigmas, symmetrized."""
    p = _prior_sigmas(recipe)
    Cw = cov_body / np.outer(p, p)
    return 0.5 * (Cw + Cw.transpose(0, 2, 1))


def _unconstrained(R: np.ndarray, evals: np.ndarray, evecs: np.ndarray, threshold: float):
    """:func:`observability` from the whitened covariance's eigen-decomposition."""
    bad = evecs[:, evals > threshold ** 2]
    names = []
    for v in bad.T:     # whitened: rotation and translation parts are comparable
        if np.linalg.norm(v[:3]) >= np.linalg.norm(v[3:]):
            names.append(_DIRECTION_NAMES_ROT[int(np.argmax(np.abs(R @ v[:3])))])
        else:
            names.append(_DIRECTION_NAMES_POS[int(np.argmax(np.abs(R @ v[3:])))])
    return sorted(set(names)), bad



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
            "marginal is); CalibrationResult.marginals().jointMarginalCovariance(keys) gives any part of the "
            "solved graph's (without the head model's share, and, where AMCL's model holds a wander at its "
            "reported std, narrower than the sigma written: CalibrationResult's docstring)")
    if prob.amcl_model is not None and prob.recipe.amcl:
        network.extra[AMCL_MODEL_KEY] = {**prob.amcl_model.to_dict(), "jumps_moved_back": prob.amcl_jumps_moved_back}
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
                         cov_out: dict | None = None, cov_body: dict | None = None,
                         cov_given: dict | None = None) -> SensorNetwork:
    """The calibrated network from the graph's solution; ``cov_out`` (optional) receives each
    sensor's world-axes position covariance (m^2). ``cov_body``: each sensor's Pose3 covariance
    (body frame, rotation first) when the caller has it, else the graph's marginals.
    ``cov_given``: the graph's own marginal given the nuisances, when ``cov_body`` adds their
    shares, from which the directions the data leave unconstrained are found (a nuisance's
    prior carried into a sensor's sigma, a consider parameter's, is no lack of data)."""
    rec = prob.recipe
    if marginals is None and cov_body is None:
        marginals = gtsam.Marginals(fg, result)
    people_count = {sid: 0 for sid in prob.sensor_ids}
    for _, seen in prob.people:
        for sid, _ in seen:
            people_count[sid] += 1
    # robot observations per sensor, counted once (not a comparison of every row per sensor)
    # (hashed, not sorted: 400 000 id strings at a large site took 0.14 s to sort)
    obs_count = pd.Series(prob.obs_sensor).value_counts().to_dict() if rec.robot else {}
    ids = list(prob.sensor_ids)
    covs = np.array([cov_body[sid] if cov_body is not None else marginals.marginalCovariance(S(i))
                     for i, sid in enumerate(ids)], float).reshape(len(ids), 6, 6)
    # (every sensor's eigen-decomposition, and below its sigmas, in one batch)
    given = covs if cov_given is None else np.array([cov_given[sid] for sid in ids], float).reshape(len(ids), 6, 6)
    evals, evecs = np.linalg.eigh(_whitened(given, rec))
    poses, kept = [], []
    for i, sid in enumerate(ids):
        installed = log.sensors[sid]
        n_obs = int(obs_count.get(sid, 0))
        T = result.atPose3(S(i))
        if n_obs + people_count[sid] == 0:
            warnings.warn(f"sensor {sid}: no observation of the robot or of shared people; "
                          "its installed pose is kept", DegenerateDataWarning, stacklevel=2)
            poses.append(installed.T_world_sensor)
            kept.append(None)
            continue
        names, bad = _unconstrained(T.rotation().matrix(), evals[i], evecs[i], UNCONSTRAINED_THRESHOLD)
        status = "ok"
        if names:
            status = "degenerate"
            # keep the installed value along the unconstrained directions
            p = _prior_sigmas(rec)
            delta = installed.T_world_sensor.localCoordinates(T) / p
            delta -= bad @ (bad.T @ delta)
            T = installed.T_world_sensor.retract(delta * p)
            warnings.warn(f"sensor {sid}: the data leave {', '.join(names)} unconstrained; the installed "
                          "value is kept there", DegenerateDataWarning, stacklevel=2)
        poses.append(T)
        kept.append((n_obs, status, names))
    cov_pos, sp, sy = sensor_sigmas_world(np.array([T.rotation().matrix() for T in poses], float).reshape(-1, 3, 3),
                                          covs)
    out = []
    for i, (sid, T, what) in enumerate(zip(ids, poses, kept, strict=True)):
        if what is None:
            installed = log.sensors[sid]
            out.append(SensorExtrinsics(sid, installed.position_m, installed.ypr_deg, sigma_position_m=sp[i],
                                        sigma_ypr_deg=sy[i], sigma_rotation_deg=rotation_sigma_deg(covs[i]),
                                        observations=0, status="no-data"))
            continue
        n_obs, status, names = what
        if cov_out is not None:
            cov_out[sid] = cov_pos[i]
        out.append(SensorExtrinsics.from_pose3(sid, T, sigma_position_m=sp[i], sigma_ypr_deg=sy[i],
                                               sigma_rotation_deg=rotation_sigma_deg(covs[i]),
                                               observations=n_obs, status=status,
                                               unobservable=names or None))
    return SensorNetwork(out, frame=log.sensors.frame)


__all__ = ["sensor_sigma_world", "sensor_sigmas_world", "rotation_sigma_deg", "observability", "finish_network",
           "JOINT_COV_MAX_SENSORS"]
