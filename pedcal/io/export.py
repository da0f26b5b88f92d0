"""Calibrated extrinsics in ROS form (``pedcal export CAL.yaml --format ...``).

Each sensor becomes the static transform T_map_sensor (parent: the file's ``frame``, child: the
sensor id, or ``prefix + id``):

- ``tf-launch``: a launch file of ``tf2_ros static_transform_publisher`` nodes, its kind by the
  output's name: ``.launch.py`` a ROS 2 Python launch file, ``.launch`` / ``.launch.xml`` XML (ROS 1
  ``args="x y z yaw pitch roll parent child"``, or with ``ros_version=2`` ROS 2's
  ``--x ... --child-frame-id``); any other name is refused. All apply R = Rz(yaw) Ry(pitch)
  Rx(roll), pedcal's convention (pedcal/frames.py), angles in radians.
- ``urdf``: a URDF snippet, one fixed joint per sensor (``origin rpy="roll pitch yaw"``: fixed-axis
  X, then Y, then Z, the same rotation).
- ``json``: translation, the rotation as ``quaternion_xyzw`` (ROS, scipy order) and
  ``quaternion_wxyz`` (GTSAM / Eigen order, the calibrated YAML's key), ypr in degrees, and what the
  calibration says of each sensor (sigma, observations, status).

``optical=True`` adds under each sensor a child frame ``<child>_optical`` (z forward, x right, y
down: REP 103's camera optical frame, rotation ``frames.OPTICAL_YPR_DEG`` from the sensor's body
frame), the frame depth-camera drivers stamp their clouds in.

Sensors whose status is not ``ok`` are exported at the pose the file gives (the installed one for
``no-data``) with their status written beside them, and a DegenerateDataWarning names each.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from pedcal import frames
from pedcal.errors import DegenerateDataWarning, PedcalInputError, warnings_at_caller
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


def transforms(network: SensorNetwork, *, prefix: str = "", optical: bool = False):
    """(parent, child, translation m, [yaw, pitch, roll] rad, sensor) of every static transform:
    map -> sensor, and with ``optical`` sensor -> sensor_optical."""
    for s in network:
        (x, y, z), ypr = _pose(s)
        child = prefix + s.id
        yield network.frame, child, (x, y, z), ypr, s
        if optical:
            yield child, f"{child}_optical", (0.0, 0.0, 0.0), np.radians(frames.OPTICAL_YPR_DEG), s


def _ros2_args(parent: str, child: str, xyz, ypr) -> list[str]:
    args = []
    for k, v in zip(("x", "y", "z", "yaw", "pitch", "roll"), (*xyz, *ypr), strict=True):
        args += [f"--{k}", _num(v)]
    return args + ["--frame-id", parent, "--child-frame-id", child]


def tf_launch_text(network: SensorNetwork, *, ros_version: int = 1, prefix: str = "", optical: bool = False) -> str:
    lines = ["<launch>", f"  <!-- pedcal calibrated extrinsics: T_{network.frame}_sensor, static -->"]
    for parent, child, xyz, ypr, s in transforms(network, prefix=prefix, optical=optical):
        name = quoteattr(_node_name(f"pedcal_{child}"))
        if parent == network.frame and _status_note(s):
            lines.append(_status_note(s).rstrip("\n"))
        if ros_version == 1:
            args = " ".join(map(_num, (*xyz, *ypr))) + f" {parent} {child}"
            lines.append(f'  <node pkg="tf2_ros" type="static_transform_publisher" name={name} '
                         f"args={quoteattr(args)} />")
        else:
            args = " ".join(_ros2_args(parent, child, xyz, ypr))
            lines.append(f'  <node pkg="tf2_ros" exec="static_transform_publisher" name={name} '
                         f"args={quoteattr(args)} />")
    return "\n".join(lines + ["</launch>", ""])


def launch_py_text(network: SensorNetwork, *, prefix: str = "", optical: bool = False) -> str:
    """A ROS 2 Python launch file (``ros2 launch pkg sensors.launch.py``) of the same nodes."""
    nodes = []
    for parent, child, xyz, ypr, s in transforms(network, prefix=prefix, optical=optical):
        note = f"  # {s.id}: status {s.status}" if parent == network.frame and _status_note(s) else ""
        nodes.append(f"        Node(package=\"tf2_ros\", executable=\"static_transform_publisher\", "
                     f"name={_node_name(f'pedcal_{child}')!r},{note}\n"
                     f"             arguments={_ros2_args(parent, child, xyz, ypr)!r}),")
    return "\n".join([f'"""pedcal calibrated extrinsics: T_{network.frame}_sensor, static (ROS 2 launch file)."""',
                      "", "from launch import LaunchDescription", "from launch_ros.actions import Node", "", "",
                      "def generate_launch_description():", "    return LaunchDescription([", *nodes,
                      "    ])", ""])


def urdf_text(network: SensorNetwork, *, prefix: str = "", robot_name: str = "pedcal_sensors",
              optical: bool = False) -> str:
    lines = [f"<robot name={quoteattr(robot_name)}>", f"  <link name={quoteattr(network.frame)} />"]
    for parent, child, (x, y, z), (yaw, pitch, roll), s in transforms(network, prefix=prefix, optical=optical):
        note = _status_note(s)
        if parent == network.frame and note:
            lines.append(note.rstrip("\n"))
        lines += [f"  <link name={quoteattr(child)} />",
                  f"  <joint name={quoteattr(f'{parent}_to_{child}')} type=\"fixed\">",
                  f"    <parent link={quoteattr(parent)} />",
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
             "quaternion_wxyz": [float(v) for v in q[[3, 0, 1, 2]]], "ypr_deg": [float(v) for v in s.ypr_deg]}
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


LAUNCH_SUFFIXES = (".launch.py", ".launch.xml", ".launch")


def _launch_kind(path: Path, ros_version: int | None) -> tuple[str, int]:
    """("py" or "xml", ROS version) of a tf-launch output from its name."""
    name = path.name.lower()
    if name.endswith(".launch.py"):
        if ros_version == 1:
            raise PedcalInputError("a .launch.py file is a ROS 2 Python launch file; ROS 1 reads XML "
                                   "(name the output .launch)", path=path)
        return "py", 2
    if name.endswith((".launch", ".launch.xml")):
        return "xml", ros_version or 1
    raise PedcalInputError("a tf-launch output is named .launch.py (ROS 2 Python launch), .launch or .launch.xml "
                           "(XML launch)", path=path)


def _check_frame_names(network: SensorNetwork, prefix: str, source) -> None:
    """Frame names a launch file or URDF can carry: no whitespace or control character (a launch
    file's ``args`` are split at spaces, so ``x y`` would become two arguments and shift the rest)."""
    for what, name in [("the parent frame", network.frame),
                       *(("a sensor's frame (--prefix + id)", prefix + s.id) for s in network)]:
        if not name or any(c.isspace() or not c.isprintable() for c in name):
            raise PedcalInputError(f"{what} {name!r} is empty or holds whitespace or a control character, which a "
                                   "launch file's args or a URDF link name cannot carry; rename it (sensors' ids, "
                                   "'frame', --prefix)", path=source)


@warnings_at_caller
def export_extrinsics(network: SensorNetwork | str | Path, path: str | Path, fmt: str = "tf-launch", *,
                      ros_version: int | None = None, prefix: str = "", optical: bool = False) -> Path:
    """Write ``network`` (a SensorNetwork or a sensors YAML path) as ``fmt`` (FORMATS) to ``path``,
    atomically. ``tf-launch``: a ``.launch.py`` path gives a ROS 2 Python launch file, ``.launch``
    or ``.launch.xml`` XML for ``ros_version`` (1 by default, or 2); another name is refused.
    ``optical``: add each sensor's ``_optical`` child frame. A DegenerateDataWarning names every
    sensor whose status is not ``ok``. Returns the path."""
    from pedcal.io.sensors_yaml import read_sensors_yaml

    source = None if isinstance(network, SensorNetwork) else network
    if not isinstance(network, SensorNetwork):
        network = read_sensors_yaml(network)
    if fmt not in FORMATS:
        raise PedcalInputError(f"unknown export format {fmt!r}, expected one of {', '.join(FORMATS)}")
    if ros_version not in (None, 1, 2):
        raise PedcalInputError(f"ROS version must be 1 or 2, got {ros_version!r}")
    path = Path(path)
    if fmt in ("tf-launch", "urdf"):
        _check_frame_names(network, prefix, source)
    if fmt == "tf-launch":
        kind, ros_version = _launch_kind(path, ros_version)
        if kind == "py":
            text = launch_py_text(network, prefix=prefix, optical=optical)
        else:
            text = tf_launch_text(network, ros_version=ros_version, prefix=prefix, optical=optical)
    elif fmt == "urdf":
        text = urdf_text(network, prefix=prefix, optical=optical)
    else:
        text = json_text(network, prefix=prefix)
    write_text_atomic(path, text)
    for s in network:
        if s.status not in (None, "ok"):
            extra = f" ({', '.join(s.unobservable)} unobservable)" if s.unobservable else ""
            where = "its installed pose" if s.status == "no-data" else "the pose the file gives"
            warnings.warn(f"{path.name}: sensor {s.id} exported with status {s.status}{extra}, at {where}",
                          DegenerateDataWarning, stacklevel=2)
    return path
