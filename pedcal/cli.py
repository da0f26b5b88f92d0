"""pedcal command line: parse, call one library function per command, map errors to exit codes.

Exit codes: 0 success, 2 bad input (message names the file, row, column), 1 anything else.
Each handler imports its library module lazily so that `pedcal --help` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
import warnings
from pathlib import Path

from pedcal import interrupts, options
from pedcal.errors import PedcalInputError

EXIT_BAD_INPUT = 2
SCHEDULER_CONNECT_S = 10      # a Dask scheduler that does not answer within this is refused


def _print_json(obj) -> None:
    from pedcal.jsontext import dumps

    print(dumps(obj, indent=2, sort_keys=False))


# ----------------------------------------------------------------------------------------- commands
def cmd_simulate(args) -> int:
    from pedcal.io.atomic import check_output
    from pedcal.sim import simulate

    check_output(args.output, inputs=[args.scenario if Path(args.scenario).exists() else None], directory=True)
    if Path(args.scenario).is_file():       # refused before the folder is copied aside
        from pedcal.sim import check_scenario_outside

        check_scenario_outside(args.scenario, args.output)

    def run(args) -> int:
        result = simulate(args.scenario, args.output, seed=args.seed, progress=not args.quiet,
                          **({"vary_nuisances": True if args.vary_nuisances == "classic" else "zoo"}
                             if getattr(args, "vary_nuisances", None) else {}))
        print(result.summary())
        return 0

    return _into_folder(args, "output", run)   # calib/, eval/ and scenario.yaml of one seed, all at once


def cmd_evaluate(args) -> int:
    from pedcal.io import read_log, read_sensors_yaml
    from pedcal.metrics import evaluate, id_listing

    log = read_log(args.log)
    ext = read_sensors_yaml(args.extrinsics)
    res = evaluate(log, ext)
    foreign = res.foreign_sensors
    if foreign:                # a file of another site, or sensors renamed: not scored, not in silence
        logging.getLogger("pedcal").warning(
            f"{args.extrinsics}: {len(foreign)} sensor(s) not in the log's sensors.yaml, not scored: "
            f"{id_listing(foreign)}")
    if log.truth is None:      # a real log: the table's position and orientation columns stay empty
        logging.getLogger("pedcal").warning(
            f"{args.log} has no truth.yaml: sensor position and orientation errors cannot be computed (left "
            f"empty); the head tracking RMS is against {res.head_reference}")
    if args.json:
        _print_json(res.to_dict())
    else:
        print(res.format_table())
    return 0


def cmd_calibrate(args) -> int:
    with _loading():
        import importlib

        from pedcal.calib import METHODS, calibrate
        from pedcal.io import read_log, write_sensors_yaml
        from pedcal.io.atomic import check_output

        importlib.import_module(METHODS[args.method][0])

    check_output(args.output, inputs=[args.log, args.graph])
    log = read_log(args.log)
    kwargs = {}
    if args.max_memory_gb is not None:
        kwargs["max_memory_gb"] = args.max_memory_gb
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
    from pedcal.io.atomic import check_output

    check_output(args.output, inputs=[args.bag, args.sensors], directory=True)
    return _into_folder(args, "output", _import_bag)      # the log folder changes all at once


def _import_bag(args) -> int:
    from pedcal.io.ros import import_bag

    pose_sigma = None if args.pose_sigma is None else (args.pose_sigma[0], math.radians(args.pose_sigma[1]))
    written = import_bag(args.bag, args.output, amcl_topic=args.amcl_topic, odom_topic=args.odom_topic,
                         sensors=args.sensors, head_offset_m=args.head_offset, localization=args.localization,
                         localization_topic=args.localization_topic, map_frame=args.map_frame,
                         base_frame=args.base_frame, head_frame=args.head_frame, people=args.people,
                         people_frame=args.people_frame, pose_sigma=pose_sigma)
    for path, n in written.items():
        print(f"wrote {path} ({n} {'rows' if path.suffix in ('.csv', '.parquet') else 'entries'})")
    return 0


def cmd_export(args) -> int:
    from pedcal.io.atomic import check_output

    check_output(args.output, inputs=[args.input, *args.extrinsics], directory=args.format == "tum")
    if args.format == "tum":
        return _into_folder(args, "output", _export_tum)    # the TUM files change all at once
    from pedcal.io.export import export_extrinsics

    if args.extrinsics:
        raise PedcalInputError("--extrinsics goes with --format tum; give the calibrated YAML as INPUT",
                               path=args.input)
    path = export_extrinsics(args.input, args.output, args.format, ros_version=args.ros, prefix=args.prefix,
                             optical=args.optical)
    print(f"wrote {path}")
    return 0


def _export_tum(args) -> int:
    from pedcal.io import read_log, read_sensors_yaml
    from pedcal.io.tum import write_tum

    log = read_log(args.input)
    nets = {p.stem: read_sensors_yaml(p) for p in args.extrinsics}
    for name, path in write_tum(log, args.output, nets).items():
        print(f"wrote {path} ({name})")
    return 0


def cmd_import_people(args) -> int:
    from pedcal.io import write_people_csv
    from pedcal.io.atomic import check_output
    from pedcal.io.pedestrians import read_pedestrians

    check_output(args.output, inputs=[args.input])
    people = read_pedestrians(args.input, kind=args.kind, fps=args.fps)
    write_people_csv(people, args.output)
    print(f"wrote {args.output} ({len(people)} rows, {people['person'].nunique()} people)")
    return 0


def cmd_demo(args) -> int:
    from pedcal.demo import run_demo
    from pedcal.io.atomic import check_output

    check_output(args.output, directory=True)
    # the logs, calibrated YAMLs and results.json of one seed change all at once
    return _into_folder(args, "output", lambda a: run_demo(a.output, seed=a.seed, scenario=a.scenario, seeds=a.seeds))


ALL_REAL = Path("<every labelled folder>")  # detect-eval --real without a folder


def cmd_train_detector(args) -> int:
    from pedcal.detect.train import train_detector_cli
    from pedcal.io.atomic import check_output

    if args.output is not None:
        check_output(args.output, inputs=[args.labelled])
    return train_detector_cli(args)


def cmd_detect(args) -> int:
    from pedcal.detect.detect_cli import detect_cli

    return detect_cli(args)


def cmd_detect_eval(args) -> int:
    from pedcal.detect.detect_cli import detect_eval_cli
    from pedcal.detect.real_eval import detect_eval_extras
    from pedcal.io.atomic import check_output

    if args.real == ALL_REAL:  # --real without a folder: every labelled folder of the real recordings
        return detect_eval_extras(args, all_real=True)
    if args.output is None or args.real is None:      # -o holds the pictures of --real frames
        rc = detect_eval_cli(args)
        return rc if rc or args.real is not None else detect_eval_extras(args, all_real=False)
    check_output(args.output, inputs=[args.real, args.model], directory=True)
    return _into_folder(args, "output", detect_eval_cli)


def _into_folder(args, name: str, run) -> int:
    """``run(args)`` writing the folder ``args.<name>`` all at once (pedcal.io.atomic.atomic_dir):
    into a temporary sibling that takes its place when ``run`` succeeds; the printed text names
    the folder, not the temporary."""
    import contextlib
    import io

    from pedcal.io.atomic import atomic_dir

    target = getattr(args, name)
    text = io.StringIO()
    with atomic_dir(target) as tmp:
        setattr(args, name, tmp)
        handlers = logging.getLogger("pedcal").handlers
        renamer = _RenameInMessages(str(tmp), str(target))
        for h in handlers:       # warnings and progress name the folder too
            h.addFilter(renamer)
        try:
            with contextlib.redirect_stdout(text):
                code = run(args)
        except (PedcalInputError, OSError) as e:    # its message names the folder too
            _rename_in_error(e, str(tmp), str(target))
            raise
        finally:
            for h in handlers:
                h.removeFilter(renamer)
            setattr(args, name, target)
            sys.stdout.write(text.getvalue().replace(str(tmp), str(target)))
        if code:
            raise _Failed(code)
        _rename_in_texts(tmp, str(tmp), str(target))
    return code


def _rename_in_error(e: Exception, old: str, new: str) -> None:
    """An input or file-system error raised inside ``_into_folder`` names the folder the user gave,
    not its temporary sibling (in place: the traceback's chain is kept)."""
    if isinstance(e, OSError):
        for name in ("filename", "filename2"):
            value = getattr(e, name, None)
            if isinstance(value, str) and old in value:
                setattr(e, name, value.replace(old, new))
    elif isinstance(e, PedcalInputError):
        e.args = tuple(a.replace(old, new) if isinstance(a, str) else a for a in e.args)
        e.detail = e.detail.replace(old, new)
        if e.path is not None:
            e.path = e.path.replace(old, new)


class _RenameInMessages(logging.Filter):
    """A log record naming the temporary folder of ``_into_folder`` names the folder the user gave."""

    def __init__(self, old: str, new: str):
        super().__init__()
        self.old, self.new = old, new

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if self.old in text:
            record.msg, record.args = text.replace(self.old, self.new), None
        return True


def _rename_in_texts(folder: Path, old: str, new: str) -> None:
    """The folder's text files (a report's command line, its links) name the folder, not the
    temporary they were written into."""
    for p in folder.rglob("*"):
        if p.suffix in (".md", ".json", ".csv", ".txt", ".yaml", ".html") and p.is_file() \
                and p.stat().st_size < 64 * 1024 ** 2:
            data = p.read_bytes()
            if old.encode() in data:
                p.write_bytes(data.replace(old.encode(), new.encode()))


class _Failed(Exception):
    """A command that wrote into a folder returned a failure code: the folder is left as it was."""

    def __init__(self, code: int):
        self.code = code


def cmd_report(args) -> int:
    from pedcal.io.atomic import check_output
    from pedcal.report.command import report_command

    if args.out is None and args.log is None and args.from_results is None:
        args.out = Path("reports/default")       # the sweep's default folder, written all at once too
    if args.out is None or getattr(args, "rerun_tracking", False):
        return report_command(args)
    check_output(args.out, inputs=[args.log, *args.extrinsics, args.from_results], directory=True)
    if args.scheduler is not None:
        import dask

        dask.config.set({"distributed.comm.timeouts.connect": f"{SCHEDULER_CONNECT_S}s"})
    try:
        return _into_folder(args, "out", report_command)
    except OSError as e:          # TimeoutError is one: no scheduler answers at the address
        if args.scheduler is None or e.filename is not None:
            raise
        raise PedcalInputError(f"cannot reach the Dask scheduler at {args.scheduler} within "
                               f"{SCHEDULER_CONNECT_S} s: {e}") from None


def cmd_follow(args) -> int:
    from pedcal.io import preflight
    from pedcal.io.atomic import check_output
    from pedcal.track.follow import run_follow

    if args.people is not None and args.target is None:
        return _list_follow_targets(args)
    if args.output is not None:
        check_output(args.output, inputs=[args.people], directory=True)
    with preflight.limits(max_follow_s=args.max_duration_s):
        res = run_follow(args.scenario, tracker=args.tracker, seed=args.seed, people_csv=args.people,
                         target_id=args.target, progress=not args.json, density_per_10m2=args.density,
                         sensing=args.sensing, lidar=args.lidar)
    if args.output is not None:
        def save(a) -> int:          # follow.json and follow_log.parquet change together
            res.save(a.output)
            return 0

        _into_folder(args, "output", save)
    if args.json:
        _print_json(res.to_dict())
    else:
        print(res.format_table())
    return 0


def _list_follow_targets(args) -> int:
    """``pedcal follow --people FILE`` without ``--target``: the people who could be followed."""
    from pedcal.sim.follow import candidate_targets
    from pedcal.track.follow import read_people

    cands = candidate_targets(read_people(args.people))
    if args.json:
        _print_json({"people": args.people.as_posix(), "candidates": [
            {"person": r.person, "start_s": float(r.start_s), "duration_s": float(r.duration_s), "rows": int(r.rows)}
            for r in cands.itertuples()]})
        return 0
    print(f"{args.people}: {len(cands)} people; give one with --target ID (longest first)")
    print(f"  {'person':>12} {'start_s':>10} {'duration_s':>10} {'rows':>6}")
    for r in cands.itertuples():
        print(f"  {r.person:>12} {r.start_s:10.1f} {r.duration_s:10.1f} {r.rows:6d}")
    return 0


def cmd_follow_bench(args) -> int:
    from pedcal.io.atomic import check_output
    from pedcal.sim.follow_lidar import check_sensing
    from pedcal.sim.walkers import SHARED_DATA
    from pedcal.track.follow_bench import run_follow_bench

    check_sensing(args.sensing, args.lidar)   # the options first, then the file system
    check_output(args.out, inputs=[args.data_dir or SHARED_DATA], directory=True)

    def run(args) -> int:
        path = run_follow_bench(args.data_dir, args.out, trackers=args.trackers, seeds=args.seeds,
                                min_duration_s=args.min_duration, max_targets=args.max_targets,
                                files=args.files, progress=not args.quiet, sensing=args.sensing, lidar=args.lidar)
        print(f"wrote {path}")
        return 0

    return _into_folder(args, "out", run)   # bench.md, the tables and figures change all at once


# ------------------------------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pedcal", description=__doc__.splitlines()[0])
    p.add_argument("-q", "--quiet", dest="log_quiet", action="store_true", help="warnings and errors only")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more detail (debug messages)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("simulate", help="simulate a scenario: a calibration log and an evaluation log")
    s.add_argument("scenario", help="scenario name in datasets/ (paper, sparse, mall) or a scenario file")
    s.add_argument("-o", "--output", required=True, type=options.path, help="output directory")
    s.add_argument("--seed", type=options.arg("seed"), default=0)
    s.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    s.add_argument("--vary-nuisances", nargs="?", const="classic", choices=("classic", "zoo"), default=None,
                   help="draw the nuisance models (head point, AMCL error, odometry, latency, depth noise) "
                        "from the seed; 'zoo' also head points that ramp or saturate with distance, one per "
                        "sensor, per-sensor clock offsets and skews, mixed heights, wall mounts, relocalizations")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("evaluate", help="the papers' accuracy figures of an extrinsics file on a log")
    s.add_argument("log", type=options.path)
    s.add_argument("--extrinsics", required=True, type=options.path)
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_evaluate)

    s = sub.add_parser("calibrate", help="calibrate the ceiling sensors of a log")
    s.add_argument("log", type=options.path)
    s.add_argument("-o", "--output", required=True, type=options.path, help="calibrated sensors YAML")
    s.add_argument("--method", default="factorgraph",
                   choices=["factorgraph", "gridsearch", "alternative", "closedform"])
    s.add_argument("--graph", type=options.path, default=None, help="factor-graph recipe (graphs/*.toml)")
    s.add_argument("--online", action="store_true", help="incremental (iSAM2) calibration")
    s.add_argument("--max-memory-gb", type=options.arg("max_memory_gb"), default=None,
                   help="refuse a log whose graph would need more memory (default 4)")
    s.add_argument("--sensor-height-sigma", type=options.arg("sensor_height_sigma"), default=None, metavar="M",
                   help="height reference: the installed sensor heights are measured to this sigma (m)")
    s.add_argument("--ceiling-height", type=options.arg("ceiling_height"), default=None, metavar="M",
                   help="height reference: every sensor is at this height (m), to --sensor-height-sigma")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("import-bag", help="ROS 1/2 bag or rostopic echo -p CSV -> a log directory")
    s.add_argument("bag", type=options.path)
    s.add_argument("-o", "--output", required=True, type=options.path, help="log directory")
    s.add_argument("--amcl-topic", default=None)
    s.add_argument("--odom-topic", default=None)
    s.add_argument("--localization", default="auto", choices=["auto", "amcl", "odometry", "tf"],
                   help="robot.csv from /amcl_pose, an Odometry topic in the map frame, or /tf map -> base_link")
    s.add_argument("--localization-topic", default=None, help="the AMCL or map-frame Odometry topic")
    s.add_argument("--map-frame", default="map")
    s.add_argument("--base-frame", default="base_link")
    s.add_argument("--head-frame", default=None, help="head offset from /tf (base frame -> this frame)")
    s.add_argument("--head-offset", type=options.arg("head_offset"), nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="head top in the base frame (m), written to meta.yaml")
    s.add_argument("--people", action="append", default=None, metavar="TOPIC=SENSOR",
                   help="people-tracker topic of one ceiling sensor -> observations.csv (repeatable; SENSOR "
                        "defaults to the topic name)")
    s.add_argument("--people-frame", default="auto", choices=["auto", "world", "sensor", "optical"],
                   help="frame of the people points (auto: from each header)")
    s.add_argument("--sensors", type=options.path, default=None,
                   help="installed sensors.yaml: maps sensor/optical-frame points, copied into the log")
    s.add_argument("--pose-sigma", type=options.arg("pose_sigma"), nargs=2, default=None, metavar=("M", "DEG"),
                   help="localization sigma when the source has no covariance (/tf)")
    s.set_defaults(func=cmd_import_bag)

    s = sub.add_parser("export", help="calibrated extrinsics as a ROS launch file, URDF or JSON; a log's paths as TUM")
    s.add_argument("input", type=options.path, help="calibrated YAML (tf-launch, urdf, json) or a log directory (tum)")
    s.add_argument("--format", required=True, choices=["tf-launch", "urdf", "json", "tum"])
    s.add_argument("-o", "--output", required=True, type=options.path, help="output file (tum: a directory)")
    s.add_argument("--ros", type=int, default=1, choices=[1, 2], help="tf-launch: ROS 1 or ROS 2 launch XML")
    s.add_argument("--prefix", default="", help="child frame = prefix + sensor id")
    s.add_argument("--extrinsics", action="append", type=options.path, default=[],
                   help="tum: also the head path seen with these extrinsics (repeatable)")
    s.add_argument("--optical", action="store_true",
                   help="tf-launch, urdf: add each sensor's <child>_optical frame (z forward, x right, y down)")
    # --ros unset: XML for ROS 1, or a ROS 2 Python launch file when the output is named .launch.py
    s.set_defaults(func=cmd_export, ros=None)

    s = sub.add_parser("import-people", help="recorded pedestrian file (ATC, ETH/UCY, THOR) -> people CSV")
    s.add_argument("input", type=options.path)
    s.add_argument("-o", "--output", required=True, type=options.path)
    s.add_argument("--kind", default="auto", choices=["auto", "atc", "eth_ucy", "thor", "people"])
    s.add_argument("--fps", type=options.arg("fps"), default=None,
                   help="frame rate of a frame-numbered (ETH/UCY) file whose name does not identify the recording")
    s.set_defaults(func=cmd_import_people)

    s = sub.add_parser("demo", help="simulate the paper scenario, calibrate it, print the accuracy table")
    s.add_argument("-o", "--output", type=options.path, default=Path("runs/paper"))
    s.add_argument("--scenario", default="paper")
    s.add_argument("--seed", type=options.arg("seed"), default=0)
    s.add_argument("--seeds", type=options.arg("seeds"), default=4,
                   help="seeds from --seed on whose mean and spread are printed after --seed's table (default 4)")
    s.set_defaults(func=cmd_demo)

    s = sub.add_parser("train-detector", help="train the person classifier (RealAdaBoost)")
    s.add_argument("-o", "--output", type=options.path, default=None,
                   help="model file (default: the shipped one of --family)")
    s.add_argument("--family", default="general", choices=["general", "fx8"],
                   help="general: every trained LIDAR (default); fx8: the paper's FX8 pair's own model")
    s.add_argument("--seed", type=options.arg("seed"), default=0)
    s.add_argument("--frames", type=options.arg("frames"), default=None,
                   help="simulated training frames (default: the family's)")
    s.add_argument("--labelled", type=options.path, default=None, help="a user's labelled clusters instead")
    s.add_argument("--data-dir", type=options.path, default=None,
                   help="general family: the real labelled recordings trained on (default: $PEDCAL_DATA, else "
                        "../shared/data beside the repository)")
    s.add_argument("--select", action="store_true",
                   help="general family: choose classifier, features and threshold anew by leave-one-dataset-"
                        "out validation over the candidates (slow) instead of the family's choice")
    s.set_defaults(func=cmd_train_detector)

    s = sub.add_parser("detect", help="detect people in a point cloud file (.pcd, .ply, KITTI .bin, .npy)")
    s.add_argument("file", type=options.path)
    s.add_argument("--model", type=options.path, default=None)
    s.add_argument("--json", action="store_true")
    s.add_argument("--sensor", default=None, help="fx8, depth-camera, vlp16, os1-32, hdl32, hdl64, pandar40, "
                                                  "solid-dense, sparse-tof (default: ray spacing estimated from "
                                                  "the cloud)")
    s.add_argument("--frame", default="body", choices=["body", "optical"],
                   help="body: x forward, y left, z up (default); optical: a camera's optical frame, x right, "
                        "y down, z forward. Detections are reported in the body frame")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--sensor-pose", default=None, type=options.sensor_pose, metavar="x,y,z,roll,pitch,yaw",
                   help="the sensor's (body frame's) pose above the floor (m, deg; positive pitch looks down)")
    g.add_argument("--floor", default="auto", choices=["auto", "plane", "none"],
                   help="auto: local ground height, stray returns below it ignored, implausible ground warned "
                        "(default); plane: one RANSAC plane; none: z is already floor height")
    s.set_defaults(func=cmd_detect)

    s = sub.add_parser("detect-eval", help="recall and precision on freshly simulated frames")
    s.add_argument("--frames", type=options.arg("frames"), default=200)
    s.add_argument("--seed", type=options.arg("seed"), default=12345)
    s.add_argument("--preset", default="fx8", help="LIDAR preset (default: the paper's FX8 pair)")
    s.add_argument("--model", type=options.path, default=None)
    s.add_argument("--json", action="store_true")
    s.add_argument("--real", type=options.path, default=None, nargs="?", const=ALL_REAL,
                   help="a folder of real frames (NAME.pcd + NAME.json boxes) instead of simulated ones; "
                        "without a folder, every labelled folder under --data-dir, per dataset and range band")
    s.add_argument("--data-dir", type=options.path, default=None,
                   help="the real recordings (default: $PEDCAL_DATA, else ../shared/data beside the repository)")
    s.add_argument("--lodo", action="store_true",
                   help="recompute the general model's leave-one-dataset-out table (retrains it once per "
                        "real dataset; slow) instead of printing the one stored with it")
    s.add_argument("-o", "--output", type=options.path, default=None, help="with --real: bird's-eye pictures here")
    s.add_argument("--sensor", default=None, help="with --real: the sensor, as for pedcal detect")
    s.add_argument("--floor", default="auto", choices=["auto", "plane", "none"],
                   help="with --real: as for pedcal detect")
    s.set_defaults(func=cmd_detect_eval)

    s = sub.add_parser("report", help="accuracy report (methods x scenarios x seeds vs the papers' tables), "
                                      "or compare extrinsics files on a log")
    s.add_argument("log", nargs="?", type=options.path, default=None, help="compare --extrinsics files on this log")
    s.add_argument("--extrinsics", action="append", type=options.path, default=[], help="calibrated YAML (repeatable)")
    s.add_argument("--scenarios", nargs="+", default=None, metavar="NAME[:SEEDS]",
                   help="default: paper sparse mall:3")
    s.add_argument("--seeds", type=options.arg("seeds"), default=10, help="seeds 0..N-1 per scenario (default 10)")
    s.add_argument("--methods", nargs="+", default=None, help="default: every method and the installed extrinsics")
    s.add_argument("--out", type=options.path, default=None, help="output directory (default reports/default)")
    s.add_argument("--from-results", type=options.path, default=None, help="rebuild the report from saved results")
    s.add_argument("--rerun-tracking", action="store_true",
                   help="with --from-results: run the following part again, keep the calibration tables")
    s.add_argument("--scheduler", default=None, type=options.scheduler_address,
                   help="address of a running Dask scheduler")
    s.add_argument("--workers", type=options.arg("workers"), default=None,
                   help="local Dask worker processes (default: cores)")
    s.add_argument("--serial", action="store_true", help="run in this process, without Dask")
    s.add_argument("--follow-scenes", nargs="+", default=None, metavar="SCENE",
                   help="following scenes for the tracking tables (default: passing corner crossing crowd recorded)")
    s.add_argument("--follow-trackers", nargs="+", default=None, metavar="TRACKER",
                   help="default: paper lidar-only factorgraph")
    s.add_argument("--follow-seeds", type=options.arg("follow_seeds"), default=None,
                   help="following seeds 0..N-1 per scene (default 5; 0 leaves the tracking tables out)")
    s.add_argument("-q", "--quiet", action="store_true")
    s.set_defaults(func=cmd_report)

    s = sub.add_parser("follow", help="follow one person in simulation and score the tracker")
    s.add_argument("scenario", nargs="?", default="passing", help="passing, corner, crossing, crowd, recorded")
    s.add_argument("--people", type=options.path, default=None, help="trajectories CSV (t, person, x, y) instead")
    s.add_argument("--target", default=None, help="with --people: the person carrying the transmitter")
    s.add_argument("--tracker", default="factorgraph", choices=["paper", "lidar-only", "factorgraph"],
                   help="the factor graph by default: at or above the paper tracker on every follow-bench recording "
                        "with the abstract model, and with --sensing lidar over seeds 0-1 (below it on ETH's "
                        "seed 0; reports/follow-bench-lidar)")
    s.add_argument("--seed", type=options.arg("seed"), default=0)
    s.add_argument("--json", action="store_true")
    s.add_argument("-o", "--output", type=options.path, default=None,
                   help="save follow.json and follow_log.parquet here")
    s.add_argument("--max-duration-s", type=options.arg("max_duration_s"), default=None,
                   help="with --people: refuse a target trajectory longer than this (default 3600 s)")
    s.add_argument("--density", type=options.arg("density"), default=None, metavar="P10M2",
                   help="crowd scene: people per 10 m^2 (default: 12 walkers, about 0.5)")
    _sensing_options(s)
    s.set_defaults(func=cmd_follow)

    s = sub.add_parser("follow-bench", help="follow every long-present person of every real recording and "
                       "report the distribution per recording and tracker")
    s.add_argument("--data-dir", type=options.path, default=None,
                   help="the recordings folder (default: ../shared/data)")
    s.add_argument("--files", nargs="+", default=None, metavar="FILE",
                   help="recordings under the data folder (default: ATC, ETH, HOTEL, ZARA, THOR)")
    s.add_argument("--trackers", nargs="+", default=None, metavar="TRACKER",
                   help="default: paper lidar-only factorgraph")
    s.add_argument("--seeds", type=options.arg("seeds"), default=3, help="seeds 0..N-1 per target (default 3)")
    s.add_argument("--min-duration", type=options.arg("min_duration"), default=45.0, metavar="S",
                   help="a target is present at least this long (default 45 s)")
    s.add_argument("--max-targets", type=options.arg("max_targets"), default=None, metavar="N",
                   help="at most N targets per recording (the longest present; default all)")
    s.add_argument("-o", "--out", type=options.path, default=Path("follow-bench"), help="output folder")
    s.add_argument("-q", "--quiet", action="store_true")
    _sensing_options(s)
    s.set_defaults(func=cmd_follow_bench)
    return p


def _sensing_options(s: argparse.ArgumentParser) -> None:
    """``--sensing`` and ``--lidar`` of ``follow`` and ``follow-bench`` (checked by ``check_sensing``)."""
    s.add_argument("--sensing", default="ideal", metavar="MODE",
                   help="ideal: the abstract detection model (default); lidar: the simulated LIDAR and the "
                        "shipped detector every frame")
    s.add_argument("--lidar", default=None, metavar="PRESET",
                   help="with --sensing lidar: the LIDAR preset or sensor name (default fx8, the paper's FX8 pair)")


def configure_logging(quiet: bool = False, verbose: int = 0) -> None:
    """The command line's logging: the ``pedcal`` logger to stderr, INFO (progress, drawn as bars
    on a terminal) by default, WARNING with ``-q``, DEBUG with ``-v``."""
    from pedcal.progress import ProgressHandler

    logger = logging.getLogger("pedcal")
    for h in [h for h in logger.handlers if isinstance(h, ProgressHandler)]:
        logger.removeHandler(h)
    handler = ProgressHandler()
    handler.setFormatter(_TaggedFormatter("%(message)s" if verbose == 0 else "%(levelname)s %(name)s: %(message)s"))
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    # a Python warning (degenerate data, an assumption the data cannot check) reaches the user as
    # one line through the same handler, not as a source location and a line of library code
    warnings.showwarning = _warning_to_log


class _TaggedFormatter(logging.Formatter):
    """A warning logged by the library reads ``warning: ...`` like a Python warning, so it stands
    apart from the error line below it."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if record.levelno >= logging.WARNING and not text.startswith(("warning: ", "WARNING ", "ERROR ")):
            text = f"warning: {text}"
        return text


def _warning_to_log(message, category, filename, lineno, file=None, line=None) -> None:
    logging.getLogger("pedcal").warning(f"warning: {message}")


def main(argv: list[str] | None = None) -> int:
    previous = interrupts.install()      # Ctrl-C: one line, exit 130, from here on
    code = None
    try:
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as e:      # usage error (an option outside its domain...) or --help: the code
            code = e.code if isinstance(e.code, int) else EXIT_BAD_INPUT
            return code
        configure_logging(quiet=args.log_quiet, verbose=args.verbose)
        code = _run(args)
        return code
    finally:
        if not interrupts.running_the_command_line():   # a Ctrl-C while the process exits is one line too
            interrupts.restore(previous)
        else:
            interrupts.command_ended()       # (a Ctrl-C during the interpreter's exit changes nothing)
            if code == 0:      # (after a failure the exit's collection still finalizes what the command left)
                _spare_the_last_collection()


@contextlib.contextmanager
def _loading():
    """The libraries a command imports inside (NumPy, SciPy, pandas, GTSAM: ~100 000 objects the
    cycle collector tracks, none of them garbage) load without its collections, which walked them
    again and again as they grew (75 ms of CPU of `pedcal calibrate`, both methods), and are then
    moved out of its sight (gc.freeze: they live as long as the process). Only in the command
    line's process; a library user's (``main`` called from Python) is left alone."""
    if not interrupts.running_the_command_line():
        yield
        return
    import gc

    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _spare_the_last_collection() -> None:
    """The process ends with this command, which returned cleanly (exit code 0): the objects the
    libraries made (NumPy, SciPy, pandas, GTSAM: modules, classes, docstrings' caches) are moved
    out of the cycle collector's sight, so that the interpreter's collections at exit do not walk
    them all again (0.1 s of CPU of a 1.5 s `pedcal calibrate`). Reference counting still frees
    them, atexit handlers (``weakref.finalize``'s among them) and the standard streams' flush still
    run. What is not finalized: cyclic garbage made before this point (objects in a reference
    cycle nothing reaches any more) is left to the operating system, its ``__del__`` and weak
    references' callbacks never run, so a file or writer left open in such a cycle is not flushed
    or closed; hence only after a clean return, the command's outputs written and closed. Not for
    a library user's process (``main`` called from Python)."""
    import gc

    gc.freeze()


def _run(args) -> int:
    try:
        return int(args.func(args) or 0)
    except PedcalInputError as e:
        print(f"pedcal {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FileNotFoundError as e:
        print(f"pedcal {args.command}: error: {e.filename or e}: no such file or directory", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:      # output piped into a reader that stopped (e.g. `| head`): not an error
        # stdout goes to devnull so the interpreter's final flush does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:
        from pedcal.io.atomic import _is_space_error

        if _is_space_error(e):        # a writer outside pedcal.io.atomic met a full disk
            print(f"pedcal {args.command}: error: {e.filename or 'an output'}: cannot write output: no space left "
                  "on the device", file=sys.stderr)
            return EXIT_BAD_INPUT
        if e.filename is None:
            raise
        # a path the user gave that cannot be read or written (permission, a directory, under a file)
        print(f"pedcal {args.command}: error: {e.filename}: {e.strerror or e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except _Failed as e:
        return e.code
    except MemoryError:
        print(f"pedcal {args.command}: error: out of memory", file=sys.stderr)
        return 1
    except KeyboardInterrupt:       # raised by a library that installed its own SIGINT handling
        print("interrupted", file=sys.stderr)
        return interrupts.EXIT_INTERRUPTED
    except Exception as e:      # Ctrl-C's SystemExit re-raised as another error by the code it interrupted:
        # ImportError("initialization failed") from a compiled module (GTSAM), RuntimeError("Error calling
        # __set_name__") from a class body being created (a dataclass field) while a module loads
        if interrupts.caused_by_interrupt(e):
            return interrupts.EXIT_INTERRUPTED
        raise


if __name__ == "__main__":
    sys.exit(main())
