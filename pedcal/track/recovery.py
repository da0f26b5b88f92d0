"""Target recovery as a factor graph: a fixed-lag smoother over the target's recent positions.

Variables (GTSAM keys): per LIDAR frame k the robot's pose ``x_k`` (Pose2), the target's position
``t_k`` and velocity ``v_k`` (Point2, world frame); per ESPAR reading the antenna's pose ``a_j``.

Factors:
- ``PriorFactorPose2`` on x_k: the robot's localization with its covariance (world x, y, yaw turned
  into GTSAM's body-frame tangent);
- constant-velocity motion, t_{k+1} = t_k + v_k dt, and a first-order Gauss-Markov velocity,
  v_{k+1} = e^(-dt/tau) v_k, whose stationary spread is the walking speed (so velocity stays bounded
  while nothing observes it): two linear custom factors, Jacobians checked numerically in the tests;
- ``BearingRangeFactor2D`` x_k -> t_k for a LIDAR detection of the target;
- ``BearingFactor2D`` a_j -> t_k for an ESPAR reading (Misu and Miura's eq. 10 antenna model as a
  factor). The antenna sits off the robot's centre: it is its own Pose2 a_j, tied to x_k by a
  ``BetweenFactorPose2`` with the mount offset (tight, 1 mm / 0.1 deg), so the bearing starts at the
  antenna, not the robot's centre. Sigma is the fitted spread of the antenna model, never tighter
  than the quantization's 30 deg / sqrt(12); a Cauchy kernel keeps multipath readings (uniformly
  random directions) from dragging the estimate;
- a weak ``PriorFactorPoint2`` seed from the grid belief (its dominant component) when the target has
  been out of sight.

As the robot moves, bearings from different places triangulate the target without stopping.
``gtsam.IncrementalFixedLagSmoother`` (iSAM2) keeps the last ``lag_s`` seconds and marginalizes older
variables into a prior.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import gtsam
import numpy as np
from gtsam.symbol_shorthand import A, T, V, X

from pedcal.errors import PedcalInputError
from pedcal.track.espar import DEFAULT_LIKELIHOOD
from pedcal.track.types import EsparReading

ESPAR_QUANTIZATION_SIGMA_RAD = math.radians(30.0) / math.sqrt(12.0)
_I2 = np.eye(2)


@dataclass(frozen=True)
class SmootherConfig:
    """The smoother's noise models and window; recorded with the tracker's results."""

    lag_s: float = 10.0
    walk_speed_mps: float = 1.2            # stationary spread of the target's velocity (per axis)
    velocity_tau_s: float = 3.0            # how long the target keeps its velocity (Gauss-Markov time)
    position_noise_m: float = 0.05         # unmodelled motion per step on top of constant velocity
    espar_sigma_rad: float = max(DEFAULT_LIKELIHOOD.sigma_rad, ESPAR_QUANTIZATION_SIGMA_RAD)
    espar_cauchy_k: float = 1.0            # Cauchy kernel scale, in sigmas
    lidar_bearing_sigma_rad: float = math.radians(3.0)
    lidar_range_sigma_m: float = 0.1       # box centre vs the person's centre
    mount_sigma_m: float = 1e-3
    mount_sigma_rad: float = math.radians(0.1)

    def __post_init__(self):
        if self.espar_sigma_rad < ESPAR_QUANTIZATION_SIGMA_RAD:
            raise PedcalInputError(f"smoother: espar_sigma_rad {self.espar_sigma_rad:.4f} is tighter than the "
                                   f"quantization's 30 deg / sqrt(12) = {ESPAR_QUANTIZATION_SIGMA_RAD:.4f} rad")
        for name in ("lag_s", "walk_speed_mps", "velocity_tau_s", "position_noise_m", "lidar_bearing_sigma_rad",
                     "lidar_range_sigma_m", "espar_cauchy_k"):
            if not getattr(self, name) > 0:
                raise PedcalInputError(f"smoother: {name} must be positive, got {getattr(self, name)}")


def constant_velocity_error(dt_s: float, factor: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
    """e = t_{k+1} - t_k - v_k dt (keys t_k, t_{k+1}, v_k)."""
    k0, k1, kv = factor.keys()
    if jacobians is not None:
        jacobians[0] = -_I2
        jacobians[1] = _I2
        jacobians[2] = -dt_s * _I2
    return values.atPoint2(k1) - values.atPoint2(k0) - dt_s * values.atPoint2(kv)


def gauss_markov_velocity_error(decay: float, factor: gtsam.CustomFactor, values: gtsam.Values,
                                jacobians) -> np.ndarray:
    """e = v_{k+1} - decay v_k (keys v_k, v_{k+1}); decay = exp(-dt / tau)."""
    k0, k1 = factor.keys()
    if jacobians is not None:
        jacobians[0] = -decay * _I2
        jacobians[1] = _I2
    return values.atPoint2(k1) - decay * values.atPoint2(k0)


def pose2_prior_noise(pose_world_robot: np.ndarray, cov_world_robot: np.ndarray) -> gtsam.noiseModel.Base:
    """GTSAM's Pose2 tangent is (x, y) in the body frame then theta: turn the world covariance into it."""
    c, s = math.cos(pose_world_robot[2]), math.sin(pose_world_robot[2])
    J = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])       # R^T on the translation block
    cov = J @ np.asarray(cov_world_robot, dtype=float) @ J.T
    cov = 0.5 * (cov + cov.T) + 1e-10 * np.eye(3)
    return gtsam.noiseModel.Gaussian.Covariance(cov)


class TargetSmoother:
    """Fixed-lag smoother of the target's world position from LIDAR detections and ESPAR bearings."""

    def __init__(self, config: SmootherConfig | None = None):
        self.config = config or SmootherConfig()
        cfg = self.config
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        self._smoother = gtsam.IncrementalFixedLagSmoother(cfg.lag_s, params)
        self._k = -1                     # index of the latest frame
        self._t_prev_s: float | None = None
        self._n_antenna = 0
        self._xy_latest: np.ndarray | None = None
        self._v_latest = np.zeros(2)
        cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(cfg.espar_cauchy_k)
        self._espar_noise = gtsam.noiseModel.Robust.Create(
            cauchy, gtsam.noiseModel.Isotropic.Sigma(1, cfg.espar_sigma_rad))
        self._lidar_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.lidar_bearing_sigma_rad, cfg.lidar_range_sigma_m]))
        self._mount_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.mount_sigma_m, cfg.mount_sigma_m, cfg.mount_sigma_rad]))

    @property
    def started(self) -> bool:
        return self._k >= 0

    def add_frame(self, t_s: float, pose_world_robot, cov_world_robot, detection_xy_robot_m=None,
                  espar: tuple[EsparReading, ...] = (), seed_xy_world_m=None, seed_sigma_m: float | None = None
                  ) -> np.ndarray | None:
        """Add one frame's robot pose and measurements, update, and return the target's latest position.

        The first frame needs a detection or a seed (something must say where the target starts).
        Returns None while nothing has started the smoother.
        """
        cfg = self.config
        pose = np.asarray(pose_world_robot, dtype=float)
        T_world_robot = gtsam.Pose2(*pose)
        det = None if detection_xy_robot_m is None else np.asarray(detection_xy_robot_m, dtype=float)
        if not self.started:
            if det is not None:
                start = T_world_robot.transformFrom(det)
                start_sigma = 0.3
            elif seed_xy_world_m is not None:
                start = np.asarray(seed_xy_world_m, dtype=float)
                start_sigma = seed_sigma_m or 3.0
            else:
                return None
            self._xy_latest = start
            seed_xy_world_m, seed_sigma_m = start, start_sigma
        if self._t_prev_s is not None and t_s <= self._t_prev_s:
            raise PedcalInputError(f"smoother: frame times must increase, got {t_s} after {self._t_prev_s}")

        k = self._k + 1
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()

        def new(key, value, insert):
            insert(key, value)
            stamps.insert((key, t_s))

        new(X(k), T_world_robot, values.insert)
        graph.add(gtsam.PriorFactorPose2(X(k), T_world_robot, pose2_prior_noise(pose, cov_world_robot)))

        # initial guess of the target: the detection, else the constant-velocity prediction
        if det is not None:
            xy0 = T_world_robot.transformFrom(det)
        elif self.started:
            xy0 = self._xy_latest + self._v_latest * (t_s - self._t_prev_s)
        else:
            xy0 = self._xy_latest
        new(T(k), np.asarray(xy0, dtype=float), values.insert)
        new(V(k), self._v_latest.copy(), values.insert)

        if self.started:
            dt = t_s - self._t_prev_s
            decay = math.exp(-dt / cfg.velocity_tau_s)
            sigma_v = cfg.walk_speed_mps * math.sqrt(max(1.0 - decay * decay, 1e-9))
            graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(2, cfg.position_noise_m * math.sqrt(dt)),
                                         [T(k - 1), T(k), V(k - 1)], partial(constant_velocity_error, dt)))
            graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(2, sigma_v), [V(k - 1), V(k)],
                                         partial(gauss_markov_velocity_error, decay)))
        else:
            graph.add(gtsam.PriorFactorPoint2(V(k), self._v_latest.copy(),
                                              gtsam.noiseModel.Isotropic.Sigma(2, cfg.walk_speed_mps)))

        if det is not None:
            graph.add(gtsam.BearingRangeFactor2D(X(k), T(k), gtsam.Rot2(math.atan2(det[1], det[0])),
                                                 float(np.hypot(det[0], det[1])), self._lidar_noise))
        for reading in espar:
            mount = np.asarray(reading.xy_antenna_robot_m, dtype=float)
            T_robot_antenna = gtsam.Pose2(mount[0], mount[1], 0.0)
            key = A(self._n_antenna)
            self._n_antenna += 1
            new(key, T_world_robot.compose(T_robot_antenna), values.insert)
            graph.add(gtsam.BetweenFactorPose2(X(k), key, T_robot_antenna, self._mount_noise))
            # the reading's bearing is in the robot frame; the antenna's frame is the robot's turned by 0
            graph.add(gtsam.BearingFactor2D(key, T(k), gtsam.Rot2(reading.bearing_robot_rad), self._espar_noise))
        if seed_xy_world_m is not None:
            graph.add(gtsam.PriorFactorPoint2(T(k), np.asarray(seed_xy_world_m, dtype=float),
                                              gtsam.noiseModel.Isotropic.Sigma(2, float(seed_sigma_m or 3.0))))

        self._smoother.update(graph, values, stamps)
        self._k, self._t_prev_s = k, t_s
        estimate = self._smoother.calculateEstimate()
        self._xy_latest = estimate.atPoint2(T(k))
        self._v_latest = estimate.atPoint2(V(k))
        return self._xy_latest.copy()

    def latest(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The target's latest world position and its marginal covariance (None before the start)."""
        if not self.started:
            return None
        return self._xy_latest.copy(), np.asarray(self._smoother.marginalCovariance(T(self._k)))

    def latest_velocity(self) -> np.ndarray:
        return self._v_latest.copy()
