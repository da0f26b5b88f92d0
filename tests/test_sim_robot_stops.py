"""The simulated robot's stops (Scenario.robot_stop_s, robot_stop_share): at the chosen waypoints
of its route the follower holds its pose for the stop's duration, then goes on from where it
stood; without stops the route is driven as before, pose for pose; the zoo draws stops for some
seeds from a stream of its own."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import pedcal.sim.nuisances as nuisances
from pedcal.errors import PedcalInputError
from pedcal.sim.nuisances import OFF_FAMILIES, switch_off, vary, zoo_families
from pedcal.sim.robot import drive_route, route_waypoints, stop_waypoints
from pedcal.sim.scenario import Scenario, load_scenario


def _held_runs(poses: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) pose index of each run of poses equal to the one before (speed 0)."""
    held = np.r_[False, np.all(poses[1:] == poses[:-1], axis=1)]
    edges = np.flatnonzero(np.diff(np.r_[0, held.astype(int), 0]))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


@pytest.mark.parametrize("name", ["paper", "cross"])
def test_the_robot_holds_still_at_its_stops_for_their_duration(name):
    """Each stop is one run of 2.5 s x 20 Hz = 50 poses equal to the one before (speed 0, the yaw
    held too), one run per chosen waypoint, in the route's order, each within the pure-pursuit
    lookahead of its waypoint; between them the robot never stands (its speed is at least 5 % of
    the cruise speed)."""
    sc = load_scenario(name).resolve(seed=3, robot_stop_s=2.5, robot_stop_share=0.3)
    wp = route_waypoints(sc)
    stops = stop_waypoints(sc, len(wp))
    assert len(stops) >= 2 and stops.min() >= 1 and stops.max() <= len(wp) - 2
    poses = drive_route(sc)
    runs = _held_runs(poses)
    assert len(runs) == len(stops)
    assert all(b - a + 1 == 50 for a, b in runs)
    held_xy = np.array([poses[a, :2] for a, _ in runs])
    assert np.all(np.linalg.norm(held_xy - wp[stops], axis=1) < sc.lookahead_m)
    moving = np.ones(len(poses) - 1, bool)
    for a, b in runs:
        moving[a - 1:b] = False
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    assert np.all(step[moving] >= 0.05 * sc.robot_speed_mps / sc.truth_rate_hz - 1e-12)


def test_stops_only_insert_holds():
    """The route with stops, its held poses taken out, is the route without stops exactly (the
    follower goes on from where it stood); cut at duration_s, it has as many poses as without."""
    sc = load_scenario("paper").resolve(seed=5, robot_stop_s=4.0, robot_stop_share=0.2)
    with_stops, without = drive_route(sc), drive_route(sc.resolve(robot_stop_s=0.0))
    keep = np.r_[True, ~np.all(with_stops[1:] == with_stops[:-1], axis=1)]
    assert len(with_stops) == len(without) + 4 * 20 * len(stop_waypoints(sc, len(route_waypoints(sc))))
    assert np.array_equal(with_stops[keep], without)
    cut = sc.resolve(duration_s=60.0)
    assert len(drive_route(cut)) == len(drive_route(cut.resolve(robot_stop_share=0.0))) == 60 * 20 + 1


@pytest.mark.parametrize("name, digest", [
    ("paper", "0f55b1fbfd0c0648dccfa6195ba043895cd00df7f12ecb8ddc85b8ce9ca1e464"),
    ("cross", "a2695871aab9c5acf7aa500ae28f93070623c547c07169627b37a02b0030d035")])
def test_without_stops_the_route_is_driven_as_before(name, digest):
    """The defaults (no stops), a stop of 0 s or a share of 0 give the path the follower drove
    before stops existed, pose for pose (its digest, to 1e-9, pinned from then), and no stop."""
    sc = load_scenario(name)
    poses = drive_route(sc)
    assert hashlib.sha256(np.round(poses, 9).tobytes()).hexdigest() == digest
    assert not _held_runs(poses)
    for off in (dict(robot_stop_s=0.0, robot_stop_share=0.5), dict(robot_stop_s=3.0, robot_stop_share=0.0)):
        assert len(stop_waypoints(sc.resolve(**off), 20)) == 0
        assert np.array_equal(drive_route(sc.resolve(**off)), poses)


def test_the_stops_are_drawn_from_a_stream_of_their_own():
    """The same seed stops at the same waypoints, another seed elsewhere; a share of 1 stops at
    every inner waypoint; a route of two waypoints has none to stop at."""
    sc = Scenario(seed=7, robot_stop_s=1.0, robot_stop_share=0.4)
    assert np.array_equal(stop_waypoints(sc, 40), stop_waypoints(sc, 40))
    assert not np.array_equal(stop_waypoints(sc, 40), stop_waypoints(sc.resolve(seed=8), 40))
    assert np.array_equal(stop_waypoints(sc.resolve(robot_stop_share=1.0), 12), np.arange(1, 11))
    assert len(stop_waypoints(sc.resolve(robot_stop_share=1.0), 2)) == 0


def test_stop_fields_are_nuisances_and_checked():
    assert Scenario.nuisances()["robot_stop_s"] == 0.0 and Scenario.nuisances()["robot_stop_share"] == 0.0
    assert Scenario(robot_stop_s=2.0, robot_stop_share=0.2).resolve(noise_free=True).robot_stop_s == 0.0
    for bad in (dict(robot_stop_s=-1.0), dict(robot_stop_share=1.5), dict(robot_stop_share=-0.1),
                dict(robot_stop_s=float("inf"))):
        with pytest.raises(PedcalInputError, match=next(iter(bad))):
            Scenario().resolve(**bad)


def test_the_zoo_draws_seeds_with_and_without_stops(monkeypatch):
    """Over seeds 0-19 the zoo draws both: none, or 1-5 s at 10-30 % of the waypoints; the draw
    changes no other field of any seed (every seed equal to its draw with the stops made none), so
    a seed drawn without stops simulates the log it did before; ``switch_off(.., ["stops"])``
    takes them out."""
    base = load_scenario("cross")
    zoo = [vary(base.resolve(seed=s), zoo=True) for s in range(20)]
    kinds = [zoo_families(z)["robot stops"] for z in zoo]
    # (pinned: the stream's draw for seeds 0-19, the README's "7 of seeds 0-19"; a changed stream
    # constant or coin moves it)
    assert kinds.count("stops") == 7 and set(kinds) == {"none", "stops"}
    for z, kind in zip(zoo, kinds, strict=True):
        if kind == "stops":
            assert 1.0 <= z.robot_stop_s <= 5.0 and 0.1 <= z.robot_stop_share <= 0.3
        else:
            assert (z.robot_stop_s, z.robot_stop_share) == (0.0, 0.0)
    monkeypatch.setattr(nuisances, "_robot_stops", lambda seed: {})
    for s, z in enumerate(zoo):
        assert vary(base.resolve(seed=s), zoo=True) == z.resolve(robot_stop_s=0.0, robot_stop_share=0.0)
    monkeypatch.undo()
    assert "stops" in OFF_FAMILIES
    sc = zoo[kinds.index("stops")]
    off = switch_off(sc, ["stops"])
    assert zoo_families(off)["robot stops"] == "none"
    assert {k for k in vars(sc) if getattr(off, k) != getattr(sc, k)} == {"robot_stop_s", "robot_stop_share"}
    assert _held_runs(drive_route(sc)) and not _held_runs(drive_route(off))


def test_a_stop_that_rounds_to_no_pose_is_no_stop():
    """A stop of 0.02 s at 20 Hz rounds to 0 held poses: no waypoint is chosen, the family says
    "none" and the route is the one without stops; 0.05 s rounds to 1 pose: "stops", each held
    one pose."""
    sc = load_scenario("paper").resolve(seed=3, duration_s=60.0, robot_stop_share=1.0)
    assert sc.truth_rate_hz == 20.0
    short = sc.resolve(robot_stop_s=0.02)
    assert len(stop_waypoints(short, len(route_waypoints(short)))) == 0
    assert zoo_families(short)["robot stops"] == "none"
    poses = drive_route(short)
    assert not _held_runs(poses)
    assert np.array_equal(poses, drive_route(sc.resolve(robot_stop_s=0.0)))
    one = sc.resolve(robot_stop_s=0.05)
    assert zoo_families(one)["robot stops"] == "stops"
    runs = _held_runs(drive_route(one))
    assert runs and all(a == b for a, b in runs)


def test_a_log_cut_before_its_first_stop_is_labelled_without_stops():
    """The family is what the log holds: the paper route cut by duration_s a second before its
    first stop begins holds none ("none", no held pose), cut a second after it began holds it
    ("stops")."""
    sc = load_scenario("paper").resolve(seed=3, duration_s=None, robot_stop_s=2.0, robot_stop_share=1.0)
    runs = _held_runs(drive_route(sc))
    assert runs
    t_first = runs[0][0] / sc.truth_rate_hz            # (pose k at k / truth_rate_hz)
    before = sc.resolve(duration_s=t_first - 1.0)
    after = sc.resolve(duration_s=t_first + 1.0)
    assert len(stop_waypoints(before, len(route_waypoints(before)))) > 0        # drawn all the same
    assert zoo_families(before)["robot stops"] == "none" and not _held_runs(drive_route(before))
    assert zoo_families(after)["robot stops"] == "stops" and _held_runs(drive_route(after))
    assert zoo_families(sc)["robot stops"] == "stops"
