"""The simulator's nuisance zoo and the corridor and cross layouts."""

import numpy as np
import pytest

from pedcal import frames
from pedcal.calib.common import interpolate_pose2
from pedcal.sim import simulate_logs
from pedcal.sim.nuisances import (
    HEAD_KINDS,
    OFF_FAMILIES,
    RAMP_SHAPES,
    draw_nuisances,
    head_model_truth,
    head_point,
    ramp_share,
    sensor_head_models,
    switch_off,
    vary,
    zoo_families,
)
from pedcal.sim.robot import amcl_table
from pedcal.sim.scenario import Scenario, load_scenario

TOP = np.array([[0.0, 0.0, 1.35]])


def _seen_from(elev_deg, dist=2.0):
    e = np.radians(elev_deg)
    return np.array([[dist * np.cos(e), 0.0, 1.35 + dist * np.sin(e)]])


def test_head_point_models_move_the_point_as_documented():
    sc = Scenario()
    top = sc.resolve(head_point="top", head_vertical_bias_m=0.02)
    np.testing.assert_allclose(head_point(TOP, _seen_from(45), top), TOP + [0, 0, 0.02])
    dome = sc.resolve(head_point="dome", head_radius_m=0.1)
    d = head_point(TOP, _seen_from(45, dist=1e5), dome)[0] - TOP[0]      # far: the same elevation from the centre
    np.testing.assert_allclose(d, [0.1 * np.cos(np.pi / 4), 0.0, -0.1 * (1 - np.sin(np.pi / 4))], atol=1e-6)
    shift = sc.resolve(head_point="shift", head_shift_m=0.04)
    np.testing.assert_allclose(head_point(TOP, _seen_from(30), shift)[0] - TOP[0], [0.04, 0.0, 0.0], atol=1e-12)
    cen = sc.resolve(head_point="centroid")
    below = head_point(TOP, _seen_from(90), cen)[0] - TOP[0]
    # straight down: the centroid of a 0.1 m hemisphere's surface is half its radius down
    assert below[0] == pytest.approx(0.0, abs=1e-3) and below[2] == pytest.approx(-0.05, abs=2e-3)
    oblique = head_point(TOP, _seen_from(20), cen)[0] - TOP[0]
    assert oblique[0] > 0.02 and -0.06 < oblique[2] < -0.02      # toward the sensor, and down


def test_vary_nuisances_is_seeded_and_draws_every_alternative():
    base = load_scenario("paper")
    draws = [vary(base.resolve(seed=s)) for s in range(40)]
    assert vary(base.resolve(seed=3)) == draws[3]
    assert {d.head_point for d in draws} == {"top", "dome", "shift", "centroid"}
    assert {d.amcl_error for d in draws} == {"white", "correlated", "jumps"}
    assert {d.depth_noise_model for d in draws} == {"linear", "quadratic"}
    assert {d.odometry for d in draws} == {True, False}
    lat = [d.latency_s for d in draws]
    assert 0.0 <= min(lat) and max(lat) <= 0.3 and np.std(lat) > 0.05
    bias = [d.head_vertical_bias_m for d in draws]
    assert max(np.abs(bias)) <= 0.03
    # the layout and the installed extrinsics are the seed's, whatever the draw
    assert all(draws[k].pitch_deg == base.pitch_deg for k in range(5))
    assert set(draw_nuisances(np.random.default_rng(0))) <= set(Scenario.field_names())


def test_amcl_error_models():
    sc = Scenario(amcl_sigma_m=0.05)
    t = np.arange(0.0, 600.0, 0.05)
    truth = dict(t=t, x=0.01 * t, y=np.zeros_like(t), yaw=np.zeros_like(t))
    import pandas as pd

    truth = pd.DataFrame(truth)
    lag1 = {}
    for kind in ("white", "correlated", "jumps"):
        amcl = amcl_table(truth, sc.resolve(amcl_error=kind, amcl_jump_rate_hz=1 / 60.0), np.random.default_rng(1))
        e = amcl["x"].to_numpy() - interpolate_pose2(truth, amcl["t"].to_numpy())[:, 0]
        lag1[kind] = np.corrcoef(e[:-1], e[1:])[0, 1]
        if kind == "jumps":
            assert np.max(np.abs(np.diff(e))) > 0.25
    assert abs(lag1["white"]) < 0.1 and lag1["correlated"] > 0.95


def test_corridor_layout_and_route():
    sim = simulate_logs("corridor", seed=0, duration_s=120.0)
    net = sim.calib.truth
    assert len(net) == 16
    y = np.array([s.position_m[1] for s in net])
    assert np.all((np.abs(y - 0.1) < 0.25) | (np.abs(y - 2.3) < 0.25))
    sides = np.abs(y - 0.1) < 0.25
    assert np.all(sides[::2] != sides[1::2])                 # alternating walls
    for s in net:                                            # looking across, into the corridor
        look = s.R_world_sensor[:, 0]
        assert look[1] * (1.2 - s.position_m[1]) > 0
    pose = sim.calib.truth_robot
    assert pose["y"].between(0.3, 2.1).all() and pose["x"].between(0.2, 19.8).all()
    seen = sim.calib.observations.loc[sim.calib.truth_observations["who"].to_numpy() == "robot", "sensor"]
    assert seen.nunique() >= 4


def test_cross_layout_keeps_sensors_out_of_the_crossing_and_the_robot_in_the_corridors():
    sim = simulate_logs("cross", seed=0)
    net = sim.calib.truth
    assert len(net) == 16
    xy = np.array([s.position_m[:2] for s in net])
    in_x = np.abs(xy[:, 1] - 7.0) < 1.3
    in_y = np.abs(xy[:, 0] - 7.0) < 1.3
    assert np.all(in_x ^ in_y)                              # on one corridor's walls, not the crossing
    assert in_x.sum() == 8
    p = sim.calib.truth_robot[["x", "y"]].to_numpy()
    inside = (np.abs(p[:, 1] - 7.0) < 1.2) | (np.abs(p[:, 0] - 7.0) < 1.2)
    assert inside.mean() > 0.99
    who = sim.calib.truth_observations["who"].to_numpy()
    assert sim.calib.observations.loc[who == "robot", "sensor"].nunique() == 16


def test_absent_odometry_and_linear_depth_noise():
    sim = simulate_logs("paper", seed=1, duration_s=60.0, odometry=False, depth_noise_model="linear")
    assert sim.calib.odometry is None
    with pytest.raises(Exception, match="expected one of"):
        simulate_logs("paper", seed=1, head_point="ellipsoid")


# ------------------------------------------------------------------------------ the zoo's families
def test_ramp_and_saturate_head_points_follow_horizontal_distance():
    sc = Scenario().resolve(head_point="ramp", head_shift_m=0.04, head_ramp_m=2.0)
    sat = sc.resolve(head_point="saturate")
    for d_h, ramp_mm, sat_mm in ((0.5, 30.0, 10.0), (1.0, 20.0, 20.0), (2.0, 0.0, 40.0), (3.5, 0.0, 40.0)):
        sensor = np.array([[d_h, 0.0, 2.6]])
        np.testing.assert_allclose(head_point(TOP, sensor, sc)[0] - TOP[0], [ramp_mm / 1000, 0, 0], atol=1e-12)
        np.testing.assert_allclose(head_point(TOP, sensor, sat)[0] - TOP[0], [sat_mm / 1000, 0, 0], atol=1e-12)
    # toward the sensor whatever its bearing
    d = head_point(TOP, np.array([[0.0, -0.5, 2.6]]), sc)[0] - TOP[0]
    np.testing.assert_allclose(d, [0.0, -0.03, 0.0], atol=1e-12)


def test_a_ramps_shape_sets_how_its_change_spreads_over_the_distance():
    x = np.array([0.0, 0.25, 0.5, 1.0, 2.0])
    np.testing.assert_allclose(ramp_share(x, "linear"), [0.0, 0.25, 0.5, 1.0, 1.0])
    np.testing.assert_allclose(ramp_share(x, "exp"), 1.0 - np.exp(-3.0 * x))
    np.testing.assert_allclose(ramp_share(x, "smooth"), [0.0, 0.15625, 0.5, 1.0, 1.0])
    # a saturating exp shift of 40 mm over 2 m: 95 % of it at 2 m, nearly all at 4 m
    sat = Scenario().resolve(head_point="saturate", head_shift_m=0.04, head_ramp_m=2.0, head_ramp_shape="exp")
    for d_h, mm in ((2.0, 40.0 * (1 - np.exp(-3.0))), (4.0, 40.0 * (1 - np.exp(-6.0)))):
        got = head_point(TOP, np.array([[d_h, 0.0, 2.6]]), sat)[0] - TOP[0]
        np.testing.assert_allclose(got, [mm / 1000, 0, 0], atol=1e-12)
    # a smooth ramp fading a 40 mm shift over 2 m: at 0.5 m (a quarter of it) 40 (1 - 0.15625) mm
    ramp = Scenario().resolve(head_point="ramp", head_shift_m=0.04, head_ramp_m=2.0, head_ramp_shape="smooth")
    got = head_point(TOP, np.array([[0.5, 0.0, 2.6]]), ramp)[0] - TOP[0]
    np.testing.assert_allclose(got, [0.03375, 0, 0], atol=1e-12)


def test_a_sinking_head_point_drops_with_horizontal_distance_whatever_its_kind():
    for kind in HEAD_KINDS:
        plain = Scenario().resolve(head_point=kind, head_shift_m=0.04, head_radius_m=0.08, head_ramp_m=3.0)
        sunk = plain.resolve(head_sink_m=0.03)
        for d_h, mm in ((0.0, 0.0), (0.75, 7.5), (3.0, 30.0), (4.5, 30.0)):
            sensor = np.array([[d_h, 0.0, 2.6]])
            got = head_point(TOP, sensor, sunk)[0] - head_point(TOP, sensor, plain)[0]
            np.testing.assert_allclose(got, [0.0, 0.0, -mm / 1000], atol=1e-12, err_msg=kind)
    # the ramp's shape sets how the sink spreads over the distance, as it does the shift's
    exp = Scenario().resolve(head_point="top", head_sink_m=0.03, head_ramp_m=2.0, head_ramp_shape="exp")
    got = head_point(TOP, np.array([[1.0, 0.0, 2.6]]), exp)[0] - TOP[0]
    np.testing.assert_allclose(got, [0.0, 0.0, -0.03 * (1 - np.exp(-1.5))], atol=1e-12)
    assert head_model_truth(exp) == "top, sinking 30 mm over 2.0 m (exp), vertical bias +0 mm"
    assert head_model_truth(exp.resolve(head_sink_m=0.0)) == "top, vertical bias +0 mm"
    # the caller's heads stay where they were (a dome of radius 0 hands back the array it got)
    tops = np.repeat(TOP, 2, axis=0)
    head_point(tops, np.array([[1.0, 0.0, 2.6], [0.0, 1.0, 2.6]]), exp.resolve(head_point="dome", head_radius_m=0.0))
    np.testing.assert_array_equal(tops, np.repeat(TOP, 2, axis=0))


def test_each_sensors_sink_is_drawn_beside_its_head_model_and_changes_no_other_draw():
    sc = load_scenario("paper").resolve(seed=3, per_sensor_head=True)
    without = sensor_head_models(sc, 8)
    with_sink = sensor_head_models(sc.resolve(head_sink_m=0.02), 8)
    assert [m.head_sink_m for m in without] == [0.0] * 8
    sinks = np.array([m.head_sink_m for m in with_sink])
    assert np.all((sinks >= 0.0) & (sinks <= 0.04)) and len(set(sinks.tolist())) == 8
    for a, b in zip(without, with_sink, strict=True):      # the kinds, shifts and shapes as they were
        assert (a.head_point, a.head_shift_m, a.head_radius_m, a.head_ramp_m, a.head_ramp_shape) == (
            b.head_point, b.head_shift_m, b.head_radius_m, b.head_ramp_m, b.head_ramp_shape)
    # one tracker for every sensor: the scenario's own sink
    assert [m.head_sink_m for m in sensor_head_models(sc.resolve(per_sensor_head=False, head_sink_m=0.02), 3)] == [
        0.02] * 3


def test_the_zoo_draws_ramp_shapes_from_a_stream_of_their_own():
    # the draws made before the shapes existed (paper, seeds 0-3) are unchanged
    before = [("top", 0.031, 2.394, False, ["centroid", "ramp", "top", "dome"]),
              ("ramp", 0.0361, 1.176, True, ["saturate", "top", "ramp", "ramp"]),
              ("shift", 0.0515, 2.808, False, ["centroid", "ramp", "shift", "shift"]),
              ("top", 0.0475, 1.351, False, ["ramp", "shift", "shift", "top"])]
    for seed, (kind, shift, ramp, per_sensor, kinds) in enumerate(before):
        sc = vary(load_scenario("paper").resolve(seed=seed), zoo=True)
        assert (sc.head_point, round(sc.head_shift_m, 4), round(sc.head_ramp_m, 3), sc.per_sensor_head) == (
            kind, shift, ramp, per_sensor)
        assert [m.head_point for m in sensor_head_models(sc.resolve(per_sensor_head=True), 4)] == kinds
    shapes = {vary(load_scenario("paper").resolve(seed=s), zoo=True).head_ramp_shape for s in range(30)}
    assert shapes == set(RAMP_SHAPES)
    per_sensor = sensor_head_models(vary(load_scenario("paper").resolve(seed=1), zoo=True), 10)
    assert len({m.head_ramp_shape for m in per_sensor}) > 1
    # without the zoo, the scenario's shape
    assert vary(load_scenario("paper").resolve(seed=1)).head_ramp_shape == "linear"


def test_zoo_leaves_the_classic_draw_alone_and_draws_every_alternative():
    base = load_scenario("lhall")
    classic = [vary(base.resolve(seed=s)) for s in range(40)]
    zoo = [vary(base.resolve(seed=s), zoo=True) for s in range(40)]
    assert [vary(base.resolve(seed=s), zoo=False) for s in range(3)] == classic[:3]
    for c, z in zip(classic, zoo, strict=True):      # what the zoo does not draw stays the classic draw
        assert (z.latency_s, z.depth_noise_model, z.odometry) == (c.latency_s, c.depth_noise_model, c.odometry)
    fam = [zoo_families(z) for z in zoo]
    assert {f["clock"] for f in fam} == {"shared", "offsets", "skew"}
    assert {f["mounts"] for f in fam} == {"ceiling", "mixed", "wall"}
    assert "relocalization" in {f["amcl"] for f in fam} and "per-sensor" in {f["head"] for f in fam}
    assert {z.head_point for z in zoo} == set(HEAD_KINDS)
    assert all(abs(z.clock_offset_s) <= 0.15 for z in zoo)
    assert {f["head sink"] for f in fam} == {"sinks", "none"}
    assert all(0.01 <= z.head_sink_m <= 0.04 for z in zoo if z.head_sink_m)
    # (pinned: the stream's draw for seeds 0-19, the README's 40 sink logs of the zoo's 100 (8 seeds
    # in five scenarios); a changed stream changes every zoo figure)
    paper = load_scenario("paper")
    assert sum(bool(vary(paper.resolve(seed=s), zoo=True).head_sink_m) for s in range(20)) == 8


def test_switch_off_makes_one_family_ideal_and_leaves_every_other_draw():
    base = load_scenario("cross")
    zoo = [vary(base.resolve(seed=s), zoo=True) for s in range(12)]
    # a seed whose draw has every family on: a per-sensor head, skewed clocks, wall mounts, relocalizations
    sc = next(z for z in zoo if z.per_sensor_head and z.clock_skew_ppm and z.wall_mounted_fraction
              and z.amcl_error == "jumps" and z.latency_s > 0.0)
    assert switch_off(sc, []) is sc
    off = {f: switch_off(sc, [f]) for f in OFF_FAMILIES}
    assert zoo_families(off["head"])["head"] == "top" and off["head"].head_vertical_bias_m == 0.0
    assert zoo_families(off["clock"])["clock"] == "shared"
    assert off["latency"].latency_s == 0.0
    assert off["jumps"].amcl_jump_m == 0.0 and zoo_families(off["jumps"])["amcl"] == "correlated"
    assert zoo_families(off["mounts"])["mounts"] == "ceiling"
    assert (off["odometry"].odom_scale_error, off["odometry"].odom_gyro_bias_dps) == (0.0, 0.0)
    assert off["odometry"].odometry == sc.odometry and off["depth"].depth_noise_model == "quadratic"
    own = {"head": {"head_point", "per_sensor_head", "head_vertical_bias_m", "head_sink_m"},
           "clock": {"clock_offset_s", "clock_skew_ppm"}, "latency": {"latency_s"}, "jumps": {"amcl_jump_m"},
           "mounts": {"sensor_height_range_m", "wall_mounted_fraction"},
           "odometry": {"odom_scale_error", "odom_gyro_bias_dps"}, "depth": {"depth_noise_model"},
           "smoothing": {"tracker_noise_rho"}, "stops": {"robot_stop_s", "robot_stop_share"}}
    for family, o in off.items():      # only the family's own fields changed
        changed = {k for k in vars(sc) if getattr(o, k) != getattr(sc, k)}
        assert changed <= own[family] and (changed or family in ("depth", "stops")), family
    assert zoo_families(off["smoothing"])["tracker noise"] == "white"
    every = switch_off(sc, OFF_FAMILIES)
    assert zoo_families(every) == {"head": "top", "clock": "shared", "mounts": "ceiling", "amcl": "correlated",
                                   "head sink": "none", "tracker noise": "white", "robot stops": "none"}
    # the same layout and route: the switched-off log's truth is the drawn one's, but for the mounts
    a = simulate_logs(sc, seed=sc.seed, duration_s=30.0).calib
    b = simulate_logs(switch_off(sc, ["head", "clock", "latency"]), seed=sc.seed, duration_s=30.0).calib
    assert a.truth.ids == b.truth.ids
    for sid in a.truth.ids:
        np.testing.assert_allclose(a.truth[sid].position_m, b.truth[sid].position_m)
    np.testing.assert_allclose(a.truth_robot[["x", "y"]].to_numpy(), b.truth_robot[["x", "y"]].to_numpy())
    # AMCL's table, every column, the same draws (but the jumps' size), and the same sightings
    for family in ("head", "clock", "latency", "odometry", "depth", "smoothing"):
        c = simulate_logs(off[family], seed=sc.seed, duration_s=30.0).calib
        assert c.robot.equals(a.robot), family
        pairs = sorted(map(tuple, c.observations[["sensor", "track"]].drop_duplicates().to_numpy().tolist()))
        assert pairs == sorted(map(tuple, a.observations[["sensor", "track"]].drop_duplicates().to_numpy().tolist()))
    j = simulate_logs(off["jumps"], seed=sc.seed, duration_s=30.0).calib
    assert j.robot.drop(columns=["x", "y", "yaw"]).equals(a.robot.drop(columns=["x", "y", "yaw"]))
    with pytest.raises(ValueError, match="unknown nuisance family 'weather'"):
        switch_off(sc, ["weather"])


def test_per_sensor_clock_offsets_shift_only_that_sensors_stamps():
    kw = dict(seed=3, duration_s=60.0)
    plain = simulate_logs("paper", **kw).calib
    late = simulate_logs("paper", clock_offset_s=0.15, **kw).calib
    truth = late.meta.notes["simulated"]["truth"]["clock_offset_s"]
    assert len(truth) == 10 and max(abs(v) for v in truth.values()) <= 0.15
    assert np.std(list(truth.values())) > 0.03
    for sid, offset in truth.items():
        a = plain.observations[plain.observations["sensor"] == sid]
        b = late.observations[late.observations["sensor"] == sid]
        np.testing.assert_allclose(b["t"].to_numpy() - a["t"].to_numpy(), offset, atol=1e-9)
        np.testing.assert_allclose(b[["x", "y", "z"]].to_numpy(), a[["x", "y", "z"]].to_numpy())
    assert "truth" not in plain.meta.notes["simulated"]


def test_clock_skew_grows_with_time():
    kw = dict(seed=3, duration_s=60.0)
    plain = simulate_logs("paper", **kw).calib.observations
    skewed = simulate_logs("paper", clock_skew_ppm=1000.0, **kw)
    ppm = skewed.calib.meta.notes["simulated"]["truth"]["clock_skew_ppm"]
    sc = skewed.scenario
    for sid, rate in ppm.items():
        a, b = plain[plain["sensor"] == sid], skewed.calib.observations[skewed.calib.observations["sensor"] == sid]
        t_true = a["t"].to_numpy() - sc.latency_s      # the jitter is common to both, a small error here
        np.testing.assert_allclose(b["t"].to_numpy() - a["t"].to_numpy(), 1e-6 * rate * (t_true - sc.start_time_s),
                                   atol=1e-6 * abs(rate) * 0.1 + 1e-9)


def test_lhall_wings_share_no_view_and_the_robot_joins_them():
    from pedcal.sim.ceiling import coverage

    sim = simulate_logs("lhall", seed=0)
    net, sc = sim.calib.truth, sim.scenario
    grid = np.mgrid[0:16:0.05, 0:16:0.05].reshape(2, -1).T
    wing_x = np.array([s.position_m[0] < 16.0 - 3.0 for s in net])      # the wing along x ends at the corner
    assert wing_x.sum() == 7 and (~wing_x).sum() == 7
    for h in (1.35, 1.9):
        seen = coverage(net, sc, np.column_stack([grid, np.full(len(grid), h)]))
        assert not np.any(seen[wing_x].any(axis=0) & seen[~wing_x].any(axis=0))
    who = sim.calib.truth_observations["who"].to_numpy()
    assert sim.calib.observations.loc[who == "robot", "sensor"].nunique() == 14


def test_mixed_heights_and_wall_mounts():
    sim = simulate_logs("paper", seed=4, duration_s=30.0, sensor_height_range_m=[2.6, 4.5],
                        wall_mounted_fraction=0.3)
    z = np.array([s.position_m[2] for s in sim.calib.truth])
    pitch = np.array([frames.ypr_deg_from_rot(s.R_world_sensor)[1] for s in sim.calib.truth])
    wall = (pitch >= 10.0) & (pitch <= 25.0)
    assert wall.sum() == 3                                    # the paper's pitches are 40-60 deg
    # ceiling sensors at the mixed heights; wall mounts lower, at the height their aim gives
    assert np.all((z[~wall] >= 2.6) & (z[~wall] <= 4.5)) and np.ptp(z[~wall]) > 0.8
    assert np.all((z[wall] > 1.7 + 2.0 * np.tan(np.radians(10.0)) - 1e-9)
                  & (z[wall] < 1.7 + 3.5 * np.tan(np.radians(25.0)) + 1e-9))
    # the layout's other draws are the seed's: the ceiling sensors' x, y as without the mounts;
    # a wall mount moved straight back along its view (never forward, never sideways)
    plain = simulate_logs("paper", seed=4, duration_s=30.0).calib.truth
    moved = 0
    for a, b, w in zip(plain, sim.calib.truth, wall, strict=True):
        if not w:
            np.testing.assert_array_equal(a.position_m[:2], b.position_m[:2])
            continue
        yaw = np.radians(frames.ypr_deg_from_rot(a.R_world_sensor)[0])
        look, d = np.array([np.cos(yaw), np.sin(yaw)]), b.position_m[:2] - a.position_m[:2]
        assert abs(look[0] * d[1] - look[1] * d[0]) < 1e-9 and d @ look <= 1e-9
        moved += np.linalg.norm(d) > 0.1
    assert moved >= 1                                         # the check is not only of unmoved mounts
    with pytest.raises(Exception, match="0 < min <= max"):
        Scenario().resolve(sensor_height_range_m=[3.0, 2.0])


def test_per_sensor_heads_differ_and_are_recorded():
    sim = simulate_logs("paper", seed=5, duration_s=30.0, per_sensor_head=True)
    models = sim.calib.meta.notes["simulated"]["truth"]["head_point"]
    assert len(models) == 10 and len(set(models.values())) > 3
    heads = sensor_head_models(sim.scenario, 10)
    assert [m.head_vertical_bias_m for m in heads] == [sim.scenario.head_vertical_bias_m] * 10
