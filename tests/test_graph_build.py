"""The graph build's batched pieces against the per-row code they replace: the robot's head frames
made in one pass, the graph rebuilt under a new AMCL model from the first graph's blocks, and the
association's expanded squared residuals."""

import dataclasses

import gtsam
import numpy as np
import pandas as pd
import pytest
from test_factorgraph import _exact_recipe, make_exact_log

from pedcal.calib.amcl_model import AmclErrorModel
from pedcal.calib.association import _residuals, _squared_residuals, rigid_from_moments
from pedcal.calib.graph import (
    BLOCKS,
    GraphRecipe,
    S,
    X,
    _odometry_at,
    build_parts,
    head_frame,
    head_frames,
    observation_block,
    observation_sigmas,
    optimize_graph,
    pose_arrays,
    prepare,
    rebuild_parts,
    set_amcl_model,
    unique_rows,
)


def test_head_frames_are_head_frame_row_by_row():
    rng = np.random.default_rng(0)
    pose2 = np.column_stack([rng.uniform(-50, 50, (40, 2)), rng.uniform(-4.0, 4.0, 40)])
    head_m = np.array([0.12, -0.03, 1.31])
    batch = head_frames(pose2, head_m)
    assert len(batch) == len(pose2)
    for row, P in zip(pose2, batch, strict=True):
        Q = head_frame(*row, head_m)
        assert np.array_equal(P.matrix(), Q.matrix())
    assert head_frames(np.zeros((0, 3)), head_m) == []


@pytest.fixture()
def first_solve():
    log = make_exact_log(seed=4, duration=40.0)
    # no odometry: the robot's motion from AMCL smoothed (which AMCL's jumps, left out, change)
    rec = _exact_recipe(odometry=False, smoothness=True, amcl_smooth_above_m=-1.0)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    assert prob.smoothed_amcl is not None
    parts = build_parts(log, prob)
    result, _ = optimize_graph(parts.graph(), parts.values, rec, max_iterations=3)
    return log, rec, prob, parts, result


def _model(prob, **kw):
    """An estimated AMCL model unlike the assumed one (node spacing, sigmas; ``kw`` overrides)."""
    fields = dict(white_sigma_m=0.012, correlated_sigma_m=0.03, correlation_s=15.0, source="estimated")
    fields.update(kw)
    return dataclasses.replace(prob.amcl_model, **fields)


@pytest.fixture(scope="module")
def noisy_solve():
    """first_solve's log with 3 cm of noise on every observed point: the bearing's sigma, the
    lateral sigma estimated from it over the range, differs between a range read at the measured
    points and one read at the points a solution predicts."""
    log = make_exact_log(seed=4, duration=40.0)
    rng = np.random.default_rng(4)
    log.observations[["x", "y", "z"]] += rng.normal(0.0, 0.03, (len(log.observations), 3))
    rec = _exact_recipe(odometry=False, smoothness=True, amcl_smooth_above_m=-1.0)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    parts = build_parts(log, prob)
    result, _ = optimize_graph(parts.graph(), parts.values, rec, max_iterations=3)
    return log, rec, prob, parts, result


def _observations_at(prob, values, prior) -> gtsam.NonlinearFactorGraph:
    """The robot observations' block built here, factor by factor: each measured head point's
    bearing and range (the problem's shifts all 0), its sigmas those of the range the point
    ``values`` predicts (the sensor's pose and the robot's head frame there), rounded to the
    noise models' 1 cm, over the square root of the observations merged into it and times the
    noise's frame-to-frame correlation factor (graph.noise_correlation_factor); ``prior`` first."""
    from pedcal.calib.graph import noise_correlation_factor
    assert prob.ray_shift_m == prob.horizontal_shift_m == prob.curvature_m == 0.0
    graph = gtsam.NonlinearFactorGraph()
    graph.add(prior)
    for j in np.flatnonzero(prob.fac_key_index < len(prob.pose_times)):
        i, k = int(prob.fac_sensor_index[j]), int(prob.fac_key_index[j])
        T = values.atPose3(S(i))
        predicted = T.rotation().matrix().T @ (values.atPose3(X(k)).translation() - T.translation())
        noise_range = round(float(np.linalg.norm(predicted)) / 0.01) * 0.01
        sigmas = (observation_sigmas(prob.recipe, np.array([noise_range]))[0]
                  * noise_correlation_factor(prob.noise_estimate) / np.sqrt(prob.fac_count[j]))
        p = prob.fac_p_sensor[j]
        graph.add(gtsam.BearingRangeFactorPose3(S(i), X(k), gtsam.Unit3(p), float(np.linalg.norm(p)),
                                                gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    return graph


@pytest.mark.parametrize("excluded", [False, True])
def test_rebuild_under_a_new_amcl_model_equals_a_full_build(noisy_solve, excluded):
    log, _, prob, parts, result = noisy_solve
    assert isinstance(prob.amcl_model, AmclErrorModel)
    mask = None
    if excluded:         # AMCL's jumps left out: with AMCL standing in for odometry, the motion changes
        mask = np.zeros(len(log.robot), bool)
        mask[10:25] = True
    set_amcl_model(log, prob, _model(prob, excluded=mask),
                   rotations={sid: result.atPose3(S(i)).rotation().matrix() for i, sid in enumerate(prob.sensor_ids)})
    full = build_parts(log, prob)        # everything built anew, at the initial values
    fast = rebuild_parts(log, prob, parts, result)
    for name in BLOCKS:
        assert fast.blocks[name].size() == full.blocks[name].size(), name
    # the full build's variables, each at the first solution's value where it has one, except the
    # AMCL error's nodes (new with the model: at the full build's zero)
    assert sorted(fast.values.keys()) == sorted(full.values.keys())
    for key in full.values.keys():
        c = chr(gtsam.Symbol(key).chr())
        src = result if c != "a" and result.exists(key) else full.values
        if c == "l":
            assert np.array_equal(fast.values.atPoint3(key), src.atPoint3(key))
        else:
            assert np.array_equal(fast.values.atPose3(key).matrix(), src.atPose3(key).matrix()), c
    # the same factors: the same error at the same values, and at moved ones, against the full
    # build's other blocks and an observation block built here factor by factor with the noise
    # ranges read at the points the first solution predicts (the full build, at the initial
    # values, reads them at the measured points: on this log that changes the error)
    obs = _observations_at(prob, result, full.blocks["observations"].at(0))
    fg_fast, fg_full = fast.graph(), full.graph(observations=obs)
    assert full.graph().error(fast.values) != pytest.approx(fg_full.error(fast.values), rel=1e-6)
    assert fg_fast.error(fast.values) == pytest.approx(fg_full.error(fast.values), rel=1e-12)
    moved = gtsam.Values(fast.values)
    for i in range(len(prob.sensor_ids)):
        moved.update(S(i), full.values.atPose3(S(i)).retract(np.full(6, 1e-3)))
    assert fg_fast.error(moved) == pytest.approx(fg_full.error(moved), rel=1e-12)
    # the motion block is the first graph's own when its inputs stayed, else built anew
    assert (fast.blocks["motion"] is parts.blocks["motion"]) == (not excluded)
    assert fast.blocks["sensors"] is parts.blocks["sensors"]


def _odometry_solve():
    """A log with wheel odometry (the true path in an odometry frame of its own, 1 mm of random
    walk), its problem, first graph and a first solve of two iterations."""
    log = make_exact_log(seed=5, duration=30.0)
    rng = np.random.default_rng(5)
    t = log.robot["t"].to_numpy(float)
    odo = log.robot[["t", "x", "y", "yaw"]].copy()
    odo["x"] += 0.5 + 0.001 * rng.normal(size=len(t)).cumsum()
    log.odometry = odo
    rec = _exact_recipe(odometry=True)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    assert prob.odometry is not None
    parts = build_parts(log, prob)
    result, _ = optimize_graph(parts.graph(), parts.values, rec, max_iterations=2)
    return log, rec, prob, parts, result


def test_rebuild_rebuilds_the_motion_block_when_the_odometry_corrections_change():
    log, rec, prob, parts, result = _odometry_solve()
    same = rebuild_parts(log, prob, parts, result)
    assert same.blocks["motion"] is parts.blocks["motion"]
    prob.odometry_scale_correction = 0.01
    changed = rebuild_parts(log, prob, parts, result)
    assert changed.blocks["motion"] is not parts.blocks["motion"]
    assert changed.graph().error(changed.values) != pytest.approx(same.graph().error(same.values), rel=1e-9)


def test_squared_residuals_are_the_direct_ones_squared():
    rng = np.random.default_rng(1)
    for offset in (0.0, 1000.0):       # a scene about the origin, and one a kilometre away
        p = rng.normal(0.0, 2.0, (300, 3))
        q = rng.normal(0.0, 3.0, (300, 3)) + offset
        w = np.ones(5)
        R, t = rigid_from_moments(w, rng.normal(size=(5, 3)), rng.normal(size=(5, 3)) + offset,
                                  rng.normal(size=(5, 3, 3)))
        direct = _residuals(R, t, p, q) ** 2
        assert _squared_residuals(R, t, p, q) == pytest.approx(direct, abs=1e-9)
        # a hypothesis that explains every point exactly: zero, not a negative rounding
        exact = _squared_residuals(R[:1], t[:1], p, p @ R[0].T + t[0])
        assert np.all(exact >= 0.0) and np.max(exact) < 1e-12
    assert _squared_residuals(R, t, np.zeros((0, 3)), np.zeros((0, 3))).shape == (5, 0)


def test_pose_arrays_read_the_poses_as_one_lookup_per_key_does(first_solve):
    _, _, prob, _, result = first_solve
    keys = [X(k) for k in range(len(prob.pose_times))][::-3] + [S(i) for i in range(len(prob.sensor_ids))]
    R, t = pose_arrays(result, keys)
    R0 = np.stack([result.atPose3(k).rotation().matrix() for k in keys])
    t0 = np.stack([result.atPose3(k).translation() for k in keys])
    assert np.array_equal(R, R0) and np.array_equal(t, t0)
    # laid out alike, products of them are the same to the last digit (the profile's right-hand
    # sides are taken from them, and its steps amplify a last-digit change)
    assert np.array_equal(np.einsum("nji,njk->nik", R[:-1], R[1:]), np.einsum("nji,njk->nik", R0[:-1], R0[1:]))
    assert np.array_equal(np.einsum("nji,nj->ni", R[:-1], t[1:] - t[:-1]),
                          np.einsum("nji,nj->ni", R0[:-1], t0[1:] - t0[:-1]))
    R_empty, t_empty = pose_arrays(result, [])
    assert R_empty.shape == (0, 3, 3) and t_empty.shape == (0, 3)
    with pytest.raises(KeyError, match="x999999"):
        pose_arrays(result, [X(1), X(999999)])


def test_people_renumbered_after_sightings_are_left_out():
    # a sighting left out in the middle: the later people's variables move down one index, each
    # keeping its own solved point (not the one its new index held before)
    from pedcal.calib.factorgraph import people_renumbered
    from pedcal.calib.graph import L

    values = gtsam.Values()
    values.insert(S(0), gtsam.Pose3(gtsam.Rot3.Yaw(0.3), np.array([1.0, 2.0, 3.0])))
    values.insert(X(0), gtsam.Pose3())
    for m in range(4):
        values.insert(L(m), np.array([float(m), 10.0 + m, 1.7]))
    out = people_renumbered(values, np.array([0, 2, 3]))
    assert [np.asarray(out.atPoint3(L(m))).tolist() for m in range(3)] == [
        [0.0, 10.0, 1.7], [2.0, 12.0, 1.7], [3.0, 13.0, 1.7]]
    assert not out.exists(L(3))
    assert out.atPose3(S(0)).equals(values.atPose3(S(0)), 0.0)
    assert out.exists(X(0)) and out.size() == 5


def test_reestimate_starts_each_kept_person_at_its_own_solution(monkeypatch):
    # the re-solve after contradicted sightings are dropped starts every remaining person where
    # the first solve put that person
    import warnings

    from test_profile import shared_people_problem

    import pedcal.calib.factorgraph as fg
    from pedcal.calib.graph import L
    from pedcal.errors import DegenerateDataWarning

    sim, prob, parts = shared_people_problem()
    n = len(prob.people)
    assert n > 10
    # an AMCL model unlike the assumed one, so that the re-solve goes on to the people
    monkeypatch.setattr(fg, "estimate_model", lambda *a, **kw: _model(prob))
    result = parts.values
    bad = np.zeros(n, bool)
    bad[[1, 4]] = True                      # two sightings the solution "contradicts"
    monkeypatch.setattr(fg, "people_misfit", lambda prob, result: np.where(bad, np.inf, 0.0))
    seen = {}

    def capture(graph, values, rec, **kw):
        seen["values"] = values
        return values, 0

    monkeypatch.setattr(fg, "optimize_graph", capture)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        fg._reestimate_amcl(sim.calib, prob, parts, result, progress=False)
    assert len(prob.people) == n - 2
    kept = np.flatnonzero(~bad)
    for m in (0, 1, 3, n - 3):
        assert np.array_equal(np.asarray(seen["values"].atPoint3(L(m))), np.asarray(result.atPoint3(L(int(kept[m])))))


def _lm(fg, values, max_iterations: int, relative_error_tol: float):
    """GTSAM's Levenberg-Marquardt as optimize_graph configured it before: (result, iterations)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_error_tol)
    params.setLinearSolverType("SEQUENTIAL_CHOLESKY")
    params.setOrdering(fg.orderingCOLAMD())
    opt = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    return opt.optimize(), opt.iterations()


def test_optimize_graph_takes_levenberg_marquardts_steps(first_solve):
    # every step lowers the error: the undamped steps are LM's to a micrometre, and so is the count
    log, rec, prob, parts, _ = first_solve
    fg = parts.graph()
    for max_iterations, tol in ((3, 1e-5), (50, 1e-3), (50, 1e-5)):
        ours, n_ours = optimize_graph(fg, parts.values, rec, max_iterations=max_iterations,
                                      relative_error_tol=tol, gauss_newton_step=False)
        lm, n_lm = _lm(fg, parts.values, max_iterations, tol)
        assert n_ours == n_lm
        assert fg.error(ours) == pytest.approx(fg.error(lm), rel=1e-9)
        for key in [S(i) for i in range(len(prob.sensor_ids))] + [X(0), X(len(prob.pose_times) - 1)]:
            assert np.linalg.norm(ours.atPose3(key).translation() - lm.atPose3(key).translation()) < 1e-6


def _spy_linear_solvers(monkeypatch) -> list[str]:
    """The linear solver types the optimizers' parameters are given from now on, in order (GTSAM's
    Gauss-Newton and Levenberg-Marquardt parameters replaced by subclasses that record them)."""
    chosen = []

    def spy(base):
        class Spy(base):
            def setLinearSolverType(self, solver):
                chosen.append(solver)
                super().setLinearSolverType(solver)
        return Spy

    monkeypatch.setattr(gtsam, "GaussNewtonParams", spy(gtsam.GaussNewtonParams))
    monkeypatch.setattr(gtsam, "LevenbergMarquardtParams", spy(gtsam.LevenbergMarquardtParams))
    return chosen


def test_optimize_graph_eliminates_sequentially_up_to_a_size_with_the_same_steps(first_solve, monkeypatch):
    # sequential elimination on a graph up to SEQUENTIAL_MAX_VARIABLES variables, multifrontal
    # above: the same iterations and the same solution to rounding
    import pedcal.calib.profile as profile_mod

    log, rec, prob, parts, _ = first_solve
    fg = parts.graph()
    chosen = _spy_linear_solvers(monkeypatch)
    monkeypatch.setattr(profile_mod, "SEQUENTIAL_MAX_VARIABLES", parts.values.size())
    sequential, n_seq = optimize_graph(fg, parts.values, rec, max_iterations=3, gauss_newton_step=False)
    assert chosen and set(chosen) == {"SEQUENTIAL_CHOLESKY"}
    chosen.clear()
    monkeypatch.setattr(profile_mod, "SEQUENTIAL_MAX_VARIABLES", parts.values.size() - 1)
    multifrontal, n_multi = optimize_graph(fg, parts.values, rec, max_iterations=3, gauss_newton_step=False)
    assert chosen and set(chosen) == {"MULTIFRONTAL_CHOLESKY"}
    assert n_seq == n_multi > 0
    assert fg.error(sequential) == pytest.approx(fg.error(multifrontal), rel=1e-12)
    for key in [S(i) for i in range(len(prob.sensor_ids))] + [X(0), X(len(prob.pose_times) - 1)]:
        assert np.linalg.norm(sequential.atPose3(key).translation() - multifrontal.atPose3(key).translation()) < 1e-9


def test_optimize_graph_stops_on_the_predicted_remaining_decrease(first_solve):
    # with predicted_stop, the iterations stop once theta / (1 - theta) of the last decrease
    # (theta: its ratio to the one before) is below the tolerance, where LM's test, on the last
    # decrease itself, goes on one iteration more; the steps taken are the same
    log, rec, prob, parts, _ = first_solve
    fg = parts.graph()
    tol = 1e-3
    errors = [fg.error(parts.values)]
    for n in (1, 2):
        r, _ = optimize_graph(fg, parts.values, rec, max_iterations=n, relative_error_tol=1e-15,
                              gauss_newton_step=False)
        errors.append(fg.error(r))
    d1, d2 = errors[0] - errors[1], errors[1] - errors[2]
    theta = d2 / d1
    assert d2 > tol * errors[1]                         # (LM's test goes on after the second)
    assert theta / (1.0 - theta) * d2 <= tol * errors[2]
    plain, n_plain = optimize_graph(fg, parts.values, rec, relative_error_tol=tol, gauss_newton_step=False)
    ours, n_ours = optimize_graph(fg, parts.values, rec, relative_error_tol=tol, gauss_newton_step=False,
                                  predicted_stop=True)
    assert (n_plain, n_ours) == (3, 2)
    assert fg.error(ours) == pytest.approx(errors[2], rel=1e-12)


def _replayed_errors(errors):
    """A stand-in for GTSAM's Gauss-Newton optimizer whose error after k iterations is
    ``errors[k]`` (the last one from then on); its values never move."""
    class Replayed:
        def __init__(self, fg, values, params):
            self.k, self.v = 0, values

        def iterate(self):
            self.k += 1

        def error(self):
            return errors[min(self.k, len(errors) - 1)]

        def values(self):
            return self.v
    return Replayed


@pytest.mark.parametrize("errors, lm_stops_at, stops_at", [
    # theta 0.5: the remainder is the second decrease itself, 20 > 1.5 % of 1000 (where theta
    # alone, 10, would stop), so both stop at the third, 10 <= 1.5 % of 1000
    ([1060.0, 1020.0, 1000.0, 990.0, 985.0, 982.5], 3, 3),
    # theta 0.4: 2/3 of the second decrease to come, 13.3 <= 1.5 % of 1000 = 15, where LM's
    # test on the decrease itself (20 > 15.3) needs one iteration more
    ([1070.0, 1020.0, 1000.0, 992.0, 989.0], 3, 2),
    # a growing decrease (theta 1.5): no prediction (the series' sum, negative, is no bound);
    # LM's test alone
    ([1000.0, 960.0, 900.0, 899.0, 898.99], 3, 3),
])
def test_predicted_stop_sums_the_geometric_series_of_the_decreases(monkeypatch, errors, lm_stops_at, stops_at):
    # the error sequences scripted: the stop at theta / (1 - theta) of the last decrease, theta
    # its ratio to the one before, against 1.5 % of the error, and LM's own test beside it
    monkeypatch.setattr(gtsam, "GaussNewtonOptimizer", _replayed_errors(errors))
    counts = [optimize_graph(gtsam.NonlinearFactorGraph(), gtsam.Values(), GraphRecipe(), max_iterations=10,
                             gauss_newton_step=False, relative_error_tol=0.015, ordering=gtsam.Ordering(),
                             predicted_stop=predicted)[1] for predicted in (False, True)]
    assert counts == [lm_stops_at, stops_at]


def test_optimize_graph_hands_a_rising_step_to_levenberg_marquardt():
    # a point seen at 1 m straight ahead by a held sensor, started behind it: the undamped first
    # step raises the error (checked here), so LM goes on from the start and reaches its optimum
    from gtsam.symbol_shorthand import L

    fg = gtsam.NonlinearFactorGraph()
    fg.add(gtsam.PriorFactorPose3(S(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    fg.add(gtsam.PriorFactorPoint3(L(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 10.0)))
    fg.add(gtsam.BearingRangeFactor3D(S(0), L(0), gtsam.Unit3(np.array([1.0, 0.0, 0.0])), 1.0,
                                      gtsam.noiseModel.Isotropic.Sigma(3, 0.01)))
    values = gtsam.Values()
    values.insert(S(0), gtsam.Pose3())
    values.insert(L(0), np.array([-0.65179115, -0.17471729, 1.66372399]))
    gn = gtsam.GaussNewtonOptimizer(fg, values, gtsam.GaussNewtonParams())
    gn.iterate()
    assert gn.error() > fg.error(values)
    rec = GraphRecipe()
    result, iterations = optimize_graph(fg, values, rec, gauss_newton_step=False)
    lm, n_lm = _lm(fg, values, rec.max_iterations, rec.relative_error_tol)
    assert iterations == n_lm
    assert fg.error(result) == pytest.approx(fg.error(lm), abs=1e-9)
    assert np.allclose(result.atPoint3(L(0)), [1.0, 0.0, 0.0], atol=1e-3)


def test_kept_values_keeps_the_named_variables_alone():
    from gtsam.symbol_shorthand import A, L

    from pedcal.calib.graph import _kept_values

    values = gtsam.Values()
    for i in range(3):
        values.insert(S(i), gtsam.Pose3(gtsam.Rot3.Yaw(0.1 * i), np.array([i, 1.0, 3.0])))
    for k in range(5):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3.Yaw(-0.2 * k), np.array([0.5 * k, 2.0, 1.2])))
    values.insert(A(0), gtsam.Pose3())
    values.insert(L(1), np.array([1.0, 2.0, 1.7]))
    kept = _kept_values(values, {"s": 2, "x": 5})
    assert sorted(kept.keys()) == sorted([S(0), S(1)] + [X(k) for k in range(5)])
    for key in kept.keys():
        assert np.array_equal(kept.atPose3(key).matrix(), values.atPose3(key).matrix())
    assert values.size() == 10                       # the original untouched
    assert _kept_values(values, {}).size() == 0


def test_optimize_graph_goes_on_with_levenberg_marquardt_after_an_accepted_step():
    # a point seen by three robust (Cauchy) bearing-range views that disagree: the first undamped
    # step lowers the error, the second raises it (checked here); LM goes on from the first step's
    # values, as if started there
    from gtsam.symbol_shorthand import L

    rng = np.random.default_rng(42)
    fg = gtsam.NonlinearFactorGraph()
    fg.add(gtsam.PriorFactorPose3(S(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    fg.add(gtsam.PriorFactorPoint3(L(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 10.0)))
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0),
                                            gtsam.noiseModel.Isotropic.Sigma(3, 0.05))
    for d in rng.normal(size=(3, 3)):
        fg.add(gtsam.BearingRangeFactor3D(S(0), L(0), gtsam.Unit3(d), float(rng.uniform(0.5, 2)), robust))
    values = gtsam.Values()
    values.insert(S(0), gtsam.Pose3())
    values.insert(L(0), rng.normal(size=3))
    gn = gtsam.GaussNewtonOptimizer(fg, values, gtsam.GaussNewtonParams())
    gn.iterate()
    first = gtsam.Values(gn.values())
    gn.iterate()
    assert fg.error(first) < fg.error(values) and gn.error() > fg.error(first)
    rec = GraphRecipe()
    result, iterations = optimize_graph(fg, values, rec, gauss_newton_step=False)
    lm, n_lm = _lm(fg, first, rec.max_iterations - 1, rec.relative_error_tol)
    assert iterations == 1 + n_lm
    assert fg.error(result) == pytest.approx(fg.error(lm), abs=1e-9) and fg.error(result) < fg.error(first)
    assert np.allclose(result.atPoint3(L(0)), lm.atPoint3(L(0)), atol=1e-9)


def test_optimize_graph_hands_an_indeterminate_system_to_levenberg_marquardt():
    # two poses tied to each other alone: the undamped system has a free direction (GTSAM refuses
    # it, checked here), LM's damping holds it and meets the measurement
    fg = gtsam.NonlinearFactorGraph()
    Z = gtsam.Pose3(gtsam.Rot3.Yaw(0.3), np.array([1.0, 0.0, 0.0]))
    fg.add(gtsam.BetweenFactorPose3(X(0), X(1), Z, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(X(1), gtsam.Pose3(gtsam.Rot3.Yaw(0.1), np.array([0.5, 0.2, 0.0])))
    params = gtsam.GaussNewtonParams()
    params.setLinearSolverType("SEQUENTIAL_CHOLESKY")
    with pytest.raises(RuntimeError, match="Indeterminate"):
        gtsam.GaussNewtonOptimizer(fg, values, params).iterate()
    rec = GraphRecipe()
    result, iterations = optimize_graph(fg, values, rec, gauss_newton_step=False)
    lm, n_lm = _lm(fg, values, rec.max_iterations, rec.relative_error_tol)
    assert iterations == n_lm > 0
    assert fg.error(result) < 1e-12
    assert result.atPose3(X(0)).between(result.atPose3(X(1))).equals(Z, 1e-9)


def test_per_row_takes_each_names_value_once():
    # one value per row, each distinct name's computed once, in any order of first appearance;
    # no rows: an empty stack of the value's shape
    from pedcal.calib.problem import per_row

    calls = []
    values = {"s2": 2.0, "s1": 1.0, "s3": 3.0}
    names = np.array(["s2", "s1", "s2", "s3", "s1"], dtype=object)
    out = per_row(names, lambda n: (calls.append(n), values[n])[1])
    assert out.tolist() == [2.0, 1.0, 2.0, 3.0, 1.0]
    assert sorted(calls) == ["s1", "s2", "s3"]
    assert per_row(np.array([], dtype=object), values.get, (3, 3)).shape == (0, 3, 3)


def test_unique_rows_are_numpys_unique_over_rows():
    rng = np.random.default_rng(3)
    # repeated keys and scales, ties in the first column broken by the second, -0.0 and 0.0 alike
    a = np.column_stack([rng.integers(0, 6, 400).astype(float), rng.choice([0.25, 0.5, -0.0, 0.0, 1.0], 400)])
    uniq, inverse = unique_rows(a)
    want, want_inverse = np.unique(a, axis=0, return_inverse=True)
    np.testing.assert_array_equal(uniq, want)
    np.testing.assert_array_equal(inverse, np.asarray(want_inverse).ravel())
    np.testing.assert_array_equal(uniq[inverse], a)
    ints = rng.integers(-3, 3, (50, 2))
    np.testing.assert_array_equal(unique_rows(ints)[0], np.unique(ints, axis=0))
    empty_uniq, empty_inverse = unique_rows(np.zeros((0, 2)))
    assert empty_uniq.shape == (0, 2) and empty_inverse.shape == (0,)


@pytest.mark.parametrize("n", [1, 2, 7, 400])
@pytest.mark.parametrize("sigma", [0.2, 0.3, 1.0, 1.9, 2.5, 3.7, 25.0, 300.0])
def test_gaussian_smoothing_is_scipys_gaussian_filter1d_with_the_nearest_edges(n, sigma):
    # the kernel's radius int(4 sigma + 0.5) beyond the series' length (repeated end values) and
    # within it, below one sample (a kernel of 3) and a single sample; sigmas whose radius the
    # rounding's + 0.5 moves (0.2, 1.9, 3.7: 1, 8, 15 against 0, 7, 14 without it)
    from scipy.ndimage import gaussian_filter1d

    from pedcal.calib.common import gaussian_smooth_nearest

    v = 5.0 + np.cumsum(np.random.default_rng(n).standard_normal(n))
    got = gaussian_smooth_nearest(v, sigma)
    want = gaussian_filter1d(v, sigma, mode="nearest")
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12 * np.max(np.abs(v)))
    assert gaussian_smooth_nearest(np.zeros(0), sigma).shape == (0,)


def test_gaussian_smoothing_keeps_a_constant_and_takes_its_truncation():
    from pedcal.calib.common import gaussian_smooth_nearest

    np.testing.assert_allclose(gaussian_smooth_nearest(np.full(9, 3.5), 2.0), 3.5, rtol=1e-15)
    # a unit step at sample 10 of 21 seen from sample 0, 10 samples away: within the kernel's
    # reach at truncate 4 (radius 8 at sigma 2: not reached), at truncate 6 (radius 12: reached)
    step = (np.arange(21) >= 10).astype(float)
    assert gaussian_smooth_nearest(step, 2.0)[0] == 0.0
    assert gaussian_smooth_nearest(step, 2.0, truncate=6.0)[0] > 0.0


@pytest.mark.parametrize("n, size", [(1, 1), (11, 3), (11, 9), (12, 11), (50, 49), (300, 151)])
def test_running_median_is_scipys_median_filter_to_the_last_digit(n, size):
    from scipy.ndimage import median_filter

    from pedcal.calib.common import running_median_nearest

    rng = np.random.default_rng(size)
    e = rng.standard_normal((n, 2))
    e[rng.integers(0, n, max(n // 10, 1))] += 5.0                 # outliers the median ignores
    np.testing.assert_array_equal(running_median_nearest(e, size), median_filter(e, size=(size, 1), mode="nearest"))
    # a 1-D series alike, and ties (repeated values)
    r = np.round(e[:, 0])
    np.testing.assert_array_equal(running_median_nearest(r, size), median_filter(r, size=size, mode="nearest"))


def test_running_median_refuses_an_even_window_and_a_value_not_finite():
    from pedcal.calib.common import running_median_nearest

    with pytest.raises(ValueError, match="odd"):
        running_median_nearest(np.zeros((5, 2)), 4)
    # (pandas' rolling median spreads a NaN or an infinity over its window, where scipy's does
    # not: refused rather than silently different)
    for bad in (np.nan, np.inf):
        e = np.zeros((20, 2))
        e[7, 1] = bad
        with pytest.raises(ValueError, match="finite"):
            running_median_nearest(e, 5)
    assert running_median_nearest(np.zeros((0, 2)), 5).shape == (0, 2)


def test_the_odometry_at_the_pose_times_is_interpolated_once_and_again_for_new_times_or_odometry():
    from types import SimpleNamespace

    from pedcal.calib.common import interpolate_pose2

    t = np.linspace(0.0, 10.0, 21)
    odo = pd.DataFrame({"t": t, "x": 0.1 * t, "y": np.sin(t), "yaw": 0.05 * t})
    prob = SimpleNamespace(odometry=odo)
    times = np.array([0.5, 2.25, 7.0])
    first = _odometry_at(prob, times)
    np.testing.assert_array_equal(first, interpolate_pose2(odo, times))
    assert _odometry_at(prob, times.copy()) is first             # the same times: kept
    assert not first.flags.writeable                            # (shared: nobody may change it)
    other = _odometry_at(prob, times + 0.25)
    np.testing.assert_array_equal(other, interpolate_pose2(odo, times + 0.25))
    prob.odometry = odo.assign(x=odo["x"] + 1.0)                 # a new odometry: taken again
    np.testing.assert_allclose(_odometry_at(prob, times + 0.25)[:, 0], other[:, 0] + 1.0, rtol=0, atol=1e-12)


def test_amcls_estimates_are_read_once_per_robot_table_and_kept_read_only(noisy_solve):
    from pedcal.calib.graph import _amcl_measurements

    log, _, prob, _, _ = noisy_solve
    first = _amcl_measurements(log, prob)
    assert _amcl_measurements(log, prob) is first                 # the same table: kept
    t, yaw, cov, frames = first
    assert not (t.flags.writeable or yaw.flags.writeable or cov.flags.writeable) and isinstance(frames, tuple)
    order = np.argsort(log.robot["t"].to_numpy(float), kind="stable")
    np.testing.assert_array_equal(t, log.robot["t"].to_numpy(float)[order])
    np.testing.assert_array_equal(cov[:, 5], log.robot["cov_yawyaw"].to_numpy(float)[order])
    # the same table under another head offset: read again, its frames moved by the offset turned
    # by each estimate's heading
    shifted = dataclasses.replace(log, meta=dataclasses.replace(
        log.meta, head_offset_m=np.add(log.meta.head_offset_m, [0.1, 0.0, 0.0])))
    other = _amcl_measurements(shifted, prob)
    assert other is not first
    step = other[3][5].translation() - frames[5].translation()
    np.testing.assert_allclose(step, [0.1 * np.cos(yaw[5]), 0.1 * np.sin(yaw[5]), 0.0], rtol=0, atol=1e-12)
    # a new robot table (AMCL's jumps moved back, a copy): read again, from it
    moved = dataclasses.replace(log, robot=log.robot.assign(yaw=log.robot["yaw"] + 0.1))
    again = _amcl_measurements(moved, prob)
    assert again is not first
    np.testing.assert_allclose(again[1], yaw + 0.1, rtol=0, atol=1e-15)


def test_amcls_residuals_leave_out_a_sighting_at_the_sensors_origin(noisy_solve, monkeypatch):
    # a head point at (0, 0, 0) in the sensor's frame (a tracker's placeholder) has no ray to
    # shift the head model along: left out of the per-sensor residuals rather than turned into
    # a NaN the jump detector's running median would refuse
    from pedcal.calib.factorgraph import amcl_residuals

    log, _, prob, _, result = noisy_solve
    points = prob.head_points_sensor()
    j = int(np.flatnonzero((prob.fac_key_index < len(prob.pose_times)) & (prob.fac_sensor_index == 0))[0])
    monkeypatch.setattr(prob, "ray_shift_m", 0.02)
    # what it should give: the same residuals with sighting j's factor unused
    keys = prob.fac_key_index.copy()
    keys[j] = len(prob.pose_times)
    monkeypatch.setattr(prob, "fac_key_index", keys)
    want = amcl_residuals(log, prob, result)[2]
    monkeypatch.undo()
    zeroed = points.copy()
    zeroed[j] = 0.0
    monkeypatch.setattr(prob, "ray_shift_m", 0.02)
    monkeypatch.setattr(type(prob), "head_points_sensor", lambda self: zeroed)
    out = amcl_residuals(log, prob, result)[2]
    for (rows, e), (rows_want, e_want) in zip(out, want, strict=True):
        assert np.array_equal(rows, rows_want) and np.array_equal(e, e_want)


def test_the_first_profile_step_takes_its_block_at_the_solution_it_is_linearized_at(monkeypatch):
    # build_parts reads the observation block's noise ranges at the measured points (its initial
    # values are no solution); the profile's right-hand sides (ObservationRhs) read them at the
    # points the solution predicts. The first profile step after a solve must whiten A, b and B
    # alike: its step is the one of a block built at that solution (on this log the stale block's
    # step moved the ray shift 1.3 sigma further)
    import warnings

    import pedcal.calib.factorgraph as fgm
    from pedcal.errors import DegenerateDataWarning
    from pedcal.sim import simulate_logs

    sim = simulate_logs("paper", seed=0, duration_s=60.0, vary_nuisances="zoo")
    rec = GraphRecipe.load("default")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob = prepare(sim.calib, rec)
        parts = build_parts(sim.calib, prob)
        result, _ = optimize_graph(parts.graph(), parts.values, rec, max_iterations=10, relative_error_tol=1e-3)
    steps = []
    step_of = fgm.profile_step

    def both(*args, **kw):
        # (both before the loop moves the problem's nuisances: the blocks read them)
        # (the fresh block linearized by GTSAM, not taken from the terms of the one held)
        fresh = step_of(*args, **{**kw, "obs0": observation_block(sim.calib, prob, args[2]), "obs_linear": None})
        steps.append((step_of(*args, **kw), fresh))
        return steps[-1][0]

    monkeypatch.setattr(fgm, "profile_step", both)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        fgm._estimate_nuisances(sim.calib, prob, parts, result, max_steps=1, final_graph=False)
    (taken, fresh), = steps
    sigma = np.sqrt(np.diag(fresh.covariance))
    assert np.all(np.abs(taken.dtheta - fresh.dtheta) <= 1e-6 * sigma), (taken.dtheta - fresh.dtheta) / sigma


def test_rebuild_without_the_observation_block_holds_the_same_values():
    # the caller building the observation block next: the block left empty, the variables (the
    # people's at the given solution) those of the full rebuild; a solution missing a person's
    # position has the block built, for that person's initial one
    from test_profile import shared_people_problem

    from pedcal.calib.graph import L

    sim, prob, parts = shared_people_problem()
    assert len(prob.people) > 10
    result = gtsam.Values(parts.values)
    for m in (0, 3):
        result.update(L(m), result.atPoint3(L(m)) + np.array([0.1, -0.2, 0.05]))
    full = rebuild_parts(sim.calib, prob, parts, result)
    bare = rebuild_parts(sim.calib, prob, parts, result, observations=False)
    assert bare.blocks["observations"].size() == 0 < full.blocks["observations"].size()
    for name in BLOCKS:
        if name != "observations":
            assert bare.blocks[name].size() == full.blocks[name].size(), name
    assert sorted(bare.values.keys()) == sorted(full.values.keys())
    for key in full.values.keys():
        if chr(gtsam.Symbol(key).chr()) == "l":
            assert np.array_equal(bare.values.atPoint3(key), full.values.atPoint3(key))
        else:
            assert np.array_equal(bare.values.atPose3(key).matrix(), full.values.atPose3(key).matrix())
    assert np.array_equal(bare.values.atPoint3(L(3)), result.atPoint3(L(3)))
    missing = gtsam.Values(result)
    missing.erase(L(2))
    built = rebuild_parts(sim.calib, prob, parts, missing, observations=False)
    assert built.blocks["observations"].size() == full.blocks["observations"].size()
    assert built.values.exists(L(2))


@pytest.mark.parametrize("odometry, excluded", [(False, False), (False, True), (True, True)])
def test_the_rebuilt_graph_is_solved_again_only_when_the_motion_changed(request, monkeypatch, odometry, excluded):
    # with the profile's Gauss-Newton steps to follow, the graph rebuilt under AMCL's model is
    # left to them (its observation block too, which they build first), unless the model's jumps
    # changed the robot's motion (AMCL standing in for odometry): then LM solves it again first;
    # with wheel odometry, jumps left out change no motion
    import pedcal.calib.factorgraph as fg

    log, rec, prob, parts, result = _odometry_solve() if odometry else request.getfixturevalue("first_solve")
    assert (prob.odometry is not None) == odometry
    mask = None
    if excluded:
        mask = np.zeros(len(log.robot), bool)
        mask[10:25] = True
    monkeypatch.setattr(fg, "estimate_model", lambda *a, **kw: _model(prob, excluded=mask))
    calls = []
    monkeypatch.setattr(fg, "optimize_graph", lambda graph, values, rec, **kw: calls.append(kw) or (values, 3))
    rebuilt, _, iterations = fg._reestimate_amcl(log, prob, parts, result, progress=False, gauss_newton_step=False)
    assert (prob.amcl_model.excluded is not None) == excluded
    if excluded and not odometry:
        assert iterations == 3 and len(calls) == 1 and calls[0]["relative_error_tol"] == 1e-3
        assert not calls[0].get("predicted_stop", False)       # (LM's test alone: see the first solve's)
        assert rebuilt.blocks["observations"].size() > 0
    else:
        assert iterations == 0 and not calls
        assert rebuilt.blocks["observations"].size() == 0


@pytest.mark.parametrize("estimate_amcl_model, profiled", [(True, True), (False, True), (True, False)])
def test_only_the_first_solve_before_amcls_model_stops_on_the_predicted_remainder(monkeypatch, estimate_amcl_model,
                                                                                  profiled):
    # the first solve stops on the predicted remainder when the AMCL model is estimated from its
    # residuals (a re-solve follows, with the profile's Gauss-Newton steps), not when its result
    # is the one the final profile steps start from
    import pedcal.calib.factorgraph as fg
    from pedcal.calib import calibrate
    from pedcal.sim import simulate_logs

    class FirstSolve(Exception):
        pass

    def first(graph, values, rec, **kw):
        raise FirstSolve(kw)

    monkeypatch.setattr(fg, "optimize_graph", first)
    sim = simulate_logs("paper", seed=1)
    rec = GraphRecipe.load("default")
    rec.estimate_amcl_model = estimate_amcl_model
    rec.estimate_head_model = profiled          # (the head model held: no profile steps follow)
    assert fg._profiled(rec) is profiled and rec.amcl and rec.robot
    with pytest.raises(FirstSolve) as solve:
        calibrate(sim.calib, method="factorgraph", graph=rec)
    kw = solve.value.args[0]
    assert kw["predicted_stop"] is (estimate_amcl_model and profiled) and kw["gauss_newton_step"] is (not profiled)
    # (profiled: the first profile step follows before the model, 1 % of the error is enough;
    # not profiled, the re-solve under the model starts from it: 0.1 %; without the model's
    # re-solve, the recipe's own tolerance)
    assert kw["relative_error_tol"] == ((1e-2 if profiled else 1e-3) if estimate_amcl_model else None)
