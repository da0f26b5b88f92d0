"""ROS inputs: rostopic echo -p CSV of /amcl_pose, ROS 2 bag (real TurtleBot 4 drive), ROS 1 bag."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pedcal.errors import PedcalInputError
from pedcal.io.logdir import read_table
from pedcal.io.ros import import_bag, read_bag, read_rostopic_amcl_csv
from pedcal.model import ODOMETRY_COLUMNS, ROBOT_COLUMNS
from tests.conftest import assert_refused_for_what_it_is


def test_rostopic_amcl_csv_real_file(shared_data):
    path = shared_data / "amcl_uf_retail" / "amcldata.txt"
    robot = read_rostopic_amcl_csv(path)
    assert list(robot.columns) == list(ROBOT_COLUMNS)
    assert len(robot) == 171
    # First data row of the file, as text:
    # stamp 1616790898067856789, x -2.75719687795, y -0.097601933199, q = (0, 0, 0.998372875965,
    # 0.0570228071759), covariance0 0.0712466169579, covariance1 -0.00327444398329,
    # covariance7 0.00904397566664, covariance35 0.0348277739631.
    r0 = robot.iloc[0]
    assert r0["t"] == pytest.approx(1616790898.067856789, abs=1e-6)
    assert r0["x"] == -2.75719687795 and r0["y"] == -0.097601933199
    assert r0["yaw"] == pytest.approx(2 * np.arctan2(0.998372875965, 0.0570228071759), abs=1e-12)
    assert (r0["cov_xx"], r0["cov_xy"], r0["cov_yy"], r0["cov_yawyaw"]) == (
        0.0712466169579, -0.00327444398329, 0.00904397566664, 0.0348277739631)
    assert r0["cov_xyaw"] == 0.0 and r0["cov_yyaw"] == 0.0
    # Header stamps increase, yaw wrapped, variances non-negative.
    assert (np.diff(robot["t"]) > 0).all()
    assert (np.abs(robot["yaw"]) <= np.pi).all()
    assert (robot[["cov_xx", "cov_yy", "cov_yawyaw"]] >= 0).all().all()


def test_rostopic_amcl_csv_falls_back_to_receive_time(tmp_path, shared_data):
    raw = pd.read_csv(shared_data / "amcl_uf_retail" / "amcldata.txt", dtype=str)
    raw.drop(columns=["field.header.stamp"]).to_csv(tmp_path / "a.csv", index=False)
    robot = read_rostopic_amcl_csv(tmp_path / "a.csv")
    assert robot["t"].iloc[0] == pytest.approx(1616790898.126369607, abs=1e-6)


def test_rostopic_amcl_csv_bad_input(tmp_path, shared_data):
    raw = pd.read_csv(shared_data / "amcl_uf_retail" / "amcldata.txt", dtype=str)
    bad = raw.copy()
    bad.loc[4, "field.pose.pose.position.x"] = "oops"
    bad.to_csv(tmp_path / "a.csv", index=False)
    with pytest.raises(PedcalInputError, match="oops") as ei:
        read_rostopic_amcl_csv(tmp_path / "a.csv")
    assert (ei.value.row, ei.value.column) == (4, "field.pose.pose.position.x")
    raw.drop(columns=["field.pose.covariance35"]).to_csv(tmp_path / "b.csv", index=False)
    with pytest.raises(PedcalInputError, match="covariance35"):
        read_rostopic_amcl_csv(tmp_path / "b.csv")


@pytest.mark.parametrize("what,match", [("missing", "rostopic CSV not found"),
                                        ("folder", "is a directory, expected a rostopic CSV")])
def test_rostopic_amcl_csv_path_that_is_no_regular_file_is_named_for_what_it_is(tmp_path, what, match):
    assert_refused_for_what_it_is(read_rostopic_amcl_csv, tmp_path / "amcl.csv", what, match)


def test_ros2_bag_odometry(tmp_path, shared_data):
    bag = shared_data / "turtlebot4_ros2_bag"
    with pytest.raises(PedcalInputError, match="no localization in the bag"):
        read_bag(bag)                       # the drive has no localization (only odom -> base_link)
    tables = read_bag(bag, require_localization=False)
    assert tables.robot is None
    assert "no /tf chain 'map' -> 'base_link'" in tables.missing
    odo = tables.odometry
    assert list(odo.columns) == list(ODOMETRY_COLUMNS) and len(odo) == 920
    assert odo["t"].iloc[0] == pytest.approx(1663967375.744427509, abs=1e-6)   # header stamp
    assert odo["x"].iloc[0] == pytest.approx(6.539614677429199)
    # A TurtleBot drives below 0.5 m/s.
    speed = np.hypot(np.diff(odo["x"]), np.diff(odo["y"])) / np.diff(odo["t"])
    assert np.median(speed[np.isfinite(speed)]) < 0.5
    # The .db3 file names the same bag.
    assert len(read_bag(next(bag.glob("*.db3")), require_localization=False).odometry) == 920

    # Without localization the import is refused (calibrate would need robot.csv) and writes nothing.
    with pytest.raises(PedcalInputError, match="no localization in the bag"):
        import_bag(bag, tmp_path / "log")
    assert not (tmp_path / "log").exists()
    # Taking the odom frame as the map: robot.csv from the Odometry topic in that frame.
    written = import_bag(bag, tmp_path / "log", map_frame="odom", pose_sigma=(0.05, 0.03))
    assert written == {tmp_path / "log" / "robot.csv": 920}
    back = read_table(tmp_path / "log" / "robot.csv", ROBOT_COLUMNS)
    assert (np.diff(back["t"]) > 0).all()
    np.testing.assert_allclose(back["cov_xx"], 0.05 ** 2)


def test_ros2_bag_bad_topics(shared_data):
    bag = shared_data / "turtlebot4_ros2_bag"
    with pytest.raises(PedcalInputError, match=r"topic /amcl_pose not in the bag; topics: .*/odom \(nav_msgs"):
        read_bag(bag, amcl_topic="/amcl_pose")
    with pytest.raises(PedcalInputError, match="is sensor_msgs/msg/LaserScan, expected nav_msgs/msg/Odometry"):
        read_bag(bag, odom_topic="/scan")


def write_ros1_bag(path, poses, topics=("/amcl_pose",)):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    PWCS = ts.types["geometry_msgs/msg/PoseWithCovarianceStamped"]
    PWC, Pose = ts.types["geometry_msgs/msg/PoseWithCovariance"], ts.types["geometry_msgs/msg/Pose"]
    Point, Quat = ts.types["geometry_msgs/msg/Point"], ts.types["geometry_msgs/msg/Quaternion"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    with Writer(path) as w:
        for topic in topics:
            conn = w.add_connection(topic, PWCS.__msgtype__, typestore=ts)
            for i, (t, x, y, yaw, cov) in enumerate(poses):
                sec, nsec = int(t), int(round((t - int(t)) * 1e9))
                msg = PWCS(Header(i, Time(sec, nsec), "map"),
                           PWC(Pose(Point(x, y, 0.0), Quat(0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))), cov))
                w.write(conn, sec * 10**9 + nsec + 5_000_000, ts.serialize_ros1(msg, PWCS.__msgtype__))


def test_ros1_bag_amcl_round_trip(tmp_path):
    rng = np.random.default_rng(11)
    n = 25
    t = 1_700_000_000 + np.cumsum(rng.uniform(0.1, 0.5, n))
    x, y, yaw = rng.normal(size=n), rng.normal(size=n), rng.uniform(-3, 3, n)
    covs = []
    for _ in range(n):
        c = np.zeros((6, 6))
        a = rng.normal(size=(3, 3))
        c[np.ix_([0, 1, 5], [0, 1, 5])] = a @ a.T
        covs.append(c.reshape(36))
    write_ros1_bag(tmp_path / "amcl.bag", list(zip(t, x, y, yaw, covs, strict=True)))
    robot = read_bag(tmp_path / "amcl.bag").robot
    assert len(robot) == n
    np.testing.assert_allclose(robot["t"], t, atol=2e-6)
    np.testing.assert_allclose(robot[["x", "y"]].to_numpy(), np.column_stack([x, y]), atol=0)
    np.testing.assert_allclose(robot["yaw"], yaw, atol=1e-12)
    c = np.stack(covs).reshape(n, 6, 6)
    np.testing.assert_array_equal(robot["cov_xyaw"], c[:, 0, 5])
    np.testing.assert_array_equal(robot["cov_yyaw"], c[:, 1, 5])
    np.testing.assert_array_equal(robot["cov_yawyaw"], c[:, 5, 5])
    written = import_bag(tmp_path / "amcl.bag", tmp_path / "out")
    assert written == {tmp_path / "out" / "robot.csv": n}


def test_ros1_bag_ambiguous_and_missing(tmp_path):
    pose = [(1.0, 0.0, 0.0, 0.0, np.eye(6).reshape(36))]
    write_ros1_bag(tmp_path / "two.bag", pose, topics=("/amcl_pose", "/pose"))
    with pytest.raises(PedcalInputError, match="several geometry_msgs/msg/PoseWithCovarianceStamped topics"):
        read_bag(tmp_path / "two.bag")
    assert len(read_bag(tmp_path / "two.bag", amcl_topic="/pose").robot) == 1
    with pytest.raises(PedcalInputError, match="bag not found"):
        read_bag(tmp_path / "nope.bag")
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    with pytest.raises(PedcalInputError, match="cannot open"):
        read_bag(tmp_path / "junk.bag")


def test_rostopic_csv_not_utf8_and_empty_file_are_named(tmp_path):
    rows = [b"%time,field.header.seq,field.pose.pose.position.x\n"] + \
        [f"{1616790898126369607 + i * 10 ** 8},{i},{0.1 * i}\n".encode() for i in range(3000)]
    rows[2500] = rows[2500].replace(b",", b",\xe9", 1)
    data = b"".join(rows)
    p = tmp_path / "amcl.txt"
    p.write_bytes(data)
    with pytest.raises(PedcalInputError, match=rf"not UTF-8 text \(byte 0xe9 on line 2501, at offset "
                                               rf"{data.index(bytes([0xe9]))}\): not a rostopic echo -p CSV"):
        import_bag(p, tmp_path / "log")
    p.write_bytes(b"")
    with pytest.raises(PedcalInputError, match="empty file, expected a ROS bag or a rostopic echo -p CSV"):
        import_bag(p, tmp_path / "log")
    assert not (tmp_path / "log").exists()
