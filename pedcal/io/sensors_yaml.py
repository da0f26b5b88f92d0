"""sensors.yaml, truth.yaml and the calibrated extrinsics file (LOG_FORMAT.md, "sensors.yaml").

One reader for the three schemas: the installed and truth files hold ``frame`` and
``sensors: [{id, position, ypr_deg}]``; the calibrated file adds per sensor ``quaternion_wxyz``
(the same rotation, for programs), ``sigma`` (``position_m``, ``ypr_deg`` and ``rotation_deg``:
a rotation vector in the sensor frame, meaningful at any pitch), ``observations``, ``status`` and
(when degenerate) ``unobservable``, and at the top level what the calibration estimated beside
the extrinsics: ``tracker_latency_s``, ``head_model`` (vertical offset and shift toward the
sensor of the tracker's head point, with sigma), ``position_covariance_m2`` (the joint covariance
of all sensors' positions) and ``model_mismatch`` (residuals against the noise model). A
calibrated file is a valid sensors.yaml.

Sensor ids are kept as the text written in the file, so ``id: 01`` is "01" (YAML would read it
as the integer 1) and matches the ``sensor`` column of observations.csv, which is read as text.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from pedcal.errors import PedcalInputError
from pedcal.io.atomic import write_text_atomic
from pedcal.model import SENSOR_STATUSES, SensorExtrinsics, SensorNetwork

SENSOR_KEYS = ("id", "position", "ypr_deg", "quaternion_wxyz", "sigma", "observations", "status", "unobservable")


# ------------------------------------------------------------------------------------------- reading
def load_yaml_file(path: str | Path) -> tuple[object, yaml.Node | None]:
    """Parse a YAML file; returns (data, node tree). Syntax errors become PedcalInputError."""
    path = Path(path)
    if not path.is_file():
        raise PedcalInputError("file not found", path=path)
    text = path.read_text(encoding="utf-8")
    try:
        loader = yaml.SafeLoader(text)
        try:
            node = loader.get_single_node()
            data = loader.construct_document(node) if node is not None else None
        finally:
            loader.dispose()
    except yaml.YAMLError as e:
        raise PedcalInputError(f"not valid YAML: {e}", path=path) from None
    return data, node


def _mapping_value_node(node: yaml.Node | None, key: str) -> yaml.Node | None:
    if not isinstance(node, yaml.MappingNode):
        return None
    for k, v in node.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return v
    return None


def read_vector(value, n: int, what: str, path: Path, *, nonnegative: bool = False) -> np.ndarray:
    """A list of ``n`` finite numbers (bool is not a number), else PedcalInputError."""
    ok = (isinstance(value, (list, tuple)) and len(value) == n
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value))
    if ok:
        arr = np.asarray(value, dtype=float)
        ok = bool(np.isfinite(arr).all()) and (not nonnegative or bool((arr >= 0).all()))
    if not ok:
        sign = "non-negative " if nonnegative else ""
        raise PedcalInputError(f"{what}: expected a list of {n} finite {sign}numbers, got {value!r}",
                               path=path)
    return arr


def read_sensors_yaml(path: str | Path) -> SensorNetwork:
    """Read an installed, truth or calibrated sensors YAML file into a SensorNetwork."""
    path = Path(path)
    data, root = load_yaml_file(path)
    if not isinstance(data, dict) or "sensors" not in data:
        raise PedcalInputError("expected a mapping with a 'sensors' list (LOG_FORMAT.md, sensors.yaml)",
                               path=path)
    entries = data["sensors"]
    if not isinstance(entries, list) or not entries:
        raise PedcalInputError("'sensors' must be a non-empty list of {id, position, ypr_deg}", path=path)
    seq_node = _mapping_value_node(root, "sensors")
    item_nodes = seq_node.value if isinstance(seq_node, yaml.SequenceNode) else [None] * len(entries)

    sensors: list[SensorExtrinsics] = []
    line_of_id: dict[str, int] = {}
    for i, (entry, item_node) in enumerate(zip(entries, item_nodes, strict=True)):
        line = item_node.start_mark.line + 1 if item_node is not None else None
        where = f"sensors[{i}]" + (f" (line {line})" if line else "")
        if not isinstance(entry, dict):
            raise PedcalInputError(f"{where}: expected a mapping with id, position, ypr_deg", path=path)
        for key in ("id", "position", "ypr_deg"):
            if entry.get(key) is None:
                raise PedcalInputError(f"{where}: missing '{key}'", path=path)
        id_node = _mapping_value_node(item_node, "id")
        sensor_id = id_node.value if isinstance(id_node, yaml.ScalarNode) else str(entry["id"])
        if isinstance(entry["id"], (list, dict)) or sensor_id == "":
            raise PedcalInputError(f"{where}: 'id' must be a non-empty string", path=path)
        where = f"sensor '{sensor_id}'" + (f" (line {line})" if line else "")
        if sensor_id in line_of_id:
            raise PedcalInputError(f"{where}: duplicate sensor id (first at line {line_of_id[sensor_id]})",
                                   path=path)
        line_of_id[sensor_id] = line
        extra = _read_calibrated_fields(entry, where, path)
        sensors.append(SensorExtrinsics(
            sensor_id,
            read_vector(entry["position"], 3, f"{where} position", path),
            read_vector(entry["ypr_deg"], 3, f"{where} ypr_deg", path),
            **extra))
    frame = data.get("frame", "map")
    if not isinstance(frame, str):
        raise PedcalInputError(f"'frame' must be a string, got {frame!r}", path=path)
    extra_top = {k: v for k, v in data.items() if k not in ("frame", "sensors")}
    return SensorNetwork(sensors, frame=frame, extra=extra_top)


def _read_calibrated_fields(entry: dict, where: str, path: Path) -> dict:
    out: dict = {}
    sigma = entry.get("sigma")
    if sigma is not None:
        if not isinstance(sigma, dict):
            raise PedcalInputError(f"{where}: 'sigma' must be a mapping with position_m and ypr_deg",
                                   path=path)
        if sigma.get("position_m") is not None:
            out["sigma_position_m"] = read_vector(sigma["position_m"], 3, f"{where} sigma.position_m", path,
                                                  nonnegative=True)
        if sigma.get("ypr_deg") is not None:
            out["sigma_ypr_deg"] = read_vector(sigma["ypr_deg"], 3, f"{where} sigma.ypr_deg", path,
                                               nonnegative=True)
        if sigma.get("rotation_deg") is not None:
            out["sigma_rotation_deg"] = read_vector(sigma["rotation_deg"], 3, f"{where} sigma.rotation_deg", path,
                                                    nonnegative=True)
    if entry.get("quaternion_wxyz") is not None:    # written beside ypr_deg for programs; ypr_deg rules
        read_vector(entry["quaternion_wxyz"], 4, f"{where} quaternion_wxyz", path)
    n_obs = entry.get("observations")
    if n_obs is not None:
        if isinstance(n_obs, bool) or not isinstance(n_obs, int) or n_obs < 0:
            raise PedcalInputError(f"{where}: 'observations' must be a non-negative integer, got {n_obs!r}",
                                   path=path)
        out["observations"] = n_obs
    status = entry.get("status")
    if status is not None:
        if status not in SENSOR_STATUSES:
            raise PedcalInputError(f"{where}: 'status' must be one of {', '.join(SENSOR_STATUSES)}, "
                                   f"got {status!r}", path=path)
        out["status"] = status
    unobservable = entry.get("unobservable")
    if unobservable is not None:
        if not isinstance(unobservable, list) or not all(isinstance(u, str) for u in unobservable):
            raise PedcalInputError(f"{where}: 'unobservable' must be a list of direction names", path=path)
        out["unobservable"] = list(unobservable)
    return out


# ------------------------------------------------------------------------------------------- writing
class _FlowList(list):
    """A list written on one line: [1.2, 0.8, 2.6]."""


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(_FlowList, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True))
# Notes and extra keys may carry numpy values (a simulator's seed, a vector): write them as plain YAML.
_Dumper.add_multi_representer(np.generic, lambda d, v: d.represent_data(v.item()))
_Dumper.add_representer(np.ndarray, lambda d, v: d.represent_data(_FlowList(v.tolist()) if v.ndim == 1
                                                                  else v.tolist()))


def flow_vector(values) -> _FlowList:
    """Plain Python floats (repr is the shortest exact form, so values round-trip exactly)."""
    return _FlowList(float(v) for v in np.asarray(values, dtype=float).reshape(-1))


def dump_yaml(data: dict) -> str:
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=False, allow_unicode=True)


def sensors_yaml_text(network: SensorNetwork) -> str:
    sensors = []
    for s in network:
        d: dict = {"id": str(s.id), "position": flow_vector(s.position_m), "ypr_deg": flow_vector(s.ypr_deg)}
        if s.status is not None:      # calibrated files: the rotation as a quaternion as well
            q_xyzw = s.T_world_sensor.rotation().toQuaternion().coeffs()
            d["quaternion_wxyz"] = flow_vector(np.round(q_xyzw[[3, 0, 1, 2]], 12))
        sigma = {}
        if s.sigma_position_m is not None:
            sigma["position_m"] = flow_vector(s.sigma_position_m)
        if s.sigma_ypr_deg is not None:
            sigma["ypr_deg"] = flow_vector(s.sigma_ypr_deg)
        if s.sigma_rotation_deg is not None:
            sigma["rotation_deg"] = flow_vector(s.sigma_rotation_deg)
        if sigma:
            d["sigma"] = sigma
        if s.observations is not None:
            d["observations"] = int(s.observations)
        if s.status is not None:
            if s.status not in SENSOR_STATUSES:
                raise ValueError(f"sensor '{s.id}': status must be one of {SENSOR_STATUSES}, got {s.status!r}")
            d["status"] = s.status
        if s.unobservable is not None:
            d["unobservable"] = _FlowList(str(u) for u in s.unobservable)
        sensors.append(d)
    data = {"frame": network.frame, "sensors": sensors}
    data.update({k: v for k, v in network.extra.items() if k not in data})
    return dump_yaml(data)


def write_sensors_yaml(network: SensorNetwork, path: str | Path) -> Path:
    """Write any of the three schemas (fields that are None are left out), atomically."""
    path = Path(path)
    write_text_atomic(path, sensors_yaml_text(network))
    return path
