"""Picking out the robot's observations: a robot driving a figure-eight under three ceiling
sensors, a pedestrian walking 0.7 m beside it, other walkers, short false tracks, a track
swap and a tracker latency, all built here with known truth."""

import numpy as np
import pandas as pd
import pytest

from pedcal.calib.association import associate_robot, estimate_latency, score_association
from pedcal.calib.closedform import fit_rigid
from pedcal.calib.common import head_world, robot_head_at
from pedcal.errors import PedcalInputError
from pedcal.frames import rotation_angle_deg
from pedcal.model import ROBOT_COLUMNS, Log, Meta, SensorExtrinsics, SensorNetwork

HEAD_M = 1.35
PEDESTRIAN_HEAD_M = 1.70
# aim points on the head plane: the figure-eight's crossing and its two lobes
AIMS = {"s0": (0.0, 0.0, 30.0), "s1": (2.8, 1.1, 200.0), "s2": (-2.8, -1.1, 20.0)}
INSTALL_ERRORS = {"s0": ([0.6, -0.5, 0.3], [8.0, -6.0, 5.0]),
                  "s1": ([-0.7, 0.4, -0.2], [-10.0, 5.0, 7.0]),
                  "s2": ([0.3, 0.8, 0.1], [12.0, 4.0, -6.0])}


def _truth_sensors():
    sensors = []
    for sid, (ax, ay, yaw_deg) in AIMS.items():
        yaw = np.radians(yaw_deg)
        # 45 deg down from 2.6 m: the optical axis meets the head plane 1.25 m ahead
        d = 2.6 - HEAD_M
        sensors.append(SensorExtrinsics(sid, [ax - d * np.cos(yaw), ay - d * np.sin(yaw), 2.6],
                                        [yaw_deg, 45.0, 0.0]))
    return SensorNetwork(sensors)


def _installed(truth):
    return SensorNetwork([SensorExtrinsics(s.id, s.position_m + INSTALL_ERRORS[s.id][0],
                                           s.ypr_deg + INSTALL_ERRORS[s.id][1]) for s in truth])


def _visible(sensor, p_world, half_angle_deg=40.0):
    p = sensor.to_sensor(p_world)
    cos = p[:, 0] / np.linalg.norm(p, axis=1)
    return cos > np.cos(np.radians(half_angle_deg))


def _tracks(visible):
    """Run ids of consecutive visible samples (-1 where invisible)."""
    edges = np.diff(np.r_[False, visible].astype(int))
    return np.where(visible, np.cumsum(edges == 1) - 1, -1)


def make_log(*, seed=0, noise=True, latency_s=0.2, pedestrian=True, false_tracks=True, swap=True,
             walkers=3):
    """Synthetic log with known truth. Returns (log, extra) with the rows of interest."""
    rng = np.random.default_rng(seed)
    rate_hz, duration_s = 10.0, 80.0
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    u = 2.0 * np.pi * 2.0 * t / duration_s              # two laps of a figure-eight
    x, y = 3.0 * np.sin(u), 1.5 * np.sin(2.0 * u)
    yaw = np.arctan2(np.gradient(y), np.gradient(x))
    truth_robot = pd.DataFrame({"t": t, "x": x, "y": y, "yaw": yaw})
    # AMCL: truth plus a slowly varying (time-correlated) error of a few cm
    amcl_sigma = 0.03 if noise else 0.0
    kernel = np.ones(20) / np.sqrt(20)
    err = np.column_stack([np.convolve(rng.normal(0, amcl_sigma, len(t) + 19), kernel, "valid")
                           for _ in range(2)])
    robot = pd.DataFrame({"t": t, "x": x + err[:, 0], "y": y + err[:, 1], "yaw": yaw})
    for c in ROBOT_COLUMNS[4:]:
        robot[c] = 0.0025 if c in ("cov_xx", "cov_yy") else (0.01 if c == "cov_yawyaw" else 0.0)
    truth = _truth_sensors()
    installed = _installed(truth)
    head_true = head_world(truth_robot[["x", "y", "yaw"]].to_numpy(), [0, 0, HEAD_M])
    obs_sigma = 0.02 if noise else 0.0

    people = []   # (who, times, world points)
    people.append(("robot", t, head_true))
    if pedestrian:
        # walks beside the robot, 0.7 m to its left where it starts, copying its every move
        # (the worst case: the same path shifted, which a per-segment fit cannot tell apart)
        left = 0.7 * np.array([-np.sin(yaw[0]), np.cos(yaw[0]), 0.0])
        m = t < 14.0
        people.append(("p_beside", t[m], head_true[m] + left + [0, 0, PEDESTRIAN_HEAD_M - HEAD_M]))
    for k in range(walkers):
        t0 = rng.uniform(0, duration_s - 20)
        tw = t[(t >= t0) & (t < t0 + 20)]
        start = rng.uniform(-4, 4, 2)
        heading = rng.uniform(0, 2 * np.pi)
        path = start + np.outer(tw - t0, 0.8 * np.array([np.cos(heading), np.sin(heading)]))
        people.append((f"w{k}", tw, np.column_stack([path, np.full(len(tw), rng.uniform(1.5, 1.85))])))

    rows = []   # t, sensor, track, world xyz (installed), who
    next_track = 100
    for s_true in truth:
        s_inst = installed[s_true.id]
        for who, tw, pw in people:
            vis = _visible(s_true, pw)
            runs = _tracks(vis)
            for r in range(runs.max() + 1):
                m = runs == r
                p_sensor = s_true.to_sensor(pw[m]) + rng.normal(0, obs_sigma, (m.sum(), 3))
                world = s_inst.to_world(p_sensor)
                for ti, wi in zip(tw[m] + latency_s, world, strict=True):
                    rows.append((ti, s_true.id, next_track, *wi, who))
                next_track += 1
        if false_tracks:
            for _ in range(4):   # short tracks of nothing, anywhere in view
                n = int(rng.integers(2, 6))
                p_sensor = np.array([2.0, 0.0, 0.0]) + rng.normal(0, 0.5, 3) + rng.normal(0, 0.02, (n, 3))
                world = s_inst.to_world(p_sensor)
                t0 = rng.uniform(0, duration_s - 1)
                for i, wi in enumerate(world):
                    rows.append((t0 + i / rate_hz, s_true.id, next_track, *wi, "false"))
                next_track += 1
    obs = pd.DataFrame(rows, columns=["t", "sensor", "track", "x", "y", "z", "who"])
    extra = {}
    if swap:
        # s2's second robot pass: at mid-pass the tracker hands the robot's track id to a walker
        # that then leaves in another direction; the robot continues under a new id
        r2 = obs[(obs.sensor == "s2") & (obs.who == "robot")]
        passes = r2.groupby("track")["t"].min().sort_values()
        track = passes.index[-1]
        pass_rows = r2[r2.track == track].sort_values("t")
        mid = pass_rows.index[len(pass_rows) // 2:]
        obs.loc[mid, "track"] = next_track                 # robot continues under a new id
        t_sw = obs.loc[mid, "t"].to_numpy()
        s_true, s_inst = truth["s2"], installed["s2"]
        start = s_true.to_world(np.array([[1.8, 0.0, 0.0]]))[0]
        away = start[:2] + np.outer(t_sw - t_sw[0], [0.0, 0.9])
        pw = np.column_stack([away, np.full(len(t_sw), 1.75)])
        world = s_inst.to_world(s_true.to_sensor(pw) + rng.normal(0, obs_sigma, (len(t_sw), 3)))
        swapped = pd.DataFrame({"t": t_sw, "sensor": "s2", "track": track, "x": world[:, 0],
                                "y": world[:, 1], "z": world[:, 2], "who": "p_swap"})
        obs = pd.concat([obs, swapped], ignore_index=True)
        extra["swap_track"] = track
    obs = obs.sample(frac=1.0, random_state=seed).reset_index(drop=True)   # file order is arbitrary
    truth_obs = pd.DataFrame({"row": np.arange(len(obs)), "who": obs["who"].to_numpy()})
    log = Log(sensors=installed, robot=robot, observations=obs.drop(columns="who"), meta=Meta(),
              truth=truth, truth_robot=truth_robot, truth_observations=truth_obs)
    return log, extra


@pytest.fixture(scope="module")
def busy():
    log, extra = make_log()
    return log, extra, associate_robot(log)


def test_sensor_frame_points_handed_in_give_the_same_association(busy):
    # the caller's log.observation_points_sensor() (read once per calibration) in place of the
    # association's own reading: the same robot observations and latency; other points are used
    log, _, res = busy
    p = log.observation_points_sensor()
    given = associate_robot(log, p_sensor=p)
    assert np.array_equal(given.is_robot, res.is_robot) and given.latency_s == res.latency_s
    assert np.array_equal(p, log.observation_points_sensor())          # (read, not changed)
    moved = associate_robot(log, p_sensor=p + np.array([0.0, 0.0, 5.0]))   # (every point 5 m off)
    assert not np.array_equal(moved.is_robot, res.is_robot)


def test_picks_out_the_robot_among_pedestrians_false_tracks_and_a_swap(busy):
    log, _, res = busy
    score = score_association(log, res.is_robot)
    assert score["precision"] >= 0.99
    assert score["recall"] >= 0.97


def test_pedestrian_walking_beside_the_robot_is_rejected(busy):
    log, _, res = busy
    who = log.truth_observations["who"].to_numpy()
    beside = who == "p_beside"
    assert beside.sum() > 80                      # it was seen, in parallel with the robot
    assert not res.is_robot[beside].any()
    # on its own, each of its segments fits a plausible transform about as well as the robot:
    # only the transform shared with the sensor's other robot passes rejects it
    p_sensor = log.observation_points_sensor()
    t_obs = log.observations["t"].to_numpy()
    for (sid, _), rows in log.observations[beside].groupby(["sensor", "track"]).groups.items():
        if len(rows) < 20:
            continue
        q = robot_head_at(log, t_obs[rows] - res.latency_s)
        R, t = fit_rigid(p_sensor[rows], q)
        rms_m = np.sqrt(np.mean(np.sum((p_sensor[rows] @ R.T + t - q) ** 2, axis=1)))
        assert rms_m < 0.1
        assert 0.5 < np.linalg.norm(t - log.truth[sid].position_m) < 1.2   # a shifted transform


def test_track_swap_keeps_only_the_robot_part(busy):
    log, extra, res = busy
    who = log.truth_observations["who"].to_numpy()
    swapped_track = (log.observations["sensor"] == "s2").to_numpy() & (
        log.observations["track"] == extra["swap_track"]).to_numpy()
    assert res.is_robot[swapped_track & (who == "robot")].mean() >= 0.8
    assert not res.is_robot[swapped_track & (who == "p_swap")].any()
    seg = res.segments[(res.segments.sensor == "s2") & (res.segments.track == str(extra["swap_track"]))]
    assert seg["robot"].tolist() == ["part"]


def test_false_tracks_are_rejected(busy):
    log, _, res = busy
    assert not res.is_robot[log.truth_observations["who"].to_numpy() == "false"].any()


def test_latency_and_consensus_transforms_near_truth(busy):
    log, _, res = busy
    assert res.latency_s == pytest.approx(0.2, abs=0.03)
    for s in log.truth:
        est = res.extrinsics[s.id]
        assert est.status == "ok"
        assert np.linalg.norm(est.position_m - s.position_m) < 0.06
        assert rotation_angle_deg(est.R_world_sensor, s.R_world_sensor) < 1.5


def test_estimate_latency_from_true_association():
    log, _ = make_log(noise=False, latency_s=-0.15, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    truth_mask = log.truth_observations["who"].to_numpy() == "robot"
    assert estimate_latency(log, truth_mask) == pytest.approx(-0.15, abs=1e-3)


def test_sensor_that_never_saw_the_robot_keeps_installed_pose():
    log, _ = make_log(pedestrian=False, swap=False)
    who = log.truth_observations["who"].to_numpy()
    drop = (who == "robot") & (log.observations["sensor"] == "s1").to_numpy()
    keep = np.flatnonzero(~drop)
    log.observations = log.observations.iloc[keep].reset_index(drop=True)
    log.truth_observations = pd.DataFrame({"row": np.arange(len(keep)), "who": who[keep]})
    res = associate_robot(log)
    s1 = res.extrinsics["s1"]
    assert s1.status == "no-data"
    np.testing.assert_allclose(s1.position_m, log.sensors["s1"].position_m)
    assert not res.is_robot[(log.observations["sensor"] == "s1").to_numpy()].any()
    assert score_association(log, res.is_robot)["precision"] >= 0.99


def test_unknown_sensor_names_row_and_column():
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    log.observations.loc[7, "sensor"] = "s9"
    with pytest.raises(PedcalInputError) as e:
        associate_robot(log)
    assert e.value.row == 7 and e.value.column == "sensor" and "s9" in str(e.value)


def test_score_needs_truth_and_one_entry_per_row():
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    with pytest.raises(PedcalInputError, match="expected one per observation"):
        score_association(log, np.ones(3, bool))
    log.truth_observations = None
    with pytest.raises(PedcalInputError, match="truth_observations"):
        score_association(log, np.ones(len(log.observations), bool))


def test_unknown_parameter_is_refused():
    log, _ = make_log(noise=False, pedestrian=False, false_tracks=False, swap=False, walkers=0)
    with pytest.raises(TypeError, match="inlier_mm"):
        associate_robot(log, inlier_mm=3)


def test_companion_replacing_the_robot_is_not_taken_for_it():
    # seed 1: for half of the run the trackers follow a person 0.7 m beside the robot instead of
    # it; on one sensor that person has more tracked seconds than the robot's own passes, but
    # it needs the sensor 0.7 m sideways and a head-height higher than installed
    from pedcal.sim import simulate_logs

    sim = simulate_logs("paper", seed=1, companion_fraction=0.5, companion_replaces_robot=True)
    who = sim.calib.truth_observations["who"].astype(str).to_numpy()
    assert (who == "companion").sum() > 0.15 * (who == "robot").sum()
    res = associate_robot(sim.calib)
    score = score_association(sim.calib, res.is_robot)
    assert score["precision"] > 0.99 and score["recall"] > 0.98
    assert not (res.is_robot & (who == "companion")).any()


def test_pooled_rigid_sse_is_the_fits_residuals():
    # per group the optimal rigid fit's squared residuals, summed: against the fit made and its
    # residuals formed, for rotated and shifted noisy copies, a mirrored group (the determinant's
    # sign) and a leading axis of head-point sets
    from pedcal.calib.association import moments, pooled_rigid_sse, rigid_from_moments

    rng = np.random.default_rng(3)
    sizes = [3, 7, 40]
    p = rng.normal(size=(sum(sizes), 3)) * [2.0, 1.0, 0.3]
    bounds = np.r_[0, np.cumsum(sizes)].tolist()
    q = np.zeros((4, len(p), 3))
    for L in range(4):
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            R *= np.sign(np.linalg.det(R))
            if L == 3 and b - a == 40:
                R = R @ np.diag([1.0, 1.0, -1.0])          # a mirror no rotation reaches
            q[L, a:b] = p[a:b] @ R.T + rng.normal(size=3) * 5.0 + rng.normal(scale=0.05, size=(b - a, 3))
    got = pooled_rigid_sse(p, bounds, q)
    assert got.shape == (4,)
    for L in range(4):
        want = 0.0
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            R, t = rigid_from_moments(*moments(p[a:b], q[L, a:b]))
            want += float(np.sum((p[a:b] @ R.T + t - q[L, a:b]) ** 2))
        assert got[L] == pytest.approx(want, rel=1e-9, abs=1e-12)
    assert got[3] > 10 * got[0]                           # the mirrored group does not fit
    assert pooled_rigid_sse(p, bounds, q[0]).shape == ()
    # the groups' SVDs in one call: the values of a call per group, summed in the groups' order,
    # to the bit
    alone = np.zeros(4)
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        alone += pooled_rigid_sse(p[a:b], [0, b - a], q[:, a:b])
    np.testing.assert_array_equal(got, alone)


def test_pooled_rigid_sse_of_no_group_is_zero():
    from pedcal.calib.association import pooled_rigid_sse

    rng = np.random.default_rng(5)
    got = pooled_rigid_sse(rng.normal(size=(6, 3)), [0], rng.normal(size=(2, 4, 6, 3)))
    np.testing.assert_array_equal(got, np.zeros((2, 4)))


def test_segment_table_medians_are_each_segments():
    # segments of odd and even length, in scrambled order, an unexplained (infinite) residual
    from pedcal.calib.association import DEFAULT_PARAMS, _segment_columns, _segment_table, _SensorRows

    rng = np.random.default_rng(5)
    codes = np.repeat([2, 0, 1, 3], [5, 4, 1, 2])
    n = len(codes)
    sd = _SensorRows("s1", np.arange(n), rng.uniform(0, 10, n), codes, np.array([f"k{c}" for c in codes]),
                     rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), np.ones(n, bool))
    r = rng.uniform(0.0, 1.0, n)
    r[3] = np.inf
    cols = _segment_columns(sd, r, r < 0.5, np.full(len(sd.seg_start), "no", dtype=object), DEFAULT_PARAMS)
    want = [np.median(r[a:b]) for a, b in zip(sd.seg_start, sd.seg_end, strict=True)]
    assert np.array_equal(cols["median_residual_m"], want)
    table = _segment_table([cols, cols])
    assert len(table) == 2 * len(sd.seg_start) and list(table["sensor"].unique()) == ["s1"]
    assert len(_segment_table([])) == 0
