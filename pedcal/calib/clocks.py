"""Per-sensor clock offsets: each tracker PC stamps with its own clock, so each sensor's
observations are late by the shared tracker latency plus an offset of its own (NTP leaves a
tenth of a second between machines). As Kalibr estimates a camera-IMU time offset inside its
batch estimate, each sensor's offset is a nuisance of the factor graph's profile
(:func:`pedcal.calib.factorgraph._estimate_nuisances`), estimated with its sigma and carried
into the sensors' covariance; the shared latency is the association's plus the offsets' mean,
and the offsets are written about it.

An observation stamped t belongs to the instant t - latency - delta_i. Carried to its pose
variable at t_k (FactorGraphProblem.carry_observations) the head's motion from that instant is
added, so an offset delta_i moves the carried point by R_i^T (h(t) - h(t - delta_i)), to second
order delta_i R_i^T v(t - delta_i / 2), v the head's velocity: the offset enters the
observations nearly linearly, like the head point's horizontal shift
(``fac_p_sensor + delta_i R_i^T v`` in :func:`clock_shift_sensor`). Only the robot's
motion tells an offset: a sensor that sees the robot only standing, or only crossing one way
(where the offset is a shift its translation takes), keeps its prior, and its sigma says so.
"""

from __future__ import annotations

import logging

import numpy as np

from pedcal.calib.profile import Nuisance
from pedcal.metrics import CLOCK_OFFSET_KEY, LATENCY_KEY, SIGMA_CLOCK_OFFSET_KEY, SIGMA_LATENCY_KEY

PREFIX = "clock_offset_s:"                        # nuisance names: PREFIX + sensor id
MIN_FACTORS = 20        # a sensor with fewer robot-observation factors keeps the shared latency
STEP_S = 0.01           # finite-difference step of the profile (the offset enters linearly)
# half-width (s) of the central difference that gives the head's velocity: the offsets' regressor.
# Wheel odometry's white increments (a millimetre per 50 ms step) over a 40 ms difference make a
# velocity 7 % off at 0.3 m/s, AMCL's jitter far more, and an offset fitted to a noisy regressor is
# off by more than its sigma says (paper, offsets of +-0.15 s, seeds 0, 3, 4: 37 % of the offsets
# within 1 sigma at 0.02 s, 70 % at 0.25 s, 80 % at 0.5 s; without odometry 7 %, 27 %, 53 %);
# the robot's speed changes over seconds, so a second's difference keeps its shape. Taken from the
# graph's solved poses (solved_velocity_world), 73 % within 1 sigma there; on the L-shaped hall the
# offsets shared by a wing still trade with the wing's place along its axis (README).
VELOCITY_HALF_WINDOW_S = 0.5


def is_clock_nuisance(name: str) -> bool:
    return name.startswith(PREFIX)


def clock_nuisances(prob, result=None) -> list[Nuisance]:
    """The per-sensor clock offsets to estimate (recipe ``clock_offsets``, prior 0 +-
    ``clock_offset_sigma_s``), one per sensor with MIN_FACTORS robot-observation factors; each
    starts at 0 on ``prob`` the first time. ``result``: the graph's current solution, whose
    robot poses give the head's velocity from then on (:func:`solved_velocity_world`)."""
    rec = prob.recipe
    if not (rec.robot and rec.clock_offsets and rec.clock_offset_sigma_s > 0.0) or prob.fac_sensor_index is None:
        return []
    counts = np.bincount(prob.fac_sensor_index, minlength=len(prob.sensor_ids))
    out = []
    for i, sid in enumerate(prob.sensor_ids):
        if counts[i] >= MIN_FACTORS:
            name = PREFIX + sid
            if not hasattr(prob, name):
                setattr(prob, name, 0.0)
            out.append(Nuisance(name, 0.0, rec.clock_offset_sigma_s, STEP_S))
    if out and result is not None:
        prob._pose_velocity_world = solved_velocity_world(prob, result)
    return out


def solved_velocity_world(prob, result) -> np.ndarray | None:
    """(n_poses, 3) the head's world velocity at each robot pose from the solved poses: a
    central difference over +-VELOCITY_HALF_WINDOW_S of the graph's x(k), which fuse odometry
    (or AMCL's motion) with what every sensor saw. Without odometry the raw motion is AMCL's
    own, whose wandering error's increments (a few cm/s over a second) the regressor would
    carry; the solved path is the better measure of it. None without poses."""
    from pedcal.calib.keys import X

    t = prob.pose_times
    n = sum(1 for k in range(len(t)) if result.exists(X(k)))
    if n < 2:
        return None
    x = np.array([result.atPose3(X(k)).translation() for k in range(n)])
    t = t[:n]
    lo = np.clip(np.searchsorted(t, t - VELOCITY_HALF_WINDOW_S), 0, n - 1)
    hi = np.clip(np.searchsorted(t, t + VELOCITY_HALF_WINDOW_S), 0, n - 1)
    dt = t[hi] - t[lo]
    v = (x[hi] - x[lo]) / np.maximum(dt, 1e-9)[:, None]
    v[dt <= 0.0] = 0.0
    return v


def _velocity_world_at(prob, t: np.ndarray) -> np.ndarray:
    """(n, 3) the head's world velocity at times ``t``: the solved poses' central difference
    (:func:`solved_velocity_world`) taken linearly between the poses, or, before any solve, the
    robot's motion's over +-VELOCITY_HALF_WINDOW_S."""
    pose_v = getattr(prob, "_pose_velocity_world", None)
    if pose_v is None or len(pose_v) < 2:
        return prob.motion.velocity(t, h=VELOCITY_HALF_WINDOW_S)
    tp = prob.pose_times[:len(pose_v)]
    return np.column_stack([np.interp(t, tp, pose_v[:, c]) for c in range(3)])


def _sensor_rotations(prob) -> np.ndarray:
    """(n_factors, 3, 3) each robot-observation factor's sensor rotation R_world_sensor (the
    sensors' initial ones: a degree off changes a millimetre-sized term by a few per cent);
    cached on the problem until its factors change."""
    cached = getattr(prob, "_clock_rotations", None)
    # the cache holds the array it was made from, so an identity test cannot meet a new array
    # that took a freed one's id (ids are reused once an object is gone)
    if cached is not None and cached[0] is prob.fac_sensor_index:
        return cached[1]
    R = np.stack([prob.init_sensors[sid].rotation().matrix() for sid in prob.sensor_ids])[prob.fac_sensor_index]
    prob._clock_rotations = (prob.fac_sensor_index, R)
    return R


def clock_shift_sensor(prob, theta: dict, use: np.ndarray) -> np.ndarray | float:
    """What the sensors' clock offsets add to the robot-observation factors ``use`` (sensor
    frame, m): the head's motion over the offset, R_i^T (h(t) - h(t - delta_i)), t the factor's
    pose time (its observations carried there with the shared latency; module docstring), to
    second order delta_i R_i^T v(t - delta_i / 2): the velocity at the middle of the interval,
    not at its end (at its end the shift is off by a delta^2 / 2, a few millimetres for a tenth
    of a second on a turn, which the offsets of the sensors that see the turns absorb: a bias
    of several of their sigma). ``theta`` overrides the problem's offsets by name. 0 when no
    offset is estimated."""
    offsets = np.zeros(len(prob.sensor_ids))
    any_set = False
    for i, sid in enumerate(prob.sensor_ids):
        name = PREFIX + sid
        value = theta.get(name, getattr(prob, name, 0.0))
        if value:
            offsets[i] = value
            any_set = True
    if not any_set:
        return 0.0
    delta = offsets[prob.fac_sensor_index[use]]
    v_world = _velocity_world_at(prob, prob.pose_times[prob.fac_key_index[use]] - 0.5 * delta)
    return delta[:, None] * np.einsum("nji,nj->ni", _sensor_rotations(prob)[use], v_world)


def centered_offsets(delta_s: np.ndarray, cov_s2: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The offsets ``delta_s`` (n,) with covariance ``cov_s2`` (n, n) split into their mean, the
    shared latency's correction, and each offset about it, so that the latency and the offsets
    do not count the same time twice: (mean, its sigma, delta - mean, the sigma of each
    delta_i - mean). With c_i = e_i - 1/n (e_i the i-th unit vector), var(delta_i - mean) =
    c_i^T C c_i, and var(mean) = 1^T C 1 / n^2: offsets that move together (a latency error they
    share) leave the centred ones sure and the mean unsure, not each offset unsure."""
    delta_s = np.asarray(delta_s, float)
    cov_s2 = np.asarray(cov_s2, float)
    mean = float(delta_s.mean())
    total = float(cov_s2.mean())                     # 1^T C 1 / n^2
    sigma_mean = float(np.sqrt(max(total, 0.0)))
    # c_i^T C c_i = C_ii - 2 (C 1)_i / n + 1^T C 1 / n^2, in O(n^2)
    sigma = np.sqrt(np.maximum(np.diag(cov_s2) - 2.0 * cov_s2.mean(axis=1) + total, 0.0))
    return mean, sigma_mean, delta_s - mean, sigma


def record_clocks(network, prob, shifts) -> None:
    """Write the estimated clock offsets to the calibrated network: the shared latency becomes
    the association's plus the offsets' mean, with that mean's sigma, and each sensor's offset
    is taken about it, with the sigma of its departure from the mean
    (:func:`centered_offsets`, from the profile's covariance; ``shifts``: the profile's
    result). Offsets whose sigma was fitted per sensor given the robot's path (above the recipe's
    ``clock_offsets_joint_max``) are logged as such: that sigma leaves out the path's share."""
    if shifts is None:
        return
    idx = [j for j, n in enumerate(shifts.names) if is_clock_nuisance(n)]
    if not idx:
        return
    ids = [shifts.names[j][len(PREFIX):] for j in idx]
    if getattr(shifts, "local", None) is not None:
        logging.getLogger(__name__).warning(
            f"{len(ids)} sensors' clock offsets (more than clock_offsets_joint_max = "
            f"{prob.recipe.clock_offsets_joint_max}): each offset's sigma (and its share of its sensor's "
            "covariance) is its own profile's given the robot's path; their coupling through the path is "
            "left out, so those sigmas are lower bounds"
            + (" (so are those of the sensors' own head shift departures, fitted alike)"
               if getattr(prob.recipe, "head_shift_per_sensor_sigma_m", 0.0) > 0.0 else ""))
    delta = np.array([getattr(prob, shifts.names[j]) for j in idx])
    mean, sigma_mean, centred, sigma = centered_offsets(delta, np.asarray(shifts.cov)[np.ix_(idx, idx)])
    network.extra[LATENCY_KEY] = round(prob.latency_s + mean, 4)
    network.extra[SIGMA_LATENCY_KEY] = round(sigma_mean, 4)
    network.extra[CLOCK_OFFSET_KEY] = {sid: round(float(d), 4) for sid, d in zip(ids, centred, strict=True)}
    network.extra[SIGMA_CLOCK_OFFSET_KEY] = {sid: round(float(s), 4) for sid, s in zip(ids, sigma, strict=True)}


__all__ = ["clock_nuisances", "clock_shift_sensor", "record_clocks", "is_clock_nuisance", "centered_offsets"]
