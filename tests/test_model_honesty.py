"""The calibration's honesty about its own model: the sigma widened by the model check, the
check's variance ratio, the head-point profile away from its prior, AMCL's jumps found."""

import copy
import dataclasses
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import pedcal.calib.factorgraph as factorgraph
from pedcal.calib import calibrate
from pedcal.calib.amcl_model import detect_jumps
from pedcal.calib.factorgraph import _estimate_nuisances, model_check
from pedcal.calib.graph import GraphRecipe, observation_block, optimize_graph
from pedcal.sim import simulate_logs
from pedcal.sim.robot import ou_process
from tests.test_profile import solved_graph


@pytest.fixture(scope="module")
def misfit_pair():
    """A log whose sensors' clocks are off by up to 0.15 s each (the robot is seen where it was
    up to 45 mm earlier or later), calibrated by a graph told to keep one shared latency (a misfit
    it cannot absorb) twice: as it is, and with the model check's variance ratios forced to 1
    (the sigma before widening)."""
    sim = simulate_logs("paper", seed=2, duration_s=150.0, clock_offset_s=0.15)
    rec = GraphRecipe.load("default")
    rec.clock_offsets = False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        widened = calibrate(sim.calib, method="factorgraph", graph=rec)
        original = factorgraph.model_check

        def unwidened_check(prob, result, threshold=1.5):
            check = original(prob, result, threshold)
            return dataclasses.replace(check, variance_ratio={k: 1.0 for k in check.variance_ratio})

        factorgraph.model_check = unwidened_check
        try:
            plain = calibrate(sim.calib, method="factorgraph", graph=rec)
        finally:
            factorgraph.model_check = original
    return widened, plain


def test_widened_sigma_is_the_plain_sigma_times_the_root_of_the_variance_ratio(misfit_pair):
    widened, plain = misfit_pair
    ratio = widened.diagnostics.model_mismatch.variance_ratio
    assert max(ratio.values()) > 1.5, "the log is meant not to fit"
    checked = 0
    for s in widened.network:
        if s.status != "ok" or s.id not in ratio:
            continue
        p = plain.network[s.id]
        np.testing.assert_allclose(s.position_m, p.position_m, atol=1e-9)       # the same solution
        np.testing.assert_allclose(np.asarray(s.sigma_position_m) / np.asarray(p.sigma_position_m),
                                   np.sqrt(max(1.0, ratio[s.id])), rtol=1e-6)
        checked += 1
    assert checked >= 5


def test_joint_covariance_diagonal_is_the_widened_per_sensor_sigma(misfit_pair):
    widened, plain = misfit_pair
    ids = [s.id for s in widened.network]
    for res in (widened, plain):
        C = res.position_covariance_m2
        assert C.shape == (3 * len(ids), 3 * len(ids))
        sigma = np.sqrt(np.diag(C)).reshape(-1, 3)
        for k, sid in enumerate(ids):
            if res.network[sid].status == "ok":
                np.testing.assert_allclose(sigma[k], res.network[sid].sigma_position_m, rtol=1e-6)
    # and it is widened: not the plain one where a sensor's ratio exceeds 1
    assert np.any(np.diag(widened.position_covariance_m2) > 1.5 * np.diag(plain.position_covariance_m2))


# ------------------------------------------------------------------------------------ model check
def _fake_problem(n_sensors: int, rows_per_sensor: int):
    sensor_index = np.repeat(np.arange(n_sensors), rows_per_sensor)
    return SimpleNamespace(recipe=SimpleNamespace(robot=True), pose_times=np.zeros(len(sensor_index) + 1),
                           fac_key_index=np.arange(len(sensor_index)), fac_sensor_index=sensor_index,
                           sensor_ids=[f"s{i + 1:02d}" for i in range(n_sensors)])


@pytest.mark.parametrize("sigma_scale, expected", [(1.0, 1.0), (2.0, 4.0)])
def test_model_check_variance_ratio_of_residuals_of_known_variance(monkeypatch, sigma_scale, expected):
    rng = np.random.default_rng(7)
    prob = _fake_problem(4, 3000)
    z = sigma_scale * rng.standard_normal((4 * 3000, 3))
    monkeypatch.setattr(factorgraph, "robot_residuals", lambda prob, result: z)
    check = model_check(prob, None)
    # the median of 3000 chi-square(1) draws is within ~4 % of its own: 10 % is a wide margin
    for sid in prob.sensor_ids:
        assert check.variance_ratio[sid] == pytest.approx(expected, rel=0.1)
    assert (check.sensors == prob.sensor_ids) == (expected > 1.5)


def test_model_check_ratio_follows_one_sensor_and_skips_the_thinly_seen(monkeypatch):
    rng = np.random.default_rng(8)
    prob = _fake_problem(3, 2000)
    z = rng.standard_normal((6000, 3))
    z[2000:4000] *= 3.0                                 # the second sensor 3x noisier
    prob.fac_sensor_index = prob.fac_sensor_index.copy()
    prob.fac_sensor_index[4000:5995] = 0                # the third keeps 5 rows: too few to judge
    monkeypatch.setattr(factorgraph, "robot_residuals", lambda prob, result: z)
    check = model_check(prob, None)
    assert set(check.variance_ratio) == {"s01", "s02"}
    assert check.variance_ratio["s02"] == pytest.approx(9.0, rel=0.1)
    assert check.sensors == ["s02"]


# ------------------------------------------------------------------------------------ profile
@pytest.fixture(scope="module")
def shifted_paper():
    """Paper seed 3 with the head point shifted 5 cm toward the sensor, a recipe whose priors on
    the shifts are tight (4 mm: the prior weighs as much as the data, so its gradient away from
    its mean matters), the graph solved at the prior mean."""
    sim = simulate_logs("paper", seed=3, head_point="shift", head_shift_m=0.05, duration_s=200.0)
    rec = GraphRecipe.load("default")
    rec.estimate_amcl_model = False
    rec.head_ray_shift_sigma_m = rec.head_horizontal_shift_sigma_m = 0.004
    rec.clock_offsets = False                     # the head point's shifts alone
    rec.head_shift_per_sensor_sigma_m = 0.0       # (no sensor's own departure either)
    return (sim, *solved_graph(sim.calib, rec))


def test_profile_step_from_away_from_the_prior_mean_matches_the_nonlinear_profile(shifted_paper):
    # the profile's steps from shifts 3 prior sigma away from the prior mean end on the minimum of
    # the nonlinear profile (the graph re-solved by Levenberg-Marquardt at fixed shifts, plus the
    # shifts' prior), and their Hessian is the profile's curvature: a quadratic through six
    # re-solved points around where they end puts the minimum within a quarter sigma of it.
    # (A single step from there lands 1-3 sigma short: the profile is not quadratic that far.)
    sim, prob, parts, result = shifted_paper
    prob = copy.deepcopy(prob)
    parts = copy.copy(parts)
    parts.blocks = dict(parts.blocks)
    rec = prob.recipe
    mean = np.array([rec.head_radius_m, 0.0])
    prior_sigma = np.array([rec.head_ray_shift_sigma_m, rec.head_horizontal_shift_sigma_m])
    prob.ray_shift_m, prob.horizontal_shift_m = mean + np.array([3.0, -3.0]) * prior_sigma
    parts.blocks["observations"] = observation_block(sim.calib, prob, result)
    shifts = _estimate_nuisances(sim.calib, prob, parts, result, max_steps=8, tolerance=0.01, curvature=False,
                                 odometry=False)
    assert 1 < shifts.solves < 8
    assert shifts.names == ["ray_shift_m", "horizontal_shift_m"]
    landed = np.array([prob.ray_shift_m, prob.horizontal_shift_m])
    sigma = np.sqrt(np.diag(shifts.cov))

    def profile(th):
        obs = observation_block(sim.calib, prob, shifts.result,
                                theta={"ray_shift_m": th[0], "horizontal_shift_m": th[1]})
        fg = parts.graph(observations=obs)
        solved, _ = optimize_graph(fg, shifts.result, rec)
        return fg.error(solved) + 0.5 * np.sum(((th - mean) / prior_sigma) ** 2)

    D = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [1, 1]], float)
    f = np.array([profile(landed + d * sigma) for d in D])
    # f = c + g.d + 0.5 d'Ad in units of sigma: six points, six coefficients
    X = np.column_stack([np.ones(6), D, 0.5 * D[:, 0] ** 2, D[:, 0] * D[:, 1], 0.5 * D[:, 1] ** 2])
    c, g0, g1, a00, a01, a11 = np.linalg.solve(X, f)
    A = np.array([[a00, a01], [a01, a11]])
    minimum = -np.linalg.solve(A, [g0, g1])
    assert np.all(np.abs(minimum) < 0.25), minimum
    # the step's Hessian in the same units is the profile's curvature
    H_sigma = shifts.cov.copy()
    H_sigma = np.linalg.inv(H_sigma) * np.outer(sigma, sigma)
    np.testing.assert_allclose(A, H_sigma, atol=0.2)


# ------------------------------------------------------------------------------------ AMCL jumps
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_single_ten_second_amcl_jump_is_flagged_with_the_default_window(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 300.0, 0.2)                        # AMCL at 5 Hz, a 5 min run
    e = np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    e += rng.normal(0.0, 0.01, e.shape)
    t_jump = rng.uniform(50.0, 240.0)
    on = (t >= t_jump) & (t < t_jump + 10.0)
    e[on] += 0.4 * np.array([np.cos(seed), np.sin(seed)])
    flagged = detect_jumps(t, e)
    assert flagged[on].mean() > 0.9
    assert flagged[~on].mean() < 0.02
