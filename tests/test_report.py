"""pedcal report: sweeps on Dask equal serial runs, reports rebuild byte for byte from saved
results, the tables hold the means of the saved per-seed results, and the comparison of
extrinsics files on a user's log."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pedcal.cli import main
from pedcal.errors import PedcalInputError
from pedcal.report import (
    SweepConfig,
    build,
    build_report,
    load_results,
    register_section,
    results_from_cases,
    run_sweep,
    save_results,
)
from pedcal.report.build import accuracy_section, header_section, sigma_consistency
from pedcal.report.results import TABLES
from pedcal.report.sweep import parse_scenarios

# The cheap methods on the smallest scenario: a sweep of two seeds takes a few seconds; one short
# following episode with two trackers for the tracking table.
CONFIG = SweepConfig(scenarios=[("sparse", 2)], methods=["installed", "alternative", "closedform"], seeds=2,
                     out="reports/test", follow_scenes=["passing"], follow_trackers=["paper", "lidar-only"],
                     follow_seeds=1)


@pytest.fixture(scope="module")
def serial_cases():
    return run_sweep(CONFIG, serial=True, progress=False)


@pytest.fixture(scope="module")
def results_dir(serial_cases, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    save_results(results_from_cases(CONFIG, serial_cases), out)
    build_report(out)
    return out


def _files(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_dask_sweep_equals_serial(serial_cases):
    dask_cases = run_sweep(CONFIG, workers=2, progress=False)
    assert [(c.get("scenario", c.get("scene")), c["seed"]) for c in dask_cases] == [
        ("sparse", 0), ("sparse", 1), ("passing", 0)]
    serial, parallel = results_from_cases(CONFIG, serial_cases), results_from_cases(CONFIG, dask_cases)
    for name in TABLES:
        pd.testing.assert_frame_equal(getattr(parallel, name), getattr(serial, name), check_exact=True)


def test_saved_results_and_report_are_byte_identical(serial_cases, results_dir, tmp_path):
    # Saving the same results again gives the same bytes (timings.json is not among them).
    again = tmp_path / "again"
    save_results(results_from_cases(CONFIG, serial_cases), again)
    saved = _files(results_dir)
    for name, data in _files(again).items():
        assert data == saved[name], name
    # Rebuilding from the saved results alone gives the same Markdown and PNGs.
    rebuilt = tmp_path / "rebuilt"
    shutil.copytree(results_dir, rebuilt)
    for p in rebuilt.rglob("*.png"):
        p.unlink()
    (rebuilt / "report.md").unlink()
    assert main(["report", "--from-results", str(rebuilt)]) == 0
    first, second = _files(results_dir), _files(rebuilt)
    assert first.keys() == second.keys()
    pngs = [k for k in first if k.endswith(".png")]
    assert len(pngs) >= 3
    for name in first:
        assert first[name] == second[name], name


def test_report_header_is_the_command_and_timings_stay_out(results_dir):
    text = (results_dir / "report.md").read_text()
    assert text.splitlines()[0] == "# pedcal calibration report"
    assert CONFIG.command() in text
    assert "--scenarios sparse --seeds 2 --methods installed alternative closedform" in CONFIG.command()
    assert "`timings.json`, which this report does not read" in text
    assert "time" not in (results_dir / "results.json").read_text()


def _table_rows(text: str, heading: str) -> dict[str, list[str]]:
    block = text.split(heading, 1)[1].split("\n\n", 3)[2]
    rows = {}
    for line in block.splitlines()[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def test_table_ii_holds_the_means_of_the_saved_per_seed_results(results_dir):
    saved = json.loads((results_dir / "results.json").read_text())
    runs = pd.DataFrame(saved["runs"]["rows"], columns=saved["runs"]["columns"])
    parquet = pd.read_parquet(results_dir / "runs.parquet")     # the same table, every digit
    pd.testing.assert_frame_equal(runs, parquet.round(6), check_dtype=False)
    rows = _table_rows((results_dir / "report.md").read_text(), "### Table II")
    assert set(rows) == set(CONFIG.methods)
    for method, cells in rows.items():
        r = runs[runs["method"] == method]
        assert len(r) == 2
        for cell, column in ((cells[0], "sensor_rms_mm"), (cells[2], "head_rms_mm")):
            v = r[column].to_numpy(float)
            m = re.fullmatch(r"([\d.]+) ± ([\d.]+) \(([\d.]+)–([\d.]+)\)", cell)
            assert m, cell
            expected = (v.mean(), v.std(ddof=1), v.min(), v.max())
            assert [float(g) for g in m.groups()] == pytest.approx(expected, abs=0.051)
    assert rows["alternative"][1] == "379.53"       # the published figure beside ours
    assert rows["closedform"][1] == "–"             # pedcal's own method: nothing published
    # The closed form beats the installed extrinsics on every seed.
    inst = runs[runs["method"] == "installed"]["sensor_rms_mm"].to_numpy()
    assert (runs[runs["method"] == "closedform"]["sensor_rms_mm"].to_numpy() < inst).all()


def test_sections_can_be_appended_from_saved_results(results_dir, tmp_path, monkeypatch):
    def tracking_section(ctx):
        n = len(ctx.results.runs)
        return f"## Tracking\n\n{n} runs read from {ctx.results_dir.name}"

    path = build_report(results_dir, out_dir=tmp_path, sections=[header_section, tracking_section])
    text = path.read_text()
    assert text.startswith("# pedcal calibration report")
    assert text.rstrip().endswith(f"6 runs read from {results_dir.name}")
    monkeypatch.setattr(build, "SECTIONS", [header_section, accuracy_section])
    register_section(tracking_section)
    text = build_report(results_dir, out_dir=tmp_path / "b").read_text()
    assert text.index("### Table II") < text.index("## Tracking")


def test_sigma_consistency_of_a_consistent_and_an_overconfident_method(results_dir):
    rng = np.random.default_rng(7)
    n = 4000
    sigma_mm = rng.uniform(5.0, 50.0, (n, 3))
    rows = []
    for method, scale in (("consistent", 1.0), ("overconfident", 3.0)):
        err = scale * sigma_mm * rng.standard_normal((n, 3))
        rows.append(pd.DataFrame({"scenario": "x", "method": method, "status": "ok",
                                  **{f"err_{a}_mm": err[:, i] for i, a in enumerate("xyz")},
                                  **{f"sigma_{a}_mm": sigma_mm[:, i] for i, a in enumerate("xyz")}}))
    res = load_results(results_dir)
    res.sensors = pd.concat(rows, ignore_index=True)
    res.config = SweepConfig(scenarios=[("x", 1)], methods=["consistent", "overconfident"])
    tab = sigma_consistency(res, "x").set_index("method")
    assert tab.loc["consistent", ["within_1", "within_2", "within_3"]].to_numpy(float) == pytest.approx(
        [0.6827, 0.9545, 0.9973], abs=0.015)
    assert tab.loc["overconfident", "within_1"] == pytest.approx(0.2611, abs=0.015)   # P(|z| < 1/3)
    assert tab.loc["consistent", "axes"] == 3 * n


def test_sigma_consistency_counts_a_sensor_left_uncalibrated_or_without_sigma_as_a_miss(results_dir):
    """Four of eight sensors missed (one with no data, one degenerate: its sigma the prior's, one ok
    without a sigma, one with an infinite sigma): the shares are over all 24 axes, so a method is not
    more consistent for dropping the sensors it fails; with half the axes missed the median is inf."""
    ratio = np.array([0.5, 0.5, 0.5, 0.5, 1.5, 1.5, 2.5, 0.5])
    status = ["ok", "ok", "ok", "degenerate", "ok", "ok", "no-data", "ok"]
    sigma = np.full(8, 10.0)
    sigma[7] = np.nan                                    # ok, but no sigma reported
    sigma[5] = np.inf                                    # ok, an infinite sigma: no sigma either
    d = pd.DataFrame({"scenario": "x", "method": "m", "status": status,
                      **{f"err_{a}_mm": ratio * 10.0 for a in "xyz"}, **{f"sigma_{a}_mm": sigma for a in "xyz"}})
    res = load_results(results_dir)
    res.sensors = d
    res.config = SweepConfig(scenarios=[("x", 1)], methods=["m"])
    r = sigma_consistency(res, "x").iloc[0]
    assert (r["axes"], r["missed"]) == (24, 12)
    assert r.within_1 == pytest.approx(3 / 8)            # sensors 0-2 (3, degenerate, is a miss)
    assert r.within_2 == pytest.approx(4 / 8) and r.within_3 == pytest.approx(4 / 8)
    assert r.median_ratio == np.inf        # 9 of 0.5, 3 of 1.5, 12 misses: (1.5 + inf) / 2 (0.5 without misses)



def test_sigma_consistency_leaves_out_a_method_without_any_sigma(results_dir):
    d = pd.DataFrame({"scenario": "x", "method": "m", "status": ["ok", "ok"],
                      **{f"err_{a}_mm": [1.0, 2.0] for a in "xyz"}, **{f"sigma_{a}_mm": np.nan for a in "xyz"}})
    res = load_results(results_dir)
    res.sensors = d
    res.config = SweepConfig(scenarios=[("x", 1)], methods=["m"])
    assert sigma_consistency(res, "x").empty


def test_sigma_consistency_shows_a_method_that_gave_up_on_every_sensor_of_one_scenario(results_dir):
    """A method with sigmas in scenario "a" that gave up on both sensors of scenario "b" (not ok, no
    sigma) is a row of "b" with its 6 misses and 0 %, not left out as a method without a sigma."""
    d = pd.DataFrame({"scenario": ["a", "a", "b", "b"], "method": "m",
                      "status": ["ok", "ok", "degenerate", "no-data"],
                      **{f"err_{a}_mm": [1.0, 2.0, np.nan, np.nan] for a in "xyz"},
                      **{f"sigma_{a}_mm": [10.0, 10.0, np.nan, np.nan] for a in "xyz"}})
    res = load_results(results_dir)
    res.sensors = d
    res.config = SweepConfig(scenarios=[("a", 1), ("b", 1)], methods=["m"])
    assert sigma_consistency(res, "a").iloc[0]["within_1"] == 1.0
    r = sigma_consistency(res, "b").iloc[0]
    assert (r["method"], r["axes"], r["missed"]) == ("m", 6, 6)
    assert (r.within_1, r.within_2, r.within_3) == (0.0, 0.0, 0.0) and r.median_ratio == np.inf


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory) -> Path:
    from pedcal.calib import calibrate
    from pedcal.io import write_sensors_yaml
    from pedcal.sim import simulate

    out = tmp_path_factory.mktemp("sim")
    sim = simulate("sparse", out, seed=3)
    write_sensors_yaml(calibrate(sim.calib, method="closedform").network, out / "closedform.yaml")
    return out


def test_report_log_extrinsics_writes_the_table(sim_log, tmp_path):
    from pedcal.io import read_log, read_sensors_yaml
    from pedcal.metrics import evaluate

    out = tmp_path / "cmp"
    assert main(["report", str(sim_log / "eval"), "--extrinsics", str(sim_log / "closedform.yaml"),
                 "--out", str(out), "-q"]) == 0
    text = (out / "report.md").read_text()
    ev = evaluate(read_log(sim_log / "eval"), read_sensors_yaml(sim_log / "closedform.yaml"))
    row = next(line for line in text.splitlines() if line.startswith("| closedform |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == f"{ev.sensor_position_rms_mm.combined:.1f}"
    assert cells[4] == f"{ev.head_tracking_rms_mm:.1f}"
    assert any(line.startswith("| installed |") for line in text.splitlines())
    assert (out / "figures" / "trajectories.png").stat().st_size > 1000
    assert (out / "figures" / "head_rms_per_sensor.png").stat().st_size > 1000
    saved = json.loads((out / "results.json").read_text())
    assert [r["label"] for r in saved["summary"]] == ["installed", "closedform"]


def test_report_log_without_truth_scores_against_amcl(sim_log, tmp_path):
    log = tmp_path / "log"
    shutil.copytree(sim_log / "eval", log)
    for name in ("truth.yaml", "truth_robot.csv", "truth_observations.csv"):
        (log / name).unlink()
    out = tmp_path / "cmp"
    assert main(["report", str(log), "--extrinsics", str(sim_log / "closedform.yaml"), "--out", str(out),
                 "-q"]) == 0
    text = (out / "report.md").read_text()
    assert "AMCL head path (robot.csv)" in text
    row = next(line for line in text.splitlines() if line.startswith("| closedform |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == "–" and float(cells[4]) < 200.0      # no truth: no sensor error, head RMS vs AMCL


def test_bad_extrinsics_file_exits_2_naming_it(sim_log, tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensors:\n  - id: s04\n    position: [1.0, 2.0]\n    ypr_deg: [0, 45, 0]\n")
    out = tmp_path / "cmp"
    assert main(["report", str(sim_log / "eval"), "--extrinsics", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "position" in err and "Traceback" not in err
    assert not (out / "report.md").exists()
    assert main(["report", str(sim_log / "eval"), "--extrinsics", str(tmp_path / "missing.yaml"),
                 "--out", str(out)]) == 2
    assert "missing.yaml" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--scenarios", "nowhere"], "nowhere"),
    (["--scenarios", "sparse:0"], "sparse:0"),
    (["--methods", "magic"], "magic"),
    (["--extrinsics", "a.yaml"], "LOG"),
    (["--follow-scenes", "nowhere"], "nowhere"),
    (["--follow-trackers", "psychic"], "psychic"),
    (["--follow-seeds", "-1"], "-1"),
])
def test_bad_report_arguments_exit_2(argv, message, tmp_path, capsys):
    assert main(["report", *argv, "--out", str(tmp_path / "r"), "--serial", "-q"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_from_results_of_a_directory_without_results_exits_2(tmp_path, capsys):
    assert main(["report", "--from-results", str(tmp_path)]) == 2
    assert "results.json" in capsys.readouterr().err


def test_parse_scenarios():
    assert parse_scenarios(["paper", "mall:3"], 10) == [("paper", 10), ("mall", 3)]
    with pytest.raises(PedcalInputError, match="twice"):
        parse_scenarios(["paper", "paper:2"], 10)


def test_crlb_row_is_the_ratio_of_the_saved_errors_to_the_saved_bound(results_dir):
    sensors = pd.read_parquet(results_dir / "sensors.parquet")
    bounds = pd.read_parquet(results_dir / "bounds.parquet")
    assert len(bounds) == 2 * 5 and (bounds["crlb_3d_mm"] > 0).all()
    d = sensors[(sensors["method"] == "closedform") & (sensors["status"] == "ok")].merge(
        bounds, on=["scenario", "seed", "sensor"])
    ratios = [np.sqrt(np.mean(g["err_mm"] ** 2)) / np.sqrt(np.mean(g["crlb_3d_mm"] ** 2)) for _, g in d.groupby("seed")]
    text = (results_dir / "report.md").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| sparse | closedform | 10 |"))
    m = re.search(r"\| ([\d.]+) ± ([\d.]+) \(", row)
    assert float(m.group(1)) == pytest.approx(np.mean(ratios), abs=0.0051)
    assert float(m.group(1)) > 0.5       # no unbiased estimate beats the bound by much


def test_tracking_table_holds_the_follow_metrics_of_each_tracker(results_dir):
    from pedcal.track.follow import run_follow

    text = (results_dir / "report.md").read_text(encoding="utf-8")
    block = text.split("## Following a specific person", 1)[1].split("\n\n")[2]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]
    saved = load_results(results_dir).tracking
    assert sorted(saved["tracker"]) == ["lidar-only", "paper"]
    for tracker in ("paper", "lidar-only"):
        expected = run_follow("passing", tracker=tracker, seed=0).to_dict()
        row = saved[saved["tracker"] == tracker].iloc[0]
        assert row["with_target_fraction"] == pytest.approx(expected["with_target_fraction"])
        assert row["id_switches"] == expected["id_switches"]
        cells = [r for r in rows if r[:2] == ["passing", tracker]][0]
        assert cells[2].startswith(f"{expected['with_target_fraction']:.3f}")


def test_rerun_tracking_replaces_only_the_tracking_table(results_dir, tmp_path):
    from pedcal.report import rerun_tracking

    out = tmp_path / "copy"
    shutil.copytree(results_dir, out)
    before = load_results(out)
    t = before.tracking.copy()
    t["with_target_fraction"] = -1.0          # stale figures that the rerun must replace
    before.tracking = t
    save_results(before, out)
    rerun_tracking(out, progress=False)
    after = load_results(out)
    pd.testing.assert_frame_equal(after.runs, load_results(results_dir).runs)
    pd.testing.assert_frame_equal(after.tracking, load_results(results_dir).tracking)
    assert (out / "report.md").read_text(encoding="utf-8") == (results_dir / "report.md").read_text(encoding="utf-8")


@pytest.mark.parametrize("damage", ["truncated", "other columns"])
@pytest.mark.parametrize("table", ["runs", "sensors", "heads", "robot", "bounds"])
def test_from_results_with_a_damaged_table_exits_2_naming_it(results_dir, tmp_path, capsys, table, damage):
    """A cut Parquet file raised pyarrow's error and a table of other columns a KeyError: tracebacks."""
    copy = tmp_path / "results"
    shutil.copytree(results_dir, copy)
    p = copy / f"{table}.parquet"
    if damage == "truncated":
        p.write_bytes(p.read_bytes()[:200])
    else:
        pd.DataFrame({"a": [1.0]}).to_parquet(p)
    assert main(["report", "--from-results", str(copy), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert f"{p}: cannot read the Parquet table" in err if damage == "truncated" else \
        f"{p}, column 'scenario': not a table `pedcal report` writes: missing column(s) scenario" in err
    assert "Traceback" not in err and not (tmp_path / "out").exists()


def _sensor_records_of_a_kept_and_a_missing_sensor() -> pd.DataFrame:
    """The sensors table of a method that returned sensor "a" (ok, with sigmas) of a log of "a"
    and "b" (true positions (0, 0, 3) and (2, 0, 3) m)."""
    from types import SimpleNamespace

    from pedcal.report.sweep import _sensor_records

    truth = {sid: SimpleNamespace(position_m=np.array([x, 0.0, 3.0]), ypr_deg=np.zeros(3))
             for sid, x in (("a", 0.0), ("b", 2.0))}
    net = [SimpleNamespace(id="a", status="ok", observations=5, position_m=np.array([0.01, 0.0, 3.0]),
                           sigma_position_m=np.full(3, 0.02), sigma_ypr_deg=np.ones(3))]
    ev = SimpleNamespace(sensors=[SimpleNamespace(id="a", position_error_mm=[10.0, 0.0, 0.0],
                                                  orientation_error_deg=0.5, head_rms_mm=3.0,
                                                  head_observations=5)],
                         missing_sensors=["b"])
    return pd.DataFrame(_sensor_records("x", 0, "m", net, truth, ev))


def test_a_sensor_missing_from_the_returned_network_is_a_missed_row(results_dir):
    """The method returned sensor "a" only; "b" of the log is a row with status "missing" and NaN
    errors and sigmas, so the sigma consistency counts its 3 axes among the misses."""
    recs = _sensor_records_of_a_kept_and_a_missing_sensor()
    assert list(recs["sensor"]) == ["a", "b"] and list(recs["status"]) == ["ok", "missing"]
    b = recs.iloc[1]
    assert b["true_x_m"] == 2.0 and b["observations"] == 0
    assert np.isnan(b[["err_x_mm", "err_mm", "sigma_x_mm", "sigma_z_mm", "est_x_m"]].to_numpy(float)).all()
    res = load_results(results_dir)
    assert set(recs.columns) == set(res.sensors.columns)
    res.sensors = recs
    res.config = SweepConfig(scenarios=[("x", 1)], methods=["m"])
    r = sigma_consistency(res, "x").iloc[0]
    assert (r["axes"], r["missed"]) == (6, 3)


def test_the_runs_row_counts_a_sensor_missing_from_the_returned_network_as_uncalibrated(monkeypatch):
    """A method that leaves a sensor of the log out of its network has that sensor counted in the
    runs row's ``sensors`` and ``no_data``, as the sensors table holds it (status "missing"):
    dropping a sensor must not read as one failure fewer."""
    import pedcal.demo
    from pedcal.model import SensorNetwork
    from pedcal.report.sweep import run_case

    real = pedcal.demo.calibrate_scored

    def drop_last(sim, method):
        network, runtime_s, assoc = real(sim, method)
        return SensorNetwork(network.sensors[:-1], network.frame, dict(network.extra)), runtime_s, assoc

    monkeypatch.setattr(pedcal.demo, "calibrate_scored", drop_last)
    case = run_case("sparse", 0, ["installed"])
    n_log = len({r["sensor"] for r in case["sensors"]})
    run = case["runs"][0]
    assert n_log >= 2 and [r["status"] for r in case["sensors"]].count("missing") == 1
    assert (run["sensors"], run["no_data"], run["ok"]) == (n_log, 1, 0)


def test_the_covariance_floorplan_crosses_a_missing_sensor_out():
    """A sensor missing from the returned network is drawn as uncalibrated (a cross at its true
    position), not as a calibrated sensor with a NaN error."""
    from pedcal.report.figures import covariance_floorplan

    fig = covariance_floorplan(_sensor_records_of_a_kept_and_a_missing_sensor(), ["m"], "t")
    crosses = [c for c in fig.axes[0].collections if c.get_label() == "no data: not calibrated"]
    assert len(crosses) == 1 and crosses[0].get_offsets().tolist() == [[2.0, 0.0]]
