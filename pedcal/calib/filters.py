"""The two 1-D filters the calibration smooths tracks and residuals with, in numpy: SciPy's
``scipy.ndimage.gaussian_filter1d`` and a running median (``scipy.ndimage.median_filter`` along
one axis, ``mode="nearest"``), each giving SciPy's numbers to the last digit (the same weights,
the same sums in the same order). ``scipy.ndimage`` costs ~40 ms to import, which every
``pedcal calibrate --method factorgraph`` paid for these two calls alone."""

from __future__ import annotations

import numpy as np

_PAD_MODES = {"nearest": "edge", "reflect": "symmetric"}     # SciPy's mode -> numpy.pad's
MEDIAN_CHUNK_ENTRIES = 1_000_000        # window entries :func:`running_median` copies at once (8 MB)


def gaussian_filter1d(x, sigma: float, axis: int = 0, mode: str = "reflect", truncate: float = 4.0) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter1d(x, sigma, axis=axis, mode=mode, truncate=truncate)``
    (order 0; ``mode`` "reflect" or "nearest"): the normalized Gaussian weights w_j, j = -r..r,
    r = int(truncate sigma + 0.5), and, as SciPy's symmetric correlation sums them, y_i = x_i w_0
    + sum over j = r..1 of (x_i-j + x_i+j) w_j, the line padded by the mode."""
    if mode not in _PAD_MODES:
        raise ValueError(f"mode must be one of {sorted(_PAD_MODES)}, got {mode!r}")
    x = np.moveaxis(np.asarray(x, float), axis, 0)
    r = int(truncate * float(sigma) + 0.5)
    j = np.arange(-r, r + 1)
    phi = np.exp(-0.5 / (float(sigma) * float(sigma)) * j ** 2)
    w = (phi / phi.sum())[::-1]
    n = len(x)
    padded = np.pad(x, [(r, r)] + [(0, 0)] * (x.ndim - 1), mode=_PAD_MODES[mode])
    out = padded[r:r + n] * w[r]
    for k in range(-r, 0):          # (SciPy's order: the outermost pair first)
        out += (padded[r + k:r + k + n] + padded[r - k:r - k + n]) * w[r + k]
    return np.moveaxis(out, 0, axis)


def running_median(x, size: int) -> np.ndarray:
    """The median of each row's window of ``size`` rows (odd) centred on it, each column on its
    own, the ends padded with the first and last rows: ``scipy.ndimage.median_filter(x,
    size=(size, 1, ...), mode="nearest")`` (the window's middle value itself, no mean of two)."""
    x = np.asarray(x, float)
    size = int(size)
    if size < 1 or size % 2 == 0:
        raise ValueError(f"the window must be an odd number of rows, got {size}")
    half = size // 2
    padded = np.pad(x, [(half, half)] + [(0, 0)] * (x.ndim - 1), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, size, axis=0)      # (n, ..., size), a view
    out = np.empty(x.shape)
    # (a chunk of rows' windows copied at a time: all of them are size times the input)
    step = max(1, MEDIAN_CHUNK_ENTRIES // max(size * int(np.prod(x.shape[1:])), 1))
    for lo in range(0, len(x), step):
        out[lo:lo + step] = np.partition(windows[lo:lo + step], half, axis=-1)[..., half]
    return out


__all__ = ["gaussian_filter1d", "running_median"]
