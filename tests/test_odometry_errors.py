"""Odometry's systematic errors estimated in the factor graph: the corrections of its calibration
(scale, heading drift per metre and per second) are profile nuisances of the graph
(pedcal.calib.graph.motion_block, pedcal.calib.factorgraph), their sigma carried into the
sensors' and written to the calibrated YAML."""

import warnings

import numpy as np
import pytest

from pedcal.calib.factorgraph import calibrate_factorgraph
from pedcal.errors import DegenerateDataWarning
from pedcal.metrics import ODOMETRY_MODEL_KEY, evaluate
from pedcal.sim import simulate_logs


def true_odometry_scale(log, window_s: float = 20.0) -> float:
    """The factor that makes the log's odometry distances true: net displacements over
    ``window_s`` windows of the truth against the odometry's (the odometry's white noise, which
    lengthens its path, averages out over a window)."""
    t = log.truth_robot["t"].to_numpy(float)
    edges = np.arange(t[0], t[-1], window_s)
    net = []
    for table in (log.truth_robot, log.odometry):
        tt = table["t"].to_numpy(float)
        xy = np.column_stack([np.interp(edges, tt, table[c].to_numpy(float)) for c in ("x", "y")])
        net.append(np.linalg.norm(np.diff(xy, axis=0), axis=1))
    return float(np.sum(net[0] * net[1]) / np.sum(net[1] ** 2))


def _rms_xy_mm(sim, result) -> float:
    E = np.array([s.position_error_mm for s in evaluate(sim.eval, result.network).sensors])
    return float(np.sqrt(np.mean(np.sum(E[:, :2] ** 2, axis=1))))


@pytest.fixture(scope="module")
def scaled_odometry():
    """Paper seed 1 with odometry 2 % off in scale and a slowly wandering AMCL, the odometry left
    uncalibrated (odometry_calibrate false): what a calibration against AMCL would remove is left
    to the graph alone."""
    sim = simulate_logs("paper", seed=1, amcl_error="correlated", odom_scale_error=0.02,
                        odom_yaw_drift_deg_per_m=0.0, odom_gyro_bias_dps=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateDataWarning)
        on = calibrate_factorgraph(sim.calib, odometry_calibrate=False)
        off = calibrate_factorgraph(sim.calib, odometry_calibrate=False, estimate_odometry_errors=False)
    return sim, on, off


def test_the_graph_recovers_an_odometry_scale_error_and_states_its_sigma(scaled_odometry):
    sim, on, _ = scaled_odometry
    model = on.network.extra[ODOMETRY_MODEL_KEY]
    truth = true_odometry_scale(sim.calib)
    assert abs(truth - 1.0) > 0.015                      # the log's odometry is 2 % off
    assert 0.0 < model["sigma_scale"] < 0.005
    assert abs(model["scale"] - truth) < 3 * model["sigma_scale"] + 0.001, (model, truth)
    assert model["source"].startswith("calibrated")
    # the drifts were not simulated: their corrections stay within a few of their sigma of 0
    assert abs(model["yaw_drift_deg_per_m"]) < 3 * model["sigma_yaw_drift_deg_per_m"] + 0.05


def test_estimating_odometrys_errors_keeps_a_scaled_odometry_from_distorting_the_network(scaled_odometry):
    # taken as the robot's true motion, a 2 % scale error stretches the trajectory the sensors
    # are fitted to; estimated, the network comes out a third more accurate or better (measured:
    # 15.1 against 27.7 mm)
    sim, on, off = scaled_odometry
    assert _rms_xy_mm(sim, on) < 0.65 * _rms_xy_mm(sim, off), (_rms_xy_mm(sim, on), _rms_xy_mm(sim, off))
