"""Speed of the raycast LIDAR simulator: scene generation, raycasting-structure build, render.

Run: .venv/bin/python benchmarks/bench_lidar_sim.py [--frames N] [--presets a,b,...]

For every preset it renders N random scenes (people and clutter; the FX8 presets with the
front pair of mounts, the others with one mount on the robot's centre) and prints per frame:
the time of ``random_scene``, of the first render (which builds open3d's RaycastingScene),
of a render that reuses it, of a tracking step (``Scene.step`` moves and re-poses walking
people, so the next render rebuilds), the number of rays and points, the rays cast per second
by a render that reuses the structure (wall and CPU time: ``time.process_time`` counts every
core's work, open3d casts on several threads), and a render of a ``random_nuisances`` variant
of the preset (stray returns below the ground, another intensity scale).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from pedcal.sim.lidar import LIDAR_PRESETS, Mount, fx8_pair_mounts, random_nuisances, render
from pedcal.sim.scene import random_scene


def bench(preset: str, frames: int) -> dict:
    lidar = LIDAR_PRESETS[preset]
    mounts = fx8_pair_mounts() if preset.startswith("fx8") else (Mount(0.0, 0.0, 1.2),)
    far = min(lidar.max_range_m, 9.0)
    area = (0.8, far, -far, far)
    t_scene, t_first, t_cached, t_step, n_points, n_triangles = [], [], [], [], [], []
    cpu_cached, t_nuisance = [], []
    for k in range(frames):
        rng = np.random.default_rng([42, k])
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = random_scene(rng, area=area)
        t1 = time.perf_counter()
        frame = render(scene, lidar, mounts, rng)
        t2, c2 = time.perf_counter(), time.process_time()
        render(scene, lidar, mounts, rng)
        t3, c3 = time.perf_counter(), time.process_time()
        variant = random_nuisances(lidar, rng)
        render(scene, variant, mounts, rng)
        t_nuisance.append(time.perf_counter() - t3)
        t_s = time.perf_counter()
        scene.step(1.0 / lidar.rate_hz)
        render(scene, lidar, mounts, rng)
        t4 = time.perf_counter()
        cpu_cached.append(c3 - c2)
        t_scene.append(t1 - t0)
        t_first.append(t2 - t1)
        t_cached.append(t3 - t2)
        t_step.append(t4 - t_s)
        n_points.append(len(frame.points))
        n_triangles.append(len(scene.raycasting()[3]))
    return dict(preset=preset, rays=lidar.n_rays * len(mounts), points=np.mean(n_points),
                triangles=np.mean(n_triangles), scene_ms=1e3 * np.median(t_scene),
                first_ms=1e3 * np.median(t_first), cached_ms=1e3 * np.median(t_cached),
                cached_cpu_ms=1e3 * np.median(cpu_cached), nuisance_ms=1e3 * np.median(t_nuisance),
                step_ms=1e3 * np.median(t_step))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--presets", default=",".join(LIDAR_PRESETS), help="comma-separated LIDAR presets")
    args = ap.parse_args()
    print(f"{args.frames} random scenes per preset; median milliseconds per frame (render: wall / CPU)")
    print(f"{'preset':<15} {'mounts x rays':>13} {'points/frame':>12} {'triangles':>9} {'random_scene':>12} "
          f"{'render+build':>12} {'render':>15} {'Mrays/s':>7} {'nuisances':>9} {'step+render':>11}")
    for preset in args.presets.split(","):
        r = bench(preset, args.frames)
        print(f"{r['preset']:<15} {r['rays']:>13d} {r['points']:>12.0f} {r['triangles']:>9.0f} "
              f"{r['scene_ms']:>12.2f} {r['first_ms']:>12.2f} {r['cached_ms']:>7.2f} / {r['cached_cpu_ms']:>5.1f} "
              f"{r['rays'] / r['cached_ms'] / 1e3:>7.2f} {r['nuisance_ms']:>9.2f} {r['step_ms']:>11.2f}")


if __name__ == "__main__":
    main()
