"""SNAPCAT-3D style baseline: shared observations of people between overlapping sensors."""

from __future__ import annotations

import warnings

import gtsam
import numpy as np
import pandas as pd
import pytest

from pedcal import frames
from pedcal.calib import calibrate
from pedcal.calib.alternative import build_tracks, coincidence_error, match_shared_observations
from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.model import ROBOT_COLUMNS, Log, SensorExtrinsics, SensorNetwork

RATE_HZ = 15.0

# Four sensors 2.6 m up, 45 deg down, around a shared area; s4 far away sees only its own walker.
TRUTH = SensorNetwork([
    SensorExtrinsics("s0", [0.0, 0.0, 2.6], [0.0, 45.0, 0.0]),
    SensorExtrinsics("s1", [4.0, 0.0, 2.6], [180.0, 45.0, 0.0]),
    SensorExtrinsics("s2", [2.0, 3.0, 2.7], [-90.0, 40.0, 2.0]),
    SensorExtrinsics("s3", [2.0, -2.5, 2.5], [90.0, 40.0, -1.0]),
    SensorExtrinsics("s4", [20.0, 0.0, 2.6], [0.0, 45.0, 0.0]),
])


def _visible(p_sensor: np.ndarray) -> np.ndarray:
    """A 70 x 60 deg depth camera seeing 0.3-5 m."""
    r = np.linalg.norm(p_sensor, axis=1)
    horiz = np.degrees(np.arctan2(p_sensor[:, 1], p_sensor[:, 0]))
    vert = np.degrees(np.arctan2(p_sensor[:, 2], p_sensor[:, 0]))
    return (p_sensor[:, 0] > 0) & (r > 0.3) & (r < 5.0) & (np.abs(horiz) < 35) & (np.abs(vert) < 30)


def _walkers(rng, n_people, duration_s):
    """Piecewise-linear walks at 1.2 m/s through the shared area: (t knots, xyz knots) per person."""
    people = []
    for _ in range(n_people):
        waypoints = np.column_stack([rng.uniform(-0.5, 4.5, 8), rng.uniform(-2.5, 2.5, 8)])
        seg = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
        t = rng.uniform(0, 5) + np.r_[0.0, np.cumsum(seg / 1.2)]
        keep = t <= duration_s
        xyz = np.column_stack([waypoints[keep], np.full(keep.sum(), rng.uniform(1.55, 1.85))])
        people.append((t[keep], xyz))
    return people


def _observe(truth, installed, people, rng, noise_m=0.0, false_tracks=0, duration_s=60.0, t0_s=0.0):
    """observations.csv as the trackers report it: unsynchronized 15 Hz samples, a new track id
    per contiguous visible stretch, world points computed with the installed extrinsics."""
    rows = []
    next_id = 0
    for s in truth:
        t = t0_s + rng.uniform(0, 1 / RATE_HZ) + np.arange(0, duration_s, 1 / RATE_HZ)
        for t_knots, xyz_knots in people:
            inside = (t >= t_knots[0]) & (t <= t_knots[-1])
            tt = t[inside]
            p_world = np.column_stack([np.interp(tt, t_knots, xyz_knots[:, k]) for k in range(3)])
            p_sensor = s.to_sensor(p_world) + rng.normal(0, noise_m, p_world.shape)
            vis = _visible(p_sensor)
            # contiguous visible stretches -> tracks
            starts = np.flatnonzero(np.diff(np.r_[0, vis.astype(int)]) == 1)
            ends = np.flatnonzero(np.diff(np.r_[vis.astype(int), 0]) == -1)
            for a, b in zip(starts, ends, strict=True):
                if b - a < 3:
                    continue
                w = installed[s.id].to_world(p_sensor[a:b + 1])
                rows.append(pd.DataFrame({"t": tt[a:b + 1], "sensor": s.id, "track": f"k{next_id}",
                                          "x": w[:, 0], "y": w[:, 1], "z": w[:, 2]}))
                next_id += 1
        for _ in range(false_tracks):
            t0 = t0_s + rng.uniform(0, duration_s - 3)
            tt = t[(t >= t0) & (t < t0 + 3)]
            p_sensor = np.array([2.0, 0.0, -1.0]) + np.cumsum(rng.normal(0, 0.05, (len(tt), 3)), axis=0)
            w = installed[s.id].to_world(p_sensor)
            rows.append(pd.DataFrame({"t": tt, "sensor": s.id, "track": f"k{next_id}",
                                      "x": w[:, 0], "y": w[:, 1], "z": w[:, 2]}))
            next_id += 1
    obs = pd.concat(rows, ignore_index=True).sample(frac=1.0, random_state=0).reset_index(drop=True)
    return Log(sensors=installed, robot=pd.DataFrame(columns=list(ROBOT_COLUMNS)), observations=obs,
               truth=truth)


def _perturb(truth, rng, position_m, angle_deg):
    return SensorNetwork([SensorExtrinsics(s.id, s.position_m + rng.uniform(-position_m, position_m, 3),
                                           s.ypr_deg + rng.uniform(-angle_deg, angle_deg, 3)) for s in truth])


def _scene(seed=0, position_m=0.3, angle_deg=5.0, noise_m=0.0, false_tracks=0, n_people=8):
    rng = np.random.default_rng(seed)
    installed = _perturb(TRUTH, rng, position_m, angle_deg)
    people = _walkers(rng, n_people, 60.0)
    # s4's own walker, far from every other sensor
    people.append((np.array([0.0, 20.0]), np.array([[20.5, -2.0, 1.7], [22.5, 2.0, 1.7]])))
    return _observe(TRUTH, installed, people, rng, noise_m=noise_m, false_tracks=false_tracks)


def _relative_errors(est: SensorNetwork, truth: SensorNetwork, ref: str, ids):
    """Position (mm) and angle (deg) errors of T_ref^-1 T_k, estimate vs truth."""
    out = {}
    for sid in ids:
        rel_est = est[ref].T_world_sensor.between(est[sid].T_world_sensor)
        rel_true = truth[ref].T_world_sensor.between(truth[sid].T_world_sensor)
        d_mm = 1000 * np.linalg.norm(rel_est.translation() - rel_true.translation())
        d_deg = frames.rotation_angle_deg(rel_est.rotation().matrix(), rel_true.rotation().matrix())
        out[sid] = (d_mm, d_deg)
    return out


def _calibrate(log, **options):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = calibrate(log, method="alternative", **options)
    return result, [w for w in caught if issubclass(w.category, DegenerateDataWarning)]


@pytest.fixture(scope="module")
def noise_free():
    log = _scene(seed=0)
    return log, *_calibrate(log)


def test_coincidence_jacobian_matches_numerical():
    rng = np.random.default_rng(3)
    T_i = frames.pose3([1.0, 2.0, 2.6], [30.0, 45.0, 3.0])
    T_j = frames.pose3([4.0, -1.0, 2.5], [-120.0, 50.0, -2.0])
    p_i, p_j = rng.normal(size=3), rng.normal(size=3)
    values = gtsam.Values()
    values.insert(0, T_i)
    values.insert(1, T_j)
    factor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [0, 1],
                                lambda this, v, H: coincidence_error(p_i, p_j, this, v, H))
    H = [np.zeros((3, 6)), np.zeros((3, 6))]
    e0 = coincidence_error(p_i, p_j, factor, values, H)
    h = 1e-6
    for n, (key, T) in enumerate([(0, T_i), (1, T_j)]):
        num = np.empty((3, 6))
        for k in range(6):
            d = np.zeros(6)
            d[k] = h
            v = gtsam.Values(values)
            v.update(key, T.retract(d))
            num[:, k] = (coincidence_error(p_i, p_j, factor, v, None) - e0) / h
        np.testing.assert_allclose(H[n], num, atol=1e-5)


def test_relative_poses_recovered_noise_free(noise_free):
    log, result, _ = noise_free
    errors = _relative_errors(result.network, log.truth, "s0", ["s1", "s2", "s3"])
    for sid, (d_mm, d_deg) in errors.items():
        assert d_mm < 5.0, (sid, d_mm)
        assert d_deg < 0.1, (sid, d_deg)
    # the installed relative poses were far off: the data did the work
    installed = _relative_errors(log.sensors, log.truth, "s0", ["s1", "s2", "s3"])
    assert min(d for d, _ in installed.values()) > 100.0
    assert result.method == "alternative" and result.is_robot is None
    assert {"s0-s1", "s0-s2", "s0-s3"} <= set(result.diagnostics.pairs)
    for sid in ["s0", "s1", "s2", "s3"]:
        s = result.network[sid]
        assert s.status == "ok" and s.observations > 50
        assert np.all(np.isfinite(s.sigma_position_m)) and np.all(np.isfinite(s.sigma_ypr_deg))


def test_sensor_without_overlap_is_no_data_and_keeps_installed_pose(noise_free):
    log, result, degenerate_warnings = noise_free
    s4 = result.network["s4"]
    assert s4.status == "no-data" and s4.observations == 0
    np.testing.assert_array_equal(s4.position_m, log.sensors["s4"].position_m)
    np.testing.assert_array_equal(s4.ypr_deg, log.sensors["s4"].ypr_deg)
    assert any("s4" in str(w.message) for w in degenerate_warnings)
    assert "s4" in result.diagnostics.no_data


def test_absolute_frame_comes_from_the_installed_network():
    """Installed poses all off by one common rigid motion: the relative constraints are already
    met, so the result stays on the installed network (SNAPCAT-3D cannot see a coherent error)."""
    rng = np.random.default_rng(1)
    G = frames.pose3([0.4, -0.3, 0.05], [6.0, 0.0, 0.0])
    installed = SensorNetwork([SensorExtrinsics.from_pose3(s.id, G.compose(s.T_world_sensor)) for s in TRUTH])
    log = _observe(TRUTH, installed, _walkers(rng, 6, 60.0), rng)
    result, _ = _calibrate(log)
    for sid in ["s0", "s1", "s2", "s3"]:
        np.testing.assert_allclose(result.network[sid].position_m, installed[sid].position_m, atol=2e-3)
        assert frames.rotation_angle_deg(result.network[sid].R_world_sensor, installed[sid].R_world_sensor) < 0.05


def test_noisy_with_false_tracks_and_large_installed_errors():
    log = _scene(seed=2, position_m=0.6, angle_deg=10.0, noise_m=0.02, false_tracks=4)
    result, _ = _calibrate(log)
    for sid, (d_mm, d_deg) in _relative_errors(result.network, log.truth, "s0", ["s1", "s2", "s3"]).items():
        assert d_mm < 30.0, (sid, d_mm)
        assert d_deg < 0.5, (sid, d_deg)
    for entry in result.diagnostics.matches_per_pair.values():
        assert entry["residual_rms_mm"] < 80.0


def test_tracks_from_handed_in_sensor_frame_points(noise_free):
    # build_tracks takes the caller's log.observation_points_sensor() (read once per calibration):
    # the same tracks as from its own reading; the points given are the ones used
    log = noise_free[0]
    p = log.observation_points_sensor()
    own, given = build_tracks(log), build_tracks(log, p)
    assert own.keys() == given.keys() and any(own.values())
    for sid in own:
        assert [(a.track, a.rows.tolist()) for a in own[sid]] == [(b.track, b.rows.tolist()) for b in given[sid]]
        assert all(np.array_equal(a.p_sensor, b.p_sensor) for a, b in zip(own[sid], given[sid], strict=True))
    shifted = build_tracks(log, p + 1.0)
    sid = next(s for s in own if own[s])
    assert np.allclose(shifted[sid][0].p_sensor, own[sid][0].p_sensor + 1.0)


def test_people_side_by_side_are_ambiguous():
    """Two walkers 0.4 m apart: with installed errors either pairing is as consistent as the
    other, so none is accepted between their tracks."""
    rng = np.random.default_rng(4)
    t = np.array([0.0, 10.0])
    people = [(t, np.array([[0.5, y, 1.7], [3.5, y, 1.7]])) for y in (-0.2, 0.2)]
    truth = SensorNetwork([TRUTH["s0"], TRUTH["s1"]])
    installed = _perturb(truth, rng, 0.2, 3.0)
    log = _observe(truth, installed, people, rng, duration_s=10.0)
    report = match_shared_observations(build_tracks(log), log.sensors)
    assert report.gated >= 4
    assert report.ambiguous >= 4
    assert not report.matches


def test_bad_input_names_row_and_column(noise_free):
    log = noise_free[0]
    bad = Log(sensors=log.sensors, robot=log.robot, observations=log.observations.copy())
    bad.observations.loc[7, "sensor"] = "nope"
    with pytest.raises(PedcalInputError) as err:
        calibrate(bad, method="alternative")
    assert err.value.row == 7 and err.value.column == "sensor" and "nope" in str(err.value)
    bad = Log(sensors=log.sensors, robot=log.robot, observations=log.observations.copy())
    bad.observations.loc[3, "z"] = np.nan
    with pytest.raises(PedcalInputError) as err:
        calibrate(bad, method="alternative")
    assert err.value.row == 3 and err.value.column == "z"
    with pytest.raises(PedcalInputError, match="graph"):
        calibrate(log, method="alternative", graph="x.toml")
    with pytest.raises(PedcalInputError, match="min_overlap_s"):
        calibrate(log, method="alternative", min_overlap_s=-1)


def test_one_straight_walk_is_degenerate_and_no_people_is_no_data():
    rng = np.random.default_rng(5)
    truth = SensorNetwork([TRUTH["s0"], TRUTH["s1"]])
    installed = _perturb(truth, rng, 0.2, 3.0)
    walk = [(np.array([0.0, 10.0]), np.array([[0.5, 0.1, 1.7], [3.5, 0.3, 1.7]]))]
    result, caught = _calibrate(_observe(truth, installed, walk, rng, duration_s=10.0))
    assert [s.status for s in result.network] == ["degenerate", "degenerate"]
    assert result.network["s0"].unobservable
    assert any("one line" in str(w.message) for w in caught)

    empty = Log(sensors=installed, robot=pd.DataFrame(columns=list(ROBOT_COLUMNS)),
                observations=pd.DataFrame({c: [] for c in ("t", "sensor", "track", "x", "y", "z")}))
    result, caught = _calibrate(empty)
    assert [s.status for s in result.network] == ["no-data", "no-data"]
    assert any("s0, s1" in str(w.message) for w in caught)


def test_text_in_a_number_column_is_an_input_error(noise_free):
    log = noise_free[0]
    obs = log.observations.astype({"x": object})
    obs.loc[11, "x"] = "1,5"
    with pytest.raises(PedcalInputError) as err:
        calibrate(Log(sensors=log.sensors, robot=log.robot, observations=obs), method="alternative")
    assert err.value.row == 11 and err.value.column == "x" and "1,5" in str(err.value)


def test_real_pedestrian_flow_atc(shared_data):
    """Real walkers (ATC shopping centre, 1 Hz tracks, groups included) through a simulated
    four-sensor network over the busiest corridor cell: relative poses come back."""
    from pedcal.io.pedestrians import read_atc

    people_table = read_atc(shared_data / "atc" / "atc-1024-10_test.csv")
    rng = np.random.default_rng(6)
    centre = np.array([-22.5, 2.5])   # busiest 5 m cell of this recording
    shift = np.r_[centre - np.array([2.0, 0.0]), 0.0]
    truth = SensorNetwork([SensorExtrinsics(s.id, s.position_m + shift, s.ypr_deg) for s in TRUTH])
    people = []
    for _, walk in people_table.sort_values("t").groupby("person"):
        if len(walk) >= 2:
            xy = walk[["x", "y"]].to_numpy(float)
            people.append((walk["t"].to_numpy(float), np.column_stack([xy, np.full(len(xy), rng.uniform(1.5, 1.9))])))
    t0_s = people_table["t"].min()
    duration_s = people_table["t"].max() - t0_s
    log = _observe(truth, _perturb(truth, rng, 0.5, 8.0), people, rng, duration_s=duration_s, t0_s=t0_s)
    result, _ = _calibrate(log, sample_period_s=1.0)   # one shared point a second keeps it fast
    assert result.diagnostics.rounds[0]["ambiguous"] > 0   # walkers in groups
    assert {"s0-s1", "s0-s2", "s0-s3"} <= set(result.diagnostics.pairs)
    for sid, (d_mm, d_deg) in _relative_errors(result.network, truth, "s0", ["s1", "s2", "s3"]).items():
        assert d_mm < 10.0, (sid, d_mm)
        assert d_deg < 0.2, (sid, d_deg)


def _never_covisible(log: Log) -> set[str]:
    """Sensors that never see a real landmark (robot or person) in the same 0.5 s as another sensor."""
    seen = log.observations.assign(who=log.truth_observations["who"].to_numpy(),
                                   slot=np.floor(log.observations["t"].to_numpy(float) / 0.5))
    seen = seen[seen["who"] != "false"]
    groups = seen.groupby(["who", "slot"])["sensor"].agg(lambda s: set(s.astype(str)))
    shared = set().union(*[g for g in groups if len(g) > 1])
    return set(log.sensors.ids) - shared


def test_simulated_sparse_network_is_no_data():
    """Five sensors sharing no view: nothing reaches them, every one keeps its installed pose."""
    sim = pytest.importorskip("pedcal.sim")
    log = sim.simulate_logs("sparse", seed=0).calib
    result, caught = _calibrate(log)
    assert _never_covisible(log) <= {s.id for s in result.network if s.status == "no-data"}
    # the scenario's frusta only touch at their edges (a walker leaving one, entering the next):
    # never the minimum simultaneous overlap, so no sensor is reached
    assert all(s.status == "no-data" for s in result.network)
    for s in result.network:
        np.testing.assert_array_equal(s.position_m, log.sensors[s.id].position_m)
    assert any(all(sid in str(w.message) for sid in log.sensors.ids) for w in caught)


def test_simulated_paper_relative_poses_noise_free():
    sim = pytest.importorskip("pedcal.sim")
    log = sim.simulate_logs("paper", seed=0, noise_free=True).calib
    result, _ = _calibrate(log)
    no_data = {s.id for s in result.network if s.status == "no-data"}
    assert _never_covisible(log) <= no_data
    reached = [sid for sid in log.sensors.ids if sid not in no_data]
    assert len(reached) >= 4
    for sid, (d_mm, d_deg) in _relative_errors(result.network, log.truth, reached[0], reached[1:]).items():
        assert d_mm < 10.0, (sid, d_mm)   # robot turns between 15 Hz samples: a few mm
        assert d_deg < 0.2, (sid, d_deg)
