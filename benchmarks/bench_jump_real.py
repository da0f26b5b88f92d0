"""AMCL's relocalization-jump detector (``pedcal.calib.amcl_model.detect_steps``) on the real
robot tracks in ../shared/data, as recorded and with a jump put into them: what it flags on the
track as given (a false jump), and the share of a known jump's estimates it finds (a detector
that says nothing flags nothing on the track as given as well; only the recall tells them apart).

    .venv/bin/python benchmarks/bench_jump_real.py [--draws 20] [--sizes 0.2 0.4] [--hold 10]

Tracks: ``amcl_uf_retail`` (a real AMCL pose topic: 171 estimates over 124 s, 0.4 s apart at the
median, holes up to 3.2 s) and the wheel odometry of ``turtlebot4_ros2_bag`` (920 poses over
46 s, read with ``pedcal.io.ros.read_bag(localization="odometry", map_frame="odom")``). Each
draw (seeded) moves the estimates of a ``--hold`` s stretch starting at a uniform time, at
least 8 s from either end, by ``--sizes`` metres in a uniform direction; per track and size:
the mean and the least recall over the draws, and the estimates flagged outside the jump.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pedcal.calib.amcl_model import detect_steps  # noqa: E402
from pedcal.io.ros import read_bag, read_rostopic_amcl_csv  # noqa: E402
from pedcal.sim.walkers import SHARED_DATA  # noqa: E402


def tracks() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (t, xy) of every real robot track found, time-sorted."""
    out = {}
    amcl = SHARED_DATA / "amcl_uf_retail" / "amcldata.txt"
    bag = SHARED_DATA / "turtlebot4_ros2_bag"
    if amcl.is_file():
        out["amcl_uf_retail (AMCL)"] = read_rostopic_amcl_csv(amcl)
    if bag.is_dir():
        out["turtlebot4_ros2_bag (odometry)"] = read_bag(bag, localization="odometry", map_frame="odom").robot
    out = {name: df.sort_values("t", kind="stable") for name, df in out.items()}     # each sorted once
    return {name: (df["t"].to_numpy(float), df[["x", "y"]].to_numpy(float)) for name, df in out.items()}


def recall(t: np.ndarray, xy: np.ndarray, size_m: float, hold_s: float, draws: int, seed: int = 0):
    """(each draw's share of the jump's estimates flagged, estimates flagged outside the jumps,
    estimates outside them, draws whose jump held no estimate) for ``draws`` seeded jumps of
    ``size_m`` held ``hold_s``. A jump falling in a gap of the track holds no estimate: it has no
    share (a NaN would spoil the row's mean), is counted apart, and its estimates are all outside."""
    rng = np.random.default_rng(seed)
    shares, false, outside, empty = [], 0, 0, 0
    for _ in range(draws):
        t0 = rng.uniform(t.min() + 8.0, t.max() - 8.0 - hold_s)
        angle = rng.uniform(0.0, 2.0 * np.pi)
        inside = (t >= t0) & (t < t0 + hold_s)
        flagged = detect_steps(t, xy + inside[:, None] * size_m * np.array([np.cos(angle), np.sin(angle)]))
        if inside.any():
            shares.append(float(flagged[inside].mean()))
        else:
            empty += 1
        false += int(flagged[~inside].sum())
        outside += int((~inside).sum())
    return np.array(shares), false, outside, empty


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--sizes", type=float, nargs="+", default=[0.2, 0.4])
    ap.add_argument("--hold", type=float, default=10.0)
    args = ap.parse_args()
    found = tracks()
    if not found:
        print(f"no real robot track under {SHARED_DATA}", file=sys.stderr)
        return
    print("| track | estimates, span | flagged as given | jump (m) | recall mean / least | flagged outside |")
    print("|---|---|---|---|---|---|")
    for name, (t, xy) in found.items():
        given = int(detect_steps(t, xy).sum())
        for size in args.sizes:
            shares, false, outside, empty = recall(t, xy, size, args.hold, args.draws)
            rec = f"{shares.mean():.2f} / {shares.min():.2f}" if len(shares) else "-"
            if empty:
                rec += f" ({empty} of {args.draws} draws in a gap: no estimate)"
            print(f"| {name} | {len(t)}, {t.max() - t.min():.0f} s | {given} | {size:.2f} | "
                  f"{rec} | {false} of {outside} |")


if __name__ == "__main__":
    main()
