"""The vectorized features and boxes against the per-cluster code they replaced: on simulated
frames of several sensors and on a real 67k-point SUSTech frame, every cluster's 264 features
agree to 1e-9 and ``detect`` returns the same detections as the reference computation."""

import numpy as np
import pytest

from pedcal.detect import detection as det
from pedcal.detect.features import (
    BAND_M,
    HALF_WIDTH_M,
    HEAD_DEPTH_M,
    INTENSITY_MAX,
    MIN_RANGE_M,
    N_BANDS,
    N_FEATURES,
    N_SLICES,
    N_TOP_BANDS,
    TOP_BAND_M,
    TORSO_BAND_M,
    Z_TOP_M,
    block_slices,
    features_matrix,
    scan_steps_rad,
)
from pedcal.detect.train import EVAL_STREAM, simulated_frame

_UPPER3 = np.triu_indices(3)


# ------------------------------------------------------- reference: the former per-cluster code
def _upper6(c: np.ndarray) -> np.ndarray:
    """The 6 distinct entries of a symmetric 3x3 matrix: xx, xy, xz, yy, yz, zz."""
    return c[_UPPER3]


def _cov2(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(var a, cov ab, var b) over the masked points; zeros when fewer than 2 points."""
    n = int(mask.sum())
    if n < 2:
        return np.zeros(3)
    a, b = a[mask], b[mask]
    da, db = a - a.mean(), b - b.mean()
    return np.array([da @ da, da @ db, db @ db]) / n


def _hist2d(z: np.ndarray, s: np.ndarray, n_z: int, n_s: int) -> np.ndarray:
    """Normalized (n_z x n_s) histogram of (z, s), z in [0, Z_TOP_M], s in +-HALF_WIDTH_M, clipped."""
    iz = np.clip((z / Z_TOP_M * n_z).astype(int), 0, n_z - 1)
    i_s = np.clip(((s + HALF_WIDTH_M) / (2 * HALF_WIDTH_M) * n_s).astype(int), 0, n_s - 1)
    h = np.bincount(iz * n_s + i_s, minlength=n_z * n_s).astype(float)
    return h / max(len(z), 1)


def _axes(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e1, e2): horizontal major/minor principal axes, e2 pointing away from the sensor."""
    centroid = xy.mean(axis=0)
    d = xy - centroid
    cov = d.T @ d / max(len(xy), 1)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    e2 = vecs[:, 0]
    if e2 @ centroid < 0:
        e2 = -e2
    e1 = np.array([-e2[1], e2[0]])
    return e1, e2


def reference_cluster_features(points: np.ndarray, scan_steps=(np.nan, np.nan)) -> np.ndarray:
    """The N_FEATURES-vector of one cluster (N, 4) ``x, y, z, intensity``; see the module table."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] < 3 or len(pts) == 0:
        raise ValueError(f"a cluster is a non-empty (N, 4) array, got shape {pts.shape}")
    n = len(pts)
    xyz = pts[:, :3]
    inten = pts[:, 3] if pts.shape[1] > 3 else np.zeros(n)
    f = np.zeros(N_FEATURES)
    b = block_slices()

    f[b["n_points"]] = n
    f[b["min_distance_m"]] = np.sqrt((xyz[:, :2] ** 2).sum(axis=1)).min()

    centred = xyz - xyz.mean(axis=0)
    cov3 = centred.T @ centred / n
    f[b["covariance_3d"]] = _upper6(cov3)
    # Moment of inertia about the centroid, I = sum(|r|^2 E - r r^T), divided by N.
    inertia = np.trace(cov3) * np.eye(3) - cov3
    f[b["inertia_tensor"]] = _upper6(inertia)

    e1, e2 = _axes(xyz[:, :2])
    u = centred[:, :2] @ e1
    v = centred[:, :2] @ e2
    z = xyz[:, 2]

    # Main plane (u, z) split into the upper half and the lower left and right halves.
    z_mid = 0.5 * (z.min() + z.max())
    upper = z > z_mid
    f[b["covariance_2d_zones"]] = np.concatenate([
        _cov2(u, z, upper), _cov2(u, z, ~upper & (u < 0)), _cov2(u, z, ~upper & (u >= 0))])

    f[b["hist_main_plane"]] = _hist2d(z, u, 14, 7).ravel()
    f[b["hist_secondary_plane"]] = _hist2d(z, v, 9, 5).ravel()

    # Slice feature: N_SLICES equal height slices between the lowest and highest point; in each,
    # the extent along e1 (length) and along e2 (width); empty slices give 0.
    height = z.max() - z.min()
    k = np.clip(((z - z.min()) / max(height, 1e-9) * N_SLICES).astype(int), 0, N_SLICES - 1)
    lo = np.full((N_SLICES, 2), np.inf)
    hi = np.full((N_SLICES, 2), -np.inf)
    uv = np.column_stack([u, v])
    np.minimum.at(lo, k, uv)
    np.maximum.at(hi, k, uv)
    ext = np.where(np.isfinite(lo), hi - lo, 0.0)
    f[b["slices"]] = ext.ravel()

    f[b["intensity_mean_std"]] = [inten.mean(), inten.std()]
    ib = np.clip((inten / INTENSITY_MAX * 25).astype(int), 0, 24)
    f[b["intensity_hist"]] = np.bincount(ib, minlength=25) / n

    # g1: per 0.2 m band of floor height, the extent along e1 and the largest gap along e1.
    band = (z / BAND_M).astype(int)
    inside = (band >= 0) & (band < N_BANDS)
    g1 = np.zeros((N_BANDS, 2))
    if inside.any():
        bu = np.column_stack([band[inside], u[inside]])
        bu = bu[np.lexsort((bu[:, 1], bu[:, 0]))]  # by band, then along e1
        bnd = bu[:, 0].astype(int)
        lo, hi = np.full(N_BANDS, np.inf), np.full(N_BANDS, -np.inf)
        np.minimum.at(lo, bnd, bu[:, 1])
        np.maximum.at(hi, bnd, bu[:, 1])
        g1[:, 0] = np.where(np.isfinite(lo), hi - lo, 0.0)
        same = bnd[1:] == bnd[:-1]
        np.maximum.at(g1[:, 1], bnd[1:][same], np.diff(bu[:, 1])[same])
    f[b["height_bands"]] = g1.ravel()

    # g2: per band below the highest point, the extents along e1 and e2 and the share of points.
    top = (z.max() - z) / TOP_BAND_M
    tb = top.astype(int)
    near_top = tb < N_TOP_BANDS
    lo = np.full((N_TOP_BANDS, 2), np.inf)
    hi = np.full((N_TOP_BANDS, 2), -np.inf)
    np.minimum.at(lo, tb[near_top], uv[near_top])
    np.maximum.at(hi, tb[near_top], uv[near_top])
    share = np.bincount(tb[near_top], minlength=N_TOP_BANDS) / n
    f[b["top_profile"]] = np.column_stack([np.where(np.isfinite(lo), hi - lo, 0.0), share]).ravel()

    # g3
    f[b["z_extent_distance"]] = [z.min(), z.max(), np.hypot(*xyz[:, :2].mean(axis=0))]

    # g4: area, rows, columns and fill in the scan's rays
    daz, d_el = scan_steps
    if np.isfinite(daz) and np.isfinite(d_el):
        c = xyz[:, :2].mean(axis=0)
        r = max(np.hypot(*c), MIN_RANGE_M)
        bearing = np.angle(np.exp(1j * (np.arctan2(xyz[:, 1], xyz[:, 0]) - np.arctan2(c[1], c[0]))))
        rows = np.ptp(z) / (r * d_el) + 1
        cols = np.ptp(bearing) / daz + 1
        f[b["scan_normalized"]] = [n * (r * daz) * (r * d_el), rows, cols, n / (rows * cols)]

    # g5: eigen shape, verticality, rms radius, torso and head widths along e1, their ratio, aspect
    vals, vecs = np.linalg.eigh(cov3)
    l3, l2, l1 = vals
    if l1 > 0:
        shape = [(l1 - l2) / l1, (l2 - l3) / l1, max(l3, 0.0) / l1, abs(vecs[2, 2])]
    else:
        shape = [0.0, 0.0, 0.0, 0.0]
    torso = (z >= TORSO_BAND_M[0]) & (z <= TORSO_BAND_M[1])
    head = z >= z.max() - HEAD_DEPTH_M
    torso_w = np.ptp(u[torso]) if torso.any() else 0.0
    head_w = np.ptp(u[head])
    f[b["pole_or_person"]] = shape + [np.sqrt(max(cov3[0, 0] + cov3[1, 1], 0.0)), torso_w, head_w,
                                      head_w / torso_w if torso_w > 0 else 0.0,
                                      np.ptp(u) / np.ptp(z) if np.ptp(z) > 0 else 0.0]
    return f


def reference_min_area_box(xy: np.ndarray) -> det.Box:
    """The minimum-area box of one cluster by rotating calipers on its convex hull."""
    from scipy.spatial import ConvexHull, QhullError

    xy = np.asarray(xy, dtype=float)
    try:
        hull = xy[ConvexHull(xy).vertices]
    except (QhullError, ValueError):
        hull = xy
    if len(hull) >= 3:
        edges = np.roll(hull, -1, axis=0) - hull
        angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    else:
        d = xy - xy.mean(axis=0)
        _, vecs = np.linalg.eigh(d.T @ d + 1e-12 * np.eye(2))
        angles = np.array([np.arctan2(vecs[1, 1], vecs[0, 1])])
    c, s = np.cos(angles), np.sin(angles)
    a = c[:, None] * hull[None, :, 0] + s[:, None] * hull[None, :, 1]
    b = -s[:, None] * hull[None, :, 0] + c[:, None] * hull[None, :, 1]
    ea = a.max(axis=1) - a.min(axis=1)
    eb = b.max(axis=1) - b.min(axis=1)
    k = int(np.argmin(ea * eb))
    ca = 0.5 * (a[k].max() + a[k].min())
    cb = 0.5 * (b[k].max() + b[k].min())
    cx, cy = c[k] * ca - s[k] * cb, s[k] * ca + c[k] * cb
    yaw = angles[k] if ea[k] >= eb[k] else angles[k] + np.pi / 2
    yaw = float(np.mod(yaw + np.pi / 2, np.pi) - np.pi / 2)
    return det.Box(float(cx), float(cy), float(max(ea[k], eb[k])), float(min(ea[k], eb[k])), yaw)


def _needs_calipers(pts: np.ndarray, c: det.Candidate) -> bool:
    """Whether ``segment`` fits this cluster's box by rotating calipers (else the axis-aligned box)."""
    xy = pts[c.indices, :2]
    extent = np.ptp(xy, axis=0).max()
    return (len(c.indices) >= det.MIN_CLUSTER_POINTS and c.height >= det.GATE_HEIGHT_M[0]
            and extent <= det.SPLIT_WIDTH_M[1] * np.sqrt(2)
            and not (c.height > det.GATE_HEIGHT_M[1] and extent * np.sqrt(2) <= det.SPLIT_WIDTH_M[0]))


def _frames() -> list[tuple[str, np.ndarray]]:
    out = []
    for preset, seed in (("fx8", 11), ("hdl32", 12)):
        out += [(f"{preset}-{k}", simulated_frame(EVAL_STREAM, seed, k, preset=preset).points.astype(float))
                for k in range(3)]
    return out


def _real_frame(shared_data) -> np.ndarray:
    from pedcal.detect.detect_cli import detect_file

    files = sorted((shared_data / "sustech_points").glob("*.pcd"))
    if not files:
        pytest.skip(f"no SUSTech frames in {shared_data / 'sustech_points'}")
    return detect_file(files[0], det.load_model()).points  # floor-referenced


def _check_frame(pts: np.ndarray) -> int:
    """Features of every cluster, every rotating-calipers box and ``detect``'s output against the
    reference; returns the number of clusters checked."""
    model = det.load_model()
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= det.MAX_RANGE_M]  # as detect() does
    steps = scan_steps_rad(pts)
    cands = det.segment(pts, cut_low=det.FAMILY_CUT_LOW[det.model_family(scan_steps=steps)])  # as detect() does
    assert cands
    clusters = [pts[c.indices] for c in cands]
    expected = np.vstack([reference_cluster_features(c, steps) for c in clusters])
    got = features_matrix(clusters, steps)
    assert got.shape == expected.shape == (len(cands), N_FEATURES)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    for c in cands:
        if _needs_calipers(pts, c):
            ref = reference_min_area_box(pts[c.indices, :2])
            assert np.allclose([c.box.cx, c.box.cy, c.box.width, c.box.depth, c.box.yaw],
                               [ref.cx, ref.cy, ref.width, ref.depth, ref.yaw], rtol=0, atol=1e-9)
            if c.gated:  # (a wide cluster cut at its heads stays ungated whatever its box)
                assert det.passes_gate(c.height, ref.width, ref.depth, len(c.indices))
    gated = [c for c in cands if c.gated]
    pts_m = det.intensity_for(pts, getattr(model, "metadata_", {}).get("intensity", "raw"))  # as the model reads it
    score = model.predict_proba(np.vstack([reference_cluster_features(pts_m[c.indices], steps)[:model.n_features_]
                                           for c in gated])) if gated else np.zeros(0)
    got_dets = det.detect(pts, model)
    assert len(got_dets) == len(gated)
    for d, c, s in zip(got_dets, gated, score, strict=True):
        assert (d.is_person, d.n_points) == (bool(s >= 0.5), len(c.indices))
        assert [d.x, d.y, d.height, d.width, d.depth, d.yaw, d.score] == pytest.approx(
            [c.box.cx, c.box.cy, c.height, c.box.width, c.box.depth, c.box.yaw, s], abs=1e-9)
    return len(cands)


@pytest.mark.parametrize("name_pts", _frames(), ids=lambda v: v[0])
def test_simulated_frames_match_the_per_cluster_reference(name_pts):
    assert _check_frame(name_pts[1]) >= 3


def test_real_sustech_frame_matches_the_per_cluster_reference(shared_data):
    assert _check_frame(_real_frame(shared_data)) > 500


def test_constructed_edge_cases_match_the_reference():
    rng = np.random.default_rng(3)
    clusters = [
        np.array([[1.0, 0.5, 0.2, 0.3]]),  # one point
        np.array([[1.0, 0.5, 0.2, 0.3], [1.1, 0.5, 1.0, 0.4]]),  # two
        np.tile([[2.0, 0.0, 1.0, 0.5]], (5, 1)),  # identical points
        np.column_stack([np.full(50, 3.0), np.full(50, 4.0), rng.uniform(0, 1.7, 50), np.full(50, 0.5)]),
        np.column_stack([rng.normal(-2, 0.2, (300, 2)), rng.uniform(-0.3, 2.5, 300), rng.uniform(-0.2, 1.4, 300)]),
        rng.normal([5.0, 5.0, 1.0], 0.3, (40, 3)),  # no intensity column
    ]
    steps = (np.radians(0.2), np.radians(1.0))
    np.testing.assert_allclose(features_matrix(clusters, steps),
                               np.vstack([reference_cluster_features(c, steps) for c in clusters]), rtol=0, atol=1e-9)
    # without the frame's steps, each cluster's own points estimate them
    np.testing.assert_allclose(features_matrix(clusters),
                               np.vstack([reference_cluster_features(c, scan_steps_rad(c)) for c in clusters]),
                               rtol=0, atol=1e-9)


def test_degenerate_boxes_match_the_reference():
    rng = np.random.default_rng(4)
    cases = [np.array([[1.0, 2.0]]), np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]),
             np.zeros((4, 2)), rng.normal(0, 0.3, (200, 2))]
    xy = np.concatenate(cases)
    groups = np.split(np.arange(len(xy)), np.cumsum([len(c) for c in cases])[:-1])
    assert det.min_area_boxes(xy, groups) == [reference_min_area_box(c) for c in cases]
