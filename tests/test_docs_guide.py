"""docs/guide.md runs: its python blocks and the `pedcal` lines of its sh blocks, in order, in an
empty directory holding the guide's three inputs (a ROS bag, installed extrinsics, a pedestrian
recording). Other shell lines (evo) name tools outside pedcal and are not run."""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import numpy as np

from pedcal.cli import main
from pedcal.io import write_sensors_yaml

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "guide.md"
BLOCK = re.compile(r"^```(python|sh)\n(.*?)^```", re.S | re.M)


def _recording(path: Path) -> None:
    """ETH/UCY layout (frame ped_id x y, frames step 10 at 25 fps): three people for 30 s."""
    rows = []
    for frame in range(0, 750, 10):
        s = frame / 25.0
        rows += [(frame, 1, 0.9 * s - 10, 0.0), (frame, 2, 12 - 0.8 * s, 1.5), (frame, 3, 0.5 * s - 8, -2.0)]
    path.write_text("".join(f"{f}\t{p}.0\t{x:.3f}\t{y:.3f}\n" for f, p, x, y in rows))


def test_guide_examples_run(tmp_path, monkeypatch):
    import logging

    from tests.test_ros_import import SENSORS, write_scene_bag

    levels = {name: logging.getLogger(name).level for name in ("pedcal", "pedcal.calib")}
    try:
        _run_guide(tmp_path, monkeypatch, SENSORS, write_scene_bag)
    finally:                                            # the guide sets logger levels
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _run_guide(tmp_path, monkeypatch, SENSORS, write_scene_bag):  # noqa: N803

    write_scene_bag(tmp_path / "run.bag", 1)
    write_sensors_yaml(SENSORS, tmp_path / "installed.yaml")
    _recording(tmp_path / "recording.txt")
    monkeypatch.chdir(tmp_path)
    blocks = BLOCK.findall(GUIDE.read_text())
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
