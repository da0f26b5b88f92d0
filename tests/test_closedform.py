"""Closed-form (Horn/Umeyama) baseline: exact recovery, degenerate and empty sensors, bad input."""

import warnings

import numpy as np
import pandas as pd
import pytest
from test_association import make_log

from pedcal.calib import calibrate
from pedcal.calib.closedform import calibrate_closedform, fit_rigid
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.frames import rot_from_ypr_deg, rotation_angle_deg


def _errors(network, truth):
    pos_mm = {s.id: 1000 * np.linalg.norm(network[s.id].position_m - s.position_m) for s in truth}
    ang_deg = {s.id: rotation_angle_deg(network[s.id].R_world_sensor, s.R_world_sensor) for s in truth}
    return pos_mm, ang_deg


def test_fit_rigid_recovers_a_known_transform():
    rng = np.random.default_rng(1)
    R_true = rot_from_ypr_deg([130.0, 50.0, -20.0])
    t_true = np.array([2.0, -1.0, 2.6])
    p = rng.uniform(-2, 2, (30, 3))
    R, t = fit_rigid(p, p @ R_true.T + t_true)
    np.testing.assert_allclose(R, R_true, atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-12)


def test_fit_rigid_planar_points_give_a_rotation_not_a_reflection():
    rng = np.random.default_rng(2)
    R_true = rot_from_ypr_deg([-60.0, 40.0, 10.0])
    p = np.column_stack([rng.uniform(-2, 2, (20, 2)), np.zeros(20)])   # all on a plane
    R, t = fit_rigid(p, p @ R_true.T + [1.0, 2.0, 3.0])
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R, R_true, atol=1e-12)


def test_fit_rigid_weights_ignore_a_zero_weight_outlier():
    rng = np.random.default_rng(3)
    R_true = rot_from_ypr_deg([10.0, 45.0, 0.0])
    p = rng.uniform(-2, 2, (12, 3))
    q = p @ R_true.T + [0.5, 0.5, 2.0]
    q[0] += [3.0, -2.0, 1.0]
    w = np.ones(12)
    w[0] = 0.0
    R, _ = fit_rigid(p, q, w)
    np.testing.assert_allclose(R, R_true, atol=1e-12)


def test_noise_free_true_association_recovers_truth():
    log, _ = make_log(noise=False, latency_s=0.1, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    is_robot = log.truth_observations["who"].to_numpy() == "robot"
    res = calibrate_closedform(log, is_robot=is_robot)
    assert res.method == "closedform"
    assert res.diagnostics.tracker_latency_s == pytest.approx(0.1, abs=1e-3)
    pos_mm, ang_deg = _errors(res.network, log.truth)
    assert max(pos_mm.values()) < 1.0
    assert max(ang_deg.values()) < 0.01
    assert all(s.status == "ok" for s in res.network)
    # every robot observation is a pair, but those stamped past the end of robot.csv
    assert sum(s.observations for s in res.network) + res.diagnostics.unpaired_robot_observations == \
        is_robot.sum()
    assert res.diagnostics.unpaired_robot_observations <= 3


def test_busy_log_through_the_dispatcher_with_association():
    log, _ = make_log()
    res = calibrate(log, method="closedform")
    pos_mm, ang_deg = _errors(res.network, log.truth)
    assert max(pos_mm.values()) < 60.0       # AMCL's few-cm correlated error is the floor
    assert max(ang_deg.values()) < 1.5
    assert res.is_robot is not None and res.is_robot.sum() > 1000


def test_straight_pass_is_degenerate_and_keeps_the_installed_pose():
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    is_robot = log.truth_observations["who"].to_numpy() == "robot"
    s0 = (log.observations["sensor"] == "s0").to_numpy()
    t_obs = log.observations["t"].to_numpy()
    # keep only s0's observations from one stretch of straight driving through the crossing
    straight = is_robot & s0 & (t_obs > 19.0) & (t_obs < 21.0)
    assert straight.sum() >= 10
    is_robot = is_robot & (~s0 | straight)
    with pytest.warns(DegenerateDataWarning, match="s0.*line"):
        res = calibrate_closedform(log, is_robot=is_robot)
    s = res.network["s0"]
    assert s.status == "degenerate" and "rotation about" in s.unobservable[0]
    np.testing.assert_allclose(s.position_m, log.sensors["s0"].position_m)
    np.testing.assert_allclose(s.ypr_deg, log.sensors["s0"].ypr_deg)
    assert res.network["s1"].status == "ok"


def test_too_few_pairs_is_no_data():
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    is_robot = log.truth_observations["who"].to_numpy() == "robot"
    s1_rows = np.flatnonzero(is_robot & (log.observations["sensor"] == "s1").to_numpy())
    is_robot[s1_rows[4:]] = False
    with warnings.catch_warnings():
        warnings.simplefilter("error", DegenerateDataWarning)
        res = calibrate_closedform(log, is_robot=is_robot)
    s1 = res.network["s1"]
    assert s1.status == "no-data" and s1.observations == 4
    np.testing.assert_allclose(s1.position_m, log.sensors["s1"].position_m)


def test_mask_of_wrong_length_is_an_input_error():
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    with pytest.raises(PedcalInputError, match="one entry per observation"):
        calibrate_closedform(log, is_robot=np.ones(5, bool))


@pytest.fixture(scope="module")
def paper_noise_free():
    from pedcal.sim import simulate_logs

    return simulate_logs("paper", seed=0, noise_free=True).calib


def test_noise_free_paper_scenario_association_and_closed_form_are_exact(paper_noise_free):
    from pedcal.calib.association import score_association

    log = paper_noise_free
    res = calibrate_closedform(log)
    score = score_association(log, res.is_robot)
    assert score["precision"] == 1.0 and score["recall"] == 1.0
    pos_mm, ang_deg = _errors(res.network, log.truth)
    assert max(pos_mm.values()) < 1.0
    assert max(ang_deg.values()) < 0.01
    assert abs(res.diagnostics.tracker_latency_s) < 1e-3


def test_paper_scenario_with_default_nuisances():
    from pedcal.calib.association import score_association
    from pedcal.metrics import evaluate
    from pedcal.sim import simulate_logs

    log = simulate_logs("paper", seed=0).calib
    res = calibrate_closedform(log)
    score = score_association(log, res.is_robot)
    assert score["precision"] >= 0.99 and score["recall"] >= 0.98
    assert res.diagnostics.tracker_latency_s == pytest.approx(0.1, abs=0.03)   # the scenario's tracker latency
    # AMCL's correlated error is the floor of a per-sensor fit; the installed poses are ~370 mm off
    assert evaluate(log, res.network).sensor_position_rms_mm.combined < 80.0


def test_every_sensor_fitted_at_once_equals_its_own_fit_and_ignores_unknown_sensors():
    # the batched fits (grouped by one sort) against fit_rigid on each sensor's own pairs, with a
    # sensor the network does not hold interleaved in the log and one sensor left without pairs
    from pedcal.calib.closedform import _fits

    rng = np.random.default_rng(3)
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    ids = [s.id for s in log.sensors]
    n = 400
    sensor = rng.choice(ids[:-1] + ["stranger"], size=n)
    p_sensor, p_world = rng.normal(0, 2, (n, 3)), rng.normal(0, 2, (n, 3))
    fits = _fits(log, *pd.factorize(sensor, use_na_sentinel=False), p_sensor, p_world)
    assert len(fits) == len(ids)
    for sid, (count, spread, direction, R, t, rms) in zip(ids, fits, strict=True):
        mine = sensor == sid
        assert count == mine.sum()
        if not count:
            assert sid == ids[-1] and np.all(np.isnan(R)) and rms == 0.0
            continue
        R_own, t_own = fit_rigid(p_sensor[mine], p_world[mine])
        np.testing.assert_allclose(R, R_own, atol=1e-12)
        np.testing.assert_allclose(t, t_own, atol=1e-12)
        evals, evecs = np.linalg.eigh(np.cov(p_world[mine].T))
        assert spread == pytest.approx(np.sqrt(evals[1]), rel=1e-12)
        assert abs(direction @ evecs[:, 2]) == pytest.approx(1.0, abs=1e-12)
        residual = np.linalg.norm(p_sensor[mine] @ R_own.T + t_own - p_world[mine], axis=1)
        assert rms == pytest.approx(np.sqrt(np.mean(residual ** 2)), rel=1e-12)
