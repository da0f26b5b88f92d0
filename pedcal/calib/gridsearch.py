"""Kimoto et al.'s decoupled grid search (eqs. 1-9), exact at the paper's resolution.

Each ceiling sensor is calibrated on its own from N pairs: ``p_sensor[i]``, the top of the robot's
head as the sensor saw it (sensor frame), and ``head_world[i]``, the robot's localized head top at
the same time (world frame). Definitions used here (population statistics, ddof = 0):

- eq. 1: ``p'_i = R(yaw, pitch, roll) p_i + t`` with R = Rz(yaw) Ry(pitch) Rx(roll)
  (:mod:`pedcal.frames`).
- eqs. 2-3: ``ZDev(pitch, roll) = std_i(z'_i - z_head,i)``. It depends on the angles only through
  the third row r3 = (-sin pitch, cos pitch sin roll, cos pitch cos roll) of R (not on yaw nor t).
- eqs. 4-5: ``ZDist(z) = mean_i |z'_i - z_head,i|`` with the chosen pitch and roll.
- eqs. 6-7: ``XYDev(yaw) = sqrt(var_i(dx_i) + var_i(dy_i))`` with ``d_i = p'_xy,i - head_xy,i``
  and the chosen pitch and roll (it does not depend on t).
- eqs. 8-9: ``XYDist(x, y) = mean_i ||d_i||`` with the chosen yaw, pitch and roll.

The stages run in that order (pitch/roll, z, yaw, x/y), each over a grid centred on the sensor's
installed value: ``centre + step * k`` for ``k = -K..K``, ``K = round(range / step)``; the paper
uses +-60 deg at 0.01 deg (12001 values per angle, 12001^2 pitch/roll cells) and +-1000 mm at
5 mm (401 values per offset, 401^2 x/y cells). Where several cells share the minimum, the first
in grid order wins (pitch-major for pitch/roll, x-major for x/y, ascending otherwise).

Exactness. :func:`brute_force_grid_search_sensor` evaluates every cell with the plain
definitions above (``_zdev_cells`` and friends). :func:`grid_search_sensor` returns the same
cells, bit for bit, much faster:

- ZDev: ``var = r3^T S r3 - 2 r3^T c + v`` with S = cov(p), c = cov(p, z_head), v = var(z_head)
  is, on the pitch/roll grid, ``A(pitch) + B(pitch) g(roll) + C(pitch) h(roll) + D(pitch) k(roll)``:
  O(1) per cell after one O(N) pass. Its slope is at most ``2 (|S| + |c|)`` per radian in pitch
  and in roll, so a branch and bound over blocks of the 12001^2 grid (a block's centre value
  minus slope x its angular reach bounds every cell in it) evaluates only the cells near the
  minimum; a flat objective falls back to a chunked scan of every cell. Every cell whose
  closed-form value is within a rounding bound ``tol`` of the minimum is then evaluated with the
  plain definition, which picks the winner. Since both computations err by less than tol / 2,
  the plain argmin is always among these candidates.
- XYDev: the same screening with ``var = T_q - 2 (cos yaw a + sin yaw b) + T_h``.
- ZDist: the plain definition on all 401 values (cheap).
- XYDist: branch and bound over blocks of the x/y grid. XYDist is 1-Lipschitz, so a block whose
  centre cell has value f is bounded below by ``f - r`` (r: the largest centre-to-cell distance);
  blocks whose bound exceeds the best cell found (plus a rounding margin) cannot hold the argmin
  and are dropped, the others are split until single cells. Every cell is either evaluated with
  the plain definition or proven worse, so the result is the exhaustive argmin.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from pedcal.calib.common import CalibrationResult, GridSearchDiagnostics, robot_head_at
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.model import Log, SensorExtrinsics, SensorNetwork

MIN_OBSERVATIONS = 10            # fewer robot observations: the sensor keeps its installed pose
DEGENERATE_MINOR_STD_M = 0.10    # spread of the robot's head across its path below this ...
DEGENERATE_MINOR_RATIO = 0.10    # ... or below this fraction of the spread along it: a straight pass
# Rounding bound of the closed-form screens, relative to the magnitude of their terms. Float64
# rounding is ~1e-16 relative; the candidates kept are re-evaluated exactly, so a generous
# bound costs a few extra evaluations and nothing in exactness.
SCREEN_RTOL = 1e-9
MAX_SCREEN_CANDIDATES = 2_000_000
BNB_MAX_BLOCKS = 1_000_000       # more open blocks than this: the objective is flat, scan instead
CHUNK_ELEMENTS = 4_000_000       # cells x points (or cells) held in memory at once


@dataclass
class GridSearchResult:
    """The grid optimum of one sensor, the objective values there (metres) and the grid
    indices, as offsets k in ``centre + step * k`` (stage order: pitch, roll, z, yaw, x, y)."""

    extrinsics: SensorExtrinsics
    zdev_m: float
    zdist_m: float
    xydev_m: float
    xydist_m: float
    index: dict = field(default_factory=dict)
    on_range_edge: list[str] = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# Grids and the plain objectives (eqs. 2-9), shared by the fast and the brute-force searches.


def _grid(centre: float, half_range: float, step: float) -> np.ndarray:
    if not (step > 0 and half_range >= 0):
        raise ValueError(f"grid needs step > 0 and range >= 0, got step {step}, range {half_range}")
    k_max = int(round(half_range / step))
    return centre + step * np.arange(-k_max, k_max + 1, dtype=float)


class _AngleTable:
    """Sines and cosines of one angle grid, computed once so every search reads the same bits."""

    def __init__(self, centre_deg: float, half_range_deg: float, step_deg: float):
        self.deg = _grid(centre_deg, half_range_deg, step_deg)
        rad = np.radians(self.deg)
        self.sin = np.sin(rad)
        self.cos = np.cos(rad)

    def __len__(self) -> int:
        return len(self.deg)


def _zdev_cells(p, head_z, tz, pitch: _AngleTable, roll: _AngleTable, ip, ir) -> np.ndarray:
    """ZDev (eqs. 2-3) of the cells (pitch[ip], roll[ir]): std of z'_i - z_head,i, where
    z' = r3 . p + tz (eq. 1, third row)."""
    sp, cp = pitch.sin[ip][:, None], pitch.cos[ip][:, None]
    sr, cr = roll.sin[ir][:, None], roll.cos[ir][:, None]
    z = -sp * p[:, 0] + cp * (sr * p[:, 1] + cr * p[:, 2]) + tz
    return np.std(z - head_z, axis=1)


def _rotate_pitch_roll(p, pitch: _AngleTable, roll: _AngleTable, ip: int, ir: int) -> np.ndarray:
    """q = Ry(pitch) Rx(roll) p for one pitch/roll cell, (N, 3)."""
    sp, cp, sr, cr = pitch.sin[ip], pitch.cos[ip], roll.sin[ir], roll.cos[ir]
    v = sr * p[:, 1] + cr * p[:, 2]
    return np.column_stack([cp * p[:, 0] + sp * v, cr * p[:, 1] - sr * p[:, 2], -sp * p[:, 0] + cp * v])


def _zdist_cells(q_z, head_z, z_grid, iz) -> np.ndarray:
    """ZDist (eqs. 4-5) of the z offsets z_grid[iz]: mean |z'_i - z_head,i|."""
    return np.mean(np.abs(q_z + z_grid[iz][:, None] - head_z), axis=1)


def _xydev_cells(q, head_xy, t_xy, yaw: _AngleTable, iy) -> np.ndarray:
    """XYDev (eqs. 6-7) of the yaws yaw[iy]: sqrt(var dx + var dy), d = (Rz(yaw) q)_xy + t - head."""
    sy, cy = yaw.sin[iy][:, None], yaw.cos[iy][:, None]
    dx = cy * q[:, 0] - sy * q[:, 1] + t_xy[0] - head_xy[:, 0]
    dy = sy * q[:, 0] + cy * q[:, 1] + t_xy[1] - head_xy[:, 1]
    return np.sqrt(np.var(dx, axis=1) + np.var(dy, axis=1))


def _xydist_cells(r_xy, head_xy, x_grid, y_grid, ix, iy) -> np.ndarray:
    """XYDist (eqs. 8-9) of the cells (x_grid[ix], y_grid[iy]): mean ||r + (x, y) - head_xy||,
    with r = (R p)_xy the rotated sensor points."""
    dx = r_xy[:, 0] + x_grid[ix][:, None] - head_xy[:, 0]
    dy = r_xy[:, 1] + y_grid[iy][:, None] - head_xy[:, 1]
    return np.mean(np.sqrt(dx * dx + dy * dy), axis=1)


def _rows_per_chunk(row_len: int) -> int:
    return max(1, CHUNK_ELEMENTS // max(1, row_len))


class _Progress:
    def __init__(self, enabled: bool, label: str):
        self.enabled, self.label, self.last = enabled, label, -1

    def __call__(self, stage: str, fraction: float):
        if not self.enabled:
            return
        pct = int(100 * fraction) // 10 * 10
        if pct != self.last or fraction >= 1.0:
            self.last = pct
            logging.getLogger(__name__).info(f"gridsearch {self.label}: {stage} {pct:3d}%",
                                             extra={"progress": (pct, 100)})


def _first_min(values: np.ndarray, flat: np.ndarray) -> tuple[float, int]:
    """(min value, smallest flat index among the cells holding it)."""
    vmin = values.min()
    return float(vmin), int(flat[values == vmin].min())


# --------------------------------------------------------------------------------------------
# Brute force: every cell with the plain definition.


def _brute_argmin(n_cells: int, evaluate, row_len: int, progress=None) -> tuple[float, int]:
    """First argmin in flat order of evaluate(flat_indices) over range(n_cells), in chunks."""
    best_val, best_idx = np.inf, -1
    chunk = _rows_per_chunk(row_len)
    for start in range(0, n_cells, chunk):
        flat = np.arange(start, min(n_cells, start + chunk))
        vals = evaluate(flat)
        j = int(np.argmin(vals))
        if vals[j] < best_val:
            best_val, best_idx = float(vals[j]), int(flat[j])
        if progress is not None:
            progress(min(n_cells, start + chunk) / n_cells)
    return best_val, best_idx


def brute_force_grid_search_sensor(p_sensor, head_world, initial: SensorExtrinsics, *,
                                   angle_range_deg: float = 60.0, angle_step_deg: float = 0.01,
                                   offset_range_m: float = 1.0, offset_step_m: float = 0.005,
                                   progress: bool = False) -> GridSearchResult:
    """The plain exhaustive search of eqs. 1-9: every grid cell of every stage evaluated by
    definition. O(cells x N): for checking :func:`grid_search_sensor` on reduced ranges."""
    p, head = _check_pairs(p_sensor, head_world)
    grids = _Grids(initial, angle_range_deg, angle_step_deg, offset_range_m, offset_step_m)
    show = _Progress(progress, initial.id)
    n, timings = len(p), {}

    t0 = time.perf_counter()
    n_roll = len(grids.roll)
    zdev, k = _brute_argmin(
        len(grids.pitch) * n_roll,
        lambda f: _zdev_cells(p, head[:, 2], grids.z[grids.kz0], grids.pitch, grids.roll,
                              f // n_roll, f % n_roll),
        n, lambda x: show("pitch/roll", x))
    ip, ir = divmod(k, n_roll)
    timings["pitch_roll"] = time.perf_counter() - t0
    return _finish_stages(p, head, grids, ip, ir, zdev, timings, brute=True, show=show)


# --------------------------------------------------------------------------------------------
# Fast exact search.


def _check_pairs(p_sensor, head_world) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(p_sensor, dtype=float)
    head = np.asarray(head_world, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or head.shape != p.shape:
        raise ValueError(f"p_sensor and head_world must both be (N, 3), got {p.shape} and {head.shape}")
    if len(p) == 0:
        raise ValueError("no pairs to calibrate from")
    if not (np.isfinite(p).all() and np.isfinite(head).all()):
        raise ValueError("p_sensor and head_world must be finite")
    return p, head


class _Grids:
    def __init__(self, initial: SensorExtrinsics, angle_range_deg, angle_step_deg, offset_range_m,
                 offset_step_m):
        yaw0, pitch0, roll0 = (float(a) for a in initial.ypr_deg)
        x0, y0, z0 = (float(a) for a in initial.position_m)
        self.initial = initial
        self.pitch = _AngleTable(pitch0, angle_range_deg, angle_step_deg)
        self.roll = _AngleTable(roll0, angle_range_deg, angle_step_deg)
        self.yaw = _AngleTable(yaw0, angle_range_deg, angle_step_deg)
        self.x = _grid(x0, offset_range_m, offset_step_m)
        self.y = _grid(y0, offset_range_m, offset_step_m)
        self.z = _grid(z0, offset_range_m, offset_step_m)
        self.kz0 = np.array([len(self.z) // 2])   # the installed z (ZDev does not depend on it)
        self.offset_step_m = float(offset_step_m)


def _screen_tol(scale: float, magnitude: float) -> float:
    """Bound on the closed-form and plain rounding errors (see SCREEN_RTOL)."""
    return SCREEN_RTOL * (scale + np.sqrt(scale) * magnitude) + 1e-300


def _verify_candidates(flat, vals, best: float, tol: float, evaluate_plain, what: str,
                       overflow: bool = False) -> tuple[float, int]:
    """First plain argmin among the cells whose closed-form value is within ``tol`` of the
    closed-form minimum ``best``: it is the exhaustive plain argmin (module docstring).
    ``overflow``: too many such cells were found to keep (``flat`` holds the first minimum)."""
    sel = vals <= best + tol
    flat, vals = flat[sel], vals[sel]
    if overflow or len(flat) > MAX_SCREEN_CANDIDATES:
        warnings.warn(f"{what} is flat to rounding over more than {MAX_SCREEN_CANDIDATES} grid cells: "
                      "it is not determined "
                      "by the data; taking the first closed-form minimum", DegenerateDataWarning,
                      stacklevel=4)
        return _first_min(vals, flat)
    flat = np.unique(flat)
    plain = np.concatenate([evaluate_plain(flat[s:s + 65536]) for s in range(0, len(flat), 65536)])
    return _first_min(plain, flat)


def _screened_scan(chunks, tol: float):
    """Scan (flat indices, closed-form values) chunks in grid order, keeping the cells within tol
    of the running minimum: (kept flat, kept values, minimum). When more than
    MAX_SCREEN_CANDIDATES stay within tol (a flat objective), only the first minimum is kept."""
    best, first = np.inf, -1
    kept_flat, kept_val, n_kept, overflow = [], [], 0, False
    for flat, vals in chunks:
        vmin = float(vals.min())
        if vmin < best:
            first = int(flat[np.argmin(vals)])
        if vmin > best + tol or overflow:
            best = min(best, vmin)
            continue
        best = min(best, vmin)
        sel = vals <= best + tol
        kept_flat.append(flat[sel])
        kept_val.append(vals[sel])
        n_kept += int(sel.sum())
        if n_kept > MAX_SCREEN_CANDIDATES:               # drop what the new minimum excludes
            f, v = np.concatenate(kept_flat), np.concatenate(kept_val)
            keep = v <= best + tol
            kept_flat, kept_val, n_kept = [f[keep]], [v[keep]], int(keep.sum())
            overflow = n_kept > MAX_SCREEN_CANDIDATES
    if overflow:
        return np.array([first]), np.array([best]), best, True
    return np.concatenate(kept_flat), np.concatenate(kept_val), best, False


def _branch_and_bound(evaluate, nx: int, ny: int, reach, slack: float, keep_tol: float,
                      max_blocks: int | None = None, show=None):
    """Cells of an nx x ny grid (flat index ix * ny + iy) within keep_tol of the minimum of a
    function with a Lipschitz-type bound: |f(cell) - f(centre)| <= reach(|dix|, |diy|) + slack
    (slack: rounding). Returns (flat, values, minimum) of every evaluated cell within keep_tol of
    the running minimum, a superset of the cells within keep_tol of the grid minimum: a block is
    dropped only when its centre value minus the reach of its farthest cell minus slack exceeds
    the best cell seen plus keep_tol; the others are halved until they are single cells.
    Returns None when more than max_blocks blocks stay open (a flat function: scan instead)."""
    max_blocks = BNB_MAX_BLOCKS if max_blocks is None else max_blocks
    blocks = np.array([[0, nx, 0, ny]])   # half-open index ranges ix0, ix1, iy0, iy1
    best = np.inf
    kept_flat, kept_val = [], []
    level = 0
    while len(blocks):
        if len(blocks) > max_blocks:
            return None
        ix0, ix1, iy0, iy1 = blocks.T
        cx, cy = (ix0 + ix1 - 1) // 2, (iy0 + iy1 - 1) // 2
        vals = np.concatenate([evaluate(cx[s:s + 16384], cy[s:s + 16384]) for s in range(0, len(blocks), 16384)])
        best = min(best, float(vals.min()))
        sel = vals <= best + keep_tol
        kept_flat.append((cx * ny + cy)[sel])
        kept_val.append(vals[sel])
        bound = vals - reach(np.maximum(cx - ix0, ix1 - 1 - cx), np.maximum(cy - iy0, iy1 - 1 - cy)) - slack
        b = blocks[(bound <= best + keep_tol) & ((ix1 - ix0) * (iy1 - iy0) > 1)]
        mx, my = (b[:, 0] + b[:, 1]) // 2, (b[:, 2] + b[:, 3]) // 2
        children = np.concatenate([
            np.column_stack([b[:, 0], mx, b[:, 2], my]), np.column_stack([b[:, 0], mx, my, b[:, 3]]),
            np.column_stack([mx, b[:, 1], b[:, 2], my]), np.column_stack([mx, b[:, 1], my, b[:, 3]])])
        blocks = children[(children[:, 1] > children[:, 0]) & (children[:, 3] > children[:, 2])]
        level += 1
        if show is not None:
            show(min(1.0, level / np.ceil(np.log2(max(nx, ny, 2)) + 1)))
    return np.concatenate(kept_flat), np.concatenate(kept_val), best


def _zdev_fast(p, head_z, grids: _Grids, show) -> tuple[float, int, int]:
    """Pitch/roll minimizing ZDev (eqs. 2-3) over the whole grid via sufficient statistics."""
    pc = p - p.mean(axis=0)
    hc = head_z - head_z.mean()
    n = len(p)
    S = pc.T @ pc / n                 # cov(p), 3x3
    c = pc.T @ hc / n                 # cov(p, z_head)
    v = float(hc @ hc / n)            # var(z_head)
    pitch, roll = grids.pitch, grids.roll
    sp, cp, sr, cr = pitch.sin, pitch.cos, roll.sin, roll.cos
    # var(pitch, roll) = r3^T S r3 - 2 r3^T c + v with r3 = (-sp, cp sr, cp cr), split as
    # [A, B, C, D](pitch) . [1, g, h, k](roll):
    rows = np.column_stack([S[0, 0] * sp * sp + 2 * c[0] * sp + v, cp * cp, -2 * sp * cp, -2 * cp])
    cols = np.vstack([np.ones_like(sr),
                      S[1, 1] * sr * sr + 2 * S[1, 2] * sr * cr + S[2, 2] * cr * cr,
                      S[0, 1] * sr + S[0, 2] * cr,
                      c[1] * sr + c[2] * cr])
    cols_t = np.ascontiguousarray(cols.T)
    scale = (np.sqrt(np.trace(S)) + np.sqrt(v)) ** 2
    tz = grids.z[grids.kz0]
    magnitude = np.abs(p).sum(axis=1).max() + abs(float(tz[0])) + np.abs(head_z).max()
    tol = _screen_tol(scale, magnitude)
    n_pitch, n_roll = len(pitch), len(roll)

    # |dvar/dangle| = |2 (S r3 - c) . dr3/dangle| <= 2 (|S| + |c|) per radian, for pitch and roll
    # (|dr3/dpitch| = 1, |dr3/droll| = |cos pitch| <= 1).
    slope = 2.0 * (np.linalg.norm(S, 2) + np.linalg.norm(c)) * (1.0 + 1e-9)
    step_p = np.radians(np.abs(np.diff(pitch.deg)).max(initial=0.0))
    step_r = np.radians(np.abs(np.diff(roll.deg)).max(initial=0.0))
    found = _branch_and_bound(lambda ip, ir: np.einsum("ij,ij->i", rows[ip], cols_t[ir]), n_pitch, n_roll,
                              lambda di, dj: slope * (step_p * di + step_r * dj), tol, tol,
                              show=lambda x: show("pitch/roll", x))
    if found is None:
        chunk = _rows_per_chunk(n_roll)

        def chunks():
            for start in range(0, n_pitch, chunk):
                stop = min(n_pitch, start + chunk)
                yield np.arange(start * n_roll, stop * n_roll), (rows[start:stop] @ cols).ravel()
                show("pitch/roll (full scan)", stop / n_pitch)

        found = _screened_scan(chunks(), tol)
    else:
        found = (*found, False)
    flat, vals, best, overflow = found
    zdev, k = _verify_candidates(
        flat, vals, best, tol, lambda f: _zdev_cells(p, head_z, tz, pitch, roll, f // n_roll, f % n_roll),
        "ZDev over pitch/roll", overflow)
    ip, ir = divmod(k, n_roll)
    return zdev, ip, ir


def _xydev_fast(q, head_xy, t_xy, yaw: _AngleTable) -> tuple[float, int]:
    """Yaw minimizing XYDev (eqs. 6-7): var dx + var dy = T_q - 2 (cos yaw a + sin yaw b) + T_h."""
    qc = q[:, :2] - q[:, :2].mean(axis=0)
    hc = head_xy - head_xy.mean(axis=0)
    n = len(q)
    M = qc.T @ hc / n                 # cross-covariance E[q~ h~^T], 2x2
    t_q, t_h = float((qc * qc).sum() / n), float((hc * hc).sum() / n)
    a, b = M[0, 0] + M[1, 1], M[0, 1] - M[1, 0]
    vals = t_q - 2 * (yaw.cos * a + yaw.sin * b) + t_h
    scale = (np.sqrt(t_q) + np.sqrt(t_h)) ** 2
    magnitude = np.abs(q[:, :2]).sum(axis=1).max() + np.abs(t_xy).sum() + np.abs(head_xy).sum(axis=1).max()
    tol = _screen_tol(scale, magnitude)
    return _verify_candidates(np.arange(len(yaw)), vals, float(vals.min()), tol,
                              lambda f: _xydev_cells(q, head_xy, t_xy, yaw, f), "XYDev over yaw")


def _xydist_branch_and_bound(r_xy, head_xy, x_grid, y_grid, step_m: float) -> tuple[float, int, int]:
    """First-in-grid-order (x-major) argmin of XYDist (eqs. 8-9) over x_grid x y_grid, exact.

    XYDist is 1-Lipschitz in (x, y), so a block whose centre cell has plain value f holds no cell
    below f - r, r the farthest cell of the block from its centre: blocks that cannot reach the
    best cell seen are dropped (:func:`_branch_and_bound`), every other cell is evaluated."""
    ny = len(y_grid)
    scale = np.abs(r_xy).sum(axis=1).max() + np.abs(head_xy).sum(axis=1).max() + np.abs(x_grid).max() \
        + np.abs(y_grid).max()
    slack = 1e-9 * (1.0 + scale)      # covers the rounding of two plain evaluations, generously
    flat, vals, best = _branch_and_bound(
        lambda ix, iy: _xydist_cells(r_xy, head_xy, x_grid, y_grid, ix, iy), len(x_grid), ny,
        lambda di, dj: step_m * (1.0 + 1e-9) * np.hypot(di, dj), slack, 0.0, max_blocks=len(x_grid) * ny)
    value, k = _first_min(vals, flat)
    return value, k // ny, k % ny


def _finish_stages(p, head, grids: _Grids, ip: int, ir: int, zdev: float, timings: dict, *, brute: bool,
                   show) -> GridSearchResult:
    """Stages z (eqs. 4-5), yaw (eqs. 6-7) and x/y (eqs. 8-9) after pitch/roll are chosen."""
    initial = grids.initial
    q = _rotate_pitch_roll(p, grids.pitch, grids.roll, ip, ir)

    t0 = time.perf_counter()
    iz_all = np.arange(len(grids.z))
    zvals = _zdist_cells(q[:, 2], head[:, 2], grids.z, iz_all)
    zdist, iz = _first_min(zvals, iz_all)
    timings["z"] = time.perf_counter() - t0
    show("z", 1.0)

    t0 = time.perf_counter()
    t_xy = initial.position_m[:2]
    if brute:
        xydev, iyaw = _brute_argmin(len(grids.yaw), lambda f: _xydev_cells(q, head[:, :2], t_xy, grids.yaw, f),
                                    len(p))
    else:
        xydev, iyaw = _xydev_fast(q, head[:, :2], t_xy, grids.yaw)
    timings["yaw"] = time.perf_counter() - t0
    show("yaw", 1.0)

    t0 = time.perf_counter()
    sy, cy = grids.yaw.sin[iyaw], grids.yaw.cos[iyaw]
    r_xy = np.column_stack([cy * q[:, 0] - sy * q[:, 1], sy * q[:, 0] + cy * q[:, 1]])
    ny = len(grids.y)
    if brute:
        xydist, k = _brute_argmin(
            len(grids.x) * ny, lambda f: _xydist_cells(r_xy, head[:, :2], grids.x, grids.y, f // ny, f % ny),
            len(p), lambda x: show("x/y", x))
        ix, iy = divmod(k, ny)
    else:
        xydist, ix, iy = _xydist_branch_and_bound(r_xy, head[:, :2], grids.x, grids.y, grids.offset_step_m)
    timings["xy"] = time.perf_counter() - t0
    show("x/y", 1.0)

    half = {"pitch": len(grids.pitch) // 2, "roll": len(grids.roll) // 2, "z": len(grids.z) // 2,
            "yaw": len(grids.yaw) // 2, "x": len(grids.x) // 2, "y": ny // 2}
    index = {"pitch": ip - half["pitch"], "roll": ir - half["roll"], "z": iz - half["z"],
             "yaw": iyaw - half["yaw"], "x": ix - half["x"], "y": iy - half["y"]}
    on_edge = [name for name, k in index.items() if half[name] > 0 and abs(k) == half[name]]
    if on_edge:
        warnings.warn(f"sensor {initial.id}: grid optimum on the edge of the search range for "
                      f"{', '.join(on_edge)}; the true value may lie outside it", UserWarning, stacklevel=3)
    yaw_deg = (grids.yaw.deg[iyaw] + 180.0) % 360.0 - 180.0
    roll_deg = (grids.roll.deg[ir] + 180.0) % 360.0 - 180.0
    ext = SensorExtrinsics(initial.id, [grids.x[ix], grids.y[iy], grids.z[iz]],
                           [yaw_deg, grids.pitch.deg[ip], roll_deg], observations=len(p), status="ok")
    return GridSearchResult(ext, zdev_m=zdev, zdist_m=zdist, xydev_m=xydev, xydist_m=xydist, index=index,
                            on_range_edge=on_edge, timings_s=timings)


def grid_search_sensor(p_sensor, head_world, initial: SensorExtrinsics, *, angle_range_deg: float = 60.0,
                       angle_step_deg: float = 0.01, offset_range_m: float = 1.0,
                       offset_step_m: float = 0.005, progress: bool = False) -> GridSearchResult:
    """Kimoto et al.'s grid search (eqs. 1-9) of one sensor from N pairs (``p_sensor`` in the sensor
    frame, ``head_world`` the robot's head top in the world), ranges centred on ``initial``.

    Returns the same cells as :func:`brute_force_grid_search_sensor` (see the module docstring),
    in seconds at the paper's resolution."""
    p, head = _check_pairs(p_sensor, head_world)
    grids = _Grids(initial, angle_range_deg, angle_step_deg, offset_range_m, offset_step_m)
    show = _Progress(progress, initial.id)
    t0 = time.perf_counter()
    zdev, ip, ir = _zdev_fast(p, head[:, 2], grids, show)
    timings = {"pitch_roll": time.perf_counter() - t0}
    return _finish_stages(p, head, grids, ip, ir, zdev, timings, brute=False, show=show)


# --------------------------------------------------------------------------------------------
# Whole log.


def _straight_pass(head_xy: np.ndarray, R_world_sensor: np.ndarray) -> list[str] | None:
    """Directions the pairs leave unobservable when the robot's head positions are (nearly) one
    line or one spot, else None. With the head at one height on a line, every tilt about the line
    fits ZDev (eqs. 2-3) equally, and the position across the line moves with that tilt."""
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(head_xy.T, bias=True)), 0.0))  # ascending
    minor, major = float(spread[0]), float(spread[1])
    if major < DEGENERATE_MINOR_STD_M:
        return ["yaw, pitch, roll: the robot was seen at one spot", "x, y, z: coupled with the rotation"]
    if minor < DEGENERATE_MINOR_STD_M or minor < DEGENERATE_MINOR_RATIO * major:
        _, vecs = np.linalg.eigh(np.cov(head_xy.T, bias=True))
        u_world = np.array([vecs[0, 1], vecs[1, 1], 0.0])
        u_sensor = R_world_sensor.T @ u_world
        return [f"tilt about the robot's path (world axis [{u_world[0]:.2f}, {u_world[1]:.2f}, 0], "
                f"sensor axis [{u_sensor[0]:.2f}, {u_sensor[1]:.2f}, {u_sensor[2]:.2f}]): pitch/roll",
                "position across the path: x/y/z"]
    return None


def _robot_mask(log: Log, is_robot, progress: bool) -> np.ndarray:
    if is_robot is None:
        from pedcal.calib.association import associate_robot

        return np.asarray(associate_robot(log, progress=progress).is_robot, dtype=bool)
    mask = np.asarray(is_robot)
    if mask.shape != (len(log.observations),) or mask.dtype != bool:
        raise ValueError(f"is_robot must be a boolean mask over the {len(log.observations)} observation "
                         f"rows, got dtype {mask.dtype} and shape {mask.shape}")
    return mask


def calibrate_gridsearch(log: Log, *, progress: bool = False, is_robot=None, **options) -> CalibrationResult:
    """Calibrate every sensor of ``log`` with Kimoto et al.'s grid search (eqs. 1-9).

    ``is_robot`` (bool mask over ``log.observations`` rows) picks the robot's observations; when
    None, :func:`pedcal.calib.association.associate_robot` picks them. Each sensor pairs its robot
    points (sensor frame, installed extrinsics undone) with the AMCL head at the same times.
    ``options`` go to :func:`grid_search_sensor` (ranges and steps). Sensors with fewer than
    MIN_OBSERVATIONS robot observations keep their installed pose (status ``no-data``); a straight
    pass gives status ``degenerate`` and a DegenerateDataWarning."""
    t_start = time.perf_counter()
    mask = _robot_mask(log, is_robot, progress)
    obs = log.observations
    sensor_col = obs["sensor"].astype(str).to_numpy()
    unknown = sorted(set(sensor_col[mask]) - set(log.sensors.ids))
    if unknown:
        row = int(np.flatnonzero(mask & np.isin(sensor_col, unknown))[0])
        raise PedcalInputError(f"sensor '{unknown[0]}' is not in sensors.yaml",
                               path=None if log.path is None else log.path / "observations.csv",
                               row=row, column="sensor")
    xyz_t = obs[["x", "y", "z", "t"]].to_numpy(dtype=float)
    bad = mask & ~np.isfinite(xyz_t).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        col = ["x", "y", "z", "t"][int(np.flatnonzero(~np.isfinite(xyz_t[row]))[0])]
        raise PedcalInputError("expected a finite number", row=row, column=col,
                               path=None if log.path is None else log.path / "observations.csv")
    p_sensor_all = log.observation_points_sensor()
    head_all = robot_head_at(log, xyz_t[:, 3])

    calibrated, diagnostics = [], {}
    for sensor in log.sensors:
        rows = mask & (sensor_col == sensor.id)
        n = int(rows.sum())
        if n < MIN_OBSERVATIONS:
            calibrated.append(SensorExtrinsics(sensor.id, sensor.position_m.copy(), sensor.ypr_deg.copy(),
                                               observations=n, status="no-data"))
            if progress:
                logging.getLogger(__name__).warning(f"gridsearch {sensor.id}: {n} robot observations, "
                                                    "installed pose kept")
            continue
        res = grid_search_sensor(p_sensor_all[rows], head_all[rows], sensor, progress=progress, **options)
        ext = res.extrinsics
        unobservable = _straight_pass(head_all[rows, :2], ext.R_world_sensor)
        if unobservable:
            ext.status, ext.unobservable = "degenerate", unobservable
            warnings.warn(f"sensor {sensor.id}: the robot's {n} observations are (nearly) on one line or "
                          f"spot; cannot estimate {'; '.join(unobservable)}", DegenerateDataWarning,
                          stacklevel=2)
        calibrated.append(ext)
        diagnostics[sensor.id] = res
    network = SensorNetwork(calibrated, frame=log.sensors.frame, extra=dict(log.sensors.extra))
    return CalibrationResult(network=network, method="gridsearch", runtime_s=time.perf_counter() - t_start,
                             is_robot=mask, diagnostics=GridSearchDiagnostics(sensors=diagnostics,
                                                                              options=dict(options)))
