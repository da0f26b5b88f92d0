"""Write the three input files docs/guide.md uses into a directory (default: the current one), as a
deployment would have them:

- ``run.bag``: a ROS 1 bag of a robot driving under four ceiling sensors (AMCL, wheel odometry, /tf
  with a head frame, and the sensors' people trackers in four message types), the same scene the
  test suite imports (tests/test_ros_import.py);
- ``installed.yaml``: those sensors' hand-measured extrinsics;
- ``recording.txt``: an ETH/UCY-style pedestrian recording (frame, person, x, y at 25 fps; three
  people for 30 s).

Run from a clone of the repository: ``python docs/make_guide_inputs.py [DIR]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def write_recording(path: Path) -> None:
    """ETH/UCY layout (frame ped_id x y, frames step 10 at 25 fps): three people for 30 s."""
    rows = []
    for frame in range(0, 750, 10):
        s = frame / 25.0
        rows += [(frame, 1, 0.9 * s - 10, 0.0), (frame, 2, 12 - 0.8 * s, 1.5), (frame, 3, 0.5 * s - 8, -2.0)]
    path.write_text("".join(f"{f}\t{p}.0\t{x:.3f}\t{y:.3f}\n" for f, p, x, y in rows))


def make_guide_inputs(out_dir: str | Path = ".") -> list[Path]:
    """Write run.bag, installed.yaml and recording.txt into ``out_dir``; returns their paths."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))        # the bag's scene lives with the tests
    from pedcal.io import write_sensors_yaml
    from tests.test_ros_import import SENSORS, write_scene_bag

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "run.bag", out / "installed.yaml", out / "recording.txt"]
    if paths[0].exists():
        paths[0].unlink()                     # the bag writer does not overwrite
    write_scene_bag(paths[0], 1)
    write_sensors_yaml(SENSORS, paths[1])
    write_recording(paths[2])
    return paths


if __name__ == "__main__":
    for p in make_guide_inputs(sys.argv[1] if len(sys.argv) > 1 else "."):
        print(f"wrote {p}")
