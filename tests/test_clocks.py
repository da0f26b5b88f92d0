"""Per-sensor clock offsets: estimated by the factor graph with their sigma, written to the
calibrated YAML and applied by evaluate and export."""

import json
import warnings

import numpy as np
import pytest

from pedcal.calib import calibrate
from pedcal.calib.recipe import GraphRecipe
from pedcal.errors import PedcalInputError
from pedcal.io import read_sensors_yaml, write_sensors_yaml
from pedcal.io.export import json_text
from pedcal.metrics import (
    CLOCK_OFFSET_KEY,
    LATENCY_KEY,
    SIGMA_CLOCK_OFFSET_KEY,
    SIGMA_LATENCY_KEY,
    evaluate,
    sensor_time_correction_s,
)
from pedcal.sim import simulate_logs


def _xy_rms_mm(sim, network) -> float:
    E = np.array([s.position_error_mm for s in evaluate(sim.eval, network).sensors])
    return float(np.sqrt(np.mean(np.sum(E[:, :2] ** 2, axis=1))))


@pytest.fixture(scope="module")
def offset_paper():
    """Paper seed 1, each sensor's clock off by up to +-0.15 s, calibrated with and without the
    per-sensor offsets."""
    sim = simulate_logs("paper", seed=1, clock_offset_s=0.15)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for on in (True, False):
            rec = GraphRecipe.load("default")
            rec.clock_offsets = on
            out[on] = calibrate(sim.calib, method="factorgraph", graph=rec)
    return sim, out


def test_known_clock_offsets_are_recovered_with_their_sigma(offset_paper):
    sim, res = offset_paper
    truth = sim.calib.meta.notes["simulated"]["truth"]["clock_offset_s"]
    true_mean = float(np.mean(list(truth.values())))
    extra = res[True].network.extra
    est, sigma = extra[CLOCK_OFFSET_KEY], extra[SIGMA_CLOCK_OFFSET_KEY]
    assert set(est) == set(truth)
    err = np.array([est[s] - (truth[s] - true_mean) for s in est])
    # offsets drawn over +-150 ms (std 87 ms here) recovered within 40 ms each, 25 ms RMS; the
    # sigma is a few ms to tens of ms, not a placeholder
    assert np.std(list(truth.values())) > 0.05
    assert np.max(np.abs(err)) < 0.040 and np.sqrt(np.mean(err ** 2)) < 0.025
    assert all(0.001 < v < 0.05 for v in sigma.values())
    # the shared latency is their mean: about the offsets' mean, within 20 ms of the truth
    assert extra[LATENCY_KEY] == pytest.approx(sim.scenario.latency_s + true_mean, abs=0.02)
    # with the sigma of the offsets' mean (measured 5 ms; 7.7 ms off)
    assert 0.001 < extra[SIGMA_LATENCY_KEY] < 0.02
    assert abs(extra[LATENCY_KEY] - sim.scenario.latency_s - true_mean) < 3 * extra[SIGMA_LATENCY_KEY]
    assert abs(np.mean(list(est.values()))) < 1e-3
    # and the sensors are placed better than under one shared latency
    assert _xy_rms_mm(sim, res[True].network) < 0.8 * _xy_rms_mm(sim, res[False].network)
    assert CLOCK_OFFSET_KEY not in res[False].network.extra
    # the model check judges the residuals with the offsets applied: what one shared latency leaves
    # is flagged, what the offsets explain is not
    flagged = {on: len(res[on].diagnostics.model_mismatch.sensors) for on in (True, False)}
    assert flagged[True] <= 1 < flagged[False], flagged


def test_clock_offsets_go_through_the_yaml_and_into_evaluate_and_export(offset_paper, tmp_path):
    sim, res = offset_paper
    net = res[True].network
    back = read_sensors_yaml(write_sensors_yaml(net, tmp_path / "cal.yaml"))
    assert back.extra[CLOCK_OFFSET_KEY] == pytest.approx(net.extra[CLOCK_OFFSET_KEY])
    assert back.extra[SIGMA_CLOCK_OFFSET_KEY] == pytest.approx(net.extra[SIGMA_CLOCK_OFFSET_KEY])
    sid = net.ids[0]
    exported = {d["id"]: d for d in json.loads(json_text(back))["sensors"]}
    assert exported[sid]["clock_offset_s"] == pytest.approx(net.extra[CLOCK_OFFSET_KEY][sid])
    # evaluate: on a log whose only nuisance is the clocks, the true extrinsics with the true clocks
    # put the head where it was (to a millimetre), with one shared latency they do not
    clean = simulate_logs("paper", seed=1, duration_s=90.0, noise_free=True, clock_offset_s=0.15)
    truth = clean.calib.meta.notes["simulated"]["truth"]["clock_offset_s"]
    shared = clean.calib.truth.copy()
    shared.extra[LATENCY_KEY] = clean.scenario.latency_s
    own = clean.calib.truth.copy()
    own.extra.update({LATENCY_KEY: clean.scenario.latency_s, CLOCK_OFFSET_KEY: truth})
    assert evaluate(clean.calib, own).head_tracking_rms_mm < 1.0
    assert evaluate(clean.calib, shared).head_tracking_rms_mm > 10.0


def test_time_correction_per_sensor():
    sensors = np.array(["a", "b", "c", "a"])
    np.testing.assert_allclose(sensor_time_correction_s({CLOCK_OFFSET_KEY: {"a": 0.05, "b": -0.02}}, sensors, 0.1),
                               [0.15, 0.08, 0.1, 0.15])
    np.testing.assert_allclose(sensor_time_correction_s({}, sensors, 0.1), [0.1] * 4)
    assert sensor_time_correction_s({}, np.array([], str), 0.1).shape == (0,)


@pytest.mark.parametrize("bad, match", [({"s01": "soon"}, "clock_offset_s.s01"), ([0.1], "mapping of sensor id"),
                                        ({"s01": 120.0}, "implausible")])
def test_bad_clock_offsets_in_a_yaml_are_refused(tmp_path, bad, match):
    sim = simulate_logs("paper", seed=0, duration_s=10.0)
    net = sim.calib.truth.copy()
    path = write_sensors_yaml(net, tmp_path / "ok.yaml")
    import yaml

    data = yaml.safe_load(path.read_text())
    data[CLOCK_OFFSET_KEY] = bad
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(PedcalInputError, match=match):
        read_sensors_yaml(path)


def test_offsets_are_split_into_their_mean_and_departures_with_each_ones_sigma():
    from pedcal.calib.clocks import centered_offsets

    delta = np.array([0.10, 0.02, -0.03])
    # offsets that share a latency error (correlation 0.8) and one of their own
    C = 0.01 ** 2 * (0.2 * np.eye(3) + 0.8)
    mean, sigma_mean, centred, sigma = centered_offsets(delta, C)
    assert mean == pytest.approx(0.03)
    np.testing.assert_allclose(centred, [0.07, -0.01, -0.06])
    # var(mean) = 1^T C 1 / n^2 = 1e-4 (0.2 / 3 + 0.8); var(delta_i - mean) = 1e-4 x 0.2 x (1 - 1/3)
    assert sigma_mean == pytest.approx(0.01 * np.sqrt(0.2 / 3 + 0.8))
    np.testing.assert_allclose(sigma, 0.01 * np.sqrt(0.2 * 2 / 3))
    # the shared part leaves the departures' sigma alone: it is the mean's
    _, sigma_mean_own, _, sigma_own = centered_offsets(delta, 0.01 ** 2 * 0.2 * np.eye(3))
    np.testing.assert_allclose(sigma_own, sigma)
    assert sigma_mean > 3 * sigma_mean_own
    # one offset: its departure from the mean is 0, sure
    assert centered_offsets(np.array([0.05]), np.array([[1e-4]]))[3] == pytest.approx([0.0])
    # unequal, uncorrelated offsets (the cross term -2 (C 1)_i / n is not a constant here):
    # c_i^T C c_i = (1 - 1/n)^2 C_ii + sum_{j != i} C_jj / n^2
    var = np.array([1.0, 4.0, 9.0]) * 1e-4
    _, sm, _, s = centered_offsets(delta, np.diag(var))
    expected = [(2 / 3) ** 2 * var[i] + (var.sum() - var[i]) / 9 for i in range(3)]
    np.testing.assert_allclose(s, np.sqrt(expected), rtol=1e-12)
    assert sm == pytest.approx(np.sqrt(var.sum()) / 3, rel=1e-12)


def test_a_clock_offset_moves_a_point_by_the_heads_motion_over_it_to_second_order():
    # the head on a circle of 1 m at 0.5 rad/s, seen by a sensor turned 30 deg about z and
    # 0.15 s late: the shift is the motion over the offset, R^T (h(t) - h(t - delta)), to a
    # tenth of a millimetre (the velocity taken at the middle of the offset), where the velocity
    # at its end would be off by delta^2 / 2 x 0.25 m/s^2 (2.8 mm)
    from types import SimpleNamespace

    import gtsam

    from pedcal.calib.clocks import PREFIX, clock_shift_sensor

    w, delta = 0.5, 0.15
    t = np.arange(0.0, 20.0, 0.2)
    h = lambda s: np.column_stack([np.cos(w * s), np.sin(w * s), np.zeros_like(s)])  # noqa: E731
    v = w * np.column_stack([-np.sin(w * t), np.cos(w * t), np.zeros_like(t)])
    R = gtsam.Rot3.Rz(np.radians(30.0))
    prob = SimpleNamespace(sensor_ids=["a"], init_sensors={"a": gtsam.Pose3(R, np.zeros(3))}, pose_times=t,
                           fac_key_index=np.arange(5, 95), fac_sensor_index=np.zeros(90, int),
                           _pose_velocity_world=v, motion=None)
    use = np.arange(90)
    shift = clock_shift_sensor(prob, {PREFIX + "a": delta}, use)
    tk = t[prob.fac_key_index]
    exact = (h(tk) - h(tk - delta)) @ R.matrix()
    assert np.max(np.abs(shift - exact)) < 1e-4
    at_end = delta * v[prob.fac_key_index] @ R.matrix()
    assert np.max(np.abs(at_end - exact)) > 2.5e-3
    # pinned: delta R^T v(t - delta / 2), v linear between the poses
    mid = np.column_stack([np.interp(tk - delta / 2, t, v[:, c]) for c in range(3)])
    np.testing.assert_allclose(shift, delta * mid @ R.matrix(), atol=1e-15)
    assert clock_shift_sensor(prob, {PREFIX + "a": 0.0}, use) == 0.0
