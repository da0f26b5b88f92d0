"""The head point's shifts estimated by their profile on the linearized graph
(pedcal.calib.profile): the linear algebra against GTSAM's, the estimate and its sigma against
the nonlinear profile solved point by point, and no bias from noise the shifts do not cause."""

import copy
import dataclasses
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
    rec.head_shift_per_sensor_sigma_m = 0.0       # the shared shifts alone
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



def test_a_given_orderings_keys_outside_the_system_are_skipped_and_its_missing_ones_come_last():
    # the order follows the Ordering over the system's own variables, each variable's columns
    # together; a key the system lacks is skipped, the system's variables the Ordering lacks
    # come last in key order
    values = gtsam.Values()
    for k in (5, 1, 9, 3):
        values.insert(k, gtsam.Point3(0.0, 0.0, 0.0))
    values.insert(7, gtsam.Pose3())
    cols = Columns.of(values)                          # keys 1, 3, 5, 7 (6 wide), 9
    ordering = gtsam.Ordering()
    for k in (9, 4, 7, 1):                             # 4: not a variable of the system
        ordering.push_back(k)
    order = fill_reducing_order(ordering, cols)
    want = np.concatenate([cols.index([k]) for k in (9, 7, 1, 3, 5)])
    assert np.array_equal(order, want)
    assert np.array_equal(np.sort(order), np.arange(cols.n))


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
    # two right-hand sides at once, as the profile's sensitivities are solved (by the triangular
    # factors' own solves): GTSAM's step too
    Y = np.column_stack([y, 2.0 * y])
    X = _normal_solver(A, order)(Y)
    assert np.abs(X[:, 1] - 2.0 * X[:, 0]).max() < 1e-9 * np.abs(X).max()
    assert np.abs(X[:, 0] - step).max() < 1e-9 * max(np.abs(step).max(), 1.0)


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


def test_joint_marginal_covariance_equals_gtsams(dome_paper, monkeypatch):
    # either elimination (sequential on a graph up to SEQUENTIAL_MAX_VARIABLES variables,
    # multifrontal above), each the one that ran (spied on), equal to GTSAM's to rounding and
    # not the same arrays (two eliminations, not one twice)
    import pedcal.calib.profile as profile_mod
    from pedcal.calib.graph import H, S
    from pedcal.calib.profile import joint_marginal_covariance

    _, prob, parts, result = dome_paper
    ran = []

    def spy(name):
        method = getattr(gtsam.GaussianFactorGraph, name)

        def eliminate(self, ordering):
            ran.append(name)
            return method(self, ordering)
        return eliminate

    for name in ("eliminatePartialSequential", "eliminatePartialMultifrontal"):
        monkeypatch.setattr(gtsam.GaussianFactorGraph, name, spy(name))
    fg = parts.graph()
    keys = [S(2), H(0), S(0)]
    theirs = gtsam.Marginals(fg, result).jointMarginalCovariance(gtsam.KeyVector(keys)).fullMatrix()
    ours = {}
    for threshold, elimination in ((result.size(), "eliminatePartialSequential"),
                                   (result.size() - 1, "eliminatePartialMultifrontal")):
        monkeypatch.setattr(profile_mod, "SEQUENTIAL_MAX_VARIABLES", threshold)
        ran.clear()
        ours[elimination] = joint_marginal_covariance(fg, result, keys)
        assert ran == [elimination]
        assert np.allclose(ours[elimination], theirs, rtol=1e-6, atol=1e-12 * np.abs(theirs).max())
    assert not np.array_equal(*ours.values())


def _rhs_against_gtsam(log, prob, values, thetas, seed=0):
    """Largest |b| and largest difference between ObservationRhs and the right-hand side of the
    observation block's own linearization, over ``thetas`` and unit / random sigma scales."""
    from pedcal.calib.graph import ObservationRhs

    cols = Columns.of(values)
    rhs = ObservationRhs(log, prob, values)
    rng = np.random.default_rng(seed)
    n = observation_block(log, prob, values).size()
    worst, size = 0.0, 0.0
    for th in thetas:
        for scale in (np.ones(n), np.exp(0.5 * rng.normal(size=n))):
            gfg = observation_block(log, prob, values, theta=th, sigma_scale=scale).linearize(values)
            b = sparse_system(gfg, cols)[1]
            ours = rhs(th, scale)
            assert ours.shape == b.shape
            worst, size = max(worst, float(np.abs(ours - b).max())), max(size, float(np.abs(b).max()))
    return worst, size


def test_observation_rhs_equals_gtsams_linearization(dome_paper):
    # the robot's bearing-range factors and the head offset's prior, at the solution and with
    # every shift moved (the measurements change, the predictions do not)
    sim, prob, parts, result = dome_paper
    thetas = [None, {"ray_shift_m": 0.04, "horizontal_shift_m": -0.015, "curvature_m": 0.02}]
    worst, size = _rhs_against_gtsam(sim.calib, prob, result, thetas)
    assert size > 1.0                   # residuals of several sigma: the comparison is not vacuous
    assert worst < 1e-8


def test_observation_rhs_factor_rows_are_the_blocks(dome_paper):
    # the rows each factor of the observation block takes in its linearization, from its
    # structure (the head offset's prior 6, each observation 3), as GTSAM's factors give them:
    # the robot's block with its prior, and the shared people's without one
    from pedcal.calib.graph import ObservationRhs
    from pedcal.calib.profile import _factor_rows

    sim, prob, parts, result = dome_paper
    block = observation_block(sim.calib, prob, result)
    rows = ObservationRhs(sim.calib, prob, result).factor_rows()
    assert block.at(0).dim() == 6 and rows[1] == 6          # (the prior leads)
    assert np.array_equal(rows, _factor_rows(block))
    sim, prob, parts = shared_people_problem()
    values = parts.values
    block = observation_block(sim.calib, prob, values)
    rows = ObservationRhs(sim.calib, prob, values).factor_rows()
    assert block.size() > 10 and np.array_equal(rows, _factor_rows(block))


def shared_people_problem():
    """Paper seed 0 with every track taken for a person: the robot's, seen by two sensors at
    once, are the shared person sightings. Returns (sim, prob, parts)."""
    sim = simulate_logs("paper", seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob = prepare(sim.calib, GraphRecipe.load("default"), is_robot=np.zeros(len(sim.calib.observations), bool))
        parts = build_parts(sim.calib, prob)
    return sim, prob, parts


def test_observation_rhs_equals_gtsams_for_shared_people():
    # the people's bearing-range factors to their Point3 variables (the robot counted as a person)
    sim, prob, parts = shared_people_problem()
    assert len(prob.people) > 100
    # away from the initial values, so that predictions and measurements differ
    values = parts.values.retract(_random_delta(parts.values, 0.01, seed=1))
    worst, size = _rhs_against_gtsam(sim.calib, prob, values, [None, {"ray_shift_m": 0.03, "horizontal_shift_m": 0.01}])
    assert size > 1.0
    assert worst < 1e-8


def _random_delta(values, sd, seed):
    rng = np.random.default_rng(seed)
    vv = gtsam.VectorValues()
    dims = values.dims()
    for key in values.keys():
        vv.insert(key, sd * rng.normal(size=int(dims[key])))
    return vv


def test_unit3_basis_is_gtsams():
    from pedcal.calib.graph import _unit3_basis

    rng = np.random.default_rng(4)
    n = rng.normal(size=(200, 3))
    n[:3] = [[0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 1.0]]      # ties between components
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    b1, b2 = _unit3_basis(n)
    theirs = np.stack([gtsam.Unit3(v).basis() for v in n])
    assert np.allclose(np.stack([b1, b2], axis=-1), theirs, atol=1e-12)


def _shift_profile(prob, parts):
    """The factors the head point's shifts do not enter (all blocks but the observations) and the
    two shifts as nuisances of the recipe's priors."""
    from pedcal.calib.profile import Nuisance

    rec = prob.recipe
    fixed = gtsam.NonlinearFactorGraph()
    for name in ("sensors", "amcl", "motion"):
        fixed.push_back(parts.blocks[name])
    return fixed, [Nuisance("ray_shift_m", rec.head_radius_m, rec.head_ray_shift_sigma_m, rec.head_ray_shift_step_m),
                   Nuisance("horizontal_shift_m", 0.0, rec.head_horizontal_shift_sigma_m,
                            rec.head_ray_shift_step_m)]


def test_profile_step_with_residuals_equals_the_rebuilt_factors(dome_paper):
    # B from the numpy right-hand side (exact weights) against B from rebuilt GTSAM factors
    # (weights quantized to 0.1 %): the same step to a small fraction of its sigma
    from pedcal.calib.graph import ObservationRhs, S
    from pedcal.calib.profile import profile_step

    sim, prob, parts, result = dome_paper
    rec = prob.recipe
    fixed, nuis = _shift_profile(prob, parts)
    names = [n.name for n in nuis]
    theta = np.array([prob.ray_shift_m, prob.horizontal_shift_m])
    rhs = ObservationRhs(sim.calib, prob, result)

    def build(th, scale):
        return observation_block(sim.calib, prob, result, theta=dict(zip(names, th, strict=True)),
                                 sigma_scale=scale)

    # (the fixture's blocks may have been moved on by another test: the observations built here)
    kw = dict(obs0=observation_block(sim.calib, prob, result), kernel=(rec.robust_kernel, rec.robust_k),
              plain_leading=1)
    old = profile_step(fixed, build, result, theta, nuis, **kw)
    new = profile_step(fixed, build, result, theta, nuis,
                       residuals=lambda th, s: rhs(dict(zip(names, th, strict=True)), s), **kw)
    sigma = np.sqrt(np.diag(old.covariance))
    assert np.all(np.abs(new.dtheta - old.dtheta) < 0.02 * sigma)
    assert np.allclose(new.hessian, old.hessian, rtol=0.02)
    assert np.allclose(new.z0, old.z0)
    sensors = Columns.of(result).index([S(i) for i in range(len(prob.sensor_ids))])
    assert np.abs(new.Z[sensors] - old.Z[sensors]).max() < 0.02 * np.abs(old.Z[sensors]).max()


def test_disjoint_groups_share_no_factor():
    from pedcal.calib.profile import _disjoint_groups

    footprint = {1: [0, 1], 2: [2, 3], 3: [1, 5], 4: [7]}
    # 0 has no footprint (it enters everything): alone; 2 joins 1; 3 shares factor 1 with that
    # group, so it starts its own; 4 joins the first group it overlaps nothing of
    assert _disjoint_groups([0, 1, 2, 3, 4], footprint) == [[0], [1, 2, 4], [3]]
    assert _disjoint_groups([], footprint) == []


def test_group_rows_are_each_footprints_rows_in_turn():
    # factors of 3, 1, 0, 2 and 3 rows; footprints in any order, one empty: the rows of each
    # footprint's factors in its order, concatenated, each row labelled with its footprint
    from pedcal.calib.profile import _group_rows

    rows = np.array([0, 3, 4, 4, 6, 9], np.int64)
    footprints = [[4, 0], [], [1, 2], np.array([3])]
    got, member = _group_rows(footprints, rows)
    assert np.array_equal(got, [6, 7, 8, 0, 1, 2, 3, 4, 5])
    assert np.array_equal(member, [0, 0, 0, 0, 0, 0, 2, 3, 3])
    # a footprint of a factor without rows first: the next one's rows, labelled with it
    got, member = _group_rows([[2], [0]], rows)
    assert np.array_equal(got, [0, 1, 2]) and np.array_equal(member, [1, 1, 1])
    empty, none = _group_rows([[], []], rows)
    assert len(empty) == len(none) == 0


def _clock_profile(dome_paper, footprint_of, calls: list | None = None):
    """One profile step with the ray shift and every sensor's clock offset; ``calls`` (if given)
    collects one entry per evaluation of the observations' right-hand side."""
    from pedcal.calib.clocks import clock_nuisances
    from pedcal.calib.graph import ObservationRhs
    from pedcal.calib.profile import Nuisance, profile_step

    sim, prob, parts, result = dome_paper
    prob = copy.deepcopy(prob)
    rec = prob.recipe
    nuis = [Nuisance("ray_shift_m", rec.head_radius_m, rec.head_ray_shift_sigma_m, rec.head_ray_shift_step_m)]
    # (the clocks' steps distinct: a grouped column divided by another's step shows)
    nuis += [dataclasses.replace(n, step=n.step * (1 + 0.25 * i)) for i, n in enumerate(clock_nuisances(prob))]
    names = [n.name for n in nuis]
    theta = np.array([getattr(prob, n) for n in names], float)
    fixed = gtsam.NonlinearFactorGraph()
    for name in ("sensors", "amcl", "motion"):
        fixed.push_back(parts.blocks[name])
    rhs = ObservationRhs(sim.calib, prob, result)

    def counted(th, s):
        if calls is not None:
            calls.append(1)
        return rhs(dict(zip(names, th, strict=True)), s)

    step = profile_step(fixed, None, result, theta, nuis, obs0=observation_block(sim.calib, prob, result),
                        kernel=(rec.robust_kernel, rec.robust_k), plain_leading=1,
                        residuals=counted,
                        footprint=footprint_of(prob, rhs, names))
    return step, nuis


def _clock_footprints(prob, rhs, names):
    index = {sid: i for i, sid in enumerate(prob.sensor_ids)}
    return {j: rhs.robot_factors(index[n.split(":", 1)[1]]) for j, n in enumerate(names) if n.startswith("clock")}


def test_grouped_clock_columns_equal_one_by_one(dome_paper):
    # the clock offsets moved together (each its own sensor's factors) give the columns moved
    # one at a time: the same step, Hessian and sensitivities
    grouped_calls, one_by_one_calls = [], []
    together, nuis = _clock_profile(dome_paper, _clock_footprints, grouped_calls)
    alone, _ = _clock_profile(dome_paper, lambda prob, rhs, names: None, one_by_one_calls)
    assert len(nuis) >= 5                          # the ray shift and the sensors' clocks
    # and the grouping took place: the clocks' columns in one evaluation, not one each
    assert len(one_by_one_calls) - len(grouped_calls) == len(nuis) - 2
    assert (together.B != alone.B).nnz == 0         # the columns bit for bit
    assert np.allclose(together.hessian, alone.hessian, rtol=1e-9, atol=1e-9 * np.abs(alone.hessian).max())
    assert np.allclose(together.dtheta, alone.dtheta, rtol=1e-7, atol=1e-12)
    assert np.allclose(together.Z, alone.Z, rtol=1e-7, atol=1e-9 * np.abs(alone.Z).max())


def test_a_wrong_footprint_falls_back_to_one_by_one(dome_paper):
    # the ray shift enters every factor: declared as entering one sensor's alone, its group's
    # rows outside the footprints move, and its nuisances are taken one at a time
    def wrong(prob, rhs, names):
        fp = _clock_footprints(prob, rhs, names)
        fp[0] = rhs.robot_factors(len(prob.sensor_ids) - 1)[:1]
        return fp

    wrong_step, _ = _clock_profile(dome_paper, wrong)
    alone, _ = _clock_profile(dome_paper, lambda prob, rhs, names: None)
    assert np.allclose(wrong_step.hessian, alone.hessian, rtol=1e-9, atol=1e-9 * np.abs(alone.hessian).max())


def test_profile_hessian_equals_the_formed_residual_change(dome_paper):
    # M^T M from B^T B - (A^T B)^T Z equals M = A Z - B formed row by row, and the gradient M^T r
    step, nuis = _clock_profile(dome_paper, _clock_footprints)
    M = step.A @ step.Z - step.B.toarray()
    info = np.diag([1.0 / n.prior_sigma ** 2 for n in nuis])
    assert np.allclose(step.hessian, M.T @ M + info, rtol=1e-8, atol=1e-8 * np.abs(step.hessian).max())
    r = np.random.default_rng(2).normal(size=M.shape[0])
    from pedcal.calib.profile import _residual_change_t

    assert np.allclose(_residual_change_t(step, r), M.T @ r, rtol=1e-8, atol=1e-8 * np.abs(M.T @ r).max())


def test_pose3_log_is_gtsams():
    from pedcal.calib.graph import pose3_log

    rng = np.random.default_rng(5)
    poses = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * scale), rng.normal(size=3))
             for scale in (0.0, 1e-8, 1e-5, 1e-3, 0.3, 1.5) for _ in range(20)]
    ours = pose3_log(np.stack([p.rotation().matrix() for p in poses]), np.stack([p.translation() for p in poses]))
    theirs = np.stack([gtsam.Pose3.Logmap(p) for p in poses])
    assert np.abs(ours - theirs).max() < 1e-10


def test_motion_rhs_equals_gtsams_linearization(dome_paper):
    # the odometry block's right-hand side with its calibration's corrections moved, at values
    # away from the odometry's own path
    from pedcal.calib.graph import MotionRhs, motion_block

    sim, prob, parts, result = dome_paper
    assert prob.odometry is not None
    values = result.retract(_random_delta(result, 0.01, seed=3))
    cols = Columns.of(values)
    rhs = MotionRhs(sim.calib, prob, values)
    for th in (None, {"odometry_scale_correction": 0.004, "odometry_drift_rad_per_m": 1e-3,
                      "odometry_drift_rad_per_s": -2e-4}):
        b = sparse_system(motion_block(sim.calib, prob, theta=th).linearize(values), cols)[1]
        ours = rhs(th)
        assert ours.shape == b.shape and np.abs(b).max() > 1.0
        assert np.abs(ours - b).max() < 1e-7


def test_normal_solve_of_many_right_hand_sides():
    # many columns at once, in a scrambled column order: each column solves N x = y
    import scipy.sparse as sps

    rng = np.random.default_rng(0)
    n = 120
    A = (sps.random(400, n, density=0.05, random_state=1, format="csr")
         + sps.vstack([sps.eye(n), sps.csr_matrix((400 - n, n))])).tocsr()
    Y = rng.normal(size=(n, 70))
    X = _normal_solver(A, rng.permutation(n))(Y)
    assert np.abs((A.T @ A) @ X - Y).max() < 1e-10


def test_joint_system_is_the_stacked_blocks():
    # [[A, C], [prior]] assembled from the CSR arrays equals scipy's stacking, with empty rows
    # in A and in C, and unsorted C
    import scipy.sparse as sps

    from pedcal.calib.profile import _joint_system

    rs = np.random.RandomState(3)
    A = sps.random(50, 30, density=0.1, random_state=rs, format="csr")
    A[7] = 0.0
    A.eliminate_zeros()
    C = sps.random(50, 4, density=0.2, random_state=rs, format="csc")
    prior = sps.csr_matrix((np.r_[2.0, 3.0], (np.r_[0, 1], np.r_[31, 33])), shape=(2, 34))
    got = _joint_system(A, C, prior)
    want = sps.vstack([sps.hstack([A, C]), prior]).tocsr()
    assert got.shape == want.shape == (52, 34) and got.nnz == want.nnz
    assert abs(got - want).max() == 0.0
    # A given as row blocks (one of them empty) is the same as A stacked
    blocks = [A[:20], sps.csr_matrix((0, 30)), A[20:45], A[45:]]
    got = _joint_system(blocks, C, prior)
    assert got.shape == want.shape and got.nnz == want.nnz
    assert np.array_equal(got.indptr, want.indptr) and abs(got - want).max() == 0.0


def test_joint_system_lays_each_row_out_as_its_a_entries_then_its_c_entries():
    # blocks whose rows hold no C entry (a fixed block's, taken in one piece) between blocks
    # whose rows do: each row's A entries in A's order, then its C entries in column order
    import scipy.sparse as sps

    from pedcal.calib.profile import _joint_system

    rs = np.random.RandomState(4)
    A = sps.random(60, 20, density=0.2, random_state=rs, format="csr")
    C = sps.random(60, 3, density=0.3, random_state=rs, format="lil")
    C[:25] = 0.0
    C[40:48] = 0.0
    C = sps.csc_matrix(C)
    C.eliminate_zeros()
    prior = sps.csr_matrix((np.r_[5.0], (np.r_[0], np.r_[22])), shape=(1, 23))
    got = _joint_system([A[:25], A[25:40], A[40:48], A[48:]], C, prior)
    C_rows = sps.csr_matrix(C)
    C_rows.sort_indices()
    for r in range(60):
        a = slice(A.indptr[r], A.indptr[r + 1])
        c = slice(C_rows.indptr[r], C_rows.indptr[r + 1])
        row = slice(got.indptr[r], got.indptr[r + 1])
        assert np.array_equal(got.indices[row], np.r_[A.indices[a], C_rows.indices[c] + 20])
        assert np.array_equal(got.data[row], np.r_[A.data[a], C_rows.data[c]])
    assert np.array_equal(got.indices[got.indptr[60]:], [22]) and got.data[-1] == 5.0


def test_near_solve_is_the_direct_solve_of_the_moved_system():
    # conjugate gradients preconditioned with a nearby system's factorization reach the moved
    # system's own solution; without that factorization, or out of iterations, None
    import scipy.sparse as sps

    from pedcal.calib.profile import _near_solve

    rng = np.random.default_rng(4)
    n = 90
    A0 = (sps.random(300, n, density=0.05, random_state=2, format="csr")
          + sps.vstack([sps.eye(n), sps.csr_matrix((300 - n, n))])).tocsr()
    A1 = A0.copy()
    A1.data = A1.data * (1.0 + 0.05 * rng.standard_normal(A1.nnz))        # the Jacobians moved by 5 %
    y = rng.normal(size=n)
    order = rng.permutation(n)
    exact = _normal_solver(A1, order)(y)
    near = _normal_solver(A0, order)
    x = _near_solve(A1, y, near, rtol=1e-12)
    assert x is not None
    assert np.abs(x - exact).max() < 1e-9 * np.abs(exact).max()
    assert np.abs(near(y) - exact).max() > 1e-3 * np.abs(exact).max()     # (the factorization alone is off)
    assert _near_solve(A1, y, None) is None
    assert _near_solve(A1, y, near, rtol=1e-12, max_iterations=0) is None
    assert np.array_equal(_near_solve(A1, np.zeros(n), near), np.zeros(n))


def test_columns_index_of_many_keys_equals_key_by_key():
    values = gtsam.Values()
    for i in range(30):
        values.insert(gtsam.symbol("x", i), gtsam.Pose3())
        values.insert(gtsam.symbol("l", i), gtsam.Point3(0.0, 0.0, float(i)))
    cols = Columns.of(values)
    keys = [gtsam.symbol("l", i) for i in range(29, -1, -2)] + [gtsam.symbol("x", i) for i in range(0, 30, 3)]
    assert len(keys) > 16                       # (the sorted-array lookup)
    expected = np.concatenate([cols.offset[k] + np.arange(cols.dim[k]) for k in keys])
    assert np.array_equal(cols.index(keys), expected)
    assert np.array_equal(cols.index(np.asarray(keys, np.uint64)), expected)
    assert np.array_equal(cols.index(keys[:3]), expected[:9])
    with pytest.raises(KeyError):
        cols.index(keys + [gtsam.symbol("a", 0)])
    with pytest.raises(KeyError):
        cols.index([gtsam.symbol("a", 0)])
    assert len(cols.index([])) == 0


def test_chord_step_with_the_kept_factorization_equals_a_fresh_one(dome_paper, monkeypatch):
    # a chord step solves z0 by conjugate gradients preconditioned with the full step's
    # factorization: the same step as with a factorization of its own, to their tolerance
    from pedcal.calib.graph import ObservationRhs
    from pedcal.calib.profile import profile_step, retract_flat

    sim, prob, parts, result = dome_paper
    rec = prob.recipe
    fixed, nuis = _shift_profile(prob, parts)
    names = [n.name for n in nuis]
    cols = Columns.of(result)
    p = copy.copy(prob)
    theta = np.array([p.ray_shift_m, p.horizontal_shift_m])

    def step_at(values, th, previous=None, order=None):
        rhs = ObservationRhs(sim.calib, p, values)
        return profile_step(fixed, lambda t, s: observation_block(sim.calib, p, values,
                                                                  theta=dict(zip(names, t, strict=True))),
                            values, th, nuis, cols, obs0=observation_block(sim.calib, p, values),
                            kernel=(rec.robust_kernel, rec.robust_k), plain_leading=1, previous=previous,
                            order=order, residuals=lambda t, s: rhs(dict(zip(names, t, strict=True)), s))

    full = step_at(result, theta)
    assert "_normal_solve" in full.__dict__
    theta = theta + full.dtheta
    p.ray_shift_m, p.horizontal_shift_m = theta
    moved = retract_flat(result, full.z0 + full.Z @ full.dtheta, cols)
    import pedcal.calib.profile as profile_mod

    factorized, real = [], profile_mod._normal_solver
    monkeypatch.setattr(profile_mod, "_normal_solver", lambda *a, **k: factorized.append(1) or real(*a, **k))
    kept = step_at(moved, theta, previous=full, order=full.order)
    assert factorized == []          # z0 from the kept factorization, none of its own
    # its B is its own point's (the exact gradient -B^T r), not the full step's
    assert kept.B.shape == full.B.shape and abs(kept.B - full.B).max() > 0.0
    monkeypatch.undo()
    bare = copy.copy(full)
    bare.__dict__.pop("_normal_solve")
    fresh = step_at(moved, theta, previous=bare, order=full.order)
    assert np.abs(kept.z0).max() > 0.0
    # (to the conjugate gradients' tolerance, CHORD_RTOL of the residual: measured 1.8e-6 of the
    # largest |z0| (0.7 mm), a nanometre, and dtheta within 1.3e-7 of its largest sigma; fixed
    # bounds, not loosened by a larger CHORD_RTOL)
    from pedcal.calib.profile import CHORD_RTOL

    assert CHORD_RTOL <= 1e-6
    assert np.abs(kept.z0 - fresh.z0).max() < 1e-5 * np.abs(fresh.z0).max()
    assert np.abs(kept.z0 - fresh.z0).max() < 1e-8
    assert np.abs(kept.dtheta - fresh.dtheta).max() < 1e-6 * np.sqrt(np.diag(full.covariance)).max()
    # a selection keeps the factorization (the same system)
    assert full.select(np.array([0])).__dict__["_normal_solve"] is full.__dict__["_normal_solve"]


def test_factor_rows_follow_the_graph_they_were_kept_for():
    # each factor's first row and the end; kept for the same graph, taken anew once it grows,
    # and forgotten with the graph
    import gc

    from pedcal.calib.profile import _FACTOR_ROWS, _factor_rows

    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.PriorFactorPose3(1, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    g.add(gtsam.PriorFactorPoint3(2, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    first = _factor_rows(g)
    assert first.tolist() == [0, 6, 9]
    assert _factor_rows(g) is first
    g.add(gtsam.PriorFactorPoint2(3, np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)))
    assert _factor_rows(g).tolist() == [0, 6, 9, 11]
    key = id(g)
    del g
    gc.collect()
    assert key not in _FACTOR_ROWS
    assert _factor_rows(gtsam.NonlinearFactorGraph()).tolist() == [0]


def test_free_memory_is_handed_back_before_large_factorizations_only(monkeypatch):
    # below RELEASE_BEFORE_ENTRIES the factorization starts at once; at or above, after handing
    # the free memory back; the factors are the same either way
    import scipy.sparse as sps

    import pedcal.calib.profile as profile

    calls = []
    monkeypatch.setattr(profile, "release_free_memory", lambda: calls.append(1))
    rng = np.random.default_rng(5)
    A = (sps.random(60, 20, density=0.2, random_state=3, format="csr") + sps.vstack(
        [sps.eye(20), sps.csr_matrix((40, 20))])).tocsr()
    N = (A.T @ A).toarray()
    y = rng.normal(size=20)
    small = profile._normal_solver(A)(y)
    assert calls == []
    monkeypatch.setattr(profile, "RELEASE_BEFORE_ENTRIES", A.nnz)
    large = profile._normal_solver(A)(y)
    assert calls == [1]
    assert np.array_equal(small, large)
    assert np.abs(N @ large - y).max() < 1e-10


def test_steps_to_come_are_the_geometric_series_of_a_contracting_step():
    from pedcal.calib.profile import steps_to_come_below

    # a step of 0.14 sigma after one of 1.24 (rate 0.113): 0.018 sigma to come, below 0.1
    u, before = np.array([0.14, -0.02, 0.0]), np.array([1.24, 0.1, 0.0])
    rate = np.linalg.norm(u) / np.linalg.norm(before)
    assert rate / (1 - rate) * 0.14 < 0.02
    assert steps_to_come_below(u, rate, 0.1) is True
    assert steps_to_come_below(u, rate, 0.01) is False
    # the steps' sizes, whatever their signs: the same step reversed is no nearer converged
    assert steps_to_come_below(-u, rate, 0.1) is True and steps_to_come_below(-u, rate, 0.01) is False
    # a slow contraction (rate 0.8): four times this step to come
    assert steps_to_come_below(np.array([0.08]), 0.8, 0.3) is False
    assert steps_to_come_below(np.array([0.08]), 0.8, 0.33) is True
    # nothing to measure the contraction by: no rate, a step no shorter than the last (one of
    # the same length, -u: rate 1 exactly; a longer one), a rate or a step that is not a number
    same = np.linalg.norm(u) / np.linalg.norm(-u)
    assert same == 1.0
    for step, r in ((u, None), (u, same), (u, 1.5), (u, np.nan), (np.array([0.01, np.nan, 0.0]), rate)):
        assert steps_to_come_below(step, r, 0.1) is None
