import gtsam
import numpy as np
import pytest

from pedcal import frames


def test_positive_pitch_looks_down():
    R = frames.rot_from_ypr_deg([0.0, 45.0, 0.0])
    optical_axis_world = R @ np.array([1.0, 0.0, 0.0])
    assert optical_axis_world[2] == pytest.approx(-np.sqrt(0.5))
    assert optical_axis_world[0] == pytest.approx(np.sqrt(0.5))


def test_matches_gtsam_ypr():
    rng = np.random.default_rng(1)
    for _ in range(20):
        ypr = rng.uniform([-180, -80, -180], [180, 80, 180])
        R = frames.rot_from_ypr_deg(ypr)
        R_gtsam = gtsam.Rot3.Ypr(*np.radians(ypr)).matrix()
        np.testing.assert_allclose(R, R_gtsam, atol=1e-12)
        np.testing.assert_allclose(frames.ypr_deg_from_rot(R), ypr, atol=1e-9)


def test_world_sensor_round_trip():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(50, 3))
    pos, ypr = [1.0, 2.0, 2.6], [90.0, 45.0, 3.0]
    back = frames.sensor_from_world(frames.world_from_sensor(p, pos, ypr), pos, ypr)
    np.testing.assert_allclose(back, p, atol=1e-12)
    T = frames.pose3(pos, ypr)
    np.testing.assert_allclose(T.transformFrom(p[0]), frames.world_from_sensor(p[:1], pos, ypr)[0])


def test_wrap_and_rotation_angle():
    assert frames.wrap_angle_rad(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    Ra = frames.rot_from_ypr_deg([10, 20, 30])
    Rb = Ra @ frames.rot_from_ypr_deg([0, 0, 7])
    assert frames.rotation_angle_deg(Ra, Rb) == pytest.approx(7.0)
