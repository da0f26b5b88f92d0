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
the sensors'. d is read at the point the graph's variables predict (the robot's head seen from
the sensor's pose: :class:`pedcal.calib.graph.Regressors`), not at the measured one, whose noise
would move the regressor and the residual together (errors in variables: a line shrinking the
network with the noise); u at the measured one (the Regressors' note). The knots are placed at
quantiles of the measured distances (a choice of basis, not a regressor).

How flexible the function is, the data decide (:func:`select_head_profile`), among the constant,
one-parameter shapes (:func:`shapes`: a line; a shift rising or fading from d_0 to an interior
knot and flat beyond, which is how a tracker's pull saturates; flat to a knot and rising after)
and the m free knots. Recipe ``cv``: each model is fitted on every sensor's observations but
one's and judged by the chi^2 it takes off that one's (:func:`held_out_gain`, from the profile's
rows: no re-solve), summed over the sensors; the simplest model within one standard error of the
best is kept, a non-constant one only when its gain exceeds its own standard error. Recipe
``bic``: the chi^2 each model gains over the constant (a likelihood ratio: the profile is
quadratic for nuisances that enter linearly) against k ln(n), for k parameters and n
robot-observation factors. Both report the score's overdispersion over 20 s blocks
(:func:`overdispersion`), the check of the chi^2's noise scale. The function is shared by every
sensor (one tracker).
"""

from __future__ import annotations

import gtsam
import numpy as np
import scipy.sparse as sps
from scipy.special import ndtri

from pedcal.calib.profile import Nuisance, ProfileStep
from pedcal.errors import PedcalInputError

PREFIX = "head_profile_m:"            # nuisance names: PREFIX + knot index (1..m)
SENSOR_PREFIX = "head_shift_sensor_m:"  # a sensor's own departure from the shared shift: + sensor id
SLOPE = "head_profile_slope_m"        # a one-parameter shape's amplitude (m; the line's rise from d_0 to d_m)
MODES = ("off", "cv", "bic", "linear", "knots")
STEP_M = 0.01                         # finite-difference step of the profile (they enter linearly)
MIN_FACTORS = 100                     # fewer robot-observation factors: the constant shift only
CLUSTER_S = 20.0                      # the residuals' clusters for the overdispersion: this long each
MIN_SENSOR_FACTORS = 30              # fewer robot observations of a sensor: it keeps the shared shift
FAMILY_ALPHA = 0.05                  # a sensor's own departure: its false-keep rate over all sensors
MIN_CLUSTERS = 8                      # fewer clusters: no overdispersion estimate (taken as 1)
KNOT_QUANTILES_END = 0.05             # the end knots at these quantiles of d (the ends are sparse)


def is_head_profile(name: str) -> bool:
    return name.startswith(PREFIX) or name.startswith(SENSOR_PREFIX) or name == SLOPE


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


def _shape(prob, knots_m: np.ndarray) -> tuple[str, np.ndarray]:
    """The one-parameter shape the selection kept (name, (m,) knot values per unit of SLOPE;
    :func:`shapes`), the line unless another was kept."""
    return getattr(prob, "_head_shape", None) or ("linear", line_of_knots(knots_m))


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
    if rec.head_profile_per_sensor and rec.head_shift_per_sensor_sigma_m > 0.0:
        raise PedcalInputError("head_profile_per_sensor selects each sensor's own departure, which "
                               "head_shift_per_sensor_sigma_m > 0 already holds as a random effect: set that to 0 "
                               "to select them instead", column="head_profile_per_sensor")
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
    c = c + getattr(prob, SLOPE, 0.0) * _shape(prob, knots)[1]
    prob.head_profile_slope_m = 0.0
    out = []
    for j in range(1, len(knots)):
        setattr(prob, PREFIX + str(j), float(c[j - 1]))
        out.append(Nuisance(PREFIX + str(j), 0.0, rec.head_profile_sigma_m, STEP_M))
    if rec.head_profile_per_sensor:
        # each sensor's own tracker: a departure from the shared shift, where it sees the robot enough
        out += _departures(prob, MIN_SENSOR_FACTORS, rec.head_profile_sigma_m)
    return out


def _departures(prob, min_factors: int, sigma: float) -> list[Nuisance]:
    """Each sensor's own departure delta_s from the shared horizontal shift, prior 0 +- ``sigma``,
    for the sensors with at least ``min_factors`` robot-observation factors (each starts at 0 on
    ``prob`` the first time)."""
    n_pose = len(prob.pose_times)
    counts = np.bincount(prob.fac_sensor_index[prob.fac_key_index < n_pose], minlength=len(prob.sensor_ids))
    out = []
    for i, sid in enumerate(prob.sensor_ids):
        if counts[i] >= min_factors:
            name = SENSOR_PREFIX + sid
            setattr(prob, name, float(getattr(prob, name, 0.0)))
            out.append(Nuisance(name, 0.0, sigma, STEP_M))
    return out


def considered_nuisances(prob) -> list[Nuisance]:
    """The shift against distance as a consider parameter (recipe ``head_profile`` off and
    ``head_profile_consider``): the line (SLOPE, rising by it from d_0 to d_m) at 0, prior
    ``head_profile_sigma_m``, whose sensitivity the first profile step takes and
    :func:`leave_out` removes from the estimate, what the data leave of its prior
    (:func:`considered_rms`) carried into the sensors' covariance. [] when a profile is
    estimated, without the horizontal shift or with too few observations."""
    rec = prob.recipe
    if (rec.head_profile != "off" or not rec.head_profile_consider or not rec.robot
            or not rec.estimate_head_horizontal_shift or rec.head_horizontal_shift_sigma_m <= 0.0
            or rec.head_profile_sigma_m <= 0.0 or _knots(prob) is None):
        return []
    prob.head_profile_slope_m = 0.0
    return [Nuisance(SLOPE, 0.0, rec.head_profile_sigma_m, STEP_M)]


def leave_out(step: ProfileStep, j: int, held: tuple = ()) -> tuple[ProfileStep, np.ndarray]:
    """The profile step without nuisance ``j`` (held at its value, the others' Newton step
    re-solved) and the variables' error per unit of its true departure from that value:
    S = Z_j - Z_o H_oo^-1 H_oj (n,), the others o re-optimized (they absorb what they can of it,
    H the profile's information), but for those in ``held``, which stay at their values as well
    (a nuisance a later selection drops takes up nothing). Its prior sigma^2 S S^T is the
    consider covariance."""
    H = step.hessian
    g = -H @ step.dtheta
    keep = np.flatnonzero(np.arange(len(H)) != j)
    o = np.array([i for i in keep if i not in held], int)
    S = step.Z[:, j] - step.Z[:, o] @ np.linalg.solve(H[np.ix_(o, o)], H[o, j])
    reduced = step.select(keep)
    reduced.dtheta = -np.linalg.solve(H[np.ix_(keep, keep)], g[keep])
    return reduced, S


def line_moments(step: ProfileStep, j: int, held: tuple = ()) -> tuple[float, float]:
    """(d, v): nuisance ``j``'s posterior mean's distance from the value the ``step`` was taken
    at and its variance, the profile's, the other nuisances free but those in ``held`` (their
    rows and columns of the Hessian left out): with the free ones' Newton step -H^-1 g (g =
    -H dtheta), d its j-th entry and v = (H^-1)_jj."""
    H = step.hessian
    g = -H @ step.dtheta
    free = np.array([i for i in range(len(H)) if i == j or i not in held], int)
    at = int(np.flatnonzero(free == j)[0])
    cov = np.linalg.inv(H[np.ix_(free, free)])
    return float(-(cov @ g[free])[at]), float(cov[at, at])


def considered_rms(step: ProfileStep, j: int, held: tuple = ()) -> float:
    """How far nuisance ``j`` may be from its truth when held at the value the ``step`` was taken
    at, by what the data say of it: the root of its posterior's second moment about that value,
    sqrt(d^2 + v), d and v its posterior mean's distance from it and its variance, the profile's
    (its prior included; the other nuisances free but those in ``held``, which stay at their
    values): with the free ones' Newton step -H^-1 g, d its j-th entry and v = (H^-1)_jj.
    Holding it moves the variables by S times its error (:func:`leave_out`), so their error's
    expected square given the data is S S^T times this squared: the consider covariance with
    the prior's sigma replaced by what is left of it once the data are seen. Where the data say
    nothing, d = 0 and v the prior's variance (the prior's sigma again); where they measure the
    nuisance near the held value, their sigma; where they find it away from it, that distance.

    Nuisances ``held`` (the head point's curvature, when its selection leaves it out) are an
    assumption of the model, and d moves with it: the square of that move, d - d_free (d_free
    the same distance with them free), is added, d^2 + v + (d - d_free)^2 under the root, so the
    width covers how far the hold moves the nuisance (nothing when none is held). On the
    centroid's head point, whose shift rises 22-31 mm over the line's distances, d held and free
    straddle the truth (held -4 to +26 mm, free -25 to +7 mm) and the data's width alone left
    the sensors' horizontal errors 1.41 times their sigma (README, "Candidate widths")."""
    d, v = line_moments(step, j, held)
    # (nothing held: the line's Newton step itself, -(H^-1 g)_j = dtheta_j)
    moved = d - float(step.dtheta[j]) if held else 0.0
    return float(np.sqrt(d ** 2 + v + moved ** 2))


def sensor_shift_nuisances(prob) -> list[Nuisance]:
    """Each sensor's own constant departure delta_s of the horizontal shift toward the sensor
    from the shared one, a random effect (recipe ``head_shift_per_sensor_sigma_m`` > 0): every
    sensor that saw the robot gets one, always in the model (no selection), prior 0 +- that
    sigma, the spread of the head point between trackers. Where a sensor sees people all around
    it, the departure is a radial contraction of its view, which the data estimate; where it
    sees them from one side (a wall mount, a corridor's end), it moves the sensor's position
    along its view axis alike, and it stays near its prior: its covariance, carried into the
    sensor's by the profile (:mod:`pedcal.calib.profile`), widens that sensor's sigma along
    that axis alone. Each starts at 0 on ``prob`` the first time; [] when off, without the
    horizontal shift, or without robot observations."""
    rec = prob.recipe
    sigma = rec.head_shift_per_sensor_sigma_m
    if sigma < 0.0:
        raise PedcalInputError(f"head_shift_per_sensor_sigma_m must be 0 (off) or positive, got {sigma}",
                               column="head_shift_per_sensor_sigma_m")
    if (sigma == 0.0 or not rec.robot or not rec.estimate_head_horizontal_shift
            or rec.head_horizontal_shift_sigma_m <= 0.0 or prob.fac_sensor_index is None):
        return []
    return _departures(prob, 1, sigma)


SPREAD_MIN_SENSORS = 3                # fewer sensors whose departure the data determine: the recipe's sigma
SPREAD_MAX_M = 0.1                    # the spread's grid reaches this far (a head's size)
SPREAD_GRID = np.linspace(1e-4, SPREAD_MAX_M, 200)   # (m, ~0.5 mm apart; from 0.1 mm: the limit tau -> 0 is finite)


def spread_log_likelihood(H: np.ndarray, g: np.ndarray, theta: np.ndarray, prior_mean: np.ndarray,
                          prior_sigma: np.ndarray, own: np.ndarray, grid_m: np.ndarray = SPREAD_GRID) -> np.ndarray:
    """The log marginal likelihood of the departures' prior sigma tau at each of ``grid_m``, from
    the profile's quadratic at ``theta`` (its Hessian ``H`` and gradient ``g``, both with the
    nuisances' priors of ``prior_mean`` and ``prior_sigma`` in): the data's part is H_d = H - P_0
    and g_d = g - P_0 r (r = theta - prior_mean, P_0 = diag(prior_sigma^-2)); with the departures
    (indices ``own``) given their prior mean +- tau and the other nuisances their priors (P(tau)), every
    nuisance is integrated out (the quadratic profile is exact for nuisances that enter
    linearly): with A = H_d + P(tau) and b = g_d + P(tau) r,

        l(tau) = 1/2 b^T A^-1 b - 1/2 r^T P(tau) r - 1/2 ln det A - k ln tau      (+ const),

    k the departures' count (their prior's normalisation). With a diffuse shared shift this is
    the restricted (REML) likelihood of a random effect's variance (Harville 1977): the shared
    shift, their mean, is integrated out, not estimated."""
    own = np.asarray(own, np.int64)
    r = np.asarray(theta, float) - np.asarray(prior_mean, float)
    p0 = 1.0 / np.asarray(prior_sigma, float) ** 2
    H, g = np.asarray(H, float), np.asarray(g, float)
    # only the departures' diagonal moves with lam = tau^-2: with the other nuisances (N) at their
    # priors and eliminated, A's Schur complement on the departures is S + lam I (S = A_OO - C^T K^-1 C, K = A_NN,
    # C = A_NO at lam = 0), and one eigen-decomposition S = U diag(s) U^T gives every tau:
    # ln det A = ln det K + sum ln(s + lam) and b^T A^-1 b = b_N^T K^-1 b_N + sum c^2 / (s + lam),
    # c = U^T (b_O - C^T K^-1 b_N); b_N = g_N (the priors' r cancels there), b_O = g_d,O + lam r_O.
    # The terms without tau (K's) are left out: the likelihood is read by its differences.
    other = np.setdiff1d(np.arange(len(p0)), own)
    A0 = H.copy()
    A0[own, own] -= p0[own]                          # H_d with the other nuisances' priors kept
    K, C = A0[np.ix_(other, other)], A0[np.ix_(other, own)]
    K_inv_C = np.linalg.solve(K, C) if len(other) else np.zeros((0, len(own)))
    K_inv_g = np.linalg.solve(K, g[other]) if len(other) else np.zeros(0)
    s_eig, U = np.linalg.eigh(A0[np.ix_(own, own)] - C.T @ K_inv_C)
    # (S is the data's part of a Gauss-Newton Hessian's Schur complement, positive semi-definite: an
    # eigenvalue below 0 by rounding is 0; one well below is no such Hessian, and its likelihood NaN,
    # which estimate_departure_spread reports as not estimated)
    floor = -1e-9 * float(np.max(np.abs(s_eig), initial=0.0))
    s_eig = np.where(s_eig >= floor, np.maximum(s_eig, 0.0), np.nan)
    c0 = U.T @ (g[own] - p0[own] * r[own] - C.T @ K_inv_g)
    r_eig = U.T @ r[own]
    tau = np.asarray(grid_m, float)
    lam = 1.0 / tau ** 2
    d = s_eig[None, :] + lam[:, None]
    c = c0[None, :] + lam[:, None] * r_eig[None, :]
    return (0.5 * np.sum(c * c / d, axis=1) - 0.5 * lam * float(r[own] @ r[own]) - 0.5 * np.sum(np.log(d), axis=1)
            - len(own) * np.log(tau))


def spread_summary(loglik: np.ndarray, grid_m: np.ndarray = SPREAD_GRID) -> dict:
    """tau's estimate from its log likelihood on ``grid_m``: ``estimate_m`` the maximum's tau (0 at
    the grid's first point) and, under a flat prior on tau over the grid (its points evenly spaced,
    as SPREAD_GRID's: the weights are the likelihood's alone), ``rms_m`` = sqrt(E[tau^2 | data]), the prior
    sigma the departures take (a departure's variance averaged over what the data leave of
    tau: its own uncertainty carried, not the point estimate's alone), and ``upper_m`` its
    posterior's 95 % quantile."""
    w = np.exp(loglik - np.max(loglik))
    w /= w.sum()
    cdf = np.cumsum(w)
    best = int(np.argmax(loglik))
    # (the maximum at the grid's first point: the limit tau -> 0, reported as 0)
    return {"estimate_m": 0.0 if best == 0 else float(grid_m[best]),
            "rms_m": float(np.sqrt(np.sum(w * grid_m ** 2))),
            "upper_m": float(grid_m[min(int(np.searchsorted(cdf, 0.95)), len(grid_m) - 1)])}


def spread_from_estimates(departure_m: np.ndarray, sigma_m: np.ndarray, grid_m: np.ndarray = SPREAD_GRID) -> dict:
    """tau from independent per-sensor estimates y_s = mu + delta_s + e_s (e_s ~ N(0, sigma_s^2),
    delta_s ~ N(0, tau^2), mu diffuse): :func:`spread_log_likelihood` on their quadratic,
    parameters (mu, delta_1..k). Public, for head points estimated elsewhere (one per sensor, with
    their sigma); the factor graph reads its own departures jointly (:func:`estimate_departure_spread`).
    Sensors with a non-finite estimate or sigma, or a sigma not positive, are left out; fewer than
    two left: an estimate of nan ("sensors" says how many)."""
    y, s = np.asarray(departure_m, float), np.asarray(sigma_m, float)
    ok = np.isfinite(y) & np.isfinite(s) & (s > 0.0)
    y, s = y[ok], s[ok]
    k = len(y)
    if k < 2:
        return {"estimate_m": float("nan"), "rms_m": float("nan"), "upper_m": float("nan"), "sensors": k}
    J = np.column_stack([np.ones(k), np.eye(k)])
    W = 1.0 / s ** 2
    mu_sigma = 1e3 * float(np.max(np.abs(y)) + np.max(s))      # diffuse
    prior_sigma = np.r_[mu_sigma, np.full(k, 1.0)]
    H = J.T @ (W[:, None] * J) + np.diag(1.0 / prior_sigma ** 2)
    g = -J.T @ (W * y)                     # the gradient at theta = 0 (priors' part 0 there)
    ll = spread_log_likelihood(H, g, np.zeros(k + 1), np.zeros(k + 1), prior_sigma, np.arange(1, k + 1), grid_m)
    return {**spread_summary(ll, grid_m), "sensors": k}


def estimate_departure_spread(prob, step: ProfileStep, nuis: list[Nuisance], theta: np.ndarray, use: bool = True):
    """The departures' prior sigma tau estimated from the data: :func:`spread_log_likelihood`
    on the profile ``step`` at ``theta`` (``nuis`` its nuisances, in order), its posterior
    summarised by :func:`spread_summary`. It counts the sensors whose departure the data
    determine (seen from around: the data at least halve its prior variance, the other nuisances
    integrated out); with fewer than SPREAD_MIN_SENSORS, or departures each fitted with the path on
    its own (more sensors than ``clock_offsets_joint_max``), there is no estimate. With ``use`` (recipe
    ``head_shift_per_sensor_sigma_estimate``) the step is re-taken with the departures' prior
    their prior mean +- ``rms_m`` (its Hessian's prior part exchanged, the Newton step re-solved), or, without an
    estimate, the recipe's ``head_shift_per_sensor_sigma_m`` is kept with a
    DegenerateDataWarning; without ``use`` the estimate is only reported and the step, the
    nuisances and their prior stay as they were. Returns (step, nuisances, record): the record
    (estimate_m, rms_m, upper_m: None without an estimate; sensors, prior_m the recipe's sigma,
    applied: the prior's sigma the departures keep is rms_m; None without departures) is what the
    caller keeps as ``prob.departure_spread`` for the head model's note (:func:`spread_note`)."""
    import warnings

    from pedcal.errors import DegenerateDataWarning
    own = np.array([j for j, n in enumerate(nuis) if is_sensor_shift(n.name)], np.int64)
    sigma0 = prob.recipe.head_shift_per_sensor_sigma_m
    if not len(own):
        if not any(is_sensor_shift(name) for name in vars(prob)):
            return step, nuis, None
        # departures fitted with the path, each on its own (more sensors than clock_offsets_joint_max):
        # no joint quadratic to read their spread from
        informed, why = 0, "each sensor's own shift is fitted with the path on its own (clock_offsets_joint_max)"
    else:
        # a departure the data determine: its posterior variance (the others integrated out: the
        # Hessian's inverse) at most half its prior's
        p0 = np.array([1.0 / n.prior_sigma ** 2 for n in nuis])
        informed = int(np.sum(np.diag(step.covariance)[own] <= 0.5 / p0[own]))
        why = (f"the data determine {informed} sensors' own shift (seen from around), fewer than "
               f"{SPREAD_MIN_SENSORS}")
    record = {"prior_m": sigma0, "sensors": informed, "applied": False}

    def not_estimated(why: str):
        """The recipe's sigma kept (named in a warning where the estimate was to be used)."""
        if use:
            warnings.warn(f"the spread of the head point between the sensors' trackers is not estimated: {why}; "
                          f"its prior sigma head_shift_per_sensor_sigma_m = {1000 * sigma0:.0f} mm is kept",
                          DegenerateDataWarning, stacklevel=4)
        return step, nuis, {**record, "estimate_m": None, "rms_m": None, "upper_m": None, "why": why}
    if informed < SPREAD_MIN_SENSORS:
        return not_estimated(why)
    H = step.hessian
    g = -H @ step.dtheta
    mean = np.array([n.prior_mean for n in nuis])
    sigma = np.array([n.prior_sigma for n in nuis])
    summary = spread_summary(spread_log_likelihood(H, g, theta, mean, sigma, own))
    if not np.isfinite(list(summary.values())).all():
        return not_estimated("its likelihood is not finite on the Hessian the solve left")
    record.update(summary)
    if not use:
        return step, nuis, record
    record["applied"] = True
    tau = record["rms_m"]
    # the prior's part exchanged: H' = H + dP, g' = g + dP r, the Newton step -H'^-1 g'
    dp = np.zeros(len(nuis))
    dp[own] = 1.0 / tau ** 2 - p0[own]
    H_new = H + np.diag(dp)
    g_new = g + dp * (np.asarray(theta, float) - mean)
    step.hessian = H_new
    step.dtheta = -np.linalg.solve(H_new, g_new)
    nuis = [Nuisance(n.name, n.prior_mean, tau, n.step) if is_sensor_shift(n.name) else n for n in nuis]
    return step, nuis, record


def spread_record(record: dict | None) -> dict | None:
    """The head model's ``per_sensor_shift_spread`` (:func:`estimate_departure_spread`'s record):
    estimate_m, upper_m (its 95 % quantile), rms_m (its posterior's root mean square; all None
    without an estimate), sensors (those informing it), prior_sigma_m (the sigma the departures'
    prior had: rms_m where the estimate was used, else the recipe's). None without departures."""
    if not record:
        return None

    def metres(v):
        return None if v is None else round(float(v), 5)
    return {"estimate_m": metres(record.get("estimate_m")), "upper_m": metres(record.get("upper_m")),
            "rms_m": metres(record.get("rms_m")), "sensors": int(record["sensors"]),
            "prior_sigma_m": metres(record["rms_m"] if record.get("applied") else record["prior_m"])}


def spread_note(record: dict | None) -> str:
    """The head model's note on the departures' prior sigma (:func:`estimate_departure_spread`)."""
    if not record:
        return ""
    recipe = f"the recipe's prior sigma {1000 * record['prior_m']:.0f} mm (head_shift_per_sensor_sigma_m)"
    if record.get("estimate_m") is None:
        why = record.get("why") or f"the data determine {record['sensors']} sensors' own shift"
        return f"The spread of the head point between the sensors' trackers was not estimated ({why}): each " \
               f"sensor's own shift has {recipe}."
    found = (f"The spread of the head point between the sensors' trackers, estimated from {record['sensors']} "
             f"sensors' own shifts: {1000 * record['estimate_m']:.1f} mm (95 % below {1000 * record['upper_m']:.1f} "
             f"mm; the root of its mean square over what the data leave of it {1000 * record['rms_m']:.1f} mm)")
    if record.get("applied"):
        return f"{found}, each sensor's own shift's prior sigma."
    return (f"{found}; each sensor's own shift keeps {recipe} (head_shift_per_sensor_sigma_estimate = true "
            "takes the estimate).")


def is_sensor_shift(name: str) -> bool:
    """Whether ``name`` is a sensor's own departure of the horizontal shift."""
    return name.startswith(SENSOR_PREFIX)


def sensor_departures(prob, theta: dict | None = None) -> np.ndarray:
    """(n_sensors,) each sensor's departure from the shared horizontal shift (m; 0 for one without
    its own), ``theta`` overriding by name."""
    theta = theta or {}
    return np.array([float(theta.get(SENSOR_PREFIX + sid, getattr(prob, SENSOR_PREFIX + sid, 0.0)))
                     for sid in prob.sensor_ids])


def knot_values(prob, theta: dict | None = None) -> np.ndarray | None:
    """(m,) the knots' departures c_1..c_m on ``prob`` (``theta`` overriding by name), the line
    included; None when no profile is set."""
    knots = getattr(prob, "_head_knots", None)
    if knots is None:
        return None
    theta = theta or {}
    c = np.array([theta.get(PREFIX + str(j), getattr(prob, PREFIX + str(j), 0.0)) for j in range(1, len(knots))])
    return c + float(theta.get(SLOPE, getattr(prob, SLOPE, 0.0))) * _shape(prob, knots)[1]


def head_profile_shift_sensor(prob, theta: dict, use: np.ndarray, toward_sensor: np.ndarray | None = None,
                              distance_m: np.ndarray | None = None) -> np.ndarray | float:
    """What the profile moves the robot-observation factors ``use`` by (sensor frame, m): the
    point taken back toward the head top, -(sum_j c_j phi_j(d) + delta_s) u (module docstring;
    delta_s the observing sensor's own departure), u and d the factors' ``toward_sensor`` and
    ``distance_m`` (the observation block's, read at the predicted point:
    :class:`pedcal.calib.graph.Regressors`), by default read at the measured points. 0 when no
    profile is set."""
    c = knot_values(prob, theta)
    own = sensor_departures(prob, theta)
    if (c is None or not np.any(c)) and not np.any(own):
        return 0.0
    u = prob.fac_toward_sensor[use] if toward_sensor is None else toward_sensor
    shift = own[prob.fac_sensor_index[use]]
    if c is not None and np.any(c):
        d = horizontal_distance(prob.fac_p_sensor[use], u) if distance_m is None else distance_m
        shift = shift + hats(d, prob._head_knots)[:, 1:] @ c
    return -shift[:, None] * u


def _row_labels(graphs, n_rows: int, label_of) -> np.ndarray:
    """(n_rows,) a label for every row of the profile's linear system, whose rows are
    ``graphs``' factors in order, each its dim() rows: ``label_of(symbols, previous)`` of the
    factor's keys (as (char, index) pairs) and the label of the factor before it in its graph
    (None for the first); rows beyond the graphs' (the local nuisances' priors) get -1."""
    labels = np.full(n_rows, -1, np.int64)
    row = 0
    for graph in graphs:
        previous = None
        for i in range(graph.size()):
            factor = graph.at(i)
            symbols = [(chr(gtsam.Symbol(key).chr()), gtsam.Symbol(key).index()) for key in factor.keys()]
            label = label_of(symbols, previous)
            dim = int(factor.dim())
            labels[row:row + dim] = label
            row += dim
            previous = label
    return labels


def time_blocks(times: np.ndarray, cluster_s: float = CLUSTER_S) -> tuple[np.ndarray, int]:
    """(each time's block (int64), the blocks' count): block floor(t / ``cluster_s``) -
    floor(t_0 / ``cluster_s``), t_0 the earliest of ``times``, so the blocks are counted from the
    log's first (stamps since the epoch, as a ROS bag's, would give labels of ~10^8, and times
    before 0 labels below 0, which the residuals' clusters read as left out); no times: none, 1."""
    times = np.asarray(times, float)
    if not times.size:
        return np.zeros(0, np.int64), 1
    first = np.floor(float(times.min()) / cluster_s)
    n_blocks = int(np.floor(float(times.max()) / cluster_s) - first) + 1
    return (np.floor(times / cluster_s) - first).astype(np.int64), n_blocks


def row_clusters(graphs, pose_times: np.ndarray, n_rows: int, cluster_s: float = CLUSTER_S,
                 people: bool = True) -> np.ndarray:
    """(n_rows,) the time cluster of every row of the profile's system (:func:`_row_labels`): a
    factor on a robot pose X(k) falls in the block of ``cluster_s`` seconds holding pose k, a
    factor on a person L(m) in that person's cluster, any other in the cluster of the factor
    before it in its graph (AMCL's error nodes between poses, in time order), else -1 (the
    priors). The blocks are counted from the first pose's (:func:`time_blocks`)."""
    pose_blocks, n_blocks = time_blocks(np.asarray(pose_times, float), cluster_s)

    def label_of(symbols, previous):
        for c, k in symbols:
            if c == "x" and k < len(pose_times):
                return int(pose_blocks[k])
        for c, k in symbols:
            if c == "l":
                return n_blocks + int(k) if people else -1
        return -1 if previous is None else previous
    return _row_labels(graphs, n_rows, label_of)


def row_sensors(graphs, n_rows: int) -> np.ndarray:
    """(n_rows,) the sensor index i of every row of the profile's system whose factor holds a
    sensor's pose S(i) (its prior, its observations of the robot and of people), -1 for the
    others (AMCL, motion, the head point's prior)."""
    def label_of(symbols, previous):
        return next((int(k) for c, k in symbols if c == "s"), -1)
    return _row_labels(graphs, n_rows, label_of)


def _efficient_rows(step: ProfileStep, nuis: list[Nuisance], extra: list[int],
                    others: list[int] | None = None, M: np.ndarray | None = None) -> np.ndarray:
    """(rows, len(extra)) each row's residual change with the ``extra`` nuisances, the variables
    and the other nuisances profiled out: M = A Z - B (the variables profiled), then the other
    nuisances' columns projected out with the data's Hessian, m_i = M_i,e - M_i,o H_oo^-1 H_oe,
    so that sum_i m_i m_i^T is the extra nuisances' information given the others (their priors
    left out) and sum_i m_i rho_i their efficient score. ``others``: the nuisances profiled out
    (default every one not extra; the rest are held). ``M``: A Z - B when the caller has it."""
    if M is None:
        M = np.asarray(step.A @ step.Z) - step.B.toarray()
    H = step.hessian - np.diag([1.0 / n.prior_sigma ** 2 for n in nuis])
    if others is None:
        others = [j for j in range(len(nuis)) if j not in extra]
    if not others:
        return M[:, extra]
    W = np.linalg.solve(H[np.ix_(others, others)], H[np.ix_(others, extra)])
    return M[:, extra] - M[:, others] @ W


def overdispersion(m: np.ndarray, rho: np.ndarray, clusters: np.ndarray) -> float:
    """How much the residuals scatter the efficient score of rows ``m`` (:func:`_efficient_rows`)
    beyond what the noise model says: phi = tr(S^-1 V) / k, S = sum_i m_i m_i^T the model's
    information, V the score's empirical covariance over the residuals' ``clusters`` (errors
    correlated within a time block, such as AMCL's wander, scatter the score as whole blocks):
    each row's share m_i rho_i summed per cluster, centred, times C / (C - 1). 1 when the noise
    model holds; nan with fewer than MIN_CLUSTERS clusters (rows labelled -1 left out). A
    diagnostic of the chi^2's noise scale, reported beside the selection."""
    keep = clusters >= 0
    labels, cl = np.unique(clusters[keep], return_inverse=True)
    if len(labels) < MIN_CLUSTERS:
        return float("nan")
    U = np.zeros((len(labels), m.shape[1]))
    np.add.at(U, cl, m[keep] * rho[keep, None])
    U -= U.mean(axis=0)
    V = U.T @ U * len(labels) / (len(labels) - 1)
    return float(np.trace(np.linalg.solve(m.T @ m, V)) / m.shape[1])


def held_out_gain(m: np.ndarray, rho: np.ndarray, folds: np.ndarray, prior_info: np.ndarray) -> np.ndarray:
    """Per fold f (each label >= 0 of ``folds``, in order), the chi^2 its rows lose when the
    extra parameters (rows ``m``, (n, k); residuals ``rho`` with the parameters at 0) take the
    step the other rows fit, under prior information ``prior_info`` (k, k): with
    g_f = sum_f m_i rho_i, H_f = sum_f m_i m_i^T and g, H the sums over every row, the step
    Delta = -(H - H_f + P)^-1 (g - g_f) and the held-out gain
    -(2 Delta^T g_f + Delta^T H_f Delta) = |rho_f|^2 - |rho_f + m_f Delta|^2. Rows labelled -1
    always fit. Positive: the shape fitted elsewhere predicts the held-out rows."""
    g_all = m.T @ rho
    H_all = m.T @ m
    out = []
    for f in np.unique(folds[folds >= 0]):
        r = folds == f
        g_f = m[r].T @ rho[r]
        H_f = m[r].T @ m[r]
        delta = -np.linalg.solve(H_all - H_f + prior_info, g_all - g_f)
        out.append(-(2.0 * delta @ g_f + delta @ H_f @ delta))
    return np.array(out)


def shapes(knots_m: np.ndarray) -> dict[str, np.ndarray]:
    """The one-parameter shapes of the shift against distance, as (m,) knot values c_1..c_m per
    unit of amplitude: ``linear`` (from d_0 to d_m), ``saturating@D`` (from d_0 to the interior
    knot D, flat beyond: a shift that grows, or fades, with distance and then stays) and
    ``onset@D`` (flat to D, then linear to d_m)."""
    d = np.asarray(knots_m, float)
    out = {"linear": line_of_knots(d)}
    for h in range(1, len(d) - 1):
        out[f"saturating@{d[h]:.2f}"] = (np.minimum(d[1:], d[h]) - d[0]) / (d[h] - d[0])
        out[f"onset@{d[h]:.2f}"] = np.maximum(d[1:] - d[h], 0.0) / (d[-1] - d[h])
    return out


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


def select_head_profile(prob, step: ProfileStep, nuis: list[Nuisance], folds: np.ndarray | None = None,
                        clusters: np.ndarray | None = None) -> tuple[ProfileStep, list[Nuisance], dict]:
    """The profile step and nuisances with the head profile the data support, from a step that
    holds the knots' departures (and, with ``head_profile_per_sensor``, each sensor's own
    departure delta_s). Recipe ``head_profile``: ``cv`` compares the constant shift, the
    one-parameter shapes (:func:`shapes`) and the free knots by how well each, fitted without
    one sensor's rows (``folds``, :func:`row_sensors`), predicts that sensor's
    (:func:`held_out_gain`, summed over the sensors, with its standard error from their
    spread), and keeps the simplest model within one standard error of the best, a model other
    than the constant only when its gain exceeds its own standard error. A sensor's own
    departure is kept when, fitted without one time block (``clusters``, :func:`row_clusters`),
    it predicts that block's rows, summed over the blocks, by more than z standard errors (z at
    a one-sided FAMILY_ALPHA family-wise level over the sensors): one sensor at a time, the best
    first, the others judged again with it free. ``bic`` compares the chi^2 each model gains
    against k ln(n) for k parameters and n robot-observation factors (the constant wins a tie; a
    sensor's departure against ln(n)); ``linear`` keeps the line, ``knots`` the knots (and both
    every sensor's departure). The chi^2 are the profile's decrease from the profile at 0 (the
    constant shift): a likelihood ratio, the quadratic profile being exact for nuisances that
    enter linearly. Returns (step, nuisances, what was compared: model -> (chi^2, penalty) for
    bic or (held-out gain, its standard error) for cv, "sensors" -> sensor id -> (gain, the bar
    it had to pass) at its last judgement, the model chosen, and the residuals'
    overdispersion over the time ``clusters`` (:func:`overdispersion`))."""
    idx = [j for j, n in enumerate(nuis) if n.name.startswith(PREFIX)]
    # (the departures of a random effect, head_shift_per_sensor_sigma_m, are no candidates: they
    # stay, with the other nuisances)
    own = ([] if getattr(prob.recipe, "head_shift_per_sensor_sigma_m", 0.0) > 0.0 else
           [j for j, n in enumerate(nuis) if n.name.startswith(SENSOR_PREFIX)])
    if not idx:
        return step, nuis, {}
    knots = prob._head_knots
    k_all = len(nuis)
    rest = [j for j in range(k_all) if j not in idx and j not in own]      # the other nuisances
    H = step.hessian
    # the profile moved back to 0 (b), then each model's best step from there
    b = np.zeros(k_all)
    b[idx + own] = -np.array([getattr(prob, nuis[j].name) for j in idx + own])
    g = -H @ step.dtheta + H @ b
    # each row's residual change M = A Z - B (none when some nuisances joined the variables:
    # their Z rows are gone, and the criteria fall back to the chi^2's)
    M = (np.asarray(step.A @ step.Z) - step.B.toarray()
         if step.rho0 is not None and step.A is not None and step.B is not None
         and step.A.shape[1] == step.Z.shape[0] else None)

    def best(cols):          # the nuisances' move to the best of ``cols`` (the rest of the profile at 0)
        T = np.eye(k_all)[:, cols]
        return b - T @ np.linalg.solve(T.T @ H @ T, T.T @ g)

    def chi2(T):
        return float((T.T @ g) @ np.linalg.solve(T.T @ H @ T, T.T @ g))

    mode = prob.recipe.head_profile
    compared: dict = {}
    n = max(int(np.sum(prob.fac_key_index < len(prob.pose_times))), 2)
    info = 1.0 / prob.recipe.head_profile_sigma_m ** 2
    time_folds = clusters is not None and M is not None and len(clusters) == len(step.rho0)
    # each sensor's own departure against the shared profile, forward: the best supported one
    # joins, then the others are judged again with it free (the knots free, the shift shared by
    # the sensors without one of their own; the departures not yet kept held at 0: with every
    # one free, a sensor's and the shared shift would be one direction)
    kept_own = [] if own and mode in ("cv", "bic") else list(own)
    if own and mode in ("cv", "bic"):
        compared["sensors"] = {}
        # the held-out gain's bar: z standard errors, z the one-sided 5 % family-wise level over
        # the sensors (Bonferroni), so that sensors without a tracker of their own rarely get one
        z_bar = float(ndtri(1.0 - FAMILY_ALPHA / len(own)))     # the standard normal quantile
        while True:
            others = rest + idx + kept_own
            T = np.eye(k_all)[:, others]
            verdicts = {}
            rho_others = step.rho0 + M @ best(others) if mode == "cv" and time_folds else None   # (per round)
            for j in (j for j in own if j not in kept_own):
                if mode == "cv" and time_folds:
                    m = _efficient_rows(step, nuis, [j], others, M=M)
                    gains = held_out_gain(m, rho_others, clusters, np.array([[info]]))
                    verdicts[j] = (float(gains.sum()), z_bar * float(np.sqrt(len(gains)) * np.std(gains, ddof=1)))
                else:
                    verdicts[j] = (chi2(np.eye(k_all)[:, sorted(others + [j])]) - chi2(T), float(np.log(n)))
                compared["sensors"][nuis[j].name[len(SENSOR_PREFIX):]] = verdicts[j]
            passing = [j for j, (gain, bar) in verdicts.items() if gain > bar]
            if not passing:
                break
            kept_own.append(max(passing, key=lambda j: verdicts[j][0] - verdicts[j][1]))
        kept_own.sort()
    others = sorted(rest + kept_own)
    at = sum(j < idx[0] for j in others)      # the shape's columns go where the knots were

    def with_shape(L):
        T = np.zeros((k_all, len(others) + L.shape[1]))
        T[others, :] = np.delete(np.eye(len(others) + L.shape[1]), range(at, at + L.shape[1]), axis=0)
        T[idx, at:at + L.shape[1]] = L
        return T

    models = {"constant": np.zeros((len(idx), 0)), **{n: v[:, None] for n, v in shapes(knots).items()},
              "knots": np.eye(len(idx))}
    T0 = with_shape(models["constant"])
    rho = None
    if M is not None:
        m_rows = _efficient_rows(step, nuis, idx, others, M=M)
        rho = step.rho0 + M @ best(others)      # the knots at 0, the others at their best there
        if time_folds:
            compared["overdispersion"] = overdispersion(m_rows, rho, clusters)
    cv = (mode == "cv" and rho is not None and folds is not None and len(folds) == len(rho)
          and len(np.unique(folds[folds >= 0])) >= 3)
    if cv:
        for name, L in models.items():
            gains = held_out_gain(m_rows @ L, rho, folds, info * L.T @ L) if L.shape[1] else np.zeros(3)
            compared[name] = (float(gains.sum()), float(np.sqrt(len(gains)) * np.std(gains, ddof=1)))
        top = max(models, key=lambda name: compared[name][0])
        # the simplest within one standard error of the best (the line before the bent shapes,
        # the knots last), the constant unless a model's gain exceeds its own standard error
        floor = compared[top][0] - compared[top][1]
        fits = [name for name in models if compared[name][0] >= floor
                and (name == "constant" or compared[name][0] > compared[name][1])]
        mode = fits[0] if fits else "constant"
    elif mode in ("bic", "cv"):
        # (cv without its folds: fewer than three sensors' rows, or no residuals)
        base = chi2(T0)
        for name, L in models.items():
            compared[name] = (chi2(with_shape(L)) - base, float(L.shape[1] * np.log(n)))
        mode = max(models, key=lambda name: compared[name][0] - compared[name][1])
    compared["chosen"] = mode
    for j in idx + own:      # the profile starts again from nothing (its move is in b)
        setattr(prob, nuis[j].name, 0.0)
    prob.head_profile_slope_m = 0.0
    prob._head_shape = None
    L = models[mode]
    reduced = _reduced(step, with_shape(L), b)
    kept = [nuis[j] for j in others]
    if mode in ("constant", "knots"):
        return reduced, kept[:at] + [nuis[j] for j in idx if mode == "knots"] + kept[at:], compared
    # the shape's amplitude a, each knot a L_j of prior sigma s: its prior sigma s / |L|, the
    # one the restricted Hessian T^T H T carries
    prob._head_shape = (mode, L[:, 0])
    sigma = prob.recipe.head_profile_sigma_m / max(float(np.linalg.norm(L)), 1e-9)
    return reduced, kept[:at] + [Nuisance(SLOPE, 0.0, sigma, STEP_M)] + kept[at:], compared


def profile_record(prob, names: list[str], cov: np.ndarray, horizontal_shift_m: float) -> dict | None:
    """The estimated horizontal shift at the knots, for the calibrated YAML's head model:
    {model, distance_m, shift_m, sigma_shift_m}, the shift at d_j being the constant shift plus
    c_j, its sigma from the profile's covariance ``cov`` (in ``names`` order), and with sensors'
    own departures kept, per_sensor_shift_m and sigma_per_sensor_shift_m (sensor id -> the
    shared shift plus the sensor's departure, at d_0). None when the data kept the constant
    shift for every sensor."""
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
    model, line = _shape(prob, knots)
    for j in range(1, len(knots)):
        if PREFIX + str(j) in names:
            J[j, names.index(PREFIX + str(j))] = 1.0
        if SLOPE in names:
            J[j, names.index(SLOPE)] = line[j - 1]
    sigma = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))
    shift = horizontal_shift_m + np.r_[0.0, c]
    model = model if SLOPE in names else "knots" if any(n.startswith(PREFIX) for n in names) else "constant"
    out = {"model": model, "distance_m": [round(float(v), 4) for v in knots],
           "shift_m": [round(float(v), 5) for v in shift], "sigma_shift_m": [round(float(v), 5) for v in sigma]}
    out.update(departures_record(prob, names, cov, horizontal_shift_m))
    return out


def departures_record(prob, names: list[str], cov: np.ndarray, horizontal_shift_m: float) -> dict:
    """Each sensor's own horizontal shift toward the sensor where ``names`` hold its departure
    delta_s (selected, or the random effect of ``head_shift_per_sensor_sigma_m``): per_sensor_shift_m
    (sensor id -> the shared shift plus delta_s, m) and sigma_per_sensor_shift_m (its sigma,
    sqrt(var(shared) + var(delta_s) + 2 cov(shared, delta_s)) from the profile's covariance ``cov``,
    in ``names`` order). Empty without departures or without the shared shift."""
    names = list(names)
    own = [n for n in names if n.startswith(SENSOR_PREFIX)]
    if not own or "horizontal_shift_m" not in names:
        return {}
    # (the entries read from cov: a per-sensor map J's quadratic form J cov J^T, diagonal only,
    # is a triple loop over thousands of nuisances at a large site)
    cov = np.asarray(cov, float)
    h, d = names.index("horizontal_shift_m"), np.array([names.index(n) for n in own])
    sigma = np.sqrt(np.maximum(cov[h, h] + cov[d, d] + cov[h, d] + cov[d, h], 0.0))
    ids = [n[len(SENSOR_PREFIX):] for n in own]
    return {"per_sensor_shift_m": {sid: round(float(horizontal_shift_m + getattr(prob, n)), 5)
                                   for sid, n in zip(ids, own, strict=True)},
            "sigma_per_sensor_shift_m": {sid: round(float(v), 5) for sid, v in zip(ids, sigma, strict=True)}}


PER_SENSOR_HEIGHT_NOTE = ("A tracker whose head point sits higher or lower for one sensor than for the others "
                          "moves that sensor's observations of the robot up or down alike: a vertical offset of "
                          "one sensor's own is that sensor's height error, which the robot cannot tell apart; the "
                          "installed heights as a reference (sensor_height_sigma_m) hold it.")


def head_depth_note(head_vertical_sigma_m: float) -> str:
    """What the sensors' vertical sigma rests on without a height reference: the shared vertical
    offset is known only to its prior (a dome's facing point, offset = -ray shift, give or take
    ``head_vertical_sigma_m``), so that sigma holds for a tracker whose point, seen from straight
    above, lies within it of the head top, and a point deeper in the head is a shared height
    error beyond it. (The simulator's centroid of the head's top 10 cm lies 43-50 mm below the
    top at every elevation, its shift toward the sensor 0-50 mm: the graph's point, at the prior's
    mean, stays within 7 mm of the top, 42-59 mm (1.4-2.0 sigma) above the tracker's on the zoo's
    ten centroid logs, and the sensors' heights are off by 46-63 mm, their spread 0.4-3.4 mm.)"""
    return (f"That sigma holds for a tracker whose point seen from straight above lies within "
            f"{1000 * head_vertical_sigma_m:.0f} mm of the head top (a blob's highest point, a dome's facing "
            "point): a point deeper in the head (a centroid of the head's top, 4-5 cm lower; an ellipsoid's "
            "centre or a skeleton's head joint, about the head's radius) puts every sensor that much higher, "
            "beyond its sigma. Give a height reference, the tracker's point seen from above as the log's "
            "head_offset (meta.yaml), or a head_vertical_sigma_m that covers its depth.")


def record_head_profile(head_model, prob, shifts) -> None:
    """Put the profile the solve kept (if any) into ``head_model`` (its ``horizontal_profile``),
    or without one each sensor's own shift where its departure was estimated (its
    ``per_sensor_shift_m`` and sigma, :func:`departures_record`), from the nuisances' result
    ``shifts`` (None: nothing estimated); without a height reference
    its note also says which trackers its vertical sigma holds for (:func:`head_depth_note`)
    and that a per-sensor vertical offset is a height error (PER_SENSOR_HEIGHT_NOTE)."""
    if head_model is None:
        return
    if head_model.height_reference == "none" and head_model.note:
        depth = head_depth_note(prob.recipe.head_vertical_sigma_m)
        for note in (depth, PER_SENSOR_HEIGHT_NOTE):
            if note not in head_model.note:
                head_model.note = f"{head_model.note} {note}"
    record = prob.departure_spread
    spread = spread_note(record)
    if spread and spread not in head_model.note:
        head_model.note = f"{head_model.note} {spread}".strip()
    head_model.per_sensor_shift_spread = spread_record(record)
    if shifts is None:
        return
    # (with the profile off, knots set by a line only considered at 0 are no profile)
    if prob.recipe.head_profile != "off":
        head_model.horizontal_profile = profile_record(prob, shifts.names, shifts.cov, prob.horizontal_shift_m)
    if head_model.horizontal_profile is None:
        # no profile kept: each sensor's own shift (the random effect's departures) beside the shared one
        own = departures_record(prob, shifts.names, shifts.cov, prob.horizontal_shift_m)
        head_model.per_sensor_shift_m = own.get("per_sensor_shift_m")
        head_model.sigma_per_sensor_shift_m = own.get("sigma_per_sensor_shift_m")


def shift_at(profile: dict, d_m: np.ndarray) -> np.ndarray:
    """The horizontal shift toward the sensor (m) a YAML head profile gives at horizontal
    distances ``d_m``: linear between its knots, flat beyond them."""
    return np.interp(np.asarray(d_m, float), np.asarray(profile["distance_m"], float),
                     np.asarray(profile["shift_m"], float))


def own_shift(profile: dict, sensor_id: str) -> float:
    """A sensor's own departure (m) from a YAML head profile's shared shift: its
    ``per_sensor_shift_m`` (its shift at the first knot, d_0) less the profile's ``shift_m[0]``;
    0 for a sensor without one."""
    shared_m = profile["shift_m"][0]
    return profile.get("per_sensor_shift_m", {}).get(sensor_id, shared_m) - shared_m


__all__ = ["record_head_profile", "head_depth_note", "PER_SENSOR_HEIGHT_NOTE", "head_profile_nuisances",
           "head_profile_shift_sensor", "select_head_profile",
           "profile_record", "departures_record", "is_head_profile", "hats", "horizontal_distance", "shift_at",
           "line_of_knots", "shapes",
           "held_out_gain", "own_shift", "overdispersion", "row_clusters", "row_sensors", "sensor_departures",
           "knot_values", "sensor_shift_nuisances", "is_sensor_shift", "spread_log_likelihood", "spread_summary",
           "spread_from_estimates", "estimate_departure_spread", "spread_note", "spread_record"]
