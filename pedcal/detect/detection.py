"""Person detection in a 3-D LIDAR frame, step by step as Misu and Miura (Sec. 3):

1. ``grid_cells``: the points go onto a horizontal 2-D grid (``cell_size_m``, ~0.1 m);
2. ``object_cells``: a cell is an object cell when its highest and lowest points differ by more
   than ``min_cell_span_m`` (0.2 m); flat cells (floor, low clutter) are not;
3. ``cluster_cells``: Euclidean clustering of the object cells = connected components with
   8-connectivity (``scipy.ndimage.label``), optionally bridging gaps of ``gap_cells`` cells;
4. ``cluster_points``: a cluster's points are all the points in its cells above the floor;
5. ``min_area_box``: the minimum-area box of the points' horizontal convex hull by rotating
   calipers, giving width >= depth and the yaw of the width axis; height = max z (floor-based);
6. ``passes_gate``: 0.8 <= h <= 2.0, w <= 1.2, d <= 1.2 m; a cluster taller than 2 m is cut
   below 2 m (a person against a wall), one 0.8-3.2 m wide at its heads (``split_by_heads``:
   people side by side; for the FX8 model's frames, one with a single head is cut free of the low
   objects it touches, ``split_low``: a pushed pram), and the parts are gated in turn (``segment``);
7. the RealAdaBoost classifier on Kidono et al.'s 213 features, 47 metric height profiles and 4
   measures in the scan's own rays (``pedcal.detect.features``; the frame's ray steps are
   estimated once per frame, ``scan_steps_rad``), the model of the frame's sensor family
   (``model_family``: the general one, or the FX8 pair's own).

Frames: points are (N, 4) ``x, y, z, intensity`` in the robot's base (or sensor's) frame with z up
and z = 0 at the floor, metres; ``Detection.x, y`` are the box centre in that frame. ``detect``
takes a cloud as its sensor gives it too (``frame="optical"`` for a camera's optical frame,
``floor="auto"`` for the local ground: ``pedcal.detect.ground``).
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np
import scipy.sparse as sps
from scipy import ndimage
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from pedcal.detect.adaboost import RealAdaBoost, open_model_npz
from pedcal.detect.features import (
    DEFAULT_SENSOR_HEIGHT_M,
    N_FEATURES,
    N_FEATURES_BEFORE_G5,
    features_matrix,
    frame_normalized_intensity,
    scan_steps_rad,
)
from pedcal.detect.model_check import load_checked
from pedcal.errors import PedcalInputError
from pedcal.options import check

CELL_SIZE_M = 0.1
MIN_CELL_SPAN_M = 0.2
FLOOR_TOLERANCE_M = 0.05
MAX_GRID_CELLS = 1 << 24  # a denser grid is compacted (``grid_cells``)
MIN_CLUSTER_POINTS = 5  # fewer points above the floor: a fragment, not gated
GATE_HEIGHT_M = (0.8, 2.0)
MAX_RANGE_M = 60.0  # detect() leaves out points farther from the sensor
GATE_MAX_WIDTH_M = 1.2
GATE_MAX_DEPTH_M = 1.2
SPLIT_WIDTH_M = (0.8, 2.0)  # clusters this wide are tried for two or three heads (not walls, cars)
# Wider clusters, up to GROUP_WIDTH_M (five or six people shoulder to shoulder), are cut at their
# heads only into three or more parts that each pass the gate's width and show a body's depth
# (GROUP_PART_MIN_DEPTH_M: the visible half of a torso is 0.15-0.3 m deep): a wall with a ragged
# top, cut at its bumps, leaves flat slices.
GROUP_WIDTH_M = 3.2
GROUP_PART_MIN_DEPTH_M = 0.15
HEAD_DIP_M = 0.15
HEAD_KMEANS_STEPS = 3
HEAD_MIN_SHARE = 0.7
HEAD_SEPARATION_M = 0.35
# A wide cluster with one head (a person pushing a pram or trolley, or standing at a chair or box)
# keeps only its cells whose highest point reaches this share of its height: above a pusher's
# hands (0.58 h) and a pram's top, below the shoulders (0.82 h) (``split_low``).
LOW_CUT_SHARE = 0.62
# A cluster lower than the gate's 0.8 m whose top is hidden (``top_occluded``: the rays just above
# it end on something nearer, as a person's legs under a sign or behind another person) shows no
# height to gate on: it is gated on its width and depth alone (``segment(occluded_low=True)``).
# Nearer means by more than the range noise of the trained sensors (3 sigma of 0.03 m) and a
# person's depth at the legs can show, and the rows above are the next two scan lines.
OCCLUDER_MARGIN_M = 0.2
OCCLUSION_ROWS = 2
# Hidden low clusters whose centres are this close are one object (a walking person's legs, a
# stride apart at the knees; people's centres are further apart, shoulder width and more).
LEG_SPAN_M = 0.5


@dataclass(frozen=True)
class Detection:
    x: float  # box centre, m
    y: float
    height: float  # m above the floor (max z)
    width: float  # longer horizontal side of the box, m
    depth: float  # shorter side, m
    yaw: float  # direction of the width side, rad in [-pi/2, pi/2)
    score: float  # P(person) from the classifier (nan when no classifier ran)
    is_person: bool
    n_points: int

    def to_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Box:
    cx: float
    cy: float
    width: float
    depth: float
    yaw: float


# ------------------------------------------------------------------------------------------ steps
def grid_cells(points: np.ndarray, cell_size_m: float = CELL_SIZE_M) -> tuple[np.ndarray, tuple[int, int],
                                                                                np.ndarray]:
    """Step 1: per point (row, col) cell index on a grid anchored at the cloud's minimum corner.

    Returns ``(ij (N, 2) int, shape (rows, cols), origin_xy (2,))``.
    """
    xy = points[:, :2]
    origin = xy.min(axis=0) if len(xy) else np.zeros(2)
    ij = np.floor((xy - origin) / cell_size_m).astype(np.int64)
    shape = tuple(int(v) for v in (ij.max(axis=0) + 1)) if len(ij) else (0, 0)
    if shape[0] * shape[1] > MAX_GRID_CELLS:
        ij = np.column_stack([_compact_axis(ij[:, 0]), _compact_axis(ij[:, 1])])
        shape = tuple(int(v) for v in (ij.max(axis=0) + 1))
        if shape[0] * shape[1] > 4 * MAX_GRID_CELLS:
            raise PedcalInputError(f"the cloud spreads over {np.ptp(xy[:, 0]):.0f} x {np.ptp(xy[:, 1]):.0f} m "
                                   f"with too many distinct {cell_size_m} m cells for the detection grid; crop it "
                                   "to the sensor's range")
    return ij, shape, origin


def _compact_axis(k: np.ndarray, max_gap: int = 8) -> np.ndarray:
    """Cell indices along one axis with every run of empty rows longer than ``max_gap`` shortened
    to ``max_gap``: neighbourhoods (and gaps up to ``max_gap`` - 1 cells) are unchanged, but a cloud
    spread over kilometres (a few far or corrupt points) no longer needs a grid of that size."""
    used, inverse = np.unique(k, return_inverse=True)
    step = np.minimum(np.diff(used, prepend=used[0]), max_gap)
    return np.cumsum(step)[inverse]


def cell_z_range(ij: np.ndarray, z: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(highest z, lowest z) of the points in each cell, (rows, cols) maps (-inf / +inf when empty)."""
    flat = ij[:, 0] * shape[1] + ij[:, 1]
    n = shape[0] * shape[1]
    z_hi = np.full(n, -np.inf)
    z_lo = np.full(n, np.inf)
    np.maximum.at(z_hi, flat, z)
    np.minimum.at(z_lo, flat, z)
    return z_hi.reshape(shape), z_lo.reshape(shape)


def object_cells(ij: np.ndarray, z: np.ndarray, shape: tuple[int, int],
                 min_cell_span_m: float = MIN_CELL_SPAN_M) -> np.ndarray:
    """Step 2: boolean (rows, cols) map of the cells whose max z - min z > ``min_cell_span_m``."""
    z_hi, z_lo = cell_z_range(ij, z, shape)
    return (z_hi - z_lo) > min_cell_span_m


def cluster_cells(occupied: np.ndarray, gap_cells: int = 0) -> tuple[np.ndarray, int]:
    """Step 3: label connected object cells (8-connectivity). With ``gap_cells`` > 0, cells up to
    that many empty cells apart join one cluster (the labels stay on the object cells only)."""
    structure = np.ones((3, 3), dtype=bool)
    if gap_cells > 0:
        grown = ndimage.binary_dilation(occupied, structure=structure, iterations=gap_cells)
        labels, n = ndimage.label(grown, structure=structure)
        labels = np.where(occupied, labels, 0)
        # relabel to 1..k without the labels that only covered dilated cells
        used = np.unique(labels[labels > 0])
        remap = np.zeros(labels.max() + 1, dtype=np.int64)
        remap[used] = np.arange(1, len(used) + 1)
        return remap[labels], len(used)
    labels, n = ndimage.label(occupied, structure=structure)
    return labels, int(n)


def cluster_points(points: np.ndarray, ij: np.ndarray, labels: np.ndarray,
                   floor_tolerance_m: float = FLOOR_TOLERANCE_M) -> list[np.ndarray]:
    """Step 4: indices into ``points`` of each cluster (label 1..k): all points in its cells
    higher than ``floor_tolerance_m`` above the floor."""
    point_label = labels[ij[:, 0], ij[:, 1]]
    keep = (point_label > 0) & (points[:, 2] > floor_tolerance_m)
    idx = np.flatnonzero(keep)
    lab = point_label[idx]
    order = np.argsort(lab, kind="stable")
    idx, lab = idx[order], lab[order]
    splits = np.flatnonzero(np.diff(lab)) + 1
    return [g for g in np.split(idx, splits) if len(g)]


def min_area_box(xy: np.ndarray) -> Box:
    """Step 5: minimum-area enclosing box by rotating calipers on the convex hull.

    One side of the minimum box lies on a hull edge (Freeman and Shapira 1975), so every edge
    direction is tried at once. Width is the longer side, ``yaw`` its direction in [-pi/2, pi/2).
    Degenerate inputs (fewer than 3 points, collinear) fall back to the principal axes.
    """
    xy = np.asarray(xy, dtype=float)
    return min_area_boxes(xy, [np.arange(len(xy))])[0]


def min_area_boxes(xy: np.ndarray, groups: list[np.ndarray]) -> list[Box]:
    """``min_area_box`` of each group of rows of ``xy`` (N, 2): a convex hull per group (Qhull),
    then the rotating calipers of all groups at once: every (group, edge direction, hull point)
    projection in one array, reduced per direction and per group."""
    hulls, angles = [], []
    for idx in groups:
        pts = xy[idx]
        try:
            hull = pts[ConvexHull(pts).vertices]
        except (QhullError, ValueError):
            hull = pts
        if len(hull) < 3:
            d = pts - pts.mean(axis=0)
            _, vecs = np.linalg.eigh(d.T @ d + 1e-12 * np.eye(2))
            angles.append(np.array([np.arctan2(vecs[1, 1], vecs[0, 1])]))
        else:
            angles.append(None)
        hulls.append(hull)
    m = np.array([len(h) for h in hulls])
    h_start = np.concatenate([[0], np.cumsum(m)[:-1]])
    hull = np.concatenate(hulls)
    group_of_point = np.repeat(np.arange(len(groups)), m)
    # edge directions mod pi/2 of every hull (each vertex to the next, the last to the first)
    nxt = np.arange(len(hull)) + 1
    nxt[h_start + m - 1] = h_start
    edges = hull[nxt] - hull
    edge_angle = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2)
    # distinct directions per group, ascending (np.unique per group); degenerate groups get theirs
    order = np.lexsort((edge_angle, group_of_point))
    ang, grp = edge_angle[order], group_of_point[order]
    first = np.ones(len(ang), dtype=bool)
    first[1:] = (grp[1:] != grp[:-1]) | (ang[1:] != ang[:-1])
    ang, grp = ang[first], grp[first]
    degenerate = [k for k, a in enumerate(angles) if a is not None]
    if degenerate:
        keep = ~np.isin(grp, degenerate)
        ang = np.concatenate([ang[keep]] + [angles[k] for k in degenerate])
        grp = np.concatenate([grp[keep], degenerate])
        order = np.argsort(grp, kind="stable")
        ang, grp = ang[order], grp[order]
    # every (direction, hull point of its group) pair: (P,) coordinates along both box axes
    reps = m[grp]
    dir_start = np.concatenate([[0], np.cumsum(reps)[:-1]])
    pair_dir = np.repeat(np.arange(len(ang)), reps)
    pair_pt = h_start[grp][pair_dir] + np.arange(len(pair_dir)) - dir_start[pair_dir]
    c, s = np.cos(ang), np.sin(ang)
    hx, hy = hull[pair_pt, 0], hull[pair_pt, 1]
    a = c[pair_dir] * hx + s[pair_dir] * hy
    b = -s[pair_dir] * hx + c[pair_dir] * hy
    a_hi, a_lo = np.maximum.reduceat(a, dir_start), np.minimum.reduceat(a, dir_start)
    b_hi, b_lo = np.maximum.reduceat(b, dir_start), np.minimum.reduceat(b, dir_start)
    ea, eb = a_hi - a_lo, b_hi - b_lo
    area = ea * eb
    # per group, the first direction of least area (np.argmin)
    g_start = np.flatnonzero(np.r_[True, grp[1:] != grp[:-1]])
    least = np.minimum.reduceat(area, g_start)
    k = np.minimum.reduceat(np.where(area == least[grp], np.arange(len(ang)), len(ang)), g_start)
    ca = 0.5 * (a_hi[k] + a_lo[k])
    cb = 0.5 * (b_hi[k] + b_lo[k])
    cx, cy = c[k] * ca - s[k] * cb, s[k] * ca + c[k] * cb
    yaw = np.where(ea[k] >= eb[k], ang[k], ang[k] + np.pi / 2)
    yaw = np.mod(yaw + np.pi / 2, np.pi) - np.pi / 2
    width, depth = np.maximum(ea[k], eb[k]), np.minimum(ea[k], eb[k])
    return [Box(float(cx[i]), float(cy[i]), float(width[i]), float(depth[i]), float(yaw[i])) for i in range(len(k))]


def passes_gate(height_m: float, width_m: float, depth_m: float, n_points: int = MIN_CLUSTER_POINTS) -> bool:
    """Step 6: the size gate 0.8 <= h <= 2.0, w <= 1.2, d <= 1.2 m (and at least
    MIN_CLUSTER_POINTS points, so one stray point in a cell is no candidate)."""
    return (n_points >= MIN_CLUSTER_POINTS and GATE_HEIGHT_M[0] <= height_m <= GATE_HEIGHT_M[1]
            and width_m <= GATE_MAX_WIDTH_M and depth_m <= GATE_MAX_DEPTH_M)


@dataclass
class Candidate:
    """A clustered object that passed (or failed) the gate, before classification."""

    indices: np.ndarray  # into the frame's points
    box: Box
    height: float
    gated: bool


def segment(points: np.ndarray, cell_size_m: float = CELL_SIZE_M, min_cell_span_m: float = MIN_CELL_SPAN_M,
            gap_cells: int = 0, floor_tolerance_m: float = FLOOR_TOLERANCE_M,
            split_tall: bool = True, split_wide: bool = True, cut_low: bool = False,
            occluded_low: bool = False, scan_steps: tuple[float, float] | None = None,
            sensor_xyz: tuple[float, float, float] = (0.0, 0.0, DEFAULT_SENSOR_HEIGHT_M)) -> list[Candidate]:
    """Steps 1-6: every cluster of the frame with its box, height and gate verdict.

    With ``split_tall``, a cluster taller than the gate's 2.0 m is split by its height profile:
    its cells whose highest point is above 2.0 m (a wall or pillar seen up to that height) are
    dropped and the rest is clustered again, so a person standing against a wall or beside a
    pillar becomes a candidate of its own. The parts follow the rejected cluster in the
    list (which stays, ungated); each part is gated as any cluster.

    With ``split_wide``, a cluster 0.8-2.0 m wide (``SPLIT_WIDTH_M``: two or three people side by
    side, who touch in the grid) is cut at its heads (``split_by_heads``); when it has two or more, the parts
    follow and the whole stays ungated; one 2.0-3.2 m wide (``GROUP_WIDTH_M``: a group shoulder to
    shoulder) only into three or more parts of a person's width and depth
    (``GROUP_PART_MIN_DEPTH_M``). With ``cut_low`` too, a wide cluster of one head (a person
    pushing a pram) is cut free of the low objects it touches (``split_low``); a family's frames
    are segmented as its model was trained (``FAMILY_CUT_LOW``).

    With ``occluded_low``, a cluster lower than the gate's 0.8 m whose top is hidden from the sensor
    at ``sensor_xyz`` by something nearer (``top_occluded``, in the frame's ray steps ``scan_steps``,
    rad; estimated when None) is gated on its width and depth alone: a person seen only below the
    waist, past a sign, a plant or another person, is as tall as a person for all the scan can tell.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must be (N, 4) x, y, z, intensity; got shape {pts.shape}")
    if len(pts) == 0:
        return []
    ij, shape, _ = grid_cells(pts, cell_size_m)
    z_hi, z_lo = cell_z_range(ij, pts[:, 2], shape)
    occ = (z_hi - z_lo) > min_cell_span_m
    labels, n = cluster_cells(occ, gap_cells)
    if n == 0:
        return []
    out = _candidates(pts, cluster_points(pts, ij, labels, floor_tolerance_m))
    oversized = [c for c in out if c.height > GATE_HEIGHT_M[1]]
    if split_tall and oversized:
        in_oversized = np.zeros(len(pts), dtype=bool)
        in_oversized[np.concatenate([c.indices for c in oversized])] = True
        low_labels, m = cluster_cells(occ & (z_hi <= GATE_HEIGHT_M[1]), gap_cells)
        if m:
            # a part's cells all lie in one cluster's cells: test its first point
            out += _candidates(pts, [idx for idx in cluster_points(pts, ij, low_labels, floor_tolerance_m)
                                     if in_oversized[idx[0]]])
    if split_wide:
        for i in range(len(out)):
            c = out[i]
            if SPLIT_WIDTH_M[0] < c.box.width <= SPLIT_WIDTH_M[1] and c.height >= GATE_HEIGHT_M[0]:
                parts = split_by_heads(pts, c.indices, cell_size_m)
                if len(parts) < 2:
                    parts = split_low(pts, c.indices, cell_size_m) if cut_low else []
                if parts:
                    out[i] = replace(c, gated=False)
                    out += _candidates(pts, parts)
            elif SPLIT_WIDTH_M[1] < c.box.width <= GROUP_WIDTH_M and c.height >= GATE_HEIGHT_M[0]:
                parts = _candidates(pts, split_by_heads(pts, c.indices, cell_size_m))
                if len(parts) >= 3 and all(p.box.width <= GATE_MAX_WIDTH_M and p.box.depth >= GROUP_PART_MIN_DEPTH_M
                                           for p in parts):
                    out[i] = replace(c, gated=False)
                    out += parts
    if occluded_low:
        out = _gate_occluded_low(pts, out, scan_steps, sensor_xyz)
    return out


def _gate_occluded_low(pts: np.ndarray, cands: list[Candidate], scan_steps, sensor_xyz) -> list[Candidate]:
    """``cands`` and, after them, the clusters lower than the gate whose top is hidden
    (``top_occluded``), those within ``LEG_SPAN_M`` of each other joined (a walking person's two
    legs are two clusters when the grid cells between them are empty), each group gated on its
    width and depth (and point count) alone, unless a gated cluster has its centre within
    ``LEG_SPAN_M``: that one's legs. The low clusters themselves stay ungated."""
    low = [i for i, c in enumerate(cands) if not c.gated and c.height < GATE_HEIGHT_M[0]
           and max(c.box.width, c.box.depth) <= GATE_MAX_WIDTH_M * np.sqrt(2)]
    if not low:
        return cands
    if scan_steps is None:
        scan_steps = scan_steps_rad(pts, float(sensor_xyz[2]))
    hidden = top_occluded(pts, [cands[i].indices for i in low], scan_steps, sensor_xyz)
    low = [i for i, h in zip(low, hidden, strict=True) if h]
    if not low:
        return cands
    # single-link groups of the hidden clusters by their (axis-aligned) box centres
    xy = np.array([[cands[i].box.cx, cands[i].box.cy] for i in low])
    near = np.linalg.norm(xy[:, None] - xy[None], axis=2) <= LEG_SPAN_M
    group = connected_components(sps.csr_matrix(near), directed=False)[1]
    parts = [np.concatenate([cands[low[j]].indices for j in np.flatnonzero(group == g)]) for g in np.unique(group)]
    parts = [idx for idx in parts if len(idx) >= MIN_CLUSTER_POINTS]
    # legs within a stride of a gated cluster's centre are that cluster's (a person whose middle
    # alone is hidden, or whose own torso hides a trailing leg)
    g_xy = np.array([[c.box.cx, c.box.cy] for c in cands if c.gated]).reshape(-1, 2)
    if len(g_xy):
        parts = [idx for idx in parts if np.linalg.norm(g_xy - pts[idx, :2].mean(axis=0), axis=1).min() > LEG_SPAN_M]
    if not parts:
        return cands
    out = list(cands)
    for idx, box in zip(parts, min_area_boxes(pts[:, :2], parts), strict=True):
        ok = box.width <= GATE_MAX_WIDTH_M and box.depth <= GATE_MAX_DEPTH_M
        out.append(Candidate(idx, box, float(pts[idx, 2].max()), ok))
    return out


def top_occluded(pts: np.ndarray, groups: list[np.ndarray], scan_steps, sensor_xyz,
                 margin_m: float = OCCLUDER_MARGIN_M, rows: int = OCCLUSION_ROWS) -> np.ndarray:
    """Per group of point indices, whether its top is hidden from the sensor: in the frame's
    (azimuth, elevation) ray grid (``scan_steps``, rad) about the sensor at ``sensor_xyz``, the
    cells of the ``rows`` scan lines just above the group's highest ray, over the group's
    azimuths (one step more each side), hold returns, and most of them (at least half) are
    nearer horizontally than the group's nearest point by more than ``margin_m``. All False
    when the steps are unknown (nan)."""
    daz, d_el = (float(v) for v in scan_steps)
    out = np.zeros(len(groups), dtype=bool)
    if not (np.isfinite(daz) and np.isfinite(d_el) and daz > 0 and d_el > 0) or not groups:
        return out
    d = pts[:, :3] - np.asarray(sensor_xyz, dtype=float)
    r = np.hypot(d[:, 0], d[:, 1])
    col = np.floor((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / daz).astype(np.int64)
    row = np.floor((np.arctan2(d[:, 2], r) + np.pi / 2) / d_el).astype(np.int64)
    n_rows = int(np.ceil(np.pi / d_el)) + rows + 2
    key = col * n_rows + row
    order = np.argsort(key, kind="stable")
    skey = key[order]
    first = np.r_[True, skey[1:] != skey[:-1]]
    ukey = skey[first]
    nearest = np.minimum.reduceat(r[order], np.flatnonzero(first))  # per occupied cell
    for g, idx in enumerate(groups):
        c_lo, c_hi = col[idx].min() - 1, col[idx].max() + 1
        if c_hi - c_lo > np.pi / daz:  # wraps round the sensor: no direction above it
            continue
        top = row[idx].max()
        cells = (np.arange(c_lo, c_hi + 1)[:, None] * n_rows + np.arange(top + 1, top + rows + 1)[None]).ravel()
        at = np.minimum(np.searchsorted(ukey, cells), len(ukey) - 1)
        hit = ukey[at] == cells
        if hit.any():
            out[g] = np.mean(nearest[at[hit]] < r[idx].min() - margin_m) >= 0.5
    return out


def _cluster_height_map(pts: np.ndarray, idx: np.ndarray, cell_size_m: float) -> tuple[np.ndarray, ...]:
    """(xyz of the cluster's points ``idx``, each point's cell (row, col) on a ``cell_size_m`` grid
    from the cluster's least x and y, the highest z in each cell: (rows, cols), -inf when empty)."""
    xyz = pts[idx, :3]
    ij, shape, _ = grid_cells(xyz, cell_size_m)
    z_hi, _ = cell_z_range(ij, xyz[:, 2], shape)
    return xyz, ij, z_hi


def split_low(pts: np.ndarray, idx: np.ndarray, cell_size_m: float = CELL_SIZE_M) -> list[np.ndarray]:
    """A wide cluster with one head cut free of the low objects it touches (a pram or trolley
    pushed by the handle, a chair or box beside a person): its cells whose highest point is below
    ``LOW_CUT_SHARE`` of the cluster's height are dropped and the rest is clustered again (8-connected
    cells); each part of at least MIN_CLUSTER_POINTS points keeps all the points of its cells. An
    empty list when nothing is dropped (a wall, a car: nothing to cut)."""
    xyz, ij, z_hi = _cluster_height_map(pts, idx, cell_size_m)
    high = z_hi >= LOW_CUT_SHARE * xyz[:, 2].max()
    if high.sum() == np.isfinite(z_hi).sum():
        return []
    labels, _ = cluster_cells(high)
    own = labels[ij[:, 0], ij[:, 1]]
    return [idx[own == k] for k in range(1, own.max() + 1) if (own == k).sum() >= MIN_CLUSTER_POINTS]


def split_by_heads(pts: np.ndarray, idx: np.ndarray, cell_size_m: float = CELL_SIZE_M) -> list[np.ndarray]:
    """A wide cluster (people walking side by side) cut at its heads.

    Head candidates are the peaks of the cluster's cell height map (cells highest within their
    3 x 3 neighbourhood that reach ``HEAD_MIN_SHARE`` of the cluster's height). From the highest
    down, a candidate is kept when it lies at least ``HEAD_SEPARATION_M`` from every kept head and
    the height map dips by at least ``HEAD_DIP_M`` below the lower of the two on the way between
    them (a neck and shoulders, not one person's flat top). Each point goes to the nearest kept
    head, the heads then moved to their points' centroids a few times (k-means). Fewer than two
    heads: no split (an empty list)."""
    xyz, _, z_hi = _cluster_height_map(pts, idx, cell_size_m)
    peak = (z_hi == ndimage.maximum_filter(z_hi, size=3, mode="constant", cval=-np.inf))
    peak &= z_hi >= HEAD_MIN_SHARE * xyz[:, 2].max()
    r, c = np.nonzero(peak)
    order = np.argsort(-z_hi[r, c], kind="stable")
    kept: list[tuple[np.ndarray, float]] = []  # (cell position (row, col), height)
    for k in order:
        rc, h = np.array([r[k], c[k]], float), float(z_hi[r[k], c[k]])
        if all(_separate_heads(z_hi, rc, h, q, hq, cell_size_m) for q, hq in kept):
            kept.append((rc, h))
    if len(kept) < 2:
        return []
    # Each point to the nearest head, refined by a few k-means (Lloyd) steps on the horizontal
    # positions so the cut runs midway between the two bodies, not between two peak cells.
    centres = (np.array([q for q, _ in kept]) + 0.5) * cell_size_m + xyz[:, :2].min(axis=0)
    for _ in range(HEAD_KMEANS_STEPS):
        owner = np.argmin(np.linalg.norm(xyz[:, None, :2] - centres[None], axis=2), axis=1)
        centres = np.array([xyz[owner == k, :2].mean(axis=0) if (owner == k).any() else centres[k]
                            for k in range(len(centres))])
    owner = np.argmin(np.linalg.norm(xyz[:, None, :2] - centres[None], axis=2), axis=1)
    return [idx[owner == k] for k in range(len(kept)) if (owner == k).sum() >= MIN_CLUSTER_POINTS]


def _separate_heads(z_hi: np.ndarray, a: np.ndarray, ha: float, b: np.ndarray, hb: float, cell_size_m: float) -> bool:
    if np.hypot(*(a - b)) * cell_size_m < HEAD_SEPARATION_M:
        return False
    n = int(np.ceil(np.hypot(*(a - b)) * 2)) + 1
    # cells on the way (a cell met twice changes neither the minimum nor whether any is seen)
    path = np.rint(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)).astype(int)
    z = z_hi[path[:, 0], path[:, 1]]
    z = z[np.isfinite(z)]  # empty cells (gaps between scan lines) say nothing
    return bool(len(z) and z.min() <= min(ha, hb) - HEAD_DIP_M)


def _candidates(pts: np.ndarray, groups: list[np.ndarray]) -> list[Candidate]:
    """A Candidate per group of point indices (extents of all groups in one vectorized pass)."""
    if not groups:
        return []
    sizes = np.array([len(g) for g in groups])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    sub = pts[np.concatenate(groups), :3]
    top = np.maximum.reduceat(sub, starts, axis=0)
    low = np.minimum.reduceat(sub[:, :2], starts, axis=0)
    # Any enclosing rectangle's longer side is >= the points' diameter / sqrt(2) >= the longer
    # axis-aligned extent / sqrt(2): beyond GROUP_WIDTH_M * sqrt(2) the cluster can neither pass
    # the gate nor be cut at heads. The minimum-area box's sides are at most the diameter, itself at
    # most sqrt(2) x the longer axis-aligned extent: a cluster taller than the gate and narrower
    # than SPLIT_WIDTH_M[0] / sqrt(2) (a pole, a trunk) can neither pass the gate nor be cut.
    ext = top[:, :2] - low
    cheap = ((sizes < MIN_CLUSTER_POINTS) | (top[:, 2] < GATE_HEIGHT_M[0])
             | (ext.max(axis=1) > GROUP_WIDTH_M * np.sqrt(2))
             | ((top[:, 2] > GATE_HEIGHT_M[1]) & (ext.max(axis=1) * np.sqrt(2) <= SPLIT_WIDTH_M[0])))
    fitted = np.flatnonzero(~cheap)
    boxes = dict(zip(fitted, min_area_boxes(pts[:, :2], [groups[k] for k in fitted]), strict=True)) \
        if len(fitted) else {}
    out = []
    for k, idx in enumerate(groups):
        h = float(top[k, 2])
        if cheap[k]:
            # fails the gate whatever its box: the axis-aligned box is enough (a real scan holds
            # thousands of such fragments and walls; the rotating calipers would dominate the run time)
            cx, cy = 0.5 * (low[k] + top[k, :2])
            e = ext[k]
            box = Box(float(cx), float(cy), float(e.max()), float(e.min()), 0.0 if e[0] >= e[1] else -np.pi / 2)
            out.append(Candidate(idx, box, h, False))
        else:
            box = boxes[k]
            out.append(Candidate(idx, box, h, passes_gate(h, box.width, box.depth, len(idx))))
    return out


# ------------------------------------------------------------------------------------- classifier
# One classifier per family of sensors (``pedcal train-detector --family NAME`` trains each):
# "general" for the LIDARs of every resolution and range (spinning, solid-state), "fx8" for the
# paper's FX8 pair, whose narrow field of view (60 x 50 deg, 0.3-5 m) shows near people cut at the
# knees and the head and whose clusters the general model, trained mostly on other scans, scores
# too low (``pedcal.detect.train.MODEL_FAMILIES``).
MODEL_FILES = {"general": "detector_model.npz", "fx8": "detector_model_fx8.npz"}
DEFAULT_MODEL_PATH = Path(str(resources.files("pedcal") / "data" / MODEL_FILES["general"]))
# The sensors (``pedcal.detect.sensors.SENSORS`` names and ``pedcal.sim.lidar`` presets) of each
# family but the general one.
FAMILY_SENSORS = {"fx8": ("fx8", "fx8_far")}
# ``segment(cut_low=...)`` of each family's frames, as its model was trained: the FX8 model with
# pushers cut free of their prams (on simulated FX8 frames 11 of 124 misses were pushers merged
# with their pram). The general model keeps the segmentation it was trained with (with it, the cut
# adds a false detection within 15 m to the real SUSTech frames).
FAMILY_CUT_LOW = {"general": False, "fx8": True}
# ``segment(occluded_low=...)`` of each family's frames, as its model was trained: off for both.
# On simulated FX8 frames most people missed with no candidate at all are legs below a nearer
# sign, plant, coat stand or person (seeds 12345 / 777 / 4242 of detect-eval: 14 of 17, 15 of 19,
# 16 of 23), and gating the hidden low clusters makes most of them candidates; but an FX8 model
# trained with them does not tell them from the legs of chairs, boxes and trolleys (3200
# validation frames: 1485 such clusters, 190 of them people; at best recall 0.53 and precision
# 0.52) and turns more lenient on fragments of people and on clutter (on those seeds recall
# 0.931 / 0.931 / 0.918 -> 0.945 / 0.936 / 0.926, precision 0.976 / 0.972 / 0.976 -> 0.975 /
# 0.959 / 0.958), so it is not used.
FAMILY_OCCLUDED_LOW = {"general": False, "fx8": False}


def model_path(family: str = "general") -> Path:
    """The shipped model file of a family (``MODEL_FILES``)."""
    if family not in MODEL_FILES:
        raise PedcalInputError(f"unknown detector model family {family!r}; expected one of "
                               f"{', '.join(MODEL_FILES)}", column="family")
    return Path(str(resources.files("pedcal") / "data" / MODEL_FILES[family]))


def model_family(sensor: str | None = None, scan_steps: tuple[float, float] | None = None) -> str:
    """Which family's model serves a frame: the named ``sensor``'s (a ``SENSORS`` name or a LIDAR
    preset), else that of the known sensor whose ray steps are nearest (ratio of azimuth and of
    elevation steps, in log) to the frame's estimated ``scan_steps`` (rad, ``scan_steps_rad``);
    "general" when neither is known."""
    if sensor is None and scan_steps is not None and np.all(np.isfinite(scan_steps)):
        from pedcal.detect.sensors import SENSORS

        names = list(SENSORS)
        steps_deg = np.array([SENSORS[n][1] for n in names])
        dist = np.linalg.norm(np.log(np.degrees(np.asarray(scan_steps, dtype=float)) / steps_deg), axis=1)
        sensor = names[int(np.argmin(dist))]
    return next((f for f, members in FAMILY_SENSORS.items() if sensor in members), "general")


def load_classifier(path: str | Path):
    """A RealAdaBoost or a GradientBoostedTrees model from its .npz, whichever the file holds."""
    from pedcal.detect.gbt import GradientBoostedTrees

    p = Path(path)
    with open_model_npz(p, "a detector model .npz (RealAdaBoost or gradient-boosted trees)") as d:
        trees = "lightgbm_model" in d.files
    return GradientBoostedTrees.load(p) if trees else RealAdaBoost.load(p)


@functools.lru_cache(maxsize=4)
def _load_cached(path: str, mtime: float):
    """The model at ``path``, its structure checked (model_check) once per file version."""
    return load_checked(lambda: load_classifier(path), path)


def load_model(path: str | Path | None = None, family: str = "general"):
    """The classifier at ``path`` (default: the shipped model of ``family``, ``model_path``)."""
    p = Path(path) if path is not None else model_path(family)
    mtime = p.stat().st_mtime if p.exists() else 0.0
    model = _load_cached(str(p), mtime)
    if model.n_features_ not in (N_FEATURES, N_FEATURES_BEFORE_G5):
        raise PedcalInputError(f"the model was trained on {model.n_features_} features per cluster, the "
                               f"detector computes {N_FEATURES}; retrain it with pedcal train-detector", path=p)
    return model


# How a model reads intensity (its ``metadata_["intensity"]``): "raw" as the file holds it (models
# trained on simulated frames alone, whose intensities are 0-1), "frame" divided by the frame's
# 95th percentile (``frame_normalized_intensity``: sensors with other units), "none" left out (0).
INTENSITY_MODES = ("raw", "frame", "none")


def intensity_for(points: np.ndarray, mode: str = "raw") -> np.ndarray:
    """The (N, 4) frame with its intensity as a model of intensity ``mode`` reads it."""
    if mode not in INTENSITY_MODES:
        raise PedcalInputError(f"unknown intensity mode {mode!r}; expected one of {', '.join(INTENSITY_MODES)}",
                               column="intensity")
    if mode == "frame":
        return frame_normalized_intensity(points)
    if mode == "none":
        out = np.zeros((len(points), 4))
        out[:, :3] = np.asarray(points, dtype=float)[:, :3]
        return out
    return points


def candidate_features(points: np.ndarray, groups: list[np.ndarray], scan_steps, intensity: str = "raw",
                       n_features: int = N_FEATURES) -> np.ndarray:
    """(len(groups), n_features) features of the clusters (groups of row indices of ``points``), the
    frame's intensity read as ``intensity`` (``intensity_for``); a model trained on the first
    ``n_features`` (older files: N_FEATURES_BEFORE_G5) gets those."""
    pts = intensity_for(points, intensity)
    return features_matrix([pts[g] for g in groups], scan_steps)[:, :n_features]


def score_candidates(clf, points: np.ndarray, groups: list[np.ndarray], scan_steps) -> np.ndarray:
    """P(person) of each cluster under the classifier ``clf``, its features as ``clf`` was trained on."""
    mode = getattr(clf, "metadata_", {}).get("intensity", "raw")
    return clf.predict_proba(candidate_features(points, groups, scan_steps, mode, clf.n_features_))


def gated_candidates(points: np.ndarray, *, cell_size_m: float = CELL_SIZE_M, gap_cells: int = 0,
                     max_range_m: float = MAX_RANGE_M, sensor_height_m: float = DEFAULT_SENSOR_HEIGHT_M,
                     sensor: str | None = None, sensor_xy_m: tuple[float, float] = (0.0, 0.0)):
    """(points (N, 4) within ``max_range_m``, the frame's ray steps, its model family, the gated
    Candidates): what ``detect`` classifies, and what training on real frames labels."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 2 and pts.shape[1] == 3:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if pts.ndim == 2 and len(pts) and max_range_m is not None:
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= max_range_m]
    steps = scan_steps_rad(pts, sensor_height_m) if pts.ndim == 2 and len(pts) else (np.nan, np.nan)
    family = model_family(sensor, steps)
    cands = [c for c in segment(pts, cell_size_m=cell_size_m, gap_cells=gap_cells, cut_low=FAMILY_CUT_LOW[family],
                                occluded_low=FAMILY_OCCLUDED_LOW[family], scan_steps=steps,
                                sensor_xyz=(*sensor_xy_m, sensor_height_m))
             if c.gated]
    return pts, steps, family, cands


def detect(points: np.ndarray, model: RealAdaBoost | str | Path | None = None, *,
           threshold: float = 0.5, cell_size_m: float = CELL_SIZE_M, gap_cells: int = 0,
           max_range_m: float = MAX_RANGE_M, sensor_height_m: float | None = None,
           sensor: str | None = None, sensor_xy_m: tuple[float, float] = (0.0, 0.0),
           frame: str = "body", floor: str = "none") -> list[Detection]:
    """People in one frame: the gated clusters, each scored by the classifier.

    ``points`` is (N, 4) ``x, y, z, intensity`` with z = 0 at the floor (N, 3 gets intensity 0);
    ``model`` a RealAdaBoost, a path to one, or None for the shipped model of the frame's family
    (``model_family``: that of ``sensor``, a ``SENSORS`` name or LIDAR preset, when it is named,
    else the one whose sensors' ray steps are nearest the frame's), whose segmentation the frame
    gets (``FAMILY_CUT_LOW``). Points farther than
    ``max_range_m`` horizontally from the origin (the sensor) are left out: a person there holds
    a handful of points from any LIDAR. ``sensor_height_m`` is where the sensor sits above the
    floor (the frame's ray steps are estimated as seen from there; a metre off changes them by a
    few percent); ``sensor_xy_m`` where it sits horizontally (the FX8 pair's centre is 0.2 m ahead
    of the base), seen from where a cluster's top is hidden or not (``top_occluded``). Returns
    every gated cluster as a Detection; ``is_person`` is ``score >= threshold``.

    A cloud as the sensor gives it (the sensor at the origin) is put into the detector's frame
    first (``pedcal.detect.ground.detector_frame``): ``frame="optical"`` for a camera's optical
    frame (x right, y down, z forward), ``floor="auto"`` to subtract the local ground (its
    warnings are logged), ``"plane"`` one floor plane; the sensor's height is then the one found
    unless ``sensor_height_m`` is given (``DEFAULT_SENSOR_HEIGHT_M`` when neither is known).
    Detections are always in the sensor's body frame (x forward, y left, z up).
    """
    check(threshold=threshold, cell_size_m=cell_size_m, gap_cells=gap_cells)
    pts = np.asarray(points, dtype=float)
    if frame != "body" or floor != "none":
        from pedcal.detect.ground import detector_frame

        prepared = detector_frame(pts, frame=frame, floor=floor)
        pts = prepared.points
        if sensor_height_m is None:
            sensor_height_m = prepared.sensor_height_m
    if sensor_height_m is None:
        sensor_height_m = DEFAULT_SENSOR_HEIGHT_M
    pts, steps, family, cands = gated_candidates(pts, cell_size_m=cell_size_m, gap_cells=gap_cells,
                                                 max_range_m=max_range_m, sensor_height_m=sensor_height_m,
                                                 sensor=sensor, sensor_xy_m=sensor_xy_m)
    if not cands:
        return []
    clf = model if hasattr(model, "predict_proba") else load_model(model, family if model is None else "general")
    score = score_candidates(clf, pts, [c.indices for c in cands], steps)
    return [Detection(c.box.cx, c.box.cy, c.height, c.box.width, c.box.depth, c.box.yaw,
                      float(s), bool(s >= threshold), len(c.indices)) for c, s in zip(cands, score, strict=True)]
