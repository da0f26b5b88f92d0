"""`pedcal report`: the command line's three forms, each one library call."""

from __future__ import annotations

from pedcal.errors import PedcalInputError


def report_command(args) -> int:
    """``pedcal report LOG --extrinsics A --extrinsics B``: compare calibrations on a log;
    ``pedcal report --from-results DIR``: rebuild the report from saved results;
    ``pedcal report [--scenarios ...] [--seeds N] ...``: run the sweep and build the report."""
    from pedcal.report import build_report, compare_extrinsics, run_report
    from pedcal.report.sweep import (
        DEFAULT_FOLLOW_SCENES,
        DEFAULT_FOLLOW_SEEDS,
        DEFAULT_FOLLOW_TRACKERS,
        DEFAULT_SCENARIOS,
        METHOD_ORDER,
    )

    if args.log is not None:
        if args.from_results is not None:
            raise PedcalInputError("give either a LOG to compare calibrations on or --from-results, not both")
        path = compare_extrinsics(args.log, args.extrinsics, args.out, progress=not args.quiet)
    elif args.extrinsics:
        raise PedcalInputError("--extrinsics compares calibrations on a log: give the LOG directory before it")
    elif args.from_results is not None and getattr(args, "rerun_tracking", False):
        from pedcal.report import rerun_tracking

        if args.out is not None:
            raise PedcalInputError("--rerun-tracking updates the results in place: leave --out out")
        path = rerun_tracking(args.from_results, progress=not args.quiet)
    elif args.from_results is not None:
        path = build_report(args.from_results, args.out)
    else:
        path = run_report(args.scenarios or DEFAULT_SCENARIOS, args.seeds, args.methods or METHOD_ORDER,
                          args.out or "reports/default", scheduler=args.scheduler, workers=args.workers,
                          serial=args.serial, progress=not args.quiet,
                          follow_scenes=args.follow_scenes or DEFAULT_FOLLOW_SCENES,
                          follow_trackers=args.follow_trackers or DEFAULT_FOLLOW_TRACKERS,
                          follow_seeds=DEFAULT_FOLLOW_SEEDS if args.follow_seeds is None else args.follow_seeds)
    print(f"wrote {path}")
    return 0
