"""Which part of each sensor's own head point leaks into its horizontal position error? On the
nuisance zoo's logs with a head model per sensor (``--vary-nuisances zoo``, per_sensor_head), the
factor graph's error of each sensor against what its head model's misfit predicts.

    nice -n 5 .venv/bin/python benchmarks/bench_head_leak.py [--scenarios paper corridor cross] \
        [--seeds 10] [--first-seed 0] [--recipe KEY=VALUE ...] [--json OUT]

Per robot sighting of the calibration log, the head point's true offset from the head top (the
sensor's own simulated model, :func:`pedcal.sim.nuisances.head_point`, at the true robot path)
and the offset the graph's estimated model gives (vertical offset, ray shift, horizontal shift
or its profile against distance, the sensor's own departure of it, curvature:
``result.diagnostics.head_model``, applied as :func:`pedcal.metrics.reproject_observations`
applies it); their
difference d (world, m) is what the graph takes for the head top's error. A sensor pose moved by
a small rigid motion (omega about its centre c, translation tau) explains d_k by
omega x (x_k - c) + tau: the weighted least-squares tau (each sighting whitened by the graph's
own range and lateral sigmas, :func:`pedcal.calib.recipe.observation_sigmas` of the recipe
with the depth and lateral noise the graph estimated from the log,
``result.diagnostics.observation_noise``, far_factor past the reliable range included) is the
position error the misfit
predicts, were the robot's path and the other sensors held. That prediction is split by the
misfit's parts, each fitted alone (the fit is linear, so they add up): the horizontal part of d
toward the sensor (its per-sensor mean, ``radial const``, and what varies with distance,
``radial var``) and the vertical part. d has no part across: every simulated head model and the
graph's own move the head point within the vertical plane through the sensor and the head top
(the largest across part found is printed as a check). The sensors' errors and predictions are
taken about their mean over the log (the "rest": the common shift is AMCL's) and projected on
each sensor's view axis (the mean horizontal unit from the sensor to its sightings of the
robot) and across it.

Printed: per log and pooled, the RMS of the actual rest error along and across the view axis,
of the prediction and of each part; along the view axis, the regression slope and R^2 of actual
on predicted, on each part, and on the error of the graph's per-sensor horizontal shift
(estimated less the truth's per-sensor mean offset toward the sensor); across it, where the
misfit has no part and the prediction is small, the RMS alone; what a sensor's own horizontal shift, ray shift or
both, free beside its pose, would leave of the predicted leak, and the variance they cost; and
by the sensors' head-point kind (:data:`pedcal.sim.nuisances.HEAD_KINDS`), the actual rest
error, the predicted leak and what those own shifts would leave of it. Figures only; no
assertion. ``--json`` writes the per-sensor rows, with fields the printout does not use: the
sensor's simulated head model (``radius``, ``shift``, ``ramp``), its median horizontal distance
to the sightings (``dist_m``), the estimated model's mean offset toward the sensor
(``est_radial_m``), the number of sightings (``n``), and per log the estimated shared model
(``head``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_factorgraph_nuisances import recipe_overrides  # noqa: E402

PARTS = ("radial const", "radial var", "vertical")
EXTRAS = ("h", "ray", "h+ray")


def rigid_translation(x: np.ndarray, d: np.ndarray, c: np.ndarray, w: np.ndarray,
                      extra: np.ndarray | None = None, want_vif: bool = True) -> tuple[np.ndarray, float]:
    """(3,) the translation tau of the small rigid motion about ``c`` (rotation omega free) that
    best explains displacements ``d`` (N, 3) of points ``x`` (N, 3), each row whitened by the
    (N, 3, 3) ``w``: least squares of w_k (omega x (x_k - c) + tau + extra_k beta - d_k), the
    (N, 3, m) ``extra`` columns free beside it (none by default); and the variance inflation of
    tau's horizontal part along the sightings' mean direction that the extra columns bring (1:
    none), from the least squares' normal matrix (NaN, not computed, when ``want_vif`` is
    false)."""
    r = x - c
    n = len(x)
    m = 0 if extra is None else extra.shape[2]
    J = np.zeros((n, 3, 6 + m))
    # omega x r = -[r]_x omega
    J[:, 0, 1], J[:, 0, 2] = r[:, 2], -r[:, 1]
    J[:, 1, 0], J[:, 1, 2] = -r[:, 2], r[:, 0]
    J[:, 2, 0], J[:, 2, 1] = r[:, 1], -r[:, 0]
    J[:, :, 3:6] = np.eye(3)
    if m:
        J[:, :, 6:] = extra
    A = np.einsum("nij,njk->nik", w, J).reshape(-1, 6 + m)
    b = np.einsum("nij,nj->ni", w, d).ravel()
    tau = np.linalg.lstsq(A, b, rcond=None)[0][3:6]
    if not want_vif:
        return tau, float("nan")
    axis = np.append(r[:, :2].mean(axis=0), 0.0)
    axis /= max(np.linalg.norm(axis), 1e-12)
    cov_full = np.linalg.pinv(A.T @ A)[3:6, 3:6]
    A6 = A[:, :6]
    cov_rigid = np.linalg.pinv(A6.T @ A6)[3:6, 3:6]
    return tau, float(axis @ cov_full @ axis) / max(float(axis @ cov_rigid @ axis), 1e-30)


def whitening(x: np.ndarray, c: np.ndarray, rec) -> np.ndarray:
    """(N, 3, 3) rows whitening a sighting's error: the range sigma along the ray from ``c``,
    the lateral sigma across it (recipe ``rec``'s noise model, as the graph weighs them)."""
    from pedcal.calib.recipe import observation_sigmas

    ray = x - c
    rng = np.linalg.norm(ray, axis=1)
    u = ray / rng[:, None]
    sig = observation_sigmas(rec, rng)
    s_r, s_lat = sig[:, 2], sig[:, 0] * rng          # the bearing sigma as a distance across the ray
    P = np.einsum("ni,nj->nij", u, u)
    return P / s_r[:, None, None] + (np.eye(3) - P) / s_lat[:, None, None]


def estimated_head_offset(x: np.ndarray, c: np.ndarray, head, sid: str) -> dict:
    """The head point the graph's estimated model ``head`` gives for sensor ``sid`` at ``c``
    and head tops ``x`` (N, 3, world): ``off`` (N, 3) its offset from the head top (m), ``hs``
    (N,) the horizontal shift toward the sensor in it, ``u_h`` (N, 3) the horizontal unit toward
    the sensor, ``u_ray`` (N, 3) the unit along the ray to it and ``dist_h`` (N,) the horizontal
    distance to it (m), all read at the head top moved up by the vertical offset. The model of
    :func:`pedcal.metrics.reproject_observations`, run forward: the ray shift toward the sensor,
    curvature_m cos^2(e) up, then the horizontal shift toward the sensor -- with a
    ``horizontal_profile`` read at the head point's horizontal distance (plus the sensor's own
    departure, ``per_sensor_shift_m`` at the profile's first knot), without one the sensor's own
    shift (``per_sensor_shift_m``) where it was estimated, else the shared one."""
    from pedcal.calib.headpoint import own_shift, shift_at

    q = x + np.array([0.0, 0.0, head.vertical_offset_m])
    u = c - q
    u_ray = u / np.linalg.norm(u, axis=1, keepdims=True)
    u_h = np.column_stack([u[:, :2], np.zeros(len(u))])
    dist_h = np.linalg.norm(u_h, axis=1)
    u_h /= np.maximum(dist_h, 1e-9)[:, None]
    cos2 = np.sum(u[:, :2] ** 2, axis=1) / np.sum(u ** 2, axis=1)
    profile = head.horizontal_profile
    if profile is not None:
        own = own_shift(profile, sid)
        # the distance after the ray shift, less the horizontal shift itself (one fixed-point
        # step: the profile is read at the head point, as reproject_observations reads it)
        d0 = dist_h - head.ray_shift_m * np.sqrt(cos2)
        hs = shift_at(profile, d0 - (shift_at(profile, d0) + own)) + own
    else:
        hs = np.full(len(q), float((head.per_sensor_shift_m or {}).get(sid, head.horizontal_shift_m)))
    off = (q - x + head.ray_shift_m * u_ray + hs[:, None] * u_h
           + head.curvature_m * cos2[:, None] * np.array([0.0, 0.0, 1.0]))
    return dict(off=off, hs=hs, u_h=u_h, u_ray=u_ray, dist_h=dist_h)


def run_one(scenario: str, seed: int, recipe: dict) -> dict | None:
    from pedcal.calib import calibrate
    from pedcal.calib.common import robot_head_at
    from pedcal.calib.recipe import GraphRecipe
    from pedcal.metrics import robot_rows
    from pedcal.sim import simulate_logs
    from pedcal.sim.nuisances import head_point, sensor_clocks, sensor_head_models

    warnings.simplefilter("ignore")
    sim = simulate_logs(scenario, seed=seed, vary_nuisances="zoo")
    sc, log = sim.scenario, sim.calib
    if not sc.per_sensor_head:
        return None
    c0 = time.process_time()
    res = calibrate(log, method="factorgraph", **recipe)
    cpu = time.process_time() - c0
    head = res.diagnostics.head_model
    # the noise model the graph weighed the sightings with: the recipe's, its depth and lateral
    # sigmas replaced by those estimated from the log (pedcal.calib.problem.prepare)
    rec = GraphRecipe(**recipe)
    noise = res.diagnostics.observation_noise or {}
    for key in ("range_sigma_floor_m", "range_sigma_k_per_m", "lateral_sigma_m"):
        if key in noise:
            setattr(rec, key, float(noise[key]))
    models = sensor_head_models(sc, len(log.truth))
    mask, _ = robot_rows(log)
    obs = log.observations[mask]
    sensors = obs["sensor"].astype(str).to_numpy()
    index = {sid: k for k, sid in enumerate(log.truth.ids)}
    k_sensor = np.array([index[s] for s in sensors], int)
    offset, _ = sensor_clocks(sc, len(log.truth))
    t = obs["t"].to_numpy(float) - sc.latency_s - offset[k_sensor]
    top = robot_head_at(log, t, truth=True)
    rows = []
    for sid in log.truth.ids:
        mine = sensors == sid
        if mine.sum() < 30 or sid not in res.network:
            continue
        k = index[sid]
        c = log.truth[sid].position_m
        x = top[mine]
        true_off = head_point(x, np.tile(c, (len(x), 1)), models[k]) - x
        est = estimated_head_offset(x, c, head, sid)
        est_off, u_h = est["off"], est["u_h"]
        d = est_off - true_off          # what the graph takes for the head top's displacement
        radial = np.sum(d * u_h, axis=1)
        across_u = np.column_stack([-u_h[:, 1], u_h[:, 0], np.zeros(len(u_h))])
        across_max = float(np.max(np.abs(np.sum(d * across_u, axis=1))))
        parts = {"radial const": radial.mean() * u_h, "radial var": (radial - radial.mean())[:, None] * u_h,
                 "vertical": d[:, 2:3] * np.array([0.0, 0.0, 1.0])}
        w = whitening(x, c, rec)
        # the sensor moves so that its sightings land on the graph's head top: by d, rigidly
        # (T_est p - T_true p = est_off - true_off = d, the displacement rigid_translation fits)
        pred = rigid_translation(x, d, c, w, want_vif=False)[0]
        part_pred = {p: rigid_translation(x, v, c, w, want_vif=False)[0] for p, v in parts.items()}
        # what a sensor's own extra terms, free beside its pose, would leave of the leak (the
        # misfit taken up by them as far as the pose cannot), and what they cost in variance
        ray_u = est["u_ray"]
        bases = {"h": u_h[:, :, None], "ray": ray_u[:, :, None], "h+ray": np.stack([u_h, ray_u], axis=2)}
        extra = {}
        for name, basis in bases.items():
            tau, vif = rigid_translation(x, d, c, w, basis)
            extra[name] = dict(pred=tau[:2].tolist(), vif=vif)
        view = (x - c)[:, :2].mean(axis=0)
        true_radial = float(np.mean(np.sum(true_off * u_h, axis=1)))
        rows.append(dict(sensor=sid, kind=models[k].head_point, radius=models[k].head_radius_m,
                         shift=models[k].head_shift_m, ramp=models[k].head_ramp_m,
                         err=(res.network[sid].position_m - c)[:2].tolist(), pred=pred[:2].tolist(),
                         parts={p: v[:2].tolist() for p, v in part_pred.items()}, extra=extra,
                         view=(view / max(np.linalg.norm(view), 1e-9)).tolist(),
                         dist_m=float(np.median(est["dist_h"])), true_radial_m=true_radial,
                         est_radial_m=float(np.mean(np.sum(est_off * u_h, axis=1))),
                         shift_est_m=float(np.mean(est["hs"])), across_max_m=across_max, n=int(mine.sum())))
    return dict(scenario=scenario, seed=seed, cpu_s=cpu, rows=rows,
                head=dict(vertical=head.vertical_offset_m, ray=head.ray_shift_m, horizontal=head.horizontal_shift_m,
                          curvature=head.curvature_m))


def along_across(rows: list[dict], key, sub=None, leaf=None) -> np.ndarray:
    """(n, 2) the rest (about the log's mean) of a per-sensor 2-D vector, along and across each
    sensor's view axis."""
    v = np.array([(r[key][sub][leaf] if leaf else r[key][sub]) if sub else r[key] for r in rows])
    v = v - v.mean(axis=0)
    a = np.array([r["view"] for r in rows])
    return np.column_stack([np.sum(v * a, axis=1), a[:, 0] * v[:, 1] - a[:, 1] * v[:, 0]])


def fit(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Slope through 0 and R^2 (about 0) of y on x."""
    sxx = float(np.sum(x * x))
    if sxx <= 1e-12 * max(float(np.sum(y * y)), 1e-30):     # x nil against y: no slope to read
        return float("nan"), float("nan")
    b = float(np.sum(x * y)) / sxx
    return b, 1.0 - float(np.sum((y - b * x) ** 2)) / max(float(np.sum(y * y)), 1e-30)


def rms_mm(v: np.ndarray) -> np.ndarray:
    """RMS over the rows (axis 0), in mm."""
    return 1000 * np.sqrt(np.mean(v ** 2, axis=0))


def summarize(results: list[dict]) -> None:
    from pedcal.sim.nuisances import HEAD_KINDS

    act, pred, parts, shift_err = [], [], {p: [] for p in PARTS}, []
    extras = {e: [] for e in EXTRAS}
    kinds = []
    used = [r for r in results if len(r["rows"]) >= 2]
    if not used:        # (a leak is read about a log's mean: one sensor has none to read)
        print(f"no log of {len(results)} has two sensors with a head model and an estimate: nothing to pool")
        return
    print("| log | sensors | rest along / across (mm) | predicted along / across | "
          + " | ".join(PARTS) + " | CPU (s) |")
    print("|---|---|---|---|" + "---|" * len(PARTS) + "---|")
    for r in used:
        rows = r["rows"]
        a, p = along_across(rows, "err"), along_across(rows, "pred")
        pp = {q: along_across(rows, "parts", q) for q in PARTS}
        act.append(a)
        pred.append(p)
        for q in PARTS:
            parts[q].append(pp[q])
        for e in EXTRAS:
            extras[e].append(along_across(rows, "extra", e, "pred"))
        kinds += [x["kind"] for x in rows]
        se = np.array([x["shift_est_m"] - x["true_radial_m"] for x in rows])
        shift_err.append(se - se.mean())
        ra, rp = rms_mm(a), rms_mm(p)
        print(f"| {r['scenario']} {r['seed']} | {len(rows)} | {ra[0]:.1f} / {ra[1]:.1f} | {rp[0]:.1f} / {rp[1]:.1f} | "
              + " | ".join(f"{rms_mm(pp[q])[0]:.1f} / {rms_mm(pp[q])[1]:.1f}" for q in PARTS)
              + f" | {r['cpu_s']:.1f} |")
    A, P = np.concatenate(act), np.concatenate(pred)
    X = {e: np.concatenate(v) for e, v in extras.items()}
    kinds = np.array(kinds)
    across_max = max(x["across_max_m"] for r in used for x in r["rows"])
    print(f"\npooled over {len(A)} sensors of {len(act)} logs (mm RMS; slope, R^2 of actual on predicted; "
          f"largest misfit across the sensor's vertical plane {1000 * across_max:.1g} mm):")
    Q = {q: np.concatenate(parts[q]) for q in PARTS}
    b, r2 = fit(A[:, 0], P[:, 0])
    print(f"  along the view axis: actual {rms_mm(A[:, 0]):.1f}, predicted {rms_mm(P[:, 0]):.1f}, "
          f"slope {b:.2f}, R^2 {r2:.2f}")
    for q in PARTS:
        b, r2 = fit(A[:, 0], Q[q][:, 0])
        print(f"    part {q:12s}: {rms_mm(Q[q][:, 0]):5.1f} mm, slope {b:+.2f}, R^2 {r2:+.2f}")
    # across, the parts are a millimetre against errors of centimetres: a slope on them means nothing
    print(f"  across (RMS alone): actual {rms_mm(A[:, 1]):.1f}, predicted {rms_mm(P[:, 1]):.1f}; parts "
          + ", ".join(f"{q} {rms_mm(Q[q][:, 1]):.1f}" for q in PARTS))
    for e in EXTRAS:
        vif = np.array([x["extra"][e]["vif"] for r in used for x in r["rows"]])
        print(f"  the sensor's own {e:5s} free beside its pose: predicted leak left along / across "
              f"{rms_mm(X[e][:, 0]):.1f} / {rms_mm(X[e][:, 1]):.1f} mm; "
              f"its variance inflation along the view axis median {np.median(vif):.1f}, 90th percentile "
              f"{np.quantile(vif, 0.9):.1f}")
    S = np.concatenate(shift_err)
    b, r2 = fit(A[:, 0], -S)
    print(f"  along the view axis on -(per-sensor shift estimated - true mean radial offset), rest: "
          f"RMS {rms_mm(S):.1f} mm, slope {b:.2f}, R^2 {r2:.2f}")
    print("\nby the sensor's head-point kind (mm RMS of the rest, along / across the view axis; the leak "
          "predicted, and what it leaves with the sensor's own shifts free):")
    print("| kind | sensors | actual | predicted | " + " | ".join(f"left, own {e}" for e in EXTRAS) + " |")
    print("|---|---|---|---|" + "---|" * len(EXTRAS))
    for kind in HEAD_KINDS:
        m = kinds == kind
        if not m.any():
            continue
        cells = [rms_mm(A[m]), rms_mm(P[m])] + [rms_mm(X[e][m]) for e in EXTRAS]
        print(f"| {kind} | {int(m.sum())} | " + " | ".join(f"{v[0]:.1f} / {v[1]:.1f}" for v in cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["paper", "corridor", "cross"])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--recipe", nargs="+", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path, help="write the per-sensor rows here")
    args = ap.parse_args()
    recipe = recipe_overrides(args.recipe, ap)
    results = []
    for sc in args.scenarios:
        for s in range(args.first_seed, args.first_seed + args.seeds):
            r = run_one(sc, s, recipe)
            if r is not None:
                results.append(r)
                print(f"{sc} seed {s}: {len(r['rows'])} sensors, {r['cpu_s']:.1f} s", file=sys.stderr, flush=True)
    if args.json:
        args.json.write_text(json.dumps(results))
    summarize(results)


if __name__ == "__main__":
    main()
