"""bench_jump_real's recall: the share of a put-in jump's estimates the detector finds, and what
it flags outside, on a track of known content."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_jump_real import recall  # noqa: E402


def test_a_dense_straight_track_gives_every_jump_back_and_nothing_else():
    # 10 Hz along a straight line at 0.5 m/s with 1 cm jitter: a 0.4 m jump held 10 s is found
    # whole in every draw, nothing outside it
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 60.0, 0.1)
    xy = np.column_stack([0.5 * t, np.zeros_like(t)]) + rng.normal(0.0, 0.01, (len(t), 2))
    shares, false, outside, empty = recall(t, xy, 0.4, 10.0, draws=5)
    assert len(shares) == 5 and empty == 0
    assert np.all(shares == 1.0) and false == 0
    assert outside == 5 * (len(t) - 100)        # each jump holds 100 estimates


def test_a_jump_below_the_detectors_floor_is_a_recall_of_zero_not_a_pass():
    # 5 cm, below min_jump_m (0.1 m): never flagged, and the recall says so (0, not left out)
    t = np.arange(0.0, 60.0, 0.1)
    xy = np.column_stack([0.5 * t, np.zeros_like(t)])
    shares, false, _, _ = recall(t, xy, 0.05, 10.0, draws=3)
    assert np.all(shares == 0.0) and false == 0


def test_a_jump_in_a_gap_of_the_track_is_counted_apart_not_a_nan_share():
    # 10 Hz but for a 200 s gap in the middle of 240 s: a 1 s jump lands in the gap in most draws,
    # holds no estimate, and is counted apart; the shares are the other draws' only, all finite
    t = np.r_[np.arange(0.0, 20.0, 0.1), np.arange(220.0, 240.0, 0.1)]
    xy = np.column_stack([0.5 * t, np.zeros_like(t)])
    shares, _, outside, empty = recall(t, xy, 0.4, 1.0, draws=20)
    assert empty > 0 and len(shares) + empty == 20
    assert np.all(np.isfinite(shares))
    assert outside >= empty * len(t)         # a draw in the gap: every estimate is outside
