"""Shared pieces of every calibration method: the result type and robot-head interpolation."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from pedcal.model import Log, SensorNetwork


def _plain(value):
    """numpy scalars and arrays as Python numbers and lists, recursively (for JSON / YAML)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclass
class Diagnostics:
    """What every calibration method reports beside the extrinsics (None where a method has no
    such thing); each method's own part is a subclass."""

    latency_s: float | None = None              # tracker latency the method applied (s)
    association_runtime_s: float | None = None  # time spent picking out the robot (s)

    def to_dict(self) -> dict:
        return _plain(asdict(self))


@dataclass
class GridSearchDiagnostics(Diagnostics):
    # per searched sensor its GridSearchResult (pedcal.calib.gridsearch): the objective values
    # at the optimum, the grid indices and ``on_range_edge``, the stages whose optimum lies on the
    # edge of the searched range (the range was too small for them)
    sensors: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)                          # search ranges and steps

    @property
    def on_range_edge(self) -> dict[str, list[str]]:
        """{sensor: stages} of the sensors whose optimum lies on a range edge."""
        return {sid: s.on_range_edge for sid, s in self.sensors.items() if s.on_range_edge}


@dataclass
class ClosedFormDiagnostics(Diagnostics):
    unpaired_robot_observations: int = 0      # robot rows outside robot.csv's time span
    rms_residual_m: dict[str, float] = field(default_factory=dict)   # per fitted sensor


@dataclass
class AlternativeDiagnostics(Diagnostics):
    pairs: list[str] = field(default_factory=list)            # sensor pairs with shared sightings
    matches_per_pair: dict = field(default_factory=dict)
    rounds: list = field(default_factory=list)
    no_data: list[str] = field(default_factory=list)          # sensors sharing nothing
    params: dict = field(default_factory=dict)


@dataclass
class HeadModel:
    """The tracker's head point as the factor graph estimated it: the head top moved
    ``vertical_offset_m`` up, then ``ray_shift_m`` along the ray toward the sensor (a dome of
    radius r: -r and r), ``horizontal_shift_m`` horizontally toward it and ``curvature_m`` times
    cos^2 of the sensor's elevation (seen from the head) up, with their 1-sigma;
    ``height_reference`` says what fixed the offset (``none``: its prior only, which ``note``
    states)."""

    vertical_offset_m: float
    ray_shift_m: float
    horizontal_shift_m: float = 0.0
    curvature_m: float = 0.0
    sigma_vertical_offset_m: float = 0.0
    sigma_ray_shift_m: float = 0.0
    sigma_horizontal_shift_m: float = 0.0
    sigma_curvature_m: float = 0.0
    height_reference: str = "none"
    estimated: bool = True
    note: str = ""

    def to_dict(self) -> dict:
        return _plain(asdict(self))


@dataclass
class ModelMismatch:
    """Residuals against the noise model: per sensor the robust variance ratio (1 when the
    model holds), the sensors beyond ``threshold`` and the misfit in words."""

    variance_ratio: dict[str, float] = field(default_factory=dict)
    threshold: float = 1.5
    sensors: list[str] = field(default_factory=list)
    misfit: str = ""
    head_model_misfit: str = ""     # a systematic misfit of the head-point model, in words

    def to_dict(self) -> dict:
        return _plain(asdict(self))


@dataclass
class FactorGraphDiagnostics(Diagnostics):
    recipe: str = ""
    iterations: int = 0
    factors: int = 0
    variables: int = 0
    build_s: float = 0.0
    optimize_s: float = 0.0
    shared_people: int = 0                        # instants two sensors saw one person
    odometry: dict = field(default_factory=dict)  # estimated scale and heading drifts
    head_model: HeadModel | None = None
    model_mismatch: ModelMismatch | None = None
    position_cov_world_m2: dict[str, np.ndarray] = field(default_factory=dict)   # per sensor
    amcl_model: object | None = None              # AmclErrorModel the graph was solved with
    observation_noise: dict = field(default_factory=dict)   # the sensors' noise estimated from the log
    online_trace: object | None = None            # OnlineTrace of the incremental solver


@dataclass
class GraphKeys:
    """Which GTSAM symbol is which: ``sensors`` {sensor id: key of its Pose3 T_world_sensor},
    ``robot_poses`` / ``amcl_errors`` / ``people`` (keys and the times they belong to, s) and
    ``head_model`` (the key of the head point's vertical offset, a Pose3 whose height is the
    offset's change from its initial value; None when it is not estimated)."""

    sensors: dict[str, int] = field(default_factory=dict)
    robot_poses: list[int] = field(default_factory=list)
    robot_pose_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    amcl_errors: list[int] = field(default_factory=list)
    amcl_error_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    people: list[int] = field(default_factory=list)
    people_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    head_model: int | None = None


@dataclass
class CalibrationResult:
    """What a calibration method returns. ``network`` has the calibrated schema of
    LOG_FORMAT.md (status, observations, sigma where the method gives one).

    The factor graph also hands over its estimator's objects: ``graph`` (the GTSAM
    NonlinearFactorGraph solved last), ``values`` (its solution), ``keys`` (which symbol is which
    sensor, robot pose, AMCL error node, person and nuisance variable), ``marginals()`` (GTSAM
    Marginals, computed on first use), ``position_covariance_m2`` (the joint covariance of all
    sensors' positions, world axes, 3n x 3n in ``network`` order, with the head model's and the
    model check's share) and ``factor_residuals()`` (each factor's whitened residual)."""

    network: SensorNetwork
    method: str
    runtime_s: float = 0.0
    # Boolean mask over the rows of log.observations: True where the method used the row as
    # an observation of the robot (None when the method does not pick out the robot).
    is_robot: np.ndarray | None = None
    diagnostics: Diagnostics = field(default_factory=Diagnostics)
    graph: object | None = None          # gtsam.NonlinearFactorGraph
    values: object | None = None         # gtsam.Values
    keys: GraphKeys | None = None
    position_covariance_m2: np.ndarray | None = None
    _marginals: object | None = field(default=None, repr=False)

    def marginals(self):
        """GTSAM Marginals of the solution (computed on first use; None without a graph)."""
        if self._marginals is None and self.graph is not None:
            import gtsam

            self._marginals = gtsam.Marginals(self.graph, self.values)
        return self._marginals

    def factor_residuals(self) -> list[np.ndarray]:
        """Whitened residual of every factor of ``graph`` at ``values`` (before any robust
        kernel's reweighting), in graph order; empty without a graph."""
        if self.graph is None:
            return []
        return [np.asarray(self.graph.at(n).whitenedError(self.values)) for n in range(self.graph.size())]

    def summary(self) -> str:
        lines = [f"method {self.method}: {len(self.network)} sensors in {self.runtime_s:.2f} s"]
        for s in self.network:
            sig = ""
            if s.sigma_position_m is not None:
                sig = "  sigma " + " ".join(f"{1000 * v:.1f}" for v in s.sigma_position_m) + " mm"
            extra = f" unobservable: {', '.join(s.unobservable)}" if s.unobservable else ""
            lines.append(f"  {s.id:>8s} {s.status or '':10s} obs {s.observations or 0:6d}"
                         f"  pos {np.array2string(s.position_m, precision=3)}"
                         f"  ypr {np.array2string(s.ypr_deg, precision=2)}{sig}{extra}")
        head = getattr(self.diagnostics, "head_model", None)
        if head is not None:
            lines.append(f"head point: {1000 * head.vertical_offset_m:+.1f} +- "
                         f"{1000 * head.sigma_vertical_offset_m:.1f} mm from the head top, "
                         f"{1000 * head.ray_shift_m:.1f} +- {1000 * head.sigma_ray_shift_m:.1f} mm toward the "
                         f"sensor along the ray and {1000 * head.horizontal_shift_m:.1f} +- "
                         f"{1000 * head.sigma_horizontal_shift_m:.1f} mm horizontally"
                         + (f", {1000 * head.curvature_m:.1f} +- {1000 * head.sigma_curvature_m:.1f} mm x cos^2 "
                            "(elevation) up" if head.sigma_curvature_m else "")
                         + f" (height reference: {head.height_reference})")
            if head.note:
                lines.append(f"  {head.note}")
        mismatch = getattr(self.diagnostics, "model_mismatch", None)
        if mismatch is not None and mismatch.sensors:
            lines.append(f"model mismatch: {mismatch.misfit}; their sigma widened by that factor")
        return "\n".join(lines)


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.elapsed_s = time.perf_counter() - self.t0


def interpolate_pose2(track: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """Robot base (x, y, yaw) at times ``t`` by linear interpolation of a t/x/y/yaw table,
    yaw unwrapped before interpolating. Times outside the table are clamped to its ends."""
    track = track.sort_values("t")
    tt = track["t"].to_numpy(float)
    x = np.interp(t, tt, track["x"].to_numpy(float))
    y = np.interp(t, tt, track["y"].to_numpy(float))
    yaw = np.interp(t, tt, np.unwrap(track["yaw"].to_numpy(float)))
    return np.column_stack([x, y, yaw])


def head_world(pose2: np.ndarray, head_offset_m) -> np.ndarray:
    """World position of the robot's head top for base poses (N, 3) [x, y, yaw]."""
    off = np.asarray(head_offset_m, dtype=float)
    c, s = np.cos(pose2[:, 2]), np.sin(pose2[:, 2])
    return np.column_stack([pose2[:, 0] + c * off[0] - s * off[1],
                            pose2[:, 1] + s * off[0] + c * off[1],
                            np.full(len(pose2), off[2])])


def head_interpolator(log: Log, *, truth: bool = False):
    """t -> the robot's head top in the world (N, 3), from robot.csv (AMCL) or, with
    ``truth=True``, from truth_robot.csv. AMCL's estimates come at a few Hz: on a turn a straight
    chord between them is off by centimetres, so robot.csv is interpolated with a cubic spline
    (x, y and unwrapped yaw; one row per time stamp). truth_robot.csv is dense and the simulator
    interpolates it linearly, so it is read the same way. Times outside the table are clamped to
    its ends."""
    track = log.truth_robot if truth else log.robot
    if track is None:
        raise ValueError("the log has no truth_robot.csv" if truth else "the log has no robot.csv")
    track = track.groupby("t", sort=True)[["x", "y", "yaw"]].mean()
    tt = track.index.to_numpy(float)
    xy_yaw = np.column_stack([track["x"].to_numpy(float), track["y"].to_numpy(float),
                              np.unwrap(track["yaw"].to_numpy(float))])
    spline = CubicSpline(tt, xy_yaw, axis=0) if len(tt) >= 4 and not truth else None
    head_offset_m = log.meta.head_offset_m

    def head_at(t):
        t = np.clip(np.asarray(t, float), tt[0], tt[-1])
        if spline is None:
            pose2 = np.column_stack([np.interp(t, tt, xy_yaw[:, i]) for i in range(3)])
        else:
            pose2 = spline(t)
        return head_world(np.atleast_2d(pose2), head_offset_m)

    return head_at


def robot_head_at(log: Log, t: np.ndarray, *, truth: bool = False) -> np.ndarray:
    """The robot's head top in the world at times ``t`` (see :func:`head_interpolator`)."""
    return head_interpolator(log, truth=truth)(t)
