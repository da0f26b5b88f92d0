"""People shoulder to shoulder (centres 0.45-0.5 m apart, heights 1.45-1.95 m, so one's shoulders
can be as high as the other's head) are cut into one candidate each; a single person is not cut."""

from __future__ import annotations

import numpy as np

from pedcal.detect.detection import segment
from pedcal.sim.lidar import Mount, fx8_pair_mounts, render
from pedcal.sim.scene import Scene, make_person, random_person


def _whole(frame, cands, pid, share=0.6):
    """A gated candidate made mostly of person ``pid``'s points."""
    for c in cands:
        ids, counts = np.unique(frame.object_id[c.indices], return_counts=True)
        j = int(np.argmax(counts))
        if ids[j] == pid and counts[j] >= share * len(c.indices):
            return True
    return False


def _pair_frame(rng, preset):
    scene = Scene(floor_reflectance=0.3)
    r = rng.uniform(5.0, 11.0) if preset != "fx8" else rng.uniform(1.5, 4.5)
    bearing, sep = rng.uniform(-0.4, 0.4), rng.uniform(0.45, 0.5)
    ids = []
    for side in (-0.5, 0.5):
        p = make_person(rng.uniform(1.45, 1.95), rng.uniform(0.35, 0.5), rng.uniform(0.2, 0.3), "standing",
                        (0.5, 0.5), rng)
        p.x_m = float(r * np.cos(bearing) - np.sin(bearing) * side * sep)
        p.y_m = float(r * np.sin(bearing) + np.cos(bearing) * side * sep)
        p.yaw_rad = float(bearing + np.pi + rng.normal(0.0, 0.2))
        ids.append(scene.add(p))
    mounts = fx8_pair_mounts() if preset == "fx8" else Mount(0.0, 0.0, 1.8, 0.0, 0.0)
    return render(scene, preset, mounts, rng), ids


def test_people_shoulder_to_shoulder_of_different_heights_are_cut_apart():
    split = 0
    for k in range(24):
        rng = np.random.default_rng([41, k])
        frame, ids = _pair_frame(rng, ("fx8", "hdl64", "hdl32")[k % 3])
        cands = [c for c in segment(frame.points.astype(float)) if c.gated]
        split += all(_whole(frame, cands, pid) for pid in ids)
    assert split >= 22, f"only {split} of 24 touching pairs cut into two people"


def test_a_single_person_is_not_cut():
    whole = 0
    for k in range(24):
        rng = np.random.default_rng([42, k])
        scene = Scene(floor_reflectance=0.3)
        p = random_person(rng, static=bool(k % 2))
        r, bearing = rng.uniform(1.0, 4.5), rng.uniform(-0.4, 0.4)
        p.x_m, p.y_m, p.yaw_rad = float(r * np.cos(bearing)), float(r * np.sin(bearing)), float(rng.uniform(-3, 3))
        pid = scene.add(p)
        frame = render(scene, "fx8", fx8_pair_mounts(), rng)
        cands = [c for c in segment(frame.points.astype(float)) if c.gated]
        n_person = int((frame.object_id == pid).sum())
        whole += any((frame.object_id[c.indices] == pid).sum() >= 0.8 * n_person for c in cands)
    assert whole >= 22, f"only {whole} of 24 single people kept whole"
