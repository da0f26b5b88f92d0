"""The "alternative" baseline: SNAPCAT-3D style calibration from shared observations of people
(Glas et al. 2015), as compared against in Kimoto et al.

Every head the ceiling trackers reported is a landmark, the robot included (treated as one more
unlocalized person: robot.csv and the robot association are not used). When two sensors track
the same person at the same time, the two sensor-frame points of each shared instant must map to
one world point:

    T_world_i · p_i(t) = T_world_j · p_j(t)                                     (point coincidence)

All sensor poses are solved jointly from these relative constraints; the absolute frame comes,
as in SNAPCAT-3D, from the installed (hand-measured) poses, used as a weak prior on every
sensor. The result therefore inherits the coherent (common-mode) error of the installed network,
and a sensor that shares no view with any other cannot be reached at all: it keeps its installed
pose with status ``no-data``.

Shared observations (``match_shared_observations``): tracks of two sensors overlapping in time
for at least ``min_overlap_s`` are compared at the samples of the first track, the second being
linearly interpolated (trackers run at ~15 Hz, unsynchronized; brackets longer than ``max_gap_s``
are not interpolated across). In the first round the installed extrinsics can displace points by
up to ~1 m, so a match is judged by the *consistency* of the world offset over the overlap
(RMS spread about its median, ``max_spread_m``), with the median offset itself only gated loosely
(``max_offset_m``). A candidate is ambiguous, and rejected, when another candidate sharing one of
its tracks over an intersecting time span scores within ``ambiguity_ratio`` of it (people walking
side by side). Later rounds (``rounds``) re-match with the refined extrinsics, where the offset
itself must be small (``refined_max_offset_m``) and is part of the score.

Solver: GTSAM, one ``Pose3`` per sensor, one robust (Huber) pairwise factor per shared instant,
a ``PriorFactorPose3`` at the installed pose per sensor, Levenberg-Marquardt. The pairwise form
is the landmark form with each two-view landmark eliminated exactly (a point seen by two sensors
with isotropic noise sigma gives the coincidence residual with noise sigma·√2), so the graph
holds only the sensor poses; that keeps the solve and the marginal covariances (the reported
sigma) cheap, and GTSAM gives per-factor robust kernels and the Pose3 manifold directly.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field
from functools import partial

import gtsam
import numpy as np
import pandas as pd

from pedcal.calib.common import AlternativeDiagnostics, CalibrationResult, Timer
from pedcal.calib.options import AlternativeOptions
from pedcal.calib.readback import sensor_sigma_world
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.model import Log, SensorExtrinsics, SensorNetwork

DEFAULT_PARAMS = AlternativeOptions().to_kwargs()     # the fields of AlternativeOptions, commented there


@dataclass
class Track:
    """One tracker track: samples sorted by time, head points in the sensor's own frame."""

    sensor: str
    track: str
    t: np.ndarray          # (N,) s, strictly increasing
    p_sensor: np.ndarray   # (N, 3) m
    rows: np.ndarray       # (N,) rows of log.observations


@dataclass
class SharedPoints:
    """Simultaneous head points of one matched track pair of sensors (i, j)."""

    sensor_i: str
    sensor_j: str
    track_i: str
    track_j: str
    t: np.ndarray           # (M,) s
    p_i_sensor: np.ndarray  # (M, 3) m, measured by sensor i
    p_j_sensor: np.ndarray  # (M, 3) m, sensor j's track interpolated to t
    offset_m: float         # |median world offset| when matched
    spread_m: float         # RMS of the world offset about its median when matched


@dataclass
class MatchReport:
    matches: list[SharedPoints] = field(default_factory=list)
    candidates: int = 0      # track pairs overlapping long enough in time
    gated: int = 0           # of those, passing the offset / consistency gates
    ambiguous: int = 0       # of those, rejected as ambiguous


# ------------------------------------------------------------------------------------ input checks
def _params(options: dict) -> dict:
    unknown = sorted(set(options) - set(DEFAULT_PARAMS))
    if unknown:
        raise PedcalInputError(f"option(s) {', '.join(unknown)} not understood by method 'alternative'; "
                               f"expected some of {', '.join(DEFAULT_PARAMS)}")
    params = {**DEFAULT_PARAMS, **options}
    for name, value in params.items():
        if name == "compute_sigma":
            continue
        if name == "rounds":
            if int(value) != value or value < 1:
                raise PedcalInputError(f"option rounds must be an integer >= 1, got {value!r}")
            continue
        try:
            ok = np.isfinite(float(value)) and float(value) >= 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise PedcalInputError(f"option {name} must be a non-negative number, got {value!r}")
    return params


def _observations_file(log: Log) -> str:
    return str(log.path / "observations.csv") if log.path is not None else "observations.csv"


def _check_observations(log: Log) -> None:
    obs = log.observations
    where = _observations_file(log)
    for col in ("t", "sensor", "track", "x", "y", "z"):
        if col not in obs.columns:
            raise PedcalInputError(f"missing column '{col}' (expected t, sensor, track, x, y, z)",
                                   path=where, column=col)
    for col in ("t", "x", "y", "z"):
        values = pd.to_numeric(obs[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise PedcalInputError(f"expected a finite number, got {obs[col].iloc[bad[0]]!r}",
                                   path=where, row=int(bad[0]), column=col)
    known = set(log.sensors.ids)
    sensor_col = obs["sensor"].astype(str).to_numpy()
    bad = np.flatnonzero(~np.isin(sensor_col, list(known)))
    if bad.size:
        raise PedcalInputError(f"sensor '{sensor_col[bad[0]]}' is not in sensors.yaml "
                               f"(known: {', '.join(sorted(known))})", path=where, row=int(bad[0]),
                               column="sensor")


def build_tracks(log: Log, p_sensor: np.ndarray | None = None) -> dict[str, list[Track]]:
    """Tracks of every sensor (tracks with fewer than two distinct time stamps are dropped;
    a repeated time stamp within a track keeps its first row). ``p_sensor``:
    ``log.observation_points_sensor()`` when the caller has it (read, not changed)."""
    obs = log.observations
    p_sensor = log.observation_points_sensor() if p_sensor is None else np.asarray(p_sensor, float)
    t_all = obs["t"].to_numpy(float)
    sensor_col = obs["sensor"].astype(str).to_numpy()
    track_col = obs["track"].astype(str).to_numpy()
    tracks: dict[str, list[Track]] = {sid: [] for sid in log.sensors.ids}
    groups = obs.groupby([sensor_col, track_col], sort=True).indices
    for (sid, tid), rows in groups.items():
        rows = rows[np.argsort(t_all[rows], kind="stable")]
        _, first = np.unique(t_all[rows], return_index=True)
        rows = rows[first]
        if len(rows) >= 2:
            tracks[sid].append(Track(sid, tid, t_all[rows], p_sensor[rows], rows))
    return tracks


# ---------------------------------------------------------------------------------------- matching
def _interpolation(t_query: np.ndarray, t_track: np.ndarray, max_gap_s: float):
    """Where t_query falls inside t_track with a bracketing interval no longer than max_gap_s:
    (valid mask, bracket index k (t_track[k-1] <= t <= t_track[k]), weight of sample k)."""
    k = np.clip(np.searchsorted(t_track, t_query), 1, len(t_track) - 1)
    t0, t1 = t_track[k - 1], t_track[k]
    valid = (t_query >= t_track[0]) & (t_query <= t_track[-1]) & (t1 - t0 <= max_gap_s)
    w = (t_query - t0) / (t1 - t0)
    return valid, k, w


def _lerp(points: np.ndarray, k: np.ndarray, w: np.ndarray) -> np.ndarray:
    return points[k - 1] + w[:, None] * (points[k] - points[k - 1])


def _sensor_pair_matches(tracks_i, tracks_j, world_i, world_j, params, refined: bool):
    """Candidates, gated scores and accepted matches between the tracks of two sensors."""
    if not tracks_i or not tracks_j:
        return 0, 0, 0, []
    start_i = np.array([tr.t[0] for tr in tracks_i])
    end_i = np.array([tr.t[-1] for tr in tracks_i])
    start_j = np.array([tr.t[0] for tr in tracks_j])
    end_j = np.array([tr.t[-1] for tr in tracks_j])
    overlap_s = np.minimum(end_i[:, None], end_j[None, :]) - np.maximum(start_i[:, None], start_j[None, :])
    cand_a, cand_b = np.nonzero(overlap_s >= params["min_overlap_s"])
    gated = []   # (a, b, score, t_lo, t_hi, SharedPoints)
    for a, b in zip(cand_a, cand_b, strict=True):
        ta, tb = tracks_i[a].t, tracks_j[b].t
        valid, k, w = _interpolation(ta, tb, params["max_gap_s"])
        if valid.sum() < 2 or np.ptp(ta[valid]) < params["min_overlap_s"]:
            continue
        k, w = k[valid], w[valid]
        d_world = world_i[a][valid] - _lerp(world_j[b], k, w)
        median = np.median(d_world, axis=0)
        offset_m = float(np.linalg.norm(median))
        spread_m = float(np.sqrt(np.mean(np.sum((d_world - median) ** 2, axis=1))))
        if refined:
            if offset_m > params["refined_max_offset_m"] or spread_m > params["max_spread_m"]:
                continue
            score = float(np.sqrt(np.mean(np.sum(d_world ** 2, axis=1))))
        else:
            if offset_m > params["max_offset_m"] or spread_m > params["max_spread_m"]:
                continue
            score = spread_m
        t_shared = ta[valid]
        shared = SharedPoints(tracks_i[a].sensor, tracks_j[b].sensor, tracks_i[a].track, tracks_j[b].track,
                              t_shared, tracks_i[a].p_sensor[valid], _lerp(tracks_j[b].p_sensor, k, w),
                              offset_m, spread_m)
        gated.append((a, b, score, t_shared[0], t_shared[-1], shared))
    accepted, ambiguous = [], 0
    for n, (a, b, score, lo, hi, shared) in enumerate(gated):
        rivals = [g[2] for m, g in enumerate(gated)
                  if m != n and (g[0] == a or g[1] == b) and g[3] < hi and lo < g[4]]
        if rivals and not score < params["ambiguity_ratio"] * min(rivals):
            ambiguous += 1
            continue
        accepted.append(shared)
    return len(cand_a), len(gated), ambiguous, accepted


def _thin(shared: SharedPoints, period_s: float) -> SharedPoints:
    """At most one shared instant per ``period_s`` (consecutive 15 Hz samples are not
    independent evidence)."""
    if period_s <= 0:
        return shared
    _, keep = np.unique(np.floor((shared.t - shared.t[0]) / period_s), return_index=True)
    return SharedPoints(shared.sensor_i, shared.sensor_j, shared.track_i, shared.track_j, shared.t[keep],
                        shared.p_i_sensor[keep], shared.p_j_sensor[keep], shared.offset_m, shared.spread_m)


def match_shared_observations(tracks: dict[str, list[Track]], network: SensorNetwork, *,
                              refined: bool = False, **options) -> MatchReport:
    """Track pairs of every two sensors that are the same person at the same time, judged with
    the world points that ``network``'s extrinsics give. ``refined=False`` for the installed
    extrinsics (offset gated loosely, score = consistency of the offset), ``True`` once the
    extrinsics are calibrated (the offset itself must be small and is scored)."""
    params = _params(options)
    world = {sid: [network[sid].to_world(tr.p_sensor) for tr in trs] for sid, trs in tracks.items()}
    report = MatchReport()
    ids = [sid for sid in network.ids if sid in tracks]
    for n, sid_i in enumerate(ids):
        for sid_j in ids[n + 1:]:
            cand, gated, ambiguous, accepted = _sensor_pair_matches(
                tracks[sid_i], tracks[sid_j], world[sid_i], world[sid_j], params, refined)
            report.candidates += cand
            report.gated += gated
            report.ambiguous += ambiguous
            report.matches.extend(_thin(s, params["sample_period_s"]) for s in accepted)
    return report


# ----------------------------------------------------------------------------------------- solving
def coincidence_error(p_i_sensor: np.ndarray, p_j_sensor: np.ndarray, this: gtsam.CustomFactor,
                      values: gtsam.Values, H) -> np.ndarray:
    """Point coincidence T_world_i · p_i − T_world_j · p_j (world axes, m), with the Jacobians
    in GTSAM's Pose3 tangent order [rotation, translation], body frame:
    d(T·p)/dξ = [−R [p]×, R]."""
    keys = this.keys()
    T_i, T_j = values.atPose3(keys[0]), values.atPose3(keys[1])
    if H is None:
        return T_i.transformFrom(p_i_sensor) - T_j.transformFrom(p_j_sensor)
    # GTSAM's own transformFrom Jacobians (the expression above), far cheaper than numpy here.
    H_i, H_j, H_point = (np.zeros((3, 6), order="F"), np.zeros((3, 6), order="F"),
                         np.zeros((3, 3), order="F"))
    err = T_i.transformFrom(p_i_sensor, H_i, H_point) - T_j.transformFrom(p_j_sensor, H_j, H_point)
    H[0] = H_i
    H[1] = -H_j
    return err


def _solve(installed: SensorNetwork, initial: SensorNetwork, matches: list[SharedPoints], params: dict,
           compute_sigma: bool):
    """Joint LM solve of the sensor poses that appear in ``matches``; returns
    ({sensor: Pose3}, {sensor: 6x6 body covariance} or None, final error, iterations)."""
    active = sorted({m.sensor_i for m in matches} | {m.sensor_j for m in matches}, key=installed.ids.index)
    key = {sid: gtsam.symbol("s", n) for n, sid in enumerate(active)}
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, np.radians(params["prior_sigma_deg"])),
                                                         np.full(3, params["prior_sigma_position_m"])])
    for sid in active:
        graph.add(gtsam.PriorFactorPose3(key[sid], installed[sid].T_world_sensor, prior_noise))
        values.insert(key[sid], initial[sid].T_world_sensor)
    # Two-view landmark eliminated: each tracker's sigma adds in quadrature.
    point_noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(params["huber_k"]),
        gtsam.noiseModel.Isotropic.Sigma(3, np.sqrt(2.0) * params["point_sigma_m"]))
    for m in matches:
        for p_i, p_j in zip(m.p_i_sensor, m.p_j_sensor, strict=True):
            graph.add(gtsam.CustomFactor(point_noise, [key[m.sensor_i], key[m.sensor_j]],
                                         partial(coincidence_error, p_i.copy(), p_j.copy())))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(100)
    lm.setRelativeErrorTol(1e-8)
    lm.setAbsoluteErrorTol(1e-10)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    result = optimizer.optimize()
    poses = {sid: result.atPose3(key[sid]) for sid in active}
    covs = None
    if compute_sigma and active:
        marginals = gtsam.Marginals(graph, result)
        covs = {sid: marginals.marginalCovariance(key[sid]) for sid in active}
    return poses, covs, float(graph.error(result)), int(optimizer.iterations())


def _residual_rms_mm(m: SharedPoints, network: SensorNetwork) -> float:
    d = network[m.sensor_i].to_world(m.p_i_sensor) - network[m.sensor_j].to_world(m.p_j_sensor)
    return float(1000.0 * np.sqrt(np.mean(np.sum(d ** 2, axis=1))))


def _path_spread_m(points_sensor: np.ndarray) -> float:
    """Second principal spread (RMS, m) of a sensor's shared points: ~0 when they lie on a line,
    which leaves the rotation about that line to the prior."""
    centred = points_sensor - points_sensor.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    return float(sv[1] / np.sqrt(len(points_sensor))) if len(sv) > 1 else 0.0


# ------------------------------------------------------------------------------------- entry point
def calibrate_alternative(log: Log, *, progress: bool = False, **options) -> CalibrationResult:
    """SNAPCAT-3D style calibration (Glas et al. 2015) of every ceiling sensor of ``log`` from
    people seen simultaneously by overlapping sensors, anchored by the installed poses.

    Options (keywords): see ``DEFAULT_PARAMS``. Sensors sharing no observation with any other keep
    their installed pose with status ``no-data`` (a DegenerateDataWarning names them); sensors whose
    shared points lie on one line are ``degenerate`` (rotation about that line set by the prior).
    """
    params = _params(options)

    def say(msg: str) -> None:
        if progress:
            logging.getLogger(__name__).info(f"alternative: {msg}")

    with Timer() as timer:
        _check_observations(log)
        installed = log.sensors
        tracks = build_tracks(log)
        say(f"{sum(map(len, tracks.values()))} tracks in {len(installed)} sensors")
        current = installed.copy()
        rounds_info = []
        covs = None
        matches: list[SharedPoints] = []
        match_options = {k: params[k] for k in DEFAULT_PARAMS}
        for rnd in range(int(params["rounds"])):
            report = match_shared_observations(tracks, current, refined=rnd > 0, **match_options)
            if rnd > 0 and not report.matches:
                say(f"round {rnd + 1}: no matches with the refined extrinsics; keeping round {rnd}")
                break
            matches = report.matches
            n_points = sum(len(m.t) for m in matches)
            say(f"round {rnd + 1}: {report.candidates} candidate track pairs, {report.gated} gated, "
                f"{report.ambiguous} ambiguous, {len(matches)} matched, {n_points} shared points")
            if not matches:
                rounds_info.append({"candidates": report.candidates, "gated": report.gated,
                                    "ambiguous": report.ambiguous, "matched": 0, "points": 0})
                break
            last = rnd == int(params["rounds"]) - 1
            poses, covs, error, iterations = _solve(installed, current, matches, params,
                                                    compute_sigma=bool(params["compute_sigma"]) and last)
            current = installed.copy()
            for sid, T in poses.items():
                current.sensors[current.ids.index(sid)] = SensorExtrinsics.from_pose3(sid, T)
            rounds_info.append({"candidates": report.candidates, "gated": report.gated,
                                "ambiguous": report.ambiguous, "matched": len(matches), "points": n_points,
                                "final_error": error, "iterations": iterations})
        if covs is None and matches and params["compute_sigma"]:
            # The last round stopped early: marginals of the kept solution.
            _, covs, _, _ = _solve(installed, current, matches, {**params}, compute_sigma=True)

        shared_points = {sid: [] for sid in installed.ids}
        per_pair: dict[str, dict] = {}
        for m in matches:
            shared_points[m.sensor_i].append(m.p_i_sensor)
            shared_points[m.sensor_j].append(m.p_j_sensor)
            entry = per_pair.setdefault(f"{m.sensor_i}-{m.sensor_j}", {"tracks": 0, "points": 0, "_sq": 0.0})
            entry["tracks"] += 1
            entry["points"] += len(m.t)
            entry["_sq"] += (_residual_rms_mm(m, current) ** 2) * len(m.t)
        for entry in per_pair.values():
            entry["residual_rms_mm"] = float(np.sqrt(entry.pop("_sq") / entry["points"]))

        out, no_data, degenerate = [], [], []
        for s in installed:
            if not shared_points[s.id]:
                no_data.append(s.id)
                out.append(SensorExtrinsics(s.id, s.position_m.copy(), s.ypr_deg.copy(), observations=0,
                                            status="no-data"))
                continue
            pts = np.concatenate(shared_points[s.id])
            est = current[s.id]
            sigma_p = sigma_ypr = None
            if covs is not None:
                _, sigma_p, sigma_ypr = sensor_sigma_world(est.T_world_sensor, covs[s.id])
            status, unobservable = "ok", None
            if _path_spread_m(pts) < params["min_path_spread_m"]:
                status, unobservable = "degenerate", ["rotation about the shared path"]
                degenerate.append(s.id)
            out.append(SensorExtrinsics(s.id, est.position_m, est.ypr_deg, sigma_position_m=sigma_p,
                                        sigma_ypr_deg=sigma_ypr, observations=len(pts), status=status,
                                        unobservable=unobservable))
        if no_data:
            warnings.warn(f"sensor(s) {', '.join(no_data)} share no simultaneous observation of a person "
                          "with any other sensor: their pose cannot be estimated and stays as installed",
                          DegenerateDataWarning, stacklevel=2)
        if degenerate:
            warnings.warn(f"sensor(s) {', '.join(degenerate)}: the shared observations lie on one line; "
                          "the rotation about it is left to the installed pose", DegenerateDataWarning,
                          stacklevel=2)
        network = SensorNetwork(out, installed.frame, dict(installed.extra))
    say(f"done in {timer.elapsed_s:.2f} s")
    diagnostics = AlternativeDiagnostics(pairs=sorted(per_pair), matches_per_pair=per_pair, rounds=rounds_info,
                                         no_data=no_data, params=params)
    return CalibrationResult(network, method="alternative", runtime_s=timer.elapsed_s, is_robot=None,
                             diagnostics=diagnostics)
