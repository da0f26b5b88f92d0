"""The simulator's nuisance zoo: alternative models of what makes a log differ from the truth,
and a per-seed draw among them (``pedcal simulate SCENARIO --vary-nuisances``).

A calibration is judged on logs it did not generate: a head tracker that reports the top of the
blob, a dome's facing point, a point shifted toward the sensor or the centroid of the head's top;
AMCL whose error is white, slowly wandering, or wandering with jumps; odometry absent, off in
scale or drifting in heading; a latency of 0-0.3 s; depth noise linear or quadratic in range.
"""

from __future__ import annotations

import numpy as np

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
    elif kind == "shift":
        out = p + np.column_stack([sc.head_shift_m * u_h, np.zeros(len(p))])
    elif kind == "centroid":
        if _CENTROID is None:
            _CENTROID = _centroid_table()
        elev = np.arctan2(to_sensor[:, 2], d_h[:, 0])
        e_tab, h_tab, z_tab = _CENTROID
        out = p + np.column_stack([np.interp(elev, e_tab, h_tab)[:, None] * u_h, np.interp(elev, e_tab, z_tab)])
    else:
        out = p.copy()
    if sc.head_vertical_bias_m:
        out = out + np.array([0.0, 0.0, sc.head_vertical_bias_m])
    return out


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


def vary(sc: Scenario) -> Scenario:
    """``sc`` with the nuisance zoo drawn from its seed (the draw has its own stream, so the
    layout and the installed extrinsics stay those of the seed)."""
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x5EED]))
    return sc.resolve(**draw_nuisances(rng))


def head_model_truth(sc: Scenario) -> str:
    """A one-line description of the scenario's head-point model."""
    detail = {"dome": f"radius {1000 * sc.head_radius_m:.0f} mm", "shift": f"{1000 * sc.head_shift_m:.0f} mm",
              "centroid": f"top {1000 * CENTROID_CAP_M:.0f} mm of a {1000 * HEAD_SPHERE_M:.0f} mm head",
              "top": ""}[sc.head_point]
    return f"{sc.head_point} {detail}, vertical bias {1000 * sc.head_vertical_bias_m:+.0f} mm".replace("  ", " ")


__all__ = ["head_point", "dome_point", "draw_nuisances", "vary", "head_model_truth"]
