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

import json
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedcal.errors import PedcalInputError

GROW_M = 0.3
RANGE_BANDS_M = ((0.0, 10.0), (10.0, 15.0), (15.0, 20.0), (20.0, 30.0), (30.0, np.inf))
NEAR_M = 15.0  # the headline figures: pedestrians and false detections within this range
PERSON_TYPES = ("Pedestrian",)
CLOUD_SUFFIXES = (".pcd", ".bin", ".ply", ".npy")


def read_boxes(path: Path) -> list[dict]:
    """Boxes of a label file as dicts ``type, id, cx, cy, cz, length, width, height, yaw``."""
    try:
        raw = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PedcalInputError(f"not a readable JSON label file: {e}", path=path) from None
    if not isinstance(raw, list):
        raise PedcalInputError("a label file is a JSON list of boxes", path=path)
    out = []
    for row, b in enumerate(raw):
        try:
            p, s, r = b["psr"]["position"], b["psr"]["scale"], b["psr"]["rotation"]
            out.append(dict(type=str(b["obj_type"]), id=str(b.get("obj_id", row)), cx=float(p["x"]),
                            cy=float(p["y"]), cz=float(p["z"]), length=float(s["x"]), width=float(s["y"]),
                            height=float(s["z"]), yaw=float(r["z"])))
        except (KeyError, TypeError, ValueError) as e:
            raise PedcalInputError(f"box without obj_type / psr.position, scale, rotation ({e})", path=path,
                                   row=row) from None
    return out


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
    folder = Path(folder)
    if not folder.is_dir():
        raise PedcalInputError("no such folder of labelled frames", path=folder)
    pairs = []
    for cloud in sorted(p for p in folder.iterdir() if p.suffix.lower() in CLOUD_SUFFIXES):
        label = cloud.with_suffix(".json")
        if label.is_file():
            pairs.append((cloud, label))
    if not pairs:
        raise PedcalInputError("no frame with a label file (NAME.pcd|.bin|.ply|.npy beside NAME.json)", path=folder)
    return pairs


def evaluate_real(folder: str | Path, model=None, out_dir: str | Path | None = None, *, detect_options=None,
                  frames: list[str] | None = None) -> dict:
    """Per frame and per range band: pedestrians, found, person detections, false positives.

    ``detect_options`` go to ``pedcal.detect.files.detect_file`` (sensor, pose, floor);
    ``frames`` restricts the evaluation to these frame names (file stems).
    """
    from pedcal.detect.files import detect_file

    pairs = frame_pairs(Path(folder))
    if frames is not None:
        pairs = [p for p in pairs if p[0].stem in set(frames)]
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
    n_frames = len(frame_rows)
    fp_near = sum(f["false_positives_near"] for f in frame_rows)
    return dict(frames=frame_rows, bands=bands, pedestrians=pedestrians,
                recall=ratio(sum(found), sum(people)),
                precision=ratio(sum(dets_band) - sum(fp_band), sum(dets_band)),
                recall_near=ratio(sum(p["found"] for p in near), len(near)), pedestrians_near=len(near),
                false_positives_near_per_frame=ratio(fp_near, n_frames), near_m=NEAR_M)


def format_real(res: dict) -> str:
    lines = [f"{len(res['frames'])} frames, {len(res['pedestrians'])} labelled pedestrians: recall "
             f"{res['recall']:.3f}, precision {res['precision']:.3f}",
             f"within {res['near_m']:.0f} m: recall {res['recall_near']:.3f} of {res['pedestrians_near']} "
             f"pedestrians, {res['false_positives_near_per_frame']:.2f} false detections per frame",
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
