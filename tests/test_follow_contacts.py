"""People as obstacles: the robot-caused contact figures on scripted logs, and the crowd avoidance
of the simulated robot (it goes round a person standing in its way, yields to one walking at it)."""

import numpy as np
import pandas as pd
import pytest

from pedcal.follow_types import TrackerOutput
from pedcal.sim.follow import FRAME_HZ, PERSON_RADIUS_M, ROBOT_RADIUS_M, RobotController
from pedcal.track.follow import contact_metrics, robot_contact_frames

TOUCH_M = ROBOT_RADIUS_M + PERSON_RADIUS_M


def contact_log(robot_xy, people_xy):
    gap, caused = robot_contact_frames(robot_xy, people_xy)
    return pd.DataFrame({"t": np.arange(len(robot_xy)) / FRAME_HZ, "clearance_m": gap, "robot_contact": caused})


def test_robot_driving_into_a_standing_person_scores_a_contact():
    # 16 frames at 0.2 m per frame along x through a person standing at x = 2; a second person is
    # present only in the first three frames, far away (NaN afterwards)
    robot = np.stack([0.2 * np.arange(16), np.zeros(16)], axis=1)
    people = np.full((16, 2, 2), np.nan)
    people[:, 0] = [2.0, 0.0]
    people[:3, 1] = [0.0, 9.0]
    gap, caused = robot_contact_frames(robot, people)
    # overlapping at x = 1.6 .. 2.4; the robot's step deepened it at 1.6, 1.8 and 2.0 (leaving after)
    assert np.flatnonzero(caused).tolist() == [8, 9, 10]
    np.testing.assert_allclose(gap[[0, 10, 15]], [2.0 - TOUCH_M, -TOUCH_M, 1.0 - TOUCH_M])
    m = contact_metrics(contact_log(robot, people))
    assert m["robot_contacts"] == 1 and m["contact_frame_fraction"] == pytest.approx(3 / 16)
    assert m["contacts_per_min"] == pytest.approx(1 / (16 / FRAME_HZ / 60.0))
    assert m["min_clearance_m"] == pytest.approx(-TOUCH_M)


def test_person_walking_into_a_waiting_robot_is_not_robot_caused():
    robot = np.zeros((12, 2))
    people = np.stack([3.0 - 0.25 * np.arange(12), np.zeros(12)], axis=1)[:, None, :]  # ends at 0.25 m
    gap, caused = robot_contact_frames(robot, people)
    assert not caused.any() and gap.min() == pytest.approx(0.25 - TOUCH_M)
    m = contact_metrics(contact_log(robot, people))
    assert m["robot_contacts"] == 0 and m["contacts_per_min"] == 0.0 and m["contact_frame_fraction"] == 0.0
    assert m["min_clearance_m"] == pytest.approx(0.25 - TOUCH_M)  # they did overlap: it is reported


def test_two_separate_drives_into_people_are_two_contacts_and_nobody_gives_no_clearance():
    caused = np.array([False, True, True, False, False, True, False])
    log = pd.DataFrame({"t": np.arange(7) / FRAME_HZ, "clearance_m": np.nan, "robot_contact": caused})
    m = contact_metrics(log)
    assert m["robot_contacts"] == 2 and m["contact_frame_fraction"] == pytest.approx(3 / 7)
    assert m["min_clearance_m"] is None  # nobody was ever present
    assert contact_metrics(log.drop(columns="robot_contact")) == dict.fromkeys(m)  # no columns: undefined


def drive(ctrl, people_at, goal_xy, n_frames=120, pose0=(0.0, 0.0, 0.0)):
    """The robot driving to ``goal_xy`` (the tracker's goal) among people at ``people_at(t)`` (N, 2)."""
    pose = np.array(pose0, float)
    out = TrackerOutput("Lost", None, None, None, goal_xy_world_m=np.asarray(goal_xy, float))
    dt = 1.0 / FRAME_HZ
    robot, people = [], []
    for k in range(n_frames):
        t = k * dt
        xy = people_at(t)
        robot.append(pose[:2].copy())
        people.append(xy)
        v, w = ctrl.command(pose, out, None, xy, (xy - people_at(t - dt)) / dt)
        pose, _ = ctrl.step(pose, v, w, dt, None)
    return np.array(robot), np.array(people)


def test_robot_goes_round_a_person_standing_in_its_way():
    def standing(t):
        return np.array([[3.0, 0.0]])

    robot, people = drive(RobotController(), standing, (6.0, 0.0))
    _, caused = robot_contact_frames(robot, people)
    assert not caused.any() and np.linalg.norm(robot - [3.0, 0.0], axis=1).min() >= TOUCH_M
    assert np.linalg.norm(robot[-1] - [6.0, 0.0]) <= 0.35  # and still gets there
    # without the avoidance it drives straight through
    robot, people = drive(RobotController(avoid=None), standing, (6.0, 0.0))
    assert robot_contact_frames(robot, people)[1].any()


def test_robot_yields_to_a_person_walking_at_it():
    def head_on(t):
        return np.array([[6.0 - 1.0 * t, 0.05]])  # 1 m/s straight at the robot along its path

    robot, people = drive(RobotController(), head_on, (6.0, 0.0), n_frames=60)
    gap, caused = robot_contact_frames(robot, people)
    assert not caused.any()
    assert np.linalg.norm(robot[-1] - [6.0, 0.0]) <= 0.5
    robot, people = drive(RobotController(avoid=None), head_on, (6.0, 0.0), n_frames=60)
    assert robot_contact_frames(robot, people)[1].any()


def test_following_past_a_bystander_on_the_targets_path_goes_round_and_keeps_the_target():
    from pedcal.track.follow import run_follow

    t = np.arange(0.0, 25.0, 0.25)
    people = pd.concat([pd.DataFrame({"t": t, "person": "a", "x": 0.8 * t, "y": 0.0}),
                        pd.DataFrame({"t": t, "person": "b", "x": 8.0, "y": 0.4})])  # stands by the path
    res = run_follow(people_csv=people, target_id="a", tracker="paper", seed=0)
    m, log = res.metrics, res.log
    assert m.robot_contacts == 0 and m.contact_frame_fraction == 0.0 and not log["robot_contact"].any()
    assert m.min_clearance_m == pytest.approx(log["clearance_m"].min()) and m.min_clearance_m > 0.0
    gap_b = np.hypot(log["robot_x"] - 8.0, log["robot_y"] - 0.4) - TOUCH_M
    assert gap_b.min() > 0.0 and log["robot_x"].iloc[-1] > 10.0  # went round b, and on after the target
    assert m.with_target_fraction >= 0.9


def test_people_are_perceived_where_they_are_relative_to_the_robot():
    from pedcal.sim.follow import Episode, route_walker, to_robot
    from pedcal.track.follow import perceived_people

    walker = route_walker("w", [[2.0, 1.0], [12.0, 1.0]], 1.0)            # 1 m/s along +x from t = 0
    late = route_walker("late", [[0.0, 3.0], [0.0, 9.0]], 1.0, t0_s=5.0)  # appears at t = 5 s
    ep = Episode("e", [walker, late], "w", np.zeros(3), 10.0)
    true, est = np.array([1.0, 0.5, 0.3]), np.array([1.1, 0.45, 0.35])   # localization off by 0.05 rad
    xy, v = perceived_people(ep, 5.0, true, est)
    np.testing.assert_allclose(to_robot(xy, est), to_robot(np.array([[7.0, 1.0], [0.0, 3.0]]), true), atol=1e-12)
    np.testing.assert_allclose(v[0], [np.cos(0.05), np.sin(0.05)], atol=1e-9)  # turned with the pose error
    np.testing.assert_allclose(v[1], [0.0, 0.0])  # just appeared: no velocity yet


def test_following_adds_the_targets_speed_away_from_the_robot():
    # the target 1.5 m ahead (0.3 m beyond the follow distance): the proportional law asks 0.3 m/s;
    # walking away at 0.5 m/s, the target's speed is added (0.8 m/s), so the robot closes in to the
    # follow distance instead of trailing it by 0.5 m; walking toward the robot, nothing is added
    ctrl = RobotController(avoid=None)
    out = TrackerOutput("Tracking", 1, np.array([1.5, 0.0]), None)
    people = np.array([[1.5, 0.0], [0.0, 3.0]])  # the target and a bystander
    pose = np.zeros(3)
    v, w = ctrl.command(pose, out, None, people, np.array([[0.5, 0.0], [0.0, 0.0]]))
    assert v == pytest.approx(0.3 + 0.5) and w == pytest.approx(0.0)
    assert ctrl.command(pose, out, None, people, np.array([[-0.5, 0.0], [0.0, 0.0]]))[0] == pytest.approx(0.3)
    assert ctrl.command(pose, out, None, people, None)[0] == pytest.approx(0.3)  # no velocities: the law alone
    v_fast = ctrl.command(pose, out, None, people, np.array([[1.5, 0.0], [0.0, 0.0]]))[0]
    assert v_fast == pytest.approx(ctrl.v_max_mps)  # capped at the top speed
    # nobody within 0.5 m of the estimate (the target not among the people): the law alone
    assert ctrl.command(pose, out, None, people[1:], np.zeros((1, 2)))[0] == pytest.approx(0.3)


def simulate_follow(ctrl, n_frames=120, velocities=True):
    """The robot following a target walking +x at 0.8 m/s from 1.5 m ahead, nobody else about (its
    velocity given to the controller or not); the robot-to-target distance at the end (m)."""
    pose, dt = np.zeros(3), 1.0 / FRAME_HZ
    for k in range(n_frames):
        target = np.array([1.5 + 0.8 * k * dt, 0.0])
        out = TrackerOutput("Tracking", 1, target, None)
        v, w = ctrl.command(pose, out, None, target[None], np.array([[0.8, 0.0]]) if velocities else None)
        pose, _ = ctrl.step(pose, v, w, dt, None)
    return float(np.linalg.norm(np.array([1.5 + 0.8 * n_frames * dt, 0.0]) - pose[:2]))


def test_robot_settles_at_the_follow_distance_behind_a_walking_target():
    ctrl = RobotController()
    # steady state: k_v (d - 1.2) + 0.8 = 0.8, so d = 1.2 m; the law alone settles at 1.2 + 0.8 / k_v
    assert simulate_follow(ctrl) == pytest.approx(ctrl.follow_distance_m, abs=0.05)
    assert simulate_follow(ctrl, velocities=False) == pytest.approx(ctrl.follow_distance_m + 0.8 / ctrl.k_v, abs=0.05)
