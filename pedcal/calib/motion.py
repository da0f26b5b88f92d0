"""The robot's motion as the graph uses it: its head frame, the wheel odometry with its systematic
errors calibrated against AMCL (:func:`calibrate_odometry`), AMCL smoothed where it stands in for
odometry, and the short-term displacement of the head between two nearby instants
(:class:`RobotMotion`)."""

from __future__ import annotations

import gtsam
import numpy as np
import pandas as pd

from pedcal.calib.common import head_interpolator, head_world, pose2_interpolator
from pedcal.model import Log


def head_frame(x: float, y: float, yaw: float, head_m: np.ndarray) -> gtsam.Pose3:
    """The robot's head frame: the base pose (x, y, yaw) composed with the head offset
    ``head_m`` (base frame; its z is the dome centre's height)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([x + c * head_m[0] - s * head_m[1],
                                                      y + s * head_m[0] + c * head_m[1], head_m[2]]))



def smoothed_track(track: pd.DataFrame, sigma_s: float) -> pd.DataFrame:
    """A t/x/y/yaw table smoothed by a Gaussian of ``sigma_s`` seconds in time (x, y and unwrapped
    yaw): at each estimate the line fitted to its neighbours within 4 sigma, each weighted by the
    Gaussian of its time from it (local linear regression). Where the samples sit evenly on
    both sides this is the Gaussian's weighted mean; at the track's ends, at gaps (a left-out
    jump, a dropout) and where AMCL publishes irregularly the line carries a steady motion as it
    is, where a Gaussian of the samples' index read the estimates as evenly spaced, folded the
    path back at its ends (lagging by 0.8 v sigma, 20 cm at 1 m/s over 0.5 s) and averaged
    across gaps. An estimate with no neighbour within reach stays as it is."""
    tr = track.groupby("t", sort=True)[["x", "y", "yaw"]].mean()
    t = tr.index.to_numpy(float)
    xy_yaw = np.column_stack([tr["x"].to_numpy(float), tr["y"].to_numpy(float), np.unwrap(tr["yaw"].to_numpy(float))])
    n, reach = len(t), 4.0 * max(float(sigma_s), 1e-9)
    i = np.arange(n)
    lo, hi = np.searchsorted(t, t - reach), np.searchsorted(t, t + reach, side="right")
    s0, s1, s2 = np.zeros(n), np.zeros(n), np.zeros(n)
    y0, y1 = np.zeros((n, 3)), np.zeros((n, 3))
    before, after = (int((i - lo).max()), int((hi - 1 - i).max())) if n else (0, 0)
    for o in range(-before, after + 1):       # the neighbours o estimates away, for every estimate at once
        j = np.clip(i + o, 0, max(n - 1, 0))
        u = t[j] - t
        w = np.exp(-0.5 * (u / sigma_s) ** 2) * ((i + o >= lo) & (i + o < hi))
        s0 += w
        s1 += w * u
        s2 += w * u * u
        y0 += w[:, None] * xy_yaw[j]
        y1 += (w * u)[:, None] * xy_yaw[j]
    det = s0 * s2 - s1 ** 2
    line = det > 1e-12 * np.maximum(s0 * s2, 1e-300)
    out = y0 / np.maximum(s0, 1e-300)[:, None]          # (one neighbour in reach: itself)
    out[line] = (s2[line, None] * y0[line] - s1[line, None] * y1[line]) / det[line, None]
    return pd.DataFrame({"t": t, "x": out[:, 0], "y": out[:, 1], "yaw": out[:, 2]})


def smoothed_increment_var(white_sigma_m: float, dt_s, rate_hz: float, smooth_s: float):
    """Variance (m^2, per axis) of the increment over ``dt_s`` of a white jitter of std
    ``white_sigma_m`` sampled at ``rate_hz`` and smoothed by a Gaussian of ``smooth_s`` seconds
    (:func:`smoothed_track`): the kernel's slope squared summed over the samples,
    white^2 dt^2 / (rate 4 sqrt(pi) s^3), for dt up to about s."""
    return white_sigma_m ** 2 * np.asarray(dt_s, float) ** 2 / (rate_hz * 4.0 * np.sqrt(np.pi) * smooth_s ** 3)



def calibrate_odometry(odometry: pd.DataFrame, amcl: pd.DataFrame, window_s: float = 20.0,
                       amcl_correlation_s: float = 20.0, drift_prior_deg_per_m: float = 2.0,
                       drift_prior_deg_per_s: float = 0.2):
    """Wheel odometry with its systematic errors removed: a heading drift per metre driven and
    per second (wheel-base error, gyro bias) from a least-squares fit of the odometry-minus-AMCL
    heading against distance and time over the whole run, and the distance scale from the
    displacements over ``window_s`` windows (AMCL's wander averages out over many windows).
    At a steady speed distance and time are nearly collinear, so the two drifts are held by a
    weak prior (``drift_prior_*``, far beyond a working odometry's) and the AMCL heading samples
    are weighted as the independent ones they are: one per 2 x ``amcl_correlation_s``.
    Returns (DataFrame t, x, y, yaw in the odometry frame, dict of the estimates)."""
    odo = odometry.sort_values("t")
    t = odo["t"].to_numpy(float)
    xy = odo[["x", "y"]].to_numpy(float)
    yaw = np.unwrap(odo["yaw"].to_numpy(float))
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    d = np.diff(xy, axis=0)
    fwd, left = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    dyaw, dt = np.diff(yaw), np.diff(t)
    dist = np.hypot(fwd, left)
    s_m = np.r_[0.0, np.cumsum(dist)]
    est = dict(scale=1.0, yaw_drift_deg_per_m=0.0, yaw_drift_deg_per_s=0.0)
    at = amcl.sort_values("t")
    ta = at["t"].to_numpy(float)
    inside = (t >= ta[0]) & (t <= ta[-1])
    if inside.sum() >= 10 and t[inside][-1] - t[inside][0] > 2 * window_s:
        yaw_a = np.interp(t[inside], ta, np.unwrap(at["yaw"].to_numpy(float)))
        diff = np.unwrap(yaw[inside] - yaw_a)
        n = int(inside.sum())
        span = t[inside][-1] - t[inside][0]
        sig_yaw = float(np.sqrt(np.median(at["cov_yawyaw"].to_numpy(float)))) if "cov_yawyaw" in at else 0.02
        # weight of one sample: n_eff / n independent samples of AMCL's heading std
        w = np.sqrt(max(span / (2.0 * amcl_correlation_s), 1.0) / n) / max(sig_yaw, 1e-4)
        M = np.column_stack([np.ones(n), s_m[inside], t[inside] - t[inside][0]]) * w
        prior = np.diag([0.0, 1.0 / np.radians(drift_prior_deg_per_m), 1.0 / np.radians(drift_prior_deg_per_s)])
        coef = np.linalg.lstsq(np.vstack([M, prior]), np.r_[diff * w, np.zeros(3)], rcond=None)[0]
        est["yaw_drift_deg_per_m"] = float(np.degrees(coef[1]))
        est["yaw_drift_deg_per_s"] = float(np.degrees(coef[2]))
        dyaw = dyaw - coef[1] * dist - coef[2] * dt
    yaw_c = np.r_[yaw[0], yaw[0] + np.cumsum(dyaw)]
    cc, sc = np.cos(yaw_c[:-1]), np.sin(yaw_c[:-1])
    xy_c = xy[0] + np.r_[np.zeros((1, 2)), np.cumsum(np.column_stack([cc * fwd - sc * left, sc * fwd + cc * left]),
                                                     axis=0)]
    if inside.sum() >= 10:
        edges = np.arange(max(t[0], ta[0]), min(t[-1], ta[-1]), window_s)
        if len(edges) >= 3:
            da = np.diff(np.column_stack([np.interp(edges, ta, at["x"].to_numpy(float)),
                                          np.interp(edges, ta, at["y"].to_numpy(float))]), axis=0)
            do = np.diff(np.column_stack([np.interp(edges, t, xy_c[:, 0]), np.interp(edges, t, xy_c[:, 1])]), axis=0)
            na, no = np.linalg.norm(da, axis=1), np.linalg.norm(do, axis=1)
            if np.sum(no ** 2) > 1.0:        # the robot drove at least a metre per window on average
                est["scale"] = float(np.sum(na * no) / np.sum(no ** 2))
    xy_c = xy_c[0] + est["scale"] * (xy_c - xy_c[0])
    return pd.DataFrame({"t": t, "x": xy_c[:, 0], "y": xy_c[:, 1], "yaw": yaw_c}), est


class RobotMotion:
    """The robot's short-term motion: where the head moves between two nearby instants, from
    the (calibrated) wheel odometry rotated into the map by AMCL's heading, or from the AMCL
    spline when there is no odometry."""

    def __init__(self, log: Log, odometry: pd.DataFrame | None, head_at=None):
        """``head_at``: :func:`pedcal.calib.common.head_interpolator` of ``log`` when the caller has it."""
        self.head_offset = np.asarray(log.meta.head_offset_m, float)
        self.amcl_head = head_interpolator(log) if head_at is None else head_at
        self.odo = odometry
        if odometry is not None:
            self._amcl_yaw = pose2_interpolator(log.robot).yaw      # (sorted and unwrapped once)
            self._odo_at = pose2_interpolator(odometry)

    def displacement(self, t_from: np.ndarray, t_to: np.ndarray, from_index: np.ndarray | None = None,
                     to_index: np.ndarray | None = None) -> np.ndarray:
        """World displacement (N, 3) of the head top from ``t_from`` to ``t_to``; with
        ``from_index`` (``to_index``), from ``t_from[from_index]`` (to ``t_to[to_index]``): each
        time's head read once however many rows take it (the observations carried to the poses,
        consecutive observations of a track), the same values as at the picked times."""
        def pick(x, index):
            return x if index is None else x[index]

        same = t_from is t_to
        if self.odo is None:
            h_from = self.amcl_head(t_from)
            return pick(h_from if same else self.amcl_head(t_to), to_index) - pick(h_from, from_index)
        h_from = head_world(self._odo_at(t_from), self.head_offset)
        h0 = pick(h_from, from_index)
        h1 = pick(h_from if same else head_world(self._odo_at(t_to), self.head_offset), to_index)
        mid = 0.5 * (pick(t_from, from_index) + pick(t_to, to_index))
        # heading of the map relative to the odometry frame at that time (AMCL minus odometry)
        rot = self._amcl_yaw(mid) - self._odo_at.yaw(mid)
        c, s = np.cos(rot), np.sin(rot)
        d = h1 - h0
        return np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]])

    def velocity(self, t: np.ndarray, h: float = 0.02) -> np.ndarray:
        return self.displacement(t - h, t + h) / (2 * h)



__all__ = ["head_frame", "smoothed_track", "smoothed_increment_var", "calibrate_odometry", "RobotMotion"]
