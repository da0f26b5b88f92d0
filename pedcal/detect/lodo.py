"""Real labelled frames in training, and leave-one-dataset-out (LODO) model choice.

Real clusters. Every labelled frame of every folder of the real recordings
(``pedcal.detect.real_eval.labelled_folders``) is prepared as ``pedcal detect`` prepares a file
(density, ground: ``real_eval.prepared_frame``) and segmented as the detector segments it
(``detection.gated_candidates``); each gated cluster is labelled from the boxes
(``real_eval.label_real_clusters``: a person when its points mostly lie in one Pedestrian box;
every other gated cluster, cyclists, bicycles, bollards, signs, cars and unlabelled street
furniture included, a negative). Besides the frame itself, ``copies`` augmented versions of it
(``real_eval.augment_frame``: scan lines dropped to 16 or 32, range-dependent thinning,
intensity in other units or absent) go through the same steps, so that one model serves sensors
it never saw. Copy k of frame F draws from ``np.random.default_rng([REAL_STREAM, seed, crc32(F), k])``.

LODO. The datasets are the frames' ``real_eval.dataset_of`` (KITTI, Argoverse 2, SUSTech): each
in turn is left out, a model is trained on the simulated clusters and every other dataset's real
clusters (all copies), and the left-out dataset's own frames (not augmented) are scored as
``pedcal detect-eval --real`` scores them: recall within ``NEAR_M`` (15 m) of the pedestrians
with at least ``MIN_POINTS`` (10) points, false persons per frame within 15 m, and per range
band. The two Argoverse sweeps 0.1 s apart are one dataset, so never on both sides. A
configuration (classifier, intensity mode, feature set, weight of the real clusters) and a
decision threshold are chosen by their *worst* left-out dataset (``select_config``): per dataset
the shortfall min(recall / REAL_TARGET_RECALL, REAL_TARGET_FP / false persons per frame), the
least of these over the datasets is maximized; the mean over datasets breaks ties only.
"""

from __future__ import annotations

import logging
import time
import zlib
from dataclasses import asdict, dataclass

import numpy as np

from pedcal.detect.real_eval import NEAR_M, RANGE_BANDS_M

REAL_STREAM = 7404
REAL_COPIES = 6  # augmented versions of each real frame, besides the frame itself
REAL_TARGET_RECALL = 0.85  # within NEAR_M, pedestrians with >= MIN_POINTS points
REAL_TARGET_FP = 1.0  # false persons per frame within NEAR_M
THRESHOLDS = tuple(np.round(np.arange(0.2, 0.91, 0.05), 2))
N_NEAR_BANDS = int(np.searchsorted([b[1] for b in RANGE_BANDS_M], NEAR_M, side="right"))


@dataclass(frozen=True)
class Config:
    """One candidate of the model choice."""

    classifier: str = "gbt"  # "gbt" (GradientBoostedTrees) or "adaboost" (RealAdaBoost)
    intensity: str = "frame"  # pedcal.detect.detection.INTENSITY_MODES
    n_features: int = 273  # N_FEATURES, or N_FEATURES_BEFORE_G5 (without block g5)
    real_weight: float = 5.0  # weight of a real cluster against a simulated one
    tree_depth: int = 0  # RealAdaBoost's partitions
    n_rounds: int = 300  # boosting rounds (trees)

    def name(self) -> str:
        clf = self.classifier + (f"-d{self.tree_depth}" if self.classifier == "adaboost" else "")
        return f"{clf} int={self.intensity} f={self.n_features} w={self.real_weight:g} r={self.n_rounds}"


@dataclass
class RealClusters:
    """The real training clusters of one frame copy."""

    dataset: str
    frame: str
    copy: int  # 0: the frame itself
    X: dict  # intensity mode -> (n, N_FEATURES)
    y: np.ndarray  # (n,) 1 person, 0 not, -1 left out
    table: dict | None  # copy 0: real_eval.frame_scores_table, to score the frame


def real_clusters(data_dir=None, copies: int = REAL_COPIES, seed: int = 0, modes=("raw", "frame", "none"),
                  progress: bool = False, detect_options=None) -> list[RealClusters]:
    """Every labelled real frame and ``copies`` augmented copies of it, as RealClusters."""
    from pedcal.detect.detection import candidate_features, gated_candidates
    from pedcal.detect.pointcloud_io import read_point_cloud_report
    from pedcal.detect.real_eval import (
        augment_frame,
        dataset_of,
        frame_pairs,
        frame_scores_table,
        label_real_clusters,
        labelled_folders,
        prepared_frame,
        read_boxes,
    )

    out = []
    t0 = time.monotonic()
    for folder in labelled_folders(data_dir):
        for cloud, label in frame_pairs(folder):
            raw = read_point_cloud_report(cloud).points
            boxes = read_boxes(label)
            for k in range(copies + 1):
                if k:
                    rng = np.random.default_rng([REAL_STREAM, seed, zlib.crc32(cloud.stem.encode()), k])
                    pts_k, _ = augment_frame(raw, rng)
                else:
                    pts_k = raw
                pts, height, xy = prepared_frame(pts_k, **(detect_options or {}))
                pts, steps, _, cands = gated_candidates(pts, sensor_height_m=height, sensor_xy_m=xy)
                groups = [c.indices for c in cands]
                X = {m: candidate_features(pts, groups, steps, m) for m in modes}
                out.append(RealClusters(dataset_of(cloud), cloud.stem, k, X, label_real_clusters(pts, cands, boxes),
                                        frame_scores_table(pts, cands, boxes, raw) if k == 0 else None))
            if progress:
                logging.getLogger(__name__).info(f"  real frame {cloud.stem}: {copies + 1} copies "
                                                 f"({time.monotonic() - t0:.0f} s)")
    return out


def stack_real(records: list[RealClusters], mode: str, n_features: int, leave_out: str | None = None):
    """(X, y) of the labelled clusters of every record but those of dataset ``leave_out``."""
    keep = [r for r in records if r.dataset != leave_out]
    if not keep:
        return np.zeros((0, n_features)), np.zeros(0, dtype=np.int64)
    X = np.vstack([r.X[mode][:, :n_features] for r in keep])
    y = np.concatenate([r.y for r in keep])
    return X[y >= 0], y[y >= 0]


def fit_config(config: Config, X_sim: np.ndarray, y_sim: np.ndarray, X_real: np.ndarray, y_real: np.ndarray,
               seed: int = 0):
    """A classifier of ``config`` trained on simulated and real clusters, the real ones weighted
    ``config.real_weight`` (sample weights of LightGBM; RealAdaBoost's initial weights)."""
    from pedcal.detect.adaboost import RealAdaBoost
    from pedcal.detect.gbt import GradientBoostedTrees

    X = np.vstack([X_sim[:, :config.n_features], X_real[:, :config.n_features]])
    y = np.concatenate([y_sim, y_real])
    w = np.concatenate([np.ones(len(y_sim)), np.full(len(y_real), config.real_weight)])
    if config.classifier == "gbt":
        model = GradientBoostedTrees(n_estimators=config.n_rounds, seed=seed).fit(X, y, sample_weight=w)
    elif config.classifier == "adaboost":
        model = RealAdaBoost(n_rounds=config.n_rounds, n_bins=16, seed=seed, tree_depth=config.tree_depth)
        model.fit(X, y, sample_weight=w)
    else:
        raise ValueError(f"unknown classifier {config.classifier!r}")
    model.metadata_ = dict(intensity=config.intensity, config=asdict(config))
    return model


def probability_decision(model, probability: float) -> float:
    """The decision value F at which ``model.predict_proba`` is ``probability``: log-odds for
    GradientBoostedTrees, half of them for RealAdaBoost (P = 1 / (1 + exp(-2F)))."""
    logit = float(np.log(probability / (1.0 - probability)))
    return logit if hasattr(model, "booster_") else 0.5 * logit


def dataset_metrics(tables: list[dict], scores: list[np.ndarray], threshold: float) -> dict:
    """Recall within NEAR_M (pedestrians with >= MIN_POINTS points), false persons per frame
    within NEAR_M, and per band, of one dataset's frames at ``threshold``."""
    from pedcal.detect.real_eval import score_frame

    n_bands = len(RANGE_BANDS_M)
    people, found, fp = np.zeros(n_bands, int), np.zeros(n_bands, int), np.zeros(n_bands, int)
    fp_near = 0
    for t, s in zip(tables, scores, strict=True):
        r = score_frame(t, s, threshold)
        people += r["people"]
        found += r["found"]
        fp += r["false_positives"]
        fp_near += r["false_near"]
    p_near, f_near = int(people[:N_NEAR_BANDS].sum()), int(found[:N_NEAR_BANDS].sum())
    return dict(recall_near=f_near / p_near if p_near else float("nan"), people_near=p_near, found_near=f_near,
                fp_near_per_frame=fp_near / max(len(tables), 1), frames=len(tables),
                bands=[dict(band_m=[lo, None if not np.isfinite(hi) else hi], people=int(people[i]),
                            found=int(found[i]), false_positives=int(fp[i]))
                       for i, (lo, hi) in enumerate(RANGE_BANDS_M)])


def dataset_score(recall_near: float, fp_near_per_frame: float) -> float:
    """How far one left-out dataset is from the targets, as in ``choose_threshold``: the lesser of
    recall / REAL_TARGET_RECALL and REAL_TARGET_FP / false persons per frame (>= 1: both met).
    A dataset without pedestrians within reach counts by its false persons alone."""
    r = recall_near / REAL_TARGET_RECALL if np.isfinite(recall_near) else np.inf
    f = REAL_TARGET_FP / fp_near_per_frame if fp_near_per_frame > 0 else np.inf
    return float(min(r, f, 1e6))


def lodo(config: Config, sim: tuple[dict, np.ndarray], records: list[RealClusters], seed: int = 0,
         thresholds=THRESHOLDS) -> dict:
    """{threshold: {dataset: dataset_metrics}} of ``config``, each dataset scored by the model
    trained without it."""
    X_sim, y_sim = sim[0][config.intensity], sim[1]
    datasets = sorted({r.dataset for r in records})
    out = {float(t): {} for t in thresholds}
    for d in datasets:
        X_real, y_real = stack_real(records, config.intensity, config.n_features, leave_out=d)
        model = fit_config(config, X_sim, y_sim, X_real, y_real, seed)
        own = [r for r in records if r.dataset == d and r.copy == 0]
        scores = [model.predict_proba(r.X[config.intensity][:, :config.n_features]) if len(r.y) else np.zeros(0)
                  for r in own]
        for t in thresholds:
            out[float(t)][d] = dataset_metrics([r.table for r in own], scores, float(t))
    return out


def select_config(results: dict) -> tuple[str, float, dict]:
    """(config name, threshold, {dataset: metrics}) of the candidate whose *worst* left-out dataset
    is best (``dataset_score``); the mean over the datasets breaks ties. ``results`` is
    {config name: {threshold: {dataset: metrics}}} (``lodo`` of each candidate)."""
    rows = selection_rows(results)
    if not rows:
        raise ValueError("no candidate to select from")
    best = max(rows, key=lambda r: (r["worst"], r["mean"]))  # the first of equals
    return best["config"], best["threshold"], results[best["config"]][best["threshold"]]


def _band_name(band_m) -> str:
    lo, hi = band_m
    return f"{lo:.0f}-{hi:.0f}" if hi is not None else f">{lo:.0f}"


def format_lodo(by_dataset: dict, title: str = "") -> str:
    """The LODO table of one model: per left-out dataset, recall within 15 m, false persons per
    frame within 15 m, and per range band."""
    lines = [title] if title else []
    lines.append(f"{'left out':>15} {'frames':>6} {'recall<15m':>10} {'FP/frame<15m':>12}  per band "
                 "(found/pedestrians >= 10 points, false persons)")
    for d, m in sorted(by_dataset.items()):
        bands = "  ".join(f"{_band_name(b['band_m'])}: {b['found']}/{b['people']} fp {b['false_positives']}"
                          for b in m["bands"])
        lines.append(f"{d:>15} {m['frames']:6d} {m['recall_near']:10.3f} {m['fp_near_per_frame']:12.2f}  {bands}")
    if by_dataset:
        worst = min(by_dataset, key=lambda d: dataset_score(by_dataset[d]["recall_near"],
                                                            by_dataset[d]["fp_near_per_frame"]))
        lines.append(f"worst left-out dataset: {worst}")
    return "\n".join(lines)


def selection_rows(results: dict) -> list[dict]:
    """Per candidate configuration, its best threshold by the worst left-out dataset, with that
    worst score, the mean score and each dataset's recall and false persons per frame."""
    rows = []
    for name, by_t in results.items():
        best = None
        for t, by_d in by_t.items():
            s = [dataset_score(m["recall_near"], m["fp_near_per_frame"]) for m in by_d.values()]
            key = (min(s), float(np.mean(s)))
            if best is None or key > best[0]:
                best = (key, t, by_d)
        (worst, mean), t, by_d = best
        rows.append(dict(config=name, threshold=float(t), worst=worst, mean=mean,
                         datasets={d: [m["recall_near"], m["fp_near_per_frame"]] for d, m in sorted(by_d.items())}))
    return rows


def format_selection(rows: list[dict]) -> str:
    """The candidates of the model choice, best worst left-out dataset first."""
    lines = ["model choice, leave-one-dataset-out (score per dataset: min(recall<15m / 0.85, 1 / FP per frame "
             "<15m); the worst dataset decides):"]
    for r in sorted(rows, key=lambda r: (-r["worst"], -r["mean"])):
        per = "  ".join(f"{d}: {v[0]:.2f}/{v[1]:.2f}" for d, v in r["datasets"].items())
        lines.append(f"  {r['config']:<42} P>={r['threshold']:.2f} worst {r['worst']:.3f} mean {r['mean']:.3f}  "
                     f"(recall/FP) {per}")
    return "\n".join(lines)
