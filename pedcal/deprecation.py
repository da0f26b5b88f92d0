"""Former attribute names kept as deprecated aliases of their new names.

pedcal's Python names follow the calibrated YAML's (``tracker_latency_s``, ``amcl_error_model``,
``odometry_model``, ``position_covariance_m2``). :func:`renamed_fields` keeps the former names of a
dataclass working: reading or setting one, or passing it to the constructor,
warns with a DeprecationWarning pointing at the caller's line.
"""

from __future__ import annotations

import functools
import warnings
from typing import Any


def _warn(cls_name: str, old: str, new: str, stacklevel: int) -> None:
    warnings.warn(f"{cls_name}.{old} is deprecated, use {cls_name}.{new} (the calibrated YAML's name)",
                  DeprecationWarning, stacklevel=stacklevel + 1)


def renamed_fields(**renames: str):
    """Class decorator for a dataclass: ``old=new`` pairs, each former name an alias of its new
    field (a property, and a keyword of the constructor)."""

    def decorate(cls):
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            for old, new in renames.items():
                if old in kwargs:
                    if new in kwargs:
                        raise TypeError(f"{cls.__name__}() got both {old!r} and its new name {new!r}")
                    _warn(cls.__name__, old, new, 2)
                    kwargs[new] = kwargs.pop(old)
            init(self, *args, **kwargs)

        cls.__init__ = __init__
        for old, new in renames.items():
            setattr(cls, old, _alias(cls.__name__, old, new))
        return cls

    return decorate


def _alias(cls_name: str, old: str, new: str) -> property:
    def get(self):
        _warn(cls_name, old, new, 2)
        return getattr(self, new)

    def put(self, value) -> None:
        _warn(cls_name, old, new, 2)
        setattr(self, new, value)

    return property(get, put, doc=f"Deprecated alias of ``{new}``.")
