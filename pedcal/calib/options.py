"""Options of each calibration method as a typed dataclass.

``calibrate(log, method=..., options=GridSearchOptions(angle_step_deg=0.05))`` passes them; the
keyword form ``calibrate(log, method="gridsearch", angle_step_deg=0.05)`` is read into the same
dataclass, so a misspelled name is refused before any work with the method's valid names listed
(:class:`PedcalOptionError`, both a PedcalInputError and a TypeError).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from pedcal.errors import PedcalInputError

if TYPE_CHECKING:
    from pedcal.calib.graph import GraphRecipe
    from pedcal.model import SensorNetwork


class PedcalOptionError(PedcalInputError, TypeError):
    """An option a calibration method does not take (or the wrong options type for a method)."""


def _refuse_unknown(method: str, given, valid) -> None:
    unknown = sorted(set(given) - set(valid))
    if unknown:
        raise PedcalOptionError(f"option(s) {', '.join(unknown)} not understood by method '{method}'; "
                                f"its options are {', '.join(sorted(valid))}")


@dataclass
class MethodOptions:
    """Base of the per-method options; ``method`` names the calibration method they belong to.
    A method that passes further keywords on (the association's parameters, recipe fields) keeps
    them in the dict field named by ``rest``, whose valid names ``rest_names()`` gives."""

    method: ClassVar[str] = ""
    rest: ClassVar[str | None] = None

    @classmethod
    def rest_names(cls) -> list[str]:
        return []

    @classmethod
    def names(cls) -> list[str]:
        """Every keyword the method takes (what ``calibrate(..., **options)`` accepts)."""
        own = [f.name for f in dataclasses.fields(cls) if f.name != cls.rest]
        return own + [k for k in cls.rest_names() if k not in own]

    @classmethod
    def from_kwargs(cls, **kwargs: Any):
        """The options from ``calibrate``'s keywords; unknown names raise PedcalOptionError."""
        _refuse_unknown(cls.method, kwargs, cls.names())
        if cls.rest is None:
            return cls(**kwargs)
        own = {f.name for f in dataclasses.fields(cls)} - {cls.rest}
        return cls(**{k: v for k, v in kwargs.items() if k in own},
                   **{cls.rest: {k: v for k, v in kwargs.items() if k not in own}})

    def __post_init__(self) -> None:
        if self.rest is not None:
            _refuse_unknown(self.method, getattr(self, self.rest), self.rest_names())

    def to_kwargs(self) -> dict[str, Any]:
        """Keywords of the method's function (``pedcal.calib.METHODS``)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return out if self.rest is None else {**out.pop(self.rest), **out}


@dataclass
class GridSearchOptions(MethodOptions):
    """Kimoto et al.'s grid search (eqs. 1-9): search ranges about the installed pose and steps."""

    method: ClassVar[str] = "gridsearch"
    is_robot: np.ndarray | None = None     # bool mask over log.observations rows; None: associate
    angle_range_deg: float = 60.0
    angle_step_deg: float = 0.01
    offset_range_m: float = 1.0
    offset_step_m: float = 0.005


@dataclass
class ClosedFormOptions(MethodOptions):
    """Per-sensor Horn/Umeyama fit. ``association``: parameters of the robot association
    (keys of ``pedcal.calib.association.DEFAULT_PARAMS``); as keywords they are given by name."""

    method: ClassVar[str] = "closedform"
    is_robot: np.ndarray | None = None
    latency_s: float | None = None         # tracker latency; None: estimated
    min_pairs: int = 5                      # pedcal.calib.closedform.MIN_PAIRS
    collinear_spread_m: float = 0.1         # pedcal.calib.closedform.COLLINEAR_SPREAD_M
    association: dict[str, Any] = field(default_factory=dict)
    rest: ClassVar[str | None] = "association"

    @classmethod
    def rest_names(cls) -> list[str]:
        from pedcal.calib.association import DEFAULT_PARAMS

        return list(DEFAULT_PARAMS)


@dataclass
class AlternativeOptions(MethodOptions):
    """SNAPCAT-3D style shared observations of people (Glas et al. 2015): gates, rounds, noise and
    priors. Its defaults are ``pedcal.calib.alternative.DEFAULT_PARAMS``."""

    method: ClassVar[str] = "alternative"
    min_overlap_s: float = 2.0          # shortest simultaneous stretch that makes a track match
    max_gap_s: float = 0.5              # never interpolate a track across a longer gap
    max_offset_m: float = 1.5           # round 1: |median world offset| gate (installed errors ~1 m)
    max_spread_m: float = 0.35          # round 1: RMS of the offset about its median
    refined_max_offset_m: float = 0.3   # later rounds: |median world offset| gate
    ambiguity_ratio: float = 0.5        # accept only if score < ratio x best competitor's score
    sample_period_s: float = 0.2        # at most one shared point per track pair per period
    rounds: int = 2                     # match -> solve rounds
    point_sigma_m: float = 0.03         # head point noise of one tracker (isotropic, 1 sigma)
    huber_k: float = 1.345              # Huber threshold, in sigmas
    prior_sigma_position_m: float = 0.5  # weak prior at the installed position (1 sigma, per axis)
    prior_sigma_deg: float = 10.0       # weak prior at the installed orientation (1 sigma, per axis)
    min_path_spread_m: float = 0.1      # below this, a sensor's shared points are (nearly) on a line
    compute_sigma: bool = True          # marginal covariances -> sigma in the calibrated schema


@dataclass
class FactorGraphOptions(MethodOptions):
    """pedcal's factor graph. ``graph``: a recipe name in graphs/, a TOML path or a GraphRecipe;
    ``online``: incremental iSAM2; ``init_network``: the network to start from; the height
    reference of the head point's vertical offset (``sensor_height_sigma_m``: the installed heights
    measured to this sigma; with ``ceiling_height_m``: every sensor at that height); ``recipe``:
    any other GraphRecipe field by name, overriding the recipe (as keywords, given by name)."""

    method: ClassVar[str] = "factorgraph"
    graph: str | Path | GraphRecipe | None = None
    online: bool = False
    is_robot: np.ndarray | None = None
    init_network: SensorNetwork | None = None
    sensor_height_sigma_m: float | None = None
    ceiling_height_m: float | None = None
    recipe: dict[str, Any] = field(default_factory=dict)
    rest: ClassVar[str | None] = "recipe"

    @classmethod
    def rest_names(cls) -> list[str]:
        from pedcal.calib.graph import GraphRecipe

        return [f.name for f in dataclasses.fields(GraphRecipe) if f.name not in ("name", "description")]

    def to_kwargs(self) -> dict[str, Any]:
        out = super().to_kwargs()
        for height in ("sensor_height_sigma_m", "ceiling_height_m"):   # None: the recipe's own
            if out[height] is None:
                del out[height]
        return out


OPTIONS: dict[str, type[MethodOptions]] = {
    cls.method: cls for cls in (FactorGraphOptions, GridSearchOptions, AlternativeOptions, ClosedFormOptions)}


def resolve_options(method: str | None, options: MethodOptions | None, kwargs: dict[str, Any]
                    ) -> tuple[str, MethodOptions]:
    """(method, its options) from ``calibrate``'s arguments: ``options`` or the keywords, not both;
    the method defaults to that of ``options`` (else ``factorgraph``)."""
    if method is None:
        method = options.method if isinstance(options, MethodOptions) else "factorgraph"
    if method not in OPTIONS:
        raise PedcalInputError(f"unknown calibration method '{method}', expected one of {', '.join(OPTIONS)}")
    cls = OPTIONS[method]
    if options is None:
        return method, cls.from_kwargs(**kwargs)
    if not isinstance(options, cls):
        raise PedcalOptionError(f"method '{method}' takes {cls.__name__}, got {type(options).__name__}")
    if kwargs:
        raise PedcalOptionError(f"give the options as {cls.__name__} or as keywords, not both "
                                f"(keywords {', '.join(sorted(kwargs))})")
    return method, options
