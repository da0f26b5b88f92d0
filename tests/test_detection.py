"""Each step of the detection pipeline on constructed clouds, and the real KITTI pedestrian."""

import numpy as np
import pytest

from pedcal.detect import detection as det
from pedcal.detect.adaboost import RealAdaBoost
from pedcal.detect.features import N_FEATURES


def box_surface(rng, cx, cy, w, d, h, yaw, n=3000):
    """Points on the four vertical faces and the top of a w x d x h box yawed by ``yaw``."""
    u = rng.uniform(-0.5, 0.5, n) * w
    v = rng.uniform(-0.5, 0.5, n) * d
    face = rng.integers(0, 5, n)
    u = np.where(face == 0, -w / 2, np.where(face == 1, w / 2, u))
    v = np.where(face == 2, -d / 2, np.where(face == 3, d / 2, v))
    z = np.where(face == 4, h, rng.uniform(0.0, h, n))
    c, s = np.cos(yaw), np.sin(yaw)
    return np.column_stack([cx + c * u - s * v, cy + s * u + c * v, z, np.full(n, 0.3)])


def cylinder_person(rng, cx, cy, radius=0.22, h=1.7, n=1500):
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0.0, h, n)
    return np.column_stack([cx + radius * np.cos(a), cy + radius * np.sin(a), z, rng.uniform(0.1, 0.5, n)])


def floor(rng, n=2000, extent=5.0):
    xy = rng.uniform(0, extent, (n, 2)) - [0, extent / 2]
    return np.column_stack([xy, rng.normal(0, 0.01, n), np.full(n, 0.1)])


@pytest.mark.parametrize("yaw_deg", [0.0, 17.0, 45.0, -63.0, 89.0])
def test_min_area_box_recovers_size_and_yaw(yaw_deg):
    rng = np.random.default_rng(1)
    pts = box_surface(rng, 2.0, -1.0, 0.9, 0.4, 1.0, np.radians(yaw_deg))
    box = det.min_area_box(pts[:, :2])
    assert box.width == pytest.approx(0.9, abs=0.01)
    assert box.depth == pytest.approx(0.4, abs=0.01)
    assert (box.cx, box.cy) == pytest.approx((2.0, -1.0), abs=0.01)
    err = (np.degrees(box.yaw) - yaw_deg + 90) % 180 - 90
    assert abs(err) < 1.0


def test_min_area_box_degenerate_inputs_are_finite():
    for xy in (np.array([[1.0, 2.0]]), np.array([[0.0, 0.0], [1.0, 1.0]]),
               np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])):
        box = det.min_area_box(xy)
        assert np.isfinite([box.cx, box.cy, box.width, box.depth, box.yaw]).all()
    box = det.min_area_box(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]))
    assert box.width == pytest.approx(2.0) and box.depth == pytest.approx(0.0, abs=1e-9)


def test_flat_patch_has_no_object_cells_and_a_post_has_one():
    rng = np.random.default_rng(2)
    pts = floor(rng)
    pts[:, 2] += rng.uniform(0, 0.15, len(pts))  # bumpy but lower than the 0.2 m rule
    ij, shape, _ = det.grid_cells(pts, 0.1)
    assert not det.object_cells(ij, pts[:, 2], shape).any()
    post = np.column_stack([np.full(50, 2.03), np.full(50, 0.03), np.linspace(0, 1.0, 50), np.zeros(50)])
    pts = np.vstack([pts, post])
    ij, shape, _ = det.grid_cells(pts, 0.1)
    occ = det.object_cells(ij, pts[:, 2], shape)
    assert occ.sum() == 1


def test_far_points_do_not_blow_up_the_grid_and_leave_the_clusters_unchanged():
    rng = np.random.default_rng(5)
    pts = floor(rng)
    post = np.column_stack([np.full(50, 2.03), np.full(50, 0.03), np.linspace(0, 1.0, 50), np.zeros(50)])
    pts = np.vstack([pts, post])
    near = det.segment(pts)
    far = np.vstack([pts, [[900.0, -900.0, 1.0, 0.0], [-900.0, 900.0, 0.5, 0.0]]])
    ij, shape, _ = det.grid_cells(far, 0.1)
    assert shape[0] * shape[1] <= det.MAX_GRID_CELLS  # not the 18000 x 18000 of a dense grid
    got = det.segment(far)
    assert [len(c.indices) for c in got] == [len(c.indices) for c in near]
    assert [c.box for c in got] == [c.box for c in near]


def test_clustering_separates_objects_and_gap_tolerance_joins_them():
    occ = np.zeros((10, 10), bool)
    occ[1:3, 1:3] = True
    occ[3, 3] = True  # diagonal neighbour: 8-connectivity joins it
    occ[1:3, 5:7] = True  # two empty cells away
    labels, n = det.cluster_cells(occ)
    assert n == 2 and labels[3, 3] == labels[1, 1]
    labels, n = det.cluster_cells(occ, gap_cells=1)
    assert n == 1 and (labels[occ] == 1).all() and (labels[~occ] == 0).all()


def test_cluster_points_drop_the_floor():
    rng = np.random.default_rng(3)
    pts = np.vstack([floor(rng), cylinder_person(rng, 2.0, 0.0)])
    cands = det.segment(pts)
    assert len(cands) == 1
    c = cands[0]
    assert (pts[c.indices, 2] > det.FLOOR_TOLERANCE_M).all()
    assert len(c.indices) == pytest.approx((pts[2000:, 2] > det.FLOOR_TOLERANCE_M).sum(), abs=0)


def test_gate_rejects_wall_and_passes_person_cylinder():
    rng = np.random.default_rng(4)
    wall = box_surface(rng, 3.0, 0.0, 3.0, 0.1, 1.8, 0.3)
    low = box_surface(rng, 1.5, -1.5, 0.5, 0.5, 0.5, 0.0)
    person = cylinder_person(rng, 2.0, 2.0)
    pts = np.vstack([floor(rng), wall, low, person])
    cands = det.segment(pts)
    assert len(cands) == 3
    gated = [c for c in cands if c.gated]
    assert len(gated) == 1
    g = gated[0]
    assert (g.box.cx, g.box.cy) == pytest.approx((2.0, 2.0), abs=0.02)
    assert g.height == pytest.approx(1.7, abs=0.02)
    assert g.box.width == pytest.approx(0.44, abs=0.03)
    assert not det.passes_gate(1.8, 3.0, 0.1)
    assert not det.passes_gate(0.5, 0.5, 0.5)
    assert not det.passes_gate(2.2, 0.5, 0.5)
    assert det.passes_gate(1.7, 0.5, 0.3)


def test_detect_scores_gated_clusters_with_a_given_model():
    rng = np.random.default_rng(5)
    # a toy model: a person's top slice is head-size (0.4 m), a box's top is its whole width (1 m)
    X = np.zeros((200, N_FEATURES))
    y = np.arange(200) % 2
    X[:, 166 + 2 * 9] = np.where(y == 1, 0.4, 1.0)  # length of the top tenth of the height
    model = RealAdaBoost(n_rounds=5, n_bins=4).fit(X, y)
    pts = np.vstack([floor(rng), cylinder_person(rng, 2.0, 1.0), box_surface(rng, 2.0, -1.0, 1.0, 0.6, 1.2, 0.0)])
    dets = det.detect(pts, model)
    assert len(dets) == 2
    person, box = sorted(dets, key=lambda d: -d.y)
    assert person.y == pytest.approx(1.0, abs=0.05) and box.y == pytest.approx(-1.0, abs=0.05)
    assert person.score > 0.9 > 0.1 > box.score
    assert person.is_person and not box.is_person
    assert person.n_points > 1000 and box.n_points > 1000
    assert person.to_dict()["x"] == pytest.approx(person.x)


def test_people_side_by_side_are_cut_at_their_heads():
    rng = np.random.default_rng(9)
    # two people whose shoulders touch (centres 0.5 m apart): one cluster 0.95 m wide
    pair = np.vstack([cylinder_person(rng, 3.0, 0.25, radius=0.22, h=1.8),
                      cylinder_person(rng, 3.0, -0.25, radius=0.22, h=1.6)])
    head = lambda cx, cy, top: np.column_stack([cx + rng.normal(0, 0.06, 300), cy + rng.normal(0, 0.06, 300),  # noqa: E731
                                                 rng.uniform(top - 0.25, top, 300), np.full(300, 0.3)])
    body = np.vstack([pair[pair[:, 2] < 1.35], head(3.0, 0.25, 1.8), head(3.0, -0.25, 1.6)])
    pts = np.vstack([floor(rng), body])
    whole = det.segment(pts, split_wide=False)
    assert len(whole) == 1 and whole[0].box.width > 0.8
    gated = [c for c in det.segment(pts) if c.gated]
    assert len(gated) == 2
    assert sorted(c.box.cy for c in gated) == pytest.approx([-0.25, 0.25], abs=0.08)
    assert sorted(c.height for c in gated) == pytest.approx([1.6, 1.8], abs=0.02)
    # a wide object with a flat top (a cabinet) and one person with a bag have one head at most
    cabinet = box_surface(rng, 3.0, 0.0, 1.0, 0.5, 1.5, 0.0)
    assert det.split_by_heads(np.vstack([floor(rng), cabinet]), np.arange(2000, 5000)) == []
    one = np.vstack([pair[pair[:, 1] > 0], head(3.0, 0.25, 1.8),
                     box_surface(rng, 3.0, -0.35, 0.3, 0.15, 0.9, 0.0, n=400)])
    assert det.split_by_heads(one, np.arange(len(one))) == []


def test_detect_empty_and_three_column_input():
    assert det.detect(np.zeros((0, 4))) == []
    rng = np.random.default_rng(6)
    assert det.detect(floor(rng)[:, :3]) == []


def test_a_few_stray_points_are_no_candidate():
    assert not det.passes_gate(1.5, 0.3, 0.2, n_points=det.MIN_CLUSTER_POINTS - 1)
    rng = np.random.default_rng(7)
    stray = np.array([[2.0, 0.0, 1.2, 0.3], [2.02, 0.01, 1.0, 0.3]])
    cands = det.segment(np.vstack([floor(rng), stray]))
    assert len(cands) == 1 and not cands[0].gated


def test_person_against_a_tall_wall_is_split_off_by_height():
    rng = np.random.default_rng(8)
    wall = box_surface(rng, 3.0, 0.0, 0.1, 3.0, 2.5, 0.0, n=6000)  # thin along x, 3 m along y, 2.5 m tall
    person = cylinder_person(rng, 2.75, 0.5, radius=0.2, h=1.7)  # touching the wall's cells
    pts = np.vstack([floor(rng), wall, person])
    whole = det.segment(pts, split_tall=False)
    assert len(whole) == 1 and not whole[0].gated  # one cluster, 3 m wide and 2.5 m tall
    cands = det.segment(pts)
    gated = [c for c in cands if c.gated]
    assert len(gated) == 1
    g = gated[0]
    assert (g.box.cx, g.box.cy) == pytest.approx((2.75, 0.5), abs=0.08)
    assert g.height == pytest.approx(1.7, abs=0.02)
    # the part keeps most of the person (not the cells it shares with the wall), none of the wall
    assert (pts[g.indices, 2] <= det.GATE_HEIGHT_M[1]).all()
    assert len(g.indices) >= 0.7 * (person[:, 2] > det.FLOOR_TOLERANCE_M).sum()
    # a pillar alone leaves no part behind
    pillar = box_surface(rng, 2.0, -1.0, 0.4, 0.4, 2.5, 0.0)
    assert not any(c.gated for c in det.segment(np.vstack([floor(rng), pillar])))


def test_a_person_is_cut_free_of_the_pram_they_push():
    rng = np.random.default_rng(10)
    person = cylinder_person(rng, 3.0, 0.0, radius=0.22, h=1.7)
    pram = box_surface(rng, 3.0, 0.72, 0.5, 0.8, 0.9, 0.0, n=3000)  # touching in front (along +y)
    handle = np.column_stack([np.full(200, 3.0) + rng.uniform(-0.2, 0.2, 200), rng.uniform(0.2, 0.35, 200),
                              np.full(200, 0.99), np.full(200, 0.3)])
    pts = np.vstack([floor(rng), person, pram, handle])
    whole = det.segment(pts, split_wide=False)
    assert len(whole) == 1 and whole[0].box.width > det.GATE_MAX_WIDTH_M and not whole[0].gated
    assert det.split_by_heads(pts, whole[0].indices) == []  # one head: not a pair
    assert not any(c.gated for c in det.segment(pts))  # without cut_low: one wide cluster, ungated
    gated = [c for c in det.segment(pts, cut_low=True) if c.gated]
    assert len(gated) == 1
    g = gated[0]
    assert (g.box.cx, g.box.cy) == pytest.approx((3.0, 0.0), abs=0.08)
    assert g.height == pytest.approx(1.7, abs=0.02)
    n_pram = np.isin(g.indices, np.arange(2000 + len(person), len(pts))).sum()
    assert n_pram <= 0.05 * len(g.indices)
    # a wide flat-topped object (a cabinet) has no low cells to drop
    cabinet = box_surface(rng, 3.0, 0.0, 1.0, 0.5, 1.5, 0.0)
    assert det.split_low(np.vstack([floor(rng), cabinet]), np.arange(2000, 5000)) == []


def test_each_frame_gets_the_model_of_its_sensor_family():
    assert det.model_family("fx8") == "fx8" and det.model_family("fx8_far") == "fx8"
    assert det.model_family("hdl64") == "general" and det.model_family() == "general"
    # no sensor named: the known sensor whose ray steps are nearest the frame's (estimated) ones
    assert det.model_family(scan_steps=np.radians([0.56, 0.78])) == "fx8"  # as estimated on FX8 frames
    assert det.model_family(scan_steps=np.radians([0.44, 0.556])) == "general"  # solid-dense
    assert det.model_family(scan_steps=np.radians([0.2, 0.36])) == "general"  # the SUSTech frames
    assert det.model_family(scan_steps=(np.nan, np.nan)) == "general"
    assert det.load_model(family="fx8").tree_depth > 0 and det.load_model().n_features_ == N_FEATURES
    with pytest.raises(det.PedcalInputError, match="family"):
        det.model_path("nonsense")


def test_legs_below_a_nearer_panel_are_gated_and_an_open_low_box_is_not():
    # A hanging panel 1.5 m away hides a person 3 m away above the knees: the legs' cluster is
    # lower than the 0.8 m gate, but its top is hidden, so with occluded_low it is gated on its
    # width and depth. A box as low in the open is not (nothing nearer above it).
    from pedcal.sim.lidar import fx8_pair_mounts, render
    from pedcal.sim.scene import Scene, SceneObject, box, make_person

    rng = np.random.default_rng(3)
    panel = SceneObject("sign", False, box((0.0, 0.0, 1.15), (0.05, 1.0, 0.9), 0.5), x_m=1.5, y_m=0.0)
    person = make_person(1.75, 0.45, 0.28, "standing", (0.5, 0.5), rng)
    person.x_m, person.y_m = 3.0, 0.0
    low_box = SceneObject("box", False, box((0.0, 0.0, 0.3), (0.4, 0.4, 0.6), 0.5), x_m=3.0, y_m=1.5)
    scene = Scene([panel, person, low_box])
    frame = render(scene, "fx8", fx8_pair_mounts(), rng)
    pts = frame.points.astype(float)
    sensor = tuple(frame.sensor_positions_base.mean(axis=0))

    def gated_ids(**kw):
        out = []
        for c in det.segment(pts, sensor_xyz=sensor, **kw):
            if c.gated:
                ids, n = np.unique(frame.object_id[c.indices], return_counts=True)
                out.append(int(ids[np.argmax(n)]))
        return out

    legs = frame.object_id == person.id
    assert legs.sum() >= 10 and pts[legs, 2].max() < det.GATE_HEIGHT_M[0]  # only the legs show
    assert person.id not in gated_ids()
    assert gated_ids(occluded_low=True).count(person.id) >= 1
    assert low_box.id not in gated_ids(occluded_low=True)
    # unknown ray steps: nothing is taken as hidden
    assert not det.top_occluded(pts, [np.flatnonzero(legs)], (np.nan, np.nan), sensor).any()
