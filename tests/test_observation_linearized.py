"""The observation block's linearization made in numpy from its terms
(ObservationRhs.linearized), against GTSAM's linearization of the block built from the same
terms; and the profile's steps that take it, without the block's factors, against the same steps
on the block GTSAM linearizes."""

import copy
import warnings

import gtsam
import numpy as np
import pytest
from test_profile import shared_people_problem, solved_graph

import pedcal.calib.factorgraph as fgm
from pedcal.calib.clocks import is_clock_nuisance
from pedcal.calib.graph import GraphRecipe, MotionRhs, ObservationRhs, S, build_parts, observation_block_terms, prepare
from pedcal.calib.keys import symbols
from pedcal.calib.profile import Columns, sparse_system, sqrt_weights
from pedcal.errors import DegenerateDataWarning
from pedcal.sim import simulate_logs


@pytest.fixture(scope="module")
def paper_robot():
    """Paper seed 3 with a 7 cm dome, the robot alone (no shared people), solved once."""
    sim = simulate_logs("paper", seed=3, head_point="dome", head_radius_m=0.07)
    rec = GraphRecipe.load("default")
    rec.people = False
    rec.estimate_amcl_model = False
    return (sim, rec, *solved_graph(sim.calib, rec))


def _both(log, prob, values):
    """(GTSAM's (A, b) of the block built at ``values``, the terms' own (A, b))."""
    block, terms = observation_block_terms(log, prob, values)
    cols = Columns.of(values)
    gtsams = sparse_system(block.linearize(values), cols)
    return gtsams, ObservationRhs(log, prob, values, terms=terms).linearized(cols)


@pytest.mark.parametrize("kernel", ["huber", "cauchy", "none"])
def test_linearized_equals_gtsams_linearization_of_the_block(paper_robot, kernel):
    sim, rec, prob, parts, result = paper_robot
    prob = copy.copy(prob)
    prob.recipe = copy.copy(rec)
    prob.recipe.robust_kernel = kernel
    prob.recipe.robust_k = 0.5              # (many factors beyond it: the reweighting matters)
    # away from the solution, so that the errors are large and every factor's weight differs
    values = result.retract(_random_delta(result, 0.005, seed=2))
    (A, b), (A_ours, b_ours) = _both(sim.calib, prob, values)
    assert A.shape == A_ours.shape and A.shape[0] > 3000
    # the same pattern (the entries GTSAM leaves out as at most 1e-12 left out too), values to rounding
    assert np.array_equal(A.indptr, A_ours.indptr) and np.array_equal(A.indices, A_ours.indices)
    assert np.abs(A.data - A_ours.data).max() <= 1e-11 * np.abs(A.data).max()
    assert np.abs(b).max() > 1.0 and np.abs(b - b_ours).max() < 1e-8
    # the head offset's prior leads (6 rows), then 3 per observation
    assert A[:6].nnz > 0 and A.shape[0] == 6 + 3 * (prob.fac_key_index < len(prob.pose_times)).sum()
    if kernel != "none":
        plain = copy.copy(prob)
        plain.recipe = copy.copy(prob.recipe)
        plain.recipe.robust_kernel = "none"
        (A_plain, _), _ = _both(sim.calib, plain, values)
        # (the weights below 1 on many factors' rows: the reweighting was exercised)
        assert np.mean(np.abs(A.data) < (1.0 - 1e-6) * np.abs(A_plain.data)) > 0.1


def _random_delta(values, sd, seed):
    rng = np.random.default_rng(seed)
    delta = gtsam.VectorValues()
    for key, dim in values.dims().items():
        delta.insert(key, rng.normal(0.0, sd, int(dim)))
    return delta


def test_linearized_is_refused_where_gtsams_must_linearize(paper_robot):
    sim, rec, prob, parts, result = paper_robot
    cols = Columns.of(result)
    block, terms = observation_block_terms(sim.calib, prob, result)
    assert ObservationRhs(sim.calib, prob, result, terms=terms).linearized(cols) is not None
    # (terms read at other values or at the measured points are refused when the rhs is made: test_reuse.py)
    # a kernel whose weights it does not make (Tukey's)
    tukey = copy.copy(prob)
    tukey.recipe = copy.copy(rec)
    tukey.recipe.robust_kernel = "tukey"
    _, t_terms = observation_block_terms(sim.calib, tukey, result)
    assert ObservationRhs(sim.calib, tukey, result, terms=t_terms).linearized(cols) is None
    # shared people's sightings (bearing-range factors to points)
    sim_p, prob_p, parts_p = shared_people_problem()
    _, p_terms = observation_block_terms(sim_p.calib, prob_p, parts_p.values)
    assert (~p_terms.is_pose).sum() > 100
    assert ObservationRhs(sim_p.calib, prob_p, parts_p.values, terms=p_terms).linearized(
        Columns.of(parts_p.values)) is None
    # the robot's observations and people's sightings in one block (the robot's tracks before the
    # median time, the later ones people's): the robot's terms are there, the people refuse it
    sim_m = simulate_logs("paper", seed=0)
    t = sim_m.calib.observations["t"].to_numpy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob_m = prepare(sim_m.calib, GraphRecipe.load("default"), is_robot=t < np.median(t))
        parts_m = build_parts(sim_m.calib, prob_m)
    _, m_terms = observation_block_terms(sim_m.calib, prob_m, parts_m.values)
    assert m_terms.robot_points is not None and m_terms.is_pose.sum() > 1000 and (~m_terms.is_pose).sum() > 100
    assert m_terms.robust and prob_m.recipe.robust_kernel.lower() == "huber"
    assert ObservationRhs(sim_m.calib, prob_m, parts_m.values, terms=m_terms).linearized(
        Columns.of(parts_m.values)) is None


def _nuisances(sim, prob, parts, result, monkeypatch, gtsams: bool, motions: list | None = None, **kw):
    """_estimate_nuisances on copies, counting the observation blocks made (and the odometry's
    blocks, into ``motions``); ``gtsams``: every step's blocks made and linearized by GTSAM (the
    terms' own linearization refused, the odometry's block built and linearized)."""
    prob, parts = copy.deepcopy(prob), copy.copy(parts)
    parts.blocks = dict(parts.blocks)
    made = []
    build, build_motion = fgm.observation_graph, fgm.motion_block

    def counted(p, terms):
        made.append(terms)
        return build(p, terms)

    def counted_motion(*args, **kw):
        if motions is not None and "theta" not in kw:
            motions.append(1)
        return build_motion(*args, **kw)

    monkeypatch.setattr(fgm, "observation_graph", counted)
    monkeypatch.setattr(fgm, "motion_block", counted_motion)
    if gtsams:
        monkeypatch.setattr(ObservationRhs, "linearized", lambda self, cols: None)
        init = MotionRhs.__init__

        def keeping(self, log, p, values, **kw):
            init(self, log, p, values, **kw)
            self.kept_values = values

        monkeypatch.setattr(MotionRhs, "__init__", keeping)
        monkeypatch.setattr(MotionRhs, "linearized", lambda self, cols: sparse_system(
            counted_motion(self.log, self.prob).linearize(self.kept_values), cols))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        shifts = fgm._estimate_nuisances(sim.calib, prob, parts, result, **kw)
    monkeypatch.undo()
    return shifts, prob, parts, made


def test_profile_steps_without_the_blocks_factors_equal_gtsams(paper_robot, monkeypatch):
    sim, rec, prob, parts, result = paper_robot
    parts.colamd()              # (the solver's ordering kept, as the calibration keeps it: no block made for it)
    assert prob.odometry is not None and rec.estimate_odometry_errors    # (the odometry's corrections profiled)
    motions, motions_gtsam = [], []
    ours, prob_ours, parts_ours, made = _nuisances(sim, prob, parts, result, monkeypatch, gtsams=False,
                                                   motions=motions, odometry=True)
    theirs, prob_theirs, _, made_gtsam = _nuisances(sim, prob, parts, result, monkeypatch, gtsams=True,
                                                    motions=motions_gtsam, odometry=True)
    assert ours.solves == theirs.solves >= 2
    # the block made once, for the final graph (GTSAM's way: once per step, and the final one);
    # the odometry's once, at the final corrections (GTSAM's: every step's)
    assert len(made) == 1 and len(made_gtsam) == ours.solves + 1
    assert len(motions) == 1 and len(motions_gtsam) >= ours.solves + 1
    assert prob_ours.odometry_scale_correction != 0.0
    for name in ("ray_shift_m", "horizontal_shift_m", "odometry_scale_correction", "odometry_drift_rad_per_m"):
        assert getattr(prob_ours, name) == pytest.approx(getattr(prob_theirs, name), abs=1e-10)
    assert np.abs(ours.cov - theirs.cov).max() <= 1e-8 * np.abs(theirs.cov).max()
    for i in range(len(prob.sensor_ids)):
        T, U = ours.result.atPose3(S(i)), theirs.result.atPose3(S(i))
        assert np.abs(T.translation() - U.translation()).max() < 1e-9
    # the final graph holds the block at the final values: GTSAM's block built there anew
    block, _ = observation_block_terms(sim.calib, prob_ours, ours.result)
    assert parts_ours.blocks["observations"].size() == block.size() > 1000
    assert parts_ours.blocks["observations"].error(ours.result) == pytest.approx(block.error(ours.result), rel=1e-12)
    assert ours.graph.size() == theirs.graph.size()
    motion = fgm.motion_block(sim.calib, prob_ours)
    assert parts_ours.blocks["motion"].size() == motion.size() > 100
    assert parts_ours.blocks["motion"].error(ours.result) == pytest.approx(motion.error(ours.result), rel=1e-12)


def test_motion_linearized_equals_gtsams_linearization_of_the_block(paper_robot):
    sim, rec, prob, parts, result = paper_robot
    prob = copy.copy(prob)
    # the odometry's corrections away from 0 and the poses off the solution: large errors, turns
    prob.odometry_scale_correction, prob.odometry_drift_rad_per_m = 0.02, np.radians(0.5)
    values = result.retract(_random_delta(result, 0.02, seed=5))
    cols = Columns.of(values)
    A, b = sparse_system(fgm.motion_block(sim.calib, prob).linearize(values), cols)
    A_ours, b_ours = MotionRhs(sim.calib, prob, values).linearized(cols)
    assert A.shape == A_ours.shape and A.shape[0] > 600
    assert np.array_equal(A.indptr, A_ours.indptr) and np.array_equal(A.indices, A_ours.indices)
    # (the Logmap's derivative GTSAM's own: its Jacobians to rounding)
    assert np.abs(A.data - A_ours.data).max() <= 1e-13 * np.abs(A.data).max()
    assert np.abs(b).max() > 1.0 and np.abs(b - b_ours).max() < 1e-9 * np.abs(b).max()


def test_a_pass_whose_graph_is_rebuilt_leaves_the_block_empty_unmade(paper_robot, monkeypatch):
    # (final_graph False: the caller rebuilds; the step took the terms' linearization)
    sim, rec, prob, parts, result = paper_robot
    shifts, _, parts_out, made = _nuisances(sim, prob, parts, result, monkeypatch, gtsams=False, max_steps=1,
                                            final_graph=False)
    assert shifts.graph is None and made == []
    assert parts_out.blocks["observations"].size() == 0


def test_people_in_the_block_have_it_made_and_linearized_by_gtsam(monkeypatch):
    # shared people's sightings: the terms cannot make the linearization, each step's block is made
    sim, prob, parts = shared_people_problem()
    rec = prob.recipe
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        result, _ = fgm.optimize_graph(parts.graph(), parts.values, rec, max_iterations=3)
    shifts, _, _, made = _nuisances(sim, prob, parts, result, monkeypatch, gtsams=False, max_steps=2)
    assert len(made) == shifts.solves + 1


def test_every_steps_linearization_and_its_residuals_agree_through_two_passes(monkeypatch):
    # paper seed 5 with the default recipe: two nuisance passes (the AMCL model's re-solve between
    # them) with every sensor's clock offset profiled; at each step, the b of the block's
    # linearization (its robust weights in it) is the right-hand side its B's columns are
    # differences of, at the same theta and weights (a clock offset's regressor read at another
    # velocity than the linearization's would part them)
    sim = simulate_logs("paper", seed=5)
    step, passes, gaps = fgm.profile_step, [], []

    def estimate(*args, **kw):
        passes.append(len(gaps))
        return nuisances(*args, **kw)

    def checked(fixed, observations, values, theta, nuisances, cols, **kw):
        A_o, b_o = kw["obs_linear"]()
        rows = kw["factor_rows"]
        assert rows[-1] == len(b_o) > 3000
        sqrt_w = sqrt_weights(np.sqrt(np.add.reduceat(b_o ** 2, rows[:-1])), *kw["kernel"])
        sqrt_w[:kw["plain_leading"]] = 1.0
        b_ref = kw["residuals"](theta, 1.0 / np.maximum(sqrt_w, 1e-12))
        gaps.append((np.abs(b_o - b_ref).max(), np.abs(b_o).max(), sum(is_clock_nuisance(n.name) for n in nuisances)))
        return step(fixed, observations, values, theta, nuisances, cols, **kw)

    nuisances = fgm._estimate_nuisances
    monkeypatch.setattr(fgm, "_estimate_nuisances", estimate)
    monkeypatch.setattr(fgm, "profile_step", checked)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fgm.calibrate_factorgraph(sim.calib, graph="default")
    gaps = np.array(gaps)
    # two passes, the second of several steps, each step with every clock offset
    assert len(passes) == 2 and len(gaps) - passes[1] >= 2 and np.all(gaps[:, 2] == len(sim.calib.sensors.sensors))
    assert gaps[:, 1].min() > 1.0 and gaps[:, 0].max() < 1e-9


def _tiny(jacobian: np.ndarray) -> int:
    """How many entries of a factor's dense Jacobian GTSAM's sparse export leaves out as near-zero."""
    return int(np.sum((np.abs(jacobian) > 0.0) & (np.abs(jacobian) <= 1e-12)))


def test_the_near_zero_entries_gtsam_leaves_out_are_left_out(paper_robot):
    sim, rec, prob, parts, result = paper_robot
    # an observation's predicted point 1e-15 m off its sensor's y-z plane: its direction's Unit3
    # basis (the x axis the smallest component's) has entries ~1e-15, as have its Jacobian's rows
    values = gtsam.Values(result)
    block, terms = observation_block_terms(sim.calib, prob, values)
    i = 100
    rhs = ObservationRhs(sim.calib, prob, values, terms=terms)
    d = rhs.u_pred[i] * rhs.range_pred[i]
    key = int(symbols("x", [terms.target[i]])[0])
    X, R_s = values.atPose3(key), values.atPose3(S(int(terms.sensor[i]))).rotation().matrix()
    values.update(key, gtsam.Pose3(X.rotation(), X.translation() - (d[0] - 1e-15) * R_s[:, 0]))
    block, terms = observation_block_terms(sim.calib, prob, values)
    assert _tiny(block.at(rhs.first + i).linearize(values).jacobian()[0]) >= 3
    cols = Columns.of(values)
    A, b = sparse_system(block.linearize(values), cols)
    A_ours, b_ours = ObservationRhs(sim.calib, prob, values, terms=terms).linearized(cols)
    assert np.array_equal(A.indptr, A_ours.indptr) and np.array_equal(A.indices, A_ours.indices)
    assert np.abs(A.data - A_ours.data).max() <= 1e-11 * np.abs(A.data).max()
    # the robot's poses level (roll 0, z 0), every other one pitched 3e-16 rad: the odometry's
    # Jacobians hold entries ~1e-15 where a level pair's are 0
    for k in range(len(prob.pose_times)):
        key = int(symbols("x", [k])[0])
        X = values.atPose3(key)
        values.update(key, gtsam.Pose3(gtsam.Rot3.Ypr(X.rotation().yaw(), 3e-16 * (k % 2), 0.0),
                                       np.r_[X.translation()[:2], 0.0]))
    motion = fgm.motion_block(sim.calib, prob)
    assert sum(_tiny(motion.at(j).linearize(values).jacobian()[0]) for j in range(motion.size())) > 1000
    A, b = sparse_system(motion.linearize(values), cols)
    A_ours, b_ours = MotionRhs(sim.calib, prob, values).linearized(cols)
    assert np.array_equal(A.indptr, A_ours.indptr) and np.array_equal(A.indices, A_ours.indices)
    assert np.abs(A.data - A_ours.data).max() <= 1e-11 * np.abs(A.data).max()


def test_an_ordering_to_compute_is_computed_from_the_held_block(paper_robot, monkeypatch):
    # no ordering kept, the block built before the solve held: its structure is the one the
    # ordering needs, no block made at the solution for it (a pass whose graph is rebuilt: none)
    sim, rec, prob, parts, result = paper_robot
    parts = copy.copy(parts)
    parts.ordering = None
    assert parts.blocks["observations"].size() > 1000
    shifts, _, parts_out, made = _nuisances(sim, prob, parts, result, monkeypatch, gtsams=False, max_steps=1,
                                            final_graph=False)
    assert made == [] and parts_out.ordering is not None
