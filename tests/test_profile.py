"""The head point's shifts estimated by their profile on the linearized graph
(pedcal.calib.profile): the linear algebra against GTSAM's, the estimate and its sigma against
the nonlinear profile solved point by point, and no bias from noise the shifts do not cause."""

import copy
import warnings

import gtsam
import numpy as np
import pytest

from pedcal.calib.common import interpolate_pose2
from pedcal.calib.factorgraph import _estimate_nuisances, calibrate_factorgraph
from pedcal.calib.graph import GraphRecipe, build_parts, observation_block, optimize_graph, prepare
from pedcal.calib.profile import Columns, _normal_solver, fill_reducing_order, sparse_system
from pedcal.errors import DegenerateDataWarning
from pedcal.sim import simulate_logs


@pytest.fixture(scope="module")
def dome_paper():
    """Paper seed 3 with a 7 cm dome shifted 2 cm horizontally, the graph solved once (the AMCL
    model kept as assumed), and its problem."""
    sim = simulate_logs("paper", seed=3, head_point="dome", head_radius_m=0.07)
    rec = GraphRecipe.load("default")
    rec.estimate_amcl_model = False
    return (sim, *solved_graph(sim.calib, rec))


def solved_graph(log, rec):
    """(problem, parts, solution) of ``log``'s graph under ``rec``, solved once."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob = prepare(log, rec)
        parts = build_parts(log, prob)
        result, _ = optimize_graph(parts.graph(), parts.values, rec)
    return prob, parts, result


def test_sparse_system_reproduces_gtsams_gauss_newton_step(dome_paper):
    _, _, parts, result = dome_paper
    gfg = parts.graph().linearize(result)
    cols = Columns.of(result)
    A, b = sparse_system(gfg, cols)
    step = np.asarray(gfg.optimize().vector(cols.keys)).ravel()
    # the normal equations hold at GTSAM's solution, and a block's columns map onto the whole's
    assert np.linalg.norm(A.T @ (A @ step - b)) < 1e-8 * np.linalg.norm(A.T @ b)
    A_obs, b_obs = sparse_system(parts.blocks["observations"].linearize(result), cols)
    assert A_obs.shape[1] == A.shape[1]
    assert abs(A_obs - A[-A_obs.shape[0]:, :]).max() < 1e-9
    assert np.allclose(b_obs, b[-len(b_obs):])



def test_normal_solve_in_the_graphs_colamd_order_is_gtsams_step(dome_paper):
    # the order is a permutation of every column (each variable's together) and the solve in it
    # is GTSAM's Gauss-Newton step, as the solve in SuperLU's own ordering is
    _, _, parts, result = dome_paper
    gfg = parts.graph().linearize(result)
    cols = Columns.of(result)
    A, b = sparse_system(gfg, cols)
    order = fill_reducing_order(gfg, cols)
    assert np.array_equal(np.sort(order), np.arange(cols.n))
    position = np.argsort(order)
    for key in cols.keys:
        at = position[cols.index([key])]
        assert np.array_equal(at, at[0] + np.arange(cols.dim[key]))
    step = np.asarray(gfg.optimize().vector(cols.keys)).ravel()
    y = A.T @ b
    for solve in (_normal_solver(A, order), _normal_solver(A)):
        x = solve(y)
        assert np.abs(x - step).max() < 1e-9 * max(np.abs(step).max(), 1.0)
    # two right-hand sides at once, as the profile's sensitivities are solved
    Y = np.column_stack([y, 2.0 * y])
    X = _normal_solver(A, order)(Y)
    assert np.abs(X[:, 1] - 2.0 * X[:, 0]).max() < 1e-9 * np.abs(X).max()

def test_profile_estimate_and_sigma_match_the_nonlinear_profile(dome_paper):
    # the profile step's optimum and Hessian against the graph re-solved by Levenberg-Marquardt
    # at the estimate and one sigma either side of it on each shift
    sim, prob, parts, result = dome_paper
    prob = copy.deepcopy(prob)
    shifts = _estimate_nuisances(sim.calib, prob, parts, result)
    theta = np.array([prob.ray_shift_m, prob.horizontal_shift_m])
    sigma = np.sqrt(np.diag(shifts.cov))
    rec = prob.recipe
    assert theta[0] == pytest.approx(0.07, abs=3 * sigma[0] + 0.003)

    def profile(th):
        obs = observation_block(sim.calib, prob, shifts.result,
                                theta={"ray_shift_m": th[0], "horizontal_shift_m": th[1]})
        fg = parts.graph(observations=obs)
        solved, _ = optimize_graph(fg, shifts.result, rec)
        prior = 0.5 * ((th[0] - rec.head_radius_m) / rec.head_ray_shift_sigma_m) ** 2 \
            + 0.5 * (th[1] / rec.head_horizontal_shift_sigma_m) ** 2
        return fg.error(solved) + prior

    f0 = profile(theta)
    for j in range(2):
        d = np.zeros(2)
        d[j] = sigma[j]
        # one marginal sigma away the profile (chi^2 / 2) rises by at least the conditional
        # half: between 0.5 (uncorrelated) and a few (strongly correlated shifts)
        for side in (1, -1):
            rise = profile(theta + side * d) - f0
            assert 0.25 < rise < 5.0, (j, side, rise)


def test_lateral_noise_alone_does_not_bias_the_shifts():
    # a head top (no shift at all) seen with 2 cm of lateral noise and nothing else, AMCL exact:
    # sigmas that moved with the shifts put them at +13 / -11 mm here; now within 3 sigma of 0
    sim = simulate_logs("corridor", seed=18, noise_free=True, lateral_noise_m=0.02, head_point="top", odometry=True,
                        amcl_error="white")
    log = copy.copy(sim.calib)
    robot = log.robot.copy()
    truth = interpolate_pose2(log.truth_robot, robot["t"].to_numpy(float))
    robot["x"], robot["y"], robot["yaw"] = truth[:, 0], truth[:, 1], truth[:, 2]
    robot["cov_xx"] = robot["cov_yy"] = 1e-6
    robot["cov_xy"] = 0.0
    log.robot = robot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        res = calibrate_factorgraph(log, estimate_amcl_model=False, people=False)
    head = res.diagnostics.head_model
    assert abs(head.ray_shift_m) < 3 * head.sigma_ray_shift_m + 0.001
    assert abs(head.horizontal_shift_m) < 3 * head.sigma_horizontal_shift_m + 0.001


def test_gtsam_orders_a_linearized_graphs_columns_by_key():
    # Columns relies on it: sparseJacobian_ and VectorValues.vector lay variables out in key order
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    for key, p in ((7, [1.0, 2.0, 3.0]), (2, [0.5, 0.0, 1.0])):
        g.add(gtsam.PriorFactorPoint3(key, np.array(p), noise))
        v.insert(key, np.zeros(3))
    gfg = g.linearize(v)
    cols = Columns.of(v)
    assert cols.keys == [2, 7]
    A, b = sparse_system(gfg, cols)
    x = np.linalg.lstsq(A.toarray(), b, rcond=None)[0]
    assert np.allclose(x, [0.5, 0.0, 1.0, 1.0, 2.0, 3.0])
    assert np.allclose(np.asarray(gfg.optimize().vector(cols.keys)).ravel(), x)


def test_joint_marginal_covariance_equals_gtsams(dome_paper):
    from pedcal.calib.graph import H, S
    from pedcal.calib.profile import joint_marginal_covariance

    _, prob, parts, result = dome_paper
    fg = parts.graph()
    keys = [S(2), H(0), S(0)]
    ours = joint_marginal_covariance(fg, result, keys)
    theirs = gtsam.Marginals(fg, result).jointMarginalCovariance(gtsam.KeyVector(keys)).fullMatrix()
    assert np.allclose(ours, theirs, rtol=1e-6, atol=1e-12 * np.abs(theirs).max())
