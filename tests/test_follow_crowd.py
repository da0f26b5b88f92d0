"""The simulated crowd's walkers react to the robot as the episode plays (they step around its
disc); recorded and scripted walkers never do."""

import numpy as np
import pandas as pd
import pytest

from pedcal.sim.follow import (
    FRAME_HZ,
    PERSON_RADIUS_M,
    ROBOT_COMFORT_M,
    ROBOT_RADIUS_M,
    ReactiveCrowd,
    make_episode,
    on_frame_grid,
    people_episode,
    recorded_episode,
    route_walker,
)
from pedcal.track.follow import run_episode

TOUCH_M = ROBOT_RADIUS_M + PERSON_RADIUS_M  # centre distance at which the discs touch (m)


def play_against_standing_robot(robot_xy_m, walker, duration_s):
    """Every frame's reacted position (world, m) of ``walker`` against a robot standing at ``robot_xy_m``."""
    crowd = ReactiveCrowd([walker])
    crowd.reset()
    out = []
    for k in range(int(duration_s * FRAME_HZ) + 1):
        t = k / FRAME_HZ
        crowd.react(t, np.asarray(robot_xy_m, float), np.zeros(2))
        out.append(walker.at(t))
    return np.array(out)


def test_walker_heading_straight_at_a_standing_robot_steps_around_it():
    # the plan walks along y = 0 from x = -4 to x = 4 at 1 m/s, straight through a robot at the origin
    w = on_frame_grid(route_walker("w0", [[-4.0, 0.0], [4.0, 0.0]], 1.0), 12.0)
    plan = w.xy_world_m.copy()
    assert np.min(np.linalg.norm(plan, axis=1)) < 1e-9  # unreacted, it would walk through the robot's centre
    xy = play_against_standing_robot([0.0, 0.0], w, 12.0)
    d = np.linalg.norm(xy, axis=1)
    assert d.min() >= TOUCH_M  # never in contact with the robot's disc
    assert d.min() >= TOUCH_M + 0.1  # and it keeps a comfort margin
    assert np.abs(xy[:, 1]).max() > 0.5  # it went round, sideways
    np.testing.assert_allclose(xy[-1], [4.0, 0.0], atol=0.05)  # and back onto its plan, at its end
    # far from the robot it walks its plan as laid out
    np.testing.assert_allclose(xy[:8], plan[:8])
    # played again, the same (deterministic; the plan restored first)
    np.testing.assert_array_equal(play_against_standing_robot([0.0, 0.0], w, 12.0), xy)


def test_walker_that_would_appear_inside_the_robot_appears_outside_it():
    w = on_frame_grid(route_walker("w0", [[0.1, 0.0], [3.0, 0.0]], 1.0), 4.0)
    xy = play_against_standing_robot([0.0, 0.0], w, 4.0)
    assert np.linalg.norm(xy, axis=1).min() >= TOUCH_M


def test_crowd_episode_people_keep_off_the_robot_and_replay_the_same():
    ep = make_episode("crowd", 0, 1.0)
    assert ep.crowd is not None and ep.walker("target") in ep.crowd.walkers
    a = run_episode(ep, "paper", 0)
    assert a.metrics.min_clearance_m > 0.0 and a.metrics.robot_contacts == 0
    b = run_episode(ep, "paper", 0)  # the same episode object played again
    pd.testing.assert_frame_equal(a.log, b.log)


def positions(ep):
    t = np.arange(0.0, ep.duration_s + 1e-9, 1.0 / FRAME_HZ)
    return [np.array([w.at(ti) if w.at(ti) is not None else (np.nan, np.nan) for ti in t]) for w in ep.walkers]


def test_recorded_walkers_are_unchanged_by_the_robot(shared_data):
    ep = recorded_episode(np.random.default_rng(3), data_dir=shared_data)
    assert ep.crowd is None
    ep.duration_s = 15.0
    before = positions(ep)
    run_episode(ep, "paper", 3)
    for a, b in zip(before, positions(ep), strict=True):
        np.testing.assert_array_equal(a, b)


def test_people_table_and_scripted_walkers_do_not_react():
    t = np.arange(0.0, 10.0, 0.25)
    # a person walks straight through where the robot starts (1.5 m behind the target's start)
    table = pd.concat([pd.DataFrame({"t": t, "person": "a", "x": 1.0 * t, "y": 0.0}),
                       pd.DataFrame({"t": t, "person": "b", "x": 5.0 - 1.0 * t, "y": 0.0})])
    ep = people_episode(table, "a")
    assert ep.crowd is None
    before = positions(ep)
    run_episode(ep, "paper", 0)
    for a, b in zip(before, positions(ep), strict=True):
        np.testing.assert_array_equal(a, b)
    for name in ("passing", "corner", "crossing"):
        assert make_episode(name, 0).crowd is None


KEEP_M = ROBOT_RADIUS_M + PERSON_RADIUS_M + ROBOT_COMFORT_M  # centre distance a reacting walker keeps (m)


def test_walker_at_the_keep_out_distance_walks_on_past_the_robot():
    # walkers start exactly at the keep-out distance of a standing robot (the floating-point boundary,
    # on several sides) and plan to walk 4 m at 1 m/s along its tangent: nothing is in their way, and
    # they walk it all (a "step away" of zero length once froze a walker there for seconds)
    robot = np.array([0.3, 0.1])
    for ang in np.linspace(0.0, 2 * np.pi, 12, endpoint=False):
        n = np.array([np.cos(ang), np.sin(ang)])
        start = robot + KEEP_M * n
        w = on_frame_grid(route_walker("w0", [start, start + 4.0 * np.array([-n[1], n[0]])], 1.0), 4.0)
        xy = play_against_standing_robot(robot, w, 4.0)
        assert np.linalg.norm(xy[-1] - start) == pytest.approx(4.0, abs=0.05), ang
        assert np.linalg.norm(xy - robot, axis=1).min() >= KEEP_M - 1e-9


def test_walker_the_robot_came_too_close_to_restores_the_gap_and_walks_on():
    # the robot stands 0.6 m from a walker (inside the 0.7 m it keeps) who walks past along +x
    crowd_walker = on_frame_grid(route_walker("w0", [[-2.0, 0.6], [2.0, 0.6]], 1.0), 4.0)
    crowd = ReactiveCrowd([crowd_walker])
    crowd.reset()
    i = 8  # t = 2 s: the plan is at (0, 0.6), right beside the robot
    cur = crowd_walker.xy_world_m[i - 1]
    np.testing.assert_allclose(cur, [-0.25, 0.6])
    crowd.react(i / FRAME_HZ, np.array([-0.25, 0.0]), np.zeros(2))
    step = crowd_walker.xy_world_m[i]
    assert np.linalg.norm(step - [-0.25, 0.0]) >= KEEP_M - 1e-9  # the gap restored in one step
    assert step[0] > cur[0] + 0.1  # while walking on along its wish
