"""Calibration of ceiling sensor extrinsics.

``calibrate(log, method=...)`` is the public entry point; each method lives in its own module:

- ``factorgraph``: pedcal's estimator, one GTSAM factor graph (default)
- ``gridsearch``: Kimoto et al.'s decoupled grid search, eqs. 1-9 (baseline and initializer)
- ``alternative``: SNAPCAT-3D style shared observations of people (Glas et al. 2015)
- ``closedform``: per-sensor Horn/Umeyama fit on the robot's observations
"""

from __future__ import annotations

import importlib

from pedcal.calib.common import CalibrationResult
from pedcal.model import Log

METHODS = {
    "factorgraph": ("pedcal.calib.factorgraph", "calibrate_factorgraph"),
    "gridsearch": ("pedcal.calib.gridsearch", "calibrate_gridsearch"),
    "alternative": ("pedcal.calib.alternative", "calibrate_alternative"),
    "closedform": ("pedcal.calib.closedform", "calibrate_closedform"),
}


def calibrate(log: Log, method: str = "factorgraph", *, progress: bool = False, **options) -> CalibrationResult:
    """Calibrate every sensor of ``log`` with ``method``; returns a CalibrationResult whose
    ``network`` is the calibrated schema of LOG_FORMAT.md.

    ``progress=True`` logs progress at INFO on the ``pedcal`` logger. ``options`` by method:

    - ``factorgraph``: ``graph`` (a recipe name in graphs/, a TOML path or a GraphRecipe),
      ``online`` (True: incremental iSAM2), ``is_robot`` (bool mask over ``log.observations``
      rows; None: the association finds the robot), ``init_network`` (a SensorNetwork to start
      from), a height reference for the head point's vertical offset (``sensor_height_sigma_m``:
      the installed heights are measured to this sigma; with ``ceiling_height_m``: every sensor
      at that height), and any GraphRecipe field by name to override the recipe
    - ``gridsearch``: ``is_robot``, ``angle_range_deg`` (60), ``angle_step_deg`` (0.01),
      ``offset_range_m`` (1.0), ``offset_step_m`` (0.005)
    - ``alternative``: the keys of ``pedcal.calib.alternative.DEFAULT_PARAMS`` (gates, rounds,
      noise, priors, ``compute_sigma``)
    - ``closedform``: ``is_robot``, ``latency_s``, ``min_pairs``, ``collinear_spread_m``, and the
      association's parameters (``pedcal.calib.association.DEFAULT_PARAMS``)

    An option a method does not take raises an error naming it. ``log`` is validated first
    (pedcal.io.validate) and refused when it would need more than ``max_memory_gb`` (default 4)."""
    if method not in METHODS:
        raise ValueError(f"unknown calibration method '{method}', expected one of {', '.join(METHODS)}")
    from pedcal.io.preflight import check_calibration
    from pedcal.options import check

    check(**{k: options[k] for k in ("sensor_height_sigma_m", "ceiling_height_m") if k in options})

    log = check_calibration(log, options.pop("max_memory_gb", None))   # validated; refused beyond the memory limit
    module, func = METHODS[method]
    return getattr(importlib.import_module(module), func)(log, progress=progress, **options)


__all__ = ["calibrate", "CalibrationResult", "METHODS"]
