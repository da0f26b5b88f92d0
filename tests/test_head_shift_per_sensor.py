"""Each sensor's own departure of the head point's horizontal shift, a random effect
(pedcal.calib.headpoint.sensor_shift_nuisances, recipe head_shift_per_sensor_sigma_m): always
in the model, estimated where a sensor sees the robot all around, near its prior where the
view is one-sided, its covariance carried into the sensors' sigma."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

import pedcal.calib.factorgraph as fgmod
from pedcal.calib import calibrate
from pedcal.calib.headpoint import (
    SENSOR_PREFIX,
    departures_record,
    head_profile_shift_sensor,
    sensor_shift_nuisances,
)
from pedcal.calib.keys import S
from pedcal.calib.profile import joint_marginal_covariance
from pedcal.errors import PedcalInputError
from pedcal.frames import toward_sensor_horizontal
from pedcal.io import read_sensors_yaml, write_sensors_yaml
from pedcal.metrics import HEAD_MODEL_KEY, evaluate, reproject_observations, robot_rows
from pedcal.sim import simulate_logs

SIGMA_M = 0.02


def _prob(sigma: float, counts=(5, 0, 3)):
    rec = SimpleNamespace(head_shift_per_sensor_sigma_m=sigma, robot=True, estimate_head_horizontal_shift=True,
                          head_horizontal_shift_sigma_m=0.05)
    sensor = np.repeat(np.arange(len(counts)), counts)
    return SimpleNamespace(recipe=rec, sensor_ids=[f"s{i}" for i in range(len(counts))], pose_times=np.arange(10.0),
                           fac_sensor_index=sensor, fac_key_index=np.zeros(len(sensor), int))


def test_every_sensor_that_saw_the_robot_gets_a_departure_with_the_prior_sigma():
    prob = _prob(SIGMA_M)
    nuis = sensor_shift_nuisances(prob)
    assert [n.name for n in nuis] == [SENSOR_PREFIX + "s0", SENSOR_PREFIX + "s2"]     # s1 saw nothing
    assert all(n.prior_mean == 0.0 and n.prior_sigma == SIGMA_M for n in nuis)
    assert getattr(prob, SENSOR_PREFIX + "s0") == 0.0
    assert sensor_shift_nuisances(_prob(0.0)) == []


def test_a_negative_sigma_is_refused_naming_the_key():
    with pytest.raises(PedcalInputError, match="head_shift_per_sensor_sigma_m"):
        sensor_shift_nuisances(_prob(-0.01))


def test_a_departure_moves_its_own_sensors_points_toward_the_sensor_alone():
    prob = _prob(SIGMA_M, counts=(2, 2))
    prob.fac_p_sensor = np.array([[1.0, 0.0, 2.0], [0.0, 1.0, 2.0], [1.0, 1.0, 2.0], [2.0, 0.0, 2.0]])
    prob.fac_toward_sensor = -prob.fac_p_sensor * np.array([1.0, 1.0, 0.0])
    prob.fac_toward_sensor /= np.linalg.norm(prob.fac_toward_sensor, axis=1, keepdims=True)
    out = head_profile_shift_sensor(prob, {SENSOR_PREFIX + "s1": 0.03}, np.arange(4))
    # -delta_s u: the point taken back toward the head top, away from the sensor
    np.testing.assert_allclose(out[:2], 0.0)
    np.testing.assert_allclose(out[2:], -0.03 * prob.fac_toward_sensor[2:])


def _shifted_log(seed: int, **overrides):
    """The paper's room (with a third of the sensors on walls, a one-sided view, unless
    ``overrides`` say otherwise) and every sensor's tracker shifting the robot's head point
    toward it by its own 3 cm, either way."""
    sim = simulate_logs("paper", seed=seed, **(overrides or dict(wall_mounted_fraction=0.3,
                                                                  sensor_height_range_m=[2.6, 4.5])))
    log = sim.calib
    ids = list(log.truth.ids)
    delta = dict(zip(ids, np.random.default_rng(seed).choice([-1.0, 1.0], len(ids)) * 0.03, strict=True))
    obs = log.observations
    P = obs[["x", "y", "z"]].to_numpy(float).copy()
    robot = robot_rows(log)[0]
    sensor = obs["sensor"].astype(str).to_numpy()
    for sid in ids:
        m = (sensor == sid) & robot
        # (the log's points are in the world of the installed extrinsics: to the sensor's frame and back)
        p = log.sensors[sid].to_sensor(P[m])
        P[m] = log.sensors[sid].to_world(p + delta[sid] * toward_sensor_horizontal(p, log.truth[sid].R_world_sensor))
    obs[["x", "y", "z"]] = P
    return sim, delta


def _calibrate(log, sigma, monkeypatch, **overrides):
    """calibrate() with the posterior's inputs captured (prob, graph, solution, nuisances)."""
    seen = {}
    original = fgmod._posterior

    def spy(log_, prob, fg, result, shifts):
        seen.update(prob=prob, fg=fg, result=result, shifts=shifts)
        return original(log_, prob, fg, result, shifts)
    monkeypatch.setattr(fgmod, "_posterior", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(log, method="factorgraph", head_shift_per_sensor_sigma_m=sigma, **overrides)
    return res, seen


@pytest.fixture(scope="module")
def shifted():
    return _shifted_log(0)


def _view_axis(R):
    """The horizontal unit of a sensor's optical axis (its x axis, world)."""
    a = R[:, 0].copy()
    a[2] = 0.0
    return a / np.linalg.norm(a)


def test_the_sigma_is_the_graph_marginal_plus_the_departures_share_and_covers_the_wall_sensors(shifted,
                                                                                                monkeypatch):
    sim, _ = shifted
    res, seen = _calibrate(sim.calib, SIGMA_M, monkeypatch)
    prob, shifts = seen["prob"], seen["shifts"]
    ids = list(prob.sensor_ids)
    n = len(ids)
    # the formula, pinned: C = the graph's joint marginal + S Sigma S^T (S the sensors'
    # sensitivity to the nuisances, Sigma their profile covariance: the departures marginalized),
    # each sensor's block widened by its residuals' variance ratio, rotated to the world axes
    keys = [S(i) for i in range(n)] + [fgmod.H(0)]
    C = joint_marginal_covariance(seen["fg"], seen["result"], keys)
    k = shifts.sensitivity.shape[1]
    sens = shifts.sensitivity[:6 * len(keys)]
    C = C + sens @ shifts.cov[:k, :k] @ sens.T
    if shifts.unmodelled is not None:         # a curvature the data show, widening (head_curvature widen)
        dc, sens_c, _ = shifts.unmodelled
        C = C + dc ** 2 * np.outer(sens_c[:6 * len(keys)], sens_c[:6 * len(keys)])
    if shifts.considered is not None:         # the shift against distance held at 0, its prior carried
        sd, sens_s = shifts.considered
        C = C + sd ** 2 * np.outer(sens_s[:6 * len(keys)], sens_s[:6 * len(keys)])
    assert shifts.local is None
    ratio = res.diagnostics.model_mismatch.variance_ratio
    own = [j for j, name in enumerate(shifts.names[:k]) if name.startswith(SENSOR_PREFIX)]
    assert len(own) == n
    E = {s.id: np.asarray(s.position_error_mm) / 1000 for s in evaluate(sim.eval, res.network).sensors}
    covered = []
    for i, sid in enumerate(ids):
        R = seen["result"].atPose3(S(i)).rotation().matrix()
        scale2 = max(1.0, ratio.get(sid, 1.0))
        world = R @ C[6 * i + 3:6 * i + 6, 6 * i + 3:6 * i + 6] @ R.T * scale2
        np.testing.assert_allclose(res.position_covariance_m2[3 * i:3 * i + 3, 3 * i:3 * i + 3], world,
                                   rtol=1e-6, atol=1e-12)
        if sim.calib.truth[sid].R_world_sensor[2, 0] > -0.5:       # pitched < 30 deg: a wall mount
            # the departures' own share, S_d Sigma_dd S_d^T: along the view axis (the robot seen
            # in front, a shift toward the sensor moves it along there), more than across it
            a = _view_axis(sim.calib.truth[sid].R_world_sensor)
            b = np.array([-a[1], a[0], 0.0])
            Sd = sens[6 * i + 3:6 * i + 6, own]
            share = R @ Sd @ shifts.cov[np.ix_(own, own)] @ Sd.T @ R.T
            assert a @ share @ a > b @ share @ b > 0.0
            covered.append(abs(a @ E[sid]) <= 2.0 * np.sqrt(a @ world @ a))
    assert covered and np.mean(covered) >= 0.75, covered


@pytest.fixture(scope="module")
def nadir():
    # every sensor looking straight down: the robot seen on every side of it, the departure a
    # radial contraction of the view that no pose can take up
    return _shifted_log(0, pitch_deg=[89.0])


@pytest.mark.parametrize("joint_max", [200, 0])
def test_a_sensor_seeing_the_robot_all_around_has_its_departure_estimated(nadir, joint_max, monkeypatch):
    # (joint_max 0: many sensors' way, the departures fitted with the path beside the clock offsets)
    sim, delta = nadir
    _, seen = _calibrate(sim.calib, SIGMA_M, monkeypatch, clock_offsets_joint_max=joint_max)
    prob, shifts = seen["prob"], seen["shifts"]
    ids = list(prob.sensor_ids)
    assert sum(name.startswith(SENSOR_PREFIX) for name in shifts.names) == len(ids)
    assert (shifts.local is not None) == (joint_max == 0)
    est = np.array([prob.horizontal_shift_m + getattr(prob, SENSOR_PREFIX + sid) for sid in ids])
    true = np.array([delta[sid] for sid in ids])
    # the shared part (the simulator's own head point, shared by all) is not the departures':
    # each sensor's departure from the sensors' mean
    d_est, d_true = est - est.mean(), true - true.mean()
    # within 8 mm (the departures' sigma here: ~6.5 mm; their prior, 20 mm, shrinks a 30 mm one by ~3 mm)
    for sid in ids:
        assert d_est[ids.index(sid)] == pytest.approx(d_true[ids.index(sid)], abs=0.008), sid


def test_without_per_sensor_shifts_the_sigma_and_positions_barely_change(monkeypatch):
    sim = simulate_logs("paper", seed=1, wall_mounted_fraction=0.3, sensor_height_range_m=[2.6, 4.5])
    # (the shift against distance not considered: with the departures estimated, they take up part
    # of what it would move, and its carried share shrinks)
    res0, _ = _calibrate(sim.calib, 0.0, monkeypatch, head_profile_consider=False)
    res, _ = _calibrate(sim.calib, SIGMA_M, monkeypatch, head_profile_consider=False)
    s0 = np.sqrt(np.diag(res0.position_covariance_m2))
    s1 = np.sqrt(np.diag(res.position_covariance_m2))
    p0 = np.array([res0.network[sid].position_m for sid in res0.network.ids])
    p1 = np.array([res.network[sid].position_m for sid in res.network.ids])
    # the sigma up by at most 10 % (here 4 %), the positions moved by at most half their sigma
    # (here 6 mm of ~20: the departures take up the simulated dome's per-sensor share)
    assert np.all(s1 >= s0 * 0.99)
    assert np.max(s1 / s0) <= 1.10
    assert np.all(np.abs(p1 - p0).ravel() <= 0.5 * s0)


def test_without_a_distance_profile_no_shape_is_chosen(monkeypatch):
    # the departures alone (head_profile off, the default) leave the profile's shape choice out:
    # its row labelling walks every factor, and there is nothing to choose among
    def refuse(*args, **kwargs):
        raise AssertionError("the head profile's shapes were compared with no profile on")

    monkeypatch.setattr(fgmod, "select_head_profile", refuse)
    monkeypatch.setattr(fgmod, "row_sensors", refuse)
    sim = simulate_logs("paper", seed=0)
    res, seen = _calibrate(sim.calib, SIGMA_M, monkeypatch)
    assert sum(name.startswith(SENSOR_PREFIX) for name in seen["shifts"].names) == len(seen["prob"].sensor_ids)
    assert all(s.status == "ok" for s in res.network)


def test_the_departures_record_is_the_shared_shift_plus_each_departure_with_its_sigma():
    prob = SimpleNamespace(**{SENSOR_PREFIX + "s1": 0.012, SENSOR_PREFIX + "s2": -0.004})
    names = ["ray_shift_m", "horizontal_shift_m", SENSOR_PREFIX + "s1", SENSOR_PREFIX + "s2"]
    cov = np.array([[4.0, 0.0, 0.0, 0.0], [0.0, 1.0, -0.5, 0.25], [0.0, -0.5, 2.0, 0.0],
                    [0.0, 0.25, 0.0, 3.0]]) * 1e-6
    rec = departures_record(prob, names, cov, 0.02)
    assert rec["per_sensor_shift_m"] == {"s1": 0.032, "s2": 0.016}
    # var(shared + departure) = var(shared) + var(departure) + 2 cov: 1 + 2 - 1 and 1 + 3 + 0.5 (mm^2),
    # written to 10 micrometres
    assert rec["sigma_per_sensor_shift_m"] == {"s1": round(np.sqrt(2.0) * 1e-3, 5), "s2": round(np.sqrt(4.5) * 1e-3, 5)}
    # no departures, or no shared shift to depart from: nothing
    assert departures_record(prob, names[:2], cov[:2, :2], 0.02) == {}
    assert departures_record(prob, [names[0], names[2]], cov[np.ix_([0, 2], [0, 2])], 0.02) == {}


def test_evaluate_takes_each_sensors_own_shift_toward_it_in_place_of_the_shared_one():
    # a noise-free log whose tracker shifts the head point 3 cm toward every sensor
    clean = simulate_logs("paper", seed=1, duration_s=60.0, noise_free=True, head_point="shift", head_shift_m=0.03)
    ids = list(clean.calib.truth.ids)
    base = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, "horizontal_shift_m": -0.03}
    right, flipped = clean.calib.truth.copy(), clean.calib.truth.copy()
    right.extra[HEAD_MODEL_KEY] = {**base, "per_sensor_shift_m": {sid: 0.03 for sid in ids}}
    flipped.extra[HEAD_MODEL_KEY] = {**base, "per_sensor_shift_m": {sid: -0.03 for sid in ids}}
    # each sensor's own 3 cm, not the shared -3 cm: the head where it was; with the sign flipped, 6 cm off
    assert evaluate(clean.calib, right).head_tracking_rms_mm < 1.0
    assert evaluate(clean.calib, flipped).head_tracking_rms_mm > 50.0
    # one sensor named: its points alone move, by its shift less the shared one, away from the sensor
    shared, own = clean.calib.truth.copy(), clean.calib.truth.copy()
    shared.extra[HEAD_MODEL_KEY] = {**base, "horizontal_shift_m": 0.03}
    own.extra[HEAD_MODEL_KEY] = {**base, "horizontal_shift_m": 0.03, "per_sensor_shift_m": {ids[0]: 0.05}}
    a, b = reproject_observations(clean.calib, shared), reproject_observations(clean.calib, own)
    mine = (clean.calib.observations["sensor"].astype(str) == ids[0]).to_numpy() & np.isfinite(a[:, 0])
    assert mine.any() and np.array_equal(a[~mine], b[~mine], equal_nan=True)
    moved = b[mine] - a[mine]
    np.testing.assert_allclose(np.linalg.norm(moved, axis=1), 0.02, atol=1e-9)
    to_sensor = np.asarray(clean.calib.truth[ids[0]].position_m)[:2] - a[mine][:, :2]
    assert np.all(np.einsum("ij,ij->i", moved[:, :2], to_sensor) < 0.0)


def test_the_calibrated_yaml_carries_the_departures_and_evaluate_applies_them(nadir, monkeypatch, tmp_path):
    sim, delta = nadir
    res, seen = _calibrate(sim.calib, SIGMA_M, monkeypatch)
    prob, shifts = seen["prob"], seen["shifts"]
    hm = res.network.extra[HEAD_MODEL_KEY]
    assert "horizontal_profile" not in hm          # (the default: no profile against distance)
    want = departures_record(prob, shifts.names, shifts.cov, prob.horizontal_shift_m)
    assert hm["per_sensor_shift_m"] == want["per_sensor_shift_m"]
    assert hm["sigma_per_sensor_shift_m"] == want["sigma_per_sensor_shift_m"]
    assert sorted(hm["per_sensor_shift_m"]) == sorted(prob.sensor_ids)
    assert all(0.0 < s < 0.05 for s in hm["sigma_per_sensor_shift_m"].values())
    back = read_sensors_yaml(write_sensors_yaml(res.network, tmp_path / "cal.yaml"))
    assert back.extra[HEAD_MODEL_KEY]["per_sensor_shift_m"] == hm["per_sensor_shift_m"]
    assert back.extra[HEAD_MODEL_KEY]["sigma_per_sensor_shift_m"] == hm["sigma_per_sensor_shift_m"]
    # the estimated shifts follow the log's +-3 cm ones (each about the sensors' mean, within 8 mm as above)
    est = np.array([hm["per_sensor_shift_m"][sid] for sid in prob.sensor_ids])
    true = np.array([delta[sid] for sid in prob.sensor_ids])
    np.testing.assert_allclose(est - est.mean(), true - true.mean(), atol=0.008)
    # evaluate on the log they were estimated from: with them, the head tracked better than with
    # the shared shift alone, and worse with each departure's sign flipped
    shared_only, flipped = res.network.copy(), res.network.copy()
    shared_only.extra[HEAD_MODEL_KEY] = {k: v for k, v in hm.items() if "per_sensor" not in k}
    flipped.extra[HEAD_MODEL_KEY] = {**hm, "per_sensor_shift_m": {
        sid: 2.0 * hm["horizontal_shift_m"] - v for sid, v in hm["per_sensor_shift_m"].items()}}
    # (the log's own noise, AMCL's and the depth's, is most of the RMS)
    rms = [evaluate(sim.calib, net).head_tracking_rms_mm for net in (back, shared_only, flipped)]
    assert rms[0] < 0.9 * rms[1] < 0.9 ** 2 * rms[2], rms


@pytest.mark.parametrize("key, bad, match", [("per_sensor_shift_m", 0.03, "mapping of sensor id"),
                                             ("per_sensor_shift_m", {"s1": "x"}, r"per_sensor_shift_m\.s1"),
                                             ("sigma_per_sensor_shift_m", {"s1": -0.01}, "implausible")])
def test_a_bad_per_sensor_shift_in_a_yaml_is_refused_naming_it(tmp_path, key, bad, match):
    sim = simulate_logs("paper", seed=0, duration_s=10.0)
    path = write_sensors_yaml(sim.calib.truth.copy(), tmp_path / "ok.yaml")
    data = yaml.safe_load(path.read_text())
    data[HEAD_MODEL_KEY] = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, key: bad}
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(PedcalInputError, match=match):
        read_sensors_yaml(path)


@pytest.mark.parametrize("use", [False, True])
def test_the_spread_between_trackers_is_estimated_and_recorded(nadir, use, monkeypatch):
    # every sensor's own shift 30 mm either way (their spread 30 mm), seen all around: the
    # departures' prior sigma estimated from the data (pedcal.calib.headpoint.estimate_departure_spread)
    # nearer the truth than the recipe's 20 mm is (the binding bound, ~10 mm here; 2.5 of its standard
    # errors, ~7 mm at 10 sensors of ~6.5 mm sigma, is looser), reported whether used (recipe
    # head_shift_per_sensor_sigma_estimate) or not
    sim, delta = nadir
    res, seen = _calibrate(sim.calib, SIGMA_M, monkeypatch, head_shift_per_sensor_sigma_estimate=use)
    spread = seen["prob"].departure_spread
    assert spread["applied"] == use
    true = np.std(list(delta.values()))
    assert spread["sensors"] == len(delta)
    assert abs(spread["estimate_m"] - true) < abs(SIGMA_M - true)      # nearer than the recipe's value
    assert spread["estimate_m"] <= spread["rms_m"] <= spread["upper_m"]
    own = [n for n in seen["shifts"].names if n.startswith(SENSOR_PREFIX)]
    assert len(own) == len(delta)
    hm = res.network.extra[HEAD_MODEL_KEY]
    assert f"{1000 * spread['estimate_m']:.1f} mm" in hm["note"]
    rec = hm["per_sensor_shift_spread"]
    assert rec["estimate_m"] == round(spread["estimate_m"], 5) and rec["sensors"] == len(delta)
    assert rec["prior_sigma_m"] == (round(spread["rms_m"], 5) if use else SIGMA_M)


def test_the_estimated_spread_used_widens_every_departures_prior_and_so_its_sigma(nadir, monkeypatch):
    # the trackers' spread here (30 mm) above the recipe's 20 mm: with the estimate used
    # (head_shift_per_sensor_sigma_estimate), the departures' prior is its rms (estimate_departure_spread's
    # step and nuisances carried on), so each departure's profile variance is larger than with the recipe's
    sim, _ = nadir
    variances = {}
    for use in (False, True):
        _, seen = _calibrate(sim.calib, SIGMA_M, monkeypatch, head_shift_per_sensor_sigma_estimate=use)
        shifts = seen["shifts"]
        k = shifts.cov.shape[0]
        own = [j for j, name in enumerate(shifts.names[:k]) if name.startswith(SENSOR_PREFIX)]
        variances[use] = {shifts.names[j]: shifts.cov[j, j] for j in own}
        spread = seen["prob"].departure_spread
    assert spread["rms_m"] > SIGMA_M
    assert variances[True].keys() == variances[False].keys() and len(variances[True]) == len(sim.calib.truth.ids)
    for name, var in variances[True].items():
        assert var > variances[False][name], name
