"""Following one person in simulation: scenes, scripted episodes, walkers, per-frame sensing, the robot.

World frame: the map frame (x, y metres, yaw radians counter-clockwise). People are discs
(``PERSON_RADIUS_M``) with a height and a clothing reflectance (a Beta distribution of LIDAR
intensities in [0, 1]); walls are an :class:`~pedcal.io.maps.OccupancyMap`.

Sensing at ``FRAME_HZ`` (4 Hz, Misu and Miura's FX8 pair): a person is in view when within
``FOV_RAD`` (120 deg) in front and 0.3-5 m, and the ray from the robot to its centre crosses no
occupied cell and no other person's disc (:func:`visible_people`). A person in view is detected with a
range-dependent probability, its position with ``SIGMA_POS_M`` noise; clutter adds false detections
near walls. ESPAR readings come from :class:`~pedcal.sim.espar.EsparSimulator` with the target's true
position in the robot frame; the localization estimate is the truth plus a correlated (AR(1)) error.

The robot is a unicycle with speed and turn limits (:class:`RobotController`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.errors import PedcalInputError
from pedcal.follow_types import FollowFrame, PersonDetection, TrackerOutput
from pedcal.frames import wrap_angle_rad
from pedcal.io.maps import OccupancyMap
from pedcal.sim.espar import EsparSimulator

FRAME_HZ = 4.0
PERSON_RADIUS_M = 0.25
TARGET_PERSON_M = 0.5  # the person the target estimate stands for: the nearest within this (as a track's match)
ROBOT_RADIUS_M = 0.3  # the robot's disc: the planner keeps walls this far, contacts use it
FOV_RAD = np.radians(120.0)
MIN_RANGE_M, MAX_RANGE_M = 0.3, 5.0
SIGMA_POS_M = 0.05
N_REFLECTANCE_BINS = 25
N_REFLECTANCE_POINTS = 80  # LIDAR points on a person whose intensities make the histogram
FOLLOW_DISTANCE_M = 1.2
MAP_RESOLUTION_M = 0.05


# ------------------------------------------------------------------------------------------ people
@dataclass
class Walker:
    """One person: a trajectory sampled in time (present only within ``t_s``'s span)."""

    person_id: str
    t_s: np.ndarray  # (N,) increasing
    xy_world_m: np.ndarray  # (N, 2)
    height_m: float = 1.7
    reflectance_ab: tuple[float, float] = (2.0, 5.0)  # Beta(a, b) of the clothing's intensities
    stays: bool = False  # stands at its last position after the span (scripted routes)

    def at(self, t_s: float) -> np.ndarray | None:
        """Position at ``t_s`` (linear interpolation), None outside the recorded span (after it,
        the last position if ``stays``)."""
        if len(self.t_s) == 0 or t_s < self.t_s[0] or (t_s > self.t_s[-1] and not self.stays):
            return None
        return np.array([np.interp(t_s, self.t_s, self.xy_world_m[:, 0]),
                         np.interp(t_s, self.t_s, self.xy_world_m[:, 1])])


def route_walker(person_id: str, waypoints_xy_m, speeds_mps, t0_s: float = 0.0, *, waits_s=None,
                 height_m: float = 1.7, reflectance_ab=(2.0, 5.0)) -> Walker:
    """A walker along ``waypoints_xy_m`` (K, 2); leg k at ``speeds_mps[k]``; ``waits_s[k]`` seconds
    standing at waypoint k before leg k (default none)."""
    wp = np.asarray(waypoints_xy_m, dtype=float)
    speeds = np.broadcast_to(np.asarray(speeds_mps, dtype=float), (len(wp) - 1,))
    waits = np.zeros(len(wp)) if waits_s is None else np.asarray(waits_s, dtype=float)
    t, pts = [t0_s], [wp[0]]
    for k in range(len(wp) - 1):
        if waits[k] > 0:
            t.append(t[-1] + waits[k])
            pts.append(wp[k])
        t.append(t[-1] + np.linalg.norm(wp[k + 1] - wp[k]) / speeds[k])
        pts.append(wp[k + 1])
    return Walker(person_id, np.array(t), np.array(pts), height_m, tuple(reflectance_ab), stays=True)


def random_walkers(n: int, area_xy_m: tuple[float, float, float, float], t1_s: float, rng: np.random.Generator,
                   occupancy: OccupancyMap | None = None) -> list[Walker]:
    """Built-in walker model: each walker goes straight between random free points of the area
    (x0, y0, x1, y1) at 0.6-1.4 m/s, pausing 0-3 s at each, from t = 0 to ``t1_s``."""
    x0, y0, x1, y1 = area_xy_m
    out = []
    for i in range(n):
        def point():
            for _ in range(50):
                p = rng.uniform([x0, y0], [x1, y1])
                if occupancy is None or not occupancy.is_occupied(p):
                    return p
            return p
        wp, waits, speeds = [point()], [], []
        t = 0.0
        while t < t1_s:
            nxt = point()
            v = rng.uniform(0.6, 1.4)
            w = rng.uniform(0.0, 3.0)
            t += w + np.linalg.norm(nxt - wp[-1]) / v
            wp.append(nxt)
            speeds.append(v)
            waits.append(w)
        waits.append(0.0)
        out.append(route_walker(f"w{i}", wp, speeds, waits_s=waits, height_m=float(rng.uniform(1.5, 1.9)),
                                reflectance_ab=_random_clothing(rng)))
    return out


def avoid_collisions(walkers: list[Walker], fixed: list[Walker], duration_s: float, dt_s: float = 0.25,
                     occupancy: OccupancyMap | None = None, strength_mps: float = 2.0, range_m: float = 0.3,
                     max_speed_mps: float = 2.0) -> list[Walker]:
    """Re-play ``walkers`` so they keep out of each other's and the ``fixed`` people's way (the
    scripted target): each step a walker heads for where its own trajectory is one step later and is
    pushed off every other person by ``strength_mps * exp((2 r - d) / range_m)`` (a social force on
    the velocity, Helbing and Molnar's exponential repulsion); a step into a wall is not taken."""
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    present = np.array([[w.at(ti) is not None for ti in t] for w in walkers]).reshape(len(walkers), len(t))
    orig = np.array([[w.at(ti) if ok else (np.nan, np.nan) for ti, ok in zip(t, row, strict=True)]
                     for w, row in zip(walkers, present, strict=True)]).reshape(len(walkers), len(t), 2)
    fixed_xy = np.array([[f.at(ti) if f.at(ti) is not None else (np.nan, np.nan) for ti in t] for f in fixed]
                        ).reshape(len(fixed), len(t), 2)
    out = orig.copy()
    for k in range(1, len(t)):
        cur = out[:, k - 1].copy()
        start = present[:, k] & ~present[:, k - 1]
        cur[start] = orig[start, k]
        others = np.concatenate([cur, fixed_xy[:, k - 1]])
        d = cur[:, None, :] - others[None, :, :]
        dist = np.linalg.norm(d, axis=2)
        np.fill_diagonal(dist[:, :len(walkers)], np.inf)
        dist = np.where(np.isnan(dist), np.inf, dist)
        push = strength_mps * np.exp((2 * PERSON_RADIUS_M - dist) / range_m)
        rep = np.nansum(np.where(np.isfinite(dist)[..., None], push[..., None] * d / np.maximum(dist, 1e-6)[..., None],
                                 0.0), axis=1)
        nxt = orig[:, min(k + 1, len(t) - 1)]
        nxt = np.where(np.isnan(nxt), cur, nxt)
        own_speed = np.nan_to_num(np.linalg.norm(nxt - orig[:, k], axis=1) / dt_s)
        want = (nxt - cur) / dt_s  # back onto its own trajectory, at most 0.5 m/s faster than it walks
        want_speed = np.linalg.norm(want, axis=1, keepdims=True)
        v = want * np.minimum(1.0, (own_speed[:, None] + 0.5) / np.maximum(want_speed, 1e-9)) + rep
        speed = np.linalg.norm(v, axis=1, keepdims=True)
        v *= np.minimum(1.0, max_speed_mps / np.maximum(speed, 1e-9))
        step = cur + v * dt_s
        if occupancy is not None:
            bad = occupancy.is_occupied(np.nan_to_num(step))
            step[bad] = cur[bad]
        out[:, k] = np.where(present[:, k, None], step, np.nan)
    res = []
    for w, row, xy in zip(walkers, present, out, strict=True):
        if row.sum() >= 2:
            res.append(Walker(w.person_id, t[row], xy[row], w.height_m, w.reflectance_ab, w.stays))
    return res


ROBOT_COMFORT_M = 0.15  # the gap a walker keeps from the robot's disc beyond contact (m)
SIDESTEP_DEG = (0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 130.0)  # headings a reacting walker tries, off its wish


def on_frame_grid(walker: Walker, duration_s: float, dt_s: float = 1.0 / FRAME_HZ) -> Walker:
    """``walker`` sampled at the frames (multiples of ``dt_s`` s) of its span within ``duration_s``,
    so that each frame's position can be changed on its own (:class:`ReactiveCrowd`)."""
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    t = t[(t >= walker.t_s[0] - 1e-9) & ((t <= walker.t_s[-1] + 1e-9) | walker.stays)]
    xy = np.array([walker.at(ti) if walker.at(ti) is not None else walker.xy_world_m[0] for ti in t]).reshape(-1, 2)
    return Walker(walker.person_id, t, xy, walker.height_m, walker.reflectance_ab, walker.stays)


class ReactiveCrowd:
    """Simulated walkers who react to the robot as people do, frame by frame as the episode plays.

    Each walker holds its planned trajectory (world frame, m, sampled at the frames); at every frame
    (:meth:`react`) it heads from where it actually is for where its plan is at that frame (at most
    0.5 m/s faster than the plan walks, so a detour rejoins the plan), and a step that would end
    within ``ROBOT_RADIUS_M + PERSON_RADIUS_M + comfort_m`` of the robot's centre (now, or where the
    robot's current velocity takes it in one frame) is not taken: the walker tries headings turned
    off its wish (``SIDESTEP_DEG``, the side away from the robot first), then half its speed, then
    waits; one already that close steps straight away from the robot. Steps into a wall or onto
    another walker (the discs overlapping) are avoided when another step keeps off the robot too.
    Recorded walkers are never given one: real people in a recording do not see the robot.

    The walkers' ``xy_world_m`` at the frame just played is overwritten in place, so
    ``Walker.at`` answers the reacted positions; :meth:`reset` restores the plan before an episode
    is played (a run is deterministic per seed and may be repeated).
    """

    def __init__(self, walkers: list[Walker], occupancy: OccupancyMap | None = None,
                 comfort_m: float = ROBOT_COMFORT_M, dt_s: float = 1.0 / FRAME_HZ):
        self.walkers = walkers
        self.plan = [w.xy_world_m.copy() for w in walkers]
        self.occupancy = occupancy
        self.keep_m = ROBOT_RADIUS_M + PERSON_RADIUS_M + comfort_m
        self.dt_s = dt_s

    def reset(self) -> None:
        """Every walker back on its plan."""
        for w, plan in zip(self.walkers, self.plan, strict=True):
            w.xy_world_m = plan.copy()

    def react(self, t_s: float, robot_xy_m: np.ndarray, robot_v_mps: np.ndarray) -> None:
        """Place every walker present at ``t_s`` (a frame time, s) given the robot's centre (world, m)
        at ``t_s`` and its velocity over the last frame (world, m/s)."""
        r = np.asarray(robot_xy_m, float)
        r_next = r + np.asarray(robot_v_mps, float) * self.dt_s
        idx = []
        for w in self.walkers:
            i = int(np.searchsorted(w.t_s, t_s - 1e-6))
            idx.append(i if i < len(w.t_s) and abs(w.t_s[i] - t_s) < 1e-6 else None)
        prev = np.array([w.xy_world_m[i - 1] if i is not None and i > 0 else (np.nan, np.nan)
                         for w, i in zip(self.walkers, idx, strict=True)]).reshape(-1, 2)
        for j, (w, plan, i) in enumerate(zip(self.walkers, self.plan, idx, strict=True)):
            if i is None:
                continue
            if i == 0:  # it appears where its plan puts it, outside the robot's keep-out disc
                d = w.xy_world_m[0] - r
                n = float(np.linalg.norm(d))
                if n < self.keep_m:
                    w.xy_world_m[0] = r + (d / n if n > 1e-9 else np.array([1.0, 0.0])) * self.keep_m
                continue
            cur = w.xy_world_m[i - 1]
            own_speed = np.linalg.norm(plan[i] - plan[i - 1]) / self.dt_s
            want = (plan[i] - cur) / self.dt_s
            speed = float(np.linalg.norm(want))
            if speed > own_speed + 0.5:
                want *= (own_speed + 0.5) / speed
            others = np.delete(prev, j, axis=0)
            others = others[np.isfinite(others[:, 0])]
            w.xy_world_m[i] = self._step(cur, want, r, r_next, others)

    def _step(self, cur: np.ndarray, want: np.ndarray, r: np.ndarray, r_next: np.ndarray,
              others: np.ndarray) -> np.ndarray:
        """The walker's next position (world, m) from ``cur`` wishing to walk at ``want`` (m/s), the
        robot's centre at ``r`` now and ``r_next`` a frame on, the other walkers at ``others`` (M, 2)."""
        d_now = float(np.linalg.norm(cur - r))
        cand = [np.zeros((0, 2))]
        if float(np.linalg.norm(want)) > 1e-9:
            # headings off the wish, the side away from the robot first; full then half speed
            side = np.sign(want[0] * (r - cur)[1] - want[1] * (r - cur)[0]) or 1.0  # +1: robot left of the wish
            angles = np.radians([a * s for a in SIDESTEP_DEG for s in ((-side, side) if a else (1.0,))])
            c, s = np.cos(angles), np.sin(angles)
            dirs = np.stack([c * want[0] - s * want[1], s * want[0] + c * want[1]], axis=1)
            cand += [cur + dirs * self.dt_s, cur + 0.5 * dirs * self.dt_s]
        if d_now < self.keep_m:  # too close already (the robot came to it): a step straight away
            away = (cur - r) / max(d_now, 1e-9)
            cand.append((cur + away * min(self.keep_m - d_now, 1.5 * self.dt_s))[None])
        cand = np.concatenate([*cand, cur[None]])  # waiting last
        d_r, d_next = np.linalg.norm(cand - r, axis=1), np.linalg.norm(cand - r_next, axis=1)
        d_cand = np.minimum(d_r, d_next)
        walled = self._walled(cur, cand)
        # at the keep-out distance or beyond, now and a frame on (a walker already inside it walks
        # on if a step restores the gap, else steps away); failing that, never nearer the robot
        # than it already is; waiting where it stands never brings it nearer
        comfortable = (d_cand >= self.keep_m - 1e-9) & ~walled
        near_now = min(self.keep_m, d_now) - 1e-9
        near_next = min(self.keep_m, float(np.linalg.norm(cur - r_next))) - 1e-9
        clear = (d_r >= near_now) & (d_next >= near_next) & ~walled
        clear[-1] = True                 # waiting (the last) is always a way out
        free = np.ones(len(cand), bool)
        if len(others):  # nor onto another walker (an overlap not begun nor deepened)
            d_cur = np.linalg.norm(cur - others, axis=1)
            d = np.linalg.norm(cand[:, None] - others[None], axis=2)
            free = (d >= np.minimum(2 * PERSON_RADIUS_M, d_cur)[None] - 1e-9).all(axis=1)
        for ok in (comfortable & free, clear & free):
            if ok.any():
                return cand[int(np.argmax(ok))]
        return cand[int(np.argmax(clear))]

    def _walled(self, cur: np.ndarray, cand: np.ndarray) -> np.ndarray:
        if self.occupancy is None:
            return np.zeros(len(cand), bool)
        return self.occupancy.is_occupied(cand) | segments_blocked(self.occupancy, np.broadcast_to(cur, cand.shape),
                                                                   cand)


def _random_clothing(rng: np.random.Generator) -> tuple[float, float]:
    mean = rng.uniform(0.1, 0.9)
    conc = rng.uniform(6.0, 20.0)
    return (mean * conc, (1.0 - mean) * conc)


def reflectance_histogram(ab: tuple[float, float], rng: np.random.Generator, n_points: int = N_REFLECTANCE_POINTS,
                          n_bins: int = N_REFLECTANCE_BINS, noise: float = 0.03) -> np.ndarray:
    """Normalized histogram of ``n_points`` intensities drawn from Beta(a, b) plus Gaussian noise."""
    x = np.clip(rng.beta(ab[0], ab[1], n_points) + rng.normal(0.0, noise, n_points), 0.0, 1.0)
    h, _ = np.histogram(x, bins=n_bins, range=(0.0, 1.0))
    return h / h.sum()


# ------------------------------------------------------------------------------------------- walls
def box_map(extent_xy_m: tuple[float, float, float, float], walls_xy_m: list[tuple[float, float, float, float]],
            resolution_m: float = MAP_RESOLUTION_M) -> OccupancyMap:
    """An occupancy map over ``extent`` (x0, y0, x1, y1) whose occupied cells are the given
    rectangles (x0, y0, x1, y1) plus a one-cell border."""
    x0, y0, x1, y1 = extent_xy_m
    cols = int(np.ceil((x1 - x0) / resolution_m))
    rows = int(np.ceil((y1 - y0) / resolution_m))
    m = OccupancyMap(np.zeros((rows, cols), bool), np.ones((rows, cols), bool), np.zeros((rows, cols), bool),
                     resolution_m, np.array([x0, y0, 0.0]))
    ii, jj = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    c = m.cell_to_world(np.stack([ii, jj], axis=-1))
    occ = np.zeros((rows, cols), bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    for wx0, wy0, wx1, wy1 in walls_xy_m:
        occ |= (c[..., 0] >= wx0) & (c[..., 0] <= wx1) & (c[..., 1] >= wy0) & (c[..., 1] <= wy1)
    m.occupied, m.free = occ, ~occ
    return m


def segments_blocked(occupancy: OccupancyMap | None, a_xy_m: np.ndarray, b_xy_m: np.ndarray) -> np.ndarray:
    """For segments a[i] -> b[i] (N, 2): True where the segment crosses an occupied cell (sampled at
    half the map's resolution; the end point itself is not tested)."""
    a = np.atleast_2d(np.asarray(a_xy_m, dtype=float))
    b = np.atleast_2d(np.asarray(b_xy_m, dtype=float))
    if occupancy is None or len(b) == 0:
        return np.zeros(len(b), bool)
    n = max(2, int(np.ceil(np.linalg.norm(b - a, axis=1).max() / (0.5 * occupancy.resolution_m))))
    s = np.linspace(0.0, 1.0, n, endpoint=False)[1:]
    pts = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]
    return occupancy.is_occupied(pts).any(axis=1)


# ----------------------------------------------------------------------------------------- sensing
def to_robot(xy_world_m: np.ndarray, pose_world_robot: np.ndarray) -> np.ndarray:
    """World points (N, 2) in the robot frame of ``pose_world_robot`` (x, y, yaw)."""
    c, s = np.cos(pose_world_robot[2]), np.sin(pose_world_robot[2])
    d = np.atleast_2d(xy_world_m) - pose_world_robot[:2]
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


def to_world(xy_robot_m: np.ndarray, pose_world_robot: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose_world_robot[2]), np.sin(pose_world_robot[2])
    p = np.atleast_2d(xy_robot_m)
    return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]], axis=1) + pose_world_robot[:2]


def in_field_of_view(xy_robot_m: np.ndarray) -> np.ndarray:
    """Within 0.3-5 m and 120 deg in front of the robot."""
    p = np.atleast_2d(xy_robot_m)
    r = np.hypot(p[:, 0], p[:, 1])
    return (r >= MIN_RANGE_M) & (r <= MAX_RANGE_M) & (np.abs(np.arctan2(p[:, 1], p[:, 0])) <= FOV_RAD / 2)


def visible_people(pose_world_robot: np.ndarray, xy_world_m: np.ndarray, occupancy: OccupancyMap | None,
                   radius_m: float = PERSON_RADIUS_M) -> np.ndarray:
    """Which people (N, 2) the LIDAR sees from the true pose: in the field of view, the ray to the
    centre crossing no wall, and no other person's disc nearer than the person covering that ray."""
    xy = np.atleast_2d(np.asarray(xy_world_m, dtype=float)).reshape(-1, 2)
    if len(xy) == 0:
        return np.zeros(0, bool)
    origin = np.asarray(pose_world_robot[:2], dtype=float)
    vis = in_field_of_view(to_robot(xy, pose_world_robot))
    vis &= ~segments_blocked(occupancy, np.broadcast_to(origin, xy.shape), xy)
    # people occlusion: distance of every other centre j from segment origin -> i, before i
    d = xy - origin
    L2 = np.maximum((d ** 2).sum(axis=1), 1e-12)
    u = ((xy[None, :, :] - origin) * d[:, None, :]).sum(axis=2) / L2[:, None]  # (i, j) projection of j on ray i
    closest = origin + np.clip(u, 0.0, 1.0)[..., None] * d[:, None, :]
    dist = np.linalg.norm(xy[None, :, :] - closest, axis=2)
    blocks = (dist < radius_m) & (u > 0.0) & (u < 1.0)
    np.fill_diagonal(blocks, False)
    return vis & ~blocks.any(axis=1)


@dataclass(frozen=True)
class SensorModel:
    """Detection and localization error model."""

    p_detect: float = 0.95  # within 4 m; falls linearly to p_detect_far at 5 m
    p_detect_far: float = 0.8
    sigma_pos_m: float = SIGMA_POS_M
    clutter_per_frame: float = 0.05  # expected false detections per frame (near walls when any)
    loc_sigma_xy_m: float = 0.05  # stationary std of the localization error
    loc_sigma_yaw_rad: float = np.radians(1.0)
    loc_tau_s: float = 3.0  # correlation time of the localization error


class Sensing:
    """Per-frame detections, ESPAR readings and localization estimate for one episode (seeded)."""

    def __init__(self, occupancy: OccupancyMap | None, rng: np.random.Generator, model: SensorModel | None = None,
                 espar: EsparSimulator | None = None):
        self.occupancy = occupancy
        self.rng = rng
        self.model = model or SensorModel()
        self.espar = espar or EsparSimulator(rng=np.random.default_rng(rng.integers(2 ** 32)))
        m = self.model
        self.loc_sigma = np.array([m.loc_sigma_xy_m, m.loc_sigma_xy_m, m.loc_sigma_yaw_rad])
        self.loc_err = rng.normal(0.0, 1.0, 3) * self.loc_sigma
        self.t_prev_s: float | None = None

    def _p_detect(self, r_m: np.ndarray) -> np.ndarray:
        m = self.model
        return np.where(r_m <= 4.0, m.p_detect, m.p_detect + (m.p_detect_far - m.p_detect) * (r_m - 4.0))

    def _clutter(self, pose: np.ndarray) -> list[PersonDetection]:
        out = []
        for _ in range(self.rng.poisson(self.model.clutter_per_frame)):
            bearing = self.rng.uniform(-FOV_RAD / 2, FOV_RAD / 2)
            r = np.linspace(MIN_RANGE_M, MAX_RANGE_M, 100)
            ray = np.stack([r * np.cos(bearing), r * np.sin(bearing)], axis=1)
            hit = (self.occupancy.is_occupied(to_world(ray, pose)) if self.occupancy is not None
                   else np.zeros(len(r), bool))
            rng_m = r[np.argmax(hit)] - 0.3 if hit.any() else self.rng.uniform(1.0, MAX_RANGE_M)
            if rng_m < MIN_RANGE_M:
                continue
            xy = np.array([rng_m * np.cos(bearing), rng_m * np.sin(bearing)])
            out.append(PersonDetection(xy, float(self.rng.uniform(1.0, 1.9)), float(self.rng.uniform(0.5, 0.8)),
                                       reflectance_histogram(_random_clothing(self.rng), self.rng)))
        return out

    def frame(self, t_s: float, pose_world_robot: np.ndarray, people: list[tuple[Walker, np.ndarray]],
              target_xy_world_m: np.ndarray | None, robot_stopped: bool) -> tuple[FollowFrame, np.ndarray]:
        """The frame at ``t_s`` seen from the true pose; also which of ``people`` were in view."""
        m = self.model
        pose = np.asarray(pose_world_robot, dtype=float)
        xy = np.array([p for _, p in people]).reshape(-1, 2)
        vis = visible_people(pose, xy, self.occupancy)
        xy_robot = to_robot(xy, pose)
        r = np.hypot(xy_robot[:, 0], xy_robot[:, 1])
        detected = vis & (self.rng.random(len(xy)) < self._p_detect(r))
        dets = [PersonDetection(xy_robot[i] + self.rng.normal(0.0, m.sigma_pos_m, 2), people[i][0].height_m,
                                float(self.rng.uniform(0.8, 1.0)),
                                reflectance_histogram(people[i][0].reflectance_ab, self.rng))
                for i in np.flatnonzero(detected)]
        dets += self._clutter(pose)
        order = self.rng.permutation(len(dets))
        # localization error: AR(1) with correlation time loc_tau_s
        dt = 1.0 / FRAME_HZ if self.t_prev_s is None else t_s - self.t_prev_s
        a = np.exp(-dt / m.loc_tau_s)
        self.loc_err = a * self.loc_err + np.sqrt(1 - a * a) * self.rng.normal(0.0, 1.0, 3) * self.loc_sigma
        est = pose + self.loc_err
        est[2] = wrap_angle_rad(est[2])
        t_prev = t_s - 1.0 / FRAME_HZ if self.t_prev_s is None else self.t_prev_s
        target_robot = None if target_xy_world_m is None else to_robot(target_xy_world_m, pose)[0]
        espar = self.espar.readings(t_prev, t_s, target_robot)
        self.t_prev_s = t_s
        return (FollowFrame(float(t_s), est, np.diag(self.loc_sigma ** 2), tuple(dets[i] for i in order), espar,
                            bool(robot_stopped)), vis)


# ------------------------------------------------------------------------------------------- robot
class Planner:
    """Shortest paths on a coarse copy of the map (walls inflated by the robot's radius), with
    :func:`scipy.sparse.csgraph.dijkstra` from the goal; the robot aims at the farthest point of the
    path within ``lookahead_m`` that it sees in a straight line."""

    def __init__(self, occupancy: OccupancyMap, cell_m: float = 0.2, robot_radius_m: float = ROBOT_RADIUS_M,
                 lookahead_m: float = 1.5):
        from scipy import ndimage
        from scipy.sparse import coo_matrix

        self.occ, self.cell_m, self.lookahead_m = occupancy, cell_m, lookahead_m
        rows, cols = occupancy.shape
        corners = occupancy.cell_to_world(np.array([[rows - 1, 0], [0, cols - 1]]))
        self.x0, self.y0 = corners[0] - occupancy.resolution_m / 2
        x1, y1 = corners[1] + occupancy.resolution_m / 2
        nx, ny = int((x1 - self.x0) / cell_m), int((y1 - self.y0) / cell_m)
        cx = self.x0 + (np.arange(nx) + 0.5) * cell_m
        cy = self.y0 + (np.arange(ny) + 0.5) * cell_m
        X, Y = np.meshgrid(cx, cy)  # [iy, ix]
        self.xy = np.stack([X, Y], axis=-1)
        blocked = occupancy.is_occupied(self.xy)
        r = int(np.ceil(robot_radius_m / cell_m))
        self.blocked = ndimage.binary_dilation(blocked, iterations=r) if r > 0 else blocked
        self.shape = (ny, nx)
        idx = np.arange(ny * nx).reshape(ny, nx)
        src, dst, w = [], [], []
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = idx[max(0, -dy):ny - max(0, dy), max(0, -dx):nx - max(0, dx)]
            b = idx[max(0, dy):max(0, dy) + a.shape[0], max(0, dx):max(0, dx) + a.shape[1]]
            ok = ~self.blocked.ravel()[a.ravel()] & ~self.blocked.ravel()[b.ravel()]
            src.append(a.ravel()[ok])
            dst.append(b.ravel()[ok])
            w.append(np.full(ok.sum(), cell_m * np.hypot(dx, dy)))
        n = ny * nx
        self.graph = coo_matrix((np.concatenate(w), (np.concatenate(src), np.concatenate(dst))), shape=(n, n)).tocsr()
        self._cache: dict[int, np.ndarray] = {}

    def _node(self, xy: np.ndarray, free: bool) -> int:
        ix = int(np.clip((xy[0] - self.x0) // self.cell_m, 0, self.shape[1] - 1))
        iy = int(np.clip((xy[1] - self.y0) // self.cell_m, 0, self.shape[0] - 1))
        if free and self.blocked[iy, ix]:  # nearest free cell
            fy, fx = np.nonzero(~self.blocked)
            k = int(np.argmin((fy - iy) ** 2 + (fx - ix) ** 2))
            iy, ix = int(fy[k]), int(fx[k])
        return iy * self.shape[1] + ix

    def nearest_free(self, xy) -> np.ndarray:
        return self.xy.reshape(-1, 2)[self._node(np.asarray(xy, float), True)]

    def aim(self, from_xy: np.ndarray, goal_xy: np.ndarray) -> np.ndarray | None:
        """The point to steer to on the way to ``goal_xy``; None when no path exists."""
        from scipy.sparse.csgraph import dijkstra

        g = self._node(goal_xy, True)
        if g not in self._cache:
            self._cache[g] = dijkstra(self.graph, directed=False, indices=g, return_predecessors=True)[1]
        pred = self._cache[g]
        node = self._node(from_xy, True)
        path = [node]
        while node != g and pred[node] >= 0 and len(path) < 10000:
            node = int(pred[node])
            path.append(node)
        if path[-1] != g:
            return None
        pts = self.xy.reshape(-1, 2)[path]
        near = np.flatnonzero(np.linalg.norm(pts - from_xy, axis=1) <= self.lookahead_m)
        for k in near[::-1]:
            if not segments_blocked(self.occ, from_xy, pts[k])[0]:
                return pts[k]
        return pts[min(1, len(pts) - 1)]


@dataclass(frozen=True)
class CrowdAvoidance:
    """People as moving obstacles: velocity obstacles with a time horizon, sampled (van den Berg,
    Lin and Manocha's RVO choice, penalty ``||u - u_want|| + k_touch / t_touch``, plus ``k_slow``
    times the speed short of the wanted one), then a unicycle step that keeps clear.

    The robot wants to move at ``u_want`` (the follow law's speed toward its aim). Every velocity u
    of a polar grid (``n_speeds`` speeds up to v_max x ``n_headings`` headings, ``u_want`` and
    standing still among them) is rolled out straight over ``horizon_s`` against every person
    moving on at its current velocity; ``t_touch`` is the first time the robot's disc would come
    within ``margin_m`` of touching a person's, nearer than waiting where it is would leave it
    (infinite: never; moving away from somebody already close is no touch). The u of least penalty
    is the velocity to steer for: it keeps the wish when nobody is in the way, and otherwise slows,
    goes round, or waits. The speed term matters where a person stands in the way: the plain RVO
    penalty ranks waiting behind them (``||u_want||``) at or above every sideways way round, and the
    robot would wait for ever. Recorded walkers do not react to the robot, so nothing is left to
    them.

    The unicycle turns toward that velocity's heading and drives at its speed times the cosine of
    the heading error (:meth:`RobotController.command`). A step that would end within ``margin_m``
    of touching a person, where it is now or where it will be one frame on, and nearer to that
    person than standing still would, is not driven: the robot only turns (a person walking into a
    waiting robot is not its doing)."""

    horizon_s: float = 2.0
    step_s: float = 1.0 / FRAME_HZ
    n_speeds: int = 6
    n_headings: int = 24
    margin_m: float = 0.1
    k_touch_m: float = 0.5  # penalty weight: metres per second of speed against 1 / (seconds to touch)
    k_slow: float = 0.5  # penalty per m/s below the wanted speed: going round beats waiting behind somebody
    k_turn: float = 0.3  # penalty per m/s of a velocity pointing behind the robot (half (1 - cos) of the turn)
    range_m: float = 6.0  # people farther than this from the robot are left out
    robot_radius_m: float = ROBOT_RADIUS_M
    person_radius_m: float = PERSON_RADIUS_M

    def _near(self, xy_m: np.ndarray, people_xy_world_m, people_v_world_mps) -> tuple[np.ndarray, np.ndarray]:
        xy = np.asarray(people_xy_world_m, float).reshape(-1, 2)
        vel = np.nan_to_num(np.asarray(people_v_world_mps, float).reshape(-1, 2))
        near = np.linalg.norm(xy - xy_m, axis=1) <= self.range_m
        return xy[near], vel[near]

    def velocity(self, xy_world_m: np.ndarray, u_want_mps: np.ndarray, v_max_mps: float,
                 people_xy_world_m: np.ndarray, people_v_world_mps: np.ndarray, yaw_rad: float | None = None
                 ) -> np.ndarray:
        """The velocity (2,) to steer for from ``xy_world_m`` wanting ``u_want_mps`` (2,), people at
        ``people_xy_world_m`` (N, 2) moving at ``people_v_world_mps`` (N, 2)."""
        x0 = np.asarray(xy_world_m, float)
        u_want = np.asarray(u_want_mps, float)
        xy, vel = self._near(x0, people_xy_world_m, people_v_world_mps)
        if len(xy) == 0:
            return u_want
        speed = np.linspace(0.0, v_max_mps, self.n_speeds)[1:]
        head = np.linspace(-np.pi, np.pi, self.n_headings, endpoint=False)
        u = np.concatenate([[u_want, np.zeros(2)],
                            (speed[:, None, None] * np.stack([np.cos(head), np.sin(head)], axis=1)).reshape(-1, 2)])
        tk = np.arange(1, int(round(self.horizon_s / self.step_s)) + 1) * self.step_s  # (H,)
        rel = (xy - x0)[None, :, :] + tk[:, None, None] * vel[None]  # (H, N, 2) people from the start
        dist = np.linalg.norm(rel[None] - tk[None, :, None, None] * u[:, None, None, :], axis=3)  # (S, H, N)
        # a touch of the robot's making: within the margin, and nearer than waiting there would be
        waiting = np.linalg.norm(rel, axis=2)  # (H, N)
        hit = ((dist < self.robot_radius_m + self.person_radius_m + self.margin_m) & (dist < waiting[None])
               ).any(axis=2)  # (S, H)
        t_touch = np.where(hit.any(axis=1), tk[np.argmax(hit, axis=1)], np.inf)
        short = np.maximum(np.hypot(*u_want) - np.hypot(u[:, 0], u[:, 1]), 0.0)
        cost = np.linalg.norm(u - u_want, axis=1) + self.k_slow * short + self.k_touch_m / t_touch
        if yaw_rad is not None:  # a unicycle turns before it drives: a velocity behind it costs its turn
            cost += self.k_turn * np.hypot(u[:, 0], u[:, 1]) * 0.5 * (1.0 - np.cos(np.arctan2(u[:, 1], u[:, 0])
                                                                                   - yaw_rad))
        return u[int(np.argmin(cost))]

    def step_is_clear(self, pose_world_robot: np.ndarray, v_mps: float, w_radps: float,
                      people_xy_world_m: np.ndarray, people_v_world_mps: np.ndarray) -> bool:
        """Whether the unicycle step (v, w) keeps ``margin_m`` from touching everybody it nears (both
        where they are and where they will be a frame on)."""
        pose = np.asarray(pose_world_robot, float)
        if v_mps <= 0.0:
            return True
        xy, vel = self._near(pose[:2], people_xy_world_m, people_v_world_mps)
        yaw = pose[2] + w_radps * self.step_s  # as RobotController.step: turn, then drive
        nxt = pose[:2] + v_mps * self.step_s * np.array([np.cos(yaw), np.sin(yaw)])
        there = np.concatenate([xy, xy + self.step_s * vel])
        d = np.linalg.norm(there - nxt, axis=1)
        nearer = d < np.linalg.norm(there - pose[:2], axis=1)
        return not ((d < self.robot_radius_m + self.person_radius_m + self.margin_m) & nearer).any()


@dataclass(frozen=True)
class RobotController:
    """Unicycle following the tracker: ``FOLLOW_DISTANCE_M`` behind the target while tracking (speed
    ``k_v`` times the distance beyond it, plus the target's own speed away from the robot, taken from
    the person at the target's estimate, so it keeps that distance behind a walking target rather than
    trailing it by its speed over ``k_v``), to the tracker's goal when the target is not in view,
    still when asked to stop (turning in place to the heading the tracker asks to face, if any). Given
    the people around it, it steers for the velocity :class:`CrowdAvoidance` (``avoid``) picks and
    drives no step into them; ``avoid=None`` drives through people."""

    v_max_mps: float = 1.0
    w_max_radps: float = 1.5
    k_v: float = 1.0
    k_w: float = 2.0
    follow_distance_m: float = FOLLOW_DISTANCE_M
    goal_tolerance_m: float = 0.3
    clearance_m: float = 0.35  # the step is refused when this far ahead is occupied
    face_tolerance_rad: float = np.radians(45.0)  # asked to stop and face a heading: within the view
    avoid: CrowdAvoidance | None = CrowdAvoidance()

    def command(self, pose_est: np.ndarray, out: TrackerOutput, planner: Planner | None = None,
                people_xy_world_m: np.ndarray | None = None, people_v_world_mps: np.ndarray | None = None
                ) -> tuple[float, float]:
        """(v_mps, w_radps) from the estimated pose and the tracker's output; with a ``planner``,
        goals inside walls move to the nearest free cell and an aim behind a wall is reached along
        the planned path; with the people around (positions and velocities in the frame of
        ``pose_est``), the robot goes where :class:`CrowdAvoidance` leads."""
        if out.stop_robot:
            if out.face_world_rad is None:
                return 0.0, 0.0
            err = float(wrap_angle_rad(out.face_world_rad - pose_est[2]))
            return 0.0, (float(np.clip(self.k_w * err, -self.w_max_radps, self.w_max_radps))
                         if abs(err) > self.face_tolerance_rad else 0.0)
        wanted = self._wanted_velocity(pose_est, out, planner)
        if wanted is None:
            return 0.0, 0.0
        u, aim_rad = wanted
        people = self.avoid is not None and people_xy_world_m is not None and len(people_xy_world_m) > 0
        if (people_xy_world_m is not None and len(people_xy_world_m) and people_v_world_mps is not None
                and out.target_track_id is not None and out.target_xy_world_m is not None):
            # the target's own speed away from the robot added (feed-forward): the proportional law
            # alone trails a walking target by its speed / k_v beyond the follow distance
            d_t = np.linalg.norm(np.asarray(people_xy_world_m) - out.target_xy_world_m, axis=1)
            if d_t.min() <= TARGET_PERSON_M:
                ahead = np.asarray(out.target_xy_world_m, float) - pose_est[:2]
                ahead /= max(float(np.linalg.norm(ahead)), 1e-9)
                v_away = float(np.asarray(people_v_world_mps)[int(np.argmin(d_t))] @ ahead)
                u_norm = float(np.linalg.norm(u))
                if v_away > 0 and u_norm > 1e-9:
                    u = u / u_norm * min(u_norm + v_away, self.v_max_mps)
        if people:
            people_v = (np.zeros_like(people_xy_world_m) if people_v_world_mps is None
                        else people_v_world_mps)
            u = self.avoid.velocity(pose_est[:2], u, self.v_max_mps, people_xy_world_m, people_v, pose_est[2])
        speed = float(np.hypot(*u))
        heading = float(np.arctan2(u[1], u[0])) if speed > 1e-9 else aim_rad  # still: face the aim
        heading_err = float(wrap_angle_rad(heading - pose_est[2]))
        w = float(np.clip(self.k_w * heading_err, -self.w_max_radps, self.w_max_radps))
        v = speed * max(0.0, np.cos(heading_err))
        if people and not self.avoid.step_is_clear(pose_est, v, w, people_xy_world_m, people_v):
            v = 0.0
        return v, w

    def _wanted_velocity(self, pose_est: np.ndarray, out: TrackerOutput, planner: Planner | None
                         ) -> tuple[np.ndarray, float] | None:
        """The follow law's velocity (2,) toward its aim, people left out, and the aim's direction
        (rad); None without an aim."""
        if out.target_track_id is not None and out.target_xy_world_m is not None:
            aim, stand_off = np.asarray(out.target_xy_world_m, float), self.follow_distance_m
        elif out.goal_xy_world_m is not None:
            aim, stand_off = np.asarray(out.goal_xy_world_m, float), self.goal_tolerance_m
        else:
            return None
        if planner is not None:
            if stand_off == self.goal_tolerance_m:
                aim = planner.nearest_free(aim)
            if segments_blocked(planner.occ, pose_est[:2], aim)[0]:
                via = planner.aim(pose_est[:2], aim)
                if via is not None:
                    aim, stand_off = via, 0.0
        d = aim - pose_est[:2]
        dist = float(np.hypot(*d))
        speed = float(np.clip(self.k_v * (dist - stand_off), 0.0, self.v_max_mps))
        return speed * d / max(dist, 1e-9), float(np.arctan2(d[1], d[0]))

    def step(self, pose_true: np.ndarray, v: float, w: float, dt_s: float,
             occupancy: OccupancyMap | None) -> tuple[np.ndarray, bool]:
        """Integrate the unicycle; a step that would bring an occupied cell within ``clearance_m``
        ahead only turns. Returns the new pose and whether the robot stood still."""
        yaw = pose_true[2] + w * dt_s
        nxt = pose_true[:2] + v * dt_s * np.array([np.cos(yaw), np.sin(yaw)])
        if occupancy is not None and v > 0:
            ahead = nxt + self.clearance_m * np.array([np.cos(yaw), np.sin(yaw)])
            if occupancy.is_occupied(np.stack([nxt, ahead])).any():
                nxt, v = pose_true[:2], 0.0
        return np.array([nxt[0], nxt[1], wrap_angle_rad(yaw)]), v == 0.0 and w == 0.0


# ---------------------------------------------------------------------------------------- episodes
@dataclass
class Episode:
    """A scene: walls, walkers (one of them the target), the robot's start, the duration."""

    name: str
    walkers: list[Walker]
    target_id: str
    robot_pose0: np.ndarray  # (3,) x, y, yaw
    duration_s: float
    occupancy: OccupancyMap | None = None
    t0_s: float = 0.0
    notes: str = ""
    extra: dict = field(default_factory=dict)
    robot_max_speed_mps: float = 1.0  # the robot's top speed (RobotController.v_max_mps)
    crowd: ReactiveCrowd | None = None  # simulated walkers who react to the robot (None: nobody does)

    def people_at(self, t_s: float) -> list[tuple[Walker, np.ndarray]]:
        out = []
        for w in self.walkers:
            p = w.at(t_s)
            if p is not None:
                out.append((w, p))
        return out

    def walker(self, person_id: str) -> Walker:
        return next(w for w in self.walkers if w.person_id == person_id)


TARGET_CLOTHING = (8.0, 3.0)  # bright clothing (mean 0.73)


def passing_episode(rng: np.random.Generator) -> Episode:
    """Fig. 7: the target walks ahead of the robot; a person crosses between them."""
    target = route_walker("target", [[1.6, 0.0], [1.6, 0.0], [13.0, 0.0]], [1.0, 0.7], waits_s=[4.0, 0.0],
                          reflectance_ab=TARGET_CLOTHING)
    # the passer reaches the line robot-target about 0.6 m behind the target at t = 12 s
    x_c = 1.6 + 0.7 * 8.0 - 0.6
    passer = route_walker("passer", [[x_c + 1.5, 3.5], [x_c, 0.0], [x_c - 1.2, -2.8]], [1.0, 1.0],
                          t0_s=12.0 - np.hypot(1.5, 3.5) / 1.0, reflectance_ab=(3.0, 8.0), height_m=1.75)
    occ = box_map((-3.0, -5.0, 17.0, 5.0), [])
    return Episode("passing", [target, passer], "target", np.array([0.0, 0.0, 0.0]), 25.0, occ,
                   notes="a person passes between the robot and the target (Misu and Miura, Fig. 7)")


def corner_episode(rng: np.random.Generator) -> Episode:
    """Fig. 8: the target turns a corner and leaves the field of view behind a wall."""
    # corridor along +x (y in [-1.5, 1.5]) up to x = 10.5; at its end a corridor along +y (x in [9, 10.5]);
    # off that corridor, through a door at y in [3.5, 4.7], a room to the east (x in [10.7, 16])
    walls = [(-3.0, -5.0, 16.5, -1.5),        # south wall
             (-3.0, 1.5, 9.0, 12.0),          # north-west block: the inner corner at (9, 1.5)
             (10.5, -1.5, 10.7, 3.5),         # east wall of the corridor, below the door
             (10.5, 4.7, 10.7, 12.0),         # and above it
             (10.7, 7.5, 16.5, 12.0)]         # the room's north wall
    occ = box_map((-3.0, -5.0, 16.5, 12.0), walls)
    # the target turns left close to the inner corner, hurries on and enters the room
    target = route_walker("target", [[1.4, 0.0], [1.4, 0.0], [9.7, 0.0], [9.7, 4.1], [14.5, 4.5], [14.5, 4.5]],
                          [1.0, 0.8, 1.6, 1.6, 1.0], waits_s=[4.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                          reflectance_ab=TARGET_CLOTHING)
    other = route_walker("bystander", [[9.8, 10.0], [9.8, 8.0], [9.8, 8.0]], [0.3, 0.3], t0_s=0.0,
                         reflectance_ab=(3.0, 8.0))
    return Episode("corner", [target, other], "target", np.array([0.0, 0.0, 0.0]), 40.0, occ,
                   notes="the target turns a corner out of view (Misu and Miura, Fig. 8)")


def crossing_episode(rng: np.random.Generator) -> Episode:
    """Fig. 9: two people walk side by side, then cross (swap sides) and part."""
    target = route_walker("target", [[1.6, 0.35], [1.6, 0.35], [6.0, 0.35], [8.0, -0.35], [14.0, -2.5]],
                          [1.0, 0.7, 0.7, 0.7], waits_s=[4.0, 0, 0, 0, 0], reflectance_ab=TARGET_CLOTHING)
    # the companion falls half a metre behind while they cross, so it passes between robot and target
    other = route_walker("companion", [[1.6, -0.35], [1.6, -0.35], [6.0, -0.35], [8.0, 0.35], [14.0, 2.5]],
                         [1.0, 0.7, 0.7, 0.7], waits_s=[4.0, 0, 0.8, 0, 0], reflectance_ab=(7.0, 4.0))
    occ = box_map((-3.0, -6.0, 17.0, 6.0), [])
    return Episode("crossing", [target, other], "target", np.array([0.0, 0.0, 0.0]), 25.0, occ,
                   notes="two people walk side by side and cross (Misu and Miura, Fig. 9)")


TARGET_ROUTE = [[1.5, 0.0], [1.5, 0.0], [12.0, 0.0], [12.0, 8.0], [2.0, 8.0], [2.0, 2.0]]


def _target_on_route(route=TARGET_ROUTE) -> Walker:
    return route_walker("target", route, 0.8, waits_s=[4.0] + [0.0] * (len(route) - 1),
                        reflectance_ab=TARGET_CLOTHING)


CROWD_AREA_XY_M = (-3.0, -3.0, 15.0, 11.0)  # where the crowd scene's walkers go (252 m^2)


def walkers_for_density(density_per_10m2: float, area_xy_m=CROWD_AREA_XY_M) -> int:
    """How many walkers give ``density_per_10m2`` people per 10 m^2 over the area (x0, y0, x1, y1)."""
    if not np.isfinite(density_per_10m2) or density_per_10m2 < 0:
        raise PedcalInputError(f"crowd density {density_per_10m2!r}: expected people per 10 m^2 >= 0")
    x0, y0, x1, y1 = area_xy_m
    return int(round(density_per_10m2 * (x1 - x0) * (y1 - y0) / 10.0))


def crowd_episode(rng: np.random.Generator, n_walkers: int = 12, density_per_10m2: float | None = None) -> Episode:
    """The target walks a loop in a hall while built-in random walkers cross it: ``n_walkers`` of
    them, or as many as make ``density_per_10m2`` people per 10 m^2 over the walkers' area."""
    if density_per_10m2 is not None:
        n_walkers = walkers_for_density(density_per_10m2)
    occ = box_map((-4.0, -4.0, 16.0, 12.0), [])
    target = _target_on_route()
    duration = float(min(45.0, target.t_s[-1]))
    others = random_walkers(n_walkers, CROWD_AREA_XY_M, target.t_s[-1], rng, occ)
    others = avoid_collisions(others, [target], duration, occupancy=occ)
    # everybody, the target too, steps around the robot as the episode plays: the walkers' plans
    # were laid out before the robot moved, and a person walking its route (the target's included)
    # would not walk through a robot standing in it
    people = [on_frame_grid(w, duration) for w in [target, *others]]
    x0, y0, x1, y1 = CROWD_AREA_XY_M
    density = n_walkers * 10.0 / ((x1 - x0) * (y1 - y0))
    return Episode("crowd", people, "target", np.array([0.0, 0.0, 0.0]), duration, occ,
                   notes=f"{n_walkers} built-in random walkers ({density:.2f} people per 10 m^2), "
                         f"stepping around the robot", crowd=ReactiveCrowd(people, occ))


RECORDED_FILE = "eth_ucy/biwi_hotel.txt"


def recorded_episode(rng: np.random.Generator, data_dir: str | Path | None = None,
                     file: str = RECORDED_FILE) -> Episode:
    """The target walks a loop while real pedestrians (ETH/UCY, THOR or ATC recording ``file``
    under ``data_dir``) walk around it: a random 45 s window of the recording, rotated randomly and
    shifted so its centre sits on the route's centre."""
    from pedcal.io.pedestrians import read_pedestrians
    from pedcal.sim.walkers import SHARED_DATA

    path = Path(data_dir if data_dir is not None else SHARED_DATA) / file
    if not path.is_file():
        raise PedcalInputError("recorded pedestrian file not found (the recorded scene needs it)", path=path)
    df = read_pedestrians(path)
    target = _target_on_route()
    duration = float(min(45.0, target.t_s[-1]))
    t_rec = df["t"].to_numpy(float)
    t_start = float(rng.uniform(t_rec.min(), max(t_rec.min(), t_rec.max() - duration)))
    win = df[(df["t"] >= t_start) & (df["t"] <= t_start + duration)]
    yaw = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    xy = win[["x", "y"]].to_numpy(float)
    xy = (xy - xy.mean(axis=0)) @ np.array([[c, s], [-s, c]]) + np.array([7.0, 4.0])
    walkers = []
    for pid, idx in win.groupby("person", sort=True).indices.items():
        t = win["t"].to_numpy(float)[idx] - t_start
        if len(t) < 2:
            continue
        walkers.append(Walker(f"p{pid}", t, xy[idx], float(rng.uniform(1.5, 1.9)), _random_clothing(rng)))
    occ = box_map((-4.0, -4.0, 18.0, 12.0), [])
    walkers = avoid_collisions(walkers, [target], duration, occupancy=occ)
    return Episode("recorded", [target, *walkers], "target", np.array([0.0, 0.0, 0.0]), duration, occ,
                   notes=f"pedestrians from {file}, window at {t_start:.1f} s, turned {np.degrees(yaw):.0f} deg")


def candidate_targets(people: pd.DataFrame, min_duration_s: float = 0.0) -> pd.DataFrame:
    """The people of a ``t, person, x, y`` table who could carry the transmitter: ``person``,
    ``start_s`` (time of the first row), ``duration_s``, ``rows``, those present at least
    ``min_duration_s``, longest first."""
    g = people.assign(person=people["person"].astype(str)).groupby("person", sort=True)["t"]
    out = pd.DataFrame({"start_s": g.min(), "duration_s": g.max() - g.min(), "rows": g.size()}).reset_index()
    out = out[out["duration_s"] >= min_duration_s]
    return out.sort_values(["duration_s", "person"], ascending=[False, True], kind="stable").reset_index(drop=True)


def people_episode(people: pd.DataFrame, target_id: str, source: str | Path | None = None) -> Episode:
    """An episode from a people table (``t, person, x, y``) over the target's time span (the other
    people within it): the robot starts 1.5 m behind the target's first position, facing its first
    motion; no walls."""
    ids = people["person"].astype(str)
    if target_id not in set(ids):
        raise PedcalInputError(f"--target {target_id!r} is not a person of the file (people: "
                               f"{', '.join(sorted(set(ids))[:10])}{', ...' if ids.nunique() > 10 else ''})",
                               path=source, column="person")
    tgt = people[ids == target_id].sort_values("t")
    if len(tgt) < 2:
        raise PedcalInputError(f"target {target_id!r} has fewer than 2 rows", path=source, column="person")
    t0, t1 = float(tgt["t"].iloc[0]), float(tgt["t"].iloc[-1])
    walkers = []
    for pid, g in people.assign(person=ids).sort_values("t", kind="stable").groupby("person", sort=True):
        t = g["t"].to_numpy(float) - t0
        if len(t) < 2 or t[-1] < 0.0 or t[0] > t1 - t0:
            continue
        walkers.append(Walker(str(pid), t, g[["x", "y"]].to_numpy(float),
                              reflectance_ab=TARGET_CLOTHING if pid == target_id else (3.0, 8.0)))
    txy = tgt[["x", "y"]].to_numpy(float)
    v_max = robot_speed_for(tgt["t"].to_numpy(float), txy)
    moved = np.flatnonzero(np.linalg.norm(txy - txy[0], axis=1) > 0.3)
    head = txy[moved[0]] - txy[0] if len(moved) else np.array([1.0, 0.0])
    yaw = float(np.arctan2(head[1], head[0]))
    start = txy[0] - 1.5 * np.array([np.cos(yaw), np.sin(yaw)])
    return Episode("people", walkers, target_id, np.array([start[0], start[1], yaw]), t1 - t0, None,
                   notes=f"people from {source}; robot top speed {v_max:.2f} m/s", robot_max_speed_mps=v_max)


ROBOT_SPEED_MARGIN = 1.2  # a following robot's top speed over the target's fast walking (95th percentile)


def robot_speed_for(t_s: np.ndarray, xy_m: np.ndarray, floor_mps: float = 1.0) -> float:
    """A top speed that lets the robot keep up with a person walking ``xy_m`` at times ``t_s``:
    ``ROBOT_SPEED_MARGIN`` times the 95th percentile of the person's speed between samples, at
    least ``floor_mps``. A recorded target may walk faster than the scripted scenes' 1 m/s robot;
    the bench measures the trackers, not a robot too slow to follow."""
    dt = np.diff(t_s)
    ok = dt > 0
    if not ok.any():
        return floor_mps
    v = np.linalg.norm(np.diff(xy_m, axis=0)[ok], axis=1) / dt[ok]
    return float(max(floor_mps, ROBOT_SPEED_MARGIN * np.percentile(v, 95)))


SCENARIOS: dict[str, Callable[[np.random.Generator], Episode]] = {
    "passing": passing_episode,
    "corner": corner_episode,
    "crossing": crossing_episode,
    "crowd": crowd_episode,
    "recorded": recorded_episode,
}


def make_episode(name: str, seed: int = 0, density_per_10m2: float | None = None) -> Episode:
    """The episode registered as ``name`` (``SCENARIOS``), seeded; ``density_per_10m2`` sets the
    crowd scene's walkers (people per 10 m^2)."""
    if name not in SCENARIOS:
        raise PedcalInputError(f"unknown scenario {name!r}; expected one of {', '.join(SCENARIOS)}")
    if density_per_10m2 is not None:
        if name != "crowd":
            raise PedcalInputError(f"--density sets the crowd scene's walkers; scenario {name!r} has none to set")
        return crowd_episode(np.random.default_rng(seed), density_per_10m2=density_per_10m2)
    return SCENARIOS[name](np.random.default_rng(seed))


__all__ = ["FRAME_HZ", "PERSON_RADIUS_M", "N_REFLECTANCE_BINS", "Walker", "route_walker", "random_walkers",
           "avoid_collisions", "ReactiveCrowd", "on_frame_grid",
           "reflectance_histogram", "box_map", "segments_blocked", "to_robot", "to_world",
           "in_field_of_view",
           "visible_people", "SensorModel", "Sensing", "RobotController", "CrowdAvoidance", "ROBOT_RADIUS_M", "Episode",
           "SCENARIOS", "make_episode",
           "people_episode", "candidate_targets", "robot_speed_for", "walkers_for_density", "CROWD_AREA_XY_M",
           "passing_episode", "corner_episode", "crossing_episode", "crowd_episode",
           "recorded_episode"]
