"""Kidono et al.'s 213 features, the metric profiles and the scan-ray measures after them: layout,
finiteness on tiny clusters, known values, and the ray steps estimated from a cloud."""

import numpy as np
import pytest

from pedcal.detect.features import (
    BLOCKS,
    N_FEATURES,
    N_FEATURES_BEFORE_G5,
    N_KIDONO,
    block_slices,
    cluster_features,
    features_matrix,
    frame_normalized_intensity,
    scan_steps_rad,
)


def test_blocks_sum_to_213_plus_47_plus_4_plus_9():
    assert sum(n for _, n in BLOCKS) == N_FEATURES == 273
    assert block_slices()["pole_or_person"] == slice(N_FEATURES_BEFORE_G5, N_FEATURES)
    b = block_slices()
    assert b["intensity_hist"].stop == N_KIDONO == 213
    shape = sum(n for name, n in BLOCKS[:8])
    assert shape == 186 and BLOCKS[7][0] == "slices"


@pytest.mark.parametrize("n", [1, 2, 3])
def test_tiny_clusters_are_finite(n):
    pts = np.array([[1.0, 0.5, 0.2, 0.3], [1.1, 0.5, 1.0, 0.4], [1.0, 0.6, 1.5, 0.2]])[:n]
    f = cluster_features(pts)
    assert f.shape == (N_FEATURES,)
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
    assert features_matrix([]).shape == (0, N_FEATURES)
    m = features_matrix([np.ones((3, 4)), np.ones((5, 4)) * 2])
    assert m.shape == (2, N_FEATURES)
    with pytest.raises(ValueError):
        cluster_features(np.zeros((0, 4)))


def test_height_bands_and_top_profile_of_two_legs_under_a_head():
    # two 'legs' 0.3 m apart along y up to 0.8 m, a 0.2 m 'head' at 1.5-1.7 m, seen along x
    rng = np.random.default_rng(2)
    n = 3000
    z_leg = rng.uniform(0.0, 0.8, n)
    y_leg = np.where(rng.random(n) < 0.5, -0.15, 0.15) + rng.uniform(-0.03, 0.03, n)
    z_head = rng.uniform(1.5, 1.7, n // 3)
    y_head = rng.uniform(-0.1, 0.1, n // 3)
    pts = np.column_stack([np.full(n + n // 3, 3.0), np.concatenate([y_leg, y_head]),
                           np.concatenate([z_leg, z_head]), np.full(n + n // 3, 0.4)])
    pts[:, 0] += rng.uniform(-0.02, 0.02, len(pts))
    f = cluster_features(pts)
    b = block_slices()
    bands = f[b["height_bands"]].reshape(10, 2)  # (length along e1 = y here, largest gap)
    assert bands[:4, 0] == pytest.approx(np.full(4, 0.36), abs=0.01)
    assert bands[:4, 1] == pytest.approx(np.full(4, 0.24), abs=0.02)  # the gap between the legs
    assert bands[4:7].max() == 0.0  # nothing between 0.8 and 1.4 m
    assert bands[8, 0] == pytest.approx(0.2, abs=0.01) and bands[8, 1] < 0.02
    top = f[b["top_profile"]].reshape(8, 3)
    assert top[:2, 0] == pytest.approx([0.2, 0.2], abs=0.01)
    assert top[3:, 2].sum() == pytest.approx(0.0)  # 0.225-0.6 m below the top: the empty gap
    assert top[:, 2].sum() == pytest.approx((n // 3) / len(pts), abs=1e-9)
    assert f[b["z_extent_distance"]] == pytest.approx([0.0, 1.7, 3.0], abs=0.02)


def _grid_surface(range_m, width_m, z_m, daz_rad, del_rad, sensor_height_m=1.5, az_offsets_rad=None):
    """Points where a scan with the given steps hits a flat surface facing the sensor at ``range_m``:
    ``width_m`` wide, from z_m[0] to z_m[1]. ``az_offsets_rad`` staggers each row's azimuths."""
    el = np.arange(np.arctan2(z_m[0] - sensor_height_m, range_m), np.arctan2(z_m[1] - sensor_height_m, range_m),
                   del_rad)
    az = np.arange(-width_m / 2 / range_m, width_m / 2 / range_m, daz_rad)
    rows = []
    for k, e in enumerate(el):
        a = az + (0.0 if az_offsets_rad is None else az_offsets_rad[k % len(az_offsets_rad)])
        rows.append(np.column_stack([np.full(len(a), range_m), range_m * np.tan(a),
                                     sensor_height_m + range_m * np.tan(e) / np.cos(a), np.full(len(a), 0.5)]))
    return np.vstack(rows)


def test_scan_steps_are_recovered_from_a_cloud():
    daz, d_el = np.radians(0.2), np.radians(1 / 3)
    # a wall of a scan whose lasers fire at staggered azimuths (as a spinning LIDAR's do)
    wall = _grid_surface(12.0, 16.0, (0.4, 3.0), daz, d_el, az_offsets_rad=np.radians([0.0, 0.07, 0.13, 0.05]))
    got = scan_steps_rad(wall, 1.5)
    assert got == pytest.approx((daz, d_el), rel=0.02)
    # a metre off in the sensor height changes little
    assert scan_steps_rad(wall, 0.5) == pytest.approx((daz, d_el), rel=0.05)
    assert scan_steps_rad(_grid_surface(5.0, 8.0, (0.4, 2.5), np.radians(0.4), np.radians(2.0)), 1.5) == \
        pytest.approx((np.radians(0.4), np.radians(2.0)), rel=0.02)
    assert np.isnan(scan_steps_rad(wall[:5], 1.5)).all()


def test_scan_measures_of_a_person_sized_board_and_a_pole():
    """g4 of a 0.5 x 1.7 m board and of a 4 cm pole, 10 m away in a 0.2 x 1/3 deg scan: the board's
    area is its own, 0.85 m^2 (to the rounding of its 15 columns and 30 rows), it spans
    1.7 m / (10 m x 1/3 deg) + 1 = 30 rows and 15 columns and fills them; the pole covers 2 columns
    and an eighth of a square metre."""
    steps = (np.radians(0.2), np.radians(1 / 3))
    board = _grid_surface(10.0, 0.5, (0.0, 1.7), *steps)
    pole = _grid_surface(10.0, 0.04, (0.0, 1.7), *steps)
    g4 = features_matrix([board, pole], steps)[:, block_slices()["scan_normalized"]]
    area, rows, cols, fill = g4.T
    assert area[0] == pytest.approx(0.85, rel=0.1) and area[1] < 0.15
    assert rows == pytest.approx([1.7 / (10 * steps[1]) + 1] * 2, rel=0.05)
    assert cols[0] == pytest.approx(0.5 / (10 * steps[0]), rel=0.1) and cols[1] <= 3
    assert fill[0] == pytest.approx(1.0, rel=0.1)


def test_g5_tells_a_pole_from_a_person():
    """A 0.1 m pole, 1.8 m high: a line (linearity ~1), vertical, head as wide as its shaft. A
    person-shaped cluster: 0.45 m shoulders under a 0.2 m head."""
    rng = np.random.default_rng(5)
    n = 600
    pole = np.column_stack([8.0 + rng.uniform(-0.05, 0.05, n), rng.uniform(-0.05, 0.05, n),
                            rng.uniform(0.0, 1.8, n), np.zeros(n)])
    z = rng.uniform(0.0, 1.75, n)
    half_width = np.where(z > 1.5, 0.1, np.where(z > 0.9, 0.225, 0.15))
    person = np.column_stack([8.0 + rng.uniform(-0.1, 0.1, n), rng.uniform(-1, 1, n) * half_width, z, np.zeros(n)])
    g = block_slices()["pole_or_person"]
    fp, fq = cluster_features(pole)[g], cluster_features(person)[g]
    linearity, planarity, scattering, vertical, radius, torso_w, head_w, ratio, aspect = fp
    assert linearity > 0.98 and vertical > 0.999 and radius == pytest.approx(np.sqrt(2 * 0.1**2 / 12), rel=0.1)
    assert linearity + planarity + scattering == pytest.approx(1.0)
    assert ratio == pytest.approx(1.0, abs=0.1) and aspect < 0.1
    assert fq[7] == pytest.approx(0.2 / 0.45, abs=0.05) and fq[5] == pytest.approx(0.45, abs=0.02)
    assert fq[0] < fp[0] and fq[4] > fp[4]


def test_g5_of_one_point_is_zero():
    assert (cluster_features(np.array([[3.0, 0.0, 1.0, 0.2]]))[block_slices()["pole_or_person"]] == 0).all()


def test_frame_normalized_intensity_removes_the_units():
    rng = np.random.default_rng(6)
    pts = np.column_stack([rng.uniform(1, 10, (500, 3)), rng.uniform(0, 1, 500)])
    kitti, argo = frame_normalized_intensity(pts), frame_normalized_intensity(pts * [1, 1, 1, 255.0])
    assert kitti == pytest.approx(argo)
    assert np.percentile(kitti[:, 3], 95) == pytest.approx(1.0, abs=0.01)
    none = pts.copy()
    none[:, 3] = 0.0
    assert (frame_normalized_intensity(none)[:, 3] == 0).all()
    assert (frame_normalized_intensity(pts[:, :3])[:, 3] == 0).all()
    nan = pts.copy()
    nan[0, 3] = np.nan
    assert np.isfinite(frame_normalized_intensity(nan)).all()
