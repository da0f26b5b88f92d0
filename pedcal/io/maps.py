"""Occupancy maps in the ROS map_server layout: a YAML file naming a PGM image.

YAML keys: ``image`` (relative to the YAML file), ``resolution`` (m per cell), ``origin``
([x, y, yaw]: the pose of the lower-left pixel in the world frame), ``negate``, ``occupied_thresh``,
``free_thresh``, optional ``mode`` (trinary | scale | raw). As in map_server, a pixel's occupancy
probability is p = (maxval - value) / maxval (value / maxval when negate); p > occupied_thresh is
occupied, p < free_thresh is free, anything between is unknown. In raw mode the pixel value is the
occupancy in percent.

One departure from map_server, on by default: in trinary mode a pixel of exactly 205, the gray that
map_saver writes for unknown cells, is unknown whatever the thresholds say. Maps whose YAML raises
free_thresh above 0.196 (such as the TurtleBot 4 floor map in shared/data, free_thresh 0.25) would
otherwise turn everything outside the building into free space. ``saver_unknown_value=None`` gives
map_server's pure threshold rule.

Grids are indexed [row, col] like the image: row 0 is the top of the image, i.e. the largest y.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedcal.errors import PedcalInputError
from pedcal.io.sensors_yaml import load_yaml_file, read_vector

_WHITESPACE = b" \t\r\n\x0b\x0c"


def read_pgm(path: str | Path) -> tuple[np.ndarray, int]:
    """A PGM image (P5 binary or P2 ASCII) as (2-D integer array [row, col], maxval)."""
    path = Path(path)
    if not path.is_file():
        raise PedcalInputError("map image not found", path=path)
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos] in _WHITESPACE:
            pos += 1
        if pos < len(data) and data[pos:pos + 1] == b"#":          # comment to end of line
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        start = pos
        while pos < len(data) and data[pos] not in _WHITESPACE and data[pos:pos + 1] != b"#":
            pos += 1
        if start == pos:
            raise PedcalInputError("truncated PGM header", path=path)
        tokens.append(data[start:pos])
    magic = tokens[0]
    if magic not in (b"P5", b"P2"):
        raise PedcalInputError(f"not a PGM image (magic {magic!r}, expected P5 or P2)", path=path)
    try:
        width, height, maxval = (int(t) for t in tokens[1:])
    except ValueError:
        raise PedcalInputError(f"bad PGM header {b' '.join(tokens)!r}", path=path) from None
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise PedcalInputError(f"bad PGM size {width}x{height} or maxval {maxval}", path=path)
    n = width * height
    if magic == b"P5":
        dtype = np.dtype(">u2") if maxval > 255 else np.dtype("u1")
        body = data[pos + 1:]                                     # one whitespace byte after maxval
        if len(body) < n * dtype.itemsize:
            raise PedcalInputError(f"PGM data truncated: {len(body)} bytes for {width}x{height} pixels",
                                   path=path)
        pixels = np.frombuffer(body, dtype=dtype, count=n).astype(np.int64)
    else:
        try:
            pixels = np.array(data[pos:].split(), dtype=np.int64)
        except ValueError:
            raise PedcalInputError("PGM (P2) pixel values must be integers", path=path) from None
        if pixels.size < n:
            raise PedcalInputError(f"PGM data truncated: {pixels.size} values for {width}x{height} pixels",
                                   path=path)
        pixels = pixels[:n]
    if (pixels > maxval).any():
        raise PedcalInputError(f"pixel values above maxval {maxval}", path=path)
    return pixels.reshape(height, width), maxval


@dataclass
class OccupancyMap:
    """Boolean grids [row, col] (row 0 = top of the image = max y) and the grid's placement."""

    occupied: np.ndarray
    free: np.ndarray
    unknown: np.ndarray
    resolution_m: float
    origin_xy_yaw: np.ndarray          # pose of the lower-left pixel's corner (m, m, rad)
    path: Path | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupied.shape

    def _rotation(self) -> np.ndarray:
        c, s = np.cos(self.origin_xy_yaw[2]), np.sin(self.origin_xy_yaw[2])
        return np.array([[c, -s], [s, c]])

    def world_to_cell(self, xy) -> np.ndarray:
        """World points (..., 2) -> integer cells (..., 2) as [row, col]; may fall outside the grid."""
        xy = np.asarray(xy, dtype=float)
        local = (xy - self.origin_xy_yaw[:2]) @ self._rotation()      # R^T (p - origin), row vectors
        col = np.floor(local[..., 0] / self.resolution_m).astype(np.int64)
        row_from_bottom = np.floor(local[..., 1] / self.resolution_m).astype(np.int64)
        return np.stack([self.shape[0] - 1 - row_from_bottom, col], axis=-1)

    def cell_to_world(self, ij) -> np.ndarray:
        """Cells (..., 2) as [row, col] -> world coordinates (..., 2) of the cell centres."""
        ij = np.asarray(ij, dtype=float)
        local = np.stack([(ij[..., 1] + 0.5) * self.resolution_m,
                          (self.shape[0] - 1 - ij[..., 0] + 0.5) * self.resolution_m], axis=-1)
        return local @ self._rotation().T + self.origin_xy_yaw[:2]

    def in_bounds(self, ij) -> np.ndarray:
        ij = np.asarray(ij)
        return (ij[..., 0] >= 0) & (ij[..., 0] < self.shape[0]) & (ij[..., 1] >= 0) & (ij[..., 1] < self.shape[1])

    def _lookup(self, grid: np.ndarray, xy, outside: bool) -> np.ndarray:
        ij = self.world_to_cell(xy)
        inside = self.in_bounds(ij)
        out = np.full(inside.shape, outside)
        out[inside] = grid[ij[..., 0][inside], ij[..., 1][inside]]
        return out

    def is_occupied(self, xy) -> np.ndarray:
        """True where the map marks the point occupied; points off the map are not occupied."""
        return self._lookup(self.occupied, xy, False)

    def is_free(self, xy) -> np.ndarray:
        """True where the map marks the point free; points off the map are not free (unknown)."""
        return self._lookup(self.free, xy, False)


def _number(data: dict, key: str, path: Path, default=None) -> float:
    value = data.get(key, default)
    if value is None:
        raise PedcalInputError(f"missing '{key}'", path=path)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise PedcalInputError(f"'{key}' must be a number, got {value!r}", path=path)
    return float(value)


MAP_SAVER_UNKNOWN = 205


def read_occupancy_map(yaml_path: str | Path, saver_unknown_value: int | None = MAP_SAVER_UNKNOWN
                       ) -> OccupancyMap:
    """Read a map_server map (YAML + PGM) into an OccupancyMap (see the module notes on 205)."""
    yaml_path = Path(yaml_path)
    data, _ = load_yaml_file(yaml_path)
    if not isinstance(data, dict) or not isinstance(data.get("image"), str):
        raise PedcalInputError("expected a map_server YAML with 'image', 'resolution', 'origin'", path=yaml_path)
    resolution_m = _number(data, "resolution", yaml_path)
    if resolution_m <= 0:
        raise PedcalInputError(f"'resolution' must be positive, got {resolution_m}", path=yaml_path)
    if data.get("origin") is None:
        raise PedcalInputError("missing 'origin'", path=yaml_path)
    origin = read_vector(data["origin"], 3, "origin [x, y, yaw]", yaml_path)
    occupied_thresh = _number(data, "occupied_thresh", yaml_path, 0.65)
    free_thresh = _number(data, "free_thresh", yaml_path, 0.196)
    negate = data.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise PedcalInputError(f"'negate' must be 0 or 1, got {negate!r}", path=yaml_path)
    mode = data.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise PedcalInputError(f"'mode' must be trinary, scale or raw, got {mode!r}", path=yaml_path)
    image_path = Path(data["image"])
    if not image_path.is_absolute():
        image_path = yaml_path.parent / image_path
    pixels, maxval = read_pgm(image_path)
    if mode == "raw":
        p = pixels / 100.0
        valid = pixels <= 100
    else:
        p = (pixels if negate else maxval - pixels) / maxval
        valid = np.ones(pixels.shape, dtype=bool)
        if mode == "trinary" and saver_unknown_value is not None and maxval == 255:
            valid = pixels != saver_unknown_value
    occupied = valid & (p > occupied_thresh)
    free = valid & (p < free_thresh)
    return OccupancyMap(occupied=occupied, free=free, unknown=~(occupied | free), resolution_m=resolution_m,
                        origin_xy_yaw=origin, path=yaml_path)
