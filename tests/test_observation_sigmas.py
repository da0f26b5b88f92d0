"""The depth sensors' noise model (pedcal.calib.recipe.observation_sigmas) and the range the
observation factors take it at (pedcal.calib.graph.observation_terms): the range as observed,
not as the head point's shifts move it."""

import warnings

import numpy as np
import pytest

from pedcal.calib.graph import build_parts, observation_terms
from pedcal.calib.problem import prepare
from pedcal.calib.recipe import GraphRecipe, observation_sigmas
from pedcal.errors import DegenerateDataWarning
from pedcal.sim import simulate_logs


def _recipe(**kw) -> GraphRecipe:
    rec = GraphRecipe.load("default")
    rec.range_sigma_floor_m, rec.range_sigma_k_per_m = 0.005, 1.5e-3
    rec.reliable_range_m, rec.far_factor, rec.lateral_sigma_m = 3.5, 2.0, 0.012
    for k, v in kw.items():
        setattr(rec, k, v)
    return rec


def test_range_sigma_is_floor_plus_k_r_squared_doubled_past_the_reliable_range():
    rec = _recipe()
    r = np.array([1.0, 2.0, 3.5, 3.6, 5.0])
    sig = observation_sigmas(rec, r)
    expected = 0.005 + 1.5e-3 * r ** 2
    expected[3:] *= 2.0                  # past 3.5 m; at 3.5 m exactly still within
    np.testing.assert_allclose(sig[:, 2], expected, rtol=0, atol=1e-15)
    # the bearing sigma: the lateral distance across the ray over the range, both axes alike
    np.testing.assert_allclose(sig[:, 0], 0.012 / r, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(sig[:, 0], sig[:, 1])


def test_bearing_sigma_is_held_below_0_3_m_and_a_scalar_range_is_one_row():
    rec = _recipe()
    sig = observation_sigmas(rec, np.array([0.0, 0.1, 0.3]))
    np.testing.assert_allclose(sig[:, 0], 0.012 / 0.3, rtol=0, atol=1e-15)   # no division by ~0
    np.testing.assert_allclose(sig[:, 2], 0.005 + 1.5e-3 * np.array([0.0, 0.1, 0.3]) ** 2, rtol=0, atol=1e-15)
    assert observation_sigmas(rec, 2.0).shape == (1, 3)


def test_far_factor_one_leaves_the_far_range_undoubled():
    sig = observation_sigmas(_recipe(far_factor=1.0), np.array([5.0]))
    assert sig[0, 2] == pytest.approx(0.005 + 1.5e-3 * 25.0, abs=1e-15)


@pytest.fixture(scope="module")
def problem():
    sim = simulate_logs("paper", seed=3, duration_s=40.0, walkers="none")
    rec = GraphRecipe.load("default")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob = prepare(sim.calib, rec, is_robot=np.ones(len(sim.calib.observations), bool))
        parts = build_parts(sim.calib, prob)       # (a graph built: its values predict every range)
    return sim.calib, prob, parts.values


def test_robot_factors_take_their_noise_at_the_observed_range_whatever_the_shifts(problem):
    log, prob, values = problem
    observed = np.linalg.norm(prob.fac_p_sensor, axis=1)
    n = len(observed)
    assert n > 100
    base = observation_terms(log, prob, values)
    shifted = observation_terms(log, prob, values, theta={"ray_shift_m": 0.04, "horizontal_shift_m": 0.05})
    robot = np.flatnonzero(base.is_pose)
    assert len(robot) == n
    # the factors' ranges move with the shifts ...
    assert np.max(np.abs(shifted.range_m[robot] - base.range_m[robot])) > 0.03
    # ... their noise stays at the range as observed (sigmas that moved with the shifts would
    # reward shifts that shrink them)
    np.testing.assert_array_equal(base.noise_range_m[robot], observed)
    np.testing.assert_array_equal(shifted.noise_range_m[robot], observed)
    # and each factor's sigmas are the noise model's there (rounded to the noise cache's 1 cm),
    # over the square root of its merged count
    rounded = np.round(observed / 0.01) * 0.01
    np.testing.assert_allclose(base.sigmas(prob.recipe)[robot],
                               observation_sigmas(prob.recipe, rounded) / np.sqrt(prob.fac_count)[:, None],
                               rtol=1e-12)
