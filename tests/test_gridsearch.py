"""Kimoto et al.'s grid search: exact against the exhaustive search, recovers a known pose."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pedcal import frames
from pedcal.calib import calibrate
from pedcal.calib import gridsearch as gs
from pedcal.errors import DegenerateDataWarning
from pedcal.model import Log, SensorExtrinsics, SensorNetwork

HEAD_Z_M = 1.35


def _visible_heads(truth: SensorExtrinsics, n: int, rng, half_width_m: float = 1.2) -> np.ndarray:
    """n head positions at z = 1.35 around where the optical axis meets the head plane, kept
    inside a 35 deg cone about the axis (a plausible frustum)."""
    axis = truth.R_world_sensor[:, 0]
    centre = truth.position_m + (HEAD_Z_M - truth.position_m[2]) / axis[2] * axis
    out = []
    while sum(len(o) for o in out) < n:
        xy = centre[:2] + rng.uniform(-half_width_m, half_width_m, (4 * n, 2))
        head = np.column_stack([xy, np.full(len(xy), HEAD_Z_M)])
        p = truth.to_sensor(head)
        cos_off_axis = p[:, 0] / np.linalg.norm(p, axis=1)
        out.append(head[cos_off_axis > np.cos(np.radians(35.0))])
    return np.concatenate(out)[:n]


def _pairs(seed: int, n: int, noise_m: float, offset_m: float, angle_deg: float):
    rng = np.random.default_rng(seed)
    truth = SensorExtrinsics("s1", [rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(2.5, 3.0)],
                             [rng.uniform(-180, 180), rng.uniform(30, 60), rng.uniform(-5, 5)])
    head = _visible_heads(truth, n, rng)
    p_sensor = truth.to_sensor(head) + rng.normal(0.0, noise_m, (n, 3))
    head_world = head + np.column_stack([rng.normal(0.0, noise_m, (n, 2)), np.zeros(n)])
    initial = SensorExtrinsics("s1", truth.position_m + rng.uniform(-offset_m, offset_m, 3),
                               truth.ypr_deg + rng.uniform(-angle_deg, angle_deg, 3))
    return truth, p_sensor, head_world, initial


@pytest.mark.parametrize("seed,noise_m", [(0, 0.0), (1, 0.01), (2, 0.05), (3, 0.02)])
def test_fast_search_equals_exhaustive_search(seed, noise_m):
    truth, p, head, initial = _pairs(seed, 120, noise_m, offset_m=0.06, angle_deg=1.5)
    opts = dict(angle_range_deg=2.0, angle_step_deg=0.01, offset_range_m=0.1, offset_step_m=0.005)
    fast = gs.grid_search_sensor(p, head, initial, **opts)
    brute = gs.brute_force_grid_search_sensor(p, head, initial, **opts)
    assert fast.index == brute.index
    np.testing.assert_array_equal(fast.extrinsics.ypr_deg, brute.extrinsics.ypr_deg)
    np.testing.assert_array_equal(fast.extrinsics.position_m, brute.extrinsics.position_m)
    assert (fast.zdev_m, fast.zdist_m, fast.xydev_m, fast.xydist_m) == \
        (brute.zdev_m, brute.zdist_m, brute.xydev_m, brute.xydist_m)


def test_full_scan_fallback_equals_exhaustive_search(monkeypatch):
    """With branch and bound disabled, the chunked closed-form scan of every pitch/roll cell."""
    truth, p, head, initial = _pairs(8, 90, 0.02, offset_m=0.06, angle_deg=1.5)
    opts = dict(angle_range_deg=2.0, offset_range_m=0.1)
    brute = gs.brute_force_grid_search_sensor(p, head, initial, **opts)
    monkeypatch.setattr(gs, "BNB_MAX_BLOCKS", 1)
    monkeypatch.setattr(gs, "CHUNK_ELEMENTS", 5000)    # many chunks, the minimum in a late one
    fast = gs.grid_search_sensor(p, head, initial, **opts)
    assert fast.index == brute.index and fast.zdev_m == brute.zdev_m


@pytest.mark.filterwarnings("ignore:sensor s1. grid optimum on the edge:UserWarning")
def test_flat_objective_warns(monkeypatch):
    """Every sensor point identical: ZDev is the same everywhere, pitch/roll are not determined."""
    p = np.tile([2.0, 0.1, -0.3], (30, 1))
    head = np.column_stack([np.linspace(0, 1, 30), np.zeros(30), np.full(30, 1.35)])
    initial = SensorExtrinsics("s1", [0.0, 0.0, 2.6], [0.0, 45.0, 0.0])
    monkeypatch.setattr(gs, "MAX_SCREEN_CANDIDATES", 1000)
    monkeypatch.setattr(gs, "BNB_MAX_BLOCKS", 100)
    with pytest.warns(DegenerateDataWarning, match="ZDev over pitch/roll is flat"):
        res = gs.grid_search_sensor(p, head, initial, angle_range_deg=1.0, offset_range_m=0.05)
    assert res.zdev_m < 1e-12 and abs(res.index["pitch"]) <= 100 and abs(res.index["roll"]) <= 100


def test_fast_search_equals_exhaustive_search_on_unstructured_points():
    """Points that no pose explains: the optimum sits anywhere, also on the range edge."""
    rng = np.random.default_rng(7)
    p = rng.normal(0.0, 1.0, (60, 3))
    head = rng.normal(0.0, 1.0, (60, 3))
    initial = SensorExtrinsics("s1", [0.1, -0.2, 2.6], [10.0, 40.0, 0.0])
    opts = dict(angle_range_deg=1.0, angle_step_deg=0.01, offset_range_m=0.5, offset_step_m=0.005)
    with pytest.warns(UserWarning, match="edge of the search range"):
        fast = gs.grid_search_sensor(p, head, initial, **opts)
    with pytest.warns(UserWarning, match="edge of the search range"):
        brute = gs.brute_force_grid_search_sensor(p, head, initial, **opts)
    assert fast.index == brute.index
    assert fast.on_range_edge == brute.on_range_edge and fast.on_range_edge


@pytest.mark.parametrize("seed", [4, 5])
def test_yaw_and_xy_stages_exact_over_the_papers_full_ranges(seed):
    """XYDev over 12001 yaws (+-60 deg at 0.01 deg) and XYDist over 401^2 offsets
    (+-1000 mm at 5 mm), each against the plain definition on every cell."""
    truth, p, head, initial = _pairs(seed, 80, 0.03, offset_m=0.5, angle_deg=10.0)
    grids = gs._Grids(initial, 60.0, 0.01, 1.0, 0.005)
    q = gs._rotate_pitch_roll(p, grids.pitch, grids.roll, 3000, 7000)
    t_xy = initial.position_m[:2]
    all_yaws = np.arange(len(grids.yaw))
    plain_yaw = gs._xydev_cells(q, head[:, :2], t_xy, grids.yaw, all_yaws)
    assert gs._xydev_fast(q, head[:, :2], t_xy, grids.yaw) == (plain_yaw.min(), int(np.argmin(plain_yaw)))

    r_xy = q[:, :2] + [0.2, -0.3]
    nx, ny = len(grids.x), len(grids.y)
    flat = np.arange(nx * ny)
    plain_xy = np.concatenate([gs._xydist_cells(r_xy, head[:, :2], grids.x, grids.y, f // ny, f % ny)
                               for f in np.array_split(flat, 16)])
    k = int(np.argmin(plain_xy))
    assert gs._xydist_branch_and_bound(r_xy, head[:, :2], grids.x, grids.y, 0.005) == \
        (plain_xy[k], k // ny, k % ny)


def test_plain_objective_does_not_depend_on_batch():
    """The screens rely on one cell evaluating to the same bits alone and in a batch."""
    truth, p, head, initial = _pairs(6, 101, 0.02, offset_m=0.1, angle_deg=1.0)
    grids = gs._Grids(initial, 1.0, 0.01, 0.1, 0.005)
    ip, ir = np.repeat(np.arange(0, 201, 7), 29), np.tile(np.arange(0, 201, 7), 29)
    batch = gs._zdev_cells(p, head[:, 2], 2.6, grids.pitch, grids.roll, ip, ir)
    single = [gs._zdev_cells(p, head[:, 2], 2.6, grids.pitch, grids.roll, ip[i:i + 1], ir[i:i + 1])[0]
              for i in range(0, len(ip), 37)]
    np.testing.assert_array_equal(batch[::37], single)


@pytest.mark.parametrize("seed", [10, 11])
def test_noise_free_pairs_recover_the_true_pose(seed):
    """Installed pose off by up to 0.5 m / 10 deg; the paper's full ranges and resolution."""
    truth, p, head, initial = _pairs(seed, 400, 0.0, offset_m=0.5, angle_deg=10.0)
    res = gs.grid_search_sensor(p, head, initial)
    est = res.extrinsics
    assert frames.rotation_angle_deg(est.R_world_sensor, truth.R_world_sensor) < 0.02
    np.testing.assert_allclose(est.position_m, truth.position_m, atol=0.005)
    yaw_err = (est.ypr_deg[0] - truth.ypr_deg[0] + 180.0) % 360.0 - 180.0
    assert abs(yaw_err) < 0.02
    np.testing.assert_allclose(est.ypr_deg[1:], truth.ypr_deg[1:], atol=0.02)
    assert res.zdev_m < 1e-3 and res.xydist_m < 5e-3
    assert est.status == "ok" and est.observations == 400


def test_search_is_centred_on_the_installed_pose():
    truth, p, head, initial = _pairs(12, 200, 0.0, offset_m=0.0, angle_deg=0.0)
    initial = SensorExtrinsics("s1", truth.position_m + [0.3, 0.0, 0.0], truth.ypr_deg + [5.0, 0.0, 0.0])
    with pytest.warns(UserWarning, match="x, yaw|yaw, x"):
        res = gs.grid_search_sensor(p, head, initial, angle_range_deg=2.0, offset_range_m=0.2)
    assert res.index["yaw"] == -200 and res.index["x"] == -40
    assert set(res.on_range_edge) == {"yaw", "x"}


def test_bad_pairs_are_rejected():
    initial = SensorExtrinsics("s1", [0, 0, 2.6], [0, 45, 0])
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        gs.grid_search_sensor(np.zeros((5, 3)), np.zeros((4, 3)), initial)
    with pytest.raises(ValueError, match="finite"):
        gs.grid_search_sensor(np.full((5, 3), np.nan), np.zeros((5, 3)), initial)


# ---------------------------------------------------------------------------- whole log


def _log(sensors_truth, sensors_installed, robot_xy: np.ndarray, rng, noise_m=0.0) -> Log:
    """A log whose robot drives robot_xy (one row per 0.1 s); every sensor that sees the head
    reports it (installed extrinsics applied), plus a pedestrian the mask must leave out."""
    t = 0.1 * np.arange(len(robot_xy))
    step = np.diff(robot_xy, axis=0, append=robot_xy[-1:] + (robot_xy[-1:] - robot_xy[-2:-1]))
    yaw = np.arctan2(step[:, 1], step[:, 0])
    cov = {c: 0.0 for c in ("cov_xy", "cov_xyaw", "cov_yyaw")}
    robot = pd.DataFrame({"t": t, "x": robot_xy[:, 0], "y": robot_xy[:, 1], "yaw": yaw,
                          "cov_xx": 0.0025, "cov_yy": 0.0025, "cov_yawyaw": 0.01, **cov})
    head = np.column_stack([robot_xy, np.full(len(t), HEAD_Z_M)])
    rows, who = [], []
    for s_true, s_inst in zip(sensors_truth, sensors_installed, strict=True):
        p = s_true.to_sensor(head)
        seen = p[:, 0] / np.linalg.norm(p, axis=1) > np.cos(np.radians(35.0))
        p_meas = p[seen] + rng.normal(0.0, noise_m, (int(seen.sum()), 3))
        xyz = s_inst.to_world(p_meas)
        rows.append(pd.DataFrame({"t": t[seen], "sensor": s_true.id, "track": 1,
                                  "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}))
        who += ["robot"] * int(seen.sum())
        rows.append(pd.DataFrame({"t": t[seen][:20], "sensor": s_true.id, "track": 2,
                                  "x": xyz[:20, 0] + 0.7, "y": xyz[:20, 1], "z": xyz[:20, 2] + 0.3}))
        who += ["p1"] * min(20, int(seen.sum()))
    obs = pd.concat(rows, ignore_index=True)
    truth_obs = pd.DataFrame({"row": np.arange(len(obs)), "who": who})
    return Log(SensorNetwork(list(sensors_installed)), robot, obs, truth=SensorNetwork(list(sensors_truth)),
               truth_observations=truth_obs)


def _truth_mask(log: Log) -> np.ndarray:
    mask = np.zeros(len(log.observations), dtype=bool)
    tr = log.truth_observations
    mask[tr.loc[tr["who"] == "robot", "row"].to_numpy()] = True
    return mask


def _wander(rng, centre, n=600, radius_m=1.3) -> np.ndarray:
    """A robot wandering around centre with varied headings (a reflected random walk)."""
    xy, heading, out = np.array(centre, float), 0.0, []
    for _ in range(n):
        heading += rng.normal(0.0, 0.35)
        nxt = xy + 0.05 * np.array([np.cos(heading), np.sin(heading)])
        if np.linalg.norm(nxt - centre) > radius_m:
            heading += np.pi
            continue
        xy = nxt
        out.append(xy.copy())
    return np.array(out)


def test_calibrate_gridsearch_on_a_log():
    rng = np.random.default_rng(20)
    truth = [SensorExtrinsics("a", [0.0, 0.0, 2.6], [0.0, 45.0, 1.0]),
             SensorExtrinsics("b", [6.0, 0.0, 2.7], [180.0, 40.0, -2.0]),
             SensorExtrinsics("c", [30.0, 30.0, 2.6], [0.0, 45.0, 0.0])]       # never sees the robot
    installed = [SensorExtrinsics(s.id, s.position_m + rng.uniform(-0.3, 0.3, 3),
                                  s.ypr_deg + rng.uniform(-5, 5, 3)) for s in truth]
    path = np.concatenate([_wander(rng, [1.25, 0.0]), _wander(rng, [4.6, 0.0])])
    log = _log(truth, installed, path, rng)
    mask = _truth_mask(log)
    res = calibrate(log, method="gridsearch", is_robot=mask, angle_range_deg=8.0, offset_range_m=0.5)
    assert res.method == "gridsearch" and res.runtime_s > 0
    np.testing.assert_array_equal(res.is_robot, mask)
    for s in truth[:2]:
        est = res.network[s.id]
        assert est.status == "ok", est.unobservable
        assert est.observations == int((mask & (log.observations["sensor"] == s.id)).sum()) > 100
        assert frames.rotation_angle_deg(est.R_world_sensor, s.R_world_sensor) < 0.03
        np.testing.assert_allclose(est.position_m, s.position_m, atol=0.006)
    c = res.network["c"]
    assert c.status == "no-data" and c.observations == 0
    np.testing.assert_array_equal(c.position_m, installed[2].position_m)


@pytest.mark.filterwarnings("ignore:sensor a. grid optimum on the edge:UserWarning")
def test_straight_pass_is_flagged_degenerate():
    rng = np.random.default_rng(21)
    truth = [SensorExtrinsics("a", [0.0, 0.0, 2.6], [30.0, 45.0, 0.0])]
    installed = [SensorExtrinsics("a", [0.1, -0.1, 2.65], [32.0, 43.0, 1.0])]
    line = np.column_stack([np.linspace(-1.0, 4.0, 300), np.full(300, 1.0)])
    log = _log(truth, installed, line, rng, noise_m=0.005)
    with pytest.warns(DegenerateDataWarning, match="sensor a"):
        res = calibrate(log, method="gridsearch", is_robot=_truth_mask(log), angle_range_deg=4.0,
                        offset_range_m=0.3)
    a = res.network["a"]
    assert a.status == "degenerate"
    assert any("tilt about the robot's path" in u for u in a.unobservable)
    assert "[1.00, 0.00, 0]" in a.unobservable[0] or "[-1.00, 0.00, 0]" in a.unobservable[0]


def test_mask_of_wrong_length_is_rejected():
    rng = np.random.default_rng(22)
    s = SensorExtrinsics("a", [0.0, 0.0, 2.6], [0.0, 45.0, 0.0])
    log = _log([s], [s], _wander(rng, [1.25, 0.0], n=100), rng)
    with pytest.raises(ValueError, match="boolean mask"):
        calibrate(log, method="gridsearch", is_robot=np.ones(3, dtype=bool))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fast_search_equals_exhaustive_search_with_head_heights_that_vary(seed):
    # people and the robot's head bob: heads 5 cm either side of their mean height
    truth, p, head, initial = _pairs(seed, 120, 0.01, offset_m=0.06, angle_deg=1.5)
    head = head + np.column_stack([np.zeros((len(head), 2)),
                                   np.random.default_rng(100 + seed).uniform(-0.05, 0.05, len(head))])
    opts = dict(angle_range_deg=2.0, angle_step_deg=0.01, offset_range_m=0.1, offset_step_m=0.005)
    fast = gs.grid_search_sensor(p, head, initial, **opts)
    brute = gs.brute_force_grid_search_sensor(p, head, initial, **opts)
    assert fast.index == brute.index
    assert (fast.zdev_m, fast.zdist_m, fast.xydev_m, fast.xydist_m) == \
        (brute.zdev_m, brute.zdist_m, brute.xydev_m, brute.xydist_m)


def test_on_range_edge_is_a_field_of_the_typed_diagnostics():
    truth, p, head, initial = _pairs(5, 120, 0.01, offset_m=0.06, angle_deg=1.5)
    initial.position_m = initial.position_m + np.array([0.0, 0.0, 0.4])     # 0.4 m off: beyond 0.1 m
    log_res = gs.grid_search_sensor(p, head, initial, angle_range_deg=2.0, angle_step_deg=0.05,
                                    offset_range_m=0.1, offset_step_m=0.01)
    assert "z" in log_res.on_range_edge
    from pedcal.calib.common import GridSearchDiagnostics

    d = GridSearchDiagnostics(sensors={"s1": log_res})
    assert d.on_range_edge == {"s1": log_res.on_range_edge}
