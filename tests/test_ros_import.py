"""ROS in: bags written here with rosbags (ROS 1 and ROS 2) whose truth is known -> import-bag ->
read_log; and the shared real TurtleBot 4 bag and real AMCL CSV through the command line."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from pedcal.cli import EXIT_BAD_INPUT, main
from pedcal.errors import PedcalInputError
from pedcal.io import read_log
from pedcal.io.ros import (
    AMCL_MSGTYPE,
    MARKER_ARRAY_MSGTYPE,
    ODOM_MSGTYPE,
    PEOPLE_MSGTYPE,
    POSE_ARRAY_MSGTYPE,
    SPENCER_MSGTYPE,
    TF_MSGTYPE,
    import_bag,
    read_bag,
    read_rostopic_amcl_csv,
)
from pedcal.model import SensorExtrinsics, SensorNetwork
from tests.rosbag_fixture import BagWriter, header, make, point, pose, transform

T0 = 1_700_000_000.0
HEAD_TORSO = ((0.1, 0.0, 0.5), 0.3)         # base_link -> torso (m, yaw rad)
TORSO_HEAD = ((0.05, 0.02, 0.7), 0.0)       # torso -> head
SENSORS = SensorNetwork([SensorExtrinsics("s01", [1.0, 1.0, 2.6], [90.0, 45.0, 0.0]),
                         SensorExtrinsics("s02", [3.0, 0.5, 2.7], [60.0, 50.0, 2.0]),
                         SensorExtrinsics("s03", [5.0, 3.5, 2.5], [-90.0, 40.0, -1.0]),
                         SensorExtrinsics("s04", [7.0, 2.0, 2.6], [180.0, 55.0, 0.0])])


def robot_truth(t):
    s = t - T0
    return np.column_stack([1 + 0.3 * s, 2 + 0.5 * np.sin(0.2 * s), 0.3 + 0.05 * s])


def map_odom(t):
    s = t - T0
    return np.column_stack([0.5 + 0.01 * s, -0.2 + 0.005 * s, 0.1 + 0.002 * s])   # linear: interpolation exact


def compose2(a, b):
    """SE(2) a * b, rows (x, y, yaw)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([a[:, 0] + c * b[:, 0] - s * b[:, 1], a[:, 1] + s * b[:, 0] + c * b[:, 1],
                            a[:, 2] + b[:, 2]])


def inverse2(a):
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([-(c * a[:, 0] + s * a[:, 1]), s * a[:, 0] - c * a[:, 1], -a[:, 2]])


def people_truth(t):
    s = t - T0
    return {"a": np.column_stack([0.5 * s, np.full_like(s, 1.0), np.full_like(s, 1.7)]),
            "b": np.column_stack([8 - 0.4 * s, np.full_like(s, 3.0), np.full_like(s, 1.6)])}


def q_yaw(yaw):
    return (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))


def write_scene_bag(path, version: int, *, localization=True):
    t_fast = T0 + 0.1 * np.arange(200)
    t_amcl = T0 + 0.5 * np.arange(40)
    t_people = T0 + 0.2 * np.arange(50)
    with BagWriter(path, version) as w:
        ts = w.ts
        tr = lambda *a: transform(ts, *a)   # noqa: E731
        w.write("/tf_static", TF_MSGTYPE, T0, make(ts, TF_MSGTYPE, transforms=[
            tr(T0, "base_link", "torso", *HEAD_TORSO), tr(T0, "torso", "head", *TORSO_HEAD)]))
        if localization:
            for t, (x, y, yaw) in zip(t_amcl, robot_truth(t_amcl), strict=True):
                cov = np.zeros(36)
                cov[[0, 7, 35]] = (0.01, 0.02, 0.003)
                msg = make(ts, AMCL_MSGTYPE, header=header(ts, t, "map"),
                           pose=make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=pose(ts, (x, y, 0), q_yaw(yaw)),
                                     covariance=cov))
                w.write("/amcl_pose", AMCL_MSGTYPE, t + 0.01, msg)
            for t in T0 + np.arange(20.0):       # map -> odom at 1 Hz
                x, y, yaw = map_odom(np.array([t]))[0]
                w.write("/tf", TF_MSGTYPE, t, make(ts, TF_MSGTYPE, transforms=[tr(t, "map", "odom", (x, y, 0), yaw)]))
        odom_base = compose2(inverse2(map_odom(t_fast)), robot_truth(t_fast))
        for t, ob, mb in zip(t_fast, odom_base, robot_truth(t_fast), strict=True):
            w.write("/tf", TF_MSGTYPE, t, make(ts, TF_MSGTYPE, transforms=[tr(t, "odom", "base_link",
                                                                             (ob[0], ob[1], 0), ob[2])]))
            for topic, frame, p in (("/odom", "odom", ob), ("/robot_pose", "map", mb)):
                if topic == "/robot_pose" and not localization:
                    continue
                twc = make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=pose(ts, (p[0], p[1], 0), q_yaw(p[2])))
                w.write(topic, ODOM_MSGTYPE, t, make(ts, ODOM_MSGTYPE, header=header(ts, t, frame),
                                                     child_frame_id="base_link", pose=twc))
        truth = people_truth(t_people)
        for k, t in enumerate(t_people):
            pa, pb = truth["a"][k], truth["b"][k]
            people = [make(ts, "people_msgs/msg/Person", name=n, position=point(ts, p))
                      for n, p in (("a", pa), ("b", pb))]
            w.write("/s01/people", PEOPLE_MSGTYPE, t, make(ts, PEOPLE_MSGTYPE, header=header(ts, t, "map"),
                                                           people=people))
            local = [SENSORS["s02"].to_sensor(p[None])[0] for p in (pa, pb)]
            tracks = [make(ts, "spencer_tracking_msgs/msg/TrackedPerson", track_id=i,
                           pose=make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=pose(ts, p)))
                      for i, p in zip((7, 9), local, strict=True)]
            w.write("/s02/tracked", SPENCER_MSGTYPE, t, make(ts, SPENCER_MSGTYPE, header=header(ts, t, "s02_link"),
                                                             tracks=tracks))
            opt = [SENSORS["s03"].to_sensor(p[None])[0] for p in (pb, pa)]       # order varies: no identities
            opt = [(-p[1], -p[2], p[0]) for p in opt]                           # optical: z forward, x right, y down
            w.write("/s03/poses", POSE_ARRAY_MSGTYPE, t, make(ts, POSE_ARRAY_MSGTYPE,
                                                             header=header(ts, t, "s03_optical_frame"),
                                                             poses=[pose(ts, p) for p in opt]))
            markers = [make(ts, "visualization_msgs/msg/Marker", header=header(ts, t, "map"), ns="people", id=i,
                            action=0, pose=pose(ts, p)) for i, p in ((1, pa), (2, pb))]
            markers.append(make(ts, "visualization_msgs/msg/Marker", header=header(ts, t, "map"), ns="people",
                                id=3, action=2))                                  # DELETE: no detection
            w.write("/s04/markers", MARKER_ARRAY_MSGTYPE, t, make(ts, MARKER_ARRAY_MSGTYPE, markers=markers))
    return t_fast, t_amcl, t_people


def bag_path(tmp_path, version):
    return tmp_path / ("scene.bag" if version == 1 else "scene_ros2")


@pytest.fixture(params=[1, 2], ids=["ros1", "ros2"])
def scene(request, tmp_path):
    path = bag_path(tmp_path, request.param)
    return path, write_scene_bag(path, request.param)


def test_localization_sources(scene):
    path, (t_fast, t_amcl, _) = scene
    amcl = read_bag(path)                                        # auto: AMCL first
    assert amcl.sources["robot"].startswith("/amcl_pose")
    np.testing.assert_allclose(amcl.robot["t"], t_amcl, atol=1e-6)
    np.testing.assert_allclose(amcl.robot[["x", "y", "yaw"]], robot_truth(amcl.robot["t"].to_numpy()), atol=1e-9)
    np.testing.assert_allclose(amcl.robot[["cov_xx", "cov_yy", "cov_yawyaw"]], [[0.01, 0.02, 0.003]] * len(t_amcl))
    assert amcl.sources["odometry"].startswith("/odom ")        # the Odometry topic not in the map frame

    odo = read_bag(path, localization="odometry", pose_sigma=(0.04, 0.02))
    assert odo.sources["robot"].startswith("/robot_pose")
    np.testing.assert_allclose(odo.robot[["x", "y", "yaw"]], robot_truth(odo.robot["t"].to_numpy()), atol=1e-9)
    np.testing.assert_allclose(odo.robot["cov_yawyaw"], 0.02 ** 2)

    tf = read_bag(path, localization="tf", pose_sigma=(0.04, 0.02))
    assert tf.sources["robot"] == "/tf map -> base_link"
    # map -> odom (1 Hz) interpolated at the odom -> base_link stamps, composed: the true path
    inside = (t_fast >= T0) & (t_fast <= T0 + 19.0)
    np.testing.assert_allclose(tf.robot["t"], t_fast[inside], atol=1e-6)
    np.testing.assert_allclose(tf.robot[["x", "y", "yaw"]], robot_truth(tf.robot["t"].to_numpy()), atol=1e-6)

    with pytest.raises(PedcalInputError, match="topic /amcl_pose is geometry_msgs/msg/PoseWithCovarianceStamped, "
                                               "expected nav_msgs/msg/Odometry"):
        read_bag(path, localization="odometry", localization_topic="/amcl_pose")


def test_people_topics_into_observations(scene, tmp_path):
    path, (_, _, t_people) = scene
    sensors_yaml = tmp_path / "installed.yaml"
    from pedcal.io import write_sensors_yaml

    write_sensors_yaml(SENSORS, sensors_yaml)
    out = tmp_path / "log"
    code = main(["import-bag", str(path), "-o", str(out), "--sensors", str(sensors_yaml), "--head-frame", "head",
                 "--people", "/s01/people=s01", "--people", "/s02/tracked=s02", "--people", "/s03/poses=s03",
                 "--people", "/s04/markers=s04"])
    assert code == 0
    log = read_log(out)
    # head offset: base_link -> torso -> head from /tf_static
    (p1, y1), (p2, _) = HEAD_TORSO, TORSO_HEAD
    expected = np.asarray(p1) + Rotation.from_euler("z", y1).apply(p2)
    np.testing.assert_allclose(log.meta.head_offset_m, expected, atol=1e-12)
    obs = log.observations
    truth = people_truth(obs["t"].to_numpy())
    xyz = obs[["x", "y", "z"]].to_numpy()
    d = np.minimum(np.linalg.norm(xyz - truth["a"], axis=1), np.linalg.norm(xyz - truth["b"], axis=1))
    assert d.max() < 1e-9            # every frame's points back in the world, to rounding
    assert obs.groupby("sensor").size().to_dict() == {s: 2 * len(t_people) for s in SENSORS.ids}   # DELETE dropped
    assert set(obs.loc[obs["sensor"] == "s02", "track"]) == {"7", "9"}
    assert set(obs.loc[obs["sensor"] == "s04", "track"]) == {"people/1", "people/2"}
    # PoseArray: anonymous poses chained into one track per person
    s03 = obs[obs["sensor"] == "s03"]
    who = np.where(np.linalg.norm(s03[["x", "y", "z"]].to_numpy() - people_truth(s03["t"].to_numpy())["a"], axis=1)
                   < 1e-6, "a", "b")
    assert s03["track"].nunique() == 2
    assert pd.crosstab(s03["track"], who).gt(0).sum(axis=1).eq(1).all()
    assert (out / "sensors.yaml").is_file() and len(log.sensors) == 4


def test_sensor_frame_needs_installed_extrinsics(tmp_path):
    path = bag_path(tmp_path, 2)
    write_scene_bag(path, 2)
    with pytest.raises(PedcalInputError, match=r"frame 's02_link'.*sensor 's02'.*--sensors"):
        read_bag(path, people=["/s02/tracked=s02"])
    with pytest.raises(PedcalInputError, match="topic /odom is nav_msgs/msg/Odometry, expected one of"):
        read_bag(path, people=["/odom=s01"], sensors=SENSORS)


def test_bag_without_localization_exits_2(tmp_path, capsys):
    path = bag_path(tmp_path, 1)
    write_scene_bag(path, 1, localization=False)
    code = main(["import-bag", str(path), "-o", str(tmp_path / "log"), "--people", "/s01/people=s01"])
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT and "no localization in the bag" in err
    assert "PoseWithCovarianceStamped" in err and "/odom in 'odom'" in err and "'map' -> 'base_link'" in err
    assert not (tmp_path / "log").exists()


def test_read_bag_without_localization_raises_like_the_cli(tmp_path):
    path = bag_path(tmp_path, 2)
    write_scene_bag(path, 2, localization=False)
    with pytest.raises(PedcalInputError, match="no localization in the bag") as err:
        read_bag(path, people=["/s01/people=s01"], sensors=SENSORS)
    assert "'map' -> 'base_link'" in str(err.value) and err.value.path == str(path)
    tables = read_bag(path, people=["/s01/people=s01"], sensors=SENSORS, require_localization=False)
    assert tables.robot is None and "PoseWithCovarianceStamped" in tables.missing and len(tables.observations) > 0


def test_real_turtlebot_bag(shared_data, tmp_path, capsys):
    bag = shared_data / "turtlebot4_ros2_bag"
    code = main(["import-bag", str(bag), "-o", str(tmp_path / "none")])
    assert code == EXIT_BAD_INPUT and "no /tf chain 'map' -> 'base_link'" in capsys.readouterr().err
    # The drive's frame is odom: /tf odom -> base_link is the same path as /odom, stamp for stamp.
    tf = read_bag(bag, localization="tf", map_frame="odom", head_frame="oakd_lite_link")
    odo = read_bag(bag, map_frame="odom", localization="odometry")
    m = tf.robot.merge(odo.robot, on="t", suffixes=("_tf", "_odom"))
    assert len(m) == len(odo.robot) == 920
    np.testing.assert_allclose(m[["x_tf", "y_tf"]].to_numpy(), m[["x_odom", "y_odom"]].to_numpy(), atol=1e-9)
    assert np.abs(np.angle(np.exp(1j * (m["yaw_tf"] - m["yaw_odom"])))).max() < 1e-9
    # the camera sits on the robot's top plate: a few cm from the centre, 0.1-0.4 m up
    x, y, z = tf.head_offset_m
    assert abs(x) < 0.2 and abs(y) < 0.05 and 0.1 < z < 0.4
    code = main(["import-bag", str(bag), "-o", str(tmp_path / "log"), "--map-frame", "odom", "--localization", "tf",
                 "--head-frame", "oakd_lite_link", "--pose-sigma", "0.05", "2"])
    assert code == 0
    robot = pd.read_csv(tmp_path / "log" / "robot.csv")
    assert len(robot) == len(tf.robot) and np.allclose(robot["cov_yawyaw"], np.radians(2) ** 2)


def test_real_amcl_csv_through_import_bag(shared_data, tmp_path):
    path = shared_data / "amcl_uf_retail" / "amcldata.txt"
    assert main(["import-bag", str(path), "-o", str(tmp_path / "log")]) == 0
    robot = pd.read_csv(tmp_path / "log" / "robot.csv")
    direct = read_rostopic_amcl_csv(path).sort_values("t").reset_index(drop=True)
    pd.testing.assert_frame_equal(robot, direct, check_exact=True)


@pytest.mark.parametrize("version", [1, 2], ids=["ros1", "ros2"])
def test_simulated_log_through_a_bag_calibrates_alike(tmp_path, version):
    """A simulated log published as a deployment would (AMCL, wheel odometry, one people_msgs topic
    per ceiling sensor, one sensor reporting in its own frame) comes back through import-bag as the
    same tables, and calibrates to the same extrinsics."""
    import pedcal
    from tests.rosbag_fixture import BagWriter

    log = pedcal.simulate_logs("sparse", seed=1, duration_s=120).calib
    path = tmp_path / ("sim.bag" if version == 1 else "sim_ros2")
    local_sensor = log.sensors.ids[0]
    with BagWriter(path, version) as w:
        ts = w.ts
        for r in log.robot.itertuples():
            cov = np.zeros((6, 6))
            for (i, j), v in {(0, 0): r.cov_xx, (0, 1): r.cov_xy, (0, 5): r.cov_xyaw, (1, 1): r.cov_yy,
                              (1, 5): r.cov_yyaw, (5, 5): r.cov_yawyaw}.items():
                cov[i, j] = cov[j, i] = v
            msg = make(ts, AMCL_MSGTYPE, header=header(ts, r.t, "map"),
                       pose=make(ts, "geometry_msgs/msg/PoseWithCovariance",
                                 pose=pose(ts, (r.x, r.y, 0), q_yaw(r.yaw)), covariance=cov.reshape(36)))
            w.write("/amcl_pose", AMCL_MSGTYPE, r.t, msg)
        for r in log.odometry.itertuples():
            twc = make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=pose(ts, (r.x, r.y, 0), q_yaw(r.yaw)))
            w.write("/odom", ODOM_MSGTYPE, r.t, make(ts, ODOM_MSGTYPE, header=header(ts, r.t, "odom"),
                                                     pose=twc))
        obs = log.observations
        for (t, sid), g in obs.groupby(["t", "sensor"], sort=True):
            xyz = g[["x", "y", "z"]].to_numpy()
            frame = "map"
            if sid == local_sensor:
                xyz, frame = log.sensors[sid].to_sensor(xyz), f"{sid}_link"
            people = [make(ts, "people_msgs/msg/Person", name=str(k), position=point(ts, p))
                      for k, p in zip(g["track"], xyz, strict=True)]
            w.write(f"/{sid}/people", PEOPLE_MSGTYPE, t, make(ts, PEOPLE_MSGTYPE, header=header(ts, t, frame),
                                                             people=people))
    out = tmp_path / "log"
    import_bag(path, out, sensors=log.sensors, head_offset_m=log.meta.head_offset_m,
               people={f"/{s}/people": s for s in log.sensors.ids})
    back = read_log(out)
    ref = log.robot.sort_values("t").reset_index(drop=True)
    np.testing.assert_allclose(back.robot["t"], ref["t"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.robot[["x", "y"]], ref[["x", "y"]], rtol=0, atol=0)
    np.testing.assert_allclose(np.angle(np.exp(1j * (back.robot["yaw"] - ref["yaw"]))), 0, atol=1e-12)
    np.testing.assert_allclose(back.robot.iloc[:, 4:], ref.iloc[:, 4:], rtol=0, atol=0)
    assert len(back.odometry) == len(log.odometry)
    key = ["sensor", "track", "t"]
    a = back.observations.sort_values(key).reset_index(drop=True)
    b = log.observations.astype({"track": str}).sort_values(key).reset_index(drop=True)
    assert len(a) == len(b) and (a["sensor"] == b["sensor"]).all() and (a["track"] == b["track"]).all()
    np.testing.assert_allclose(a[["x", "y", "z"]], b[["x", "y", "z"]], rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.meta.head_offset_m, log.meta.head_offset_m)
    direct = pedcal.calibrate(log, method="closedform").network
    via_bag = pedcal.calibrate(back, method="closedform").network
    for s in direct:
        assert np.linalg.norm(via_bag[s.id].position_m - s.position_m) < 1e-3, s.id
        assert via_bag[s.id].status == s.status


def _write_amcl_pose(w, t: float, xyz) -> None:
    """One /amcl_pose message at ``t`` s: position ``xyz`` (m), heading 0, a fixed covariance."""
    cov = np.zeros(36)
    cov[[0, 7, 35]] = (0.01, 0.02, 0.003)
    w.write("/amcl_pose", AMCL_MSGTYPE, t, make(w.ts, AMCL_MSGTYPE, header=header(w.ts, t, "map"), pose=make(
        w.ts, "geometry_msgs/msg/PoseWithCovariance", pose=pose(w.ts, xyz), covariance=cov)))


def test_detections_and_poses_holding_nan_are_dropped_and_counted(tmp_path, caplog):
    """A tracker's message with a NaN position went into observations.csv as an empty cell: the
    import succeeded and the log it wrote could not be read."""
    path = tmp_path / "nan_ros2"
    with BagWriter(path, 2) as w:
        ts = w.ts
        for k in range(20):
            t = T0 + 0.5 * k
            _write_amcl_pose(w, t, (0.1 * k, 0.0, 0.0) if k != 11 else (np.nan, 0.0, 0.0))
            p = (0.1 * k, 1.0, 1.7) if k not in (3, 7) else (np.inf if k == 7 else np.nan, 1.0, 1.7)
            w.write("/people", PEOPLE_MSGTYPE, t, make(ts, PEOPLE_MSGTYPE, header=header(ts, t, "map"), people=[
                make(ts, "people_msgs/msg/Person", name="a", position=point(ts, p))]))
    out = tmp_path / "log"
    with caplog.at_level("WARNING"):
        written = import_bag(path, out, people=["/people=s01"], sensors=SENSORS)
    assert written[out / "robot.csv"] == 19 and written[out / "observations.csv"] == 18
    assert f"1 of 20 robot rows from /amcl_pose ({AMCL_MSGTYPE}) dropped: a NaN or infinite value (the first at " \
           f"t = {T0 + 5.5!r} s)" in caplog.text
    assert f"2 of 20 observations rows from /people ({PEOPLE_MSGTYPE}) as sensor s01 dropped" in caplog.text
    log = read_log(out)
    assert np.isfinite(log.observations[["x", "y", "z"]].to_numpy()).all() and len(log.robot) == 19


def test_a_bag_whose_every_amcl_pose_holds_nan_or_inf_is_refused_naming_the_topic(tmp_path):
    """Nothing would be left of the robot's track once its NaN rows are dropped: the import stops,
    naming the bag and the topic, and writes nothing."""
    path = tmp_path / "nan_ros2"
    with BagWriter(path, 2) as w:
        for k in range(4):
            _write_amcl_pose(w, T0 + 0.5 * k, (np.nan, 0.0, 0.0) if k % 2 else (0.1 * k, np.inf, 0.0))
    out = tmp_path / "log"
    with pytest.raises(PedcalInputError, match=re.escape(
            f"every one of the 4 robot rows from /amcl_pose ({AMCL_MSGTYPE}) holds a NaN or infinite value")) as ei:
        import_bag(path, out)
    assert ei.value.path == str(path)
    assert not out.exists()
