"""Frames and rotation convention of pedcal, stated once.

World frame: the robot's map frame, z up, metres.
Sensor frame: x along the optical axis, y to the left, z up (ROS REP 103 body axes).
Orientation: ``ypr_deg = [yaw, pitch, roll]`` with R = Rz(yaw) · Ry(pitch) · Rx(roll) mapping
sensor-frame vectors into the world frame, so ``p_world = R @ p_sensor + position``.
A sensor looking 45° down has pitch = +45° (a positive rotation about y tips +x toward -z).
This is GTSAM's ``Rot3.Ypr`` convention; ``T_world_sensor`` below is a ``gtsam.Pose3``.
"""

from __future__ import annotations

import gtsam
import numpy as np

# A camera's optical frame (z forward, x right, y down; REP 103 "_optical") in its body frame:
# R_sensor_optical = Rz(-90 deg) Ry(0) Rx(-90 deg), so p_sensor = R_sensor_optical @ p_optical = (z, -x, -y).
OPTICAL_YPR_DEG = (-90.0, 0.0, -90.0)


def rot_from_ypr_deg(ypr_deg) -> np.ndarray:
    """3x3 rotation matrix R_world_sensor from [yaw, pitch, roll] in degrees."""
    yaw, pitch, roll = np.radians(np.asarray(ypr_deg, dtype=float))
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def ypr_deg_from_rot(R: np.ndarray) -> np.ndarray:
    """[yaw, pitch, roll] in degrees from a rotation matrix (inverse of rot_from_ypr_deg); of a
    stack of them (..., 3, 3), (..., 3)."""
    R = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    return np.degrees(np.stack([yaw, pitch, roll], -1))


def pose3(position_m, ypr_deg) -> gtsam.Pose3:
    """T_world_sensor as a gtsam.Pose3."""
    return gtsam.Pose3(gtsam.Rot3(rot_from_ypr_deg(ypr_deg)), np.asarray(position_m, dtype=float))


def position_ypr_from_pose3(T_world_sensor: gtsam.Pose3) -> tuple[np.ndarray, np.ndarray]:
    """(position_m, ypr_deg) of a gtsam.Pose3."""
    return np.asarray(T_world_sensor.translation(), dtype=float), ypr_deg_from_rot(
        T_world_sensor.rotation().matrix()
    )


def world_from_sensor(points_sensor: np.ndarray, position_m, ypr_deg) -> np.ndarray:
    """Map (N, 3) sensor-frame points into the world: p_world = R p_sensor + t."""
    R = rot_from_ypr_deg(ypr_deg)
    return np.asarray(points_sensor, dtype=float) @ R.T + np.asarray(position_m, dtype=float)


def sensor_from_world(points_world: np.ndarray, position_m, ypr_deg) -> np.ndarray:
    """Map (N, 3) world points into the sensor frame: p_sensor = R^T (p_world - t)."""
    R = rot_from_ypr_deg(ypr_deg)
    return (np.asarray(points_world, dtype=float) - np.asarray(position_m, dtype=float)) @ R


def wrap_angle_rad(a):
    """Wrap angles to (-pi, pi]."""
    return np.mod(np.asarray(a, dtype=float) + np.pi, 2.0 * np.pi) - np.pi


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle in degrees of the relative rotation R_a^T R_b (geodesic distance on SO(3))."""
    c = (np.trace(np.asarray(R_a).T @ np.asarray(R_b)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def up_by_cos2_elevation(p_sensor: np.ndarray, R_world_sensor: np.ndarray) -> np.ndarray:
    """(N, 3) the world's up, expressed in the sensor frame, times cos^2 of the sensor's elevation
    seen from each sensor-frame point (``R_world_sensor``: (N, 3, 3) or (3, 3)): up itself for a
    sensor on the horizon, 0 for one straight above."""
    R = np.broadcast_to(R_world_sensor, (len(p_sensor), 3, 3))
    back = -np.einsum("nij,nj->ni", R, p_sensor)          # world, point -> sensor
    cos2 = np.sum(back[:, :2] ** 2, axis=1) / np.maximum(np.sum(back ** 2, axis=1), 1e-18)
    return cos2[:, None] * R[:, 2, :]                      # R^T e_z: the world's up in the sensor frame


def toward_sensor_horizontal(p_sensor: np.ndarray, R_world_sensor: np.ndarray) -> np.ndarray:
    """(N, 3) unit horizontal vectors from sensor-frame points toward their sensor, expressed in
    the sensor frame (``R_world_sensor``: (N, 3, 3) or (3, 3)); zero straight under it."""
    R = np.broadcast_to(R_world_sensor, (len(p_sensor), 3, 3))
    back = -np.einsum("nij,nj->ni", R, p_sensor)          # world, point -> sensor
    back[:, 2] = 0.0
    norm = np.linalg.norm(back, axis=1, keepdims=True)
    back = np.where(norm > 1e-9, back / np.maximum(norm, 1e-9), 0.0)
    return np.einsum("nji,nj->ni", R, back)
