"""Writes ROS 1 / ROS 2 bags with rosbags for the import tests: messages built from the
typestore's field definitions (every field not given gets its zero value), the tracker packages'
types registered from their .msg text."""

from __future__ import annotations

import numpy as np

from pedcal.io.ros import register_custom_types

NUMPY_OF = {"float64": np.float64, "float32": np.float32, "uint8": np.uint8, "int8": np.int8, "uint16": np.uint16,
            "int16": np.int16, "uint32": np.uint32, "int32": np.int32, "uint64": np.uint64, "int64": np.int64}


def typestore(version: int):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    register_custom_types(ts)
    if "tf2_msgs/msg/TFMessage" not in ts.fielddefs:       # the Noetic store lacks tf2_msgs
        from rosbags.typesys import get_types_from_msg

        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", "tf2_msgs/msg/TFMessage"))
    return ts


def _zero(ts, desc):
    kind, detail = desc
    kind = int(kind)
    if kind == 1:                                   # base type
        name = detail[0]
        return "" if name == "string" else False if name == "bool" else NUMPY_OF.get(name, float)(0)
    if kind == 2:                                   # nested message
        return make(ts, detail)
    inner, length = detail
    if int(inner[0]) == 1 and inner[1][0] in NUMPY_OF:
        return np.zeros(length if kind == 3 else 0, dtype=NUMPY_OF[inner[1][0]])
    return [_zero(ts, inner) for _ in range(length if kind == 3 else 0)]


def make(ts, msgtype: str, **given):
    fields = ts.fielddefs[msgtype][1]
    values = {name: given[name] if name in given else _zero(ts, desc) for name, desc in fields}
    return ts.types[msgtype](**values)


def stamp(ts, t: float):
    sec = int(np.floor(t))
    return make(ts, "builtin_interfaces/msg/Time", sec=sec, nanosec=int(round((t - sec) * 1e9)))


def header(ts, t: float, frame: str):
    return make(ts, "std_msgs/msg/Header", stamp=stamp(ts, t), frame_id=frame)


def point(ts, p):
    return make(ts, "geometry_msgs/msg/Point", x=float(p[0]), y=float(p[1]), z=float(p[2]))


def pose(ts, p, q_xyzw=(0.0, 0.0, 0.0, 1.0)):
    q = make(ts, "geometry_msgs/msg/Quaternion", x=q_xyzw[0], y=q_xyzw[1], z=q_xyzw[2], w=q_xyzw[3])
    return make(ts, "geometry_msgs/msg/Pose", position=point(ts, p), orientation=q)


def transform(ts, t: float, parent: str, child: str, p, yaw_rad: float):
    tr = make(ts, "geometry_msgs/msg/Transform",
              translation=make(ts, "geometry_msgs/msg/Vector3", x=float(p[0]), y=float(p[1]), z=float(p[2])),
              rotation=make(ts, "geometry_msgs/msg/Quaternion", z=np.sin(yaw_rad / 2), w=np.cos(yaw_rad / 2)))
    return make(ts, "geometry_msgs/msg/TransformStamped", header=header(ts, t, parent), child_frame_id=child,
                transform=tr)


class BagWriter:
    """``with BagWriter(path, version) as w: w.write(topic, msgtype, t_s, msg)``."""

    def __init__(self, path, version: int):
        self.version, self.ts = version, typestore(version)
        if version == 1:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import Writer

            self.writer = Writer(path, version=9)
        self.conns = {}

    def __enter__(self):
        self.writer.open()
        return self

    def __exit__(self, *exc):
        self.writer.close()

    def write(self, topic: str, msgtype: str, t_s: float, msg) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        data = self.ts.serialize_ros1(msg, msgtype) if self.version == 1 else self.ts.serialize_cdr(msg, msgtype)
        self.writer.write(self.conns[topic], int(round(t_s * 1e9)), data)
