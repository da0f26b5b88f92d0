"""The head point's shift against distance as a consider parameter
(pedcal.calib.headpoint.considered_nuisances, leave_out; recipe head_profile_consider): with no
profile estimated, a line rising 0 +- head_profile_sigma_m across the robot's distances is held
at 0 and what the data leave of its prior (its posterior's root mean square about 0,
considered_rms) carried into the sensors' covariance. Under a wandering AMCL the robot's path
takes its scale from the sensors' views, whose radial scale such a line sets: a corridor's
sensors then spread along it by what the line moves them, which the sigma must carry; where the
data measure the line near 0, the sigma is not widened by the prior's."""

import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pedcal.calib.factorgraph as fgmod
from pedcal.calib import calibrate
from pedcal.calib.headpoint import SLOPE, considered_nuisances, considered_rms, leave_out
from pedcal.calib.profile import ProfileStep
from pedcal.sim import simulate_logs


def _linear_problem(seed: int = 0, n: int = 6, k: int = 3, m: int = 40):
    """A linear least-squares problem y = A x + B theta with a prior 0 +- sigma on each theta: the
    variables' conditional sensitivity Z = -(A^T A)^-1 A^T B, the profile's information H (the
    data's, the variables profiled out, plus the priors)."""
    rng = np.random.default_rng(seed)
    A, B = rng.normal(size=(m, n)), rng.normal(size=(m, k))
    sigma = np.array([0.5, 1.0, 2.0])[:k]
    AtA_inv = np.linalg.inv(A.T @ A)
    Z = -AtA_inv @ A.T @ B
    P = np.eye(m) - A @ AtA_inv @ A.T
    H = B.T @ P @ B + np.diag(1.0 / sigma ** 2)
    return A, B, sigma, Z, H


def _solve(A, B, sigma, y, fixed: dict):
    """The joint least-squares solution (x, theta) with the thetas in ``fixed`` held at their
    values and the others under their priors."""
    n, k = A.shape[1], B.shape[1]
    free = [j for j in range(k) if j not in fixed]
    r = y - sum(B[:, j] * v for j, v in fixed.items())
    M = np.block([[A, B[:, free]], [np.zeros((len(free), n)), np.diag(1.0 / sigma[free])]])
    sol = np.linalg.lstsq(M, np.r_[r, np.zeros(len(free))], rcond=None)[0]
    return sol[:n], sol[n:]


def test_leave_out_is_the_exact_error_of_holding_a_nuisance_and_the_others_newton_step():
    A, B, sigma, Z, H = _linear_problem()
    rng = np.random.default_rng(1)
    x_true, theta_true = rng.normal(size=A.shape[1]), np.array([0.3, -0.7, 1.1])
    y = A @ x_true + B @ theta_true
    # the profile at theta = 0: its gradient and Newton step
    x0 = np.linalg.lstsq(A, y, rcond=None)[0]
    g = -(B.T @ (y - A @ x0))                 # d(chi^2 / 2)/d theta at 0, the variables profiled out
    step = ProfileStep(dtheta=-np.linalg.solve(H, g), hessian=H, z0=x0, Z=Z, cols=None)
    j = 1
    reduced, S = leave_out(step, j)
    # the others' step: the joint solution with theta_j held at 0
    x_held, theta_held = _solve(A, B, sigma, y, {j: 0.0})
    np.testing.assert_allclose(reduced.dtheta, theta_held, rtol=1e-9, atol=1e-12)
    # holding theta_j at 0 instead of c moves the variables by -S c, the others re-optimized
    c = 0.8
    x_at_c, _ = _solve(A, B, sigma, y, {j: c})
    np.testing.assert_allclose(x_held - x_at_c, -S * c, rtol=1e-9, atol=1e-12)
    # and S is not the conditional sensitivity: the others take up part of it
    assert not np.allclose(S, Z[:, j])


def _posterior(A, B, sigma, y, j, held=()):
    """theta_j's posterior mean and variance from the joint least squares (the variables free, the
    other thetas under their priors but those in ``held``, known at 0), noise sigma 1."""
    k = B.shape[1]
    free = [i for i in range(k) if i not in held]
    n = A.shape[1]
    M = np.block([[A, B[:, free]], [np.zeros((len(free), n)), np.diag(1.0 / sigma[free])]])
    sol = np.linalg.lstsq(M, np.r_[y, np.zeros(len(free))], rcond=None)[0]
    cov = np.linalg.inv(M.T @ M)
    at = n + free.index(j)
    return sol[at], cov[at, at]


def _step_at_zero(A, B, Z, H, y):
    x0 = np.linalg.lstsq(A, y, rcond=None)[0]
    g = -(B.T @ (y - A @ x0))
    return ProfileStep(dtheta=-np.linalg.solve(H, g), hessian=H, z0=x0, Z=Z, cols=None)


@pytest.mark.parametrize("held", [(), (2,)])
def test_considered_rms_is_the_posterior_second_moment_about_the_held_value_plus_the_holds_move(held):
    A, B, sigma, Z, H = _linear_problem()
    rng = np.random.default_rng(2)
    y = A @ rng.normal(size=A.shape[1]) + B @ np.array([0.3, -0.7, 1.1]) + rng.normal(size=len(A))
    step = _step_at_zero(A, B, Z, H, y)
    mu, v = _posterior(A, B, sigma, y, 1, held)
    # a nuisance held (the curvature): how far the hold moves the posterior mean counts too
    mu_free = _posterior(A, B, sigma, y, 1, ())[0]
    assert considered_rms(step, 1, held=held) == pytest.approx(np.sqrt(mu ** 2 + v + (mu - mu_free) ** 2), rel=1e-9)
    assert abs(mu) > 0.1                # (the data moved it: the distance counts, not the variance alone)
    if held:
        assert abs(mu - mu_free) > 0.05    # (the hold moved it: the move counts)


def test_considered_rms_is_the_prior_sigma_where_the_data_say_nothing():
    A, B, sigma, Z, H = _linear_problem()
    B[:, 1] = 0.0                       # theta_1 enters no observation
    P = np.eye(len(A)) - A @ np.linalg.solve(A.T @ A, A.T)
    H = B.T @ P @ B + np.diag(1.0 / sigma ** 2)
    y = np.random.default_rng(3).normal(size=len(A))
    step = _step_at_zero(A, B, -np.linalg.solve(A.T @ A, A.T @ B), H, y)
    assert considered_rms(step, 1) == pytest.approx(sigma[1], rel=1e-12)


@pytest.mark.parametrize("drawn", [True, False])
def test_the_considered_variance_is_the_held_estimates_mean_squared_error(drawn):
    # theta_j held at 0, its truth drawn from its prior (drawn) or 0 (the model holds): the
    # variables' squared error averaged over draws against what the covariance predicts with
    # the data's width of theta_j and with its prior's. Drawn from the prior, both are right on
    # average; at 0, the prior's over-predicts it where the data measure theta_j, the data's not
    A, B, sigma, Z, H = _linear_problem(m=60)
    j, n = 1, A.shape[1]
    _, S = leave_out(ProfileStep(dtheta=np.zeros(3), hessian=H, z0=None, Z=Z, cols=None), j)
    o = [0, 2]
    info = np.block([[A.T @ A, A.T @ B[:, o]], [B[:, o].T @ A, B[:, o].T @ B[:, o] + np.diag(1.0 / sigma[o] ** 2)]])
    given = np.diag(np.linalg.inv(info))[:n]     # the variables' variance with theta_j known
    rng = np.random.default_rng(4)
    draws = 2000
    X, theta = rng.normal(size=(draws, n)), rng.normal(size=(draws, 3)) * sigma
    theta[:, j] *= drawn
    Y = X @ A.T + theta @ B.T + rng.normal(size=(draws, len(A)))
    # the joint least squares with theta_j held at 0 (_solve's), linear in y: all draws at once
    M = np.block([[A, B[:, o]], [np.zeros((2, n)), np.diag(1.0 / sigma[o])]])
    err2 = np.mean((Y @ np.linalg.pinv(M)[:n, :len(A)].T - X) ** 2, axis=0)
    width2 = np.mean([considered_rms(_step_at_zero(A, B, Z, H, y), j) ** 2 for y in Y])
    predicted, prior_predicted = given + S ** 2 * width2, given + S ** 2 * sigma[j] ** 2
    if drawn:
        np.testing.assert_allclose(err2 / predicted, 1.0, atol=0.1)
        np.testing.assert_allclose(err2 / prior_predicted, 1.0, atol=0.1)
    else:
        # (a little over: the data's estimate of theta_j scatters about 0 by its own sigma, which
        # the width counts as a distance it may be from its truth besides its variance)
        assert np.all((err2 / predicted > 0.75) & (err2 / predicted < 1.1))
        most = np.argmax(np.abs(S))
        assert prior_predicted[most] > 2.0 * err2[most]


def _prob(mode="off", consider=True, n_obs=400):
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(0.3, 3.0, n_obs), rng.uniform(-1.0, 1.0, n_obs), np.full(n_obs, 1.5)])
    toward = -p * np.array([1.0, 1.0, 0.0])
    toward /= np.linalg.norm(toward, axis=1, keepdims=True)
    rec = SimpleNamespace(head_profile=mode, head_profile_consider=consider, robot=True,
                          estimate_head_horizontal_shift=True, head_horizontal_shift_sigma_m=0.05,
                          head_profile_sigma_m=0.03, head_profile_knots=4)
    return SimpleNamespace(recipe=rec, fac_p_sensor=p, fac_toward_sensor=toward)


def test_the_line_is_considered_only_when_no_profile_is_estimated():
    nuis = considered_nuisances(_prob())
    assert [(n.name, n.prior_mean, n.prior_sigma) for n in nuis] == [(SLOPE, 0.0, 0.03)]
    assert considered_nuisances(_prob(mode="linear")) == []       # estimated: its covariance is carried anyway
    assert considered_nuisances(_prob(consider=False)) == []
    assert considered_nuisances(_prob(n_obs=20)) == []            # too few observations for knots


def _corridor(seed: int):
    # a 12 m corridor whose tracker shifts the head point 5 cm toward the sensor right under it,
    # fading to nothing 2 m away (outside the graph's constant-shift family), AMCL wandering
    return simulate_logs("corridor", seed=seed, head_point="ramp", head_shift_m=0.05, head_ramp_m=2.0,
                         head_ramp_shape="linear", amcl_error="correlated", walkers="none",
                         area_m=[12.0, 2.4], corridor_sensors=10)


def _stretch(sim, res):
    """The sensors' position error along the corridor per metre along it (least-squares slope,
    m/m) and its sigma from the joint covariance."""
    ids = list(res.network.ids)
    E = np.array([res.network[i].position_m - sim.calib.truth[i].position_m for i in ids])
    x = np.array([sim.calib.truth[i].position_m[0] for i in ids])
    w = np.zeros(3 * len(ids))
    w[3 * np.arange(len(ids))] = (x - x.mean()) / np.sum((x - x.mean()) ** 2)
    return float(w @ E.ravel()), float(np.sqrt(w @ res.position_covariance_m2 @ w))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_corridor_stretched_by_a_fading_head_shift_is_within_its_sigma(seed, monkeypatch):
    sim = _corridor(seed)
    seen = {}
    original = fgmod._posterior

    def spy(log_, prob, fg, result, shifts):
        seen["shifts"] = shifts
        return original(log_, prob, fg, result, shifts)

    monkeypatch.setattr(fgmod, "_posterior", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        held = calibrate(sim.calib, method="factorgraph", head_profile_consider=False)
        res = calibrate(sim.calib, method="factorgraph")
    slope0, sigma0 = _stretch(sim, held)
    slope, sigma = _stretch(sim, res)
    # the estimate is the same (the line is held at 0 either way); the stretch, 12-15 mm/m here,
    # was 8-10 sigma of the old covariance and is within 2 of the new
    np.testing.assert_allclose([res.network[i].position_m for i in res.network.ids],
                               [held.network[i].position_m for i in held.network.ids], atol=1e-9)
    assert slope == pytest.approx(slope0, abs=1e-9)
    assert abs(slope) > 0.008
    assert abs(slope0) > 5.0 * sigma0
    assert abs(slope) < 2.0 * sigma
    # the covariance's added share is the line's width times its sensitivity, nothing else; the
    # data find the line beyond its prior's sigma (the ramp falls 5 cm), and the width says so
    sd, sens = seen["shifts"].considered
    assert sd > 0.03 and sens.shape == (6 * len(res.network.ids) + 6,)


@pytest.mark.filterwarnings("ignore")
def test_a_sensors_sigma_widened_by_nuisances_keeps_its_estimate(monkeypatch):
    # a nuisance's prior carried into the sensors' covariance (the consider line's, which on a
    # large site reaches the installed prior's size) widens the sigma; it is no lack of data,
    # so the estimate is not replaced by the installed pose. The graph's own marginal given the
    # nuisances decides what the data constrain: widened as well, the sensors are degenerate.
    sim = simulate_logs("paper", seed=0, duration_s=60.0)
    base = calibrate(sim.calib, method="factorgraph")
    original = fgmod._posterior
    wide = np.diag([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])       # 1 m sigma on each axis, m^2

    def widened(*args, given_too: bool = False, **kwargs):
        cov_body, cov_given, *rest = original(*args, **kwargs)
        cov_body = {sid: c + wide for sid, c in cov_body.items()}
        if given_too:
            cov_given = {sid: c + wide for sid, c in cov_given.items()}
        return (cov_body, cov_given, *rest)

    monkeypatch.setattr(fgmod, "_posterior", widened)
    seen = [s.id for s in base.network if s.status == "ok"]
    assert len(seen) >= 4
    res = calibrate(sim.calib, method="factorgraph")
    for sid in seen:
        assert res.network[sid].status == "ok"
        np.testing.assert_allclose(res.network[sid].position_m, base.network[sid].position_m, atol=1e-9)
        assert np.all(res.network[sid].sigma_position_m > 0.99)
    monkeypatch.setattr(fgmod, "_posterior", lambda *a, **k: widened(*a, given_too=True, **k))
    res = calibrate(sim.calib, method="factorgraph")
    assert all(res.network[sid].status == "degenerate" for sid in seen)


def test_on_a_site_whose_head_point_is_the_models_the_line_widens_the_sigma_by_what_the_data_leave(monkeypatch):
    # the scale benchmark's site (40 sensors, 12 x 8 m, the head point the model's: no line):
    # the sensors' sensitivity to the line is a stretch of the whole network, which the 3 cm
    # prior made 1.6x the sigma without the line; the data measure the line to a few mm, and
    # the width is what they leave of the prior
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_factorgraph_scale import synthetic_log

    log = synthetic_log(40, seed=1)
    seen = {}
    original = fgmod._posterior
    rms_calls = []
    considered_rms = fgmod.considered_rms

    def recording(step, j, held=()):
        rms_calls.append((held, considered_rms(step, j, held=held)))
        return rms_calls[-1][1]
    monkeypatch.setattr(fgmod, "considered_rms", recording)

    def spy(log_, prob, fg, result, shifts):
        seen["considered"] = shifts.considered
        return original(log_, prob, fg, result, shifts)

    monkeypatch.setattr(fgmod, "_posterior", spy)
    kwargs = dict(is_robot=np.ones(len(log.observations), bool), estimate_latency=False, people=False,
                  head_radius_m=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fgmod.calibrate_factorgraph(log, **kwargs)
        sd = seen["considered"][0]
        calls = list(rms_calls)
        held = fgmod.calibrate_factorgraph(log, head_profile_consider=False, **kwargs)
    # the curvature left out, the width is taken again with it held at 0 (what is considered)
    assert calls and calls[-1][0] and sd == calls[-1][1]
    assert 0.0 < sd < 0.3 * 0.03          # (1.8-7.3 mm on seeds 0-3)
    sigma = np.median([s.sigma_position_m[:2] for s in res.network], axis=0)
    sigma_held = np.median([s.sigma_position_m[:2] for s in held.network], axis=0)
    assert np.all(sigma >= sigma_held - 1e-9)
    assert np.all(sigma < 1.15 * sigma_held)
