"""The factor graph's variable keys (GTSAM symbols; :mod:`pedcal.calib.graph` describes each):
``S(i)`` sensor i's pose, ``X(k)`` the robot's head frame at pose time k, ``A(j)`` AMCL's error at
node j, ``L(m)`` a person seen by two sensors at once, ``H(0)`` the head point's vertical offset."""

import gtsam

S = gtsam.symbol_shorthand.S
X = gtsam.symbol_shorthand.X
A = gtsam.symbol_shorthand.A
L = gtsam.symbol_shorthand.L
H = gtsam.symbol_shorthand.H

__all__ = ["S", "X", "A", "L", "H"]
