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
    SENSOR_PREFIX,
    SLOPE,
    hats,
    held_out_gain,
    horizontal_distance,
    knot_values,
    line_of_knots,
    overdispersion,
    profile_record,
    select_head_profile,
    shapes,
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
    less with distance, nothing from 2 m on; calibrated with the constant shift, the profile
    chosen by held-out sensors (cv) and the free knots, without the sensors' own departures (each
    sensor sees the robot over its own range of distances, so they take up part of the profile)."""
    sim = simulate_logs("paper", seed=1, duration_s=200.0, head_point="ramp", head_shift_m=0.05, head_ramp_m=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return sim, {mode: calibrate(sim.calib, method="factorgraph", head_profile=mode,
                                     head_shift_per_sensor_sigma_m=0.0)
                     for mode in ("off", "cv", "knots")}


def _xy_rms_mm(sim, network) -> float:
    E = np.array([network[s].position_m - sim.calib.truth[s].position_m for s in sim.calib.sensors.ids])
    return float(1000 * np.sqrt(np.mean(np.sum(E[:, :2] ** 2, axis=1))))


@pytest.mark.xfail(strict=True, reason=(
    "with the distance read at the predicted point the profile's level trades against the ray shift "
    "under the observation noise on this log (knots 45, 32, 13, 14 mm against 36, 22, 0, 0; cv keeps the "
    "constant shift, 36.5 mm xy); read at the measured point the errors in variables happened to cancel "
    "it here (README, the line's bias)"))
def test_a_shift_ramping_down_with_distance_is_recovered_at_the_knots(ramp_log):
    sim, res = ramp_log
    for mode, tolerance in (("knots", 0.008), ("cv", 0.015)):
        prof = res[mode].diagnostics.head_model.horizontal_profile
        assert prof is not None and prof["model"] != "constant"
        d = np.array(prof["distance_m"])
        truth = 0.05 * (1.0 - np.clip(d / 2.0, 0.0, 1.0))
        # what a recovery would show: the free knots within 8 mm at every knot, the shape cv keeps
        # (a fade ending near the true 2 m) within 15 mm (today: knots 8.6-13.5 mm off, cv keeps
        # the constant; RAMP_TODAY_MM below)
        assert np.max(np.abs(np.array(prof["shift_m"]) - truth)) < tolerance, (mode, prof)
        assert all(0.001 < s < 0.02 for s in prof["sigma_shift_m"])
        # and the sensors sit better than under the constant shift (today 36.5 -> 36.5 with cv, 26.6
        # with the knots)
        assert _xy_rms_mm(sim, res[mode].network) < 0.85 * _xy_rms_mm(sim, res["off"].network)
    assert res["off"].diagnostics.head_model.horizontal_profile is None


# The ramp log's figures on the code of the expected failure above (measured, mm): the free knots'
# error at each knot (their values 44.9, 31.6, 12.9, 13.5 against the truth's 36.3, 22.0, 0, 0)
# and each mode's xy RMS; cv keeps the constant shift here (None: with AMCL's wander held at its
# reported std in the graph it kept a rise from 2.3 m, the wrong shape, 45.1 mm xy)
RAMP_TODAY_MM = {"knots": ([8.6, 9.6, 12.9, 13.5], 26.6), "cv": (None, 36.5)}
RAMP_KNOT_MARGIN_MM, RAMP_XY_MARGIN_MM = 5.0, 3.0


def test_the_ramps_recovery_gets_no_worse_than_it_is(ramp_log):
    # while the recovery above fails, a further regression must not go unseen: each knot's error
    # within 5 mm of today's and each mode's xy RMS within 3 mm of it (seeded log: the figures move
    # only with the code)
    sim, res = ramp_log
    for mode, (knot_mm, xy_mm) in RAMP_TODAY_MM.items():
        prof = res[mode].diagnostics.head_model.horizontal_profile
        if knot_mm is None:
            assert prof is None, (mode, prof)
        else:
            assert prof is not None and len(prof["shift_m"]) == len(knot_mm), (mode, prof)
            d = np.array(prof["distance_m"])
            truth = 0.05 * (1.0 - np.clip(d / 2.0, 0.0, 1.0))
            err_mm = 1000 * np.abs(np.array(prof["shift_m"]) - truth)
            assert np.all(err_mm <= np.array(knot_mm) + RAMP_KNOT_MARGIN_MM), (mode, err_mm.round(1))
        assert _xy_rms_mm(sim, res[mode].network) <= xy_mm + RAMP_XY_MARGIN_MM, mode


def test_without_a_height_reference_the_note_says_a_per_sensor_offset_is_a_height_error(ramp_log):
    _, res = ramp_log
    note = res["off"].network.extra[HEAD_MODEL_KEY]["note"]
    assert PER_SENSOR_HEIGHT_NOTE in note and note.count(PER_SENSOR_HEIGHT_NOTE) == 1


def test_the_profile_goes_through_the_yaml_and_into_evaluate(ramp_log, tmp_path):
    sim, res = ramp_log
    back = read_sensors_yaml(write_sensors_yaml(res["knots"].network, tmp_path / "cal.yaml"))
    assert back.extra[HEAD_MODEL_KEY]["horizontal_profile"] == res["knots"].network.extra[HEAD_MODEL_KEY][
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
    # a sensor's own departure the YAML records moves that sensor's points alone, by it, toward the sensor
    from pedcal.metrics import reproject_observations

    sid = clean.calib.truth.sensors[0].id
    own = with_profile.copy()
    own.extra[HEAD_MODEL_KEY] = {**with_profile.extra[HEAD_MODEL_KEY], "horizontal_profile": {
        **true_profile, "per_sensor_shift_m": {sid: true_profile["shift_m"][0] + 0.03}}}
    a, b = reproject_observations(clean.calib, with_profile), reproject_observations(clean.calib, own)
    mine = (clean.calib.observations["sensor"].astype(str) == sid).to_numpy() & np.isfinite(a[:, 0])
    assert mine.any() and np.array_equal(a[~mine], b[~mine], equal_nan=True)
    moved = a[mine] - b[mine]
    np.testing.assert_allclose(np.linalg.norm(moved, axis=1), 0.03, atol=1e-9)
    np.testing.assert_allclose(moved[:, 2], 0.0, atol=1e-9)
    # a larger shift toward the sensor means the head top was farther from it: b lies farther away
    to_sensor = np.asarray(clean.calib.truth[sid].position_m)[:2] - a[mine][:, :2]
    assert np.all(np.einsum("ij,ij->i", moved[:, :2], to_sensor) > 0.0)


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


def test_selected_per_sensor_departures_beside_the_random_effect_are_refused():
    # both would hold each sensor's own departure: one must be chosen, not one silently dropped
    sim = simulate_logs("paper", seed=0, duration_s=30.0)
    with warnings.catch_warnings(), pytest.raises(PedcalInputError, match="head_shift_per_sensor_sigma_m"):
        warnings.simplefilter("ignore")
        calibrate(sim.calib, method="factorgraph", head_profile="cv", head_profile_per_sensor=True)


# ---------------------------------------------------------------- selection by held-out sensors
def test_held_out_gain_is_the_held_out_rows_chi2_loss_under_the_step_the_other_rows_fit():
    rng = np.random.default_rng(11)
    m = rng.normal(size=(60, 2))
    rho = rng.normal(size=60)
    folds = np.repeat([0, 1, 2, -1], 15)
    P = np.diag([0.5, 2.0])
    gains = held_out_gain(m, rho, folds, P)
    for f in range(3):
        fit = folds != f                          # the other folds and the rows of no fold
        delta = -np.linalg.solve(m[fit].T @ m[fit] + P, m[fit].T @ rho[fit])
        held = folds == f
        assert gains[f] == pytest.approx(np.sum(rho[held] ** 2) - np.sum((rho[held] + m[held] @ delta) ** 2))
    assert len(gains) == 3


def test_overdispersion_is_one_for_independent_rows_and_grows_with_errors_shared_within_clusters():
    rng = np.random.default_rng(5)
    n, c = 4000, 40
    clusters = np.repeat(np.arange(c), n // c)
    m = rng.normal(size=(n, 2)) + 0.5
    assert overdispersion(m, rng.normal(size=n), clusters) == pytest.approx(1.0, abs=0.35)
    # an error shared by a cluster's rows and a slope shared too: the score scatters as whole clusters
    m_shared = np.repeat(rng.normal(size=(c, 2)), n // c, axis=0) + rng.normal(size=(n, 2)) * 0.1
    rho = np.repeat(rng.normal(size=c), n // c) + rng.normal(size=n)
    assert overdispersion(m_shared, rho, clusters) > 10.0
    # too few clusters to tell
    assert np.isnan(overdispersion(m, rng.normal(size=n), np.repeat(np.arange(4), n // 4)))


def test_overdispersion_pinned_cluster_by_cluster():
    # tr(S^-1 V) / k: V the clusters' score sums centred, times C / (C - 1); S over every row.
    # Residuals with a mean (the centring matters) and two rows left out (-1)
    rng = np.random.default_rng(8)
    m = rng.normal(size=(90, 2))
    rho = rng.normal(size=90) + 0.7
    clusters = np.repeat(np.arange(9), 10)
    clusters[[4, 33]] = -1
    U = np.array([(m[clusters == c] * rho[clusters == c, None]).sum(axis=0) for c in range(9)])
    U = U - U.mean(axis=0)
    want = np.trace(np.linalg.solve(m.T @ m, U.T @ U * 9 / 8)) / 2
    assert overdispersion(m, rho, clusters) == pytest.approx(want, rel=1e-12)


def test_the_shapes_rise_by_one_to_their_knot_and_stay_or_start_there():
    got = shapes(KNOTS)
    assert sorted(got) == sorted(["linear", "saturating@1.00", "onset@1.00", "saturating@2.00", "onset@2.00"])
    np.testing.assert_allclose(got["saturating@1.00"], [1.0, 1.0, 1.0])
    np.testing.assert_allclose(got["saturating@2.00"], [1.0 / 3.0, 1.0, 1.0])
    np.testing.assert_allclose(got["onset@1.00"], [0.0, 1.0 / 3.0, 1.0])
    np.testing.assert_allclose(got["onset@2.00"], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(got["linear"], line_of_knots(KNOTS))


SENSORS = 8


def _linear_profile(shape_mm: np.ndarray, seed: int, per_row: int = 400, noise: float = 1.0,
                    own_mm: np.ndarray | None = None):
    """A linear model of the head profile's system, profiled exactly: SENSORS sensors, each a
    2-d offset variable seen by per_row observations at horizontal distances 0.3-5 m, whose
    residual is A x - b - B theta; theta = [horizontal shift, c_1..c_3] on KNOTS, the truth a
    constant 20 mm plus knot values ``shape_mm`` (mm at d_1..d_3); with ``own_mm`` (one per
    sensor), each sensor's own departure too, in 10 time blocks. Returns (prob, step, nuis,
    folds by sensor, the truth's knot values in m; with own_mm, the time blocks too)."""
    rng = np.random.default_rng(seed)
    n = SENSORS * per_row
    sensor = np.repeat(np.arange(SENSORS), per_row)
    d = rng.uniform(0.3, 5.0, n)
    az = rng.uniform(0.0, 2 * np.pi, n)
    u = np.column_stack([np.cos(az), np.sin(az)])
    # two rows per observation (x and y), whitened at 5 mm: the point moves by -shift(d) u
    rows = 2 * n
    A = sps.csr_matrix((np.ones(rows) / 0.005, (np.arange(rows), 2 * np.repeat(sensor, 2) + np.tile([0, 1], n))),
                       shape=(rows, 2 * SENSORS))
    basis = np.column_stack([np.ones(n), hats(d, KNOTS)[:, 1:]])          # [shift, c_1..c_3] per observation
    theta_true = np.r_[0.02, np.asarray(shape_mm, float) / 1000.0]
    nuis = [Nuisance("horizontal_shift_m", 0.0, 0.05, 0.01)] + [Nuisance(PREFIX + str(j), 0.0, 0.03, 0.01)
                                                                for j in (1, 2, 3)]
    ids = [f"s{i}" for i in range(SENSORS)]
    if own_mm is not None:
        basis = np.column_stack([basis, np.eye(SENSORS)[sensor]])
        theta_true = np.r_[theta_true, np.asarray(own_mm, float) / 1000.0]
        nuis += [Nuisance(SENSOR_PREFIX + sid, 0.0, 0.03, 0.01) for sid in ids]
    Bd = (np.repeat(basis, 2, axis=0) * u.reshape(-1)[:, None]) / 0.005
    x_true = rng.normal(size=2 * SENSORS) * 0.1
    b = A @ x_true - Bd @ theta_true + rng.normal(size=rows) * noise
    N = (A.T @ A).toarray()
    B = sps.csc_matrix(Bd)
    z0 = np.linalg.solve(N, A.T @ b)
    Z = np.linalg.solve(N, (A.T @ B).toarray())
    rho0 = A @ z0 - b
    M = A @ Z - Bd
    info = np.diag([1.0 / nu.prior_sigma ** 2 for nu in nuis])
    H = M.T @ M + info
    step = ProfileStep(dtheta=-np.linalg.solve(H, M.T @ rho0), hessian=H, z0=z0, Z=Z,
                       cols=Columns(keys=[], offset={}, dim={}, n=2 * SENSORS), A=A, B=B, rho0=rho0)
    rec = SimpleNamespace(head_profile="cv", head_profile_sigma_m=0.03)
    prob = SimpleNamespace(recipe=rec, _head_knots=KNOTS, fac_key_index=np.zeros(n, int), pose_times=np.arange(10.0),
                           horizontal_shift_m=0.0, head_profile_slope_m=0.0, sensor_ids=ids)
    for nu in nuis[1:]:
        setattr(prob, nu.name, 0.0)
    if own_mm is not None:
        blocks = np.repeat(np.tile(np.repeat(np.arange(10), per_row // 10), SENSORS), 2)
        return prob, step, nuis, np.repeat(sensor, 2), theta_true[1:4], blocks
    return prob, step, nuis, np.repeat(sensor, 2), theta_true[1:4]


def _chosen_knots(prob, step, kept) -> np.ndarray:
    """The knot values c_1..c_3 (m) after the reduced step is taken."""
    theta = dict(zip([n.name for n in kept], step.dtheta, strict=True))
    return knot_values(prob, theta)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_cv_keeps_the_constant_for_a_constant_shift(seed):
    prob, step, nuis, folds, _ = _linear_profile(np.zeros(3), seed)
    out, kept, compared = select_head_profile(prob, step, nuis, folds=folds)
    assert compared["chosen"] == "constant", compared
    assert [n.name for n in kept] == ["horizontal_shift_m"]
    assert out.dtheta[0] == pytest.approx(0.02, abs=0.002)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cv_finds_a_saturating_and_a_fading_shift_and_recovers_it_at_the_knots(seed):
    # rising 30 mm from d_0 to 2 m and flat beyond; falling 30 mm to 1 m and flat beyond
    for truth, shape in (([10.0, 30.0, 30.0], "saturating@2.00"), ([-30.0, -30.0, -30.0], "saturating@1.00")):
        prob, step, nuis, folds, c_true = _linear_profile(np.array(truth), seed)
        out, kept, compared = select_head_profile(prob, step, nuis, folds=folds)
        assert compared["chosen"] == shape, compared
        assert SLOPE in [n.name for n in kept]
        # within 2 mm at every knot (the knots' sigma here: ~0.5 mm)
        np.testing.assert_allclose(_chosen_knots(prob, out, kept), c_true, atol=0.002)


def test_cv_keeps_the_free_knots_for_a_bend_no_shape_holds():
    prob, step, nuis, folds, c_true = _linear_profile(np.array([30.0, -10.0, 20.0]), 0)
    out, kept, compared = select_head_profile(prob, step, nuis, folds=folds)
    assert compared["chosen"] == "knots"
    np.testing.assert_allclose(out.dtheta[1:], c_true, atol=0.002)


def test_cv_without_three_sensors_falls_back_to_bic():
    prob, step, nuis, folds, _ = _linear_profile(np.zeros(3), 0)
    _, _, compared = select_head_profile(prob, step, nuis, folds=np.minimum(folds, 1))
    assert compared["constant"] == (0.0, 0.0) and compared["linear"][1] == pytest.approx(np.log(len(folds) // 2))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_cv_keeps_a_sensors_own_shift_where_its_held_out_time_blocks_support_it(seed):
    # sensors s2 and s5 run trackers of their own, 25 mm and -15 mm off the shared shift
    own = np.zeros(SENSORS)
    own[2], own[5] = 25.0, -15.0
    prob, step, nuis, folds, _, blocks = _linear_profile(np.zeros(3), seed, own_mm=own)
    out, kept, compared = select_head_profile(prob, step, nuis, folds=folds, clusters=blocks)
    assert compared["chosen"] == "constant"
    kept_ids = sorted(n.name[len(SENSOR_PREFIX):] for n in kept if n.name.startswith(SENSOR_PREFIX))
    assert kept_ids == ["s2", "s5"], compared["sensors"]
    theta = dict(zip([n.name for n in kept], out.dtheta, strict=True))
    # each kept departure within 2 mm (the shared shift takes the mean of all sensors': the
    # departures are relative to it, their prior holding the split)
    shared = theta["horizontal_shift_m"]
    assert shared + theta[SENSOR_PREFIX + "s2"] == pytest.approx(0.045, abs=0.002)
    assert shared + theta[SENSOR_PREFIX + "s5"] == pytest.approx(0.005, abs=0.002)
    assert shared == pytest.approx(0.02, abs=0.002)


def test_without_time_blocks_a_sensors_own_shift_is_judged_by_bic():
    own = np.zeros(SENSORS)
    own[2] = 25.0
    prob, step, nuis, folds, _, _ = _linear_profile(np.zeros(3), 0, own_mm=own)
    _, kept, compared = select_head_profile(prob, step, nuis, folds=folds, clusters=None)
    assert [n.name for n in kept if n.name.startswith(SENSOR_PREFIX)] == [SENSOR_PREFIX + "s2"]
    assert compared["sensors"]["s3"][1] == pytest.approx(np.log(SENSORS * 400))


def test_the_record_holds_each_kept_sensors_shift_with_its_sigma_and_goes_through_the_yaml(tmp_path):
    prob = SimpleNamespace(_head_knots=KNOTS, head_profile_slope_m=0.0, _head_shape=None,
                           **{PREFIX + str(j): 0.0 for j in (1, 2, 3)}, **{SENSOR_PREFIX + "s2": 0.012})
    names = ["ray_shift_m", "horizontal_shift_m", SENSOR_PREFIX + "s2"]
    cov = np.array([[4.0, 0.0, 0.0], [0.0, 1.0, -0.5], [0.0, -0.5, 2.0]]) * 1e-6
    rec = profile_record(prob, names, cov, 0.02)
    assert rec["model"] == "constant" and rec["shift_m"] == [0.02] * 4
    assert rec["per_sensor_shift_m"] == {"s2": 0.032}
    # var(shift + departure) = 1 + 2 - 2 x 0.5 (mm^2)
    assert rec["sigma_per_sensor_shift_m"]["s2"] == pytest.approx(np.sqrt(2.0) * 1e-3, abs=1e-5)
    # without a kept departure or profile: no record
    assert profile_record(prob, names[:2], cov[:2, :2], 0.02) is None
    sim = simulate_logs("paper", seed=0, duration_s=10.0)
    net = sim.calib.truth.copy()
    net.extra[HEAD_MODEL_KEY] = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, "horizontal_shift_m": 0.02,
                                 "horizontal_profile": rec}
    back = read_sensors_yaml(write_sensors_yaml(net, tmp_path / "cal.yaml"))
    assert back.extra[HEAD_MODEL_KEY]["horizontal_profile"]["per_sensor_shift_m"] == {"s2": 0.032}


LINE_SETUP = dict(amcl_error="correlated", amcl_sigma_m=0.05, amcl_sigma_yaw_deg=1.0,
                  sensor_height_range_m=[2.6, 4.5])     # (benchmarks/bench_line_bias.py's)


def _line_and_stretch_mm_per_m(sim, res) -> tuple[float, float]:
    """The estimated line's rise per metre between its end knots and the network's stretch along x
    (the slope of the sensors' x error against their true x), both mm/m."""
    prof = res.network.extra[HEAD_MODEL_KEY]["horizontal_profile"]
    d, s = np.asarray(prof["distance_m"]), np.asarray(prof["shift_m"])
    ids = sim.calib.sensors.ids
    x = np.array([sim.calib.truth[i].position_m[0] for i in ids])
    err = np.array([res.network[i].position_m[0] for i in ids]) - x
    return 1000 * (s[-1] - s[0]) / (d[-1] - d[0]), 1000 * np.sum((x - x.mean()) * err) / np.sum((x - x.mean()) ** 2)


@pytest.mark.parametrize("noise", ["off", "on"])
def test_the_line_read_at_the_predicted_distance_is_recovered_and_does_not_shrink_the_corridor(noise):
    """The head point the blob's top (its line 0), AMCL wandering: without observation noise the
    estimated line and the corridor's stretch are 0 within 0.5 mm/m (measured -0.2, -0.2); with
    it (depth 1.5e-3 r^2, doubled past 3.5 m; lateral 1 cm) within 10 and 7 mm/m (measured -7.1,
    -4.7: a bias that is not the regressors', README), where the distance read at the measured
    point gave a line of -14.9 and a stretch of -9.6 mm/m (errors in variables: the observation's
    error moved the distance and the residual)."""
    noisy = dict(depth_noise_k_per_m=1.5e-3, lateral_noise_m=0.01, far_noise_factor=2.0) if noise == "on" else {}
    sim = simulate_logs("corridor", seed=0, noise_free=True, **LINE_SETUP, **noisy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(sim.calib, method="factorgraph", head_profile="linear")
    line, stretch = _line_and_stretch_mm_per_m(sim, res)
    line_tol, stretch_tol = (0.5, 0.5) if noise == "off" else (10.0, 7.0)
    assert abs(line) < line_tol and abs(stretch) < stretch_tol, (line, stretch)
