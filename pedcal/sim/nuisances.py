"""The simulator's nuisance zoo: alternative models of what makes a log differ from the truth,
and a per-seed draw among them (``pedcal simulate SCENARIO --vary-nuisances``).

A calibration is judged on logs it did not generate: a head tracker that reports the top of the
blob, a dome's facing point, a point shifted toward the sensor or the centroid of the head's top;
AMCL whose error is white, slowly wandering, or wandering with jumps; odometry absent, off in
scale or drifting in heading; a latency of 0-0.3 s; depth noise linear or quadratic in range.

``--vary-nuisances zoo`` draws, besides, from a stream of its own (so the classic draw of a seed
is unchanged): head points whose shift toward the sensor ramps down or saturates with horizontal
distance (linearly, exponentially or smoothly: the shape from a stream of its own), a head model
per sensor (each sensor running its own tracker), per-sensor clock offsets (+-0.15 s) and skews,
mixed mounting heights (2.6-4.5 m), wall-mounted sensors pitched 10-25 deg, AMCL
relocalizations (0.4 m held for 10 s) and, from streams of their own, tracker noise white or
correlated frame to frame (rho 0.3-0.85: a tracker that filters its output), the robot's stops
(1-5 s at 10-30 % of its route's waypoints, half the seeds) and a head point that sinks as heads
are seen from the side (1-4 cm at head_ramp_m, per sensor with a tracker per sensor; half the
seeds), beyond what a dome's or a centroid's point does.
"""

from __future__ import annotations

import numpy as np

from pedcal.sim.robot import drive_route, route_waypoints, stop_waypoints
from pedcal.sim.scenario import Scenario

HEAD_SPHERE_M = 0.1      # the head of the ``centroid`` model: a sphere of this radius
CENTROID_CAP_M = 0.1     # ... of which the tracker averages the top this many metres


def _centroid_table(n_elev: int = 91, n_pts: int = 4000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offset of the ``centroid`` head point from the head top, (toward the sensor horizontally,
    up) in metres, against the sensor's elevation seen from the head (rad): the area-weighted
    centroid of the points of the sphere within CENTROID_CAP_M of its top whose normal faces the
    (distant) sensor. Fibonacci points on the sphere (uniform in area)."""
    k = np.arange(n_pts) + 0.5
    z = 1.0 - 2.0 * k / n_pts
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    pts = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])      # unit normals
    cap = pts[:, 2] * HEAD_SPHERE_M >= HEAD_SPHERE_M - CENTROID_CAP_M
    elev = np.linspace(0.0, np.pi / 2, n_elev)
    horiz, up = np.zeros(n_elev), np.zeros(n_elev)
    for i, e in enumerate(elev):
        seen = cap & (pts @ np.array([np.cos(e), 0.0, np.sin(e)]) > 0.0)
        c = pts[seen].mean(axis=0) * HEAD_SPHERE_M
        horiz[i], up[i] = c[0], c[2] - HEAD_SPHERE_M
    return elev, horiz, up


_CENTROID = None


def dome_point(p_top_world: np.ndarray, sensor_pos: np.ndarray, head_radius_m: float) -> np.ndarray:
    """The point of a head dome (a sphere of radius r under the head top) that faces the sensor:
    the centre plus r along the unit vector toward the sensor. It is shifted r cos(e)
    horizontally toward the sensor and r (1 - sin e) down, e the sensor's elevation."""
    if head_radius_m == 0.0:
        return p_top_world
    centre = p_top_world - np.array([0.0, 0.0, head_radius_m])
    u = sensor_pos - centre
    return centre + head_radius_m * u / np.linalg.norm(u, axis=1, keepdims=True)


RAMP_SHAPES = ("linear", "exp", "smooth")


def ramp_share(x: np.ndarray, shape: str) -> np.ndarray:
    """The share of a ``ramp`` or ``saturate`` head point's change done at x = d / head_ramp_m
    (Scenario.head_ramp_shape): linear min(x, 1), exp 1 - exp(-3 x), smooth 3 x^2 - 2 x^3 on
    min(x, 1)."""
    x = np.maximum(np.asarray(x, float), 0.0)
    if shape == "exp":
        return 1.0 - np.exp(-3.0 * x)
    c = np.minimum(x, 1.0)
    return c * c * (3.0 - 2.0 * c) if shape == "smooth" else c


def _ramp_shape(seed: int, i: int) -> str:
    """A ramp's shape drawn from a stream of its own (seed, i: the sensor, -1 the shared model),
    so that adding it left every other draw of the zoo as it was."""
    return str(np.random.default_rng(np.random.SeedSequence([seed, 0x5A9E, i + 1])).choice(RAMP_SHAPES))


def head_point(p_top_world: np.ndarray, sensor_pos: np.ndarray, sc: Scenario) -> np.ndarray:
    """The point a tracker reports for heads whose tops are at ``p_top_world`` (N, 3), seen from
    sensors at ``sensor_pos`` (N, 3), under the scenario's ``head_point`` model plus its
    vertical bias."""
    global _CENTROID
    p = np.asarray(p_top_world, float)
    to_sensor = sensor_pos - p
    horiz = to_sensor[:, :2]
    d_h = np.linalg.norm(horiz, axis=1, keepdims=True)
    u_h = np.where(d_h > 1e-9, horiz / np.maximum(d_h, 1e-9), 0.0)
    kind = sc.head_point
    if kind == "dome":
        out = dome_point(p, sensor_pos, sc.head_radius_m)
    elif kind in ("shift", "ramp", "saturate"):
        # the shift toward the sensor against horizontal distance: constant, ramping down to
        # nothing at head_ramp_m, or growing to head_shift_m there and saturating
        frac = ramp_share(d_h / sc.head_ramp_m, sc.head_ramp_shape) if kind != "shift" else np.ones_like(d_h)
        shift = sc.head_shift_m * (1.0 - frac if kind == "ramp" else frac)
        out = p + np.column_stack([shift * u_h, np.zeros(len(p))])
    elif kind == "centroid":
        if _CENTROID is None:
            _CENTROID = _centroid_table()
        elev = np.arctan2(to_sensor[:, 2], d_h[:, 0])
        e_tab, h_tab, z_tab = _CENTROID
        out = p + np.column_stack([np.interp(elev, e_tab, h_tab)[:, None] * u_h, np.interp(elev, e_tab, z_tab)])
    else:
        out = p.copy()
    if sc.head_sink_m:
        # (a new array: a dome of radius 0 returns the caller's own)
        out = out - np.outer(sc.head_sink_m * ramp_share(d_h[:, 0] / sc.head_ramp_m, sc.head_ramp_shape), [0, 0, 1])
    if sc.head_vertical_bias_m:
        out = out + np.array([0.0, 0.0, sc.head_vertical_bias_m])
    return out


HEAD_KINDS = ("top", "dome", "shift", "centroid", "ramp", "saturate")


def _draw_head(rng: np.random.Generator) -> dict:
    """A head model of the zoo: any kind, radius 0-0.12 m, shift 2-6 cm, ramp over 1-3 m."""
    return dict(head_point=str(rng.choice(HEAD_KINDS)), head_radius_m=float(rng.uniform(0.0, 0.12)),
                head_shift_m=float(rng.uniform(0.02, 0.06)), head_ramp_m=float(rng.uniform(1.0, 3.0)))


def _sensor_sinks(seed: int, n: int, sink_m: float) -> np.ndarray:
    """Each of ``n`` sensors' sink (m): uniform in 0-2 x ``sink_m``, from a stream of its own (so
    that adding it left every other draw as it was); zeros when ``sink_m`` is 0."""
    if not sink_m:
        return np.zeros(n)
    return np.random.default_rng(np.random.SeedSequence([seed, 0x5170])).uniform(0.0, 2.0, n) * sink_m


def _zoo_sink(seed: int) -> float:
    """The head point's sink of a zoo seed (m), from a stream of its own: none for half the
    seeds, else uniform in 1-4 cm (per sensor, 0-2 x that)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5170, 2]))
    return 0.0 if rng.random() < 0.5 else float(rng.uniform(0.01, 0.04))


def sensor_head_models(sc: Scenario, n: int) -> list[Scenario]:
    """The head model of each of ``n`` sensors: ``sc`` itself, or with per_sensor_head one drawn
    per sensor from the seed (:func:`_draw_head`, its sink :func:`_sensor_sinks`; the vertical
    bias stays the scenario's)."""
    if not sc.per_sensor_head:
        return [sc] * n
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x4EAD]))
    sinks = _sensor_sinks(sc.seed, n, sc.head_sink_m)
    return [sc.resolve(**_draw_head(rng), head_ramp_shape=_ramp_shape(sc.seed, i), head_sink_m=float(sinks[i]))
            for i in range(n)]


def _tracker_noise_rho(seed: int) -> float:
    """The tracker noise's frame-to-frame correlation of a zoo seed, from a stream of its own (so
    that adding it left every other draw of the zoo as it was): white (0) for half the seeds,
    else uniform in 0.3-0.85 (a tracker filtering its output at 10-30 Hz)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7AC0]))
    return 0.0 if rng.random() < 0.5 else float(rng.uniform(0.3, 0.85))


def _robot_stops(seed: int) -> dict:
    """The robot's stops of a zoo seed, from a stream of their own (so that adding them left
    every other draw of the zoo as it was): none for half the seeds, else 1-5 s at 10-30 % of
    the route's waypoints (a robot at its goals, or waiting for people to pass)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5709, 2]))
    if rng.random() < 0.5:
        return dict(robot_stop_s=0.0, robot_stop_share=0.0)
    return dict(robot_stop_s=float(rng.uniform(1.0, 5.0)), robot_stop_share=float(rng.uniform(0.1, 0.3)))


def sensor_clocks(sc: Scenario, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-sensor clock offsets (s) and skews (ppm) of ``n`` sensors, uniform in +-clock_offset_s
    and +-clock_skew_ppm, from a stream of their own (zeros when off)."""
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0xC10C]))
    offset = rng.uniform(-1.0, 1.0, n) * sc.clock_offset_s
    return offset, rng.uniform(-1.0, 1.0, n) * sc.clock_skew_ppm


def draw_zoo(rng: np.random.Generator) -> dict:
    """One draw of the zoo's further families, as scenario overrides, each with its
    alternatives: the head point (any of HEAD_KINDS, the same for every sensor or drawn per
    sensor); clocks (shared, per-sensor offsets of up to +-0.15 s, offsets and skews up to
    +-50 ppm); mounts (ceiling at sensor_height_m, mixed heights 2.6-4.5 m, or mixed heights with
    a third of the sensors wall-mounted, pitched 10-25 deg); AMCL relocalizations (none beyond
    the classic draw, or 0.4 m jumps held for 10 s every ~2 min)."""
    out = _draw_head(rng)
    out["per_sensor_head"] = bool(rng.random() < 0.5)
    clocks = str(rng.choice(["shared", "offsets", "skew"]))
    out["clock_offset_s"] = 0.0 if clocks == "shared" else float(rng.uniform(0.05, 0.15))
    out["clock_skew_ppm"] = float(rng.uniform(10.0, 50.0)) if clocks == "skew" else 0.0
    mounts = str(rng.choice(["ceiling", "mixed", "wall"]))
    out["sensor_height_range_m"] = None if mounts == "ceiling" else [2.6, 4.5]
    out["wall_mounted_fraction"] = 1.0 / 3.0 if mounts == "wall" else 0.0
    if rng.random() < 0.5:
        out.update(amcl_error="jumps", amcl_jump_m=0.4, amcl_jump_life_s=[10.0, 10.0], amcl_jump_rate_hz=1.0 / 120.0)
    return out


def zoo_families(sc: Scenario) -> dict[str, str]:
    """The family each nuisance of the zoo falls in for ``sc`` (for splitting figures)."""
    return {"head": ("per-sensor" if sc.per_sensor_head else sc.head_point),
            "clock": ("skew" if sc.clock_skew_ppm else "offsets" if sc.clock_offset_s else "shared"),
            "mounts": ("wall" if sc.wall_mounted_fraction else "mixed" if sc.sensor_height_range_m else "ceiling"),
            "amcl": ("correlated" if sc.amcl_error == "jumps" and sc.amcl_jump_m <= 0.0
                     else "relocalization" if sc.amcl_error == "jumps" and sc.amcl_jump_life_s[0] >= 10.0
                     else sc.amcl_error),
            "head sink": "sinks" if sc.head_sink_m else "none",
            "tracker noise": "correlated" if sc.tracker_noise_rho > 0 else "white",
            "robot stops": "stops" if _stops_realized(sc) else "none"}


def _stops_realized(sc: Scenario) -> bool:
    """Whether the robot stops at some waypoint of its route (drawn stops on a short route may
    pick none, a stop shorter than half a truth period holds no pose, and a log cut short by
    ``duration_s`` may end before the first stop: the family is what the log holds, not what was
    drawn). A cut log's drive is simulated to see: a stop holds a pose unchanged from one truth
    step to the next, which the follower's motion never does."""
    if not len(stop_waypoints(sc, len(route_waypoints(sc)))):
        return False
    if sc.duration_s is None:
        return True
    poses = drive_route(sc)
    return bool(np.any(np.all(np.diff(poses, axis=0) == 0.0, axis=1)))


# each family :func:`switch_off` takes out of a drawn scenario, and the values it sets
OFF_FAMILIES = ("head", "clock", "latency", "jumps", "mounts", "odometry", "depth", "smoothing", "stops")


def switch_off(sc: Scenario, families) -> Scenario:
    """``sc`` (its nuisances drawn) with the nuisance ``families`` (of OFF_FAMILIES) switched off,
    every other draw of the seed left as it was (the layout, the routes, the noise streams): for
    controlled experiments, the same log with one family at a time made ideal. ``head``: the head
    top itself, the same for every sensor, no vertical bias; ``clock``: one shared clock (no
    per-sensor offsets or skews); ``latency``: none; ``jumps``: AMCL's jumps or relocalizations
    of size 0 (drawn as before, so AMCL's wander and reported covariance stay the same draws);
    ``mounts``: every sensor on the ceiling at sensor_height_m (this one changes which
    observations there are, and with them the tracker's noise draws: not a paired comparison);
    ``odometry``: no scale error nor gyro bias (the odometry, when the log has one, stays);
    ``depth``: depth noise quadratic in range (the simulator's own model); ``smoothing``: the
    tracker's noise white frame to frame (the same draws, not correlated); ``stops``: the robot
    never stops (the same route driven without its holds; the log's time, and with it every
    draw along it, differs: not a paired comparison)."""
    off = {}
    for family in families:
        if family not in OFF_FAMILIES:
            raise ValueError(f"unknown nuisance family '{family}', expected one of {', '.join(OFF_FAMILIES)}")
        off.update({"head": dict(head_point="top", per_sensor_head=False, head_vertical_bias_m=0.0, head_sink_m=0.0),
                    "clock": dict(clock_offset_s=0.0, clock_skew_ppm=0.0),
                    "latency": dict(latency_s=0.0),
                    "jumps": dict(amcl_jump_m=0.0) if sc.amcl_error == "jumps" else {},
                    "mounts": dict(sensor_height_range_m=None, wall_mounted_fraction=0.0),
                    "odometry": dict(odom_scale_error=0.0, odom_gyro_bias_dps=0.0),
                    "depth": dict(depth_noise_model="quadratic"),
                    "smoothing": dict(tracker_noise_rho=0.0),
                    "stops": dict(robot_stop_s=0.0, robot_stop_share=0.0)}[family])
    return sc.resolve(**off) if off else sc


def draw_nuisances(rng: np.random.Generator) -> dict:
    """One draw of the nuisance zoo, as scenario overrides: head point (top, dome of radius
    0-0.12 m, shift toward the sensor 0-6 cm, centroid of the top 10 cm; vertical bias +-3 cm),
    AMCL error (white, correlated, correlated with 0.3 m jumps), odometry (absent, 1-3 % scale
    error, yaw-rate bias), latency 0-0.3 s, depth noise linear or quadratic in range."""
    out = dict(head_point=str(rng.choice(["top", "dome", "shift", "centroid"])),
               head_radius_m=float(rng.uniform(0.0, 0.12)), head_shift_m=float(rng.uniform(0.0, 0.06)),
               head_vertical_bias_m=float(rng.uniform(-0.03, 0.03)),
               amcl_error=str(rng.choice(["white", "correlated", "jumps"])),
               latency_s=float(rng.uniform(0.0, 0.3)),
               depth_noise_model=str(rng.choice(["quadratic", "linear"])))
    odometry = str(rng.choice(["absent", "scale", "yaw_rate"]))
    out["odometry"] = odometry != "absent"
    out["odom_scale_error"] = float(rng.uniform(0.01, 0.03)) if odometry == "scale" else 0.005
    out["odom_gyro_bias_dps"] = float(rng.uniform(0.05, 0.2)) if odometry == "yaw_rate" else 0.02
    return out


def vary(sc: Scenario, zoo: bool = False) -> Scenario:
    """``sc`` with the nuisance zoo drawn from its seed (the draw has its own stream, so the
    layout and the installed extrinsics stay those of the seed); ``zoo`` also draws the further
    families (:func:`draw_zoo`) from a stream of their own, after the classic draw, and the
    tracker noise's correlation, the robot's stops and the head point's sink each from a stream of
    its own."""
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x5EED]))
    out = sc.resolve(**draw_nuisances(rng))
    if zoo:
        out = out.resolve(**draw_zoo(np.random.default_rng(np.random.SeedSequence([sc.seed, 0x5EED, 2]))),
                          head_ramp_shape=_ramp_shape(sc.seed, -1), tracker_noise_rho=_tracker_noise_rho(sc.seed),
                          head_sink_m=_zoo_sink(sc.seed),
                          **_robot_stops(sc.seed))
    return out


def head_model_truth(sc: Scenario) -> str:
    """A one-line description of the scenario's head-point model."""
    ramp = f"{1000 * sc.head_shift_m:.0f} mm over {sc.head_ramp_m:.1f} m ({sc.head_ramp_shape})"
    detail = {"dome": f"radius {1000 * sc.head_radius_m:.0f} mm", "shift": f"{1000 * sc.head_shift_m:.0f} mm",
              "ramp": ramp, "saturate": ramp,
              "centroid": f"top {1000 * CENTROID_CAP_M:.0f} mm of a {1000 * HEAD_SPHERE_M:.0f} mm head",
              "top": ""}[sc.head_point]
    sink = (f", sinking {1000 * sc.head_sink_m:.0f} mm over {sc.head_ramp_m:.1f} m ({sc.head_ramp_shape})"
            if sc.head_sink_m else "")
    named = f"{sc.head_point} {detail}" if detail else sc.head_point
    return f"{named}{sink}, vertical bias {1000 * sc.head_vertical_bias_m:+.0f} mm"


def sensor_truth(sc: Scenario, ids: list[str]) -> dict:
    """The per-sensor nuisances of the zoo as a truth record (empty when every one is off):
    clock offset (s) and skew (ppm), head model. (Mounts are in the true extrinsics.)"""
    out: dict = {}
    if sc.clock_offset_s or sc.clock_skew_ppm:
        offset, skew = sensor_clocks(sc, len(ids))
        out["clock_offset_s"] = {i: float(v) for i, v in zip(ids, offset, strict=True)}
        out["clock_skew_ppm"] = {i: float(v) for i, v in zip(ids, skew, strict=True)}
    if sc.per_sensor_head:
        out["head_point"] = {i: head_model_truth(m) for i, m in zip(ids, sensor_head_models(sc, len(ids)), strict=True)}
    return out


__all__ = ["switch_off", "OFF_FAMILIES",
           "head_point", "dome_point", "draw_nuisances", "draw_zoo", "vary", "head_model_truth", "sensor_clocks",
           "sensor_head_models", "sensor_truth", "zoo_families", "HEAD_KINDS", "RAMP_SHAPES", "ramp_share"]
