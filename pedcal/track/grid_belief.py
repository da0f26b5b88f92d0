"""Grid belief over where an out-of-sight target can be, on a local window of the occupancy map.

A discrete Bayes filter on world-aligned cells (``belief[iy, ix]``, iy along +y, ix along +x, cell
centre ``origin_xy_world_m + (ix + 0.5, iy + 0.5) * resolution_m``). It holds what the Kalman
filters cannot: multi-modal hypotheses shaped by walls.

- walls: cells the map marks occupied carry zero belief, always (``blocked``);
- motion: a masked diffusion with sigma = walking speed x dt, done as several one-cell Gaussian
  steps so belief never jumps a one-cell wall, then renormalized;
- negative information: cells the LIDAR saw empty in this frame (inside its field of view, within
  range, not behind a wall or a person: rays cast on the grid) are multiplied by (1 - p_det);
- the antenna: each cell's bearing from the antenna multiplies the belief by the reading's
  likelihood P(Z | A) (:mod:`pedcal.track.espar`, eq. 10: fitted spread plus a multipath floor);
- the smoother's Gaussian sharpens it (``observe_gaussian``).

Unlike the paper's target-existence grid (accumulated over 10 readings while the robot stands
still), this one is updated every frame while the robot moves.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.frames import wrap_angle_rad
from pedcal.io.maps import OccupancyMap
from pedcal.track.espar import DEFAULT_LIKELIHOOD, EsparLikelihood


@dataclass(frozen=True)
class GridBeliefConfig:
    """Everything the grid belief assumes; recorded with the tracker's results."""

    resolution_m: float = 0.1
    half_size_m: float = 8.0            # the window spans 2 x half_size_m around its centre
    walk_speed_mps: float = 1.2         # diffusion sigma per step = walk_speed_mps * dt_s
    fov_rad: float = math.radians(120.0)
    max_range_m: float = 5.0
    min_range_m: float = 0.3
    p_detect: float = 0.9               # chance the detector finds the target in a cell it saw empty
    person_radius_m: float = 0.3        # people occlude the LIDAR over this radius
    robot_clear_m: float = 0.5          # nobody stands within this of the robot's centre (robot + person radius)
    block_unknown: bool = False         # also give zero belief to cells the map does not know free
    n_rays: int = 241                   # rays cast over the field of view
    recenter_margin_m: float = 3.0      # shift the window when the estimate is this close to its edge

    def __post_init__(self):
        for name in ("resolution_m", "half_size_m", "max_range_m", "fov_rad"):
            if not getattr(self, name) > 0:
                raise PedcalInputError(f"grid belief: {name} must be positive, got {getattr(self, name)}")
        if not 0.0 <= self.p_detect < 1.0:
            raise PedcalInputError(f"grid belief: p_detect must be in [0, 1), got {self.p_detect}")


_MAP_BLOCKED: dict[tuple[int, float, bool], tuple[OccupancyMap, np.ndarray, np.ndarray]] = {}


def _map_blocked(occupancy: OccupancyMap, resolution_m: float, block_unknown: bool) -> tuple[np.ndarray, np.ndarray]:
    """World-aligned cells of ``resolution_m`` over the whole map: (origin_xy_world_m, blocked[iy, ix]).

    A cell is blocked when any occupied map cell falls in it (sub-sampled at the map's resolution). The
    origin is a multiple of the cell size, as every window's. Cached per map object: a tracker starts a
    grid at every loss of the target.
    """
    key = (id(occupancy), resolution_m, block_unknown)
    hit = _MAP_BLOCKED.get(key)
    if hit is not None and hit[0] is occupancy:
        return hit[1], hit[2]
    rows, cols = occupancy.shape
    corners = occupancy.cell_to_world(np.array([[-0.5, -0.5], [-0.5, cols - 0.5], [rows - 0.5, -0.5],
                                                [rows - 0.5, cols - 0.5]]))
    lo = np.floor(corners.min(axis=0) / resolution_m) * resolution_m
    shape = np.ceil((corners.max(axis=0) - lo) / resolution_m).astype(int)[::-1]     # (ny, nx)
    k = max(1, int(math.ceil(resolution_m / occupancy.resolution_m)))
    ny, nx = int(shape[0]), int(shape[1])
    blocked = np.zeros((ny, nx), dtype=bool)
    sub_x = lo[0] + (np.arange(nx * k) + 0.5) * (resolution_m / k)
    for r0 in range(0, ny, 64):                       # bands of rows keep the sub-sample arrays small
        r1 = min(r0 + 64, ny)
        sub_y = lo[1] + (np.arange(r0 * k, r1 * k) + 0.5) * (resolution_m / k)
        xx, yy = np.meshgrid(sub_x, sub_y)
        xy = np.stack([xx, yy], axis=-1)
        bad = occupancy.is_occupied(xy)
        if block_unknown:
            bad |= ~occupancy.is_free(xy)
        blocked[r0:r1] = bad.reshape(r1 - r0, k, nx, k).any(axis=(1, 3))
    _MAP_BLOCKED[key] = (occupancy, lo, blocked)
    return lo, blocked


class GridBelief:
    """Belief over the target's cell in a local window; see the module notes."""

    def __init__(self, occupancy: OccupancyMap | None, center_xy_world_m, config: GridBeliefConfig | None = None,
                 espar_model: EsparLikelihood = DEFAULT_LIKELIHOOD):
        self.config = config or GridBeliefConfig()
        self.espar_model = espar_model
        # P(Z | A) tabulated over the wrapped difference (0.1 deg steps): the 12-direction normalization
        # of eq. 10 costs 12 exponentials per cell otherwise
        self._espar_diff_rad = np.linspace(-np.pi, np.pi, 3601)
        self._espar_table = espar_model.p_direction(self._espar_diff_rad)
        self.occupancy = occupancy
        self.n_cells = int(round(2.0 * self.config.half_size_m / self.config.resolution_m))
        self._place(np.asarray(center_xy_world_m, dtype=float))
        self.belief = self._uniform()

    # ---- geometry -------------------------------------------------------------------------
    def _place(self, center_xy_world_m: np.ndarray) -> None:
        res = self.config.resolution_m
        # snap the window to a multiple of the cell size so recentring shifts by whole cells
        self.origin_xy_world_m = np.floor((center_xy_world_m - self.config.half_size_m) / res) * res
        self.blocked = self._blocked_mask(self.origin_xy_world_m)
        axis = (np.arange(self.n_cells) + 0.5) * res
        self.x_m = self.origin_xy_world_m[0] + axis          # (nx,) cell centres
        self.y_m = self.origin_xy_world_m[1] + axis          # (ny,)

    def _blocked_mask(self, origin_xy_world_m: np.ndarray) -> np.ndarray:
        """The window's slice of the whole map's blocked cells (computed once per map and cell size)."""
        n = self.n_cells
        if self.occupancy is None:
            return np.zeros((n, n), dtype=bool)
        map_origin, map_blocked = _map_blocked(self.occupancy, self.config.resolution_m, self.config.block_unknown)
        i0, j0 = np.rint((origin_xy_world_m[::-1] - map_origin[::-1]) / self.config.resolution_m).astype(int)
        out = np.zeros((n, n), dtype=bool)
        ny, nx = map_blocked.shape
        ys, xs = slice(max(i0, 0), min(i0 + n, ny)), slice(max(j0, 0), min(j0 + n, nx))
        if ys.start < ys.stop and xs.start < xs.stop:
            out[ys.start - i0:ys.stop - i0, xs.start - j0:xs.stop - j0] = map_blocked[ys, xs]
        return out

    def cell_of(self, xy_world_m) -> np.ndarray:
        """World points (..., 2) -> [iy, ix] (may fall outside the window)."""
        rel = (np.asarray(xy_world_m, dtype=float) - self.origin_xy_world_m) / self.config.resolution_m
        return np.floor(rel[..., ::-1]).astype(np.int64)

    def in_window(self, ij) -> np.ndarray:
        ij = np.asarray(ij)
        return ((ij >= 0) & (ij < self.n_cells)).all(axis=-1)

    def cell_center(self, ij) -> np.ndarray:
        ij = np.asarray(ij, dtype=float)
        return self.origin_xy_world_m + (ij[..., ::-1] + 0.5) * self.config.resolution_m

    def is_blocked(self, xy_world_m) -> np.ndarray:
        ij = self.cell_of(xy_world_m)
        inside = self.in_window(ij)
        out = np.zeros(inside.shape, dtype=bool)
        out[inside] = self.blocked[ij[..., 0][inside], ij[..., 1][inside]]
        return out

    def recenter(self, center_xy_world_m) -> None:
        """Move the window to a new centre, keeping the belief of the cells both windows share."""
        old_origin, old_belief = self.origin_xy_world_m, self.belief
        self._place(np.asarray(center_xy_world_m, dtype=float))
        shift = np.round((self.origin_xy_world_m - old_origin) / self.config.resolution_m).astype(int)
        dx, dy = int(shift[0]), int(shift[1])
        n = self.n_cells
        new = np.zeros_like(old_belief)
        src_y, dst_y = slice(max(dy, 0), n + min(dy, 0)), slice(max(-dy, 0), n - max(dy, 0))
        src_x, dst_x = slice(max(dx, 0), n + min(dx, 0)), slice(max(-dx, 0), n - max(dx, 0))
        if abs(dx) < n and abs(dy) < n:
            new[dst_y, dst_x] = old_belief[src_y, src_x]
        # cells entering the window know nothing yet: give them the old window's smallest mass
        entering = np.ones((n, n), dtype=bool)
        if abs(dx) < n and abs(dy) < n:
            entering[dst_y, dst_x] = False
        floor = old_belief[old_belief > 0].min() if (old_belief > 0).any() else 1.0
        new[entering] = floor
        self.belief = new
        self._normalize()

    def keep_in_window(self, xy_world_m) -> None:
        """Recentre when a point of interest comes within ``recenter_margin_m`` of the window's edge."""
        xy = np.asarray(xy_world_m, dtype=float)
        lo = self.origin_xy_world_m + self.config.recenter_margin_m
        hi = self.origin_xy_world_m + 2.0 * self.config.half_size_m - self.config.recenter_margin_m
        if (xy < lo).any() or (xy > hi).any():
            self.recenter(xy)

    # ---- belief updates ---------------------------------------------------------------------
    def _uniform(self) -> np.ndarray:
        belief = (~self.blocked).astype(float)
        total = belief.sum()
        return belief / total if total > 0 else belief

    def _normalize(self) -> None:
        self.belief[self.blocked] = 0.0
        total = self.belief.sum()
        if not total > 0 or not np.isfinite(total):
            warnings.warn("grid belief: every free cell was ruled out; the target's position cannot be "
                          "estimated from the grid, restarting from a uniform belief", DegenerateDataWarning,
                          stacklevel=3)
            self.belief = self._uniform()
            return
        self.belief /= total

    def reset_gaussian(self, xy_world_m, sigma_m: float | None = None, cov_world=None) -> None:
        """Start from a Gaussian around a point (e.g. where the target was last seen): isotropic of
        ``sigma_m``, or of the (2, 2) world covariance ``cov_world`` (metres squared)."""
        xy = np.asarray(xy_world_m, dtype=float)
        self.keep_in_window(xy)
        if cov_world is None:
            gx = np.exp(-0.5 * ((self.x_m - xy[0]) / sigma_m) ** 2)
            gy = np.exp(-0.5 * ((self.y_m - xy[1]) / sigma_m) ** 2)
            self.belief = np.outer(gy, gx) + 1e-12
        else:
            info = np.linalg.inv(np.asarray(cov_world, dtype=float))
            dx = self.x_m[None, :] - xy[0]
            dy = self.y_m[:, None] - xy[1]
            q = info[0, 0] * dx * dx + 2.0 * info[0, 1] * dx * dy + info[1, 1] * dy * dy
            self.belief = np.exp(-0.5 * q) + 1e-12
        self._normalize()

    def predict(self, dt_s: float) -> None:
        """Motion step: masked diffusion with sigma = walking speed x dt (in one-cell steps)."""
        if dt_s <= 0:
            return
        sigma_cells = self.config.walk_speed_mps * dt_s / self.config.resolution_m
        # n steps of sigma 1 cell (kernel radius 1) add up to sigma sqrt(n); belief never crosses a wall cell
        n_steps = max(1, int(math.ceil(sigma_cells ** 2)))
        sigma_step = sigma_cells / math.sqrt(n_steps)
        free = ~self.blocked
        belief = self.belief
        for _ in range(n_steps):
            belief = ndimage.gaussian_filter(belief, sigma_step, truncate=1.0 / max(sigma_step, 1e-9),
                                             mode="constant")
            belief *= free
        self.belief = belief
        self._normalize()

    def visible_cells(self, pose_world_sensor, occluders_xy_world_m=()) -> tuple[np.ndarray, np.ndarray]:
        """Cells the LIDAR at ``pose_world_sensor`` (x_m, y_m, yaw_rad) sees as free space this frame.

        Rays over the field of view stop at the first blocked cell and at people (the occluders,
        radius ``person_radius_m``); a cell is seen when its centre lies nearer than its ray's end by
        at least one cell. Returns (iy, ix) index arrays.
        """
        cfg = self.config
        x0, y0, yaw = (float(v) for v in pose_world_sensor)
        res = cfg.resolution_m
        ray_rel_rad = np.linspace(-cfg.fov_rad / 2.0, cfg.fov_rad / 2.0, cfg.n_rays)
        r_samples = np.arange(cfg.min_range_m, cfg.max_range_m + res, res / 2.0)
        ang = yaw + ray_rel_rad
        pts = np.stack([x0 + np.cos(ang)[:, None] * r_samples, y0 + np.sin(ang)[:, None] * r_samples], axis=-1)
        hit = self.is_blocked(pts)                                    # (n_rays, n_samples)
        ray_end_m = np.where(hit.any(axis=1), r_samples[np.argmax(hit, axis=1)], cfg.max_range_m)
        occ = np.asarray(occluders_xy_world_m, dtype=float).reshape(-1, 2)
        if len(occ):
            d_occ = np.hypot(occ[:, 0] - x0, occ[:, 1] - y0)
            b_occ = np.arctan2(occ[:, 1] - y0, occ[:, 0] - x0)
            half_width = np.arctan2(cfg.person_radius_m, np.maximum(d_occ, 1e-6))
            shadowed = np.abs(wrap_angle_rad(ang[:, None] - b_occ[None, :])) <= half_width[None, :]
            ray_end_m = np.minimum(ray_end_m, np.where(shadowed, d_occ - cfg.person_radius_m, np.inf).min(axis=1))
        # only the square around the sensor can be in range
        lo = self.cell_of(np.array([x0, y0]) - cfg.max_range_m)
        hi = self.cell_of(np.array([x0, y0]) + cfg.max_range_m) + 1
        iy0, ix0 = np.clip(lo, 0, self.n_cells)
        iy1, ix1 = np.clip(hi, 0, self.n_cells)
        if iy1 <= iy0 or ix1 <= ix0:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
        dx = self.x_m[ix0:ix1][None, :] - x0
        dy = self.y_m[iy0:iy1][:, None] - y0
        d = np.hypot(dx, dy)
        rel = wrap_angle_rad(np.arctan2(dy, dx) - yaw)
        in_fov = np.abs(rel) <= cfg.fov_rad / 2.0
        ray = np.clip(np.rint((rel + cfg.fov_rad / 2.0) / cfg.fov_rad * (cfg.n_rays - 1)).astype(int),
                      0, cfg.n_rays - 1)
        seen = in_fov & (d >= cfg.min_range_m) & (d <= ray_end_m[ray] - res) & ~self.blocked[iy0:iy1, ix0:ix1]
        iy, ix = np.nonzero(seen)
        return iy + iy0, ix + ix0

    def observe_empty(self, pose_world_sensor, occluders_xy_world_m=()) -> int:
        """Negative information: the target was not detected, so cells seen empty lose belief, and
        the robot's footprint (``robot_clear_m`` around the sensor) holds nobody.

        Returns how many cells were seen.
        """
        iy, ix = self.visible_cells(pose_world_sensor, occluders_xy_world_m)
        self.belief[iy, ix] *= 1.0 - self.config.p_detect
        # the robot's own footprint: the sensor never sees it (min range, behind), yet nobody is there
        x0, y0 = float(pose_world_sensor[0]), float(pose_world_sensor[1])
        near = ((self.x_m[None, :] - x0) ** 2 + (self.y_m[:, None] - y0) ** 2) <= self.config.robot_clear_m ** 2
        self.belief[near] = 0.0
        self._normalize()
        return len(iy)

    def bearing_likelihood(self, xy_antenna_world_m, bearing_world_rad: float) -> np.ndarray:
        """P(Z | A) of every cell for one reading (eq. 10; A = the cell's bearing from the antenna)."""
        dx = self.x_m[None, :] - float(xy_antenna_world_m[0])
        dy = self.y_m[:, None] - float(xy_antenna_world_m[1])
        diff = wrap_angle_rad(bearing_world_rad - np.arctan2(dy, dx))
        step = self._espar_diff_rad[1] - self._espar_diff_rad[0]
        return self._espar_table[np.rint((diff + np.pi) / step).astype(np.int64)]

    def observe_bearing(self, xy_antenna_world_m, bearing_world_rad: float) -> None:
        """Multiply by the antenna likelihood of one reading."""
        self.belief *= self.bearing_likelihood(xy_antenna_world_m, bearing_world_rad)
        self._normalize()

    def observe_gaussian(self, mean_xy_world_m, cov_world: np.ndarray, floor: float = 0.05) -> None:
        """Sharpen with a Gaussian estimate (the smoother's); ``floor`` keeps other modes alive."""
        mean = np.asarray(mean_xy_world_m, dtype=float)
        info = np.linalg.inv(np.asarray(cov_world, dtype=float) + 1e-9 * np.eye(2))
        dx = self.x_m[None, :] - mean[0]
        dy = self.y_m[:, None] - mean[1]
        m2 = info[0, 0] * dx * dx + 2.0 * info[0, 1] * dx * dy + info[1, 1] * dy * dy
        self.belief *= np.exp(-0.5 * m2) + floor
        self._normalize()

    def copy(self) -> GridBelief:
        """An independent belief on the same window (the map masks are shared, read-only)."""
        other = object.__new__(GridBelief)
        other.__dict__.update(self.__dict__)
        other.belief = self.belief.copy()
        return other

    # ---- answers ----------------------------------------------------------------------------
    def mode(self) -> np.ndarray:
        """Centre of the most probable cell (always a free cell)."""
        iy, ix = np.unravel_index(np.argmax(self.belief), self.belief.shape)
        return np.array([self.x_m[ix], self.y_m[iy]])

    def estimate(self, component_radius_m: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
        """Mean and covariance of the dominant component (the mass within a radius of the mode).

        Returns (xy_world_m, cov_world, mass): xy is a free cell's centre (the mean, or the mode if the
        mean falls in a blocked cell), mass is the belief inside the component.
        """
        mode = self.mode()
        dx = self.x_m[None, :] - mode[0]
        dy = self.y_m[:, None] - mode[1]
        near = dx * dx + dy * dy <= component_radius_m ** 2
        w = self.belief * near
        mass = float(w.sum())
        mean = np.array([(w * (self.x_m[None, :])).sum(), (w * self.y_m[:, None]).sum()]) / mass
        ex = self.x_m[None, :] - mean[0]
        ey = self.y_m[:, None] - mean[1]
        cov = np.array([[(w * ex * ex).sum(), (w * ex * ey).sum()],
                        [(w * ex * ey).sum(), (w * ey * ey).sum()]]) / mass
        cov += (self.config.resolution_m ** 2 / 12.0) * np.eye(2)
        ij = self.cell_of(mean)
        xy = self.cell_center(ij) if self.in_window(ij) and not self.blocked[ij[0], ij[1]] else mode
        return xy, cov, mass

    def spread_m(self) -> float:
        """Root of the trace of the whole belief's covariance: how far the hypotheses lie apart."""
        px, py = self.belief.sum(axis=0), self.belief.sum(axis=1)
        mx, my = px @ self.x_m, py @ self.y_m
        return float(math.sqrt(px @ (self.x_m - mx) ** 2 + py @ (self.y_m - my) ** 2))
