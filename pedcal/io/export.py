"""Calibrated extrinsics in ROS form (``pedcal export CAL.yaml --format ...``).

Each sensor becomes the static transform T_map_sensor (parent: the file's ``frame``, child: the
sensor id, or ``prefix + id``):

- ``tf-launch``: a launch file of ``tf2_ros static_transform_publisher`` nodes; ROS 1 XML
  (``args="x y z yaw pitch roll parent child"``) or, with ``ros_version=2``, ROS 2 XML
  (``--x ... --child-frame-id``). Both apply R = Rz(yaw) Ry(pitch) Rx(roll), pedcal's convention
  (pedcal/frames.py), angles in radians.
- ``urdf``: a URDF snippet, one fixed joint per sensor (``origin rpy="roll pitch yaw"``: fixed-axis
  X, then Y, then Z, the same rotation).
- ``json``: translation, quaternion (x, y, z, w), ypr in degrees, and what the calibration says of
  each sensor (sigma, observations, status).

Sensors whose status is not ``ok`` are exported at the pose the file gives (the installed one for
``no-data``) with their status written beside them.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from pedcal.io.atomic import write_text_atomic
from pedcal.model import SensorNetwork

FORMATS = ("tf-launch", "urdf", "json")


def _num(v: float) -> str:
    return repr(float(v))          # shortest text that reads back to the same double


def _node_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", text)


def _status_note(s) -> str:
    if s.status in (None, "ok"):
        return ""
    extra = f" ({', '.join(s.unobservable)} unobservable)" if s.unobservable else ""
    return f"  <!-- {s.id}: status {s.status}{extra} -->\n"


def _pose(s) -> tuple[np.ndarray, np.ndarray]:
    """(translation m, [yaw, pitch, roll] rad) of T_parent_sensor."""
    return s.position_m, np.radians(s.ypr_deg)


def tf_launch_text(network: SensorNetwork, *, ros_version: int = 1, prefix: str = "") -> str:
    lines = ["<launch>", f"  <!-- pedcal calibrated extrinsics: T_{network.frame}_sensor, static -->"]
    for s in network:
        (x, y, z), (yaw, pitch, roll) = _pose(s)
        child, name = prefix + s.id, quoteattr(_node_name(f"pedcal_{prefix}{s.id}"))
        if _status_note(s):
            lines.append(_status_note(s).rstrip("\n"))
        if ros_version == 1:
            args = " ".join(map(_num, (x, y, z, yaw, pitch, roll))) + f" {network.frame} {child}"
            lines.append(f'  <node pkg="tf2_ros" type="static_transform_publisher" name={name} '
                         f"args={quoteattr(args)} />")
        else:
            args = " ".join(f"--{k} {_num(v)}" for k, v in zip(("x", "y", "z", "yaw", "pitch", "roll"),
                                                                (x, y, z, yaw, pitch, roll), strict=True))
            args += f" --frame-id {network.frame} --child-frame-id {child}"
            lines.append(f'  <node pkg="tf2_ros" exec="static_transform_publisher" name={name} '
                         f"args={quoteattr(args)} />")
    return "\n".join(lines + ["</launch>", ""])


def urdf_text(network: SensorNetwork, *, prefix: str = "", robot_name: str = "pedcal_sensors") -> str:
    lines = [f"<robot name={quoteattr(robot_name)}>", f"  <link name={quoteattr(network.frame)} />"]
    for s in network:
        (x, y, z), (yaw, pitch, roll) = _pose(s)
        child = prefix + s.id
        note = _status_note(s)
        if note:
            lines.append(note.rstrip("\n"))
        lines += [f"  <link name={quoteattr(child)} />",
                  f"  <joint name={quoteattr(f'{network.frame}_to_{child}')} type=\"fixed\">",
                  f"    <parent link={quoteattr(network.frame)} />",
                  f"    <child link={quoteattr(child)} />",
                  f'    <origin xyz="{_num(x)} {_num(y)} {_num(z)}" rpy="{_num(roll)} {_num(pitch)} {_num(yaw)}" />',
                  "  </joint>"]
    return "\n".join(lines + ["</robot>", ""])


def json_text(network: SensorNetwork, *, prefix: str = "") -> str:
    sensors = []
    for s in network:
        q = Rotation.from_matrix(s.R_world_sensor).as_quat()
        d = {"id": s.id, "parent_frame": network.frame, "child_frame": prefix + s.id,
             "translation_m": [float(v) for v in s.position_m], "quaternion_xyzw": [float(v) for v in q],
             "ypr_deg": [float(v) for v in s.ypr_deg]}
        if s.sigma_position_m is not None:
            d["sigma_position_m"] = [float(v) for v in s.sigma_position_m]
        if s.sigma_ypr_deg is not None:
            d["sigma_ypr_deg"] = [float(v) for v in s.sigma_ypr_deg]
        for key in ("observations", "status", "unobservable"):
            if getattr(s, key) is not None:
                d[key] = getattr(s, key)
        for key in ("clock_offset_s", "sigma_clock_offset_s"):       # the sensor's own clock
            if s.id in (network.extra.get(key) or {}):
                d[key] = float(network.extra[key][s.id])
        sensors.append(d)
    return json.dumps({"frame": network.frame, "sensors": sensors}, indent=2) + "\n"


def export_extrinsics(network: SensorNetwork | str | Path, path: str | Path, fmt: str = "tf-launch", *,
                      ros_version: int = 1, prefix: str = "") -> Path:
    """Write ``network`` (a SensorNetwork or a sensors YAML path) as ``fmt`` (FORMATS) to ``path``,
    atomically. Returns the path."""
    from pedcal.errors import PedcalInputError
    from pedcal.io.sensors_yaml import read_sensors_yaml

    if not isinstance(network, SensorNetwork):
        network = read_sensors_yaml(network)
    if fmt not in FORMATS:
        raise PedcalInputError(f"unknown export format {fmt!r}, expected one of {', '.join(FORMATS)}")
    if ros_version not in (1, 2):
        raise PedcalInputError(f"ROS version must be 1 or 2, got {ros_version!r}")
    text = {"tf-launch": lambda: tf_launch_text(network, ros_version=ros_version, prefix=prefix),
            "urdf": lambda: urdf_text(network, prefix=prefix),
            "json": lambda: json_text(network, prefix=prefix)}[fmt]()
    path = Path(path)
    write_text_atomic(path, text)
    return path
