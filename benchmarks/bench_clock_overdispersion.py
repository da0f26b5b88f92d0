"""The clock offsets' overdispersion (pedcal.calib.clocks.offset_overdispersion): its cost inside
the factor graph's solve and the precision of its Monte-Carlo null, on the simulator's zoo logs
(``simulate_logs(..., vary_nuisances="zoo")``, as bench_factorgraph_nuisances.py --zoo).

    nice -n 10 .venv/bin/python benchmarks/bench_clock_overdispersion.py \
        [--scenarios paper sparse corridor cross lhall] [--seeds 4] [--draws 32] [--no-exact]
        [--gaussian] [--parts [--repeats 5]]

Per log: the offsets (k) and time blocks (C); the CPU time of widen_for_overdispersion inside
``calibrate`` (time.process_time, one run); the largest move of an offset's widening factor
sqrt(max(1, phi)) (its sigma's) when the null's draws are seeded 1, 2, 3 instead of 0 (the Monte
Carlo's own noise), and, unless ``--no-exact``, when the null is the exact expectation

    E V(r) = C / (C - 1) tr(G K P K^T G),  P = I - A N^-1 A^T,  G = I - 1 1^T / C,

(K: each block's row sums weighted by the offset's efficient rows m; tr(G K K^T G) from the block
sums of m^2, and tr(G K A N^-1 A^T K^T G) by k C solves through the step's factorization, whose
CPU time is shown), against which the solve's null E V(e) - E V(H e) (the first term exact, the
second, the projection's share, by the draws: a control variate at the plain mean's cost) is
compared over four seeds of its draws.

With ``--gaussian``, the null's draws are standard normal (``default_rng(seed).standard_normal``,
the same seeds) instead of :func:`pedcal.calib.clocks.null_draws`' signs, everywhere in the run
(the calibrations' own widenings too): the comparison behind NULL_DRAWS' comment in clocks.py,

    nice -n 10 .venv/bin/python benchmarks/bench_clock_overdispersion.py \
        --scenarios paper corridor cross --seeds 2 --no-exact [--gaussian]

With ``--parts``, instead, where one call's CPU time goes (the fastest of ``--repeats`` calls on
the captured system, after the calibration's own): how many times a calibration widens (once: a
cache of anything across its calls would serve only a second calibration in the same process),
whether the last full profile step kept its factorization (else the call makes one, shown as
"factorization"), the seeded draws, A^T e, the 32-column solve, A s written into X, the block
scores (:func:`pedcal.calib.clocks.block_scores`), the efficient weights and the whole call.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
import scipy.sparse as sps

import pedcal.calib.factorgraph as fgmod
from pedcal.calib import calibrate, clocks
from pedcal.sim import simulate_logs


def gaussian_draws(rows: int, draws: int, seed: int) -> np.ndarray:
    """(rows, draws) standard normal errors, seeded: the null's draws under ``--gaussian``."""
    return np.random.default_rng(seed).standard_normal((rows, draws))


def captured_widening(scenario: str, seed: int) -> tuple[tuple | None, float, int]:
    """(the arguments widen_for_overdispersion got in one calibration of the zoo log, or None
    without a widening; its CPU s; the widenings in the calibration)."""
    seen: dict = {}
    original = fgmod.widen_for_overdispersion

    def spy(*args):
        c0 = time.process_time()
        out = original(*args)
        seen.update(args=args, cpu=time.process_time() - c0, calls=seen.get("calls", 0) + 1)
        return out
    fgmod.widen_for_overdispersion = spy
    try:
        calibrate(simulate_logs(scenario, seed=seed, vary_nuisances="zoo").calib, method="factorgraph")
    finally:
        fgmod.widen_for_overdispersion = original
    return seen.get("args"), seen.get("cpu", 0.0), seen.get("calls", 0)


def captured_system(scenario: str, seed: int) -> tuple[tuple | None, float, int]:
    """((the profile step, the nuisances, the residuals at the estimate, the rows' time blocks) that
    offset_overdispersion got in one calibration of the zoo log, or None without a widening; its
    CPU s there; the widenings in the calibration), as widen_for_overdispersion makes them."""
    captured, cpu, calls = captured_widening(scenario, seed)
    if captured is None or captured[0] is None:
        return None, cpu, calls
    reference, nuis, theta, _cov, pose_times, node_times = captured
    step, theta_ref = reference
    d = np.asarray(theta, float) - np.asarray(theta_ref, float)
    rho = step.rho0 + np.asarray(step.A @ (step.Z @ d)) - step.B @ d
    return (step, nuis, rho, clocks.row_blocks(step, pose_times, node_times)), cpu, calls


def captured_systems(args):
    """(the log's label, captured_system's system, its CPU s, the widenings) of each scenario and
    seed asked for, a log without a widening said in a table row and skipped."""
    for scenario in args.scenarios:
        for seed in range(args.seeds):
            system, cpu, calls = captured_system(scenario, seed)
            if system is None:
                print(f"| {scenario} {seed} | no widening ({calls} widenings) |")
                continue
            yield f"{scenario} {seed}", system, cpu, calls


def parts(step, nuis, rho: np.ndarray, blocks: np.ndarray, draws: int) -> dict | None:
    """CPU s of each part of one offset_overdispersion call, its own steps taken in turn (the same
    operations, in the same order); None without offsets to widen."""
    from pedcal.calib.profile import _normal_solver

    out, c0 = {}, time.process_time()

    def mark(name):
        nonlocal c0
        out[name] = out.get(name, 0.0) + time.process_time() - c0
        c0 = time.process_time()
    weights = clocks.efficient_weights(step, nuis, blocks)
    mark("weights")
    if weights is None:           # (no clock offsets, or too few time blocks: nothing is widened)
        return None
    solve = step.__dict__.get("_normal_solve")
    if solve is None:
        solve = _normal_solver(step.A, step.order)
        mark("factorization")
    e = clocks.null_draws(len(rho), draws, 0)
    mark("draws")
    X = np.empty((len(rho), draws + 1))
    X[:, 0] = rho
    y = np.asarray(step.A.T @ e)
    mark("A^T e")
    s = solve(y)
    mark("solve")
    X[:, 1:] = step.A @ s
    mark("A s")
    clocks.block_scores(step, weights, X)
    mark("block scores")
    clocks.offset_overdispersion(step, nuis, rho, blocks, draws=draws)
    mark("whole call")
    return out


def main_parts(args) -> None:
    """The --parts table (see the module's text)."""
    names = ["factorization", "draws", "A^T e", "solve", "A s", "block scores", "weights", "whole call"]
    print("CPU ms; widenings: calls per calibration; in calibrate: the call inside it\n\n"
          "| log | widenings | factorization kept | in calibrate | " + " | ".join(names) + " |\n|"
          + "---|" * (len(names) + 4))
    for label, (step, nuis, rho, blocks), cpu, calls in captured_systems(args):
        runs = [parts(step, nuis, rho, blocks, args.draws) for _ in range(args.repeats)]
        if runs[0] is None:
            print(f"| {label} | {calls} | no offsets or too few blocks |", flush=True)
            continue
        best = {k: min(r.get(k, 0.0) for r in runs) for k in names}
        print(f"| {label} | {calls} | {'_normal_solve' in step.__dict__} | {1000 * cpu:.1f} | "
              + " | ".join(f"{1000 * best[k]:.1f}" for k in names) + " |", flush=True)


def block_operator(step, nuis, clusters: np.ndarray):
    """(the offsets' indices, K^T (rows x k C)): (K x)[c C + b] = sum over block b of m_ic x_i,
    the whole rows x offsets matrix of efficient rows m at once (the solve's path,
    clocks.block_scores, takes a block at a time)."""
    idx, W, block, C = clocks.efficient_weights(step, nuis, clusters)
    m = np.asarray(step.A @ (step.Z @ W)) - np.asarray(step.B @ W)
    kept = block >= 0
    k = len(idx)
    KT = sps.csr_matrix((m[kept].ravel(), (np.arange(k) * C + block[kept][:, None]).ravel(),
                         np.r_[0, np.cumsum(np.where(kept, k, 0))]), shape=(len(clusters), k * C))
    return idx, KT


def exact_overdispersion(step, nuis, rho: np.ndarray, clusters: np.ndarray) -> tuple[np.ndarray, float]:
    """(phi_j with the null's exact expectation (module docstring), the CPU s of its k C solves)."""
    out = np.full(len(nuis), np.nan)
    idx, KT = block_operator(step, nuis, clusters)
    k = len(idx)
    C = KT.shape[1] // k
    U = np.asarray(KT.T @ rho).reshape(k, C)
    V = np.sum((U - U.mean(axis=1, keepdims=True)) ** 2, axis=1) * C / (C - 1)
    tr_gkkg = np.asarray(KT.multiply(KT).sum(axis=0)).reshape(k, C).sum(axis=1) * (1.0 - 1.0 / C)
    Y = np.asarray((step.A.T @ KT).todense()).reshape(-1, k, C)
    Y -= Y.mean(axis=2, keepdims=True)                      # A^T K^T G, per offset
    solve = step.__dict__.get("_normal_solve")
    c0 = time.process_time()
    if solve is None:
        from pedcal.calib.profile import _normal_solver
        solve = _normal_solver(step.A, step.order)
    NY = solve(Y.reshape(-1, k * C)).reshape(Y.shape)
    cpu = time.process_time() - c0
    out[idx] = V / (C / (C - 1) * (tr_gkkg - np.einsum("nkc,nkc->k", Y, NY)))
    return out, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["paper", "sparse", "corridor", "cross", "lhall"])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--draws", type=int, default=clocks.NULL_DRAWS)
    ap.add_argument("--no-exact", action="store_true")
    ap.add_argument("--gaussian", action="store_true",
                    help="the null's draws standard normal instead of clocks.null_draws' signs")
    ap.add_argument("--parts", action="store_true", help="one call's CPU time by part instead")
    ap.add_argument("--repeats", type=int, default=5, help="--parts: calls timed, the fastest kept")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.gaussian:
        clocks.null_draws = gaussian_draws        # (offset_overdispersion reads the module's name)
        print("null draws: standard normal (--gaussian)")
    load0 = os.getloadavg()
    if args.parts:
        main_parts(args)
        print(f"load average (1 min) {load0[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2 cores)")
        return
    print("| log | k | C | widening CPU (ms) | sigma move, draws seeded 1-3 (%) | sigma move, exact null (%) "
          "| exact's solves CPU (ms) | control variate against exact, draws seeded 0-3 (%) |"
          "\n|---|---|---|---|---|---|---|---|")
    moves_seed, moves_exact, moves_cv = [], [], []
    for label, (step, nuis, rho, blocks), cpu, _calls in captured_systems(args):
        phi = clocks.offset_overdispersion(step, nuis, rho, blocks, draws=args.draws)
        on = np.isfinite(phi)
        if not on.any():
            print(f"| {label} | no offsets or too few blocks |")
            continue

        def move(other, ref=phi, on=on):
            return float(np.max(np.abs(np.sqrt(np.maximum(1.0, other[on]) / np.maximum(1.0, ref[on])) - 1.0)))
        by_seed = max(move(clocks.offset_overdispersion(step, nuis, rho, blocks, draws=args.draws, seed=s))
                      for s in (1, 2, 3))
        moves_seed.append(by_seed)
        cells = ["-", "-", "-"]
        if not args.no_exact:
            exact, exact_cpu = exact_overdispersion(step, nuis, rho, blocks)
            moves_exact.append(move(exact))
            moves_cv.append(max(move(clocks.offset_overdispersion(step, nuis, rho, blocks, draws=args.draws,
                                                                  seed=s), ref=exact) for s in range(4)))
            cells = [f"{100 * moves_exact[-1]:.1f}", f"{1000 * exact_cpu:.0f}", f"{100 * moves_cv[-1]:.1f}"]
        C = int((np.bincount(blocks[blocks >= 0]) > 0).sum())
        print(f"| {label} | {int(on.sum())} | {C} | {1000 * cpu:.0f} | {100 * by_seed:.1f} | "
              + " | ".join(cells) + " |", flush=True)
    if moves_seed:
        print(f"\nlargest move of a sigma over {len(moves_seed)} logs: draws reseeded {100 * max(moves_seed):.1f} %"
              + (f", exact null {100 * max(moves_exact):.1f} %, the control variate's from the exact "
                 f"{100 * max(moves_cv):.1f} %" if moves_exact else "")
              + f" ({args.draws} draws)")
    print(f"load average (1 min) {load0[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2 cores)")


if __name__ == "__main__":
    main()
