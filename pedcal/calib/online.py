"""Online calibration: the factor graph of :mod:`pedcal.calib.factorgraph` fed to iSAM2 in time
order, reporting each sensor's convergence as data arrive.

Each factor is released at the latest time of the variables it touches (sensors have no time;
robot poses, AMCL errors and people have theirs), so the solver sees exactly what a live system
would have seen by then. After the last step the estimate equals the batch graph's up to iSAM2's
relinearization tolerance.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from pedcal.calib.common import CalibrationResult, FactorGraphDiagnostics
from pedcal.calib.graph import GraphRecipe, S, _network_from_result, build_graph, finish_network, prepare
from pedcal.model import Log


@dataclass
class OnlineStep:
    t: float                              # log time up to which data were consumed
    sigma_position_mm: dict[str, float]   # per sensor, largest 1-sigma horizontal position axis
    converged: list[str]
    waiting: list[str]                    # sensors that still need the robot


@dataclass
class OnlineTrace:
    steps: list[OnlineStep] = field(default_factory=list)


def _factor_times(graph, prob) -> np.ndarray:
    out = np.full(graph.size(), -np.inf)
    for n in range(graph.size()):
        t = -np.inf
        for key in graph.at(n).keys():
            sym = gtsam.Symbol(key)
            c, i = chr(sym.chr()), sym.index()
            if c == "x":
                t = max(t, prob.pose_times[i])
            elif c == "a":
                t = max(t, prob.amcl_node_times[i])
            elif c == "l":
                t = max(t, prob.people[i][0])
        out[n] = t
    return out


def factors_until(graph, values, order: np.ndarray, ft: np.ndarray, pos: int, edge_s: float, added: set[int]
                  ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, int]:
    """The next iSAM2 update: the factors of ``graph`` in time ``order`` from ``pos`` whose time
    (``ft``, ``_factor_times``) is at most ``edge_s``, with initial values of the variables not yet
    in ``added`` (which it extends); returns them and the next position."""
    new_graph, new_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    while pos < len(order) and ft[order[pos]] <= edge_s:
        f = graph.at(int(order[pos]))
        new_graph.add(f)
        for key in f.keys():
            if key not in added:
                added.add(key)
                new_values.insert(key, values.atPose3(key) if chr(gtsam.Symbol(key).chr()) in "sxah"
                                  else values.atPoint3(key))
        pos += 1
    return new_graph, new_values, pos


# iSAM2 relinearizes a variable whose estimate moved by more than this since its last
# linearization (rad or m, on every update): 1 cm / 0.6 deg. At 1 mm a third of the robot's
# poses were relinearized on every pass (paper seeds 0 and 1: updates of 24 ms median, 67 ms at
# most, CPU); at 1 cm half of that and at most 48 ms, the final sensors within 0.7 mm of it
# (RMS 54.6 -> 54.4 and 32.6 -> 32.3 mm), as the last updates relinearize what is left.
RELINEARIZE_THRESHOLD = 0.01


def isam2_params() -> gtsam.ISAM2Params:
    """The online solver's iSAM2 parameters (relinearization checked on every update)."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
    params.relinearizeSkip = 1
    return params


def calibrate_online(log: Log, *, recipe: GraphRecipe, is_robot=None, progress: bool = False,
                     step_s: float = 10.0, converged_sigma_mm: float = 30.0) -> CalibrationResult:
    """Incremental calibration (iSAM2). ``step_s``: seconds of log consumed per update; a sensor
    counts as converged when its largest 1-sigma horizontal position axis is below
    ``converged_sigma_mm``. The head point's shift toward the sensor stays at its prior here
    (the batch solve estimates it)."""
    t0 = time.perf_counter()
    prob = prepare(log, recipe, is_robot=is_robot, progress=progress)
    graph, values = build_graph(log, prob)
    ft = _factor_times(graph, prob)
    order = np.argsort(ft, kind="stable")
    finite = ft[np.isfinite(ft)]
    t_start = finite.min() if len(finite) else 0.0
    t_end = finite.max() if len(finite) else 0.0
    isam = gtsam.ISAM2(isam2_params())
    added: set[int] = set()
    trace = OnlineTrace()
    pos = 0
    edges = list(np.arange(t_start + step_s, t_end + step_s, step_s))
    sensor_keys = [S(i) for i in range(len(prob.sensor_ids))]
    for edge in edges:
        new_graph, new_values, pos = factors_until(graph, values, order, ft, pos, edge, added)
        if new_graph.size() == 0:
            continue
        isam.update(new_graph, new_values)
        sig = {}
        for sid, key in zip(prob.sensor_ids, sensor_keys, strict=True):
            # horizontal (world xy): the common height is shared with the head model's vertical
            # offset, which the robot alone cannot determine however long it drives
            R = isam.calculateEstimatePose3(key).rotation().matrix()
            cov_xy = (R @ isam.marginalCovariance(key)[3:, 3:] @ R.T)[:2, :2]
            sig[sid] = float(1000.0 * np.sqrt(np.max(np.linalg.eigvalsh(cov_xy))))
        conv = [s for s, v in sig.items() if v < converged_sigma_mm]
        step = OnlineStep(t=float(min(edge, t_end)), sigma_position_mm=sig, converged=conv,
                          waiting=[s for s in prob.sensor_ids if s not in conv])
        trace.steps.append(step)
        if progress:
            logging.getLogger(__name__).info(f"[online] t={step.t - t_start:7.1f} s  converged {len(conv)}/{len(sig)}"
                                             f"  still need the robot: {', '.join(step.waiting) or 'none'}")
    for _ in range(3):       # a few extra relinearization passes at the end
        isam.update()
    result = isam.calculateEstimate()
    marg = gtsam.Marginals(graph, result)
    network = _network_from_result(log, prob, graph, result, progress, marginals=marg)
    mask = finish_network(log, prob, network)
    return CalibrationResult(network=network, method="factorgraph-online", runtime_s=time.perf_counter() - t0,
                             is_robot=mask, graph=graph, values=result,
                             diagnostics=FactorGraphDiagnostics(recipe=recipe.name, tracker_latency_s=prob.latency_s,
                                                                factors=graph.size(), variables=result.size(),
                                                                shared_people=len(prob.people),
                                                                online_trace=trace))


__all__ = ["calibrate_online", "OnlineTrace", "OnlineStep"]
