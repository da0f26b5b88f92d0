"""The head point's horizontal shift toward the sensor as a function of the viewing geometry: a
tracker that takes the blob's point nearest the sensor, or a centroid of what it sees of the
head, pulls its point toward a sensor seen from the side more (or less) than toward one seen
from nearly above. The graph's constant horizontal shift (``horizontal_shift_m``) becomes a
piecewise-linear function of the horizontal distance d from the sensor to the head,

    shift(d) = horizontal_shift_m + sum_{j=1..m} c_j phi_j(d),

phi_j the linear hats on knots d_0 < ... < d_m at quantiles of the robot observations' d (each
1 at d_j, 0 at its neighbours, the end ones held flat beyond the knots), so that shift(d_0) is
the constant shift and shift(d_j) = horizontal_shift_m + c_j. The c_j enter the observations
linearly, like the constant shift (``- c_j phi_j(d) u`` on the point, u the horizontal unit
toward the sensor, :func:`head_profile_shift_sensor`), so they are nuisances of the factor
graph's profile (:mod:`pedcal.calib.profile`) with the others, their covariance carried into
the sensors'.

How flexible the function is, the data decide (:func:`select_head_profile`): from the profile's
first step (a quadratic in the nuisances) the chi^2 each model gains over the constant one -- a
straight line in d (one parameter, c_j = a (d_j - d_0) / (d_m - d_0)) or the m hats -- against
the Bayesian information criterion's penalty, k ln(n) for k parameters and n robot-observation
factors; the constant wins a tie. The function is shared by every sensor (one tracker); a
tracker per sensor, each with its own shift, is left to the model check.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from pedcal.calib.profile import Nuisance, ProfileStep
from pedcal.errors import PedcalInputError

PREFIX = "head_profile_m:"            # nuisance names: PREFIX + knot index (1..m)
SLOPE = "head_profile_slope_m"        # the straight line's rise from d_0 to d_m (m)
MODES = ("off", "bic", "linear", "knots")
STEP_M = 0.01                         # finite-difference step of the profile (they enter linearly)
MIN_FACTORS = 100                     # fewer robot-observation factors: the constant shift only
KNOT_QUANTILES_END = 0.05             # the end knots at these quantiles of d (the ends are sparse)


def is_head_profile(name: str) -> bool:
    return name.startswith(PREFIX) or name == SLOPE


def horizontal_distance(p_sensor: np.ndarray, toward_sensor: np.ndarray) -> np.ndarray:
    """Horizontal distance (m) from the sensor to points ``p_sensor`` (sensor frame), given the
    horizontal unit toward the sensor in the sensor frame (``toward_sensor``): the point's
    horizontal part is -d u in the world, and a dot product does not depend on the frame."""
    return np.maximum(-np.sum(np.asarray(p_sensor, float) * np.asarray(toward_sensor, float), axis=1), 0.0)


def hats(d_m: np.ndarray, knots_m: np.ndarray) -> np.ndarray:
    """(N, m + 1) linear hats on ``knots_m`` at distances ``d_m``, flat beyond the ends: each row
    sums to 1 and interpolates linearly between the knots."""
    d = np.clip(np.asarray(d_m, float), knots_m[0], knots_m[-1])
    eye = np.eye(len(knots_m))
    return np.column_stack([np.interp(d, knots_m, eye[j]) for j in range(len(knots_m))])


def line_of_knots(knots_m: np.ndarray) -> np.ndarray:
    """(m,) the knots' values c_1..c_m of a straight line rising by 1 from d_0 to d_m."""
    return (knots_m[1:] - knots_m[0]) / max(float(knots_m[-1] - knots_m[0]), 1e-9)


def _knots(prob) -> np.ndarray | None:
    """The knots, chosen once per problem from the robot observations' horizontal distances
    (quantiles KNOT_QUANTILES_END .. 1 - KNOT_QUANTILES_END, evenly), or None when too few."""
    knots = getattr(prob, "_head_knots", None)
    if knots is not None:
        return knots
    rec = prob.recipe
    if prob.fac_p_sensor is None or len(prob.fac_p_sensor) < MIN_FACTORS:
        return None
    d = horizontal_distance(prob.fac_p_sensor, prob.fac_toward_sensor)
    q = np.linspace(KNOT_QUANTILES_END, 1.0 - KNOT_QUANTILES_END, rec.head_profile_knots)
    knots = np.quantile(d, q)
    if np.any(np.diff(knots) < 0.05):          # the robot seen at nearly one distance: nothing to fit
        return None
    prob._head_knots = knots
    return knots


def head_profile_nuisances(prob) -> list[Nuisance]:
    """The knots' departures c_1..c_m from the constant shift (recipe ``head_profile``: bic or
    knots; linear starts from them too and is reduced to the line), prior 0 +-
    ``head_profile_sigma_m``; [] when off, without the horizontal shift, or with too few
    observations. A line left by an earlier pass is carried into the knots first."""
    rec = prob.recipe
    if rec.head_profile not in MODES:
        raise PedcalInputError(f"head_profile must be one of {', '.join(MODES)}, got {rec.head_profile!r}",
                               column="head_profile")
    if (rec.head_profile == "off" or not rec.robot or not rec.estimate_head_horizontal_shift
            or rec.head_horizontal_shift_sigma_m <= 0.0 or rec.head_profile_sigma_m <= 0.0):
        return []
    if rec.head_profile_knots < 2:
        raise PedcalInputError(f"head_profile_knots must be 2 or more, got {rec.head_profile_knots}",
                               column="head_profile_knots")
    knots = _knots(prob)
    if knots is None:
        return []
    c = np.array([getattr(prob, PREFIX + str(j), 0.0) for j in range(1, len(knots))])
    c = c + getattr(prob, SLOPE, 0.0) * line_of_knots(knots)
    prob.head_profile_slope_m = 0.0
    out = []
    for j in range(1, len(knots)):
        setattr(prob, PREFIX + str(j), float(c[j - 1]))
        out.append(Nuisance(PREFIX + str(j), 0.0, rec.head_profile_sigma_m, STEP_M))
    return out


def knot_values(prob, theta: dict | None = None) -> np.ndarray | None:
    """(m,) the knots' departures c_1..c_m on ``prob`` (``theta`` overriding by name), the line
    included; None when no profile is set."""
    knots = getattr(prob, "_head_knots", None)
    if knots is None:
        return None
    theta = theta or {}
    c = np.array([theta.get(PREFIX + str(j), getattr(prob, PREFIX + str(j), 0.0)) for j in range(1, len(knots))])
    return c + float(theta.get(SLOPE, getattr(prob, SLOPE, 0.0))) * line_of_knots(knots)


def head_profile_shift_sensor(prob, theta: dict, use: np.ndarray) -> np.ndarray | float:
    """What the profile moves the robot-observation factors ``use`` by (sensor frame, m): the
    point taken back toward the head top, -sum_j c_j phi_j(d) u (module docstring). 0 when no
    profile is set."""
    c = knot_values(prob, theta)
    if c is None or not np.any(c):
        return 0.0
    d = horizontal_distance(prob.fac_p_sensor[use], prob.fac_toward_sensor[use])
    return -(hats(d, prob._head_knots)[:, 1:] @ c)[:, None] * prob.fac_toward_sensor[use]


def _reduced(step: ProfileStep, T: np.ndarray, b: np.ndarray) -> ProfileStep:
    """The profile step in new parameters r with theta = theta_0 + b + T r (the quadratic profile
    restricted to T's columns, from theta_0 moved by ``b``): gradient T^T (g + H b), Hessian
    T^T H T; the variables' step z0 takes the move b with it (z0 + Z b)."""
    H = step.hessian
    g = -H @ step.dtheta + H @ b
    Hr = T.T @ H @ T
    return ProfileStep(dtheta=-np.linalg.solve(Hr, T.T @ g), hessian=Hr, z0=step.z0 + step.Z @ b, Z=step.Z @ T,
                       cols=step.cols, order=step.order, A=step.A,
                       B=None if step.B is None else sps.csc_matrix(step.B @ sps.csc_matrix(T)))


def select_head_profile(prob, step: ProfileStep, nuis: list[Nuisance]) -> tuple[ProfileStep, list[Nuisance], dict]:
    """The profile step and nuisances with the head profile the data support (recipe
    ``head_profile``: bic compares the constant shift, a line and the knots by chi^2 - k ln(n);
    linear keeps the line; knots keeps the knots), from a step that holds the knots' departures.
    The chi^2 are the profile's decrease from the knots at 0 (the constant shift): a likelihood
    ratio, the quadratic profile being exact for nuisances that enter linearly. Returns (step,
    nuisances, what was compared: model -> (chi^2, penalty), and the model chosen)."""
    idx = [j for j, n in enumerate(nuis) if n.name.startswith(PREFIX)]
    if not idx:
        return step, nuis, {}
    knots = prob._head_knots
    k_all = len(nuis)
    others = [j for j in range(k_all) if j not in idx]
    H = step.hessian
    # the knots moved back to 0 (b), then each model's best step from there
    b = np.zeros(k_all)
    b[idx] = -np.array([getattr(prob, nuis[j].name) for j in idx])
    g = -H @ step.dtheta + H @ b

    def chi2(T):
        return float((T.T @ g) @ np.linalg.solve(T.T @ H @ T, T.T @ g))

    T0 = np.eye(k_all)[:, others]
    line = np.zeros((k_all, 1))
    line[idx, 0] = line_of_knots(knots)
    T1 = np.column_stack([T0[:, :idx[0]], line, T0[:, idx[0]:]])      # the line where the knots were
    base = chi2(T0)
    n = max(int(np.sum(prob.fac_key_index < len(prob.pose_times))), 2)
    compared = {"constant": (0.0, 0.0), "linear": (chi2(T1) - base, float(np.log(n))),
                "knots": (chi2(np.eye(k_all)) - base, float(len(idx) * np.log(n)))}
    mode = prob.recipe.head_profile
    if mode == "bic":
        mode = max(("constant", "linear", "knots"), key=lambda m: compared[m][0] - compared[m][1])
    compared["chosen"] = mode
    if mode == "knots":
        return step, nuis, compared
    for j in idx:            # the knots start again from nothing (their move is in b)
        setattr(prob, nuis[j].name, 0.0)
    prob.head_profile_slope_m = 0.0
    if mode == "constant":
        return _reduced(step, T0, b), [nuis[j] for j in others], compared
    # the line's rise a, each knot a L_j of prior sigma s: its prior sigma s / |L|, the one the
    # restricted Hessian T^T H T carries
    sigma = prob.recipe.head_profile_sigma_m / max(float(np.linalg.norm(line)), 1e-9)
    slope = Nuisance(SLOPE, 0.0, sigma, STEP_M)
    return _reduced(step, T1, b), [nuis[j] for j in others if j < idx[0]] + [slope] + [
        nuis[j] for j in others if j > idx[0]], compared


def profile_record(prob, names: list[str], cov: np.ndarray, horizontal_shift_m: float) -> dict | None:
    """The estimated horizontal shift at the knots, for the calibrated YAML's head model:
    {model, distance_m, shift_m, sigma_shift_m}, the shift at d_j being the constant shift plus
    c_j, its sigma from the profile's covariance ``cov`` (in ``names`` order). None when the
    data kept the constant shift."""
    knots = getattr(prob, "_head_knots", None)
    c = knot_values(prob)
    if knots is None or c is None:
        return None
    names = list(names)
    if not any(is_head_profile(n) for n in names) or "horizontal_shift_m" not in names:
        return None
    # each knot's shift as a linear map of the nuisances: e_hs + (e_{c_j} or L_j e_slope)
    J = np.zeros((len(knots), len(names)))
    J[:, names.index("horizontal_shift_m")] = 1.0
    line = line_of_knots(knots)
    for j in range(1, len(knots)):
        if PREFIX + str(j) in names:
            J[j, names.index(PREFIX + str(j))] = 1.0
        if SLOPE in names:
            J[j, names.index(SLOPE)] = line[j - 1]
    sigma = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))
    shift = horizontal_shift_m + np.r_[0.0, c]
    return {"model": "linear" if SLOPE in names else "knots", "distance_m": [round(float(v), 4) for v in knots],
            "shift_m": [round(float(v), 5) for v in shift], "sigma_shift_m": [round(float(v), 5) for v in sigma]}


PER_SENSOR_HEIGHT_NOTE = ("A tracker whose head point sits higher or lower for one sensor than for the others "
                          "moves that sensor's observations of the robot up or down alike: a vertical offset of "
                          "one sensor's own is that sensor's height error, which the robot cannot tell apart; the "
                          "installed heights as a reference (sensor_height_sigma_m) hold it.")


def record_head_profile(head_model, prob, shifts) -> None:
    """Put the profile the solve kept (if any) into ``head_model`` (its ``horizontal_profile``),
    from the nuisances' result ``shifts`` (None: nothing estimated); without a height reference
    its note also says that a per-sensor vertical offset is a height error
    (PER_SENSOR_HEIGHT_NOTE)."""
    if head_model is None:
        return
    if head_model.height_reference == "none" and head_model.note and PER_SENSOR_HEIGHT_NOTE not in head_model.note:
        head_model.note = f"{head_model.note} {PER_SENSOR_HEIGHT_NOTE}"
    if shifts is None:
        return
    head_model.horizontal_profile = profile_record(prob, shifts.names, shifts.cov, prob.horizontal_shift_m)


def shift_at(profile: dict, d_m: np.ndarray) -> np.ndarray:
    """The horizontal shift toward the sensor (m) a YAML head profile gives at horizontal
    distances ``d_m``: linear between its knots, flat beyond them."""
    return np.interp(np.asarray(d_m, float), np.asarray(profile["distance_m"], float),
                     np.asarray(profile["shift_m"], float))


__all__ = ["record_head_profile", "head_profile_nuisances", "head_profile_shift_sensor", "select_head_profile",
           "profile_record", "is_head_profile", "hats", "horizontal_distance", "shift_at", "line_of_knots",
           "knot_values"]
