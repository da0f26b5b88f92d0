"""Constant-velocity filter algebra against hand-computed values, the bearing EKF's Jacobian against
numerical differences, and the entropy rules of filter management (eqs. 2, 5, 6, 7-8)."""

import numpy as np
import pytest

from pedcal.track.kalman import (
    CVTrack,
    area_m2,
    bearing_h,
    bearing_jacobian,
    cv_process_noise,
    detection_world,
    mahalanobis,
    predict,
    renyi2_entropy_mm,
    update_bearing,
    update_position,
)

# Per axis: position variance 4, velocity variance 3, covariance 2.
P_AXIS = np.array([[4.0, 0, 2, 0], [0, 4, 0, 2], [2, 0, 3, 0], [0, 2, 0, 3]])


def test_predict_one_step_by_hand():
    x = np.array([1.0, 2.0, 0.5, -1.0])
    x1, P1 = predict(x, P_AXIS, 0.5, sigma_accel_mps2=2.0)
    np.testing.assert_allclose(x1, [1.25, 1.5, 0.5, -1.0])
    # F P F^T per axis with F = [[1, .5], [0, 1]]: [[4 + 2*.5*2 + .25*3, 2 + .5*3], [., 3]] = [[6.75, 3.5], [3.5, 3]]
    # Q per axis, sigma_a^2 = 4: [[.5^4/4, .5^3/2], [., .5^2]] * 4 = [[.0625, .25], [.25, 1]]
    np.testing.assert_allclose(P1[np.ix_([0, 2], [0, 2])], [[6.8125, 3.75], [3.75, 4.0]])
    np.testing.assert_allclose(P1[np.ix_([1, 3], [1, 3])], [[6.8125, 3.75], [3.75, 4.0]])
    assert P1[0, 1] == 0.0 and P1[0, 3] == 0.0
    np.testing.assert_allclose(cv_process_noise(0.5, 2.0)[0, 0], 0.0625)


def test_update_one_step_by_hand():
    x = np.array([1.0, 2.0, 0.5, -1.0])
    x1, P1 = update_position(x, P_AXIS, np.array([2.0, 1.0]), np.eye(2))
    # S = 4 + 1 = 5, K per axis = (4/5, 2/5); innovations (+1, -1).
    np.testing.assert_allclose(x1, [1.8, 1.2, 0.9, -1.4])
    np.testing.assert_allclose(P1[np.ix_([0, 2], [0, 2])], [[0.8, 0.4], [0.4, 2.2]])
    np.testing.assert_allclose(P1, P1.T)


def test_mahalanobis_by_hand():
    x = np.array([0.0, 0.0, 0.0, 0.0])
    P = np.diag([3.0, 1.0, 1.0, 1.0])
    d = mahalanobis(x, P, np.array([[2.0, 0.0], [0.0, 2.0]]), np.eye(2))
    np.testing.assert_allclose(d, [1.0, np.sqrt(2.0)])  # S = diag(4, 2)


def test_detection_to_world_adds_pose_uncertainty():
    pose = np.array([1.0, 2.0, np.pi / 2])
    cov = np.diag([0.02, 0.03, 0.01])
    z, R = detection_world(np.array([1.0, 0.0]), pose, cov, sigma_lidar_m=0.05)
    np.testing.assert_allclose(z, [1.0, 3.0], atol=1e-12)
    # d z / d yaw = R(yaw) (-y, x) = R(90 deg) (0, 1) = (-1, 0): the yaw variance lands on world x.
    np.testing.assert_allclose(R, np.diag([0.0025 + 0.02 + 0.01, 0.0025 + 0.03]), atol=1e-12)


def test_bearing_jacobian_matches_numerical_differences():
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = np.r_[rng.uniform(-4, 4, 2), rng.normal(size=2)]
        ant = rng.uniform(-1, 1, 2)
        yaw = rng.uniform(-3, 3)
        J = bearing_jacobian(x, ant)
        h = 1e-6
        num = [(bearing_h(x + h * e, ant, yaw) - bearing_h(x - h * e, ant, yaw)) / (2 * h) for e in np.eye(4)]
        np.testing.assert_allclose(J, num, atol=1e-6)


def test_bearing_update_pulls_towards_the_bearing_and_gates_multipath():
    # Target believed at (3, 0.5) with 0.5 m sigma; the antenna at the origin says bearing 0.
    x = np.array([3.0, 0.5, 0.0, 0.0])
    P = np.diag([0.25, 0.25, 0.1, 0.1])
    x1, P1, ok = update_bearing(x, P, 0.0, np.zeros(2), 0.0, sigma_rad=np.radians(20.0))
    assert ok
    assert 0.0 < x1[1] < 0.5  # moved towards the x axis
    assert P1[1, 1] < P[1, 1] and P1[0, 0] == pytest.approx(P[0, 0], rel=0.1)  # range barely informed
    x2, P2, ok2 = update_bearing(x, P, np.pi, np.zeros(2), 0.0, sigma_rad=np.radians(20.0))
    assert not ok2 and x2 is x and P2 is P


def test_new_filter_is_confirmed_by_its_second_detection():
    R = 0.05 ** 2 * np.eye(2)
    tr = CVTrack.from_detection(0, np.zeros(2), R, 0.0)
    assert not tr.manage()
    assert not tr.confirmed
    tr.predict(0.25)
    ref = tr.area_ref_m2
    tr.update(np.array([0.02, 0.0]), R)
    assert not tr.manage()
    assert tr.area_m2 <= 0.5 * ref and tr.confirmed


def test_tentative_filter_missed_once_is_deleted():
    tr = CVTrack.from_detection(0, np.zeros(2), 0.05 ** 2 * np.eye(2), 0.0)
    tr.manage()
    tr.predict(0.25)  # no detection: the unknown velocity spreads it over ~0.25 m
    assert tr.manage()
    assert not tr.confirmed


def test_confirmed_filter_is_deleted_when_its_entropy_rises_20_percent_above_its_minimum():
    R = 0.05 ** 2 * np.eye(2)
    tr = CVTrack.from_detection(0, np.zeros(2), R, 0.0)
    tr.manage()
    for k in range(1, 20):
        tr.predict(0.25 * k)
        tr.update(np.array([0.1 * 0.25 * k, 0.0]), R)
        assert not tr.manage()
    h_min = tr.entropy_min
    deleted_at = None
    for k in range(20, 40):
        tr.predict(0.25 * k)
        h = renyi2_entropy_mm(tr.P)
        if tr.manage():
            deleted_at = k
            break
        assert h <= 1.2 * h_min
    assert deleted_at is not None and deleted_at > 20  # survives one missed frame
    assert renyi2_entropy_mm(tr.P) > 1.2 * h_min
    # On the area scale that is a growth of exp(0.2 H_min) over the minimum.
    assert area_m2(tr.P) > np.exp(h_min) / (4e6 * np.pi) * np.exp(0.2 * h_min)


def test_batched_detections_and_distances_match_the_single_ones():
    from pedcal.track.kalman import detections_world, mahalanobis_matrix

    rng = np.random.default_rng(1)
    pose, cov = np.array([0.5, -1.0, 2.0]), np.diag([0.01, 0.02, 0.003])
    xy = rng.uniform(-4, 4, (5, 2))
    z, R = detections_world(xy, pose, cov)
    for j in range(5):
        zj, Rj = detection_world(xy[j], pose, cov)
        np.testing.assert_allclose(z[j], zj)
        np.testing.assert_allclose(R[j], Rj)
    X = np.c_[rng.uniform(-4, 4, (3, 2)), np.zeros((3, 2))]
    Ps = np.stack([P_AXIS * s for s in (0.1, 0.5, 1.0)])
    D = mahalanobis_matrix(X, Ps, z, R)
    for t in range(3):
        np.testing.assert_allclose(D[t], [mahalanobis(X[t], Ps[t], z[j], R[j])[0] for j in range(5)])
