"""AMCL's error model estimated from the data (pedcal.calib.amcl_model): the variogram and its
fit on series of known kind, jumps, and the model the factor graph estimates on simulated
logs whose AMCL error is white, wandering or jumping."""

import warnings

import numpy as np
import pandas as pd
import pytest

from pedcal.calib.amcl_model import (
    VARIOGRAM_LAGS_S,
    AmclErrorModel,
    ar1_factor_sigmas,
    assumed_model,
    detect_jumps,
    detect_steps,
    estimate_model,
    fit_variogram,
    hold_at_floor,
    node_drift_variance,
    robust_variogram,
)
from pedcal.calib.factorgraph import calibrate_factorgraph
from pedcal.errors import DegenerateDataWarning
from pedcal.sim import simulate_logs
from pedcal.sim.robot import ou_process


def _assert_pairs_within_each_series(t, series):
    """robust_variogram's pairs, and so its semivariances, are those of a search within each series."""
    gamma, pairs = robust_variogram(t, series, min_pairs=5)
    for n, lag in enumerate(VARIOGRAM_LAGS_S):
        diffs = []
        for rows, e in series:
            tg = t[rows]
            j = np.searchsorted(tg, tg + lag)
            ok = j < len(tg)
            ok[ok] = np.abs(tg[j[ok]] - tg[ok] - lag) <= 0.25 * lag + 1e-6
            diffs.append(e[j[ok]] - e[ok])
        d = np.concatenate(diffs)
        assert pairs[n] == len(d)
        if len(d) >= 5:
            mad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
            assert gamma[n] == 0.5 * float(np.mean(mad ** 2))
        else:
            assert np.isnan(gamma[n])
    assert pairs.max() > 0


def test_the_variograms_pairs_are_each_series_own_at_every_lag():
    # all series searched at once: the pairs, and so the semivariances, are those of a search
    # within each series (times with ties, empty series, series of one sample)
    rng = np.random.default_rng(31)
    t = np.sort(np.round(rng.uniform(0.0, 300.0, 3000), 1))
    sizes = [0, 1, 5, 150, 0, 400, 80, 2]
    series = [(np.sort(rng.choice(len(t), k, replace=False)), rng.normal(size=(k, 2))) for k in sizes]
    _assert_pairs_within_each_series(t, series)
    empty, none = robust_variogram(t, [])
    assert np.all(np.isnan(empty)) and not none.any()


def test_the_variograms_pairs_stop_at_each_series_end():
    # series over consecutive spans of time: a search past one series' end would find, a lag
    # later, the next series' first samples, which are no pairs of either
    rng = np.random.default_rng(37)
    t = np.arange(3000) * 0.1
    cuts = [0, 400, 401, 1100, 1900, 3000]
    series = [(np.arange(a, b), rng.normal(size=(b - a, 2))) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    _assert_pairs_within_each_series(t, series)


def _visits(rng, t, n_sensors=6, visit_s=8.0):
    """Per sensor the sorted indices of the instants it 'sees': visits of visit_s, in turn."""
    slot = np.floor(t / visit_s).astype(int) % n_sensors
    return [np.flatnonzero(slot == s) for s in range(n_sensors)]


def _fit(series_xy, t, groups):
    gamma, pairs = robust_variogram(t, [(g, series_xy[g]) for g in groups])
    n_eff = 0.5 * np.minimum(pairs, np.maximum(len(t) * 0.2 / VARIOGRAM_LAGS_S, 1.0) * 2.0)
    return fit_variogram(VARIOGRAM_LAGS_S, gamma, n_eff, max_correlation_s=300.0)


def test_white_and_wandering_errors_are_told_apart():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 600.0, 0.2)
    groups = _visits(rng, t)
    white = rng.normal(0.0, 0.05, (len(t), 2))
    w, c, _ = _fit(white, t, groups)
    assert c == 0.0 and w == pytest.approx(0.05, rel=0.1)
    ou = np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    ou += rng.normal(0.0, 0.005, ou.shape)
    w, c, tau = _fit(ou, t, groups)
    # the rate of wander (c^2 / tau) is what the short lags show: 2.5e-3 / 20 m^2/s
    assert c > 0.02 and c ** 2 / tau == pytest.approx(0.05 ** 2 / 20.0, rel=0.35)
    assert w < 0.012


def test_the_wandering_std_is_at_least_amcls_reported_one_at_the_rate_it_shows():
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 600.0, 0.2)
    groups = _visits(rng, t, visit_s=5.0)       # short visits: the long lags say little
    ou = np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    gamma, pairs = robust_variogram(t, [(g, ou[g]) for g in groups])
    n_eff = 0.5 * np.minimum(pairs, np.maximum(len(t) * 0.2 / VARIOGRAM_LAGS_S, 1.0) * 2.0)
    free = fit_variogram(VARIOGRAM_LAGS_S, gamma, n_eff, max_correlation_s=300.0)
    held = fit_variogram(VARIOGRAM_LAGS_S, gamma, n_eff, max_correlation_s=300.0, floor_sigma_m=0.05)
    assert held[1] == pytest.approx(max(free[1], 0.05))
    assert held[1] ** 2 / held[2] == pytest.approx(free[1] ** 2 / free[2], rel=1e-6)


def _short_visits_ou(seed: int):
    """An OU error (5 cm, 20 s) seen in short visits (the long lags say little), as 600 s of
    AMCL estimates at 5 Hz with the sensors' series."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 600.0, 0.2)
    groups = _visits(rng, t, visit_s=5.0)
    ou = np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    return t, [(g, ou[g]) for g in groups]


def test_consider_solves_with_the_datas_wander_and_keeps_the_held_one_beside_it():
    """floor "consider": the model is the data's ("off"'s), the held one ("hold"'s, at least
    AMCL's reported std at the rate the data show) kept beside it, and held() gives it back."""
    t, series = _short_visits_ou(4)
    assumed = AmclErrorModel(white_sigma_m=0.01, correlated_sigma_m=0.05, correlation_s=20.0)
    hold, consider, off = (estimate_model(t, series, assumed, prior_sigma_m=0.08, floor=f)
                           for f in ("hold", "consider", "off"))
    assert 0.0 < off.correlated_sigma_m < 0.08                    # the floor binds on these data
    assert (consider.correlated_sigma_m, consider.correlation_s) == (off.correlated_sigma_m, off.correlation_s)
    assert (consider.held_sigma_m, consider.held_correlation_s) == \
        pytest.approx((hold.correlated_sigma_m, hold.correlation_s), rel=1e-12)
    assert hold.correlated_sigma_m == 0.08 and off.held_sigma_m == 0.0 and hold.held_sigma_m == 0.0
    held = consider.held()
    assert (held.correlated_sigma_m, held.correlation_s, held.white_sigma_m) == \
        (consider.held_sigma_m, consider.held_correlation_s, consider.white_sigma_m)
    assert held.held() is None and off.held() is None and hold.held() is None
    assert consider.to_dict()["held_sigma_m"] == 0.08 and "held_sigma_m" not in off.to_dict()
    with pytest.raises(ValueError, match="floor must be one of"):
        estimate_model(t, series, assumed, prior_sigma_m=0.08, floor="wide")
    with pytest.raises(ValueError, match="floor must be one of"):        # also when it would return early
        estimate_model(t, series, assumed, prior_sigma_m=0.08, floor="wide", min_covered=10 ** 9)


def test_consider_holds_nothing_where_the_data_wander_more_than_reported_or_not_at_all():
    t, series = _short_visits_ou(4)
    assumed = AmclErrorModel(white_sigma_m=0.01, correlated_sigma_m=0.05, correlation_s=20.0)
    above = estimate_model(t, series, assumed, prior_sigma_m=0.001, floor="consider")
    assert above.correlated_sigma_m > 0.001 and above.held_sigma_m == 0.0
    rng = np.random.default_rng(7)
    white = [(rows, rng.normal(0.0, 0.03, (len(rows), 2))) for rows, _ in series]
    flat = estimate_model(t, white, assumed, prior_sigma_m=0.08, floor="consider")
    assert flat.correlated_sigma_m == 0.0 and flat.held_sigma_m == 0.0


def test_hold_at_floor_keeps_the_rate_of_wander_and_caps_the_correlation_time():
    # variances: 0.02^2 over 10 s is 0.04^2 over 40 s
    assert hold_at_floor(0.02 ** 2, 10.0, 0.04, 1e4) == pytest.approx((0.04 ** 2, 40.0))
    assert hold_at_floor(0.02 ** 2, 10.0, 0.04, 25.0) == pytest.approx((0.04 ** 2, 25.0))
    assert hold_at_floor(0.05 ** 2, 10.0, 0.04, 1e4) == (0.05 ** 2, 10.0)


def test_error_nodes_resolve_a_wandering_error_and_are_few_without_one():
    # a quarter of the correlation time, within AMCL's period and the recipe's most; a white error
    # (no wandering part, whatever correlation time the fit left) needs no resolution: one node
    # per estimate there would double the graph for nothing
    wandering = AmclErrorModel(white_sigma_m=0.01, correlated_sigma_m=0.05, correlation_s=2.0)
    assert wandering.node_spacing_s(0.1, 1.0) == pytest.approx(0.5)
    assert AmclErrorModel(0.01, 0.05, 0.1).node_spacing_s(0.1, 1.0) == pytest.approx(0.1)
    assert AmclErrorModel(0.01, 0.05, 60.0).node_spacing_s(0.1, 1.0) == pytest.approx(1.0)
    assert AmclErrorModel(0.05, 0.0, 0.1).node_spacing_s(0.1, 1.0) == pytest.approx(1.0)


def test_jumps_are_found_and_nothing_else():
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 400.0, 0.2)
    e = np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    truth = np.zeros(len(t), bool)
    for start in (50.0, 170.0, 300.0):
        on = (t >= start) & (t < start + 6.0)
        e[on] += 0.3 * np.array([np.cos(start), np.sin(start)])
        truth |= on
    found = detect_jumps(t, e)
    assert found[truth].mean() > 0.8
    assert found[~truth].mean() < 0.01


def _track(rng, t):
    """A robot's path: straight legs at 0.3 m/s joined by turns, with stops (m)."""
    speed = 0.3 * np.clip(np.abs(np.sin(2 * np.pi * t / 70.0)) * 3.0, 0.0, 1.0)
    heading = np.cumsum(0.2 * np.sin(2 * np.pi * t / 45.0)) * (t[1] - t[0]) * 3.0
    d = np.column_stack([speed * np.cos(heading), speed * np.sin(heading)]) * (t[1] - t[0])
    return np.cumsum(d, axis=0)


def test_steps_in_amcls_track_are_jumps_wherever_the_robot_was():
    # AMCL's estimates of a moving robot with a wandering and a white error, jumping 0.4 m (and
    # 0.25 m inside one of them) for 10 s and back: those estimates, and only those; a step that
    # never comes back (a relocalization that was right) leaves nothing out
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 400.0, 0.2)
    p = _track(rng, t) + np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    p += rng.normal(0.0, 0.008, p.shape)
    truth = np.zeros(len(t), bool)
    for start, size, angle in ((40.0, 0.4, 1.0), (150.0, 0.4, 4.0), (154.0, 0.25, 2.0), (260.0, 0.4, 5.5)):
        on = (t >= start) & (t < start + 10.0)
        p[on] += size * np.array([np.cos(angle), np.sin(angle)])
        truth |= on
    assert np.array_equal(detect_steps(t, p), truth)
    p[t >= 340.0] += np.array([0.0, 0.5])
    assert np.array_equal(detect_steps(t, p), truth)
    clean = _track(rng, t) + rng.normal(0.0, 0.008, p.shape)
    assert not detect_steps(t, clean).any()
    assert not detect_steps(t[:9], p[:9]).any()          # too few to tell


def _wandering_track(rng, t):
    """_track with AMCL's wandering (5 cm, 20 s) and white (8 mm) error."""
    p = _track(rng, t) + np.column_stack([ou_process(rng, len(t), t[1] - t[0], 0.05, 20.0) for _ in range(2)])
    return p + rng.normal(0.0, 0.008, p.shape)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_steps_within_one_window_are_both_found(seed):
    # at 10 Hz: a 0.4 m jump that ends 0.3 s before another starts (the zoo corridor seed 12's
    # relocalizations), and two steps out 0.3 s apart (0.4 m, then 0.15 m 34 deg away: above the
    # 0.1 m threshold by half of it, so a doubled threshold misses it) that come
    # back in one: every estimate of both, and nothing else (a window's largest step alone missed
    # one of each pair, and its bookkeeping left the jumps in)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 300.0, 0.1)
    p = _wandering_track(rng, t)
    truth = np.zeros(len(t), bool)
    for start, stop, size, angle in ((60.0, 70.0, 0.4, 1.0), (70.3, 80.3, 0.4, 3.0),
                                     (180.0, 190.0, 0.4, 5.0), (180.3, 190.0, 0.15, 5.6)):
        on = (t >= start - 1e-9) & (t < stop - 1e-9)
        p[on] += size * np.array([np.cos(angle), np.sin(angle)])
        truth |= on
    assert np.array_equal(detect_steps(t, p), truth)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("period_s", [0.1, 0.2])
def test_no_steps_are_found_in_a_wandering_track_without_jumps(seed, period_s):
    # 10 minutes of a moving robot's AMCL track, wandering 5 cm over 20 s with 8 mm of jitter
    rng = np.random.default_rng(100 + seed)
    t = np.arange(0.0, 600.0, period_s)
    assert not detect_steps(t, _wandering_track(rng, t)).any()


def test_irregular_timestamps_do_not_feed_the_step_search_back():
    # a jerky track (the path drawn per estimate, the estimates at exponential gaps): a window that
    # extrapolates over a hole grew when a neighbouring step was taken out, past the step itself,
    # and the search took it again and again (sizes 0.8 -> 2.8 -> 7.3 -> 19 m, to numpy's
    # overflow); the search ends, with no overflow
    import warnings

    rng = np.random.default_rng(10)
    t = np.cumsum(rng.exponential(0.1, 3000))
    p = _wandering_track(rng, t)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        flagged = detect_steps(t, p)
    assert flagged.sum() < 0.01 * len(t)


def _irregular_track(rng, mean_gap_s: float, n: int):
    """AMCL's estimates at irregular times (exponential gaps of ``mean_gap_s``) of the wandering
    track sampled every 50 ms: (t, p)."""
    t = np.cumsum(rng.exponential(mean_gap_s, n))
    t_fine = np.arange(0.0, t[-1] + 1.0, 0.05)
    p_fine = _wandering_track(rng, t_fine)
    return t, p_fine[np.minimum(np.searchsorted(t_fine, t), len(t_fine) - 1)]


@pytest.mark.parametrize("seed", range(10, 20))
def test_at_irregular_times_a_jump_is_found_and_nothing_else(seed):
    # each step counted in its own standard error: a window that extrapolates over a hole reads its
    # line several times as noisy, and counted in metres alone its noise raised the robust scale
    # until three of these ten 0.4 m jumps went unseen
    rng = np.random.default_rng(seed)
    t, p = _irregular_track(rng, 0.1, 3000)
    assert not detect_steps(t, p).any()
    on = (t >= 100.0) & (t < 110.0)
    p[on] += [0.0, 0.4]
    assert np.array_equal(detect_steps(t, p), on)


def _jumped(p: np.ndarray, t: np.ndarray, start_s: float, stop_s: float, step_m) -> np.ndarray:
    """``p`` moved by ``step_m`` from ``start_s`` to ``stop_s`` (in place): the jump's mask."""
    on = (t >= start_s - 1e-9) & (t < stop_s - 1e-9)
    p[on] += step_m
    return on


def test_a_non_finite_estimate_does_not_hide_a_later_jump():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 0.1)
    p = _wandering_track(rng, t)
    on = _jumped(p, t, 100.0, 110.0, [0.4, 0.0])
    p[50] = np.nan
    flagged = detect_steps(t, p)
    assert np.array_equal(flagged, on)


def test_estimates_all_at_one_instant_have_no_step():
    # twelve estimates stamped alike (a replayed message): one instant, no gap between estimates,
    # nothing flagged, no offset (the windows' search had nothing to reduce over and raised)
    p = np.random.default_rng(4).normal(size=(12, 2))
    mask, off = detect_steps(np.full(12, 3.0), p, offsets=True)
    assert not mask.any() and mask.shape == (12,)
    np.testing.assert_array_equal(off, np.zeros((12, 2)))


def test_track_jumps_stay_left_out_where_no_sensor_saw_the_robot():
    # the assumed model leaves AMCL's track jumps out; the estimated one keeps them, with those
    # the sensors' residuals show (here none: the residuals are AMCL's wander alone)
    import pandas as pd

    from pedcal.calib.recipe import GraphRecipe

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 0.2)
    p = _track(rng, t) + rng.normal(0.0, 0.008, (len(t), 2))
    on = (t >= 100.0) & (t < 110.0)
    p[on] += 0.4
    amcl = pd.DataFrame({"t": t, "x": p[:, 0], "y": p[:, 1], "yaw": 0.0, "cov_xx": 0.05 ** 2, "cov_xy": 0.0,
                         "cov_xyaw": 0.0, "cov_yy": 0.05 ** 2, "cov_yyaw": 0.0, "cov_yawyaw": 0.01})
    assumed = assumed_model(amcl.iloc[::-1], GraphRecipe.load("default"))      # any row order
    assert np.array_equal(assumed.excluded, on) and np.array_equal(assumed.track_jumps, on)
    assert assumed.jumps == 1 and assumed.excluded_s == pytest.approx(10.0)
    e = np.column_stack([ou_process(rng, len(t), 0.2, 0.05, 20.0) for _ in range(2)])
    seen = [np.flatnonzero(t < 80.0), np.flatnonzero(t > 200.0)]      # nobody sees the jump
    model = estimate_model(t, [(rows, e[rows]) for rows in seen], assumed, prior_sigma_m=0.05)
    assert model.source == "estimated"
    assert np.array_equal(model.excluded, on) and model.jumps == 1


@pytest.mark.parametrize("assumed_tau_s", [5.0, 40.0])
def test_a_white_error_keeps_the_assumed_correlation_time(assumed_tau_s):
    # residuals with no wandering part say nothing of a correlation time (the fit's is any point
    # of a flat cost), which weighs AMCL's heading: the assumed one is kept, not the fit's
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 300.0, 0.2)
    e = rng.normal(0.0, 0.03, (len(t), 2))
    seen = [np.flatnonzero((t > a) & (t < a + 20.0)) for a in range(0, 300, 30)]
    assumed = AmclErrorModel(white_sigma_m=0.01, correlated_sigma_m=0.05, correlation_s=assumed_tau_s)
    model = estimate_model(t, [(rows, e[rows]) for rows in seen], assumed, min_covered=10)
    assert model.source == "estimated" and model.correlated_sigma_m == 0.0
    assert model.white_sigma_m == pytest.approx(0.03, rel=0.1)
    assert model.correlation_s == assumed_tau_s


@pytest.mark.parametrize("kind", ["white", "correlated"])
def test_the_graph_estimates_the_kind_of_amcl_error_it_was_given(kind):
    sim = simulate_logs("paper", seed=2, amcl_error=kind)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        res = calibrate_factorgraph(sim.calib)
    model = res.diagnostics.amcl_error_model
    assert model.source == "estimated"
    if kind == "white":
        assert model.correlated_sigma_m == 0.0
        assert model.white_sigma_m == pytest.approx(sim.scenario.amcl_sigma_m, rel=0.15)
    else:
        # the wander the sensors' sigma is read with (the held one where the reported std binds:
        # amcl_reported_floor "consider"), and the rate of wander the residuals show
        sigma_model = model.held() or model
        assert model.correlated_sigma_m <= sigma_model.correlated_sigma_m
        assert sigma_model.correlated_sigma_m == pytest.approx(sim.scenario.amcl_sigma_m, rel=0.3)
        assert 0.4 * sim.scenario.amcl_tau_s < sigma_model.correlation_s < 2.5 * sim.scenario.amcl_tau_s
        assert model.correlated_sigma_m ** 2 / model.correlation_s == \
            pytest.approx(sim.scenario.amcl_sigma_m ** 2 / sim.scenario.amcl_tau_s, rel=0.3)
    assert res.network.extra["amcl_error_model"]["source"] == "estimated"


def test_consider_estimates_with_the_datas_wander_and_reads_the_sigma_under_the_held_one():
    """amcl_reported_floor on a log whose AMCL residuals wander less than AMCL reports: "consider"
    solves the graph "off" solves (the data's wander: the same positions, bit for bit) and
    reads the sensors' covariance under the held model, as "hold" does: its horizontal sigma
    within 10 % of "hold"'s (read at another solution), "off"'s below 0.8 of it."""
    sim = simulate_logs("paper", seed=2, amcl_error="correlated")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        off, consider, hold = (calibrate_factorgraph(sim.calib, amcl_reported_floor=f)
                               for f in ("off", "consider", "hold"))
    model = consider.diagnostics.amcl_error_model
    assert model.held_sigma_m > model.correlated_sigma_m > 0.0, "the reported std must bind on this log"
    ids = [s.id for s in consider.network]
    def positions(r):
        return np.array([r.network[s].position_m for s in ids])
    def sigma_xy(r):
        return np.array([r.network[s].sigma_position_m[:2] for s in ids])
    assert np.array_equal(positions(off), positions(consider))
    assert not np.allclose(positions(hold), positions(consider), atol=1e-4)
    np.testing.assert_allclose(sigma_xy(consider), sigma_xy(hold), rtol=0.1)
    assert np.all(sigma_xy(off) < 0.8 * sigma_xy(hold))
    assert consider.network.extra["amcl_error_model"]["held_sigma_m"] == round(model.held_sigma_m, 5)


def test_hold_writes_no_held_wander_and_reads_the_sigma_from_the_graph_it_solved(monkeypatch):
    """amcl_reported_floor "hold" (the behaviour before "consider"): no held wander in the model
    or the YAML, and the covariance is read from the very graph solved."""
    import pedcal.calib.factorgraph as fgm

    seen = []
    held_graph = fgm._held_graph
    monkeypatch.setattr(fgm, "_held_graph", lambda log, prob, parts, fg: seen.append(
        (held_graph(log, prob, parts, fg), fg)) or seen[-1][0])
    sim = simulate_logs("paper", seed=2, amcl_error="correlated")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        res = calibrate_factorgraph(sim.calib, amcl_reported_floor="hold")
    assert res.diagnostics.amcl_error_model.held_sigma_m == 0.0
    assert "held_sigma_m" not in res.network.extra["amcl_error_model"]
    assert len(seen) == 1 and seen[0][0] is seen[0][1]


def test_an_unknown_amcl_reported_floor_is_refused_naming_the_key():
    from pedcal.errors import PedcalInputError

    sim = simulate_logs("paper", seed=2)
    with pytest.raises(PedcalInputError, match="amcl_reported_floor must be hold, consider, off, got 'wide'"):
        calibrate_factorgraph(sim.calib, amcl_reported_floor="wide")


def test_amcl_jumps_seen_by_the_sensors_are_left_out():
    # relocalization jumps of 0.4 m for 2-10 s: the estimates the graph leaves out are jumps (the
    # AMCL error the simulator added exceeds 0.2 m there), and most jump estimates taken while a
    # ceiling sensor saw the robot are left out, and so are those while none did (AMCL's track
    # steps out and back)
    from pedcal.calib.common import interpolate_pose2

    sim = simulate_logs("paper", seed=6, amcl_error="jumps", amcl_jump_rate_hz=1 / 40.0, amcl_jump_m=0.4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        # (the track's own jumps left out, not moved back: amcl_jumps_moved_back's own test below)
        res = calibrate_factorgraph(sim.calib, amcl_jumps_moved_back=False)
    model = res.diagnostics.amcl_error_model
    amcl = sim.calib.robot.sort_values("t", kind="stable")
    truth = interpolate_pose2(sim.calib.truth_robot, amcl["t"].to_numpy(float))
    err = np.hypot(amcl["x"].to_numpy(float) - truth[:, 0], amcl["y"].to_numpy(float) - truth[:, 1])
    jump = err > 0.2
    assert model.jumps >= 3 and model.excluded is not None
    assert jump[model.excluded].mean() > 0.9                  # what is left out is a jump
    assert model.excluded[jump].mean() > 0.95                 # and the jumps are, seen or not
    assert res.network.extra["amcl_error_model"]["jumps"] == model.jumps
    assert res.network.extra["amcl_error_model"]["jumps_moved_back"] == 0


def test_a_sensor_that_sees_the_robot_only_inside_a_jump_without_odometry_is_calibrated():
    # the zoo's cross seed 2: no odometry, five relocalization jumps of 0.4 m for 7-20 s; sensor
    # s01 sees the robot 5 s at the log's start and 5 s inside a 20 s jump. With the jumps left out
    # the robot's path there was the smoothness factor's alone, which carried the jump's steps:
    # s01 929 mm off with a 48 mm sigma, the log's horizontal RMS 264 mm. Moved back by their
    # steps, the jumps' estimates hold the path: 45 mm, s01 within 2 sigma (the seed's draw
    # without the robot's stops, which the zoo drew for it later: the log this case was found on)
    from pedcal.metrics import evaluate
    from pedcal.sim.nuisances import switch_off, vary
    from pedcal.sim.scenario import load_scenario

    sim = simulate_logs(switch_off(vary(load_scenario("cross").resolve(seed=2), zoo=True), ["stops"]), seed=2)
    assert sim.calib.odometry is None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate_factorgraph(sim.calib)
    assert res.network.extra["amcl_error_model"]["jumps_moved_back"] == 5
    ev = evaluate(sim.eval, res.network)
    assert ev.sensor_position_rms_mm.horizontal < 60.0
    s01 = next(s for s in ev.sensors if s.id == "s01")
    assert np.all(np.abs(s01.position_error_mm[:2]) / 1000.0 <= 2.0 * res.network["s01"].sigma_position_m[:2])


def _ar1_precision(prior_sig, step_sig, n):
    """The precision the graph's AR(1) factors add up to: priors on the diagonal, increments."""
    Q = np.diag(1.0 / prior_sig ** 2)
    for m in range(1, n):
        Q[np.ix_([m - 1, m], [m - 1, m])] += np.array([[1.0, -1.0], [-1.0, 1.0]]) / step_sig ** 2
    return Q


def test_ar1_factor_sigmas_are_the_stationary_ar1_free_at_the_ends():
    sigma, a, n = 0.05, 0.7, 6
    prior_sig, step_sig = ar1_factor_sigmas(sigma, a, n)
    Q = _ar1_precision(prior_sig, step_sig, n)
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    Q_exact = np.linalg.inv(sigma ** 2 * a ** lag)
    # the exact precision everywhere but the two ends' diagonal, a / (sigma^2 (1 + a)) short there
    short = np.zeros(n)
    short[[0, -1]] = a / (sigma ** 2 * (1.0 + a))
    np.testing.assert_allclose(Q, Q_exact - np.diag(short), rtol=1e-9, atol=1e-6)
    # the mean's variance: sigma^2 (1 + a) / (n (1 - a))
    one = np.ones(n)
    assert 1.0 / (one @ Q @ one) == pytest.approx(sigma ** 2 * (1.0 + a) / (n * (1.0 - a)), rel=1e-9)
    # one node: the process's own std
    only, _ = ar1_factor_sigmas(sigma, a, 1)
    np.testing.assert_allclose(only, [sigma])


def test_node_drift_variance_formula_and_shared_span():
    sigma, tau = 0.05, 20.0
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 12.0])    # nodes at 0, 5, 10 (the last past them)
    node, var = node_drift_variance(t, 0.0, 5.0, 3, sigma, tau, per_span=True)
    np.testing.assert_array_equal(node, [0, 0, 0, 1, 1, 1, 2])
    change = sigma ** 2 * (1.0 - np.exp(-2.0 * np.abs(t - 5.0 * node) / tau))
    # five estimates between nodes 0 and 5, two from 5 on (the one past the last node counts there)
    np.testing.assert_allclose(var, change * np.array([5, 5, 5, 5, 5, 2, 2]), rtol=1e-12)
    assert var[0] == 0.0                                   # on its node: no change
    # per estimate (the recipe's default): the change alone
    _, alone = node_drift_variance(t, 0.0, 5.0, 3, sigma, tau, per_span=False)
    np.testing.assert_allclose(alone, change, rtol=1e-12)
    # no default of its own to disagree with the recipe's: the caller says which
    with pytest.raises(TypeError, match="per_span"):
        node_drift_variance(t, 0.0, 5.0, 3, sigma, tau)


@pytest.mark.parametrize("per_span", [False, True])
def test_the_graph_counts_the_change_as_its_recipe_says(monkeypatch, per_span):
    # the AMCL block takes the recipe's amcl_change_per_span (default off), whatever the function's
    import pedcal.calib.graph as graph
    from pedcal.calib.recipe import GraphRecipe

    assert GraphRecipe().amcl_change_per_span is False
    asked = []
    monkeypatch.setattr(graph, "node_drift_variance",
                        lambda *a, **kw: asked.append(kw["per_span"]) or node_drift_variance(*a, **kw))
    sim = simulate_logs("paper", seed=0, duration_s=20.0)
    rec = GraphRecipe(amcl_change_per_span=per_span)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        graph.build_parts(sim.calib, graph.prepare(sim.calib, rec))
    assert asked and set(asked) == {per_span}


def _model_covariance(t, node_t0, dn, n_nodes, sigma, tau, white):
    """AMCL's error covariance at ``t`` as the graph models it: the nodes' AR(1) (its factors),
    each estimate's change since its node (node_drift_variance) and the white error."""
    prior_sig, step_sig = ar1_factor_sigmas(sigma, np.exp(-dn / tau), n_nodes)
    C_nodes = np.linalg.inv(_ar1_precision(prior_sig, step_sig, n_nodes))
    node, drift = node_drift_variance(t, node_t0, dn, n_nodes, sigma, tau, per_span=True)
    return C_nodes[np.ix_(node, node)] + np.diag(drift + white ** 2)


@pytest.mark.parametrize("tau, sweep_s", [(20.0, 12.5), (5.0, 12.5), (60.0, 30.0)])
def test_common_shift_and_turn_sigma_match_a_monte_carlo_of_the_process(tau, sweep_s):
    """The network's common shift and turn, as the graph reads them from AMCL (the weighted
    least squares under its model of AMCL's error), on a robot sweeping back and forth: the sigma
    the model claims against the spread of those estimates over 1500 draws of the process itself
    (white plus Ornstein-Uhlenbeck), within 15 %. The turn rests on the error's short lags, which
    estimates tied to their nearest node as independent draws would overstate 2-3 times."""
    rng = np.random.default_rng(11)
    sigma, white, dt, T = 0.05, 0.004, 0.2, 220.0
    dn = tau / 4.0
    t = np.arange(0.0, T, dt)
    n_nodes = int(np.round(T / dn)) + 1
    phase = (t / sweep_s) % 2.0
    x_m = 12.5 * np.where(phase < 1.0, phase, 2.0 - phase)          # the robot's position across the site
    A = np.column_stack([np.ones(len(t)), x_m - x_m.mean()])          # shift, turn (rad) x lever arm
    Cm = _model_covariance(t, 0.0, dn, n_nodes, sigma, tau, white)
    Cinv_A = np.linalg.solve(Cm, A)
    claimed = np.linalg.inv(A.T @ Cinv_A)
    W = claimed @ Cinv_A.T                                            # the estimator the graph is
    draws = np.array([W @ (ou_process(rng, len(t), dt, sigma, tau) + rng.normal(0.0, white, len(t)))
                      for _ in range(1500)])
    ratio = draws.std(axis=0) / np.sqrt(np.diag(claimed))
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
    # the shift's sigma is the run mean's, the process free at the run's ends (ar1_factor_sigmas):
    # between the OU mean's exact std, sqrt(2 sigma^2 tau / T (1 - tau / T (1 - e^-T/tau))), and
    # the same without the ends' correction, sqrt(2 sigma^2 tau / T)
    shift_sigma = np.sqrt(claimed[0, 0])
    assert AmclErrorModel(0.0, sigma, tau).floor_sigma_m(T) * 0.98 <= shift_sigma <= sigma * np.sqrt(2 * tau / T) * 1.03


def test_the_steps_offsets_move_a_jumps_estimates_back_onto_the_track():
    # a 0.4 m jump out and back, and one out in two steps (0.3 m, then 0.2 m 3 s later) and back in
    # one: the estimates less their offsets are the track without the jumps, within ~1 cm
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 300.0, 0.1)
    clean = _wandering_track(rng, t)
    p = clean.copy()
    for start, stop, step in ((100.0, 110.0, [0.4, 0.1]), (200.0, 210.0, [0.0, -0.3]), (203.0, 210.0, [0.2, 0.0])):
        p[(t >= start - 1e-9) & (t < stop - 1e-9)] += step
    jump, offset = detect_steps(t, p, offsets=True)
    assert np.array_equal(jump, (t >= 100.0 - 1e-9) & (t < 110.0 - 1e-9) | (t >= 200.0 - 1e-9) & (t < 210.0 - 1e-9))
    assert not offset[~jump].any()
    miss = np.linalg.norm(p - offset - clean, axis=1)
    assert miss[jump].mean() < 0.015 and miss.max() < 0.03
    # (and as a mask alone, the same)
    assert np.array_equal(detect_steps(t, p), jump)


def test_jumps_moved_back_keeps_the_tables_rows_and_moves_only_the_jumps():
    import pandas as pd

    from pedcal.calib.amcl_model import jumps_moved_back
    from pedcal.model import Log

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 200.0, 0.2)
    p = _wandering_track(rng, t)
    on = _jumped(p, t, 80.0, 90.0, [0.4, 0.0])
    robot = pd.DataFrame({"t": t, "x": p[:, 0], "y": p[:, 1], "yaw": np.zeros(len(t)),
                          **{c: np.full(len(t), 1e-3) for c in ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy",
                                                                 "cov_yyaw", "cov_yawyaw")}})
    shuffled = robot.sample(frac=1.0, random_state=5).reset_index(drop=True)      # rows in any order
    log = Log(sensors=None, robot=shuffled, observations=pd.DataFrame())
    moved, n_jumps, steps = jumps_moved_back(log)
    assert n_jumps == 1 and steps.sum() == 50 and moved is not log and log.robot is shuffled
    changed = (moved.robot[["x", "y"]].to_numpy() != shuffled[["x", "y"]].to_numpy()).any(axis=1)
    in_jump = (shuffled["t"].to_numpy() >= 80.0 - 1e-9) & (shuffled["t"].to_numpy() < 90.0 - 1e-9)
    assert np.array_equal(changed, in_jump)
    # (the offset is the mean of the step out and the step back, each off by AMCL's wander over
    # the +-1 s windows, ~1.5 cm here, and its jitter: 2.2 cm off the 0.4 m on this track)
    assert np.abs(moved.robot["x"].to_numpy()[in_jump] - (shuffled["x"].to_numpy()[in_jump] - 0.4)).max() < 0.03
    assert moved.robot.drop(columns=["x", "y"]).equals(shuffled.drop(columns=["x", "y"]))
    clean = Log(sensors=None, robot=robot.assign(x=robot["x"] - 0.4 * on), observations=pd.DataFrame())
    unmoved = jumps_moved_back(clean)
    assert unmoved.log is clean and unmoved.jumps == 0 and not unmoved.steps.any()


@pytest.mark.parametrize("later", ["jump out and back", "step that stays"])
def test_steps_that_pair_in_doubt_move_nothing(later):
    # AMCL starting 0.4 m off and converging at 5 s, then a jump out at 30 s (back at 40 s, or
    # never): the steps at 5 and 30 s cancel, and so pair the right 5-30 s stretch as a jump. The
    # shorter wrong stretch is the start's, so that pairing is in doubt (the first rule: its
    # opening step is the track's first, sooner after the start than the jump lasts): nothing is
    # moved
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 200.0, 0.1)
    clean = _wandering_track(rng, t)
    p = clean.copy()
    p[t < 5.0 - 1e-9] += [0.4, 0.0]
    p[(t >= 30.0 - 1e-9) & ((t < 40.0 - 1e-9) if later == "jump out and back" else True)] += [0.4, 0.0]
    jump, offset = detect_steps(t, p, offsets=True)
    assert not offset.any()
    # and so the log's track is left as it is: the pairing in doubt moves nothing back
    from pedcal.calib.amcl_model import jumps_moved_back
    from pedcal.model import Log

    log = Log(sensors=None, robot=_robot_table(t, p), observations=pd.DataFrame())
    unmoved = jumps_moved_back(log)
    assert unmoved.log is log and unmoved.jumps == 0 and unmoved.steps.any()     # found, not moved
    # while a jump well after the start, as long as it lasts, is moved back
    p2 = clean.copy()
    _jumped(p2, t, 60.0, 80.0, [0.4, 0.0])
    jump2, offset2 = detect_steps(t, p2, offsets=True)
    assert jump2.sum() == 200 and np.abs(offset2[jump2, 0] - 0.4).max() < 0.03


@pytest.mark.parametrize("stays_from_s, in_doubt", [(90.0, True), (140.0, False)])
def test_a_jump_followed_soon_by_a_step_that_stays_is_in_doubt(stays_from_s, in_doubt):
    # the second rule: a jump out and back (60-70 s), then a step out that never comes back within
    # max_jump_s of the jump's end (at 90 s): the lasting step could be the right one and the
    # jump's stretch the complement of a longer wrong one, so the jump is not moved; 70 s later,
    # beyond max_jump_s (60 s), the two are unrelated and the jump is moved back
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 300.0, 0.1)
    p = _wandering_track(rng, t)
    on = _jumped(p, t, 60.0, 70.0, [0.4, 0.0])
    _jumped(p, t, stays_from_s, 1e9, [0.4, 0.0])
    jump, offset = detect_steps(t, p, offsets=True)
    assert np.array_equal(jump, on)
    if in_doubt:
        assert not offset.any()
    else:
        assert np.abs(offset[on, 0] - 0.4).max() < 0.03 and not offset[~on].any()


def _robot_table(t, p):
    import pandas as pd

    return pd.DataFrame({"t": t, "x": p[:, 0], "y": p[:, 1], "yaw": np.zeros(len(t)),
                         **{c: np.full(len(t), 1e-3) for c in ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy",
                                                                "cov_yyaw", "cov_yawyaw")}})


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_jump_is_found_where_the_sampling_rate_changes(seed):
    # 10 Hz, with 50 Hz bursts of 10 s every 20 s: each step is counted in its own standard error
    # (the square root of the two lines' variances), not in their variance, or the bursts' windows
    # and the sparse ones are weighed unlike and the jump is missed
    rng = np.random.default_rng(seed)
    fine = np.arange(0.0, 300.0, 0.02)
    path = _track(rng, fine) + np.column_stack([ou_process(rng, len(fine), 0.02, 0.05, 20.0) for _ in range(2)])
    dense = np.concatenate([np.arange(a, a + 10.0, 0.02) for a in range(0, 300, 20)])
    t = np.unique(np.round(np.concatenate([np.arange(0.0, 300.0, 0.1), dense]), 6))
    p = np.column_stack([np.interp(t, fine, path[:, c]) for c in range(2)]) + rng.normal(0.0, 0.008, (len(t), 2))
    assert not detect_steps(t, p).any()
    on = _jumped(p, t, 133.0, 143.0, [0.2, 0.0])
    assert np.array_equal(detect_steps(t, p), on)


def test_a_step_below_min_jump_m_is_no_jump_however_quiet_the_track():
    # a quiet track (2 mm of jitter, no wander): a 9 cm step out and back stands far above the
    # noise in standard errors, but it is below min_jump_m (10 cm) in metres
    rng = np.random.default_rng(9)
    t = np.arange(0.0, 200.0, 0.1)
    p = np.column_stack([0.3 * t, np.zeros(len(t))]) + rng.normal(0.0, 0.002, (len(t), 2))
    _jumped(p, t, 100.0, 110.0, [0.09, 0.0])
    assert not detect_steps(t, p).any()
    _jumped(p, t, 100.0, 110.0, [0.03, 0.0])       # 12 cm: a jump (at min_jump_m 0.08 or 0.12 one fails)
    assert detect_steps(t, p).sum() == 100


def test_a_step_that_never_comes_back_does_not_hide_a_later_jump():
    # a lasting 0.4 m step along x at 30 s (a relocalization that was right, or never undone),
    # then a jump along y at 150-160 s: the offset opened at 30 s never returns within
    # max_jump_s, so the search starts again from the later step and finds the jump alone
    rng = np.random.default_rng(12)
    t = np.arange(0.0, 250.0, 0.1)
    p = _wandering_track(rng, t)
    p[t >= 30.0 - 1e-9] += [0.4, 0.0]
    on = _jumped(p, t, 150.0, 160.0, [0.0, 0.4])
    assert np.array_equal(detect_steps(t, p), on)


def test_amcls_period_is_the_median_step_of_its_stamps_or_the_default():
    from pedcal.calib.amcl_model import amcl_period_s

    # steps 0.1, 0.2, 0.2: the median 0.2 (the smallest 0.1, the mean 0.167)
    assert amcl_period_s(np.array([0.0, 0.1, 0.3, 0.5]), 5.0) == pytest.approx(0.2, abs=1e-15)
    assert amcl_period_s(np.array([3.0]), 5.0) == 5.0            # one stamp: no step to read
    assert amcl_period_s(np.zeros(0), 2.5) == 2.5
    # the stamps as given: repeated ones are steps of 0 (distinct stamps are the caller's to pass)
    assert amcl_period_s(np.array([0.0, 0.0, 0.0, 0.1]), 5.0) == 0.0
    assert amcl_period_s(np.unique([0.0, 0.0, 0.0, 0.1]), 5.0) == pytest.approx(0.1, abs=1e-15)


def test_the_sensors_noise_in_the_residuals_is_not_counted_as_amcls():
    """A residual is AMCL's error less what the sensor saw, its noise included; the graph's
    observation factors carry that noise, so the white part of AMCL's model is the variogram's
    nugget less the noise's variance per axis: sqrt(w^2 - noise_m2), pinned on the same data
    (the fit itself does not move), and near the AMCL's own 20 mm where the sensors add 30 mm."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 600.0, 0.2)
    groups = _visits(rng, t)
    e = rng.normal(0.0, 0.02, (len(t), 2)) + rng.normal(0.0, 0.03, (len(t), 2))
    series = [(g, e[g]) for g in groups]
    assumed = AmclErrorModel(white_sigma_m=0.01, correlated_sigma_m=0.05, correlation_s=20.0)
    both = estimate_model(t, series, assumed)
    amcl = estimate_model(t, series, assumed, noise_m2=0.03 ** 2)
    assert both.correlated_sigma_m == amcl.correlated_sigma_m == 0.0
    assert both.white_sigma_m == pytest.approx(np.hypot(0.02, 0.03), rel=0.1)
    assert amcl.white_sigma_m == pytest.approx(np.sqrt(both.white_sigma_m ** 2 - 0.03 ** 2), rel=1e-12)
    assert amcl.white_sigma_m == pytest.approx(0.02, rel=0.2)


def test_noise_beyond_the_nugget_leaves_amcls_white_part_at_its_floor():
    rng = np.random.default_rng(12)
    t = np.arange(0.0, 600.0, 0.2)
    groups = _visits(rng, t)
    e = rng.normal(0.0, 0.01, (len(t), 2))
    assumed = AmclErrorModel(white_sigma_m=0.01, correlated_sigma_m=0.05, correlation_s=20.0)
    model = estimate_model(t, [(g, e[g]) for g in groups], assumed, noise_m2=0.02 ** 2, min_white_m=0.002)
    assert model.white_sigma_m == 0.002


def test_the_residuals_noise_is_the_sensors_horizontal_variance_per_axis():
    """residual_noise_m2: a point straight below its sensor has only the lateral noise
    horizontally (lateral^2 per axis); one seen horizontally along the world x has its depth
    noise along x and its lateral noise along y ((range^2 + lateral^2) / 2 per axis); a factor
    merging n observations has 1/n of it (g_n / n for a correlated tracker's reports:
    graph.merged_variance_factor, the depth's and the lateral correlation each on its own axis);
    a tilted sensor's ray counts by its horizontal share; factors without a pose variable are
    left out."""
    from types import SimpleNamespace

    import gtsam

    from pedcal.calib.factorgraph import residual_noise_m2
    from pedcal.calib.keys import S
    from pedcal.calib.recipe import GraphRecipe

    rec = GraphRecipe(range_sigma_floor_m=0.01, range_sigma_k_per_m=0.0, lateral_sigma_m=0.004, reliable_range_m=10.0)
    values = gtsam.Values()
    values.insert(S(0), gtsam.Pose3())
    values.insert(S(1), gtsam.Pose3(gtsam.Rot3.Yaw(np.pi / 2), np.zeros(3)))

    def prob(p, count, sensor, key, noise_estimate=None):
        return SimpleNamespace(recipe=rec, sensor_ids=["a", "b"], pose_times=np.zeros(2),
                               fac_p_sensor=np.asarray(p, float), fac_count=np.asarray(count),
                               fac_sensor_index=np.asarray(sensor), fac_key_index=np.asarray(key),
                               noise_estimate=noise_estimate)

    below = prob([[0.0, 0.0, -2.0]], [1], [0], [0])
    assert residual_noise_m2(below, values) == pytest.approx(0.004 ** 2, rel=1e-12)
    level = prob([[2.0, 0.0, 0.0]], [1], [0], [1])
    assert residual_noise_m2(level, values) == pytest.approx(0.5 * (0.01 ** 2 + 0.004 ** 2), rel=1e-12)
    # (sensor b turned a quarter about the vertical: its ray along the world y, the same variance)
    turned = prob([[2.0, 0.0, 0.0]], [4], [1], [1])
    assert residual_noise_m2(turned, values) == pytest.approx(0.5 * (0.01 ** 2 + 0.004 ** 2) / 4, rel=1e-12)
    mixed = prob([[0.0, 0.0, -2.0], [2.0, 0.0, 0.0], [2.0, 0.0, 0.0]], [1, 1, 1], [0, 0, 0], [0, 1, 5])
    assert residual_noise_m2(mixed, values) == pytest.approx(0.5 * (0.004 ** 2 + 0.5 * (0.01 ** 2 + 0.004 ** 2)))
    assert residual_noise_m2(prob(np.zeros((0, 3)), [], [], []), values) == 0.0
    # a tracker correlated at 0.6 frame to frame: three reports' mean has 2.04 / 3 of one's variance
    correlated = {"frame_correlation": {"along": 0.6, "lateral": 0.6}}
    merged = prob([[0.0, 0.0, -2.0]], [3], [0], [0], correlated)
    assert residual_noise_m2(merged, values) == pytest.approx(0.004 ** 2 * 2.04 / 3, rel=1e-12)
    # the depth's and the lateral correlation apart (0.6 and 0.2): three reports' variance factors
    # 2.04 and 1 + 2 (2/3 0.2 + 1/3 0.04), each on its own axis (depth along the world x)
    g_lateral = 1.0 + 2.0 * (2.0 / 3.0 * 0.2 + 1.0 / 3.0 * 0.04)
    apart = prob([[2.0, 0.0, 0.0]], [3], [0], [1], {"frame_correlation": {"along": 0.6, "lateral": 0.2}})
    assert residual_noise_m2(apart, values) == pytest.approx(0.5 * (0.01 ** 2 * 2.04 + 0.004 ** 2 * g_lateral) / 3,
                                                             rel=1e-12)
    # a tilted sensor (turned a quarter about the vertical, then pitched 45 deg): its ray's
    # horizontal share is cos^2 45 = 1/2, the rest of the depth noise vertical
    tilted_values = gtsam.Values()
    tilted_values.insert(S(0), gtsam.Pose3(gtsam.Rot3.Ypr(np.pi / 2, np.pi / 4, 0.0), np.zeros(3)))
    tilted_values.insert(S(1), gtsam.Pose3())
    tilted = prob([[2.0, 0.0, 0.0]], [1], [0], [1])
    want = 0.5 * (2.0 * 0.004 ** 2 + (0.01 ** 2 - 0.004 ** 2) * 0.5)
    assert residual_noise_m2(tilted, tilted_values) == pytest.approx(want, rel=1e-12)
