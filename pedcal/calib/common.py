"""Shared pieces of every calibration method: the result type and robot-head interpolation."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from pedcal.deprecation import renamed_fields
from pedcal.model import Log, SensorExtrinsics, SensorNetwork, plain

if TYPE_CHECKING:
    import gtsam

    from pedcal.calib.amcl_model import AmclErrorModel
    from pedcal.calib.online import OnlineTrace


@renamed_fields(latency_s="tracker_latency_s")
@dataclass
class Diagnostics:
    """What every calibration method reports beside the extrinsics (None where a method has no
    such thing); each method's own part is a subclass. Names follow the calibrated YAML's
    (``tracker_latency_s``, ...); the former names still read, with a DeprecationWarning."""

    tracker_latency_s: float | None = None      # tracker latency the method applied (s)
    association_runtime_s: float | None = None  # time spent picking out the robot (s)

    def to_dict(self) -> dict:
        return plain(asdict(self))


@renamed_fields(latency_s="tracker_latency_s")
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


@renamed_fields(latency_s="tracker_latency_s")
@dataclass
class ClosedFormDiagnostics(Diagnostics):
    unpaired_robot_observations: int = 0      # robot rows outside robot.csv's time span
    rms_residual_m: dict[str, float] = field(default_factory=dict)   # per fitted sensor


@renamed_fields(latency_s="tracker_latency_s")
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
    # the horizontal shift against the horizontal distance from the sensor, where the data show
    # one (pedcal.calib.headpoint.profile_record): it replaces horizontal_shift_m
    horizontal_profile: dict | None = None
    # without a profile, each sensor's own horizontal shift where its departure from the shared
    # one was estimated (sensor id -> m; pedcal.calib.headpoint.departures_record) and its sigma:
    # they replace horizontal_shift_m for those sensors
    per_sensor_shift_m: dict | None = None
    sigma_per_sensor_shift_m: dict | None = None
    # the spread of the head point between the sensors' trackers (the departures' prior sigma)
    # as the data estimate it (pedcal.calib.headpoint.spread_record)
    per_sensor_shift_spread: dict | None = None

    def to_dict(self) -> dict:
        out = plain(asdict(self))
        for key in ("horizontal_profile", "per_sensor_shift_m", "sigma_per_sensor_shift_m", "per_sensor_shift_spread"):
            if out.get(key) is None:
                out.pop(key, None)
        return out


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
        return plain(asdict(self))


@renamed_fields(latency_s="tracker_latency_s", odometry="odometry_model", amcl_model="amcl_error_model",
                position_cov_world_m2="position_covariance_m2")
@dataclass
class FactorGraphDiagnostics(Diagnostics):
    recipe: str = ""
    iterations: int = 0
    factors: int = 0
    variables: int = 0
    build_s: float = 0.0
    optimize_s: float = 0.0
    shared_people: int = 0                        # instants two sensors saw one person
    odometry_model: dict = field(default_factory=dict)  # estimated scale and heading drifts
    head_model: HeadModel | None = None
    model_mismatch: ModelMismatch | None = None
    # per sensor its 3x3 position covariance, world axes (m^2): the diagonal blocks of
    # CalibrationResult.position_covariance_m2
    position_covariance_m2: dict[str, np.ndarray] = field(default_factory=dict)
    amcl_error_model: AmclErrorModel | None = None       # the AMCL error model the graph was solved with
    observation_noise: dict = field(default_factory=dict)   # the sensors' noise estimated from the log
    online_trace: OnlineTrace | None = None               # trace of the incremental solver


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
    model check's share) and ``factor_residuals()`` (each factor's whitened residual).

    The graph's variables and their frames (``keys`` names each; all in the map frame):

    - ``keys.sensors[id]``: ``Pose3`` T_world_sensor (sensor x = optical axis, pedcal/frames.py).
    - ``keys.robot_poses[k]``: ``Pose3`` of the robot's *head point*, not its base: the base pose
      (x, y, yaw) at ``keys.robot_pose_times[k]`` composed with meta.yaml's head offset, at the
      head point's height: the head top plus the vertical offset, i.e. head offset z minus the
      recipe's ``head_radius_m`` (0.05 m by default, the offset's initial value) plus the head
      model's z. The base is this pose moved back by the horizontal head offset, at z = 0.
    - ``keys.amcl_errors[j]``: ``Pose3``, a pure world translation: AMCL's slowly wandering error
      at ``keys.amcl_error_times[j]`` (its inverse, F = E^-1).
    - ``keys.people[m]``: ``Point3`` of a person's head seen by two sensors at once.
    - ``keys.head_model``: ``Pose3`` whose z is the head point's vertical offset *measured from the
      default -head_radius_m* built into the robot poses: the offset reported in
      ``diagnostics.head_model.vertical_offset_m`` is ``-head_radius_m + z`` (z -0.052 m is an
      offset of -0.102 m with the default radius). Its prior holds x, y and the rotation at zero
      and centres z on ``head_radius_m`` minus the ray shift (a dome's offset, -shift), give or
      take the recipe's ``head_vertical_sigma_m``; every AMCL error node's height is tied to it.

    Held fixed in the graph (not variables): the tracker latency (estimated once before the
    graph, ``diagnostics.tracker_latency_s``; observation times are shifted by it), the head
    point's shifts toward the sensor along the ray and horizontally (and its curvature), which a
    profile likelihood around the graph estimates, AMCL's error model and the odometry's
    corrections. So ``marginals()`` holds the graph's uncertainty given those, and
    ``position_covariance_m2`` (and the sigma of ``network``) adds the shifts' share (their sigma
    times the sensors' sensitivity to them) and widens sensors whose residuals exceed the noise
    model (``diagnostics.model_mismatch``): it is never smaller than the marginals' (the 3-D sigma
    about 10 % larger on docs/guide.md's simulated log). Where AMCL's residuals wander less than
    AMCL reports (recipe ``amcl_reported_floor = "consider"``, the default) ``graph`` is solved with
    the residuals' wander and ``position_covariance_m2`` read from it with its AMCL block under the
    wander held at AMCL's reported std (``diagnostics.amcl_error_model.held()``), which widens it
    further. :meth:`reoptimize` adds factors to the
    graph and solves it again; :meth:`network_from_values` reads a SensorNetwork back from any
    ``gtsam.Values``."""

    network: SensorNetwork
    method: str
    runtime_s: float = 0.0
    # Boolean mask over the rows of log.observations: True where the method used the row as
    # an observation of the robot (None when the method does not pick out the robot).
    is_robot: np.ndarray | None = None
    diagnostics: Diagnostics = field(default_factory=Diagnostics)
    graph: gtsam.NonlinearFactorGraph | None = None
    values: gtsam.Values | None = None
    keys: GraphKeys | None = None
    position_covariance_m2: np.ndarray | None = None
    _marginals: gtsam.Marginals | None = field(default=None, repr=False)

    def marginals(self) -> gtsam.Marginals | None:
        """GTSAM Marginals of the solution (computed on first use; None without a graph). They
        are the graph's own: see the class docstring for what ``position_covariance_m2`` adds."""
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

    def network_from_values(self, values: gtsam.Values, marginals: gtsam.Marginals | None = None) -> SensorNetwork:
        """The SensorNetwork of ``values`` (e.g. ``values`` after your own solve of ``graph``): each
        sensor's pose read from its key, status, observations and the file's extra keys kept from
        ``network``; with ``marginals`` the sigma are theirs (the graph's alone: no head-model
        share, no widening), else None. A sensor whose key ``values`` lacks is refused."""
        from pedcal.calib.graph import rotation_sigma_deg, sensor_sigma_world

        if self.keys is None:
            raise ValueError(f"method {self.method!r} has no graph: its result holds no GTSAM keys")
        out = []
        for s in self.network:
            key = self.keys.sensors[s.id]
            if not values.exists(key):
                raise KeyError(f"values hold no pose of sensor {s.id!r} (key {key})")
            T = values.atPose3(key)
            extra: dict[str, Any] = {"sigma_position_m": None, "sigma_ypr_deg": None, "sigma_rotation_deg": None}
            if marginals is not None:
                cov = marginals.marginalCovariance(key)
                _, extra["sigma_position_m"], extra["sigma_ypr_deg"] = sensor_sigma_world(T, cov)
                extra["sigma_rotation_deg"] = rotation_sigma_deg(cov)
            moved = SensorExtrinsics.from_pose3(s.id, T)
            out.append(replace(s, position_m=moved.position_m, ypr_deg=moved.ypr_deg, **extra))
        return SensorNetwork(out, self.network.frame, dict(self.network.extra))

    def reoptimize(self, extra_factors: gtsam.NonlinearFactorGraph | Iterable[gtsam.NonlinearFactor],
                   params: gtsam.LevenbergMarquardtParams | None = None) -> CalibrationResult:
        """Solve ``graph`` plus ``extra_factors`` (a NonlinearFactorGraph or factors on
        ``keys``' symbols, e.g. a ``gtsam.PriorFactorPose3`` on one sensor's key) again with
        Levenberg-Marquardt from ``values``; returns a new result whose ``network``,
        ``position_covariance_m2`` and sigma are the new graph's own (its marginals: what the
        class docstring says is held fixed stays so, no head-model share is added and AMCL's
        block is the solved one, not the held one the first sigma was read with).
        ``self`` is left unchanged."""
        import gtsam

        if self.graph is None or self.values is None or self.keys is None:
            raise ValueError(f"method {self.method!r} has no graph to re-optimize")
        graph = gtsam.NonlinearFactorGraph(self.graph)
        if isinstance(extra_factors, gtsam.NonlinearFactorGraph):
            graph.push_back(extra_factors)
        else:
            for factor in extra_factors:
                graph.add(factor)
        values = gtsam.LevenbergMarquardtOptimizer(graph, self.values,
                                                   params or gtsam.LevenbergMarquardtParams()).optimize()
        marginals = gtsam.Marginals(graph, values)
        network = self.network_from_values(values, marginals)
        keys = [self.keys.sensors[sid] for sid in network.ids]
        C = marginals.jointMarginalCovariance(gtsam.KeyVector(keys)).fullMatrix()
        n = len(keys)
        R = np.stack([values.atPose3(k).rotation().matrix() for k in keys])
        Ct = C.reshape(n, 6, n, 6)[:, 3:, :, 3:]     # Pose3 tangent: rotation, then body-frame translation
        joint_pos = np.einsum("iab,ibjc,jdc->iajd", R, Ct, R).reshape(3 * n, 3 * n)
        return replace(self, network=network, graph=graph, values=values, position_covariance_m2=joint_pos,
                       _marginals=marginals)

    def to_dict(self) -> dict:
        """``method``, ``runtime_s``, ``network`` (:meth:`SensorNetwork.to_dict`: one flat row per
        sensor), ``diagnostics`` (its ``to_dict()``), ``robot_observations`` (rows used as the robot,
        or None) and ``position_covariance_m2`` ({sensors: ids, matrix: 3n x 3n lists} or None).
        The GTSAM objects are left out."""
        cov = self.position_covariance_m2
        return {"method": self.method, "runtime_s": float(self.runtime_s), "network": self.network.to_dict(),
                "diagnostics": self.diagnostics.to_dict(),
                "robot_observations": None if self.is_robot is None else int(np.sum(self.is_robot)),
                "position_covariance_m2": None if cov is None else {"sensors": self.network.ids,
                                                                     "matrix": plain(np.asarray(cov))}}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per sensor, indexed by id: :meth:`SensorNetwork.to_dataframe`'s columns (x_m,
        y_m, z_m, the angles, their sigma, observations, status)."""
        return self.network.to_dataframe()

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
        from pedcal.metrics import network_sigma_split  # (here: pedcal.metrics imports this module)

        try:
            split = network_sigma_split(self.network)
        except ValueError:          # (a covariance of another shape than the network's: no split to print)
            split = None
        if split is not None:
            def mm(v):
                return ", ".join(f"{1000 * x:.1f}" for x in v)

            lines.append(f"network sigma x, y, z: common position {mm(split['common_m'])} mm (shared by every sensor: "
                         "AMCL's error averaged over the run, the head point's height); each sensor about it "
                         f"{mm(split['relative_rms_m'])} mm RMS ({split['sensors']} sensors ok)")
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


def rows_taken(index: np.ndarray, n: int):
    """``index`` (integer rows of a table of ``n``), or ``slice(None)`` when it takes every row in
    order: the table's own values then read as they are, not copied by a gather (at a large
    network's hundreds of thousands of rows, fresh pages the kernel zeroes)."""
    index = np.asarray(index)
    if index.dtype != bool and len(index) == n and n and index[0] == 0 and index[-1] == n - 1 \
            and np.array_equal(index, np.arange(n)):
        return slice(None)
    return index


def interpolate_pose2(track: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """Robot base (x, y, yaw) at times ``t`` by linear interpolation of a t/x/y/yaw table,
    yaw unwrapped before interpolating. Times outside the table are clamped to its ends."""
    return pose2_interpolator(track)(t)


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of rows (n, 3) x (n, 3), to the bit (each component one product less another,
    as NumPy takes it), without its moves of the axes (a third of the noise estimate's time)."""
    a0, a1, a2 = a.T
    b0, b1, b2 = b.T
    return np.column_stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def ray_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors across each ray ``u`` (n, 3, unit rows), (b1, b2): b1 = u x a normalized,
    a the x axis unless u is within 26 deg of it (then y), b2 = u x b1; the frame the noise's
    depth and lateral parts are read in."""
    a = np.where(np.abs(u[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    b1 = cross_rows(u, a)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    return b1, cross_rows(u, b1)


def pose2_interpolator(track: pd.DataFrame):
    """t -> :func:`interpolate_pose2` (``track``, t), the table sorted and its yaw unwrapped once
    for every call (the robot's motion reads the odometry at three sets of times per call); its
    ``yaw(t)`` the yaw column alone."""
    track = track.sort_values("t")
    tt = track["t"].to_numpy(float)
    x, y = track["x"].to_numpy(float), track["y"].to_numpy(float)
    yaw = np.unwrap(track["yaw"].to_numpy(float))

    def at(t):
        return np.column_stack([np.interp(t, tt, x), np.interp(t, tt, y), np.interp(t, tt, yaw)])

    at.yaw = lambda t: np.interp(t, tt, yaw)        # (the third column alone)
    return at


def gaussian_smooth_nearest(v: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter1d(v, sigma, mode="nearest", truncate=truncate)`` of a 1-D
    array (sigma > 0, in samples): the same kernel (a Gaussian over +-int(truncate sigma + 0.5)
    samples, normalized to sum 1) and the same edges (the end values repeated), by NumPy's
    convolution, equal to rounding (1e-15 relative): importing scipy.ndimage alone took 27 ms
    of a 1.3 s ``pedcal calibrate`` (its array-API dispatch is set up at import)."""
    v = np.asarray(v, float)
    if not len(v):
        return v.copy()
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 / (float(sigma) * float(sigma)) * x ** 2)
    # (symmetric: the convolution is the correlation scipy takes)
    return np.convolve(np.pad(v, radius, mode="edge"), kernel / kernel.sum(), mode="valid")


def running_median_nearest(a: np.ndarray, size: int) -> np.ndarray:
    """``scipy.ndimage.median_filter(a, size=(size, 1), mode="nearest")`` of an (n, k) array of
    finite values, ``size`` odd: each column's median over the ``size`` rows centred on each row,
    the end rows repeated beyond the ends, by pandas' rolling median (an odd window's median is
    one of its values: the same to the last digit, and 5x faster here). scipy.ndimage is not
    imported for it: that alone took 27 ms of a 1.3 s ``pedcal calibrate``."""
    a = np.asarray(a, float)
    if size < 1 or size % 2 == 0:
        raise ValueError(f"the window must be an odd number of rows, got {size}")
    if not len(a):
        return a.copy()
    if not np.isfinite(a).all():      # (pandas' window would spread it, scipy's does not)
        raise ValueError(f"a running median of values not all finite ({int((~np.isfinite(a)).sum())} of {a.size})")
    half = size // 2
    padded = np.pad(a.reshape(len(a), -1), ((half, half), (0, 0)), mode="edge")
    med = pd.DataFrame(padded).rolling(size, center=True).median().to_numpy()
    return med[half:half + len(a)].reshape(a.shape)


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
