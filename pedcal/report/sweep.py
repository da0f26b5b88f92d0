"""Sweeps of scenarios x seeds x methods: one task per (scenario, seed), run serially or on Dask.

A task simulates ``simulate_logs(scenario, seed)``, calibrates its calibration log with every
method and evaluates each on the evaluation log (the same route driven again), as
``pedcal.demo.run_methods`` does for one log. Everything random in a task is seeded by
(scenario, seed) alone, so a task gives the same numbers wherever it runs; results are sorted by
(scenario order, seed, method order) whatever order the tasks finish in.
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from pedcal.errors import DegenerateDataWarning, PedcalInputError

# The statuses of a sensor a method left uncalibrated: "no-data" (returned with no estimate) and
# "missing" (left out of the returned network, a row of the sensors table all the same).
UNCALIBRATED = ("no-data", "missing")
METHOD_ORDER = ("installed", "alternative", "gridsearch", "closedform", "factorgraph")
DEFAULT_SCENARIOS = ("paper", "sparse", "mall:3")
DEFAULT_SEEDS = 10
# Head tracks kept for the trajectory figures (first seed of each scenario): at most this many
# robot observations per method, and this many robot poses.
MAX_HEAD_POINTS = 3000
MAX_ROBOT_POINTS = 2000
# Person following (pedcal follow): scenes x trackers x seeds, one task per (scene, seed).
DEFAULT_FOLLOW_SCENES = ("passing", "corner", "crossing", "crowd", "recorded")
DEFAULT_FOLLOW_TRACKERS = ("paper", "lidar-only", "factorgraph")
DEFAULT_FOLLOW_SEEDS = 5
FOLLOW_KEYS = ("frames", "with_target_fraction", "near_fraction", "median_distance_m", "followed_to_end",
               "id_switches", "lost_episodes", "mean_reacquire_s", "max_reacquire_s", "unrecovered_losses",
               "searching_episodes", "searching_frames", "lost_position_error_m", "mota", "motp", "idf1")


@dataclass
class SweepConfig:
    """What a sweep runs; recorded in results.json so the report says how to regenerate it."""

    scenarios: list[tuple[str, int]]           # (scenario, number of seeds: 0 .. n-1)
    methods: list[str] = field(default_factory=lambda: list(METHOD_ORDER))
    seeds: int = DEFAULT_SEEDS                 # the --seeds the command line gave
    out: str = "reports/default"
    follow_scenes: list[str] = field(default_factory=lambda: list(DEFAULT_FOLLOW_SCENES))
    follow_trackers: list[str] = field(default_factory=lambda: list(DEFAULT_FOLLOW_TRACKERS))
    follow_seeds: int = 0                      # following seeds 0 .. n-1 per scene (0: no tracking part)

    def cases(self) -> list[tuple[str, int]]:
        return [(name, seed) for name, n in self.scenarios for seed in range(n)]

    def follow_cases(self) -> list[tuple[str, int]]:
        return [(scene, seed) for scene in self.follow_scenes for seed in range(self.follow_seeds)]

    def command(self) -> str:
        """The command line that regenerates this sweep (the report's header)."""
        names = [name if n == self.seeds else f"{name}:{n}" for name, n in self.scenarios]
        follow = f" --follow-seeds {self.follow_seeds}"
        if self.follow_seeds:
            follow = (f" --follow-scenes {' '.join(self.follow_scenes)} "
                      f"--follow-trackers {' '.join(self.follow_trackers)}" + follow)
        return (f"pedcal report --scenarios {' '.join(names)} --seeds {self.seeds} "
                f"--methods {' '.join(self.methods)}{follow} --out {self.out}")

    def to_dict(self) -> dict:
        return {"scenarios": [[name, n] for name, n in self.scenarios], "methods": list(self.methods),
                "seeds": self.seeds, "out": self.out, "follow_scenes": list(self.follow_scenes),
                "follow_trackers": list(self.follow_trackers), "follow_seeds": self.follow_seeds,
                "command": self.command()}

    @classmethod
    def from_dict(cls, d: dict) -> SweepConfig:
        return cls(scenarios=[(str(a), int(b)) for a, b in d["scenarios"]], methods=list(d["methods"]),
                   seeds=int(d["seeds"]), out=str(d["out"]),
                   follow_scenes=list(d.get("follow_scenes", DEFAULT_FOLLOW_SCENES)),
                   follow_trackers=list(d.get("follow_trackers", DEFAULT_FOLLOW_TRACKERS)),
                   follow_seeds=int(d.get("follow_seeds", 0)))


def parse_scenarios(specs, seeds: int) -> list[tuple[str, int]]:
    """``["paper", "mall:3"]`` -> ``[("paper", seeds), ("mall", 3)]``; names are checked."""
    from pedcal.sim import load_scenario

    if seeds < 1:
        raise PedcalInputError(f"--seeds: expected a positive number of seeds, got {seeds}")
    out = []
    for spec in specs:
        name, _, n = str(spec).partition(":")
        try:
            n_seeds = int(n) if n else seeds
        except ValueError:
            raise PedcalInputError(f"--scenarios: expected NAME or NAME:SEEDS, got '{spec}'") from None
        if n_seeds < 1:
            raise PedcalInputError(f"--scenarios: '{spec}' asks for {n_seeds} seeds, expected at least 1")
        load_scenario(name)            # an unknown scenario is an input error naming it
        out.append((name, n_seeds))
    if len({name for name, _ in out}) != len(out):
        raise PedcalInputError(f"--scenarios: a scenario is named twice in {' '.join(map(str, specs))}")
    return out


def check_methods(methods) -> list[str]:
    from pedcal.calib import METHODS

    known = ("installed", *METHODS)
    bad = [m for m in methods if m not in known]
    if bad:
        raise PedcalInputError(f"--methods: unknown method(s) {', '.join(bad)}, expected some of {', '.join(known)}")
    return sorted(set(methods), key=lambda m: (METHOD_ORDER + tuple(METHODS)).index(m))


def _nan(x) -> float:
    return float("nan") if x is None else float(x)


def _sensor_records(scenario: str, seed: int, method: str, network, truth, ev) -> list[dict]:
    errs = {e.id: e for e in ev.sensors}
    # a sensor of the log left out of the returned network is a row too (status "missing", no
    # estimate), so that the tables count it among the misses instead of never seeing it
    missing = [SimpleNamespace(id=sid, status="missing", observations=0, position_m=np.full(3, np.nan),
                               sigma_position_m=None, sigma_ypr_deg=None) for sid in ev.missing_sensors]
    out = []
    for s in [*network, *missing]:
        t = truth[s.id]
        e = errs.get(s.id)
        err = np.asarray(e.position_error_mm if e else [np.nan] * 3, float)
        sig_mm = (np.full(3, np.nan) if s.sigma_position_m is None else 1000.0 * np.asarray(s.sigma_position_m))
        sig_deg = np.full(3, np.nan) if s.sigma_ypr_deg is None else np.asarray(s.sigma_ypr_deg, float)
        out.append(dict(
            scenario=scenario, seed=seed, method=method, sensor=s.id,
            status=s.status or "installed", observations=int(s.observations or 0),
            err_x_mm=err[0], err_y_mm=err[1], err_z_mm=err[2], err_mm=float(np.linalg.norm(err)),
            orient_err_deg=_nan(e.orientation_error_deg if e else None),
            sigma_x_mm=sig_mm[0], sigma_y_mm=sig_mm[1], sigma_z_mm=sig_mm[2],
            sigma_yaw_deg=sig_deg[0], sigma_pitch_deg=sig_deg[1], sigma_roll_deg=sig_deg[2],
            true_x_m=t.position_m[0], true_y_m=t.position_m[1], true_z_m=t.position_m[2],
            true_yaw_deg=t.ypr_deg[0], true_pitch_deg=t.ypr_deg[1], true_roll_deg=t.ypr_deg[2],
            est_x_m=s.position_m[0], est_y_m=s.position_m[1], est_z_m=s.position_m[2],
            head_rms_mm=_nan(e.head_rms_mm if e else None),
            head_observations=int(e.head_observations if e else 0)))
    return [{k: (float(v) if isinstance(v, np.floating) else v) for k, v in r.items()} for r in out]


def thin_mask(mask: np.ndarray, max_rows: int) -> np.ndarray:
    """``mask`` keeping every k-th of its True rows, k the smallest step leaving at most ``max_rows``."""
    rows = np.flatnonzero(mask)
    keep = np.zeros(len(mask), bool)
    keep[rows[:: max(1, -(-len(rows) // max_rows))]] = True
    return keep


def head_track_records(log, network, keep: np.ndarray, **labels) -> list[dict]:
    """The observations in ``keep`` recomputed with ``network``: records of labels, sensor, t_s,
    x_m, y_m (the head positions of the trajectory figures)."""
    from pedcal.metrics import reproject_observations

    p_world = reproject_observations(log, network, keep)[keep]
    sensor_col = log.observations["sensor"].astype(str).to_numpy()[keep]
    t_s = log.observations["t"].to_numpy(float)[keep]
    ok = np.isfinite(p_world[:, 0])
    return [dict(labels, sensor=str(sid), t_s=float(t), x_m=float(p[0]), y_m=float(p[1]))
            for sid, t, p in zip(sensor_col[ok], t_s[ok], p_world[ok], strict=True)]


def robot_path_records(log, *, truth: bool = True, **labels) -> list[dict]:
    """The robot's head path (x, y) at the times of truth_robot.csv (``truth``) or robot.csv,
    thinned to at most MAX_ROBOT_POINTS."""
    from pedcal.calib.common import robot_head_at

    track = log.truth_robot if truth else log.robot
    t_s = np.sort(track["t"].to_numpy(float))
    t_s = t_s[:: max(1, -(-len(t_s) // MAX_ROBOT_POINTS))]
    head = robot_head_at(log, t_s, truth=truth)
    return [dict(labels, t_s=float(t), x_m=float(p[0]), y_m=float(p[1])) for t, p in zip(t_s, head, strict=True)]


def run_case(scenario: str, seed: int, methods: list[str], keep_heads: bool = False) -> dict:
    """Simulate (scenario, seed), calibrate with each method, evaluate on the evaluation log.

    Returns plain records: ``runs`` (one per method), ``sensors`` (one per method and sensor),
    ``heads`` / ``robot`` (the calibrated head tracks and the true robot path, when
    ``keep_heads``) and ``timings`` (solve times, kept apart: they vary from run to run)."""
    from pedcal.demo import calibrate_scored
    from pedcal.metrics import evaluate, robot_rows
    from pedcal.sim import simulate_logs

    sim = simulate_logs(scenario, seed=seed)
    truth = sim.calib.truth
    runs, sensors, heads, timings = [], [], [], {}
    keep = thin_mask(robot_rows(sim.eval)[0], MAX_HEAD_POINTS)
    for method in methods:
        with warnings.catch_warnings():
            # What a method cannot estimate is in each sensor's status, which the report counts.
            warnings.simplefilter("ignore", DegenerateDataWarning)
            network, runtime_s, assoc = calibrate_scored(sim, method)
            ev = evaluate(sim.eval, network)
        # a sensor of the log the method left out counts among the sensors and the uncalibrated
        statuses = [s.status or "installed" for s in network] + ["missing"] * len(ev.missing_sensors)
        rms = ev.sensor_position_rms_mm
        runs.append(dict(
            scenario=scenario, seed=seed, method=method,
            sensor_rms_mm=rms.combined, sensor_rms_x_mm=rms.x, sensor_rms_y_mm=rms.y,
            sensor_rms_z_mm=rms.z, orientation_rms_deg=float(ev.orientation_rms_deg),
            head_rms_mm=_nan(ev.head_tracking_rms_mm), head_observations=int(ev.head_observations),
            sensors=len(statuses), ok=statuses.count("ok"), degenerate=statuses.count("degenerate"),
            no_data=sum(statuses.count(u) for u in UNCALIBRATED),
            assoc_precision=_nan(assoc["precision"] if assoc else None),
            assoc_recall=_nan(assoc["recall"] if assoc else None),
            latency_s=_nan(network.extra.get("tracker_latency_s"))))
        sensors += _sensor_records(scenario, seed, method, network, truth, ev)
        timings[method] = runtime_s
        if keep_heads:
            heads += head_track_records(sim.eval, network, keep, scenario=scenario, seed=seed, method=method)
    robot_path = robot_path_records(sim.eval, scenario=scenario, seed=seed) if keep_heads else []
    return dict(scenario=scenario, seed=seed, runs=runs, sensors=sensors, heads=heads, robot=robot_path,
                bounds=crlb_records(sim.calib, scenario=scenario, seed=seed), timings=timings)


def run_follow_case(scene: str, seed: int, trackers: list[str]) -> dict:
    """Run the following episode (scene, seed) with each tracker (``pedcal.track.follow.run_follow``);
    one record of the follow metrics per tracker."""
    from pedcal.track.follow import run_follow

    rows = []
    for tracker in trackers:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = run_follow(scene, tracker=tracker, seed=seed).to_dict()
        rows.append(dict(scene=scene, seed=seed, tracker=tracker,
                         **{k: (None if m.get(k) is None else float(m[k])) for k in FOLLOW_KEYS}))
    return dict(scene=scene, seed=seed, tracking=rows)


def check_follow(scenes, trackers) -> tuple[list[str], list[str]]:
    """The following scenes and trackers, checked against the simulator's and the tracker registry."""
    from pedcal.sim.follow import SCENARIOS
    from pedcal.track.trackers import TRACKERS

    for name in scenes:
        if name not in SCENARIOS:
            raise PedcalInputError(f"--follow-scenes: unknown scene {name!r}; expected one of {', '.join(SCENARIOS)}")
    for name in trackers:
        if name not in TRACKERS:
            raise PedcalInputError(f"--follow-trackers: unknown tracker {name!r}; expected one of "
                                   f"{', '.join(TRACKERS)}")
    return list(scenes), list(trackers)


def _run_task(task: tuple) -> dict:
    """One sweep task: ("calib", scenario, seed, methods, keep_heads) or ("follow", scene, seed, trackers)."""
    return run_case(*task[1:]) if task[0] == "calib" else run_follow_case(*task[1:])


def crlb_records(log, **labels) -> list[dict]:
    """Per sensor the Cramér-Rao bound (1-sigma per world axis and the 3-D sqrt(trace), mm) of its
    position from the calibration log (``pedcal.calib.crlb``, the factor graph's noise models)."""
    from pedcal.calib.crlb import sensor_position_crlb

    res = sensor_position_crlb(log)
    out = []
    for sid, cov in res.position_covariance_m2.items():
        sig = res.sigma_mm(sid)
        out.append(dict(labels, sensor=str(sid), crlb_x_mm=float(sig[0]), crlb_y_mm=float(sig[1]),
                        crlb_z_mm=float(sig[2]), crlb_3d_mm=float(1000.0 * np.sqrt(np.trace(cov)))))
    return out


def _progress(enabled: bool, text: str) -> None:
    if enabled:
        logging.getLogger(__name__).info(f"report: {text}")


def run_sweep(config: SweepConfig, *, scheduler: str | None = None, workers: int | None = None,
              serial: bool = False, progress: bool = True) -> list[dict]:
    """Run every (scenario, seed) task of ``config``: serially, on the Dask scheduler at
    ``scheduler`` (an address), or on a LocalCluster of ``workers`` processes (default: the cores
    present), one thread each. Returns the task results sorted by (scenario order, seed)."""
    first_seed = {name: 0 for name, _ in config.scenarios}
    tasks = [("calib", name, seed, list(config.methods), seed == first_seed[name]) for name, seed in config.cases()]
    tasks += [("follow", scene, seed, list(config.follow_trackers)) for scene, seed in config.follow_cases()]
    t0 = time.perf_counter()
    done: list[dict] = []

    def label(r: dict) -> str:
        return f"{r['scenario']} seed {r['seed']}" if "scenario" in r else f"following {r['scene']} seed {r['seed']}"

    if serial:
        for k, task in enumerate(tasks, 1):
            done.append(_run_task(task))
            _progress(progress, f"{k}/{len(tasks)} done ({label(done[-1])}, {time.perf_counter() - t0:.0f} s)")
    else:
        from dask.distributed import Client, LocalCluster, as_completed

        from pedcal.interrupts import children_ignore

        cluster = None
        if scheduler is None:
            n = workers or os.cpu_count() or 1
            _progress(progress, f"starting a local Dask cluster: {n} worker processes, 1 thread each")
            # ":0": any free port for the scheduler's HTTP endpoint, so parallel sweeps do not collide.
            with children_ignore():      # Ctrl-C reaches the workers too: this process alone answers it
                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                       silence_logs=logging.CRITICAL)   # a task's error reaches us as its result
        try:
            with Client(scheduler or cluster) as client:
                futures = [client.submit(_run_task, task, key=f"pedcal-report-{task[0]}-{task[1]}-{task[2]}",
                                         pure=False) for task in tasks]
                for k, fut in enumerate(as_completed(futures), 1):
                    r = fut.result()
                    done.append(r)
                    _progress(progress, f"{k}/{len(tasks)} done ({label(r)}, {time.perf_counter() - t0:.0f} s)")
        finally:
            if cluster is not None:
                cluster.close()
    order = {name: i for i, (name, _) in enumerate(config.scenarios)}
    follow_order = {name: i for i, name in enumerate(config.follow_scenes)}

    def key(r: dict) -> tuple:
        return (0, order[r["scenario"]], r["seed"]) if "scenario" in r else (1, follow_order[r["scene"]], r["seed"])

    return sorted(done, key=key)
