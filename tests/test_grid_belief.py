"""Grid belief: walls carry no belief, negative information, antenna likelihood, masked motion."""

import numpy as np
import pytest

from pedcal.io.maps import OccupancyMap, read_occupancy_map
from pedcal.track.espar import DEFAULT_LIKELIHOOD
from pedcal.track.grid_belief import GridBelief, GridBeliefConfig


def wall_map(wall_x_m: float = 2.0, size_m: float = 20.0, res_m: float = 0.05) -> OccupancyMap:
    """A map centred on the origin with one wall (0.1 m thick) across y at x = wall_x_m, |y| < 4 m."""
    n = int(size_m / res_m)
    origin = np.array([-size_m / 2, -size_m / 2, 0.0])
    m = OccupancyMap(np.zeros((n, n), bool), np.ones((n, n), bool), np.zeros((n, n), bool), res_m, origin)
    ys = np.arange(-4.0, 4.0, res_m / 2)
    for dx in (0.0, 0.05):
        ij = m.world_to_cell(np.stack([np.full_like(ys, wall_x_m + dx), ys], axis=-1))
        m.occupied[ij[:, 0], ij[:, 1]] = True
    m.free &= ~m.occupied
    return m


def test_blocked_cells_follow_the_map():
    g = GridBelief(wall_map(), (0.0, 0.0))
    assert g.is_blocked(np.array([[2.02, 0.0], [2.02, 3.0]])).all()
    assert not g.is_blocked(np.array([[1.5, 0.0], [2.5, 0.0], [2.0, 5.0]])).any()
    assert (g.belief[g.blocked] == 0).all() and g.belief.sum() == pytest.approx(1.0)


def test_negative_information_lowers_seen_cells_only():
    cfg = GridBeliefConfig()
    g = GridBelief(wall_map(), (0.0, 0.0), cfg)
    before = g.belief.copy()
    n_seen = g.observe_empty((0.0, 0.0, 0.0))
    assert n_seen > 100
    ratio = g.belief / np.where(before > 0, before, 1.0)
    ahead = g.cell_of(np.array([1.0, 0.0]))            # in view, in front of the wall
    behind = g.cell_of(np.array([3.0, 0.0]))           # in range and field of view, hidden by the wall
    aside = g.cell_of(np.array([0.0, 1.5]))            # outside the 120 deg field of view
    far = g.cell_of(np.array([5.5, 5.5]))              # beyond 5 m
    r = {name: ratio[ij[0], ij[1]] for name, ij in
         dict(ahead=ahead, behind=behind, aside=aside, far=far).items()}
    assert r["ahead"] == pytest.approx((1 - cfg.p_detect) * r["behind"])
    assert r["behind"] == pytest.approx(r["aside"]) == pytest.approx(r["far"])


def test_a_person_occludes_the_cells_behind_it():
    g = GridBelief(None, (0.0, 0.0))
    iy, ix = g.visible_cells((0.0, 0.0, 0.0), occluders_xy_world_m=[(2.0, 0.0)])
    seen = np.zeros_like(g.blocked)
    seen[iy, ix] = True
    shadow, open_ = g.cell_of(np.array([3.5, 0.0])), g.cell_of(np.array([3.5, 1.5]))
    assert not seen[shadow[0], shadow[1]] and seen[open_[0], open_[1]]


def test_bearing_likelihood_is_the_antenna_model():
    g = GridBelief(None, (0.0, 0.0))
    xy_antenna, bearing = np.array([0.3, -0.2]), 0.7
    lik = g.bearing_likelihood(xy_antenna, bearing)
    a = np.arctan2(g.y_m[:, None] - xy_antenna[1], g.x_m[None, :] - xy_antenna[0])
    np.testing.assert_allclose(lik, DEFAULT_LIKELIHOOD.p_direction(bearing - a), atol=2e-3)


def test_motion_spreads_but_never_crosses_a_wall():
    g = GridBelief(wall_map(), (0.0, 0.0))
    g.reset_gaussian((1.5, 0.0), 0.2)
    for _ in range(20):
        g.predict(0.25)
    behind = g.x_m[None, :] > 2.1
    assert g.belief[:, behind[0]].sum() < 1e-3              # only around the wall's ends, 4 m away
    xy, cov, _ = g.estimate()
    assert np.sqrt(np.trace(cov)) > 0.5                     # it did spread


def test_target_behind_a_wall_is_never_placed_inside_it():
    """Robot in front of a wall, the antenna points through it: the belief ends behind the wall."""
    rng = np.random.default_rng(0)
    g = GridBelief(wall_map(), (0.0, 0.0))
    xy_target = np.array([3.0, 0.5])
    for _ in range(12):
        g.predict(0.25)
        g.observe_empty((0.0, 0.0, 0.0))
        bearing = np.arctan2(xy_target[1], xy_target[0]) + rng.normal(0, np.radians(20))
        g.observe_bearing((0.0, 0.0), np.round(bearing / (np.pi / 6)) * np.pi / 6)
    assert (g.belief[g.blocked] == 0).all()
    xy, _, _ = g.estimate()
    assert not g.is_blocked(xy) and not g.is_blocked(g.mode())
    assert xy[0] > 2.0                                       # behind the wall, not in front of it


def test_real_turtlebot_map(shared_data):
    occ = read_occupancy_map(shared_data / "turtlebot4_ros2_bag" / "mac_1st_floor_final.yaml")
    center = np.array([6.425, -13.225])                      # a free cell of the floor
    g = GridBelief(occ, center)
    assert 0.01 < g.blocked.mean() < 0.5
    # every occupied map cell inside the window falls in a blocked belief cell
    ij = np.argwhere(occ.occupied)
    xy = occ.cell_to_world(ij)
    inside = (np.abs(xy - center) < 7.5).all(axis=1)
    assert inside.sum() > 100 and g.is_blocked(xy[inside]).all()
    rng = np.random.default_rng(1)
    g.reset_gaussian(center, 2.0)
    for k in range(20):
        g.predict(0.25)
        g.observe_empty((center[0], center[1], 0.3 * k))
        g.observe_bearing(center, rng.uniform(-np.pi, np.pi))
    assert (g.belief[g.blocked] == 0).all() and g.belief.sum() == pytest.approx(1.0)
    xy, _, _ = g.estimate()
    assert not g.is_blocked(xy) and not occ.is_occupied(xy)


def test_recenter_keeps_the_belief_in_place():
    g = GridBelief(None, (0.0, 0.0))
    g.reset_gaussian((1.0, 1.0), 0.3)
    before = g.estimate()[0]
    g.recenter((3.0, -2.0))
    np.testing.assert_allclose(g.estimate()[0], before, atol=1e-9)


def test_window_partly_off_the_map():
    occ = wall_map(size_m=20.0)                                # map spans [-10, 10] in x and y
    g = GridBelief(occ, (8.0, 0.0))                            # window [0, 16] in x: half of it off the map
    assert g.is_blocked(np.array([2.02, 0.0])) and not g.is_blocked(np.array([12.0, 0.0]))
    ij = np.argwhere(occ.occupied)
    xy = occ.cell_to_world(ij)
    inside = (np.abs(xy - [8.0, 0.0]) < 7.9).all(axis=1)
    assert inside.sum() > 50 and g.is_blocked(xy[inside]).all()
    assert g.blocked.sum() == pytest.approx(inside.sum() / 4, rel=0.3)   # 0.05 m map cells in 0.1 m cells
