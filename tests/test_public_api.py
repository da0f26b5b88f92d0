"""The top-level API (lazy re-exports), logging instead of prints, in-memory inputs of the
path-taking entry points."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

import pedcal
from pedcal.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_import_is_lazy_and_names_resolve():
    code = ("import sys, pedcal; assert 'gtsam' not in sys.modules and 'pandas' not in sys.modules, "
            "sorted(m for m in sys.modules if m.split('.')[0] in ('gtsam', 'pandas')); "
            "assert 'calibrate' in dir(pedcal)")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, env={"PYTHONPATH": str(ROOT)})
    for name in pedcal.__all__:
        obj = getattr(pedcal, name)
        assert obj is not None
        if callable(obj):
            assert obj.__doc__, f"pedcal.{name} has no docstring"
    from pedcal.calib import calibrate
    from pedcal.track.follow import run_follow

    assert pedcal.calibrate is calibrate and pedcal.follow is run_follow
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        pedcal.nope  # noqa: B018


def test_every_module_has_a_docstring():
    import importlib
    import pkgutil

    missing = []
    for info in pkgutil.walk_packages(pedcal.__path__, "pedcal."):
        mod = importlib.import_module(info.name)
        if not (mod.__doc__ or "").strip():
            missing.append(info.name)
    assert not missing


def test_calibrate_documents_each_methods_options():
    from pedcal.calib import METHODS

    doc = pedcal.calibrate.__doc__
    for method in METHODS:
        assert f"``{method}``" in doc


@pytest.fixture(scope="module")
def small_sim():
    return pedcal.simulate_logs("sparse", seed=0, duration_s=90)


def test_progress_goes_through_logging(small_sim, caplog):
    with caplog.at_level(logging.INFO, logger="pedcal"):
        pedcal.calibrate(small_sim.calib, method="closedform", progress=True)
    msgs = [r.getMessage() for r in caplog.records if r.name.startswith("pedcal.calib")]
    assert any("closedform: sensor s04" in m for m in msgs)
    assert any("observations are the robot" in m for m in msgs)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="pedcal"):
        pedcal.calibrate(small_sim.calib, method="closedform")   # progress off: nothing at INFO
    assert not [r for r in caplog.records if r.levelno == logging.INFO]


def test_cli_quiet_and_verbose_flags(tmp_path, capsys):
    args = ["simulate", "sparse", "-o", str(tmp_path / "sim")]
    assert main(args) == 0
    assert "simulate:" in capsys.readouterr().err           # progress shown by default
    assert main(["-q", *args]) == 0
    assert "simulate:" not in capsys.readouterr().err
    assert main(["-v", *args]) == 0
    assert "INFO pedcal.sim: simulate:" in capsys.readouterr().err
    assert logging.getLogger("pedcal").level == logging.DEBUG
    main(["-q", *args])      # one handler however often main runs
    assert len(logging.getLogger("pedcal").handlers) == 1


def test_compare_extrinsics_and_follow_take_objects(small_sim, tmp_path):
    import pandas as pd

    net = pedcal.calibrate(small_sim.calib, method="closedform").network
    report = pedcal.compare_extrinsics(small_sim.eval, {"closedform": net, "truth": small_sim.eval.truth},
                                       tmp_path / "cmp", progress=False)
    text = report.read_text()
    assert "| closedform | `(in memory)` |" in text and "| truth | `(in memory)` |" in text
    # the truth scores 0 mm sensor position error; the calibration does not
    import json

    summary = {r["label"]: r for r in json.loads((tmp_path / "cmp" / "results.json").read_text())["summary"]}
    assert summary["truth"]["sensor_rms_mm"] == pytest.approx(0.0, abs=1e-6)
    assert summary["closedform"]["sensor_rms_mm"] > 1.0

    t = [0.1 * k for k in range(150)]
    people = pd.DataFrame({"t": t + t, "person": ["a"] * 150 + ["b"] * 150,
                           "x": [0.8 * v for v in t] + [6.0 - 0.5 * v for v in t], "y": [0.0] * 150 + [1.5] * 150})
    res = pedcal.follow(None, people_csv=people, target_id="a")
    assert res.metrics.frames > 0 and res.metrics.with_target_fraction > 0.5


def test_progress_bar_on_a_terminal_plain_lines_elsewhere(monkeypatch):
    import io

    from pedcal.progress import ProgressHandler

    class Tty(io.StringIO):
        def isatty(self):
            return True

    log = logging.getLogger("pedcal.test_progress")
    log.propagate = False
    handler = ProgressHandler()
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        for stream, tty in ((Tty(), True), (io.StringIO(), False)):
            monkeypatch.setattr(sys, "stderr", stream)
            for k in range(1, 5):
                log.info(f"step {k}", extra={"progress": (k, 4)})
            log.info("done")
            out = stream.getvalue()
            if tty:      # one line redrawn in place, closed at 4/4, then the plain record
                assert out.count("\r") == 4 and "step 2 [" + "#" * 12 + "." * 12 + "]  50%" in out
                assert out.endswith("step 4 [" + "#" * 24 + "] 100%\ndone\n")
            else:
                assert out == "step 1\nstep 2\nstep 3\nstep 4\ndone\n"
    finally:
        log.removeHandler(handler)
