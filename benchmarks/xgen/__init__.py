"""xgen: an independent generator of calibration logs, a held-out exam for pedcal (see README.md)."""

from .generator import FAMILIES, generate

__all__ = ["FAMILIES", "generate"]
