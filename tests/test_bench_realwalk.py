"""The recorded-crowd benchmark's diagnostics of the sigma: AMCL's true run mean over the exact std
of an OU mean (the truth's own draw), the shared / rest split per axis, and runs pooled from
several saved files."""

from __future__ import annotations

import pickle
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_realwalk import (  # noqa: E402
    _row,
    amcl_truth_z,
    load_results,
    print_table,
    shared_rest_parts,
    shared_rest_text,
    truth_z_text,
)

from pedcal.sim.robot import ou_process  # noqa: E402


def test_the_truth_z_is_the_run_mean_over_the_exact_ou_std():
    # x = T / tau = 15: var of the mean 2 sigma^2 / x (1 - (1 - e^-x) / x)
    x = 300.0 / 20.0
    std = 0.05 * np.sqrt(2.0 / x * (1.0 - (1.0 - np.exp(-x)) / x))
    z = amcl_truth_z([0.03, -0.06], 0.05, 20.0, 300.0)
    np.testing.assert_allclose(z, [0.03 / std, -0.06 / std], rtol=1e-12)


def test_the_truth_z_of_simulated_ou_runs_is_unit_normal():
    # the simulator's own OU process, 600 runs of 200 s at 5 Hz: the RMS of the z is 1 within
    # about 3 of its standard errors (1 / sqrt(2 n) = 0.03)
    rng = np.random.default_rng(7)
    n, dt = 1001, 0.2
    means = np.array([ou_process(rng, n, dt, 0.05, 20.0).mean() for _ in range(600)])
    z = amcl_truth_z(np.column_stack([means, means]), 0.05, 20.0, (n - 1) * dt)[:, 0]
    assert np.sqrt(np.mean(z ** 2)) == pytest.approx(1.0, abs=0.09)
    assert abs(np.mean(z)) < 0.15


def _run(seed: int, scenario: str = "paper", rec: str = "atc", **extra) -> dict:
    return dict(recording=rec, scenario=scenario, seed=seed, **extra)


def test_shared_and_rest_rms_per_axis():
    runs = [_run(0, z_shared=np.array([3.0, 0.0]), z_rest=np.array([[1.0, 2.0], [1.0, 0.0]])),
            _run(1, z_shared=np.array([4.0, 1.0]), z_rest=np.zeros((0, 2)))]
    # shared: x sqrt((9 + 16) / 2), y sqrt(1 / 2); rest: x 1, y sqrt(4 / 2)
    assert shared_rest_text(runs) == (f"{np.sqrt(12.5):.2f} / {np.sqrt(0.5):.2f} ; 1.00 / {np.sqrt(2.0):.2f}"
                                      " (2 of 2 logs)")


def test_the_shared_and_rest_text_counts_the_logs_it_pooled():
    """A log with a single calibrated sensor (no shared part) and one with a NaN joint covariance
    are not in the RMS: the text says 1 of 3 logs were pooled."""
    runs = [_run(0, z_shared=np.array([3.0, 4.0]), z_rest=np.array([[1.0, 1.0], [-1.0, -1.0]])),
            _run(1, z_shared=np.zeros(0), z_rest=np.zeros((0, 2))),
            _run(2, z_shared=np.array([np.nan, np.nan]), z_rest=np.full((2, 2), np.nan))]
    assert shared_rest_text(runs) == "3.00 / 4.00 ; 1.00 / 1.00 (1 of 3 logs)"


def test_runs_saved_without_the_split_print_a_dash():
    assert shared_rest_text([_run(0), _run(1, z_shared=np.zeros(2), z_rest=np.zeros((1, 2)))]) == "-"
    assert truth_z_text([_run(0)]) == "-"


def test_the_truth_z_leaves_out_logs_without_it():
    runs = [_run(0, amcl_truth_z=np.array([2.0, -1.0])), _run(1, amcl_truth_z=np.full(2, np.nan)),
            _run(2, amcl_truth_z=np.array([0.0, 1.0]))]
    assert truth_z_text(runs) == f"{np.sqrt(2.0):.2f} / 1.00 (2)"


def test_the_truth_z_counts_each_scenario_and_seeds_draw_once():
    # the three recordings' logs of (paper, 0) share one AMCL draw: one value, not three
    runs = [_run(0, rec=rec, amcl_truth_z=np.array([3.0, 0.0])) for rec in ("atc", "eth_ucy", "thor")]
    runs += [_run(0, "cross", amcl_truth_z=np.array([1.0, 2.0])), _run(1, amcl_truth_z=np.array([0.0, 0.0]))]
    assert truth_z_text(runs) == f"{np.sqrt(10.0 / 3.0):.2f} / {np.sqrt(4.0 / 3.0):.2f} (3)"


def _full_run(seed: int, scenario: str = "paper", rec: str = "atc", missed: int | None = 0) -> dict:
    # two sensors' squared horizontal errors 3^2 + 4^2 mm^2 for the graph, twice that for the grid
    extra = {} if missed is None else {"missed": missed}
    return _run(seed, scenario, rec, factorgraph=dict(sq_xy=np.array([25.0, 25.0]), cpu_s=1.0, **extra),
                gridsearch=dict(sq_xy=np.array([100.0, 100.0]), cpu_s=1.0, **extra),
                ratios=np.full((2, 3), 0.5), amcl_truth_z=np.full(2, np.nan))


def test_each_rms_shows_the_sensors_it_left_out():
    row = _row("all", [_full_run(0, missed=1), _full_run(1, missed=2)])
    assert "| 5.0 (3) | 10.0 (3) | 0.50 |" in row
    # runs saved before the misses were counted: '?', not 0
    assert "| 5.0 (?) | 10.0 (?) | 0.50 |" in _row("all", [_full_run(0, missed=None), _full_run(1)])


def test_pooled_runs_that_miss_a_recording_and_scenario_print_only_rows_with_logs(capsys):
    print_table([_full_run(0), _full_run(1)], ["atc", "eth_ucy"], ["paper", "cross"], by_scenario=True, by_seed=True)
    names = [line.split(" | ")[0].lstrip("| ") for line in capsys.readouterr().out.splitlines()[2:]]
    assert names == ["atc / paper", "all / paper", "seed 0", "seed 1", "all"]


def _save(path: Path, runs: list[dict], scenarios: list[str]) -> str:
    with open(path, "wb") as fh:
        pickle.dump(dict(title=path.stem, results=runs, recordings=["atc"], scenarios=scenarios), fh)
    return str(path)


def test_several_saved_runs_pool_their_logs(tmp_path):
    a = _save(tmp_path / "a.pkl", [_run(0), _run(1)], ["paper"])
    b = _save(tmp_path / "b.pkl", [_run(2), _run(0, "cross")], ["paper", "cross"])
    pooled = load_results([a, b])
    assert [(r["scenario"], r["seed"]) for r in pooled["results"]] == [("paper", 0), ("paper", 1), ("paper", 2),
                                                                       ("cross", 0)]
    assert pooled["scenarios"] == ["paper", "cross"] and pooled["recordings"] == ["atc"]
    assert pooled["title"] == "a + b"


def test_a_log_in_two_saved_runs_is_refused(tmp_path):
    a = _save(tmp_path / "a.pkl", [_run(0), _run(1)], ["paper"])
    b = _save(tmp_path / "b.pkl", [_run(1)], ["paper"])
    with pytest.raises(ValueError, match=r"b\.pkl: log \('atc', 'paper', 1\) is also in .*a\.pkl"):
        load_results([a, b])


def test_the_split_pools_the_calibrated_sensors_with_an_error():
    # four sensors of a network of five (s4 not evaluated): s2, first in the network, not
    # calibrated and s3 without an error are left out, so the shared part is the mean of s0 and
    # s1, which sit at the network's rows 1 and 2 (10 and 20 mm per axis, independent): its sigma
    # sqrt(10^2 + 20^2) / 2 mm, and each departure +-half their difference, the same sigma; read
    # from rows 0 and 1 (10 mm each) it would be 10 / sqrt(2) mm
    ids = ["s2", "s0", "s1", "s3", "s4"]
    status = {"s0": "ok", "s1": None, "s2": "not_calibrated", "s3": "ok", "s4": "ok"}
    network = type("Net", (), {"ids": ids, "__getitem__": lambda self, k: SimpleNamespace(status=status[k])})()
    err_mm = {"s0": [30.0, -10.0, 5.0], "s1": [10.0, 10.0, 0.0], "s2": [900.0, 900.0, 0.0],
              "s3": [np.nan, 0.0, 0.0]}
    ev = SimpleNamespace(sensors=[SimpleNamespace(id=k, position_error_mm=np.array(v)) for k, v in err_mm.items()])
    cov = np.eye(15) * 0.01 ** 2
    cov[6:9, 6:9] = np.eye(3) * 0.02 ** 2
    sigma = np.sqrt(0.01 ** 2 + 0.02 ** 2) / 2.0
    shared, rest = shared_rest_parts(ev, network, cov)
    np.testing.assert_allclose(shared, np.array([0.020, 0.0]) / sigma, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rest.reshape(-1, 2), np.array([[0.010, -0.010], [-0.010, 0.010]]) / sigma,
                               rtol=1e-9, atol=1e-12)
    # without the joint covariance: nothing to split
    shared, rest = shared_rest_parts(ev, network, None)
    assert shared.shape == (0,) and rest.shape == (0,)
