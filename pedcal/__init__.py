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

__version__ = "0.1.0"

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

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'pedcal' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value          # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
