"""ROS inputs converted to the log format (LOG_FORMAT.md): ``rostopic echo -p`` CSV of /amcl_pose (or
any PoseWithCovariance-carrying topic), and ROS 1 / ROS 2 bags read through ``rosbags``.

From a bag (:func:`read_bag`, :func:`import_bag`, ``pedcal import-bag``):

- robot.csv, the localization, from one source (``localization=``): ``amcl`` a
  geometry_msgs/PoseWithCovarianceStamped topic (/amcl_pose); ``odometry`` a nav_msgs/Odometry
  topic whose header frame is the map frame (a localization filter's output); ``tf`` the /tf chain
  map -> base_link, composed and interpolated. ``auto`` takes the first present in that order.
- odometry.csv: a nav_msgs/Odometry topic in another frame (wheel odometry).
- meta.yaml ``head_offset``: the /tf (static) transform base_link -> a head frame, or given.
- observations.csv: people-tracker topics (people_msgs/People, spencer_tracking_msgs/
  TrackedPersons, geometry_msgs/PoseArray, visualization_msgs/Marker(Array)), one ceiling sensor
  per topic. Points in the map frame are kept; points in a sensor's own frame (x forward, y left,
  z up) or optical frame (z forward, x right, y down) are mapped into the world with that
  sensor's installed extrinsics (sensors.yaml), as the tracking system does (LOG_FORMAT.md).

Times are the messages' header stamps, in seconds. AMCL's covariance is the 6x6 row-major matrix
over (x, y, z, roll, pitch, yaw); robot.csv keeps the upper triangle of its (x, y, yaw) block:
indices 0, 1, 5, 7, 11, 35. A source without covariance (/tf, an Odometry with zero covariance)
gets the ``pose_sigma`` given, with a warning saying so.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pedcal.errors import PedcalInputError, show
from pedcal.io.atomic import write_text_atomic
from pedcal.io.inputs import not_utf8_error, regular_file
from pedcal.io.logdir import meta_yaml_text, parse_float_column, write_table
from pedcal.model import OBSERVATION_COLUMNS, ODOMETRY_COLUMNS, ROBOT_COLUMNS, Meta, SensorNetwork
from pedcal.options import check

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
    path = regular_file(path, "rostopic CSV")
    try:
        raw = pd.read_csv(path, dtype=str, keep_default_na=False)
    except UnicodeDecodeError as e:
        raise not_utf8_error(path, e, "not a rostopic echo -p CSV") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        raise PedcalInputError(f"cannot read rostopic CSV: {show(str(e).strip(), 160)[1:-1]}", path=path) from None
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
PEOPLE_MSGTYPE = "people_msgs/msg/People"
SPENCER_MSGTYPE = "spencer_tracking_msgs/msg/TrackedPersons"
POSE_ARRAY_MSGTYPE = "geometry_msgs/msg/PoseArray"
MARKER_MSGTYPE = "visualization_msgs/msg/Marker"
MARKER_ARRAY_MSGTYPE = "visualization_msgs/msg/MarkerArray"
TF_MSGTYPE = "tf2_msgs/msg/TFMessage"
PEOPLE_MSGTYPES = (PEOPLE_MSGTYPE, SPENCER_MSGTYPE, POSE_ARRAY_MSGTYPE, MARKER_MSGTYPE, MARKER_ARRAY_MSGTYPE)
LOCALIZATION_SOURCES = ("auto", "amcl", "odometry", "tf")
OBSERVATION_FRAMES = ("auto", "world", "sensor", "optical")
# Assumed 1-sigma of a localization without covariance (/tf, zero-covariance Odometry): AMCL's
# typical accuracy (~5 cm, ~2 deg; Kimoto et al.). Override with pose_sigma / --pose-sigma.
DEFAULT_POSE_SIGMA = (0.05, np.radians(2.0))
# PoseArray carries no identities: poses are chained into tracks by nearest neighbour within this
# gap (a person walks < 2 m/s, so at >= 5 Hz one step is < 0.4 m) and this time.
POSE_ARRAY_LINK_M = 0.5
POSE_ARRAY_LINK_S = 1.0
MARKER_DELETE_ACTIONS = (2, 3)        # visualization_msgs/Marker DELETE, DELETEALL

# Message definitions of the tracker packages outside the standard ROS distributions, registered
# so ROS 2 bags (which carry no definitions) can be read. ROS 1 bags embed their own.
CUSTOM_MSG_TEXT = {
    "people_msgs/msg/Person": "string name\ngeometry_msgs/Point position\ngeometry_msgs/Point velocity\n"
                              "float64 reliability\nstring[] tagnames\nstring[] tags\n",
    "people_msgs/msg/People": "std_msgs/Header header\npeople_msgs/Person[] people\n",
    "spencer_tracking_msgs/msg/TrackedPerson": "uint64 track_id\nbool is_occluded\nbool is_matched\n"
                                               "uint64 detection_id\nbuiltin_interfaces/Duration age\n"
                                               "geometry_msgs/PoseWithCovariance pose\n"
                                               "geometry_msgs/TwistWithCovariance twist\n",
    "spencer_tracking_msgs/msg/TrackedPersons": "std_msgs/Header header\n"
                                                "spencer_tracking_msgs/TrackedPerson[] tracks\n",
}


def register_custom_types(typestore) -> None:
    """Add people_msgs and spencer_tracking_msgs (CUSTOM_MSG_TEXT) to a rosbags typestore."""
    from rosbags.typesys import get_types_from_msg

    types = {}
    for name, text in CUSTOM_MSG_TEXT.items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)


def _open_reader(paths: list[Path]):
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    # ROS 2 sqlite bags carry no message definitions; the standard Humble ones and the tracker
    # packages' (CUSTOM_MSG_TEXT) cover ours.
    store = get_typestore(Stores.ROS2_HUMBLE)
    register_custom_types(store)
    try:
        reader = AnyReader(paths, default_typestore=store)
        reader.open()
    except (AnyReaderError, OSError, ValueError) as e:
        raise PedcalInputError(f"cannot open as a ROS 1 or ROS 2 bag: {e}", path=paths[0]) from None
    except Exception as e:       # noqa: BLE001 - damaged index or header bytes fail with other types too
        raise PedcalInputError(f"cannot open as a ROS 1 or ROS 2 bag (damaged?): {_brief(e)}", path=paths[0]) from None
    return reader


def _bag_paths(path: Path) -> list[Path]:
    """AnyReader takes a ROS 1 .bag file or a ROS 2 bag folder; a .db3/.mcap file means its folder."""
    if not path.exists():
        raise PedcalInputError("bag not found", path=path)
    if path.is_file() and path.suffix in (".db3", ".mcap"):
        return [path.parent]
    return [path]


def _listing(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"


def _pick_topic(topics: dict[str, str], msgtype: str | tuple[str, ...], requested: str | None, path: Path,
                option: str, candidates: list[str] | None = None) -> str | None:
    types = (msgtype,) if isinstance(msgtype, str) else msgtype
    if requested is not None:
        if requested not in topics:
            raise PedcalInputError(f"topic {requested} not in the bag; topics: {_listing(topics)}", path=path)
        if topics[requested] not in types:
            raise PedcalInputError(f"topic {requested} is {topics[requested]}, expected {' or '.join(types)}",
                                   path=path)
        return requested
    found = sorted(t for t, ty in topics.items() if ty in types) if candidates is None else sorted(candidates)
    if len(found) > 1:
        raise PedcalInputError(f"several {' or '.join(types)} topics ({', '.join(found)}); choose one with {option}",
                               path=path)
    return found[0] if found else None


def _stamp_s(stamp) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _messages(reader, topic: str):
    """(log time s, message) of one topic in bag order. A record the bag reader cannot read or a
    payload it cannot decode (a truncated or corrupted bag) raises PedcalInputError naming the
    topic and the message's index."""
    conns = [c for c in reader.connections if c.topic == topic]
    where = reader.paths[0] if getattr(reader, "paths", None) else None
    records = reader.messages(connections=conns)
    index = 0
    while True:
        try:
            conn, t_ns, raw = next(records)
        except StopIteration:
            return
        except Exception as e:   # noqa: BLE001 - the bag reader fails on damaged bytes with many types
            raise PedcalInputError(f"topic {topic}, message {index}: cannot read the bag record (truncated or "
                                   f"corrupt bag): {_brief(e)}", path=where) from None
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as e:   # noqa: BLE001 - idem, for the message's payload
            raise PedcalInputError(f"topic {topic}, message {index}: cannot decode its {conn.msgtype} payload "
                                   f"(truncated or corrupt): {_brief(e)}", path=where) from None
        yield t_ns * 1e-9, msg
        index += 1


def _brief(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    return show(f"{type(e).__name__}: {text}" if text else type(e).__name__, 160)[1:-1]


def _first_frame(reader, topic: str) -> str | None:
    for _, msg in _messages(reader, topic):
        return msg.header.frame_id.lstrip("/")
    return None


def _pose_rows(reader, topic: str, with_covariance: bool) -> pd.DataFrame:
    t, xy, q, cov = [], [], [], []
    for _, msg in _messages(reader, topic):
        pose = msg.pose.pose
        t.append(_stamp_s(msg.header.stamp))
        xy.append((pose.position.x, pose.position.y))
        q.append((pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w))
        if with_covariance:
            cov.append(np.asarray(msg.pose.covariance, dtype=float)[list(COVARIANCE_INDEX.values())])
    xy_arr = np.asarray(xy, dtype=float).reshape(-1, 2)
    out = {"t": np.asarray(t, dtype=float), "x": xy_arr[:, 0], "y": xy_arr[:, 1],
           "yaw": yaw_from_quaternions(np.asarray(q, dtype=float), topic)}
    if with_covariance:
        cov_arr = np.asarray(cov, dtype=float).reshape(-1, len(COVARIANCE_INDEX))
        out.update({name: cov_arr[:, k] for k, name in enumerate(COVARIANCE_INDEX)})
    return pd.DataFrame(out, columns=list(ROBOT_COLUMNS if with_covariance else ODOMETRY_COLUMNS))


def _fill_covariance(robot: pd.DataFrame, pose_sigma, source: str) -> pd.DataFrame:
    """Covariance columns of a source that gave none: the assumed ``pose_sigma`` (m, rad), said."""
    given = pose_sigma is not None
    sigma_m, sigma_yaw_rad = DEFAULT_POSE_SIGMA if pose_sigma is None else map(float, pose_sigma)
    if not given:
        logging.getLogger(__name__).warning(
            f"{source} carries no covariance; robot.csv gets an assumed sigma of {sigma_m:.3f} m and "
            f"{np.degrees(sigma_yaw_rad):.1f} deg (set it with --pose-sigma M DEG)")
    robot = robot.copy()
    for name in COVARIANCE_INDEX:
        robot[name] = 0.0
    robot["cov_xx"] = robot["cov_yy"] = sigma_m ** 2
    robot["cov_yawyaw"] = sigma_yaw_rad ** 2
    return robot[list(ROBOT_COLUMNS)]


# ----------------------------------------------------------------------------------------------- tf
@dataclass
class _Edge:
    """One parent -> child transform over time (static: one sample)."""

    t: list = field(default_factory=list)
    xyz: list = field(default_factory=list)
    q_xyzw: list = field(default_factory=list)
    static: bool = False


def _read_tf(reader, topics: dict[str, str]) -> dict[tuple[str, str], _Edge]:
    edges: dict[tuple[str, str], _Edge] = {}
    for topic in ("/tf", "/tf_static"):
        if topics.get(topic) != TF_MSGTYPE:
            continue
        for _, msg in _messages(reader, topic):
            for tr in msg.transforms:
                key = (tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/"))
                e = edges.setdefault(key, _Edge())
                e.static = e.static or topic == "/tf_static"
                r, tt = tr.transform.rotation, tr.transform.translation
                e.t.append(_stamp_s(tr.header.stamp))
                e.xyz.append((tt.x, tt.y, tt.z))
                e.q_xyzw.append((r.x, r.y, r.z, r.w))
    return edges


def _tf_chain(edges: dict[tuple[str, str], _Edge], source: str,
              target: str) -> list[tuple[tuple[str, str], bool]] | None:
    """Edges from ``source`` to ``target`` (breadth first over the tree, either direction);
    each (edge key, inverted)."""
    nbrs: dict[str, list] = {}
    for a, b in edges:
        nbrs.setdefault(a, []).append((b, (a, b), False))
        nbrs.setdefault(b, []).append((a, (a, b), True))
    prev = {source: None}
    queue = [source]
    while queue:
        f = queue.pop(0)
        if f == target:
            chain = []
            while prev[f] is not None:
                f, key, inv = prev[f]
                chain.append((key, inv))
            return chain[::-1]
        for g, key, inv in nbrs.get(f, []):
            if g not in prev:
                prev[g] = (f, key, inv)
                queue.append(g)
    return None


def _frames_text(edges) -> str:
    return ", ".join(f"{a} -> {b}" for a, b in sorted(edges)) or "none"


def _edge_at(e: _Edge, t: np.ndarray) -> tuple[np.ndarray, Rotation]:
    """The edge's transform at times ``t``: linear in translation, slerp in rotation."""
    from scipy.spatial.transform import Slerp

    order = np.argsort(np.asarray(e.t), kind="stable")
    te, xyz = np.asarray(e.t)[order], np.asarray(e.xyz, float)[order]
    rots = Rotation.from_quat(np.asarray(e.q_xyzw, float)[order])
    if e.static or len(te) == 1:
        return np.repeat(xyz[-1:], len(t), axis=0), Rotation.from_quat(np.repeat(rots[-1:].as_quat(), len(t), 0))
    te, keep = np.unique(te, return_index=True)
    xyz, rots = xyz[keep], rots[keep]
    p = np.column_stack([np.interp(t, te, xyz[:, k]) for k in range(3)])
    return p, Slerp(te, rots)(np.clip(t, te[0], te[-1]))


def tf_poses(edges: dict[tuple[str, str], _Edge], source: str, target: str, path) -> tuple[np.ndarray, np.ndarray,
                                                                                            Rotation]:
    """T_source_target over time from /tf: (t, translation (N, 3), rotation). Times are those of the
    chain's fastest moving edge, inside every moving edge's span (no extrapolation)."""
    chain = _tf_chain(edges, source, target)
    if chain is None:
        raise PedcalInputError(f"no /tf chain {source} -> {target}; transforms: {_frames_text(edges)}", path=path)
    moving = [edges[k] for k, _ in chain if not edges[k].static and len(set(edges[k].t)) > 1]
    if moving:
        fastest = max(moving, key=lambda e: len(e.t))
        t = np.unique(np.asarray(fastest.t, float))
        lo, hi = max(min(e.t) for e in moving), min(max(e.t) for e in moving)
        t = t[(t >= lo) & (t <= hi)]
    else:
        t = np.array([max(max(edges[k].t) for k, _ in chain)]) if chain else np.zeros(1)
    p = np.zeros((len(t), 3))
    R = Rotation.identity(len(t))
    for key, inverted in chain:          # T_source_target = T_0 T_1 ... composed from the source
        pe, Re = _edge_at(edges[key], t)
        if inverted:
            Re = Re.inv()
            pe = -Re.apply(pe)
        p = p + R.apply(pe)
        R = R * Re
    return t, p, R


# ----------------------------------------------------------------------------------------- people
def _people_points(msgtype: str, msg, t_log_s: float) -> list[tuple[float, str, str, tuple[float, float, float]]]:
    """(t, track, frame, point) of each person in one tracker message; ``track`` "" when the type has none."""
    t = (_stamp_s(msg.header.stamp) if hasattr(msg, "header") else 0.0) or t_log_s   # unstamped: receive time
    frame = msg.header.frame_id.lstrip("/") if hasattr(msg, "header") else ""
    if msgtype == PEOPLE_MSGTYPE:
        return [(t, str(p.name), frame, (p.position.x, p.position.y, p.position.z)) for p in msg.people]
    if msgtype == SPENCER_MSGTYPE:
        return [(t, str(int(p.track_id)), frame, (p.pose.pose.position.x, p.pose.pose.position.y,
                                                    p.pose.pose.position.z)) for p in msg.tracks]
    if msgtype == POSE_ARRAY_MSGTYPE:
        return [(t, "", frame, (p.position.x, p.position.y, p.position.z)) for p in msg.poses]
    markers = [msg] if msgtype == MARKER_MSGTYPE else list(msg.markers)
    out = []
    for m in markers:
        if int(m.action) in MARKER_DELETE_ACTIONS:
            continue
        tm = _stamp_s(m.header.stamp) or t_log_s
        track = f"{m.ns}/{m.id}" if m.ns else str(m.id)
        out.append((tm, track, m.header.frame_id.lstrip("/"), (m.pose.position.x, m.pose.position.y,
                                                               m.pose.position.z)))
    return out


def _link_tracks(t: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Track ids for anonymous detections (PoseArray): each detection continues the nearest track
    last seen within POSE_ARRAY_LINK_M / POSE_ARRAY_LINK_S (one-to-one per message), else starts one."""
    from scipy.optimize import linear_sum_assignment

    ids = np.empty(len(t), dtype=np.int64)
    last_t, last_p = np.zeros(0), np.zeros((0, 3))
    next_id = 0
    for stamp in np.unique(t):
        rows = np.flatnonzero(t == stamp)
        alive = np.flatnonzero(stamp - last_t <= POSE_ARRAY_LINK_S)
        assigned = np.full(len(rows), -1)
        if len(alive):
            d = np.linalg.norm(xyz[rows, None, :2] - last_p[None, alive, :2], axis=2)
            r, c = linear_sum_assignment(np.where(d <= POSE_ARRAY_LINK_M, d, 1e6))
            ok = d[r, c] <= POSE_ARRAY_LINK_M
            assigned[r[ok]] = alive[c[ok]]
        for k, row in enumerate(rows):
            if assigned[k] < 0:
                assigned[k] = next_id
                next_id += 1
                last_t, last_p = np.append(last_t, 0.0), np.vstack([last_p, np.zeros(3)])
            ids[row] = assigned[k]
            last_t[assigned[k]], last_p[assigned[k]] = stamp, xyz[row]
    return ids


def _frame_kind(frame_id: str, map_frame: str) -> str:
    if frame_id == map_frame:
        return "world"
    return "optical" if "optical" in frame_id else "sensor"


def optical_to_sensor(points_optical: np.ndarray) -> np.ndarray:
    """Optical frame (z forward, x right, y down; REP 103 camera optical) -> sensor body frame
    (x forward, y left, z up): p_sensor = (z, -x, -y)."""
    p = np.asarray(points_optical, float).reshape(-1, 3)
    return np.column_stack([p[:, 2], -p[:, 0], -p[:, 1]])


def _observations(reader, topics: dict[str, str], people: dict[str, str], frame: str, map_frame: str,
                  sensors: SensorNetwork | None, path: Path) -> pd.DataFrame | None:
    parts = []
    for topic, sensor in people.items():
        if topic not in topics:
            raise PedcalInputError(f"people topic {topic} not in the bag; topics: {_listing(topics)}", path=path)
        msgtype = topics[topic]
        if msgtype not in PEOPLE_MSGTYPES:
            raise PedcalInputError(f"topic {topic} is {msgtype}, expected one of {', '.join(PEOPLE_MSGTYPES)}",
                                   path=path)
        rows = [r for t_log, msg in _messages(reader, topic) for r in _people_points(msgtype, msg, t_log)]
        if not rows:
            logging.getLogger(__name__).warning(f"people topic {topic} holds no detections")
            continue
        t = np.array([r[0] for r in rows], float)
        xyz = np.array([r[3] for r in rows], float)
        track = np.array([r[1] for r in rows], dtype=object)
        if msgtype == POSE_ARRAY_MSGTYPE:
            track = _link_tracks(t, xyz).astype(str).astype(object)
        kinds = np.array([frame if frame != "auto" else _frame_kind(r[2], map_frame) for r in rows])
        if (kinds != "world").any():
            if sensors is None or sensor not in sensors:
                have = f" (sensors.yaml has {', '.join(sensors.ids)})" if sensors is not None else ""
                raise PedcalInputError(
                    f"topic {topic} gives points in the frame '{rows[int(np.flatnonzero(kinds != 'world')[0])][2]}', "
                    f"not '{map_frame}': mapping them into the world needs the installed extrinsics of sensor "
                    f"'{sensor}'; pass sensors.yaml (--sensors){have}", path=path)
            ext = sensors[sensor]
            opt = kinds == "optical"
            xyz[opt] = optical_to_sensor(xyz[opt])
            local = kinds != "world"
            xyz[local] = ext.to_world(xyz[local])   # p_world = R_installed p_sensor + position_installed
        parts.append(pd.DataFrame({"t": t, "sensor": sensor, "track": track, "x": xyz[:, 0], "y": xyz[:, 1],
                                   "z": xyz[:, 2]}, columns=list(OBSERVATION_COLUMNS)))
    if not parts:
        return None
    obs = pd.concat(parts, ignore_index=True).sort_values("t", kind="stable")
    dup = obs.duplicated(["sensor", "track", "t"]).to_numpy()
    if dup.any():
        logging.getLogger(__name__).warning(f"{int(dup.sum())} repeated (sensor, track, time) detections dropped")
        obs = obs[~dup]
    return obs.reset_index(drop=True)


# -------------------------------------------------------------------------------------------- read
@dataclass
class BagLog:
    """What a bag gives a log directory: tables in the log format (None when absent) and, per
    table, where it came from (``sources``: table -> "topic (message type)" or "/tf a -> b")."""

    robot: pd.DataFrame | None = None
    odometry: pd.DataFrame | None = None
    observations: pd.DataFrame | None = None
    head_offset_m: np.ndarray | None = None
    sources: dict[str, str] = field(default_factory=dict)
    missing: str = ""       # why robot is None: what the bag lacks

    def to_dict(self) -> dict:
        """Row counts, head offset and sources (JSON-ready)."""
        return {"rows": {k: None if getattr(self, k) is None else len(getattr(self, k))
                         for k in ("robot", "odometry", "observations")},
                "head_offset_m": None if self.head_offset_m is None else [float(v) for v in self.head_offset_m],
                "sources": dict(self.sources)}


def _parse_people(people) -> dict[str, str]:
    """{topic: sensor id} from a mapping or "TOPIC=SENSOR" strings (SENSOR defaults to the topic's
    name, slashes to underscores)."""
    if people is None:
        return {}
    if isinstance(people, dict):
        return {str(k): str(v) for k, v in people.items()}
    out = {}
    for item in people:
        topic, _, sensor = str(item).partition("=")
        out[topic] = sensor or topic.strip("/").replace("/", "_")
    return out


def read_bag(path: str | Path, amcl_topic: str | None = None, odom_topic: str | None = None, *,
             localization: str = "auto", localization_topic: str | None = None, map_frame: str = "map",
             base_frame: str = "base_link", head_frame: str | None = None, people=None,
             people_frame: str = "auto", sensors: SensorNetwork | None = None, pose_sigma=None,
             require_localization: bool = True) -> BagLog:
    """Read a ROS 1 .bag or ROS 2 bag (folder, .db3, .mcap) into log tables (see the module doc).

    ``localization``: auto, amcl, odometry or tf; ``amcl_topic`` / ``localization_topic`` name the
    topic (else picked by type). ``odom_topic``: the wheel odometry (an Odometry topic not in
    ``map_frame``). ``head_frame``: read the head offset from /tf (``base_frame`` -> it). ``people``:
    {topic: sensor id} or ["TOPIC=SENSOR", ...]; ``people_frame`` auto (from each header: the map
    frame = world, a name with "optical" = optical, else the sensor's own), world, sensor or
    optical; ``sensors``: the installed extrinsics, needed for sensor and optical frames.
    ``pose_sigma``: (m, rad) for a localization without covariance. Rows are in time order
    (observations: stable in bag order within a time).

    A bag without localization is refused with PedcalInputError saying what it lacks (as
    ``pedcal import-bag`` does); ``require_localization=False`` returns it with ``robot`` None and
    that text in ``missing`` (e.g. to read only the people topics).
    """
    path = Path(path)
    if localization not in LOCALIZATION_SOURCES:
        raise PedcalInputError(f"unknown localization source {localization!r}, expected one of "
                               f"{', '.join(LOCALIZATION_SOURCES)}", path=path)
    if people_frame not in OBSERVATION_FRAMES:
        raise PedcalInputError(f"unknown people frame {people_frame!r}, expected one of "
                               f"{', '.join(OBSERVATION_FRAMES)}", path=path)
    people = _parse_people(people)
    reader = _open_reader(_bag_paths(path))
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        out = BagLog()
        odom_frames = {t: _first_frame(reader, t) for t, ty in topics.items() if ty == ODOM_MSGTYPE}
        in_map = [t for t, f in odom_frames.items() if f == map_frame]
        edges = _read_tf(reader, topics)
        amcl_req = amcl_topic or (localization_topic if localization == "amcl" else None)
        tried = []
        # -- localization
        if localization in ("auto", "amcl"):
            topic = _pick_topic(topics, AMCL_MSGTYPE, amcl_req, path, "--amcl-topic")
            if topic is not None:
                out.robot, out.sources["robot"] = _pose_rows(reader, topic, True), f"{topic} ({AMCL_MSGTYPE})"
            tried.append(f"no {AMCL_MSGTYPE} topic (such as /amcl_pose)")
        if out.robot is None and localization in ("auto", "odometry"):
            req = localization_topic if localization == "odometry" else None
            topic = _pick_topic(topics, ODOM_MSGTYPE, req, path, "--localization-topic", candidates=in_map)
            if topic is not None:
                robot = _pose_rows(reader, topic, True)
                cov = robot[["cov_xx", "cov_yy", "cov_yawyaw"]].to_numpy()
                if not (cov > 0).all():
                    robot = _fill_covariance(robot, pose_sigma, f"Odometry {topic}")
                out.robot, out.sources["robot"] = robot, f"{topic} ({ODOM_MSGTYPE}, frame {map_frame})"
            frames = ", ".join(f"{t} in '{f}'" for t, f in sorted(odom_frames.items())) or "none"
            tried.append(f"no {ODOM_MSGTYPE} topic in the frame '{map_frame}' (Odometry topics: {frames})")
        if out.robot is None and localization in ("auto", "tf"):
            if _tf_chain(edges, map_frame, base_frame) is not None:
                t, p, R = tf_poses(edges, map_frame, base_frame, path)
                yaw = R.as_euler("ZYX")[:, 0]
                robot = pd.DataFrame({"t": t, "x": p[:, 0], "y": p[:, 1], "yaw": yaw})
                out.robot = _fill_covariance(robot, pose_sigma, f"/tf {map_frame} -> {base_frame}")
                out.sources["robot"] = f"/tf {map_frame} -> {base_frame}"
            tried.append(f"no /tf chain '{map_frame}' -> '{base_frame}' (transforms: {_frames_text(edges)})")
        if out.robot is None:
            out.missing = "; ".join(tried)
        # -- wheel odometry
        if odom_topic is not None:
            topic = _pick_topic(topics, ODOM_MSGTYPE, odom_topic, path, "--odom-topic")
        else:
            others = [t for t in odom_frames if t not in in_map]
            topic = _pick_topic(topics, ODOM_MSGTYPE, None, path, "--odom-topic", candidates=others)
        if topic is not None:
            out.odometry, out.sources["odometry"] = _pose_rows(reader, topic, False), f"{topic} ({ODOM_MSGTYPE})"
        # -- head offset
        if head_frame is not None:
            _, p, _ = tf_poses(edges, base_frame, head_frame, path)
            out.head_offset_m = p[-1]
            out.sources["head_offset"] = f"/tf {base_frame} -> {head_frame}"
        # -- people
        if people:
            out.observations = _observations(reader, topics, people, people_frame, map_frame, sensors, path)
            if out.observations is not None:
                out.sources["observations"] = ", ".join(f"{t} ({topics[t]}) as sensor {s}" for t, s in people.items())
        if out.robot is None and require_localization:     # after every other topic was checked
            raise _no_localization(out, path)
        return out
    finally:
        reader.close()


def _no_localization(tables: BagLog, bag: Path) -> PedcalInputError:
    return PedcalInputError(f"no localization in the bag, so no robot.csv (calibration needs it): "
                            f"{tables.missing}. Choose a source with --localization amcl|odometry|tf "
                            "(localization= in Python), --map-frame or --base-frame", path=bag)


def _is_rostopic_csv(path: Path) -> bool:
    if not path.is_file() or path.suffix in (".bag", ".db3", ".mcap"):
        return False
    with path.open("r", encoding="utf-8", errors="replace") as f:
        return f.readline().lstrip().startswith(("%time", "field."))


def _check_import_options(out_dir, head_offset_m, pose_sigma) -> None:
    """Before any work: the numbers in their domains (pedcal.options) and an output folder that
    will read back as one log (no table of the other format beside the CSV written)."""
    if pose_sigma is not None:
        check(pose_sigma_m=pose_sigma[0], pose_sigma_rad=pose_sigma[1])
    for v in ([] if head_offset_m is None else np.asarray(head_offset_m, dtype=object).ravel()):
        check(head_offset=v)
    for name in ("robot", "odometry", "observations"):
        other = Path(out_dir) / f"{name}.parquet"
        if other.exists():
            raise PedcalInputError(f"the folder holds {other.name}; the import writes {name}.csv, and a log "
                                   "with both does not read: remove it or import into another folder", path=other)


def import_bag(bag: str | Path, out_dir: str | Path, amcl_topic: str | None = None,
               odom_topic: str | None = None, *, sensors=None, head_offset_m=None, **options) -> dict[Path, int]:
    """Write a bag's log tables into ``out_dir`` atomically: robot.csv, odometry.csv,
    observations.csv, meta.yaml (head offset from /tf or ``head_offset_m``) and sensors.yaml (a copy
    of ``sensors``, a path or SensorNetwork). ``options`` go to :func:`read_bag`. A ``rostopic echo
    -p`` CSV of a PoseWithCovarianceStamped or Odometry topic gives robot.csv.

    Returns {written file: number of rows (1 for YAML)}. Refused, with what is missing: a bag
    without localization (robot.csv is required), a table repeating a time stamp."""
    from pedcal.io.sensors_yaml import read_sensors_yaml, write_sensors_yaml

    bag = Path(bag)
    _check_import_options(out_dir, head_offset_m, options.get("pose_sigma"))
    network = read_sensors_yaml(sensors) if isinstance(sensors, (str, Path)) else sensors
    if bag.is_file() and bag.stat().st_size == 0:
        raise PedcalInputError("empty file, expected a ROS bag or a rostopic echo -p CSV", path=bag)
    if _is_rostopic_csv(bag):
        robot = read_rostopic_amcl_csv(bag)
        if not (robot[["cov_xx", "cov_yy", "cov_yawyaw"]].to_numpy() > 0).all():
            robot = _fill_covariance(robot, options.get("pose_sigma"), f"the rostopic CSV {bag.name}")
        tables = BagLog(robot=robot, sources={"robot": str(bag)})
    else:
        tables = read_bag(bag, amcl_topic=amcl_topic, odom_topic=odom_topic, sensors=network, **options)
    if tables.robot is None:
        raise _no_localization(tables, bag)
    if head_offset_m is not None:
        tables.head_offset_m = np.asarray(head_offset_m, float).reshape(3)
    out_dir = Path(out_dir)
    prepared = {}
    for name in ("robot", "odometry"):
        df = getattr(tables, name)
        if df is None:
            continue
        if len(df) == 0:
            raise PedcalInputError(f"the {name} source ({tables.sources.get(name)}) holds no messages", path=bag)
        df = df.sort_values("t", kind="stable").reset_index(drop=True)
        dup = df["t"].duplicated().to_numpy()
        if dup.any():
            t_dup = df["t"].iloc[int(np.flatnonzero(dup)[0])]
            raise PedcalInputError(f"{name} messages repeat the header stamp {t_dup!r}", path=bag)
        prepared[name] = df
    if tables.observations is not None:
        prepared["observations"] = tables.observations
    for name, df in prepared.items():     # a tracker's lost track, a message of NaNs: dropped, counted
        numeric = df.select_dtypes("number").to_numpy(dtype=float)
        bad = ~np.isfinite(numeric).all(axis=1)
        if bad.any():
            if bad.all():
                raise PedcalInputError(f"every one of the {len(df)} {name} rows from {tables.sources.get(name)} "
                                       "holds a NaN or infinite value", path=bag)
            logging.getLogger(__name__).warning(
                f"{int(bad.sum())} of {len(df)} {name} rows from {tables.sources.get(name)} dropped: a NaN or infinite "
                f"value (the first at t = {float(df['t'].to_numpy()[np.flatnonzero(bad)[0]])!r} s)")
            prepared[name] = df[~bad].reset_index(drop=True)
    written: dict[Path, int] = {}
    for name, df in prepared.items():   # validate everything before writing anything
        p = write_table(df, out_dir / f"{name}.csv")
        written[p] = len(df)
    if tables.head_offset_m is not None:
        p = out_dir / "meta.yaml"
        notes = {"source": {k: v for k, v in tables.sources.items()}}
        write_text_atomic(p, meta_yaml_text(Meta(head_offset_m=tables.head_offset_m, notes=notes)))
        written[p] = 1
    if network is not None:
        written[write_sensors_yaml(network, out_dir / "sensors.yaml")] = len(network)
    elif not (out_dir / "sensors.yaml").is_file():
        logging.getLogger(__name__).warning(f"{out_dir} has no sensors.yaml: add the installed extrinsics "
                                            "(--sensors) before calibrating")
    for name, src in tables.sources.items():
        logging.getLogger(__name__).info(f"import-bag: {name} from {src}")
    return written
