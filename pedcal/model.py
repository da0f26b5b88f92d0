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
# Columns of a sensor's row in to_dict() / to_dataframe() tables (one row per sensor).
POSITION_COLUMNS = ("x_m", "y_m", "z_m")
YPR_COLUMNS = ("yaw_deg", "pitch_deg", "roll_deg")
SIGMA_POSITION_COLUMNS = ("sigma_x_m", "sigma_y_m", "sigma_z_m")
SIGMA_YPR_COLUMNS = ("sigma_yaw_deg", "sigma_pitch_deg", "sigma_roll_deg")
SIGMA_ROTATION_COLUMNS = ("sigma_rotation_x_deg", "sigma_rotation_y_deg", "sigma_rotation_z_deg")
DEFAULT_HEAD_OFFSET_M = (0.0, 0.0, 1.35)


def plain(value):
    """numpy scalars and arrays as Python numbers and lists, recursively (for JSON / YAML)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def sensor_codes(column: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """Each row's sensor as a code and the sensors' names (str, numbered by first appearance): the
    factorization of ``str`` of each value, every code a valid index (a missing value named by
    its text: NaN 'nan', None 'None', a string column's pd.NA '<NA>'). An object column is
    factorized by its values' texts (pandas' own factorization would merge 1, 1.0 and True, and
    name the code of 1.0 and 1 after the first); any other column (str, string, numbers) by its
    values, a Python string made per distinct value only, values whose texts agree then merged
    (the one exception: a float column's 0.0 and -0.0, one value to pandas, share a code, named
    after the first)."""
    if column.dtype == object:
        codes, names = pd.factorize(column.map(str))
        return codes, np.asarray(names, dtype=object)
    codes, values = pd.factorize(column, use_na_sentinel=False)
    names = np.array([str(v) for v in values], dtype=object)
    if len(set(names.tolist())) < len(names):     # (a categorical of 3 and '3', say)
        merged, names = pd.factorize(names)
        codes = merged[codes]
    return codes, names


def rows_by_code(codes: np.ndarray, n_codes: int) -> list[np.ndarray]:
    """The rows of each code 0 .. ``n_codes`` - 1, ascending, from one stable sort of the codes
    (one pass over the rows, not one per code)."""
    codes = np.asarray(codes)
    order = np.argsort(codes, kind="stable")
    bounds = np.r_[0, np.cumsum(np.bincount(codes, minlength=n_codes))]
    return [order[bounds[i]:bounds[i + 1]] for i in range(n_codes)]


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

    def to_dict(self) -> dict:
        """One flat row: ``id``, ``x_m``, ``y_m``, ``z_m``, ``yaw_deg``, ``pitch_deg``, ``roll_deg``
        (T_world_sensor), then what a calibration says of the sensor (``sigma_x_m`` ...
        ``sigma_roll_deg``, ``sigma_rotation_x_deg`` ... (a rotation vector in the sensor frame),
        ``observations``, ``status``, ``unobservable`` as one comma-separated text): None where it
        says nothing. Plain Python numbers and text only, no lists (a table cell each)."""
        row: dict = {"id": self.id}
        row.update(zip(POSITION_COLUMNS, map(float, self.position_m), strict=True))
        row.update(zip(YPR_COLUMNS, map(float, self.ypr_deg), strict=True))
        for names, sigma in ((SIGMA_POSITION_COLUMNS, self.sigma_position_m), (SIGMA_YPR_COLUMNS, self.sigma_ypr_deg),
                             (SIGMA_ROTATION_COLUMNS, self.sigma_rotation_deg)):
            row.update(zip(names, [None] * 3 if sigma is None else map(float, np.reshape(sigma, 3)), strict=True))
        row["observations"] = None if self.observations is None else int(self.observations)
        row["status"] = self.status
        row["unobservable"] = None if self.unobservable is None else ",".join(self.unobservable)
        return row

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

    def _find(self, sensor_id) -> SensorExtrinsics | None:
        """The sensor of that id, or None: by an id -> position index, checked on every use and
        rebuilt when the list changed under it (a sensor replaced, added or removed), instead of
        a scan of the list per look-up (quadratic over a network's sensors). A miss rebuilds it (an
        absent id and one added to the list since look alike): to test many ids, use a set of ``ids``."""
        sid = str(sensor_id)
        index = self.__dict__.get("_index")
        i = None if index is None else index.get(sid)
        if i is None or i >= len(self.sensors) or self.sensors[i].id != sid:
            index = self.__dict__["_index"] = {s.id: k for k, s in enumerate(self.sensors)}
            i = index.get(sid)
        return None if i is None else self.sensors[i]

    def __getitem__(self, sensor_id: str) -> SensorExtrinsics:
        s = self._find(sensor_id)
        if s is None:
            raise KeyError(sensor_id)
        return s

    def __contains__(self, sensor_id) -> bool:
        return self._find(sensor_id) is not None

    def __len__(self) -> int:
        return len(self.sensors)

    def __iter__(self):
        return iter(self.sensors)

    def copy(self) -> SensorNetwork:
        return SensorNetwork([replace(s, position_m=s.position_m.copy(), ypr_deg=s.ypr_deg.copy())
                              for s in self.sensors], self.frame, dict(self.extra))

    def to_dict(self) -> dict:
        """``frame``, ``sensors`` (one flat row per sensor, :meth:`SensorExtrinsics.to_dict`) and
        ``extra`` (the file's other top-level keys, numpy values as plain numbers and lists)."""
        return {"frame": self.frame, "sensors": [s.to_dict() for s in self.sensors], "extra": plain(self.extra)}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per sensor, indexed by id: the columns of :meth:`SensorExtrinsics.to_dict`."""
        rows = [s.to_dict() for s in self.sensors]
        columns = list(SensorExtrinsics("_", np.zeros(3), np.zeros(3)).to_dict())
        return pd.DataFrame(rows, columns=columns).set_index("id")


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

    def to_dict(self) -> dict:
        """What the log holds, briefly: ``path``, ``meta`` (head offset and notes), ``sensors`` (the
        installed network, :meth:`SensorNetwork.to_dict`), ``truth`` (or None) and ``tables``: per
        table its rows and time span (s); the tables themselves are DataFrames already."""
        tables = {}
        for name in ("robot", "observations", "odometry", "truth_robot", "truth_observations"):
            table = getattr(self, name)
            if table is None:
                continue
            t = table["t"].to_numpy(float) if "t" in table and len(table) else np.zeros(0)
            tables[name] = {"rows": len(table), "t_start_s": float(t.min()) if t.size else None,
                            "t_end_s": float(t.max()) if t.size else None}
        return {"path": None if self.path is None else str(self.path),
                "meta": {"head_offset_m": plain(self.meta.head_offset_m), "notes": plain(self.meta.notes)},
                "sensors": self.sensors.to_dict(), "truth": None if self.truth is None else self.truth.to_dict(),
                "tables": tables}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per installed sensor (the columns of :meth:`SensorNetwork.to_dataframe`) with
        ``observation_rows`` (its rows in observations.csv) and, when the log has truth.yaml, the
        true pose as ``truth_x_m`` ... ``truth_roll_deg``."""
        df = self.sensors.to_dataframe()
        counts = self.observations["sensor"].astype(str).value_counts() if len(self.observations) else pd.Series()
        df["observation_rows"] = [int(counts.get(sid, 0)) for sid in df.index]
        if self.truth is not None:
            truth = self.truth.to_dataframe()[list(POSITION_COLUMNS + YPR_COLUMNS)].add_prefix("truth_")
            df = df.join(truth)
        return df

    def observation_points_sensor(self) -> np.ndarray:
        """Head points in each sensor's own frame, undoing the installed extrinsics
        (p_sensor = R_installed^T (p_world - position_installed), LOG_FORMAT.md)."""
        out = np.empty((len(self.observations), 3))
        xyz = self.observations[["x", "y", "z"]].to_numpy(dtype=float)
        # each sensor's rows from the column's codes: no Python string made per row
        codes, names = sensor_codes(self.observations["sensor"])
        for sid, rows in zip(names, rows_by_code(codes, len(names)), strict=True):
            if sid in self.sensors:
                out[rows] = self.sensors[sid].to_sensor(xyz[rows])
        return out
