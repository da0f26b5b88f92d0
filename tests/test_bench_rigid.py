"""The nuisance benchmark's diagnostic of a network's own geometry: the horizontal RMS left after
the best common 2-D rigid transform (a turn and a shift) of the estimated network onto the truth."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_factorgraph_nuisances import rigid_residual_rms_mm  # noqa: E402


def _turn(rad: float) -> np.ndarray:
    return np.array([[np.cos(rad), -np.sin(rad)], [np.sin(rad), np.cos(rad)]])


def test_a_turned_and_shifted_copy_of_the_truth_leaves_nothing():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.0, 20.0, (16, 2))
    est = truth @ _turn(0.03).T + np.array([0.10, -0.20])
    assert rigid_residual_rms_mm(est, truth) == pytest.approx(0.0, abs=1e-6)


def test_what_no_rigid_transform_holds_is_left():
    # a 0.4 % stretch along x about the centre: no turn or shift takes it up (the best one is
    # the identity by symmetry), so the RMS left is the stretch's own, pinned
    x = np.linspace(0.0, 19.0, 16)
    truth = np.column_stack([x, np.where(np.arange(16) % 2, 2.3, 0.1)])
    est = truth.copy()
    est[:, 0] = x.mean() + 1.004 * (x - x.mean())
    left = 1000 * 0.004 * np.sqrt(np.mean((x - x.mean()) ** 2))
    assert rigid_residual_rms_mm(est, truth) == pytest.approx(left, rel=1e-3)
    # and a mirror image is not a rigid transform: the fit does not undo it
    mirrored = truth * np.array([-1.0, 1.0])
    assert rigid_residual_rms_mm(mirrored, truth) > 1000.0


def test_fewer_than_two_sensors_give_nan():
    assert np.isnan(rigid_residual_rms_mm(np.zeros((1, 2)), np.zeros((1, 2))))


def test_missed_sensors_are_summed_over_logs_and_unknown_when_not_counted():
    from bench_factorgraph_nuisances import missed_text

    rs = [{"factorgraph": {"missed": 0}, "gridsearch": {"missed": 2}},
          {"factorgraph": {"missed": 1}, "gridsearch": {"missed": 3}}]
    assert (missed_text(rs, "factorgraph"), missed_text(rs, "gridsearch")) == ("1", "5")
    assert missed_text(rs + [{"factorgraph": {}}], "factorgraph") == "?"     # saved before counting
