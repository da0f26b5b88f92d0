"""An independent generator of calibration logs (LOG_FORMAT.md, version 1): a held-out exam.

Everything here is built from the log format and the physics alone; it shares no code and no
modelling choice with pedcal's simulator, so that a calibration developed against that simulator
is tested on worlds it has never seen. The models (layouts, robot, AMCL, trackers, clocks,
pedestrians) are described in README.md beside this file. Do not tune pedcal to these logs.

Frames follow LOG_FORMAT.md: world = map (z up, m); sensor frame x along the optical axis, y left,
z up; R_world_sensor = Rz(yaw) Ry(pitch) Rx(roll), so positive pitch looks down.

    from xgen import generate
    info = generate("out/lhall-3", seed=3, family="lhall")
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FAMILIES = ("rooms", "lhall", "corridor", "openhall")

SIM_DT_S = 0.02  # robot dynamics integration step (50 Hz)

# depth-sensor models: horizontal / vertical field of view (deg), min / max range (m)
SENSOR_MODELS = {
    "structured-light": (58.0, 45.0, 0.5, 4.5),
    "tof-wide": (90.0, 70.0, 0.3, 5.0),
    "stereo": (86.0, 57.0, 0.4, 6.0),
    "long-range": (70.0, 55.0, 0.5, 9.0),
}
DOWN_MODELS = ("structured-light", "tof-wide", "stereo")
WALL_MODELS = ("stereo", "long-range")


# ------------------------------------------------------------------------------------- rotations
def rot_world_sensor(yaw_rad: float, pitch_rad: float, roll_rad: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (LOG_FORMAT.md), sensor-frame vectors -> world."""
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def ypr_from_rot(r_world_sensor: np.ndarray) -> np.ndarray:
    """Inverse of rot_world_sensor: (yaw, pitch, roll) in radians, pitch in [-pi/2, pi/2]."""
    r = r_world_sensor
    pitch = math.asin(float(np.clip(-r[2, 0], -1.0, 1.0)))
    yaw = math.atan2(r[1, 0], r[0, 0])
    roll = math.atan2(r[2, 1], r[2, 2])
    return np.array([yaw, pitch, roll])


def small_rotation(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation matrix of a rotation vector."""
    angle = float(np.linalg.norm(rotvec_rad))
    if angle < 1e-12:
        return np.eye(3)
    k = rotvec_rad / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


def wrap_rad(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


# ---------------------------------------------------------------------------------------- layout
@dataclass
class Sensor:
    id: str
    position_m: np.ndarray           # true, world
    r_world_sensor: np.ndarray       # true
    model: str
    mount: str                       # "ceiling" | "wall"
    region: int                      # index of the free-space rectangle it watches
    installed_position_m: np.ndarray = field(default=None)
    installed_r_world_sensor: np.ndarray = field(default=None)


@dataclass
class Layout:
    family: str
    rects: list                      # free space: union of axis-aligned (x0, y0, x1, y1)
    sensors: list
    joints: list                     # rect pairs' shared points a path must pass through
    long_axis_rad: list              # per rect: the direction AMCL is least sure along


def _inside(p_xy, rect, margin):
    x0, y0, x1, y1 = rect
    return x0 + margin <= p_xy[0] <= x1 - margin and y0 + margin <= p_xy[1] <= y1 - margin


def _clip(p_xy, rect, margin):
    x0, y0, x1, y1 = rect
    return np.array([np.clip(p_xy[0], x0 + margin, x1 - margin), np.clip(p_xy[1], y0 + margin, y1 - margin)])


def _ceiling_sensor(rng, footprint_xy, height_m, head_z_m, region):
    """A sensor looking (nearly) straight down whose optical axis meets the head plane near footprint_xy."""
    model = DOWN_MODELS[rng.integers(len(DOWN_MODELS))]
    tilt_deg = rng.uniform(0.0, 3.0) if rng.random() < 0.3 else rng.uniform(3.0, 35.0)
    pitch_deg = 90.0 - tilt_deg
    yaw_deg = rng.uniform(-180.0, 180.0)
    roll_deg = rng.normal(0.0, 2.0)
    drop_m = (height_m - head_z_m) * math.tan(math.radians(tilt_deg))
    yaw = math.radians(yaw_deg)
    pos = np.array([footprint_xy[0] - drop_m * math.cos(yaw), footprint_xy[1] - drop_m * math.sin(yaw), height_m])
    r = rot_world_sensor(yaw, math.radians(pitch_deg), math.radians(roll_deg))
    return model, pos, r


def _wall_sensor(rng, wall_xy, inward_rad, height_m, region):
    """A sensor on a wall looking into the room, pitched 10-25 deg down from horizontal."""
    model = WALL_MODELS[rng.integers(len(WALL_MODELS))]
    yaw = inward_rad + math.radians(rng.uniform(-35.0, 35.0))
    pitch = math.radians(rng.uniform(10.0, 25.0))
    roll = math.radians(rng.normal(0.0, 1.5))
    pos = np.array([wall_xy[0], wall_xy[1], height_m])
    return model, pos, rot_world_sensor(yaw, pitch, roll)


def _grid_points(rng, rect, spacing_m, jitter_m, drop_p, margin_m):
    x0, y0, x1, y1 = rect
    nx = max(1, int(round((x1 - x0 - 2 * margin_m) / spacing_m)) + 1)
    ny = max(1, int(round((y1 - y0 - 2 * margin_m) / spacing_m)) + 1)
    xs = np.linspace(x0 + margin_m, x1 - margin_m, nx) if nx > 1 else np.array([(x0 + x1) / 2])
    ys = np.linspace(y0 + margin_m, y1 - margin_m, ny) if ny > 1 else np.array([(y0 + y1) / 2])
    pts = []
    for x in xs:
        for y in ys:
            if rng.random() < drop_p:
                continue
            p = np.array([x, y]) + rng.normal(0.0, jitter_m, 2)
            pts.append(_clip(p, rect, margin_m))
    return pts


def _wall_spot(rng, rect):
    """A point on one wall of rect and the inward direction."""
    x0, y0, x1, y1 = rect
    side = rng.integers(4)
    if side == 0:
        return np.array([rng.uniform(x0 + 0.5, x1 - 0.5), y0]), math.pi / 2
    if side == 1:
        return np.array([rng.uniform(x0 + 0.5, x1 - 0.5), y1]), -math.pi / 2
    if side == 2:
        return np.array([x0, rng.uniform(y0 + 0.5, y1 - 0.5)]), 0.0
    return np.array([x1, rng.uniform(y0 + 0.5, y1 - 0.5)]), math.pi


def _one_room(rng, w_range, h_range, spacing_range, jitter_m, drop_p, margin_m, n_wall_range):
    """A rectangular room with a jittered grid of ceiling sensors: rects, joints, AMCL axes, sensor
    spots and the number of wall sensors."""
    w, h = rng.uniform(*w_range), rng.uniform(*h_range)
    rects = [(0.0, 0.0, w, h)]
    axes = [rng.uniform(0, math.pi)]
    spots = [(p, 0) for p in _grid_points(rng, rects[0], rng.uniform(*spacing_range), jitter_m, drop_p, margin_m)]
    return rects, [], axes, spots, int(rng.integers(*n_wall_range))


def make_layout(rng, family: str, head_z_m: float) -> Layout:
    ceiling_m = rng.uniform(2.6, 4.5)

    def height():
        return float(np.clip(ceiling_m + rng.normal(0.0, 0.08), 2.6, 4.5))

    if family == "rooms":
        rects, joints, axes, spots, n_wall = _one_room(rng, (6.0, 14.0), (5.0, 10.0), (2.5, 3.5), 0.3, 0.1, 1.0, (0, 3))
    elif family == "lhall":
        wa, wb = rng.uniform(3.0, 5.0), rng.uniform(3.0, 5.0)
        la, lb = rng.uniform(12.0, 18.0), rng.uniform(10.0, 15.0)
        # wing A along x, wing B along y, sharing the corner [0, wb] x [0, wa]
        rects = [(0.0, 0.0, la, wa), (0.0, 0.0, wb, lb)]
        joints = [np.array([wb / 2, wa / 2])]
        axes = [0.0, math.pi / 2]
        spacing = rng.uniform(2.8, 3.8)
        # the wings share no view: footprints stay 1.8 m beyond the corner square
        a = [(p, 0) for p in _grid_points(rng, (wb + 1.8, 0.0, la, wa), spacing, 0.25, 0.1, 0.9)]
        b = [(p, 1) for p in _grid_points(rng, (0.0, wa + 1.8, wb, lb), spacing, 0.25, 0.1, 0.9)]
        spots = a + b
        n_wall = 0
    elif family == "corridor":
        length, width = rng.uniform(20.0, 36.0), rng.uniform(2.0, 3.5)
        rects = [(0.0, 0.0, length, width)]
        joints = []
        axes = [0.0]
        spacing = rng.uniform(3.0, 5.0)
        xs = np.arange(1.2, length - 1.0, spacing) + rng.normal(0.0, 0.3, len(np.arange(1.2, length - 1.0, spacing)))
        spots = [(np.array([x, width / 2 + rng.uniform(-0.3, 0.3) * width]), 0) for x in xs]
        n_wall = int(rng.integers(1, 4))
    elif family == "openhall":
        rects, joints, axes, spots, n_wall = _one_room(rng, (14.0, 22.0), (10.0, 16.0), (3.5, 4.5), 0.7, 0.25, 1.2,
                                                       (2, 5))
    else:
        raise ValueError(f"unknown family {family!r}; known: {', '.join(FAMILIES)}")

    sensors = []
    for footprint, region in spots:
        model, pos, r = _ceiling_sensor(rng, footprint, height(), head_z_m, region)
        sensors.append(Sensor(f"s{len(sensors) + 1:02d}", pos, r, model, "ceiling", region))
    for _ in range(n_wall):
        region = int(rng.integers(len(rects)))
        wall_xy, inward = _wall_spot(rng, rects[region])
        if family == "corridor" and rng.random() < 0.6:
            # along the corridor from a side wall: turn the view toward its far end
            along = 0.0 if wall_xy[0] < rects[0][2] / 2 else math.pi
            inward = along + (inward - along) * 0.35
        height_m = float(np.clip(rng.uniform(2.6, 3.3), 2.6, ceiling_m))
        model, pos, r = _wall_sensor(rng, wall_xy, inward, height_m, region)
        sensors.append(Sensor(f"s{len(sensors) + 1:02d}", pos, r, model, "wall", region))
    return Layout(family, rects, sensors, joints, axes)


def install_errors(rng, sensors, scale: float):
    """Installed (hand-measured) extrinsics: truth plus tens of cm and several degrees."""
    for s in sensors:
        d_xy = rng.normal(0.0, 0.18 * scale, 2)
        d_z = rng.normal(0.0, 0.06 * scale)
        s.installed_position_m = s.position_m + np.array([d_xy[0], d_xy[1], d_z])
        # a turn about the vertical (how it was aimed) and a tilt of the bracket (sensor frame)
        d_yaw = math.radians(rng.normal(0.0, 4.0 * scale))
        d_tilt = np.radians(rng.normal(0.0, 2.5 * scale, 2))
        s.installed_r_world_sensor = (rot_world_sensor(d_yaw, 0.0, 0.0) @ s.r_world_sensor
                                      @ small_rotation(np.array([d_tilt[0], d_tilt[1], 0.0])))


# ---------------------------------------------------------------------------------- robot path
def _target_xy(s: Sensor, head_z_m: float):
    """Where the optical axis meets the head plane (its view's centre for the robot's head)."""
    axis = s.r_world_sensor[:, 0]
    drop = s.position_m[2] - head_z_m
    if axis[2] >= -1e-3:
        return s.position_m[:2] + 3.0 * axis[:2] / max(np.linalg.norm(axis[:2]), 1e-9)
    reach = drop / -axis[2]
    reach = min(reach, SENSOR_MODELS[s.model][3] * 0.75)
    return s.position_m[:2] + reach * axis[:2]


def _region_of(layout, p_xy, margin=0.0):
    for i, r in enumerate(layout.rects):
        if _inside(p_xy, r, margin):
            return i
    return None


def _route(layout, points_regions):
    """Insert the joint between consecutive waypoints that lie in different wings only."""
    out = []
    prev = None
    for p, _ in points_regions:
        if prev is not None and layout.joints:
            in_prev_only = _region_of_only(layout, prev)
            in_this_only = _region_of_only(layout, p)
            if in_prev_only is not None and in_this_only is not None and in_prev_only != in_this_only:
                out.append(layout.joints[0])
        out.append(p)
        prev = p
    return out


def _region_of_only(layout, p_xy):
    inside = [i for i, r in enumerate(layout.rects) if _inside(p_xy, r, 0.0)]
    return inside[0] if len(inside) == 1 else None


def plan_waypoints(rng, layout: Layout, head_z_m: float, mode: str, margin_m: float = 0.55):
    if mode == "tour":
        targets = []
        for s in layout.sensors:
            t = _target_xy(s, head_z_m)
            reg = s.region if _region_of(layout, t) is None else _region_of(layout, t)
            targets.append((_clip(t, layout.rects[reg], margin_m), reg))
        pts = []
        for pass_i in range(2):
            order = list(rng.permutation(len(targets)))
            # greedy nearest neighbour from a random start, so the route is not absurdly long
            cur = order.pop(0)
            seq = [cur]
            while order:
                d = [np.linalg.norm(targets[j][0] - targets[cur][0]) for j in order]
                cur = order.pop(int(np.argmin(d)))
                seq.append(cur)
            if pass_i == 1:
                seq = seq[::-1]
            for j in seq:
                c, reg = targets[j]
                rect = layout.rects[reg]
                if rng.random() < 0.35:
                    # a small loop under the sensor: several headings through its view
                    rad = rng.uniform(0.5, 1.0)
                    a0 = rng.uniform(0, 2 * math.pi)
                    turn = 1.0 if rng.random() < 0.5 else -1.0
                    for k in range(7):
                        a = a0 + turn * k * 2 * math.pi / 6
                        pts.append((_clip(c + rad * np.array([math.cos(a), math.sin(a)]), rect, margin_m), reg))
                else:
                    pts.append((_clip(c + rng.normal(0.0, 0.6, 2), rect, margin_m), reg))
        return pts
    if mode == "lawnmower":
        # lanes along the longer side, then (half the time) across, each with its own offset
        pts = []
        spacing = rng.uniform(0.8, 1.6)
        for reg, rect in enumerate(layout.rects):
            x0, y0, x1, y1 = rect
            along_x = ((x1 - x0) >= (y1 - y0)) != (rng.random() < 0.3)
            m = margin_m + rng.uniform(0.0, spacing / 2)
            if along_x:
                lanes = np.arange(y0 + m, y1 - margin_m + 1e-9, spacing)
                for k, y in enumerate(lanes):
                    a, b = (x0 + margin_m, x1 - margin_m) if k % 2 == 0 else (x1 - margin_m, x0 + margin_m)
                    pts += [(np.array([a, y]), reg), (np.array([b, y]), reg)]
            else:
                lanes = np.arange(x0 + m, x1 - margin_m + 1e-9, spacing)
                for k, x in enumerate(lanes):
                    a, b = (y0 + margin_m, y1 - margin_m) if k % 2 == 0 else (y1 - margin_m, y0 + margin_m)
                    pts += [(np.array([x, a]), reg), (np.array([x, b]), reg)]
        return pts
    if mode == "shuttle":
        # back and forth through each wing on lanes across its width, weaving a little
        pts = []
        for _ in range(2):
            for reg, rect in enumerate(layout.rects):
                x0, y0, x1, y1 = rect
                along_x = (x1 - x0) >= (y1 - y0)
                width = (y1 - y0) if along_x else (x1 - x0)
                for lane in rng.uniform(margin_m, width - margin_m, 3):
                    n = int(rng.integers(3, 7))
                    u = np.linspace(0, 1, n)
                    if rng.random() < 0.5:
                        u = u[::-1]
                    for ui in u:
                        off = np.clip(lane + rng.normal(0, 0.3), margin_m, width - margin_m)
                        if along_x:
                            p = np.array([x0 + margin_m + ui * (x1 - x0 - 2 * margin_m), y0 + off])
                        else:
                            p = np.array([x0 + off, y0 + margin_m + ui * (y1 - y0 - 2 * margin_m)])
                        pts.append((p, reg))
        return pts
    raise ValueError(mode)


def plan_drive(rng, layout: Layout, head_z_m: float, mode: str, length_m: float):
    """Plans of the mode, one after another (each drawn afresh), until the route is length_m long."""
    pts = []
    route = []
    while True:
        pts += plan_waypoints(rng, layout, head_z_m, mode)
        route = _route(layout, pts)
        if len(route) > 1 and np.sum(np.linalg.norm(np.diff(np.array(route), axis=0), axis=1)) >= length_m:
            return route


@dataclass
class Drive:
    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray               # unwrapped
    v_mps: np.ndarray
    w_radps: np.ndarray


def drive(rng, waypoints, max_time_s: float) -> Drive:
    """Differential-drive robot following waypoints: turn toward the next, cruise at a speed drawn
    per leg (0.3-0.8 m/s), accelerations limited, stops of 1-6 s at some waypoints."""
    a_max, alpha_max = rng.uniform(0.3, 0.7), rng.uniform(1.0, 2.5)
    w_max = rng.uniform(0.6, 1.2)
    k_turn = rng.uniform(1.5, 3.0)
    p_stop = rng.uniform(0.05, 0.25)
    x, y = float(waypoints[0][0]), float(waypoints[0][1])
    d0 = waypoints[1] - waypoints[0] if len(waypoints) > 1 else np.array([1.0, 0.0])
    yaw = math.atan2(d0[1], d0[0]) + rng.normal(0, 0.3)
    v = w = 0.0
    ts, xs, ys, yaws, vs, ws = [], [], [], [], [], []
    t = 0.0
    i = 1
    v_leg = rng.uniform(0.3, 0.8)
    hold = rng.uniform(1.0, 3.0)
    while t < max_time_s and i < len(waypoints):
        target = waypoints[i]
        dx, dy = target[0] - x, target[1] - y
        dist = math.hypot(dx, dy)
        if hold > 0:
            v_cmd, w_cmd = 0.0, 0.0
            hold -= SIM_DT_S
        elif dist < 0.15:
            i += 1
            v_leg = rng.uniform(0.3, 0.8)
            if rng.random() < p_stop:
                hold = rng.uniform(1.0, 6.0)
            continue
        else:
            err = float(wrap_rad(math.atan2(dy, dx) - yaw))
            w_cmd = float(np.clip(k_turn * err, -w_max, w_max))
            v_cmd = v_leg * max(0.0, math.cos(err)) ** 3 * min(1.0, 0.25 + dist)
        v += float(np.clip(v_cmd - v, -a_max * SIM_DT_S, a_max * SIM_DT_S))
        w += float(np.clip(w_cmd - w, -alpha_max * SIM_DT_S, alpha_max * SIM_DT_S))
        for column, value in ((ts, t), (xs, x), (ys, y), (yaws, yaw), (vs, v), (ws, w)):
            column.append(value)
        # exact unicycle arc over one step
        if abs(w) > 1e-9:
            x += v / w * (math.sin(yaw + w * SIM_DT_S) - math.sin(yaw))
            y -= v / w * (math.cos(yaw + w * SIM_DT_S) - math.cos(yaw))
        else:
            x += v * math.cos(yaw) * SIM_DT_S
            y += v * math.sin(yaw) * SIM_DT_S
        yaw += w * SIM_DT_S
        t += SIM_DT_S
    return Drive(np.array(ts), np.array(xs), np.array(ys), np.array(yaws), np.array(vs), np.array(ws))


def pose_at(d: Drive, t_s):
    t_s = np.asarray(t_s, float)
    return np.interp(t_s, d.t_s, d.x_m), np.interp(t_s, d.t_s, d.y_m), np.interp(t_s, d.t_s, d.yaw_rad)


# ------------------------------------------------------------------------------------------ AMCL
def amcl_error(rng, layout: Layout, d: Drive):
    """AMCL's error on the drive's time grid and the covariance an honest AMCL would report.

    'ou': an Ornstein-Uhlenbeck process in x, y, yaw, larger along the local region's long axis;
    'rw': a random walk that grows with distance driven and resets on good scan matches.
    Both may have relocalization jumps (0.2-0.5 m, 5-15 s) the reported covariance ignores."""
    n = len(d.t_s)
    kind = "ou" if rng.random() < 0.5 else "rw"
    err = np.zeros((n, 3))
    cov = np.zeros((n, 3, 3))
    every = zip(d.x_m[::25], d.y_m[::25], strict=True)
    regions = np.array([_region_of(layout, np.array([x, y])) or 0 for x, y in every])
    regions = np.repeat(regions, 25)[:n]
    params = {"kind": kind}
    if kind == "ou":
        s_along, s_cross = rng.uniform(0.03, 0.09), None
        s_cross = s_along * rng.uniform(0.4, 1.0)
        s_yaw = math.radians(rng.uniform(0.5, 2.0))
        tau_xy, tau_yaw = rng.uniform(3.0, 30.0), rng.uniform(2.0, 20.0)
        params.update(sigma_along_m=s_along, sigma_cross_m=s_cross, sigma_yaw_rad=s_yaw, tau_xy_s=tau_xy,
                      tau_yaw_s=tau_yaw)
        u = np.zeros((n, 3))
        u[0] = rng.normal(size=3)
        f_xy, f_yaw = math.exp(-SIM_DT_S / tau_xy), math.exp(-SIM_DT_S / tau_yaw)
        q = np.array([math.sqrt(1 - f_xy ** 2)] * 2 + [math.sqrt(1 - f_yaw ** 2)])
        f = np.array([f_xy, f_xy, f_yaw])
        eps = rng.normal(size=(n, 3))
        for k in range(1, n):
            u[k] = f * u[k - 1] + q * eps[k]
        for k in range(n):
            a = layout.long_axis_rad[regions[k]]
            rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
            l_xy = rot @ np.diag([s_along, s_cross])
            err[k, :2] = l_xy @ u[k, :2]
            err[k, 2] = s_yaw * u[k, 2]
            cov[k, :2, :2] = l_xy @ l_xy.T
            cov[k, 2, 2] = s_yaw ** 2
    else:
        s0 = rng.uniform(0.01, 0.025)
        k_xy = rng.uniform(0.02, 0.05)           # m per sqrt(m driven)
        k_yaw = math.radians(rng.uniform(0.5, 1.5))
        reset_mean_s = rng.uniform(15.0, 60.0)
        cap = rng.uniform(0.08, 0.15)
        params.update(sigma_reset_m=s0, growth_m_per_sqrt_m=k_xy, growth_yaw_rad_per_sqrt_m=k_yaw,
                      reset_mean_s=reset_mean_s, cap_m=cap)
        var = np.array([s0 ** 2, s0 ** 2, math.radians(0.3) ** 2])
        e = rng.normal(0, np.sqrt(var))
        next_reset = rng.exponential(reset_mean_s)
        for k in range(n):
            ds = abs(d.v_mps[k]) * SIM_DT_S + 0.02 * SIM_DT_S
            g = np.array([k_xy, k_xy, k_yaw]) ** 2 * ds
            e = e + rng.normal(0, np.sqrt(g))
            var = var + g
            if d.t_s[k] >= next_reset or np.hypot(e[0], e[1]) > cap:
                var = np.array([s0 ** 2, s0 ** 2, math.radians(0.3) ** 2])
                e = rng.normal(0, np.sqrt(var))
                next_reset = d.t_s[k] + rng.exponential(reset_mean_s)
            err[k] = e
            cov[k] = np.diag(var)
    # white jitter of the particle filter's mean, honest in the covariance too
    jit = np.array([rng.uniform(0.003, 0.01)] * 2 + [math.radians(0.2)])
    err += rng.normal(0, 1, (n, 3)) * jit
    cov[:, [0, 1, 2], [0, 1, 2]] += jit ** 2
    jumps = []
    n_jumps = int(rng.choice([0, 0, 1, 1, 2, 3]))
    for _ in range(n_jumps):
        t0 = rng.uniform(0.1, 0.85) * d.t_s[-1]
        dur = rng.uniform(5.0, 15.0)
        mag, ang = rng.uniform(0.2, 0.5), rng.uniform(0, 2 * math.pi)
        dyaw = math.radians(rng.uniform(-3, 3))
        m = (d.t_s >= t0) & (d.t_s < t0 + dur)
        err[m] += np.array([mag * math.cos(ang), mag * math.sin(ang), dyaw])
        jumps.append({"t_start_s": float(t0), "duration_s": float(dur), "size_m": float(mag)})
    params["jumps"] = jumps
    return err, cov, params


def odometry(rng, d: Drive):
    """Wheel odometry: the two wheels' speeds with radius errors and a wheel-base error,
    encoder noise, integrated from a random start pose in the odom frame."""
    base_m = rng.uniform(0.35, 0.55)
    scale_l, scale_r = 1 + rng.normal(0, 0.01, 2)
    base_est = base_m * (1 + rng.normal(0, 0.02))
    v_l = d.v_mps - d.w_radps * base_m / 2
    v_r = d.v_mps + d.w_radps * base_m / 2
    n = len(d.t_s)
    v_l = v_l * scale_l + rng.normal(0, 0.004, n)
    v_r = v_r * scale_r + rng.normal(0, 0.004, n)
    v = (v_l + v_r) / 2
    w = (v_r - v_l) / base_est
    yaw = rng.uniform(-math.pi, math.pi) + np.concatenate([[0.0], np.cumsum(w[:-1] * SIM_DT_S)])
    x = rng.uniform(-5, 5) + np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(yaw[:-1]) * SIM_DT_S)])
    y = rng.uniform(-5, 5) + np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(yaw[:-1]) * SIM_DT_S)])
    return x, y, yaw, {"wheel_scale": [float(scale_l), float(scale_r)], "base_ratio": float(base_est / base_m)}


# ------------------------------------------------------------------------------- head trackers
HEAD_PROFILES = ("ramp", "shrink", "centroid", "tanh-elev")


def _fibonacci_cap(n=400):
    """Unit directions on the upper hemisphere (the head's top surface samples)."""
    k = np.arange(n) + 0.5
    z = 1 - k / n                         # (0, 1]
    phi = k * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z ** 2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


HEMI = _fibonacci_cap()


def draw_profile(rng):
    kind = HEAD_PROFILES[rng.integers(len(HEAD_PROFILES))]
    if kind == "ramp":
        return {"kind": kind, "shift_m": rng.uniform(0.03, 0.10), "sat_m": rng.uniform(1.0, 3.0),
                "drop0_m": rng.uniform(0.0, 0.05), "drop1_m": rng.uniform(0.0, 0.06)}
    if kind == "shrink":
        return {"kind": kind, "shift_m": rng.uniform(0.03, 0.08), "scale_m": rng.uniform(0.5, 2.0),
                "drop0_m": rng.uniform(0.0, 0.04), "drop1_m": rng.uniform(0.0, 0.06)}
    if kind == "centroid":
        return {"kind": kind, "radius_m": rng.uniform(0.10, 0.16), "half_height_m": rng.uniform(0.06, 0.15),
                "slice_m": rng.uniform(0.06, 0.20)}
    return {"kind": kind, "shift_m": rng.uniform(0.02, 0.08), "scale_m": rng.uniform(0.5, 2.5),
            "radius_m": rng.uniform(0.06, 0.14)}


def tracked_point(profile, top_w, sensor_w):
    """Where a tracker puts the head whose top is top_w (N x 3), seen from sensor_w (3,). A
    profile's "ideal" ("xy" or "z", IDEAL "head-xy" / "head-z") keeps the head top's own
    horizontal or vertical coordinates: only the other part of the profile is left."""
    out = _tracked_point(profile, top_w, sensor_w)
    ideal = profile.get("ideal")
    if ideal == "xy":
        out[:, :2] = top_w[:, :2]
    elif ideal == "z":
        out[:, 2] = top_w[:, 2]
    return out


def _tracked_point(profile, top_w, sensor_w):
    to_s = sensor_w[None, :2] - top_w[:, :2]
    d = np.linalg.norm(to_s, axis=1)
    u = to_s / np.maximum(d, 1e-6)[:, None]
    kind = profile["kind"]
    out = top_w.copy()
    if kind == "none":                  # an ideal tracker (IDEAL "head")
        return out
    if kind == "ramp":
        r = np.minimum(d, profile["sat_m"]) / profile["sat_m"]
        out[:, :2] += u * (profile["shift_m"] * r)[:, None]
        out[:, 2] -= profile["drop0_m"] + profile["drop1_m"] * r
    elif kind == "shrink":
        g = 1.0 / (1.0 + (d / profile["scale_m"]) ** 2)
        out[:, :2] += u * (profile["shift_m"] * g)[:, None]
        out[:, 2] -= profile["drop0_m"] + profile["drop1_m"] * (1 - g)
    elif kind == "tanh-elev":
        out[:, :2] += u * (profile["shift_m"] * np.tanh(d / profile["scale_m"]))[:, None]
        elev = np.arctan2(sensor_w[2] - top_w[:, 2], d)
        out[:, 2] -= profile["radius_m"] * (1 - np.sin(elev))
    else:
        # centroid of the visible points of an ellipsoidal head cap within slice_m of its top
        a, c = profile["radius_m"], profile["half_height_m"]
        pts_local = HEMI * np.array([a, a, c])                 # centre at origin
        normals = HEMI / np.array([a, a, c]) ** 2
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        keep = pts_local[:, 2] >= c - profile["slice_m"]
        pts_local, normals = pts_local[keep], normals[keep]
        for lo in range(0, len(top_w), 4096):
            centre = top_w[lo:lo + 4096] - np.array([0.0, 0.0, c])
            p = centre[:, None, :] + pts_local[None, :, :]
            view = sensor_w[None, None, :] - p
            cosang = np.einsum("nmk,mk->nm", view, normals) / np.linalg.norm(view, axis=2)
            wgt = np.clip(cosang, 0.0, None)                    # projected area seen by the sensor
            wsum = wgt.sum(axis=1, keepdims=True)
            cen = (wgt[:, :, None] * p).sum(axis=1) / np.maximum(wsum, 1e-9)
            cen[wsum[:, 0] < 1e-9] = top_w[lo:lo + 4096][wsum[:, 0] < 1e-9]
            out[lo:lo + 4096] = cen
    return out


@dataclass
class TrackerSpec:
    rate_hz: float
    phase_s: float
    clock_offset_s: float
    skew: float
    stamp_jitter_s: float
    profile: dict
    noise_range_k: float        # sigma along the ray = k0 + k * range^2
    noise_range_k0: float
    noise_lateral_k: float      # sigma across = k * range
    noise_corr: float           # AR(1) coefficient between frames
    p_miss: float
    loss_rate_per_s: float
    loss_mean_s: float
    p_outlier: float
    new_track_gap_s: float
    noise_off: bool = False     # an ideal tracker (IDEAL "noise"): no noise, no outliers


def draw_tracker(rng, clocks: bool) -> TrackerSpec:
    return TrackerSpec(
        rate_hz=float(rng.uniform(10.0, 30.0)), phase_s=float(rng.uniform(0, 0.1)),
        clock_offset_s=float(rng.uniform(-0.15, 0.15)) if clocks else 0.0,
        skew=float(rng.uniform(-8e-5, 8e-5)) if clocks and rng.random() < 0.5 else 0.0,
        stamp_jitter_s=float(rng.uniform(0.0, 0.006)), profile=draw_profile(rng),
        noise_range_k=float(rng.uniform(0.0012, 0.004)), noise_range_k0=float(rng.uniform(0.002, 0.008)),
        noise_lateral_k=float(rng.uniform(0.002, 0.006)), noise_corr=float(rng.uniform(0.0, 0.8)),
        p_miss=float(rng.uniform(0.02, 0.25)), loss_rate_per_s=float(rng.uniform(0.0, 0.08)),
        loss_mean_s=float(rng.uniform(0.4, 3.0)), p_outlier=float(rng.uniform(0.0, 0.015)),
        new_track_gap_s=float(rng.uniform(0.4, 1.0)))


def in_view(s: Sensor, p_w: np.ndarray, edge_deg: float = 0.0):
    """Which of the points p_w (N x 3) lie in the sensor's frustum and range (true pose)."""
    hfov, vfov, rmin, rmax = SENSOR_MODELS[s.model]
    p_s = (p_w - s.position_m) @ s.r_world_sensor
    rng_m = np.linalg.norm(p_s, axis=1)
    az = np.degrees(np.arctan2(p_s[:, 1], p_s[:, 0]))
    el = np.degrees(np.arctan2(p_s[:, 2], p_s[:, 0]))
    ok = (p_s[:, 0] > 0) & (np.abs(az) < hfov / 2 - edge_deg) & (np.abs(el) < vfov / 2 - edge_deg)
    return ok & (rng_m > rmin) & (rng_m < rmax)


def observe(rng, s: Sensor, spec: TrackerSpec, head_fn, t_span, latency_s, t_mid_s):
    """One entity's detections by one sensor: frames at the sensor's rate, the head as its tracker
    sees it (profile, depth-proportional noise, outliers), misses and losses, clock stamp.
    head_fn(t) -> N x 3 true head tops (NaN when the entity is absent). Returns capture times,
    stamps, reported world points (computed with the installed extrinsics) and a segment id per row."""
    t0, t1 = t_span
    k0 = math.ceil((t0 - spec.phase_s) * spec.rate_hz)
    k1 = math.floor((t1 - spec.phase_s) * spec.rate_hz)
    if k1 <= k0:
        return None
    t_cap = spec.phase_s + np.arange(k0, k1 + 1) / spec.rate_hz
    top = head_fn(t_cap)
    present = np.all(np.isfinite(top), axis=1)
    vis = present.copy()
    vis[present] = in_view(s, top[present])
    if not vis.any():
        return None
    edge = np.zeros_like(vis)
    edge[vis] = ~in_view(s, top[vis], edge_deg=3.0)
    detect = vis & (rng.random(len(t_cap)) > spec.p_miss) & ~(edge & (rng.random(len(t_cap)) < 0.5))
    # track losses: a Poisson process of losses lasting loss_mean_s on average
    t_vis = t_cap[vis]
    n_loss = rng.poisson(spec.loss_rate_per_s * max(t_vis[-1] - t_vis[0], 0.0))
    for _ in range(n_loss):
        a = rng.uniform(t_vis[0], t_vis[-1])
        detect &= ~((t_cap >= a) & (t_cap < a + rng.exponential(spec.loss_mean_s)))
    idx = np.flatnonzero(detect)
    if idx.size == 0:
        return None
    q_w = tracked_point(spec.profile, top[idx], s.position_m)
    p_s = (q_w - s.position_m) @ s.r_world_sensor        # true sensor frame
    rng_m = np.linalg.norm(p_s, axis=1)
    ray = p_s / rng_m[:, None]
    # two unit vectors across the ray
    ref = np.where(np.abs(ray[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(ray, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(ray, e1)
    white = rng.normal(size=(idx.size, 3))
    # AR(1) along the frames: a tracker's smoothing makes consecutive errors alike
    corr = np.empty_like(white)
    rho = spec.noise_corr
    corr[0] = white[0]
    for k in range(1, idx.size):
        contiguous = idx[k] == idx[k - 1] + 1
        corr[k] = rho * corr[k - 1] + math.sqrt(1 - rho ** 2) * white[k] if contiguous else white[k]
    s_r = spec.noise_range_k0 + spec.noise_range_k * rng_m ** 2
    s_l = spec.noise_lateral_k * rng_m
    noise = ray * (s_r * corr[:, 0])[:, None] + e1 * (s_l * corr[:, 1])[:, None] + e2 * (s_l * corr[:, 2])[:, None]
    outl = rng.random(idx.size) < spec.p_outlier
    noise[outl] += rng.normal(0, 0.35, (int(outl.sum()), 3))
    if spec.noise_off:
        noise[:] = 0.0
    p_meas_s = p_s + noise
    reported_w = p_meas_s @ s.installed_r_world_sensor.T + s.installed_position_m
    tc = t_cap[idx]
    jitter = rng.normal(0, spec.stamp_jitter_s + 1e-9, idx.size)
    stamp = tc + latency_s + spec.clock_offset_s + spec.skew * (tc - t_mid_s) + jitter
    seg = np.concatenate([[0], np.cumsum(np.diff(tc) > spec.new_track_gap_s)])
    return tc, stamp, reported_w, seg


# --------------------------------------------------------------------------------- pedestrians
def walkers(rng, layout: Layout, t_end_s: float, n: int):
    """People walking between random points of the free space (0.9-1.5 m/s, pausing), present
    for part of the run; returns one head function per walker."""
    fns = []
    for _ in range(n):
        h = rng.uniform(1.50, 1.90)
        speed = rng.uniform(0.9, 1.5)
        t_in = rng.uniform(0, 0.7 * t_end_s)
        t_out = min(t_end_s, t_in + rng.uniform(40.0, 200.0))
        reg = int(rng.integers(len(layout.rects)))
        pts = []
        t = t_in
        cur = _clip(np.array([rng.uniform(layout.rects[reg][0], layout.rects[reg][2]),
                              rng.uniform(layout.rects[reg][1], layout.rects[reg][3])]), layout.rects[reg], 0.4)
        pts.append((t, cur))
        while t < t_out:
            if rng.random() < 0.4 and len(layout.rects) > 1:
                reg = int(rng.integers(len(layout.rects)))
                nxt = layout.joints[0] if layout.joints else cur
                t += np.linalg.norm(nxt - cur) / speed
                pts.append((t, nxt))
                cur = nxt
            r = layout.rects[reg]
            nxt = _clip(np.array([rng.uniform(r[0], r[2]), rng.uniform(r[1], r[3])]), r, 0.4)
            t += np.linalg.norm(nxt - cur) / speed
            pts.append((t, nxt))
            if rng.random() < 0.3:
                t += rng.uniform(1.0, 8.0)
                pts.append((t, nxt))
            cur = nxt
        tt = np.array([p[0] for p in pts])
        xy = np.array([p[1] for p in pts])
        sway = rng.uniform(0.01, 0.03)

        def fn(t_s, tt=tt, xy=xy, h=h, sway=sway, t_in=t_in, t_out=t_out):
            t_s = np.asarray(t_s, float)
            out = np.stack([np.interp(t_s, tt, xy[:, 0]), np.interp(t_s, tt, xy[:, 1]),
                            h + sway * np.sin(2 * math.pi * 1.8 * t_s)], axis=1)
            out[(t_s < t_in) | (t_s > min(t_out, tt[-1]))] = np.nan
            return out
        fns.append(fn)
    return fns


# ------------------------------------------------------------------------------------ writing
def _fmt(v, nd=6):
    return f"{v:.{nd}f}"


def _sensor_yaml(sensors, installed: bool, note: str) -> str:
    lines = [f"# {note}", "frame: map", "sensors:"]
    for s in sensors:
        pos = s.installed_position_m if installed else s.position_m
        r = s.installed_r_world_sensor if installed else s.r_world_sensor
        ypr = np.degrees(ypr_from_rot(r))
        lines.append(f"  - id: {s.id}")
        lines.append(f"    position: [{_fmt(pos[0])}, {_fmt(pos[1])}, {_fmt(pos[2])}]")
        lines.append(f"    ypr_deg: [{_fmt(ypr[0], 5)}, {_fmt(ypr[1], 5)}, {_fmt(ypr[2], 5)}]")
    return "\n".join(lines) + "\n"


def _csv(columns, rows_cols) -> str:
    """rows_cols: list of (array, format) per column."""
    n = len(rows_cols[0][0])
    out = [",".join(columns)]
    cols = []
    for arr, fmt in rows_cols:
        cols.append([fmt.format(v) for v in arr])
    for i in range(n):
        out.append(",".join(c[i] for c in cols))
    return "\n".join(out) + "\n"


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w", newline="\n") as fh:
        fh.write(text)
    os.replace(tmp, path)


# ---------------------------------------------------------------------------------- generation
FAMILY_CODE = {name: i + 101 for i, name in enumerate(FAMILIES)}
PATH_MODES = {"rooms": ("tour", "lawnmower"), "lhall": ("tour", "shuttle"),
              "corridor": ("tour", "shuttle"), "openhall": ("tour", "lawnmower")}


IDEAL = ("head", "head-xy", "head-z", "noise", "clocks", "amcl", "people")
HEAD_PROFILE_MODES = ("per-sensor", "shared")


def generate(out_dir, seed: int, family: str, max_time_s: float = 600.0, walkers_max: int = 5,
             ideal=(), head_profiles: str = "per-sensor") -> dict:
    """Write one log directory (LOG_FORMAT.md) of the family from the seed; return what was drawn
    (also written to ``xgen.json`` in the log, beside the format's truth files).

    ``ideal`` switches nuisances off, for diagnosis, in the same world (every draw is still made,
    so the rest of the log is unchanged): "head" (the tracker reports the head top), "head-xy" /
    "head-z" (only its horizontal / vertical coordinates the head top's: the other part of each
    tracker's profile alone; both: "head"), "noise" (no tracker noise or outliers), "clocks" (no
    per-sensor offsets, skew or stamp jitter; the shared latency stays), "amcl" (AMCL reports the
    true pose, its covariance unchanged), "people" (no pedestrians, no false tracks).

    ``head_profiles``: "per-sensor" (each tracker its own head-point profile and parameters) or
    "shared" (one tracker software for all: every sensor gets the first sensor's profile; the bias
    it produces still depends on each sensor's viewing geometry). The world is otherwise the same."""
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; known: {', '.join(FAMILIES)}")
    if head_profiles not in HEAD_PROFILE_MODES:
        raise ValueError(f"unknown head_profiles {head_profiles!r}; known: {', '.join(HEAD_PROFILE_MODES)}")
    unknown = set(ideal) - set(IDEAL)
    if unknown:
        raise ValueError(f"unknown ideal {sorted(unknown)}; known: {', '.join(IDEAL)}")
    rng = np.random.default_rng([int(seed), FAMILY_CODE[family]])
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    head_offset = np.array([rng.uniform(-0.08, 0.08), 0.0, rng.uniform(1.10, 1.50)])
    layout = make_layout(rng, family, head_offset[2])
    install_errors(rng, layout.sensors, scale=rng.uniform(0.7, 1.4))
    mode = PATH_MODES[family][rng.integers(2)]
    wps = plan_drive(rng, layout, head_offset[2], mode, length_m=rng.uniform(120.0, 260.0))
    d = drive(rng, wps, max_time_s)
    t_base = 0.0 if rng.random() < 0.5 else float(1.7e9 + rng.integers(0, 10 ** 7))
    t_end = float(d.t_s[-1])

    # AMCL
    err, cov_true, amcl_params = amcl_error(rng, layout, d)
    if "amcl" in ideal:
        err[:] = 0.0
    amcl_rate = rng.uniform(4.0, 15.0)
    t_amcl = np.arange(rng.uniform(0, 0.1), t_end, 1.0 / amcl_rate)
    t_amcl = np.sort(t_amcl + rng.normal(0, 0.1 / amcl_rate, len(t_amcl)).clip(-0.4 / amcl_rate, 0.4 / amcl_rate))
    t_amcl = t_amcl[(t_amcl >= 0) & (t_amcl <= t_end)]
    k_amcl = np.clip(np.searchsorted(d.t_s, t_amcl), 0, len(d.t_s) - 1)
    xt, yt, yawt = pose_at(d, t_amcl)
    cov_factor = float(rng.choice([1.0, 1.0, 0.5, 2.0]))        # reported sigma / honest sigma
    cov_rep = cov_true[k_amcl] * cov_factor ** 2
    ax, ay, ayaw = xt + err[k_amcl, 0], yt + err[k_amcl, 1], wrap_rad(yawt + err[k_amcl, 2])

    # trackers
    clocks = rng.random() < 0.7
    latency = float(rng.uniform(0.03, 0.20))
    specs = {s.id: draw_tracker(rng, clocks) for s in layout.sensors}
    first = specs[layout.sensors[0].id].profile
    for spec in specs.values():
        if head_profiles == "shared":
            spec.profile = dict(first)
        if "head" in ideal or {"head-xy", "head-z"} <= set(ideal):
            spec.profile = {"kind": "none"}
        elif "head-xy" in ideal:
            spec.profile = {**spec.profile, "ideal": "xy"}
        elif "head-z" in ideal:
            spec.profile = {**spec.profile, "ideal": "z"}
        if "noise" in ideal:
            spec.noise_off = True
        if "clocks" in ideal:
            spec.clock_offset_s, spec.skew, spec.stamp_jitter_s = 0.0, 0.0, 0.0
    robot_head = lambda t: _robot_head(d, head_offset, t)  # noqa: E731
    n_walk = int(rng.integers(0, walkers_max + 1))
    people = walkers(rng, layout, t_end, n_walk)
    entities = [("robot", robot_head)] + [(f"p{i + 1}", fn) for i, fn in enumerate(people)]
    rows = []          # (stamp, sensor, track, x, y, z, who)
    for s in layout.sensors:
        spec = specs[s.id]
        next_track = 1 + int(rng.integers(0, 50))
        for who, fn in entities:
            res = observe(rng, s, spec, fn, (0.0, t_end), latency, t_end / 2)
            if res is None:
                continue
            _, stamp, pts, seg = res
            tracks = next_track + seg
            next_track = int(tracks.max()) + 1 + int(rng.integers(0, 3))
            if who != "robot" and "people" in ideal:
                continue
            for k in range(len(stamp)):
                rows.append((stamp[k], s.id, int(tracks[k]), pts[k, 0], pts[k, 1], pts[k, 2], who))
        # false tracks: short wandering blobs inside the view
        for _ in range(rng.poisson(t_end / 90.0)):
            t0 = rng.uniform(0, t_end)
            dur = rng.uniform(0.3, 3.0)
            tt = np.arange(t0, t0 + dur, 1.0 / spec.rate_hz)
            c = _target_xy(s, 1.0) + rng.normal(0, 0.7, 2)
            z = rng.uniform(0.4, 2.0)
            pw = np.column_stack([c[0] + 0.1 * np.cumsum(rng.normal(0, 0.05, len(tt))),
                                  c[1] + 0.1 * np.cumsum(rng.normal(0, 0.05, len(tt))), np.full(len(tt), z)])
            ok = in_view(s, pw)
            if not ok.any():
                continue
            p_s = (pw[ok] - s.position_m) @ s.r_world_sensor
            rep = p_s @ s.installed_r_world_sensor.T + s.installed_position_m
            for k, tk in enumerate(tt[ok]):
                stamp = tk + latency + spec.clock_offset_s
                if "people" not in ideal:
                    rows.append((stamp, s.id, next_track, rep[k, 0], rep[k, 1], rep[k, 2], "false"))
            next_track += 1

    order = sorted(range(len(rows)), key=lambda i: (rows[i][0], rows[i][1]))
    rows = [rows[i] for i in order]

    # ---- files
    _write_atomic(out / "sensors.yaml", _sensor_yaml(layout.sensors, True, "installed (hand-measured) extrinsics"))
    _write_atomic(out / "truth.yaml", _sensor_yaml(layout.sensors, False, "true extrinsics"))
    c = cov_rep
    _write_atomic(out / "robot.csv", _csv(
        ["t", "x", "y", "yaw", "cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"],
        [(t_amcl + t_base, "{:.6f}"), (ax, "{:.5f}"), (ay, "{:.5f}"), (ayaw, "{:.6f}"),
         (c[:, 0, 0], "{:.4e}"), (c[:, 0, 1], "{:.4e}"), (c[:, 0, 2], "{:.4e}"), (c[:, 1, 1], "{:.4e}"),
         (c[:, 1, 2], "{:.4e}"), (c[:, 2, 2], "{:.4e}")]))
    tr_t = np.arange(0.0, t_end, 0.05)
    tx, ty, tyaw = pose_at(d, tr_t)
    _write_atomic(out / "truth_robot.csv", _csv(["t", "x", "y", "yaw"], [
        (tr_t + t_base, "{:.6f}"), (tx, "{:.5f}"), (ty, "{:.5f}"), (wrap_rad(tyaw), "{:.6f}")]))
    has_odom = rng.random() < 0.75
    odo_params = None
    if has_odom:
        ox, oy, oyaw, odo_params = odometry(rng, d)
        odo_rate = rng.uniform(20.0, 50.0)
        t_odo = np.arange(0.0, t_end, 1.0 / odo_rate)
        _write_atomic(out / "odometry.csv", _csv(["t", "x", "y", "yaw"], [
            (t_odo + t_base, "{:.6f}"), (np.interp(t_odo, d.t_s, ox), "{:.5f}"),
            (np.interp(t_odo, d.t_s, oy), "{:.5f}"), (wrap_rad(np.interp(t_odo, d.t_s, oyaw)), "{:.6f}")]))
    elif (out / "odometry.csv").exists():
        (out / "odometry.csv").unlink()
    _write_atomic(out / "observations.csv", _csv(["t", "sensor", "track", "x", "y", "z"], [
        ([r[0] + t_base for r in rows], "{:.6f}"), ([r[1] for r in rows], "{}"), ([r[2] for r in rows], "{}"),
        ([r[3] for r in rows], "{:.5f}"), ([r[4] for r in rows], "{:.5f}"), ([r[5] for r in rows], "{:.5f}")]))
    _write_atomic(out / "truth_observations.csv", _csv(["row", "who"], [
        (range(len(rows)), "{}"), ([r[6] for r in rows], "{}")]))
    _write_atomic(out / "meta.yaml", (
        f"head_offset: [{_fmt(head_offset[0], 4)}, {_fmt(head_offset[1], 4)}, {_fmt(head_offset[2], 4)}]\n"
        f"generator: xgen\nfamily: {family}\nseed: {int(seed)}\n"))

    amcl_mean = err[:, :2].mean(axis=0)
    info = {
        "family": family, "seed": int(seed), "path_mode": mode, "duration_s": t_end, "t_base_s": t_base,
        "rects": [list(map(float, r)) for r in layout.rects],
        "head_offset_m": head_offset.tolist(),
        "sensors": [{"id": s.id, "mount": s.mount, "model": s.model, "region": s.region,
                     "height_m": float(s.position_m[2]),
                     "pitch_deg": float(np.degrees(ypr_from_rot(s.r_world_sensor)[1])),
                     "profile": specs[s.id].profile, "rate_hz": specs[s.id].rate_hz,
                     "clock_offset_s": specs[s.id].clock_offset_s, "skew": specs[s.id].skew,
                     "robot_observations": int(sum(1 for r in rows if r[1] == s.id and r[6] == "robot"))}
                    for s in layout.sensors],
        "amcl": {**amcl_params, "rate_hz": float(amcl_rate), "reported_sigma_factor": cov_factor,
                 "run_mean_error_m": amcl_mean.tolist()},
        "latency_s": latency, "clock_offsets": clocks, "odometry": odo_params if has_odom else None,
        "walkers": 0 if "people" in ideal else n_walk, "observations": len(rows), "ideal": sorted(ideal),
        "head_profiles": head_profiles,
        "robot_observations": int(sum(1 for r in rows if r[6] == "robot")),
    }
    _write_atomic(out / "xgen.json", json.dumps(info, indent=1, sort_keys=True) + "\n")
    return info


def _robot_head(d: Drive, head_offset, t_s):
    x, y, yaw = pose_at(d, t_s)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.stack([x + c * head_offset[0] - s * head_offset[1], y + s * head_offset[0] + c * head_offset[1],
                    np.full_like(x, head_offset[2])], axis=1)
    t_s = np.asarray(t_s, float)
    out[(t_s < d.t_s[0]) | (t_s > d.t_s[-1])] = np.nan
    return out
