"""Target-existence grid (Sec. 5.3): 10 simulated readings of a static transmitter."""

import numpy as np

from pedcal.sim.espar import EsparParams, EsparSimulator
from pedcal.track.existence_grid import N_READINGS, ExistenceGrid
from pedcal.track.kalman import rot2

POSE = np.array([1.0, 1.0, 0.5])  # the robot, stopped, in the world
TARGET_WORLD = np.array([4.0, 3.0])


def ten_readings(seed: int):
    sim = EsparSimulator(EsparParams(), np.random.default_rng(seed))
    target_robot = rot2(POSE[2]).T @ (TARGET_WORLD - POSE[:2])
    out = sim.readings(0.0, 2.5, target_robot)  # 2 antennas x 2 Hz x 2.5 s
    assert len(out) == N_READINGS
    return out


def bearing_deg(xy_world):
    d = np.asarray(xy_world) - POSE[:2]
    return np.degrees(np.arctan2(d[1], d[0]))


def test_grid_peaks_on_the_targets_bearing_after_10_readings():
    for seed in range(5):
        g = ExistenceGrid(POSE[:2], half_size_m=6.0, cell_m=0.25, max_range_m=6.0)
        g.add(ten_readings(seed), POSE)
        assert g.complete
        # Two antennas 0.3 m apart fix a bearing, not a range: the best cell lies within
        # 15 deg (half a direction) of the target's bearing from the robot.
        err = abs((bearing_deg(g.best_xy_world_m()) - bearing_deg(TARGET_WORLD) + 180) % 360 - 180)
        assert err < 15.0, (seed, err)
        assert abs(g.probabilities().sum() - 1.0) < 1e-9


def test_grid_with_the_last_position_prior_peaks_near_the_target():
    for seed in range(5):
        # Last seen 1 m from where the target now stands; prior sigma 1.5 m.
        g = ExistenceGrid(POSE[:2], half_size_m=6.0, cell_m=0.25,
                          prior_xy_world_m=TARGET_WORLD + [0.0, 1.0], prior_sigma_m=1.5)
        g.add(ten_readings(seed), POSE)
        assert np.linalg.norm(g.best_xy_world_m() - TARGET_WORLD) < 1.0, seed


def test_empty_grid_is_its_prior_and_far_cells_are_excluded():
    g = ExistenceGrid(np.zeros(2), half_size_m=4.0, cell_m=0.5, max_range_m=3.0,
                      prior_xy_world_m=np.array([1.25, -0.75]), prior_sigma_m=1.0)
    np.testing.assert_allclose(g.best_xy_world_m(), [1.25, -0.75])
    p = g.probabilities()
    assert p.shape == (16, 16)
    far = np.linalg.norm(g.xy_world_m, axis=1) > 3.0
    assert np.all(p.ravel()[far] == 0.0)
