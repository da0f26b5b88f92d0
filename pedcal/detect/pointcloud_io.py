"""Point-cloud files for ``pedcal detect``: PCD, PLY, KITTI .bin and .npy, read without crashing.

Every reader returns an (N, 4) float64 array ``x, y, z, intensity`` in the file's frame:

- ``.pcd`` (PCL's format, v0.5-0.7): the header is parsed here, so any field layout works
  (padding fields named ``_``, ``COUNT 0``, extra fields, 1/2/4/8-byte integer or float fields);
  ``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF, column-major). A header that
  promises more points than the data hold is an error naming both counts; trailing bytes after
  the promised points are ignored. Reading through a C++ reader is avoided on purpose: a PCD
  with a ``COUNT 0`` padding field aborts open3d's tensor reader.
- ``.ply``: ASCII or binary, through ``plyfile``: the ``vertex`` element's ``x, y, z``;
- ``.bin``: KITTI Velodyne layout, little-endian float32 ``x, y, z, intensity`` per point;
- ``.npy``: an (N, 3+) array, an organized (H, W, 3+) array, or a structured array with
  ``x, y, z`` fields.

Intensity comes from a field named ``intensity`` (or ``reflectance``, ``scalar_intensity``,
``i``) when present, else the mean of the colour channels (0..1) when the file has colours,
else 0; it is put on a 0..1 scale (``reflectance_scale``). Points with a NaN or infinite
coordinate (the invalid pixels of an organized depth cloud) are dropped;
``read_point_cloud_report`` says how many. Points farther than ``MAX_RANGE_M`` (no LIDAR sees
that far; such values are corrupt) are dropped too.

``pedcal.detect.ground`` then puts z = 0 on the floor (the local ground height, or one floor plane).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedcal.errors import DegenerateDataWarning, PedcalInputError
from pedcal.io.inputs import regular_file

SUFFIXES = (".bin", ".pcd", ".ply", ".npy")
_INTENSITY_FIELDS = ("intensity", "reflectance", "scalar_intensity", "scalar_Intensity", "i", "remission")
_COLOUR_FIELDS = (("red", "green", "blue"), ("r", "g", "b"))
MAX_RANGE_M = 1000.0  # horizontal distance beyond which a point is taken as corrupt
MAX_HEADER_BYTES = 1 << 16
MAX_POINTS = 200_000_000  # a header promising more is not a point cloud this reader will allocate
# One frame of a 128-beam LIDAR is a few MB; a file beyond this (a sparse file, a whole map) would be
# read whole into memory, and then copied as float64.
MAX_FILE_BYTES = 1 << 30


@dataclass(frozen=True)
class CloudRead:
    """A read cloud and what was dropped from it."""

    points: np.ndarray  # (N, 4) x, y, z, intensity of the kept points
    n_in_file: int  # points (pixels) the file holds
    n_invalid: int  # dropped: a NaN or infinite coordinate
    n_too_far: int  # dropped: farther than MAX_RANGE_M horizontally
    organized: tuple[int, int] | None  # (height, width) of an organized cloud

    def summary(self) -> str:
        """One line for the user: what was read and dropped (empty when nothing was dropped)."""
        parts = []
        if self.n_invalid:
            what = "pixels" if self.organized else "points"
            parts.append(f"{self.n_invalid} {what} without a valid return (NaN or infinite) dropped")
        if self.n_too_far:
            parts.append(f"{self.n_too_far} points farther than {MAX_RANGE_M:.0f} m dropped as corrupt")
        if not parts:
            return ""
        shape = f" ({self.organized[0]} x {self.organized[1]} organized)" if self.organized else ""
        return f"{self.n_in_file} points in the file{shape}; " + "; ".join(parts)


# -------------------------------------------------------------------------------------------- PCD
_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4",
              ("I", 8): "<i8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}


@dataclass(frozen=True)
class PcdHeader:
    fields: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    points: int
    data: str
    data_offset: int  # byte offset of the first data byte

    @property
    def point_bytes(self) -> int:
        return sum(s * c for s, c in zip(self.sizes, self.counts, strict=True))

    def column(self, name: str) -> tuple[int, int, str] | None:
        """(byte offset within a point, index among the values of a point, numpy type) of the
        first value of field ``name``; None when the file has no such field (or its COUNT is 0)."""
        off = idx = 0
        for f, s, t, c in zip(self.fields, self.sizes, self.types, self.counts, strict=True):
            if f == name and c > 0:
                return off, idx, _PCD_TYPES[(t, s)]
            off += s * c
            idx += c
        return None


def _pcd_header(raw: bytes, path: Path) -> PcdHeader:
    """Parse the header lines up to and including ``DATA``; every inconsistency is an input error."""
    if not raw:
        raise PedcalInputError("empty file, expected a PCD point cloud", path=path)
    entries: dict[str, list[str]] = {}
    pos = 0
    line_no = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0 or end > MAX_HEADER_BYTES:
            raise PedcalInputError("no 'DATA ascii|binary|binary_compressed' line in the first "
                                   f"{min(len(raw), MAX_HEADER_BYTES)} bytes: not a PCD file", path=path)
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        line_no += 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if not re.fullmatch(r"[A-Z_]+", key):
            raise PedcalInputError(f"header line {line_no} {line[:40]!r} is not a PCD header entry", path=path)
        entries[key] = values
        if key == "DATA":
            break
    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH", "DATA"):
        if key not in entries:
            raise PedcalInputError(f"the PCD header has no {key} line", path=path)
    fields = tuple(entries["FIELDS"])
    n = len(fields)

    def ints(key: str, default: list[str] | None = None) -> tuple[int, ...]:
        vals = entries.get(key, default)
        try:
            out = tuple(int(v) for v in vals)
        except ValueError:
            raise PedcalInputError(f"PCD header {key} {' '.join(vals)!r}: integers expected", path=path) from None
        if any(v < 0 for v in out):
            raise PedcalInputError(f"PCD header {key} {' '.join(vals)!r}: negative value", path=path)
        return out

    sizes = ints("SIZE")
    types = tuple(t.upper() for t in entries["TYPE"])
    counts = ints("COUNT", ["1"] * n)
    for key, vals in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(vals) != n:
            raise PedcalInputError(f"PCD header {key} has {len(vals)} entries for {n} FIELDS", path=path)
    for f, s, t in zip(fields, sizes, types, strict=True):
        if (t, s) not in _PCD_TYPES:
            raise PedcalInputError(f"PCD field {f!r}: TYPE {t} SIZE {s} is not a PCD type (I/U 1, 2, 4, 8 "
                                   "bytes, F 4 or 8 bytes)", path=path)
    (width,) = ints("WIDTH")[:1] or (0,)
    height = ints("HEIGHT", ["1"])[0] if entries.get("HEIGHT") else 1
    points = ints("POINTS", [str(width * height)])[0] if entries.get("POINTS") else width * height
    if points != width * height:
        raise PedcalInputError(f"PCD header POINTS {points} is not WIDTH x HEIGHT = {width} x {height}", path=path)
    if points > MAX_POINTS:
        raise PedcalInputError(f"PCD header promises {points} points, more than {MAX_POINTS}", path=path)
    data = entries["DATA"][0].lower() if entries["DATA"] else ""
    if data not in ("ascii", "binary", "binary_compressed"):
        raise PedcalInputError(f"PCD DATA {data!r}: expected ascii, binary or binary_compressed", path=path)
    for name in ("x", "y", "z"):
        if name not in fields:
            raise PedcalInputError(f"the PCD has no {name!r} field (FIELDS {' '.join(fields)})", path=path)
        if counts[fields.index(name)] < 1:
            raise PedcalInputError(f"the PCD field {name!r} has COUNT 0 (no values): expected COUNT 1", path=path)
    return PcdHeader(fields, sizes, types, counts, width, height, points, data, pos)


def _pcd_columns(header: PcdHeader, names: list[str]) -> list[tuple[str, tuple[int, int, str]]]:
    return [(n, c) for n in names if (c := header.column(n)) is not None]


def read_pcd(path: Path) -> tuple[np.ndarray, tuple[int, int] | None]:
    """(N, 4) points of a PCD file (NaN kept) and (height, width) when the cloud is organized."""
    raw = path.read_bytes()
    h = _pcd_header(raw, path)
    want = ["x", "y", "z", *_INTENSITY_FIELDS, *(c for group in _COLOUR_FIELDS for c in group), "rgb"]
    cols = dict(_pcd_columns(h, want))
    n, body = h.points, raw[h.data_offset:]
    values: dict[str, np.ndarray] = {}
    if h.data == "ascii":
        values = _pcd_ascii(body, h, cols, path)
    elif n == 0:
        values = {name: np.empty(0) for name in cols}
    elif h.data == "binary":
        need = n * h.point_bytes
        if len(body) < need:
            raise PedcalInputError(
                f"the PCD header promises {n} points of {h.point_bytes} bytes ({need} bytes of binary data) but "
                f"the file holds {len(body)} bytes after the header ({len(body) // max(h.point_bytes, 1)} "
                "complete points): truncated, or a wrong POINTS/WIDTH", path=path)
        for name, (off, _, dt) in cols.items():
            values[name] = np.ndarray((n,), dtype=dt, buffer=body, offset=off, strides=(h.point_bytes,))
    else:
        values = _pcd_compressed(body, h, cols, path)
    organized = (h.height, h.width) if h.height > 1 else None
    return _assemble(values, n), organized


def _pcd_ascii(body: bytes, h: PcdHeader, cols: dict, path: Path) -> dict[str, np.ndarray]:
    lines = [ln for ln in body.decode("ascii", errors="replace").splitlines() if ln.strip()]
    if len(lines) < h.points:
        raise PedcalInputError(f"the PCD header promises {h.points} points but the ASCII data hold "
                               f"{len(lines)} lines", path=path, row=len(lines))
    n_values = sum(h.counts)
    out = {name: np.empty(h.points) for name in cols}
    for row, line in enumerate(lines[: h.points]):
        tok = line.split()
        if len(tok) != n_values:
            raise PedcalInputError(f"{len(tok)} values on the line, the header's fields give {n_values}",
                                   path=path, row=row)
        for name, (_, idx, _) in cols.items():
            try:
                out[name][row] = float(tok[idx])
            except ValueError:
                raise PedcalInputError(f"field {name!r}: {tok[idx][:20]!r} is not a number", path=path,
                                       row=row, column=name) from None
    return out


def _pcd_compressed(body: bytes, h: PcdHeader, cols: dict, path: Path) -> dict[str, np.ndarray]:
    """PCL's binary_compressed: uint32 compressed size, uint32 uncompressed size, LZF data holding
    every field's values for all points one field after another (column-major)."""
    import lzf

    if len(body) < 8:
        raise PedcalInputError("binary_compressed data shorter than its 8-byte size header", path=path)
    comp_size, raw_size = (int(v) for v in np.frombuffer(body[:8], "<u4"))
    need = h.points * h.point_bytes
    if raw_size != need:
        raise PedcalInputError(f"binary_compressed data unpack to {raw_size} bytes, the header's {h.points} "
                               f"points of {h.point_bytes} bytes need {need}", path=path)
    if comp_size > len(body) - 8:
        raise PedcalInputError(f"binary_compressed data claim {comp_size} compressed bytes, the file holds "
                               f"{len(body) - 8}: truncated", path=path)
    if need == 0:
        return {name: np.empty(0) for name in cols}
    try:
        data = lzf.decompress(body[8: 8 + comp_size], raw_size)
    except ValueError:
        data = None
    if data is None or len(data) != raw_size:
        raise PedcalInputError("binary_compressed data do not decompress (corrupt LZF stream)", path=path)
    # field f starts at points * (bytes of the fields before it); its values are contiguous
    starts, acc = {}, 0
    for f, s, c in zip(h.fields, h.sizes, h.counts, strict=True):
        starts.setdefault(f, acc)
        acc += h.points * s * c
    out = {}
    for name, (_, _, dt) in cols.items():
        c = h.counts[h.fields.index(name)]
        arr = np.frombuffer(data, dtype=dt, count=h.points * c, offset=starts[name])
        out[name] = arr.reshape(h.points, c)[:, 0]
    return out


def _assemble(values: dict[str, np.ndarray], n: int) -> np.ndarray:
    """(n, 4) x, y, z, intensity from named columns (intensity from a named field, colours, or 0)."""
    xyz = np.column_stack([np.asarray(values[k], dtype=float) for k in ("x", "y", "z")]) if n else np.zeros((0, 3))
    intensity = np.zeros(n)
    for name in _INTENSITY_FIELDS:
        if name in values:
            intensity = np.asarray(values[name], dtype=float)
            break
    else:
        for group in _COLOUR_FIELDS:
            if all(c in values for c in group):
                col = np.column_stack([np.asarray(values[c], dtype=float) for c in group])
                if np.nanmax(col, initial=0.0) > 1.0:  # 8-bit colours
                    col = col / 255.0
                intensity = col.mean(axis=1)
                break
        else:
            if "rgb" in values:  # PCL's packed colour: the bytes of a float32 (or uint32) are 0x00RRGGBB
                packed = np.asarray(values["rgb"])
                if packed.dtype.kind == "f":
                    packed = packed.astype(np.float32).view(np.uint32)
                packed = packed.astype(np.uint32)
                rgb = np.column_stack([(packed >> s) & 0xFF for s in (16, 8, 0)]) / 255.0
                intensity = rgb.mean(axis=1)
    return np.column_stack([xyz, intensity])


# ---------------------------------------------------------------------------------- PLY, .bin, .npy
def read_ply(path: Path) -> np.ndarray:
    from plyfile import PlyData

    try:
        with open(path, "rb") as fh:
            ply = PlyData.read(fh)
        vertex = ply["vertex"]
        names = set(vertex.data.dtype.names or ())
        if not {"x", "y", "z"} <= names:
            raise PedcalInputError(f"the PLY vertex element has no x, y, z properties ({', '.join(sorted(names))})",
                                   path=path)
        values = _numeric_fields({k: vertex.data[k] for k in names}, "PLY vertex property", path)
    except PedcalInputError:
        raise
    except Exception as e:  # noqa: BLE001 - hostile bytes fail in plyfile with many exception types
        raise PedcalInputError(f"not a readable PLY point cloud: {e}", path=path) from None
    return _assemble(values, len(vertex.data))


def _numeric_fields(columns: dict, what: str, path: Path) -> dict[str, np.ndarray]:
    """The columns holding one number per point; x, y, z must be such columns (not a list, a
    sub-array, text or a nested record)."""
    def numeric(v) -> bool:
        return isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.kind in "fiub" and not v.dtype.names

    for name in ("x", "y", "z"):
        v = columns[name]
        if not numeric(v):
            kind = ("lists" if v.dtype == object else "records" if v.dtype.names else
                    "text" if v.dtype.kind in "US" else f"{v.dtype} values of shape {v.shape[1:] or v.dtype.shape}")
            raise PedcalInputError(f"the {what} {name!r} holds {kind}, expected one number per point", path=path)
    return {k: v for k, v in columns.items() if numeric(v)}


def read_kitti_bin(path: Path) -> np.ndarray:
    raw = path.read_bytes()
    if len(raw) == 0 or len(raw) % 16:
        raise PedcalInputError(f"a KITTI .bin holds float32 x, y, z, intensity (16 bytes a point); "
                               f"its {len(raw)} bytes are not a positive multiple of 16", path=path)
    return np.frombuffer(raw, dtype="<f4").reshape(-1, 4).astype(float)


def read_npy(path: Path) -> tuple[np.ndarray, tuple[int, int] | None]:
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - a corrupt header fails in numpy's parser with any of a dozen types

        raise PedcalInputError(f"not a readable .npy array: {e}", path=path) from None
    if not isinstance(arr, np.ndarray):      # np.load opens an .npz archive whatever its name
        arr.close()
        raise PedcalInputError("an .npz archive named .npy: expected one .npy array", path=path)
    if arr.dtype.names:
        if not {"x", "y", "z"} <= set(arr.dtype.names):
            raise PedcalInputError(f"a structured .npy needs x, y, z fields; it has {', '.join(arr.dtype.names)}",
                                   path=path)
        organized = arr.shape if arr.ndim == 2 and arr.shape[0] > 1 else None
        flat = arr.reshape(-1)
        return _assemble(_numeric_fields({k: flat[k] for k in arr.dtype.names}, "structured .npy field", path),
                         len(flat)), organized
    if arr.dtype.kind not in "fiu" or arr.ndim not in (2, 3) or arr.shape[-1] < 3:
        raise PedcalInputError(f"a .npy point cloud is (N, 3+) or organized (H, W, 3+) numbers; got "
                               f"{arr.dtype} {arr.shape}", path=path)
    organized = arr.shape[:2] if arr.ndim == 3 else None
    flat = arr.reshape(-1, arr.shape[-1]).astype(float)
    pts = flat[:, :4] if flat.shape[1] >= 4 else np.column_stack([flat, np.zeros(len(flat))])
    return pts, organized


def reflectance_scale(intensity: np.ndarray) -> np.ndarray:
    """Intensities on the detector's 0..1 reflectance scale: values already within [0, 1] are
    kept; 8-bit intensities (max <= 255, as most automotive LIDARs report) are divided by 255;
    larger scales (16-bit) by their maximum."""
    top = float(intensity.max(initial=0.0))
    if top <= 1.0:
        return intensity
    return intensity / (255.0 if top <= 255.0 else top)


def read_point_cloud_report(path: str | Path) -> CloudRead:
    """Read a .pcd, .ply, .bin or .npy file: the finite points and what was dropped."""
    path = Path(path)
    if not path.exists():
        raise PedcalInputError("no such point-cloud file", path=path)
    size = regular_file(path, "point-cloud file").stat().st_size     # a FIFO or device is not read
    if size > MAX_FILE_BYTES:
        raise PedcalInputError(f"{size / 1e9:.3g} GB, more than one frame's point cloud (up to "
                               f"{MAX_FILE_BYTES / 1e9:.3g} GB is read): crop or split it", path=path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise PedcalInputError(f"unknown point-cloud type '{suffix}', expected one of {', '.join(SUFFIXES)}",
                               path=path)
    organized = None
    if suffix == ".bin":
        pts = read_kitti_bin(path)
    elif suffix == ".pcd":
        pts, organized = read_pcd(path)
    elif suffix == ".ply":
        pts = read_ply(path)
    else:
        pts, organized = read_npy(path)
    n_file = len(pts)
    with np.errstate(invalid="ignore", over="ignore"):
        finite = np.isfinite(pts[:, :3]).all(axis=1)
        pts[~np.isfinite(pts[:, 3]), 3] = 0.0
        far = finite & ~(np.hypot(pts[:, 0], pts[:, 1]) <= MAX_RANGE_M)
        far |= finite & ~(np.abs(pts[:, 2]) <= MAX_RANGE_M)
    keep = finite & ~far
    out = np.ascontiguousarray(pts[keep], dtype=float)
    out[:, 3] = reflectance_scale(out[:, 3])
    if len(out) == 0:
        raise PedcalInputError(f"no valid points: {n_file} in the file, {int((~finite).sum())} NaN or infinite, "
                               f"{int(far.sum())} farther than {MAX_RANGE_M:.0f} m", path=path)
    return CloudRead(out, n_file, int((~finite).sum()), int(far.sum()), organized)


def read_point_cloud(path: str | Path) -> np.ndarray:
    """(N, 4) ``x, y, z, intensity`` of a .pcd, .ply, .bin or .npy file, invalid points dropped
    (a DegenerateDataWarning says how many); PedcalInputError when the file cannot be read."""
    res = read_point_cloud_report(path)
    if res.n_invalid or res.n_too_far:
        warnings.warn(f"{path}: {res.summary()}", DegenerateDataWarning, stacklevel=2)
    return res.points


# The ground (``ground_referenced``, ``floor_referenced``) lives in pedcal.detect.ground; its
# names stay importable from here.
from pedcal.detect.ground import floor_referenced, ground_referenced, is_floor_referenced  # noqa: E402

__all__ = ["CloudRead", "read_point_cloud", "read_point_cloud_report", "reflectance_scale", "floor_referenced",
           "ground_referenced", "is_floor_referenced"]
