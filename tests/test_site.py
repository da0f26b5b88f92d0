"""A site of independent runs (pedcal.calib.site): each run's log calibrated on its own, serially
or on Dask, with the same result as calibrating it alone; sites whose runs share a sensor, share
a name or hold none refused before any work."""

import copy
import dataclasses
import warnings

import pytest
import yaml

from pedcal.calib import calibrate
from pedcal.calib.site import calibrate_site
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.io import read_log, write_log
from pedcal.model import SensorNetwork
from pedcal.sim import simulate_logs


def _renamed(log, prefix: str):
    """``log`` with every sensor id prefixed (a floor of its own)."""
    out = copy.copy(log)
    out.sensors = SensorNetwork([dataclasses.replace(s, id=prefix + s.id) for s in log.sensors],
                                frame=log.sensors.frame)
    if log.truth is not None:
        out.truth = SensorNetwork([dataclasses.replace(s, id=prefix + s.id) for s in log.truth],
                                  frame=log.truth.frame)
    out.observations = log.observations.assign(sensor=prefix + log.observations["sensor"].astype(str))
    return out


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("site")
    runs = []
    for floor, seed in (("floor1", 0), ("floor2", 1)):
        write_log(_renamed(simulate_logs("paper", seed=seed).calib, f"{floor}_"), root / floor)
        runs.append(root / floor)
    return root, runs


def _positions(path):
    return {s["id"]: s["position"] for s in yaml.safe_load(path.read_text())["sensors"]}


def test_each_run_is_calibrated_as_alone(site, tmp_path):
    _, runs = site
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        done = calibrate_site(runs, tmp_path / "out", method="closedform", serial=True)
        alone = [calibrate(read_log(r), method="closedform") for r in runs]
    assert [d["run"] for d in done] == ["floor1", "floor2"]
    for d, res in zip(done, alone, strict=True):
        got = _positions(tmp_path / "out" / f"{d['run']}.yaml")
        assert set(got) == {s.id for s in res.network} and all(k.startswith(d["run"]) for k in got)
        for s in res.network:
            assert got[s.id] == pytest.approx(list(s.position_m), abs=1e-9)
        assert d["solve_cpu_s"] > 0.0 and set(d["sensors"].values()) <= {"ok", "degenerate", "no-data"}


def test_runs_on_a_dask_cluster_give_the_serial_result(site, tmp_path):
    _, runs = site
    serial = calibrate_site(runs, tmp_path / "serial", method="closedform", serial=True)
    parallel = calibrate_site(runs, tmp_path / "dask", method="closedform", workers=2)
    assert [d["run"] for d in parallel] == [d["run"] for d in serial]
    for d in serial:
        assert ((tmp_path / "dask" / f"{d['run']}.yaml").read_text()
                == (tmp_path / "serial" / f"{d['run']}.yaml").read_text())


def test_a_sensor_in_two_runs_is_refused(site, tmp_path):
    root, runs = site
    write_log(simulate_logs("paper", seed=2).calib, root / "plain_a")
    write_log(simulate_logs("paper", seed=3).calib, root / "plain_b")
    with pytest.raises(PedcalInputError, match="sensor s01 is in run plain_a and run plain_b"):
        calibrate_site([root / "plain_a", root / "plain_b"], tmp_path / "out", serial=True)
    assert not (tmp_path / "out").exists()


def test_runs_of_one_name_no_run_and_a_missing_log_are_refused(site, tmp_path):
    root, runs = site
    (tmp_path / "other").mkdir()
    with pytest.raises(PedcalInputError, match="two runs named floor1"):
        calibrate_site([runs[0], runs[0]], tmp_path / "out", serial=True)
    with pytest.raises(PedcalInputError, match="no run to calibrate"):
        calibrate_site([], tmp_path / "out", serial=True)
    with pytest.raises(PedcalInputError, match="expected a log directory"):
        calibrate_site([tmp_path / "other"], tmp_path / "out", serial=True)
    assert not (tmp_path / "out").exists()
