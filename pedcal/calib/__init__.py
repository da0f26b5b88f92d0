"""Calibration of ceiling sensor extrinsics.

``calibrate(log, method=...)`` is the public entry point; each method lives in its own module:

- ``factorgraph``: pedcal's estimator, one GTSAM factor graph (default)
- ``gridsearch``: Kimoto et al.'s decoupled grid search, eqs. 1-9 (baseline and initializer)
- ``alternative``: SNAPCAT-3D style shared observations of people (Glas et al. 2015)
- ``closedform``: per-sensor Horn/Umeyama fit on the robot's observations
"""

from __future__ import annotations

import importlib
from typing import Any

from pedcal.calib.common import CalibrationResult
from pedcal.calib.options import (
    OPTIONS,
    AlternativeOptions,
    ClosedFormOptions,
    FactorGraphOptions,
    GridSearchOptions,
    MethodOptions,
    PedcalOptionError,
    resolve_options,
)
from pedcal.errors import warnings_at_caller
from pedcal.model import Log

METHODS = {
    "factorgraph": ("pedcal.calib.factorgraph", "calibrate_factorgraph"),
    "gridsearch": ("pedcal.calib.gridsearch", "calibrate_gridsearch"),
    "alternative": ("pedcal.calib.alternative", "calibrate_alternative"),
    "closedform": ("pedcal.calib.closedform", "calibrate_closedform"),
}


@warnings_at_caller
def calibrate(log: Log, method: str | None = None, *, options: MethodOptions | None = None,
              progress: bool = False, max_memory_gb: float | None = None, **kwargs: Any) -> CalibrationResult:
    """Calibrate every sensor of ``log`` with ``method``; returns a CalibrationResult whose
    ``network`` is the calibrated schema of LOG_FORMAT.md.

    ``options``: the method's typed options (``pedcal.calib.OPTIONS``): FactorGraphOptions,
    GridSearchOptions, AlternativeOptions or ClosedFormOptions; ``method`` defaults to the one of
    ``options``, else ``factorgraph``. The same options may come as keywords
    (``calibrate(log, method="gridsearch", angle_step_deg=0.05)``); a name the method does not take
    is refused before any work, with the method's names listed (PedcalOptionError: a
    PedcalInputError and a TypeError). By method:

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

    ``progress=True`` logs progress at INFO on the ``pedcal`` logger. ``log`` is validated first
    (pedcal.io.validate) and refused when it would need more than ``max_memory_gb`` (default 4).
    Warnings the calibration raises point at the line that called ``calibrate``."""
    method, opts = resolve_options(method, options, kwargs)
    from pedcal.io.preflight import check_calibration

    log = check_calibration(log, max_memory_gb)   # validated; refused beyond the memory limit
    module, func = METHODS[method]
    return getattr(importlib.import_module(module), func)(log, progress=progress, **opts.to_kwargs())


__all__ = ["calibrate", "CalibrationResult", "METHODS", "OPTIONS", "MethodOptions", "FactorGraphOptions",
           "GridSearchOptions", "AlternativeOptions", "ClosedFormOptions", "PedcalOptionError"]
