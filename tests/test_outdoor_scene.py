"""Street scenes for the spinning LIDARs: outdoor clutter that reaches the detector's gate as
negatives, people out to 30 m with a scan's realistic point counts, and indoor scenes unchanged."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from pedcal.detect.detection import segment
from pedcal.detect.train import label_clusters, random_rig
from pedcal.sim.lidar import Mount, render
from pedcal.sim.scene import (
    CLUTTER_KINDS,
    OUTDOOR_CLUTTER_KINDS,
    OUTDOOR_CLUTTER_WEIGHTS,
    STREET_CLUTTER_KINDS,
    make_clutter,
    random_scene,
)


@pytest.mark.parametrize("kind", STREET_CLUTTER_KINDS)
def test_every_outdoor_kind_builds_a_mesh_standing_on_the_floor(kind):
    rng = np.random.default_rng(3)
    for _ in range(5):
        obj = make_clutter(kind, rng)
        v = obj.mesh_local.vertices
        assert np.isfinite(v).all()
        assert v[:, 2].min() >= -1e-6  # nothing below the floor
        assert 0.09 < obj.height_m < 10.0
        assert obj.radius_m > 0


def test_street_scene_gives_gated_outdoor_negatives_and_sparse_far_people():
    def street(allow_occlusion):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return random_scene(np.random.default_rng(5), area=(-30, 30, -30, 30), fov_half_angle_deg=180.0,
                                n_people=(12, 12), n_clutter=(50, 50), clutter_weights=OUTDOOR_CLUTTER_WEIGHTS,
                                allow_occlusion=allow_occlusion)

    # a 32-beam scan: hundreds of points on an unoccluded person a few metres away, tens beyond 12 m
    frame = render(street(False), "hdl32", Mount(0.0, 0.0, 1.8, 0.0, 0.0), np.random.default_rng(1))
    people = [o for o in frame.objects if o["is_person"]]
    rng_m = np.array([np.hypot(o["x_m"], o["y_m"]) for o in people])
    pts = np.array([o["visible_points"] for o in people])
    assert rng_m.max() > 15.0
    assert pts[rng_m > 12.0].max() < 60
    assert pts[rng_m < 6.0].min() > 150
    scene = street(True)
    kinds = {o.kind for o in scene.objects if not o.is_person}
    assert kinds <= set(OUTDOOR_CLUTTER_KINDS) and {"tree", "street_pole", "car"} <= kinds
    frame = render(scene, "hdl32", Mount(0.0, 0.0, 1.8, 0.0, 0.0), np.random.default_rng(1))
    cands = [c for c in segment(frame.points.astype(float)) if c.gated]
    labels = label_clusters(frame, cands)
    kind_of = {o["id"]: o["kind"] for o in frame.objects}
    negatives = set()
    for c, lab in zip(cands, labels, strict=True):
        ids, counts = np.unique(frame.object_id[c.indices], return_counts=True)
        if lab == 0:
            negatives.add(kind_of.get(int(ids[np.argmax(counts)]), "floor"))
    # thin vertical street objects and flat-faced blocks pass the size gate: the classifier must learn
    # to reject them
    assert {"tree", "street_pole"} <= negatives and negatives & {"cabinet", "panel"}


def test_indoor_scenes_draw_only_indoor_clutter_and_training_streets_outdoor():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        indoor = random_scene(np.random.default_rng(0), n_clutter=(30, 30), area=(0.8, 12.0, -12.0, 12.0))
    assert {o.kind for o in indoor.objects if not o.is_person} <= {*CLUTTER_KINDS, "pram"}  # prams with pushers
    outdoor = [random_rig(np.random.default_rng(k), "hdl32")[1].get("clutter_weights") for k in range(40)]
    assert 8 < sum(w is OUTDOOR_CLUTTER_WEIGHTS for w in outdoor) < 40
