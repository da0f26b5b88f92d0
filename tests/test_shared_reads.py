"""What the calibration reads once and hands on (the AMCL head spline, the odometry's sorted table,
each time's head, a column's codes, every row taken as it is) gives, to the bit, what reading it
again where it is used gave."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from pedcal.calib.association import associate_robot
from pedcal.calib.common import head_interpolator, interpolate_pose2, pose2_interpolator, rows_taken
from pedcal.calib.motion import RobotMotion
from pedcal.errors import PedcalInputError
from pedcal.io.logdir import parse_text_column
from pedcal.io.preflight import check_calibration
from pedcal.model import rows_by_code, sensor_codes
from pedcal.sim import simulate_logs


@pytest.fixture(scope="module")
def log():
    return check_calibration(simulate_logs("paper", seed=0).calib)


def test_association_hands_on_the_head_spline_it_read(log):
    assoc = associate_robot(log)
    t = np.random.default_rng(0).uniform(log.robot["t"].min() - 1.0, log.robot["t"].max() + 1.0, 500)
    assert np.array_equal(assoc.head_at(t), head_interpolator(log)(t))


def test_pose2_interpolator_is_interpolate_pose2_and_its_yaw_the_third_column(log):
    track = log.odometry.sample(frac=1.0, random_state=0)          # (unsorted: sorted inside)
    t = np.random.default_rng(1).uniform(track["t"].min() - 2.0, track["t"].max() + 2.0, 300)
    at = pose2_interpolator(track)
    assert np.array_equal(at(t), interpolate_pose2(track, t))
    # (and both what the sorted track interpolates to, its yaw unwrapped: computed here apart)
    ordered = track.sort_values("t")
    tt = ordered["t"].to_numpy(float)
    want = np.column_stack([np.interp(t, tt, ordered["x"].to_numpy(float)),
                            np.interp(t, tt, ordered["y"].to_numpy(float)),
                            np.interp(t, tt, np.unwrap(ordered["yaw"].to_numpy(float)))])
    assert np.array_equal(at(t), want)
    assert np.array_equal(at.yaw(t), want[:, 2])


@pytest.mark.parametrize("odometry", [True, False])
def test_displacement_between_indexed_times_is_the_displacement_between_the_picked_times(log, odometry):
    motion = RobotMotion(log, log.odometry.sort_values("t") if odometry else None)
    rng = np.random.default_rng(2)
    t0, t1 = float(log.robot["t"].min()), float(log.robot["t"].max())
    times = np.sort(rng.uniform(t0, t1, 200))
    grid = np.linspace(t0, t1, 50)
    i, j = rng.integers(0, len(times), 400), rng.integers(0, len(grid), 400)
    # to a second table's times, by index
    assert np.array_equal(motion.displacement(times, grid, from_index=i, to_index=j),
                          motion.displacement(times[i], grid[j]))
    # between rows of one table (each time's head read once)
    k = rng.integers(0, len(times), 400)
    assert np.array_equal(motion.displacement(times, times, from_index=i, to_index=k),
                          motion.displacement(times[i], times[k]))
    assert np.array_equal(motion.displacement(times, times), np.zeros((len(times), 3)))   # (one array: read once)


def test_rows_taken_is_a_slice_only_for_every_row_in_order():
    assert rows_taken(np.arange(5), 5) == slice(None)
    for index in (np.arange(4), np.array([0, 2, 1, 3, 4]), np.array([0, 1, 1, 3, 4]), np.arange(1, 6)):
        out = rows_taken(index, 5)
        assert isinstance(out, np.ndarray) and np.array_equal(out, index)
    mask = np.ones(5, bool)          # (a mask of every row is a mask, not an index)
    assert not isinstance(rows_taken(mask, 5), slice)
    assert isinstance(rows_taken(np.zeros(0, int), 0), np.ndarray)


def test_text_columns_already_text_are_stripped_as_object_columns_are():
    values = [" s1", "s2 ", "s 3", "4"]
    text = parse_text_column(pd.Series(values, dtype=str), None, "sensor")
    obj = parse_text_column(pd.Series(values, dtype=object), None, "sensor")
    assert text.tolist() == obj.tolist() == ["s1", "s2", "s 3", "4"]
    assert text.dtype == obj.dtype
    for bad, row in (([" s1", " ", "s3"], 1), (["s1", "s2", None], 2)):
        with pytest.raises(PedcalInputError, match=f"row {row}.*empty cell"):
            parse_text_column(pd.Series(bad, dtype=str), None, "sensor")


def test_observation_points_by_codes_are_each_sensors_own(log):
    p = log.observation_points_sensor()
    sensor = log.observations["sensor"].to_numpy()
    xyz = log.observations[["x", "y", "z"]].to_numpy(float)
    for s in log.sensors:
        rows = np.flatnonzero(sensor == s.id)
        assert np.array_equal(p[rows], s.to_sensor(xyz[rows]))


def test_sensor_codes_are_the_text_columns_factorization():
    # a number and its text share a code, as they share a text; a missing value is the text 'nan'
    column = pd.Series(["b", 3, "a", np.nan, "3", "b", "a", np.nan, 3], dtype=object)
    codes, names = sensor_codes(column)
    want_codes, want_names = pd.factorize(np.array([str(v) for v in column], dtype=object))
    assert np.array_equal(codes, want_codes)
    assert list(names) == list(want_names) == ["b", "3", "a", "nan"]
    codes, names = sensor_codes(pd.Series(["s2", "s1", "s2"]))
    assert codes.tolist() == [0, 1, 0] and list(names) == ["s2", "s1"]


def test_sensor_codes_keep_apart_the_numbers_whose_texts_differ_in_an_object_column():
    # pandas' factorization merges 1, 1.0 and True (and names them after the first): by their
    # texts they are three sensors, and the text '1' is the number 1's
    column = pd.Series([1, 1.0, "1", True, None, 1.0], dtype=object)
    codes, names = sensor_codes(column)
    want_codes, want_names = pd.factorize(np.array([str(v) for v in column], dtype=object))
    assert np.array_equal(codes, want_codes) and list(names) == list(want_names)
    assert codes.tolist() == [0, 1, 0, 2, 3, 1] and list(names) == ["1", "1.0", "True", "None"]
    assert all(type(n) is str for n in names)


def test_sensor_codes_name_a_string_columns_missing_value_by_its_text():
    # a string column's pd.NA is a sensor named '<NA>' (its text), coded like any other
    column = pd.Series(["s2", pd.NA, "s1", pd.NA, "s2"], dtype="string")
    codes, names = sensor_codes(column)
    assert codes.tolist() == [0, 1, 2, 1, 0] and list(names) == ["s2", "<NA>", "s1"]
    assert list(names) == list(pd.factorize(np.array([str(v) for v in column], dtype=object))[1])


def test_rows_by_code_are_each_codes_rows_in_order():
    codes = np.random.default_rng(2).integers(0, 5, 200)      # sensor_codes gives no negative code
    groups = rows_by_code(codes, 6)
    assert len(groups) == 6
    for code, rows in enumerate(groups):
        assert np.array_equal(rows, np.flatnonzero(codes == code))
    assert len(groups[5]) == 0
    assert rows_by_code(np.zeros(0, np.int64), 2)[1].tolist() == []


def test_association_names_the_first_row_of_an_unknown_sensor(log):
    obs = log.observations.copy()
    obs.loc[[7, 3], "sensor"] = "ghost"
    with pytest.raises(PedcalInputError, match="sensor 'ghost' is not in sensors.yaml") as err:
        associate_robot(dataclasses.replace(log, observations=obs))
    assert err.value.row == 3 and err.value.column == "sensor"
