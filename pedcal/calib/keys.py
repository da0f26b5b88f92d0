"""The factor graph's variable keys (GTSAM symbols; :mod:`pedcal.calib.graph` describes each):
``S(i)`` sensor i's pose, ``X(k)`` the robot's head frame at pose time k, ``A(j)`` AMCL's error at
node j, ``L(m)`` a person seen by two sensors at once, ``H(0)`` the head point's vertical offset."""

import gtsam
import numpy as np

S = gtsam.symbol_shorthand.S
X = gtsam.symbol_shorthand.X
A = gtsam.symbol_shorthand.A
L = gtsam.symbol_shorthand.L
H = gtsam.symbol_shorthand.H

_INDEX_BITS = 56          # a Symbol: its character in the top byte, its index below


def symbol_parts(keys) -> tuple[np.ndarray, np.ndarray]:
    """(character code, index) of GTSAM Symbol ``keys`` (an array of uint64), as uint64 arrays."""
    keys = np.asarray(keys, np.uint64)
    return keys >> np.uint64(_INDEX_BITS), keys & np.uint64((1 << _INDEX_BITS) - 1)


def symbols(char: str, indices) -> np.ndarray:
    """The GTSAM Symbol keys ``char``(i) of ``indices`` (uint64 array; ``symbols("x", range(n))``
    equals ``[X(k) for k in range(n)]``), made in one pass, not one binding call each."""
    index = np.asarray(indices, np.uint64).reshape(-1)
    return (np.uint64(ord(char)) << np.uint64(_INDEX_BITS)) | index


__all__ = ["S", "X", "A", "L", "H", "symbol_parts", "symbols"]
