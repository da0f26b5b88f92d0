"""ROS inputs converted to the log format: ``rostopic echo -p`` CSV of /amcl_pose, and ROS 1 / ROS 2
bags (through ``rosbags``) holding PoseWithCovarianceStamped (-> robot.csv) and Odometry
(-> odometry.csv). Times are the messages' header stamps, in seconds.

AMCL's covariance is the 6x6 row-major matrix over (x, y, z, roll, pitch, yaw); robot.csv keeps
the upper triangle of its (x, y, yaw) block: indices 0, 1, 5, 7, 11, 35.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pedcal.errors import PedcalInputError
from pedcal.io.logdir import parse_float_column, write_table
from pedcal.model import ODOMETRY_COLUMNS, ROBOT_COLUMNS

AMCL_MSGTYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
ODOM_MSGTYPE = "nav_msgs/msg/Odometry"
# robot.csv covariance column -> index in the 6x6 row-major (x, y, z, roll, pitch, yaw) matrix.
COVARIANCE_INDEX = {"cov_xx": 0, "cov_xy": 1, "cov_xyaw": 5, "cov_yy": 7, "cov_yyaw": 11, "cov_yawyaw": 35}
NS_PER_S = 1_000_000_000


def yaw_from_quaternions(q_xyzw: np.ndarray, path: Path | str, column: str = "orientation") -> np.ndarray:
    """Heading (rad) of each quaternion (x, y, z, w): the Z angle of the intrinsic Z-Y-X Euler angles."""
    q_xyzw = np.asarray(q_xyzw, dtype=float).reshape(-1, 4)
    norm = np.linalg.norm(q_xyzw, axis=1)
    bad = ~(norm > 1e-9)
    if bad.any():
        raise PedcalInputError("zero-length orientation quaternion", path=path, row=int(np.flatnonzero(bad)[0]),
                               column=column)
    return Rotation.from_quat(q_xyzw).as_euler("ZYX")[:, 0]


def seconds_from_ns(ns: np.ndarray) -> np.ndarray:
    """Integer nanoseconds -> float seconds, splitting first so no precision is lost before the sum."""
    ns = np.asarray(ns, dtype=np.int64)
    return (ns // NS_PER_S).astype(float) + (ns % NS_PER_S).astype(float) * 1e-9


def _parse_ns_column(values: pd.Series, path: Path, column: str) -> np.ndarray:
    text = values.astype(str).str.strip()
    bad = ~text.str.fullmatch(r"\d+").to_numpy(dtype=bool)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise PedcalInputError(f"expected an integer time stamp in nanoseconds, got {text.iloc[row]!r}",
                               path=path, row=row, column=column)
    return text.astype(np.int64).to_numpy()


# ----------------------------------------------------------------------------- rostopic echo -p CSV
def read_rostopic_amcl_csv(path: str | Path) -> pd.DataFrame:
    """``rostopic echo -p /amcl_pose`` CSV -> robot.csv columns (rows in file order)."""
    path = Path(path)
    if not path.is_file():
        raise PedcalInputError("file not found", path=path)
    try:
        raw = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise PedcalInputError(f"cannot read rostopic CSV: {e}", path=path) from None
    raw.columns = [c.strip() for c in raw.columns]
    stamp_col = next((c for c in ("field.header.stamp", "%time") if c in raw.columns), None)
    pose = "field.pose.pose."
    needed = [f"{pose}position.x", f"{pose}position.y"] + [f"{pose}orientation.{a}" for a in "xyzw"]
    needed += [f"field.pose.covariance{i}" for i in COVARIANCE_INDEX.values()]
    missing = ([] if stamp_col else ["field.header.stamp (or %time)"]) + [c for c in needed if c not in raw]
    if missing:
        raise PedcalInputError(f"not a rostopic echo -p CSV of PoseWithCovarianceStamped: missing column(s) "
                               f"{', '.join(missing)}", path=path, column=missing[0])
    if len(raw) == 0:
        raise PedcalInputError("no messages (no data rows)", path=path)
    num = {c: parse_float_column(raw[c], path, c) for c in needed}
    q = np.column_stack([num[f"{pose}orientation.{a}"] for a in "xyzw"])
    out = {"t": seconds_from_ns(_parse_ns_column(raw[stamp_col], path, stamp_col)),
           "x": num[f"{pose}position.x"], "y": num[f"{pose}position.y"],
           "yaw": yaw_from_quaternions(q, path, f"{pose}orientation")}
    for name, i in COVARIANCE_INDEX.items():
        out[name] = num[f"field.pose.covariance{i}"]
    return pd.DataFrame(out, columns=list(ROBOT_COLUMNS))


# ------------------------------------------------------------------------------------------- bags
def _open_reader(paths: list[Path]):
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    # ROS 2 sqlite bags carry no message definitions; the standard Humble ones cover ours.
    try:
        reader = AnyReader(paths, default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (AnyReaderError, OSError, ValueError) as e:
        raise PedcalInputError(f"cannot open as a ROS 1 or ROS 2 bag: {e}", path=paths[0]) from None
    return reader


def _bag_paths(path: Path) -> list[Path]:
    """AnyReader takes a ROS 1 .bag file or a ROS 2 bag folder; a .db3/.mcap file means its folder."""
    if not path.exists():
        raise PedcalInputError("bag not found", path=path)
    if path.is_file() and path.suffix in (".db3", ".mcap"):
        return [path.parent]
    return [path]


def _pick_topic(topics: dict[str, str], msgtype: str, requested: str | None, path: Path,
                option: str) -> str | None:
    listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
    if requested is not None:
        if requested not in topics:
            raise PedcalInputError(f"topic {requested} not in the bag; topics: {listing}", path=path)
        if topics[requested] != msgtype:
            raise PedcalInputError(f"topic {requested} is {topics[requested]}, expected {msgtype}", path=path)
        return requested
    found = sorted(t for t, ty in topics.items() if ty == msgtype)
    if len(found) > 1:
        raise PedcalInputError(f"several {msgtype} topics ({', '.join(found)}); choose one with {option}",
                               path=path)
    return found[0] if found else None


def _stamp_s(msg) -> float:
    return float(msg.header.stamp.sec) + float(msg.header.stamp.nanosec) * 1e-9


def _pose_rows(reader, connections, with_covariance: bool) -> pd.DataFrame:
    t, xy, q, cov = [], [], [], []
    for conn, _, raw in reader.messages(connections=connections):
        msg = reader.deserialize(raw, conn.msgtype)
        pose = msg.pose.pose
        t.append(_stamp_s(msg))
        xy.append((pose.position.x, pose.position.y))
        q.append((pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w))
        if with_covariance:
            cov.append(np.asarray(msg.pose.covariance, dtype=float)[list(COVARIANCE_INDEX.values())])
    xy_arr = np.asarray(xy, dtype=float).reshape(-1, 2)
    topic = connections[0].topic
    out = {"t": np.asarray(t, dtype=float), "x": xy_arr[:, 0], "y": xy_arr[:, 1],
           "yaw": yaw_from_quaternions(np.asarray(q, dtype=float), topic)}
    if with_covariance:
        cov_arr = np.asarray(cov, dtype=float).reshape(-1, len(COVARIANCE_INDEX))
        out.update({name: cov_arr[:, k] for k, name in enumerate(COVARIANCE_INDEX)})
    return pd.DataFrame(out, columns=list(ROBOT_COLUMNS if with_covariance else ODOMETRY_COLUMNS))


def read_bag(path: str | Path, amcl_topic: str | None = None, odom_topic: str | None = None) -> dict:
    """Read a ROS 1 .bag or ROS 2 bag (folder, .db3, .mcap).

    Returns ``{"robot": DataFrame | None, "odometry": DataFrame | None}`` with robot.csv columns from
    the PoseWithCovarianceStamped topic and odometry.csv columns from the nav_msgs Odometry topic,
    each picked by message type unless named. Rows are in bag (receive) order.
    """
    path = Path(path)
    reader = _open_reader(_bag_paths(path))
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        amcl = _pick_topic(topics, AMCL_MSGTYPE, amcl_topic, path, "--amcl-topic")
        odom = _pick_topic(topics, ODOM_MSGTYPE, odom_topic, path, "--odom-topic")
        if amcl is None and odom is None:
            listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
            raise PedcalInputError(f"no {AMCL_MSGTYPE} or {ODOM_MSGTYPE} topic in the bag; topics: {listing}",
                                   path=path)
        out: dict = {"robot": None, "odometry": None}
        for key, topic, with_cov in (("robot", amcl, True), ("odometry", odom, False)):
            if topic is not None:
                conns = [c for c in reader.connections if c.topic == topic]
                out[key] = _pose_rows(reader, conns, with_cov)
        return out
    finally:
        reader.close()


def import_bag(bag: str | Path, out_dir: str | Path, amcl_topic: str | None = None,
               odom_topic: str | None = None) -> dict[Path, int]:
    """Write robot.csv and/or odometry.csv (sorted by time) of ``bag`` into ``out_dir``, atomically.

    Returns {written file: number of rows}. A table whose messages repeat a time stamp is refused
    (robot.csv needs one pose per t).
    """
    tables = read_bag(bag, amcl_topic=amcl_topic, odom_topic=odom_topic)
    out_dir = Path(out_dir)
    written: dict[Path, int] = {}
    prepared = {}
    for name, df in tables.items():
        if df is None:
            continue
        if len(df) == 0:
            raise PedcalInputError(f"the {name} topic holds no messages", path=bag)
        df = df.sort_values("t", kind="stable").reset_index(drop=True)
        dup = df["t"].duplicated().to_numpy()
        if dup.any():
            t_dup = df["t"].iloc[int(np.flatnonzero(dup)[0])]
            raise PedcalInputError(f"{name} messages repeat the header stamp {t_dup!r}", path=bag)
        prepared[name] = df
    for name, df in prepared.items():   # validate everything before writing anything
        p = write_table(df, out_dir / f"{name}.csv")
        written[p] = len(df)
    return written
