"""The depth sensors' noise model (pedcal.calib.recipe.observation_sigmas) and what the
observation factors read at the predicted point, not at the noisy measured one
(pedcal.calib.graph.Regressors): the range the noise is taken at (not as the head point's shifts
move it), the shifts' directions and the distance the shift's profile is read at; the factors'
Jacobians, which leave the regressors' own dependence on the variables out, by finite
differences."""

import warnings

import gtsam
import numpy as np
import pytest

from pedcal.calib.graph import H, L, S, X, build_parts, observation_block, observation_terms, optimize_graph
from pedcal.calib.headpoint import SENSOR_PREFIX, SLOPE, _knots, hats, line_of_knots
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


def _predicted(prob, values):
    """Each robot-observation factor's target seen from its sensor, one GTSAM call per factor:
    (points (n, 3) sensor frame, the sensors' rotations (n, 3, 3))."""
    pts, rots = [], []
    for i, k in zip(prob.fac_sensor_index.tolist(), prob.fac_key_index.tolist(), strict=True):
        T = values.atPose3(S(i))
        pts.append(T.transformTo(values.atPose3(X(k)).translation()))
        rots.append(T.rotation().matrix())
    return np.array(pts), np.array(rots)


def _toward_and_distance(p, R):
    """The horizontal unit toward the sensor (sensor frame) and the horizontal distance, from the
    world-frame offset of the points from their sensors."""
    w = np.einsum("nij,nj->ni", R, p)                 # the point less the sensor, world frame
    d = np.hypot(w[:, 0], w[:, 1])
    toward_w = np.column_stack([-w[:, 0] / d, -w[:, 1] / d, np.zeros(len(d))])
    return np.einsum("nji,nj->ni", R, toward_w), d


def test_robot_factors_take_their_noise_at_the_predicted_range_whatever_the_shifts(problem):
    log, prob, values = problem
    p_pred, _ = _predicted(prob, values)
    observed = np.linalg.norm(prob.fac_p_sensor, axis=1)
    predicted = np.linalg.norm(p_pred, axis=1) - prob.ray_shift_m      # the reported point's, predicted
    n = len(observed)
    assert n > 100
    # (the fixture's values are a rough start: its predictions are decimetres from the measurements)
    assert np.median(np.abs(predicted - observed)) > 0.01
    base = observation_terms(log, prob, values)
    shifted = observation_terms(log, prob, values, theta={"ray_shift_m": 0.04, "horizontal_shift_m": 0.05})
    robot = np.flatnonzero(base.is_pose)
    assert len(robot) == n
    # the factors' ranges move with the shifts ...
    assert np.max(np.abs(shifted.range_m[robot] - base.range_m[robot])) > 0.03
    # ... their noise stays at the range the variables predict (sigmas that moved with the
    # shifts would reward shifts that shrink them; read at the measured range they would weight
    # down the observations their noise pushed far)
    np.testing.assert_allclose(base.noise_range_m[robot], predicted, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(shifted.noise_range_m[robot], base.noise_range_m[robot])
    # and each factor's sigmas are the noise model's there (rounded to the noise cache's 1 cm),
    # over the square root of its merged count
    rounded = np.round(base.noise_range_m[robot] / 0.01) * 0.01
    np.testing.assert_allclose(base.sigmas(prob.recipe)[robot],
                               observation_sigmas(prob.recipe, rounded) / np.sqrt(prob.fac_count)[:, None],
                               rtol=1e-12)


def test_a_block_built_at_initial_values_reads_everything_at_the_measured_points(problem):
    log, prob, values = problem
    terms = observation_terms(log, prob, values, predicted=False, theta={"horizontal_shift_m": 0.05})
    robot = np.flatnonzero(terms.is_pose)
    np.testing.assert_array_equal(terms.noise_range_m[robot], np.linalg.norm(prob.fac_p_sensor, axis=1))
    base = observation_terms(log, prob, values, predicted=False)
    np.testing.assert_allclose(terms.p_sensor[robot] - base.p_sensor[robot], -0.05 * prob.fac_toward_sensor,
                               rtol=0, atol=1e-12)


def test_the_profile_reads_the_predicted_distance_and_the_shifts_the_measured_direction(problem):
    log, prob, values = problem
    p_pred, R = _predicted(prob, values)
    d = _toward_and_distance(p_pred, R)[1]
    toward = prob.fac_toward_sensor           # the direction, read at the measured point
    base = observation_terms(log, prob, values)
    robot = np.flatnonzero(base.is_pose)

    def moved(**theta):
        return observation_terms(log, prob, values, theta=theta).p_sensor[robot] - base.p_sensor[robot]

    # the horizontal shift, the curvature and a sensor's own departure along the measured direction
    np.testing.assert_allclose(moved(horizontal_shift_m=0.05), -0.05 * toward, rtol=0, atol=1e-12)
    np.testing.assert_allclose(moved(curvature_m=0.03), -0.03 * prob.fac_up_cos2, rtol=0, atol=1e-12)
    sid = prob.sensor_ids[int(prob.fac_sensor_index[0])]
    mine = prob.fac_sensor_index == prob.fac_sensor_index[0]
    got = moved(**{SENSOR_PREFIX + sid: 0.02})
    np.testing.assert_allclose(got[mine], -0.02 * toward[mine], rtol=0, atol=1e-12)
    assert not np.any(got[~mine])
    # the shift against distance: a line rising 30 mm across the knots, at the predicted distance
    knots = _knots(prob)
    assert knots is not None
    try:
        line = hats(d, knots)[:, 1:] @ line_of_knots(knots)
        np.testing.assert_allclose(moved(**{SLOPE: 0.03}), -0.03 * line[:, None] * toward, rtol=0, atol=1e-12)
        # (at the measured distance it would differ: the regressor's noise; here the rough values')
        d_obs = -np.sum(prob.fac_p_sensor * toward, axis=1)
        assert np.max(np.abs(hats(d_obs, knots)[:, 1:] @ line_of_knots(knots) - line)) > 0.01
    finally:
        del prob._head_knots


def test_the_people_take_their_noise_at_their_predicted_range():
    sim = simulate_logs("paper", seed=3, duration_s=40.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob = prepare(sim.calib, GraphRecipe.load("default"), is_robot=np.zeros(len(sim.calib.observations), bool))
        values = build_parts(sim.calib, prob).values       # (the people's positions inserted)
    terms = observation_terms(sim.calib, prob, values)
    people = np.flatnonzero(~terms.is_pose)
    assert len(people) > 20
    expected = [np.linalg.norm(values.atPose3(S(int(i))).transformTo(values.atPoint3(L(int(m))))) - prob.ray_shift_m
                for i, m in zip(terms.sensor[people], terms.target[people], strict=True)]
    np.testing.assert_allclose(terms.noise_range_m[people], expected, rtol=0, atol=1e-12)
    measured = [np.linalg.norm(p) for _, seen in prob.people for _, p in seen]
    assert np.max(np.abs(np.asarray(measured) - expected)) > 0.01      # (not the measured ranges)


def _jacobians(log, prob, values, theta, j, first, h=1e-6):
    """Robot-observation factor ``j``'s whitened Jacobian (3 x 12, its sensor's then its pose's
    tangent) three ways: GTSAM's; central differences of the factor as built at ``values``
    (its measurement fixed); and of the factor rebuilt at each perturbed point (the regressors
    moving with the variables)."""
    block = observation_block(log, prob, values, theta=theta, robust=False, predicted=True)
    factor = block.at(first + j)
    keys = list(factor.keys())
    J = np.asarray(factor.linearize(values).jacobian()[0])
    frozen, moving = np.zeros((3, 12)), np.zeros((3, 12))
    for c in range(12):
        key = keys[c // 6]
        e = []
        for sign in (1.0, -1.0):
            v = gtsam.Values(values)
            delta = np.zeros(6)
            delta[c % 6] = sign * h
            v.update(key, values.atPose3(key).retract(delta))
            e.append((factor.whitenedError(v),
                      observation_block(log, prob, v, theta=theta, robust=False).at(first + j).whitenedError(v)))
        frozen[:, c] = (e[0][0] - e[1][0]) / (2 * h)
        moving[:, c] = (e[0][1] - e[1][1]) / (2 * h)
    return J, frozen, moving


def test_the_factors_jacobians_leave_out_only_the_regressors_small_dependence_on_the_variables(problem):
    """GTSAM's Jacobian is the derivative of the factor as built; the factor rebuilt at a moved
    point (its distance read there) differs from it by the distance's part alone: nothing without
    a profile, linear in it, and a few percent of the Jacobian for a slope of centimetres per
    metre."""
    log, prob, values = problem
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        values = optimize_graph(build_parts(log, prob).graph(), values, prob.recipe)[0]
    first = int(values.exists(H(0)) and prob.recipe.amcl and prob.recipe.estimate_head_model)
    p_pred, R = _predicted(prob, values)
    d = _toward_and_distance(p_pred, R)[1]
    # factors the solution fits (GTSAM's bearing Jacobian drops terms of the order of the bearing's
    # error), a metre or more away
    u_pred = p_pred / np.linalg.norm(p_pred, axis=1, keepdims=True)
    u_meas = prob.fac_p_sensor / np.linalg.norm(prob.fac_p_sensor, axis=1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(u_pred * u_meas, axis=1), -1.0, 1.0))
    knots = _knots(prob)
    # (between the end knots: the hats are flat beyond them, the line's slope 0 there)
    picks = np.flatnonzero((d > max(1.0, knots[0])) & (d < knots[-1]) & (angle < 0.005))[::7][:4]
    assert len(picks) >= 3
    try:
        for j in picks.tolist():
            J0, frozen0, moving0 = _jacobians(log, prob, values, {}, j, first)
            # GTSAM's Jacobian is the factor's derivative (its bearing part to the order of the bearing's
            # error, here below a sigma)
            np.testing.assert_allclose(frozen0, J0, rtol=0, atol=3e-3 * np.abs(J0).max())
            np.testing.assert_allclose(moving0, frozen0, rtol=0, atol=1e-6 * np.abs(J0).max())   # no shift, no part
            # the constant shift's direction is read at the measured point: no part at all
            J, frozen, moving = _jacobians(log, prob, values, {"horizontal_shift_m": 0.03}, j, first)
            np.testing.assert_allclose(moving, frozen, rtol=0, atol=1e-6 * np.abs(J).max())
            theta = {"horizontal_shift_m": 0.03, SLOPE: 0.03}
            J, frozen, moving = _jacobians(log, prob, values, theta, j, first)
            np.testing.assert_allclose(frozen, J, rtol=0, atol=0.05 * np.abs(J).max())   # (errors of centimetres)
            left_out = moving - frozen
            size = np.linalg.norm(left_out) / np.linalg.norm(J)
            assert 1e-4 < size < 0.03, size
            # linear in the shifts (to first order): twice the shifts, twice the part
            _, frozen2, moving2 = _jacobians(log, prob, values, {k: 2 * v for k, v in theta.items()}, j, first)
            np.testing.assert_allclose(moving2 - frozen2, 2 * left_out, rtol=0, atol=0.1 * np.abs(left_out).max())
    finally:
        del prob._head_knots
