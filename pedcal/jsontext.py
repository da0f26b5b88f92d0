"""JSON that every reader parses: what pedcal prints or writes with ``--json`` is strict JSON.

Python's ``json`` writes NaN and infinities as bare ``NaN`` / ``Infinity``, which is not JSON
(RFC 8259) and which ``jq``, JavaScript and most other readers refuse; a figure that has no value
(the recall of frames without a person, say) is ``null`` instead. NumPy scalars and arrays and paths
are written as their plain values.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np


def plain(obj):
    """``obj`` with non-finite floats as None, NumPy values as Python ones, paths as strings."""
    if isinstance(obj, dict):
        return {str(k) if isinstance(k, Path) else k: plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def dumps(obj, **kwargs) -> str:
    """``json.dumps`` of ``plain(obj)``; never NaN or Infinity in the text."""
    return json.dumps(plain(obj), allow_nan=False, **kwargs)


__all__ = ["plain", "dumps"]
