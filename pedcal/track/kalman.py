"""Constant-velocity Kalman filter of one person in the WORLD frame (Misu and Miura, Sec. 4.1-4.3).

State x = (x_m, y_m, vx_mps, vy_mps) in the world (map) frame. Detections arrive in the robot
frame; :func:`detection_world` moves them to the world with the robot's localization and adds the
localization's uncertainty to the LIDAR noise (first order). The ESPAR bearing is an EKF update
(eq. 6) with the antenna's position and the robot's yaw.

Filter management by entropy (eqs. 7-8). The paper uses the quadratic Renyi entropy of the 2-D
position Gaussian, H2 = ln(4 pi sqrt(det P_xy)); in metres it is negative for any filter worth
keeping, so "drops by 50 %" / "rises by 20 %" need a scale on which percentages mean something:

- confirmation: the uncertainty AREA a = sqrt(det P_xy) (m^2, proportional to exp(H2)) has fallen to
  ``CONFIRM_AREA_RATIO`` = 50 % of ``area_ref_m2``, the area of the filter's first prediction (one
  frame after creation, when its velocity is still unknown); in entropy this is a drop of ln 2;
- deletion: H2 computed with P in mm^2 (positive for any sigma above 0.3 mm) has risen
  ``DELETE_ENTROPY_RISE`` = 20 % above its minimum over the filter's life, or the area exceeds
  ``MAX_AREA_M2``. For a filter whose minimum sigma was 40 mm this is sigma growing about 2.7 times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedcal.frames import wrap_angle_rad

SIGMA_LIDAR_M = 0.05  # the FX8's +-50 mm
SIGMA_ACCEL_MPS2 = 0.7  # white-noise acceleration of a walking person
SIGMA_V0_MPS = 1.0  # the unknown velocity of a new filter
CONFIRM_AREA_RATIO = 0.5
DELETE_ENTROPY_RISE = 0.2
MAX_AREA_M2 = 1.0  # sigma about 1 m: nobody knows where this person is


# ------------------------------------------------------------------------------------------ algebra
def cv_transition(dt_s: float) -> np.ndarray:
    """F of the constant-velocity model over ``dt_s`` (eq. 2)."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt_s
    return F


def cv_process_noise(dt_s: float, sigma_accel_mps2: float = SIGMA_ACCEL_MPS2) -> np.ndarray:
    """Q of piecewise-constant white acceleration: G G^T sigma_a^2 with G = (dt^2/2, dt) per axis."""
    a, b, c = sigma_accel_mps2 ** 2 * np.array([dt_s ** 4 / 4, dt_s ** 3 / 2, dt_s ** 2])
    return np.array([[a, 0, b, 0], [0, a, 0, b], [b, 0, c, 0], [0, b, 0, c]])


def predict(x: np.ndarray, P: np.ndarray, dt_s: float,
            sigma_accel_mps2: float = SIGMA_ACCEL_MPS2) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: x <- F x, P <- F P F^T + Q."""
    F = cv_transition(dt_s)
    return F @ x, F @ P @ F.T + cv_process_noise(dt_s, sigma_accel_mps2)


H_POS = np.hstack([np.eye(2), np.zeros((2, 2))])


def update_position(x: np.ndarray, P: np.ndarray, z_world: np.ndarray,
                    R_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 5 with H = [I 0]: K = P H^T (H P H^T + R)^-1, x += K (z - H x), P = (I - K H) P
    (Joseph form, so P stays symmetric positive definite)."""
    S = P[:2, :2] + R_world
    K = np.linalg.solve(S, P[:2, :]).T  # P H^T S^-1, S symmetric
    x_new = x + K @ (z_world - x[:2])
    IKH = np.eye(4) - K @ H_POS
    return x_new, IKH @ P @ IKH.T + K @ R_world @ K.T


def mahalanobis(x: np.ndarray, P: np.ndarray, z_world: np.ndarray, R_world: np.ndarray) -> np.ndarray:
    """Mahalanobis distance d of detections ``z_world`` (M, 2) with covariances ``R_world`` (M, 2, 2)
    (or one (2, 2)) from the predicted position: d^2 = nu^T (H P H^T + R)^-1 nu (eq. 4)."""
    z = np.atleast_2d(z_world)
    S = P[:2, :2] + np.asarray(R_world)
    nu = z - x[:2]
    return np.sqrt(np.einsum("mi,mi->m", nu, np.linalg.solve(S, nu[..., None])[..., 0]))


def mahalanobis_matrix(X: np.ndarray, Ps: np.ndarray, z_world: np.ndarray, R_world: np.ndarray) -> np.ndarray:
    """(T, M) Mahalanobis distances of M detections from T filters' predicted positions at once
    (states ``X`` (T, 4), covariances ``Ps`` (T, 4, 4), detections (M, 2) with ``R_world`` (M, 2, 2))."""
    S = Ps[:, None, :2, :2] + R_world[None]
    nu = z_world[None, :, :] - X[:, None, :2]
    return np.sqrt(np.einsum("tmi,tmi->tm", nu, np.linalg.solve(S, nu[..., None])[..., 0]))


def rot2(yaw_rad: float) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s], [s, c]])


def detection_world(xy_robot_m: np.ndarray, pose_world_robot: np.ndarray, cov_world_robot: np.ndarray,
                    sigma_lidar_m: float = SIGMA_LIDAR_M) -> tuple[np.ndarray, np.ndarray]:
    """A robot-frame detection in the world frame and its covariance: p_world = t + R(yaw) p_robot,
    R_world = R(yaw) sigma_lidar^2 I R(yaw)^T + J cov_pose J^T with J = d p_world / d(x, y, yaw)."""
    z, R = detections_world(np.asarray(xy_robot_m, dtype=float)[None, :2], pose_world_robot, cov_world_robot,
                            sigma_lidar_m)
    return z[0], R[0]


def detections_world(xy_robot_m: np.ndarray, pose_world_robot: np.ndarray, cov_world_robot: np.ndarray,
                     sigma_lidar_m: float = SIGMA_LIDAR_M) -> tuple[np.ndarray, np.ndarray]:
    """:func:`detection_world` for M detections (M, 2) at once: (M, 2) points, (M, 2, 2) covariances."""
    p_robot = np.asarray(xy_robot_m, dtype=float).reshape(-1, 2)
    Rot = rot2(float(pose_world_robot[2]))
    z = pose_world_robot[:2] + p_robot @ Rot.T
    J = np.zeros((len(p_robot), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, :, 2] = np.column_stack([-p_robot[:, 1], p_robot[:, 0]]) @ Rot.T
    return z, sigma_lidar_m ** 2 * np.eye(2) + J @ np.asarray(cov_world_robot) @ J.transpose(0, 2, 1)


def bearing_h(x: np.ndarray, xy_antenna_world_m: np.ndarray, yaw_robot_rad: float) -> float:
    """Eq. 6: the target's bearing in the robot frame, h = atan2(y - y_a, x - x_a) - yaw_r."""
    d = x[:2] - xy_antenna_world_m
    return float(wrap_angle_rad(np.arctan2(d[1], d[0]) - yaw_robot_rad))


def bearing_jacobian(x: np.ndarray, xy_antenna_world_m: np.ndarray) -> np.ndarray:
    """(4,) dh/dx of eq. 6: (-(y - y_a), x - x_a, 0, 0) / r^2."""
    d = x[:2] - xy_antenna_world_m
    r2 = float(d @ d)
    return np.array([-d[1] / r2, d[0] / r2, 0.0, 0.0])


def update_bearing(x: np.ndarray, P: np.ndarray, bearing_robot_rad: float, xy_antenna_world_m: np.ndarray,
                   yaw_robot_rad: float, sigma_rad: float, var_yaw_rad2: float = 0.0,
                   gate: float = 2.5) -> tuple[np.ndarray, np.ndarray, bool]:
    """EKF update of eq. 6 with one ESPAR bearing (noise ``sigma_rad``, the fitted likelihood's, plus
    the robot's yaw variance since dh/dyaw_r = -1). A reading whose normalized innovation exceeds
    ``gate`` is taken for multipath and skipped. Returns (x, P, accepted)."""
    Hb = bearing_jacobian(x, xy_antenna_world_m)
    nu = float(wrap_angle_rad(bearing_robot_rad - bearing_h(x, xy_antenna_world_m, yaw_robot_rad)))
    S = float(Hb @ P @ Hb) + sigma_rad ** 2 + var_yaw_rad2
    if nu * nu > gate * gate * S:
        return x, P, False
    K = P @ Hb / S
    IKH = np.eye(4) - np.outer(K, Hb)
    return x + K * nu, IKH @ P @ IKH.T + np.outer(K, K) * (S - float(Hb @ P @ Hb)), True


# ----------------------------------------------------------------------------------------- entropy
def area_m2(P: np.ndarray) -> float:
    """Uncertainty area sqrt(det P_xy) in m^2 (proportional to exp(H2))."""
    return float(np.sqrt(max(np.linalg.det(P[:2, :2]), 0.0)))


def renyi2_entropy_mm(P: np.ndarray) -> float:
    """Eq. 7: quadratic Renyi entropy of the position Gaussian, ln(4 pi sqrt(det P_xy)), with P_xy in
    mm^2 (positive for any sigma above ~0.3 mm, so relative changes are meaningful)."""
    return float(np.log(4.0 * np.pi * max(area_m2(P), 1e-12) * 1e6))


# ------------------------------------------------------------------------------------------- track
@dataclass
class CVTrack:
    """One person filter with its entropy bookkeeping (eq. 8)."""

    track_id: int
    x: np.ndarray  # (4,) x_m, y_m, vx_mps, vy_mps (world)
    P: np.ndarray  # (4, 4)
    t_s: float
    confirmed: bool = False
    area_ref_m2: float | None = None  # the first prediction's area (confirmation reference)
    entropy_min: float = np.inf  # minimum H2 (mm) over the filter's life (deletion reference)
    hits: int = 1
    misses: int = 0
    detected: bool = True  # a detection updated it in the latest frame

    @classmethod
    def from_detection(cls, track_id: int, z_world: np.ndarray, R_world: np.ndarray, t_s: float,
                       sigma_v0_mps: float = SIGMA_V0_MPS) -> CVTrack:
        P = np.zeros((4, 4))
        P[:2, :2] = R_world
        P[2:, 2:] = sigma_v0_mps ** 2 * np.eye(2)
        return cls(track_id, np.array([z_world[0], z_world[1], 0.0, 0.0]), P, t_s)

    def predict(self, t_s: float, sigma_accel_mps2: float = SIGMA_ACCEL_MPS2) -> None:
        dt = t_s - self.t_s
        if dt > 0:
            self.x, self.P = predict(self.x, self.P, dt, sigma_accel_mps2)
            self.t_s = t_s
        if self.area_ref_m2 is None:
            self.area_ref_m2 = area_m2(self.P)

    def update(self, z_world: np.ndarray, R_world: np.ndarray) -> None:
        self.x, self.P = update_position(self.x, self.P, z_world, R_world)

    @property
    def xy(self) -> np.ndarray:
        return self.x[:2]

    @property
    def area_m2(self) -> float:
        return area_m2(self.P)

    def manage(self, confirm_ratio: float = CONFIRM_AREA_RATIO, delete_rise: float = DELETE_ENTROPY_RISE,
               max_area_m2: float = MAX_AREA_M2) -> bool:
        """Eq. 8 after the frame's updates: confirm when the area fell to ``confirm_ratio`` of the
        reference; return True when the filter should be deleted (H2 in mm rose ``delete_rise``
        above its minimum, or the area is over ``max_area_m2``)."""
        h = renyi2_entropy_mm(self.P)
        self.entropy_min = min(self.entropy_min, h)
        a = self.area_m2
        if not self.confirmed and self.area_ref_m2 is not None and a <= confirm_ratio * self.area_ref_m2:
            self.confirmed = True
        return a > max_area_m2 or h > (1.0 + delete_rise) * self.entropy_min


__all__ = ["SIGMA_LIDAR_M", "cv_transition", "cv_process_noise", "predict", "update_position", "mahalanobis",
           "mahalanobis_matrix", "detection_world", "detections_world", "bearing_h", "bearing_jacobian",
           "update_bearing", "area_m2", "renyi2_entropy_mm", "CVTrack", "rot2"]
