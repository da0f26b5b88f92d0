"""The sigma's honesty over many logs: the share of errors within 1 sigma, the RMS of error over
sigma (which does not reward a sigma that is only wide), and their intervals from a bootstrap
over the logs (a log's sensors share one draw of AMCL's error: the log is the unit)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from pedcal.metrics import format_clustered, log_bootstrap, sigma_honesty, sigma_ratio_rms, within_sigma_share
from pedcal.model import SensorExtrinsics, SensorNetwork

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_factorgraph_nuisances import by_seed, family_filter, seeds_with, sigma_ratios  # noqa: E402

INF = np.inf


def test_the_share_within_sigma_counts_a_miss_in_the_denominator_and_never_within():
    ratios = np.array([[0.5, 2.0], [1.0, INF], [3.0, 0.2], [INF, np.nan]])
    assert within_sigma_share(ratios) == pytest.approx([2 / 4, 1 / 4])
    assert within_sigma_share(ratios, k=2.0) == pytest.approx([2 / 4, 2 / 4])
    assert np.all(np.isnan(within_sigma_share(np.zeros((0, 3)))))


def test_the_ratio_rms_by_hand_leaves_misses_out():
    ratios = np.array([[0.5, 2.0, INF], [1.0, INF, INF], [3.0, 0.2, np.nan]])
    out = sigma_ratio_rms(ratios)
    assert out[0] == pytest.approx(np.sqrt((0.25 + 1.0 + 9.0) / 3))
    assert out[1] == pytest.approx(np.sqrt((4.0 + 0.04) / 2))
    assert np.isnan(out[2])                       # no finite ratio on that axis


def test_a_sigma_only_wide_is_within_but_its_ratio_rms_says_so():
    # errors N(0, 1) against a sigma 3x too wide: nearly all within 1 sigma (the share rewards
    # it), the ratio RMS a third (it does not); against the right sigma, ~68 % and ~1
    rng = np.random.default_rng(0)
    err = np.abs(rng.normal(size=(4000, 3)))
    wide, right = err / 3.0, err / 1.0
    assert np.all(within_sigma_share(wide) > 0.99)
    assert sigma_ratio_rms(wide) == pytest.approx([1 / 3] * 3, rel=0.05)
    assert within_sigma_share(right) == pytest.approx([0.683] * 3, abs=0.03)
    assert sigma_ratio_rms(right) == pytest.approx([1.0] * 3, rel=0.05)


def test_the_bootstrap_is_seeded_and_its_interval_holds_the_pooled_estimate():
    rng = np.random.default_rng(1)
    logs = [np.abs(rng.normal(scale=s, size=(rng.integers(3, 9), 3))) for s in rng.uniform(0.5, 2.0, 12)]
    a = log_bootstrap(logs, within_sigma_share, n_boot=500, seed=7)
    b = log_bootstrap(logs, within_sigma_share, n_boot=500, seed=7)
    np.testing.assert_array_equal(a.low, b.low)
    np.testing.assert_array_equal(a.high, b.high)
    c = log_bootstrap(logs, within_sigma_share, n_boot=500, seed=8)     # another seed, other resamples
    assert not np.array_equal(a.low, c.low)
    assert a.logs == 12 and a.rows == sum(len(x) for x in logs)
    np.testing.assert_allclose(a.estimate, within_sigma_share(np.concatenate(logs)))
    assert np.all(a.low <= a.estimate) and np.all(a.estimate <= a.high)
    assert np.all(a.high - a.low > 0.05)          # twelve logs of unequal sigma: not a point


def test_two_logs_all_in_and_all_out_span_the_whole_range():
    # each resample holds each log 0, 1 or 2 times: shares 0, 1/2, 1 with probability 1/4, 1/2,
    # 1/4, so the 90 % interval runs from 0 to 1 about the pooled 1/2
    logs = [np.array([[0.5]]), np.array([[2.0]])]
    fig = log_bootstrap(logs, within_sigma_share, n_boot=2000, seed=0, level=0.9)
    assert fig.estimate == pytest.approx([0.5])
    assert fig.low == pytest.approx([0.0]) and fig.high == pytest.approx([1.0])


def test_one_log_or_identical_logs_give_no_width():
    one = log_bootstrap([np.array([[0.5, 2.0], [1.5, 0.1]])], sigma_ratio_rms, n_boot=200)
    np.testing.assert_allclose(one.low, one.estimate)
    np.testing.assert_allclose(one.high, one.estimate)
    same = log_bootstrap([np.array([[0.5], [2.0]])] * 5, within_sigma_share, n_boot=200)
    assert same.low == pytest.approx([0.5]) and same.high == pytest.approx([0.5])


def test_bad_bootstrap_input_is_refused():
    with pytest.raises(ValueError, match="at least one log"):
        log_bootstrap([], within_sigma_share)
    with pytest.raises(ValueError, match="level"):
        log_bootstrap([np.ones((1, 1))], within_sigma_share, level=1.0)


def test_sigma_honesty_pairs_the_share_and_the_ratio_on_the_same_resamples():
    logs = [np.array([[0.5, INF]]), np.array([[2.0, 1.0]]), np.array([[1.0, 0.4], [3.0, 0.2]])]
    within, rms = sigma_honesty(logs, n_boot=300, seed=3)
    assert within.estimate == pytest.approx([2 / 4, 3 / 4])
    assert rms.estimate == pytest.approx([np.sqrt((0.25 + 4 + 1 + 9) / 4), np.sqrt((1 + 0.16 + 0.04) / 3)])
    assert within.logs == rms.logs == 3
    # the same resamples: each figure is log_bootstrap's with the seed given, for both
    for fig, statistic in ((within, within_sigma_share), (rms, sigma_ratio_rms)):
        alone = log_bootstrap(logs, statistic, 300, 3)
        np.testing.assert_array_equal(fig.low, alone.low)
        np.testing.assert_array_equal(fig.high, alone.high)


def test_the_bootstrap_counts_the_rows_missed_beside_the_rows():
    # a row with any non-finite ratio (inf: a miss; NaN) is a miss, whatever its other axes
    logs = [np.array([[0.5, INF], [1.0, 2.0]]), np.array([[np.nan, 1.0]]), np.zeros((0, 2)), np.array([[INF, INF]])]
    within, rms = sigma_honesty(logs, n_boot=50, seed=0)
    assert (within.rows, within.misses) == (rms.rows, rms.misses) == (4, 3)
    assert log_bootstrap([np.array([[0.5], [2.0]])], sigma_ratio_rms, n_boot=10).misses == 0


def test_the_benches_print_the_sensors_missed_beside_the_honesty(capsys):
    from bench_factorgraph_nuisances import print_honesty
    from bench_realwalk import _row

    rs = [dict(seed=0, ratios=np.array([[0.5, 0.5, 0.5], [INF, INF, INF]]),
               factorgraph=dict(sq_xy=np.array([1.0])), gridsearch=dict(sq_xy=np.array([4.0]))),
          dict(seed=1, ratios=np.array([[2.0, np.nan, 2.0]]),
               factorgraph=dict(sq_xy=np.array([1.0])), gridsearch=dict(sq_xy=np.array([4.0])))]
    print_honesty([("g", rs)])
    out = capsys.readouterr().out
    assert "| sensors (missed) |" in out and "| g | 2 (2) | 3 (2) | " in out
    # (saved without the RMS's own misses: '?' beside each RMS)
    assert _row("r", rs).startswith("| r | 2 (2) | 3 (2) | 1.0 (?) | 2.0 (?) | 0.50 | ")


def test_the_format_names_each_axis_estimate_and_interval():
    logs = [np.array([[0.5, 2.0, 0.1]]), np.array([[2.0, 0.5, 0.2]])]
    fig = log_bootstrap(logs * 2, within_sigma_share, n_boot=400)
    assert format_clustered(fig, 100) == "50 [0-100] / 50 [0-100] / 100 [100-100]"
    # two logs: a bootstrap only repeats them, so no interval is claimed
    two = log_bootstrap(logs, within_sigma_share, n_boot=400)
    assert format_clustered(two, 100, unit="seeds") == "50 / 50 / 100 (2 seeds: no interval)"
    # three logs, the fewest that get one
    three = log_bootstrap(logs + logs[:1], within_sigma_share, n_boot=400)
    assert re.fullmatch(r"67 \[\d+-100\] / 33 \[0-\d+\] / 100 \[100-100\]", format_clustered(three, 100, unit="seeds"))
    rms = log_bootstrap([np.array([[INF]])] * 3, sigma_ratio_rms, n_boot=10)
    assert format_clustered(rms, digits=2) == "- [---]"          # no finite ratio


def test_a_missing_sensor_is_a_miss_in_the_benchmarks_ratios():
    net = SensorNetwork([SensorExtrinsics("a", [0.0, 0.0, 3.0], [0.0, 90.0, 0.0]),
                         SensorExtrinsics("b", [1.0, 0.0, 3.0], [0.0, 90.0, 0.0])])
    net["a"].sigma_position_m = np.array([0.01, 0.02, 0.04])
    net["b"].sigma_position_m = np.array([0.01, 0.01, 0.01])
    net["b"].status = "no-data"                   # its sigma the prior's: a miss
    ratios = sigma_ratios(net, ["a", "b"], [np.array([-0.005, 0.03, -0.02]), np.array([0.0, 0.0, 0.0])], missing=1)
    assert ratios.shape == (3, 3)
    np.testing.assert_allclose(ratios[0], [0.5, 1.5, 0.5])
    assert np.all(np.isinf(ratios[1:]))
    assert within_sigma_share(ratios) == pytest.approx([1 / 3, 0.0, 1 / 3])
    assert sigma_ratio_rms(ratios) == pytest.approx([0.5, 1.5, 0.5])


def test_the_bench_resamples_seeds_not_scenarios():
    rs = [dict(seed=0, ratios=np.array([[0.5, 0.5, 0.5]])), dict(seed=1, ratios=np.array([[2.0, 2.0, 2.0]])),
          dict(seed=0, ratios=np.array([[0.7, 0.7, 0.7], [0.9, 0.9, 0.9]]))]
    blocks = by_seed(rs)
    assert [len(b) for b in blocks] == [3, 1]
    np.testing.assert_allclose(blocks[0][:, 0], [0.5, 0.7, 0.9])


def test_only_selects_the_seeds_whose_zoo_draws_the_family():
    from pedcal.sim import load_scenario
    from pedcal.sim.nuisances import vary, zoo_families

    seeds = seeds_with("paper", {"head": "top"}, 0, 3)
    assert len(seeds) == 3 and seeds == sorted(seeds)
    base = load_scenario("paper")
    drawn = [zoo_families(vary(base.resolve(seed=s), zoo=True))["head"] for s in range(seeds[-1] + 1)]
    assert [s for s, h in enumerate(drawn) if h == "top"] == seeds


def test_only_refuses_an_unknown_family():
    import argparse

    ap = argparse.ArgumentParser()
    assert family_filter(["head=top", "amcl=correlated"], ap) == {"head": "top", "amcl": "correlated"}
    with pytest.raises(SystemExit):
        family_filter(["hair=long"], ap)
    with pytest.raises(SystemExit):
        family_filter(["head"], ap)


def test_only_refuses_a_value_the_zoo_never_draws_naming_those_it_does(capsys):
    import argparse

    with pytest.raises(SystemExit):
        family_filter(["head=tpo"], argparse.ArgumentParser())
    assert "--only head=tpo: the zoo draws head as one of per-sensor, top, dome, shift, centroid, ramp, " \
           "saturate" in capsys.readouterr().err
    assert family_filter(["amcl=relocalization", "head=per-sensor"], argparse.ArgumentParser()) == \
        {"amcl": "relocalization", "head": "per-sensor"}


def test_the_families_values_are_those_the_zoo_draws():
    # every value named is drawn in 300 seeds (each has a chance of 1/12 or more), and no other
    from bench_factorgraph_nuisances import ZOO_FAMILY_VALUES

    from pedcal.sim import load_scenario
    from pedcal.sim.nuisances import vary, zoo_families

    base = load_scenario("paper")
    drawn = [zoo_families(vary(base.resolve(seed=s), zoo=True)) for s in range(300)]
    assert set(drawn[0]) == set(ZOO_FAMILY_VALUES)
    for family, values in ZOO_FAMILY_VALUES.items():
        assert {d[family] for d in drawn} == set(values), family


def test_the_exams_ratios_count_a_sensor_at_its_prior_or_without_sigma_as_a_miss():
    from bench_xgen import honesty_table, log_ratios

    row = {"method": "m", "sensors": [
        {"dx": 0.01, "dy": -0.03, "dz": 0.0, "sigma_p": [0.02, 0.02, 0.01], "status": "ok"},
        {"dx": 0.0, "dy": 0.0, "dz": 0.0, "sigma_p": [0.5, 0.5, 0.5], "status": "no-data"},
        {"dx": 0.0, "dy": 0.0, "dz": 0.0, "sigma_p": None, "status": "missing"}]}
    r = log_ratios(row)
    np.testing.assert_allclose(r[0], [0.5, 1.5, 0.0])
    assert np.all(np.isinf(r[1:]))
    text = honesty_table([row] * 3, "m", [("all", [row] * 3)], "t")
    assert "| all | 3 | 9 (6) | 33 [33-33] / 0 [0-0] / 33 [33-33] | 0.50 [0.50-0.50] / 1.50 [1.50-1.50] / 0.00" in text
    # a method without any sigma has no table
    bare = {"method": "g", "sensors": [{**row["sensors"][0], "sigma_p": None}]}
    assert honesty_table([bare], "g", [("all", [bare])], "t") == ""


def test_the_exams_coverage_counts_within_k_sigma_and_a_miss_as_outside():
    from bench_xgen import shared_shift_removed, summarize

    def sensor(r, status="ok"):          # |error| / sigma = r on every axis, position and rotation
        return {"dx": -0.01 * r, "dy": 0.02 * r, "dz": 0.01 * r, "sigma_p": [0.01, 0.02, 0.01],
                "rot_deg": [r, -r, 0.5 * r], "sigma_rot_deg": [1.0, 1.0, 0.5], "status": status, "yaw_deg": 0.0}

    row = {"method": "m", "rc": 0, "cpu_s": 1.0, "wall_s": 1.0,
           "sensors": [sensor(0.5), sensor(1.0), sensor(1.5), sensor(2.5), sensor(0.1, "no-data"),
                       {**sensor(0.1), "sigma_p": None, "sigma_rot_deg": None}]}
    shared_shift_removed(row)
    out = summarize([row], "m")
    assert out["cov1"] == pytest.approx([100 * 2 / 6] * 3) and out["cov2"] == pytest.approx([100 * 3 / 6] * 3)
    assert out["rot1"] == pytest.approx(100 * 2 / 6) and out["rot2"] == pytest.approx(100 * 3 / 6)


def test_the_crowds_bench_pools_a_seeds_recordings_and_scenarios():
    # bench_realwalk resamples by_seed's blocks: one per seed, every recording and scenario of it
    runs = [dict(recording=rec, scenario=sc, seed=seed, ratios=np.full((2, 3), seed + 0.5))
            for rec in ("atc", "thor") for sc in ("paper", "cross") for seed in (1, 0)]
    out = by_seed(runs)
    assert [len(v) for v in out] == [8, 8]
    np.testing.assert_allclose(out[0], 1.5)                 # seed 1 first: the order they come in
    np.testing.assert_allclose(out[1], 0.5)


def test_the_stretch_fit_recovers_a_known_stretch_and_its_sigma():
    from bench_factorgraph_nuisances import stretch_fit

    true_xy = np.array([[0.0, 0.0], [4.0, 1.0], [8.0, 0.0], [12.0, 1.0], [16.0, 0.0]])
    d = true_xy - true_xy.mean(axis=0)
    E = np.column_stack([0.010 + 0.002 * d[:, 0], -0.020 - 0.001 * d[:, 1]])      # 2 mm/m along x, -1 along y
    # the covariance of 5 sensors' positions (3 per sensor), isotropic 10 mm, in a shuffled order
    rows = [4, 2, 0, 1, 3]
    cov = 0.01 ** 2 * np.eye(15)
    coef, sigma = stretch_fit(E, true_xy, cov, rows)
    np.testing.assert_allclose(coef, [0.010, -0.020, 0.002, -0.001], atol=1e-12)
    # the columns are orthogonal (the positions taken about their mean): sigma / sqrt(n) for the
    # shift, sigma / sqrt(sum d^2) for the stretch
    np.testing.assert_allclose(sigma, 0.01 / np.sqrt([5, 5, np.sum(d[:, 0] ** 2), np.sum(d[:, 1] ** 2)]))
    assert np.all(np.isnan(stretch_fit(E, true_xy, None, rows)[1]))


def test_the_stretch_fits_sigma_takes_each_sensors_own_x_and_y_variance():
    # a different variance per sensor (v) and per axis (x: v, y: 2 v, z: 50 v), the errors' rows in
    # a shuffled order of the network: a wrong map from rows to the covariance's blocks (rows
    # ignored, or another axis taken) gives other sigma. The columns being orthogonal and the
    # covariance diagonal, sigma of the shifts is sqrt(sum v) / n, of the stretches
    # sqrt(sum d^2 v) / sum d^2
    from bench_factorgraph_nuisances import stretch_fit

    true_xy = np.array([[0.0, 0.0], [4.0, 1.0], [8.0, 0.0], [12.0, 1.0], [16.0, 0.0]])
    d = true_xy - true_xy.mean(axis=0)
    v = np.array([1.0, 4.0, 9.0, 16.0, 25.0]) * 1e-4
    cov = np.diag(np.repeat(v, 3) * np.tile([1.0, 2.0, 50.0], 5))
    rows = np.array([4, 2, 0, 1, 3])
    vx, vy = v[rows], 2 * v[rows]
    E = np.column_stack([0.010 + 0.002 * d[:, 0], -0.020 - 0.001 * d[:, 1]])
    coef, sigma = stretch_fit(E, true_xy, cov, rows)
    np.testing.assert_allclose(coef, [0.010, -0.020, 0.002, -0.001], atol=1e-12)
    dx2, dy2 = d[:, 0] ** 2, d[:, 1] ** 2
    np.testing.assert_allclose(sigma, [np.sqrt(vx.sum()) / 5, np.sqrt(vy.sum()) / 5,
                                       np.sqrt(np.sum(dx2 * vx)) / dx2.sum(), np.sqrt(np.sum(dy2 * vy)) / dy2.sum()],
                               rtol=1e-12)


def test_the_shared_and_rest_text_is_the_rms_of_each_over_the_logs_sensors():
    from bench_factorgraph_nuisances import _z_text

    rs = [dict(z_shared=np.array([3.0, 0.0]), z_rest=np.array([1.0, -1.0, 2.0])),
          dict(z_shared=np.array([4.0, 0.0]), z_rest=np.array([0.0]))]
    assert _z_text(rs) == f"{np.sqrt(25 / 4):.2f} / {np.sqrt(6 / 4):.2f} (2 of 2 logs)" == "2.50 / 1.22 (2 of 2 logs)"
    assert _z_text([dict(z_shared=np.zeros(0), z_rest=np.zeros(0))]) == "- (0 of 1 logs)"  # no joint covariance
    # a log with a NaN joint covariance (NaN ratios) is not pooled, and the count says so
    assert _z_text(rs + [dict(z_shared=np.full(2, np.nan), z_rest=np.full(3, np.nan))]) == "2.50 / 1.22 (2 of 3 logs)"


@pytest.mark.parametrize("zoo", [False, True])
def test_the_bench_simulates_the_seeds_draw_when_nothing_is_switched_off(monkeypatch, zoo):
    # run_one's one path (switch_off of no family) simulates what simulate_logs draws itself
    from bench_factorgraph_nuisances import run_one

    import pedcal.sim
    from pedcal.sim.nuisances import switch_off

    class Simulated(Exception):
        pass

    def stop(sc):                        # the scenario simulate_logs resolved, before any simulating
        raise Simulated(sc)

    monkeypatch.setattr(pedcal.sim, "networks", stop)
    for name, seed in (("paper", 0), ("lhall", 3)):
        with pytest.raises(Simulated) as bench:
            run_one(name, seed, zoo=zoo)
        with pytest.raises(Simulated) as direct:
            pedcal.sim.simulate_logs(name, seed=seed, vary_nuisances="zoo" if zoo else True)
        assert bench.value.args[0] == direct.value.args[0]
    # and with a family off, the same draw less that family
    with pytest.raises(Simulated) as off:
        run_one("paper", 0, zoo=zoo, off=("latency",))
    with pytest.raises(Simulated) as direct:
        pedcal.sim.simulate_logs("paper", seed=0, vary_nuisances="zoo" if zoo else True)
    assert direct.value.args[0].latency_s > 0.0
    assert off.value.args[0] == switch_off(direct.value.args[0], ("latency",))


def test_a_clock_offset_not_estimated_is_a_miss_and_the_rms_is_over_the_finite_errors(monkeypatch):
    """Three sensors, "c"'s offset not estimated: it is a NaN error (outside every sigma), the
    others' errors are about the mean of the estimated ones' truth; the RMS leaves the NaN out."""
    from types import SimpleNamespace

    import bench_factorgraph_nuisances as bfn
    import pandas as pd

    monkeypatch.setattr(bfn, "sensor_clocks", lambda sc, n: (np.array([0.10, 0.00, 0.05]), np.zeros(n)))
    monkeypatch.setattr(bfn, "robot_rows", lambda log: (np.ones(len(log.observations), bool), None))
    class Truth(list):
        ids = property(list)

    log = SimpleNamespace(truth=Truth(["a", "b", "c"]),
                          observations=pd.DataFrame({"t": [1.0, 2.0], "sensor": ["a", "b"]}),
                          robot=pd.DataFrame({"t": [0.0, 3.0]}))
    sim = SimpleNamespace(calib=log, scenario=SimpleNamespace(start_time_s=0.0))
    net = SimpleNamespace(extra={bfn.CLOCK_OFFSET_KEY: {"a": 0.06, "b": -0.05},
                                 bfn.SIGMA_CLOCK_OFFSET_KEY: {"a": 0.02, "b": 0.02}})
    z, err = bfn.clock_offset_errors(sim, net)
    # truth about the estimated ones' mean 0.05: a 0.05, b -0.05
    np.testing.assert_allclose(err[:2], [0.01, 0.0], atol=1e-12)
    assert np.isnan(err[2]) and np.isnan(z[2])
    np.testing.assert_allclose(z[:2], [0.5, 0.0], atol=1e-9)
    assert np.mean(np.abs(z) <= 1) == pytest.approx(2 / 3)         # c counts as outside
    assert bfn.finite_rms(err) == pytest.approx(np.sqrt(0.01 ** 2 / 2))
    assert np.isnan(bfn.finite_rms(np.full(2, np.nan)))
    # a calibration that estimates no offset at all misses every sensor, never an empty (unscored) log
    z, err = bfn.clock_offset_errors(sim, SimpleNamespace(extra={}))
    assert len(z) == len(err) == 3
    assert np.all(np.isnan(z)) and np.all(np.isnan(err))


def _network_with_covariance(status, seed=0):
    """Sensors s0.. with ``status``, a seeded symmetric positive definite joint covariance
    (3n x 3n, world axes) in the file's ``position_covariance_m2``, in the network's order."""
    rng = np.random.default_rng(seed)
    n = len(status)
    A = rng.normal(0.0, 0.01, (3 * n, 3 * n))
    M = A @ A.T + 1e-5 * np.eye(3 * n)
    sensors = [SensorExtrinsics(f"s{i}", np.zeros(3), np.zeros(3), status=st) for i, st in enumerate(status)]
    return SensorNetwork(sensors, extra={"position_covariance_m2": {"sensors": [s.id for s in sensors],
                                                                    "matrix": M.tolist()}}), M


def test_the_network_sigma_splits_into_the_common_positions_and_each_sensors_departure():
    """network_sigma_split against the linear algebra done out: the mean of the ok sensors'
    positions, A x, has covariance A C A^T; the departures, (I - 1 A) x, theirs; the no-data sensor
    is no part of either (its rows changed, nothing moves); the two squares add up to the mean of
    the ok sensors' own variances."""
    from pedcal.metrics import network_sigma_split

    net, M = _network_with_covariance(["ok", "ok", "no-data", "ok"])
    ok = [0, 1, 3]
    rows = np.concatenate([np.arange(3 * i, 3 * i + 3) for i in ok])
    C = M[np.ix_(rows, rows)]
    A = np.hstack([np.eye(3)] * 3) / 3.0                     # the mean of three positions
    D = np.eye(9) - np.vstack([np.eye(3)] * 3) @ A           # each position less the mean
    dep = D @ C @ D.T
    want_rest = np.sqrt(np.mean([np.diag(dep[3 * i:3 * i + 3, 3 * i:3 * i + 3]) for i in range(3)], axis=0))
    got = network_sigma_split(net)
    assert got["sensors"] == 3 and got["ids"] == ["s0", "s1", "s3"]
    np.testing.assert_allclose(got["common_m"], np.sqrt(np.diag(A @ C @ A.T)), rtol=1e-12)
    np.testing.assert_allclose(got["relative_rms_m"], want_rest, rtol=1e-12)
    own = np.mean([np.diag(C[3 * i:3 * i + 3, 3 * i:3 * i + 3]) for i in range(3)], axis=0)
    np.testing.assert_allclose(np.square(got["common_m"]) + np.square(got["relative_rms_m"]), own, rtol=1e-12)
    M2 = M.copy()
    M2[6:9, :] *= 7.0
    M2[:, 6:9] *= 7.0
    net.extra["position_covariance_m2"]["matrix"] = M2.tolist()
    assert network_sigma_split(net) == got


def test_the_network_sigma_split_of_a_network_fully_correlated_is_all_common():
    """Every sensor moving as one (C_ij = C for all i, j): the common std is C's, nothing departs."""
    from pedcal.metrics import network_sigma_split

    net, _ = _network_with_covariance(["ok", "ok"])
    C = np.diag([4e-4, 9e-4, 1e-4])
    net.extra["position_covariance_m2"]["matrix"] = np.block([[C, C], [C, C]]).tolist()
    got = network_sigma_split(net)
    np.testing.assert_allclose(got["common_m"], [0.02, 0.03, 0.01], rtol=1e-12)
    np.testing.assert_allclose(got["relative_rms_m"], 0.0, atol=1e-12)


def test_the_network_sigma_split_needs_a_joint_covariance_and_an_ok_sensor():
    from pedcal.metrics import network_sigma_split

    net, M = _network_with_covariance(["ok", "degenerate"])
    assert network_sigma_split(SensorNetwork(list(net))) is None                 # no joint covariance
    # a sensor of the covariance the network lacks is not counted: here none ok is left
    assert network_sigma_split(SensorNetwork(list(net)[1:], extra=net.extra)) is None
    assert network_sigma_split(_network_with_covariance(["no-data", "degenerate"])[0]) is None
    one = network_sigma_split(net)                                               # the only ok sensor: all common
    np.testing.assert_allclose(one["common_m"], np.sqrt(np.diag(M[:3, :3])), rtol=1e-12)
    np.testing.assert_allclose(one["relative_rms_m"], 0.0, atol=1e-12)
    net.extra["position_covariance_m2"]["matrix"] = M[:3, :3].tolist()
    with pytest.raises(ValueError, match=r"position_covariance_m2: a \(3, 3\) matrix for 2 sensors, expected 6 x 6"):
        network_sigma_split(net)


def test_the_calibration_summary_states_the_network_sigma_split():
    from pedcal.calib.common import CalibrationResult
    from pedcal.metrics import network_sigma_split

    net, _ = _network_with_covariance(["ok", "ok", "ok"], seed=3)
    text = CalibrationResult(network=net, method="factorgraph").summary()
    split = network_sigma_split(net)
    common = ", ".join(f"{1000 * v:.1f}" for v in split["common_m"])
    rest = ", ".join(f"{1000 * v:.1f}" for v in split["relative_rms_m"])
    assert f"network sigma x, y, z: common position {common} mm" in text
    assert f"each sensor about it {rest} mm RMS (3 sensors ok)" in text
    assert "network sigma" not in CalibrationResult(network=SensorNetwork(list(net)), method="gridsearch").summary()
    net.extra["position_covariance_m2"]["matrix"] = np.eye(3).tolist()      # not the network's shape: no line
    assert "network sigma" not in CalibrationResult(network=net, method="factorgraph").summary()
