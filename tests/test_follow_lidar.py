"""The simulated LIDAR and the shipped detector in the following loop (``--sensing lidar``)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from pedcal.cli import EXIT_BAD_INPUT, main
from pedcal.errors import PedcalInputError
from pedcal.follow_types import PersonDetection
from pedcal.sim.follow import Episode, Walker, box_map, make_episode, route_walker
from pedcal.sim.follow_lidar import (
    HELD_THRESHOLD,
    HOLD_MAX_GATE_M,
    HOLD_S,
    LidarSensing,
    check_sensing,
    lidar_preset,
    place_clutter,
    points_in_box,
    reflectance_histogram_of,
    walker_samples,
    wall_boxes,
    wall_meshes,
)
from pedcal.sim.scene import SceneObject, box, make_clutter
from pedcal.track.follow import run_episode


def standing(pid: str, xy, duration_s: float = 30.0):
    return route_walker(pid, [xy, xy], 1.0, waits_s=[duration_s, 0.0])


def lone_episode(person_xy, walls=(), extent=(-3.0, -3.0, 8.0, 3.0)) -> Episode:
    people = [] if person_xy is None else [standing("p", person_xy)]
    return Episode("lone", people, "p", np.zeros(3), 10.0, box_map(extent, list(walls)))


def detections_at(sensing: LidarSensing, episode: Episode, t_s: float, pose=(0.0, 0.0, 0.0)):
    frame, vis = sensing.frame(t_s, np.asarray(pose, float), episode.people_at(t_s), None, True)
    return frame, vis


# ------------------------------------------------------------------------------------------ sensing
def test_a_lone_person_two_metres_ahead_is_found_within_0_3_m():
    ep = lone_episode([2.0, 0.0])
    s = LidarSensing(ep, np.random.default_rng(0), clutter_per_10m2=0.0)
    for k in range(4):
        frame, vis = detections_at(s, ep, k / 4)
        assert vis.tolist() == [True]
        assert len(frame.detections) == 1
        d = frame.detections[0]
        assert np.hypot(d.xy_robot_m[0] - 2.0, d.xy_robot_m[1]) <= 0.3
        assert d.score >= 0.5
        assert 1.2 <= d.height_m <= 2.2
        assert d.reflectance_hist.shape == (25,) and d.reflectance_hist.sum() == pytest.approx(1.0)
        # the frame's localization and ESPAR parts are Sensing's
        assert frame.pose_world_robot.shape == (3,) and frame.robot_stopped


def test_the_detection_is_in_the_robot_frame():
    """The robot at (5, 3) facing +y sees a person at (5, 5) 2 m straight ahead (x forward)."""
    ep = lone_episode([5.0, 5.0], extent=(0.0, 0.0, 10.0, 10.0))
    s = LidarSensing(ep, np.random.default_rng(1), clutter_per_10m2=0.0)
    frame, _ = detections_at(s, ep, 0.0, pose=[5.0, 3.0, np.pi / 2])
    assert len(frame.detections) == 1
    xy = frame.detections[0].xy_robot_m
    assert abs(xy[0] - 2.0) <= 0.3 and abs(xy[1]) <= 0.3


def test_a_person_behind_a_wall_is_not_reported():
    wall = (1.0, -2.0, 1.3, 2.0)  # across the robot's view, between it and the person
    seen = LidarSensing(lone_episode([2.5, 0.0]), np.random.default_rng(2), clutter_per_10m2=0.0)
    hidden_ep = lone_episode([2.5, 0.0], walls=[wall])
    hidden = LidarSensing(hidden_ep, np.random.default_rng(2), clutter_per_10m2=0.0)
    frame, _ = detections_at(seen, seen.episode, 0.0)
    assert len(frame.detections) == 1  # found without the wall: the wall is what hides it
    frame, vis = detections_at(hidden, hidden_ep, 0.0)
    assert vis.tolist() == [False]
    assert frame.detections == ()
    assert hidden.frame_stats[-1]["points"] > 1000  # the wall returns points: it is in the scene


def test_an_empty_corridor_gives_at_most_one_false_detection_in_twenty_frames():
    """Walls and clutter (1 object per 10 m^2), nobody: allowance 0.05 false detections per frame
    (the abstract model's clutter rate), over three seeds of 20 frames driving down the corridor."""
    occ = box_map((-2.0, -1.5, 14.0, 1.5), [])
    false, clutter = 0, 0
    for seed in range(3):
        ep = Episode("corridor", [], "target", np.zeros(3), 10.0, occ)
        s = LidarSensing(ep, np.random.default_rng(seed), clutter_per_10m2=1.0)
        clutter += len(s.clutter)
        for k in range(20):
            frame, vis = s.frame(k / 4, np.array([0.4 * k, 0.1 * np.sin(k), 0.05 * np.cos(k)]), [], None, False)
            false += len(frame.detections)
            assert s.frame_stats[-1]["points"] > 1000
    assert clutter >= 6  # the corridor does hold clutter
    assert false <= 3


def test_frames_are_reproducible_from_the_seed():
    ep = make_episode("crossing", 0)
    a, b = (LidarSensing(ep, np.random.default_rng(7)) for _ in range(2))
    for k in (0, 20, 40):
        t = k / 4
        fa, _ = a.frame(t, np.array([0.5, 0.0, 0.0]), ep.people_at(t), None, False)
        fb, _ = b.frame(t, np.array([0.5, 0.0, 0.0]), ep.people_at(t), None, False)
        assert len(fa.detections) == len(fb.detections)
        for da, db in zip(fa.detections, fb.detections, strict=True):
            np.testing.assert_array_equal(da.xy_robot_m, db.xy_robot_m)
            np.testing.assert_array_equal(da.reflectance_hist, db.reflectance_hist)


# ------------------------------------------------------------------------------------------- world
def test_wall_boxes_cover_exactly_the_occupied_cells():
    rng = np.random.default_rng(3)
    occ = box_map((0.0, 0.0, 3.0, 2.0), [(0.5, 0.5, 1.0, 1.5), (2.0, 0.2, 2.2, 0.4)])
    occ.occupied = occ.occupied | (rng.random(occ.shape) < 0.05)  # and scattered cells
    rects = wall_boxes(occ)
    cover = np.zeros(occ.shape, int)
    for c0, c1, r0, r1 in rects:
        cover[r0:r1 + 1, c0:c1 + 1] += 1
    np.testing.assert_array_equal(cover, occ.occupied.astype(int))  # every cell once, none outside
    assert len(rects) < occ.occupied.sum() / 3  # runs merged


def test_wall_boxes_of_an_empty_map_and_the_box_extents():
    occ = box_map((0.0, 0.0, 1.0, 1.0), [])
    occ.occupied[:] = False
    assert wall_boxes(occ).shape == (0, 4) and wall_meshes(occ) == []
    occ.occupied[5, 2:7] = True  # one run of 5 cells (0.25 m) along x
    (centre, mesh), = wall_meshes(occ, height_m=2.0)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose(hi - lo, [0.25, 0.05, 2.0], atol=1e-9)
    np.testing.assert_allclose(centre, occ.cell_to_world(np.array([5, 4])), atol=1e-9)


def test_clutter_keeps_clear_of_every_walker_path():
    ep = make_episode("crowd", 0)
    objs = place_clutter(ep, np.random.default_rng(0), per_10m2=0.5)
    assert objs
    paths = walker_samples(ep.walkers, ep.duration_s)
    for o in objs:
        c = o.collision_circles()
        d = np.linalg.norm(paths[None, :, :] - c[:, None, :2], axis=2).min()
        assert d >= c[:, 2].max() + 0.6 - 1e-9
        assert not ep.occupancy.is_occupied(c[:, :2]).any()


def test_clutter_density_must_be_a_non_negative_number():
    ep = lone_episode(None)
    for bad in (-1.0, float("nan")):
        with pytest.raises(PedcalInputError, match="clutter"):
            place_clutter(ep, np.random.default_rng(0), per_10m2=bad)


def test_points_in_box_and_the_histogram():
    pts = np.array([[1.0, 0.0, 1.0, 0.1],     # inside
                    [1.0, 0.3, 1.0, 0.9],     # beyond the depth (across the yaw = +x width axis)
                    [1.2, 0.0, 1.0, 0.5],     # inside along the width
                    [1.0, 0.0, 0.01, 0.7],    # on the floor
                    [1.0, 0.0, 1.9, 0.7]])    # above the box
    idx = points_in_box(pts, 1.0, 0.0, width=0.5, depth=0.2, yaw=0.0, height=1.5)
    assert idx.tolist() == [0, 2]
    idx = points_in_box(pts, 1.0, 0.0, width=0.5, depth=0.2, yaw=np.pi / 2, height=1.5)  # width along y now
    assert idx.tolist() == [0]
    h = reflectance_histogram_of(np.array([0.0, 0.02, 0.5, 1.0]), n_bins=5)
    np.testing.assert_allclose(h, [0.5, 0.0, 0.25, 0.0, 0.25])
    np.testing.assert_allclose(reflectance_histogram_of(np.array([]), n_bins=4), [0.25] * 4)


# ----------------------------------------------------------------------------------------- episode
def test_run_episode_with_the_lidar_in_the_loop():
    ep = make_episode("passing", 0)
    ep.duration_s = 6.0  # the target stands 1.6 m ahead for 4 s, then walks off
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run_episode(ep, "paper", seed=3, sensing="lidar")
        again = run_episode(ep, "paper", seed=3, sensing="lidar")
    assert res.sensing == "lidar:fx8"
    log = res.log
    assert len(log) == 25
    assert {"lidar_raycast_s", "lidar_detect_s", "lidar_target_detected"} <= set(log.columns)
    assert log["lidar_target_detected"].mean() >= 0.8  # the detector finds the target it sees
    assert (log["n_detections"] >= 1).mean() >= 0.8
    assert res.metrics.with_target_fraction >= 0.8
    for col in ("robot_x", "robot_y", "n_detections", "est_target_x"):
        np.testing.assert_array_equal(log[col].to_numpy(), again.log[col].to_numpy())  # seeded


def test_run_episode_ideal_is_recorded_as_ideal():
    ep = make_episode("passing", 0)
    ep.duration_s = 2.0
    res = run_episode(ep, "paper", seed=0)
    assert res.sensing == "ideal"
    assert not any(c.startswith("lidar_") for c in res.log.columns)


# --------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("sensing, lidar, match", [("camera", None, "--sensing 'camera'"),
                                                    ("lidar", "velodyne", "--lidar 'velodyne'"),
                                                    ("ideal", "fx8", "goes with --sensing lidar")])
def test_check_sensing(sensing, lidar, match):
    with pytest.raises(PedcalInputError, match=match):
        check_sensing(sensing, lidar)


def test_lidar_names_are_presets_or_sensor_names():
    assert lidar_preset("fx8") == "fx8" and lidar_preset("os1-32") == "spin32"
    assert lidar_preset("depth-camera") == "depth_camera"
    check_sensing("lidar", "os1-32")  # no error
    with pytest.raises(PedcalInputError, match="sensor name"):
        lidar_preset("fx9")


def test_walker_samples_follow_the_span():
    """Every 0.25 s of the episode within each walker's span; a scripted walker (``stays``) stands
    at its last position after it, a recorded one is gone."""
    moving = Walker("a", np.array([0.5, 1.5]), np.array([[0.0, 0.0], [2.0, 0.0]]))
    staying = route_walker("b", [[0.0, 1.0], [1.0, 1.0]], 1.0)  # walks 1 s, then stays
    pts = walker_samples([moving, staying], duration_s=2.0)
    np.testing.assert_allclose(pts[:5], [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.5, 0.0], [2.0, 0.0]])
    np.testing.assert_allclose(pts[5:], [[0.0, 1.0], [0.25, 1.0], [0.5, 1.0], [0.75, 1.0]] + [[1.0, 1.0]] * 5)
    assert walker_samples([], 2.0).shape == (0, 2)


@pytest.mark.parametrize("argv, message", [
    (["follow", "--sensing", "camera"], "expected one of ideal, lidar"),
    (["follow", "--sensing", "lidar", "--lidar", "velodyne"], "fx8"),
    (["follow", "--lidar", "fx8"], "goes with --sensing lidar"),
    (["follow-bench", "--sensing", "camera", "--data-dir", "."], "expected one of ideal, lidar"),
    (["follow-bench", "--sensing", "lidar", "--lidar", "velodyne", "--data-dir", "."], "--lidar 'velodyne'"),
])
def test_cli_bad_sensing_exits_2(capsys, argv, message):
    code = main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT
    assert message in err and "Traceback" not in err


def test_frame_stats_count_found_people_and_false_detections(monkeypatch):
    """Two people 2 m ahead, 1.2 m apart: both found, no false detection. With the detector's output
    replaced by one detection on "a" and one 2 m from anybody: one person found, one false."""
    ep = Episode("two", [standing("a", [2.0, 0.6]), standing("b", [2.0, -0.6])], "a", np.zeros(3), 5.0,
                 box_map((-3.0, -3.0, 8.0, 3.0), []))
    s = LidarSensing(ep, np.random.default_rng(4), clutter_per_10m2=0.0)
    s.frame(0.0, np.zeros(3), ep.people_at(0.0), np.array([2.0, 0.6]), True)
    st = s.frame_stats[-1]
    assert (st["detections"], st["people_detected"], st["false_detections"]) == (2, 2, 0)
    assert st["target_detected"] and st["target_range_m"] == pytest.approx(np.hypot(2.0, 0.6))

    def fake(t_s, pose, people, pose_estimate=None):
        s.frame_stats.append({"t_s": t_s})
        return [PersonDetection(np.array([2.1, 0.5]), 1.7, 0.9, np.full(25, 0.04)),
                PersonDetection(np.array([4.0, 0.0]), 1.7, 0.9, np.full(25, 0.04))]
    monkeypatch.setattr(s, "detections", fake)
    frame, _ = s.frame(0.25, np.zeros(3), ep.people_at(0.25), None, True)
    assert len(frame.detections) == 2
    st = s.frame_stats[-1]
    assert (st["people_detected"], st["false_detections"], st["target_detected"]) == (1, 1, False)
    assert np.isnan(st["target_range_m"])


# ------------------------------------------------------------------------------ near range, held tracks
def approach(sensing: LidarSensing, episode: Episode, robot_x_m):
    """Frames with the robot at each of ``robot_x_m`` on the x axis, facing +x; their detections."""
    out = []
    for k, x in enumerate(robot_x_m):
        frame, _ = sensing.frame(k / 4, np.array([x, 0.0, 0.0]), episode.people_at(k / 4), None, False)
        out.append(frame.detections)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_person_the_robot_closes_in_on_is_found_at_0_8_m(seed):
    """A person standing 2 m ahead, the robot closing in to 0.8 m (centre to centre) and standing
    there 2 s: the person is found in every frame at 0.8 m, within 0.3 m of its centre, the
    detections near range held by the person detected before (the classifier alone scores the FX8
    pair's view of the torso low)."""
    ep = Episode("near", [standing("p", [2.0, 0.0])], "p", np.zeros(3), 10.0, None)
    s = LidarSensing(ep, np.random.default_rng(seed), clutter_per_10m2=0.0)
    dets = approach(s, ep, [0.0, 0.4, 0.8, 1.0] + [1.2] * 8)
    assert len(dets[0]) == 1
    for frame_dets in dets[4:]:
        assert len(frame_dets) == 1
        assert np.hypot(frame_dets[0].xy_robot_m[0] - 0.8, frame_dets[0].xy_robot_m[1]) <= 0.3


def test_a_person_first_seen_at_0_8_m_needs_a_track_to_hold_it():
    """With no person detected before, the near-range rule passes nothing on (seed 0: the classifier
    scores the torso below the threshold in every frame); the same frames after the robot closed in
    from 2 m are found, by the rule."""
    ep = Episode("near", [standing("p", [2.0, 0.0])], "p", np.zeros(3), 10.0, None)
    s = LidarSensing(ep, np.random.default_rng(0), clutter_per_10m2=0.0)
    assert [len(d) for d in approach(s, ep, [1.2] * 4)] == [0, 0, 0, 0]
    assert all(st["near_rule"] == 0 for st in s.frame_stats)
    s = LidarSensing(ep, np.random.default_rng(0), clutter_per_10m2=0.0)
    assert [len(d) for d in approach(s, ep, [0.0, 0.4, 0.8, 1.0] + [1.2] * 4)[4:]] == [1, 1, 1, 1]
    assert all(st["near_rule"] == 1 for st in s.frame_stats[4:])


def with_clutter(sensing: LidarSensing, objects) -> None:
    """Replace the sensing's static scene by ``objects`` (SceneObjects placed in the world)."""
    sensing.static_meshes = [o.mesh_scene() for o in objects]
    sensing.static_xy_m = np.array([[o.x_m, o.y_m] for o in objects])
    sensing.static_radius_m = np.array([np.linalg.norm(m.vertices[:, :2] - [o.x_m, o.y_m], axis=1).max()
                                        for o, m in zip(objects, sensing.static_meshes, strict=True)])


def one_box(rng: np.random.Generator, x_m: float, yaw_rad: float) -> SceneObject:
    """A single box 0.4-0.8 m on a side (``make_clutter("box")`` may stack up to three: a stack as
    tall as the field of view at that range is a column the near-range rule passes, see below)."""
    side = float(rng.uniform(0.4, 0.8))
    return SceneObject("box", False, box((0.0, 0.0, side / 2), (side, side, side), 0.5), x_m, 0.0, yaw_rad)


@pytest.mark.parametrize("kind", ["pole", "box", "chair", "trolley"])
def test_clutter_at_0_8_m_is_not_a_person_even_where_one_was_held(kind):
    """A pole, a box, a chair or a trolley 0.8 m ahead, where a person was detected 0.25 s before
    (held): not reported (too thin, or below the field of view's top edge, and scored low)."""
    ep = Episode("empty", [], "p", np.zeros(3), 10.0, None)
    rng = np.random.default_rng(3)
    for trial in range(3):
        s = LidarSensing(ep, np.random.default_rng(trial), clutter_per_10m2=0.0)
        yaw = float(rng.uniform(-np.pi, np.pi))
        with_clutter(s, [one_box(rng, 0.8, yaw) if kind == "box" else make_clutter(kind, rng, x_m=0.8, yaw_rad=yaw)])
        s.held_xy_world_m, s.held_t_s = np.array([[0.8, 0.0]]), np.array([-0.25])
        frame, _ = s.frame(0.0, np.zeros(3), [], None, True)
        assert frame.detections == ()
        assert s.frame_stats[-1]["near_rule"] == 0


def test_held_columns_gate_threshold_and_age(monkeypatch):
    """The pieces of the hold: a weak cluster is passed only within the gate of a fresh held
    detection (HOLD_S, HOLD_MAX_GATE_M) and with a score of at least HELD_THRESHOLD or cut by the
    field of view."""
    from pedcal.detect.detection import Detection

    ep = Episode("empty", [], "p", np.zeros(3), 10.0, None)
    s = LidarSensing(ep, np.random.default_rng(0), clutter_per_10m2=0.0)
    pts = np.zeros((0, 4))

    def det(x, score):
        return Detection(x, 0.0, 1.5, 0.5, 0.3, 0.0, score, score >= 0.5, 100)
    gated = [det(1.0, HELD_THRESHOLD), det(1.0, HELD_THRESHOLD * 0.9), det(3.0, HELD_THRESHOLD), det(1.0, 0.9)]
    boxes = [np.zeros(0, int)] * 4
    s.held_xy_world_m, s.held_t_s = np.array([[1.2, 0.0]]), np.array([0.0])
    assert s.held_columns(0.25, np.zeros(3), pts, gated, boxes) == {0}  # not 1 (score), 2 (gate), 3 (strong)
    s.held_t_s = np.array([-HOLD_S - 0.01])
    assert s.held_columns(0.0, np.zeros(3), pts, gated, boxes) == set()  # too old
    # 1.5 s old: 0.5 + 1.0 x 1.5 = 2 m would hold the cluster 1.1 m away, the gate stops at 1 m
    s.held_xy_world_m, s.held_t_s = np.array([[1.0 - HOLD_MAX_GATE_M - 0.1, 0.0]]), np.array([-1.5])
    assert s.held_columns(0.0, np.zeros(3), pts, gated, boxes) == set()
    # the held detection in the world frame: the robot moved 1 m ahead, the cluster is 1 m nearer
    s.held_xy_world_m, s.held_t_s = np.array([[2.0, 0.0]]), np.array([-0.25])
    assert s.held_columns(0.0, np.array([1.0, 0.0, 0.0]), pts, gated, boxes) == {0}


def test_a_pillar_where_a_person_was_held_is_passed_on_and_alone_is_not():
    """The near-range rule's known confusion: a pillar of a person's width 0.8 m ahead fills the
    field of view as a near person does. Where a person was detected 0.25 s before it is passed on;
    with nobody held it is not (the classifier scores it low)."""
    ep = Episode("empty", [], "p", np.zeros(3), 10.0, None)
    pillar = SceneObject("pillar", False, box((0.0, 0.0, 1.35), (0.4, 0.4, 2.7), 0.5), 0.8, 0.0, np.pi / 4)
    found = []
    for held in (False, True):
        s = LidarSensing(ep, np.random.default_rng(0), clutter_per_10m2=0.0)
        with_clutter(s, [pillar])
        if held:
            s.held_xy_world_m, s.held_t_s = np.array([[0.8, 0.0]]), np.array([-0.25])
        frame, _ = s.frame(0.0, np.zeros(3), [], None, True)
        found.append(len(frame.detections))
    assert found == [0, 1]
