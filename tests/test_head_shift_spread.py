"""The spread of the head point between the sensors' trackers, estimated from the data
(pedcal.calib.headpoint.spread_log_likelihood, estimate_departure_spread; recipe
head_shift_per_sensor_sigma_estimate): the departures' prior sigma tau by their marginal
likelihood, its own uncertainty carried, the recipe's value kept when too few sensors inform it."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from pedcal.calib.headpoint import (
    SENSOR_PREFIX,
    SPREAD_GRID,
    estimate_departure_spread,
    spread_from_estimates,
    spread_log_likelihood,
    spread_note,
    spread_record,
    spread_summary,
)
from pedcal.calib.profile import Nuisance
from pedcal.errors import DegenerateDataWarning


def _draws(seed: int, k: int, tau: float, mu: float = 0.03):
    """k sensors' own shift estimates y_s = mu + delta_s + e_s, delta_s ~ N(0, tau^2), e_s ~ N(0,
    sigma_s^2), sigma_s uniform in 3-10 mm; (y, sigma, the true own shifts mu + delta)."""
    rng = np.random.default_rng(seed)
    sigma = rng.uniform(0.003, 0.010, k)
    own = mu + rng.normal(0.0, tau, k)
    return own + rng.normal(0.0, sigma), sigma, own


@pytest.mark.parametrize("tau", [0.01, 0.02, 0.04])
def test_a_known_spread_is_recovered(tau):
    # 100 sensors: within 3 standard errors of tau (sqrt(2 / k) (tau^2 + mean sigma^2) / (2 tau),
    # the delta method on var(tau^2 hat); 1.0, 1.5 and 2.9 mm here) and the grid's 0.5 mm spacing
    k = 100
    y, sigma, _ = _draws(7, k, tau)
    est = spread_from_estimates(y, sigma)
    assert est["sensors"] == k
    se = np.sqrt(2.0 / k) * (tau ** 2 + np.mean(sigma ** 2)) / (2.0 * tau)
    assert abs(est["estimate_m"] - tau) < 3.0 * se + 0.0005
    # its posterior's root mean square and 95 % quantile lie above the estimate, not far
    assert est["estimate_m"] <= est["rms_m"] < est["upper_m"] < est["estimate_m"] + 0.01


def test_the_likelihood_is_the_restricted_likelihood_of_independent_estimates():
    # y_s ~ N(mu, sigma_s^2 + tau^2), mu integrated out (REML): -1/2 [sum ln(v_s) + ln(sum w) +
    # sum w (y - mu_hat)^2], v_s = sigma_s^2 + tau^2, w = 1 / v, mu_hat = sum w y / sum w
    y, sigma, _ = _draws(3, 6, 0.02)
    k = len(y)
    J = np.column_stack([np.ones(k), np.eye(k)])
    mu_sigma = 1e4
    prior_sigma = np.r_[mu_sigma, np.full(k, 0.02)]
    H = J.T @ (J / sigma[:, None] ** 2) + np.diag(1.0 / prior_sigma ** 2)
    theta = np.r_[0.01, np.linspace(-0.01, 0.01, k)]      # any point: the quadratic is exact
    g = J.T @ ((J @ theta - y) / sigma ** 2) + theta / prior_sigma ** 2
    grid = np.array([0.002, 0.01, 0.03, 0.06])
    ll = spread_log_likelihood(H, g, theta, np.zeros(k + 1), prior_sigma, np.arange(1, k + 1), grid)

    def reml(tau):
        w = 1.0 / (sigma ** 2 + tau ** 2)
        mu = np.sum(w * y) / np.sum(w)
        return -0.5 * (np.sum(np.log(1.0 / w)) + np.log(np.sum(w)) + np.sum(w * (y - mu) ** 2))
    want = np.array([reml(t) for t in grid])
    np.testing.assert_allclose(ll - ll[0], want - want[0], atol=1e-6)


def test_with_an_informative_shared_prior_the_likelihood_is_the_exact_gaussian_marginal():
    # the shared shift's prior N(m0, s0^2) informative (m0 20 mm, s0 10 mm), not diffuse: y =
    # 1 mu + delta + e integrates to N(m0 1, V), V = diag(sigma^2 + tau^2) + s0^2 1 1^T, whose log
    # density is -1/2 [ln det V + d^T V^-1 d], d = y - m0 1 (the prior's part kept in K, the
    # other nuisances' block of spread_log_likelihood)
    y, sigma, _ = _draws(5, 6, 0.02)
    k = len(y)
    J = np.column_stack([np.ones(k), np.eye(k)])
    m0, s0 = 0.02, 0.01
    prior_mean = np.r_[m0, np.zeros(k)]
    prior_sigma = np.r_[s0, np.full(k, 0.02)]
    theta = np.r_[0.015, np.linspace(-0.02, 0.01, k)]      # away from 0 and from the prior's mean
    H = J.T @ (J / sigma[:, None] ** 2) + np.diag(1.0 / prior_sigma ** 2)
    g = J.T @ ((J @ theta - y) / sigma ** 2) + (theta - prior_mean) / prior_sigma ** 2
    grid = np.array([0.002, 0.01, 0.03, 0.06])
    ll = spread_log_likelihood(H, g, theta, prior_mean, prior_sigma, np.arange(1, k + 1), grid)

    def marginal(tau):
        V = np.diag(sigma ** 2 + tau ** 2) + s0 ** 2 * np.ones((k, k))
        d = y - m0
        return -0.5 * (np.linalg.slogdet(V)[1] + d @ np.linalg.solve(V, d))
    want = np.array([marginal(t) for t in grid])
    np.testing.assert_allclose(ll - ll[0], want - want[0], atol=1e-6)


def test_equal_estimates_give_no_spread_but_a_used_sigma_within_what_they_allow():
    est = spread_from_estimates(np.full(8, 0.02), np.full(8, 0.005))
    assert est["estimate_m"] == 0.0
    # what 8 sensors of 5 mm allow: a few mm, not the recipe's 20
    assert 0.0 < est["rms_m"] < 0.006


def test_one_sensor_gives_no_estimate():
    est = spread_from_estimates([0.03], [0.005])
    assert est["sensors"] == 1 and np.isnan(est["estimate_m"]) and np.isnan(est["rms_m"])


def test_sensors_with_a_nan_or_zero_sigma_or_estimate_are_left_out():
    y, sigma, _ = _draws(5, 10, 0.02)
    base = spread_from_estimates(y, sigma)
    bad = spread_from_estimates(np.r_[y, 0.5, np.nan, 0.2], np.r_[sigma, np.nan, 0.004, 0.0])
    assert bad == base


def _own_shift_sigma(y, sigma, tau):
    """Each sensor's own shift mu + delta_s and its sigma with delta_s ~ N(0, tau^2), mu diffuse
    (the graph's model reduced to independent estimates)."""
    k = len(y)
    J = np.column_stack([np.ones(k), np.eye(k)])
    H = J.T @ (J / sigma[:, None] ** 2) + np.diag(np.r_[1e-8, np.full(k, 1.0 / tau ** 2)])
    cov = np.linalg.inv(H)
    x = cov @ (J.T @ (y / sigma ** 2))
    var = cov[0, 0] + np.diag(cov)[1:] + 2.0 * cov[0, 1:]
    return x[0] + x[1:], np.sqrt(var)


def test_a_wrong_assumed_spread_misstates_the_sigma_and_the_estimate_covers_it():
    # true spread 30 mm, 10 sensors a log, 200 logs: error / sigma RMS of each sensor's own shift
    tau = 0.03
    ratios = {"5 mm": [], "20 mm": [], "estimated": [], "100 mm": []}
    for seed in range(200):
        y, sigma, own = _draws(seed, 10, tau)
        used = spread_from_estimates(y, sigma)["rms_m"]
        for name, t in (("5 mm", 0.005), ("20 mm", 0.02), ("estimated", used), ("100 mm", 0.1)):
            est, sd = _own_shift_sigma(y, sigma, t)
            ratios[name].append((est - own) / sd)
    rms = {name: float(np.sqrt(np.mean(np.square(r)))) for name, r in ratios.items()}
    assert rms["5 mm"] > 1.5            # too small a spread: sigma far too narrow
    assert rms["20 mm"] > 1.05          # the recipe's 20 mm: somewhat narrow
    assert 0.9 < rms["estimated"] < 1.1
    assert rms["100 mm"] < rms["estimated"]     # too wide a spread: sigma too wide


def _step(informed: int, uninformed: int):
    """A profile step over the shared shift and departures: ``informed`` sensors measured to 5 mm,
    ``uninformed`` ones to 1 m (seen from one side), prior 20 mm each."""
    k = informed + uninformed
    sigma = np.r_[np.full(informed, 0.005), np.full(uninformed, 1.0)]
    J = np.column_stack([np.ones(k), np.eye(k)])
    prior = np.r_[0.05, np.full(k, 0.02)]
    H = J.T @ (J / sigma[:, None] ** 2) + np.diag(1.0 / prior ** 2)
    y = 0.03 + np.random.default_rng(1).normal(0.0, 0.03, k)
    g = -J.T @ (y / sigma ** 2)
    nuis = [Nuisance("horizontal_shift_m", 0.0, 0.05, 0.02)] + [
        Nuisance(SENSOR_PREFIX + f"s{i}", 0.0, 0.02, 0.01) for i in range(k)]
    prob = SimpleNamespace(recipe=SimpleNamespace(head_shift_per_sensor_sigma_m=0.02))
    return prob, SimpleNamespace(hessian=H, dtheta=-np.linalg.solve(H, g), covariance=np.linalg.inv(H)), nuis


def test_too_few_informed_sensors_keep_the_recipes_sigma_with_a_warning():
    prob, step, nuis = _step(2, 6)
    H = step.hessian.copy()
    with pytest.warns(DegenerateDataWarning, match="determine 2 sensors' own shift"):
        step2, nuis2, rec = estimate_departure_spread(prob, step, nuis, np.zeros(len(nuis)))
    assert rec["estimate_m"] is None and rec["rms_m"] is None and not rec["applied"]
    assert nuis2 == nuis and np.array_equal(step2.hessian, H)
    assert list(vars(prob)) == ["recipe"]           # the record is returned, the caller keeps it
    assert "not estimated (the data determine 2 sensors' own shift" in spread_note(rec)
    assert "prior sigma 20 mm" in spread_note(rec)
    # only reported (the recipe's default): no warning
    prob, step, nuis = _step(2, 6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert estimate_departure_spread(prob, step, nuis, np.zeros(len(nuis)), use=False)[2]["estimate_m"] is None


def test_the_estimate_takes_the_departures_prior_and_the_step_is_the_new_optimum():
    prob, step, nuis = _step(12, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        step, nuis, rec = estimate_departure_spread(prob, step, nuis, np.zeros(len(nuis)))
    assert rec["sensors"] == 12 and rec["applied"]
    assert 0.015 < rec["estimate_m"] < 0.05 and rec["rms_m"] >= rec["estimate_m"]
    assert all(n.prior_sigma == rec["rms_m"] for n in nuis[1:]) and nuis[0].prior_sigma == 0.05
    # the Hessian's prior part is the new one: H - P(new) is the data's
    k = len(nuis) - 1
    sigma = np.r_[np.full(12, 0.005), np.full(3, 1.0)]
    J = np.column_stack([np.ones(k), np.eye(k)])
    want = J.T @ (J / sigma[:, None] ** 2) + np.diag(1.0 / np.r_[0.05, np.full(k, rec["rms_m"])] ** 2)
    np.testing.assert_allclose(step.hessian, want, rtol=1e-12)
    assert f"{1000 * rec['estimate_m']:.1f} mm" in spread_note(rec) and "keeps" not in spread_note(rec)
    assert SPREAD_GRID[0] > 0.0


def test_an_estimate_only_reported_leaves_the_step_and_the_prior_as_they_were():
    prob, step, nuis = _step(12, 3)
    H, dtheta = step.hessian.copy(), step.dtheta.copy()
    step, nuis2, rec = estimate_departure_spread(prob, step, nuis, np.zeros(len(nuis)), use=False)
    assert not rec["applied"] and 0.015 < rec["estimate_m"] < 0.05
    assert list(vars(prob)) == ["recipe"]           # the record is returned, the caller keeps it
    assert nuis2 == nuis and np.array_equal(step.hessian, H) and np.array_equal(step.dtheta, dtheta)
    # the same estimate as when used
    used = estimate_departure_spread(*_step(12, 3), np.zeros(len(nuis)))[2]
    assert rec["estimate_m"] == used["estimate_m"] and rec["rms_m"] == used["rms_m"]
    assert "keeps the recipe's prior sigma 20 mm" in spread_note(rec)


def test_the_head_models_record_names_the_prior_the_departures_had():
    prob, step, nuis = _step(12, 3)
    rec = estimate_departure_spread(prob, step, nuis, np.zeros(len(nuis)), use=False)[2]
    out = spread_record(rec)
    assert out == {"estimate_m": round(rec["estimate_m"], 5), "upper_m": round(rec["upper_m"], 5),
                   "rms_m": round(rec["rms_m"], 5), "sensors": 12, "prior_sigma_m": 0.02}
    used = spread_record({**rec, "applied": True})
    assert used["prior_sigma_m"] == round(rec["rms_m"], 5)
    none = spread_record({"prior_m": 0.02, "sensors": 1, "applied": False, "estimate_m": None, "rms_m": None,
                          "upper_m": None})
    assert none == {"estimate_m": None, "upper_m": None, "rms_m": None, "sensors": 1, "prior_sigma_m": 0.02}
    assert spread_record(None) is None


def test_the_informed_sensors_are_those_whose_posterior_variance_is_at_most_half_the_prior():
    # 15 sensors' own shifts measured to 2-60 mm against a 20 mm prior: the posterior variance (the
    # shared shift integrated out) halves the prior's for the first 10 (a rule of 0.1 or 0.9 of the
    # prior's variance would count 0 or 14)
    k = 15
    sigma = np.geomspace(0.002, 0.06, k)
    J = np.column_stack([np.ones(k), np.eye(k)])
    prior = np.r_[0.05, np.full(k, 0.02)]
    H = J.T @ (J / sigma[:, None] ** 2) + np.diag(1.0 / prior ** 2)
    g = -J.T @ (0.03 / sigma ** 2)
    nuis = [Nuisance("horizontal_shift_m", 0.0, 0.05, 0.02)] + [
        Nuisance(SENSOR_PREFIX + f"s{i}", 0.0, 0.02, 0.01) for i in range(k)]
    prob = SimpleNamespace(recipe=SimpleNamespace(head_shift_per_sensor_sigma_m=0.02))
    step = SimpleNamespace(hessian=H, dtheta=-np.linalg.solve(H, g), covariance=np.linalg.inv(H))
    post = np.diag(np.linalg.inv(H))[1:]
    assert np.sum(post <= 0.5 * 0.02 ** 2) == 10
    assert estimate_departure_spread(prob, step, nuis, np.zeros(k + 1), use=False)[2]["sensors"] == 10


def test_the_step_from_a_point_away_from_zero_is_the_optimum_under_the_estimated_prior():
    # the quadratic's optimum does not depend on where the step starts: from theta = 0 and from
    # another point (the gradient there g0 + H theta) the new step lands on the same optimum,
    # argmin of the data's quadratic plus the new prior
    prob, step0, nuis = _step(12, 3)
    H = step0.hessian
    g0 = -H @ step0.dtheta
    theta = np.linspace(-0.01, 0.02, len(nuis))
    step = SimpleNamespace(hessian=H.copy(), dtheta=-np.linalg.solve(H, g0 + H @ theta), covariance=np.linalg.inv(H))
    step, nuis2, rec = estimate_departure_spread(prob, step, nuis, theta)
    tau = rec["rms_m"]
    p_old = 1.0 / np.array([n.prior_sigma for n in nuis]) ** 2
    p_new = 1.0 / np.array([n.prior_sigma for n in nuis2]) ** 2
    H_data, g_data = H - np.diag(p_old), g0          # (the priors' gradient at theta = 0 is 0)
    optimum = -np.linalg.solve(H_data + np.diag(p_new), g_data)
    np.testing.assert_allclose(theta + step.dtheta, optimum, rtol=0, atol=1e-12)
    assert tau != 0.02 and np.all(p_new[1:] == 1.0 / tau ** 2)


def test_departures_fitted_each_on_its_own_are_named_not_estimated():
    # more sensors than clock_offsets_joint_max: the departures are local, none in the joint step;
    # used, the recipe's sigma is kept with a warning that says why, and the note says it too
    prob, step, nuis = _step(12, 3)
    shared = nuis[:1]
    setattr(prob, SENSOR_PREFIX + "s0", 0.0)          # a departure exists, fitted with the path
    with pytest.warns(DegenerateDataWarning, match="fitted with the path on its own"):
        _, _, rec = estimate_departure_spread(prob, step, shared, np.zeros(1))
    assert rec["sensors"] == 0 and rec["estimate_m"] is None and not rec["applied"]
    assert "fitted with the path on its own" in spread_note(rec)
    # without any departure (their prior sigma 0): nothing to say
    prob2 = SimpleNamespace(recipe=SimpleNamespace(head_shift_per_sensor_sigma_m=0.0))
    assert estimate_departure_spread(prob2, step, shared, np.zeros(1))[2] is None


def test_the_summary_of_a_likelihood_on_four_points_is_its_maximum_rms_and_95_percent_quantile():
    # weights 0.1, 0.4, 0.3, 0.2 on 10-40 mm: the maximum 20 mm, sqrt(E[tau^2]) = sqrt(7.6e-4) (the
    # mean would be 26 mm), the 95 % quantile the last point (the 80 % one would be 30 mm)
    out = spread_summary(np.log([0.1, 0.4, 0.3, 0.2]), np.array([0.01, 0.02, 0.03, 0.04]))
    assert out["estimate_m"] == 0.02 and out["upper_m"] == 0.04
    assert out["rms_m"] == pytest.approx(np.sqrt(7.6e-4), rel=1e-12)
    # the maximum at the grid's first point is the limit tau -> 0
    assert spread_summary(np.log([0.5, 0.3, 0.2]), np.array([1e-4, 0.01, 0.02]))["estimate_m"] == 0.0


def test_a_likelihood_that_is_not_finite_keeps_the_recipes_sigma_with_a_warning(monkeypatch):
    import pedcal.calib.headpoint as hp

    prob, step, nuis = _step(12, 3)
    H = step.hessian.copy()
    monkeypatch.setattr(hp, "spread_log_likelihood", lambda *a, **k: np.full(len(SPREAD_GRID), np.nan))
    with pytest.warns(DegenerateDataWarning, match="likelihood is not finite"):
        step2, nuis2, rec = estimate_departure_spread(prob, step, nuis, np.zeros(len(nuis)))
    assert rec["estimate_m"] is None and not rec["applied"] and nuis2 == nuis
    assert np.array_equal(step2.hessian, H)


def test_a_hessian_whose_data_part_is_not_positive_gives_no_likelihood_but_rounding_does():
    # the departures' data part -1e-2 beside 1e6 (1e-8 relative, above the 1e-9 rounding floor: no
    # Gauss-Newton Hessian): NaN, which is "not estimated"; a data part of -1e-12 beside 1e6 is
    # rounding, floored at 0: a finite likelihood
    prior = np.array([0.05, 0.02, 0.02])
    for data, finite in ((np.diag([1e6, -1e-2, 1e6]), False), (np.diag([1e6, -1e-12, 1e6]), True)):
        H = data + np.diag(1.0 / prior ** 2)
        ll = spread_log_likelihood(H, np.zeros(3), np.zeros(3), np.zeros(3), prior, np.array([1, 2]))
        assert np.isfinite(ll).all() == finite and (finite or np.isnan(ll).all())
