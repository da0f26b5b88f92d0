"""Kidono et al.'s 213 features: layout, finiteness on tiny clusters, and known values."""

import numpy as np
import pytest

from pedcal.track.features import BLOCKS, N_FEATURES, block_slices, cluster_features, features_matrix


def test_blocks_sum_to_213():
    assert sum(n for _, n in BLOCKS) == N_FEATURES == 213
    b = block_slices()
    assert b["intensity_hist"].stop == 213
    shape = sum(n for name, n in BLOCKS if not name.startswith("intensity"))
    assert shape == 186


@pytest.mark.parametrize("n", [1, 2, 3])
def test_tiny_clusters_are_finite(n):
    pts = np.array([[1.0, 0.5, 0.2, 0.3], [1.1, 0.5, 1.0, 0.4], [1.0, 0.6, 1.5, 0.2]])[:n]
    f = cluster_features(pts)
    assert f.shape == (213,)
    assert np.isfinite(f).all()


def test_identical_points_are_finite():
    f = cluster_features(np.tile([[2.0, 0.0, 1.0, 0.5]], (5, 1)))
    assert np.isfinite(f).all()


def test_known_values_of_a_vertical_line():
    rng = np.random.default_rng(0)
    n = 400
    z = rng.uniform(0, 1.7, n)
    pts = np.column_stack([np.full(n, 3.0), np.full(n, 4.0), z, np.full(n, 0.5)])
    f = cluster_features(pts)
    b = block_slices()
    assert f[b["n_points"]][0] == n
    assert f[b["min_distance_m"]][0] == pytest.approx(5.0)
    cov = f[b["covariance_3d"]]  # xx, xy, xz, yy, yz, zz
    assert cov[5] == pytest.approx(z.var())
    assert np.abs(cov[:5]).max() < 1e-12
    # inertia about a vertical line: Ixx = Iyy = var z, Izz = 0
    inertia = f[b["inertia_tensor"]]
    assert inertia[0] == pytest.approx(z.var()) and inertia[3] == pytest.approx(z.var())
    assert inertia[5] == pytest.approx(0.0, abs=1e-12)
    for name in ("hist_main_plane", "hist_secondary_plane", "intensity_hist"):
        assert f[b[name]].sum() == pytest.approx(1.0)
    assert f[b["intensity_mean_std"]] == pytest.approx([0.5, 0.0])
    assert f[b["intensity_hist"]][12] == pytest.approx(1.0)  # 0.5 falls in bin 12 of 25
    # height histogram of the main plane: all points in the middle column (u = 0)
    hist = f[b["hist_main_plane"]].reshape(14, 7)
    assert hist[:, 3].sum() == pytest.approx(1.0)


def test_slices_measure_a_box_cross_section():
    rng = np.random.default_rng(1)
    n = 5000
    # a 0.6 x 0.2 m footprint, main axis along y, at x = 2
    pts = np.column_stack([2.0 + rng.uniform(-0.1, 0.1, n), rng.uniform(-0.3, 0.3, n),
                           rng.uniform(0, 1.5, n), rng.uniform(0, 1, n)])
    f = cluster_features(pts)
    slices = f[block_slices()["slices"]].reshape(10, 2)
    assert slices[:, 0] == pytest.approx(np.full(10, 0.6), abs=0.02)
    assert slices[:, 1] == pytest.approx(np.full(10, 0.2), abs=0.02)


def test_features_matrix_and_bad_input():
    assert features_matrix([]).shape == (0, 213)
    m = features_matrix([np.ones((3, 4)), np.ones((5, 4)) * 2])
    assert m.shape == (2, 213)
    with pytest.raises(ValueError):
        cluster_features(np.zeros((0, 4)))
