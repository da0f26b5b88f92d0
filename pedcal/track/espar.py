"""The ESPAR antenna likelihood P(Z | A) of Misu and Miura (Sec. 4.3, eqs. 10-12).

Z is a reading (the direction index the antenna reports, 30 deg apart), A a hypothesized bearing
of the target seen from that antenna. The model is a Gaussian in the wrapped angle difference
between Z's direction and A, normalized over the n directions so it is a distribution over Z,
mixed with a uniform floor for multipath:

    P(Z = k | A) = (1 - m) g(d_k) / sum_j g(d_k + j s) + m / n,   g(d) = exp(-d^2 / (2 sigma^2))

with d_k = wrap(theta_k - A), s = 2 pi / n. Both sigma and m are FITTED by maximum likelihood to
readings drawn from :mod:`pedcal.sim.espar` (:func:`fit_espar_likelihood`); for the default
:class:`~pedcal.sim.espar.EsparParams` (sigma 20 deg before quantization, multipath 0.1)
``fit_espar_likelihood(EsparParams(), n=20000, seed=0)`` gives sigma = 21.83 deg (sqrt(20^2 + 30^2 / 12)
= 21.79 deg is the noise plus the quantization's spread) and m = 0.104;
those are :data:`DEFAULT_LIKELIHOOD`. Eq. 10: the readings of the two antennas are independent
given the target's place, so the likelihood of a target position is their product.

Frames: everything is in the robot frame (x forward, y left, metres; bearings counter-clockwise
from x, radians).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from pedcal.follow_types import EsparReading
from pedcal.frames import wrap_angle_rad
from pedcal.sim.espar import EsparParams, quantized_directions


@dataclass(frozen=True)
class EsparLikelihood:
    """P(Z | A): a Gaussian of ``sigma_rad`` in the wrapped angle difference, floor ``floor``."""

    sigma_rad: float
    floor: float  # the multipath probability m: a reading is uniform over the n directions
    n_directions: int = 12

    @property
    def spacing_rad(self) -> float:
        return 2.0 * np.pi / self.n_directions

    def p_direction(self, diff_rad: np.ndarray) -> np.ndarray:
        """P(Z | A) for d = wrap(theta_Z - A) of any shape (the eq. above)."""
        d = wrap_angle_rad(diff_rad)
        shifts = self.spacing_rad * np.arange(self.n_directions)
        g_all = np.exp(-0.5 * (wrap_angle_rad(d[..., None] + shifts) / self.sigma_rad) ** 2)
        g = np.exp(-0.5 * (d / self.sigma_rad) ** 2)
        return (1.0 - self.floor) * g / g_all.sum(axis=-1) + self.floor / self.n_directions

    def likelihood_grid(self, readings: Sequence[EsparReading], xy_robot_m: np.ndarray) -> np.ndarray:
        """(N,) product over ``readings`` of P(Z | A) for targets at ``xy_robot_m`` (N, 2), A the
        bearing of each position from the reading's antenna (eq. 10). No readings: all ones."""
        xy = np.asarray(xy_robot_m, dtype=float).reshape(-1, 2)
        if len(readings) == 0:
            return np.ones(len(xy))
        bearing_z = np.array([r.bearing_robot_rad for r in readings])
        xy_ant = np.array([np.asarray(r.xy_antenna_robot_m, dtype=float) for r in readings])
        d = xy[None, :, :] - xy_ant[:, None, :]  # (R, N, 2)
        a = np.arctan2(d[..., 1], d[..., 0])
        return np.prod(self.p_direction(bearing_z[:, None] - a), axis=0)

    def likelihood(self, readings: Sequence[EsparReading], xy_target_robot_m: np.ndarray) -> float:
        """P(readings | target at ``xy_target_robot_m``), the product of eq. 10."""
        return float(self.likelihood_grid(readings, np.asarray(xy_target_robot_m, dtype=float)[None, :2])[0])

    @property
    def p_lost(self) -> float:
        """P(Z | lost): the target could be anywhere, so every direction is equally likely."""
        return 1.0 / self.n_directions


def fit_espar_likelihood(params: EsparParams | None = None, n: int = 20000, seed: int = 0) -> EsparLikelihood:
    """Fit sigma and the multipath floor of :class:`EsparLikelihood` by maximum likelihood to ``n``
    readings simulated with ``params`` at uniformly random true bearings."""
    params = params if params is not None else EsparParams()
    rng = np.random.default_rng(seed)
    a = rng.uniform(-np.pi, np.pi, n)
    k = quantized_directions(a, params, rng)
    diff = wrap_angle_rad(k * params.spacing_rad - a)

    def nll(v: np.ndarray) -> float:
        model = EsparLikelihood(float(np.exp(v[0])), float(1.0 / (1.0 + np.exp(-v[1]))), params.n_directions)
        return -float(np.log(model.p_direction(diff)).sum())

    x0 = np.array([np.log(max(np.radians(params.sigma_deg), 0.5 * params.spacing_rad)), -2.0])
    res = minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-3})
    return EsparLikelihood(float(np.exp(res.x[0])), float(1.0 / (1.0 + np.exp(-res.x[1]))), params.n_directions)


# fit_espar_likelihood(EsparParams(), n=20000, seed=0); tests/test_espar.py checks it still holds.
DEFAULT_LIKELIHOOD = EsparLikelihood(sigma_rad=float(np.radians(21.83)), floor=0.104, n_directions=12)


def likelihood(readings: Sequence[EsparReading], xy_target_robot_m: np.ndarray,
               model: EsparLikelihood = DEFAULT_LIKELIHOOD) -> float:
    """P(readings | target at ``xy_target_robot_m``) (eq. 10) under ``model``."""
    return model.likelihood(readings, xy_target_robot_m)


def likelihood_grid(readings: Sequence[EsparReading], xy_robot_m: np.ndarray,
                    model: EsparLikelihood = DEFAULT_LIKELIHOOD) -> np.ndarray:
    """(N,) P(readings | target at each row of ``xy_robot_m``) (eq. 10) under ``model``."""
    return model.likelihood_grid(readings, xy_robot_m)


__all__ = ["EsparLikelihood", "fit_espar_likelihood", "likelihood", "likelihood_grid", "DEFAULT_LIKELIHOOD"]
