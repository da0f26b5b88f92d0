"""Per-sensor clock offsets above ``clock_offsets_joint_max``: estimated as variables of the
linear system (their step the joint Gauss-Newton step's), each one's sigma from its own profile
with the robot's path held; the same offsets and sensors as the exact profile."""

import warnings

import numpy as np
import pytest
import scipy.sparse as sps

from pedcal.calib import calibrate
from pedcal.calib.profile import Nuisance, _local_profile, _with_local_columns
from pedcal.calib.recipe import GraphRecipe
from pedcal.metrics import CLOCK_OFFSET_KEY, LATENCY_KEY, SIGMA_CLOCK_OFFSET_KEY
from pedcal.sim import simulate_logs


@pytest.fixture(scope="module")
def exact_and_local():
    """Paper seed 2, each sensor's clock off by up to +-0.15 s, calibrated with the exact profile
    of the offsets and with each offset's sigma fitted locally (threshold 0)."""
    sim = simulate_logs("paper", seed=2, clock_offset_s=0.15)
    exact, local = _exact_and_local(sim)
    return sim, exact, local


def _exact_and_local(sim, **recipe):
    """The calibrations of ``sim`` with the offsets' exact profile and fitted locally (threshold
    0), the recipe's other fields set from ``recipe``."""
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for joint_max in (200, 0):
            rec = GraphRecipe.load("default")
            rec.clock_offsets_joint_max = joint_max
            for name, value in recipe.items():
                setattr(rec, name, value)
            out[joint_max] = calibrate(sim.calib, method="factorgraph", graph=rec)
    return out[200], out[0]


def test_local_offsets_and_sensors_equal_the_exact_profiles(exact_and_local):
    sim, exact, local = exact_and_local
    ex, lo = exact.network.extra, local.network.extra
    assert set(lo[CLOCK_OFFSET_KEY]) == set(ex[CLOCK_OFFSET_KEY]) and len(ex[CLOCK_OFFSET_KEY]) >= 5
    d = np.array([lo[CLOCK_OFFSET_KEY][s] - ex[CLOCK_OFFSET_KEY][s] for s in ex[CLOCK_OFFSET_KEY]])
    # the joint step's optimum is the profile's: offsets within 2 ms (their sigma is a few ms),
    # the shared latency within 2 ms, the sensors within 1 mm
    assert np.max(np.abs(d)) < 0.002
    assert lo[LATENCY_KEY] == pytest.approx(ex[LATENCY_KEY], abs=0.002)
    for s in exact.network:
        assert np.linalg.norm(local.network[s.id].position_m - s.position_m) < 1e-3
    # and they recover the injected offsets as well as the exact profile does (within 40 ms each)
    truth = sim.calib.meta.notes["simulated"]["truth"]["clock_offset_s"]
    mean = np.mean(list(truth.values()))
    err = np.array([lo[CLOCK_OFFSET_KEY][s] - (truth[s] - mean) for s in truth])
    assert np.max(np.abs(err)) < 0.040


def test_local_sigma_is_the_conditional_one_given_the_path(exact_and_local):
    _, exact, local = exact_and_local
    se, sl = exact.network.extra[SIGMA_CLOCK_OFFSET_KEY], local.network.extra[SIGMA_CLOCK_OFFSET_KEY]
    ratio = np.array([sl[s] / se[s] for s in se])
    # holding the path leaves out its share: never wider than the marginal, and positive (on
    # this scene, one sensor per pose, measured 0.2-0.3 of it)
    assert np.all(ratio > 0.05) and np.all(ratio <= 1.0 + 1e-6)
    # the sensors' position sigma, which carries each offset's share through its own sensor
    # alone, stays within 20 % of the exact marginal's (measured 1-2 % on sparse)
    for s in exact.network:
        sd_e = np.sqrt(np.diag(exact.diagnostics.position_covariance_m2[s.id]))
        sd_l = np.sqrt(np.diag(local.diagnostics.position_covariance_m2[s.id]))
        assert np.all((sd_l > 0.8 * sd_e) & (sd_l < 1.05 * sd_e)), (s.id, sd_l / sd_e)


def test_local_offsets_stop_on_the_predicted_steps_to_come(exact_and_local, monkeypatch):
    # the profile steps with local offsets stop when the steps still to come (the geometric
    # series of the whole step, exact nuisances' and local ones', in sigmas) are below the
    # tolerance: here on a step that is itself above it, where the step-itself rule goes on
    import pedcal.calib.factorgraph as fgm

    sim, _, _ = exact_and_local
    calls, rule = [], fgm.steps_to_come_below

    def spy(u, *rest):
        calls.append((float(np.abs(u).max()), rest[-1], rule(u, *rest)))
        return calls[-1][2]

    monkeypatch.setattr(fgm, "steps_to_come_below", spy)
    rec = GraphRecipe.load("default")
    rec.clock_offsets_joint_max = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        calibrate(sim.calib, method="factorgraph", graph=rec)
    largest, tolerance, stopped = calls[-1]
    assert stopped is True and largest > tolerance, calls


def test_local_offsets_are_logged_as_fitted_given_the_path(caplog):
    from types import SimpleNamespace

    from pedcal.calib.clocks import PREFIX, record_clocks
    from pedcal.model import SensorNetwork

    prob = SimpleNamespace(latency_s=0.1, recipe=SimpleNamespace(clock_offsets_joint_max=1),
                           **{PREFIX + "a": 0.01, PREFIX + "b": -0.03})
    names = ["ray_shift_m", PREFIX + "a", PREFIX + "b"]
    cov = np.diag([1e-6, 0.002 ** 2, 0.004 ** 2])
    for local, logged in ((None, False), ((np.array([0, 1]), np.zeros((2, 6))), True)):
        caplog.clear()
        net = SensorNetwork([])
        with caplog.at_level("WARNING"):
            record_clocks(net, prob, SimpleNamespace(names=names, cov=cov, local=local))
        assert any("lower bounds" in r.getMessage() for r in caplog.records) == logged
        # written the same either way: about their mean (-10 ms), the latency taking the mean
        assert net.extra[CLOCK_OFFSET_KEY] == {"a": 0.02, "b": -0.02}
        assert net.extra[LATENCY_KEY] == pytest.approx(0.09)
    # the sensors' own head shift departures, fitted alike above the limit, are named with them
    for sigma_m, named in ((0.0, False), (0.02, True)):
        prob.recipe.head_shift_per_sensor_sigma_m = sigma_m
        caplog.clear()
        with caplog.at_level("WARNING"):
            record_clocks(SensorNetwork([]), prob, SimpleNamespace(names=names, cov=cov,
                                                                   local=(np.array([0, 1]), np.zeros((2, 6)))))
        assert any("head shift departures" in r.getMessage() for r in caplog.records) == named


@pytest.mark.parametrize("shared", [False, True])
def test_local_profile_equals_the_dense_profile_of_each_variable(shared):
    """Each nuisance's variance and sensitivity against the dense formulas: with only its own
    variable's columns A_i free, Z_i = (A_i^T A_i)^-1 A_i^T B_i and 1 / variance =
    |A_i Z_i - B_i|^2 + 1 / sigma^2."""
    rng = np.random.default_rng(7)
    m, d, rows_each = 3, 6, 20
    n = m * d + 4                                # 4 more columns shared by all rows (a "path")
    A = np.zeros((m * rows_each + n, n))
    B = np.zeros((A.shape[0], m))
    for i in range(m):
        r = slice(i * rows_each, (i + 1) * rows_each)
        A[r, i * d:(i + 1) * d] = rng.normal(size=(rows_each, d))
        A[r, m * d:] = rng.normal(size=(rows_each, 4))
        B[r, i] = rng.normal(size=rows_each)
    A[m * rows_each:] = np.eye(n) * 0.5          # priors on every column
    columns = np.arange(m * d).reshape(m, d)
    if shared:
        # the variables listed out of order, and a fourth nuisance on the second one's rows (a
        # sensor's clock offset and its own shift departure: one pose, two nuisances)
        columns = columns[[2, 0, 1, 1]]
        B = np.c_[B[:, [2, 0, 1]], np.where(B[:, 1] != 0.0, rng.normal(size=len(B)), 0.0)]
        m = 4
    nuis = [Nuisance(f"c{i}", 0.0, 0.1 * (i + 1), 0.01) for i in range(m)]
    loc = _local_profile(sps.csr_matrix(A), sps.csc_matrix(B), columns, nuis)
    assert loc.Z.shape == (m, d) and loc.variance.shape == (m,)
    for i in range(m):
        Ai = A[:, columns[i]]
        Zi = np.linalg.solve(Ai.T @ Ai, Ai.T @ B[:, i])
        assert loc.Z[i] == pytest.approx(Zi, rel=1e-9, abs=1e-12)
        info = np.sum((Ai @ Zi - B[:, i]) ** 2) + 1.0 / nuis[i].prior_sigma ** 2
        assert loc.variance[i] == pytest.approx(1.0 / info, rel=1e-9)
    assert np.all(loc.dtheta == 0.0)


def test_local_columns_sit_just_before_their_variable_in_the_order():
    order = np.array([4, 5, 0, 1, 2, 3])          # two 2-wide variables (0-1, 2-3) after 4, 5
    out = _with_local_columns(order, np.array([[2, 3], [0, 1]]), 6)
    assert out.tolist() == [4, 5, 7, 0, 1, 6, 2, 3]
    assert sorted(out.tolist()) == list(range(8))


def test_local_offsets_survive_the_head_models_selections():
    """With the head profile (bic) and the curvature (auto) chosen inside the profile's first
    step, the offsets fitted with the path still end at the exact profile's."""
    sim = simulate_logs("paper", seed=0, clock_offset_s=0.15)
    exact, local = _exact_and_local(sim, head_profile="bic", head_curvature="auto")
    ex, lo = exact.network.extra[CLOCK_OFFSET_KEY], local.network.extra[CLOCK_OFFSET_KEY]
    assert set(ex) == set(lo)
    assert max(abs(ex[s] - lo[s]) for s in ex) < 0.002          # measured 0.3 ms
    for s in exact.network:
        assert np.linalg.norm(local.network[s.id].position_m - s.position_m) < 1e-3   # measured 0.16 mm
