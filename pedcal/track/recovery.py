"""Target recovery as a factor graph: a fixed-lag smoother over the target's recent positions.

Variables (GTSAM keys): per LIDAR frame k the robot's pose ``x_k`` (Pose2), the target's position
``t_k`` and velocity ``v_k`` (Point2, world frame); per ESPAR reading the antenna's pose ``a_j``.

Factors:
- ``PriorFactorPose2`` on x_k: the robot's localization with its covariance (world x, y, yaw turned
  into GTSAM's body-frame tangent);
- constant-velocity motion, t_{k+1} = t_k + v_k dt, and a first-order Gauss-Markov velocity,
  v_{k+1} = e^(-dt/tau) v_k, whose stationary spread is the walking speed (so velocity stays bounded
  while nothing observes it): two linear custom factors, Jacobians checked numerically in the tests;
- ``BearingRangeFactor2D`` x_k -> t_k for a LIDAR detection of the target;
- ``BearingFactor2D`` a_j -> t_k for an ESPAR reading (Misu and Miura's eq. 10 antenna model as a
  factor). The antenna sits off the robot's centre: it is its own Pose2 a_j, tied to x_k by a
  ``BetweenFactorPose2`` with the mount offset (tight, 1 mm / 0.1 deg), so the bearing starts at the
  antenna, not the robot's centre. Sigma is the fitted spread of the antenna model, never tighter
  than the quantization's 30 deg / sqrt(12); a Cauchy kernel keeps multipath readings (uniformly
  random directions) from dragging the estimate;
- a weak ``PriorFactorPoint2`` seed from the grid belief (its dominant component) when the target has
  been out of sight.

As the robot moves, bearings from different places triangulate the target without stopping.
``gtsam.IncrementalFixedLagSmoother`` (iSAM2) keeps the last ``lag_s`` seconds and marginalizes older
variables into a prior.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import gtsam
import numpy as np
from gtsam.symbol_shorthand import A, T, V, X

from pedcal.errors import PedcalInputError
from pedcal.follow_types import EsparReading, FollowFrame, TrackerOutput
from pedcal.track.espar import DEFAULT_LIKELIHOOD
from pedcal.track.grid_belief import GridBelief, GridBeliefConfig
from pedcal.track.tracker import PaperTracker

ESPAR_QUANTIZATION_SIGMA_RAD = math.radians(30.0) / math.sqrt(12.0)
_I2 = np.eye(2)


@dataclass(frozen=True)
class SmootherConfig:
    """The smoother's noise models and window; recorded with the tracker's results."""

    lag_s: float = 10.0
    walk_speed_mps: float = 1.2            # stationary spread of the target's velocity (per axis)
    velocity_tau_s: float = 3.0            # how long the target keeps its velocity (Gauss-Markov time)
    position_noise_m: float = 0.05         # unmodelled motion per step on top of constant velocity
    espar_sigma_rad: float = max(DEFAULT_LIKELIHOOD.sigma_rad, ESPAR_QUANTIZATION_SIGMA_RAD)
    espar_cauchy_k: float = 2.0            # Cauchy kernel scale, in sigmas
    espar_robust: bool = True              # False: plain Gaussian bearings (for comparison only)
    lidar_bearing_sigma_rad: float = math.radians(3.0)
    lidar_range_sigma_m: float = 0.1       # box centre vs the person's centre
    mount_sigma_m: float = 1e-3
    mount_sigma_rad: float = math.radians(0.1)

    def __post_init__(self):
        if self.espar_sigma_rad < ESPAR_QUANTIZATION_SIGMA_RAD:
            raise PedcalInputError(f"smoother: espar_sigma_rad {self.espar_sigma_rad:.4f} is tighter than the "
                                   f"quantization's 30 deg / sqrt(12) = {ESPAR_QUANTIZATION_SIGMA_RAD:.4f} rad")
        for name in ("lag_s", "walk_speed_mps", "velocity_tau_s", "position_noise_m", "lidar_bearing_sigma_rad",
                     "lidar_range_sigma_m", "espar_cauchy_k"):
            if not getattr(self, name) > 0:
                raise PedcalInputError(f"smoother: {name} must be positive, got {getattr(self, name)}")


def constant_velocity_error(dt_s: float, factor: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
    """e = t_{k+1} - t_k - v_k dt (keys t_k, t_{k+1}, v_k)."""
    k0, k1, kv = factor.keys()
    if jacobians is not None:
        jacobians[0] = -_I2
        jacobians[1] = _I2
        jacobians[2] = -dt_s * _I2
    return values.atPoint2(k1) - values.atPoint2(k0) - dt_s * values.atPoint2(kv)


def gauss_markov_velocity_error(decay: float, factor: gtsam.CustomFactor, values: gtsam.Values,
                                jacobians) -> np.ndarray:
    """e = v_{k+1} - decay v_k (keys v_k, v_{k+1}); decay = exp(-dt / tau)."""
    k0, k1 = factor.keys()
    if jacobians is not None:
        jacobians[0] = -decay * _I2
        jacobians[1] = _I2
    return values.atPoint2(k1) - decay * values.atPoint2(k0)


def pose2_prior_noise(pose_world_robot: np.ndarray, cov_world_robot: np.ndarray) -> gtsam.noiseModel.Base:
    """GTSAM's Pose2 tangent is (x, y) in the body frame then theta: turn the world covariance into it."""
    c, s = math.cos(pose_world_robot[2]), math.sin(pose_world_robot[2])
    J = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])       # R^T on the translation block
    cov = J @ np.asarray(cov_world_robot, dtype=float) @ J.T
    cov = 0.5 * (cov + cov.T) + 1e-10 * np.eye(3)
    return gtsam.noiseModel.Gaussian.Covariance(cov)


class TargetSmoother:
    """Fixed-lag smoother of the target's world position from LIDAR detections and ESPAR bearings."""

    def __init__(self, config: SmootherConfig | None = None):
        self.config = config or SmootherConfig()
        cfg = self.config
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        self._smoother = gtsam.IncrementalFixedLagSmoother(cfg.lag_s, params)
        self._k = -1                     # index of the latest frame
        self._t_prev_s: float | None = None
        self._n_antenna = 0
        self._xy_latest: np.ndarray | None = None
        self._v_latest = np.zeros(2)
        cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(cfg.espar_cauchy_k)
        bearing_noise = gtsam.noiseModel.Isotropic.Sigma(1, cfg.espar_sigma_rad)
        self._espar_noise = gtsam.noiseModel.Robust.Create(cauchy, bearing_noise) if cfg.espar_robust else bearing_noise
        self._lidar_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.lidar_bearing_sigma_rad, cfg.lidar_range_sigma_m]))
        self._mount_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.mount_sigma_m, cfg.mount_sigma_m, cfg.mount_sigma_rad]))

    @property
    def started(self) -> bool:
        return self._k >= 0

    def add_frame(self, t_s: float, pose_world_robot, cov_world_robot, detection_xy_robot_m=None,
                  espar: tuple[EsparReading, ...] = (), seed_xy_world_m=None, seed_sigma_m: float | None = None,
                  seed_velocity_world_mps=None, seed_cov_world=None) -> np.ndarray | None:
        """Add one frame's robot pose and measurements, update, and return the target's latest position.

        The first frame needs a detection or a seed (something must say where the target starts);
        ``seed_velocity_world_mps`` (e.g. the Kalman filter's last velocity) is the first velocity's
        prior mean, with the walking speed as its spread. A seed's spread is ``seed_sigma_m`` (isotropic)
        or the (2, 2) world covariance ``seed_cov_world``.
        Returns None while nothing has started the smoother.
        """
        cfg = self.config
        pose = np.asarray(pose_world_robot, dtype=float)
        T_world_robot = gtsam.Pose2(*pose)
        det = None if detection_xy_robot_m is None else np.asarray(detection_xy_robot_m, dtype=float)
        if not self.started:
            if det is not None:
                start = T_world_robot.transformFrom(det)
                start_sigma = 0.3
            elif seed_xy_world_m is not None:
                start = np.asarray(seed_xy_world_m, dtype=float)
                start_sigma = seed_sigma_m or 3.0
            else:
                return None
            self._xy_latest = start
            if seed_velocity_world_mps is not None:
                self._v_latest = np.asarray(seed_velocity_world_mps, dtype=float).copy()
            seed_xy_world_m, seed_sigma_m = start, start_sigma
        if self._t_prev_s is not None and t_s <= self._t_prev_s:
            raise PedcalInputError(f"smoother: frame times must increase, got {t_s} after {self._t_prev_s}")

        k = self._k + 1
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()

        def new(key, value, insert):
            insert(key, value)
            stamps.insert((key, t_s))

        new(X(k), T_world_robot, values.insert)
        graph.add(gtsam.PriorFactorPose2(X(k), T_world_robot, pose2_prior_noise(pose, cov_world_robot)))

        # initial guess of the target: the detection, else the constant-velocity prediction
        if det is not None:
            xy0 = T_world_robot.transformFrom(det)
        elif self.started:
            xy0 = self._xy_latest + self._v_latest * (t_s - self._t_prev_s)
        else:
            xy0 = self._xy_latest
        new(T(k), np.asarray(xy0, dtype=float), values.insert)
        new(V(k), self._v_latest.copy(), values.insert)

        if self.started:
            dt = t_s - self._t_prev_s
            decay = math.exp(-dt / cfg.velocity_tau_s)
            sigma_v = cfg.walk_speed_mps * math.sqrt(max(1.0 - decay * decay, 1e-9))
            graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(2, cfg.position_noise_m * math.sqrt(dt)),
                                         [T(k - 1), T(k), V(k - 1)], partial(constant_velocity_error, dt)))
            graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(2, sigma_v), [V(k - 1), V(k)],
                                         partial(gauss_markov_velocity_error, decay)))
        else:
            graph.add(gtsam.PriorFactorPoint2(V(k), self._v_latest.copy(),
                                              gtsam.noiseModel.Isotropic.Sigma(2, cfg.walk_speed_mps)))

        if det is not None:
            graph.add(gtsam.BearingRangeFactor2D(X(k), T(k), gtsam.Rot2(math.atan2(det[1], det[0])),
                                                 float(np.hypot(det[0], det[1])), self._lidar_noise))
        for reading in espar:
            mount = np.asarray(reading.xy_antenna_robot_m, dtype=float)
            T_robot_antenna = gtsam.Pose2(mount[0], mount[1], 0.0)
            key = A(self._n_antenna)
            self._n_antenna += 1
            new(key, T_world_robot.compose(T_robot_antenna), values.insert)
            graph.add(gtsam.BetweenFactorPose2(X(k), key, T_robot_antenna, self._mount_noise))
            # the reading's bearing is in the robot frame; the antenna's frame is the robot's turned by 0
            graph.add(gtsam.BearingFactor2D(key, T(k), gtsam.Rot2(reading.bearing_robot_rad), self._espar_noise))
        if seed_xy_world_m is not None:
            seed_noise = (gtsam.noiseModel.Gaussian.Covariance(np.asarray(seed_cov_world, dtype=float))
                          if seed_cov_world is not None and det is None
                          else gtsam.noiseModel.Isotropic.Sigma(2, float(seed_sigma_m or 3.0)))
            graph.add(gtsam.PriorFactorPoint2(T(k), np.asarray(seed_xy_world_m, dtype=float), seed_noise))

        self._smoother.update(graph, values, stamps)
        self._k, self._t_prev_s = k, t_s
        estimate = self._smoother.calculateEstimate()
        self._xy_latest = estimate.atPoint2(T(k))
        self._v_latest = estimate.atPoint2(V(k))
        return self._xy_latest.copy()

    def latest(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The target's latest world position and its marginal covariance (None before the start)."""
        if not self.started:
            return None
        return self._xy_latest.copy(), np.asarray(self._smoother.marginalCovariance(T(self._k)))

    def latest_velocity(self) -> np.ndarray:
        return self._v_latest.copy()


# ------------------------------------------------------------------------------------------ tracker
@dataclass(frozen=True)
class RecoveryConfig:
    """When the factor-graph tracker re-takes a detection, and when it gives up moving."""

    reacquire_gate: float = 3.0            # Mahalanobis distance of a detection from the estimate
    reacquire_radius_m: float = 2.5        # and never farther than this, however spread the belief
    reacquire_close_m: float = 1.0         # without a trained classifier, only this close to the estimate
    reacquire_max_error: float = 0.5       # the target's appearance classifier error e (eq. 3) at most
    veto_min_error: float = 0.8            # the paper tracker's re-take is undone above this e
    ruled_out_ratio: float = 1.0           # no fast re-take of a filter the readings since the loss put below this
                                           # likelihood ratio against "lost" (eqs. 9-10 summed since the loss)
    reacquire_p_target: float = 0.7        # P(T = i) given to the re-taken filter (the paper's threshold)
    lost_sigma0_m: float = 0.5             # grid belief around the last estimate at the loss
    sharpen_floor: float = 0.05            # the grid keeps this much outside the smoother's Gaussian
    reseed_ratio: float = 0.01             # smoother mean in a cell under this share of the mode: re-seed it
    stop_spread_m: float = 4.0             # belief spread beyond this ...
    stop_silence_s: float = 2.0            # ... and no antenna reading for this long: stop and search


def recovery_prior_cov(cov_last_world: np.ndarray, sigma_min_m: float) -> np.ndarray:
    """Where the lost target starts: the Kalman filter's last position covariance (2, 2), its
    principal axes kept, each spread at least ``sigma_min_m``."""
    w, U = np.linalg.eigh(0.5 * (np.asarray(cov_last_world, dtype=float) + np.asarray(cov_last_world).T))
    return (U * np.maximum(w, sigma_min_m ** 2)) @ U.T


class FactorGraphTracker:
    """The paper's tracker while the target is in view; a smoother + grid belief while it is not.

    In view, every frame goes through :class:`~pedcal.track.tracker.PaperTracker` (its Kalman
    filters, association, appearance classifier and target probability, eqs. 3-14). Once it
    declares the target lost, this tracker does not let the robot stop: a :class:`GridBelief` started
    at the last estimate and a :class:`TargetSmoother` seeded with the Kalman filter's last position
    and velocity take every frame's ESPAR readings and the LIDAR's negative information, and give
    ``target_xy_world_m`` and ``goal_xy_world_m`` (a free cell) each frame, so bearings taken while
    driving triangulate the target. The robot is asked to stop (state "Searching") only when the
    belief is hopelessly spread: wider than ``stop_spread_m`` with no antenna reading for
    ``stop_silence_s`` (the transmitter out of the antenna's range), where the paper's Searching
    stops after 2 s lost, always. A detection within the gate of the estimate whose reflectance the target's
    appearance classifier accepts is re-taken as the target at once, without waiting for the
    antenna to raise its probability above 0.7. Conversely, when the paper tracker re-takes a filter
    on the antenna's word alone (a passer-by in the target's direction has the same bearing), the
    re-take stands only if that filter is detected and the classifier does not reject it. The
    classifier is trusted unless the antenna's probability disowned the target's filter while the
    LIDAR still detected it: then the filter followed was not the target, the classifier learned the
    wrong person, and it is dropped (the paper tracker's antenna-driven re-take decides alone). A
    coasting filter disowned by the antenna (the target turned out of view) keeps it. The fast
    re-take also needs the antenna's readings since the loss not to rule the filter out: the product of
    their likelihood ratios P(Z | A_i) / P(Z | lost) (eqs. 9-10) at least ``ruled_out_ratio`` (1: the
    readings must not favour "lost" over it), as in a sequential probability-ratio test. The filter's
    probability at the loss says nothing here: the lost target's filter held nearly all of it, so every
    other filter, the target's new one included, sat near the floor.
    """

    name = "factorgraph"

    def __init__(self, config=None, occupancy=None, smoother_config: SmootherConfig | None = None,
                 grid_config: GridBeliefConfig | None = None, recovery_config: RecoveryConfig | None = None, **options):
        self.paper = PaperTracker(config, **options)
        self.occupancy = occupancy
        self.smoother_config = smoother_config or SmootherConfig()
        self.grid_config = grid_config
        self.recovery = recovery_config or RecoveryConfig()
        self.smoother: TargetSmoother | None = None
        self.grid = None
        self._appearance = None          # the target's classifier, kept across the loss
        self._last_velocity = np.zeros(2)
        self._t_prev_s: float | None = None
        self._estimate: tuple[np.ndarray, np.ndarray] | None = None
        self._t_last_reading_s: float | None = None
        self._log_lr: dict[int, float] = {}  # each filter's summed log P(Z | A_i) / P(Z | lost) since the loss

    # the paper tracker forgets the target's classifier when it loses the target; keep it
    def _remember_target(self) -> None:
        core = self.paper.core
        tr = core.tracks.get(core.target_id)
        if tr is not None:
            self._last_velocity = tr.x[2:4].copy()
        if core.appearance is not None:
            self._appearance = core.appearance

    def _start_recovery(self, frame: FollowFrame) -> None:
        xy0 = self.paper.last_xy if self.paper.last_xy is not None else np.asarray(frame.pose_world_robot[:2])
        cov_last = self.paper.last_cov if self.paper.last_cov is not None else np.eye(2)
        cov0 = recovery_prior_cov(cov_last, self.recovery.lost_sigma0_m)
        self.grid = GridBelief(self.occupancy, xy0, self.grid_config, self.paper.config.espar)
        self.grid.reset_gaussian(xy0, cov_world=cov0)
        self.smoother = TargetSmoother(self.smoother_config)
        self._log_lr = {}
        self._seed = (np.asarray(xy0, dtype=float), float(np.sqrt(np.linalg.eigvalsh(cov0).max())), cov0)

    def _recover(self, frame: FollowFrame) -> None:
        """One frame of the grid (motion, negative information, antenna) and the smoother."""
        pose = np.asarray(frame.pose_world_robot, dtype=float)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        R = np.array([[c, -s], [s, c]])
        grid = self.grid
        if self._t_prev_s is not None:
            grid.predict(frame.t_s - self._t_prev_s)
        people_world = [pose[:2] + R @ np.asarray(d.xy_robot_m, dtype=float) for d in frame.detections]
        grid.observe_empty(pose, people_world)
        for r in frame.espar:
            grid.observe_bearing(pose[:2] + R @ np.asarray(r.xy_antenna_robot_m, dtype=float),
                                 pose[2] + r.bearing_robot_rad)
        seed_xy, seed_sigma, seed_cov = (None, None, None)
        if not self.smoother.started:
            seed_xy, seed_sigma, seed_cov = self._seed
        elif self._estimate is not None:
            # the smoother drifted where the grid says the target cannot be: give it the grid's answer
            ij = grid.cell_of(self.smoother.latest()[0])
            belief_there = grid.belief[ij[0], ij[1]] if grid.in_window(ij) else 0.0
            if belief_there < self.recovery.reseed_ratio * grid.belief.max():
                xy_g, cov_g, _ = grid.estimate()
                seed_xy, seed_sigma = xy_g, float(np.sqrt(np.trace(cov_g)))
        self.smoother.add_frame(frame.t_s, pose, frame.cov_world_robot, espar=frame.espar,
                                seed_xy_world_m=seed_xy, seed_sigma_m=seed_sigma, seed_cov_world=seed_cov,
                                seed_velocity_world_mps=self._last_velocity if seed_xy is not None else None)
        xy_s, cov_s = self.smoother.latest()
        # the answer: the grid sharpened by the smoother's Gaussian. The product is not stored back in
        # the grid, which already holds the same readings; multiplying every frame would count them again
        fused = grid.copy()
        fused.observe_gaussian(xy_s, cov_s, floor=self.recovery.sharpen_floor)
        xy, cov, _ = fused.estimate()
        grid.keep_in_window(xy)
        self._estimate = (xy, cov)
        self._smoother_xy, self._grid_xy = xy_s, grid.estimate()[0]

    def _reacquire(self, frame: FollowFrame) -> int | None:
        """A filter detected this frame at the estimate (gate) that looks like the target."""
        if self._estimate is None or not frame.detections:
            return None
        core = self.paper.core
        xy_est, cov_est = self._estimate
        cand = [tr for tr in core.tracks.values() if tr.detected]
        if not cand:
            return None
        xy = np.array([tr.xy for tr in cand])
        S = cov_est + np.array([tr.P[:2, :2] for tr in cand])
        diff = xy - xy_est
        d = np.sqrt(np.einsum("ni,nij,nj->n", diff, np.linalg.inv(S), diff))
        dist = np.linalg.norm(diff, axis=1)
        ok = (d < self.recovery.reacquire_gate) & (dist < self.recovery.reacquire_radius_m)
        # nor a filter the antenna ruled out while the target was lost: the product of the likelihood ratios
        # of its readings since the loss below ``ruled_out_ratio`` (a filter without readings yet: 1)
        min_log_lr = math.log(self.recovery.ruled_out_ratio)
        ok &= np.array([self._log_lr.get(tr.track_id, 0.0) >= min_log_lr for tr in cand])
        if not ok.any() or self._appearance is None:
            return None          # classifier dropped (it learned somebody else): the antenna decides (eq. 9)
        if self._appearance.ready:
            ok &= self._appearance_error(frame, xy) <= self.recovery.reacquire_max_error
        else:                    # it never saw anybody else: nothing to tell people apart, take only a close one
            ok &= dist < self.recovery.reacquire_close_m
        if not ok.any():
            return None
        return cand[int(np.argmin(np.where(ok, d, np.inf)))].track_id

    def _appearance_error(self, frame: FollowFrame, xy_world_m: np.ndarray) -> np.ndarray:
        """e of eq. 3 (the target's classifier) for the detection nearest each of the points (N, 2)."""
        pose = np.asarray(frame.pose_world_robot, dtype=float)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        det_world = np.array([d.xy_robot_m for d in frame.detections]) @ np.array([[c, s], [-s, c]]) + pose[:2]
        hists = np.array([d.reflectance_hist for d in frame.detections], dtype=float)
        nearest = np.argmin(np.linalg.norm(det_world[None, :, :] - xy_world_m[:, None, :], axis=2), axis=1)
        return self._appearance.error(hists[nearest])

    def _vetoed(self, frame: FollowFrame, was: str, lost_since_s: float | None) -> bool:
        """Undo the paper tracker's re-take of a filter on the antenna's word alone when the target's
        classifier rejects its detection (a passer-by in the target's direction) or nothing detected it
        this frame; True if undone."""
        paper = self.paper
        tr = paper.core.tracks.get(paper.target_id)
        if self.grid is None or tr is None or self._appearance is None or not self._appearance.ready:
            return False
        # a filter nobody detected this frame cannot be checked: wait until a detection shows who it is
        if tr.detected and self._appearance_error(frame, tr.xy[None, :])[0] <= self.recovery.veto_min_error:
            return False
        prob = paper.prob
        p_keep = 0.5 * paper.config.lost_threshold
        prob.p_lost += prob.p.get(tr.track_id, 0.0) - p_keep
        prob.p[tr.track_id] = p_keep
        paper.core.set_target(None)
        paper.state, paper.lost_since_s = was, lost_since_s
        return True

    def _take(self, track_id: int) -> None:
        """Make ``track_id`` the paper tracker's target with P(T = i) = ``reacquire_p_target``."""
        paper = self.paper
        prob = paper.prob
        p_new = self.recovery.reacquire_p_target
        rest = sum(v for k, v in prob.p.items() if k != track_id) + prob.p_lost
        scale = (1.0 - p_new) / rest if rest > 0 else 0.0
        prob.p = {k: v * scale for k, v in prob.p.items() if k != track_id}
        prob.p[track_id] = p_new
        prob.p_lost *= scale
        paper._track(track_id)
        if self._appearance is not None:
            paper.core.appearance = self._appearance

    def _reset_recovery(self) -> None:
        self.smoother = self.grid = self._estimate = None

    def step(self, frame: FollowFrame) -> TrackerOutput:
        if frame.espar:
            self._t_last_reading_s = frame.t_s
        was, lost_since_s, was_target = self.paper.state, self.paper.lost_since_s, self.paper.target_id
        out = self.paper.step(frame)
        lost_tr = self.paper.core.tracks.get(was_target)
        if was == "Tracking" and out.state != "Tracking" and lost_tr is not None and lost_tr.detected:
            self._appearance = None        # the antenna disowned a filter still in view: it was somebody else
        if out.state == "Tracking" and was in ("Lost", "Searching") and self._vetoed(frame, was, lost_since_s):
            out = self.paper._output()
        if out.state == "Tracking":
            self._remember_target()
            self._reset_recovery()
            self._t_prev_s = frame.t_s
            return out
        if was == "Initialize" and out.state == "Initialize":
            self._t_prev_s = frame.t_s
            return out
        # lost: the paper tracker would wait and then stop; we keep moving
        if self.grid is None:
            self._start_recovery(frame)
        for tid, ratio in self.paper.likelihood_ratios.items():
            self._log_lr[tid] = self._log_lr.get(tid, 0.0) + math.log(max(ratio, 1e-300))
        take = self._reacquire(frame)
        if take is not None:
            self._take(take)
            self._reset_recovery()
            self._t_prev_s = frame.t_s
            return self.paper._output()
        self._recover(frame)
        self._t_prev_s = frame.t_s
        xy, cov = self._estimate
        silent_s = frame.t_s - (self._t_last_reading_s if self._t_last_reading_s is not None else -np.inf)
        hopeless = self.grid.spread_m() > self.recovery.stop_spread_m and silent_s > self.recovery.stop_silence_s
        return TrackerOutput("Searching" if hopeless else "Lost", None, xy.copy(), cov.copy(), out.tracks,
                             stop_robot=hopeless, goal_xy_world_m=xy.copy())
