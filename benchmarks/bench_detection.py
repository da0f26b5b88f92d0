"""Speed of ``pedcal.detect.detection.detect`` on simulated frames of the paper's FX8 pair, and
on the real labelled frames under ../shared/data (every labelled folder: SUSTech's 67k-point
automotive frames, KITTI's HDL-64E and Argoverse 2's two VLP-32C frames), per dataset.

Run: .venv/bin/python benchmarks/bench_detection.py [--frames N] [--repeats R] [--data-dir D]
Prints the points per frame and the median / p90 time of one ``detect`` call (segmentation,
gate, features and classification with the shipped model of the frame's family, chosen from its
estimated ray steps: the FX8 model for the FX8 frames, the general one for the real frames), and
of the segmentation alone, in
wall-clock time and in this process's CPU time (which other jobs on a busy machine inflate less).
For the real frames (skipped when the folder is absent) it prints ``detect`` on the
floor-referenced points and the whole file pipeline (``detect_file``: read, local ground, detect),
and the peak resident memory of the process.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from pedcal.detect.detection import detect, segment
from pedcal.detect.train import EVAL_STREAM, simulated_frame


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--data-dir", type=Path, default=None, help="the real recordings (default ../shared/data)")
    args = ap.parse_args()
    model = None  # each frame's family's shipped model (loaded once, then cached)
    frames = [simulated_frame(EVAL_STREAM, 777, k, preset="fx8").points.astype(float) for k in range(args.frames)]
    detect(frames[0], model)  # warm up (imports, caches)
    t_detect, t_segment, cpu_detect = [], [], []
    for pts in frames:
        for _ in range(args.repeats):
            c0, t0 = time.process_time(), time.perf_counter()
            detect(pts, model)
            c1, t1 = time.process_time(), time.perf_counter()
            segment(pts, cut_low=True)
            t2 = time.perf_counter()
            t_detect.append(t1 - t0)
            cpu_detect.append(c1 - c0)
            t_segment.append(t2 - t1)
    n = np.array([len(p) for p in frames])
    ms = 1e3 * np.array(t_detect)
    ms_seg = 1e3 * np.array(t_segment)
    print(f"frames: {len(frames)} of two FX8s, points per frame median {np.median(n):.0f} "
          f"(min {n.min()}, max {n.max()}), {args.repeats} repeats each")
    cpu = 1e3 * np.array(cpu_detect)
    print(f"detect:  median {np.median(ms):.2f} ms, p90 {np.percentile(ms, 90):.2f} ms "
          f"(CPU time median {np.median(cpu):.2f} ms, p90 {np.percentile(cpu, 90):.2f} ms)")
    print(f"segment: median {np.median(ms_seg):.2f} ms, p90 {np.percentile(ms_seg, 90):.2f} ms")
    bench_real(model, args.repeats, args.data_dir)
    print(f"peak resident memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


def bench_real(model, repeats: int, data_dir=None) -> None:
    from pedcal.detect.files import detect_file
    from pedcal.detect.real_eval import dataset_of, frame_pairs, labelled_folders
    from pedcal.errors import PedcalInputError

    try:
        folders = labelled_folders(data_dir)
    except PedcalInputError as e:
        print(f"real frames: {e}, skipped")
        return
    by_set: dict[str, list[Path]] = {}
    for folder in folders:
        for cloud, _ in frame_pairs(folder):
            by_set.setdefault(dataset_of(cloud), []).append(cloud)
    for name, files in sorted(by_set.items()):
        wall, cpu, wall_file, cpu_file, n = [], [], [], [], []
        for f in files:
            res = detect_file(f, model)  # warm up, and the floor-referenced points
            n.append(len(res.points))
            for _ in range(repeats):
                c0, t0 = time.process_time(), time.perf_counter()
                detect(res.points, model, sensor_height_m=max(res.floor_shift_m, 0.5))
                c1, t1 = time.process_time(), time.perf_counter()
                detect_file(f, model)
                c2, t2 = time.process_time(), time.perf_counter()
                wall.append(t1 - t0)
                cpu.append(c1 - c0)
                wall_file.append(t2 - t1)
                cpu_file.append(c2 - c1)
        for what, w, c in (("detect", wall, cpu), ("detect_file", wall_file, cpu_file)):
            w, c = 1e3 * np.array(w), 1e3 * np.array(c)
            print(f"{name} {what}: {len(files)} frames of median {int(np.median(n))} points: median "
                  f"{np.median(w):.1f} ms, p90 {np.percentile(w, 90):.1f} ms (CPU time median {np.median(c):.1f} ms)")


if __name__ == "__main__":
    main()
