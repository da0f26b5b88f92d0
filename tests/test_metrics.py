"""The papers' accuracy figures against hand computations on a tiny log."""

import numpy as np
import pandas as pd
import pytest

from pedcal.metrics import HEAD_MODEL_KEY, HEAD_RADIUS_KEY, LATENCY_KEY, evaluate
from pedcal.model import Log, Meta, SensorExtrinsics, SensorNetwork


def _tiny_log():
    """The robot drives along x at 1 m/s (head top 1.35 m up); two sensors look straight down
    from 3 m, each straight at the one observation it makes, so the head-model correction is
    purely vertical. s1 reports (1.03, 0, 1.30) stamped 1.1 s, s2 (2.0, 0, 1.34) stamped 2.1 s."""
    net = SensorNetwork([SensorExtrinsics("s1", [1.03, 0.0, 3.0], [0.0, 90.0, 0.0]),
                         SensorExtrinsics("s2", [2.0, 0.0, 3.0], [0.0, 90.0, 0.0])])
    t = np.arange(0.0, 3.0001, 0.05)
    truth_robot = pd.DataFrame(dict(t=t, x=t, y=0.0 * t, yaw=0.0 * t))
    robot = truth_robot.assign(cov_xx=1e-4, cov_xy=0.0, cov_xyaw=0.0, cov_yy=1e-4, cov_yyaw=0.0, cov_yawyaw=1e-4)
    obs = pd.DataFrame(dict(t=[1.1, 2.1], sensor=["s1", "s2"], track=["1", "1"], x=[1.03, 2.0], y=[0.0, 0.0],
                            z=[1.30, 1.34]))
    return Log(sensors=net, robot=robot, observations=obs, meta=Meta(np.array([0.0, 0.0, 1.35])), truth=net.copy(),
               truth_robot=truth_robot, truth_observations=pd.DataFrame(dict(row=[0, 1], who=["robot", "robot"])))


def test_head_tracking_rms_by_hand_with_latency_and_head_model():
    log = _tiny_log()
    ext = log.sensors.copy()
    # latency 0.1 s: the heads belong to t = 1.0 and 2.0, where the robot's head top is at
    # (1.0, 0, 1.35) and (2.0, 0, 1.35). Head model: the point is 0.1 m below the top, then
    # 0.05 m toward the sensor (up, here), so the top is the point + 0.05 m up:
    # (1.03, 0, 1.35) and (2.0, 0, 1.39): errors 0.03 and 0.04 m -> RMS sqrt((0.03^2 + 0.04^2)/2)
    ext.extra.update({LATENCY_KEY: 0.1, HEAD_MODEL_KEY: {"vertical_offset_m": -0.1, "ray_shift_m": 0.05}})
    res = evaluate(log, ext)
    assert res.head_tracking_rms_mm == pytest.approx(1000 * np.sqrt((0.03 ** 2 + 0.04 ** 2) / 2), abs=1e-6)
    per = {s.id: s.head_rms_mm for s in res.sensors}
    assert per["s1"] == pytest.approx(30.0, abs=1e-6) and per["s2"] == pytest.approx(40.0, abs=1e-6)
    assert res.head_observations == 2


@pytest.mark.parametrize("extra", [
    {LATENCY_KEY: -0.1, HEAD_MODEL_KEY: {"vertical_offset_m": -0.1, "ray_shift_m": 0.05}},   # latency sign
    {LATENCY_KEY: 0.1, HEAD_MODEL_KEY: {"vertical_offset_m": 0.1, "ray_shift_m": 0.05}},     # offset sign
    {LATENCY_KEY: 0.1, HEAD_MODEL_KEY: {"vertical_offset_m": -0.1, "ray_shift_m": -0.05}},   # shift sign
])
def test_a_flipped_sign_changes_the_head_rms(extra):
    log = _tiny_log()
    ext = log.sensors.copy()
    ext.extra.update(extra)
    assert evaluate(log, ext).head_tracking_rms_mm > 60.0


def test_older_files_head_radius_is_a_dome():
    # head_radius_m r: the point faces the sensor on a dome of radius r (offset -r, shift r); here
    # r = 0.05 moves the top 0.05 m along the ray (down), then 0.05 m up: no change vertically
    log = _tiny_log()
    ext = log.sensors.copy()
    ext.extra.update({LATENCY_KEY: 0.1, HEAD_RADIUS_KEY: 0.05})
    res = evaluate(log, ext)
    assert res.head_tracking_rms_mm == pytest.approx(1000 * np.sqrt((0.03 ** 2 + 0.05 ** 2 + 0.01 ** 2) / 2), abs=1e-6)


def test_sensor_position_rms_by_hand():
    log = _tiny_log()
    ext = log.sensors.copy()
    ext["s1"].position_m = ext["s1"].position_m + [0.003, 0.0, -0.004]
    res = evaluate(log, ext)
    r = res.sensor_position_rms_mm
    assert r.x == pytest.approx(np.sqrt(9 / 2)) and r.z == pytest.approx(np.sqrt(16 / 2)) and r.y == 0.0
    assert r.combined == pytest.approx(np.sqrt(25 / 2))
    assert res.to_dict()["sensor_position_rms_mm"] == {"x": r.x, "y": 0.0, "z": r.z, "combined": r.combined}


def test_horizontal_shift_of_the_head_model_is_undone():
    # a sensor at (2.5, 0, 2.85) looking back along -x, 45 deg down; the tracker reports the head
    # top at t = 2.0, (2.0, 0, 1.35), pulled 4 cm horizontally toward the sensor: (2.04, 0, 1.35)
    net = SensorNetwork([SensorExtrinsics("s3", [2.5, 0.0, 2.85], [180.0, 45.0, 0.0])])
    log = _tiny_log()
    log.sensors, log.truth = net, net.copy()
    log.observations = pd.DataFrame(dict(t=[2.0], sensor=["s3"], track=["1"], x=[2.04], y=[0.0], z=[1.35]))
    log.truth_observations = pd.DataFrame(dict(row=[0], who=["robot"]))
    ext = net.copy()
    ext.extra[HEAD_MODEL_KEY] = {"vertical_offset_m": 0.0, "ray_shift_m": 0.0, "horizontal_shift_m": 0.04}
    assert evaluate(log, ext).head_tracking_rms_mm == pytest.approx(0.0, abs=1e-6)
    ext.extra[HEAD_MODEL_KEY]["horizontal_shift_m"] = 0.0
    assert evaluate(log, ext).head_tracking_rms_mm == pytest.approx(40.0, abs=1e-6)


def test_extrinsics_sensors_the_log_lacks_are_named_not_scored():
    """A sensor of the extrinsics that the log's sensors.yaml lacks (another site's file, a renamed
    sensor) is listed apart, as a log sensor the extrinsics lack is, so neither passes in silence."""
    log = _tiny_log()
    ext = SensorNetwork([log.sensors["s1"], SensorExtrinsics("s9", [5.0, 0.0, 3.0], [0.0, 90.0, 0.0])])
    res = evaluate(log, ext)
    assert res.missing_sensors == ["s2"] and res.foreign_sensors == ["s9"]
    assert res.to_dict()["foreign_sensors"] == ["s9"]
    assert [s.id for s in res.sensors] == ["s1"]          # no row of NaN errors for s9
    assert res.format_table().splitlines()[-2:] == ["not in the extrinsics file (not scored): s2",
                                                     "not in the log's sensors.yaml (not scored): s9"]
    assert evaluate(log, log.sensors.copy()).foreign_sensors == []


def test_evaluate_tests_membership_on_sets_not_by_a_network_look_up_per_sensor(monkeypatch):
    """A network's look-up rebuilds its whole id index on a miss (it cannot tell an absent id from
    one added to the list since): evaluate asked it once per sensor of each side, a rebuild per
    foreign or missing sensor, quadratic over a large file of another site. It now looks up only
    ids it knows are there."""
    log = _tiny_log()
    foreign = [SensorExtrinsics(f"f{i}", [5.0 + i, 0.0, 3.0], [0.0, 90.0, 0.0]) for i in range(50)]
    ext = SensorNetwork([log.sensors["s1"], *foreign])
    misses = []
    find = SensorNetwork._find

    def spy(self, sensor_id):
        found = find(self, sensor_id)
        if found is None:
            misses.append(sensor_id)
        return found

    monkeypatch.setattr(SensorNetwork, "_find", spy)
    res = evaluate(log, ext)
    assert misses == []
    assert res.missing_sensors == ["s2"] and res.foreign_sensors == [f"f{i}" for i in range(50)]
    assert res.sensor_position_rms_mm.combined == 0.0         # s1 alone scored, against its truth


def test_the_table_lists_at_most_ten_sensors_missing_or_foreign_and_says_how_many():
    log = _tiny_log()
    ext = SensorNetwork([log.sensors["s1"], *(SensorExtrinsics(f"f{i}", [5.0 + i, 0.0, 3.0], [0.0, 90.0, 0.0])
                                              for i in range(12))])
    res = evaluate(log, ext)
    assert res.foreign_sensors == [f"f{i}" for i in range(12)]            # the result keeps them all
    assert res.format_table().splitlines()[-1] == ("not in the log's sensors.yaml (not scored): "
                                                   "f0, f1, f2, f3, f4, f5, f6, f7, f8, f9, ... (12 in all)")
    res.missing_sensors = [f"m{i}" for i in range(10)]                  # ten: all shown, no count
    assert res.format_table().splitlines()[-2] == ("not in the extrinsics file (not scored): "
                                                   "m0, m1, m2, m3, m4, m5, m6, m7, m8, m9")
