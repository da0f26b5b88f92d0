"""RealAdaBoost learns, is deterministic, and round-trips through its .npz."""

import numpy as np
import pytest

from pedcal.detect.adaboost import RealAdaBoost
from pedcal.detect.gbt import GradientBoostedTrees
from pedcal.errors import PedcalInputError


def toy(seed, n=2000, F=20):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, F))
    y = ((X[:, 4] > 0.3) | (X[:, 11] < -1.0)).astype(int)  # separable by two thresholds
    return X, y


def test_learns_a_separable_problem():
    X, y = toy(0)
    m = RealAdaBoost(n_rounds=30, n_bins=32).fit(X, y)
    Xt, yt = toy(1)
    acc = (m.predict(Xt) == yt).mean()
    assert acc > 0.97
    assert set(m.feature_[:2]) <= {4, 11}
    p = m.predict_proba(Xt)
    assert ((p > 0.5) == (m.decision_function(Xt) > 0)).all()
    assert (p >= 0).all() and (p <= 1).all()


def test_deterministic_and_save_load(tmp_path):
    X, y = toy(2)
    a = RealAdaBoost(n_rounds=20, seed=3, max_edge_samples=500).fit(X, y)
    b = RealAdaBoost(n_rounds=20, seed=3, max_edge_samples=500).fit(X, y)
    assert np.array_equal(a.feature_, b.feature_) and np.array_equal(a.h_, b.h_)
    path = tmp_path / "m.npz"
    a.save(path)
    c = RealAdaBoost.load(path)
    np.testing.assert_array_equal(a.decision_function(X), c.decision_function(X))
    assert c.n_rounds == 20 and c.seed == 3


def test_bad_inputs():
    X, y = toy(3, n=50)
    with pytest.raises(ValueError):
        RealAdaBoost().fit(X, np.ones(50))
    X[0, 0] = np.nan
    with pytest.raises(ValueError):
        RealAdaBoost().fit(X, y)
    with pytest.raises(RuntimeError):
        RealAdaBoost().decision_function(X)


def test_load_rejects_a_bad_file(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a model")
    with pytest.raises(PedcalInputError, match="bad.npz"):
        RealAdaBoost.load(bad)
    with pytest.raises(PedcalInputError):
        RealAdaBoost.load(tmp_path / "missing.npz")


def test_saved_file_is_byte_reproducible(tmp_path):
    X, y = toy(4, n=300)
    m = RealAdaBoost(n_rounds=5).fit(X, y)
    m.save(tmp_path / "a.npz")
    m.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()


def test_threshold_offset_moves_the_boundary_and_is_saved(tmp_path):
    X, y = toy(5, n=500)
    m = RealAdaBoost(n_rounds=10).fit(X, y)
    F = m.decision_function(X)
    t = float(np.median(F))
    m.set_threshold(t)
    np.testing.assert_allclose(m.decision_function(X), F - t)
    assert m.predict(X).sum() == (F > t).sum()
    assert m.predict_proba(X[F == t]).tolist() == [0.5] * int((F == t).sum())
    m.save(tmp_path / "m.npz")
    back = RealAdaBoost.load(tmp_path / "m.npz")
    assert back.bias_ == pytest.approx(-t)
    np.testing.assert_array_equal(back.decision_function(X), m.decision_function(X))


def xor(seed, n=3000, F=8):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, F))
    return X, ((X[:, 2] > 0) ^ (X[:, 5] > 0)).astype(int)  # no single feature says anything


def test_trees_learn_what_one_feature_partitions_cannot(tmp_path):
    X, y = xor(6)
    Xt, yt = xor(7)
    flat = RealAdaBoost(n_rounds=40, n_bins=16).fit(X, y)
    tree = RealAdaBoost(n_rounds=40, n_bins=16, tree_depth=2).fit(X, y)
    assert (flat.predict(Xt) == yt).mean() < 0.7
    assert (tree.predict(Xt) == yt).mean() > 0.95
    assert tree.feature_.shape == (40, 3) and tree.h_.shape == (40, 4)
    used = np.bincount(tree.feature_.ravel(), minlength=8)
    assert set(np.argsort(used)[-2:]) == {2, 5}  # the trees split mostly on the two that matter
    # saved and loaded, the same decisions; the file is byte-reproducible; depth 0 files keep their layout
    tree.save(tmp_path / "a.npz")
    tree.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    back = RealAdaBoost.load(tmp_path / "a.npz")
    assert back.tree_depth == 2
    np.testing.assert_array_equal(back.decision_function(Xt), tree.decision_function(Xt))
    flat.save(tmp_path / "flat.npz")
    with np.load(tmp_path / "flat.npz") as d:
        assert "tree_depth" not in d.files
    assert RealAdaBoost.load(tmp_path / "flat.npz").tree_depth == 0


@pytest.mark.parametrize("depth", [0, 2])
def test_sample_weights_are_the_initial_weights(depth):
    rng = np.random.default_rng(11)
    X = rng.normal(size=(400, 4))
    y = (X[:, 0] + rng.normal(0, 1.0, 400) > 0).astype(int)
    plain = RealAdaBoost(n_rounds=15, n_bins=8, tree_depth=depth).fit(X, y)
    uniform = RealAdaBoost(n_rounds=15, n_bins=8, tree_depth=depth).fit(X, y, sample_weight=np.full(400, 3.0))
    assert uniform.decision_function(X) == pytest.approx(plain.decision_function(X))
    # weighting the people tenfold makes more of the overlap people
    heavy = RealAdaBoost(n_rounds=15, n_bins=8, tree_depth=depth).fit(X, y, sample_weight=np.where(y > 0, 10.0, 1.0))
    assert heavy.predict(X).sum() > plain.predict(X).sum()
    for bad in (np.zeros(400), np.ones(3), np.full(400, np.nan)):
        with pytest.raises(ValueError, match="sample_weight"):
            RealAdaBoost(n_rounds=2).fit(X, y, sample_weight=bad)


@pytest.mark.parametrize("make", [lambda: RealAdaBoost(n_rounds=5), lambda: GradientBoostedTrees(n_estimators=5)],
                         ids=["adaboost", "gbt"])
def test_both_classifiers_refuse_scoring_untrained_or_on_other_features_and_move_their_threshold(make):
    # (the person classifiers share these: pedcal.detect.adaboost.ScoreClassifier)
    X, y = toy(6, n=300, F=12)
    with pytest.raises(RuntimeError, match="not trained"):
        make().decision_function(X)
    m = make().fit(X, y)
    with pytest.raises(ValueError, match="expected 12 features, got 5"):
        m.predict(X[:, :5])
    F = m.decision_function(X)
    t = float(np.quantile(F, 0.7))
    assert m.set_threshold(t) is m
    np.testing.assert_allclose(m.decision_function(X), F - t, rtol=0, atol=1e-12)
    assert np.array_equal(m.predict(X), (F - t > 0).astype(int)) and 0 < m.predict(X).sum() < len(X)
    # a single row (1-D) is one sample
    assert m.decision_function(X[0]).shape == (1,)
