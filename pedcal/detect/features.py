"""Kidono et al.'s 213 cluster features (Kidono, Miyasaka, Watanabe, Naito, Miura, "Pedestrian
recognition using high-definition LIDAR", IEEE IV 2011), as used by Misu and Miura (Sec. 3),
and 47 metric height profiles after them.

A cluster is an (N, 4) array ``x, y, z, intensity`` in the robot's (sensor's) base frame: x, y
horizontal with the sensor at the origin, z up with z = 0 at the floor, metres.

The vector is the concatenation of these blocks (start index, count):

==============================================  =====  =====
block                                           start  count
==============================================  =====  =====
f1  number of points                                0      1
f2  minimum horizontal distance to the sensor       1      1
f3  3-D covariance (xx, xy, xz, yy, yz, zz)         2      6
f4  normalized moment of inertia tensor             8      6
f5  2-D covariance of the main plane in 3 zones    14      9
f6  normalized 2-D histogram, main plane 14x7      23     98
f7  normalized 2-D histogram, secondary 9x5       121     45
f8  slice feature, 10 slices x (length, width)    166     20
shape total                                               186
f9  intensity mean and standard deviation         186      2
f10 normalized intensity histogram, 25 bins       188     25
reflectance total                                          27
Kidono total                                              213
g1  height bands, 10 x (length, largest gap)      213     20
g2  top profile, 8 x (length, width, share)       233     24
g3  lowest z, highest z, centroid distance        257      3
g4  in the scan's rays: area, rows, columns, fill  260      4
g5  pole or person: eigen shape, widths            264      9
==============================================  =====  =====
total                                                     273

Blocks g1-g3 extend Kidono's set with metric profiles that do not depend on the sensor's
resolution or the cluster's own height (Kidono's slices do: they split the cluster's height
into tenths): g1 cuts the floor-referenced height 0-2 m into 0.2 m bands and gives, per band,
the extent along e1 and the largest gap between consecutive points along e1 (two legs; a pot
is one block); g2 cuts the top 0.6 m of the cluster into 0.075 m bands below its highest point
and gives the extents along e1 and e2 and the share of the points (head, neck and shoulders
against the rounded top of a plant or a coat); g3 says where the visible part starts and ends
(a person close to a narrow-FOV LIDAR is cut at the knees and the head) and how far away it is.
On simulated FX8 frames they raise recall and precision by about one point each.

Block g4 measures the cluster in the scan's own rays, given the frame's azimuth and elevation
steps (``scan_steps_rad``, estimated from the whole cloud): with r the centroid's horizontal
distance, the area its points stand for, n (r daz)(r del) in m^2; the rows and columns of rays its
height and bearing span, dz / (r del) + 1 and dbearing / daz + 1; and the share of those rays
that hit it, n / (rows columns). How many points a person holds falls with range squared and
differs fifteen-fold between the trained LIDARs, so the count alone cannot tell a thin pole 10 m
from a 40-beam LIDAR (tens of points) from a person 30 m from a 16-beam one (as many): in the
scan's rays the pole covers a few hundredths of a square metre and the person half of one.
Without the steps (``scan_steps_rad=None``) each cluster's own points estimate them; when they
cannot (too few points), g4 is 0.

Block g5 tells a thin pole or sign post from a person when a sparse scan leaves few points: from
the eigenvalues l1 >= l2 >= l3 of the 3-D covariance, linearity (l1 - l2) / l1, planarity
(l2 - l3) / l1 and scattering l3 / l1 (a pole is a line, a sign a plane, a person a volume);
verticality, |z| of the principal axis; the horizontal rms radius sqrt(var x + var y), m; the
widest extent along e1 over the torso and shoulders (0.8-1.6 m above the floor) and the extent
along e1 of the top 0.25 m (the head), m, and their ratio (a person's head is narrower than
the shoulders, a post's top is as wide as its shaft, a sign's wider); and the box's width over
its height. Undefined values (a single point, no point at those heights) are 0.

Intensity units differ between sensors (KITTI's reflectance 0-1, Argoverse's 0-255, a
simulator's 0-1, none at all): ``frame_normalized_intensity`` divides a frame's intensities by
their 95th percentile before the features see them, so f9-f10 describe a cluster relative to its
own frame.

The cluster's own axes: e1 is the major principal axis of the horizontal (x, y) spread, e2 the
minor one, signed so that e2 points away from the sensor (e1 = e2 rotated by +90 deg). The *main
plane* is the vertical plane spanned by e1 and z, the *secondary plane* the one spanned by e2
and z. Histograms use a fixed metric window (u, v in [-0.6, 0.6] m about the centroid, the gate's
largest half width; z in [0, 2.1] m above the floor; values outside are clipped into the edge
bins) and are divided by the number of points, so they sum to 1. Every block is finite for any
cluster of at least one point: undefined statistics (covariance of one point, empty zones or
slices) are 0.
"""

from __future__ import annotations

import numpy as np

N_FEATURES = 273
N_FEATURES_BEFORE_G5 = 264  # models trained before block g5 read the first 264
N_KIDONO = 213  # Kidono et al.'s features come first

# (name, count) in order; the sum is checked at import.
BLOCKS: tuple[tuple[str, int], ...] = (
    ("n_points", 1),
    ("min_distance_m", 1),
    ("covariance_3d", 6),
    ("inertia_tensor", 6),
    ("covariance_2d_zones", 9),
    ("hist_main_plane", 14 * 7),
    ("hist_secondary_plane", 9 * 5),
    ("slices", 10 * 2),
    ("intensity_mean_std", 2),
    ("intensity_hist", 25),
    ("height_bands", 10 * 2),
    ("top_profile", 8 * 3),
    ("z_extent_distance", 3),
    ("scan_normalized", 4),
    ("pole_or_person", 9),
)
assert sum(n for _, n in BLOCKS) == N_FEATURES

HALF_WIDTH_M = 0.6
Z_TOP_M = 2.1
N_SLICES = 10
BAND_M = 0.2  # g1: height bands of 0.2 m from the floor up to 2.0 m
N_BANDS = 10
TOP_BAND_M = 0.075  # g2: bands below the highest point
N_TOP_BANDS = 8
INTENSITY_MAX = 1.0  # intensities are reflectances in [0, 1] (KITTI's scale); larger values clip
MIN_RANGE_M = 0.3  # g4: nearer centroids count as this far
# scan_steps_rad: elevated points (above STEP_MIN_HEIGHT_M, horizontally STEP_RANGE_M from the sensor)
STEP_MIN_HEIGHT_M = 0.3
STEP_RANGE_M = (1.0, 40.0)
STEP_MAX_POINTS = 5000
STEP_MIN_GAP_RAD = np.radians(0.1)  # elevation gaps smaller than this are one scan line's jitter
DEFAULT_SENSOR_HEIGHT_M = 1.0
TORSO_BAND_M = (0.8, 1.6)  # g5: torso and shoulders above the floor
HEAD_DEPTH_M = 0.25  # g5: the top of the cluster
INTENSITY_PERCENTILE = 95.0  # frame_normalized_intensity


def block_slices() -> dict[str, slice]:
    """Where each named block lives in the 213-vector."""
    out, start = {}, 0
    for name, n in BLOCKS:
        out[name] = slice(start, start + n)
        start += n
    return out


_BLOCK_SLICES = block_slices()
_UPPER_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # xx, xy, xz, yy, yz, zz


class _Segments:
    """Clusters stacked one after another: segment reductions over each cluster's points."""

    def __init__(self, sizes: np.ndarray):
        self.k = len(sizes)
        self.n = sizes.astype(float)
        self.starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self.cid = np.repeat(np.arange(self.k), sizes)  # cluster of every point

    def sum(self, x: np.ndarray) -> np.ndarray:
        return np.add.reduceat(x, self.starts, axis=0)

    def mean(self, x: np.ndarray) -> np.ndarray:
        return self.sum(x) / (self.n if x.ndim == 1 else self.n[:, None])

    def extents(self, bins: np.ndarray, n_bins: int, values: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
        """(k, n_bins, columns) max - min of ``values`` per cluster and bin; 0 where a bin is empty."""
        code = self.cid * n_bins + bins
        vals = values.reshape(len(values), -1)
        if keep is not None:
            code, vals = code[keep], vals[keep]
        lo = np.full((self.k * n_bins, vals.shape[1]), np.inf)
        hi = np.full((self.k * n_bins, vals.shape[1]), -np.inf)
        np.minimum.at(lo, code, vals)
        np.maximum.at(hi, code, vals)
        return np.where(np.isfinite(lo), hi - lo, 0.0).reshape(self.k, n_bins, -1)

    def hist(self, bins: np.ndarray, n_bins: int, keep: np.ndarray | None = None) -> np.ndarray:
        """(k, n_bins) count of each cluster's points per bin, divided by the cluster's size."""
        code = self.cid * n_bins + bins
        if keep is not None:
            code = code[keep]
        return np.bincount(code, minlength=self.k * n_bins).reshape(self.k, n_bins) / self.n[:, None]


def _cov2_zones(seg: _Segments, zone: np.ndarray, n_zones: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k, n_zones, 3): (var a, cov ab, var b) of each cluster's points per zone; zeros when a zone
    holds fewer than 2 points."""
    code = seg.cid * n_zones + zone
    m = seg.k * n_zones
    count = np.bincount(code, minlength=m).astype(float)
    safe = np.maximum(count, 1.0)
    da = a - (np.bincount(code, a, m) / safe)[code]
    db = b - (np.bincount(code, b, m) / safe)[code]
    out = np.column_stack([np.bincount(code, da * da, m), np.bincount(code, da * db, m),
                           np.bincount(code, db * db, m)]) / safe[:, None]
    out[count < 2] = 0.0
    return out.reshape(seg.k, n_zones, 3)


def _hist_bins(z: np.ndarray, s: np.ndarray, n_z: int, n_s: int) -> np.ndarray:
    """Bin of (z, s) in an (n_z x n_s) grid, z in [0, Z_TOP_M], s in +-HALF_WIDTH_M, clipped."""
    iz = np.clip((z / Z_TOP_M * n_z).astype(int), 0, n_z - 1)
    i_s = np.clip(((s + HALF_WIDTH_M) / (2 * HALF_WIDTH_M) * n_s).astype(int), 0, n_s - 1)
    return iz * n_s + i_s


def _axes(seg: _Segments, centred_xy: np.ndarray, centroid_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e1, e2) of every cluster, (k, 2) each: horizontal major / minor principal axes, e2 pointing
    away from the sensor."""
    cov = np.empty((seg.k, 2, 2))
    cov[:, 0, 0] = seg.sum(centred_xy[:, 0] ** 2)
    cov[:, 0, 1] = cov[:, 1, 0] = seg.sum(centred_xy[:, 0] * centred_xy[:, 1])
    cov[:, 1, 1] = seg.sum(centred_xy[:, 1] ** 2)
    cov /= seg.n[:, None, None]
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    e2 = vecs[:, :, 0]
    e2 = np.where(((e2 * centroid_xy).sum(axis=1) < 0)[:, None], -e2, e2)
    return np.column_stack([-e2[:, 1], e2[:, 0]]), e2


def cluster_axes(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e1, e2): horizontal major/minor principal axes, e2 pointing away from the sensor."""
    xy = np.asarray(xy, dtype=float)
    seg = _Segments(np.array([len(xy)]))
    centroid = xy.mean(axis=0)
    e1, e2 = _axes(seg, xy - centroid, centroid[None])
    return e1[0], e2[0]


def scan_steps_rad(points: np.ndarray, sensor_height_m: float = DEFAULT_SENSOR_HEIGHT_M, *,
                   seed: int = 0) -> tuple[float, float]:
    """(azimuth step, elevation step) between neighbouring rays of the LIDAR that made a cloud, rad,
    estimated from its points (floor-referenced, the sensor at (0, 0, ``sensor_height_m``)).

    Only points above the floor's clutter and within ``STEP_RANGE_M`` are used (at most
    ``STEP_MAX_POINTS``: whole 5-degree azimuth sectors, so every point keeps its neighbours), as
    directions seen from the sensor. The azimuth step is the median azimuth difference to each
    point's nearest neighbour with elevation differences counted fivefold (a point's neighbour
    along its own scan line). The elevation step is the median elevation gap between consecutive
    points of one azimuth column one step wide, gaps under ``STEP_MIN_GAP_RAD`` left out: each scan
    line puts about one point in a column, also when a spinning LIDAR's lasers fire at staggered
    azimuths. A range error moves a point along its ray, not across, so noise hardly matters; a
    sensor height off by a metre changes the steps by a few percent. (nan, nan) when the cloud
    holds too few such points."""
    from scipy.spatial import cKDTree

    xyz = np.asarray(points, dtype=float)[:, :3]
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    keep = (xyz[:, 2] > STEP_MIN_HEIGHT_M) & (r > STEP_RANGE_M[0]) & (r < STEP_RANGE_M[1])
    az = np.arctan2(xyz[keep, 1], xyz[keep, 0])
    el = np.arctan2(xyz[keep, 2] - sensor_height_m, r[keep])
    if len(az) > STEP_MAX_POINTS:
        sector = np.minimum(((az + np.pi) / np.radians(5.0)).astype(np.int64), 71)
        order = np.random.default_rng(seed).permutation(72)
        take = order[np.cumsum(np.bincount(sector, minlength=72)[order]) <= STEP_MAX_POINTS]
        az, el = az[np.isin(sector, take)], el[np.isin(sector, take)]
    if len(az) < 10:
        return float("nan"), float("nan")
    _, j = cKDTree(np.column_stack([az, 5.0 * el])).query(np.column_stack([az, 5.0 * el]), k=2)
    daz = float(np.median(np.abs(az[j[:, 1]] - az)))
    if not daz > 0:
        return float("nan"), float("nan")
    column = np.round(az / daz).astype(np.int64)
    order = np.lexsort((el, column))
    same = column[order][1:] == column[order][:-1]
    gaps = np.diff(el[order])[same]
    gaps = gaps[gaps > STEP_MIN_GAP_RAD]
    return (daz, float(np.median(gaps))) if len(gaps) else (float("nan"), float("nan"))


def frame_normalized_intensity(points: np.ndarray) -> np.ndarray:
    """The (N, 4) frame with its intensities divided by their ``INTENSITY_PERCENTILE``th percentile
    over the points with a positive intensity, so frames of sensors with other intensity units
    (0-1, 0-255) give clusters the same features. A frame with no positive intensity (none
    recorded) or an (N, 3) one gets intensity 0; NaN intensities count as 0."""
    pts = np.asarray(points, dtype=float)
    out = np.zeros((len(pts), 4))
    out[:, :3] = pts[:, :3]
    if pts.ndim == 2 and pts.shape[1] > 3 and len(pts):
        inten = np.nan_to_num(pts[:, 3], nan=0.0, posinf=0.0, neginf=0.0)
        positive = inten[inten > 0]
        if len(positive):
            out[:, 3] = np.maximum(inten, 0.0) / np.percentile(positive, INTENSITY_PERCENTILE)
    return out


def cluster_features(points: np.ndarray, scan_steps=None) -> np.ndarray:
    """The N_FEATURES-vector of one cluster (N, 4) ``x, y, z, intensity``; see the module table."""
    return features_matrix([points], scan_steps)[0]


def features_matrix(clusters, scan_steps=None) -> np.ndarray:
    """(len(clusters), N_FEATURES) features of a sequence of clusters, each (N, 4) ``x, y, z, intensity``
    (N, 3: intensity 0); see the module table. ``scan_steps``: the frame's (azimuth, elevation)
    ray steps in rad (``scan_steps_rad``) for block g4; None estimates them from each cluster.

    All clusters are computed at once: their points are stacked and every statistic is a
    segment reduction (``np.add.reduceat``, ``np.bincount``, ``ufunc.at``) over cluster ids.
    """
    if len(clusters) == 0:
        return np.zeros((0, N_FEATURES))
    arrs = [np.asarray(c, dtype=float) for c in clusters]
    for pts in arrs:
        if pts.ndim != 2 or pts.shape[1] < 3 or len(pts) == 0:
            raise ValueError(f"a cluster is a non-empty (N, 4) array, got shape {pts.shape}")
    seg = _Segments(np.array([len(a) for a in arrs]))
    xyz = np.concatenate([a[:, :3] for a in arrs])
    inten = np.concatenate([a[:, 3] if a.shape[1] > 3 else np.zeros(len(a)) for a in arrs])
    cid, n = seg.cid, seg.n
    f = np.zeros((seg.k, N_FEATURES))
    b = _BLOCK_SLICES

    f[:, b["n_points"]] = n[:, None]
    f[:, b["min_distance_m"]] = np.minimum.reduceat(np.sqrt((xyz[:, :2] ** 2).sum(axis=1)), seg.starts)[:, None]

    mean = seg.mean(xyz)
    centred = xyz - mean[cid]
    cov3 = np.column_stack([seg.sum(centred[:, i] * centred[:, j]) for i, j in _UPPER_PAIRS]) / n[:, None]
    f[:, b["covariance_3d"]] = cov3
    # Moment of inertia about the centroid, I = sum(|r|^2 E - r r^T), divided by N.
    trace = cov3[:, 0] + cov3[:, 3] + cov3[:, 5]
    f[:, b["inertia_tensor"]] = np.where(np.array([1, 0, 0, 1, 0, 1], bool), trace[:, None], 0.0) - cov3

    e1, e2 = _axes(seg, centred[:, :2], mean[:, :2])
    u = centred[:, 0] * e1[cid, 0] + centred[:, 1] * e1[cid, 1]
    v = centred[:, 0] * e2[cid, 0] + centred[:, 1] * e2[cid, 1]
    z = xyz[:, 2]
    z_min, z_max = np.minimum.reduceat(z, seg.starts), np.maximum.reduceat(z, seg.starts)

    # Main plane (u, z) split into the upper half and the lower left and right halves.
    upper = z > (0.5 * (z_min + z_max))[cid]
    zone = np.where(upper, 0, np.where(u < 0, 1, 2))
    f[:, b["covariance_2d_zones"]] = _cov2_zones(seg, zone, 3, u, z).reshape(seg.k, 9)

    f[:, b["hist_main_plane"]] = seg.hist(_hist_bins(z, u, 14, 7), 14 * 7)
    f[:, b["hist_secondary_plane"]] = seg.hist(_hist_bins(z, v, 9, 5), 9 * 5)

    # Slice feature: N_SLICES equal height slices between the lowest and highest point; in each,
    # the extent along e1 (length) and along e2 (width); empty slices give 0.
    height = np.maximum(z_max - z_min, 1e-9)
    k = np.clip(((z - z_min[cid]) / height[cid] * N_SLICES).astype(int), 0, N_SLICES - 1)
    uv = np.column_stack([u, v])
    f[:, b["slices"]] = seg.extents(k, N_SLICES, uv).reshape(seg.k, -1)

    i_mean = seg.mean(inten)
    f[:, b["intensity_mean_std"]] = np.column_stack([i_mean, np.sqrt(seg.mean((inten - i_mean[cid]) ** 2))])
    ib = np.clip((inten / INTENSITY_MAX * 25).astype(int), 0, 24)
    f[:, b["intensity_hist"]] = seg.hist(ib, 25)

    # g1: per 0.2 m band of floor height, the extent along e1 and the largest gap between
    # consecutive points along e1.
    band = (z / BAND_M).astype(int)
    inside = (band >= 0) & (band < N_BANDS)
    g1 = np.zeros((seg.k, N_BANDS, 2))
    if inside.any():
        g1[:, :, :1] = seg.extents(band, N_BANDS, u, inside)
        code = (cid * N_BANDS + band)[inside]
        ui = u[inside]
        order = np.lexsort((ui, code))  # by cluster and band, then along e1
        code, ui = code[order], ui[order]
        same = code[1:] == code[:-1]
        gap = np.zeros(seg.k * N_BANDS)
        np.maximum.at(gap, code[1:][same], np.diff(ui)[same])
        g1[:, :, 1] = gap.reshape(seg.k, N_BANDS)
    f[:, b["height_bands"]] = g1.reshape(seg.k, -1)

    # g2: per band below the highest point, the extents along e1 and e2 and the share of points.
    tb = ((z_max[cid] - z) / TOP_BAND_M).astype(int)
    near_top = tb < N_TOP_BANDS
    top = np.concatenate([seg.extents(tb, N_TOP_BANDS, uv, near_top),
                          seg.hist(tb, N_TOP_BANDS, near_top)[:, :, None]], axis=2)
    f[:, b["top_profile"]] = top.reshape(seg.k, -1)

    # g3
    r_c = np.hypot(mean[:, 0], mean[:, 1])
    f[:, b["z_extent_distance"]] = np.column_stack([z_min, z_max, r_c])

    # g4: the cluster in the scan's rays
    if scan_steps is None:
        steps = np.array([scan_steps_rad(a) for a in arrs])
    else:
        steps = np.broadcast_to(np.asarray(scan_steps, dtype=float), (seg.k, 2))
    daz, d_el = steps[:, 0], steps[:, 1]
    r = np.maximum(r_c, MIN_RANGE_M)
    bearing = np.arctan2(xyz[:, 1], xyz[:, 0]) - np.arctan2(mean[:, 1], mean[:, 0])[cid]
    bearing = np.angle(np.exp(1j * bearing))  # about the centroid's bearing, no wrap at +-pi
    span = np.maximum.reduceat(bearing, seg.starts) - np.minimum.reduceat(bearing, seg.starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        rows = (z_max - z_min) / (r * d_el) + 1.0
        cols = span / daz + 1.0
        g4 = np.column_stack([n * r * daz * r * d_el, rows, cols, n / (rows * cols)])
    f[:, b["scan_normalized"]] = np.where(np.isfinite(g4), g4, 0.0)
    f[:, b["pole_or_person"]] = _pole_or_person(seg, cov3, u, z, z_min, z_max)
    return f


def _pole_or_person(seg: _Segments, cov3: np.ndarray, u: np.ndarray, z: np.ndarray, z_min: np.ndarray,
                    z_max: np.ndarray) -> np.ndarray:
    """Block g5 (see the module docstring), (k, 9)."""
    cov = np.empty((seg.k, 3, 3))
    for c, (i, j) in enumerate(_UPPER_PAIRS):
        cov[:, i, j] = cov[:, j, i] = cov3[:, c]
    vals, vecs = np.linalg.eigh(cov)  # ascending
    l3, l2, l1 = vals[:, 0], vals[:, 1], vals[:, 2]
    safe = np.where(l1 > 0, l1, 1.0)
    shape = np.column_stack([(l1 - l2) / safe, (l2 - l3) / safe, np.maximum(l3, 0.0) / safe]) * (l1 > 0)[:, None]
    vertical = np.abs(vecs[:, 2, 2]) * (l1 > 0)
    radius = np.sqrt(np.maximum(cov3[:, 0] + cov3[:, 3], 0.0))
    cid = seg.cid
    torso = (z >= TORSO_BAND_M[0]) & (z <= TORSO_BAND_M[1])
    head = z >= (z_max - HEAD_DEPTH_M)[cid]
    zeros = np.zeros(len(z), dtype=np.int64)
    torso_w = seg.extents(zeros, 1, u, torso)[:, 0, 0]
    head_w = seg.extents(zeros, 1, u, head)[:, 0, 0]
    ratio = np.where(torso_w > 0, head_w / np.where(torso_w > 0, torso_w, 1.0), 0.0)
    width = seg.extents(zeros, 1, u)[:, 0, 0]
    height = z_max - z_min
    aspect = np.where(height > 0, width / np.where(height > 0, height, 1.0), 0.0)
    return np.column_stack([shape, vertical, radius, torso_w, head_w, ratio, aspect])
