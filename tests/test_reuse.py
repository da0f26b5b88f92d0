"""Quantities read once and handed on, against reading them again: the observation block's terms
taken by the right-hand sides, the AMCL track's steps by the assumed model, the sensor-frame
points by the closed form, the observations' sensor codes, the clock offsets read in one pass and
the poses a solution holds counted from its keys."""

import copy
import dataclasses

import gtsam
import numpy as np
import pandas as pd
import pytest
from test_amcl_model import _jumped, _robot_table, _wandering_track
from test_factorgraph import _exact_recipe, make_exact_log

from pedcal.calib.amcl_model import assumed_model, detect_steps, jumps_moved_back
from pedcal.calib.clocks import PREFIX, clock_offsets, clock_shift_sensor
from pedcal.calib.closedform import calibrate_closedform
from pedcal.calib.factorgraph import _count_held
from pedcal.calib.graph import (
    A,
    ObservationRhs,
    X,
    build_parts,
    observation_block,
    observation_block_terms,
    optimize_graph,
    prepare,
)
from pedcal.calib.problem import factorized, per_row
from pedcal.calib.recipe import GraphRecipe
from pedcal.model import Log


@pytest.fixture(scope="module")
def solved():
    log = make_exact_log(seed=4, duration=40.0)
    rec = _exact_recipe()
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    parts = build_parts(log, prob)
    result, _ = optimize_graph(parts.graph(), parts.values, rec, max_iterations=3)
    return log, prob, result


def test_the_blocks_terms_give_the_right_hand_side_read_anew(solved):
    log, prob, result = solved
    block, terms = observation_block_terms(log, prob, result)
    assert block.size() == observation_block(log, prob, result).size() > 100
    assert terms.robot_points is not None and terms.read_at[0] is result
    fresh, reused = ObservationRhs(log, prob, result), ObservationRhs(log, prob, result, terms=terms)
    rng = np.random.default_rng(0)
    n = len(terms.sensor) + (terms.prior is not None)
    for theta, scale in ((None, None), ({"ray_shift_m": 0.03, "horizontal_shift_m": -0.01}, None),
                         ({"curvature_m": 0.02}, np.exp(0.3 * rng.normal(size=n)))):
        a, b = fresh(theta, scale), reused(theta, scale)
        assert a.shape == b.shape and np.abs(a).max() > 0.0
        assert np.array_equal(a, b)            # the same arrays: bit for bit
    assert np.array_equal(fresh.factor_rows(), reused.factor_rows())
    assert np.array_equal(fresh.robot_factors(0), reused.robot_factors(0))


def test_terms_read_elsewhere_are_refused(solved):
    log, prob, result = solved
    _, terms = observation_block_terms(log, prob, result)
    with pytest.raises(ValueError, match="not read at these values"):
        ObservationRhs(log, prob, gtsam.Values(result), terms=terms)       # other values (a copy)
    with pytest.raises(ValueError, match="not read at these values"):
        ObservationRhs(log, prob, result, t_max=10.0, terms=terms)
    moved = dataclasses.replace(prob, ray_shift_m=prob.ray_shift_m + 0.01)
    with pytest.raises(ValueError, match="not read at these values"):
        ObservationRhs(log, moved, result, terms=terms)
    # other observations' keys (carried again) or other shared people: read again, not reused
    for field, value in (("fac_key_index", prob.fac_key_index.copy()), ("people", list(prob.people))):
        with pytest.raises(ValueError, match="not read at these values"):
            ObservationRhs(log, dataclasses.replace(prob, **{field: value}), result, terms=terms)
    # terms not read at any values (measured points, or given the regressors) carry no reading
    _, measured = observation_block_terms(log, prob, result, predicted=False)
    with pytest.raises(ValueError, match="not read at these values"):
        ObservationRhs(log, prob, result, terms=measured)


def test_assumed_model_takes_the_steps_jumps_moved_back_found():
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 200.0, 0.1)
    p = _wandering_track(rng, t)
    # AMCL 0.4 m off until 5 s, then a jump out and back (30-40 s): steps that pair in doubt,
    # found and left out by the model, not moved (tests/test_amcl_model.py)
    p[t < 5.0 - 1e-9] += [0.4, 0.0]
    p[(t >= 30.0 - 1e-9) & (t < 40.0 - 1e-9)] += [0.4, 0.0]
    robot = _robot_table(t, p).sample(frac=1.0, random_state=2).reset_index(drop=True)
    log = Log(sensors=None, robot=robot, observations=pd.DataFrame())
    rec = GraphRecipe.load("default")
    moved, n, steps = jumps_moved_back(log, rec.amcl_jump_threshold, rec.amcl_min_jump_m)
    assert moved is log and n == 0
    order = np.argsort(robot["t"].to_numpy(), kind="stable")
    expected = detect_steps(robot["t"].to_numpy()[order], robot[["x", "y"]].to_numpy()[order],
                            threshold=rec.amcl_jump_threshold, min_jump_m=rec.amcl_min_jump_m)
    assert np.array_equal(steps, expected) and steps.sum() >= 100
    a, b = assumed_model(robot, rec), assumed_model(robot, rec, steps=steps)
    assert a.excluded is not None and a.jumps >= 1
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        assert (x is None and y is None) or np.array_equal(x, y), f.name
    with pytest.raises(ValueError, match="step flags"):
        assumed_model(robot, rec, steps=steps[:-1])
    # a moved track returns its steps too (the caller looks for them again on the moved one), by
    # name as by place
    p2 = _wandering_track(np.random.default_rng(4), t)
    _jumped(p2, t, 60.0, 80.0, [0.4, 0.0])
    log2 = Log(sensors=None, robot=_robot_table(t, p2), observations=pd.DataFrame())
    res = jumps_moved_back(log2)
    moved2, n2, steps2 = res
    assert moved2 is not log2 and n2 == 1 and steps2.sum() == 200
    assert res.log is moved2 and res.jumps == 1 and res.steps is steps2


def test_closed_form_with_the_points_given_is_the_same():
    log = make_exact_log(seed=4, duration=40.0)
    mask = np.ones(len(log.observations), bool)
    a = calibrate_closedform(log, is_robot=mask, latency_s=0.0)
    b = calibrate_closedform(log, is_robot=mask, latency_s=0.0, points_sensor=log.observation_points_sensor())
    for s, u in zip(a.network, b.network, strict=True):
        assert np.array_equal(s.position_m, u.position_m) and np.array_equal(s.ypr_deg, u.ypr_deg)
    # the points given are the ones used: each sensor's points 0.1 m along its x move its estimate
    moved = calibrate_closedform(log, is_robot=mask, latency_s=0.0,
                                 points_sensor=log.observation_points_sensor() + [0.1, 0.0, 0.0])
    assert all(np.linalg.norm(s.position_m - u.position_m) > 0.05 for s, u in zip(a.network, moved.network, strict=True)
               if s.status == "ok")
    # and the association and the latency take them too (no mask, no latency given)
    c = calibrate_closedform(log)
    d = calibrate_closedform(log, points_sensor=log.observation_points_sensor())
    for s, u in zip(c.network, d.network, strict=True):
        assert np.array_equal(s.position_m, u.position_m)
    with pytest.raises(ValueError, match="points_sensor"):
        calibrate_closedform(log, is_robot=mask, latency_s=0.0, points_sensor=np.zeros((3, 3)))


def test_the_sensor_codes_are_pandas_factorize_computed_once(solved):
    names = np.array(["b", "a", "b", "c", "a"])
    codes, uniq = factorized(names)
    assert codes.tolist() == [0, 1, 0, 2, 1] and list(uniq) == ["b", "a", "c"]
    table = {"a": 1.0, "b": 2.0, "c": 3.0}
    assert per_row(names, table.get, codes=(codes, uniq)).tolist() == [2.0, 1.0, 2.0, 3.0, 1.0]
    _, prob, _ = solved
    first = prob.obs_sensor_codes()
    assert prob.obs_sensor_codes() is first
    assert np.array_equal(first[0], pd.factorize(prob.obs_sensor)[0])
    # (the names beside the codes: the ones they number)
    assert list(first[1]) == list(pd.factorize(prob.obs_sensor)[1])
    other = dataclasses.replace(prob)
    other.obs_sensor_codes()
    other.obs_sensor = prob.obs_sensor[::-1].copy()
    assert np.array_equal(other.obs_sensor_codes()[0], pd.factorize(other.obs_sensor)[0])


def test_clock_offsets_read_the_problems_and_thetas():
    class Prob:
        sensor_ids = ["s1", "s2", "s3"]

    prob = Prob()
    assert clock_offsets(prob, {}).tolist() == [0.0, 0.0, 0.0]
    setattr(prob, PREFIX + "s2", 0.02)
    assert clock_offsets(prob, {}).tolist() == [0.0, 0.02, 0.0]
    assert clock_offsets(prob, {PREFIX + "s2": -0.01, PREFIX + "s3": 0.5, "ray_shift_m": 1.0}).tolist() == [
        0.0, -0.01, 0.5]
    assert clock_shift_sensor(prob, {PREFIX + "s2": 0.0}, np.arange(4)) == 0.0     # none set: no shift
    assert np.isnan(clock_offsets(prob, {PREFIX + "s1": np.nan})[0])


def test_held_symbols_are_counted_from_the_keys():
    values = gtsam.Values()
    for k in range(5):
        values.insert(X(k), gtsam.Pose3())
    for j in (0, 1, 3):
        values.insert(A(j), gtsam.Pose3())
    assert _count_held(values, "x", 3) == 3
    assert _count_held(values, "x", 10) == 5
    assert _count_held(values, "a", 10) == 3
    assert _count_held(values, "a", 2) == 2
    assert _count_held(values, "l", 4) == 0
    assert _count_held(values, "x", 0) == 0


def test_the_clock_shift_kept_is_the_one_computed_again(solved):
    log, prob, result = solved
    prob = dataclasses.replace(prob)
    use = np.arange(len(prob.fac_p_sensor))
    names = [PREFIX + sid for sid in prob.sensor_ids]
    theta = {n: 0.01 * (i + 1) for i, n in enumerate(names)}
    first = clock_shift_sensor(prob, theta, use)
    again = clock_shift_sensor(prob, dict(theta, ray_shift_m=0.05), np.arange(len(use)))
    assert again is first and np.abs(first).max() > 0.0
    moved = clock_shift_sensor(prob, dict(theta, **{names[0]: 0.05}), use)
    assert moved is not first and not np.array_equal(moved, first)
    # each answer the computation's own: against a problem without any kept
    fresh = dataclasses.replace(prob)
    fresh.__dict__.pop("_clock_shift_last", None)
    assert np.array_equal(clock_shift_sensor(fresh, dict(theta, **{names[0]: 0.05}), use), moved)
    # other factors, or the solved velocities set, are asked anew
    assert clock_shift_sensor(prob, dict(theta, **{names[0]: 0.05}), use[:10]).shape == (10, 3)
    from pedcal.calib.clocks import solved_velocity_world
    clock_shift_sensor(prob, theta, use)          # (theta's answer kept last)
    prob._pose_velocity_world = solved_velocity_world(prob, result)
    solved_v = clock_shift_sensor(prob, theta, use)
    assert solved_v is not first and not np.array_equal(solved_v, first)
    # each other input replaced: asked anew, the answer a problem without any kept gives
    from pedcal.calib.motion import RobotMotion

    for field, value in (("fac_key_index", np.roll(prob.fac_key_index, 1)), ("pose_times", prob.pose_times + 0.3),
                         ("motion", RobotMotion(log, None))):
        kept = clock_shift_sensor(prob, theta, use)
        setattr(prob, field, value)
        changed = clock_shift_sensor(prob, theta, use)
        fresh = copy.copy(prob)             # (its solved velocities too: only the kept answer dropped)
        fresh.__dict__.pop("_clock_shift_last", None)
        assert changed is not kept and np.array_equal(changed, clock_shift_sensor(fresh, theta, use)), field


def _ordering(o: gtsam.Ordering) -> list:
    return [o.at(i) for i in range(o.size())]


def test_a_rebuild_of_the_same_structure_keeps_the_colamd_ordering(solved):
    from pedcal.calib.graph import rebuild_parts, set_amcl_model

    log, prob, result = solved
    prob = dataclasses.replace(prob)
    assert prob.recipe.amcl and not prob.people
    parts = build_parts(log, prob)
    first = parts.colamd()
    for observations in (False, True):
        same = rebuild_parts(log, prob, parts, result, observations=observations)
        assert same.ordering is first
        if not observations:
            same.blocks["observations"] = observation_block(log, prob, same.values)
        # (the ordering COLAMD gives the rebuilt graph itself)
        assert _ordering(same.graph().orderingCOLAMD()) == _ordering(first)
    carried = dataclasses.replace(prob, fac_key_index=prob.fac_key_index.copy())
    assert rebuild_parts(log, carried, parts, result).ordering is None
    # AMCL's error nodes spaced otherwise (a shorter correlation time, as a re-estimated model
    # may give): another node grid, its ordering computed anew
    regridded = dataclasses.replace(prob)
    shorter = dataclasses.replace(prob.amcl_model, correlation_s=prob.amcl_model.correlation_s / 8)
    set_amcl_model(log, regridded, shorter)
    assert len(regridded.amcl_node_times) != len(prob.amcl_node_times)
    assert rebuild_parts(log, regridded, parts, result, observations=False).ordering is None
    # AMCL's estimates left out as a jump: another structure, its ordering computed anew
    excluded = np.zeros(len(log.robot), bool)
    excluded[40:60] = True
    set_amcl_model(log, prob, dataclasses.replace(prob.amcl_model, excluded=excluded))
    other = rebuild_parts(log, prob, parts, result, observations=False)
    assert other.ordering is None
    # and a problem whose factors were carried again (new tables) keeps nothing either
    prob.fac_key_index = prob.fac_key_index.copy()
    assert rebuild_parts(log, prob, other, result).ordering is None


def test_group_medians_are_numpys_per_group():
    from pedcal.calib.factorgraph import group_medians

    rng = np.random.default_rng(0)
    for trial in range(30):
        n, m = int(rng.integers(1, 20)), int(rng.integers(0, 300))
        index, values = rng.integers(0, n, m), rng.normal(size=(m, 3)) ** 2
        if trial % 3 == 0 and m:
            values[rng.integers(0, m, 2), rng.integers(0, 3, 2)] = np.nan
        if trial % 5 == 0:
            values = np.round(values, 1)              # ties
        with np.errstate(invalid="ignore"):
            med, count = group_medians(values, index, n)
        for i in range(n):
            rows = np.flatnonzero(index == i)
            assert count[i] == len(rows)
            if len(rows):
                assert np.array_equal(med[i], np.median(values[rows], axis=0), equal_nan=True)
            else:
                assert np.isnan(med[i]).all()
    # pinned: odd and even counts
    med, count = group_medians(np.array([[3.0], [1.0], [2.0], [10.0], [4.0]]), np.array([0, 0, 0, 1, 1]), 3)
    assert med[:, 0].tolist()[:2] == [2.0, 7.0] and np.isnan(med[2, 0]) and count.tolist() == [3, 2, 0]
    # no rows at all (a graph without the robot): every group's NaN
    med, count = group_medians(np.zeros((0, 3)), np.zeros(0, int), 4)
    assert med.shape == (4, 3) and np.isnan(med).all() and count.tolist() == [0, 0, 0, 0]


def test_amcl_residuals_per_sensor_are_each_sensors_own_means(solved):
    # against the residuals one sensor at a time (its sightings mapped with its pose, averaged
    # per AMCL estimate), to the bit
    from pedcal.calib.factorgraph import S, amcl_residuals

    log, prob, result = solved
    t, res, per_sensor = amcl_residuals(log, prob, result)
    assert len(per_sensor) == len(prob.sensor_ids) and sum(len(u) for u, _ in per_sensor) > 50
    amcl = log.robot.sort_values("t", kind="stable")
    head_m = np.asarray(log.meta.head_offset_m, float)
    c, s_ = np.cos(amcl["yaw"].to_numpy(float)), np.sin(amcl["yaw"].to_numpy(float))
    z_xy = np.column_stack([amcl["x"].to_numpy(float) + c * head_m[0] - s_ * head_m[1],
                            amcl["y"].to_numpy(float) + s_ * head_m[0] + c * head_m[1]])
    times = prob.pose_times
    k = np.clip(np.searchsorted(times, t), 0, len(times) - 1)
    has = times[k] == t
    row_of_pose = np.full(len(times), -1)
    row_of_pose[k[has]] = np.flatnonzero(has)
    p = prob.head_points_sensor()
    p = p * (1.0 + prob.ray_shift_m / np.linalg.norm(p, axis=1))[:, None]
    for i in range(len(prob.sensor_ids)):
        m = np.flatnonzero((prob.fac_sensor_index == i) & (prob.fac_key_index < len(times)))
        rows = row_of_pose[prob.fac_key_index[m]]
        keep = rows >= 0
        rows = rows[keep]
        T = result.atPose3(S(i))
        seen = (p[m][keep] @ T.rotation().matrix().T + T.translation())[:, :2]
        u, inv = np.unique(rows, return_inverse=True)
        d = z_xy[rows] - seen
        mean = np.column_stack([np.bincount(inv, d[:, c], minlength=len(u)) for c in (0, 1)])
        mean = mean / np.bincount(inv, minlength=len(u))[:, None]
        assert np.array_equal(per_sensor[i][0], u) and np.array_equal(per_sensor[i][1], mean.reshape(-1, 2))


def test_the_noise_estimate_numbers_tracks_by_their_texts(solved):
    """An object track column whose tracks 7 and 7.0 alternate row by row: two tracks by their
    texts (as association numbers them), never one as pandas' factorization of the values would
    merge them; the estimate equals that of the same texts as strings, and differs from the
    one-track column's (its consecutive pairs are other pairs)."""
    from pedcal.calib.problem import estimate_observation_noise

    log, prob, _ = solved

    def with_tracks(values):
        other = copy.copy(log)
        other.observations = log.observations.copy()
        other.observations["track"] = pd.Series(values, index=log.observations.index, dtype=object)
        return other

    n = len(log.observations)
    mixed = [7 if k % 2 == 0 else 7.0 for k in range(n)]
    as_obj = estimate_observation_noise(with_tracks(mixed), prob)
    as_str = estimate_observation_noise(with_tracks([str(v) for v in mixed]), prob)
    one = estimate_observation_noise(with_tracks([7] * n), prob)
    assert as_obj is not None and as_obj == as_str
    assert one is None or one != as_obj
