"""The head point's horizontal shift as a function of the horizontal distance from the sensor
(pedcal.calib.headpoint): its basis, the choice of model by the Bayesian information criterion,
its recovery on a simulated log, its YAML record and its use by evaluate."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sps
import yaml

from pedcal.calib import calibrate
from pedcal.calib.headpoint import (
    PER_SENSOR_HEIGHT_NOTE,
    PREFIX,
    SLOPE,
    hats,
    horizontal_distance,
    line_of_knots,
    select_head_profile,
    shift_at,
)
from pedcal.calib.profile import Columns, Nuisance, ProfileStep
from pedcal.errors import PedcalInputError
from pedcal.io import read_sensors_yaml, write_sensors_yaml
from pedcal.metrics import HEAD_MODEL_KEY, evaluate
from pedcal.sim import simulate_logs

KNOTS = np.array([0.5, 1.0, 2.0, 4.0])


def test_hats_are_a_partition_of_unity_that_interpolates_linearly_and_is_flat_beyond_the_ends():
    d = np.array([0.0, 0.5, 0.75, 1.0, 3.0, 4.0, 9.0])
    B = hats(d, KNOTS)
    np.testing.assert_allclose(B.sum(axis=1), 1.0)
    np.testing.assert_allclose(B[0], [1, 0, 0, 0])          # below the first knot: flat
    np.testing.assert_allclose(B[2], [0.5, 0.5, 0, 0])
    np.testing.assert_allclose(B[4], [0, 0, 0.5, 0.5])
    np.testing.assert_allclose(B[6], [0, 0, 0, 1])          # beyond the last: flat
    # a line through the knots' values is reproduced between them
    np.testing.assert_allclose(line_of_knots(KNOTS), [0.5 / 3.5, 1.5 / 3.5, 1.0])
    c = np.r_[0.0, line_of_knots(KNOTS)]
    np.testing.assert_allclose(hats(np.array([1.5, 3.0]), KNOTS) @ c, [1.0 / 3.5, 2.5 / 3.5])


def test_horizontal_distance_from_a_sensor_frame_point():
    # a sensor looking along world x, 45 deg down: a point 2 m ahead horizontally and 2 m down
    pitch = np.radians(45.0)
    R = np.array([[np.cos(pitch), 0.0, np.sin(pitch)], [0.0, 1.0, 0.0], [-np.sin(pitch), 0.0, np.cos(pitch)]])
    p_world = np.array([[2.0, 0.0, -2.0], [0.0, 1.5, -2.0]])
    p_sensor = p_world @ R                      # R^T p for each row
    from pedcal.frames import toward_sensor_horizontal

    toward = toward_sensor_horizontal(p_sensor, R)
    np.testing.assert_allclose(horizontal_distance(p_sensor, toward), [2.0, 1.5], atol=1e-12)


def _problem(mode: str, n_factors: int = 1000):
    rec = SimpleNamespace(head_profile=mode, head_profile_sigma_m=0.03)
    prob = SimpleNamespace(recipe=rec, _head_knots=KNOTS, fac_key_index=np.zeros(n_factors, int),
                           pose_times=np.arange(10.0), horizontal_shift_m=0.0, head_profile_slope_m=0.0)
    for j in (1, 2, 3):
        setattr(prob, PREFIX + str(j), 0.0)
    return prob


def _step(grad: np.ndarray) -> tuple[ProfileStep, list]:
    """A quadratic profile over [horizontal shift, c_1, c_2, c_3] with a unit-ish Hessian and the
    given gradient at theta = 0."""
    nuis = [Nuisance("horizontal_shift_m", 0.0, 0.05, 0.01)] + [Nuisance(PREFIX + str(j), 0.0, 0.03, 0.01)
                                                                for j in (1, 2, 3)]
    rng = np.random.default_rng(3)
    A = rng.normal(size=(4, 4)) * 0.1
    H = np.eye(4) * 1e4 + A @ A.T * 1e3
    n_var = 5
    step = ProfileStep(dtheta=-np.linalg.solve(H, grad), hessian=H, z0=np.zeros(n_var), Z=np.zeros((n_var, 4)),
                       cols=Columns(keys=[], offset={}, dim={}, n=n_var),
                       A=sps.csr_matrix((7, n_var)), B=sps.csc_matrix((7, 4)))
    return step, nuis


def test_bic_keeps_the_constant_when_the_knots_gain_nothing():
    step, nuis = _step(np.array([30.0, 0.0, 0.0, 0.0]))
    out, kept, compared = select_head_profile(_problem("bic"), step, nuis)
    assert compared["chosen"] == "constant"
    assert [n.name for n in kept] == ["horizontal_shift_m"]
    # the reduced step is the step of the constant shift alone: -g / H_00
    np.testing.assert_allclose(out.dtheta, [-30.0 / step.hessian[0, 0]])


def test_bic_picks_a_line_for_a_shift_that_rises_with_distance_and_the_knots_for_a_bend():
    H = _step(np.zeros(4))[0].hessian
    # a gradient that a line explains: H times a line's knot values, large
    line = np.r_[0.0, line_of_knots(KNOTS)]
    step, nuis = _step(H @ (0.1 * line))
    _, kept, compared = select_head_profile(_problem("bic"), step, nuis)
    assert compared["chosen"] == "linear", compared
    assert SLOPE in [n.name for n in kept] and not any(n.name.startswith(PREFIX) for n in kept)
    # its chi^2 beats the penalty ln(n), and the knots add nothing beyond 2 ln(n) more
    assert compared["linear"][0] > compared["linear"][1] == pytest.approx(np.log(1000))
    assert compared["knots"][0] - compared["linear"][0] < 2 * np.log(1000)
    # a bend (up then down) needs the knots
    step, nuis = _step(H @ np.array([0.0, 0.1, -0.05, 0.1]))
    _, kept, compared = select_head_profile(_problem("bic"), step, nuis)
    assert compared["chosen"] == "knots"
    assert [n.name for n in kept] == [n.name for n in nuis]


def test_a_forced_model_is_kept_whatever_the_evidence():
    step, nuis = _step(np.zeros(4))
    assert select_head_profile(_problem("knots"), step, nuis)[2]["chosen"] == "knots"
    assert select_head_profile(_problem("linear"), step, nuis)[2]["chosen"] == "linear"


@pytest.fixture(scope="module")
def ramp_log():
    """Paper seed 1 (200 s), the head point pulled 50 mm toward the sensor seen from close by,
    less with distance, nothing from 2 m on; calibrated with the constant shift and with the
    profile chosen by BIC."""
    sim = simulate_logs("paper", seed=1, duration_s=200.0, head_point="ramp", head_shift_m=0.05, head_ramp_m=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return sim, {mode: calibrate(sim.calib, method="factorgraph", head_profile=mode) for mode in ("off", "bic")}


def _xy_rms_mm(sim, network) -> float:
    E = np.array([network[s].position_m - sim.calib.truth[s].position_m for s in sim.calib.sensors.ids])
    return float(1000 * np.sqrt(np.mean(np.sum(E[:, :2] ** 2, axis=1))))


def test_a_shift_ramping_down_with_distance_is_recovered_at_the_knots(ramp_log):
    sim, res = ramp_log
    prof = res["bic"].diagnostics.head_model.horizontal_profile
    assert prof is not None and prof["model"] == "knots"
    d = np.array(prof["distance_m"])
    truth = 0.05 * (1.0 - np.clip(d / 2.0, 0.0, 1.0))
    # within 8 mm at every knot (measured: 5.2 mm at most), each sigma a few millimetres
    assert np.max(np.abs(np.array(prof["shift_m"]) - truth)) < 0.008
    assert all(0.001 < s < 0.02 for s in prof["sigma_shift_m"])
    # and the sensors sit better than under the constant shift (measured 36.4 -> 27.2 mm)
    assert res["off"].diagnostics.head_model.horizontal_profile is None
    assert _xy_rms_mm(sim, res["bic"].network) < 0.85 * _xy_rms_mm(sim, res["off"].network)


def test_without_a_height_reference_the_note_says_a_per_sensor_offset_is_a_height_error(ramp_log):
    _, res = ramp_log
    note = res["off"].network.extra[HEAD_MODEL_KEY]["note"]
    assert PER_SENSOR_HEIGHT_NOTE in note and note.count(PER_SENSOR_HEIGHT_NOTE) == 1


def test_the_profile_goes_through_the_yaml_and_into_evaluate(ramp_log, tmp_path):
    sim, res = ramp_log
    back = read_sensors_yaml(write_sensors_yaml(res["bic"].network, tmp_path / "cal.yaml"))
    assert back.extra[HEAD_MODEL_KEY]["horizontal_profile"] == res["bic"].network.extra[HEAD_MODEL_KEY][
        "horizontal_profile"]
    # on a noise-free ramp log, the true extrinsics with the true profile put the head where it
    # was; with the constant shift at its mean they do not
    clean = simulate_logs("paper", seed=1, duration_s=60.0, noise_free=True, head_point="ramp", head_shift_m=0.05,
                          head_ramp_m=2.0)
    d = np.linspace(0.0, 6.0, 61)
    with_profile = clean.calib.truth.copy()
    true_profile = {"distance_m": d.tolist(), "shift_m": (0.05 * (1 - np.clip(d / 2, 0, 1))).tolist()}
    with_profile.extra[HEAD_MODEL_KEY] = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, "horizontal_shift_m": 0.0,
                                          "horizontal_profile": true_profile}
    constant = clean.calib.truth.copy()
    constant.extra[HEAD_MODEL_KEY] = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, "horizontal_shift_m": 0.02}
    assert evaluate(clean.calib, with_profile).head_tracking_rms_mm < 1.0
    assert evaluate(clean.calib, constant).head_tracking_rms_mm > 5.0
    np.testing.assert_allclose(shift_at({"distance_m": [1.0, 2.0], "shift_m": [0.02, 0.0]}, [0.0, 1.5, 3.0]),
                               [0.02, 0.01, 0.0])


@pytest.mark.parametrize("bad, match", [({"distance_m": [1.0], "shift_m": [0.0]}, "same length, 2 or more"),
                                        ({"distance_m": [2.0, 1.0], "shift_m": [0.0, 0.0]}, "must increase"),
                                        ({"distance_m": [1.0, 2.0], "shift_m": [0.0, "x"]}, r"shift_m\[1\]"),
                                        ("flat", "mapping with lists")])
def test_a_bad_profile_in_a_yaml_is_refused(tmp_path, bad, match):
    sim = simulate_logs("paper", seed=0, duration_s=10.0)
    path = write_sensors_yaml(sim.calib.truth.copy(), tmp_path / "ok.yaml")
    data = yaml.safe_load(path.read_text())
    data[HEAD_MODEL_KEY] = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, "horizontal_profile": bad}
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(PedcalInputError, match=match):
        read_sensors_yaml(path)


def test_an_unknown_profile_mode_is_refused():
    sim = simulate_logs("paper", seed=0, duration_s=30.0)
    with warnings.catch_warnings(), pytest.raises(PedcalInputError, match="head_profile must be one of"):
        warnings.simplefilter("ignore")
        calibrate(sim.calib, method="factorgraph", head_profile="spline")
