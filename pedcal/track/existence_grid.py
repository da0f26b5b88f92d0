"""Target-existence grid map (Misu and Miura, Sec. 5.3), accumulated while the robot stands still.

A square grid in the WORLD frame around the robot. Each ESPAR reading multiplies every cell by the
antenna likelihood P(Z | A_cell) of the cell's bearing from that antenna (eq. 10, via
:mod:`pedcal.track.espar`); after ``n_readings`` (the paper's 10) the best cell is where the robot
goes to look. The antennas sit 0.3 m apart, so the readings fix a bearing, not a range; the
optional prior (a Gaussian around the target's last estimate whose sigma grows with the time it
has been out of sight at walking speed) is what picks a place along that bearing. Cells beyond
``max_range_m`` of the robot start at zero. Log-probabilities, so products of many readings never
underflow.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pedcal.follow_types import EsparReading
from pedcal.track.espar import DEFAULT_LIKELIHOOD, EsparLikelihood
from pedcal.track.kalman import rot2

N_READINGS = 10


class ExistenceGrid:
    """Log-belief over cells of ``cell_m`` in a square of half-side ``half_size_m`` around
    ``center_xy_world_m``."""

    def __init__(self, center_xy_world_m: np.ndarray, half_size_m: float = 8.0, cell_m: float = 0.25,
                 model: EsparLikelihood = DEFAULT_LIKELIHOOD, max_range_m: float | None = None,
                 prior_xy_world_m: np.ndarray | None = None, prior_sigma_m: float | None = None):
        c = np.asarray(center_xy_world_m, dtype=float)[:2]
        ticks = np.arange(-half_size_m + 0.5 * cell_m, half_size_m, cell_m)
        gx, gy = np.meshgrid(c[0] + ticks, c[1] + ticks, indexing="xy")
        self.shape = gx.shape
        self.xy_world_m = np.column_stack([gx.ravel(), gy.ravel()])  # (N, 2) cell centres
        self.model = model
        self.log_belief = np.zeros(len(self.xy_world_m))
        if max_range_m is not None:
            far = np.linalg.norm(self.xy_world_m - c, axis=1) > max_range_m
            self.log_belief[far] = -np.inf
        if prior_xy_world_m is not None and prior_sigma_m is not None:
            d2 = np.sum((self.xy_world_m - np.asarray(prior_xy_world_m, dtype=float)[:2]) ** 2, axis=1)
            self.log_belief += -0.5 * d2 / prior_sigma_m ** 2
        self.n_readings = 0

    def add(self, readings: Sequence[EsparReading], pose_world_robot: np.ndarray) -> None:
        """Multiply every cell by P(Z | A_cell) of each reading, the robot at ``pose_world_robot``."""
        if len(readings) == 0:
            return
        pose = np.asarray(pose_world_robot, dtype=float)
        xy_robot = (self.xy_world_m - pose[:2]) @ rot2(pose[2])  # R^T (p - t) row-wise
        for r in readings:
            self.log_belief += np.log(self.model.p_direction(
                r.bearing_robot_rad - np.arctan2(xy_robot[:, 1] - r.xy_antenna_robot_m[1],
                                                 xy_robot[:, 0] - r.xy_antenna_robot_m[0])))
        self.n_readings += len(readings)

    @property
    def complete(self) -> bool:
        return self.n_readings >= N_READINGS

    def probabilities(self) -> np.ndarray:
        """(rows, cols) normalized belief."""
        lb = self.log_belief - np.max(self.log_belief)
        p = np.exp(lb)
        return (p / p.sum()).reshape(self.shape)

    def best_xy_world_m(self) -> np.ndarray:
        """Centre of the most probable cell."""
        return self.xy_world_m[int(np.argmax(self.log_belief))].copy()


__all__ = ["ExistenceGrid", "N_READINGS"]
