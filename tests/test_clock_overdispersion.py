"""The clock offsets' sigma widened by their overdispersion: how much the residuals scatter each
offset's score over time blocks beyond what the noise model says (pedcal.calib.clocks)."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sps

import pedcal.calib.factorgraph as fgmod
from pedcal.calib import calibrate
from pedcal.calib.clocks import (
    PREFIX,
    block_scores,
    centered_offsets,
    efficient_weights,
    null_draws,
    offset_overdispersion,
    row_blocks,
    widen_for_overdispersion,
    widened_covariance,
)
from pedcal.calib.keys import A, L, S, X
from pedcal.calib.profile import Columns, Nuisance
from pedcal.metrics import SIGMA_CLOCK_OFFSET_KEY
from pedcal.sim import simulate_logs


def _nuisances():
    return [Nuisance("ray_shift_m", 0.0, 0.05, 0.01), Nuisance(PREFIX + "s1", 0.0, 0.15, 0.01),
            Nuisance(PREFIX + "s2", 0.0, 0.15, 0.01)]


def _step(rng, rows=240, n=4):
    """A profile step of 3 nuisances over ``n`` variables: A, Z, B and the Hessian M^T M plus the priors."""
    A = sps.csr_matrix(rng.normal(size=(rows, n)) * (rng.random((rows, n)) < 0.5))
    Z = rng.normal(size=(n, 3))
    B = sps.csc_matrix(rng.normal(size=(rows, 3)) * (rng.random((rows, 3)) < 0.6))
    M = A @ Z - B.toarray()
    H = M.T @ M + np.diag([1 / 0.05 ** 2, 1 / 0.15 ** 2, 1 / 0.15 ** 2])
    return SimpleNamespace(A=A, Z=Z, B=B, hessian=H, order=None), M


def _scatter(x, clusters, C):
    U = np.array([np.sum(x[clusters == c]) for c in range(C)])
    return C / (C - 1) * np.sum((U - U.mean()) ** 2)


def test_the_overdispersion_is_the_scores_block_scatter_over_its_scatter_under_the_noise_model():
    rng = np.random.default_rng(7)
    step, M = _step(rng)
    rho = rng.normal(size=M.shape[0]) * 1.5
    clusters = np.repeat(np.arange(12), 20)
    clusters[:8] = -1                          # (the priors' rows: left out of the blocks)
    phi = offset_overdispersion(step, _nuisances(), rho, clusters, draws=16, seed=3)
    assert np.isnan(phi[0])                    # not a clock offset
    H = step.hessian
    A = step.A.toarray()
    # the null: white unit errors e under the model, the variables fitted, leave (I - H) e,
    # H = A N^-1 A^T; E V((I - H) e) = sum of m^2 over the blocks' rows - E V(H e), the second
    # term over the draws
    e = null_draws(M.shape[0], 16, 3)
    he = A @ np.linalg.solve(A.T @ A, A.T @ e)
    kept = clusters >= 0
    for j in (1, 2):
        o = [i for i in range(3) if i != j]
        m = M[:, j] - M[:, o] @ np.linalg.solve(H[np.ix_(o, o)], H[o, j])
        null = np.sum(m[kept] ** 2) - np.mean([_scatter(m * he[:, d], clusters, 12) for d in range(16)])
        assert null > 0.0
        assert phi[j] == pytest.approx(_scatter(m * rho, clusters, 12) / null, rel=1e-9)
    # too few blocks (fewer than 8): no estimate, no widening
    assert np.all(np.isnan(offset_overdispersion(step, _nuisances(), rho, np.repeat(np.arange(6), 40))))


@pytest.mark.parametrize("rows, draws", [(45, 7), (240, 8), (1, 1)])
def test_the_null_draws_are_seeded_signs_of_every_shape(rows, draws):
    # (rows x draws not a multiple of 8 too: the bytes' last bits are left unused)
    e = null_draws(rows, draws, 5)
    assert e.shape == (rows, draws) and e.dtype == np.float64
    assert set(np.unique(e)) <= {-1.0, 1.0}
    np.testing.assert_array_equal(e, null_draws(rows, draws, 5))
    if rows * draws > 100:
        assert not np.array_equal(e, null_draws(rows, draws, 6))


def test_the_null_draws_estimate_a_quadratic_forms_trace_without_bias_and_with_less_variance_than_gaussians():
    # E e^T K e = tr K for signs; their variance 2 (tr K^2 - sum K_ii^2), a Gaussian's 2 tr K^2
    rng = np.random.default_rng(4)
    G = rng.normal(size=(30, 30))
    K = G @ G.T + np.diag(rng.uniform(1.0, 5.0, 30))
    e = null_draws(30, 20000, 1)
    q = np.einsum("id,ij,jd->d", e, K, e)
    want_var = 2.0 * (np.sum(K ** 2) - np.sum(np.diag(K) ** 2))
    assert q.mean() == pytest.approx(np.trace(K), abs=4.0 * np.sqrt(want_var / q.size))
    assert q.var() == pytest.approx(want_var, rel=0.05)


def test_the_null_draws_vary_less_than_gaussians_on_the_solves_quadratic_form():
    # the form the null's draws estimate, V(H e) = e^T K e, K = H Q H (H = A (A^T A)^-1 A^T the
    # fitted part, Q = C / (C - 1) M^T G M the block scores' scatter, M each block's sums of m, G
    # the centring): signs' variance 2 (tr K^2 - sum K_ii^2) is 1 - sum K_ii^2 / tr K^2 = 0.913
    # of Gaussians' 2 tr K^2 here, and 100 000 signs measure theirs to ~0.5 %
    rng = np.random.default_rng(7)
    rows, C = 60, 10
    A = rng.normal(size=(rows, 6))
    H = A @ np.linalg.solve(A.T @ A, A.T)
    M = np.zeros((C, rows))
    M[np.repeat(np.arange(C), rows // C), np.arange(rows)] = rng.normal(size=rows)
    Q = C / (C - 1) * M.T @ (np.eye(C) - 1.0 / C) @ M
    K = H @ Q @ H
    assert 1.0 - np.sum(np.diag(K) ** 2) / np.sum(K ** 2) == pytest.approx(0.913, abs=1e-3)
    e = null_draws(rows, 100_000, 0)
    q = ((K @ e) * e).sum(0)
    assert q.var() == pytest.approx(2.0 * (np.sum(K ** 2) - np.sum(np.diag(K) ** 2)), rel=0.03)


def test_where_the_draws_put_the_projections_share_above_the_whole_the_plain_mean_is_the_null():
    # nearly as many variables as rows: they take up nearly all of each block's errors, and
    # the draws' estimate of the projection's share can exceed the exact whole
    rng = np.random.default_rng(11)
    rows, n = 240, 228
    A = sps.csr_matrix(rng.normal(size=(rows, n)))
    Z = rng.normal(size=(n, 3)) * 0.1
    B = sps.csc_matrix(rng.normal(size=(rows, 3)))
    M = A @ Z - B.toarray()
    H = M.T @ M + np.diag([1 / 0.05 ** 2, 1 / 0.15 ** 2, 1 / 0.15 ** 2])
    step = SimpleNamespace(A=A, Z=Z, B=B, hessian=H, order=None)
    clusters = np.repeat(np.arange(12), 20)
    rho = rng.normal(size=rows)
    Ad = A.toarray()
    o = [0, 2]
    m = M[:, 1] - M[:, o] @ np.linalg.solve(H[np.ix_(o, o)], H[o, 1])
    for seed in range(50):
        e = null_draws(rows, 8, seed)
        he = Ad @ np.linalg.solve(Ad.T @ Ad, Ad.T @ e)
        if np.sum(m ** 2) - np.mean([_scatter(m * he[:, d], clusters, 12) for d in range(8)]) <= 0.0:
            break
    else:
        pytest.fail("no draw put the projection's share above the whole")
    plain = np.mean([_scatter(m * (e[:, d] - he[:, d]), clusters, 12) for d in range(8)])
    phi = offset_overdispersion(step, _nuisances(), rho, clusters, draws=8, seed=seed)
    assert phi[1] == pytest.approx(_scatter(m * rho, clusters, 12) / plain, rel=1e-9)


def test_the_overdispersion_is_1_on_white_residuals_when_the_variables_take_up_part_of_each_block():
    # one variable per pair of blocks (a mean each pair's rows share) and an offset seen through a
    # ramp in time: the variables take up part of each block's score, which the null must remove
    # (with the projection's share left out of the null, phi reads ~0.7)
    rng = np.random.default_rng(3)
    blocks, per = 400, 10
    rows = blocks * per
    clusters = np.repeat(np.arange(blocks), per)
    t = np.arange(rows) / per
    A = sps.csr_matrix((np.ones(rows), (np.arange(rows), clusters // 2)), shape=(rows, blocks // 2))
    N = (A.T @ A).toarray()
    B = -t[:, None]
    Z = np.linalg.solve(N, A.T @ B)
    M = A @ Z - B
    step = SimpleNamespace(A=A, Z=Z, B=sps.csc_matrix(B), hessian=M.T @ M + 1.0, order=None)
    e = rng.normal(size=rows)
    rho = e - A @ np.linalg.solve(N, A.T @ e)          # white errors, the variables fitted
    phi = offset_overdispersion(step, [Nuisance(PREFIX + "s1", 0.0, 1.0, 0.01)], rho, clusters)[0]
    assert phi == pytest.approx(1.0, rel=0.2)


@pytest.mark.parametrize("shared, want", [(0.0, 1.0), (1.0, 11.0)])
def test_the_overdispersion_is_1_on_white_residuals_and_1_plus_n_s2_on_errors_a_block_shares(shared, want):
    # one offset alone (M its column), blocks of 10 rows each m = 1, one variable that takes up
    # a mean: residuals white with unit variance give phi ~ 1; an error of variance s^2 shared by
    # each block adds n s^2 = 10
    rng = np.random.default_rng(3)
    blocks, per = 400, 10
    rows = blocks * per
    A = sps.csr_matrix(np.ones((rows, 1)))
    step = SimpleNamespace(A=A, Z=np.zeros((1, 1)), B=sps.csc_matrix(-np.ones((rows, 1))),
                           hessian=np.array([[rows + 1.0]]), order=None)
    clusters = np.repeat(np.arange(blocks), per)
    rho = rng.normal(size=rows) + shared * rng.normal(size=blocks)[clusters]
    phi = offset_overdispersion(step, [Nuisance(PREFIX + "s1", 0.0, 1.0, 0.01)], rho, clusters)[0]
    # (the estimate's relative sd: sqrt(2 / blocks) ~ 7 %, the null's over 32 draws ~ 1 %)
    assert phi == pytest.approx(want, rel=0.2)


def test_the_widened_covariance_scales_each_offset_by_the_root_of_its_overdispersion_and_never_narrows():
    cov = np.array([[4.0, 1.0, 0.5], [1.0, 9.0, 2.0], [0.5, 2.0, 16.0]])
    out = widened_covariance(cov, np.array([np.nan, 4.0, 0.25]))
    d = np.array([1.0, 2.0, 1.0])              # NaN: 1; 4: its root; 0.25 < 1: not narrowed
    np.testing.assert_array_equal(out, cov * np.outer(d, d))
    assert out[1, 1] == 4.0 * cov[1, 1] and out[1, 2] / np.sqrt(out[1, 1] * out[2, 2]) == pytest.approx(
        cov[1, 2] / np.sqrt(cov[1, 1] * cov[2, 2]))
    # nothing to widen without the reference step or without offsets
    same, phi = widen_for_overdispersion(None, _nuisances(), np.zeros(3), cov, np.zeros(0), None)
    assert same is cov and np.all(np.isnan(phi))


@pytest.fixture(scope="module")
def overdispersed():
    """A log whose offsets' scores scatter over the time blocks beyond the model's (paper seed 9,
    the zoo's draw: no odometry, relocalizations, per-sensor head points and clock skews),
    calibrated with the nuisances' covariance captured before and after the widening."""
    sim = simulate_logs("paper", seed=9, vary_nuisances="zoo")
    seen = {}
    original = fgmod.widen_for_overdispersion

    def spy(reference, nuis, theta, cov, pose_times, node_times):
        out, phi = original(reference, nuis, theta, cov, pose_times, node_times)
        seen.update(names=[n.name for n in nuis], cov=cov, widened=out, phi=phi)
        return out, phi
    mp = pytest.MonkeyPatch()
    mp.setattr(fgmod, "widen_for_overdispersion", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(sim.calib, method="factorgraph")
    mp.undo()
    return sim, res, seen


def test_the_written_sigma_is_the_centred_one_of_the_widened_covariance(overdispersed):
    sim, res, seen = overdispersed
    idx = [j for j, n in enumerate(seen["names"]) if n.startswith(PREFIX)]
    phi = seen["phi"][idx]
    assert np.all(np.isfinite(phi)) and np.any(phi > 1.5)      # (here 1.8-3: the widening acts)
    delta = np.zeros(len(idx))
    *_, sigma_widened = centered_offsets(delta, seen["widened"][np.ix_(idx, idx)])
    *_, sigma_model = centered_offsets(delta, seen["cov"][np.ix_(idx, idx)])
    ids = [seen["names"][j][len(PREFIX):] for j in idx]
    written = res.network.extra[SIGMA_CLOCK_OFFSET_KEY]
    assert written == {sid: round(float(s), 4) for sid, s in zip(ids, sigma_widened, strict=True)}
    # each offset's own variance is the model's times max(1, phi)
    np.testing.assert_allclose(np.diag(seen["widened"])[idx], np.diag(seen["cov"])[idx] * np.maximum(1.0, phi))
    assert np.all(sigma_widened >= sigma_model - 1e-12) and np.any(sigma_widened > 1.2 * sigma_model)


def test_each_row_falls_in_the_time_block_of_the_latest_pose_or_amcl_node_it_holds():
    # variables: s0 (6), x0 x1 x2 (6 each, at 5, 25, 41 s), a0 a1 (6 each, at 0 and 40 s), l0 (3)
    keys = [S(0), X(0), X(1), X(2), A(0), A(1), L(0)]
    dims = [6, 6, 6, 6, 6, 6, 3]
    offset = dict(zip(keys, np.cumsum([0] + dims[:-1]).tolist(), strict=True))
    cols = Columns(keys=keys, offset=offset, dim=dict(zip(keys, dims, strict=True)), n=sum(dims))
    rows = [[S(0)], [S(0), X(0)], [X(0), X(1)], [A(0), X(2)], [A(0)], [A(0), A(1)], [S(0), L(0)], []]
    A_ = np.zeros((len(rows), cols.n))
    for i, held in enumerate(rows):
        for key in held:
            A_[i, offset[key]] = 1.0
    step = SimpleNamespace(cols=cols, A=sps.csr_matrix(A_))
    blocks = row_blocks(step, np.array([5.0, 25.0, 41.0]), np.array([0.0, 40.0]), cluster_s=20.0)
    # 3 blocks of 20 s (0-60 s): a person's rows come after them, as block 3 + its index
    np.testing.assert_array_equal(blocks, [-1, 0, 1, 2, 0, 2, 3, -1])
    # stamps since the epoch (a ROS bag's; 1.7e9 s is 85 million blocks of 20 s): the blocks are
    # counted from the log's first, the same numbers, not labels of ~10^8 that the offsets'
    # overdispersion would size its arrays by
    epoch = 1_700_000_000.0
    at_epoch = row_blocks(step, epoch + np.array([5.0, 25.0, 41.0]), epoch + np.array([0.0, 40.0]), cluster_s=20.0)
    np.testing.assert_array_equal(at_epoch, blocks)
    # a log starting within its first block's span counts from that block: 25 s later, the
    # first pose (30 s) in block 1 of the epoch-aligned grid, numbered 0
    later = row_blocks(step, np.array([30.0, 50.0, 66.0]), np.array([25.0, 65.0]), cluster_s=20.0)
    np.testing.assert_array_equal(later, [-1, 0, 1, 2, 0, 2, 3, -1])
    # an AMCL node earlier than every pose sets the first block: poses in blocks 2, 3, 4 of the
    # grid, the node at 10 s in block 0
    node_first = row_blocks(step, np.array([45.0, 65.0, 81.0]), np.array([10.0, 80.0]), cluster_s=20.0)
    np.testing.assert_array_equal(node_first, [-1, 2, 3, 4, 0, 4, 5, -1])


def test_the_row_blocks_follow_the_columns_offsets_not_the_keys_order_and_skip_poses_without_a_time():
    # the columns laid out in an order of their own: l2 (3) first, then x1, s0, x0, x5 (6 each);
    # x5 has no time (only 2 pose times), l2 is person 2: block n_blocks + 2
    keys = [S(0), X(0), X(1), X(5), L(2)]
    offset = {L(2): 0, X(1): 3, S(0): 9, X(0): 15, X(5): 21}
    dims = {S(0): 6, X(0): 6, X(1): 6, X(5): 6, L(2): 3}
    cols = Columns(keys=keys, offset=offset, dim=dims, n=27)
    rows = [[X(1)], [S(0), X(0)], [X(5)], [S(0), L(2)], [X(0), X(1)], [S(0)]]
    A_ = np.zeros((len(rows), cols.n))
    for i, held in enumerate(rows):
        for key in held:
            A_[i, offset[key] + dims[key] - 1] = 1.0        # (each variable's last column)
    step = SimpleNamespace(cols=cols, A=sps.csr_matrix(A_))
    blocks = row_blocks(step, np.array([3.0, 47.0]), None, cluster_s=10.0)
    # 5 blocks of 10 s (0-50 s): x0 in 0, x1 in 4, x5 none, l2 in 5 + 2
    np.testing.assert_array_equal(blocks, [4, 0, -1, 7, 4, -1])


def test_the_blocks_are_numbered_by_their_labels_whatever_the_gaps_between_them():
    # the same rows in blocks labelled 0..11 or with gaps (a person's label far above the poses'):
    # the same overdispersion, bit for bit
    rng = np.random.default_rng(11)
    step, M = _step(rng)
    rho = rng.normal(size=M.shape[0])
    clusters = np.repeat(np.arange(12), 20)
    clusters[[0, 5, 100]] = -1
    gapped = np.where(clusters >= 0, 3 * clusters + 7 + 1000 * (clusters == 11), -1)
    phi = offset_overdispersion(step, _nuisances(), rho, clusters, draws=8, seed=2)
    np.testing.assert_array_equal(offset_overdispersion(step, _nuisances(), rho, gapped, draws=8, seed=2), phi)
    assert np.isfinite(phi[1:]).all()


def test_nothing_is_computed_without_clock_offsets():
    # no offset among the nuisances: NaN, the step's system never touched (it has none here)
    step = SimpleNamespace(A=None, B=None, Z=None, hessian=np.eye(1), order=None)
    phi = offset_overdispersion(step, [Nuisance("ray_shift_m", 0.0, 0.05, 0.01)], np.zeros(200),
                                np.repeat(np.arange(10), 20))
    assert phi.shape == (1,) and np.isnan(phi[0])


@pytest.mark.parametrize("chunk_entries", [None, 1, 100])
def test_the_block_scores_sum_each_offsets_efficient_rows_times_the_residuals_over_each_block(chunk_entries,
                                                                                             monkeypatch):
    # (the blocks' products in one run, one block at a time, and runs of a few blocks)
    import pedcal.calib.clocks as clocks_module

    if chunk_entries is not None:
        monkeypatch.setattr(clocks_module, "SCORE_CHUNK_ENTRIES", chunk_entries)
    rng = np.random.default_rng(5)
    step, M = _step(rng)
    H = step.hessian
    clusters = np.repeat(np.array([4, 9, 2, 7, 11, 3, 8, 5, 6, 10, 12, 13]), 20)
    clusters[[3, 50]] = -1
    weights = efficient_weights(step, _nuisances(), clusters)
    assert weights[0] == [1, 2] and weights[3] == 12
    x = rng.normal(size=(len(clusters), 2))
    U, m2 = block_scores(step, weights, x)
    assert U.shape == (2, 12, 2)
    for c, j in enumerate(weights[0]):
        o = [i for i in range(3) if i != j]
        m = M[:, j] - M[:, o] @ np.linalg.solve(H[np.ix_(o, o)], H[o, j])
        for b, label in enumerate(range(2, 14)):            # the blocks in their labels' order
            want = ((m[:, None] * x)[clusters == label]).sum(axis=0)
            np.testing.assert_allclose(U[c, b], want, rtol=1e-12, atol=1e-12)
        assert m2[c] == pytest.approx(np.sum(m[clusters >= 0] ** 2), rel=1e-12)
    assert efficient_weights(step, _nuisances(), np.repeat(np.arange(7), 40)) is None    # < 8 blocks
