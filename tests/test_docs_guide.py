"""docs/guide.md runs: its python blocks and the `pedcal` lines of its sh blocks, in order, in an
empty directory holding the guide's three inputs (a ROS bag, installed extrinsics, a pedestrian
recording) as docs/make_guide_inputs.py writes them, the command the guide gives. Other shell
lines (pip, evo) name tools outside pedcal and are not run. The README's Python block runs too,
in an empty directory."""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import numpy as np

from pedcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide.md"
BLOCK = re.compile(r"^```(python|sh)\n(.*?)^```", re.S | re.M)


def _make_guide_inputs(out_dir: Path) -> list[Path]:
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_guide_inputs", ROOT / "docs" / "make_guide_inputs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_guide_inputs(out_dir)


DEPRECATED_NAME = r".* is deprecated, use .*"      # pedcal.deprecation's message


def test_guide_examples_run(tmp_path, monkeypatch):
    import logging
    import warnings

    levels = {name: logging.getLogger(name).level for name in ("pedcal", "pedcal.calib")}
    try:
        with warnings.catch_warnings():   # the guide uses no deprecated pedcal name
            warnings.filterwarnings("error", message=DEPRECATED_NAME, category=DeprecationWarning)
            _run_guide(tmp_path, monkeypatch)
    finally:                                            # the guide sets logger levels
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _run_guide(tmp_path, monkeypatch):
    text = GUIDE.read_text()
    assert "python REPO/docs/make_guide_inputs.py .\n" in text and "pip install evo\n" in text
    written = _make_guide_inputs(tmp_path)
    assert [p.name for p in written] == ["run.bag", "installed.yaml", "recording.txt"]
    monkeypatch.chdir(tmp_path)
    blocks = BLOCK.findall(text)
    assert [k for k, _ in blocks].count("python") >= 5 and [k for k, _ in blocks].count("sh") >= 5
    namespace: dict = {}
    ran = 0
    for kind, code in blocks:
        if kind == "python":
            exec(compile(code, f"{GUIDE.name} block {ran}", "exec"), namespace)   # noqa: S102
            ran += 1
            continue
        for line in code.splitlines():
            if line.startswith("pedcal "):
                assert main(shlex.split(line)[1:]) == 0, line
                ran += 1
    assert ran >= 15
    # what the examples wrote
    assert (tmp_path / "runs/sparse/compare/report.md").is_file()
    assert (tmp_path / "runs/sparse/tum/head_factorgraph.tum").is_file()
    assert (tmp_path / "runs/bag/observations.csv").is_file() and (tmp_path / "runs/bag/meta.yaml").is_file()
    assert np.isfinite(namespace["imported"].observations[["x", "y", "z"]].to_numpy()).all()
    assert os.path.getsize(tmp_path / "runs/sparse/sensors.urdf") > 0
    assert os.path.getsize(tmp_path / "runs/sparse/graph.png") > 0
    assert namespace["fg"].position_covariance_m2.shape == (3 * len(namespace["fg"].network),) * 2
    assert (tmp_path / "runs/sparse/sensors.launch.py").read_text().count("static_transform_publisher") == 2 * len(
        namespace["fg"].network)                        # --optical: a sensor's frame and its optical frame
    assert abs(namespace["shift_x"][namespace["first"]] - 0.05) < 2e-3


README = ROOT / "README.md"


def test_readme_python_block_runs_in_an_empty_directory(tmp_path, monkeypatch):
    import warnings

    blocks = [code for kind, code in BLOCK.findall(README.read_text()) if kind == "python"]
    assert len(blocks) == 1
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    with warnings.catch_warnings():       # the README uses no deprecated pedcal name
        warnings.filterwarnings("error", message=DEPRECATED_NAME, category=DeprecationWarning)
        exec(compile(blocks[0], "README.md python block", "exec"), namespace)   # noqa: S102
    assert (tmp_path / "runs/paper/eval/observations.csv").is_file()
    assert set(namespace["result"].network.ids) == set(namespace["log"].sensors.ids)
