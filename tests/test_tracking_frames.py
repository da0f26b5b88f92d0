"""The trackers' and the recovery's frame handling checked against hand computations, with the robot
away from the origin and turned (an antenna mount not rotated by the robot's yaw, or a world point
not moved into the robot frame, shows here), several antenna readings in one frame, and an
anisotropic recovery prior."""

import numpy as np
import pytest

from pedcal.follow_types import EsparReading, FollowFrame
from pedcal.track.kalman import CVTrack, update_bearing
from pedcal.track.recovery import SmootherConfig, TargetSmoother, recovery_prior_cov
from pedcal.track.tracker import PaperTracker

POSE = np.array([2.0, -1.0, 0.9])          # x_m, y_m, yaw_rad: away from the origin, turned 52 deg
COV = np.diag([1e-4, 1e-4, 1e-5])
MOUNTS = (np.array([0.3, 0.6]), np.array([-0.2, -0.5]))   # antennas well off the robot's centre


def rot(yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def reading(antenna: int, bearing_robot_rad: float) -> EsparReading:
    k = int(np.rint(bearing_robot_rad / (np.pi / 6))) % 12
    return EsparReading(antenna, k, float(bearing_robot_rad), MOUNTS[antenna])


def test_p_z_lost_is_one_twelfth_to_the_power_of_the_readings_in_the_frame():
    trk = PaperTracker()
    target_world = np.array([4.0, 1.5])
    trk.core.tracks[0] = CVTrack.from_detection(0, target_world, 0.01 * np.eye(2), 0.0)
    trk.prob.p, trk.prob.p_lost = {0: 0.4}, 0.6
    readings = (reading(0, 0.3), reading(1, -0.2), reading(0, 0.5))     # three readings in one frame
    trk._probability_update(FollowFrame(0.0, POSE, COV, (), readings, False))
    # by hand: the target in the robot frame, its bearing from each antenna, P(Z | A) of each reading
    xy_robot = rot(POSE[2]).T @ (target_world - POSE[:2])
    lik = 1.0
    for r in readings:
        d = xy_robot - r.xy_antenna_robot_m
        lik *= trk.config.espar.p_direction(np.array(r.bearing_robot_rad - np.arctan2(d[1], d[0])))
    p_lost_z = (1.0 / 12.0) ** 3
    expected = lik * 0.4 / (lik * 0.4 + p_lost_z * 0.6)
    assert trk.prob.p[0] == pytest.approx(float(expected), rel=1e-9)
    assert trk.prob.p_lost == pytest.approx(1.0 - float(expected), rel=1e-9)
    assert trk.n_readings == 3


def test_bearing_ekf_update_equals_the_hand_computation():
    x = np.array([3.0, 0.5, 0.2, -0.1])
    A = np.array([[0.3, 0.05, 0.02, 0.0], [0.05, 0.2, 0.0, 0.01], [0.02, 0.0, 0.4, 0.03], [0.0, 0.01, 0.03, 0.5]])
    P = A @ A.T + 0.05 * np.eye(4)
    ant, yaw, sigma, var_yaw, z = np.array([1.0, -0.5]), 0.3, 0.35, 0.01, 0.25
    x1, P1, ok = update_bearing(x, P, z, ant, yaw, sigma, var_yaw, gate=10.0)
    dx, dy = x[0] - ant[0], x[1] - ant[1]
    r2 = dx * dx + dy * dy
    H = np.array([-dy / r2, dx / r2, 0.0, 0.0])
    S = H @ P @ H + sigma ** 2 + var_yaw          # eq. 6: antenna noise and the robot's yaw variance
    K = P @ H / S
    nu = z - (np.arctan2(dy, dx) - yaw)
    assert ok
    np.testing.assert_allclose(x1, x + K * nu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(P1, P - np.outer(P @ H, P @ H) / S, rtol=0, atol=1e-12)


def test_paper_tracker_bearing_update_uses_the_antenna_mount_turned_by_the_robots_yaw():
    trk = PaperTracker()
    tr = CVTrack.from_detection(0, np.array([4.0, 1.5]), 0.3 * np.eye(2), 0.0)
    trk.core.tracks[0] = tr
    trk.core.target_id = 0
    tr.detected = False          # the target filter coasts: the antenna's bearing updates it (eq. 6)
    x0, P0 = tr.x.copy(), tr.P.copy()
    r = reading(0, 0.2)
    trk._espar_bearing_updates(FollowFrame(0.0, POSE, COV, (), (r,), False))
    ant_world = POSE[:2] + rot(POSE[2]) @ MOUNTS[0]
    x_exp, P_exp, _ = update_bearing(x0, P0, r.bearing_robot_rad, ant_world, POSE[2], trk.config.espar.sigma_rad,
                                     COV[2, 2], trk.config.bearing_gate)
    np.testing.assert_allclose(tr.x, x_exp, atol=1e-12)
    np.testing.assert_allclose(tr.P, P_exp, atol=1e-12)


def test_smoother_triangulates_from_a_turned_robot_with_offset_antennas():
    """Exact bearings from two antennas 0.6 m off the centre of a robot driving along its heading
    (52 deg) from (2, -1): the smoother lands on the static target; an unrotated mount would put each
    bearing's origin up to 0.5 m off and the estimate with it."""
    heading = np.array([np.cos(POSE[2]), np.sin(POSE[2])])
    target = POSE[:2] + 1.5 * heading + 3.0 * np.array([-heading[1], heading[0]])   # 3 m to the left
    smoother = TargetSmoother(SmootherConfig(walk_speed_mps=0.05))
    for k in range(1, 25):
        pose = np.r_[POSE[:2] + 0.12 * k * heading, POSE[2]]
        rs = []
        for a, mount in enumerate(MOUNTS):
            d = rot(pose[2]).T @ (target - pose[:2]) - mount
            rs.append(EsparReading(a, 0, float(np.arctan2(d[1], d[0])), mount))
        seed = None if smoother.started else pose[:2] + 2.0 * np.array(
            [np.cos(pose[2] + rs[0].bearing_robot_rad), np.sin(pose[2] + rs[0].bearing_robot_rad)])
        smoother.add_frame(0.25 * k, pose, COV, espar=tuple(rs), seed_xy_world_m=seed, seed_sigma_m=3.0)
    assert np.linalg.norm(smoother.latest()[0] - target) < 0.1


def test_recovery_prior_keeps_an_anisotropic_covariance():
    # the last filter was long along 30 deg (1 m) and narrow across it (0.1 m)
    U = rot(np.radians(30.0))
    cov_last = U @ np.diag([1.0, 0.01]) @ U.T
    cov0 = recovery_prior_cov(cov_last, 0.5)
    np.testing.assert_allclose(cov0, U @ np.diag([1.0, 0.25]) @ U.T, atol=1e-12)
    # the smoother's first marginal is that prior, its axes and all
    smoother = TargetSmoother()
    smoother.add_frame(0.0, POSE, COV, seed_xy_world_m=np.array([4.0, 1.5]), seed_sigma_m=1.0, seed_cov_world=cov0)
    xy, cov = smoother.latest()
    np.testing.assert_allclose(xy, [4.0, 1.5], atol=1e-9)
    np.testing.assert_allclose(cov, cov0, atol=1e-6)


def test_grid_belief_starts_from_an_anisotropic_prior():
    from pedcal.track.grid_belief import GridBelief

    U = rot(np.radians(-40.0))
    cov0 = U @ np.diag([1.2 ** 2, 0.4 ** 2]) @ U.T
    g = GridBelief(None, (1.0, 2.0))
    g.reset_gaussian((1.0, 2.0), cov_world=cov0)
    xy, cov, _ = g.estimate(component_radius_m=6.0)
    np.testing.assert_allclose(xy, [1.0, 2.0], atol=g.config.resolution_m)
    np.testing.assert_allclose(cov, cov0, atol=0.03)


def test_searching_paper_tracker_faces_the_antennas_bearing_and_the_robot_turns_in_place():
    from pedcal.sim.follow import RobotController

    trk = PaperTracker()
    trk.state, trk.lost_since_s = "Searching", 0.0
    yaw = POSE[2]
    # readings towards the robot's back left (150 deg in the robot frame), one of them multipath
    rs = (reading(0, np.radians(150.0)), reading(1, np.radians(150.0)), reading(0, np.radians(-60.0)),
          reading(1, np.radians(150.0)))
    out = trk.step(FollowFrame(0.0, POSE, COV, (), rs, True))
    assert out.stop_robot and out.goal_xy_world_m is None
    b = yaw + np.radians([150.0, 150.0, -60.0, 150.0])
    assert out.face_world_rad == pytest.approx(float(np.arctan2(np.sin(b).sum(), np.cos(b).sum())))
    ctrl = RobotController()
    v, w = ctrl.command(POSE, out)
    assert v == 0.0 and w == pytest.approx(ctrl.w_max_radps)          # turns left, does not drive
    facing = np.array([POSE[0], POSE[1], out.face_world_rad])
    assert ctrl.command(facing, out) == (0.0, 0.0)                    # faced: stands still for the grid


def test_confirmed_filters_take_their_detections_before_tentative_ones():
    from pedcal.follow_types import PersonDetection
    from pedcal.track.tracker import MultiPersonCore, TrackerConfig

    core = MultiPersonCore(TrackerConfig())
    R = 0.05 ** 2 * np.eye(2)
    old = CVTrack.from_detection(0, np.array([3.0, 0.0]), R, 0.0)
    old.confirmed, old.P = True, np.diag([0.04, 0.04, 0.1, 0.1])
    new = CVTrack.from_detection(1, np.array([3.3, 0.0]), R, 0.0)   # born last frame beside it
    core.tracks, core.next_id = {0: old, 1: new}, 2
    det = PersonDetection(np.array([3.28, 0.0]), 1.7, 0.9, np.full(8, 1 / 8))   # nearer the newcomer
    res = core.step(FollowFrame(0.0, np.zeros(3), COV, (det,), (), False))
    assert core.tracks[0].detected and not core.tracks[1].detected and res.detected_ids == {0}


def _core_with_target(radius_m: float):
    from pedcal.track.tracker import MultiPersonCore, TrackerConfig

    core = MultiPersonCore(TrackerConfig(maneuver_radius_m=radius_m))
    tr = CVTrack.from_detection(0, np.array([4.0, 1.0]), 0.05 ** 2 * np.eye(2), 0.0)
    tr.confirmed, tr.x[2:] = True, [0.8, 0.0]               # walking +x at 0.8 m/s
    tr.P = np.diag([0.03 ** 2, 0.03 ** 2, 0.05 ** 2, 0.05 ** 2])
    core.tracks, core.next_id = {0: tr}, 1
    core.set_target(0)
    return core


def _det_world(xy_world):
    from pedcal.follow_types import PersonDetection

    return PersonDetection(rot(POSE[2]).T @ (np.asarray(xy_world, float) - POSE[:2]), 1.7, 0.9, np.full(8, 1 / 8))


@pytest.mark.parametrize("radius_m, continued", [(0.6, True), (0.0, False)])
def test_a_turn_outside_the_gate_continues_the_target_filter_in_the_clear(radius_m, continued):
    # predicted at (4.2, 1.0); the target turned left: its detection is 0.4 m off, far outside 3 sigma
    core = _core_with_target(radius_m)
    res = core.step(FollowFrame(0.25, POSE, COV, (_det_world([4.1, 1.39]),), (), False))
    assert core.tracks[0].detected == continued
    assert (res.detected_ids == {0}) == continued               # otherwise a new filter starts there
    if continued:
        assert np.linalg.norm(core.tracks[0].xy - [4.1, 1.39]) < 0.1


def test_a_turn_among_other_people_is_not_continued():
    core = _core_with_target(0.6)
    # somebody else stands 0.7 m from the leftover detection: it may as well be a passer-by
    core.step(FollowFrame(0.25, POSE, COV, (_det_world([4.1, 1.39]), _det_world([4.5, 1.96])), (), False))
    assert not core.tracks[0].detected
