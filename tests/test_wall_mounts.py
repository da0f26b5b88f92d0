"""Wall-mounted sensors in the simulator: aimed at the floor in front of them, seen by the robot,
and recovered by the factor graph like ceiling ones."""

import warnings

import numpy as np
import pytest

from pedcal.calib import calibrate
from pedcal.calib.common import head_world
from pedcal.errors import PedcalInputError
from pedcal.metrics import evaluate
from pedcal.sim import networks, robot, simulate_logs
from pedcal.sim.ceiling import WALL_MARGIN_M, coverage, mount_draw, reaimed_pitch_deg, wall_mount
from pedcal.sim.scenario import Scenario, load_scenario

MIXED = dict(sensor_height_range_m=[2.6, 4.5])                     # the zoo's mixed-heights family
WALLS = dict(wall_mounted_fraction=1.0 / 3.0, **MIXED)              # ... and its wall family


def test_wall_mount_height_follows_the_aim_and_a_grid_sensor_moves_back_into_the_room():
    sc = Scenario(area_m=[8.2, 4.5], person_height_m=[1.5, 1.9])
    # looking +x from x = 6.8: the aimed-at point (3 m ahead) would be past the far wall, so the
    # sensor moves back until it is 0.5 m inside (x = 8.2 - 0.5 - 3 = 4.7); height 1.7 + 3 tan 20
    xy, z, yaw = wall_mount(sc, np.array([6.8, 1.1]), 0.0, 20.0, 3.0, 1.0)
    np.testing.assert_allclose(xy, [4.7, 1.1], atol=1e-12)
    assert z == pytest.approx(1.7 + 3.0 * np.tan(np.radians(20.0)), abs=1e-12) and yaw == 0.0
    # already aiming inside the room: it stays in its slot; looking -x the same, mirrored
    np.testing.assert_allclose(wall_mount(sc, np.array([0.33, 1.1]), 0.0, 20.0, 3.0, 1.0)[0], [0.33, 1.1])
    np.testing.assert_allclose(wall_mount(sc, np.array([1.4, 3.4]), 180.0, 15.0, 3.0, 1.0)[0], [3.5, 3.4],
                               atol=1e-12)
    # never past the wall behind it, even when the aim is longer than the room
    np.testing.assert_allclose(wall_mount(sc, np.array([6.8, 1.1]), 0.0, 20.0, 9.0, 1.0)[0], [WALL_MARGIN_M, 1.1],
                               atol=1e-12)


def test_wall_mount_in_a_corridor_turns_along_it_and_away_from_its_end():
    sc = load_scenario("corridor")                                # 20 x 2.4 m, sensors 0.1 m from the walls
    half = sc.area_m[1] / 2 - WALL_MARGIN_M
    turn = np.degrees(np.arccos(half / 2.2))
    xy = np.array([10.0, WALL_MARGIN_M])                          # on the y = 0 wall, looking +y
    for sign in (1.0, -1.0):
        out_xy, z, yaw = wall_mount(sc, xy, 90.0, 15.0, 2.2, sign)
        np.testing.assert_allclose(out_xy, xy)
        assert yaw == pytest.approx(90.0 + sign * turn)
        # the optical axis meets head height on the corridor's centre line
        aimed = xy + 2.2 * np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))])
        assert aimed[1] == pytest.approx(sc.area_m[1] / 2)
    # near the corridor's end, turning toward it would aim past the end: it turns the other way
    _, _, yaw = wall_mount(sc, np.array([19.5, WALL_MARGIN_M]), 90.0, 15.0, 2.2, -1.0)
    assert yaw == pytest.approx(90.0 + turn)


def test_a_raised_ceiling_sensor_is_reaimed_at_the_floor_point_of_its_slot():
    sc = Scenario(person_height_m=[1.5, 1.9])
    # at 2.6 m pitched 45 deg the axis meets head height (1.7 m) 0.9 m ahead; at 4.5 m the same
    # point is atan(2.8 / 0.9) down
    assert reaimed_pitch_deg(sc, 2.6, 45.0, 4.5) == pytest.approx(np.degrees(np.arctan2(2.8, 0.9)), abs=1e-9)
    assert reaimed_pitch_deg(sc, 2.6, 45.0, 2.6) == pytest.approx(45.0, abs=1e-9)
    assert reaimed_pitch_deg(sc, 2.6, 45.0, 1.75) == 45.0          # not above head height: left as it is


@pytest.mark.parametrize("scenario", ["paper", "sparse", "corridor", "cross", "lhall"])
@pytest.mark.parametrize("family", ["mixed", "wall"])
def test_every_sensor_of_mixed_heights_and_wall_mounts_sees_the_robots_route(scenario, family):
    # a wall mount hung at ceiling height and pitched 10-25 deg looks over every head, a ceiling
    # sensor raised without re-aiming looks beyond the wall: the robot never enters their view
    # and no calibration can place them
    for seed in range(4):
        sc = load_scenario(scenario).resolve(seed=seed, **(WALLS if family == "wall" else MIXED))
        net, _ = networks(sc)
        if family == "wall":
            assert mount_draw(sc, len(net))[1].sum() >= 1
        heads = head_world(robot.drive_route(sc), sc.head_offset_m)
        seen = coverage(net, sc, heads).sum(axis=1)
        assert np.all(seen >= 100), (scenario, seed, seen)


def test_wall_pitch_and_aim_ranges_are_checked():
    for key, bad in (("wall_pitch_deg", [20.0, 10.0]), ("wall_aim_m", [0.0, 3.0])):
        with pytest.raises(PedcalInputError, match="0 < min <= max") as err:
            Scenario().resolve(**{key: bad})
        assert err.value.column == key


def _errors_mm(sim):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(sim.calib, method="factorgraph")
    ev = evaluate(sim.eval, res.network)
    statuses = [res.network[s.id].status for s in ev.sensors]
    return np.array([s.position_error_mm for s in ev.sensors]), statuses


def test_wall_mounted_sensors_are_recovered_on_a_noise_free_log():
    # only wall mounts and mixed heights: every sensor is calibrated ("ok") and the network's
    # shape (each sensor's horizontal error about the sensors' mean error, which they share with
    # the gauge) is exact within 0.5 mm on every sensor (0.02-0.05 mm measured: the wall mounts
    # and the ceiling ones hung high, which see the robot least, alike)
    sim = simulate_logs("paper", seed=0, noise_free=True, **WALLS)
    wall = mount_draw(sim.scenario, len(sim.calib.truth))[1]
    E, statuses = _errors_mm(sim)
    assert wall.sum() == 3 and statuses == ["ok"] * len(E)
    shape = np.linalg.norm(E[:, :2] - E[:, :2].mean(axis=0), axis=1)
    assert np.all(shape < 0.5), shape


def test_wall_mounted_sensors_calibrate_like_ceiling_ones_with_the_default_nuisances():
    # the default noise: the wall mounts' horizontal errors about the network's mean error within
    # 15 mm and no larger than the worst ceiling sensor's of the same log
    sim = simulate_logs("paper", seed=0, **WALLS)
    wall = mount_draw(sim.scenario, len(sim.calib.truth))[1]
    E, statuses = _errors_mm(sim)
    assert all(statuses[k] == "ok" for k in np.flatnonzero(wall))
    shape = np.linalg.norm(E[:, :2] - E[:, :2].mean(axis=0), axis=1)
    assert np.all(shape[wall] < 15.0) and shape[wall].max() <= shape[~wall].max(), shape
