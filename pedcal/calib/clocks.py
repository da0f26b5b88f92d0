"""Per-sensor clock offsets: each tracker PC stamps with its own clock, so each sensor's
observations are late by the shared tracker latency plus an offset of its own (NTP leaves a
tenth of a second between machines). As Kalibr estimates a camera-IMU time offset inside its
batch estimate, each sensor's offset is a nuisance of the factor graph's profile
(:func:`pedcal.calib.factorgraph._estimate_nuisances`), estimated with its sigma and carried
into the sensors' covariance; the shared latency is the association's plus the offsets' mean,
and the offsets are written about it.

An observation stamped t belongs to the instant t - latency - delta_i. Carried to its pose
variable at t_k (FactorGraphProblem.carry_observations) the head's motion from that instant is
added, so an offset delta_i moves the carried point by R_i^T v delta_i to first order, v the
head's velocity: the offset enters the observations linearly, like the head point's horizontal
shift (``fac_p_sensor + delta_i R_i^T v`` in :func:`clock_shift_sensor`). Only the robot's
motion tells an offset: a sensor that sees the robot only standing, or only crossing one way
(where the offset is a shift its translation takes), keeps its prior, and its sigma says so.
"""

from __future__ import annotations

import numpy as np

from pedcal.calib.profile import Nuisance
from pedcal.metrics import CLOCK_OFFSET_KEY, LATENCY_KEY, SIGMA_CLOCK_OFFSET_KEY

PREFIX = "clock_offset_s:"                        # nuisance names: PREFIX + sensor id
MIN_FACTORS = 20        # a sensor with fewer robot-observation factors keeps the shared latency
STEP_S = 0.01           # finite-difference step of the profile (the offset enters linearly)


def is_clock_nuisance(name: str) -> bool:
    return name.startswith(PREFIX)


def clock_nuisances(prob) -> list[Nuisance]:
    """The per-sensor clock offsets to estimate (recipe ``clock_offsets``, prior 0 +-
    ``clock_offset_sigma_s``), one per sensor with MIN_FACTORS robot-observation factors; each
    starts at 0 on ``prob`` the first time."""
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
    return out


def _velocity_sensor(prob) -> np.ndarray:
    """(n_factors, 3) the head's velocity at each robot-observation factor's pose time, in its
    sensor's frame (the sensors' initial rotations: a degree off changes a millimetre-sized term
    by a few per cent); cached on the problem until its factors change."""
    key = (id(prob.fac_key_index), len(prob.fac_key_index))
    cached = getattr(prob, "_clock_velocity", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    v_world = prob.motion.velocity(prob.pose_times[prob.fac_key_index])
    R = np.stack([prob.init_sensors[sid].rotation().matrix() for sid in prob.sensor_ids])[prob.fac_sensor_index]
    v = np.einsum("nji,nj->ni", R, v_world)
    prob._clock_velocity = (key, v)
    return v


def clock_shift_sensor(prob, theta: dict, use: np.ndarray) -> np.ndarray | float:
    """What the sensors' clock offsets add to the robot-observation factors ``use`` (sensor
    frame, m): delta_i R_i^T v (module docstring); ``theta`` overrides the problem's offsets by
    name. 0 when no offset is estimated."""
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
    return offsets[prob.fac_sensor_index[use], None] * _velocity_sensor(prob)[use]


def record_clocks(network, prob, shifts) -> None:
    """Write the estimated clock offsets to the calibrated network: the shared latency becomes
    the association's plus the offsets' mean, each sensor's offset is taken about it, with its
    sigma from the profile's covariance (``shifts``: the profile's result)."""
    if shifts is None:
        return
    idx = [j for j, n in enumerate(shifts.names) if is_clock_nuisance(n)]
    if not idx:
        return
    ids = [shifts.names[j][len(PREFIX):] for j in idx]
    delta = np.array([getattr(prob, shifts.names[j]) for j in idx])
    sigma = np.sqrt(np.diag(shifts.cov)[idx])
    mean = float(delta.mean())
    network.extra[LATENCY_KEY] = round(prob.latency_s + mean, 4)
    network.extra[CLOCK_OFFSET_KEY] = {sid: round(float(d - mean), 4) for sid, d in zip(ids, delta, strict=True)}
    network.extra[SIGMA_CLOCK_OFFSET_KEY] = {sid: round(float(s), 4) for sid, s in zip(ids, sigma, strict=True)}


__all__ = ["clock_nuisances", "clock_shift_sensor", "record_clocks", "is_clock_nuisance"]
