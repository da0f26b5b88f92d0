"""The ground under a point cloud: a local ground height field that stray points cannot pull down.

``estimate_ground`` finds the ground of one frame seen from a sensor at the cloud's origin (or at
``sensor_xyz``), in a frame with z up (the sensor's body frame, or a base frame):

1. The points go onto a polar grid about the sensor: ``N_SECTORS`` azimuth sectors, range bins
   ``RANGE_BIN_M`` long up to ``FINE_RANGE_M``, then growing by ``RANGE_BIN_GROWTH`` a bin (a
   spinning LIDAR's rings thin out with range, the ground with them).
2. Each cell's ground candidate is its lowest *supported* level: the lowest point with at least
   ``SUPPORT_POINTS`` of the cell's points (all of them, when it holds fewer) within
   ``SUPPORT_BAND_M`` above it. A lone return below the road does not count; a cell holding only
   an object gives that object's lowest level, which step 3 rejects.
3. Each sector is walked outward from the sensor, as a ray-based ground filter does: a candidate
   is ground when it lies within ``max(MAX_STEP_M, MAX_SLOPE * d)`` of the last ground of its own
   sector and of each sector within ``WALK_SECTORS`` of it, ``d`` metres away (its range minus
   theirs, at most ``MAX_GAP_M``, plus the lateral distance between the sectors): a kerb, or a
   ramp or sloped street, is followed; a candidate farther below is a stray return (multipath:
   real street scans hold short runs of points 1-6 m below the road, reflected off car bodies and
   windows), one farther above an object's body (a car's side, a wall). A sector whose candidates
   stay below for ``RELOCK_CELLS`` cells in a row, consistent among themselves, has found a lower
   ground (a ramp down) and takes it. The walk starts at the frame's ground near the sensor: the
   median, over sectors, of each sector's nearest candidate, seen at the median of their ranges
   (cells nearer the sensor than that are held to it by their distance from there too).
4. Ground cells that disagree with the ground of the neighbouring sectors at the same range (the
   median over ``CONSENSUS_SECTORS`` sectors and ``CONSENSUS_BINS`` bins) by more than
   ``MAX_STEP_M`` are dropped (a sector that walked onto strays behind an occluder); each bin's
   ground is then the linear interpolation in range between the ground cells of its sector (at
   their points' own ranges), constant beyond the first and last, and sectors without ground take
   the nearest sector's. Fewer than ``MIN_GROUND_CELLS`` ground cells: every cell's candidate is
   taken, with a warning.
5. ``GroundEstimate.height_at`` is the bilinear interpolation of that grid, in azimuth (round the
   circle) and range bin.

What the estimate found is checked (``GroundEstimate.warnings``, each also logged as a warning):
ground at, or less than ``MIN_SENSOR_CLEARANCE_M`` below, the sensor (a cloud holding no ground, a
cloud in the wrong frame), a ground plane tilted by more than ``MAX_GROUND_TILT_DEG`` within ``TILT_RADIUS_M`` of the
sensor (no street or floor is that steep: a camera's optical frame read as a body frame, a
mis-stated sensor pose), no ground found at all.

``ground_referenced`` subtracts that ground from the points' z (the detector wants z = 0 on the
floor); ``floor_referenced`` subtracts one RANSAC floor plane instead.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from pedcal.errors import DegenerateDataWarning

N_SECTORS = 180  # 2 deg sectors: 0.35 m wide at 10 m
RANGE_BIN_M = 0.5
FINE_RANGE_M = 20.0
RANGE_BIN_GROWTH = 1.05  # beyond FINE_RANGE_M each bin is 5 % longer than the one before
SUPPORT_POINTS = 3
SUPPORT_BAND_M = 0.1
MAX_STEP_M = 0.2  # a kerb (0.1-0.2 m)
MAX_SLOPE = 0.15  # 8.5 deg: steep streets and wheelchair ramps (8 %), car-park ramps (15 %)
WALK_SECTORS = 3
RELOCK_CELLS = 3
MAX_GAP_M = 5.0  # beyond an occluder this long, the ground may have changed by its slope over 5 m only
CONSENSUS_SECTORS = 7
CONSENSUS_BINS = 3
MIN_SENSOR_CLEARANCE_M = 0.1
MAX_GROUND_TILT_DEG = 15.0
TILT_RADIUS_M = 20.0
MIN_GROUND_CELLS = 3

log = logging.getLogger(__name__)


_N_FINE = round(FINE_RANGE_M / RANGE_BIN_M)


def polar_coordinates(xy: np.ndarray, sensor_xy=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (sector, range bin) coordinates of horizontal positions ``xy`` (N, 2) about the
    sensor (step 1): cell (s, k) holds the positions with ``floor(u) == s`` and
    ``floor(v + 0.5) == k``; ``v`` is k at the middle of bin k (``range_bin_centre``)."""
    # single precision: a 1e-7 share of a sector or a range bin is far below anything that matters
    d = (np.asarray(xy, dtype=float).reshape(-1, 2) - np.asarray(sensor_xy, dtype=float)).astype(np.float32)
    u = (np.arctan2(d[:, 1], d[:, 0]) + np.float32(np.pi)) * np.float32(N_SECTORS / (2 * np.pi))
    v = np.hypot(d[:, 0], d[:, 1]) * np.float32(1 / RANGE_BIN_M) - np.float32(0.5)
    far = np.flatnonzero(v >= _N_FINE - 0.5)
    v[far] = _N_FINE - 0.5 + np.log((v[far] + 0.5) / _N_FINE) / np.log(RANGE_BIN_GROWTH)
    return u, v


def range_bin_centre(k: np.ndarray) -> np.ndarray:
    """Horizontal distance (m) of the middle of range bins ``k`` (the inverse of ``polar_coordinates``'
    v at integer values)."""
    k = np.asarray(k, dtype=float)
    far = FINE_RANGE_M * RANGE_BIN_GROWTH ** (k - _N_FINE + 0.5)
    return np.where(k < _N_FINE, (k + 0.5) * RANGE_BIN_M, far)


@dataclass(frozen=True)
class GroundEstimate:
    """A frame's ground height field on the polar grid about the sensor (``estimate_ground``)."""

    grid_z_m: np.ndarray  # (N_SECTORS, bins) ground height, filled everywhere (nan when no ground at all)
    is_ground: np.ndarray  # (N_SECTORS, bins) the cells whose own candidate was taken as ground
    sensor_xyz: tuple[float, float, float]
    sensor_height_m: float  # the sensor above the ground under it (nan when no ground was found)
    tilt_deg: float  # tilt of the plane through the ground cells within TILT_RADIUS_M (nan: too few)
    n_ground_cells: int
    warnings: list[str] = field(default_factory=list)
    point_ground_z_m: np.ndarray | None = None  # (N,) the ground under each point the estimate was made of

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) ground height (z, m) under horizontal positions ``xy`` (N, 2): bilinear in
        (azimuth, range bin) between the cells' centres, the sectors wrapping round."""
        return self._bilinear(*polar_coordinates(xy, self.sensor_xyz[:2]))

    def _bilinear(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        n_s, n_b = self.grid_z_m.shape
        # the sectors wrap round: one more on each side; bin n_b repeats the last
        g = np.vstack([self.grid_z_m[-1:], self.grid_z_m, self.grid_z_m[:1]])
        g = np.concatenate([g, g[:, -1:]], axis=1).astype(np.float32).ravel()
        u = np.asarray(u, dtype=np.float32) + np.float32(0.5)  # sector s's centre at u = s + 1 in g
        s0 = u.astype(np.int64)
        wu = u - s0
        v = np.clip(np.asarray(v, dtype=np.float32), 0.0, n_b - 1.0)
        k0 = v.astype(np.int64)
        wv = v - k0
        a = s0 * (n_b + 1) + k0
        b = a + (n_b + 1)
        out = (1 - wu) * ((1 - wv) * g[a] + wv * g[a + 1]) + wu * ((1 - wv) * g[b] + wv * g[b + 1])
        return out.astype(float)

    def as_dict(self) -> dict:
        """What the CLI's JSON output says about the ground."""
        return dict(sensor_height_m=_finite_or_none(self.sensor_height_m), tilt_deg=_finite_or_none(self.tilt_deg),
                    ground_cells=int(self.n_ground_cells), warnings=list(self.warnings))


def _finite_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _cell_candidates(cell: np.ndarray, z: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Step 2: (n_cells,) lowest supported level of each cell (nan when empty), and the index of
    the point that gives it (-1 when empty)."""
    span = float(np.ptp(z)) + 1.0 if len(z) else 1.0
    # cells apart by more than any height difference plus SUPPORT_BAND_M: one sort orders both
    key = cell * span + (z - z.min()) if len(z) else z
    order = np.argsort(key)
    skey, scell = key[order], cell[order]
    counts = np.bincount(cell, minlength=n_cells)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    # supported: the (need - 1)-th point after it is of the same cell and within SUPPORT_BAND_M
    need = np.minimum(SUPPORT_POINTS, counts[scell])
    ahead = np.arange(len(skey)) + need - 1
    inside = ahead < len(skey)
    ok_at = np.flatnonzero(inside & (skey[np.where(inside, ahead, 0)] - skey <= SUPPORT_BAND_M))
    ok_cell = scell[ok_at]
    first = np.ones(len(ok_cell), dtype=bool)  # the lowest supported point of each cell
    first[1:] = ok_cell[1:] != ok_cell[:-1]
    pick = starts.copy()  # no supported level: the lowest point
    pick[ok_cell[first]] = ok_at[first]
    out = np.full(n_cells, np.nan)
    at = np.full(n_cells, -1)
    filled = counts > 0
    at[filled] = order[pick[filled]]
    out[filled] = z[at[filled]]
    return out, at


def _walk(cand: np.ndarray, cand_r_m: np.ndarray, r_bin_m: np.ndarray, z_start: float, r_start_m: float) -> np.ndarray:
    """Step 3: (sectors, bins) which candidates are ground, each sector walked outward. A
    candidate must lie within the slope cone of the last ground of its own sector and of every
    sector within ``WALK_SECTORS`` of it (the lateral distance between them counted at the slope).
    A sector whose candidates stay below that cone, consistent among themselves, for
    ``RELOCK_CELLS`` cells in a row has ground lower than its neighbours' (a ramp down, a sunken
    street) and takes it: strays below the ground are runs of a few decimetres, not metres."""
    n_s, n_b = cand.shape
    ref_z = np.full(n_s, z_start)
    ref_r = np.full(n_s, r_start_m)  # where the start was seen: the sensor's own position is no ground
    run_z, run_r, run_n = np.full(n_s, np.nan), np.zeros(n_s), np.zeros(n_s, dtype=np.int64)
    ok = np.zeros((n_s, n_b), dtype=bool)
    shifts = np.arange(-WALK_SECTORS, WALK_SECTORS + 1)
    nb = (np.arange(n_s)[None] + shifts[:, None]) % n_s  # (shifts, sectors): each sector's neighbours
    for k in np.flatnonzero(np.isfinite(cand).any(axis=0)):
        c, r = cand[:, k], cand_r_m[:, k]  # each candidate's own range, not its bin's middle
        lateral_m = np.abs(shifts)[:, None] * (2 * np.pi / n_s) * r_bin_m[k]
        z = ref_z[nb]
        # a kerb, or a slope over the distance: not both
        sl = np.maximum(MAX_SLOPE * (np.minimum(np.abs(r - ref_r[nb]), MAX_GAP_M) + lateral_m), MAX_STEP_M)
        good = (c <= (z + sl).min(axis=0)) & (c >= (z - sl).max(axis=0))
        below = np.isfinite(c) & ~good & (c < ref_z)
        same_run = below & (np.abs(c - run_z) <= np.maximum(MAX_STEP_M, MAX_SLOPE * (r - run_r)))
        run_n = np.where(below, np.where(same_run, run_n + 1, 1), np.where(np.isfinite(c), 0, run_n))
        run_z, run_r = np.where(below, c, run_z), np.where(below, r, run_r)
        good |= run_n >= RELOCK_CELLS
        run_n[good] = 0
        ok[:, k] = good
        ref_z = np.where(good, c, ref_z)
        ref_r = np.where(good, r, ref_r)
    return ok


def _fill(cand: np.ndarray, cand_r_m: np.ndarray, ok: np.ndarray, r_bin_m: np.ndarray) -> np.ndarray:
    """Step 4's fill: (sectors, bins) ground height at the middle of every bin, linear in range
    between the ground cells of its sector (at their own points' ranges), constant beyond the
    first and last; sectors without ground take the nearest sector's (round the circle)."""
    n_s, n_b = cand.shape
    grid = np.full((n_s, n_b), np.nan)
    has = ok.any(axis=1)
    for s in np.flatnonzero(has):
        k = np.flatnonzero(ok[s])
        grid[s] = np.interp(r_bin_m, cand_r_m[s, k], cand[s, k])
    if has.any() and not has.all():
        with_ground = np.flatnonzero(has)
        gap = np.abs(np.arange(n_s)[:, None] - with_ground[None])
        gap = np.minimum(gap, n_s - gap)
        grid[~has] = grid[with_ground[np.argmin(gap[~has], axis=1)]]
    return grid


def estimate_ground(points: np.ndarray, sensor_xyz=(0.0, 0.0, 0.0), *, warn: bool = True) -> GroundEstimate:
    """The frame's ground (module docstring): ``points`` (N, 3+) with z up, seen from a sensor at
    ``sensor_xyz`` (m; default the cloud's origin). With ``warn``, each implausibility the
    estimate finds (``GroundEstimate.warnings``) is logged as a warning."""
    pts = np.asarray(points, dtype=float)
    sx, sy, sz = (float(v) for v in sensor_xyz)
    if len(pts) == 0:
        est = GroundEstimate(np.full((N_SECTORS, 1), np.nan), np.zeros((N_SECTORS, 1), dtype=bool), (sx, sy, sz),
                             np.nan, np.nan, 0, ["no points: no ground can be estimated"], np.zeros(0))
        return _report(est, warn)
    u, v = polar_coordinates(pts[:, :2], (sx, sy))
    sector = np.minimum(u.astype(np.int64), N_SECTORS - 1)
    k = (v + 0.5).astype(np.int64)
    n_b = int(k.max()) + 1
    cand, at = _cell_candidates(sector * n_b + k, pts[:, 2], N_SECTORS * n_b)
    cand = cand.reshape(N_SECTORS, n_b)
    cand_r = range_bin_centre(np.where(at >= 0, v[at], np.nan)).reshape(N_SECTORS, n_b)
    r_bin_m = range_bin_centre(np.arange(n_b))
    filled = np.isfinite(cand)
    notes: list[str] = []
    first = np.argmax(filled, axis=1)
    seen = filled.any(axis=1)
    near_z, near_r = cand[np.arange(N_SECTORS), first][seen], cand_r[np.arange(N_SECTORS), first][seen]
    ok = _walk(cand, cand_r, r_bin_m, float(np.median(near_z)), float(np.median(near_r)))
    grid = _fill(cand, cand_r, ok, r_bin_m)
    if ok.any():
        ok &= np.abs(cand - _consensus(grid, ok)) <= MAX_STEP_M
        grid = _fill(cand, cand_r, ok, r_bin_m) if ok.any() else grid
    n_ground = int(ok.sum())
    if n_ground < MIN_GROUND_CELLS:
        notes.append(f"no ground found: {n_ground} ground cells among {int(filled.sum())} occupied, fewer than "
                     f"{MIN_GROUND_CELLS}; the lowest points are taken as the ground")
        grid = _fill(cand, cand_r, filled, r_bin_m)
    ground_here = _at_sensor(grid)
    height = sz - ground_here
    if height < MIN_SENSOR_CLEARANCE_M:
        where = f"{-height:.2f} m above" if height < 0 else f"only {height:.2f} m below"
        notes.append(f"the ground found lies {where} the sensor: the cloud holds no ground, or its frame is "
                     "not z up (an optical frame: --frame optical), or its origin is not the sensor")
    tilt = _tilt_deg(ok, grid, r_bin_m)
    if np.isfinite(tilt) and tilt > MAX_GROUND_TILT_DEG:
        notes.append(f"the ground within {TILT_RADIUS_M:.0f} m of the sensor is tilted by {tilt:.0f} deg, steeper "
                     f"than any street or floor ({MAX_GROUND_TILT_DEG:.0f} deg): the cloud's frame is not z up "
                     "(an optical frame: --frame optical), or the sensor pose is wrong")
    est = GroundEstimate(grid, ok, (sx, sy, sz), height, tilt, n_ground, notes)
    return _report(replace(est, point_ground_z_m=est._bilinear(u, v)), warn)


def _consensus(grid: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Step 4: at each ground cell, the median of the filled grid over CONSENSUS_SECTORS sectors
    (round the circle) and CONSENSUS_BINS bins about it (nan elsewhere)."""
    s, k = np.nonzero(ok)
    ds = np.arange(CONSENSUS_SECTORS) - CONSENSUS_SECTORS // 2
    dk = np.arange(CONSENSUS_BINS) - CONSENSUS_BINS // 2
    ws = (s[:, None, None] + ds[None, :, None]) % grid.shape[0]
    wk = np.clip(k[:, None, None] + dk[None, None, :], 0, grid.shape[1] - 1)
    out = np.full(grid.shape, np.nan)
    out[s, k] = np.median(grid[ws, wk].reshape(len(s), -1), axis=1)
    return out


def _at_sensor(grid: np.ndarray) -> float:
    """The ground height under the sensor: the median over sectors of the nearest bin's ground."""
    col = grid[:, 0]
    return float(np.nanmedian(col)) if np.isfinite(col).any() else np.nan


def _tilt_deg(ok: np.ndarray, grid: np.ndarray, r_bin_m: np.ndarray) -> float:
    """Tilt (deg) of the least-squares plane z = a x + b y + c through the ground cells within
    TILT_RADIUS_M of the sensor (nan with fewer than MIN_GROUND_CELLS of them, or all on one line)."""
    s, k = np.nonzero(ok & (r_bin_m <= TILT_RADIUS_M)[None])
    if len(s) < MIN_GROUND_CELLS:
        return np.nan
    az = (s + 0.5) / N_SECTORS * 2 * np.pi - np.pi
    x, y = r_bin_m[k] * np.cos(az), r_bin_m[k] * np.sin(az)
    A = np.column_stack([x, y, np.ones_like(x)])
    coef, _, rank, _ = np.linalg.lstsq(A, grid[s, k], rcond=None)
    if rank < 3:
        return np.nan
    return float(np.degrees(np.arctan(np.hypot(coef[0], coef[1]))))


def _report(est: GroundEstimate, warn: bool) -> GroundEstimate:
    if warn:
        for note in est.warnings:
            log.warning(note)
    return est


# ------------------------------------------------------------------------ z = 0 on the floor
def is_floor_referenced(points: np.ndarray) -> bool:
    """Whether the cloud already has z = 0 on the floor: its lowest points (1st percentile of z)
    lie within 0.1 m of z = 0 and none is below -0.1 m (the simulator's frames, a crop such as
    KITTI's labelled pedestrian)."""
    z = points[:, 2]
    return abs(float(np.percentile(z, 1.0))) <= 0.1 and z.min() >= -0.1


def ground_referenced(points: np.ndarray, sensor_xyz=(0.0, 0.0, 0.0), *,
                      warn: bool = True) -> tuple[np.ndarray, float]:
    """The points with the local ground height (``estimate_ground``) subtracted from z, and the
    shift added to z under the sensor (the sensor's height above the ground there, for a message).
    An already floor-referenced cloud (``is_floor_referenced``) is returned unchanged."""
    out, shift, _ = _ground_referenced(points, sensor_xyz, warn)
    return out, shift


def _ground_referenced(points: np.ndarray, sensor_xyz, warn: bool) -> tuple[np.ndarray, float, GroundEstimate | None]:
    if len(points) == 0 or is_floor_referenced(points):
        return points, 0.0, None
    est = estimate_ground(points, sensor_xyz, warn=warn)
    out = points.copy()
    out[:, 2] -= est.point_ground_z_m
    shift = est.sensor_height_m - float(sensor_xyz[2])
    return out, float(shift) if np.isfinite(shift) else 0.0, est


def floor_referenced(points: np.ndarray, *, distance_threshold_m: float = 0.05,
                     seed: int = 0) -> tuple[np.ndarray, float]:
    """The points shifted so that z = 0 on one floor plane, and the shift that was added to z.

    A cloud already floor-referenced (``is_floor_referenced``) is returned unchanged. Otherwise
    (a KITTI scan has z = 0 at the sensor, the floor some 1.7 m below) the floor is the largest
    near-horizontal plane found by RANSAC (open3d ``segment_plane``) among the lowest 30 % of the
    points; its height under the sensor is subtracted. Without such a plane the 1st percentile of z
    is taken as the floor and a DegenerateDataWarning says so. For ground that is not one plane
    see ``ground_referenced``.
    """
    import open3d as o3d

    z = points[:, 2]
    z_low = float(np.percentile(z, 1.0))
    if is_floor_referenced(points):
        return points, 0.0
    floor_z = z_low
    low = points[z <= np.percentile(z, 30.0), :3]
    if len(low) >= 3:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(low))
        o3d.utility.random.seed(seed)
        (a, b, c, d), inliers = pc.segment_plane(distance_threshold_m, 3, 200)
        if abs(c) > 0.95 and len(inliers) >= 0.2 * len(low):
            floor_z = float(np.median(low[inliers, 2]))
        else:
            warnings.warn("no horizontal floor plane among the lowest points; the floor is taken at the "
                          f"1st percentile of z ({z_low:.2f} m)", DegenerateDataWarning, stacklevel=2)
    out = points.copy()
    out[:, 2] -= floor_z
    return out, -floor_z


# ------------------------------------------------------------------------ the detector's frame
FRAMES = ("body", "optical")
FLOOR_MODES = ("auto", "plane", "none")


def body_from_optical(points: np.ndarray) -> np.ndarray:
    """Points of a camera's optical frame (REP 103: x right, y down, z forward) in the sensor's
    body frame (x forward, y left, z up): ``x_b = z_o, y_b = -x_o, z_b = -y_o``; columns after
    the third (intensity) are kept."""
    out = np.array(points, dtype=float, copy=True)
    out[:, 0], out[:, 1], out[:, 2] = points[:, 2], -points[:, 0], -points[:, 1]
    return out


@dataclass(frozen=True)
class DetectorFrame:
    """A cloud put where the detector wants it (``detector_frame``)."""

    points: np.ndarray  # (N, 4) in the sensor's body frame (or the base frame of a sensor pose), z = 0 on the floor
    floor_shift_m: float  # added to z under the sensor to put the floor at z = 0 (0 when z was kept)
    ground: GroundEstimate | None  # the local ground (floor "auto" on a cloud not yet floor-referenced)
    sensor_height_m: float | None  # the sensor's height above the floor, where known
    sensor_xy_m: tuple[float, float]  # the sensor's horizontal position in that frame

    @property
    def warnings(self) -> list[str]:
        return list(self.ground.warnings) if self.ground is not None else []


def detector_frame(points: np.ndarray, *, frame: str = "body", floor: str = "none",
                   sensor_pose: str | None = None) -> DetectorFrame:
    """``points`` (N, 3+) of a sensor at the origin, in its body frame or (``frame="optical"``)
    its optical frame, put into its body frame with z = 0 on the floor: with ``sensor_pose``
    ("x,y,z,roll,pitch,yaw" of the body frame above the floor, m and deg) the points are mapped
    into the base frame; otherwise ``floor`` "auto" subtracts the local ground
    (``ground_referenced``), "plane" one RANSAC floor plane (``floor_referenced``), "none" keeps z."""
    from pedcal.detect.sensors import parse_sensor_pose, to_base_frame
    from pedcal.errors import PedcalInputError

    if frame not in FRAMES:
        raise PedcalInputError(f"frame {frame!r}: expected one of {', '.join(FRAMES)}", column="frame")
    if floor not in FLOOR_MODES:
        raise PedcalInputError(f"floor {floor!r}: expected one of {', '.join(FLOOR_MODES)}", column="floor")
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise PedcalInputError(f"points must be (N, 3) or (N, 4) x, y, z[, intensity]; got shape {pts.shape}")
    if pts.shape[1] == 3:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if frame == "optical":
        pts = body_from_optical(pts)
    if sensor_pose is not None:
        position_m, ypr_deg = parse_sensor_pose(sensor_pose)
        return DetectorFrame(to_base_frame(pts, position_m, ypr_deg), float(position_m[2]), None,
                             float(position_m[2]), (float(position_m[0]), float(position_m[1])))
    if floor == "none" or len(pts) == 0:
        return DetectorFrame(pts, 0.0, None, None, (0.0, 0.0))
    if floor == "plane":
        out, dz = floor_referenced(pts)
        return DetectorFrame(out, dz, None, dz if dz > 0 else None, (0.0, 0.0))
    out, dz, est = _ground_referenced(pts, (0.0, 0.0, 0.0), True)
    return DetectorFrame(out, dz, est, dz if dz > 0 else None, (0.0, 0.0))
