"""Plain data types of pedcal: sensor extrinsics and logs.

Tables are pandas DataFrames with the columns of LOG_FORMAT.md (docs/LOG_FORMAT.md), so research
code can use them directly. Readers and writers live in :mod:`pedcal.io`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import gtsam
import numpy as np
import pandas as pd

from pedcal import frames

# Column sets of the log format v1 (LOG_FORMAT.md); readers validate against these.
ROBOT_COLUMNS = ("t", "x", "y", "yaw", "cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw")
ODOMETRY_COLUMNS = ("t", "x", "y", "yaw")
TRUTH_ROBOT_COLUMNS = ("t", "x", "y", "yaw")
OBSERVATION_COLUMNS = ("t", "sensor", "track", "x", "y", "z")
TRUTH_OBSERVATION_COLUMNS = ("row", "who")
PEOPLE_COLUMNS = ("t", "person", "x", "y")

SENSOR_STATUSES = ("ok", "degenerate", "no-data")
DEFAULT_HEAD_OFFSET_M = (0.0, 0.0, 1.35)


@dataclass
class SensorExtrinsics:
    """One ceiling sensor's pose T_world_sensor, plus what a calibration says of it."""

    id: str
    position_m: np.ndarray
    ypr_deg: np.ndarray
    # Calibrated schema only (None in installed / truth files):
    sigma_position_m: np.ndarray | None = None   # 1-sigma, world axes
    sigma_ypr_deg: np.ndarray | None = None
    observations: int | None = None
    status: str | None = None                    # ok | degenerate | no-data
    unobservable: list[str] | None = None        # directions, when status is degenerate
    # 1-sigma of the orientation as a rotation vector in the sensor frame (deg): well defined at
    # any pitch, where ypr sigma is not (yaw and roll blur together looking straight down)
    sigma_rotation_deg: np.ndarray | None = None

    def __post_init__(self):
        self.id = str(self.id)
        self.position_m = np.asarray(self.position_m, dtype=float).reshape(3)
        self.ypr_deg = np.asarray(self.ypr_deg, dtype=float).reshape(3)

    @property
    def R_world_sensor(self) -> np.ndarray:
        return frames.rot_from_ypr_deg(self.ypr_deg)

    @property
    def T_world_sensor(self) -> gtsam.Pose3:
        return frames.pose3(self.position_m, self.ypr_deg)

    @classmethod
    def from_pose3(cls, sensor_id: str, T_world_sensor: gtsam.Pose3, **extra) -> SensorExtrinsics:
        position_m, ypr_deg = frames.position_ypr_from_pose3(T_world_sensor)
        return cls(sensor_id, position_m, ypr_deg, **extra)

    def to_world(self, points_sensor: np.ndarray) -> np.ndarray:
        return frames.world_from_sensor(points_sensor, self.position_m, self.ypr_deg)

    def to_sensor(self, points_world: np.ndarray) -> np.ndarray:
        return frames.sensor_from_world(points_world, self.position_m, self.ypr_deg)


@dataclass
class SensorNetwork:
    """The contents of a sensors.yaml / truth.yaml / calibrated YAML file."""

    sensors: list[SensorExtrinsics]
    frame: str = "map"
    extra: dict = field(default_factory=dict)   # top-level keys we keep but do not interpret

    def __post_init__(self):
        seen = set()
        for s in self.sensors:
            if s.id in seen:
                raise ValueError(f"duplicate sensor id '{s.id}'")
            seen.add(s.id)

    @property
    def ids(self) -> list[str]:
        return [s.id for s in self.sensors]

    def __getitem__(self, sensor_id: str) -> SensorExtrinsics:
        for s in self.sensors:
            if s.id == str(sensor_id):
                return s
        raise KeyError(sensor_id)

    def __contains__(self, sensor_id) -> bool:
        return any(s.id == str(sensor_id) for s in self.sensors)

    def __len__(self) -> int:
        return len(self.sensors)

    def __iter__(self):
        return iter(self.sensors)

    def copy(self) -> SensorNetwork:
        return SensorNetwork([replace(s, position_m=s.position_m.copy(), ypr_deg=s.ypr_deg.copy())
                              for s in self.sensors], self.frame, dict(self.extra))


@dataclass
class Meta:
    head_offset_m: np.ndarray = field(default_factory=lambda: np.array(DEFAULT_HEAD_OFFSET_M))
    notes: dict = field(default_factory=dict)    # every other key of meta.yaml, kept as read


@dataclass
class Log:
    """A log directory in memory (LOG_FORMAT.md). Observations keep file order: row i of
    ``observations`` is data row i of observations.csv, which truth_observations refers to."""

    sensors: SensorNetwork
    robot: pd.DataFrame
    observations: pd.DataFrame
    odometry: pd.DataFrame | None = None
    meta: Meta = field(default_factory=Meta)
    truth: SensorNetwork | None = None
    truth_robot: pd.DataFrame | None = None
    truth_observations: pd.DataFrame | None = None
    path: Path | None = None

    def observation_points_sensor(self) -> np.ndarray:
        """Head points in each sensor's own frame, undoing the installed extrinsics
        (p_sensor = R_installed^T (p_world - position_installed), LOG_FORMAT.md)."""
        out = np.empty((len(self.observations), 3))
        xyz = self.observations[["x", "y", "z"]].to_numpy(dtype=float)
        sensor_col = self.observations["sensor"].astype(str).to_numpy()
        for sid, rows in pd.Series(sensor_col).groupby(sensor_col, sort=False).indices.items():
            if sid in self.sensors:     # one pass over the rows, not one per sensor
                out[rows] = self.sensors[sid].to_sensor(xyz[rows])
        return out
