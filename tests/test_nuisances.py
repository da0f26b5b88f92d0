"""The simulator's nuisance zoo and the corridor and cross layouts."""

import numpy as np
import pytest

from pedcal.calib.common import interpolate_pose2
from pedcal.sim import simulate_logs
from pedcal.sim.nuisances import draw_nuisances, head_point, vary
from pedcal.sim.robot import amcl_table
from pedcal.sim.scenario import Scenario, load_scenario

TOP = np.array([[0.0, 0.0, 1.35]])


def _seen_from(elev_deg, dist=2.0):
    e = np.radians(elev_deg)
    return np.array([[dist * np.cos(e), 0.0, 1.35 + dist * np.sin(e)]])


def test_head_point_models_move_the_point_as_documented():
    sc = Scenario()
    top = sc.resolve(head_point="top", head_vertical_bias_m=0.02)
    np.testing.assert_allclose(head_point(TOP, _seen_from(45), top), TOP + [0, 0, 0.02])
    dome = sc.resolve(head_point="dome", head_radius_m=0.1)
    d = head_point(TOP, _seen_from(45, dist=1e5), dome)[0] - TOP[0]      # far: the same elevation from the centre
    np.testing.assert_allclose(d, [0.1 * np.cos(np.pi / 4), 0.0, -0.1 * (1 - np.sin(np.pi / 4))], atol=1e-6)
    shift = sc.resolve(head_point="shift", head_shift_m=0.04)
    np.testing.assert_allclose(head_point(TOP, _seen_from(30), shift)[0] - TOP[0], [0.04, 0.0, 0.0], atol=1e-12)
    cen = sc.resolve(head_point="centroid")
    below = head_point(TOP, _seen_from(90), cen)[0] - TOP[0]
    # straight down: the centroid of a 0.1 m hemisphere's surface is half its radius down
    assert below[0] == pytest.approx(0.0, abs=1e-3) and below[2] == pytest.approx(-0.05, abs=2e-3)
    oblique = head_point(TOP, _seen_from(20), cen)[0] - TOP[0]
    assert oblique[0] > 0.02 and -0.06 < oblique[2] < -0.02      # toward the sensor, and down


def test_vary_nuisances_is_seeded_and_draws_every_alternative():
    base = load_scenario("paper")
    draws = [vary(base.resolve(seed=s)) for s in range(40)]
    assert vary(base.resolve(seed=3)) == draws[3]
    assert {d.head_point for d in draws} == {"top", "dome", "shift", "centroid"}
    assert {d.amcl_error for d in draws} == {"white", "correlated", "jumps"}
    assert {d.depth_noise_model for d in draws} == {"linear", "quadratic"}
    assert {d.odometry for d in draws} == {True, False}
    lat = [d.latency_s for d in draws]
    assert 0.0 <= min(lat) and max(lat) <= 0.3 and np.std(lat) > 0.05
    bias = [d.head_vertical_bias_m for d in draws]
    assert max(np.abs(bias)) <= 0.03
    # the layout and the installed extrinsics are the seed's, whatever the draw
    assert all(draws[k].pitch_deg == base.pitch_deg for k in range(5))
    assert set(draw_nuisances(np.random.default_rng(0))) <= set(Scenario.field_names())


def test_amcl_error_models():
    sc = Scenario(amcl_sigma_m=0.05)
    t = np.arange(0.0, 600.0, 0.05)
    truth = dict(t=t, x=0.01 * t, y=np.zeros_like(t), yaw=np.zeros_like(t))
    import pandas as pd

    truth = pd.DataFrame(truth)
    lag1 = {}
    for kind in ("white", "correlated", "jumps"):
        amcl = amcl_table(truth, sc.resolve(amcl_error=kind, amcl_jump_rate_hz=1 / 60.0), np.random.default_rng(1))
        e = amcl["x"].to_numpy() - interpolate_pose2(truth, amcl["t"].to_numpy())[:, 0]
        lag1[kind] = np.corrcoef(e[:-1], e[1:])[0, 1]
        if kind == "jumps":
            assert np.max(np.abs(np.diff(e))) > 0.25
    assert abs(lag1["white"]) < 0.1 and lag1["correlated"] > 0.95


def test_corridor_layout_and_route():
    sim = simulate_logs("corridor", seed=0, duration_s=120.0)
    net = sim.calib.truth
    assert len(net) == 16
    y = np.array([s.position_m[1] for s in net])
    assert np.all((np.abs(y - 0.1) < 0.25) | (np.abs(y - 2.3) < 0.25))
    sides = np.abs(y - 0.1) < 0.25
    assert np.all(sides[::2] != sides[1::2])                 # alternating walls
    for s in net:                                            # looking across, into the corridor
        look = s.R_world_sensor[:, 0]
        assert look[1] * (1.2 - s.position_m[1]) > 0
    pose = sim.calib.truth_robot
    assert pose["y"].between(0.3, 2.1).all() and pose["x"].between(0.2, 19.8).all()
    seen = sim.calib.observations.loc[sim.calib.truth_observations["who"].to_numpy() == "robot", "sensor"]
    assert seen.nunique() >= 4


def test_cross_layout_keeps_sensors_out_of_the_crossing_and_the_robot_in_the_corridors():
    sim = simulate_logs("cross", seed=0)
    net = sim.calib.truth
    assert len(net) == 16
    xy = np.array([s.position_m[:2] for s in net])
    in_x = np.abs(xy[:, 1] - 7.0) < 1.3
    in_y = np.abs(xy[:, 0] - 7.0) < 1.3
    assert np.all(in_x ^ in_y)                              # on one corridor's walls, not the crossing
    assert in_x.sum() == 8
    p = sim.calib.truth_robot[["x", "y"]].to_numpy()
    inside = (np.abs(p[:, 1] - 7.0) < 1.2) | (np.abs(p[:, 0] - 7.0) < 1.2)
    assert inside.mean() > 0.99
    who = sim.calib.truth_observations["who"].to_numpy()
    assert sim.calib.observations.loc[who == "robot", "sensor"].nunique() == 16


def test_absent_odometry_and_linear_depth_noise():
    sim = simulate_logs("paper", seed=1, duration_s=60.0, odometry=False, depth_noise_model="linear")
    assert sim.calib.odometry is None
    with pytest.raises(Exception, match="expected one of"):
        simulate_logs("paper", seed=1, head_point="ellipsoid")
