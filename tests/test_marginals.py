"""Marginal covariances by sparse selected inversion (pedcal.calib.marginals) against the dense
inverse of the normal matrix and GTSAM's Marginals, on small graphs of the factor graph's shape:
a robot's path of poses tied by odometry, sensors seeing it from a few poses each."""

import gtsam
import numpy as np
import pytest
import scipy.sparse as sps

from pedcal.calib.marginals import _supernodes, ldl_factor, marginal_covariances, selected_inverse_blocks
from pedcal.calib.profile import Columns, fill_reducing_order, sparse_system

S, X, P = (lambda i: gtsam.symbol("s", i)), (lambda i: gtsam.symbol("x", i)), (lambda i: gtsam.symbol("p", i))


def path_graph(seed: int, n_pose: int = 60, n_sensor: int = 8, points: int = 3):
    """A path of ``n_pose`` Pose3 (a prior on the first, odometry between), ``n_sensor`` Pose3
    sensors (weak priors) each tied to a few poses, and ``points`` Point3 landmarks each seen from
    a few poses: (graph, values)."""
    rng = np.random.default_rng(seed)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()

    def pose(scale):
        return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.3, 3)), rng.normal(0, scale, 3))

    def noise(sigmas):
        return gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float))

    for k in range(n_pose):
        values.insert(X(k), pose(5.0))
    graph.add(gtsam.PriorFactorPose3(X(0), values.atPose3(X(0)), noise([0.01] * 6)))
    for k in range(1, n_pose):
        graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), pose(0.5), noise(rng.uniform(0.01, 0.1, 6))))
    for i in range(n_sensor):
        values.insert(S(i), pose(5.0))
        graph.add(gtsam.PriorFactorPose3(S(i), pose(5.0), noise([1.0] * 6)))
        for k in rng.choice(n_pose, size=4, replace=False):
            graph.add(gtsam.BetweenFactorPose3(S(i), X(int(k)), pose(2.0), noise(rng.uniform(0.02, 0.2, 6))))
    for j in range(points):
        values.insert(P(j), gtsam.Point3(*rng.normal(0, 5, 3)))
        graph.add(gtsam.PriorFactorPoint3(P(j), gtsam.Point3(*rng.normal(0, 5, 3)), noise([2.0] * 3)))
        for k in rng.choice(n_pose, size=3, replace=False):
            graph.add(gtsam.BearingRangeFactor3D(X(int(k)), P(j), gtsam.Unit3(rng.normal(0, 1, 3)),
                                                 rng.uniform(1.0, 3.0), noise([0.01, 0.01, 0.05])))
    return graph, values


def dense_marginals(graph, values, keys):
    """Each key's block of the dense inverse of the normal matrix."""
    cols = Columns.of(values)
    A, _ = sparse_system(graph.linearize(values), cols)
    Y = np.linalg.inv((A.T @ A).toarray())
    return [Y[np.ix_(cols.index([k]), cols.index([k]))] for k in keys]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_marginals_equal_the_dense_inverse_and_gtsams(seed):
    graph, values = path_graph(seed)
    keys = [S(i) for i in range(8)] + [P(0), X(0), X(31), X(59)]
    got = marginal_covariances(graph, values, keys)
    dense = dense_marginals(graph, values, keys)
    marginals = gtsam.Marginals(graph, values)
    for key, g, d in zip(keys, got, dense, strict=True):
        assert g.shape == d.shape == ((3, 3) if key == P(0) else (6, 6))
        assert np.abs(g - d).max() <= 1e-9 * np.abs(d).max()
        ref = marginals.marginalCovariance(key)
        assert np.abs(g - ref).max() <= 1e-9 * np.abs(ref).max()


def test_keys_in_any_order_and_repeated():
    # each block in its key's own tangent order, whatever the order (or repetition) of the keys
    graph, values = path_graph(3, n_pose=20, n_sensor=3, points=1)
    keys = [X(7), S(2), X(7), P(0), S(0)]
    got = marginal_covariances(graph, values, keys)
    dense = dense_marginals(graph, values, keys)
    for g, d in zip(got, dense, strict=True):
        assert np.abs(g - d).max() <= 1e-9 * np.abs(d).max()
    assert np.array_equal(got[0], got[2])


def test_one_variable_graph_is_its_priors_inverse():
    # the root supernode alone (no structure below it): D^-1 through L_JJ only
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(S(0), gtsam.Pose3())
    sigmas = np.array([0.1, 0.2, 0.3, 1.0, 2.0, 3.0])
    graph.add(gtsam.PriorFactorPose3(S(0), gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    (cov,) = marginal_covariances(graph, values, [S(0)])
    assert np.allclose(cov, np.diag(sigmas ** 2), rtol=1e-12, atol=0.0)


def test_selected_inverse_of_a_random_sparse_matrix_on_its_pattern():
    # the recurrences alone, on an SPD matrix of banded and random structure: every diagonal
    # element and a few cliques of columns against the dense inverse
    rng = np.random.default_rng(7)
    n = 120
    M = sps.random(n, n, density=0.03, random_state=np.random.RandomState(7)) + sps.eye(n, k=1)
    A = sps.vstack([M, sps.eye(n)]).tocsr()
    L, d, position = ldl_factor(A, np.arange(n)[rng.permutation(n)])
    Y = np.linalg.inv((A.T @ A).toarray())
    blocks = [np.array([position[c]]) for c in range(n)]
    diag = selected_inverse_blocks(L, d, blocks)
    assert np.allclose([b[0, 0] for b in diag], [Y[c, c] for c in range(n)], rtol=1e-10, atol=0.0)
    # a column with its parent in the elimination tree (a clique of L's pattern)
    order = np.argsort(position)
    for j in rng.choice(n - 1, size=10, replace=False):
        rows = L.indices[L.indptr[j]:L.indptr[j + 1]]
        pair = np.array([j, rows[rows > j][0]]) if np.any(rows > j) else np.array([j])
        (got,) = selected_inverse_blocks(L, d, [pair])
        want = Y[np.ix_(order[pair], order[pair])]
        assert np.allclose(got, want, rtol=1e-10, atol=1e-14)


def test_supernodes_hold_columns_of_one_structure():
    graph, values = path_graph(4)
    gfg = graph.linearize(values)
    cols = Columns.of(values)
    A, _ = sparse_system(gfg, cols)
    L, _, _ = ldl_factor(A, fill_reducing_order(gfg, cols))
    first, of = _supernodes(L)
    assert first[0] == 0 and first[-1] == L.shape[1] and np.all(np.diff(first) > 0)
    for s in range(len(first) - 1):
        head = L.indices[L.indptr[first[s]]:L.indptr[first[s] + 1]]
        for j in range(first[s], first[s + 1]):
            assert np.array_equal(L.indices[L.indptr[j]:L.indptr[j + 1]], head[j - first[s]:])
    assert np.array_equal(of[first[:-1]], np.arange(len(first) - 1))


def test_a_variable_no_factor_holds_is_an_error():
    graph, values = path_graph(5, n_pose=10, n_sensor=2, points=0)
    values.insert(S(9), gtsam.Pose3())       # no factor touches it: the normal matrix is singular
    with pytest.raises(np.linalg.LinAlgError, match="no factor holds"):
        marginal_covariances(graph, values, [S(0)])


def test_posterior_per_sensor_marginals_equal_the_joint_ones(monkeypatch):
    # above the joint covariance's limit each sensor's block comes from the selected inversion:
    # the same as the joint marginal's diagonal blocks (paper scenario, seed 1; AMCL's model as
    # assumed, for speed)
    import warnings

    from pedcal.calib import readback
    from pedcal.calib.factorgraph import calibrate_factorgraph
    from pedcal.sim import simulate_logs

    log = simulate_logs("paper", seed=1).calib
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        joint = calibrate_factorgraph(log, estimate_amcl_model=False)
        monkeypatch.setattr(readback, "JOINT_COV_MAX_SENSORS", 0)
        alone = calibrate_factorgraph(log, estimate_amcl_model=False)
    assert joint.position_covariance_m2 is not None and alone.position_covariance_m2 is None
    a, b = joint.diagnostics.position_covariance_m2, alone.diagnostics.position_covariance_m2
    assert sorted(a) == sorted(b) and len(a) == len(log.sensors)
    for sid in a:
        assert np.abs(a[sid] - b[sid]).max() <= 1e-7 * np.abs(a[sid]).max()


def test_single_column_supernodes_give_the_same_blocks(monkeypatch):
    # the recurrences hold for any partition into supernodes of nested structure: one column
    # each (every parent's clique a single column and its structure) gives the same blocks
    import pedcal.calib.marginals as marginals

    graph, values = path_graph(6)
    keys = [S(i) for i in range(8)] + [P(1)]
    fundamental = marginal_covariances(graph, values, keys)

    def one_column_each(L):
        n = L.shape[1]
        return np.arange(n + 1), np.arange(n)

    monkeypatch.setattr(marginals, "_supernodes", one_column_each)
    single = marginal_covariances(graph, values, keys)
    for a, b in zip(fundamental, single, strict=True):
        assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()


def test_a_pattern_that_is_no_filled_graph_falls_back_to_gtsam(monkeypatch):
    import pedcal.calib.marginals as marginals

    def not_closed(*_):
        raise ValueError("L's pattern is not a filled graph's")

    graph, values = path_graph(7, n_pose=20, n_sensor=3, points=0)
    monkeypatch.setattr(marginals, "selected_inverse_blocks", not_closed)
    got = marginal_covariances(graph, values, [S(1), X(4)])
    ref = gtsam.Marginals(graph, values)
    for key, g in zip([S(1), X(4)], got, strict=True):
        assert np.abs(g - ref.marginalCovariance(key)).max() <= 1e-12 * np.abs(g).max()
