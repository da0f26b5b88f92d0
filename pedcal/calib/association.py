"""Picking out the robot's observations among everything the ceiling trackers saw.

observations.csv holds every person a ceiling sensor tracked: the robot, pedestrians (some of
them walking right beside the robot), short false tracks. The robot is recognised by its
motion, not by proximity: a whole (sensor, track) segment belongs to the robot when its
sensor-frame head points follow the AMCL head trajectory under the ONE rigid transform
T_world_sensor that all of that sensor's robot segments share.

Per sensor the transform is found by consensus (RANSAC over segments, Fischler & Bolles 1981):
hypotheses are Horn/Umeyama fits to the longest plausible segments and to pairs of them, each
gated by the prior that the installed extrinsics are within ~1 m / 15 deg of the truth, and
scored by how many segment-seconds they explain (head within ``inlier_m`` in 3D, so the head
height counts). The winner is refined on all the points it explains (locally optimised
RANSAC). A pedestrian walking 0.5-1 m beside the robot fits a per-segment transform as well as
the robot does, but with a shifted one that the sensor's other robot passes reject.

The tracker's latency (observation stamps late by up to ~0.3 s) is estimated once for the whole
log, pooling every sensor: for a straight pass a time offset is indistinguishable from a shift
along the line, so one sensor alone cannot tell them apart.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field

import gtsam
import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar

from pedcal.calib.common import Timer, head_interpolator
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.model import Log, SensorExtrinsics, SensorNetwork, rows_by_code, sensor_codes

DEFAULT_PARAMS = {
    "gate_m": 2.5,            # installed-world head within this of the AMCL head (~1 m + 15 deg at ~4 m)
    "max_offset_m": 1.5,      # a hypothesis' sensor position stays this close to the installed one
    "max_angle_deg": 25.0,    # ... and its orientation this close
    "inlier_m": 0.3,          # 3D head residual of an observation the transform explains
    "max_latency_s": 0.4,     # observation stamps may be late (or early) by up to this
    "latency_step_s": 0.1,    # coarse latency grid of the first consensus pass
    "n_seed_segments": 8,     # longest plausible segments that seed hypotheses (alone and in pairs)
    "min_segment_points": 3,  # points of a seed segment, and of a part of a segment after a swap
    "min_run_s": 1.0,         # a part of a segment (after a track swap) needs this duration
    "whole_fraction": 0.6,    # explained fraction above which the whole segment is the robot
    "max_gap_points": 2,      # unexplained runs this short inside an explained run are closed
    "min_support_s": 1.0,     # a sensor needs this many explained seconds to have seen the robot
    # how far a hand measurement is off (1 sigma): hypotheses are weighted by this prior, so a
    # person beside the robot (offset sideways, head 0.2-0.5 m higher: a sensor height off by
    # that much) loses to the robot's own passes even with more seconds
    "prior_sigma_position_m": (0.5, 0.5, 0.15),
    "prior_sigma_deg": 10.0,
    "prior_weight": 1e-3,     # weight of the installed pose in the refit, relative to the data
    "collinear_spread_m": 0.1,  # second principal spread below which the pairs are a line
    "refine_iterations": 6,
}


@dataclass
class AssociationResult:
    """Which observations are the robot, and what that says of each sensor.

    ``is_robot``: bool mask over the rows of ``log.observations`` (file order).
    ``extrinsics``: per sensor the consensus T_world_sensor (status ok / degenerate / no-data;
    installed pose kept where the robot was not found). ``segments``: one row per
    (sensor, track) segment with its score. ``latency_s``: observation stamp minus the time
    the robot was really there, estimated over the whole log."""

    is_robot: np.ndarray
    extrinsics: SensorNetwork
    segments: pd.DataFrame
    latency_s: float
    runtime_s: float = 0.0
    params: dict = field(default_factory=dict)
    # the AMCL head's interpolator the association read (:func:`pedcal.calib.common.head_interpolator`
    # of the log), for a caller that reads the same track next
    head_at: object = field(default=None, repr=False, compare=False)

    def T_world_sensor(self, sensor_id: str) -> gtsam.Pose3:
        return self.extrinsics[sensor_id].T_world_sensor


# --------------------------------------------------------------------------- rigid fitting


def rigid_from_moments(w, sum_p, sum_q, sum_pq):
    """Batched weighted Horn/Umeyama fit (Umeyama 1991, eqs. 34-42, no scale) from moments.

    ``w`` (...,), ``sum_p``, ``sum_q`` (..., 3) and ``sum_pq`` (..., 3, 3) = sum w p q^T of the
    pairs (p, q); returns R (..., 3, 3), t (..., 3) minimising sum w |R p + t - q|^2."""
    w = np.asarray(w, float)[..., None]
    mean_p, mean_q = sum_p / w, sum_q / w
    # cross-covariance sum w (p - mean_p)(q - mean_q)^T
    H = sum_pq - w[..., None] * mean_p[..., :, None] * mean_q[..., None, :]
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, -1, -2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = V @ D @ np.swapaxes(U, -1, -2)
    t = mean_q - np.einsum("...ij,...j->...i", R, mean_p)
    return R, t


def moments(p, q, w=None):
    """(w, sum p, sum q, sum p q^T) of pairs (N, 3); inputs of :func:`rigid_from_moments`."""
    w = np.ones(len(p)) if w is None else np.asarray(w, float)
    return (w.sum(), w @ p, w @ q, np.einsum("n,ni,nj->ij", w, p, q))


def _anchor_moments(center_sensor, sensor: SensorExtrinsics, weight):
    """Moments of six virtual pairs pinning the fit to the installed pose: the points
    c +- 1 m along each sensor axis around ``center_sensor`` c (..., 3), paired with where the
    installed extrinsics (R0, t0) put them, sharing ``weight`` (...,). In closed form, since the
    offsets e_k sum to 0 and sum e_k e_k^T = 2 I: sum p = W c, sum q = W (R0 c + t0),
    sum p q^T = W c (R0 c + t0)^T + (W / 3) R0^T."""
    R0, t0 = sensor.R_world_sensor, sensor.position_m
    c = np.asarray(center_sensor, float)
    w = np.asarray(weight, float)
    q = c @ R0.T + t0
    spq = w[..., None, None] * (c[..., :, None] * q[..., None, :]) + (w / 3.0)[..., None, None] * R0.T
    return w, w[..., None] * c, w[..., None] * q, spq


# --------------------------------------------------------------------------- per-sensor data


class _SensorRows:
    """One sensor's observations sorted by segment then time, with per-segment bookkeeping."""

    def __init__(self, sensor, rows, t, seg_codes, tracks, p_sensor, p_installed, in_range):
        order = np.lexsort((t, seg_codes))
        self.sensor = sensor
        self.rows = rows[order]
        self.t = t[order]
        self.p = p_sensor[order]
        self.p_installed = p_installed[order]
        self.in_range = in_range[order]
        codes = seg_codes[order]
        self.seg_start = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]])
        self.seg_end = np.r_[self.seg_start[1:], len(codes)]
        self.seg_of_point = np.repeat(np.arange(len(self.seg_start)), self.seg_end - self.seg_start)
        self.seg_track = tracks[order][self.seg_start]
        self.seg_n = self.seg_end - self.seg_start
        self.seg_duration = self.t[self.seg_end - 1] - self.t[self.seg_start]
        self.set_in_range(self.in_range)

    def set_in_range(self, in_range):
        """Points the robot track covers; each stands for segment-seconds (a segment's points
        sum to its duration)."""
        self.in_range = in_range
        self.w_time = (self.seg_duration / self.seg_n)[self.seg_of_point] * in_range

    def __len__(self):
        return len(self.t)

    def seg_sum(self, values):
        return np.add.reduceat(values, self.seg_start, axis=0)


def _residuals(R, t, p, q):
    """|R p + t - q| for hypotheses R (H, 3, 3), t (H, 3) and points (N, 3): (H, N)."""
    d = p @ np.swapaxes(R, -1, -2) + (t[:, None, :] - q[None])      # matmul: ~3x einsum's speed
    return np.sqrt(np.einsum("hni,hni->hn", d, d))


def _squared_residuals(R, t, p, q):
    """|R p + t - q|^2 for hypotheses R (..., H, 3, 3), t (..., H, 3) and points p (N, 3), q
    (..., N, 3): (..., H, N), the leading axes (latencies, say) each with its own q. Expanded
    into products that are matrix products over the points (|p|^2 + |q|^2 + |t|^2 + 2 (R^T t).p
    - 2 t.q - 2 <R, q p^T>, the last the hypotheses' R (H, 9) times the pairs' q p^T (9, N)):
    ~4x the direct difference's speed. ``q`` and ``t`` are taken about q's mean, so that the
    terms stay the size of the scene around the points (their rounding ~1e-15 m^2 here, against
    inlier gates of 0.01-1 m^2)."""
    c = q.mean(axis=-2, keepdims=True) if q.shape[-2] else np.zeros(q.shape[:-2] + (1, 3))
    q, t = q - c, t - c
    qp = (q[..., :, :, None] * p[:, None, :]).reshape(q.shape[:-2] + (len(p), 9))
    d2 = ((np.einsum("ni,ni->n", p, p) + np.einsum("...ni,...ni->...n", q, q))[..., None, :]
          + np.einsum("...hi,...hi->...h", t, t)[..., :, None])
    # 2 ((R^T t).p - t.q - <R, q p^T>), its terms taken in that order in place (the hypotheses x
    # points arrays are the cost: one made per term, no more)
    cross = np.einsum("...hij,...hi->...hj", R, t) @ p.T
    cross -= t @ np.swapaxes(q, -1, -2)
    cross -= R.reshape(R.shape[:-2] + (9,)) @ np.swapaxes(qp, -1, -2)
    cross *= 2.0
    d2 += cross
    return np.maximum(d2, 0.0, out=d2)


def _prior_ok(R, t, sensor: SensorExtrinsics, params):
    """(within the gates, squared Mahalanobis distance to the installed pose under the prior)."""
    R0 = sensor.R_world_sensor
    cos_angle = (np.einsum("ij,hij->h", R0, R) - 1.0) / 2.0
    angle_deg = np.degrees(np.arccos(np.clip(cos_angle, -1.0, 1.0)))
    offset = t - sensor.position_m
    offset_m = np.linalg.norm(offset, axis=1)
    ok = (offset_m <= params["max_offset_m"]) & (angle_deg <= params["max_angle_deg"])
    d2 = np.sum((offset / np.asarray(params["prior_sigma_position_m"], float)) ** 2, axis=1) + (
        angle_deg / params["prior_sigma_deg"]) ** 2
    return ok, d2


def _consensus(sd: _SensorRows, sensor, heads_by_latency, params):
    """RANSAC over segments: best (R, t, latency index, explained seconds) or None. Every
    latency's hypotheses are fitted and scored at once (arrays over latency x hypothesis), the
    first latency with the best score kept."""
    q0 = heads_by_latency[len(heads_by_latency) // 2]
    gated = sd.in_range & (np.linalg.norm(sd.p_installed - q0, axis=1) <= params["gate_m"])
    gated_s = sd.seg_sum(sd.w_time * gated)
    plausible = (sd.seg_sum(gated.astype(float)) >= np.maximum(params["min_segment_points"], 3)) & (
        gated_s >= 0.5 * sd.seg_duration)
    cands = np.flatnonzero(plausible)
    if len(cands) == 0:
        return None
    seeds = cands[np.argsort(-gated_s[cands], kind="stable")][: params["n_seed_segments"]]
    k = len(seeds)
    members = [np.array([i]) for i in range(k)] + [np.array([i, j]) for i in range(k) for j in range(i + 1, k)]
    M = np.zeros((len(members), k))
    for h, m in enumerate(members):
        M[h, m] = 1.0
    seed_point_mask = np.isin(sd.seg_of_point, seeds) & sd.in_range
    col_of_seg = np.full(len(sd.seg_start), -1)
    col_of_seg[seeds] = np.arange(k)
    seed_col = col_of_seg[sd.seg_of_point]
    # one-hot (point, seed) of the seeds' points: a hypothesis' inliers per seed are one product
    seed_onehot = np.zeros((int(seed_point_mask.sum()), k))
    seed_onehot[np.arange(len(seed_onehot)), seed_col[seed_point_mask]] = 1.0
    w = sd.in_range.astype(float)
    seg_w = sd.seg_sum(w)[seeds]
    hw, hp = M @ seg_w, M @ sd.seg_sum(w[:, None] * sd.p)[seeds]
    # a weak pull toward the installed pose fixes the rotation about a straight seed segment
    # (the same at every latency: it depends on the sensor-frame points alone)
    anchors = _anchor_moments(hp / hw[:, None], sensor, params["prior_weight"] * hw)
    # the seeds' points alone (each seed's rows in seed order) give the seeds' moments
    seed_rows = np.concatenate([np.arange(sd.seg_start[s], sd.seg_end[s]) for s in seeds])
    seed_starts = np.r_[0, np.cumsum(sd.seg_n[seeds])[:-1]]
    q_all = np.asarray(heads_by_latency, float)                  # (L, N, 3)
    n_lat = len(q_all)
    q_seed = q_all[:, seed_rows]
    w_seed, wp_seed = w[seed_rows, None], (w[:, None] * sd.p)[seed_rows]
    seg_q = np.add.reduceat(w_seed * q_seed, seed_starts, axis=1)                      # (L, k, 3)
    seg_pq = np.add.reduceat((wp_seed[:, :, None] * q_seed[:, :, None, :]).reshape(n_lat, len(seed_rows), 9),
                             seed_starts, axis=1)                                        # (L, k, 9)
    hq, hpq = M @ seg_q, (M @ seg_pq).reshape(n_lat, len(M), 3, 3)
    R, t = rigid_from_moments(*(x + y for x, y in zip((hw, hp, hq, hpq), anchors, strict=True)))
    ok, prior_d2 = _prior_ok(R.reshape(-1, 3, 3), t.reshape(-1, 3), sensor, params)
    ok, prior_d2 = ok.reshape(n_lat, len(M)), prior_d2.reshape(n_lat, len(M))
    lat = np.flatnonzero(ok.any(axis=1))                   # latencies with a hypothesis in the gates
    if not len(lat):
        return None
    inlier = _squared_residuals(R[lat], t[lat], sd.p, q_all[lat]) < params["inlier_m"] ** 2   # (l, H, N)
    # a seed must itself follow the robot: most of its points explained
    seed_inlier = inlier[:, :, seed_point_mask].astype(float) @ seed_onehot
    seed_frac = seed_inlier / np.maximum(seg_w, 1.0)
    seeds_follow = ((seed_frac >= 0.5) | (M == 0)).all(axis=2)
    support_s = (inlier * sd.w_time).sum(axis=2)
    # explained seconds weighted by the installed prior (a Gaussian likelihood ratio)
    score = support_s * np.exp(-0.5 * prior_d2[lat])
    score[~(seeds_follow & ok[lat])] = -np.inf
    best = None
    for j, li in enumerate(lat.tolist()):
        h = int(np.argmax(score[j]))
        if np.isfinite(score[j, h]) and (best is None or score[j, h] > best[3]):
            best = (R[li, h], t[li, h], li, score[j, h], support_s[j, h])
    if best is None or best[4] < params["min_support_s"]:
        return None
    return best[:4]


def _select(sd: _SensorRows, inlier, params):
    """Which points are the robot, given which ones the transform explains: whole segments
    when most of a segment is explained, else only its explained runs (a track swap)."""
    selected = np.zeros(len(sd), bool)
    kind = np.full(len(sd.seg_start), "no", dtype=object)
    for s in np.flatnonzero(sd.seg_sum(inlier.astype(int)) > 0):
        a, b = sd.seg_start[s], sd.seg_end[s]
        f = inlier[a:b].copy()
        # close short unexplained gaps between explained points
        edges = np.diff(np.r_[0, f.astype(int), 0])
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        for e, s2 in zip(ends[:-1], starts[1:], strict=True):
            if s2 - e <= params["max_gap_points"]:
                f[e:s2] = True
        if f[sd.in_range[a:b]].mean() >= params["whole_fraction"]:
            # the whole segment, also its points past either end of robot.csv
            selected[a:b] = True
            kind[s] = "whole"
            continue
        edges = np.diff(np.r_[0, f.astype(int), 0])
        for r0, r1 in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            tt = sd.t[a + r0: a + r1]
            if r1 - r0 >= params["min_segment_points"] and tt[-1] - tt[0] >= params["min_run_s"]:
                selected[a + r0: a + r1] = True
                kind[s] = "part"
    return selected, kind


def _refine(sd: _SensorRows, sensor, R, t, q, params):
    """Locally optimised consensus: refit on everything the transform explains, repeat."""
    selected = None
    for _ in range(params["refine_iterations"]):
        r = _residuals(R[None], t[None], sd.p, q)[0]
        new_selected, kind = _select(sd, (r < params["inlier_m"]) & sd.in_range, params)
        fit_mask = new_selected & (r < params["inlier_m"]) & sd.in_range
        if fit_mask.sum() < 3 or (selected is not None and np.array_equal(new_selected, selected)):
            selected = new_selected
            break
        selected = new_selected
        m = moments(sd.p[fit_mask], q[fit_mask])
        a = _anchor_moments(m[1] / m[0], sensor, params["prior_weight"] * m[0])
        R, t = rigid_from_moments(*(x + y for x, y in zip(m, a, strict=True)))
    r = _residuals(R[None], t[None], sd.p, q)[0]
    return R, t, r, selected, kind


# --------------------------------------------------------------------------- latency


def pooled_rigid_sse(p: np.ndarray, bounds: list[int], q: np.ndarray) -> np.ndarray:
    """Sum over groups (rows ``bounds[g]:bounds[g + 1]`` of the pairs) of each group's optimal
    rigid fit's squared residual sum |R p + t - q|^2, for each leading index of ``q`` (..., N, 3)
    (``p`` (N, 3) shared): per group |p~|^2 + |q~|^2 - 2 tr(R H), p~ and q~ about their means and
    H = sum p~ q~^T, where tr(R H) is the sum of H's singular values, the least one signed by the
    rotation's determinant (Umeyama 1991, eqs. 34-42, the fit :func:`rigid_from_moments`
    makes): no residuals formed, one 3 x n by n x 3 product per group and leading index."""
    return _pooled_rigid_sse_of(p, bounds)(q)


def _pooled_rigid_sse_of(p: np.ndarray, bounds: list[int]):
    """q -> :func:`pooled_rigid_sse` (p, bounds, q), the groups' p~ and |p~|^2 taken once for every
    q, and one SVD call for every group's H (LAPACK takes the stack's matrices one by one: the
    values of a call per group, to the bit, which the latency's bounded search, on a flat
    minimum, needs)."""
    groups = [(a, b, p[a:b] - p[a:b].mean(axis=0)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    groups = [(a, b, pg.T, float(np.sum(pg * pg))) for a, b, pg in groups]

    def sse(q: np.ndarray) -> np.ndarray:
        lead = q.shape[:-2]
        q = q.reshape(-1, q.shape[-2], 3)
        total = np.zeros(len(q))
        H = np.empty((len(groups), len(q), 3, 3))
        spread = []
        for g, (a, b, pg_t, pp) in enumerate(groups):
            qg = q[:, a:b, :]
            qg = qg - qg.mean(axis=1, keepdims=True)
            H[g] = pg_t @ qg                               # (L, 3, 3)
            spread.append(pp + np.einsum("lni,lni->l", qg, qg))
        U, sv, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
        d = np.where(d == 0, 1.0, d)
        for g, s_g in enumerate(spread):                   # (summed in the groups' order)
            total += s_g - 2.0 * (sv[g, :, 0] + sv[g, :, 1] + d[g] * sv[g, :, 2])
        return total.reshape(lead)

    return sse


def estimate_latency(log: Log, is_robot: np.ndarray, *, max_latency_s: float = 0.4,
                     p_sensor: np.ndarray | None = None, head_at=None) -> float:
    """Tracker latency (observation stamp minus the time the robot was there, s) minimising the
    pooled residual of per-sensor rigid fits of the robot's observations to the AMCL head
    (``head_at``: :func:`pedcal.calib.common.head_interpolator` of ``log``, made when None)."""
    is_robot = np.asarray(is_robot, bool)
    if is_robot.sum() < 4:
        return 0.0
    codes, _ = pd.factorize(sensor_codes(log.observations["sensor"])[0][is_robot])
    counts = np.bincount(codes)
    keep = counts[codes] >= 3               # sensors with enough pairs for a fit
    order = np.argsort(codes[keep], kind="stable")
    p = (log.observation_points_sensor() if p_sensor is None else p_sensor)[is_robot][keep][order]
    t = log.observations["t"].to_numpy(float)[is_robot][keep][order]
    codes = codes[keep][order]
    if len(codes) == 0:
        return 0.0
    starts = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]])
    bounds = np.r_[starts, len(codes)].tolist()
    head_at = head_interpolator(log) if head_at is None else head_at
    sse_of = _pooled_rigid_sse_of(p, bounds)

    def sse(latency_s):
        return float(sse_of(head_at(t - latency_s)))

    grid = np.arange(-max_latency_s, max_latency_s + 1e-9, 0.02)
    # the grid in one pass (the head spline evaluated at every latency's times at once)
    values = sse_of(head_at((t[None, :] - grid[:, None]).ravel()).reshape(len(grid), len(t), 3)).tolist()
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    if hi <= lo:
        return float(grid[i])
    res = minimize_scalar(sse, bounds=(lo, hi), method="bounded", options={"xatol": 1e-5})
    return float(res.x) if res.fun <= values[i] else float(grid[i])


# --------------------------------------------------------------------------- public API


def _validate(log: Log, sensor_code: np.ndarray, sensor_names: np.ndarray):
    """``sensor_code``, ``sensor_names``: :func:`pedcal.model.sensor_codes` of the sensor column."""
    obs_path = None if log.path is None else log.path / "observations.csv"
    robot_path = None if log.path is None else log.path / "robot.csv"
    if log.robot is None or len(log.robot) < 2:
        raise PedcalInputError("the robot's localization needs at least 2 rows to find the robot's "
                               "observations", path=robot_path)
    known = set(log.sensors.ids)
    unknown = ~np.isin(sensor_names, list(known))
    if unknown.any():
        row = int(np.flatnonzero(unknown[sensor_code])[0])
        raise PedcalInputError(f"sensor '{sensor_names[sensor_code[row]]}' is not in sensors.yaml (expected one of "
                               f"{', '.join(sorted(known))})", path=obs_path, row=row, column="sensor")


def associate_robot(log: Log, *, progress: bool = False, p_sensor: np.ndarray | None = None,
                    **params) -> AssociationResult:
    """Find the robot's observations in ``log.observations`` (see the module docstring).

    ``params`` override :data:`DEFAULT_PARAMS`; ``p_sensor``: ``log.observation_points_sensor()``
    when the caller has it (read, not changed)."""
    unknown = set(params) - set(DEFAULT_PARAMS)
    if unknown:
        raise TypeError(f"unknown association parameter(s): {', '.join(sorted(unknown))}")
    params = {**DEFAULT_PARAMS, **params}
    sensor_code, sensor_names = sensor_codes(log.observations["sensor"])
    _validate(log, sensor_code, sensor_names)
    with Timer() as timer:
        obs = log.observations
        n_obs = len(obs)
        t_all = obs["t"].to_numpy(float)
        # each (sensor, track) segment numbered by first appearance, from the columns' codes (as the
        # joined texts' own numbering: distinct pairs, distinct codes), and each sensor's rows; the
        # track texts (sensor_codes: by the values' texts) made per distinct track, not per row
        track_code, track_names = sensor_codes(obs["track"])
        seg_codes = pd.factorize(sensor_code.astype(np.int64) * (int(track_code.max(initial=0)) + 1)
                                 + track_code)[0]
        rows_of = dict(zip(sensor_names, rows_by_code(sensor_code, len(sensor_names)), strict=True))
        p_sensor = log.observation_points_sensor() if p_sensor is None else np.asarray(p_sensor, float)
        p_installed = obs[["x", "y", "z"]].to_numpy(float)
        robot_t = log.robot["t"].to_numpy(float)
        # observations the robot track covers at every latency considered (pass 1)
        in_range = (t_all >= robot_t.min() + params["max_latency_s"]) & (
            t_all <= robot_t.max() - params["max_latency_s"])

        n_lat = int(round(params["max_latency_s"] / params["latency_step_s"]))
        latencies = params["latency_step_s"] * np.arange(-n_lat, n_lat + 1)
        head_at = head_interpolator(log)
        heads = np.stack([head_at(t_all - lat) for lat in latencies])

        per_sensor = {}
        for s in log.sensors:
            rows = rows_of.get(s.id, np.zeros(0, np.int64))
            if len(rows):
                per_sensor[s.id] = _SensorRows(s.id, rows, t_all[rows], seg_codes[rows], track_names[track_code[rows]],
                                               p_sensor[rows], p_installed[rows], in_range[rows])

        # pass 1: consensus per sensor over a coarse latency grid
        is_robot = np.zeros(n_obs, bool)
        found = {}
        for i, (sid, sd) in enumerate(per_sensor.items()):
            best = _consensus(sd, log.sensors[sid], heads[:, sd.rows], params)
            if best is not None:
                R, t, li, _ = best
                R, t, _, sel, _ = _refine(sd, log.sensors[sid], R, t, heads[li, sd.rows], params)
                found[sid] = (R, t)
                is_robot[sd.rows[sel]] = True
            if progress:
                logging.getLogger(__name__).info(f"association pass 1: sensor {sid} ({i + 1}/{len(per_sensor)})",
                                                 extra={"progress": (i + 1, len(per_sensor))})

        # one latency for the whole log, pooled over the sensors
        latency_s = estimate_latency(log, is_robot, max_latency_s=params["max_latency_s"], p_sensor=p_sensor,
                                     head_at=head_at)
        if progress:
            logging.getLogger(__name__).info(f"association: tracker latency {latency_s:+.3f} s")
        q_all = head_at(t_all - latency_s)
        in_range = (t_all - latency_s >= robot_t.min()) & (t_all - latency_s <= robot_t.max())
        for sd in per_sensor.values():
            sd.set_in_range(in_range[sd.rows])

        # pass 2: refine every sensor at that latency (a fresh consensus where pass 1 found nothing)
        is_robot[:] = False
        sensors_out, seg_rows = [], []
        for s in log.sensors:
            sd = per_sensor.get(s.id)
            status, n_used, R, t = "no-data", 0, None, None
            if sd is not None:
                q = q_all[sd.rows]
                if s.id in found:
                    R, t = found[s.id]
                else:
                    best = _consensus(sd, s, q[None], params)
                    if best is not None:
                        R, t = best[0], best[1]
                if R is not None:
                    R, t, r, sel, kind = _refine(sd, s, R, t, q, params)
                    n_used = int(sel.sum())
                    is_robot[sd.rows[sel]] = True
                else:
                    r = np.full(len(sd), np.inf)
                    sel = np.zeros(len(sd), bool)
                    kind = np.full(len(sd.seg_start), "no", dtype=object)
                seg_rows.append(_segment_columns(sd, r, sel, kind, params))
            if R is None or n_used < 3:
                sensors_out.append(SensorExtrinsics(s.id, s.position_m, s.ypr_deg, observations=n_used,
                                                    status="no-data"))
                continue
            spread = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(sd.p[sel].T)), 0.0))
            status = "degenerate" if spread[1] < params["collinear_spread_m"] else "ok"
            ext = SensorExtrinsics.from_pose3(s.id, gtsam.Pose3(gtsam.Rot3(R), t), observations=n_used,
                                              status=status)
            if status == "degenerate":
                ext.unobservable = ["rotation about the robot's line of travel"]
            sensors_out.append(ext)
        segments = _segment_table(seg_rows)
    if progress:
        logging.getLogger(__name__).info(f"association: {int(is_robot.sum())} of {n_obs} observations are the robot "
                                         f"({timer.elapsed_s:.2f} s)")
    return AssociationResult(is_robot, SensorNetwork(sensors_out, log.sensors.frame), segments, latency_s,
                             timer.elapsed_s, params, head_at=head_at)


SEGMENT_COLUMNS = ["sensor", "track", "n", "t_start", "t_end", "duration_s", "explained_fraction",
                   "median_residual_m", "robot", "robot_points"]


def _segment_columns(sd, r, sel, kind, params) -> dict:
    """One sensor's rows of the segment table (:data:`SEGMENT_COLUMNS`), as arrays."""
    inl = (r < params["inlier_m"]).astype(int)
    # each segment's median residual: the segment's residuals sorted (segments in order), its
    # middle one or the mean of its middle two
    r_sorted = r[np.lexsort((r, sd.seg_of_point))]
    lo, hi = sd.seg_start + (sd.seg_n - 1) // 2, sd.seg_start + sd.seg_n // 2
    median = np.where(lo == hi, r_sorted[lo], (r_sorted[lo] + r_sorted[hi]) / 2.0)
    return {
        "sensor": np.full(len(sd.seg_start), sd.sensor, dtype=object), "track": sd.seg_track, "n": sd.seg_n,
        "t_start": sd.t[sd.seg_start], "t_end": sd.t[sd.seg_end - 1], "duration_s": sd.seg_duration,
        "explained_fraction": sd.seg_sum(inl) / sd.seg_n, "median_residual_m": median,
        "robot": kind, "robot_points": sd.seg_sum(sel.astype(int)),
    }


def _segment_table(parts: list[dict]) -> pd.DataFrame:
    """The segment table of every sensor's :func:`_segment_columns`, in order."""
    if not parts:
        return pd.DataFrame(columns=SEGMENT_COLUMNS)
    return pd.DataFrame({c: np.concatenate([p[c] for p in parts]) for c in SEGMENT_COLUMNS}, columns=SEGMENT_COLUMNS)


def score_association(log: Log, is_robot) -> dict:
    """Precision and recall of ``is_robot`` against truth_observations.csv (who == "robot")."""
    if log.truth_observations is None:
        raise PedcalInputError("scoring the association needs truth_observations.csv, which the log lacks",
                               path=log.path)
    is_robot = np.asarray(is_robot, bool)
    if is_robot.shape != (len(log.observations),):
        raise PedcalInputError(f"is_robot has {is_robot.size} entries, expected one per observation "
                               f"({len(log.observations)})", path=log.path)
    truth = np.zeros(len(log.observations), bool)
    to = log.truth_observations
    rows = to["row"].to_numpy(int)
    truth[rows[to["who"].astype(str).to_numpy() == "robot"]] = True
    tp = int((is_robot & truth).sum())
    n_pred, n_true = int(is_robot.sum()), int(truth.sum())
    if n_true == 0:
        warnings.warn("truth_observations.csv has no robot rows: recall is undefined", DegenerateDataWarning,
                      stacklevel=2)
    return {"precision": tp / n_pred if n_pred else float("nan"),
            "recall": tp / n_true if n_true else float("nan"),
            "true_positives": tp, "predicted": n_pred, "robot_rows": n_true}
