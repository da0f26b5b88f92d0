"""pedcal command line: parse, call one library function per command, map errors to exit codes.

Exit codes: 0 success, 2 bad input (message names the file, row, column), 1 anything else.
Each handler imports its library module lazily so that `pedcal --help` stays fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pedcal.errors import PedcalInputError

EXIT_BAD_INPUT = 2


def _print_json(obj) -> None:
    print(json.dumps(obj, indent=2, sort_keys=False, default=_json_default))


def _json_default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


# ----------------------------------------------------------------------------------------- commands
def cmd_simulate(args) -> int:
    from pedcal.sim import simulate

    result = simulate(args.scenario, args.output, seed=args.seed, progress=not args.quiet,
                      **({"vary_nuisances": True} if getattr(args, "vary_nuisances", False) else {}))
    print(result.summary())
    return 0


def cmd_evaluate(args) -> int:
    from pedcal.io import read_log, read_sensors_yaml
    from pedcal.metrics import evaluate

    log = read_log(args.log)
    ext = read_sensors_yaml(args.extrinsics)
    res = evaluate(log, ext)
    if args.json:
        _print_json(res.to_dict())
    else:
        print(res.format_table())
    return 0


def cmd_calibrate(args) -> int:
    from pedcal.calib import calibrate
    from pedcal.io import read_log, write_sensors_yaml

    log = read_log(args.log)
    kwargs = {}
    if args.graph is not None:
        kwargs["graph"] = args.graph
    if args.online:
        kwargs["online"] = True
    if getattr(args, "sensor_height_sigma", None) is not None:
        kwargs["sensor_height_sigma_m"] = args.sensor_height_sigma
    if getattr(args, "ceiling_height", None) is not None:
        kwargs["ceiling_height_m"] = args.ceiling_height
    if (kwargs.keys() & {"sensor_height_sigma_m", "ceiling_height_m"}) and args.method != "factorgraph":
        raise PedcalInputError("--sensor-height-sigma and --ceiling-height are height references of the "
                               "factor graph (--method factorgraph)")
    result = calibrate(log, method=args.method, progress=not args.quiet, **kwargs)
    write_sensors_yaml(result.network, args.output)
    print(result.summary())
    return 0


def cmd_import_bag(args) -> int:
    from pedcal.io.ros import import_bag

    written = import_bag(args.bag, args.output, amcl_topic=args.amcl_topic, odom_topic=args.odom_topic)
    for path, n in written.items():
        print(f"wrote {path} ({n} rows)")
    return 0


def cmd_import_people(args) -> int:
    from pedcal.io import write_people_csv
    from pedcal.io.pedestrians import read_pedestrians

    people = read_pedestrians(args.input, kind=args.kind)
    write_people_csv(people, args.output)
    print(f"wrote {args.output} ({len(people)} rows, {people['person'].nunique()} people)")
    return 0


def cmd_demo(args) -> int:
    from pedcal.demo import run_demo

    return run_demo(args.output, seed=args.seed, scenario=args.scenario)


def cmd_train_detector(args) -> int:
    from pedcal.track.train import train_detector_cli

    return train_detector_cli(args)


def cmd_detect(args) -> int:
    from pedcal.track.detect_cli import detect_cli

    return detect_cli(args)


def cmd_detect_eval(args) -> int:
    from pedcal.track.detect_cli import detect_eval_cli

    return detect_eval_cli(args)


def cmd_report(args) -> int:
    from pedcal.report.command import report_command

    return report_command(args)


def cmd_follow(args) -> int:
    from pedcal.track.follow import run_follow

    res = run_follow(args.scenario, tracker=args.tracker, seed=args.seed, people_csv=args.people,
                     target_id=args.target, progress=not args.json)
    if args.output is not None:
        res.save(args.output)
    if args.json:
        _print_json(res.to_dict())
    else:
        print(res.format_table())
    return 0


# ------------------------------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pedcal", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("simulate", help="simulate a scenario: a calibration log and an evaluation log")
    s.add_argument("scenario", help="scenario name in datasets/ (paper, sparse, mall) or a scenario file")
    s.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    s.add_argument("--vary-nuisances", action="store_true",
                   help="draw the nuisance models (head point, AMCL error, odometry, latency, depth noise) "
                        "from the seed")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("evaluate", help="the papers' accuracy figures of an extrinsics file on a log")
    s.add_argument("log", type=Path)
    s.add_argument("--extrinsics", required=True, type=Path)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_evaluate)

    s = sub.add_parser("calibrate", help="calibrate the ceiling sensors of a log")
    s.add_argument("log", type=Path)
    s.add_argument("-o", "--output", required=True, type=Path, help="calibrated sensors YAML")
    s.add_argument("--method", default="factorgraph",
                   choices=["factorgraph", "gridsearch", "alternative", "closedform"])
    s.add_argument("--graph", type=Path, default=None, help="factor-graph recipe (graphs/*.toml)")
    s.add_argument("--online", action="store_true", help="incremental (iSAM2) calibration")
    s.add_argument("--sensor-height-sigma", type=float, default=None, metavar="M",
                   help="height reference: the installed sensor heights are measured to this sigma (m)")
    s.add_argument("--ceiling-height", type=float, default=None, metavar="M",
                   help="height reference: every sensor is at this height (m), to --sensor-height-sigma")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("import-bag", help="ROS 1/2 bag -> robot.csv / odometry.csv")
    s.add_argument("bag", type=Path)
    s.add_argument("-o", "--output", required=True, type=Path, help="log directory")
    s.add_argument("--amcl-topic", default=None)
    s.add_argument("--odom-topic", default=None)
    s.set_defaults(func=cmd_import_bag)

    s = sub.add_parser("import-people", help="recorded pedestrian file (ATC, ETH/UCY, THOR) -> people CSV")
    s.add_argument("input", type=Path)
    s.add_argument("-o", "--output", required=True, type=Path)
    s.add_argument("--kind", default="auto", choices=["auto", "atc", "eth_ucy", "thor", "people"])
    s.set_defaults(func=cmd_import_people)

    s = sub.add_parser("demo", help="simulate the paper scenario, calibrate it, print the accuracy table")
    s.add_argument("-o", "--output", type=Path, default=Path("runs/paper"))
    s.add_argument("--scenario", default="paper")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=cmd_demo)

    s = sub.add_parser("train-detector", help="train the person classifier (RealAdaBoost)")
    s.add_argument("-o", "--output", type=Path, default=None, help="model file (default: the shipped one)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--frames", type=int, default=None, help="simulated training frames")
    s.add_argument("--labelled", type=Path, default=None, help="a user's labelled clusters instead")
    s.set_defaults(func=cmd_train_detector)

    s = sub.add_parser("detect", help="detect people in a point cloud file (.pcd, .ply, KITTI .bin)")
    s.add_argument("file", type=Path)
    s.add_argument("--model", type=Path, default=None)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_detect)

    s = sub.add_parser("detect-eval", help="recall and precision on freshly simulated frames")
    s.add_argument("--frames", type=int, default=200)
    s.add_argument("--seed", type=int, default=12345)
    s.add_argument("--preset", default="fx8", help="LIDAR preset (default: the paper's FX8 pair)")
    s.add_argument("--model", type=Path, default=None)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_detect_eval)

    s = sub.add_parser("report", help="accuracy report (methods x scenarios x seeds vs the papers' tables), "
                                      "or compare extrinsics files on a log")
    s.add_argument("log", nargs="?", type=Path, default=None, help="compare --extrinsics files on this log")
    s.add_argument("--extrinsics", action="append", type=Path, default=[], help="calibrated YAML (repeatable)")
    s.add_argument("--scenarios", nargs="+", default=None, metavar="NAME[:SEEDS]",
                   help="default: paper sparse mall:3")
    s.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 per scenario (default 10)")
    s.add_argument("--methods", nargs="+", default=None, help="default: every method and the installed extrinsics")
    s.add_argument("--out", type=Path, default=None, help="output directory (default reports/default)")
    s.add_argument("--from-results", type=Path, default=None, help="rebuild the report from saved results")
    s.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    s.add_argument("--workers", type=int, default=None, help="local Dask worker processes (default: cores)")
    s.add_argument("--serial", action="store_true", help="run in this process, without Dask")
    s.add_argument("--follow-scenes", nargs="+", default=None, metavar="SCENE",
                   help="following scenes for the tracking tables (default: passing corner crossing crowd recorded)")
    s.add_argument("--follow-trackers", nargs="+", default=None, metavar="TRACKER",
                   help="default: paper lidar-only factorgraph")
    s.add_argument("--follow-seeds", type=int, default=None,
                   help="following seeds 0..N-1 per scene (default 5; 0 leaves the tracking tables out)")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("follow", help="follow one person in simulation and score the tracker")
    s.add_argument("scenario", nargs="?", default="passing", help="passing, corner, crossing, crowd, recorded")
    s.add_argument("--people", type=Path, default=None, help="trajectories CSV (t, person, x, y) instead")
    s.add_argument("--target", default=None, help="with --people: the person carrying the transmitter")
    s.add_argument("--tracker", default="paper", choices=["paper", "lidar-only", "factorgraph"])
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--json", action="store_true")
    s.add_argument("-o", "--output", type=Path, default=None, help="save follow.json and follow_log.parquet here")
    s.set_defaults(func=cmd_follow)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except PedcalInputError as e:
        print(f"pedcal {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FileNotFoundError as e:
        print(f"pedcal {args.command}: error: {e.filename or e}: no such file or directory", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:      # output piped into a reader that stopped (e.g. `| head`)
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
