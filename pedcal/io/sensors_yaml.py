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

import re
from pathlib import Path

import numpy as np
import yaml

from pedcal.errors import PedcalInputError, show
from pedcal.io import plausible
from pedcal.io.atomic import write_text_atomic
from pedcal.io.inputs import not_utf8_error, read_bytes_capped
from pedcal.model import SENSOR_STATUSES, SensorExtrinsics, SensorNetwork
from pedcal.options import require_path

SENSOR_KEYS = ("id", "position", "ypr_deg", "quaternion_wxyz", "sigma", "observations", "status", "unobservable")


# ------------------------------------------------------------------------------------------- reading
def read_text_file(path: str | Path, what: str = "file") -> str:
    """A UTF-8 text file (a BOM is allowed); a missing file, a directory, a device, FIFO or socket,
    a file beyond pedcal.io.inputs.MAX_TEXT_BYTES, no permission or bytes that are not UTF-8 raise
    PedcalInputError naming the file."""
    path = require_path(path, "path")
    data = read_bytes_capped(path, what)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise not_utf8_error(path, e, "save the file as UTF-8 (a binary file, or another encoding such as "
                                      "cp1252)") from None


def _yaml_error_text(e: yaml.YAMLError) -> str:
    """PyYAML's multi-line error as one line: where and what."""
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    problem = getattr(e, "problem", None) or getattr(e, "context", None) or str(e).splitlines()[0]
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    return f"{where}{problem}"


# A sensors file of 10 000 sensors has ~200 000 values; aliases expanding beyond this are an attack
# or a mistake, and printing or copying them would hang.
MAX_YAML_NODES = 2_000_000


def _expanded_size(root: yaml.Node, path: Path) -> int:
    """Number of values the node tree stands for with every alias expanded (memoized, iterative).
    The walk meets every mapping once, and refuses one that names a key twice (_refuse_repeated_key)."""
    size: dict[int, int] = {}
    pending: set[int] = set()      # expanded, children not yet summed (its ancestors on the stack)
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        if id(node) in size or (not done and id(node) in pending):
            continue
        if not done and isinstance(node, yaml.MappingNode):
            _refuse_repeated_key(node, path)
        children = ([c for kv in node.value for c in kv] if isinstance(node, yaml.MappingNode)
                    else node.value if isinstance(node, yaml.SequenceNode) else [])
        if done or not children:     # children first; a recursive alias (its own ancestor) counts 0
            size[id(node)] = 1 + sum(size.get(id(c), 0) for c in children)
        else:
            pending.add(id(node))
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in size and id(c) not in pending)
    return size[id(root)]


def _refuse_repeated_key(node: yaml.MappingNode, path: Path) -> None:
    """A mapping that names a key twice (PyYAML keeps the last silently, so a second
    ``head_offset:`` or ``position:`` would override the first unseen) raises PedcalInputError
    naming the key and both lines. Merge keys (``<<: *a``) are no keys: two of them merge both."""
    first: dict[str, yaml.Mark] = {}
    for k, _ in node.value:
        if isinstance(k, yaml.ScalarNode) and k.tag != "tag:yaml.org,2002:merge":
            if k.value in first:
                a, b = first[k.value], k.start_mark
                where = (f"line {a.line + 1}, columns {a.column + 1} and {b.column + 1}" if a.line == b.line
                         else f"line {a.line + 1} and line {b.line + 1}")
                raise PedcalInputError(f"key {show(k.value)} appears twice in one mapping ({where}); keep one",
                                       path=path)
            first[k.value] = k.start_mark


def load_yaml_file(path: str | Path) -> tuple[object, yaml.Node | None]:
    """Parse a YAML file; returns (data, node tree). Syntax errors and a key repeated in one
    mapping become PedcalInputError."""
    path = Path(path)
    text = read_text_file(path)
    try:
        loader = yaml.SafeLoader(text)
        try:
            node = loader.get_single_node()
            if node is not None and _expanded_size(node, path) > MAX_YAML_NODES:
                raise PedcalInputError(f"YAML aliases expand to more than {MAX_YAML_NODES} values (an alias bomb?)",
                                       path=path)
            data = loader.construct_document(node) if node is not None else None
        finally:
            loader.dispose()
    except PedcalInputError:
        raise
    except yaml.YAMLError as e:
        raise PedcalInputError(f"not valid YAML at {_yaml_error_text(e)}", path=path) from None
    except (RecursionError, ValueError, OverflowError) as e:
        raise PedcalInputError(f"not valid YAML: {type(e).__name__}", path=path) from None
    return data, node


def _mapping_value_node(node: yaml.Node | None, key: str) -> yaml.Node | None:
    if not isinstance(node, yaml.MappingNode):
        return None
    for k, v in node.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return v
    return None


def read_vector(value, n: int, what: str, path: Path, *, nonnegative: bool = False,
                max_abs: float | None = None, unit: str = "") -> np.ndarray:
    """A list of ``n`` finite numbers (bool is not a number), else PedcalInputError; with ``max_abs``
    a value beyond it is refused as implausible (``unit`` in the message)."""
    ok = (isinstance(value, (list, tuple)) and len(value) == n
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value))
    if ok:
        try:
            arr = np.asarray(value, dtype=float)
        except OverflowError:        # an integer beyond float range
            arr = np.full(n, np.inf)
        ok = bool(np.isfinite(arr).all()) and (not nonnegative or bool((arr >= 0).all()))
    if not ok:
        sign = "non-negative " if nonnegative else ""
        raise PedcalInputError(f"{what}: expected a list of {n} finite {sign}numbers, got {show(value, 80)}",
                               path=path)
    if max_abs is not None and (np.abs(arr) > max_abs).any():
        big = float(arr[np.argmax(np.abs(arr))])
        raise PedcalInputError(f"{what}: {big:g} {unit} is implausible (expected |value| <= {max_abs:g} {unit}; "
                               "a unit mistake?)", path=path)
    return arr


def read_sensors_yaml(path: str | Path) -> SensorNetwork:
    """Read an installed, truth or calibrated sensors YAML file into a SensorNetwork."""
    path = require_path(path, "path")
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
        if isinstance(entry["id"], (list, dict)):
            raise PedcalInputError(f"{where}: 'id' must be a non-empty string", path=path)
        id_node = _mapping_value_node(item_node, "id")
        sensor_id = id_node.value if isinstance(id_node, yaml.ScalarNode) else str(entry["id"])
        if sensor_id == "":
            raise PedcalInputError(f"{where}: 'id' must be a non-empty string", path=path)
        where = f"sensor '{sensor_id}'" + (f" (line {line})" if line else "")
        if sensor_id in line_of_id:
            raise PedcalInputError(f"{where}: duplicate sensor id (first at line {line_of_id[sensor_id]})",
                                   path=path)
        line_of_id[sensor_id] = line
        extra = _read_calibrated_fields(entry, where, path)
        sensors.append(SensorExtrinsics(
            sensor_id,
            read_vector(entry["position"], 3, f"{where} position", path, max_abs=plausible.MAX_ABS_COORDINATE_M,
                        unit="m"),
            read_vector(entry["ypr_deg"], 3, f"{where} ypr_deg", path, max_abs=plausible.MAX_ABS_ANGLE_DEG,
                        unit="deg"),
            **extra))
    frame = data.get("frame", "map")
    if not isinstance(frame, str):
        raise PedcalInputError(f"'frame' must be a string, got {show(frame)}", path=path)
    ypr = np.array([s.ypr_deg for s in sensors])
    if plausible.angles_look_like_radians(ypr):
        raise PedcalInputError(f"every ypr_deg angle lies within +-{plausible.RADIANS_LIMIT:.4f} (largest "
                               f"|angle| {np.abs(ypr).max():.4g}): these look like radians; ypr_deg is in degrees "
                               "(LOG_FORMAT.md), multiply by 180/pi", path=path)
    extra_top = {k: v for k, v in data.items() if k not in ("frame", "sensors")}
    _check_calibration_keys(extra_top, path)
    return SensorNetwork(sensors, frame=frame, extra=extra_top)


# Top-level keys of a calibrated YAML that pedcal evaluate applies: (lowest, highest, unit).
CALIBRATION_KEYS = {
    "tracker_latency_s": (-plausible.MAX_ABS_LATENCY_S, plausible.MAX_ABS_LATENCY_S, "s"),
    "sigma_tracker_latency_s": (0.0, plausible.MAX_ABS_LATENCY_S, "s"),
    "head_radius_m": (0.0, plausible.MAX_HEAD_RADIUS_M, "m"),
}


# The head-point model a calibration estimated (``head_model``, applied by pedcal evaluate): its
# offsets and their sigmas in metres, each within the head's own size.
HEAD_MODEL_FIELDS = ("vertical_offset_m", "ray_shift_m", "horizontal_shift_m", "curvature_m",
                     "sigma_vertical_offset_m", "sigma_ray_shift_m", "sigma_horizontal_shift_m",
                     "sigma_curvature_m")


def _check_number(key: str, v, lo: float, hi: float, unit: str, path: Path) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(float(v)):
        raise PedcalInputError(f"'{key}' must be a number of {unit}, got {show(v)}", path=path)
    if not lo <= v <= hi:
        raise PedcalInputError(f"'{key}' = {float(v):g} {unit} is implausible; expected {lo:g} to {hi:g} {unit}",
                               path=path)


def _check_calibration_keys(extra: dict, path: Path) -> None:
    for key, (lo, hi, unit) in CALIBRATION_KEYS.items():
        v = extra.get(key)
        if v is not None:
            _check_number(key, v, lo, hi, unit, path)
    for key, lo in (("clock_offset_s", -plausible.MAX_ABS_LATENCY_S), ("sigma_clock_offset_s", 0.0)):
        per_sensor = extra.get(key)
        if per_sensor is not None and not isinstance(per_sensor, dict):
            raise PedcalInputError(f"'{key}' must be a mapping of sensor id to seconds, got {show(per_sensor)}",
                                   path=path)
        for sid, v in (per_sensor or {}).items():
            _check_number(f"{key}.{sid}", v, lo, plausible.MAX_ABS_LATENCY_S, "s", path)
    hm = extra.get("head_model")
    if hm is None:
        return
    if not isinstance(hm, dict):
        raise PedcalInputError(f"'head_model' must be a mapping of {', '.join(HEAD_MODEL_FIELDS[:4])}, got "
                               f"{show(hm)}", path=path)
    for key in HEAD_MODEL_FIELDS:
        if hm.get(key) is not None:
            lo = 0.0 if key.startswith("sigma_") else -plausible.MAX_HEAD_RADIUS_M
            _check_number(f"head_model.{key}", hm[key], lo, plausible.MAX_HEAD_RADIUS_M, "m", path)
    _check_per_sensor_shifts(hm, "head_model", path)
    if hm.get("horizontal_profile") is not None:
        _check_head_profile(hm["horizontal_profile"], path)


def _check_per_sensor_shifts(mapping: dict, where: str, path: Path) -> None:
    """``per_sensor_shift_m`` and ``sigma_per_sensor_shift_m`` of a head model (or of its
    profile): mappings of sensor id to metres within the head's size (sigmas not negative)."""
    for key, lo in (("per_sensor_shift_m", -plausible.MAX_HEAD_RADIUS_M), ("sigma_per_sensor_shift_m", 0.0)):
        per_sensor = mapping.get(key)
        if per_sensor is None:
            continue
        if not isinstance(per_sensor, dict):
            raise PedcalInputError(f"'{where}.{key}' must be a mapping of sensor id to metres, got {show(per_sensor)}",
                                   path=path)
        for sid, v in per_sensor.items():
            _check_number(f"{where}.{key}.{sid}", v, lo, plausible.MAX_HEAD_RADIUS_M, "m", path)


def _check_head_profile(prof, path: Path) -> None:
    """``head_model.horizontal_profile``: the horizontal shift toward the sensor (m) at increasing
    horizontal distances (m), as many of each (pedcal.calib.headpoint)."""
    where = "head_model.horizontal_profile"
    if not isinstance(prof, dict) or not isinstance(prof.get("distance_m"), list) or \
            not isinstance(prof.get("shift_m"), list):
        raise PedcalInputError(f"'{where}' must be a mapping with lists distance_m and shift_m, got {show(prof)}",
                               path=path)
    d, shift = prof["distance_m"], prof["shift_m"]
    if len(d) < 2 or len(d) != len(shift):
        raise PedcalInputError(f"'{where}': distance_m and shift_m must be lists of the same length, 2 or more "
                               f"(got {len(d)} and {len(shift)})", path=path)
    for j, (dj, sj) in enumerate(zip(d, shift, strict=True)):
        _check_number(f"{where}.distance_m[{j}]", dj, 0.0, 1e3, "m", path)
        _check_number(f"{where}.shift_m[{j}]", sj, -plausible.MAX_HEAD_RADIUS_M, plausible.MAX_HEAD_RADIUS_M, "m", path)
    if any(b <= a for a, b in zip(d[:-1], d[1:], strict=True)):
        raise PedcalInputError(f"'{where}.distance_m' must increase, got {show(d)}", path=path)
    _check_per_sensor_shifts(prof, where, path)


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
            raise PedcalInputError(f"{where}: 'observations' must be a non-negative integer, got {show(n_obs)}",
                                   path=path)
        out["observations"] = n_obs
    status = entry.get("status")
    if status is not None:
        if status not in SENSOR_STATUSES:
            raise PedcalInputError(f"{where}: 'status' must be one of {', '.join(SENSOR_STATUSES)}, "
                                   f"got {show(status)}", path=path)
        out["status"] = status
    unobservable = entry.get("unobservable")
    if unobservable is not None:
        if not isinstance(unobservable, list) or not all(isinstance(u, str) for u in unobservable):
            raise PedcalInputError(f"{where}: 'unobservable' must be a list of direction names", path=path)
        out["unobservable"] = list(unobservable)
    return out


# ------------------------------------------------------------------------------------------- writing
class _FlowList(list):
    """A list written on one line: [1.2, 0.8, 2.6]. Of scalars only (floats, strings): the
    libyaml path's guard (:func:`_keys_libyaml_writes_otherwise`) does not look inside it, so a
    mapping in it with an empty or long key would be written as libyaml writes it, not PyYAML."""


class _Dumper(yaml.SafeDumper):
    """PyYAML's own (pure Python) emitter."""


# libyaml's emitter where PyYAML was built with it: the same text (the representers, which make
# the nodes, are PyYAML's Python ones either way; tests/test_io_sensors_yaml.py compares the two)
# at a fifth of the time, most of it the factor graph's 3n x 3n position covariance
_CDumper = type("_CDumper", (yaml.CSafeDumper,), {}) if getattr(yaml, "__with_libyaml__", False) else None

for _dumper in (_Dumper, _CDumper):
    if _dumper is None:
        continue
    _dumper.add_representer(_FlowList, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v,
                                                                         flow_style=True))
    # Notes and extra keys may carry numpy values (a simulator's seed, a vector): written as plain YAML.
    _dumper.add_multi_representer(np.generic, lambda d, v: d.represent_data(v.item()))
    _dumper.add_representer(np.ndarray, lambda d, v: d.represent_data(_FlowList(v.tolist()) if v.ndim == 1
                                                                      else v.tolist()))
del _dumper


def flow_vector(values) -> _FlowList:
    """Plain Python floats (repr is the shortest exact form, so values round-trip exactly)."""
    return _FlowList(float(v) for v in np.asarray(values, dtype=float).reshape(-1))


# where libyaml's text is not PyYAML's: a double-quoted scalar opens (libyaml escapes NEL as \N and
# the characters beyond the Basic Multilingual Plane as \U... that PyYAML writes as they are, and
# breaks long ones elsewhere), at a line's start (past its sequences' dashes), after a key or a
# flow collection's bracket, brace (a mapping inside a one-line list) or comma; a quote inside a
# plain or single-quoted scalar may match too, which only costs PyYAML's emitter's time
_DOUBLE_QUOTED = re.compile(r'(?:^ *(?:- )*|: |\? |[\[{]|, )"', re.M)
# PyYAML writes a key of 123 characters or more as "? key", libyaml one of more than 128 bytes (UTF-8):
# a key longer than this (in bytes) is left to PyYAML
_LONG_KEY_BYTES = 100


def _keys_libyaml_writes_otherwise(data) -> bool:
    """A mapping key in ``data`` (dicts, lists and object arrays walked, not the flow rows of numbers) that is
    empty or longer than ``_LONG_KEY_BYTES`` in UTF-8, or binary: libyaml and PyYAML write it
    differently (an empty key, or a long one as "? key" in one and not the other)."""
    stack, seen = [data], set()
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, dict):
            keys = node.keys()
            stack.extend(node.values())
        elif isinstance(node, (set, frozenset)):      # (written as a mapping of its elements)
            keys = node
        elif isinstance(node, list) and not isinstance(node, _FlowList):
            stack.extend(node)
            continue
        elif isinstance(node, np.ndarray) and node.dtype == object:     # (written as its list: dicts may be in it)
            stack.extend(node.ravel().tolist())
            continue
        else:
            continue
        for k in keys:
            if isinstance(k, (bytes, bytearray)) or k == "" or (
                    len(str(k).encode("utf-8", "surrogatepass")) > _LONG_KEY_BYTES):
                return True
    return False


def dump_yaml(data: dict) -> str:
    """``data`` as block-style YAML, keys in their order; by libyaml's emitter where PyYAML has it,
    the text of PyYAML's own: a text libyaml would write otherwise (a double-quoted scalar, an
    empty or long key, a lone surrogate it cannot encode) is written by PyYAML's emitter."""
    def dump(dumper):
        return yaml.dump(data, Dumper=dumper, sort_keys=False, default_flow_style=False, allow_unicode=True)

    if _CDumper is not None and not _keys_libyaml_writes_otherwise(data):
        try:
            text = dump(_CDumper)
        except UnicodeEncodeError:      # a lone surrogate (a "\uDCFF" escape read from a file): PyYAML escapes it
            text = None
        if text is not None and not _DOUBLE_QUOTED.search(text):
            return text
    return dump(_Dumper)


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
    """Write any of the three schemas (fields that are None are left out), atomically; a network
    with a NaN or implausible pose is refused (it would not read back)."""
    from pedcal.io.logdir import check_network

    path = require_path(path, "path")
    check_network(network, "network")
    write_text_atomic(path, sensors_yaml_text(network))
    return path
