"""The alternative widths of the considered head-point line that benchmarks/bench_consider_width.py
weighs against the graph's (pedcal.calib.headpoint.considered_rms): the moments it reads agree
with the graph's width, and each alternative has the limits its definition states."""

import sys
from pathlib import Path

import numpy as np
import pytest

from pedcal.calib.headpoint import considered_rms
from pedcal.calib.profile import ProfileStep

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_consider_width import WIDTHS, line_moments, width_of  # noqa: E402


def _step(seed: int, k: int = 4) -> ProfileStep:
    """A profile step with a random information H (k x k, positive definite) and Newton step."""
    rng = np.random.default_rng(seed)
    L = rng.normal(size=(k, k))
    return ProfileStep(dtheta=rng.normal(size=k), hessian=L @ L.T + k * np.eye(k), z0=None, Z=None, cols=None)


@pytest.mark.parametrize("held", [(), (3,)])
def test_the_moments_give_the_graphs_width(held):
    step = _step(0)
    d, v = line_moments(step, 1, held)
    d_free, v_free = line_moments(step, 1)
    # the graph's width is the spread's: the data's second moment and the hold's move of the line
    assert width_of("spread", d, v, d_free, v_free, 0.03) == pytest.approx(considered_rms(step, 1, held=held),
                                                                          rel=1e-12)
    assert width_of("data", d, v, 0.0, 1.0, 0.03) == pytest.approx(np.sqrt(d * d + v), rel=1e-12)
    if held:
        assert considered_rms(step, 1, held=held) > np.sqrt(d * d + v) * (1 + 1e-6)


def test_holding_the_curvature_moves_the_lines_estimate_and_shrinks_its_variance():
    step = _step(1)
    d_held, v_held = line_moments(step, 1, (3,))
    d_free, v_free = line_moments(step, 1)
    cov = np.linalg.inv(step.hessian)
    assert d_free == pytest.approx(step.dtheta[1], rel=1e-12)      # all free: the Newton step itself
    assert v_free == pytest.approx(cov[1, 1], rel=1e-12)
    assert v_held == pytest.approx(cov[1, 1] - cov[1, 3] ** 2 / cov[3, 3], rel=1e-10)
    assert abs(d_held - d_free) > 1e-3


def test_blend_is_the_prior_where_the_data_say_nothing_and_the_datas_where_they_pin_the_line():
    prior = 0.03
    # no information: the posterior is the prior (d 0, v the prior's variance)
    assert width_of("blend", 0.0, prior ** 2, 0.0, prior ** 2, prior) == pytest.approx(prior, rel=1e-12)
    # well informed (v / prior^2 -> 0): the data's second moment
    d, v = 0.012, 1e-10
    assert width_of("blend", d, v, 0.0, v, prior) == pytest.approx(np.sqrt(d * d + v), rel=1e-6)
    # between: exactly (1 - r) (d^2 + v) + r prior^2 under the root
    d, v = 0.01, (0.5 * prior) ** 2
    r = v / prior ** 2
    assert width_of("blend", d, v, 0.0, v, prior) == pytest.approx(
        np.sqrt((1 - r) * (d * d + v) + r * prior ** 2), rel=1e-12)


def test_the_curvature_widths_reduce_to_the_datas_when_its_hold_moves_nothing():
    d, v, prior = 0.008, 0.003 ** 2, 0.03
    for kind in ("free", "max", "spread"):
        assert width_of(kind, d, v, d, v, prior) == pytest.approx(np.sqrt(d * d + v), rel=1e-12)
    # a hold that moves the line from -0.009 to +0.009: spread adds the whole move squared
    assert width_of("spread", 0.009, v, -0.009, v, prior) == pytest.approx(np.sqrt(0.009 ** 2 + v + 0.018 ** 2))
    assert width_of("max", 0.002, v, -0.009, 2 * v, prior) == pytest.approx(np.sqrt(0.009 ** 2 + 2 * v))
    assert width_of("free", 0.002, v, -0.009, 2 * v, prior) == pytest.approx(np.sqrt(0.009 ** 2 + 2 * v))
    # the held moments the larger: max takes them, free would not
    assert width_of("max", 0.009, v, 0.002, 2 * v, prior) == pytest.approx(np.sqrt(0.009 ** 2 + v))
    assert width_of("prior", d, v, d, v, prior) == prior
    assert set(WIDTHS) == {"data", "prior", "blend", "free", "max", "spread"}
