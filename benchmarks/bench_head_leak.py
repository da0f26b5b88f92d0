"""Which part of each sensor's own head point leaks into its horizontal position error? On the
nuisance zoo's logs with a head model per sensor (``--vary-nuisances zoo``, per_sensor_head), the
factor graph's error of each sensor against what its head model's misfit predicts.

    nice -n 5 .venv/bin/python benchmarks/bench_head_leak.py [--scenarios paper corridor cross] \
        [--seeds 10] [--first-seed 0] [--recipe KEY=VALUE ...] [--json OUT]

Per robot sighting of the calibration log, the head point's true offset from the head top (the
sensor's own simulated model, :func:`pedcal.sim.nuisances.head_point`, at the true robot path)
and the offset the graph's estimated model gives (vertical offset, ray shift, horizontal shift,
the sensor's own departure of it, curvature: ``result.diagnostics.head_model``); their
difference d (world, m) is what the graph takes for the head top's error. A sensor pose moved by
a small rigid motion (omega about its centre c, translation tau) explains d_k by
omega x (x_k - c) + tau: the weighted least-squares tau (each sighting whitened by its range
and lateral sigma, recipe defaults) is the position error the misfit predicts, were the robot's
path and the other sensors held. That prediction is split by the misfit's parts, each fitted
alone (the fit is linear, so they add up): the horizontal part of d toward the sensor (its
per-sensor mean, ``radial const``, and what varies with distance, ``radial var``), across, and
vertical. The sensors' errors and predictions are taken about their mean over the log (the
"rest": the common shift is AMCL's) and projected on each sensor's view axis (the mean
horizontal unit from the sensor to its sightings of the robot) and across it.

Printed: per log and pooled, the RMS of the actual rest error along and across the view axis,
of the prediction and of each part, the regression slope and R^2 of actual on predicted, and of
actual on the error of the graph's per-sensor horizontal shift (estimated less the truth's
per-sensor mean offset toward the sensor). The prediction reads the graph's head model as
``result.diagnostics.head_model`` records it: without the sensors' own ray shifts
(``head_ray_shift_per_sensor_sigma_m``), which it does not record, so with them on only the
actual errors are comparable. Figures only; no assertion.
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

PARTS = ("radial const", "radial var", "across", "vertical")


def rigid_translation(x: np.ndarray, d: np.ndarray, c: np.ndarray, w: np.ndarray,
                      extra: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(3,) the translation tau of the small rigid motion about ``c`` (rotation omega free) that
    best explains displacements ``d`` (N, 3) of points ``x`` (N, 3), each row whitened by the
    (N, 3, 3) ``w``: least squares of w_k (omega x (x_k - c) + tau + extra_k beta - d_k), the
    (N, 3, m) ``extra`` columns free beside it (none by default); and the variance inflation of
    tau's horizontal part along the sightings' mean direction that the extra columns bring (1:
    none), from the least squares' normal matrix."""
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
    axis = np.append(r[:, :2].mean(axis=0), 0.0)
    axis /= max(np.linalg.norm(axis), 1e-12)
    cov_full = np.linalg.pinv(A.T @ A)[3:6, 3:6]
    A6 = A.reshape(n * 3, 6 + m)[:, :6]
    cov_rigid = np.linalg.pinv(A6.T @ A6)[3:6, 3:6]
    return tau, float(axis @ cov_full @ axis) / max(float(axis @ cov_rigid @ axis), 1e-30)


def whitening(x: np.ndarray, c: np.ndarray, rec) -> np.ndarray:
    """(N, 3, 3) rows whitening a sighting's error: range sigma along the ray from ``c``,
    the lateral sigma across it (recipe ``rec``'s noise model)."""
    ray = x - c
    rng = np.linalg.norm(ray, axis=1)
    u = ray / rng[:, None]
    s_r = rec.range_sigma_floor_m + rec.range_sigma_k_per_m * rng ** 2
    P = np.einsum("ni,nj->nij", u, u)
    return P / s_r[:, None, None] + (np.eye(3) - P) / rec.lateral_sigma_m


def run_one(scenario: str, seed: int, recipe: dict) -> dict | None:
    from pedcal.calib import calibrate
    from pedcal.calib.common import interpolate_pose2
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
    own = head.per_sensor_shift_m or {}
    rec = GraphRecipe()
    models = sensor_head_models(sc, len(log.truth))
    mask, _ = robot_rows(log)
    obs = log.observations[mask]
    sensors = obs["sensor"].astype(str).to_numpy()
    index = {sid: k for k, sid in enumerate(log.truth.ids)}
    k_sensor = np.array([index[s] for s in sensors], int)
    offset, _ = sensor_clocks(sc, len(log.truth))
    t = obs["t"].to_numpy(float) - sc.latency_s - offset[k_sensor]
    pose = interpolate_pose2(log.truth_robot, t)
    off = np.asarray(sc.head_offset_m, float)
    cs, sn = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    top = np.column_stack([pose[:, 0] + cs * off[0] - sn * off[1], pose[:, 1] + sn * off[0] + cs * off[1],
                           np.full(len(t), off[2])])
    rows = []
    for sid in log.truth.ids:
        mine = sensors == sid
        if mine.sum() < 30 or sid not in res.network:
            continue
        k = index[sid]
        c = log.truth[sid].position_m
        x = top[mine]
        true_off = head_point(x, np.tile(c, (len(x), 1)), models[k]) - x
        q = x + np.array([0.0, 0.0, head.vertical_offset_m])
        u = c - q
        u_h = np.column_stack([u[:, :2], np.zeros(len(u))])
        dist_h = np.linalg.norm(u_h, axis=1)
        u_h /= np.maximum(dist_h, 1e-9)[:, None]
        cos2 = np.sum(u[:, :2] ** 2, axis=1) / np.sum(u ** 2, axis=1)
        hs = own.get(sid, head.horizontal_shift_m)
        est_off = (q - x + head.ray_shift_m * u / np.linalg.norm(u, axis=1, keepdims=True)
                   + hs * u_h + head.curvature_m * cos2[:, None] * np.array([0.0, 0.0, 1.0]))
        d = est_off - true_off          # what the graph takes for the head top's displacement
        radial = np.sum(d * u_h, axis=1)
        across_u = np.column_stack([-u_h[:, 1], u_h[:, 0], np.zeros(len(u_h))])
        parts = {"radial const": radial.mean() * u_h, "radial var": (radial - radial.mean())[:, None] * u_h,
                 "across": np.sum(d * across_u, axis=1)[:, None] * across_u,
                 "vertical": d[:, 2:3] * np.array([0.0, 0.0, 1.0])}
        w = whitening(x, c, rec)
        # the sensor moves so that its sightings land on the graph's head top: by -d, rigidly
        # (T_est p - T_true p = est_off - true_off: the sensor moves by d, rigidly)
        pred = rigid_translation(x, d, c, w)[0]
        part_pred = {p: rigid_translation(x, v, c, w)[0] for p, v in parts.items()}
        # what a sensor's own extra terms, free beside its pose, would leave of the leak (the
        # misfit taken up by them as far as the pose cannot), and what they cost in variance
        ray_u = u / np.linalg.norm(u, axis=1, keepdims=True)
        bases = {"h": u_h[:, :, None], "ray": ray_u[:, :, None], "h+ray": np.stack([u_h, ray_u], axis=2)}
        extra = {}
        for name, basis in bases.items():
            tau, vif = rigid_translation(x, d, c, w, basis)
            extra[name] = dict(pred=tau[:2].tolist(), vif=vif)
        view = (x - c)[:, :2].mean(axis=0)
        one_sided = float(np.linalg.norm(np.mean(-u_h[:, :2], axis=0)))
        true_radial = float(np.mean(np.sum(true_off * u_h, axis=1)))
        rows.append(dict(sensor=sid, kind=models[k].head_point, radius=models[k].head_radius_m,
                         shift=models[k].head_shift_m, ramp=models[k].head_ramp_m,
                         err=(res.network[sid].position_m - c)[:2].tolist(), pred=pred[:2].tolist(),
                         parts={p: v[:2].tolist() for p, v in part_pred.items()}, extra=extra,
                         view=(view / max(np.linalg.norm(view), 1e-9)).tolist(), one_sided=one_sided,
                         dist_m=float(np.median(dist_h)), true_radial_m=true_radial,
                         est_radial_m=float(np.mean(np.sum((est_off - (q - x)) * u_h, axis=1))),
                         shift_est_m=float(hs), n=int(mine.sum())))
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
    if sxx <= 0:
        return float("nan"), float("nan")
    b = float(np.sum(x * y)) / sxx
    return b, 1.0 - float(np.sum((y - b * x) ** 2)) / max(float(np.sum(y * y)), 1e-30)


def summarize(results: list[dict]) -> None:
    act, pred, parts, shift_err = [], [], {p: [] for p in PARTS}, []
    print("| log | sensors | rest along / across (mm) | predicted along / across | radial const | radial var | "
          "across | vertical | CPU (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in results:
        rows = r["rows"]
        if len(rows) < 2:
            continue
        a, p = along_across(rows, "err"), along_across(rows, "pred")
        pp = {q: along_across(rows, "parts", q) for q in PARTS}
        act.append(a)
        pred.append(p)
        for q in PARTS:
            parts[q].append(pp[q])
        se = np.array([x["shift_est_m"] - x["true_radial_m"] for x in rows])
        shift_err.append(se - se.mean())

        def rms(v):
            return 1000 * np.sqrt(np.mean(v ** 2, axis=0))

        ra, rp = rms(a), rms(p)
        print(f"| {r['scenario']} {r['seed']} | {len(rows)} | {ra[0]:.1f} / {ra[1]:.1f} | {rp[0]:.1f} / {rp[1]:.1f} | "
              + " | ".join(f"{rms(pp[q])[0]:.1f} / {rms(pp[q])[1]:.1f}" for q in PARTS) + f" | {r['cpu_s']:.1f} |")
    A, P = np.concatenate(act), np.concatenate(pred)
    print(f"\npooled over {len(A)} sensors of {len(act)} logs (mm RMS; slope, R^2 of actual on predicted):")
    for ax, name in ((0, "along the view axis"), (1, "across")):
        b, r2 = fit(A[:, ax], P[:, ax])
        print(f"  {name}: actual {1000 * np.sqrt(np.mean(A[:, ax] ** 2)):.1f}, predicted "
              f"{1000 * np.sqrt(np.mean(P[:, ax] ** 2)):.1f}, slope {b:.2f}, R^2 {r2:.2f}")
        for q in PARTS:
            Q = np.concatenate(parts[q])[:, ax]
            b, r2 = fit(A[:, ax], Q)
            print(f"    part {q:12s}: {1000 * np.sqrt(np.mean(Q ** 2)):5.1f} mm, slope {b:+.2f}, R^2 {r2:+.2f}")
    for name in ("h", "ray", "h+ray"):
        X = np.concatenate([along_across(r["rows"], "extra", name, "pred") for r in results if len(r["rows"]) >= 2])
        vif = np.array([x["extra"][name]["vif"] for r in results if len(r["rows"]) >= 2 for x in r["rows"]])
        print(f"  the sensor's own {name:5s} free beside its pose: predicted leak left along / across "
              f"{1000 * np.sqrt(np.mean(X[:, 0] ** 2)):.1f} / {1000 * np.sqrt(np.mean(X[:, 1] ** 2)):.1f} mm; "
              f"its variance inflation along the view axis median {np.median(vif):.1f}, 90th percentile "
              f"{np.quantile(vif, 0.9):.1f}")
    S = np.concatenate(shift_err)
    b, r2 = fit(A[:, 0], -S)
    print(f"  along the view axis on -(per-sensor shift estimated - true mean radial offset), rest: "
          f"RMS {1000 * np.sqrt(np.mean(S ** 2)):.1f} mm, slope {b:.2f}, R^2 {r2:.2f}")


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
