"""pedcal: factor-graph calibration of ceiling depth-sensor networks with a localized robot,
and detection and tracking of a specific person with 3D LIDAR and an ESPAR antenna.

The names below are importable from ``pedcal`` itself; each is loaded on first use, so
``import pedcal`` stays fast (GTSAM, open3d and pandas load only when a function needs them).

Logs and files (docs/LOG_FORMAT.md):
    read_log, write_log, Log, Meta         a log directory <-> a Log in memory
    read_sensors_yaml, write_sensors_yaml  sensors.yaml / calibrated YAML <-> SensorNetwork
    SensorNetwork, SensorExtrinsics        extrinsics (T_world_sensor per sensor)
    read_people_csv, write_people_csv      people trajectories ``t, person, x, y``
    read_pedestrians                       ATC, ETH/UCY, THOR recordings -> people table
    read_bag, import_bag                   ROS 1 / ROS 2 bags (and ``rostopic echo -p`` CSV) -> log tables
    export_extrinsics                      calibrated extrinsics -> ROS static-transform launch, URDF, JSON
    write_tum                              robot and head paths -> TUM trajectory files (for evo)

Estimation and scoring:
    simulate, simulate_logs                seeded simulated logs (to disk / in memory)
    calibrate, CalibrationResult           calibrate a log's sensors (methods: pedcal.calib.METHODS)
    evaluate, EvaluationResult             the papers' accuracy figures of extrinsics on a log
    compare_extrinsics                     report comparing calibrations on one log
    follow, FollowResult                   follow one person (a scenario or a people table) and score it
    detect                                 people in one LIDAR frame (N x 4 points)

Errors: PedcalInputError (bad input; the CLI exits with code 2 on it).

Progress and warnings go through :mod:`logging` under the ``pedcal`` logger (progress at INFO, only
when a function is called with ``progress=True``); route or mute them with
``logging.getLogger("pedcal")``. The command line shows INFO (``-q``: warnings only, ``-v``: debug).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

if TYPE_CHECKING:     # what static tools (mypy, pyright, IDEs) see; at run time __getattr__ loads them
    from pedcal.calib import calibrate as calibrate
    from pedcal.calib.common import CalibrationResult as CalibrationResult
    from pedcal.detect.detection import detect as detect
    from pedcal.errors import PedcalInputError as PedcalInputError
    from pedcal.io.export import export_extrinsics as export_extrinsics
    from pedcal.io.logdir import read_log as read_log
    from pedcal.io.logdir import write_log as write_log
    from pedcal.io.pedestrians import read_pedestrians as read_pedestrians
    from pedcal.io.people import read_people_csv as read_people_csv
    from pedcal.io.people import write_people_csv as write_people_csv
    from pedcal.io.ros import import_bag as import_bag
    from pedcal.io.ros import read_bag as read_bag
    from pedcal.io.sensors_yaml import read_sensors_yaml as read_sensors_yaml
    from pedcal.io.sensors_yaml import write_sensors_yaml as write_sensors_yaml
    from pedcal.io.tum import write_tum as write_tum
    from pedcal.metrics import EvaluationResult as EvaluationResult
    from pedcal.metrics import evaluate as evaluate
    from pedcal.model import Log as Log
    from pedcal.model import Meta as Meta
    from pedcal.model import SensorExtrinsics as SensorExtrinsics
    from pedcal.model import SensorNetwork as SensorNetwork
    from pedcal.report.compare import compare_extrinsics as compare_extrinsics
    from pedcal.sim import simulate as simulate
    from pedcal.sim import simulate_logs as simulate_logs
    from pedcal.track.follow import FollowResult as FollowResult
    from pedcal.track.follow import run_follow as follow

# public name -> (module, attribute); resolved lazily by __getattr__ (PEP 562).
_EXPORTS = {
    "read_log": ("pedcal.io.logdir", "read_log"),
    "write_log": ("pedcal.io.logdir", "write_log"),
    "read_sensors_yaml": ("pedcal.io.sensors_yaml", "read_sensors_yaml"),
    "write_sensors_yaml": ("pedcal.io.sensors_yaml", "write_sensors_yaml"),
    "read_people_csv": ("pedcal.io.people", "read_people_csv"),
    "write_people_csv": ("pedcal.io.people", "write_people_csv"),
    "read_pedestrians": ("pedcal.io.pedestrians", "read_pedestrians"),
    "read_bag": ("pedcal.io.ros", "read_bag"),
    "import_bag": ("pedcal.io.ros", "import_bag"),
    "export_extrinsics": ("pedcal.io.export", "export_extrinsics"),
    "write_tum": ("pedcal.io.tum", "write_tum"),
    "Log": ("pedcal.model", "Log"),
    "Meta": ("pedcal.model", "Meta"),
    "SensorNetwork": ("pedcal.model", "SensorNetwork"),
    "SensorExtrinsics": ("pedcal.model", "SensorExtrinsics"),
    "simulate": ("pedcal.sim", "simulate"),
    "simulate_logs": ("pedcal.sim", "simulate_logs"),
    "calibrate": ("pedcal.calib", "calibrate"),
    "CalibrationResult": ("pedcal.calib.common", "CalibrationResult"),
    "evaluate": ("pedcal.metrics", "evaluate"),
    "EvaluationResult": ("pedcal.metrics", "EvaluationResult"),
    "compare_extrinsics": ("pedcal.report.compare", "compare_extrinsics"),
    "follow": ("pedcal.track.follow", "run_follow"),
    "FollowResult": ("pedcal.track.follow", "FollowResult"),
    "detect": ("pedcal.detect.detection", "detect"),
    "PedcalInputError": ("pedcal.errors", "PedcalInputError"),
}

__all__ = [  # a literal list, so static tools read it (tests/test_typing.py checks it against _EXPORTS)
    "__version__",
    "read_log",
    "write_log",
    "read_sensors_yaml",
    "write_sensors_yaml",
    "read_people_csv",
    "write_people_csv",
    "read_pedestrians",
    "read_bag",
    "import_bag",
    "export_extrinsics",
    "write_tum",
    "Log",
    "Meta",
    "SensorNetwork",
    "SensorExtrinsics",
    "simulate",
    "simulate_logs",
    "calibrate",
    "CalibrationResult",
    "evaluate",
    "EvaluationResult",
    "compare_extrinsics",
    "follow",
    "FollowResult",
    "detect",
    "PedcalInputError",
]


def __getattr__(name: str) -> object:
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'pedcal' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value          # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
