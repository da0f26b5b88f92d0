"""pedcal.calib.filters: the numpy Gaussian and running-median filters give SciPy's ndimage
numbers to the last digit (the calibration's tracks and AMCL's jump detection must not move when
they stopped importing scipy.ndimage)."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d as scipy_gaussian
from scipy.ndimage import median_filter

import pedcal.calib.filters as filters


@pytest.mark.parametrize("mode", ["nearest", "reflect"])
@pytest.mark.parametrize("n, sigma", [(500, 3.3), (1720, 25.0), (40, 0.2), (5, 7.0)])
def test_gaussian_filter1d_equals_scipys_to_the_last_digit(mode, n, sigma):
    # (5 samples under a kernel of radius 28: the padding wraps the line several times)
    x = np.random.default_rng(n).standard_normal((n, 3)).cumsum(axis=0)
    np.testing.assert_array_equal(filters.gaussian_filter1d(x, sigma, axis=0, mode=mode),
                                  scipy_gaussian(x, sigma, axis=0, mode=mode))
    np.testing.assert_array_equal(filters.gaussian_filter1d(x[:, 1], sigma, mode=mode),
                                  scipy_gaussian(x[:, 1], sigma, mode=mode))


def test_gaussian_filter1d_along_the_second_axis_and_of_a_constant():
    x = np.random.default_rng(3).standard_normal((4, 60))
    np.testing.assert_array_equal(filters.gaussian_filter1d(x, 2.5, axis=1, mode="nearest"),
                                  scipy_gaussian(x, 2.5, axis=1, mode="nearest"))
    flat = filters.gaussian_filter1d(np.full(30, 2.0), 4.0, mode="nearest")
    assert np.allclose(flat, 2.0, rtol=0, atol=1e-14)


@pytest.mark.parametrize("n, size", [(1720, 151), (57, 55), (11, 9), (10, 1)])
def test_running_median_equals_scipys_median_filter_with_ties(n, size):
    rng = np.random.default_rng(size)
    e = 0.05 * rng.standard_normal((n, 2))
    e[rng.random(n) < 0.2] = 0.0                # ties inside the windows
    expected = median_filter(e, size=(size, 1), mode="nearest")
    np.testing.assert_array_equal(filters.running_median(e, size), expected)


def test_running_median_in_chunks_is_the_same(monkeypatch):
    e = np.random.default_rng(7).standard_normal((300, 2))
    whole = filters.running_median(e, 31)
    monkeypatch.setattr(filters, "MEDIAN_CHUNK_ENTRIES", 100)        # 1 row a chunk
    np.testing.assert_array_equal(filters.running_median(e, 31), whole)
    # a step in the data: the median follows it, the window's middle value itself
    step = np.r_[np.zeros(20), np.ones(20)][:, None]
    out = filters.running_median(step, 5)[:, 0]
    np.testing.assert_array_equal(out, step[:, 0])


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="odd"):
        filters.running_median(np.zeros((10, 2)), 4)
    with pytest.raises(ValueError, match="mode"):
        filters.gaussian_filter1d(np.zeros(10), 1.0, mode="wrap")
