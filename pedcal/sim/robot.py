"""The robot: its route, the true trajectory, AMCL's estimates and wheel odometry.

The route is a lawnmower along x, a lawnmower along y and a loop round the area the other way,
driven by a pure-pursuit follower, so every sensor sees the robot pass in several directions.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from pedcal.calib.common import interpolate_pose2
from pedcal.frames import wrap_angle_rad
from pedcal.sim.scenario import Scenario


def _corridor_route(sc: Scenario) -> np.ndarray:
    """Up and down each corridor of a ``corridor`` / ``cross`` / ``lhall`` layout on lanes
    lane_spacing_m apart (a single corridor twice, the lanes in reverse order the second time);
    from one corridor to the next through the crossing (``lhall``: the corner)."""
    from pedcal.sim.ceiling import corridor_axes

    m = sc.route_margin_m
    axes = corridor_axes(sc)
    pts: list = []
    for n_c, (start, end, width) in enumerate(axes):
        d = end - start
        length = float(np.linalg.norm(d))
        along, left = d / length, np.array([-d[1], d[0]]) / length
        half = width / 2 - m
        offsets = np.linspace(-half, half, max(2, int(round(2 * half / sc.lane_spacing_m)) + 1))
        if len(axes) == 1:
            offsets = np.r_[offsets, offsets[::-1]]
        if n_c:                                                   # through the crossing / corner
            pts.append(tuple(start + 0.5 * d) if sc.layout == "cross" else (start[0], axes[0][0][1]))
        for k, off in enumerate(offsets):
            a, b = start + m * along + off * left, end - m * along + off * left
            pts += [tuple(a), tuple(b)] if k % 2 == 0 else [tuple(b), tuple(a)]
    wp = np.asarray(pts, float)
    keep = np.r_[True, np.linalg.norm(np.diff(wp, axis=0), axis=1) > 1e-6]
    return wp[keep]


def route_waypoints(sc: Scenario) -> np.ndarray:
    """(N, 2) waypoints: lanes along x, lanes along y, then the border loop reversed (a
    ``corridor`` or ``cross`` layout: up and down its corridors)."""
    if sc.layout != "grid":
        return _corridor_route(sc)
    m, (ax, ay) = sc.route_margin_m, sc.area_m
    x0, x1, y0, y1 = m, ax - m, m, ay - m
    ys = np.linspace(y0, y1, max(2, int(round((y1 - y0) / sc.lane_spacing_m)) + 1))
    xs = np.linspace(x1, x0, max(2, int(round((x1 - x0) / sc.lane_spacing_m)) + 1))
    pts = []
    for k, y in enumerate(ys):                                    # lawnmower along x
        pts += [(x0, y), (x1, y)] if k % 2 == 0 else [(x1, y), (x0, y)]
    start_top = pts[-1][0] > (x0 + x1) / 2                        # continue from where we are
    xs = xs if start_top else xs[::-1]
    for k, x in enumerate(xs):                                    # lawnmower along y
        pts += [(x, y1), (x, y0)] if k % 2 == 0 else [(x, y0), (x, y1)]
    last = pts[-1]
    corners = [(x0, y0), (x0, y1), (x1, y1), (x1, y0)]            # loop, clockwise
    k0 = int(np.argmin([np.hypot(c[0] - last[0], c[1] - last[1]) for c in corners]))
    pts += [corners[(k0 + i) % 4] for i in range(5)]
    wp = np.asarray(pts, float)
    keep = np.r_[True, np.linalg.norm(np.diff(wp, axis=0), axis=1) > 1e-6]
    return wp[keep]


def arc_length(wp: np.ndarray) -> np.ndarray:
    """(N,) each point's arc length (m) along the polyline ``wp`` (N, 2), 0 at the first."""
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(wp, axis=0), axis=1))]


def _densify(wp: np.ndarray, step_m: float = 0.02) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A polyline resampled every ``step_m``, its arc length, and the arc length of each of the
    polyline's points ``wp`` (:func:`arc_length`)."""
    s_wp = arc_length(wp)
    s = np.arange(0.0, s_wp[-1], step_m)
    s = np.r_[s, s_wp[-1]]
    return np.column_stack([np.interp(s, s_wp, wp[:, 0]), np.interp(s, s_wp, wp[:, 1])]), s, s_wp


def stop_poses(sc: Scenario) -> int:
    """How many poses the robot holds at a stop: robot_stop_s at truth_rate_hz, rounded."""
    return int(round(sc.robot_stop_s * sc.truth_rate_hz))


def stop_waypoints(sc: Scenario, n_waypoints: int) -> np.ndarray:
    """Indices (ascending) of the route's waypoints at which the robot stops: each of the inner
    ones (not the first nor the last) with probability robot_stop_share, drawn from a stream of
    its own (so the stops change no other draw of the seed); none when robot_stop_s holds no pose
    (it rounds to 0 poses at truth_rate_hz, as :func:`drive_route` holds round(robot_stop_s x
    truth_rate_hz) of them: :func:`stop_poses`), when robot_stop_share is 0 or without an inner waypoint."""
    if stop_poses(sc) == 0 or sc.robot_stop_share <= 0.0 or n_waypoints < 3:
        return np.zeros(0, int)
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x5709]))
    return 1 + np.flatnonzero(rng.random(n_waypoints - 2) < sc.robot_stop_share)


def drive_route(sc: Scenario) -> np.ndarray:
    """True base poses (N, 3) [x, y, yaw] every 1/truth_rate_hz s, from a pure-pursuit
    follower of the route (a unicycle: v slows in sharp turns, turn rate capped). At each
    stopping waypoint (:func:`stop_waypoints`) the follower, once its nearest point of the path
    has reached the waypoint, holds its pose for robot_stop_s and goes on from where it stood
    (without stops the poses are the follower's alone)."""
    step_m = 0.02
    wp = route_waypoints(sc)
    path, s_path, s_wp = _densify(wp, step_m)
    s_stops = s_wp[stop_waypoints(sc, len(wp))].tolist()
    n_hold = stop_poses(sc)       # > 0 at any stop (stop_waypoints)
    next_stop = 0
    dt = 1.0 / sc.truth_rate_hz
    L = sc.lookahead_m
    n_ahead = int(round(L / step_m))
    w_max = np.radians(sc.max_turn_rate_dps)
    d0 = path[min(len(path) - 1, 10)] - path[0]
    x, y, yaw = path[0, 0], path[0, 1], np.arctan2(d0[1], d0[0])
    i_near, end = 0, s_path[-1]
    max_steps = int(10 * end / (sc.robot_speed_mps * dt)) + 1000
    t_limit = np.inf if sc.duration_s is None else sc.duration_s
    px, py = path[:, 0].tolist(), path[:, 1].tolist()
    n_path = len(px)
    out = []
    for _ in range(max_steps):     # scalar math: this loop runs ~20 times per simulated second
        out.append((x, y, yaw))
        if (len(out) - 1) * dt >= t_limit:
            break
        best = math.inf
        for j in range(i_near, min(i_near + 25, n_path)):
            d2 = (px[j] - x) ** 2 + (py[j] - y) ** 2
            if d2 < best:
                best, i_best = d2, j
        i_near = i_best
        if s_path[i_near] >= end - 0.05:
            break
        if next_stop < len(s_stops) and s_path[i_near] >= s_stops[next_stop]:
            next_stop += 1         # stand still: the same pose for n_hold steps
            for _ in range(n_hold):
                if (len(out) - 1) * dt >= t_limit:
                    break
                out.append((x, y, yaw))
            if (len(out) - 1) * dt >= t_limit:
                break
        j = min(i_near + n_ahead, n_path - 1)
        alpha = math.atan2(py[j] - y, px[j] - x) - yaw
        alpha = (alpha + math.pi) % (2 * math.pi) - math.pi
        v = sc.robot_speed_mps * min(1.0, max(0.05, math.cos(alpha)))
        w = min(w_max, max(-w_max, 2.0 * sc.robot_speed_mps * math.sin(alpha) / L))
        x += v * math.cos(yaw) * dt
        y += v * math.sin(yaw) * dt
        yaw = (yaw + w * dt + math.pi) % (2 * math.pi) - math.pi
    return np.asarray(out)


def truth_table(poses: np.ndarray, t0: float, sc: Scenario) -> pd.DataFrame:
    """truth_robot.csv: t, x, y, yaw."""
    t = t0 + np.arange(len(poses)) / sc.truth_rate_hz
    return pd.DataFrame({"t": t, "x": poses[:, 0], "y": poses[:, 1], "yaw": poses[:, 2]})


def ou_process(rng: np.random.Generator, n: int, dt: float, sigma: float, tau_s: float) -> np.ndarray:
    """n samples every dt of a stationary Gauss-Markov (Ornstein-Uhlenbeck) process with std
    ``sigma`` and correlation time ``tau_s``: e_k = a e_(k-1) + sigma sqrt(1 - a^2) w_k,
    a = exp(-dt / tau) (its exact discretization)."""
    if sigma == 0.0 or n == 0:
        return np.zeros(n)
    a = np.exp(-dt / tau_s)
    w = rng.standard_normal(n)
    e0 = sigma * w[0]
    rest = lfilter([sigma * np.sqrt(1.0 - a * a)], [1.0, -a], w[1:], zi=[a * e0])[0]
    return np.r_[e0, rest]


def _slow_wave(rng: np.random.Generator, t: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """A smooth value between lo and hi, varying over tens of seconds (two random sines)."""
    periods = rng.uniform(40.0, 150.0, 2)
    phases = rng.uniform(0.0, 2 * np.pi, 2)
    u = 0.5 + 0.25 * (np.sin(2 * np.pi * t / periods[0] + phases[0])
                      + np.sin(2 * np.pi * t / periods[1] + phases[1]))
    return lo + (hi - lo) * u


def amcl_table(truth: pd.DataFrame, sc: Scenario, rng: np.random.Generator) -> pd.DataFrame:
    """robot.csv: the true pose plus an Ornstein-Uhlenbeck error (per axis and yaw), published
    at amcl_rate_hz, with a reported covariance that varies with time independently of the
    actual error, as amcl's does."""
    t_true = truth["t"].to_numpy()
    dt = 1.0 / sc.amcl_rate_hz
    t = np.arange(t_true[0], t_true[-1] + 1e-9, dt)
    pose = interpolate_pose2(truth, t)
    n = len(t)
    if sc.amcl_error == "white":
        err_x, err_y = rng.normal(0.0, sc.amcl_sigma_m, (2, n))
        err_yaw = rng.normal(0.0, np.radians(sc.amcl_sigma_yaw_deg), n)
    else:
        err_x = ou_process(rng, n, dt, sc.amcl_sigma_m, sc.amcl_tau_s)
        err_y = ou_process(rng, n, dt, sc.amcl_sigma_m, sc.amcl_tau_s)
        err_yaw = ou_process(rng, n, dt, np.radians(sc.amcl_sigma_yaw_deg), sc.amcl_tau_s)
    if sc.amcl_error == "jumps" and sc.amcl_jump_rate_hz > 0:
        # a wrong relocalization: the estimate jumps amcl_jump_m in a random direction and
        # stays off for amcl_jump_life_s until the scan matcher recovers
        for _ in range(rng.poisson(sc.amcl_jump_rate_hz * (t[-1] - t[0]))):
            t_j, life, ang = rng.uniform(t[0], t[-1]), rng.uniform(*sc.amcl_jump_life_s), rng.uniform(0, 2 * np.pi)
            on = (t >= t_j) & (t < t_j + life)
            err_x[on] += sc.amcl_jump_m * np.cos(ang)
            err_y[on] += sc.amcl_jump_m * np.sin(ang)
    sx = _slow_wave(rng, t, *sc.amcl_reported_sigma_m)
    sy = sx * _slow_wave(rng, t, 0.8, 1.25)
    rho = _slow_wave(rng, t, -0.3, 0.3)
    syaw = np.radians(_slow_wave(rng, t, *sc.amcl_reported_sigma_yaw_deg))
    zero = np.zeros(n)
    return pd.DataFrame({
        "t": t, "x": pose[:, 0] + err_x, "y": pose[:, 1] + err_y,
        "yaw": wrap_angle_rad(pose[:, 2] + err_yaw),
        "cov_xx": sx**2, "cov_xy": rho * sx * sy, "cov_xyaw": zero,
        "cov_yy": sy**2, "cov_yyaw": zero, "cov_yawyaw": syaw**2,
    })


def odometry_table(truth: pd.DataFrame, sc: Scenario, rng: np.random.Generator) -> pd.DataFrame | None:
    """odometry.csv: the true body-frame increments with a scale error, a heading drift per
    metre and per second (signs drawn at random) and white noise, integrated from the origin
    of the odom frame at truth_rate_hz. None when the scenario has no odometry."""
    if not sc.odometry:
        return None
    t = truth["t"].to_numpy()
    p = truth[["x", "y"]].to_numpy()
    yaw = truth["yaw"].to_numpy()
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    d = np.diff(p, axis=0)
    fwd = c * d[:, 0] + s * d[:, 1]                   # increments in the body frame
    left = -s * d[:, 0] + c * d[:, 1]
    dyaw = wrap_angle_rad(np.diff(yaw))
    dist = np.hypot(fwd, left)
    sign = rng.choice([-1.0, 1.0], 3)
    scale = 1.0 + sign[0] * sc.odom_scale_error
    fwd = scale * fwd + rng.normal(0.0, sc.odom_noise_m, len(fwd))
    left = scale * left + rng.normal(0.0, sc.odom_noise_m, len(left))
    dyaw = (dyaw + sign[1] * np.radians(sc.odom_yaw_drift_deg_per_m) * dist
            + sign[2] * np.radians(sc.odom_gyro_bias_dps) * np.diff(t)
            + rng.normal(0.0, np.radians(sc.odom_noise_yaw_deg), len(dyaw)))
    yaw_o = np.r_[0.0, np.cumsum(dyaw)]
    co, so = np.cos(yaw_o[:-1]), np.sin(yaw_o[:-1])
    x_o = np.r_[0.0, np.cumsum(co * fwd - so * left)]
    y_o = np.r_[0.0, np.cumsum(so * fwd + co * left)]
    return pd.DataFrame({"t": t, "x": x_o, "y": y_o, "yaw": wrap_angle_rad(yaw_o)})
