"""Per-sensor clock offsets: each tracker PC stamps with its own clock, so each sensor's
observations are late by the shared tracker latency plus an offset of its own (NTP leaves a
tenth of a second between machines). As Kalibr estimates a camera-IMU time offset inside its
batch estimate, each sensor's offset is a nuisance of the factor graph's profile
(:func:`pedcal.calib.factorgraph._estimate_nuisances`), estimated with its sigma and carried
into the sensors' covariance; the shared latency is the association's plus the offsets' mean,
and the offsets are written about it.

An observation stamped t belongs to the instant t - latency - delta_i. Carried to its pose
variable at t_k (FactorGraphProblem.carry_observations) the head's motion from that instant is
added, so an offset delta_i moves the carried point by R_i^T (h(t) - h(t - delta_i)), to second
order delta_i R_i^T v(t - delta_i / 2), v the head's velocity: the offset enters the
observations nearly linearly, like the head point's horizontal shift
(``fac_p_sensor + delta_i R_i^T v`` in :func:`clock_shift_sensor`). Only the robot's
motion tells an offset: a sensor that sees the robot only standing, or only crossing one way
(where the offset is a shift its translation takes), keeps its prior, and its sigma says so.

The profile's sigma assumes the residuals are the noise model's, white. An offset is seen through
the velocity times the time shift, which errors that last a pass of the robot share (AMCL's
wander, a head point the model does not follow), so each offset's sigma is widened by its
overdispersion (:func:`offset_overdispersion`, a cluster-robust, sandwich, estimate over 20 s
blocks of the residuals against the same statistic under the noise model) where that exceeds 1
(:func:`widened_covariance`), in the covariance the sensors' sigma takes its share from. Errors
that move every pass alike (an offset shared by a group of sensors trading with where the group
sits along the robot's path, which only AMCL holds) do not scatter the score and are not caught;
nor are offsets fitted per sensor given the path (above ``clock_offsets_joint_max``), nor, with
a head profile against distance kept (recipe ``head_profile``), the offsets of that reduced
profile, which keeps no residuals.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sps

from pedcal.calib.common import rows_taken
from pedcal.calib.headpoint import CLUSTER_S, MIN_CLUSTERS, time_blocks
from pedcal.calib.keys import symbol_parts, symbols
from pedcal.calib.profile import Nuisance
from pedcal.metrics import CLOCK_OFFSET_KEY, LATENCY_KEY, SIGMA_CLOCK_OFFSET_KEY, SIGMA_LATENCY_KEY

PREFIX = "clock_offset_s:"                        # nuisance names: PREFIX + sensor id
MIN_FACTORS = 20        # a sensor with fewer robot-observation factors keeps the shared latency
STEP_S = 0.01           # finite-difference step of the profile (the offset enters linearly)
# half-width (s) of the central difference that gives the head's velocity: the offsets' regressor.
# Wheel odometry's white increments (a millimetre per 50 ms step) over a 40 ms difference make a
# velocity 7 % off at 0.3 m/s, AMCL's jitter far more, and an offset fitted to a noisy regressor is
# off by more than its sigma says (paper, offsets of +-0.15 s, seeds 0, 3, 4: 37 % of the offsets
# within 1 sigma at 0.02 s, 70 % at 0.25 s, 80 % at 0.5 s; without odometry 7 %, 27 %, 53 %);
# the robot's speed changes over seconds, so a second's difference keeps its shape. Taken from the
# graph's solved poses (solved_velocity_world), 73 % within 1 sigma there; on the L-shaped hall the
# offsets shared by a wing still trade with the wing's place along its axis (README).
VELOCITY_HALF_WINDOW_S = 0.5
# the residuals' time blocks whose scatter of each offset's score widens its sigma
# (:func:`offset_overdispersion`) are headpoint's CLUSTER_S: about one pass of the robot under a
# sensor at its 0.3 m/s, and AMCL's wander's correlation time, so that errors shared within a pass
# count as one.
# The null's white-error draws (signs, :func:`null_draws`): they estimate the projection's share of
# the scatter (the rest is exact, a control variate); reseeded, a widened sigma moved by up to 7.6 %
# on the zoo's seeds 0-1 of five scenarios with Gaussian draws (18 % with the draws' plain mean), and
# on paper, corridor and cross seeds 0-1 by up to 3.2 % with signs, 3.6 % with Gaussian draws
# (benchmarks/bench_clock_overdispersion.py --scenarios paper corridor cross --seeds 2 --no-exact,
# and with --gaussian)
NULL_DRAWS = 32
# the efficient rows (rows x offsets) :func:`block_scores` holds at once: 32 MB
SCORE_CHUNK_ENTRIES = 4_000_000


def is_clock_nuisance(name: str) -> bool:
    return name.startswith(PREFIX)


def clock_nuisances(prob, result=None) -> list[Nuisance]:
    """The per-sensor clock offsets to estimate (recipe ``clock_offsets``, prior 0 +-
    ``clock_offset_sigma_s``), one per sensor with MIN_FACTORS robot-observation factors; each
    starts at 0 on ``prob`` the first time. ``result``: the graph's current solution, whose
    robot poses give the head's velocity from then on (:func:`solved_velocity_world`)."""
    rec = prob.recipe
    if not (rec.robot and rec.clock_offsets and rec.clock_offset_sigma_s > 0.0) or prob.fac_sensor_index is None:
        return []
    counts = np.bincount(prob.fac_sensor_index, minlength=len(prob.sensor_ids))
    out = []
    for i, sid in enumerate(prob.sensor_ids):
        if counts[i] >= MIN_FACTORS:
            name = PREFIX + sid
            if not hasattr(prob, name):
                setattr(prob, name, 0.0)
            out.append(Nuisance(name, 0.0, rec.clock_offset_sigma_s, STEP_S))
    if out and result is not None:
        prob._pose_velocity_world = solved_velocity_world(prob, result)
    return out


def solved_velocity_world(prob, result) -> np.ndarray | None:
    """(n_poses, 3) the head's world velocity at each robot pose from the solved poses: a
    central difference over +-VELOCITY_HALF_WINDOW_S of the graph's x(k), which fuse odometry
    (or AMCL's motion) with what every sensor saw. Without odometry the raw motion is AMCL's
    own, whose wandering error's increments (a few cm/s over a second) the regressor would
    carry; the solved path is the better measure of it. None without poses."""
    from pedcal.calib.graph import pose_arrays  # (the graph module imports this one)

    t = prob.pose_times
    keys = np.asarray(result.keys(), np.uint64)
    n = int(np.count_nonzero(symbol_parts(keys)[0] == np.uint64(ord("x"))))
    if n < 2:
        return None
    x = pose_arrays(result, symbols("x", range(n)))[1]
    t = t[:n]
    lo = np.clip(np.searchsorted(t, t - VELOCITY_HALF_WINDOW_S), 0, n - 1)
    hi = np.clip(np.searchsorted(t, t + VELOCITY_HALF_WINDOW_S), 0, n - 1)
    dt = t[hi] - t[lo]
    v = (x[hi] - x[lo]) / np.maximum(dt, 1e-9)[:, None]
    v[dt <= 0.0] = 0.0
    return v


def _velocity_world_at(prob, t: np.ndarray) -> np.ndarray:
    """(n, 3) the head's world velocity at times ``t``: the solved poses' central difference
    (:func:`solved_velocity_world`) taken linearly between the poses, or, before any solve, the
    robot's motion's over +-VELOCITY_HALF_WINDOW_S."""
    pose_v = getattr(prob, "_pose_velocity_world", None)
    if pose_v is None or len(pose_v) < 2:
        return prob.motion.velocity(t, h=VELOCITY_HALF_WINDOW_S)
    tp = prob.pose_times[:len(pose_v)]
    return np.column_stack([np.interp(t, tp, pose_v[:, c]) for c in range(3)])


def _sensor_rotations(prob) -> np.ndarray:
    """(n_factors, 3, 3) each robot-observation factor's sensor rotation R_world_sensor (the
    sensors' initial ones: a degree off changes a millimetre-sized term by a few per cent);
    cached on the problem until its factors change."""
    cached = getattr(prob, "_clock_rotations", None)
    # the cache holds the array it was made from, so an identity test cannot meet a new array
    # that took a freed one's id (ids are reused once an object is gone)
    if cached is not None and cached[0] is prob.fac_sensor_index:
        return cached[1]
    R = np.stack([prob.init_sensors[sid].rotation().matrix() for sid in prob.sensor_ids])[prob.fac_sensor_index]
    prob._clock_rotations = (prob.fac_sensor_index, R)
    return R


def clock_offsets(prob, theta: dict) -> np.ndarray:
    """(n_sensors,) each sensor's clock offset (s), ``theta``'s by name where it has one, else the
    problem's (0 where it has none): read from the problem's own attributes in one pass, the
    profile asks at every evaluation of the observation block."""
    own, theta = vars(prob), theta or {}
    return np.array([theta.get(n, own.get(n, 0.0)) for n in (PREFIX + sid for sid in prob.sensor_ids)], float)


def clock_shift_sensor(prob, theta: dict, use: np.ndarray) -> np.ndarray | float:
    """What the sensors' clock offsets add to the robot-observation factors ``use`` (sensor
    frame, m): the head's motion over the offset, R_i^T (h(t) - h(t - delta_i)), t the factor's
    pose time (its observations carried there with the shared latency; module docstring), to
    second order delta_i R_i^T v(t - delta_i / 2): the velocity at the middle of the interval,
    not at its end (at its end the shift is off by a delta^2 / 2, a few millimetres for a tenth
    of a second on a turn, which the offsets of the sensors that see the turns absorb: a bias
    of several of their sigma). ``theta`` overrides the problem's offsets by name. 0 when no
    offset is estimated."""
    offsets = clock_offsets(prob, theta)
    if not np.any(offsets != 0.0):     # (a NaN counts as set)
        return 0.0
    # (the last answer kept: a profile's finite differences move its other nuisances, and ask again
    # with the same offsets, factors and velocities)
    use = np.asarray(use)
    inputs = (prob.fac_sensor_index, prob.fac_key_index, prob.pose_times, prob.motion,
              getattr(prob, "_pose_velocity_world", None))
    hit = prob.__dict__.get("_clock_shift_last")
    if (hit is not None and all(a is b for a, b in zip(hit[0], inputs, strict=True))
            and np.array_equal(hit[1], offsets) and np.array_equal(hit[2], use)):
        return hit[3]
    # (every factor, the usual ask: the tables read as they are, not gathered)
    rows = rows_taken(use, len(prob.fac_sensor_index))
    delta = offsets[prob.fac_sensor_index[rows]]
    v_world = _velocity_world_at(prob, prob.pose_times[prob.fac_key_index[rows]] - 0.5 * delta)
    shift = delta[:, None] * np.einsum("nji,nj->ni", _sensor_rotations(prob)[rows], v_world)
    shift.setflags(write=False)       # (handed out again: no caller may write into it)
    prob.__dict__["_clock_shift_last"] = (inputs, offsets, use.copy(), shift)
    return shift


def null_draws(rows: int, draws: int, seed: int) -> np.ndarray:
    """(rows, draws) the null's white errors: independent signs +-1 (Rademacher), seeded. Any e
    with E e e^T = I gives E e^T K e = tr K, which is all the null asks of them (its V(H e) and
    V(e - H e) are such quadratic forms); signs estimate it with less variance than Gaussian
    draws, 2 (tr K^2 - sum_i K_ii^2) against 2 tr K^2 per draw (Hutchinson's trace estimator),
    and are drawn from random bytes, a bit each: 2 against 14 ms for 45 000 rows x 32 draws."""
    bits = np.unpackbits(np.frombuffer(np.random.default_rng(seed).bytes(-(-rows * draws // 8)), np.uint8))
    return bits[:rows * draws].reshape(rows, draws) * 2.0 - 1.0


def offset_overdispersion(step, nuis: list[Nuisance], rho: np.ndarray, clusters: np.ndarray,
                          draws: int = NULL_DRAWS, seed: int = 0) -> np.ndarray:
    """(k,) each clock offset's overdispersion phi_j (NaN for the other nuisances, and where there
    are too few time blocks): how much the residuals ``rho`` (the profile's, at the estimate)
    scatter the offset's score over the residuals' time blocks ``clusters``
    (:func:`row_blocks`, -1: left out) against how much they would if
    the noise model held. The offset's efficient rows m = M_j - M_o H_oo^-1 H_oj (M = A Z - B the
    profile residual's change with the nuisances, H the profile Hessian with the priors, o the
    other nuisances: they are profiled out too); the scatter V(rho) = C / (C - 1) sum_c
    (U_c - mean U)^2, U_c = sum over block c of m_i rho_i (the cluster-robust, sandwich, variance
    of the score; :func:`pedcal.calib.headpoint.overdispersion` is V / sum m_i^2). Under the model
    the residuals are r = (I - A N^-1 A^T) e, e white with unit variance, N = A^T A: the variables
    (each block's robot poses, AMCL's error nodes) take up part of each block's errors, so V(r)
    is below sum m_i^2: its expectation tr(Q P) (V(x) = x^T Q x, P = I - H, H = A N^-1 A^T a
    projection) is tr(Q) - tr(Q H), where tr(Q) = sum over the blocks' rows of m_i^2 exactly and
    only the projection's share E V(H e) is taken over ``draws`` seeded draws (``seed``;
    :func:`null_draws`; a fresh factorization of N when the step kept none), a control variate at
    the plain mean's cost whose Monte-Carlo noise is the share's alone:

        phi_j = V(rho) / (sum_i m_i^2 - mean_d V(H e_d)),

    or, where the draws put that share at or above the whole (the variables take up nearly all of
    each block's errors), against the plain mean of V(e_d - H e_d) over the same draws.

    1 when the model holds; more when errors that last a block move the offset more than white
    residuals would (AMCL's wander, a head point whose shift toward the sensor changes with
    distance where the model keeps it constant: an offset is seen through the robot's velocity
    times the time shift, which such errors share within a pass)."""
    out = np.full(len(nuis), np.nan)
    weights = efficient_weights(step, nuis, clusters)
    if weights is None:
        return out
    solve = step.__dict__.get("_normal_solve")
    if solve is None:
        from pedcal.calib.profile import _normal_solver
        solve = _normal_solver(step.A, step.order)
    # X = [rho, H e_1 .. H e_draws], H e_d = A N^-1 A^T e_d
    e = null_draws(len(rho), draws, seed)
    X = np.empty((len(rho), draws + 1))
    X[:, 0] = rho
    X[:, 1:] = step.A @ solve(np.asarray(step.A.T @ e))
    U, m2 = block_scores(step, weights, X)
    idx, C = weights[0], weights[3]
    U_he = U[:, :, 1:]

    def scatter(u):        # V per offset and column: C / (C - 1) sum_b (U_b - mean U)^2
        return np.sum((u - u.mean(axis=1, keepdims=True)) ** 2, axis=1) * C / (C - 1)

    null = m2 - scatter(U_he).mean(axis=1)
    if not np.all(null > 0.0):
        # (the draws' own scores only where the plain mean is needed: half the scores' cost spared)
        U_e = block_scores(step, weights, e)[0]
        null = np.where(null > 0.0, null, scatter(U_e - U_he).mean(axis=1))
    out[idx] = scatter(U[:, :, :1])[:, 0] / null
    return out


def efficient_weights(step, nuis: list[Nuisance], clusters: np.ndarray):
    """(the clock offsets' indices j among ``nuis``, W, each row's block 0..C-1 (-1: left out), C): W's
    column c = e_j - (0; H_oo^-1 H_oj), offset c's efficient rows m = M W (M = A Z - B; the other
    nuisances profiled out with the step's Hessian); the blocks those of ``clusters`` present,
    numbered in their labels' order (a count, not a sort; -1: left out). None without clock
    offsets or with fewer than MIN_CLUSTERS blocks."""
    H = np.asarray(step.hessian, float)
    idx = [j for j, nu in enumerate(nuis) if is_clock_nuisance(nu.name)]
    kept = clusters >= 0
    present = np.bincount(clusters[kept]) > 0 if kept.any() else np.zeros(0, bool)
    C = int(present.sum())
    if not idx or C < MIN_CLUSTERS:
        return None
    block = np.full(len(clusters), -1)
    block[kept] = (np.cumsum(present) - 1)[clusters[kept]]
    # e_j - (0; H_oo^-1 H_oj) is H^-1's column j over its diagonal entry (the Schur complement's
    # identity): one inverse for every offset, not a solve each
    H_inv = np.linalg.inv(H)
    W = H_inv[:, idx] / np.diag(H_inv)[idx]
    return idx, W, block, C


def block_scores(step, weights, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(U (k, C, d), m2 (k,)): U[c, b, :] = sum over block b of m_ic X_i, each clock offset's
    score of the residual columns ``X`` (rows, d) summed over each time block, ``weights`` those
    of :func:`efficient_weights`, and m2[c] = sum over the blocks' rows of m_ic^2. One block's
    efficient rows at a time (m_b = A_b Z W - B_b W): the rows x offsets matrix m whole would be
    the widening's largest memory, hundreds of MB at 200 sensors."""
    idx, W, block, C = weights
    A, B = sps.csr_matrix(step.A), sps.csr_matrix(step.B)
    ZW = step.Z @ W
    order = np.argsort(block, kind="stable")
    bounds = np.searchsorted(block[order], np.arange(-1, C) + 0.5)   # (block -1 first, left out)
    X = np.asarray(X, float).reshape(len(block), -1)
    U = np.empty((len(idx), C, X.shape[1]))
    m2 = np.zeros(len(idx))
    # the blocks' efficient rows taken a run of consecutive blocks at a time, up to
    # SCORE_CHUNK_ENTRIES of m (a product per block cost more in its own overhead than in
    # arithmetic on a few thousand rows; each row's value is the same however they are taken)
    runs, lo_block = [], 0
    while lo_block < C:
        hi_block = lo_block + 1
        while hi_block < C and (bounds[hi_block + 1] - bounds[lo_block]) * len(idx) <= SCORE_CHUNK_ENTRIES:
            hi_block += 1
        runs.append((lo_block, hi_block))
        lo_block = hi_block
    for lo_block, hi_block in runs:
        rows = order[bounds[lo_block]:bounds[hi_block]]
        if len(runs) == 1:      # (all rows' products, then picked: no copy of A's rows)
            m = (np.asarray(A @ ZW) - np.asarray(B @ W))[rows]
        else:
            m = np.asarray(A[rows] @ ZW) - np.asarray(B[rows] @ W)
        X_run = X[rows]
        for b in range(lo_block, hi_block):
            lo, hi = bounds[b] - bounds[lo_block], bounds[b + 1] - bounds[lo_block]
            U[:, b, :] = m[lo:hi].T @ X_run[lo:hi]
            m2 += np.einsum("ic,ic->c", m[lo:hi], m[lo:hi])
    return U, m2


def widened_covariance(cov: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The nuisances' covariance ``cov`` with each clock offset's rows and columns scaled by
    sqrt(max(1, phi_j)) (:func:`offset_overdispersion`; NaN: 1): D cov D, so each offset's
    variance is the model's times its overdispersion where that exceeds 1, never narrowed, and its
    correlations kept (its share of the sensors' covariance, through their sensitivity, widened
    alike)."""
    d = np.sqrt(np.maximum(1.0, np.nan_to_num(np.asarray(phi, float), nan=1.0)))
    return np.asarray(cov, float) * np.outer(d, d)


def row_blocks(step, pose_times: np.ndarray, node_times: np.ndarray | None, cluster_s: float = CLUSTER_S,
               ) -> np.ndarray:
    """(rows,) the time block of every row of the profile step's system, from the variables the
    row holds (A's sparsity, no walk over the factors): a robot pose x(k) is in block
    floor(t_k / ``cluster_s``) counted from the earliest pose's or node's (:func:`time_blocks`:
    stamps since the epoch would make the blocks' count, and the arrays
    :func:`efficient_weights` sizes by it, ~10^8), an AMCL error
    node a(j) in its time's, a person l(m) in a block of its own after them; a row takes the
    latest block among its variables', -1 when it holds none of these (the sensors' priors, the
    head offset's)."""
    t_nodes = np.zeros(0) if node_times is None else np.asarray(node_times, float)
    pose_times = np.asarray(pose_times, float)
    every_block, n_blocks = time_blocks(np.concatenate([pose_times, t_nodes]), cluster_s)
    time_block = {"x": every_block[:len(pose_times)], "a": every_block[len(pose_times):]}
    cols = step.cols
    # each variable's block from its key (GTSAM's Symbol: its character and its index)
    keys, starts, dims = cols._table()
    char, index = (part.astype(np.int64) for part in symbol_parts(keys))
    block = np.full(len(char), -1, np.int64)
    for c, times in (("x", pose_times), ("a", t_nodes)):
        mine = (char == ord(c)) & (index < len(times))
        block[mine] = time_block[c][index[mine]]
    person = char == ord("l")
    block[person] = n_blocks + index[person]
    # spread over each variable's columns
    label = np.full(cols.n, -1, np.int64)
    label[np.repeat(starts - (np.cumsum(dims) - dims), dims) + np.arange(int(dims.sum()))] = np.repeat(block, dims)
    A = sps.csr_matrix(step.A)
    entries = label[A.indices]
    out = np.full(A.shape[0], -1, np.int64)
    filled = np.diff(A.indptr) > 0
    if entries.size:
        out[filled] = np.maximum.reduceat(entries, A.indptr[:-1][filled])
    return out


def widen_for_overdispersion(reference, nuis: list[Nuisance], theta: np.ndarray, cov: np.ndarray,
                             pose_times: np.ndarray, node_times: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The profile's covariance ``cov`` of ``nuis`` (now at ``theta``) with the clock offsets
    widened by their overdispersion (:func:`widened_covariance`), and the phi_j. ``reference``:
    (the last full profile step, which kept its system, the nuisances' values it was taken at);
    the residuals at ``theta`` are its rho0 + M (theta - those values), exact for the linearized
    profile; their time blocks (:func:`row_blocks`) from the robot poses' times ``pose_times``
    and AMCL's error nodes' ``node_times``. Unchanged (phi NaN) without a reference, its system,
    or clock offsets."""
    phi = np.full(len(nuis), np.nan)
    if reference is None or not any(is_clock_nuisance(nu.name) for nu in nuis):
        return cov, phi
    step, theta_ref = reference
    if step.rho0 is None or step.A is None or step.B is None or step.B.shape[1] != len(nuis):
        return cov, phi
    d_theta = np.asarray(theta, float) - np.asarray(theta_ref, float)
    rho = step.rho0 + np.asarray(step.A @ (step.Z @ d_theta)) - step.B @ d_theta
    phi = offset_overdispersion(step, nuis, rho, row_blocks(step, pose_times, node_times))
    return widened_covariance(cov, phi), phi


def centered_offsets(delta_s: np.ndarray, cov_s2: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The offsets ``delta_s`` (n,) with covariance ``cov_s2`` (n, n) split into their mean, the
    shared latency's correction, and each offset about it, so that the latency and the offsets
    do not count the same time twice: (mean, its sigma, delta - mean, the sigma of each
    delta_i - mean). With c_i = e_i - 1/n (e_i the i-th unit vector), var(delta_i - mean) =
    c_i^T C c_i, and var(mean) = 1^T C 1 / n^2: offsets that move together (a latency error they
    share) leave the centred ones sure and the mean unsure, not each offset unsure."""
    delta_s = np.asarray(delta_s, float)
    cov_s2 = np.asarray(cov_s2, float)
    mean = float(delta_s.mean())
    total = float(cov_s2.mean())                     # 1^T C 1 / n^2
    sigma_mean = float(np.sqrt(max(total, 0.0)))
    # c_i^T C c_i = C_ii - 2 (C 1)_i / n + 1^T C 1 / n^2, in O(n^2)
    sigma = np.sqrt(np.maximum(np.diag(cov_s2) - 2.0 * cov_s2.mean(axis=1) + total, 0.0))
    return mean, sigma_mean, delta_s - mean, sigma


def record_clocks(network, prob, shifts) -> None:
    """Write the estimated clock offsets to the calibrated network: the shared latency becomes
    the association's plus the offsets' mean, with that mean's sigma, and each sensor's offset
    is taken about it, with the sigma of its departure from the mean
    (:func:`centered_offsets`, from the profile's covariance, each offset's widened by its
    overdispersion; ``shifts``: the profile's result). Offsets whose sigma was fitted per
    sensor given the robot's path (above the recipe's ``clock_offsets_joint_max``) are logged as
    such: that sigma leaves out the path's share."""
    if shifts is None:
        return
    idx = [j for j, n in enumerate(shifts.names) if is_clock_nuisance(n)]
    if not idx:
        return
    ids = [shifts.names[j][len(PREFIX):] for j in idx]
    if getattr(shifts, "local", None) is not None:
        logging.getLogger(__name__).warning(
            f"{len(ids)} sensors' clock offsets (more than clock_offsets_joint_max = "
            f"{prob.recipe.clock_offsets_joint_max}): each offset's sigma (and its share of its sensor's "
            "covariance) is its own profile's given the robot's path; their coupling through the path is "
            "left out, so those sigmas are lower bounds"
            + (" (so are those of the sensors' own head shift departures, fitted alike)"
               if getattr(prob.recipe, "head_shift_per_sensor_sigma_m", 0.0) > 0.0 else ""))
    delta = np.array([getattr(prob, shifts.names[j]) for j in idx])
    mean, sigma_mean, centred, sigma = centered_offsets(delta, np.asarray(shifts.cov)[np.ix_(idx, idx)])
    network.extra[LATENCY_KEY] = round(prob.latency_s + mean, 4)
    network.extra[SIGMA_LATENCY_KEY] = round(sigma_mean, 4)
    network.extra[CLOCK_OFFSET_KEY] = {sid: round(float(d), 4) for sid, d in zip(ids, centred, strict=True)}
    network.extra[SIGMA_CLOCK_OFFSET_KEY] = {sid: round(float(s), 4) for sid, s in zip(ids, sigma, strict=True)}


__all__ = ["clock_nuisances", "clock_offsets", "clock_shift_sensor", "record_clocks", "is_clock_nuisance",
           "centered_offsets", "null_draws", "offset_overdispersion", "efficient_weights", "block_scores",
           "widened_covariance", "widen_for_overdispersion", "row_blocks"]
