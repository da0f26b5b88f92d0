"""Real frames in training and leave-one-dataset-out model choice: the selection by the worst
left-out dataset, the real clusters' labels, the augmentation, the gradient-boosted trees' file."""

import json

import numpy as np
import pytest

from pedcal.cli import main
from pedcal.detect import lodo
from pedcal.detect.detection import Box, Candidate, load_classifier
from pedcal.detect.features import N_FEATURES
from pedcal.detect.gbt import GradientBoostedTrees
from pedcal.detect.real_eval import augment_frame, dataset_of, estimate_rings, label_real_clusters


def _m(recall, fp):
    return dict(recall_near=recall, fp_near_per_frame=fp)


def test_selection_picks_the_best_worst_dataset_not_the_best_mean():
    # "steady" is never great, "spiky" is excellent on two datasets and poor on the third: its mean
    # score is higher, its worst lower.
    results = {
        "steady": {0.5: {"kitti": _m(0.80, 0.8), "av2": _m(0.78, 0.9), "sustech": _m(0.82, 0.7)}},
        "spiky": {0.5: {"kitti": _m(1.00, 0.0), "av2": _m(0.50, 0.1), "sustech": _m(1.00, 0.0)}},
    }
    s = {n: [lodo.dataset_score(m["recall_near"], m["fp_near_per_frame"]) for m in r[0.5].values()]
         for n, r in results.items()}
    assert np.mean(s["spiky"]) > np.mean(s["steady"]) and min(s["spiky"]) < min(s["steady"])
    name, threshold, by_d = lodo.select_config(results)
    assert name == "steady" and threshold == 0.5 and by_d is results["steady"][0.5]
    # thresholds compete the same way within one configuration
    by_t = {0.3: results["spiky"][0.5], 0.6: results["steady"][0.5]}
    assert lodo.select_config({"one": by_t})[1] == 0.6
    # the mean breaks a tie of the worst
    tie = {"a": {0.5: {"x": _m(0.85, 2.0), "y": _m(0.85, 1.0)}}, "b": {0.5: {"x": _m(0.85, 2.0), "y": _m(0.95, 0.5)}}}
    assert lodo.select_config(tie)[0] == "b"
    with pytest.raises(ValueError):
        lodo.select_config({})


def test_dataset_score_is_the_lesser_shortfall():
    assert lodo.dataset_score(0.85, 1.0) == pytest.approx(1.0)
    assert lodo.dataset_score(0.425, 0.5) == pytest.approx(0.5)  # recall half its target, FP half theirs
    assert lodo.dataset_score(1.0, 4.0) == pytest.approx(0.25)
    assert lodo.dataset_score(float("nan"), 2.0) == pytest.approx(0.5)  # no pedestrian: FP alone
    assert lodo.dataset_score(0.0, 0.0) == 0.0


def _rings_frame(n_rings=64, per_ring=400, seed=0):
    """A spinning LIDAR's returns off a wall ring at 10 m: ``n_rings`` lines 0.4 deg apart."""
    rng = np.random.default_rng(seed)
    el = np.radians(-20.0 + 0.4 * np.repeat(np.arange(n_rings), per_ring) + rng.normal(0, 0.01, n_rings * per_ring))
    az = rng.uniform(-np.pi, np.pi, n_rings * per_ring)
    r = 10.0
    pts = np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el),
                           rng.uniform(0, 1, len(az))])
    return pts, np.repeat(np.arange(n_rings), per_ring)


def test_rings_are_recovered_from_the_elevation_angle():
    pts, truth = _rings_frame()
    rings = estimate_rings(pts)
    assert rings.max() + 1 == 64 and (rings == truth).all()
    assert len(estimate_rings(np.zeros((0, 4)))) == 0


def test_augmentation_drops_beams_and_is_seeded():
    pts, _ = _rings_frame()
    out = [augment_frame(pts, np.random.default_rng([1, k])) for k in range(40)]
    again = augment_frame(pts, np.random.default_rng([1, 0]))
    assert (again[0] == out[0][0]).all() and again[1] == out[0][1]
    beams = [(o, w) for o, w in out if "beams" in w and "thinning" not in w]
    assert beams
    for o, w in beams:
        assert estimate_rings(o).max() + 1 == w["beams"]
    kinds = {w["intensity"] for _, w in out}
    assert kinds == {"keep", "units", "factor", "absent"}
    for o, w in out:
        if w["intensity"] == "absent":
            assert (o[:, 3] == 0).all()
        if w["intensity"] == "units":
            assert o[:, 3].max() > 200  # 0-1 reflectance turned into 0-255 units


def _cand(idx):
    return Candidate(np.asarray(idx), Box(0, 0, 0.5, 0.3, 0.0), 1.7, True)


def test_real_clusters_labels():
    """Person when its points mostly lie in one Pedestrian box (and it holds most of that box's
    points), left out when mixed or a fragment, negative otherwise (a cyclist box included)."""
    rng = np.random.default_rng(2)
    person = np.column_stack([rng.uniform(4.8, 5.2, 100), rng.uniform(-0.2, 0.2, 100), rng.uniform(0.1, 1.7, 100)])
    pole = np.column_stack([rng.uniform(7.0, 7.05, 30), rng.uniform(2.0, 2.05, 30), rng.uniform(0.1, 2.0, 30)])
    cyclist = np.column_stack([rng.uniform(9.0, 10.5, 80), rng.uniform(-3.2, -2.8, 80), rng.uniform(0.1, 1.7, 80)])
    pts = np.vstack([person, pole, cyclist])
    boxes = [dict(type="Pedestrian", id="1", cx=5.0, cy=0.0, cz=0.9, length=0.5, width=0.5, height=1.8, yaw=0.0),
             dict(type="Cyclist", id="2", cx=9.75, cy=-3.0, cz=0.9, length=1.8, width=0.6, height=1.8, yaw=0.0)]
    whole, fragment = _cand(np.arange(100)), _cand(np.arange(30))
    mixed = _cand(np.r_[np.arange(30), 100 + np.arange(30), 130 + np.arange(40)])  # 30 of 100 in the box
    cands = [whole, fragment, mixed, _cand(100 + np.arange(30)), _cand(130 + np.arange(80))]
    assert label_real_clusters(pts, cands, boxes).tolist() == [1, -1, -1, 0, 0]
    assert label_real_clusters(pts, cands, boxes[1:]).tolist() == [0, 0, 0, 0, 0]


def test_dataset_names():
    from pathlib import Path

    assert dataset_of(Path("/d/lidar_people_train/kitti_000142.pcd")) == "kitti"
    assert dataset_of(Path("/d/lidar_people_train/av2_7fab2350_315966265259836000.pcd")) == "av2"
    assert dataset_of(Path("/d/sustech_points/000950.pcd")) == "sustech_points"


def test_trees_round_trip_with_metadata(tmp_path):
    rng = np.random.default_rng(7)
    X = rng.normal(size=(400, N_FEATURES))
    y = (X[:, 0] + 0.5 * X[:, 5] > 0).astype(int)
    m = GradientBoostedTrees(n_estimators=30, seed=3).fit(X, y, sample_weight=np.linspace(1, 2, 400))
    assert (m.predict(X) == y).mean() > 0.9
    m.set_threshold(lodo.probability_decision(m, 0.7))
    p = m.predict_proba(X)
    assert ((p >= 0.5) == (GradientBoostedTrees(n_estimators=30, seed=3).fit(X, y, np.linspace(1, 2, 400))
                           .predict_proba(X) >= 0.7)).all()
    m.metadata_ = dict(intensity="frame", lodo={"kitti": {"recall_near": 0.9}})
    m.save(tmp_path / "a.npz")
    m.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    back = load_classifier(tmp_path / "a.npz")
    assert isinstance(back, GradientBoostedTrees) and back.metadata_ == m.metadata_
    assert back.predict_proba(X) == pytest.approx(p)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(Exception, match="bad.npz"):
        load_classifier(tmp_path / "bad.npz")


def test_detect_eval_prints_the_stored_lodo_table(tmp_path, capsys):
    rng = np.random.default_rng(8)
    X = rng.normal(size=(300, N_FEATURES))
    m = GradientBoostedTrees(n_estimators=5).fit(X, (X[:, 0] > 0).astype(int))
    bands = [dict(band_m=[0.0, 10.0], people=4, found=3, false_positives=1)]
    m.metadata_ = dict(intensity="frame", lodo={"kitti": dict(recall_near=0.75, fp_near_per_frame=0.25, frames=4,
                                                              people_near=4, found_near=3, bands=bands)})
    m.save(tmp_path / "g.npz")
    assert main(["detect-eval", "--frames", "1", "--model", str(tmp_path / "g.npz")]) == 0
    out = capsys.readouterr().out
    assert "leave-one-dataset-out" in out and "kitti" in out and "0.750" in out and "0-10: 3/4 fp 1" in out
    assert main(["detect-eval", "--frames", "1", "--model", str(tmp_path / "g.npz"), "--json"]) == 0
    assert "recall" in json.loads(capsys.readouterr().out)


def test_detect_eval_real_without_a_folder_runs_every_labelled_folder(tmp_path, capsys):
    from test_real_eval import _labelled_folder

    root = tmp_path / "data"
    root.mkdir()
    folder = _labelled_folder(root, np.random.default_rng(0))
    (root / "empty").mkdir()
    (folder / "000001.bin").rename(folder / "kitti_000001.bin")
    (folder / "000001.json").rename(folder / "kitti_000001.json")
    assert main(["detect-eval", "--real", "--data-dir", str(root)]) == 0
    out = capsys.readouterr().out
    assert "kitti within 15 m, >= 10 points: recall 1.000 of 1" in out
    assert main(["detect-eval", "--real", "--data-dir", str(tmp_path / "nowhere")]) == 2
    assert main(["detect-eval", "--real", "--data-dir", str(root / "empty")]) == 2


def test_real_clusters_are_what_detect_file_classifies(tmp_path):
    """The training clusters of a real frame (copy 0) are the gated clusters ``detect_file`` scores:
    same count, same box centres; the labelled pedestrian is a person, the car is not."""
    from test_real_eval import _labelled_folder

    from pedcal.detect.files import detect_file

    root = tmp_path / "data"
    root.mkdir()
    folder = _labelled_folder(root, np.random.default_rng(0))
    recs = lodo.real_clusters(root, copies=1, seed=0)
    assert [(r.dataset, r.copy) for r in recs] == [("frames", 0), ("frames", 1)]
    dets = detect_file(folder / "000001.bin").detections
    assert recs[0].table["centres"] == pytest.approx(np.array([[d.x, d.y] for d in dets]))
    assert recs[0].y.tolist().count(1) == 1 and len(recs[0].y) == len(dets)
    assert recs[0].X["frame"].shape == (len(dets), N_FEATURES)
    assert recs[0].table["ped_points"].tolist()[0] > 100
    assert recs[1].table is None


def test_the_shipped_general_model_is_the_families_choice_with_its_lodo_table():
    from pedcal.detect.detection import load_model
    from pedcal.detect.train import MODEL_FAMILIES

    m = load_model()
    fam = MODEL_FAMILIES["general"]
    assert m.metadata_["config"] == lodo.asdict(fam.config) and m.metadata_["threshold"] == fam.threshold
    assert m.predict_proba(np.zeros((1, m.n_features_))).shape == (1,)
    table = m.metadata_["lodo"]
    assert set(table) == {"av2", "kitti", "sustech_points"}
    for row in table.values():
        assert row["people_near"] == sum(b["people"] for b in row["bands"][:lodo.N_NEAR_BANDS])
        assert 0.0 <= row["recall_near"] <= 1.0 and row["fp_near_per_frame"] >= 0.0
    # the selection stored with it: the chosen configuration has the best worst left-out dataset
    rows = m.metadata_["selection"]
    best = max(rows, key=lambda r: (r["worst"], r["mean"]))
    assert best["config"] == fam.config.name() and best["threshold"] == fam.threshold


def test_detect_eval_lodo_recomputes_the_table(tmp_path, capsys):
    """``--lodo`` retrains the model's configuration without each dataset and prints its table."""
    from dataclasses import asdict

    from test_real_eval import _labelled_folder

    root = tmp_path / "data"
    root.mkdir()
    _labelled_folder(root, np.random.default_rng(0))
    rng = np.random.default_rng(9)
    X = rng.normal(size=(200, N_FEATURES))
    m = GradientBoostedTrees(n_estimators=5).fit(X, (X[:, 0] > 0).astype(int))
    config = lodo.Config("gbt", "raw", N_FEATURES, 5.0, 0, 20)
    m.metadata_ = dict(intensity="raw", config=asdict(config), simulated_frames=6, real_copies=0, seed=0,
                       threshold=0.3)
    m.save(tmp_path / "g.npz")
    assert main(["detect-eval", "--frames", "1", "--model", str(tmp_path / "g.npz"), "--lodo",
                 "--data-dir", str(root)]) == 0
    out = capsys.readouterr().out
    assert "(recomputed)" in out and "frames      1" in out and "0-10: 1/1" in out
    m.metadata_ = {}
    m.save(tmp_path / "h.npz")
    assert main(["detect-eval", "--frames", "1", "--model", str(tmp_path / "h.npz"), "--lodo"]) == 2
    assert "train-detector" in capsys.readouterr().err
