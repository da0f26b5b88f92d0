"""The person tracker of Misu and Miura (Sec. 4-5) and the LIDAR-only follower it is compared with.

Both run the same multi-person core on each :class:`~pedcal.follow_types.FollowFrame`:

1. every filter is predicted to the frame's time (eq. 2, :mod:`pedcal.track.kalman`);
2. detections go to the world frame with the robot's pose, its covariance added to the LIDAR noise;
3. association (eqs. 3-4): l = N(d; 0, 1) (1 - e), d the Mahalanobis distance of a detection from
   a filter's predicted position and e the error of the TARGET filter's online-boosting appearance
   classifier (:mod:`pedcal.track.appearance`) on the detection's reflectance histogram. The other
   filters use e = 0.5: only the target's classifier has a meaningful set of positives (the target)
   and negatives (everybody else), and a per-person classifier for every passer-by would cost a
   boosting update per person and frame for little. Pairs are taken greedily by decreasing l, one
   to one, among pairs with d < ``gate`` (3);
4. assigned filters are updated (eq. 5); unassigned detections start tentative filters;
5. filter management by entropy (eqs. 7-8, see :class:`~pedcal.track.kalman.CVTrack.manage`);
6. the target's classifier learns from the frame (target detection positive, others negative).

:class:`PaperTracker` adds the ESPAR antenna: the target probability of every confirmed filter
(:class:`TargetProbability`, eqs. 9-14), the bearing EKF update of the undetected target (eq. 6),
the state machine of Sec. 5 and the existence grid of Sec. 5.3. :class:`LidarOnlyTracker` keeps the
filter picked at the start and, when it is lost, takes the nearest filter to its last position.

Departures from the paper, each found on recorded crowds where the paper's rule lost the target
(settings of ``TrackerConfig`` turn the first two off; the third is always on):

- a detection left unassigned near the undetected target filter, accepted by the target's
  appearance classifier and with nobody else within ``maneuver_clear_m``, continues that filter (a
  sharp turn outside the gate); ``maneuver_radius_m = 0`` turns this off;
- in Searching the stopped robot turns in place toward the antenna's recent bearing
  (``face_antenna = False`` keeps it still, as in the paper);
- association serves confirmed filters before tentative ones, so a filter born on the last frame
  cannot take the target's detection (always on).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from pedcal.follow_types import FollowFrame, TrackerOutput, TrackEstimate
from pedcal.track.appearance import OnlineBoost
from pedcal.track.espar import DEFAULT_LIKELIHOOD, EsparLikelihood
from pedcal.track.existence_grid import N_READINGS, ExistenceGrid
from pedcal.track.kalman import (
    CONFIRM_AREA_RATIO,
    DELETE_ENTROPY_RISE,
    MAX_AREA_M2,
    SIGMA_ACCEL_MPS2,
    SIGMA_LIDAR_M,
    CVTrack,
    detections_world,
    mahalanobis_matrix,
    rot2,
    update_bearing,
)


@dataclass(frozen=True)
class TrackerConfig:
    """Every tuning constant of the trackers, with the paper's values where it gives them."""

    sigma_lidar_m: float = SIGMA_LIDAR_M
    sigma_accel_mps2: float = SIGMA_ACCEL_MPS2
    gate: float = 3.0  # Mahalanobis gate of association
    confirm_ratio: float = CONFIRM_AREA_RATIO
    delete_rise: float = DELETE_ENTROPY_RISE
    max_area_m2: float = MAX_AREA_M2
    espar: EsparLikelihood = DEFAULT_LIKELIHOOD
    bearing_gate: float = 2.5  # normalized innovation beyond which a bearing is taken for multipath
    new_track_prior: float = 0.05  # share of P_lost a newly confirmed filter starts with
    p_min: float = 1e-4  # no hypothesis drops below this, so a wrong lead can still be undone
    init_min_readings: int = 4  # Initialize: readings before the target may be chosen
    init_threshold: float = 0.7  # Initialize: P(T = i) that makes filter i the target
    lost_threshold: float = 0.1  # Tracking -> Lost below this
    reassign_threshold: float = 0.7  # Lost/Searching -> Tracking above this
    lost_to_search_s: float = 2.0  # Lost this long -> Searching (the robot stops)
    grid_readings: int = N_READINGS
    grid_half_size_m: float = 8.0
    grid_cell_m: float = 0.25
    walking_speed_mps: float = 1.0  # spread of the grid's prior per second out of sight
    goal_reached_m: float = 0.5  # Searching: at the grid's goal, accumulate a new grid
    search_timeout_s: float = 15.0  # Searching: new grid if the goal was not reached by then
    reacquire_radius_m: float = 2.0  # LIDAR-only: take a filter this near the last position
    maneuver_radius_m: float = 0.6  # an unassigned detection this near the undetected target filter ...
    maneuver_lag_s: float = 0.25  # the turn happened within this (a frame): velocity spread miss / lag
    maneuver_max_error: float = 0.4  # ... whose appearance error e is at most this continues it (a turn)
    maneuver_clear_m: float = 1.0  # ... and nobody else (filter or detection) is this near it
    face_antenna: bool = True  # Searching, robot stopped: turn in place to the antenna's recent bearing
    face_readings: int = 4  # the circular mean of this many latest readings (world bearings)


# -------------------------------------------------------------------------------------- association
def association_likelihood(d: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Eq. 3-4: l = N(d; 0, 1) (1 - e)."""
    return np.exp(-0.5 * d ** 2) / np.sqrt(2.0 * np.pi) * (1.0 - e)


def greedy_assign(l: np.ndarray, d: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """One-to-one (filter, detection) pairs by decreasing ``l`` among pairs with ``d < gate``."""
    if l.size == 0:
        return []
    order = np.argsort(-l, axis=None, kind="stable")
    rows, cols = np.unravel_index(order, l.shape)
    ok = d[rows, cols] < gate
    used_r, used_c, pairs = set(), set(), []
    for i, j in zip(rows[ok].tolist(), cols[ok].tolist(), strict=True):
        if i not in used_r and j not in used_c:
            pairs.append((i, j))
            used_r.add(i)
            used_c.add(j)
    return pairs


# ------------------------------------------------------------------------------ target probability
class TargetProbability:
    """P(T = i) over filters i plus P_lost (eqs. 9-14)."""

    def __init__(self, p_min: float = 1e-4):
        self.p: dict[int, float] = {}
        self.p_lost = 1.0
        self.p_min = p_min

    def add(self, track_id: int, share: float) -> None:
        """A new filter enters with ``share`` of P_lost (taken from it); a filter that already holds
        a probability (the factor-graph tracker re-took it before it was confirmed) keeps it."""
        if track_id in self.p:
            return
        take = share * self.p_lost
        self.p[track_id] = take
        self.p_lost -= take

    def remove(self, track_id: int) -> None:
        """A deleted filter's probability goes to P_lost."""
        self.p_lost += self.p.pop(track_id, 0.0)

    def update(self, p_z_track: dict[int, float], p_z_lost: float) -> None:
        """Eq. 9: P(T = i | Z) = P(Z | A_i) P(T = i) / eta and P(lost | Z) = P(Z | lost) P_lost / eta,
        eta normalizing over the filters and lost; then no hypothesis stays below ``p_min``."""
        ids = list(self.p)
        post = np.array([p_z_track[i] * self.p[i] for i in ids] + [p_z_lost * self.p_lost])
        post /= post.sum()
        post = np.maximum(post, self.p_min)
        post /= post.sum()
        self.p = dict(zip(ids, post[:-1].tolist(), strict=True))
        self.p_lost = float(post[-1])

    def best(self, exclude: int | None = None) -> tuple[int | None, float]:
        cand = [(p, i) for i, p in self.p.items() if i != exclude]
        if not cand:
            return None, 0.0
        p, i = max(cand)
        return i, p


# ------------------------------------------------------------------------------------------ core
@dataclass
class _FrameResult:
    detected_ids: set[int] = field(default_factory=set)
    deleted_ids: list[int] = field(default_factory=list)
    confirmed_ids: list[int] = field(default_factory=list)  # newly confirmed this frame


class MultiPersonCore:
    """Filters, association and entropy management shared by every tracker; ``target_id`` is the
    filter whose appearance classifier drives e in eq. 3."""

    def __init__(self, config: TrackerConfig):
        self.config = config
        self.tracks: dict[int, CVTrack] = {}
        self.next_id = 0
        self.target_id: int | None = None
        self.appearance: OnlineBoost | None = None
        self.t_s: float | None = None

    def step(self, frame: FollowFrame) -> _FrameResult:
        c = self.config
        res = _FrameResult()
        self.t_s = frame.t_s
        ids = list(self.tracks)
        for tr in self.tracks.values():
            tr.predict(frame.t_s, c.sigma_accel_mps2)
            tr.detected = False
        dets = frame.detections
        if dets:
            z, R = detections_world(np.array([dt.xy_robot_m for dt in dets], dtype=float),
                                    np.asarray(frame.pose_world_robot, dtype=float), frame.cov_world_robot,
                                    c.sigma_lidar_m)
            pairs: list[tuple[int, int]] = []
            assigned: set[int] = set()

            def take(r: int, j: int, R_j: np.ndarray) -> None:
                tr = self.tracks[ids[r]]
                tr.update(z[j], R_j)
                tr.detected = True
                tr.hits += 1
                res.detected_ids.add(tr.track_id)
                assigned.add(j)
                pairs.append((r, j))

            if ids:
                d = mahalanobis_matrix(np.array([self.tracks[i].x for i in ids]),
                                       np.array([self.tracks[i].P for i in ids]), z, R)
                e = np.full(d.shape, 0.5)
                hists = np.array([dt.reflectance_hist for dt in dets], dtype=float)
                if self.target_id in self.tracks and self.appearance is not None:
                    e[ids.index(self.target_id)] = self.appearance.error(hists)
                lik = association_likelihood(d, e)
                # confirmed filters first, then the tentative ones on what is left: a filter born last
                # frame (clutter, a split cluster) must not take a confirmed filter's detection
                confirmed = np.array([self.tracks[i].confirmed for i in ids])
                for first, rows in ((True, np.flatnonzero(confirmed)), (False, np.flatnonzero(~confirmed))):
                    cols = np.array([j for j in range(len(dets)) if j not in assigned], dtype=int)
                    if len(rows) and len(cols):
                        for a, b in greedy_assign(lik[np.ix_(rows, cols)], d[np.ix_(rows, cols)], c.gate):
                            take(int(rows[a]), int(cols[b]), R[cols[b]])
                    if first:  # the target's filter is a confirmed one
                        j = self._maneuver(dets, z, assigned)
                        if j is not None:  # the turn the constant velocity missed: open the filter up to it
                            tr = self.tracks[self.target_id]
                            miss = z[j] - tr.xy
                            tr.P[:2, :2] += np.outer(miss, miss)
                            tr.P[2:, 2:] += np.outer(miss, miss) / c.maneuver_lag_s ** 2
                            take(ids.index(self.target_id), j, R[j])
            if self.target_id in res.detected_ids:
                self._learn(dets, pairs, ids)
            for j in range(len(dets)):
                if j not in assigned:
                    self.tracks[self.next_id] = CVTrack.from_detection(self.next_id, z[j], R[j], frame.t_s)
                    res.detected_ids.add(self.next_id)
                    self.next_id += 1
        return res

    def _maneuver(self, dets, z: np.ndarray, assigned: set[int]) -> int | None:
        """A detection left over by the association (eq. 3's gate) that continues the undetected
        target filter: within ``maneuver_radius_m`` of its prediction and accepted by the target's
        appearance classifier once trained, with nobody else within ``maneuver_clear_m`` of it. A person
        turning sharply leaves the constant-velocity gate for a frame or two; without this the
        target's filter dies and a new one must win the antenna's probability back."""
        c = self.config
        tr = self.tracks.get(self.target_id)
        if tr is None or tr.detected:
            return None
        free = [j for j in range(len(dets)) if j not in assigned]
        if not free:
            return None
        dist = np.linalg.norm(z[free] - tr.xy, axis=1)
        k = int(np.argmin(dist))
        if dist[k] > c.maneuver_radius_m:
            return None
        # in a crowd a leftover detection near the target is as likely a passer-by: only in the clear
        others = [o.xy for o in self.tracks.values() if o.track_id != self.target_id]
        others += [z[j] for j in range(len(z)) if j != free[k]]
        if others and np.min(np.linalg.norm(np.array(others) - z[free[k]], axis=1)) <= c.maneuver_clear_m:
            return None
        if self.appearance is not None and self.appearance.ready:
            e = float(self.appearance.error(np.asarray(dets[free[k]].reflectance_hist, dtype=float)[None, :])[0])
            return free[k] if e <= c.maneuver_max_error else None
        return free[k]

    def _learn(self, dets, pairs, ids) -> None:
        """Target's detection positive, the other confirmed filters' detections negative."""
        if self.appearance is None:
            self.appearance = OnlineBoost(len(dets[0].reflectance_hist))
        for r, j in pairs:
            tid = ids[r]
            if tid == self.target_id or self.tracks[tid].confirmed:
                self.appearance.update(dets[j].reflectance_hist, tid == self.target_id)

    def manage(self, res: _FrameResult) -> None:
        """Eq. 8 on every filter: confirmations and deletions of this frame into ``res``."""
        c = self.config
        for tid in list(self.tracks):
            tr = self.tracks[tid]
            was = tr.confirmed
            if not tr.detected:
                tr.misses += 1
            if tr.manage(c.confirm_ratio, c.delete_rise, c.max_area_m2):
                del self.tracks[tid]
                res.deleted_ids.append(tid)
            elif tr.confirmed and not was:
                res.confirmed_ids.append(tid)

    def set_target(self, track_id: int | None) -> None:
        """A new target: its appearance is learned afresh."""
        if track_id != self.target_id:
            self.appearance = None
        self.target_id = track_id


def _estimates(core: MultiPersonCore, p_of: Callable[[int], float]) -> list[TrackEstimate]:
    return [TrackEstimate(tr.track_id, tr.xy.copy(), tr.P[:2, :2].copy(), float(p_of(tr.track_id)), tr.detected)
            for tr in core.tracks.values() if tr.confirmed]


def _robot_xy(xy_world_m: np.ndarray, pose_world_robot: np.ndarray) -> np.ndarray:
    """World points (N, 2) in the robot frame."""
    return (np.atleast_2d(xy_world_m) - pose_world_robot[:2]) @ rot2(float(pose_world_robot[2]))


# ---------------------------------------------------------------------------------- paper tracker
class PaperTracker:
    """Misu and Miura's tracker: LIDAR filters + ESPAR target probability + Sec. 5's states."""

    name = "paper"

    def __init__(self, config: TrackerConfig | None = None, **options):
        self.config = replace(config or TrackerConfig(), **options)
        self.core = MultiPersonCore(self.config)
        self.prob = TargetProbability(self.config.p_min)
        self.state = "Initialize"
        self.n_readings = 0
        self.last_xy: np.ndarray | None = None
        self.last_cov: np.ndarray | None = None
        self.lost_since_s: float | None = None
        self.grid: ExistenceGrid | None = None
        self.goal_xy: np.ndarray | None = None
        self.goal_since_s: float | None = None
        self.bearings_world_rad: list[float] = []  # the latest readings' bearings from the robot (world)
        self.likelihood_ratios: dict[int, float] = {}  # this frame's P(Z | A_i) / P(Z | lost); empty without readings

    @property
    def target_id(self) -> int | None:
        return self.core.target_id

    def _remember_bearings(self, frame: FollowFrame) -> None:
        yaw = float(frame.pose_world_robot[2])
        self.bearings_world_rad = (self.bearings_world_rad + [yaw + r.bearing_robot_rad for r in frame.espar]
                                   )[-self.config.face_readings:]

    def antenna_heading_world_rad(self) -> float | None:
        """The circular mean of the latest readings' world bearings (None without readings)."""
        if not self.bearings_world_rad:
            return None
        b = np.asarray(self.bearings_world_rad)
        return float(np.arctan2(np.sin(b).sum(), np.cos(b).sum()))

    def _espar_bearing_updates(self, frame: FollowFrame) -> None:
        """Eq. 6: the undetected target filter takes each reading as a bearing (multipath gated)."""
        tr = self.core.tracks.get(self.target_id)
        if tr is None or tr.detected or not frame.espar:
            return
        pose = np.asarray(frame.pose_world_robot, dtype=float)
        Rot = rot2(float(pose[2]))
        for r in frame.espar:
            xy_ant = pose[:2] + Rot @ np.asarray(r.xy_antenna_robot_m, dtype=float)
            tr.x, tr.P, _ = update_bearing(tr.x, tr.P, r.bearing_robot_rad, xy_ant, float(pose[2]),
                                           self.config.espar.sigma_rad, float(frame.cov_world_robot[2, 2]),
                                           self.config.bearing_gate)

    def _probability_update(self, frame: FollowFrame) -> None:
        """Eqs. 9-14 with this frame's readings (eq. 10: their product)."""
        self.likelihood_ratios = {}
        if not frame.espar:
            return
        ids = list(self.prob.p)
        if ids:
            xy_robot = _robot_xy(np.array([self.core.tracks[i].xy for i in ids]), frame.pose_world_robot)
            lik = self.config.espar.likelihood_grid(frame.espar, xy_robot)
            p_z = dict(zip(ids, lik.tolist(), strict=True))
        else:
            p_z = {}
        p_z_lost = self.config.espar.p_lost ** len(frame.espar)
        self.prob.update(p_z, p_z_lost)
        self.n_readings += len(frame.espar)
        # this frame's likelihood ratios P(Z | A_i) / P(Z | lost) (eqs. 9-10), before any floor
        self.likelihood_ratios = {i: v / p_z_lost for i, v in p_z.items()}

    def step(self, frame: FollowFrame) -> TrackerOutput:
        c = self.config
        res = self.core.step(frame)
        self._remember_bearings(frame)
        self._espar_bearing_updates(frame)
        self.core.manage(res)
        for tid in res.deleted_ids:
            self.prob.remove(tid)
        for tid in res.confirmed_ids:
            self.prob.add(tid, c.new_track_prior)
        self._probability_update(frame)
        tgt = self.core.tracks.get(self.target_id)
        if tgt is not None:
            self.last_xy, self.last_cov = tgt.xy.copy(), tgt.P[:2, :2].copy()

        if self.state == "Initialize":
            if self.n_readings >= c.init_min_readings:
                best, p = self.prob.best()
                if best is not None and p > c.init_threshold:
                    self._track(best)
        elif self.state == "Tracking":
            if tgt is None or self.prob.p.get(self.target_id, 0.0) < c.lost_threshold:
                self.state, self.lost_since_s = "Lost", frame.t_s
                self.core.set_target(None)
        else:
            best, p = self.prob.best()
            if best is not None and p > c.reassign_threshold:
                self._track(best)
            elif self.state == "Lost" and frame.t_s - self.lost_since_s >= c.lost_to_search_s:
                self.state, self.grid, self.goal_xy = "Searching", None, None
            if self.state == "Searching":
                self._search(frame)
        return self._output()

    def _track(self, track_id: int) -> None:
        self.state = "Tracking"
        self.core.set_target(track_id)
        tr = self.core.tracks[track_id]
        self.last_xy, self.last_cov = tr.xy.copy(), tr.P[:2, :2].copy()
        self.grid = self.goal_xy = self.lost_since_s = None

    def _search(self, frame: FollowFrame) -> None:
        """Sec. 5.3: with the robot stopped, accumulate the existence grid over ``grid_readings``
        readings; then drive to its best cell, and start over there (or after a timeout)."""
        c = self.config
        pose = np.asarray(frame.pose_world_robot, dtype=float)
        if self.goal_xy is not None:
            reached = np.linalg.norm(pose[:2] - self.goal_xy) < c.goal_reached_m
            if reached or frame.t_s - self.goal_since_s > c.search_timeout_s:
                self.grid, self.goal_xy = None, None
        if self.goal_xy is not None or not frame.robot_stopped:
            return
        if self.grid is None:
            sigma = None if self.last_xy is None else 0.5 + c.walking_speed_mps * (frame.t_s - self.lost_since_s)
            self.grid = ExistenceGrid(pose[:2], c.grid_half_size_m, c.grid_cell_m, c.espar,
                                      prior_xy_world_m=self.last_xy, prior_sigma_m=sigma)
        self.grid.add(frame.espar, pose)
        if self.grid.n_readings >= c.grid_readings:
            self.goal_xy, self.goal_since_s = self.grid.best_xy_world_m(), frame.t_s

    def _output(self) -> TrackerOutput:
        tracks = _estimates(self.core, lambda i: self.prob.p.get(i, 0.0))
        if self.state == "Tracking":
            tr = self.core.tracks[self.target_id]
            return TrackerOutput("Tracking", self.target_id, tr.xy.copy(), tr.P[:2, :2].copy(), tracks)
        # Lost: drive to the last estimate; Searching: stand still until the grid gives a goal.
        stop = self.state == "Searching" and self.goal_xy is None
        xy = self.goal_xy if self.state == "Searching" and not stop else self.last_xy
        goal = None if xy is None or stop or self.state == "Initialize" else xy.copy()
        face = self.antenna_heading_world_rad() if stop and self.config.face_antenna else None
        return TrackerOutput(self.state, None, None if xy is None else xy.copy(),
                             None if xy is None or xy is self.goal_xy else self.last_cov, tracks,
                             stop_robot=stop, goal_xy_world_m=goal, face_world_rad=face)


# ----------------------------------------------------------------------------- LIDAR-only tracker
class LidarOnlyTracker:
    """The same filters and association without the antenna: the target is the confirmed filter
    nearest to ``initial_target_xy_world_m`` (default: nearest to the robot) at the first frame that
    has one; when its filter is deleted, the nearest confirmed filter within ``reacquire_radius_m``
    of its last position becomes the target (a passer-by or a crossing person can take its place)."""

    name = "lidar-only"

    def __init__(self, config: TrackerConfig | None = None, initial_target_xy_world_m=None, **options):
        self.config = replace(config or TrackerConfig(), **options)
        self.core = MultiPersonCore(self.config)
        self.initial_xy = None if initial_target_xy_world_m is None else np.asarray(initial_target_xy_world_m, float)
        self.state = "Initialize"
        self.last_xy: np.ndarray | None = None
        self.last_cov: np.ndarray | None = None

    @property
    def target_id(self) -> int | None:
        return self.core.target_id

    def _nearest(self, xy: np.ndarray, radius: float) -> int | None:
        conf = [tr for tr in self.core.tracks.values() if tr.confirmed]
        if not conf:
            return None
        dist = [np.linalg.norm(tr.xy - xy) for tr in conf]
        k = int(np.argmin(dist))
        return conf[k].track_id if dist[k] <= radius else None

    def step(self, frame: FollowFrame) -> TrackerOutput:
        res = self.core.step(frame)
        self.core.manage(res)
        tgt = self.core.tracks.get(self.target_id)
        if self.state == "Initialize":
            ref = self.initial_xy if self.initial_xy is not None else np.asarray(frame.pose_world_robot[:2], float)
            pick = self._nearest(ref, np.inf)
            if pick is not None:
                self.state = "Tracking"
                self.core.set_target(pick)
        elif tgt is None:
            self.state = "Lost"
            self.core.set_target(None)
            pick = self._nearest(self.last_xy, self.config.reacquire_radius_m)
            if pick is not None:
                self.state = "Tracking"
                self.core.set_target(pick)
        tgt = self.core.tracks.get(self.target_id)
        if tgt is not None:
            self.last_xy, self.last_cov = tgt.xy.copy(), tgt.P[:2, :2].copy()
        tracks = _estimates(self.core, lambda i: float(i == self.target_id))
        if tgt is not None:
            return TrackerOutput("Tracking", tgt.track_id, tgt.xy.copy(), tgt.P[:2, :2].copy(), tracks)
        xy = None if self.last_xy is None else self.last_xy.copy()
        return TrackerOutput(self.state, None, xy, self.last_cov, tracks,
                             goal_xy_world_m=None if self.state == "Initialize" else xy)


__all__ = ["TrackerConfig", "association_likelihood", "greedy_assign", "TargetProbability", "MultiPersonCore",
           "PaperTracker", "LidarOnlyTracker"]
