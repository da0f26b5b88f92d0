"""People and streets closer to real ones: arms swinging with the gait, groups shoulder to
shoulder, people partly hidden, sign posts and parked bicycles; scenes drawn without these
options stay as they were."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from pedcal.errors import PedcalInputError
from pedcal.sim.lidar import Mount, render
from pedcal.sim.scene import (
    HIDING_KINDS_INDOOR,
    HIDING_KINDS_STREET,
    OUTDOOR_CLUTTER_WEIGHTS,
    STREET_CLUTTER_WEIGHTS,
    Scene,
    hide_partly,
    make_clutter,
    make_person,
    person_group,
    person_mesh,
    random_scene,
)


def _quiet_scene(seed, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return random_scene(np.random.default_rng(seed), **kw)


@pytest.mark.parametrize("phase", [1.0, -1.0, 0.0])
def test_arms_swing_against_the_legs(phase):
    """gait_phase +1: the right leg forward, the left arm forward and the right one back (by the
    0.35 rad swing: the hands 0.36 h · sin(0.35) = 0.21 m off the shoulder line at h = 1.75 m)."""
    h = 1.75
    m = person_mesh(h, 0.45, 0.25, "walking", 0.5, np.random.default_rng(0), gait_phase=phase)
    v = m.vertices
    arms = v[(v[:, 2] > 0.38 * h) & (v[:, 2] < 0.5 * h) & (np.abs(v[:, 1]) > 0.17)]
    left = arms[arms[:, 1] > 0, 0].mean()
    right = arms[arms[:, 1] < 0, 0].mean()
    feet = v[v[:, 2] < 0.02]
    right_foot, left_foot = feet[feet[:, 1] < 0, 0].mean(), feet[feet[:, 1] > 0, 0].mean()
    if phase == 0.0:
        assert abs(left) < 0.03 and abs(right) < 0.03 and abs(left_foot - right_foot) < 0.01
    else:
        assert np.sign(left) == phase and np.sign(right) == -phase and min(abs(left), abs(right)) > 0.12
        assert np.sign(right_foot - left_foot) == phase


def test_a_group_stands_shoulder_to_shoulder():
    rng = np.random.default_rng(3)
    group = person_group(rng, 5, static=True, x_m=2.5, y_m=0.0, yaw_rad=np.pi)
    assert len(group) == 5 and all(p.is_person for p in group)
    y = np.array([p.y_m for p in group])
    order = np.argsort(y)
    widths = np.array([group[i].width_m for i in order])
    gaps = np.diff(y[order]) - (widths[:-1] + widths[1:]) / 2
    # side by side across the heading (-x): 0-0.12 m between shoulders, give or take the +-0.1 m
    # each stands ahead or behind (turned rows shorten the lateral spacing only by cos(0.1/0.5))
    assert np.all(gaps > -0.03) and np.all(gaps < 0.13)
    assert np.ptp([p.x_m for p in group]) <= 0.2 + 1e-9
    assert y.mean() == pytest.approx(0.0, abs=0.12)
    walking = person_group(np.random.default_rng(1), 3, static=False, velocity_mps=(0.8, 0.2))
    assert all(p.velocity_mps == (0.8, 0.2) and p.pose.startswith("walking") for p in walking)
    with pytest.raises(PedcalInputError, match="at least one"):
        person_group(rng, 0, static=True)


def test_a_depth_camera_sees_five_people_in_a_row():
    """Five people shoulder to shoulder 2.5 m in front of a wide depth camera: each has points."""
    group = person_group(np.random.default_rng(2), 5, static=True, x_m=2.5, y_m=0.0, yaw_rad=np.pi)
    scene = Scene(group, floor_half_extent_m=6.0)
    frame = render(scene, "depth_vga_wide", Mount(0.0, 0.0, 1.0), np.random.default_rng(0))
    counts = [o["visible_points"] for o in frame.objects]
    assert len(counts) == 5 and min(counts) > 2000


def test_random_scene_places_groups_clear_of_everything_else():
    for seed in range(4):
        scene = _quiet_scene(seed, n_people=1, n_groups=2, group_size=3, n_clutter=5, area=(0.8, 8.0, -6.0, 6.0))
        assert len(scene.people) >= 4  # at least one group placed beside the single person
        people = scene.people
        others = [o for o in scene.objects if not o.is_person]
        for p in people:
            r = np.hypot(p.x_m, p.y_m)
            assert 0.8 <= r <= 8.0 and abs(np.degrees(np.arctan2(p.y_m, p.x_m))) <= 60.0
            for o in others:
                c = o.collision_circles()
                assert np.all(np.hypot(c[:, 0] - p.x_m, c[:, 1] - p.y_m) > c[:, 2] + p.radius_m)
    with pytest.raises(PedcalInputError, match="group_size"):
        random_scene(0, n_groups=1, group_size=(3, 2))


@pytest.mark.parametrize("kinds", [HIDING_KINDS_STREET, HIDING_KINDS_INDOOR])
def test_hide_partly_hides_part_of_a_person(kinds):
    """An occluder between the sensor and the person 7.8 m away leaves 5-97 % of the person's
    points in view (a quarter to three quarters of the width covered, low objects hiding only the
    legs), a fifth of them or more on average."""
    shares = []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        person = make_person(1.7, 0.45, 0.25, "standing", 0.5, rng, x_m=7.5, y_m=2.0)
        scene = Scene([person])
        mount = Mount(0.0, 0.0, 1.0)
        before = (render(scene, "vlp32c", mount, np.random.default_rng(0)).object_id == person.id).sum()
        occ = hide_partly(scene, person, rng, kinds=kinds)
        assert occ is not None and occ.kind in kinds and np.hypot(occ.x_m, occ.y_m) < np.hypot(7.5, 2.0)
        after = (render(scene, "vlp32c", mount, np.random.default_rng(0)).object_id == person.id).sum()
        shares.append(after / before)
    shares = np.array(shares)
    assert shares.min() > 0.05 and np.mean(shares < 0.97) >= 0.75 and shares.mean() < 0.8


def test_random_scene_hides_a_share_of_the_people():
    plain = _quiet_scene(4, n_people=6, n_clutter=0, area=(0.8, 12.0, -12.0, 12.0))
    hidden = _quiet_scene(4, n_people=6, n_clutter=0, area=(0.8, 12.0, -12.0, 12.0), hidden_share=1.0)
    assert [o.kind for o in plain.objects if o.kind != "pram"][:6] == ["person"] * 6
    added = [o for o in hidden.objects if o.id >= len(plain.objects)]
    assert len(added) >= 4 and {o.kind for o in added} <= set(HIDING_KINDS_INDOOR)
    with pytest.raises(PedcalInputError, match="allow_occlusion"):
        random_scene(0, hidden_share=0.5, allow_occlusion=False)


def test_scenes_without_the_new_options_are_unchanged():
    """The shipped detector models were trained on these draws: a scene drawn with the defaults
    (and with the outdoor mix) holds what it held before groups, hiding and the street mix."""
    scene = _quiet_scene(0)
    assert [o.kind for o in scene.objects] == ["wall", "wall"] + ["person"] * 6 + [
        "box", "coat_stand", "sign", "trolley", "potted_plant", "coat_stand"]
    assert sum(o.x_m for o in scene.objects) == pytest.approx(40.222530244, abs=1e-8)
    assert sum(o.y_m for o in scene.objects) == pytest.approx(-8.436572654, abs=1e-8)
    street = _quiet_scene(0, clutter_weights=OUTDOOR_CLUTTER_WEIGHTS, area=(-20, 20, -20, 20),
                          fov_half_angle_deg=180.0, n_clutter=(20, 30))
    assert len(street.objects) == 33 and sum(o.x_m for o in street.objects) == pytest.approx(-6.389751649, abs=1e-8)


def test_sign_posts_carry_their_plates_at_the_top():
    rng = np.random.default_rng(6)
    for _ in range(20):
        post = make_clutter("sign_post", rng)
        v = post.mesh_local.vertices
        plates = v[np.hypot(v[:, 0], v[:, 1]) > 0.051]  # the pole is at most 5 cm in radius
        assert 2.0 <= post.height_m <= 3.2 and plates[:, 2].max() == pytest.approx(post.height_m, abs=0.02)
        assert plates[:, 2].min() > 1.05 and post.width_m >= 0.4
    # seen by a 16-beam scan from 8 m, the top of the cluster is wider than the pole below it
    scene = Scene([make_clutter("sign_post", np.random.default_rng(1), x_m=8.0)])
    frame = render(scene, "vlp16", Mount(0.0, 0.0, 1.8), np.random.default_rng(0))
    pts = frame.xyz[frame.object_id == 0]
    top, low = pts[pts[:, 2] > 1.9], pts[pts[:, 2] < 1.5]
    assert len(top) and len(low) and np.ptp(top[:, 1]) > 4 * np.ptp(low[:, 1])


def test_parked_bicycles_stand_on_their_wheels_in_racks():
    rng = np.random.default_rng(2)
    widths = []
    for _ in range(30):
        bikes = make_clutter("bicycle", rng)
        v = bikes.mesh_local.vertices
        assert v[:, 2].min() >= 0.0 and 0.85 < bikes.height_m < 1.25
        assert 1.5 < bikes.depth_m < 1.95
        widths.append(bikes.width_m)
    widths = np.array(widths)  # 0.6 m a bike, 0.45-0.7 m more for each other bike in the rack
    assert np.any(widths == 0.6) and np.any(widths > 1.05) and np.all(widths <= 0.6 + 2 * 0.7)
    assert set(STREET_CLUTTER_WEIGHTS) >= {"sign_post", "bicycle"} | set(OUTDOOR_CLUTTER_WEIGHTS)
    street = _quiet_scene(3, clutter_weights=STREET_CLUTTER_WEIGHTS, area=(-20, 20, -20, 20),
                          fov_half_angle_deg=180.0, n_clutter=(60, 60))
    assert {"sign_post", "bicycle"} <= {o.kind for o in street.objects}
