"""The Cramér-Rao bound of sensor positions: a numeric Fisher-information check and its 1/N
scaling, on small exact logs."""

import copy

import gtsam
import numpy as np
import pytest
from test_factorgraph import make_exact_log

from pedcal.calib.crlb import sensor_position_crlb, true_values
from pedcal.calib.factorgraph import GraphRecipe, S, build_graph, prepare, sensor_sigma_world
from pedcal.errors import PedcalInputError

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
