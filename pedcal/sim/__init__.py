"""Seeded simulator of a ceiling depth-sensor network watched while a localized robot drives
through it (Kimoto et al.'s experiment), with pedestrians, false tracks and every nuisance.

``simulate_logs(scenario, seed)`` returns a calibration log and an evaluation log in memory (the
same route driven twice with independent noise, the same sensors and installed extrinsics);
``simulate(scenario, out_dir, seed)`` also writes them as log directories (LOG_FORMAT.md).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pedcal.calib.common import head_world, interpolate_pose2
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.io.atomic import write_text_atomic
from pedcal.model import Log, Meta, SensorNetwork
from pedcal.options import check
from pedcal.sim import ceiling, robot, walkers
from pedcal.sim.nuisances import sensor_truth, vary
from pedcal.sim.scenario import Scenario, load_scenario

ROBOT, FALSE = "robot", "false"


@dataclass
class SimulationResult:
    calib: Log
    eval: Log
    scenario: Scenario

    def summary(self) -> str:
        lines = [f"scenario {self.scenario.name}, seed {self.scenario.seed}: "
                 f"{len(self.calib.sensors)} sensors"]
        for name, log in (("calib", self.calib), ("eval", self.eval)):
            s = log_summary(log)
            lines.append(f"  {name:5s} {s['observations']:7d} observations, {s['robot']:6d} of the robot, "
                         f"{s['pedestrians']:4d} pedestrians, {s['false_tracks']:4d} false tracks, "
                         f"{s['duration_s']:.0f} s")
        return "\n".join(lines)


def log_summary(log: Log) -> dict:
    """Counts of a simulated log: observations, robot observations, pedestrians seen, false
    tracks (distinct sensor/track pairs) and the run's duration."""
    who = log.truth_observations["who"].to_numpy()
    obs = log.observations
    is_false = who == FALSE
    false_tracks = obs.loc[is_false, ["sensor", "track"]].drop_duplicates()
    t = log.truth_robot["t"]
    return {"observations": len(obs), "robot": int((who == ROBOT).sum()),
            "pedestrians": len(np.unique(who[(who != ROBOT) & ~is_false])),
            "false_tracks": len(false_tracks), "duration_s": float(t.iloc[-1] - t.iloc[0])}


def _progress(enabled: bool, text: str) -> None:
    if enabled:
        logging.getLogger(__name__).info(f"simulate: {text}")


def _false_tracks(true_net: SensorNetwork, sc: Scenario, frames_t: np.ndarray,
                  rng: np.random.Generator) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Short false tracks per sensor: Poisson in time, a life from false_track_duration_s, a
    point inside the field of view at a height from false_track_height_m, jittering.
    Returns (sensor index, capture times, world points) per false track."""
    t0, t1 = frames_t.min(), frames_t.max()
    out = []
    for i, s in enumerate(true_net):
        n = rng.poisson(sc.false_track_rate_hz * (t1 - t0)) if sc.false_track_rate_hz > 0 else 0
        for _ in range(n):
            start = rng.uniform(t0, t1)
            life = rng.uniform(*sc.false_track_duration_s)
            t = frames_t[i][(frames_t[i] >= start) & (frames_t[i] <= start + life)]
            # A ray inside the field of view, cut at the false track's height.
            az, el = (np.radians(rng.uniform(-0.45, 0.45, 20) * sc.hfov_deg),
                      np.radians(rng.uniform(-0.45, 0.45, 20) * sc.vfov_deg))
            ray = s.R_world_sensor @ np.stack([np.ones(20), np.tan(az), np.tan(el)])
            h = rng.uniform(*sc.false_track_height_m)
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = (h - s.position_m[2]) / ray[2]
            p = s.position_m + (lam * ray).T
            ok = (lam > 0) & ceiling.in_frustum(s.to_sensor(p), sc)
            if not ok.any() or len(t) == 0:
                continue
            p = p[np.argmax(ok)] + rng.normal(0.0, sc.false_track_jitter_m, (len(t), 3))
            out.append((i, t, p))
    return out


def _in_spans(t: np.ndarray, spans: np.ndarray) -> np.ndarray:
    """Mask of times inside any of the sorted [start, end] ``spans`` (K, 2) (ends sorted too)."""
    k = np.searchsorted(spans[:, 0], t, side="right") - 1
    return (k >= 0) & (t <= spans[np.maximum(k, 0), 1])


def _run(true_net: SensorNetwork, installed: SensorNetwork, sc: Scenario, poses: np.ndarray, t0: float,
         rng_seq: np.random.SeedSequence, rank: int, progress: bool, name: str) -> Log:
    """One drive of the route: truth, AMCL, odometry, and what the ceiling tracker reports."""
    rng_amcl, rng_odom, rng_people, rng_track = (np.random.default_rng(s) for s in rng_seq.spawn(4))
    truth = robot.truth_table(poses, t0, sc)
    t1 = float(truth["t"].iloc[-1])
    amcl = robot.amcl_table(truth, sc, rng_amcl)
    odom = robot.odometry_table(truth, sc, rng_odom)
    people = walkers.pedestrians(sc, truth, rng_people, rank=rank)
    swap = people[people["person"] == "companion"] if sc.companion_replaces_robot else people.iloc[:0]
    if len(swap):
        people = people[people["person"] != "companion"]
    swaps = np.zeros((0, 2))
    if sc.companion_swap_fraction > 0:
        # how many sensors see the robot and the companion at each true pose: the swaps take
        # the stated share of the robot track's sightings
        z_companion = rng_people.uniform(*sc.person_height_m)
        pose = truth[["x", "y", "yaw"]].to_numpy(float)
        robot_seen = ceiling.coverage(true_net, sc, head_world(pose, sc.head_offset_m)).sum(axis=0)
        beside = np.column_stack([walkers.beside_robot(sc, truth, truth["t"].to_numpy(float)),
                                  np.full(len(truth), z_companion)])
        companion_seen = ceiling.coverage(true_net, sc, beside).sum(axis=0)
        swaps = walkers.companion_swaps(sc, truth, robot_seen.astype(float), companion_seen.astype(float),
                                        rng_people)
    _progress(progress, f"{name}: {t1 - t0:.0f} s of driving, {people['person'].nunique()} pedestrians")

    frames_t = ceiling.frame_times(sc, len(true_net), t0, t1, rng_track)
    n_s, n_k = frames_t.shape
    # Candidates: entity 0 is the robot in every frame of every sensor.
    sensor_parts = [np.repeat(np.arange(n_s), n_k)]
    t_parts = [frames_t.ravel()]
    p_parts = [head_world(interpolate_pose2(truth, frames_t.ravel()), sc.head_offset_m)]
    entity_parts = [np.zeros(n_s * n_k, dtype=int)]
    head_parts = [np.ones(n_s * n_k, dtype=bool)]
    labels = [ROBOT]
    if len(swap):       # the tracker reports the companion where it would report the robot
        inside = (t_parts[0] >= swap["t"].min()) & (t_parts[0] <= swap["t"].max())
        ts = swap["t"].to_numpy(float)
        p_parts[0][inside] = np.column_stack([np.interp(t_parts[0][inside], ts, swap["x"].to_numpy(float)),
                                              np.interp(t_parts[0][inside], ts, swap["y"].to_numpy(float)),
                                              np.full(inside.sum(), float(swap["z"].iloc[0]))])
        labels.append("companion")
        entity_parts[0][inside] = 1
    if len(swaps):      # identity swaps: the robot's track reports the companion beside it
        inside = _in_spans(t_parts[0], swaps)
        p_parts[0][inside] = np.column_stack([walkers.beside_robot(sc, truth, t_parts[0][inside]),
                                              np.full(inside.sum(), z_companion)])
        labels.append("companion")
        entity_parts[0][inside] = len(labels) - 1
        # ... and around each swap the companion is tracked as itself (labelled apart, so the
        # replaced share of the robot's rows can be counted)
        near = _in_spans(t_parts[0], swaps + np.array([-sc.companion_beside_s, sc.companion_beside_s])) & ~inside
        labels.append("companion-beside")
        sensor_parts.append(sensor_parts[0][near])
        t_parts.append(t_parts[0][near])
        p_parts.append(np.column_stack([walkers.beside_robot(sc, truth, t_parts[0][near]),
                                        np.full(near.sum(), z_companion)]))
        entity_parts.append(np.full(near.sum(), len(labels) - 1))
        head_parts.append(np.ones(near.sum(), dtype=bool))
    sensor_xy = np.stack([s.position_m[:2] for s in true_net])
    reach_m = sc.max_range_m + 2.0
    for person, track in people.groupby("person", sort=True):
        track = track.sort_values("t")
        tp, xy = track["t"].to_numpy(), track[["x", "y"]].to_numpy()
        if len(tp) < 2:
            continue
        labels.append(str(person))
        near = np.linalg.norm(xy[None, :, :] - sensor_xy[:, None, :], axis=2) < reach_m
        for i in np.flatnonzero(near.any(axis=1)):
            tn = tp[near[i]]
            ft = frames_t[i]
            ft = ft[(ft >= max(tn[0] - 1.0, tp[0])) & (ft <= min(tn[-1] + 1.0, tp[-1]))]
            sensor_parts.append(np.full(len(ft), i))
            t_parts.append(ft)
            p_parts.append(np.column_stack([np.interp(ft, tp, xy[:, 0]), np.interp(ft, tp, xy[:, 1]),
                                            np.full(len(ft), track["z"].iloc[0])]))
            entity_parts.append(np.full(len(ft), len(labels) - 1))
            head_parts.append(np.ones(len(ft), dtype=bool))
    for i, ft, p in _false_tracks(true_net, sc, frames_t, rng_track):
        labels.append(FALSE)
        sensor_parts.append(np.full(len(ft), i))
        t_parts.append(ft)
        p_parts.append(p)
        entity_parts.append(np.full(len(ft), len(labels) - 1))
        head_parts.append(np.zeros(len(ft), dtype=bool))

    rep = ceiling.tracker_observations(
        true_net, installed, sc, frames_t, np.concatenate(entity_parts), np.concatenate(sensor_parts),
        np.concatenate(t_parts), np.concatenate(p_parts), np.concatenate(head_parts), rng_track)
    ids = np.array(true_net.ids)
    observations = pd.DataFrame({"t": rep["t"], "sensor": ids[rep["sensor"]], "track": rep["track"],
                                 "x": rep["xyz"][:, 0], "y": rep["xyz"][:, 1], "z": rep["xyz"][:, 2]})
    truth_obs = pd.DataFrame({"row": np.arange(len(observations)),
                              "who": np.array(labels, dtype=object)[rep["entity"]].astype(str)})
    _progress(progress, f"{name}: {len(observations)} observations")
    simulated = {"scenario": sc.name, "seed": sc.seed, "run": name}
    per_sensor = sensor_truth(sc, list(true_net.ids))
    if per_sensor:      # the zoo's per-sensor nuisances, the truth of what a calibration may estimate
        simulated["truth"] = per_sensor
    meta = Meta(head_offset_m=np.asarray(sc.head_offset_m, float), notes={"simulated": simulated})
    return Log(sensors=installed.copy(), robot=amcl, observations=observations, odometry=odom, meta=meta,
               truth=true_net.copy(), truth_robot=truth, truth_observations=truth_obs)


def networks(sc: Scenario) -> tuple[SensorNetwork, SensorNetwork]:
    """The true and the installed extrinsics of a resolved scenario (seeded by ``sc.seed``)."""
    ss_layout, ss_installed = np.random.SeedSequence(sc.seed).spawn(4)[:2]
    true_net = ceiling.layout_network(sc, np.random.default_rng(ss_layout))
    return true_net, ceiling.installed_network(true_net, sc, np.random.default_rng(ss_installed))


def simulate_logs(scenario: str | Path | Scenario = "paper", seed: int = 0, progress: bool = False,
                  **overrides) -> SimulationResult:
    """Simulate the calibration and evaluation logs of ``scenario`` (a name in datasets/, a YAML
    path or a Scenario) in memory. ``overrides`` set any Scenario parameter by name;
    ``noise_free=True`` turns every nuisance off; ``vary_nuisances=True`` draws the nuisance
    models from the seed (:func:`pedcal.sim.nuisances.draw_nuisances`), after the overrides;
    ``vary_nuisances="zoo"`` draws the zoo's further families too
    (:func:`pedcal.sim.nuisances.draw_zoo`).
    The same seed gives identical logs."""
    check(seed=seed)
    noise_free = bool(overrides.pop("noise_free", False))
    vary_nuisances = overrides.pop("vary_nuisances", False)
    sc = load_scenario(scenario).resolve(noise_free=noise_free, seed=seed, **overrides)
    if vary_nuisances:
        sc = vary(sc, zoo=vary_nuisances == "zoo")
    true_net, installed = networks(sc)
    ss_calib, ss_eval = np.random.SeedSequence(sc.seed).spawn(4)[2:]
    _progress(progress, f"scenario {sc.name}: {len(true_net)} sensors, driving the route")
    poses = robot.drive_route(sc)
    t0_calib = sc.start_time_s
    calib = _run(true_net, installed, sc, poses, t0_calib, ss_calib, 0, progress, "calib")
    t0_eval = float(calib.truth_robot["t"].iloc[-1]) + sc.eval_gap_s
    evaluation = _run(true_net, installed, sc, poses, t0_eval, ss_eval, 1, progress, "eval")
    return SimulationResult(calib=calib, eval=evaluation, scenario=sc)


def check_scenario_outside(scenario: str | Path, out_dir: str | Path) -> None:
    """The scenario file ``scenario`` is none of what simulate writes into ``out_dir``
    (scenario.yaml, calib/, eval/), else PedcalInputError."""
    out_dir = Path(out_dir)
    src = Path(scenario).resolve()
    written = [(out_dir / "scenario.yaml").resolve(), (out_dir / "calib").resolve(), (out_dir / "eval").resolve()]
    if src == written[0] or any(d in src.parents for d in written[1:]):
        raise PedcalInputError(f"the scenario file is among what simulate writes into {out_dir} (scenario.yaml, "
                               "calib/, eval/); keep it elsewhere or choose another output", path=scenario)


def simulate(scenario: str | Path | Scenario, out_dir: str | Path, seed: int = 0, progress: bool = False,
             **overrides) -> SimulationResult:
    """``simulate_logs`` and write ``out_dir/calib/``, ``out_dir/eval/`` (log directories with
    truth) and ``out_dir/scenario.yaml`` (the resolved parameters, seed included)."""
    from pedcal.io import write_log

    out_dir = Path(out_dir)
    if isinstance(scenario, (str, Path)) and Path(scenario).is_file():
        check_scenario_outside(scenario, out_dir)
    result = simulate_logs(scenario, seed=seed, progress=progress, **overrides)
    for name, log in (("calib", result.calib), ("eval", result.eval)):
        if log_summary(log)["robot"] == 0:      # a log calibrate and evaluate will refuse
            sc = result.scenario
            warnings.warn(f"scenario {sc.name}, seed {sc.seed}: the {name} log holds no observation of the robot "
                          f"({len(log.observations)} observations in all): no sensor sees its head on the route "
                          "(check duration_s, max_range_m, min_range_m, the fields of view, sensor_height_m, "
                          "robot_speed_mps); it cannot be calibrated or evaluated", DegenerateDataWarning, stacklevel=2)
        log.path = out_dir / name
        write_log(log, log.path)
        _progress(progress, f"wrote {log.path}")
    write_text_atomic(out_dir / "scenario.yaml", yaml.safe_dump(result.scenario.to_dict(), sort_keys=False))
    return result


__all__ = ["simulate", "simulate_logs", "check_scenario_outside", "SimulationResult", "Scenario", "load_scenario",
           "log_summary", "networks"]
