"""Closed-form baseline: per sensor, a Horn/Umeyama rigid fit of the robot's observations.

Each robot observation pairs the head point the sensor saw (sensor frame, installed extrinsics
undone) with the AMCL head position at that time (world frame). The sensor's pose
T_world_sensor is the rotation and translation minimising sum |R p_sensor + t - p_world|^2,
solved by the SVD of the cross-covariance (Horn 1987; Umeyama 1991, eqs. 34-42 without scale).
The fit needs pairs that span a plane: when the robot passed a sensor in a straight line the
rotation about that line is unconstrained, and the installed pose is kept.
"""

from __future__ import annotations

import logging
import warnings

import gtsam
import numpy as np

from pedcal.calib.association import estimate_latency, moments, rigid_from_moments
from pedcal.calib.common import CalibrationResult, ClosedFormDiagnostics, Timer, head_interpolator
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.metrics import LATENCY_KEY
from pedcal.model import Log, SensorExtrinsics, SensorNetwork, sensor_codes

MIN_PAIRS = 5
COLLINEAR_SPREAD_M = 0.1   # second principal spread (1 sigma) of the pairs below which they are a line


def fit_rigid(p_sensor, p_world, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transform (R (3, 3), t (3,)) minimising sum w |R p_sensor + t - p_world|^2
    (Umeyama 1991, no scale). Needs at least 3 non-collinear pairs for a unique answer."""
    p_sensor = np.asarray(p_sensor, float).reshape(-1, 3)
    p_world = np.asarray(p_world, float).reshape(-1, 3)
    if len(p_sensor) != len(p_world) or len(p_sensor) == 0:
        raise ValueError(f"fit_rigid needs as many sensor points as world points, got {len(p_sensor)} "
                         f"and {len(p_world)}")
    return rigid_from_moments(*moments(p_sensor, p_world, weights))


def _fits(log: Log, row_code: np.ndarray, names, p_sensor: np.ndarray, p_world: np.ndarray) -> list[tuple]:
    """Every sensor's fit at once (the pairs grouped by sensor by one sort, their sums by
    reduceat, the 3 x 3 eigen- and singular-value problems batched): per sensor of the network,
    (pairs n, the world points' second principal spread (m, the square root of their
    covariance's middle eigenvalue) and principal direction, R, t of :func:`fit_rigid`, RMS
    residual of the fit (m)); the spread is NaN below 2 pairs, R and t without pairs.
    ``row_code``: each pair's sensor as a code into ``names``, the sensor ids (a name the network
    does not hold: no fit): :func:`pedcal.model.sensor_codes` of the sensor column gives both
    (every code a valid index, a missing id named, where plain ``pd.factorize`` codes it -1,
    which would index the last name)."""
    index = {s.id: i for i, s in enumerate(log.sensors)}
    m = len(index)
    # (each distinct name looked up once: a lookup per pair took longer than the fits)
    code = np.array([index.get(n, np.nan) for n in names], float)[row_code]
    keep = np.flatnonzero(np.isfinite(code))            # (a sensor the network does not hold: none of its fits)
    order = keep[np.argsort(code[keep], kind="stable")]
    code, p_sensor, p_world = code[order].astype(np.int64), p_sensor[order], p_world[order]
    n = np.bincount(code, minlength=m)
    first = np.searchsorted(code, np.arange(m))
    has = n > 0

    def sums(x):                                  # per sensor, (m, ...) of x's rows
        out = np.zeros((m,) + x.shape[1:])
        if has.any():
            out[has] = np.add.reduceat(x, first[has], axis=0)
        return out

    # the world points' covariance (centred first, as np.cov; unbiased): its second principal
    # spread and principal direction
    mean_w = sums(p_world) / np.maximum(n, 1)[:, None]
    d = p_world - mean_w[code]
    # (its six distinct products summed, the other three entries their mirror: the same sums)
    upper = np.triu_indices(3)
    cov = np.empty((m, 3, 3))
    cov[:, upper[0], upper[1]] = sums(d[:, upper[0]] * d[:, upper[1]])
    cov[:, upper[1], upper[0]] = cov[:, upper[0], upper[1]]
    cov /= np.maximum(n - 1, 1)[:, None, None]
    evals, evecs = np.linalg.eigh(cov)
    spread = np.where(n >= 2, np.sqrt(np.maximum(evals[:, 1], 0.0)), np.nan)
    R, t = np.full((m, 3, 3), np.nan), np.full((m, 3), np.nan)
    R[has], t[has] = rigid_from_moments(n[has].astype(float), sums(p_sensor)[has], sums(p_world)[has],
                                        sums(p_sensor[:, :, None] * p_world[:, None, :])[has])
    residual = np.linalg.norm(np.einsum("nij,nj->ni", R[code], p_sensor) + t[code] - p_world, axis=1)
    rms = np.sqrt(np.bincount(code, residual ** 2, minlength=m) / np.maximum(n, 1))
    return [(int(n[i]), float(spread[i]), evecs[i, :, 2], R[i], t[i], float(rms[i])) for i in range(m)]


def calibrate_closedform(log: Log, *, progress: bool = False, is_robot=None, latency_s: float | None = None,
                         min_pairs: int = MIN_PAIRS, collinear_spread_m: float = COLLINEAR_SPREAD_M,
                         points_sensor: np.ndarray | None = None, head_at=None,
                         **association_params) -> CalibrationResult:
    """Per-sensor Horn/Umeyama fit of the robot's observations to the AMCL head positions.

    ``is_robot``: bool mask over log.observations rows; None finds the robot with
    :func:`pedcal.calib.association.associate_robot` (``association_params`` go to it).
    ``latency_s``: tracker latency (observation stamp minus the robot's time); None takes the
    association's estimate, or estimates it from the given ``is_robot``. ``points_sensor``:
    ``log.observation_points_sensor()`` when the caller has it. ``head_at``:
    :func:`pedcal.calib.common.head_interpolator` of ``log`` (t -> the robot's head top in the
    world, from AMCL) when the caller has it, made when None; the association's when it runs."""
    with Timer() as timer:
        diagnostics = ClosedFormDiagnostics()
        # the head points in each sensor's frame, read once for the association, the latency and the fits
        p_sensor_all = log.observation_points_sensor() if points_sensor is None else np.asarray(points_sensor, float)
        if p_sensor_all.shape != (len(log.observations), 3):
            raise ValueError(f"points_sensor must be (n_observations, 3), got {p_sensor_all.shape}")
        if is_robot is None:
            from pedcal.calib.association import associate_robot

            assoc = associate_robot(log, progress=progress, p_sensor=p_sensor_all, **association_params)
            is_robot, head_at = assoc.is_robot, assoc.head_at
            diagnostics.association_runtime_s = assoc.runtime_s
            if latency_s is None:
                latency_s = assoc.latency_s
        else:
            is_robot = np.asarray(is_robot)
            if is_robot.shape != (len(log.observations),) or is_robot.dtype != bool:
                raise PedcalInputError(f"is_robot must be a boolean mask with one entry per observation "
                                       f"({len(log.observations)}), got dtype {is_robot.dtype} and shape "
                                       f"{is_robot.shape}", path=log.path)
        # (made after the association, whose error for a log without robot.csv is the clearer)
        head_at = head_interpolator(log) if head_at is None else head_at
        if latency_s is None:       # (a mask given: the association's estimate is not at hand)
            latency_s = estimate_latency(log, is_robot, head_at=head_at, p_sensor=p_sensor_all)
        diagnostics.tracker_latency_s = float(latency_s)

        # (each row's sensor by the column's codes: no Python string made per row)
        sensor_code, sensor_names = sensor_codes(log.observations["sensor"])
        t_all = log.observations["t"].to_numpy(float)
        # robot observations past either end of robot.csv have no AMCL position to pair with
        robot_t = log.robot["t"].to_numpy(float)
        covered = (t_all - latency_s >= robot_t.min()) & (t_all - latency_s <= robot_t.max())
        diagnostics.unpaired_robot_observations = int((is_robot & ~covered).sum())
        use = np.flatnonzero(is_robot & covered)
        fits = _fits(log, sensor_code[use], sensor_names, p_sensor_all[use], head_at(t_all[use] - latency_s))
        sensors_out = []
        for i, s in enumerate(log.sensors):
            n, spread_m, direction, R, t, rms_m = fits[i]
            if progress:
                logging.getLogger(__name__).info(f"closedform: sensor {s.id} ({i + 1}/{len(log.sensors)}), {n} pairs",
                                                 extra={"progress": (i + 1, len(log.sensors))})
            if n < min_pairs:
                sensors_out.append(SensorExtrinsics(s.id, s.position_m, s.ypr_deg, observations=n,
                                                    status="no-data"))
                continue
            if spread_m < collinear_spread_m:
                axis = ", ".join(f"{v:.2f}" for v in direction * np.sign(direction[np.argmax(np.abs(direction))]))
                what = f"rotation about the robot's line of travel (world direction [{axis}])"
                warnings.warn(f"sensor {s.id}: the robot's {n} observations lie on a line (spread "
                              f"{1000 * spread_m:.0f} mm across it): {what} cannot be estimated; the "
                              f"installed pose is kept", DegenerateDataWarning, stacklevel=2)
                sensors_out.append(SensorExtrinsics(s.id, s.position_m, s.ypr_deg, observations=n,
                                                    status="degenerate", unobservable=[what]))
                continue
            diagnostics.rms_residual_m[s.id] = rms_m
            sensors_out.append(SensorExtrinsics.from_pose3(s.id, gtsam.Pose3(gtsam.Rot3(R), t),
                                                           observations=n, status="ok"))
    extra = {**log.sensors.extra, LATENCY_KEY: round(float(latency_s), 4)}
    return CalibrationResult(SensorNetwork(sensors_out, log.sensors.frame, extra),
                             method="closedform", runtime_s=timer.elapsed_s, is_robot=is_robot,
                             diagnostics=diagnostics)
