"""Pedestrians the ceiling sensors see besides the robot: recorded walkers (ATC, ETH/UCY, THOR
from the shared data folder), a built-in walker model, and a companion who walks beside the robot.

Every function returns a table ``t, person, x, y, z`` (s, id, m, m, m): z is the head top.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pedcal.calib.common import interpolate_pose2
from pedcal.sim.robot import arc_length
from pedcal.sim.scenario import Scenario

SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
RECORDINGS = {"atc": "atc/atc-1024-10_test.csv", "eth_ucy": "eth_ucy/biwi_hotel.txt",
              "thor": "thor/exp-1-run-2.csv"}
COLUMNS = ["t", "person", "x", "y", "z"]
SAMPLE_DT_S = 0.2


def _empty() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=str if c == "person" else float) for c in COLUMNS})


def _with_heights(df: pd.DataFrame, sc: Scenario, rng: np.random.Generator) -> pd.DataFrame:
    """Give each person a head-top height drawn from person_height_m."""
    people = df["person"].unique()
    height = dict(zip(people, rng.uniform(*sc.person_height_m, len(people)), strict=True))
    return df.assign(z=df["person"].map(height).astype(float))[COLUMNS]


def _border_point(rng: np.random.Generator, side: int, ax: float, ay: float, out_m: float) -> np.ndarray:
    u = rng.uniform()
    return np.array([(-out_m, u * ay), (ax + out_m, u * ay), (u * ax, -out_m), (u * ax, ay + out_m)][side])


def builtin_walkers(sc: Scenario, t0: float, t1: float, rng: np.random.Generator) -> pd.DataFrame:
    """Random walkers: Poisson arrivals (walker_rate_hz) at a random border of the area, through
    a random point inside it, out at another border, at a speed from walker_speed_mps."""
    ax, ay = sc.area_m
    n = rng.poisson(sc.walker_rate_hz * (t1 - t0 + 30.0)) if sc.walker_rate_hz > 0 else 0
    parts = []
    for k in range(n):
        t_start = rng.uniform(t0 - 30.0, t1)
        side_in, side_out = rng.choice(4, 2, replace=False)
        wp = np.array([_border_point(rng, side_in, ax, ay, 1.0),
                       rng.uniform([0.0, 0.0], [ax, ay]),
                       _border_point(rng, side_out, ax, ay, 1.0)])
        speed = max(0.4, rng.normal(*sc.walker_speed_mps))
        s_wp = arc_length(wp)
        s = np.arange(0.0, s_wp[-1], speed * SAMPLE_DT_S)
        t = t_start + s / speed
        keep = (t >= t0 - 1.0) & (t <= t1 + 1.0)
        if keep.sum() < 2:
            continue
        parts.append(pd.DataFrame({"t": t[keep], "person": f"p{k + 1}",
                                   "x": np.interp(s[keep], s_wp, wp[:, 0]),
                                   "y": np.interp(s[keep], s_wp, wp[:, 1])}))
    return _with_heights(pd.concat(parts, ignore_index=True), sc, rng) if parts else _empty()


def _busiest_start(t_rec: np.ndarray, duration_s: float, rank: int) -> float:
    """Start of the ``rank``-th busiest (most samples) window of ``duration_s``, windows of
    different ranks not overlapping."""
    starts = np.arange(t_rec[0], max(t_rec[0], t_rec[-1] - duration_s) + 10.0, 10.0)
    counts = np.searchsorted(t_rec, starts + duration_s) - np.searchsorted(t_rec, starts)
    chosen: list[float] = []
    for i in np.argsort(-counts, kind="stable"):
        if all(abs(starts[i] - c) >= duration_s for c in chosen):
            chosen.append(float(starts[i]))
            if len(chosen) > rank:
                break
    return chosen[min(rank, len(chosen) - 1)]


def recorded_walkers(sc: Scenario, t0: float, t1: float, rng: np.random.Generator, *,
                     rank: int = 0) -> pd.DataFrame | None:
    """Real tracks: the ``rank``-th busiest window of the recording, shifted in time to [t0, t1]
    and in space so its centre of activity is the area's centre. None when the shared data
    folder is absent (the caller falls back to built-in walkers)."""
    path = SHARED_DATA / RECORDINGS[sc.walkers]
    if not path.is_file():
        return None
    from pedcal.io.pedestrians import read_pedestrians

    rec = read_pedestrians(path, kind=sc.walkers).sort_values("t", kind="stable")
    t_rec = rec["t"].to_numpy(float)
    start = _busiest_start(t_rec, t1 - t0, rank)
    rec = rec[(t_rec >= start) & (t_rec <= start + (t1 - t0))]
    xy = rec[["x", "y"]].to_numpy(float)
    xy = xy - np.median(xy, axis=0) + 0.5 * np.asarray(sc.area_m)
    margin = 3.0
    inside = ((xy[:, 0] > -margin) & (xy[:, 0] < sc.area_m[0] + margin)
              & (xy[:, 1] > -margin) & (xy[:, 1] < sc.area_m[1] + margin))
    df = pd.DataFrame({"t": rec["t"].to_numpy(float) - start + t0, "person": "r" + rec["person"].astype(str),
                       "x": xy[:, 0], "y": xy[:, 1]})[inside]
    return _with_heights(df.reset_index(drop=True), sc, rng) if len(df) else _empty()


def companion(sc: Scenario, truth: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """A person walking beside the robot (companion_offset_m to its left) for a contiguous
    companion_fraction of the run, starting at a random time."""
    if sc.companion_fraction <= 0 or len(truth) < 2:
        return _empty()
    n = len(truth)
    n_with = max(2, int(round(min(1.0, sc.companion_fraction) * n)))
    i0 = int(rng.integers(0, n - n_with + 1))
    part = truth.iloc[i0:i0 + n_with]
    yaw = part["yaw"].to_numpy()
    return pd.DataFrame({"t": part["t"].to_numpy(),
                         "person": "companion",
                         "x": part["x"].to_numpy() - np.sin(yaw) * sc.companion_offset_m,
                         "y": part["y"].to_numpy() + np.cos(yaw) * sc.companion_offset_m,
                         "z": rng.uniform(*sc.person_height_m)})


def beside_robot(sc: Scenario, truth: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """(N, 2) floor position of a person walking companion_offset_m to the robot's left at ``t``."""
    pose = interpolate_pose2(truth, np.asarray(t, float))
    return np.column_stack([pose[:, 0] - np.sin(pose[:, 2]) * sc.companion_offset_m,
                            pose[:, 1] + np.cos(pose[:, 2]) * sc.companion_offset_m])


def companion_swaps(sc: Scenario, truth: pd.DataFrame, robot_seen: np.ndarray, companion_seen: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """(K, 2) [start, end] times of the identity swaps: stretches of companion_swap_s at random,
    non-overlapping places of the run, added until the companion's sightings inside them make
    companion_swap_fraction of all the sightings the robot's track gives (the robot's outside the
    swaps, the companion's inside); the last one is cut to hit the fraction. ``robot_seen`` and
    ``companion_seen``: per row of ``truth``, how many sensors see the robot / the companion."""
    t = truth["t"].to_numpy(float)
    frac = min(max(sc.companion_swap_fraction, 0.0), 1.0)

    def cumulative(seen):
        return np.r_[0.0, np.cumsum(0.5 * (seen[1:] + seen[:-1]) * np.diff(t))]

    cum_r, cum_c = cumulative(robot_seen), cumulative(companion_seen)
    if frac <= 0 or cum_r[-1] <= 0 or cum_c[-1] <= 0:
        return np.zeros((0, 2))

    def excess(held_r, held_c, a, b):
        """Companion share above the target with a swap [a, b] added (times its denominator)."""
        w_r = np.interp(b, t, cum_r) - np.interp(a, t, cum_r)
        w_c = np.interp(b, t, cum_c) - np.interp(a, t, cum_c)
        return (held_c + w_c) - frac * (cum_r[-1] - held_r - w_r + held_c + w_c), w_r, w_c

    swaps: list[tuple[float, float]] = []
    held_r = held_c = 0.0
    for _ in range(10000):
        if excess(held_r, held_c, t[0], t[0])[0] >= 0:
            break
        a = rng.uniform(t[0], t[-1])
        b = min(a + rng.uniform(*sc.companion_swap_s), t[-1])
        if any(a < d + 1.0 and c < b + 1.0 for c, d in swaps):    # a second apart at least
            continue
        e, w_r, w_c = excess(held_r, held_c, a, b)
        if e > 0:       # cut the last one where the share reaches the stated one
            grid = np.linspace(a, b, 200)
            b = float(grid[np.argmax(excess(held_r, held_c, a, grid)[0] >= 0)])
            _, w_r, w_c = excess(held_r, held_c, a, b)
        swaps.append((a, b))
        held_r, held_c = held_r + w_r, held_c + w_c
    return np.array(sorted(swaps)).reshape(-1, 2)


def pedestrians(sc: Scenario, truth: pd.DataFrame, rng: np.random.Generator, *, rank: int = 0) -> pd.DataFrame:
    """Every pedestrian of one run: the scenario's walkers plus the companion."""
    t0, t1 = float(truth["t"].iloc[0]), float(truth["t"].iloc[-1])
    walkers = _empty()
    if sc.walkers in RECORDINGS:
        rec = recorded_walkers(sc, t0, t1, rng, rank=rank)
        if rec is None:
            warnings.warn(f"recorded walkers '{sc.walkers}' not found under {SHARED_DATA}; "
                          "using the built-in walker model", stacklevel=3)
            walkers = builtin_walkers(sc, t0, t1, rng)
        else:
            walkers = rec
    elif sc.walkers == "builtin":
        walkers = builtin_walkers(sc, t0, t1, rng)
    parts = [p for p in (walkers, companion(sc, truth, rng)) if len(p)]
    return pd.concat(parts, ignore_index=True) if parts else _empty()
