"""A tracker whose head point sinks as the head is seen more from the side (the simulator's
``head_sink_m``), which the graph's head model does not hold: how far it moves the sensors.

Seen from one side of its nadir, a sink growing linearly with horizontal distance d, k d, is the
sensor's tilt to first order: turning the sensor by k about its horizontal axis across the view
lowers each point by k d and moves every point by k H horizontally (H the sensor's height above
the head), which the sensor's position takes back. So a tilted sensor moves back along its view by
H k; one looking straight down that sees the robot all around it cannot take the sink as a tilt (it
is even in the offset, a tilt odd) and barely moves. Paired logs: the same seed with and without the
sink, every other draw the same, the nuisances the graph models made small."""

import warnings

import numpy as np
import pytest

from pedcal.calib.factorgraph import calibrate_factorgraph
from pedcal.errors import PedcalInputError
from pedcal.sim import simulate_logs
from pedcal.sim.scenario import load_scenario

SINK_M, RAMP_M = 0.03, 3.0           # a linear sink of 1 cm per metre over the views' distances
SLOPE = SINK_M / RAMP_M
HEAD_Z_M = 1.7                        # the paper's head height (the middle of person_height_m)
QUIET = dict(head_point="top", head_vertical_bias_m=0.0, head_ramp_m=RAMP_M, head_ramp_shape="linear",
             latency_s=0.0, amcl_error="white", amcl_sigma_m=0.003, amcl_sigma_yaw_deg=0.05, duration_s=150.0)


def _moves(seed: int, pitch_deg: float):
    """(the sensors' true extrinsics, each one's position moved by the sink (m, world))."""
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for sink in (0.0, SINK_M):
            sim = simulate_logs("paper", seed=seed, pitch_deg=[pitch_deg], head_sink_m=sink, **QUIET)
            out.append((sim.calib.truth, calibrate_factorgraph(sim.calib).network))
    (truth, plain), (_, sunk) = out
    return truth.sensors, np.array([sunk[s.id].position_m - plain[s.id].position_m for s in truth.sensors])


def test_a_sink_moves_a_tilted_sensor_back_along_its_view_by_its_height_times_the_slope():
    sensors, move = _moves(seed=1, pitch_deg=45.0)
    ratio, across = [], []
    for s, m in zip(sensors, move, strict=True):
        view = np.asarray(s.R_world_sensor)[:2, 0]           # the optical axis, horizontally
        view /= np.linalg.norm(view)
        predicted = (s.position_m[2] - HEAD_Z_M) * SLOPE
        ratio.append(-(m[:2] @ view) / predicted)              # back, away from what it sees
        across.append((m[1] * view[0] - m[0] * view[1]) / predicted)
    ratio, across = np.array(ratio), np.array(across)
    assert np.all((ratio > 0.5) & (ratio < 1.6)), ratio.round(2)
    assert 0.85 < ratio.mean() < 1.25, ratio.round(2)
    assert np.sqrt(np.mean(across ** 2)) < 0.3, across.round(2)


def test_a_sensor_looking_straight_down_at_the_robot_all_around_it_hardly_moves():
    sensors, move = _moves(seed=1, pitch_deg=89.5)
    predicted = np.array([(s.position_m[2] - HEAD_Z_M) * SLOPE for s in sensors])
    horizontal = np.linalg.norm(move[:, :2], axis=1) / predicted
    # (the sensors at the area's ends see the robot from its inside alone: tilted in effect)
    assert np.median(horizontal) < 0.3, horizontal.round(2)
    tilted = _moves(seed=1, pitch_deg=45.0)[1]
    assert np.median(np.linalg.norm(tilted[:, :2], axis=1) / predicted) > 3 * np.median(horizontal)


@pytest.mark.parametrize("sink", [float("nan"), float("inf")])
def test_a_sink_that_is_not_a_finite_number_is_refused(sink):
    with pytest.raises(PedcalInputError, match="column 'head_sink_m': expected a finite number"):
        load_scenario("paper").resolve(head_sink_m=sink)
