"""The sensors' noise estimated from consecutive observations of the robot
(pedcal.calib.problem.estimate_observation_noise): a tracker whose noise is correlated frame to
frame (a filtered track) is no longer taken for a quieter one."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from pedcal.calib.problem import estimate_observation_noise, prepare
from tests.test_factorgraph import _exact_recipe, make_exact_log

SIGMA_RANGE_M = 0.02
SIGMA_LATERAL_M = 0.012


def _noisy_log(rho: float, seed: int = 3, kind: str = "stops"):
    """The exact log (its robot standing still 3 s of every 8 with ``kind`` "stops": the
    correlation is read while it stands) with an AR(1) noise of coefficient ``rho`` frame to frame
    added in each sensor's frame (stationary: each frame's std SIGMA_RANGE_M along the ray,
    SIGMA_LATERAL_M across), mapped to the world with the installed extrinsics the observations
    were made with."""
    log = make_exact_log(seed=seed, kind=kind, duration=160.0)
    rng = np.random.default_rng(seed + 100)
    obs = log.observations.copy()
    p_w = obs[["x", "y", "z"]].to_numpy(float)
    out = p_w.copy()
    for sid in obs["sensor"].unique():
        rows = np.flatnonzero(obs["sensor"].to_numpy() == sid)
        rows = rows[np.argsort(obs["t"].to_numpy(float)[rows], kind="stable")]
        ext = log.sensors[sid]
        p_s = ext.to_sensor(p_w[rows])
        u = p_s / np.linalg.norm(p_s, axis=1, keepdims=True)
        a = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        b1 = np.cross(u, a)
        b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
        b2 = np.cross(u, b1)
        # AR(1): e_k = rho e_{k-1} + sqrt(1 - rho^2) w_k, stationary std 1
        w = rng.normal(size=(len(rows), 3))
        e = np.zeros_like(w)
        e[0] = w[0]
        for k in range(1, len(rows)):
            e[k] = rho * e[k - 1] + np.sqrt(1.0 - rho ** 2) * w[k]
        noise = (SIGMA_RANGE_M * e[:, :1] * u + SIGMA_LATERAL_M * e[:, 1:2] * b1 + SIGMA_LATERAL_M * e[:, 2:] * b2)
        out[rows] = ext.to_world(p_s + noise)
    obs[["x", "y", "z"]] = out
    noisy = copy.copy(log)
    noisy.observations = obs
    return noisy


def _estimate(rho: float):
    log = _noisy_log(rho)
    rec = _exact_recipe(estimate_observation_noise=True, reliable_range_m=10.0)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    est = estimate_observation_noise(log, prob)
    assert est is not None
    return est


def _depth_sigma(est: dict, range_m: float = 3.0) -> float:
    return est["range_sigma_floor_m"] + est["range_sigma_k_per_m"] * range_m ** 2


@pytest.mark.parametrize("rho", [0.0, 0.3, 0.5])
def test_a_frame_to_frame_correlated_noise_is_estimated_at_its_own_size(rho):
    """Each frame's noise std is recovered within 15 % whatever its correlation (one frame's
    difference alone gives sqrt(1 - rho) of it: 0.71 at 0.5), the correlation within 0.12 (read
    from the runs of reports while the robot stood, a few hundred pairs)."""
    est = _estimate(rho)
    assert est["still_pairs"] >= 100                  # (read while the robot stood)
    assert _depth_sigma(est) == pytest.approx(SIGMA_RANGE_M, rel=0.15)
    assert est["lateral_sigma_m"] == pytest.approx(SIGMA_LATERAL_M, rel=0.15)
    assert est["frame_correlation"]["along"] == pytest.approx(rho, abs=0.12)
    assert est["frame_correlation"]["lateral"] == pytest.approx(rho, abs=0.12)


def test_a_strongly_smoothed_track_is_no_longer_taken_for_a_quiet_one():
    """At a correlation of 0.8 one frame's difference gives 0.45 of the noise; the estimate is
    within 20 % of it (the correlation's own error weighs most there, as 1 / (1 - rho)), the
    correlation within 0.1."""
    est = _estimate(0.8)
    assert _depth_sigma(est) == pytest.approx(SIGMA_RANGE_M, rel=0.2)
    assert est["lateral_sigma_m"] == pytest.approx(SIGMA_LATERAL_M, rel=0.2)
    assert est["frame_correlation"]["along"] == pytest.approx(0.8, abs=0.1)
    assert est["frame_correlation"]["lateral"] == pytest.approx(0.8, abs=0.1)


def test_the_correlation_scales_one_frames_variance_by_one_over_one_less_it(monkeypatch):
    """The formula pinned: with the correlation rho read from the still robot's reports, the
    depth and lateral sigmas are one frame's difference's (as the estimate without correlation
    gives them, the AR(1) set to 0 by a cap of 0) over sqrt(1 - rho)."""
    import pedcal.calib.problem as problem

    log = _noisy_log(0.6)
    rec = _exact_recipe(estimate_observation_noise=True, reliable_range_m=10.0)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    est = estimate_observation_noise(log, prob)
    monkeypatch.setattr(problem, "MAX_NOISE_RHO", 0.0)
    one_frame = estimate_observation_noise(log, prob)
    rho_a, rho_l = est["frame_correlation"]["along"], est["frame_correlation"]["lateral"]
    assert 0.4 < rho_a < 0.8 and 0.4 < rho_l < 0.8
    assert one_frame["frame_correlation"] == {"along": 0.0, "lateral": 0.0}
    assert est["lateral_sigma_m"] == pytest.approx(one_frame["lateral_sigma_m"] / np.sqrt(1.0 - rho_l), rel=1e-3)
    assert _depth_sigma(est) == pytest.approx(_depth_sigma(one_frame) / np.sqrt(1.0 - rho_a), rel=1e-3)


def test_a_correlated_trackers_factors_are_widened_by_the_root_of_its_long_run_variance_factor():
    """noise_correlation_factor: sqrt of the mean over depth and lateral of (1 + rho) / (1 - rho),
    pinned; 1 without an estimate or for white noise."""
    from pedcal.calib.graph import noise_correlation_factor

    assert noise_correlation_factor(None) == 1.0
    assert noise_correlation_factor({"range_sigma_floor_m": 0.01}) == 1.0
    assert noise_correlation_factor({"frame_correlation": {"along": 0.0, "lateral": 0.0}}) == 1.0
    got = noise_correlation_factor({"frame_correlation": {"along": 0.6, "lateral": 0.2}})
    assert got == pytest.approx(np.sqrt(0.5 * (1.6 / 0.4 + 1.2 / 0.8)), rel=1e-12)


def test_the_observation_factors_carry_the_factor():
    """The observation block's robot factors take their sigmas times the factor (here of a given
    correlation: 0.5 along, 0.3 across) over the root of their merged count; the recipe's noise
    stays one report's."""
    from pedcal.calib.graph import observation_terms

    log = _noisy_log(0.7)
    rec = _exact_recipe(estimate_observation_noise=True, reliable_range_m=10.0)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    assert prob.recipe.range_sigma_floor_m == prob.noise_estimate["range_sigma_floor_m"]
    prob.noise_estimate = {**prob.noise_estimate, "frame_correlation": {"along": 0.5, "lateral": 0.3}}
    terms = observation_terms(log, prob)
    count = np.asarray(prob.fac_count[prob.fac_key_index < len(prob.pose_times)], float)
    want = np.sqrt(0.5 * (1.5 / 0.5 + 1.3 / 0.7)) / np.sqrt(count)
    np.testing.assert_allclose(terms.noise_scale[terms.is_pose], want, rtol=1e-12)


def test_people_sightings_take_the_correlation_a_sampling_period_apart():
    """The observation block's people factors, one sighting per people_sample_s, take the factor at
    the correlation people_sample_s / frame_period_s reports apart (the robot's, one report
    apart, unchanged); without a frame period in the estimate, the robot's."""
    from pedcal.calib.graph import noise_correlation_factor, observation_terms

    log = _noisy_log(0.7)
    rec = _exact_recipe(estimate_observation_noise=True, reliable_range_m=10.0, people=True)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    # three people, each seen by two sensors at once (points in each sensor's frame)
    sids = prob.sensor_ids[:2]
    prob.people = [(10.0 + m, [(sids[0], np.array([0.3 * m, 0.2, -2.5])), (sids[1], np.array([-0.4, 0.1 * m, -2.6]))])
                   for m in range(3)]
    est = {**prob.noise_estimate, "frame_correlation": {"along": 0.5, "lateral": 0.3}, "frame_period_s": 0.125}
    prob.noise_estimate = est
    terms = observation_terms(log, prob)
    people = ~terms.is_pose
    assert people.sum() == 6
    gap = prob.recipe.people_sample_s / 0.125
    want = np.sqrt(0.5 * ((1 + 0.5 ** gap) / (1 - 0.5 ** gap) + (1 + 0.3 ** gap) / (1 - 0.3 ** gap)))
    assert noise_correlation_factor(est, gap) == pytest.approx(want, rel=1e-12)
    np.testing.assert_allclose(terms.noise_scale[people], want, rtol=1e-12)
    count = np.asarray(prob.fac_count[prob.fac_key_index < len(prob.pose_times)], float)
    np.testing.assert_allclose(terms.noise_scale[terms.is_pose], noise_correlation_factor(est) / np.sqrt(count),
                               rtol=1e-12)
    prob.noise_estimate = {k: v for k, v in est.items() if k != "frame_period_s"}
    np.testing.assert_allclose(observation_terms(log, prob).noise_scale[people], noise_correlation_factor(est),
                               rtol=1e-12)


def test_sightings_further_apart_take_the_correlation_that_many_reports_apart():
    from pedcal.calib.graph import noise_correlation_factor

    est = {"frame_correlation": {"along": 0.6, "lateral": 0.6}}
    assert noise_correlation_factor(est, gap_frames=3.0) == pytest.approx(np.sqrt(1.216 / 0.784), rel=1e-12)
    assert noise_correlation_factor(est, gap_frames=0.5) == noise_correlation_factor(est)      # (at least one)


def test_a_merged_factors_variance_is_that_of_its_correlated_reports_mean():
    """g_c pinned: 1 for one report or white noise, 1 + 2 (2/3 rho + 1/3 rho^2) = 2.04 for three at
    0.6, toward (1 + rho) / (1 - rho) for many, and equal to a direct sum over lags."""
    from pedcal.calib.graph import merged_variance_factor

    assert merged_variance_factor(0.6, 1)[()] == pytest.approx(1.0, abs=1e-12)
    assert merged_variance_factor(0.0, [1, 5]).tolist() == [1.0, 1.0]
    assert merged_variance_factor(0.6, 3)[()] == pytest.approx(2.04, rel=1e-12)
    assert merged_variance_factor(0.6, 10 ** 6)[()] == pytest.approx(4.0, rel=1e-5)
    for c in (2, 4, 7):
        direct = 1.0 + 2.0 * sum((1.0 - k / c) * 0.8 ** k for k in range(1, c))
        assert merged_variance_factor(0.8, c)[()] == pytest.approx(direct, rel=1e-12)


def test_the_model_check_holds_a_correlated_trackers_merged_reports_to_their_own_variance():
    """A log whose trackers' noise is what the model says, correlated at 0.6, its factors merging
    about three reports each: the model check's variance ratios are near 1 (0.75-1.3), where
    taking a merged factor's variance as one report's over its count read 1.5 and named every
    sensor as misfitting."""
    import warnings

    from pedcal.calib.factorgraph import calibrate_factorgraph
    from pedcal.errors import DegenerateDataWarning

    log = _noisy_log(0.6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        res = calibrate_factorgraph(log, graph=_exact_recipe(estimate_observation_noise=True, reliable_range_m=10.0),
                                    is_robot=np.ones(len(log.observations), bool))
    ratios = res.network.extra["model_mismatch"]["variance_ratio"]
    assert ratios and all(0.75 < r < 1.3 for r in ratios.values()), ratios


@pytest.mark.parametrize("scenario,seed", [("paper", 0), ("corridor", 0)])
def test_the_robots_motion_carried_between_reports_is_not_read_as_a_correlation(scenario, seed):
    """The simulator's tracker noise is white here and its robot never stands still; the robot's
    motion carried between reports (from its odometry or AMCL) adds an error that grows with the
    reports' distance apart in time, which a correlation read from all reports took for one (0.5
    and 0.8 on these logs, the zoo's corridor with its clock offsets). No run of reports counts as
    the robot standing (not even with the corridor's clock offsets stamping a slowing robot as
    still), so none is read: 0. (That a still robot's white noise reads about 0 is the first
    test's rho = 0 case.)"""
    import warnings

    from pedcal.calib.recipe import GraphRecipe
    from pedcal.errors import DegenerateDataWarning
    from pedcal.sim import simulate_logs

    sim = simulate_logs(scenario, seed=seed, vary_nuisances="zoo" if scenario == "corridor" else False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        prob = prepare(sim.calib, GraphRecipe.load("default"), is_robot=np.ones(len(sim.calib.observations), bool))
    assert prob.noise_estimate["frame_correlation"] == {"along": 0.0, "lateral": 0.0}
    assert prob.noise_estimate["still_pairs"] == 0           # (the simulator's robot never stands)


def test_without_the_robot_standing_still_no_correlation_is_read():
    """The exact log whose robot never stops, its noise correlated at 0.6: no run of reports of a
    still robot to read it from, so the correlation is taken as 0 (the sigmas one frame's
    difference's, as before it was read), not read from the moving robot's reports."""
    log = _noisy_log(0.6, kind="loops")
    rec = _exact_recipe(estimate_observation_noise=True, reliable_range_m=10.0)
    prob = prepare(log, rec, is_robot=np.ones(len(log.observations), bool))
    assert prob.noise_estimate["frame_correlation"] == {"along": 0.0, "lateral": 0.0}
    assert prob.noise_estimate["still_pairs"] == 0
