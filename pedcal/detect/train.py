"""Training the person classifier: gated clusters of simulated LIDAR frames, or a user's labelled
clusters, -> Kidono features (and the metric profiles and scan-ray measures after them) -> RealAdaBoost.

Simulated training set. Frame k of seed s draws everything (LIDAR preset, mounts, scene, noise)
from ``np.random.default_rng([TRAIN_STREAM, s, k])``; ``pedcal detect-eval`` uses the stream tag
``EVAL_STREAM`` instead, so its frames never coincide with training frames. The presets mix the
paper's FX8 pair (20 % of the general model's frames; mount height and pitch varied) with longer-range, spinning
(16, 32 and 64 evenly spaced beams, the pandar40's 40 packed about the horizon, and the data
sheets' layouts of VLP-16, VLP-32C, HDL-64E and OS1-64/128 with per-frame nuisances; on a robot
or a car roof, people out to 20 m) and dense LIDARs, so the classifier sees people at many
resolutions and ranges. People wear skirts, coats and backpacks and push prams
(``pedcal.sim.scene.random_person``). The general model is also trained on the real labelled
frames (``train_with_real``, ``pedcal.detect.lodo``), and its classifier, features and threshold
are chosen by leave-one-dataset-out validation; KITTI's single labelled pedestrian is a test.
Scenes come from
``pedcal.sim.scene.random_scene``: static and walking people, people carrying bags, clutter
(walls, pillars, poles, chairs, plants, signs, trolleys, boxes, coat stands); for the spinning
LIDARs, ``OUTDOOR_SHARE`` of the frames are streets instead (``OUTDOOR_CLUTTER_WEIGHTS``: tree
trunks under crowns, lamp and sign posts, bollards, bushes, parked cars, cyclists, kerbs,
utility cabinets, freestanding panels) with
people all round out to 30 m, the thin vertical objects a sparse scan confuses with a person. Each gated cluster is
labelled by the majority ground-truth object id of its points: a person or not; ambiguous
clusters (mixed objects, small fragments of a person) are left out (``label_clusters``). Its
features use the frame's ray steps estimated from the frame's points, as ``detect`` does
(``frame_training_clusters``).
The FX8 pair has a model of its own (``MODEL_FAMILIES["fx8"]``, ``pedcal train-detector --family
fx8``): frames of the FX8 presets alone, with random rigs as above, and depth-3 trees as the
boosting's partitions (``RealAdaBoost(tree_depth=3)``).
The decision threshold is chosen afterwards on frames of a third stream, ``VALIDATION_STREAM``
(``choose_threshold``), so neither the training nor the evaluation frames set it. The
``sparse_tof`` preset is left out of training: ``pedcal detect-eval --preset sparse_tof`` shows
how the classifier carries over to a LIDAR it has not seen.

Labelled clusters (``--labelled PATH``), either

- an ``.npz`` with ``features`` (n, 264) float (``pedcal.detect.features``) and ``labels`` (n,)
  int (1 = person, 0 = not), or
- a directory with sub-directories ``person/`` and ``other/`` holding one cluster per file
  (``.bin``, ``.pcd``, ``.ply`` as ``pedcal detect`` reads them, or ``.npy`` (N, 4)
  ``x, y, z, intensity``), floor-referenced (z = 0 at the floor) and in the sensor's frame
  (horizontal distance from the origin is a feature).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedcal.detect.adaboost import RealAdaBoost, require_npz
from pedcal.detect.detection import (
    FAMILY_CUT_LOW,
    FAMILY_OCCLUDED_LOW,
    FLOOR_TOLERANCE_M,
    candidate_features,
    model_path,
    segment,
)
from pedcal.detect.features import N_FEATURES, N_FEATURES_BEFORE_G5, features_matrix, scan_steps_rad
from pedcal.detect.lodo import REAL_COPIES, Config
from pedcal.errors import DegenerateDataWarning, PedcalInputError

TRAIN_STREAM = 7101
EVAL_STREAM = 7202
VALIDATION_STREAM = 7303  # frames that choose the decision threshold, never trained on
DEFAULT_FRAMES = 6000
# The general model's simulated frames: with the real frames beside them, fewer than the 6000 of
# RealAdaBoost on simulation alone (their LIDARs' frames hold 40-60k points each; training and
# the choice of the model take ~10 min of CPU time with 600).
GENERAL_FRAMES = 600
VALIDATION_SHARE = 0.2  # validation frames per training frame
N_ROUNDS = 600
# The detector's targets: the threshold balances the shortfalls from both (``choose_threshold``).
TARGET_RECALL = 0.95
TARGET_PRECISION = 0.97
N_BINS = 16
COMPANION_SHARE = 0.3  # people given a companion beside them in training scenes
OUTDOOR_SHARE = 0.6  # spinning-LIDAR frames set in a street rather than a hall

# (preset, probability); mounts are drawn per frame in ``random_rig``.
# The general model serves every LIDAR but the FX8 pair (which has its own): most of its frames
# come from the spinning LIDARs with their data sheets' beam layouts (VLP-16, VLP-32C, HDL-64E,
# OS1-64/128), each frame with its own nuisances (``NUISANCE_PRESETS``), beside evenly spaced
# beams, a dense solid-state sensor and some FX8 frames.
TRAIN_PRESETS = (("fx8", 0.15), ("fx8_far", 0.05), ("spin16", 0.05), ("spin32", 0.05), ("hdl32", 0.07),
                 ("hdl64", 0.05), ("pandar40", 0.06), ("solid_dense", 0.07), ("vlp16", 0.1), ("vlp32c", 0.12),
                 ("hdl64e", 0.1), ("os1_64", 0.08), ("os1_128", 0.05))
# Presets whose training frames draw what real sensors vary (``pedcal.sim.lidar.random_nuisances``:
# stray returns below the ground, intensity 0-1, 0-255 or absent, range noise, dropout).
NUISANCE_PRESETS = ("vlp16", "vlp32c", "hdl64e", "os1_64", "os1_128")
FX8_TRAIN_PRESETS = (("fx8", 0.8), ("fx8_far", 0.2))


# The general model's classifier and threshold, chosen by leave-one-dataset-out validation
# (``pedcal train-detector --select``, ``pedcal.detect.lodo.select_config``; see README).
GENERAL_CONFIG = Config(classifier="gbt", intensity="raw", n_features=N_FEATURES, real_weight=5.0, n_rounds=300)
GENERAL_THRESHOLD = 0.3
LODO_TITLE = "leave-one-dataset-out (each real dataset scored by a model trained without it):"
CANDIDATE_CONFIGS = (
    Config("gbt", "frame", N_FEATURES, 5.0),
    Config("gbt", "none", N_FEATURES, 5.0),
    Config("gbt", "raw", N_FEATURES, 5.0),
    Config("gbt", "frame", N_FEATURES_BEFORE_G5, 5.0),  # without block g5
    Config("adaboost", "raw", N_FEATURES_BEFORE_G5, 5.0, 0, 300),  # the paper's classifier, Kidono-style features
    Config("adaboost", "frame", N_FEATURES, 5.0, 0, 300),
)


@dataclass(frozen=True)
class ModelFamily:
    """How one shipped model is trained (``pedcal train-detector --family NAME``); the detector
    picks a frame's family with ``pedcal.detect.detection.model_family``."""

    presets: tuple[tuple[str, float], ...]  # (LIDAR preset, probability) of the training frames
    frames: int  # simulated training frames by default
    n_rounds: int
    tree_depth: int  # RealAdaBoost's partitions: 0 one feature's bins, D > 0 depth-D trees
    # With a Config (pedcal.detect.lodo): that classifier, trained on the simulated frames and the
    # real labelled frames (augmented), at the decision threshold ``threshold`` (P(person)), both
    # chosen by leave-one-dataset-out validation. None: RealAdaBoost on simulated frames alone,
    # its threshold chosen on simulated validation frames.
    config: Config | None = None
    threshold: float | None = None


# "general": every trained LIDAR, simulated and real frames, the classifier of GENERAL_CONFIG (chosen by
# leave-one-dataset-out validation); its RealAdaBoost rounds and depth serve train_detector (the
# baseline on simulated frames alone, or a user's labelled clusters).
# "fx8": the FX8 pair alone. Its clusters range from a dozen points at 5 m to thousands of a near
# person cut at the knees and the head by the 50 deg vertical field of view; what a height, a
# width or a point count says depends on the range, which a sum of one-feature curves cannot
# express: on its validation clusters recall 0.91 and precision 0.93 with them, 0.94 and 0.96
# with depth-2 trees, 0.946 and 0.967 with depth-3 trees (16000 frames each). Its frames cost
# ~20 ms each, so it gets more of them (8000 -> 16000 frames: recall 0.938 -> 0.942, depth 2).
MODEL_FAMILIES = {
    "general": ModelFamily(TRAIN_PRESETS, GENERAL_FRAMES, N_ROUNDS, 0, GENERAL_CONFIG, GENERAL_THRESHOLD),
    "fx8": ModelFamily(FX8_TRAIN_PRESETS, 16000, 400, 3),
}


def random_rig(rng: np.random.Generator, preset: str):
    """(mounts, scene keyword arguments) for one training frame of ``preset``. Scenes hold more
    clutter than the evaluation's default (5-14 objects, not 3-10): hard negatives (plants, coat
    stands, signs) are what the classifier must learn to reject. Spinning LIDARs are mounted on
    a robot (0.8-1.5 m) or a car roof (1.5-2.0 m) and see people out to 20 m (a 32-beam sensor
    puts ~15 points on a person at 30 m, too few to classify), in a larger and busier scene."""
    from pedcal.sim.lidar import LIDAR_PRESETS, Mount, fx8_pair_mounts
    from pedcal.sim.scene import OUTDOOR_CLUTTER_WEIGHTS

    lidar = LIDAR_PRESETS[preset]
    if preset.startswith("fx8"):
        mounts = fx8_pair_mounts(height_m=float(rng.uniform(0.7, 1.3)), pitch_deg=float(rng.uniform(-5, 10)))
        far = min(lidar.max_range_m, 7.0)
        return mounts, dict(area=(0.8, far, -far, far), fov_half_angle_deg=60.0, n_clutter=(5, 14))
    if lidar.fov_horizontal_deg >= 360.0:
        height = float(rng.uniform(1.5, 2.0)) if rng.random() < 0.5 else float(rng.uniform(0.8, 1.5))
        far = min(lidar.max_range_m, 20.0)
        mount = Mount(0.0, 0.0, height, 0.0, float(rng.uniform(-2, 2)))
        if rng.random() < OUTDOOR_SHARE:
            # A street: people and street clutter (trunks, poles, bollards, cars, cyclists) all round
            # out to 30 m, where a 32-beam scan holds a person in ~15-40 points.
            far = min(lidar.max_range_m, 30.0)
            return mount, dict(area=(-far, far, -far, far), fov_half_angle_deg=180.0, n_people=(3, 14),
                               n_clutter=(25, 60), clutter_weights=OUTDOOR_CLUTTER_WEIGHTS)
        return mount, dict(area=(1.5, far, -far, far), fov_half_angle_deg=60.0, n_people=(2, 10),
                           n_clutter=(10, 30))
    far = min(lidar.max_range_m, 9.0)
    mount = Mount(0.0, 0.0, float(rng.uniform(0.8, 1.9)), 0.0, float(rng.uniform(-3, 5)))
    return mount, dict(area=(0.8, far, -far, far), fov_half_angle_deg=min(lidar.fov_horizontal_deg / 2, 60.0),
                       n_clutter=(5, 14))


def simulated_frame(stream: int, seed: int, k: int, preset: str | None = None,
                    presets: tuple[tuple[str, float], ...] = TRAIN_PRESETS):
    """One simulated frame (a LidarFrame) of the stream. ``preset`` None draws one from
    ``presets`` (default TRAIN_PRESETS) with a random rig; "fx8" is the paper's pair at its default
    mounts in a default scene; another preset gets a random rig and scene as in training
    (``random_rig``)."""
    from pedcal.sim.lidar import fx8_pair_mounts, random_nuisances, render
    from pedcal.sim.scene import random_scene

    rng = np.random.default_rng([stream, seed, k])
    if preset is None:
        names, p = zip(*presets, strict=True)
        preset = str(rng.choice(names, p=np.asarray(p) / sum(p)))
        mounts, scene_kw = random_rig(rng, preset)
    elif preset == "fx8":
        mounts, scene_kw = fx8_pair_mounts(), {}
    else:
        mounts, scene_kw = random_rig(rng, preset)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # objects that did not fit into a scene are simply absent
        scene = random_scene(rng, **scene_kw)
    if scene_kw:  # training rigs (not the paper's default evaluation scene): people in pairs too
        add_companions(scene, rng)
    lidar = random_nuisances(preset, rng) if preset in NUISANCE_PRESETS else preset
    return render(scene, lidar, mounts, rng)


def add_companions(scene, rng: np.random.Generator, share: float = COMPANION_SHARE) -> int:
    """Give a ``share`` of the people a companion walking or standing beside them, shoulder to
    shoulder (centres 0.45-0.7 m apart across the heading, same velocity), where it overlaps
    nothing else: people in pairs merge into one wide cluster that ``segment`` must cut at
    the heads. Returns how many were added."""
    from pedcal.sim.scene import random_person

    added = 0
    for p in list(scene.people):
        if rng.random() >= share:
            continue
        side = rng.choice([-1.0, 1.0]) * rng.uniform(0.45, 0.7)
        x = p.x_m - np.sin(p.yaw_rad) * side
        y = p.y_m + np.cos(p.yaw_rad) * side
        mate = random_person(rng, static=p.velocity_mps == (0.0, 0.0))
        clear = all(np.hypot(x - c[0], y - c[1]) >= c[2] + mate.radius_m
                    for o in scene.objects if o is not p for c in o.collision_circles())
        if clear:
            mate.x_m, mate.y_m = float(x), float(y)
            mate.yaw_rad = float(p.yaw_rad + rng.normal(0.0, 0.2))
            mate.velocity_mps = p.velocity_mps
            scene.add(mate)
            added += 1
    return added


def label_clusters(frame, candidates, min_purity: float = 0.6, min_person_share: float = 0.5,
                   above_floor: bool = False) -> np.ndarray:
    """Per cluster: 1 when the majority object id of its points is a person, 0 when it is not,
    -1 (ambiguous, left out of training) when fewer than ``min_purity`` of its points share that
    id, or when it holds less than ``min_person_share`` of that person's visible points (a
    fragment: the person's own detection is another cluster). With ``above_floor``, of the
    person's visible points above ``FLOOR_TOLERANCE_M``, the only ones a cluster can hold: a
    person seen only below the knees has a third of those points on the floor's 5 cm."""
    if above_floor:
        ids, n = np.unique(frame.object_id[frame.points[:, 2] > FLOOR_TOLERANCE_M], return_counts=True)
        above = dict(zip(ids.tolist(), n.tolist(), strict=True))
        visible = {o["id"]: above.get(o["id"], 0) for o in frame.objects if o["is_person"]}
    else:
        visible = {o["id"]: o["visible_points"] for o in frame.objects if o["is_person"]}
    labels = np.zeros(len(candidates), dtype=np.int64)
    for i, c in enumerate(candidates):
        ids, counts = np.unique(frame.object_id[c.indices], return_counts=True)
        j = int(np.argmax(counts))
        if counts[j] < min_purity * len(c.indices):
            labels[i] = -1
        elif int(ids[j]) in visible:
            labels[i] = 1 if counts[j] >= min_person_share * visible[int(ids[j])] else -1
    return labels


def frame_training_clusters(frame, family: str = "general", intensity="raw"):
    """(features, labels) of the unambiguous gated clusters of one simulated frame (``label_clusters``),
    segmented as ``detect`` segments the frames of the model ``family``, the features with the
    frame's ray steps as ``detect`` computes them and its intensity read as ``intensity``
    (``pedcal.detect.detection.INTENSITY_MODES``); a tuple of modes gives {mode: features}."""
    pts = frame.points.astype(float)
    steps = scan_steps_rad(pts, frame.sensor_height_m)
    cands = [c for c in segment(pts, cut_low=FAMILY_CUT_LOW[family], occluded_low=FAMILY_OCCLUDED_LOW[family],
                                scan_steps=steps, sensor_xyz=tuple(frame.sensor_positions_base.mean(axis=0)))
             if c.gated]
    lab = label_clusters(frame, cands, above_floor=FAMILY_OCCLUDED_LOW[family])
    groups = [c.indices for c, v in zip(cands, lab, strict=True) if v >= 0]
    modes = (intensity,) if isinstance(intensity, str) else tuple(intensity)
    X = {m: candidate_features(pts, groups, steps, m) if groups else np.zeros((0, N_FEATURES)) for m in modes}
    return (X[intensity] if isinstance(intensity, str) else X), lab[lab >= 0]


def simulated_training_set(frames: int, seed: int = 0, progress: bool = False, *,
                           stream: int = TRAIN_STREAM, family: str = "general", intensity="raw"):
    """(features (n, N_FEATURES), labels (n,)) of every unambiguous gated cluster of ``frames``
    simulated frames of ``stream`` (TRAIN_STREAM, or VALIDATION_STREAM for the threshold), their
    LIDARs drawn from the model ``family``'s presets and segmented as its frames are; with a tuple
    of ``intensity`` modes, ({mode: features}, labels)."""
    modes = (intensity,) if isinstance(intensity, str) else tuple(intensity)
    feats, labels = {m: [] for m in modes}, []
    t0 = time.monotonic()
    presets = MODEL_FAMILIES[family].presets
    for k in range(frames):
        X, y = frame_training_clusters(simulated_frame(stream, seed, k, presets=presets), family, modes)
        if len(y):
            for m in modes:
                feats[m].append(X[m])
            labels.append(y)
        if progress and ((k + 1) % 250 == 0 or k + 1 == frames):
            n = sum(len(v) for v in labels)
            logging.getLogger(__name__).info(f"  simulated {k + 1}/{frames} frames, {n} gated clusters "
                                             f"({time.monotonic() - t0:.0f} s)", extra={"progress": (k + 1, frames)})
    if not labels:
        X = {m: np.zeros((0, N_FEATURES)) for m in modes}
        y = np.zeros(0, dtype=np.int64)
    else:
        X, y = {m: np.vstack(v) for m, v in feats.items()}, np.concatenate(labels)
    return (X[intensity] if isinstance(intensity, str) else X), y


def _read_cluster(path: Path) -> np.ndarray:
    from pedcal.detect.pointcloud_io import read_point_cloud

    if path.suffix.lower() == ".npy":
        try:
            pts = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise PedcalInputError(f"not a .npy array: {e}", path=path) from None
        if not isinstance(pts, np.ndarray):     # an .npz archive named .npy
            pts.close()
            raise PedcalInputError("an .npz archive, expected a .npy array", path=path)
        if pts.ndim != 2 or pts.shape[1] not in (3, 4) or len(pts) == 0 or not np.isfinite(pts).all():
            raise PedcalInputError(f"a cluster .npy is a finite (N, 4) x, y, z, intensity array, got {pts.shape}",
                                   path=path)
        return pts if pts.shape[1] == 4 else np.column_stack([pts, np.zeros(len(pts))])
    return read_point_cloud(path)


def read_labelled(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(features, labels) from a user's labelled clusters (see the module docstring)."""
    path = Path(path)
    if path.is_dir():
        clusters, labels = [], []
        for sub, label in (("person", 1), ("other", 0)):
            files = sorted(p for p in (path / sub).glob("*")
                           if p.suffix.lower() in (".npy", ".bin", ".pcd", ".ply")) if (path / sub).is_dir() else []
            clusters += [_read_cluster(p) for p in files]
            labels += [label] * len(files)
        if not clusters:
            raise PedcalInputError("a labelled-cluster directory needs person/ and other/ sub-directories with "
                                   ".npy/.bin/.pcd/.ply clusters", path=path)
        return features_matrix(clusters), np.asarray(labels, dtype=np.int64)
    if not path.is_file():
        raise PedcalInputError("no such labelled-cluster file or directory", path=path)
    require_npz(path, f"labelled clusters (an .npz with 'features' (n, {N_FEATURES}) and 'labels' (n,), or a "
                      "folder of person/ and other/ clusters)")
    try:
        with np.load(path, allow_pickle=False) as d:
            X, y = np.asarray(d["features"], dtype=float), np.asarray(d["labels"])
    except KeyError as e:
        raise PedcalInputError(f"missing array {e} (expected 'features' (n, {N_FEATURES}) and 'labels' (n,))",
                               path=path) from None
    except (OSError, ValueError) as e:
        raise PedcalInputError(f"not an .npz with 'features' and 'labels': {e}", path=path) from None
    if X.ndim != 2 or X.shape[1] != N_FEATURES:
        raise PedcalInputError(f"'features' must be (n, {N_FEATURES}), got {X.shape}", path=path, column="features")
    if y.shape != (len(X),) or not np.isin(y, (0, 1)).all():
        raise PedcalInputError(f"'labels' must be (n,) = ({len(X)},) of 0/1, got shape {y.shape}", path=path,
                               column="labels")
    bad = np.flatnonzero(~np.isfinite(X).all(axis=1))
    if len(bad):
        raise PedcalInputError("features hold NaN or infinite values", path=path, row=int(bad[0]),
                               column="features")
    return X, y.astype(np.int64)


def choose_threshold(decision: np.ndarray, labels: np.ndarray) -> tuple[float, float, float]:
    """(decision value, recall, precision) of the threshold ``F >= t`` on validation clusters that
    maximizes min(recall / TARGET_RECALL, precision / TARGET_PRECISION): the cut where recall and
    precision fall short of their targets by the same share (both targets met when it is >= 1).
    Unlike the F1 optimum, which is flat and moves with the sample, this crossing of a rising and
    a falling curve is stable. Ties go to the higher threshold (fewer false positives)."""
    order = np.argsort(-decision, kind="stable")
    d, y = decision[order], labels[order] > 0
    tp = np.cumsum(y)  # true positives when the k+1 highest scores are called people
    last = np.r_[np.flatnonzero(np.diff(d) != 0), len(d) - 1]  # one cut per distinct value
    tp, called = tp[last], last + 1
    recall, precision = tp / max(int(y.sum()), 1), tp / called
    k = int(np.argmax(np.minimum(recall / TARGET_RECALL, precision / TARGET_PRECISION)))
    return float(d[last[k]]), float(recall[k]), float(precision[k])


def train_detector(frames: int | None = None, seed: int = 0, labelled: str | Path | None = None, *,
                   family: str = "general", n_rounds: int | None = None, n_bins: int = N_BINS,
                   tree_depth: int | None = None, validation_frames: int | None = None,
                   progress: bool = False) -> RealAdaBoost:
    """Train the RealAdaBoost person classifier of a model ``family`` (``MODEL_FAMILIES``: its
    LIDAR presets, and by default its frames, rounds and tree depth) on simulated frames, or on a
    user's labelled clusters when ``labelled`` is given (then ``frames`` adds simulated frames only
    when it is given too). Deterministic given the arguments.

    With simulated frames, ``validation_frames`` (default VALIDATION_SHARE of them) more frames of
    VALIDATION_STREAM choose the decision threshold (``choose_threshold``: recall and precision
    equally short of their targets on their clusters), stored in the model as its offset so that
    ``is_person`` is still ``P >= 0.5``; ``model.validation_`` holds the threshold's recall and
    precision on those clusters.
    """
    if family not in MODEL_FAMILIES:
        raise PedcalInputError(f"unknown detector model family {family!r}; expected one of "
                               f"{', '.join(MODEL_FAMILIES)}", column="family")
    fam = MODEL_FAMILIES[family]
    n_rounds = fam.n_rounds if n_rounds is None else n_rounds
    tree_depth = fam.tree_depth if tree_depth is None else tree_depth
    X_parts, y_parts = [], []
    if labelled is not None:
        X, y = read_labelled(labelled)
        X_parts.append(X)
        y_parts.append(y)
    n_sim = 0 if labelled is not None and not frames else (fam.frames if frames is None else int(frames))
    if n_sim:
        X, y = simulated_training_set(n_sim, seed, progress, family=family)
        X_parts.append(X)
        y_parts.append(y)
    X, y = np.vstack(X_parts), np.concatenate(y_parts)
    if len(np.unique(y)) < 2:
        raise PedcalInputError(f"training needs people and non-people; got {int(y.sum())} people among "
                               f"{len(y)} clusters", path=labelled)
    if progress:
        logging.getLogger(__name__).info(f"training RealAdaBoost on {len(y)} clusters ({int(y.sum())} people), "
                                         f"{n_rounds} rounds")
    model = RealAdaBoost(n_rounds=n_rounds, n_bins=n_bins, seed=seed, tree_depth=tree_depth)
    model.fit(X, y, progress=progress)
    model.validation_ = None
    n_val = 0 if not n_sim else (max(1, round(VALIDATION_SHARE * n_sim)) if validation_frames is None
                                 else int(validation_frames))
    if n_val:
        if progress:
            logging.getLogger(__name__).info(f"choosing the threshold on {n_val} validation frames")
        X_val, y_val = simulated_training_set(n_val, seed, progress, stream=VALIDATION_STREAM, family=family)
        if len(np.unique(y_val)) == 2:
            t, recall, precision = choose_threshold(model.decision_function(X_val), y_val)
            model.set_threshold(t)
            model.validation_ = dict(decision_threshold=t, recall=recall, precision=precision,
                                     clusters=len(y_val), people=int(y_val.sum()))
    model.training_accuracy_ = float((model.predict(X) == y).mean())
    model.training_size_ = len(y)
    return model


def train_with_real(frames: int | None = None, seed: int = 0, *, family: str = "general", data_dir=None,
                    config: Config | None = None, threshold: float | None = None, select: bool = False,
                    real_copies: int = REAL_COPIES, progress: bool = False):
    """The classifier of a model ``family`` with a Config (``MODEL_FAMILIES``), trained on
    ``frames`` simulated frames and every labelled real frame under ``data_dir`` (default
    ``pedcal.detect.real_eval.default_data_dir``) with ``real_copies`` augmented copies each
    (``pedcal.detect.lodo``); see ``fit_with_real``. A ``data_dir`` given that is no folder is an
    input error; without the default folder a DegenerateDataWarning says the model is trained on
    simulated frames alone. Deterministic given the arguments and
    the data."""
    from pedcal.detect import lodo
    from pedcal.detect.real_eval import default_data_dir

    fam = MODEL_FAMILIES[family]
    n_sim = fam.frames if frames is None else int(frames)
    root = Path(data_dir) if data_dir is not None else default_data_dir()
    records = []
    if data_dir is not None or root.is_dir():   # a --data-dir that is no folder: labelled_folders refuses it
        records = lodo.real_clusters(root, real_copies, seed, progress=progress)
    else:
        warnings.warn(f"no real recordings at {root}: the detector is trained on simulated frames alone and "
                      "no leave-one-dataset-out table can be made", DegenerateDataWarning, stacklevel=2)
    modes = tuple(sorted({c.intensity for c in CANDIDATE_CONFIGS})) if select and records \
        else ((config or fam.config).intensity,)
    sim = simulated_training_set(n_sim, seed, progress, family=family, intensity=modes)
    model = fit_with_real(sim, records, seed, config=config or fam.config,
                          threshold=fam.threshold if threshold is None else threshold, select=select, progress=progress)
    model.metadata_.update(simulated_frames=n_sim, real_copies=real_copies)
    return model


def fit_with_real(sim: tuple[dict, np.ndarray], records: list, seed: int = 0, *, config: Config,
                  threshold: float, select: bool = False, progress: bool = False):
    """A classifier of ``config`` trained on the simulated clusters ``sim`` ({intensity mode:
    features}, labels) and the real ones ``records`` (``lodo.real_clusters``, every copy), whose
    offset puts P(person) = 0.5 at the probability ``threshold``. With ``select``, ``config`` and
    ``threshold`` are chosen anew among ``CANDIDATE_CONFIGS`` and ``lodo.THRESHOLDS`` by
    leave-one-dataset-out validation on these same clusters (``lodo.select_config``: the best
    worst left-out dataset). The model's ``metadata_`` holds the leave-one-dataset-out table of
    its configuration and threshold (``lodo``) and, with ``select``, every candidate's scores."""
    from pedcal.detect import lodo

    log = logging.getLogger(__name__)
    metadata: dict = dict(seed=seed, real_frames=sorted({r.frame for r in records}))
    table = None
    if select and records:
        results = {}
        for c in CANDIDATE_CONFIGS:
            t0 = time.monotonic()
            results[c.name()] = lodo.lodo(c, sim, records, seed)
            if progress:
                log.info(f"  LODO {c.name()} ({time.monotonic() - t0:.0f} s)")
        name, threshold, table = lodo.select_config(results)
        config = next(c for c in CANDIDATE_CONFIGS if c.name() == name)
        metadata["selection"] = lodo.selection_rows(results)
    elif records:
        if progress:
            log.info("leave-one-dataset-out table of the configuration")
        table = lodo.lodo(config, sim, records, seed, thresholds=(threshold,))[float(threshold)]
    if table is not None:
        metadata["lodo"] = table
    X_sim, y_sim = sim[0][config.intensity], sim[1]
    X_real, y_real = lodo.stack_real(records, config.intensity, config.n_features)
    if progress:
        log.info(f"training {config.name()} on {len(y_sim)} simulated clusters ({int(y_sim.sum())} people) and "
                 f"{len(y_real)} real ones ({int(y_real.sum())} people)")
    model = lodo.fit_config(config, X_sim, y_sim, X_real, y_real, seed)
    model.set_threshold(lodo.probability_decision(model, threshold))
    model.metadata_.update(metadata, threshold=float(threshold))
    model.training_size_ = len(y_sim) + len(y_real)
    X = np.vstack([X_sim[:, :config.n_features], X_real[:, :config.n_features]])
    model.training_accuracy_ = float((model.predict(X) == np.concatenate([y_sim, y_real])).mean())
    return model


def train_detector_cli(args) -> int:
    """``pedcal train-detector [--family F] [-o MODEL] [--seed S] [--frames N] [--labelled PATH]``."""
    from pedcal.detect.lodo import format_lodo, format_selection

    family = getattr(args, "family", "general")
    output = Path(args.output) if args.output is not None else model_path(family)
    if MODEL_FAMILIES[family].config is not None and args.labelled is None:
        model = train_with_real(frames=args.frames, seed=args.seed, family=family,
                                data_dir=getattr(args, "data_dir", None), select=getattr(args, "select", False),
                                progress=True)
        model.save(output)
        meta = model.metadata_
        print(f"wrote {output}: {meta['config']} on {model.training_size_} clusters, training accuracy "
              f"{model.training_accuracy_:.4f}, threshold P >= {meta['threshold']:.2f}")
        if "selection" in meta:
            print(format_selection(meta["selection"]))
        if "lodo" in meta:
            print(format_lodo(meta["lodo"], LODO_TITLE))
        return 0
    model = train_detector(frames=args.frames, seed=args.seed, labelled=args.labelled, family=family,
                           progress=True)
    model.save(output)
    print(f"wrote {output}: {model.n_rounds} rounds on {model.training_size_} clusters, "
          f"training accuracy {model.training_accuracy_:.4f}")
    if model.validation_:
        v = model.validation_
        print(f"threshold F >= {v['decision_threshold']:.3f} chosen on {v['clusters']} validation clusters "
              f"({v['people']} people): recall {v['recall']:.4f}, precision {v['precision']:.4f}")
    return 0
