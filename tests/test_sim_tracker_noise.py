"""The simulator's tracker noise correlated frame to frame (Scenario.tracker_noise_rho): a
stationary AR(1) per track (pedcal.sim.ceiling.ar1, ar1_coefficients), drawn per zoo seed from a
stream of its own, and read back by the calibration's noise estimate."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import pedcal.calib.problem as problem
import pedcal.sim.nuisances as nuisances
from pedcal.calib.problem import estimate_observation_noise, prepare
from pedcal.calib.recipe import GraphRecipe
from pedcal.errors import PedcalInputError
from pedcal.sim import simulate_logs
from pedcal.sim.ceiling import ar1, ar1_coefficients, measure
from pedcal.sim.nuisances import OFF_FAMILIES, switch_off, vary, zoo_families
from pedcal.sim.scenario import Scenario, load_scenario

RANGE_M = 2.5


def _tracks(n_tracks: int, n_frames: int, sc: Scenario):
    """Rows of ``n_tracks`` tracks of ``n_frames`` consecutive frames each, sorted by track then
    time as the tracker sorts them: capture times (s) and the start-of-track mask."""
    t = np.tile(np.arange(n_frames) / sc.frame_rate_hz, n_tracks)
    new_track = np.tile(np.arange(n_frames) == 0, n_tracks)
    return t, new_track


def _noise(rho: float, n_tracks: int = 600, n_frames: int = 40, seed: int = 5):
    """The simulated noise of a head at RANGE_M straight below the sensor's x axis, as
    (along the ray, across 1, across 2) per row, shaped (n_tracks, n_frames), and the scenario."""
    sc = Scenario(tracker_noise_rho=rho, far_noise_factor=1.0)
    t, new_track = _tracks(n_tracks, n_frames, sc)
    p = np.tile([RANGE_M, 0.0, 0.0], (len(t), 1))
    coef = ar1_coefficients(t, new_track, sc)
    d = measure(p, sc, np.random.default_rng(seed), coef) - p
    return d.T.reshape(3, n_tracks, n_frames), sc


def _lag1(x: np.ndarray) -> float:
    """Lag-1 correlation within tracks (rows), pooled."""
    a, b = x[:, :-1].ravel(), x[:, 1:].ravel()
    return float(np.mean(a * b) / np.sqrt(np.mean(a * a) * np.mean(b * b)))


@pytest.mark.parametrize("rho", [0.0, 0.7])
def test_noise_has_lag1_correlation_rho_and_each_frames_std_unchanged(rho):
    """24 000 rows: the pooled lag-1 correlation of the depth and lateral noise within 0.03 of
    rho (its standard error ~0.005), the std within 5 % of k r^2 and lateral_noise_m (standard
    error ~1.5 % at 0.7: fewer independent frames); the first and last frames of the tracks have
    the same std (stationary, within 15 %: 600 draws each)."""
    (along, l1, _l2), sc = _noise(rho)
    sigma_depth = sc.depth_noise_k_per_m * RANGE_M ** 2
    assert _lag1(along) == pytest.approx(rho, abs=0.03)
    assert _lag1(l1) == pytest.approx(rho, abs=0.03)
    assert np.std(along) == pytest.approx(sigma_depth, rel=0.05)
    assert np.std(l1) == pytest.approx(sc.lateral_noise_m, rel=0.05)
    assert np.std(along[:, 0]) == pytest.approx(sigma_depth, rel=0.15)
    assert np.std(along[:, -1]) == pytest.approx(sigma_depth, rel=0.15)
    # the correlation ends with the track: none between one track's last frame and the next's first
    assert abs(np.corrcoef(along[:-1, -1], along[1:, 0])[0, 1]) < 0.15


def test_ar1_is_the_recursion_and_restarts_at_each_track():
    """ar1 pinned against the recursion e_k = a_k e_{k-1} + sqrt(1 - a_k^2) w_k written out, on
    (N,) and (N, 3) draws; a_k = 0 gives w_k itself (a restart)."""
    rng = np.random.default_rng(2)
    coef = np.array([0.0, 0.7, 0.49, 0.7, 0.0, 0.7, 0.7, 0.0, 0.0, 0.3])
    for w in (rng.standard_normal(len(coef)), rng.standard_normal((len(coef), 3))):
        e = np.empty_like(w)
        for k in range(len(coef)):
            e[k] = w[k] if k == 0 else coef[k] * e[k - 1] + np.sqrt(1.0 - coef[k] ** 2) * w[k]
        np.testing.assert_allclose(ar1(w, coef), e, rtol=0, atol=1e-15)
        restart = coef == 0.0
        assert np.array_equal(ar1(w, coef)[restart], w[restart])
    w = rng.standard_normal(5)
    assert np.array_equal(ar1(w, np.zeros(5)), w)


def test_coefficients_are_rho_per_frame_elapsed_and_zero_at_a_new_track():
    """A missed frame (two frame periods since the previous report) correlates as rho^2; a new
    track restarts (0)."""
    sc = Scenario(tracker_noise_rho=0.6, frame_rate_hz=10.0)
    t = np.array([0.0, 0.1, 0.2, 0.4, 0.5, 3.0, 3.1, 3.4])
    new_track = np.array([True, False, False, False, False, True, False, False])
    np.testing.assert_allclose(ar1_coefficients(t, new_track, sc),
                               [0.0, 0.6, 0.6, 0.36, 0.6, 0.0, 0.6, 0.6 ** 3], rtol=1e-12)


def test_white_noise_is_todays_draws_exactly():
    """rho = 0 takes the white path: the same draws to the bit as measure without coefficients,
    and as a log simulated with the field left at its default."""
    sc = Scenario()
    p = np.random.default_rng(1).uniform(1.0, 4.0, (50, 3))
    t, new_track = _tracks(5, 10, sc)
    white = measure(p, sc, np.random.default_rng(3))
    assert np.array_equal(measure(p, sc, np.random.default_rng(3), ar1_coefficients(t, new_track, sc)), white)
    # a correlated draw starts each track from the same white draw
    corr = measure(p, sc.resolve(tracker_noise_rho=0.7), np.random.default_rng(3),
                   ar1_coefficients(t, new_track, sc.resolve(tracker_noise_rho=0.7)))
    assert np.array_equal(corr[new_track], white[new_track]) and not np.allclose(corr, white)
    # and a whole log's observations are those made before the correlation existed (their digest,
    # to 1e-9, pinned from commit 62d410d's simulator)
    a = simulate_logs(load_scenario("paper"), seed=4, duration_s=20.0).calib.observations
    digest = hashlib.sha256(np.round(a[["t", "x", "y", "z"]].to_numpy(float), 9).tobytes()
                            + "|".join(map(str, a["sensor"])).encode() + "|".join(map(str, a["track"])).encode())
    assert len(a) == 606
    assert digest.hexdigest() == "90c98a6d51e0156167649a443b787e2e474a574b07c25d927433a3632b96275e"


def test_the_domain_is_zero_to_one_excluded():
    for bad in (-0.1, 1.0, 1.5, float("nan")):
        with pytest.raises(PedcalInputError, match="a correlation within"):
            Scenario().resolve(tracker_noise_rho=bad)
    assert Scenario().resolve(tracker_noise_rho=0.99).tracker_noise_rho == 0.99
    assert Scenario.nuisances()["tracker_noise_rho"] == 0.0


def test_the_zoo_draws_both_kinds_from_a_stream_of_its_own(monkeypatch):
    """Seeds 0-19 of the zoo hold white and correlated tracker noise, rho within 0.3-0.85; the
    draw changes no other field of any seed (every field but rho equal with the draw made 0),
    and a seed drawn correlated simulates the same sightings and robot table as with it off,
    only the observed points differ (besides the first of each track, that starts from the same
    white draw)."""
    base = load_scenario("cross")
    zoo = [vary(base.resolve(seed=s), zoo=True) for s in range(20)]
    rhos = np.array([z.tracker_noise_rho for z in zoo])
    # (pinned: the stream's draw for seeds 0-19, the README's "11 of seeds 0-19")
    assert np.sum(rhos > 0.0) == 11
    assert np.all((rhos == 0.0) | ((rhos >= 0.3) & (rhos <= 0.85)))
    assert {zoo_families(z)["tracker noise"] for z in zoo} == {"white", "correlated"}
    monkeypatch.setattr(nuisances, "_tracker_noise_rho", lambda seed: 0.0)
    for s, z in enumerate(zoo):
        assert vary(base.resolve(seed=s), zoo=True) == z.resolve(tracker_noise_rho=0.0)
    monkeypatch.undo()
    sc = zoo[int(np.argmax(rhos))]
    assert "smoothing" in OFF_FAMILIES and switch_off(sc, ["smoothing"]).tracker_noise_rho == 0.0
    a = simulate_logs(sc, seed=sc.seed, duration_s=20.0).calib
    b = simulate_logs(switch_off(sc, ["smoothing"]), seed=sc.seed, duration_s=20.0).calib
    assert a.robot.equals(b.robot)
    assert a.observations.drop(columns=["x", "y", "z"]).equals(b.observations.drop(columns=["x", "y", "z"]))
    assert not np.allclose(a.observations[["x", "y", "z"]].to_numpy(), b.observations[["x", "y", "z"]].to_numpy())


def _correlated_paper_log(**overrides):
    """The paper site's whole route (seed 1), the robot alone, every nuisance off but the
    tracker's noise (k = 1.5e-3 / m, 1 cm across) correlated at rho = 0.7; ``overrides`` on top."""
    sc = load_scenario("paper").resolve(noise_free=True, depth_noise_k_per_m=1.5e-3, lateral_noise_m=0.01,
                                        tracker_noise_rho=0.7, walkers="none", false_track_rate_hz=0.0,
                                        **overrides)
    log = simulate_logs(sc, seed=1).calib
    prob = prepare(log, GraphRecipe(estimate_observation_noise=False), is_robot=np.ones(len(log.observations), bool))
    return sc, log, prob


def test_the_noise_estimate_recovers_a_correlated_trackers_noise(monkeypatch):
    """End to end: the paper site's whole route with the robot standing 3 s at every waypoint
    (the estimate reads the correlation only from reports taken while it stands), every nuisance
    off but the tracker's noise correlated at rho = 0.7. The calibration's noise estimate gives
    each frame's noise within 25 % (depth at the observations' median range, below
    reliable_range_m), its correlation within 0.1; one frame's difference alone (the correlation
    capped at 0) gives ~sqrt(0.3) = 0.55 of it."""
    sc, log, prob = _correlated_paper_log(robot_stop_s=3.0, robot_stop_share=1.0)
    r_mid = float(np.median(np.linalg.norm(prob.obs_p_raw, axis=1)))
    assert r_mid < sc.reliable_range_m

    def depth(est):
        return est["range_sigma_floor_m"] + est["range_sigma_k_per_m"] * r_mid ** 2

    est = estimate_observation_noise(log, prob)
    truth_depth = sc.depth_noise_k_per_m * r_mid ** 2
    assert depth(est) == pytest.approx(truth_depth, rel=0.25)
    assert est["lateral_sigma_m"] == pytest.approx(sc.lateral_noise_m, rel=0.25)
    assert est["frame_correlation"]["along"] == pytest.approx(0.7, abs=0.1)
    assert est["frame_correlation"]["lateral"] == pytest.approx(0.7, abs=0.1)
    monkeypatch.setattr(problem, "MAX_NOISE_RHO", 0.0)
    one = estimate_observation_noise(log, prob)
    assert depth(one) < 0.7 * truth_depth and one["lateral_sigma_m"] < 0.7 * sc.lateral_noise_m


def test_a_robot_that_never_stands_reads_no_correlation():
    """The same log with a robot that never stops: no reports taken while it stands, so the
    estimate falls back to a correlation of 0 (the motion carried between reports would read as
    one) and each frame's noise to one frame's difference's, ~0.55 of the truth."""
    sc, log, prob = _correlated_paper_log()
    est = estimate_observation_noise(log, prob)
    assert est["frame_correlation"] == {"along": 0.0, "lateral": 0.0}
    assert est["lateral_sigma_m"] < 0.7 * sc.lateral_noise_m
