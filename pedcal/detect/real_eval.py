"""``pedcal detect-eval --real DIR``: recall and precision on real labelled point clouds.

A folder holds frames ``NAME.pcd`` (or .bin, .ply, .npy) each with ``NAME.json``, a list of
3-D boxes ``{obj_type, obj_id, psr: {position: {x, y, z}, scale: {x, y, z}, rotation: {z}}}``
(box centre, full size, yaw about z) in the cloud's frame, as SUSTechPOINTS labels them.
``Pedestrian`` boxes are the truth; every other box (cars, riders, ...) is a negative.

Matching: a person detection matches a pedestrian box when its centre lies inside the box's
horizontal footprint grown by ``GROW_M`` (0.3 m) on every side; one detection per box, the
nearest to the box centre first (Hungarian assignment). Unmatched person detections are false
positives. Ranges are horizontal distances from the sensor (the cloud's origin), binned into
``RANGE_BANDS_M``; the per-pedestrian list gives range, points in the box and the verdict, so
every labelled pedestrian is accounted for. With ``out_dir``, a bird's-eye picture of each frame
(points, boxes, detections) is written there.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedcal import jsontext
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.io.inputs import check_records, read_json

GROW_M = 0.3
RANGE_BANDS_M = ((0.0, 10.0), (10.0, 15.0), (15.0, 20.0), (20.0, 30.0), (30.0, np.inf))
NEAR_M = 15.0  # the headline figures: pedestrians and false detections within this range
MIN_POINTS = 10  # ... of pedestrians with at least this many points in their box
PERSON_TYPES = ("Pedestrian",)
CLOUD_SUFFIXES = (".pcd", ".bin", ".ply", ".npy")


def read_boxes(path: Path) -> list[dict]:
    """Boxes of a label file as dicts ``type, id, cx, cy, cz, length, width, height, yaw``."""
    raw = read_json(path, "JSON label file")    # regular file, size capped, depth and digits bounded
    if not isinstance(raw, list):
        raise PedcalInputError("a label file is a JSON list of boxes", path=path)
    out = []
    for row, b in enumerate(raw):
        try:
            p, s, r = b["psr"]["position"], b["psr"]["scale"], b["psr"]["rotation"]
            out.append(dict(type=str(b["obj_type"]), id=str(b.get("obj_id", row)), cx=float(p["x"]),
                            cy=float(p["y"]), cz=float(p["z"]), length=float(s["x"]), width=float(s["y"]),
                            height=float(s["z"]), yaw=float(r["z"])))
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise PedcalInputError(f"box without obj_type / psr.position, scale, rotation ({e})", path=path,
                                   row=row) from None
    return check_records(out, path, finite=("cx", "cy", "cz", "yaw"), positive=("length", "width", "height"))


def in_box(xy: np.ndarray, box: dict, grow_m: float = 0.0) -> np.ndarray:
    """(N,) bool: which horizontal positions lie inside the box's footprint grown by ``grow_m``."""
    c, s = np.cos(box["yaw"]), np.sin(box["yaw"])
    d = np.asarray(xy, dtype=float).reshape(-1, 2) - [box["cx"], box["cy"]]
    u = d[:, 0] * c + d[:, 1] * s
    v = -d[:, 0] * s + d[:, 1] * c
    return (np.abs(u) <= box["length"] / 2 + grow_m) & (np.abs(v) <= box["width"] / 2 + grow_m)


def points_in_box(points: np.ndarray, box: dict) -> int:
    """Number of points inside the 3-D box (in the file's frame, before any floor shift)."""
    inside = in_box(points[:, :2], box)
    dz = np.abs(points[:, 2] - box["cz"]) <= box["height"] / 2
    return int((inside & dz).sum())


def match_boxes(det_xy: np.ndarray, boxes: list[dict], grow_m: float = GROW_M) -> np.ndarray:
    """(k, 2) pairs (detection index, box index), one-to-one, a detection's centre inside the grown box."""
    if len(det_xy) == 0 or not boxes:
        return np.zeros((0, 2), dtype=int)
    ok = np.column_stack([in_box(det_xy, b, grow_m) for b in boxes])
    dist = np.linalg.norm(det_xy[:, None, :] - np.array([[b["cx"], b["cy"]] for b in boxes])[None], axis=2)
    r, c = linear_sum_assignment(np.where(ok, dist, 1e6))
    keep = ok[r, c]
    return np.column_stack([r[keep], c[keep]])


def band_of(range_m: np.ndarray) -> np.ndarray:
    edges = np.array([b[1] for b in RANGE_BANDS_M[:-1]])
    return np.searchsorted(edges, np.asarray(range_m, dtype=float), side="right")


def frame_pairs(folder: Path) -> list[tuple[Path, Path]]:
    """(cloud, label) of every frame in ``folder``: NAME.pcd|.bin|.ply|.npy beside NAME.json. A
    cloud without its label, or a label without its cloud, is left out with a warning naming it."""
    folder = Path(folder)
    if not folder.is_dir():
        raise PedcalInputError("is a file, expected a folder of labelled frames (NAME.pcd beside NAME.json)"
                               if folder.exists() else "no such folder of labelled frames", path=folder)
    pairs, unlabelled = [], []
    for cloud in sorted(p for p in folder.iterdir() if p.suffix.lower() in CLOUD_SUFFIXES):
        label = cloud.with_suffix(".json")
        (pairs.append((cloud, label)) if label.is_file() else unlabelled.append(cloud.name))
    paired = {label.name for _, label in pairs}
    cloudless = sorted(p.name for p in folder.glob("*.json") if p.name not in paired)
    for names, what in ((unlabelled, "point cloud(s) without a NAME.json label file"),
                        (cloudless, "label file(s) without a NAME.pcd|.bin|.ply|.npy cloud")):
        if names and pairs:
            warnings.warn(f"{folder}: {len(names)} {what} left out: {', '.join(names[:5])}"
                          f"{', ...' if len(names) > 5 else ''}", DegenerateDataWarning, stacklevel=2)
    if not pairs:
        raise PedcalInputError("no frame with a label file (NAME.pcd|.bin|.ply|.npy beside NAME.json)", path=folder)
    return pairs


def evaluate_real(folder: str | Path, model=None, out_dir: str | Path | None = None, *, detect_options=None,
                  pairs: list[tuple[Path, Path]] | None = None) -> dict:
    """Per frame and per range band: pedestrians, found, person detections, false positives.

    ``detect_options`` go to ``pedcal.detect.files.detect_file`` (sensor, pose, floor); ``pairs`` are the
    (cloud, label) files to evaluate when the caller has listed them already (``frame_pairs`` of
    ``folder`` otherwise, which warns of the unpaired files again).
    """
    from pedcal.detect.files import detect_file

    if pairs is None:
        pairs = frame_pairs(Path(folder))
    n_bands = len(RANGE_BANDS_M)
    people, found = np.zeros(n_bands, int), np.zeros(n_bands, int)
    dets_band, fp_band = np.zeros(n_bands, int), np.zeros(n_bands, int)
    pedestrians, frame_rows = [], []
    for cloud, label in pairs:
        boxes = read_boxes(label)
        res = detect_file(cloud, model, **(detect_options or {}))
        persons = [d for d in res.detections if d.is_person]
        det_xy = np.array([[d.x, d.y] for d in persons]).reshape(-1, 2)
        ped = [b for b in boxes if b["type"] in PERSON_TYPES]
        pairs_ = match_boxes(det_xy, ped)
        matched_box = dict(zip(pairs_[:, 1].tolist(), pairs_[:, 0].tolist(), strict=True))
        ped_range = np.array([np.hypot(b["cx"], b["cy"]) for b in ped])
        pb = band_of(ped_range)
        np.add.at(people, pb, 1)
        np.add.at(found, pb[list(matched_box)], 1)
        det_range = np.hypot(*det_xy.T) if len(det_xy) else np.zeros(0)
        db = band_of(det_range)
        np.add.at(dets_band, db, 1)
        fp_mask = np.ones(len(persons), bool)
        fp_mask[pairs_[:, 0]] = False
        np.add.at(fp_band, db[fp_mask], 1)
        for j, b in enumerate(ped):
            pedestrians.append(dict(frame=cloud.stem, id=b["id"], range_m=float(ped_range[j]),
                                    points=points_in_box(res.raw_points, b), found=j in matched_box,
                                    score=(float(persons[matched_box[j]].score) if j in matched_box else None)))
        frame_rows.append(dict(frame=cloud.stem, pedestrians=len(ped), found=len(matched_box),
                               detections=len(persons), false_positives=int(fp_mask.sum()),
                               false_positives_near=int((fp_mask & (det_range < NEAR_M)).sum()),
                               floor_shift_m=float(res.floor_shift_m), dropped=res.read.summary()))
        if out_dir is not None:
            bev_picture(Path(out_dir) / f"{cloud.stem}_bev.png", res, boxes, persons, matched_box)

    def ratio(a, b):
        return float(a / b) if b else float("nan")

    bands = [dict(band_m=[lo, None if not np.isfinite(hi) else hi], pedestrians=int(people[i]),
                  found=int(found[i]), recall=ratio(found[i], people[i]), detections=int(dets_band[i]),
                  false_positives=int(fp_band[i]), precision=ratio(dets_band[i] - fp_band[i], dets_band[i]))
             for i, (lo, hi) in enumerate(RANGE_BANDS_M)]
    near = [p for p in pedestrians if p["range_m"] < NEAR_M]
    seen = [p for p in near if p["points"] >= MIN_POINTS]
    n_frames = len(frame_rows)
    fp_near = sum(f["false_positives_near"] for f in frame_rows)
    return dict(frames=frame_rows, bands=bands, pedestrians=pedestrians,
                recall=ratio(sum(found), sum(people)),
                precision=ratio(sum(dets_band) - sum(fp_band), sum(dets_band)),
                recall_near=ratio(sum(p["found"] for p in near), len(near)), pedestrians_near=len(near),
                recall_near_seen=ratio(sum(p["found"] for p in seen), len(seen)), pedestrians_near_seen=len(seen),
                false_positives_near_per_frame=ratio(fp_near, n_frames), near_m=NEAR_M)


def format_real(res: dict) -> str:
    lines = [f"{len(res['frames'])} frames, {len(res['pedestrians'])} labelled pedestrians: recall "
             f"{res['recall']:.3f}, precision {res['precision']:.3f}",
             f"within {res['near_m']:.0f} m: recall {res['recall_near']:.3f} of {res['pedestrians_near']} "
             f"pedestrians, {res['false_positives_near_per_frame']:.2f} false detections per frame",
             f"within {res['near_m']:.0f} m with >= {MIN_POINTS} points: recall {res['recall_near_seen']:.3f} of "
             f"{res['pedestrians_near_seen']} pedestrians",
             f"{'band_m':>10} {'peds':>5} {'found':>5} {'recall':>7} {'dets':>5} {'FP':>4} {'precision':>9}"]
    for b in res["bands"]:
        lo, hi = b["band_m"]
        name = f"{lo:.0f}-{hi:.0f}" if hi is not None else f">{lo:.0f}"
        lines.append(f"{name:>10} {b['pedestrians']:5d} {b['found']:5d} {b['recall']:7.3f} {b['detections']:5d} "
                     f"{b['false_positives']:4d} {b['precision']:9.3f}")
    lines.append(f"{'frame':>8} {'id':>5} {'range_m':>8} {'points':>6}  found")
    for p in sorted(res["pedestrians"], key=lambda p: p["range_m"]):
        lines.append(f"{p['frame']:>8} {p['id']:>5} {p['range_m']:8.2f} {p['points']:6d}  {p['found']}")
    for f in res["frames"]:
        lines.append(f"frame {f['frame']}: {f['found']}/{f['pedestrians']} found, {f['detections']} person "
                     f"detections, {f['false_positives']} false ({f['false_positives_near']} within "
                     f"{res['near_m']:.0f} m), floor {-f['floor_shift_m']:.2f} m" +
                     (f"; {f['dropped']}" if f["dropped"] else ""))
    return "\n".join(lines)


def bev_picture(path: Path, res, boxes: list[dict], persons, matched_box: dict, half_extent_m: float = 30.0):
    """Bird's-eye view of one frame: points (grey, by height), boxes (pedestrians green, others
    blue), person detections (red: false, green: matched), other gated clusters (small grey)."""
    from matplotlib.patches import Polygon

    from pedcal.plotting import new_figure, save_png

    fig = new_figure(8, 8)
    ax = fig.add_subplot(111)
    pts = res.points
    near = (np.abs(pts[:, 0]) < half_extent_m) & (np.abs(pts[:, 1]) < half_extent_m) & (pts[:, 2] > 0.15)
    ax.scatter(pts[near, 0], pts[near, 1], s=0.3, c=np.clip(pts[near, 2], 0, 2.5), cmap="Greys", vmin=-1.0,
               vmax=2.5, linewidths=0, rasterized=True)
    for b in boxes:
        c, s = np.cos(b["yaw"]), np.sin(b["yaw"])
        corners = np.array([[u, v] for u, v in ((1, 1), (-1, 1), (-1, -1), (1, -1))]) * [b["length"] / 2,
                                                                                        b["width"] / 2]
        xy = corners @ np.array([[c, s], [-s, c]]) + [b["cx"], b["cy"]]
        person = b["type"] in PERSON_TYPES
        ax.add_patch(Polygon(xy, closed=True, fill=False, lw=1.0, ec="tab:green" if person else "tab:blue"))
    others = [d for d in res.detections if not d.is_person]
    if others:
        ax.scatter([d.x for d in others], [d.y for d in others], s=6, c="0.6", marker="o", label="gated, not person")
    matched = set(matched_box.values())
    for i, d in enumerate(persons):
        ok = i in matched
        ax.scatter([d.x], [d.y], s=40, marker="x", c="tab:green" if ok else "tab:red")
    ax.scatter([], [], marker="x", c="tab:green", label="detection on a pedestrian")
    ax.scatter([], [], marker="x", c="tab:red", label="false detection")
    ax.plot([0], [0], "k^", ms=6, label="sensor")
    ax.set_xlim(-half_extent_m, half_extent_m)
    ax.set_ylim(-half_extent_m, half_extent_m)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{path.stem}: pedestrian boxes green, other boxes blue")
    ax.legend(loc="upper right", fontsize=7)
    save_png(fig, path)


# ------------------------------------------------------------------------ every labelled folder
def default_data_dir() -> Path:
    """Where the real recordings sit: ``$PEDCAL_DATA`` when set, else ``../shared/data`` beside the
    repository (the checkout holding the ``pedcal`` package)."""
    env = os.environ.get("PEDCAL_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2].parent / "shared" / "data"


def labelled_folders(data_dir: str | Path | None = None) -> list[Path]:
    """The sub-folders of ``data_dir`` (default ``default_data_dir``) holding labelled frames
    (NAME.pcd|.bin|.ply|.npy beside NAME.json), sorted by name."""
    root = Path(data_dir) if data_dir is not None else default_data_dir()
    if not root.is_dir():
        raise PedcalInputError("no folder of real recordings here (give the folder with --data-dir)", path=root)
    out = []
    for sub in sorted(p for p in root.iterdir() if p.is_dir()):
        if any(p.suffix.lower() in CLOUD_SUFFIXES and p.with_suffix(".json").is_file() for p in sub.iterdir()):
            out.append(sub)
    if not out:
        raise PedcalInputError("no sub-folder holds labelled frames (NAME.pcd beside NAME.json)", path=root)
    return out


def dataset_of(cloud: Path) -> str:
    """The dataset a frame belongs to: the prefix of its name before the first '_' when the name
    has one that starts with a letter (``kitti_000142`` -> kitti, ``av2_7fab2350_...`` -> av2: one
    folder may gather frames of several datasets), else its folder's name (``sustech_points``)."""
    head, sep, _ = cloud.stem.partition("_")
    return head.lower() if sep and head[:1].isalpha() else cloud.parent.name


def evaluate_all_real(data_dir: str | Path | None = None, model=None, *, detect_options=None) -> dict:
    """``evaluate_real`` of every frame of every labelled folder (``labelled_folders``), grouped by
    dataset (``dataset_of``): {dataset: result}."""
    out = {}
    for folder in labelled_folders(data_dir):
        by_set: dict[str, list[tuple[Path, Path]]] = {}
        for pair in frame_pairs(folder):
            by_set.setdefault(dataset_of(pair[0]), []).append(pair)
        for name, pairs in sorted(by_set.items()):
            out[name] = evaluate_real(folder, model, detect_options=detect_options, pairs=pairs)
    return out


def format_all_real(results: dict) -> str:
    """One line per dataset and range band, then the totals."""
    lines = ["every labelled pedestrian per range band (peds), found, recall, false persons (FP):",
             f"{'dataset':>15} {'band_m':>7} {'peds':>5} {'found':>5} {'recall':>7} {'FP':>4}"]
    for name, res in results.items():
        for b in res["bands"]:
            lo, hi = b["band_m"]
            band = f"{lo:.0f}-{hi:.0f}" if hi is not None else f">{lo:.0f}"
            lines.append(f"{name:>15} {band:>7} {b['pedestrians']:5d} {b['found']:5d} {b['recall']:7.3f} "
                         f"{b['false_positives']:4d}")
        lines.append(f"{name:>15} within {res['near_m']:.0f} m, >= {MIN_POINTS} points: recall "
                     f"{res['recall_near_seen']:.3f} of {res['pedestrians_near_seen']}, "
                     f"{res['false_positives_near_per_frame']:.2f} false persons per frame "
                     f"({len(res['frames'])} frames)")
    return "\n".join(lines)


# ------------------------------------------------------------- real frames as training clusters
PERSON_SHARE = 0.5  # a cluster is a person when this share of its points lies in one Pedestrian box
MIXED_SHARE = 0.2  # ... left out as ambiguous when between this and PERSON_SHARE
FRAGMENT_SHARE = 0.5  # ... and as a fragment when it holds less than this share of the box's points
LABEL_GROW_M = 0.1  # box footprints grown by this for the labels (boxes are drawn tight)
BEAM_TARGETS = (16, 32)  # augmentation: scan lines kept
RING_BIN_DEG = 0.02
RING_MIN_SEPARATION_DEG = 0.15


def estimate_rings(points: np.ndarray) -> np.ndarray:
    """(N,) scan line (ring) of each point of a spinning LIDAR's frame (sensor at the origin),
    estimated from the elevation angle when the file has no ring field: the peaks of the
    histogram of elevations (``scipy.signal.find_peaks``, at least ``RING_MIN_SEPARATION_DEG``
    apart) are the rings, each point goes to the nearest, rings numbered from the lowest."""
    from scipy.signal import find_peaks

    xyz = np.asarray(points, dtype=float)[:, :3]
    el = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    if len(el) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = float(el.min()), float(el.max())
    n_bins = max(int(np.ceil((hi - lo) / RING_BIN_DEG)), 1)
    hist, edges = np.histogram(el, bins=n_bins, range=(lo, hi + 1e-9))
    peaks, _ = find_peaks(np.r_[0, hist, 0], distance=max(int(RING_MIN_SEPARATION_DEG / RING_BIN_DEG), 1))
    if len(peaks) == 0:
        return np.zeros(len(el), dtype=np.int64)
    centres = 0.5 * (edges[peaks - 1] + edges[peaks])
    cut = 0.5 * (centres[1:] + centres[:-1])
    return np.searchsorted(cut, el).astype(np.int64)


def augment_frame(points: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """A real frame (sensor at the origin) as a sensor it was not recorded with might see it, and
    what was done: scan lines dropped to one of ``BEAM_TARGETS`` (every k-th estimated ring,
    ``estimate_rings``, from a random first one; kept when the frame has no more lines than that),
    range-dependent thinning (a point at range r kept with probability min(1, (r0 / r)^a), r0 5-15 m,
    a 0.5-1.5: the far points a coarser azimuth step loses), and the intensity rescaled to another
    sensor's units (x255 or /255, a random factor 0.1-10) or removed (0)."""
    pts = np.asarray(points, dtype=float).copy()
    what = {}
    if rng.random() < 0.7:
        rings = estimate_rings(pts)
        n_rings = int(rings.max()) + 1 if len(rings) else 0
        target = int(rng.choice(BEAM_TARGETS))
        every = int(round(n_rings / target))
        if every >= 2:
            pts = pts[(rings + int(rng.integers(every))) % every == 0]
            what["beams"] = target
    if rng.random() < 0.5:
        r = np.linalg.norm(pts[:, :3], axis=1)
        r0, a = rng.uniform(5.0, 15.0), rng.uniform(0.5, 1.5)
        pts = pts[rng.random(len(pts)) < np.minimum(1.0, (r0 / np.maximum(r, 1e-3)) ** a)]
        what["thinning"] = (round(float(r0), 2), round(float(a), 2))
    if pts.shape[1] > 3:
        kind = rng.choice(["keep", "units", "factor", "absent"], p=[0.3, 0.3, 0.2, 0.2])
        if kind == "units":
            pts[:, 3] = pts[:, 3] * 255.0 if np.nanmax(pts[:, 3], initial=0.0) <= 1.5 else pts[:, 3] / 255.0
        elif kind == "factor":
            pts[:, 3] = pts[:, 3] * 10.0 ** rng.uniform(-1.0, 1.0)
        elif kind == "absent":
            pts[:, 3] = 0.0
        what["intensity"] = str(kind)
    return pts, what


def prepared_frame(points: np.ndarray, *, sensor: str | None = None, floor: str = "auto"):
    """(points, sensor height, sensor xy) of a frame (sensor at the origin) as ``detect_file``
    prepares a file's before ``detect``: thinned to the trained density, floor at z = 0
    (``pedcal.detect.ground.detector_frame``); the height is ``DEFAULT_SENSOR_HEIGHT_M`` when
    the floor says none."""
    from pedcal.detect.features import DEFAULT_SENSOR_HEIGHT_M
    from pedcal.detect.ground import detector_frame
    from pedcal.detect.sensors import normalize_density

    prepared = detector_frame(normalize_density(np.asarray(points, dtype=float), sensor), floor=floor)
    height = DEFAULT_SENSOR_HEIGHT_M if prepared.sensor_height_m is None else prepared.sensor_height_m
    return prepared.points, float(height), tuple(prepared.sensor_xy_m)


def label_real_clusters(pts: np.ndarray, cands, boxes: list[dict]) -> np.ndarray:
    """Per gated cluster of a floor-referenced real frame: 1 when at least ``PERSON_SHARE`` of its
    points lie in one Pedestrian box's footprint (grown by ``LABEL_GROW_M``) and it holds at least
    ``FRAGMENT_SHARE`` of that box's points above the floor, -1 (left out) when fewer but at least
    ``MIXED_SHARE`` do or it is such a fragment, 0 otherwise: every other gated cluster (cyclists,
    bicycles, bollards, signs, cars, poles, unlabelled street furniture) is a negative."""
    from pedcal.detect.detection import FLOOR_TOLERANCE_M

    ped = [b for b in boxes if b["type"] in PERSON_TYPES]
    labels = np.zeros(len(cands), dtype=np.int64)
    if not ped or not cands:
        return labels
    above = pts[:, 2] > FLOOR_TOLERANCE_M
    box_points = [int((in_box(pts[:, :2], b, LABEL_GROW_M) & above).sum()) for b in ped]
    for i, c in enumerate(cands):
        inside = np.array([in_box(pts[c.indices, :2], b, LABEL_GROW_M).sum() for b in ped])
        j = int(np.argmax(inside))
        share = inside[j] / len(c.indices)
        if share >= PERSON_SHARE:
            labels[i] = 1 if inside[j] >= FRAGMENT_SHARE * box_points[j] else -1
        elif share >= MIXED_SHARE:
            labels[i] = -1
    return labels


def frame_scores_table(pts: np.ndarray, cands, boxes: list[dict], raw_points: np.ndarray) -> dict:
    """What scoring a frame's detections needs without running the detector again: the gated
    clusters' box centres, and its pedestrians' ranges and points (in the file's frame)."""
    ped = [b for b in boxes if b["type"] in PERSON_TYPES]
    return dict(centres=np.array([[c.box.cx, c.box.cy] for c in cands]).reshape(-1, 2),
                ped_range=np.array([np.hypot(b["cx"], b["cy"]) for b in ped]),
                ped_points=np.array([points_in_box(raw_points, b) for b in ped], dtype=np.int64),
                boxes=ped)


def score_frame(table: dict, scores: np.ndarray, threshold: float) -> dict:
    """Per range band (``RANGE_BANDS_M``): pedestrians with >= MIN_POINTS points, found, and false
    persons, of one frame's gated clusters (``frame_scores_table``) scored ``scores``, persons
    where score >= threshold; matched as ``evaluate_real`` matches."""
    n_bands = len(RANGE_BANDS_M)
    person = np.asarray(scores) >= threshold
    det_xy = table["centres"][person]
    pairs = match_boxes(det_xy, table["boxes"])
    seen = table["ped_points"] >= MIN_POINTS
    pb = band_of(table["ped_range"])
    found = np.zeros(len(table["boxes"]), bool)
    found[pairs[:, 1]] = True
    fp = np.ones(len(det_xy), bool)
    fp[pairs[:, 0]] = False
    db = band_of(np.hypot(*det_xy.T)) if len(det_xy) else np.zeros(0, dtype=np.int64)
    return dict(people=np.bincount(pb[seen], minlength=n_bands), found=np.bincount(pb[seen & found],
                                                                                    minlength=n_bands),
                false_positives=np.bincount(db[fp], minlength=n_bands),
                false_near=int((fp & (np.hypot(*det_xy.T) < NEAR_M)).sum()) if len(det_xy) else 0)


def detect_eval_extras(args, all_real: bool) -> int:
    """The parts of ``pedcal detect-eval`` about every real dataset: with ``all_real`` (``--real``
    without a folder) the evaluation of every labelled folder per dataset and range band; else,
    after the simulated evaluation, the leave-one-dataset-out table stored with the general model
    (or ``--model``), recomputed with ``--lodo``."""
    from pedcal.detect.detection import load_model
    from pedcal.detect.lodo import Config, format_lodo, lodo, real_clusters

    data_dir = getattr(args, "data_dir", None)
    if all_real:
        options = dict(sensor=getattr(args, "sensor", None), floor=getattr(args, "floor", "auto"))
        results = evaluate_all_real(data_dir, args.model, detect_options=options)
        print(jsontext.dumps(results, indent=2) if args.json else format_all_real(results))
        return 0
    if args.json:
        return 0
    model = load_model(args.model)
    meta = getattr(model, "metadata_", {})
    title = "general model, leave-one-dataset-out (each real dataset scored by a model trained without it):"
    if getattr(args, "lodo", False):
        from pedcal.detect.train import simulated_training_set

        if "config" not in meta:
            raise PedcalInputError("the model does not say how it was trained (no configuration in its metadata); "
                                   "--lodo needs a model of pedcal train-detector", path=args.model)
        config = Config(**meta["config"])
        seed = int(meta.get("seed", 0))
        sim = simulated_training_set(int(meta["simulated_frames"]), seed, intensity=(config.intensity,))
        records = real_clusters(data_dir, int(meta.get("real_copies", 0)), seed)
        threshold = float(meta["threshold"])
        table = lodo(config, sim, records, seed, thresholds=(threshold,))[threshold]
        print(format_lodo(table, title + " (recomputed)"))
    elif "lodo" in meta:
        print(format_lodo(meta["lodo"], title))
    else:
        print("the general model holds no leave-one-dataset-out table (trained on simulated frames alone)")
    return 0
