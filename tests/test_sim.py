"""The ceiling-network simulator: determinism, exact geometry without nuisances, nuisance
statistics, labels, scenario files and the written logs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from pedcal import frames
from pedcal.calib.common import robot_head_at
from pedcal.errors import PedcalInputError
from pedcal.sim import ceiling, simulate, simulate_logs, walkers
from pedcal.sim.scenario import Scenario, load_scenario

SHORT = 45.0   # s of driving: enough for every check below, fast


@pytest.fixture(scope="module")
def paper_full():
    return simulate_logs("paper", seed=0)


@pytest.fixture(scope="module")
def paper_clean():
    return simulate_logs("paper", seed=1, duration_s=90.0, noise_free=True)


def _tables(log):
    return [log.observations, log.robot, log.odometry, log.truth_robot, log.truth_observations]


def test_same_seed_gives_identical_logs_and_another_seed_differs():
    a = simulate_logs("paper", seed=3, duration_s=SHORT)
    b = simulate_logs("paper", seed=3, duration_s=SHORT)
    c = simulate_logs("paper", seed=4, duration_s=SHORT)
    for run in ("calib", "eval"):
        for ta, tb in zip(_tables(getattr(a, run)), _tables(getattr(b, run)), strict=True):
            pd.testing.assert_frame_equal(ta, tb)
        for sa, sb in zip(getattr(a, run).sensors, getattr(b, run).sensors, strict=True):
            np.testing.assert_array_equal(sa.position_m, sb.position_m)
    assert not np.allclose(a.calib.robot["x"].to_numpy()[:100], c.calib.robot["x"].to_numpy()[:100])
    assert not np.allclose([s.position_m for s in a.calib.sensors], [s.position_m for s in c.calib.sensors])


def test_calib_and_eval_share_sensors_and_route_with_independent_noise(paper_full):
    cal, ev = paper_full.calib, paper_full.eval
    for s, e in zip(cal.sensors, ev.sensors, strict=True):
        np.testing.assert_array_equal(s.position_m, e.position_m)
        np.testing.assert_array_equal(s.ypr_deg, e.ypr_deg)
    np.testing.assert_array_equal(cal.truth_robot[["x", "y", "yaw"]].to_numpy(),
                                  ev.truth_robot[["x", "y", "yaw"]].to_numpy())
    assert ev.truth_robot["t"].iloc[0] > cal.truth_robot["t"].iloc[-1]
    err_c = cal.robot["x"].to_numpy() - np.interp(cal.robot["t"], cal.truth_robot["t"], cal.truth_robot["x"])
    err_e = ev.robot["x"].to_numpy() - np.interp(ev.robot["t"], ev.truth_robot["t"], ev.truth_robot["x"])
    n = min(len(err_c), len(err_e))
    assert abs(np.corrcoef(err_c[:n], err_e[:n])[0, 1]) < 0.9


def test_noise_free_robot_observations_map_back_to_true_heads(paper_clean):
    for log in (paper_clean.calib, paper_clean.eval):
        who = log.truth_observations["who"].to_numpy()
        assert set(who) == {"robot"}            # no pedestrians, no false tracks
        obs = log.observations
        p_sensor = log.observation_points_sensor()            # undo the INSTALLED extrinsics
        p_true = np.empty_like(p_sensor)
        for s in log.truth:
            m = (obs["sensor"] == s.id).to_numpy()
            p_true[m] = s.to_world(p_sensor[m])                 # redo with the TRUE extrinsics
        expected = robot_head_at(log, obs["t"].to_numpy(), truth=True)
        np.testing.assert_allclose(p_true, expected, atol=1e-9, rtol=0)
        # ... and the reported points are not the true ones: the installed extrinsics are off.
        assert np.median(np.linalg.norm(obs[["x", "y", "z"]].to_numpy() - expected, axis=1)) > 0.05


def test_latency_shifts_the_instant_a_report_belongs_to():
    log = simulate_logs("paper", seed=2, duration_s=SHORT, noise_free=True, latency_s=0.1).calib
    p_sensor = log.observation_points_sensor()
    obs = log.observations
    p_true = np.vstack([log.truth[s].to_world(p_sensor[i:i + 1]) for i, s in enumerate(obs["sensor"])])
    t = obs["t"].to_numpy()
    np.testing.assert_allclose(p_true, robot_head_at(log, t - 0.1, truth=True), atol=1e-9, rtol=0)
    moving = np.linalg.norm(robot_head_at(log, t, truth=True) - p_true, axis=1)
    assert np.median(moving) > 0.01          # 0.1 s at 0.3 m/s is 3 cm


def test_noise_free_amcl_and_odometry_follow_the_truth(paper_clean):
    log = paper_clean.calib
    truth = log.truth_robot
    x_true = np.interp(log.robot["t"], truth["t"], truth["x"])
    np.testing.assert_allclose(log.robot["x"], x_true, atol=1e-9)
    # Odometry: the true trajectory expressed in a frame anchored at the first pose.
    c, s = np.cos(truth["yaw"].iloc[0]), np.sin(truth["yaw"].iloc[0])
    d = truth[["x", "y"]].to_numpy() - truth[["x", "y"]].to_numpy()[0]
    odo_expected = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    np.testing.assert_allclose(log.odometry[["x", "y"]].to_numpy(), odo_expected, atol=1e-9)


def test_amcl_error_is_a_slow_5cm_process_with_an_unrelated_reported_covariance(paper_full):
    errs = []
    for log in (paper_full.calib, paper_full.eval):
        truth = log.truth_robot
        for ax in ("x", "y"):
            errs.append(log.robot[ax].to_numpy() - np.interp(log.robot["t"], truth["t"], truth[ax]))
        sigma_rep = np.sqrt(log.robot["cov_xx"].to_numpy())
        assert 0.02 - 1e-9 <= sigma_rep.min() and sigma_rep.max() <= 0.08 + 1e-9
        assert sigma_rep.max() - sigma_rep.min() > 0.02                # it varies with time
        assert np.all(np.linalg.eigvalsh(_cov2(log.robot)) > 0)        # a valid covariance
    e = np.concatenate(errs)
    assert 0.025 < e.std() < 0.09                                      # ~5 cm (few independent draws)
    lag1 = np.corrcoef(errs[0][:-1], errs[0][1:])[0, 1]                # 5 Hz, tau 20 s
    assert lag1 > 0.95


def _cov2(robot: pd.DataFrame) -> np.ndarray:
    return np.stack([[robot["cov_xx"], robot["cov_xy"]], [robot["cov_xy"], robot["cov_yy"]]]).transpose(2, 0, 1)


def test_odometry_has_a_one_percent_scale_error_and_drifts(paper_full):
    log = paper_full.calib
    true_len = np.linalg.norm(np.diff(log.truth_robot[["x", "y"]].to_numpy(), axis=0), axis=1).sum()
    odo_len = np.linalg.norm(np.diff(log.odometry[["x", "y"]].to_numpy(), axis=0), axis=1).sum()
    assert abs(abs(odo_len / true_len - 1.0) - 0.01) < 0.003
    yaw_true = np.unwrap(log.truth_robot["yaw"].to_numpy())
    yaw_odo = np.unwrap(log.odometry["yaw"].to_numpy())
    drift_deg = np.degrees(abs((yaw_odo[-1] - yaw_odo[0]) - (yaw_true[-1] - yaw_true[0])))
    assert drift_deg > 10.0          # 0.5 deg/m over ~100 m, partly cancelled by the gyro bias


def test_installed_extrinsics_are_off_like_a_hand_survey():
    mean_err = []
    for seed in range(30):
        log = simulate_logs("paper", seed=seed, duration_s=1.0).calib
        d = np.array([np.linalg.norm(s.position_m - log.truth[s.id].position_m) for s in log.sensors])
        a = np.array([frames.rotation_angle_deg(s.R_world_sensor, log.truth[s.id].R_world_sensor)
                      for s in log.sensors])
        assert d.max() <= 1.0 + 1e-9 and a.max() <= 15.0 + 1e-6       # the caps
        mean_err.append(d.mean())
    assert 0.30 < np.mean(mean_err) < 0.45                               # ~370 mm in the paper
    assert np.min(mean_err) > 0.15 and np.max(mean_err) < 0.8      # it varies with the seed


def test_every_observation_is_inside_its_sensors_field_of_view(paper_clean, paper_full):
    sc = paper_clean.scenario
    for log in (paper_clean.calib, paper_clean.eval):
        assert ceiling.in_frustum(log.observation_points_sensor(), sc).all()
    # With noise, the reported points stay within a small margin of the field of view.
    log = paper_full.calib
    p = log.observation_points_sensor()
    r = np.linalg.norm(p, axis=1)
    az = np.degrees(np.abs(np.arctan2(p[:, 1], p[:, 0])))
    el = np.degrees(np.abs(np.arctan2(p[:, 2], p[:, 0])))
    assert (p[:, 0] > 0).all() and (az < 29 + 3).all() and (el < 22.5 + 3).all()
    assert r.min() > 0.8 - 0.2 and r.max() < 5.0 + 0.3


def test_truth_labels_are_consistent(paper_full):
    sc = paper_full.scenario
    for log in (paper_full.calib, paper_full.eval):
        obs, lab = log.observations, log.truth_observations
        assert lab["row"].tolist() == list(range(len(obs)))
        who = lab["who"].to_numpy()
        assert {"robot", "false"} <= set(who) and len(set(who)) > 3      # pedestrians too
        # A track is one entity: tracks never mix the robot, people and false tracks.
        per_track = pd.DataFrame({"k": obs["sensor"] + "/" + obs["track"].astype(str), "who": who})
        assert (per_track.groupby("k")["who"].nunique() == 1).all()
        # The robot's rows lie near its true head (dome shift, noise, latency), false ones low or high.
        rob = who == "robot"
        head = robot_head_at(log, obs["t"].to_numpy()[rob] - sc.latency_s, truth=True)
        dist = np.linalg.norm(obs[["x", "y", "z"]].to_numpy()[rob] - head, axis=1)
        assert np.median(dist) < 1.0        # the installed extrinsics are ~0.4 m off
        p_true = np.empty((len(obs), 3))
        p_sensor = log.observation_points_sensor()
        for s in log.truth:
            m = (obs["sensor"] == s.id).to_numpy()
            p_true[m] = s.to_world(p_sensor[m])
        assert np.percentile(np.linalg.norm(p_true[rob] - head, axis=1), 95) < 0.25
        z_people = p_true[(who != "robot") & (who != "false"), 2]
        assert z_people.min() > 1.3 and z_people.max() < 2.0
        z_false = p_true[who == "false", 2]
        assert z_false.min() > 0.3 and z_false.max() < 2.2
        # Within a track, stamps strictly increase in file order (LOG_FORMAT.md).
        assert (obs.groupby(["sensor", "track"])["t"].diff().dropna() > 0).all()


def test_robot_seen_by_every_sensor_from_several_directions(paper_full):
    log = paper_full.calib
    obs = log.observations[log.truth_observations["who"].to_numpy() == "robot"]
    counts = obs["sensor"].value_counts()
    assert set(counts.index) == set(log.sensors.ids)
    yaw = np.interp(obs["t"] - paper_full.scenario.latency_s, log.truth_robot["t"],
                    np.unwrap(log.truth_robot["yaw"]))
    quadrant = np.mod(np.rint(yaw / (np.pi / 2)), 4).astype(int)
    n_dirs = pd.Series(quadrant).groupby(obs["sensor"].to_numpy()).nunique()
    assert (n_dirs >= 3).sum() >= 8
    assert counts.min() < 0.25 * counts.max()     # some sensors see the robot only a little


def _head_plane_coverage(net, sc, z=1.35):
    x, y = np.meshgrid(np.arange(-2.0, sc.area_m[0] + 2.0, 0.05), np.arange(-2.0, sc.area_m[1] + 2.0, 0.05))
    return ceiling.coverage(net, sc, np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sparse_fields_of_view_do_not_overlap_and_paper_ones_do(seed):
    sparse = simulate_logs("sparse", seed=seed, duration_s=1.0)
    assert len(sparse.calib.truth) == 5
    cov = _head_plane_coverage(sparse.calib.truth, sparse.scenario)
    assert cov.any(axis=1).all()
    assert cov.sum(axis=0).max() == 1                 # no point seen by two sensors
    paper = simulate_logs("paper", seed=seed, duration_s=1.0)
    assert _head_plane_coverage(paper.calib.truth, paper.scenario).sum(axis=0).max() >= 2


def test_depth_noise_grows_with_range_squared():
    sc = Scenario()
    rng = np.random.default_rng(0)
    for r, factor in ((2.0, 1.0), (4.5, sc.far_noise_factor)):
        p = np.tile([[r, 0.0, 0.0]], (20000, 1))
        noisy = ceiling.measure(p, sc, rng)
        assert noisy[:, 0].std() == pytest.approx(sc.depth_noise_k_per_m * r**2 * factor, rel=0.05)
        assert noisy[:, 1].std() == pytest.approx(sc.lateral_noise_m, rel=0.05)


def test_head_dome_point_moves_toward_the_sensor_and_down():
    top = np.array([[0.0, 0.0, 1.35]])
    above = ceiling.dome_point(top, np.array([[0.0, 0.0, 2.6]]), 0.1)
    np.testing.assert_allclose(above, top, atol=1e-12)
    oblique = ceiling.dome_point(top, np.array([[10.0, 0.0, 1.25 + 10.0]]), 0.1)[0]  # 45 deg up
    np.testing.assert_allclose(oblique, [0.1 / np.sqrt(2), 0.0, 1.25 + 0.1 / np.sqrt(2)], atol=1e-12)


def test_companion_walks_beside_the_robot():
    res = simulate_logs("paper", seed=5, duration_s=60.0, noise_free=True, companion_fraction=0.5)
    log = res.calib
    who = log.truth_observations["who"].to_numpy()
    assert (who == "companion").sum() > 50
    assert set(who) == {"robot", "companion"}


def test_scenario_files_reject_unknown_keys_and_bad_values(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("base: paper\nsensor_heigth_m: 2.6\n")
    with pytest.raises(PedcalInputError) as exc:
        load_scenario(bad)
    assert "bad.yaml" in str(exc.value) and "sensor_heigth_m" in str(exc.value)
    bad.write_text("frame_rate_hz: fast\n")
    with pytest.raises(PedcalInputError, match="frame_rate_hz"):
        load_scenario(bad)
    with pytest.raises(PedcalInputError, match="no_such_parameter"):
        simulate_logs("paper", seed=0, no_such_parameter=1)
    with pytest.raises(PedcalInputError, match="unknown scenario 'nowhere'"):
        load_scenario("nowhere")
    with pytest.raises(PedcalInputError, match="sensor_ids"):
        simulate_logs("paper", seed=0, duration_s=1.0, sensor_ids=["s99"])
    sparse = load_scenario("sparse")
    assert sparse.sensor_ids == ["s04", "s05", "s06", "s07", "s08"] and sparse.area_m == [8.2, 4.5]


def test_a_scenario_file_is_read_once(tmp_path, monkeypatch):
    """load_scenario read each file twice: once to check it, again to parse it."""
    import pedcal.io.sensors_yaml as sensors_yaml

    reads = []
    read = sensors_yaml.read_bytes_capped
    monkeypatch.setattr(sensors_yaml, "read_bytes_capped",
                        lambda path, *a, **k: reads.append(path) or read(path, *a, **k))
    path = tmp_path / "fast.yaml"
    path.write_text("base: paper\nframe_rate_hz: 30\n")
    assert load_scenario(path).frame_rate_hz == 30.0
    assert sorted(p.name for p in reads) == ["fast.yaml", "paper.yaml"]


@pytest.mark.parametrize("line,column,match", [
    ("robot_speed_mps: .nan", "robot_speed_mps", "expected a finite number > 0, got nan"),   # a ValueError traceback
    ("robot_speed_mps: -1", "robot_speed_mps", "expected a finite number > 0, got -1.0"),   # an IndexError one
    ("area_m: [8.2, 0]", "area_m", r"expected a finite number > 0, got 0.0 \(item 1 of the list\)"),
    ("miss_prob: 1.5", "miss_prob", r"expected a share within \[0, 1\], got 1.5"),
    ("amcl_sigma_m: -0.05", "amcl_sigma_m", "expected a finite number >= 0, got -0.05"),
    ("latency_s: .inf", "latency_s", "expected a finite number, got inf"),
    ('odometry: "false"', "odometry", "expected a value like True, got 'false'"),      # bool("false") was True
    ("duration_s: long", "duration_s", "expected a number, got 'long'"),
    ("grid_rows: 3", "row_y_m", r"2 entries for 3 rows \(grid_rows\)"),     # was raised without the file
])
def test_scenario_values_outside_their_domain_are_refused_by_name(tmp_path, line, column, match):
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"base: paper\n{line}\n")
    with pytest.raises(PedcalInputError, match=match) as exc:
        load_scenario(bad)
    assert (exc.value.path, exc.value.column) == (str(bad), column)


def test_signed_scenario_values_may_be_negative():
    sc = Scenario().resolve(head_vertical_bias_m=-0.02, odom_scale_error=-0.01, clock_offset_s=-0.1,
                            head_offset_m=[-0.1, 0.0, 1.3])
    assert sc.head_vertical_bias_m == -0.02 and sc.head_offset_m == [-0.1, 0.0, 1.3]


def test_walker_speed_std_may_be_zero_and_the_companion_may_walk_on_the_right():
    """walker_speed_mps is [mean, std]: a std of 0 (every walker at the mean) was refused as not > 0;
    companion_offset_m is signed (negative: to the robot's right) but was refused when negative."""
    sc = Scenario().resolve(walker_speed_mps=[1.2, 0.0], companion_offset_m=-0.7, companion_fraction=1.0)
    assert sc.walker_speed_mps == [1.2, 0.0] and sc.companion_offset_m == -0.7
    truth = pd.DataFrame({"t": [0.0, 1.0], "x": [1.0, 2.0], "y": [3.0, 3.0], "yaw": [0.0, 0.0]})
    beside = walkers.companion(sc, truth, np.random.default_rng(0))
    np.testing.assert_allclose(beside[["x", "y"]].to_numpy(), [[1.0, 2.3], [2.0, 2.3]])   # heading +x: right is -y
    for bad, match in (([0.0, 0.2], r"> 0, got 0.0 \(item 0 of the list\)"),
                       ([1.2, -0.1], r">= 0, got -0.1 \(item 1 of the list\)")):
        with pytest.raises(PedcalInputError, match=match) as exc:
            Scenario().resolve(walker_speed_mps=bad)
        assert exc.value.column == "walker_speed_mps"


def test_noise_free_turns_every_nuisance_off():
    clean = Scenario().resolve(noise_free=True)
    for name, off in Scenario.nuisances().items():
        assert getattr(clean, name) == off
    assert {"latency_s", "depth_noise_k_per_m", "amcl_sigma_m", "false_track_rate_hz", "walkers",
            "head_radius_m", "odom_scale_error", "miss_prob"} <= set(Scenario.nuisances())


def test_written_logs_read_back(tmp_path):
    from pedcal.io import read_log

    res = simulate("paper", tmp_path / "run", seed=7, duration_s=SHORT)
    for name, mem in (("calib", res.calib), ("eval", res.eval)):
        disk = read_log(tmp_path / "run" / name)
        assert disk.truth is not None and disk.truth_observations is not None
        assert len(disk.observations) == len(mem.observations)
        np.testing.assert_allclose(disk.observations[["t", "x", "y", "z"]].to_numpy(),
                                   mem.observations[["t", "x", "y", "z"]].to_numpy(), rtol=0, atol=1e-12)
        assert disk.truth_observations["who"].tolist() == mem.truth_observations["who"].tolist()
        np.testing.assert_allclose(disk.meta.head_offset_m, [0.0, 0.0, 1.35])
        for s in mem.sensors:
            np.testing.assert_allclose(disk.sensors[s.id].position_m, s.position_m, atol=1e-9)
    saved = yaml.safe_load((tmp_path / "run" / "scenario.yaml").read_text())
    assert saved["seed"] == 7 and saved["duration_s"] == SHORT
    assert load_scenario(tmp_path / "run" / "scenario.yaml") == res.scenario
    assert "observations" in res.summary() and "false tracks" in res.summary()


def test_mall_uses_recorded_atc_walkers(shared_data):
    res = simulate_logs("mall", seed=0, duration_s=120.0)
    assert len(res.calib.truth) == 50
    who = set(res.calib.truth_observations["who"])
    assert "robot" in who and any(w.startswith("r") for w in who - {"robot"})


def test_missing_recordings_fall_back_to_builtin_walkers(monkeypatch, tmp_path):
    monkeypatch.setattr(walkers, "SHARED_DATA", tmp_path)
    with pytest.warns(UserWarning, match="built-in walker model"):
        res = simulate_logs("paper", seed=0, duration_s=120.0, walkers="atc", walker_rate_hz=0.2)
    who = set(res.calib.truth_observations["who"])
    assert any(w.startswith("p") for w in who)


def test_companion_swaps_replace_the_stated_share_in_short_stretches():
    res = simulate_logs("paper", seed=3, duration_s=150.0, companion_swap_fraction=0.2)
    log = res.calib
    who = log.truth_observations["who"].astype(str).to_numpy()
    share = (who == "companion").sum() / np.isin(who, ["robot", "companion"]).sum()
    assert 0.17 < share < 0.23
    # several stretches of a few seconds, not one span
    t = np.sort(log.observations["t"].to_numpy(float)[who == "companion"])
    breaks = np.flatnonzero(np.diff(t) > 1.0)
    starts, ends = np.r_[t[0], t[breaks + 1]], np.r_[t[breaks], t[-1]]
    assert len(starts) >= 3
    assert (ends - starts).max() <= res.scenario.companion_swap_s[1] + 0.5
    # the companion is also tracked as itself around the swaps; default runs hold no companion
    assert (who == "companion-beside").sum() > 20
    plain = simulate_logs("paper", seed=3, duration_s=30.0).calib.truth_observations["who"].astype(str)
    assert not plain.str.startswith("companion").any()


def test_a_scenario_whose_sensors_never_see_the_robot_says_so(tmp_path):
    """simulate writes logs that calibrate would refuse as empty: not in silence."""
    from pedcal.errors import DegenerateDataWarning
    from pedcal.sim import simulate

    with pytest.warns(DegenerateDataWarning, match="the (calib|eval) log holds no observation of the robot") as rec:
        res = simulate("paper", tmp_path / "run", seed=0, max_range_m=0.1)
    assert len(res.calib.observations) == 0 and len(rec) == 2
    with pytest.raises(PedcalInputError, match=r"expected an angle > 0 and <= 180 deg, got 400.0"):
        Scenario().resolve(hfov_deg=400)
