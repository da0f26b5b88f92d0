"""Raycast LIDAR simulator: geometry, frames, intensity, ground truth and seeded scenes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from pedcal.errors import PedcalInputError
from pedcal.sim.lidar import LIDAR_PRESETS, LidarModel, Mount, fx8_pair_mounts, render
from pedcal.sim.scene import (
    CLUTTER_KINDS,
    FLOOR_ID,
    PERSON_POSES,
    Mesh,
    Scene,
    SceneObject,
    box,
    cylinder,
    make_clutter,
    make_person,
    person_mesh,
    pram_in_front,
    push_reach_m,
    random_scene,
)

FX8 = LIDAR_PRESETS["fx8"]
NOISELESS = dict(range_noise_std_m=0.0, intensity_noise_std=0.0, dropout_prob=0.0)


def _wall(x_face_m: float, reflectance: float, thickness_m: float = 0.12) -> SceneObject:
    """A 20 m wall across the view whose front face is the plane x = x_face_m."""
    mesh = box((0.0, 0.0, 1.5), (20.0, thickness_m, 3.0), reflectance)
    return SceneObject(kind="wall", is_person=False, mesh_local=mesh, x_m=x_face_m + thickness_m / 2,
                       y_m=0.0, yaw_rad=np.pi / 2, length_m=20.0, radius_m=thickness_m / 2,
                       reflectance=reflectance)


def _sensor_frame(points_base: np.ndarray, mount: Mount) -> np.ndarray:
    return (points_base - mount.position_base) @ mount.R_base_sensor


def test_render_is_deterministic_by_seed():
    scene = random_scene(np.random.default_rng(7))
    a = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(1))
    b = render(random_scene(np.random.default_rng(7)), FX8, fx8_pair_mounts(), np.random.default_rng(1))
    c = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(2))
    assert a.points.dtype == np.float32 and a.points.shape[1] == 4 and len(a.points) > 1000
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.object_id, b.object_id)
    assert a.objects == b.objects
    assert len(a.points) != len(c.points) or not np.array_equal(a.points, c.points)


@pytest.mark.parametrize("preset", sorted(LIDAR_PRESETS))
def test_points_within_range_and_field_of_view(preset):
    lidar = LIDAR_PRESETS[preset].with_(**NOISELESS)
    mounts = fx8_pair_mounts() if lidar.fov_horizontal_deg < 360 else (Mount(0.0, 0.0, 1.2),)
    scene = random_scene(np.random.default_rng(11), n_people=4, n_clutter=8, ceiling_height_m=2.8)
    frame = render(scene, lidar, mounts, np.random.default_rng(0))
    assert len(frame.points) > 500
    for k, mount in enumerate(mounts):
        p_sensor = _sensor_frame(frame.xyz[frame.mount_index == k].astype(float), mount)
        r = np.linalg.norm(p_sensor, axis=1)
        assert r.min() >= lidar.min_range_m - 1e-4 and r.max() <= lidar.max_range_m + 1e-4
        az = np.degrees(np.arctan2(p_sensor[:, 1], p_sensor[:, 0]))
        el = np.degrees(np.arcsin(p_sensor[:, 2] / r))
        assert np.abs(az).max() <= lidar.fov_horizontal_deg / 2 + 0.01
        assert np.abs(el - lidar.vertical_center_deg).max() <= lidar.fov_vertical_deg / 2 + 0.01


def test_wall_at_3m_gives_points_at_x3_over_the_field_of_view():
    scene = Scene([_wall(3.0, 0.6)])
    mount = Mount(0.0, 0.0, 1.0)
    frame = render(scene, FX8, mount, np.random.default_rng(0))
    wall = frame.object_id == 0
    # Floor hits start at 1.0 m / tan(25 deg) = 2.14 m: the lower rows see the floor, not the wall.
    assert wall.sum() > 0.6 * FX8.n_rays
    assert set(np.unique(frame.object_id)) == {0, FLOOR_ID}
    x = frame.xyz[wall, 0]
    # Uniform +-sqrt(3)*30 mm along rays that are within 39 deg of the wall's normal.
    assert np.abs(x - 3.0).max() < 0.053
    assert abs(float(np.mean(x)) - 3.0) < 0.005
    az = np.degrees(np.arctan2(frame.xyz[wall, 1], frame.xyz[wall, 0]))
    assert az.min() == pytest.approx(-30.0, abs=0.5) and az.max() == pytest.approx(30.0, abs=0.5)
    el = np.degrees(np.arctan2(frame.xyz[wall, 2] - 1.0, np.hypot(frame.xyz[wall, 0], frame.xyz[wall, 1])))
    assert el.max() == pytest.approx(25.0, abs=0.6)
    # Below the wall/floor corner (elevation -atan(1/3) at the centre column) it is floor.
    assert el.min() == pytest.approx(-np.degrees(np.arctan(1.0 / 3.0)), abs=1.0)


@pytest.mark.parametrize("height_m,distance_m,pose", [(1.45, 2.0, "standing"), (1.7, 2.5, "walking"),
                                                      (1.95, 3.0, "carrying")])
def test_person_top_is_at_its_height_with_its_id(height_m, distance_m, pose):
    rng = np.random.default_rng(5)
    scene = Scene()
    scene.add(make_clutter("pillar", rng, x_m=distance_m + 1.5, y_m=1.0))
    pid = scene.add(make_person(height_m, 0.45, 0.28, pose, 0.5, rng, x_m=distance_m, y_m=0.1))
    frame = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(0))
    person = frame.object_id == pid
    assert person.sum() > 100
    assert frame.xyz[person, 2].max() == pytest.approx(height_m, abs=0.05)
    # Every person point lies in the person's footprint, the floor points at z ~ 0.
    xy = frame.xyz[person, :2] - np.array([distance_m, 0.1])
    assert np.hypot(xy[:, 0], xy[:, 1]).max() < 0.6
    assert np.abs(frame.xyz[frame.object_id == FLOOR_ID, 2]).max() < 0.03
    truth = {o["id"]: o for o in frame.objects}
    assert truth[pid]["is_person"] and truth[pid]["height_m"] == pytest.approx(height_m)
    assert truth[pid]["visible_points"] == person.sum()


def test_fx8_pair_covers_120_degrees():
    mounts = fx8_pair_mounts()
    centre = (mounts[0].position_base + mounts[1].position_base) / 2
    ring = cylinder((centre[0], centre[1], -1.0), (centre[0], centre[1], 4.0), 4.0, 0.5, resolution=360)
    scene = Scene([SceneObject(kind="pillar", is_person=False, mesh_local=ring)])
    frame = render(scene, FX8.with_(**NOISELESS), mounts, np.random.default_rng(0))
    on_ring = frame.object_id == 0
    az = np.degrees(np.arctan2(frame.xyz[on_ring, 1] - centre[1], frame.xyz[on_ring, 0] - centre[0]))
    assert az.max() - az.min() == pytest.approx(120.0, abs=1.5)
    # No gap but the 2 * 5 cm blind strip straight ahead (1.4 deg at 4 m): every other degree is hit.
    hist, edges = np.histogram(az, bins=118, range=(-59.0, 59.0))
    assert hist[np.abs(edges[:-1] + 0.5) > 1.0].min() > 0
    assert set(np.unique(frame.mount_index)) == {0, 1}


def test_intensity_in_unit_range_and_grows_with_reflectance():
    dark = render(Scene([_wall(3.0, 0.2)]), FX8, Mount(), np.random.default_rng(0))
    bright = render(Scene([_wall(3.0, 0.8)]), FX8, Mount(), np.random.default_rng(0))
    for frame in (dark, bright):
        assert frame.intensity.min() >= 0.0 and frame.intensity.max() <= 1.0
    i_dark = dark.intensity[dark.object_id == 0].mean()
    i_bright = bright.intensity[bright.object_id == 0].mean()
    # Same geometry: the ratio follows the reflectance ratio (4x), noise aside.
    assert i_bright / i_dark == pytest.approx(4.0, rel=0.1)
    # Incidence: at the wall, intensity falls off with the angle from its normal.
    w = bright.object_id == 0
    off_axis = np.abs(bright.xyz[w, 1]) / np.linalg.norm(bright.xyz[w] - Mount().position_base, axis=1)
    assert np.corrcoef(off_axis, bright.intensity[w])[0, 1] < -0.5


def test_occluded_person_has_no_visible_points():
    rng = np.random.default_rng(0)
    scene = Scene([_wall(2.0, 0.5)])
    hidden = scene.add(make_person(1.7, 0.45, 0.25, "standing", 0.5, rng, x_m=3.5))
    frame = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(0))
    assert {o["id"]: o["visible_points"] for o in frame.objects}[hidden] == 0
    assert frame.visible_people() == []
    scene.move(hidden, 1.5, 0.0)
    frame = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(0))
    assert [o["id"] for o in frame.visible_people()] == [hidden]


def test_move_and_base_pose_are_consistent():
    rng = np.random.default_rng(2)
    scene = Scene()
    pid = scene.add(make_person(1.8, 0.5, 0.3, "standing", 0.7, rng, x_m=2.5, y_m=0.0, yaw_rad=0.3))
    before = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(0))
    # Moving the person by (dx, dy) moves its points by (dx, dy).
    scene.move(pid, 2.9, -0.4)
    after = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(0))
    c0 = before.xyz[before.object_id == pid, :2].mean(axis=0)
    c1 = after.xyz[after.object_id == pid, :2].mean(axis=0)
    np.testing.assert_allclose(c1 - c0, [0.4, -0.4], atol=0.08)
    # The robot at (x, y, yaw) in the scene sees what it sees at the origin of a moved scene.
    base = (1.0, -2.0, 0.7)
    c, s = np.cos(base[2]), np.sin(base[2])
    p = scene.get(pid)
    scene.move(pid, base[0] + c * 2.5 - s * 0.0, base[1] + s * 2.5 + c * 0.0, base[2] + 0.3)
    moved = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(0), base_pose=base)
    np.testing.assert_allclose(moved.points, before.points, atol=2e-4)
    truth = {o["id"]: o for o in moved.objects}[pid]
    assert (truth["x_m"], truth["y_m"], truth["yaw_rad"]) == pytest.approx((2.5, 0.0, 0.3))
    assert p.x_m != 2.5  # the scene object itself stays in the scene frame


def test_step_moves_walking_people_and_animates_their_gait():
    rng = np.random.default_rng(4)
    scene = Scene()
    pid = scene.add(make_person(1.7, 0.45, 0.25, "walking", 0.5, rng, x_m=2.0, velocity_mps=(1.0, 0.5)))
    sid = scene.add(make_person(1.7, 0.45, 0.25, "standing", 0.5, rng, x_m=3.0, y_m=1.0))
    mesh_before = scene.get(pid).mesh_local.vertices.copy()
    scene.step(0.25)
    assert (scene.get(pid).x_m, scene.get(pid).y_m) == pytest.approx((2.25, 0.125))
    assert (scene.get(sid).x_m, scene.get(sid).y_m) == (3.0, 1.0)
    assert not np.allclose(scene.get(pid).mesh_local.vertices, mesh_before)
    assert scene.get(pid).height_m == pytest.approx(1.7)
    # Over a stride the legs swing both ways, the head and clothes keep their reflectance.
    refl = np.unique(scene.get(pid).mesh_local.reflectance)
    phases = []
    for _ in range(8):
        scene.step(0.2)
        phases.append(scene.get(pid).params["gait_phase"])
        np.testing.assert_array_equal(np.unique(scene.get(pid).mesh_local.reflectance), refl)
    assert min(phases) < -0.5 and max(phases) > 0.5


def test_person_mesh_sizes_and_poses():
    rng = np.random.default_rng(0)
    for pose in PERSON_POSES:
        m = person_mesh(1.6, 0.5, 0.3, pose, (0.2, 0.9), rng)
        assert isinstance(m, Mesh) and len(m.reflectance) == len(m.triangles)
        assert m.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-6)
        assert m.z_max_m == pytest.approx(1.6)
        y_extent = np.ptp(m.vertices[:, 1])
        assert 0.45 <= y_extent <= (0.5 if "carrying" not in pose else 0.9)
        assert np.isclose(m.reflectance, 0.2).any() and np.isclose(m.reflectance, 0.9).any()
    with pytest.raises(PedcalInputError, match="pose"):
        person_mesh(1.7, 0.4, 0.3, "dancing", 0.5, rng)


@pytest.mark.parametrize("seed", range(6))
def test_random_scene_places_without_overlap(seed):
    rng = np.random.default_rng(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = random_scene(rng, n_people=(2, 6), n_clutter=(3, 10))
    assert 2 <= len(scene.people) <= 6
    circles = [o.collision_circles() for o in scene.objects]
    for i in range(len(circles)):
        for j in range(i + 1, len(circles)):
            a, b = circles[i], circles[j]
            d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
            assert np.all(d > a[:, None, 2] + b[None, :, 2])
    for p in scene.people:
        assert abs(np.degrees(np.arctan2(p.y_m, p.x_m))) <= 60.0 and 0.8 <= np.hypot(p.x_m, p.y_m) <= 5.0
        assert 1.45 <= p.height_m <= 1.95 and 0.35 <= p.width_m <= 0.55 and 0.2 <= p.depth_m <= 0.35
    static = [p for p in scene.people if p.velocity_mps == (0.0, 0.0)]
    assert all(p.pose in ("standing", "carrying") for p in static)


def test_random_scene_without_occlusion_sees_every_person():
    for seed in range(4):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a person that fits nowhere unoccluded is left out
            scene = random_scene(np.random.default_rng(seed), n_people=3, n_clutter=6, allow_occlusion=False,
                                 area=(1.0, 4.5, -3.0, 3.0))
        assert len(scene.people) >= 2
        frame = render(scene, FX8, fx8_pair_mounts(), np.random.default_rng(seed))
        assert len(frame.visible_people(min_points=10)) == len(scene.people)


def test_every_clutter_kind_renders():
    rng = np.random.default_rng(3)
    scene = Scene()
    ids = {k: scene.add(make_clutter(k, rng, x_m=4.0, y_m=3.0 - 0.8 * i)) for i, k in enumerate(CLUTTER_KINDS)
           if k != "wall"}
    frame = render(scene, LIDAR_PRESETS["spin32"], Mount(0.0, 0.0, 1.0), np.random.default_rng(0))
    seen = {o["id"]: o["visible_points"] for o in frame.objects}
    assert all(seen[i] > 0 for i in ids.values())


def test_bad_input_is_reported():
    with pytest.raises(PedcalInputError, match="min_range_m"):
        LidarModel("bad", 10, 10, 60.0, 30.0, 5.0, 1.0)
    with pytest.raises(PedcalInputError, match="preset"):
        render(Scene(), "fx9", Mount(), 0)
    with pytest.raises(PedcalInputError, match="n_people"):
        random_scene(0, n_people=(3, 1))
    with pytest.raises(PedcalInputError, match="area"):
        random_scene(0, area=(5.0, 1.0, -1.0, 1.0))


def test_a_beam_table_lidar_casts_one_row_per_listed_elevation():
    """pandar40: 40 beams, 1/3 deg apart between -6 and +2 deg and 1 deg apart above and below;
    on a wall 10 m away the rows lie at 10 m * tan(elevation) about the sensor's height."""
    lidar = LIDAR_PRESETS["pandar40"]
    el = np.degrees(np.unique(lidar.ray_angles_rad()[1]))
    assert len(el) == 40 and el.min() == pytest.approx(-16.0) and el.max() == pytest.approx(7.0)
    gaps = np.diff(el)
    dense = (el[:-1] >= -6.0 - 1e-3) & (el[1:] <= 2.0 + 1e-3)
    assert dense.sum() == 24 and np.allclose(gaps[dense], 1 / 3, atol=1e-3)
    assert np.allclose(gaps[~dense], 1.0, atol=1e-3)
    assert lidar.fov_vertical_deg == pytest.approx(23.0) and lidar.vertical_center_deg == pytest.approx(-4.5)
    frame = render(Scene([_wall(10.0, 0.6)]), lidar.with_(**NOISELESS), Mount(0.0, 0.0, 1.8), np.random.default_rng(0))
    on_wall = frame.xyz[frame.object_id == 0].astype(float)
    straight = np.abs(on_wall[:, 1]) < 0.015  # the column straight ahead (columns are 3.5 cm apart)
    z = np.sort(on_wall[straight, 2])
    expected = np.sort(1.8 + 10.0 * np.tan(np.radians(el)))
    expected = expected[(expected > 0.0) & (expected < 3.0)]  # the wall is 3 m tall
    assert len(z) == len(expected) and np.abs(z - expected).max() < 0.01
    with pytest.raises(PedcalInputError, match="ascending"):
        LidarModel("bad", 1800, 3, 360.0, 2.0, 0.5, 50.0, vertical_center_deg=0.0, elevations_deg=(1.0, 0.0, -1.0))
    with pytest.raises(PedcalInputError, match="from_beams"):
        LidarModel("bad", 1800, 3, 360.0, 5.0, 0.5, 50.0, elevations_deg=(-1.0, 0.0, 1.0))


def test_skirts_coats_and_backpacks_change_the_outline_not_the_scene():
    rng = np.random.default_rng(0)
    plain = person_mesh(1.7, 0.45, 0.25, "standing", 0.5, np.random.default_rng(1))
    skirt = person_mesh(1.7, 0.45, 0.25, "standing", 0.5, np.random.default_rng(1), garment="skirt")
    coat = person_mesh(1.7, 0.45, 0.25, "standing", 0.5, np.random.default_rng(1), garment="coat", backpack=True)

    def added(m):  # the garment's (and backpack's) vertices, appended after the plain person's
        return m.vertices[len(plain.vertices):]

    # the skirt: from the waist (0.56 h), 0.25 m deep there like the torso, flaring to its hem
    # between 0.2 h and 0.4 h, where it is 1.2-1.9 times as deep (at most 0.7 m)
    hem = added(skirt)[:, 2].min()
    at_hem = added(skirt)[np.isclose(added(skirt)[:, 2], hem), 0]
    assert 0.2 * 1.7 <= hem <= 0.4 * 1.7 and added(skirt)[:, 2].max() == pytest.approx(0.56 * 1.7)
    assert 1.2 * 0.125 - 1e-9 <= np.abs(at_hem).max() <= 0.35
    assert np.ptp(coat.vertices[:, 0]) > np.ptp(plain.vertices[:, 0]) + 0.1  # the backpack behind the back
    for m in (skirt, coat):
        assert m.z_max_m == pytest.approx(1.7) and m.vertices[:, 2].min() >= 0.0
        np.testing.assert_array_equal(m.vertices[:len(plain.vertices)], plain.vertices)
    with pytest.raises(PedcalInputError, match="garment"):
        person_mesh(1.7, 0.45, 0.25, "standing", 0.5, rng, garment="cape")
    # random clothing comes from each person's own seed: a scene's layout and draws stay the same
    g_plain, g_dressed = np.random.default_rng(3), np.random.default_rng(3)
    a = make_person(1.7, 0.45, 0.25, "walking", 0.5, g_plain)
    b = make_person(1.7, 0.45, 0.25, "walking", 0.5, g_dressed, random_clothing=True)
    assert a.params["mesh_seed"] == b.params["mesh_seed"] and g_plain.random() == g_dressed.random()
    garments = {make_person(1.7, 0.45, 0.25, "walking", 0.5, np.random.default_rng(s), random_clothing=True)
                .params["garment"] for s in range(40)}
    assert garments == {"none", "skirt", "coat"}


def test_a_pusher_holds_the_pram_handle_and_walks_with_it():
    rng = np.random.default_rng(8)
    pusher = make_person(1.75, 0.45, 0.25, "walking", 0.5, rng, x_m=4.0, y_m=1.0, yaw_rad=0.5,
                         velocity_mps=(0.9 * np.cos(0.5), 0.9 * np.sin(0.5)), pushing=True)
    pram = pram_in_front(pusher)
    assert pram.kind == "pram" and not pram.is_person and pram.velocity_mps == pusher.velocity_mps
    # the hands (lowest arm vertices, pushed forward) meet the handle bar at 0.58 of the height
    hands = pusher.mesh_scene().vertices
    hands = hands[np.abs(hands[:, 2] - 0.58 * 1.75) < 0.05]
    forward = (hands[:, :2] - [4.0, 1.0]) @ [np.cos(0.5), np.sin(0.5)]
    handle = pram.mesh_scene().vertices
    handle_fwd = (handle[:, :2] - [4.0, 1.0]) @ [np.cos(0.5), np.sin(0.5)]
    assert forward.max() == pytest.approx(push_reach_m(1.75), abs=0.05)
    assert handle_fwd.min() == pytest.approx(push_reach_m(1.75), abs=0.03)
    assert handle[:, 2].max() == pytest.approx(0.58 * 1.75, abs=0.02)
    scene = Scene([pusher, pram])
    gap = (pram.x_m - pusher.x_m, pram.y_m - pusher.y_m)
    scene.step(1.0)
    assert pusher.x_m == pytest.approx(4.0 + 0.9 * np.cos(0.5))
    assert (pram.x_m - pusher.x_m, pram.y_m - pusher.y_m) == pytest.approx(gap, abs=1e-12)
    # random scenes give pushers their prams, placed clear of everything else
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenes = [random_scene(np.random.default_rng(s), n_people=(6, 6)) for s in range(30)]
    prams = [o for sc in scenes for o in sc.objects if o.kind == "pram"]
    assert prams and all(o.params.get("pushing") is not None for sc in scenes for o in sc.people)
