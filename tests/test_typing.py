"""Static types of the public API: pedcal ships py.typed and its lazy re-exports are visible to
type checkers, so a script using pedcal's entry points gets real types (not Any) from mypy,
GTSAM's own for the estimator's objects."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

import pedcal

ROOT = Path(__file__).resolve().parents[1]

# expression -> what mypy must reveal for it
PROBE = {
    "pedcal.calibrate(log, options=GridSearchOptions(angle_step_deg=0.05))": "pedcal.calib.common.CalibrationResult",
    "res.values": "gtsam.gtsam.Values | None",
    "res.graph": "gtsam.gtsam.NonlinearFactorGraph | None",
    "res.marginals()": "gtsam.gtsam.Marginals | None",
    "res.network": "pedcal.model.SensorNetwork",
    "res.reoptimize([])": "pedcal.calib.common.CalibrationResult",
    "res.diagnostics.tracker_latency_s": "float | None",
    "pedcal.evaluate(log, res.network)": "pedcal.metrics.EvaluationResult",
    "pedcal.read_bag('run.bag')": "pedcal.io.ros.BagLog",
    "pedcal.simulate_logs('paper')": "pedcal.sim.SimulationResult",
    "pedcal.follow('crossing')": "pedcal.track.follow.FollowResult",
    "pedcal.read_sensors_yaml('s.yaml')": "pedcal.model.SensorNetwork",
    "pedcal.export_extrinsics(res.network, 'x.launch')": "pathlib.Path",
    "pedcal.PedcalInputError('x')": "pedcal.errors.PedcalInputError",
}


def test_all_is_a_literal_of_every_lazy_export():
    assert set(pedcal.__all__) == {"__version__", *pedcal._EXPORTS}
    assert (ROOT / "pedcal" / "py.typed").is_file()
    text = (ROOT / "pedcal" / "__init__.py").read_text()
    for name, (module, attr) in pedcal._EXPORTS.items():     # each seen by static tools too
        assert f"from {module} import {attr} as {name}\n" in text, name


@pytest.mark.skipif(importlib.util.find_spec("mypy") is None,
                    reason="mypy is not installed (pip install -e '.[dev]' installs it)")
def test_mypy_reveals_real_types_of_the_public_api(tmp_path):
    script = tmp_path / "probe.py"
    lines = ["import pedcal", "from pedcal.calib import GridSearchOptions", "",
             "log = pedcal.read_log('x')",
             "res = pedcal.calibrate(log, options=GridSearchOptions(angle_step_deg=0.05))"]
    lines += [f"reveal_type({expr})" for expr in PROBE]
    script.write_text("\n".join(lines) + "\n")
    # silent: pedcal's own modules are analysed for their types but their errors not reported
    run = subprocess.run([sys.executable, "-m", "mypy", "--follow-imports=silent", "--ignore-missing-imports",
                          "--no-error-summary", "--cache-dir", str(tmp_path / "cache"), str(script)],
                         capture_output=True, text=True, cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": ""})
    revealed = re.findall(r'Revealed type is "(.*)"', run.stdout)
    assert len(revealed) == len(PROBE), run.stdout + run.stderr
    errors = [line for line in run.stdout.splitlines() if ": error:" in line]
    assert not errors, errors
    for (expr, expected), got in zip(PROBE.items(), revealed, strict=True):
        assert "Any" not in got and got == expected, (expr, got)
