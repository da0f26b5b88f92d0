"""``pedcal detect`` (people in a point-cloud file) and ``pedcal detect-eval`` (recall and precision
on freshly simulated frames of the paper's FX8 pair, or of another LIDAR preset)."""

from __future__ import annotations

import logging
import time

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedcal import jsontext
from pedcal.detect.detection import detect, load_model, model_family
from pedcal.detect.files import FLOOR_MODES, FileDetections, detect_file  # noqa: F401  (their former home)
from pedcal.errors import PedcalInputError

MATCH_RADIUS_M = 0.5
MIN_VISIBLE_POINTS = 10
DISTANCE_BANDS_M = ((0.0, 2.0), (2.0, 3.5), (3.5, 5.0))


def detect_cli(args) -> int:
    """``pedcal detect FILE [--sensor S] [--frame body|optical] [--sensor-pose x,y,z,roll,pitch,yaw |
    --floor MODE] [--model M] [--json]``."""
    res = detect_file(args.file, args.model, sensor=getattr(args, "sensor", None),
                      sensor_pose=getattr(args, "sensor_pose", None), floor=getattr(args, "floor", "auto"),
                      frame=getattr(args, "frame", "body"))
    dets, dz = res.detections, res.floor_shift_m
    if res.read.summary():
        logging.getLogger(__name__).warning(f"{args.file}: {res.read.summary()}")
    if args.json:
        print(jsontext.dumps(dict(detections=[d.to_dict() for d in dets], floor_shift_m=float(dz),
                              ground=res.ground.as_dict() if res.ground is not None else None,
                              warnings=res.warnings), indent=2))
        return 0
    if dz:
        print(f"# floor {abs(dz):.3f} m {'below' if dz > 0 else 'ABOVE'} the sensor; heights are above the floor")
    print(f"{'x_m':>8} {'y_m':>8} {'height_m':>8} {'width_m':>8} {'depth_m':>8} {'score':>6}  is_person")
    for d in dets:
        print(f"{d.x:8.3f} {d.y:8.3f} {d.height:8.3f} {d.width:8.3f} {d.depth:8.3f} {d.score:6.3f}  {d.is_person}")
    print(f"{sum(d.is_person for d in dets)} people among {len(dets)} gated clusters")
    return 0


def match_detections(det_xy: np.ndarray, truth_xy: np.ndarray, radius_m: float = MATCH_RADIUS_M) -> np.ndarray:
    """(k, 2) index pairs (detection, truth): the optimal one-to-one assignment (Hungarian) on
    horizontal distance, keeping pairs closer than ``radius_m``."""
    if len(det_xy) == 0 or len(truth_xy) == 0:
        return np.zeros((0, 2), dtype=int)
    cost = np.linalg.norm(det_xy[:, None, :] - truth_xy[None, :, :], axis=2)
    r, c = linear_sum_assignment(np.where(cost < radius_m, cost, 1e6))
    ok = cost[r, c] < radius_m
    return np.column_stack([r[ok], c[ok]])


def evaluate_detector(frames: int = 200, seed: int = 12345, model=None, progress: bool = False,
                      preset: str = "fx8") -> dict:
    """Recall and precision of ``detect`` on ``frames`` held-out simulated frames of the FX8 pair
    (or of another LIDAR ``preset``, see ``pedcal.detect.train.simulated_frame``), with ``model``
    or, when it is None, the shipped model of the preset's family (``model_family``).

    Truth: the people with at least MIN_VISIBLE_POINTS points in the frame; a person detection
    within MATCH_RADIUS_M of one (one-to-one) is a true positive. Bands are by the true person's
    horizontal distance from the robot (recall) and the detection's (precision); ``poses`` gives
    the recall of static (standing, carrying) and walking people apart.
    """
    from pedcal.detect.train import EVAL_STREAM, simulated_frame
    from pedcal.sim.lidar import LIDAR_PRESETS

    if preset not in LIDAR_PRESETS:
        raise PedcalInputError(f"unknown LIDAR preset {preset!r}; expected one of {sorted(LIDAR_PRESETS)}",
                               column="preset")
    clf = load_model(model, model_family(preset)) if not hasattr(model, "predict_proba") else model
    n_bands = len(DISTANCE_BANDS_M)
    tp = fn = fp = 0
    band_tp_truth, band_truth = np.zeros(n_bands, int), np.zeros(n_bands, int)
    band_tp_det, band_det = np.zeros(n_bands, int), np.zeros(n_bands, int)
    edges = np.array([b[1] for b in DISTANCE_BANDS_M[:-1]])
    pose_people, pose_tp = {}, {}
    t0 = time.monotonic()
    for k in range(frames):
        frame = simulated_frame(EVAL_STREAM, seed, k, preset=preset)
        people = frame.visible_people(MIN_VISIBLE_POINTS)
        truth_xy = np.array([[o["x_m"], o["y_m"]] for o in people]).reshape(-1, 2)
        dets = [d for d in detect(frame.points.astype(float), clf, sensor_height_m=frame.sensor_height_m,
                                  sensor=preset, sensor_xy_m=tuple(frame.sensor_positions_base[:, :2].mean(axis=0)))
                if d.is_person]
        det_xy = np.array([[d.x, d.y] for d in dets]).reshape(-1, 2)
        pairs = match_detections(det_xy, truth_xy)
        tp += len(pairs)
        fn += len(truth_xy) - len(pairs)
        fp += len(det_xy) - len(pairs)
        tb = np.searchsorted(edges, np.hypot(*truth_xy.T), side="right")
        db = np.searchsorted(edges, np.hypot(*det_xy.T), side="right")
        np.add.at(band_truth, tb, 1)
        np.add.at(band_det, db, 1)
        np.add.at(band_tp_truth, tb[pairs[:, 1]], 1)
        np.add.at(band_tp_det, db[pairs[:, 0]], 1)
        found = set(pairs[:, 1].tolist())
        for j, o in enumerate(people):
            motion = "walking" if o["pose"].startswith("walking") else "static"
            pose_people[motion] = pose_people.get(motion, 0) + 1
            pose_tp[motion] = pose_tp.get(motion, 0) + (j in found)
        if progress and ((k + 1) % 100 == 0 or k + 1 == frames):
            logging.getLogger(__name__).info(f"  evaluated {k + 1}/{frames} frames ({time.monotonic() - t0:.0f} s)",
                                             extra={"progress": (k + 1, frames)})

    def ratio(a, b):
        return float(a / b) if b else float("nan")

    bands = [dict(band_m=[lo, hi], people=int(band_truth[i]), detections=int(band_det[i]),
                  recall=ratio(band_tp_truth[i], band_truth[i]), precision=ratio(band_tp_det[i], band_det[i]))
             for i, (lo, hi) in enumerate(DISTANCE_BANDS_M)]
    poses = {m: dict(people=pose_people[m], recall=ratio(pose_tp[m], pose_people[m])) for m in sorted(pose_people)}
    return dict(recall=ratio(tp, tp + fn), precision=ratio(tp, tp + fp), frames=int(frames), bands=bands,
                poses=poses, preset=preset, true_positives=tp, false_negatives=fn, false_positives=fp)


def detect_eval_cli(args) -> int:
    """``pedcal detect-eval [--frames N] [--seed S] [--model M] [--preset P] [--json]``, or
    ``pedcal detect-eval --real DIR [-o PICTURES] [--json]`` on real labelled frames."""
    if getattr(args, "real", None) is not None:
        from pedcal.detect.real_eval import evaluate_real, format_real

        options = dict(sensor=getattr(args, "sensor", None), floor=getattr(args, "floor", "auto"))
        res = evaluate_real(args.real, args.model, out_dir=args.output, detect_options=options)
        print(jsontext.dumps(res, indent=2) if args.json else format_real(res))
        return 0
    res = evaluate_detector(args.frames, args.seed, args.model, progress=not args.json,
                            preset=getattr(args, "preset", "fx8"))
    if args.json:
        print(jsontext.dumps({k: res[k] for k in ("recall", "precision", "frames", "bands", "poses", "preset")},
                         indent=2))
        return 0
    print(f"{res['preset']} frames {res['frames']}: recall {res['recall']:.4f}, precision {res['precision']:.4f} "
          f"(TP {res['true_positives']}, FN {res['false_negatives']}, FP {res['false_positives']})")
    for b in res["bands"]:
        lo, hi = b["band_m"]
        print(f"  {lo:.1f}-{hi:.1f} m: recall {b['recall']:.4f} of {b['people']} people, "
              f"precision {b['precision']:.4f} of {b['detections']} detections")
    for motion, p in res["poses"].items():
        print(f"  {motion} people: recall {p['recall']:.4f} of {p['people']}")
    return 0
