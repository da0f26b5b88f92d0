"""The considered head-point line's width on zoo logs: what the data say of the line held at 0
(pedcal.calib.headpoint.considered_nuisances) and the sigma's honesty with its width replaced.

The graph carries the line (a horizontal shift toward the sensor rising with distance, held at
0) into the sensors' covariance as S S^T times a width squared, the width the root of the
line's posterior second moment about 0, sqrt(d^2 + v), with the head point's curvature held at
0 when its selection drops it, plus the square of the line's move between that hold and the
curvature free (``considered_rms``). Per log this prints the line's
estimate d with the curvature held and free (the same profile step), its sd, and v over the
prior's variance (how much of the prior the data leave), then the sigma's honesty (within 1
sigma, error / sigma RMS; bootstrap over seeds) with the width (``--width``):

- ``data``: the data's second moment alone, sqrt(d^2 + v) (the graph's before it carried the
  curvature's hold, which ``spread`` adds);
- ``prior``: the line's prior sigma (``head_profile_sigma_m``);
- ``blend``: (1 - r) (d^2 + v) + r prior^2 under the root, r = v / prior^2 (the prior where
  the data leave it, the data's second moment where they pin the line);
- ``free``: sqrt(d^2 + v) with the curvature free (its hold not trusted);
- ``max``: the larger of ``data`` and ``free``;
- ``spread``: the data's, plus the square of the line's move between the curvature held and free
  (the graph's: ``considered_rms``).

The estimates do not depend on the width (it only widens the sigma), so the runs differ in
their sigma alone. The per-log table (its last column the width the sigma carries, mm) lists the
logs with a considered line; the honesty figures pool every log. A call without a curvature in
the step gives every width but ``prior`` and ``blend`` the data's.

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/bench_consider_width.py --scenarios corridor cross \\
        --seeds 8 --first-seed 20 --jobs 2 --only head=centroid --width data spread
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from bench_factorgraph_nuisances import family_filter, print_honesty, run_one, seeds_with

import pedcal.calib.factorgraph as fgmod
from pedcal.calib.headpoint import line_moments
from pedcal.calib.recipe import GraphRecipe

WIDTHS = ("data", "prior", "blend", "free", "max", "spread")


def width_of(kind: str, d: float, v: float, d_free: float, v_free: float, prior_sigma: float) -> float:
    """The line's width (m) of kind ``kind`` (:data:`WIDTHS`) from its moments held (d, v) and
    with the curvature free (d_free, v_free)."""
    data = d * d + v
    r = v / prior_sigma ** 2
    return float(np.sqrt({"data": data, "prior": prior_sigma ** 2, "blend": (1.0 - r) * data + r * prior_sigma ** 2,
                          "free": d_free ** 2 + v_free, "max": max(data, d_free ** 2 + v_free),
                          "spread": data + (d - d_free) ** 2}[kind]))


def run_with_width(scenario: str, seed: int, kind: str, prior_sigma: float) -> dict:
    """One zoo log (``run_one``) with the considered line's width of ``kind``; the result gets
    ``consider_calls``: (d, sd, d with the curvature free, v / prior variance, width) per call,
    the last the one the sigma carries."""
    calls = []

    def width(step, j, held=()):
        d, v = line_moments(step, j, held)
        d_free, v_free = line_moments(step, j)
        w = width_of(kind, d, v, d_free, v_free, prior_sigma)
        calls.append((d, np.sqrt(v), d_free, v / prior_sigma ** 2, w))
        return w

    fgmod.considered_rms = width       # (this worker process's own module)
    out = run_one(scenario, seed, zoo=True)
    out["consider_calls"] = calls
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["corridor", "cross"])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--only", nargs="+", default=[], metavar="FAMILY=VALUE",
                    help="per scenario the first --seeds seeds from --first-seed whose zoo draws these families")
    ap.add_argument("--width", nargs="+", default=["data"], choices=WIDTHS)
    args = ap.parse_args()
    only = family_filter(args.only, ap)
    seeds = {sc: (seeds_with(sc, only, args.first_seed, args.seeds) if only
                  else list(range(args.first_seed, args.first_seed + args.seeds))) for sc in args.scenarios}
    prior_sigma = GraphRecipe().head_profile_sigma_m
    for kind in args.width:
        tasks = [(sc, s, kind, prior_sigma) for sc in args.scenarios for s in seeds[sc]]
        with ProcessPoolExecutor(args.jobs) as ex:
            results = list(ex.map(run_with_width, *zip(*tasks, strict=True)))
        print(f"\n## width {kind}: {len(args.scenarios)} scenarios x {args.seeds} seeds (first {args.first_seed})"
              + (f", only {' '.join(args.only)}" if args.only else ""))
        print("\n| scenario | seed | line held / curvature free (mm) | its sd (mm) | v / prior variance | width (mm) |")
        print("|---|---|---|---|---|---|")
        for r in results:
            if r["consider_calls"]:
                d, sd, d_free, share, w = r["consider_calls"][-1]
                print(f"| {r['scenario']} | {r['seed']} | {1000 * d:+.1f} / {1000 * d_free:+.1f} | {1000 * sd:.1f} | "
                      f"{share:.4f} | {1000 * w:.1f} |")
        print_honesty([(sc, [r for r in results if r["scenario"] == sc]) for sc in args.scenarios]
                      + [("all", results)])


if __name__ == "__main__":
    main()
