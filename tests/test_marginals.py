"""Marginal covariances by selected inversion of the Bayes tree (pedcal.calib.marginals) against
the dense inverse of the normal matrix and GTSAM's Marginals, on small graphs of the factor
graph's shape: a robot's path of poses tied by odometry, sensors seeing it from a few poses each."""

import gtsam
import numpy as np
import pytest

from pedcal.calib.marginals import marginal_covariances, tree_marginal_blocks
from pedcal.calib.profile import Columns, sparse_system

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


def test_the_nonlinear_graphs_colamd_ordering_gives_the_same_blocks():
    # the graph's own COLAMD ordering (as the solver computed it) is its linearization's: the
    # same elimination, the same blocks to the last digit; any other ordering, the same to roundoff
    graph, values = path_graph(4, n_pose=25, n_sensor=4, points=2)
    keys = [S(0), S(3), X(5), P(1)]
    got = marginal_covariances(graph, values, keys)
    same = marginal_covariances(graph, values, keys, ordering=graph.orderingCOLAMD())
    assert all(np.array_equal(g, s) for g, s in zip(got, same, strict=True))
    natural = gtsam.Ordering()
    for k in sorted(values.keys()):
        natural.push_back(k)
    other = marginal_covariances(graph, values, keys, ordering=natural)
    assert all(np.abs(g - o).max() <= 1e-9 * np.abs(g).max() for g, o in zip(got, other, strict=True))
    # an ordering of other variables (another graph's) is not used: the graph's own is computed
    short = gtsam.Ordering()
    for k in sorted(values.keys())[:-1]:
        short.push_back(k)
    stale = marginal_covariances(graph, values, keys, ordering=short)
    assert all(np.array_equal(g, s) for g, s in zip(got, stale, strict=True))
    # the right count with a key twice and one missing: not used either
    twice = gtsam.Ordering()
    ks = sorted(values.keys())
    for k in ks[:-1] + [ks[0]]:
        twice.push_back(k)
    doubled = marginal_covariances(graph, values, keys, ordering=twice)
    assert all(np.array_equal(g, s) for g, s in zip(got, doubled, strict=True))
    # every key, and one of them again: the count tells it, not the set
    extra = gtsam.Ordering()
    for k in ks + [ks[0]]:
        extra.push_back(k)
    repeated = marginal_covariances(graph, values, keys, ordering=extra)
    assert all(np.array_equal(g, s) for g, s in zip(got, repeated, strict=True))


def test_one_variable_graph_is_its_priors_inverse():
    # the root supernode alone (no structure below it): D^-1 through L_JJ only
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(S(0), gtsam.Pose3())
    sigmas = np.array([0.1, 0.2, 0.3, 1.0, 2.0, 3.0])
    graph.add(gtsam.PriorFactorPose3(S(0), gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    (cov,) = marginal_covariances(graph, values, [S(0)])
    assert np.allclose(cov, np.diag(sigmas ** 2), rtol=1e-12, atol=0.0)


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


def test_every_clique_on_the_way_to_the_root_of_a_forest():
    # two graphs with nothing between them: two trees, a key in each and one deep in a path
    g1, v1 = path_graph(8, n_pose=30, n_sensor=3, points=1)
    g2, v2 = path_graph(9, n_pose=25, n_sensor=2, points=0)
    shift = 1000
    graph, values = gtsam.NonlinearFactorGraph(g1), gtsam.Values(v1)
    for k in range(25):
        values.insert(X(shift + k), v2.atPose3(X(k)))
    for i in range(2):
        values.insert(S(shift + i), v2.atPose3(S(i)))
    rename = {X(k): X(shift + k) for k in range(25)} | {S(i): S(shift + i) for i in range(2)}
    for j in range(g2.size()):
        f = g2.at(j)
        keys = [rename[k] for k in f.keys()]
        if isinstance(f, gtsam.PriorFactorPose3):
            graph.add(gtsam.PriorFactorPose3(keys[0], f.prior(), f.noiseModel()))
        else:
            graph.add(gtsam.BetweenFactorPose3(keys[0], keys[1], f.measured(), f.noiseModel()))
    keys = [S(0), S(shift + 1), X(shift + 12), P(0)]
    gfg = graph.linearize(values)
    tree = gfg.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(gfg))
    assert len(tree.roots()) == 2
    got = tree_marginal_blocks(tree, {int(k): int(d) for k, d in values.dims().items()}, keys)
    for g, d in zip(got, dense_marginals(graph, values, keys), strict=True):
        assert np.abs(g - d).max() <= 1e-9 * np.abs(d).max()


def test_a_conditional_with_a_noise_model_falls_back_to_gtsam(monkeypatch):
    import pedcal.calib.marginals as marginals

    def not_whitened(*_):
        raise ValueError("a conditional carries a noise model")

    graph, values = path_graph(7, n_pose=20, n_sensor=3, points=0)
    monkeypatch.setattr(marginals, "tree_marginal_blocks", not_whitened)
    got = marginal_covariances(graph, values, [S(1), X(4)])
    ref = gtsam.Marginals(graph, values)
    for key, g in zip([S(1), X(4)], got, strict=True):
        assert np.abs(g - ref.marginalCovariance(key)).max() <= 1e-12 * np.abs(g).max()


def test_a_constrained_conditional_is_refused():
    # a hard constraint leaves its conditional a noise model of zero sigmas: R and S not whitened
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(S(0), gtsam.Pose3())
    graph.add(gtsam.PriorFactorPose3(S(0), gtsam.Pose3(), gtsam.noiseModel.Constrained.All(6)))
    gfg = graph.linearize(values)
    tree = gfg.eliminateMultifrontal(gtsam.Ordering.ColamdGaussianFactorGraph(gfg))
    with pytest.raises(ValueError, match="noise model"):
        tree_marginal_blocks(tree, {int(S(0)): 6}, [S(0)])
