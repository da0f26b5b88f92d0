"""The Cramér-Rao bound of sensor positions: a numeric Fisher-information check and its 1/N
scaling, on small exact logs; under AMCL's true error process, its common shift against the exact
best linear unbiased estimate of an Ornstein-Uhlenbeck mean, and the simulator's noise as the
bound takes it (never above the simulated)."""

import copy

import gtsam
import numpy as np
import pytest
from test_factorgraph import make_exact_log

from pedcal.calib.amcl_model import AmclErrorModel
from pedcal.calib.crlb import (
    KNOWN_HEADING_SIGMA_RAD,
    MIN_WHITE_M,
    CRLBResult,
    common_shift_variance_m2,
    sensor_position_crlb,
    share_rms_within_mm,
    simulator_noise,
    true_values,
)
from pedcal.calib.factorgraph import GraphRecipe, S, build_graph, prepare, sensor_sigma_world
from pedcal.calib.recipe import observation_sigmas
from pedcal.errors import PedcalInputError
from pedcal.sim.scenario import load_scenario

SIGMA_M = 0.05      # observation noise large against AMCL's 1 mm: the sensors' data dominate


def _recipe():
    return GraphRecipe(head_radius_m=0.0, estimate_latency=False, people=False, robust_kernel="none",
                       range_sigma_floor_m=SIGMA_M, range_sigma_k_per_m=0.0, lateral_sigma_m=SIGMA_M,
                       far_factor=1.0, estimate_observation_noise=False)


def _tight_amcl_log(keep_every=1):
    log = make_exact_log(seed=7)
    for c in ("cov_xx", "cov_yy"):
        log.robot[c] = 0.001 ** 2
    log.robot["cov_yawyaw"] = np.radians(0.05) ** 2
    obs = log.observations
    log.observations = obs.iloc[::keep_every].reset_index(drop=True)
    return log


def test_crlb_matches_numeric_fisher_information_of_one_sensor():
    log = _tight_amcl_log()
    rec = _recipe()
    mask = np.ones(len(log.observations), bool)
    bound = sensor_position_crlb(log, rec, is_robot=mask)
    # numeric Fisher information of sensor 0 alone: its observation factors' whitened errors
    # differentiated on the Pose3 manifold at the truth, the trajectory held at the truth, plus
    # the installed prior
    prob = prepare(log, copy.copy(rec), is_robot=mask, init_network=log.truth)
    graph, values = build_graph(log, prob)
    truth = true_values(log, prob, graph, values)
    key = S(0)
    T0 = truth.atPose3(key)
    info = np.diag(1.0 / np.r_[[np.radians(rec.sensor_prior_sigma_deg)] * 3, [rec.sensor_prior_sigma_m] * 3] ** 2)
    eps = 1e-6
    for n in range(graph.size()):
        f = graph.at(n)
        keys = list(f.keys())
        if key not in keys or len(keys) != 2:
            continue
        J = np.zeros((3, 6))
        for c in range(6):
            d = np.zeros(6)
            d[c] = eps
            v = gtsam.Values(truth)
            v.update(key, T0.retract(d))
            e_plus = f.whitenedError(v)
            v.update(key, T0.retract(-d))
            J[:, c] = (e_plus - f.whitenedError(v)) / (2 * eps)
        info += J.T @ J
    cov_world, _, _ = sensor_sigma_world(T0, np.linalg.inv(info))
    sid = prob.sensor_ids[0]
    # the graph's bound also carries the trajectory's (small) uncertainty: equal within 10 %
    assert np.trace(bound.position_covariance_m2[sid]) == pytest.approx(np.trace(cov_world), rel=0.10)
    assert np.trace(bound.position_covariance_m2[sid]) >= 0.99 * np.trace(cov_world)


def test_crlb_shrinks_as_one_over_n():
    rec = _recipe()
    full = _tight_amcl_log()
    quarter = _tight_amcl_log(keep_every=4)
    b_full = sensor_position_crlb(full, rec, is_robot=np.ones(len(full.observations), bool))
    b_quarter = sensor_position_crlb(quarter, rec, is_robot=np.ones(len(quarter.observations), bool))
    for sid, c in b_full.position_covariance_m2.items():
        ratio = np.trace(b_quarter.position_covariance_m2[sid]) / np.trace(c)
        assert 3.4 < ratio < 4.6, (sid, ratio)
    assert b_quarter.rms_bound_mm == pytest.approx(2.0 * b_full.rms_bound_mm, rel=0.08)
    assert b_full.efficiency_ratio(2 * b_full.rms_bound_mm) == pytest.approx(2.0)


def test_crlb_needs_the_truth():
    log = _tight_amcl_log()
    log.truth = None
    with pytest.raises(PedcalInputError, match="truth"):
        sensor_position_crlb(log, _recipe(), is_robot=np.ones(len(log.observations), bool))


# ------------------------------------------------------------------ the bound under the true noise
def test_common_shift_variance_is_the_exact_blue_of_an_ou_mean():
    # AR(1) of n samples, a = exp(-dt / tau): 1^T Q 1 = (2 + (n - 2)(1 - a)) / (sigma^2 (1 + a))
    sigma, tau, dt, n = 0.05, 20.0, 0.2, 500
    t = 1000.0 + dt * np.arange(n)
    a = np.exp(-dt / tau)
    ou = AmclErrorModel(white_sigma_m=0.0, correlated_sigma_m=sigma, correlation_s=tau)
    assert common_shift_variance_m2(t, ou) == pytest.approx(sigma ** 2 * (1 + a) / (2 + (n - 2) * (1 - a)), rel=1e-9)
    white = AmclErrorModel(white_sigma_m=sigma, correlated_sigma_m=0.0, correlation_s=tau)
    assert common_shift_variance_m2(t, white) == pytest.approx(sigma ** 2 / n, rel=1e-12)
    # the BLUE beats the plain mean (the floor pedcal reports, AmclErrorModel.floor_sigma_m), by 12 %
    # over a run of 5 correlation times (continuous time: (1 + 2 tau / T) (1 - tau / T (1 - e^-T/tau)))
    ratio = ou.floor_sigma_m(n * dt) ** 2 / common_shift_variance_m2(t, ou)
    assert ratio == pytest.approx(1.4 * (1 - 0.2 * (1 - np.exp(-5.0))), rel=0.01)


def test_graph_bound_on_the_common_shift_reaches_the_amcl_mean_bound():
    """With the sensors' noise tiny the network is one rigid structure known but for AMCL's
    run-mean error: the graph's bound on the sensors' mean horizontal position equals the BLUE's
    variance of that mean (3.7 % above it here, the robot's unseen stretches; with the AR(1)'s
    ends left free, as the estimator's graph has them, 32 % above), never below it."""
    log = make_exact_log(seed=7, duration=120.0)
    mask = np.ones(len(log.observations), bool)
    rec = _recipe()
    rec.range_sigma_floor_m = rec.lateral_sigma_m = 0.002
    ou = AmclErrorModel(white_sigma_m=1e-3, correlated_sigma_m=0.05, correlation_s=20.0)
    bound = sensor_position_crlb(log, rec, is_robot=mask, amcl_model=ou, amcl_sigma_yaw_rad=np.radians(1.0),
                                 joint=True)
    common_mm, rest_mm = bound.horizontal_split_mm()
    genie_mm = 1000 * np.sqrt(2 * common_shift_variance_m2(log.robot["t"].to_numpy(float), ou))
    assert genie_mm <= common_mm <= 1.04 * genie_mm
    # AMCL's heading known: the rest part (which the heading's error spreads) falls (6 % here), the common
    # shift barely moves (the bound's two heading columns bracket the truth's)
    known = sensor_position_crlb(log, rec, is_robot=mask, amcl_model=ou, amcl_sigma_yaw_rad=KNOWN_HEADING_SIGMA_RAD,
                                 joint=True)
    k_common_mm, k_rest_mm = known.horizontal_split_mm()
    # (0.936 of it here: the heading's true variance, 1 deg squared, in AMCL's covariance; its sigma
    # unsquared would give 0.888)
    assert 0.91 * rest_mm < k_rest_mm < 0.97 * rest_mm and k_common_mm == pytest.approx(common_mm, rel=0.05)
    assert common_mm ** 2 + rest_mm ** 2 == pytest.approx(bound.horizontal_rms_bound_mm ** 2, rel=1e-9)
    # a white AMCL error of the same std averages out over the run: the common shift's bound drops
    white = AmclErrorModel(white_sigma_m=0.05, correlated_sigma_m=0.0, correlation_s=1e-3)
    b_white = sensor_position_crlb(log, rec, is_robot=mask, amcl_model=white, amcl_sigma_yaw_rad=np.radians(1.0),
                                   joint=True)
    assert b_white.horizontal_split_mm()[0] < 0.2 * common_mm


def test_efficient_share_within_a_limit_is_the_rayleigh_probability():
    # one sensor, isotropic horizontal sigma s: P(|e| <= r) = 1 - exp(-r^2 / (2 s^2))
    s = 0.010
    res = CRLBResult(position_covariance_m2={"a": np.diag([s * s, s * s, 1e-4])}, recipe="x",
                     joint_position_covariance_m2=np.diag([s * s, s * s, 1e-4]))
    for r_mm in (5.0, 12.0, 20.0):
        assert res.share_within_mm(r_mm, draws=20000) == pytest.approx(1 - np.exp(-r_mm ** 2 / 200.0), abs=0.015)
    # a shift every sensor shares: the rest is nothing, the common part is the whole bound
    C = np.kron(np.ones((4, 4)), np.diag([s * s, s * s, 1e-4]))
    shared = CRLBResult(position_covariance_m2={str(i): C[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(4)},
                        recipe="x", joint_position_covariance_m2=C)
    common_mm, rest_mm = shared.horizontal_split_mm()
    assert common_mm == pytest.approx(1000 * s * np.sqrt(2), rel=1e-6) and rest_mm < 1e-3
    with pytest.raises(ValueError, match="joint"):
        CRLBResult(position_covariance_m2={"a": np.eye(3)}, recipe="x").horizontal_split_mm()


def test_efficient_share_within_a_limit_for_an_elongated_correlated_error():
    # one sensor, sigmas 15 and 5 mm along axes turned 34 deg: P(|e| <= r) by quadrature of the
    # exact 2-D normal (0.146, 0.523, 0.802 at 5, 12, 20 mm; a Rayleigh of the same trace is
    # 0.095, 0.438, 0.733)
    c, s_ = np.cos(np.radians(34.0)), np.sin(np.radians(34.0))
    R = np.array([[c, -s_], [s_, c]])
    C2 = R @ np.diag([0.015 ** 2, 0.005 ** 2]) @ R.T
    C = np.zeros((3, 3))
    C[:2, :2], C[2, 2] = C2, 1e-4
    res = CRLBResult(position_covariance_m2={"a": C}, recipe="x", joint_position_covariance_m2=C)
    for r_mm, want in ((5.0, 0.146), (12.0, 0.523), (20.0, 0.802)):
        assert res.share_within_mm(r_mm, draws=40000) == pytest.approx(want, abs=0.01)


def test_share_within_a_limit_of_a_bare_covariance():
    # a 2 x 2 covariance alone (a common shift's): the turned, correlated one gives exactly its
    # principal axes' share (the same seeded draws), the quadrature's 0.523 at 12 mm
    c, s_ = np.cos(np.radians(34.0)), np.sin(np.radians(34.0))
    R = np.array([[c, -s_], [s_, c]])
    C2 = R @ np.diag([0.015 ** 2, 0.005 ** 2]) @ R.T
    turned = share_rms_within_mm(C2, 12.0, draws=40000, seed=3)
    assert turned == share_rms_within_mm(np.diag([0.005 ** 2, 0.015 ** 2]), 12.0, draws=40000, seed=3)
    assert turned == pytest.approx(0.523, abs=0.01)
    # two sensors, each 10 mm per axis, independent: RMS^2 over them is |e|^2 / 2 with |e|^2 a
    # chi^2 of 4 degrees of freedom times s^2, P(RMS <= r) = 1 - exp(-x/2)(1 + x/2), x = 2 r^2 / s^2
    # (0.422 at 12 mm; the sum over both sensors, not their mean, would give 0.162)
    x = 2 * 12.0 ** 2 / 10.0 ** 2
    assert share_rms_within_mm(np.eye(4) * 0.01 ** 2, 12.0, draws=40000, seed=3) == pytest.approx(
        1 - np.exp(-x / 2) * (1 + x / 2), abs=0.01)
    # its diagonal alone (the correlation dropped) is another ellipse: 0.447 at 12 mm
    assert share_rms_within_mm(np.diag(np.diag(C2)), 12.0, draws=40000, seed=3) < turned - 0.03
    with pytest.raises(ValueError, match="2 n x 2 n"):
        share_rms_within_mm(np.eye(3), 12.0)


def test_common_shift_variance_takes_a_repeated_stamp_once():
    ou = AmclErrorModel(white_sigma_m=0.0, correlated_sigma_m=0.05, correlation_s=20.0)
    t = 0.2 * np.arange(100.0)
    assert common_shift_variance_m2(np.r_[t, t[:10]], ou) == pytest.approx(common_shift_variance_m2(t, ou), rel=1e-12)


def test_simulator_noise_never_exceeds_the_simulated_noise():
    sc = load_scenario("paper")
    ranges = np.linspace(sc.min_range_m, sc.max_range_m, 200)
    for model in ("quadratic", "linear"):
        s = sc.resolve(depth_noise_model=model)
        rec, amcl, sigma_yaw = simulator_noise(s)
        grow = 2.5 * ranges if model == "linear" else ranges ** 2
        true_depth = s.depth_noise_k_per_m * grow * np.where(ranges > s.reliable_range_m, s.far_noise_factor, 1.0)
        bound_depth = observation_sigmas(rec, ranges)[:, 2]
        assert np.all(bound_depth <= true_depth * (1 + 1e-12))
        if model == "quadratic":
            np.testing.assert_allclose(bound_depth, true_depth, rtol=1e-12)
        else:   # the chord touches the line at both ends of the ranges
            assert bound_depth[0] == pytest.approx(true_depth[0]) and bound_depth[-1] == pytest.approx(true_depth[-1])
        assert rec.lateral_sigma_m == s.lateral_noise_m and sigma_yaw == pytest.approx(np.radians(s.amcl_sigma_yaw_deg))
        assert (amcl.correlated_sigma_m, amcl.correlation_s) == (s.amcl_sigma_m, s.amcl_tau_s)
        assert amcl.white_sigma_m == MIN_WHITE_M and rec.head_radius_m == 0.0
        # odometry: the simulator's white noise per step, as a random walk per sqrt(s)
        assert rec.odometry_white_sigma_m ** 2 / s.truth_rate_hz == pytest.approx(s.odom_noise_m ** 2, rel=1e-12)
        assert rec.odometry_white_yaw_sigma_deg ** 2 / s.truth_rate_hz == pytest.approx(s.odom_noise_yaw_deg ** 2,
                                                                                     rel=1e-12)
    white = simulator_noise(sc.resolve(amcl_error="white"))[1]
    assert (white.white_sigma_m, white.correlated_sigma_m) == (sc.amcl_sigma_m, 0.0)
