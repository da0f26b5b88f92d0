"""ESPAR simulator and likelihood: quantization, timing, multipath, the fitted model, eq. 10."""

import numpy as np
import pytest

from pedcal.follow_types import EsparReading
from pedcal.sim.espar import EsparParams, EsparSimulator, quantized_directions, reading_times
from pedcal.track.espar import DEFAULT_LIKELIHOOD, EsparLikelihood, fit_espar_likelihood, likelihood, likelihood_grid


def test_noise_free_readings_are_the_nearest_direction_from_each_antenna():
    p = EsparParams(sigma_deg=0.0, multipath_prob=0.0)
    sim = EsparSimulator(p, np.random.default_rng(0))
    # Target at bearing 44 deg from antenna 0 (at y=+0.15) and 46.7 deg from antenna 1 (y=-0.15).
    target = np.array([2.0, 0.15 + 2.0 * np.tan(np.radians(44.0))])
    out = sim.readings(0.0, 1.0, target)
    assert len(out) == 4  # two antennas at 2 Hz over one second
    by_antenna = {r.antenna: r for r in out}
    assert by_antenna[0].direction_index == 1  # 44 deg -> 30 deg
    assert by_antenna[1].direction_index == 2  # 46.7 deg -> 60 deg
    assert by_antenna[1].bearing_robot_rad == pytest.approx(np.radians(60.0))
    np.testing.assert_allclose(by_antenna[1].xy_antenna_robot_m, [0.0, -0.15])
    # Behind the robot the bearing wraps into [-pi, pi).
    back = sim.readings(1.0, 1.5, np.array([-3.0, 0.1]))
    assert {r.direction_index for r in back} == {6}
    assert all(r.bearing_robot_rad == pytest.approx(-np.pi) for r in back)


def test_readings_are_due_once_per_period_and_none_out_of_range():
    p = EsparParams(rate_hz=2.0, max_range_m=5.0)
    t_all = np.concatenate([reading_times(a * 0.1, (a + 1) * 0.1, p, 0) for a in range(30)])
    np.testing.assert_allclose(t_all, [0.5, 1.0, 1.5, 2.0, 2.5, 3.0])  # (t_prev, t] never repeats one
    np.testing.assert_allclose(reading_times(0.0, 1.0, p, 1), [0.25, 0.75])
    sim = EsparSimulator(p, np.random.default_rng(0))
    assert sim.readings(0.0, 10.0, np.array([6.0, 0.0])) == ()
    assert sim.readings(0.0, 10.0, None) == ()


def test_simulator_is_seeded_and_multipath_rate_holds():
    p = EsparParams(sigma_deg=0.0, multipath_prob=0.3)
    k = quantized_directions(np.zeros(20000), p, np.random.default_rng(3))
    k2 = quantized_directions(np.zeros(20000), p, np.random.default_rng(3))
    np.testing.assert_array_equal(k, k2)
    # Wrong readings: multipath draws that did not land on direction 0, 0.3 * 11/12 of them.
    assert np.mean(k != 0) == pytest.approx(0.3 * 11 / 12, abs=0.01)


@pytest.mark.parametrize("sigma_deg, multipath", [(20.0, 0.1), (10.0, 0.2)])
def test_fit_recovers_the_simulators_spread_and_floor(sigma_deg, multipath):
    p = EsparParams(sigma_deg=sigma_deg, multipath_prob=multipath)
    fit = fit_espar_likelihood(p, n=20000, seed=1)
    # The readings' spread is the noise plus the quantization's (uniform over 30 deg: 30 / sqrt(12)).
    spread_deg = np.hypot(sigma_deg, 30.0 / np.sqrt(12.0))
    assert np.degrees(fit.sigma_rad) == pytest.approx(spread_deg, abs=1.0)
    assert fit.floor == pytest.approx(multipath, abs=0.02)


def test_default_likelihood_is_the_fit_to_the_default_simulator():
    fit = fit_espar_likelihood(EsparParams(), n=20000, seed=0)
    assert fit.sigma_rad == pytest.approx(DEFAULT_LIKELIHOOD.sigma_rad, abs=np.radians(0.05))
    assert fit.floor == pytest.approx(DEFAULT_LIKELIHOOD.floor, abs=0.002)


def test_p_direction_is_a_distribution_over_the_readings_and_peaks_at_the_bearing():
    m = EsparLikelihood(np.radians(22.0), 0.1)
    for a in (0.0, 0.3, -2.9):
        k = np.arange(12)
        p = m.p_direction(k * m.spacing_rad - a)
        assert p.sum() == pytest.approx(1.0)
        assert np.argmax(p) == int(np.rint(a / m.spacing_rad)) % 12
        assert p.min() >= 0.1 / 12


def test_eq10_product_over_antennas_and_grid_agrees_with_scalar():
    m = EsparLikelihood(np.radians(22.0), 0.1)
    r0 = EsparReading(0, 1, np.radians(30.0), np.array([0.0, 0.15]))
    r1 = EsparReading(1, 2, np.radians(60.0), np.array([0.0, -0.15]))
    xy = np.array([1.0, 1.5])
    a0 = np.arctan2(xy[1] - 0.15, xy[0])
    a1 = np.arctan2(xy[1] + 0.15, xy[0])
    expected = m.p_direction(np.radians(30.0) - a0) * m.p_direction(np.radians(60.0) - a1)
    assert likelihood([r0, r1], xy, m) == pytest.approx(float(expected))
    grid = np.random.default_rng(0).uniform(-5, 5, (50, 2))
    g = likelihood_grid([r0, r1], grid, m)
    assert g.shape == (50,)
    assert g[7] == pytest.approx(likelihood([r0, r1], grid[7], m))
    np.testing.assert_array_equal(likelihood_grid([], grid, m), np.ones(50))
    assert m.p_lost == pytest.approx(1 / 12)
