"""Seeded 3D scenes for the LIDAR simulator: people and the things that fool a person detector.

Frame: the scene frame is a floor-level frame, z up, metres (z = 0 on the floor). Every object
stands on the floor; its pose is its footprint centre ``(x_m, y_m)`` and a heading ``yaw_rad``
(its local +x axis, the way a person faces). Meshes are built from open3d primitives and
carry one reflectance (0..1) per triangle, which the LIDAR turns into intensity.

People follow the shapes the tracking paper's detector must accept (Misu and Miura: gate
0.8 <= h <= 2.0 m, w, d <= 1.2 m); clutter includes objects inside that gate (potted plants,
coat stands, signs, pillars) so that a shape classifier has something to reject.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from functools import cache

import numpy as np
import open3d as o3d

from pedcal.errors import PedcalInputError

PERSON_POSES = ("standing", "walking", "carrying", "walking_carrying")
GARMENTS = ("none", "skirt", "coat")  # what hangs over the legs (person_mesh)
# random_person's clothing: (garment, probability), and the share of people with a backpack
GARMENT_SHARES = (("none", 0.65), ("skirt", 0.15), ("coat", 0.2))
BACKPACK_SHARE = 0.25
PUSHING_SHARE = 0.08  # people pushing a pram or a trolley
PUSH_HANDLE_HEIGHT = 0.58  # of the person's height
CLUTTER_KINDS = (
    "wall", "pillar", "pole", "chair", "potted_plant", "sign", "trolley", "box", "coat_stand",
)
# Relative frequency of each clutter kind in random_scene (person-sized blobs are common on purpose).
CLUTTER_WEIGHTS = {
    "wall": 1.0, "pillar": 1.0, "pole": 1.0, "chair": 1.5, "potted_plant": 1.5, "sign": 1.0,
    "trolley": 1.0, "box": 1.5, "coat_stand": 1.0,
}
# Street clutter for the spinning LIDARs' outdoor scenes (``random_scene(clutter_weights=...)``):
# trunks and poles are the thin vertical objects a sparse scan confuses with a person.
# Cabinets (utility boxes) and panels (freestanding boards, A-frame signs) are the flat-faced
# person-sized blocks of a street.
OUTDOOR_CLUTTER_KINDS = (
    "tree", "street_pole", "bollard", "bush", "car", "cyclist", "kerb", "wall", "sign", "pole", "cabinet", "panel",
)
OUTDOOR_CLUTTER_WEIGHTS = {
    "tree": 2.0, "street_pole": 2.0, "bollard": 1.5, "bush": 1.5, "car": 1.5, "cyclist": 1.0, "kerb": 0.5,
    "wall": 0.5, "sign": 1.0, "pole": 1.0, "cabinet": 1.0, "panel": 1.0,
}
# Added street furniture: sign posts (a pole with plates at its top) and parked bicycles (one to
# three in a rack). A separate mix, so that scenes drawn with OUTDOOR_CLUTTER_WEIGHTS stay as they were.
STREET_CLUTTER_KINDS = OUTDOOR_CLUTTER_KINDS + ("sign_post", "bicycle")
STREET_CLUTTER_WEIGHTS = {**OUTDOOR_CLUTTER_WEIGHTS, "sign_post": 1.5, "bicycle": 1.5}
# What ``hide_partly`` stands in front of a person, indoors and in a street.
HIDING_KINDS_INDOOR = ("person", "box", "pillar", "trolley", "potted_plant")
HIDING_KINDS_STREET = ("person", "car", "bush", "cabinet", "panel")
CLUTTER_IN_VIEW = 0.75  # share of non-wall clutter random_scene puts inside the sensors' cone
FLOOR_ID = -1
CEILING_ID = -2


# --------------------------------------------------------------------------------------------
# Meshes
# --------------------------------------------------------------------------------------------


@dataclass
class Mesh:
    """Triangle mesh with one reflectance per triangle (local or scene frame, metres)."""

    vertices: np.ndarray  # (V, 3) float64
    triangles: np.ndarray  # (T, 3) int32
    reflectance: np.ndarray  # (T,) float32, 0..1

    @staticmethod
    def concat(meshes: list[Mesh]) -> Mesh:
        """One mesh from several (triangle indices offset by the vertex counts)."""
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return Mesh(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.triangles + o for m, o in zip(meshes, offsets, strict=True)]).astype(np.int32),
            np.concatenate([m.reflectance for m in meshes]).astype(np.float32),
        )

    def placed(self, x_m: float, y_m: float, yaw_rad: float) -> Mesh:
        """The mesh rotated by yaw about z and moved to (x, y) on the floor."""
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return Mesh(self.vertices @ R.T + np.array([x_m, y_m, 0.0]), self.triangles, self.reflectance)

    @property
    def z_max_m(self) -> float:
        return float(self.vertices[:, 2].max())


@cache
def _unit_primitive(kind: str, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices/triangles of an open3d unit primitive: sphere r=1, cylinder r=1 z in [-.5,.5],
    box [-.5,.5]^3."""
    if kind == "sphere":
        m = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=resolution)
    elif kind == "cylinder":
        m = o3d.geometry.TriangleMesh.create_cylinder(radius=1.0, height=1.0, resolution=resolution, split=1)
    elif kind == "box":
        m = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
        m.translate((-0.5, -0.5, -0.5))
    else:  # pragma: no cover - internal
        raise ValueError(kind)
    v = np.asarray(m.vertices, dtype=float).copy()
    t = np.asarray(m.triangles, dtype=np.int32).copy()
    v.setflags(write=False)
    t.setflags(write=False)
    return v, t


def _mesh(kind: str, scale, R: np.ndarray, center, reflectance: float, resolution: int = 8) -> Mesh:
    v, t = _unit_primitive(kind, resolution)
    verts = (v * np.asarray(scale, dtype=float)) @ R.T + np.asarray(center, dtype=float)
    return Mesh(verts, t, np.full(len(t), reflectance, dtype=np.float32))


def _rot_z(yaw_rad: float) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def ellipsoid(center, radii, reflectance: float, resolution: int = 8) -> Mesh:
    """Axis-aligned ellipsoid (a scaled open3d sphere)."""
    return _mesh("sphere", radii, np.eye(3), center, reflectance, resolution)


def box(center, size, reflectance: float, yaw_rad: float = 0.0) -> Mesh:
    """Box of size (sx, sy, sz) centred at ``center``, turned by yaw about z."""
    return _mesh("box", size, _rot_z(yaw_rad), center, reflectance)


def cylinder(p0, p1, radius_m: float, reflectance: float, resolution: int = 8) -> Mesh:
    """Capped cylinder of the given radius from point p0 to point p1."""
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    z = axis / length
    # Any orthonormal frame whose third column is the axis.
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    return _mesh("cylinder", (radius_m, radius_m, length), R, (p0 + p1) / 2.0, reflectance, resolution)


def ring(center, radius_m: float, tube_m: float, reflectance: float, axis: str = "y") -> Mesh:
    """A torus (a bicycle wheel's tyre and rim) of the given radius and tube radius, its axis along
    local ``axis`` ("x", "y" or "z"); an open3d torus."""
    m = o3d.geometry.TriangleMesh.create_torus(torus_radius=radius_m, tube_radius=tube_m, radial_resolution=20,
                                               tubular_resolution=6)
    R = {"z": np.eye(3), "y": _rot_x(np.pi / 2), "x": _rot_y(np.pi / 2)}[axis]
    v = np.asarray(m.vertices, dtype=float) @ R.T + np.asarray(center, dtype=float)
    t = np.asarray(m.triangles, dtype=np.int32)
    return Mesh(v, t, np.full(len(t), reflectance, dtype=np.float32))


def frustum(z0_m: float, z1_m: float, radii0_m, radii1_m, reflectance: float, resolution: int = 12,
            center_xy=(0.0, 0.0)) -> Mesh:
    """Vertical elliptic frustum (a skirt, a coat's hem): horizontal radii (x, y) ``radii0_m`` at
    height z0_m, ``radii1_m`` at z1_m, between them linear; an open3d cylinder scaled per height."""
    v, t = _unit_primitive("cylinder", resolution)
    s = (v[:, 2:3] + 0.5)  # 0 at the bottom cap, 1 at the top
    r = (1.0 - s) * np.asarray(radii0_m, dtype=float) + s * np.asarray(radii1_m, dtype=float)
    verts = np.column_stack([v[:, :2] * r + np.asarray(center_xy, dtype=float), z0_m + s[:, 0] * (z1_m - z0_m)])
    return Mesh(verts, t.copy(), np.full(len(t), reflectance, dtype=np.float32))


def floor_mesh(half_extent_m: float, z_m: float, reflectance: float) -> Mesh:
    """A square horizontal plane (two triangles) centred on the origin."""
    e = half_extent_m
    v = np.array([[-e, -e, z_m], [e, -e, z_m], [e, e, z_m], [-e, e, z_m]], dtype=float)
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32), np.full(2, reflectance, np.float32))


# --------------------------------------------------------------------------------------------
# People
# --------------------------------------------------------------------------------------------


def push_reach_m(height_m: float) -> float:
    """How far in front of a person's centre their hands hold a pram's handle (PUSH_HANDLE_HEIGHT of
    the height, the arms (0.36 h from the shoulders at 0.77 h) straight)."""
    arm_len, drop = 0.36 * height_m, (0.77 - PUSH_HANDLE_HEIGHT) * height_m
    return float(np.sqrt(arm_len**2 - drop**2))


def person_mesh(height_m: float, width_m: float, depth_m: float, pose: str = "standing",
                reflectance=0.5, rng: np.random.Generator | None = None, *,
                gait_phase: float | None = None, garment: str = "none", backpack: bool = False,
                pushing: bool = False) -> Mesh:
    """Mesh of a person in its local frame: feet on z = 0, facing +x, top of the head at height_m.

    ``width_m`` is the shoulder width (y), ``depth_m`` the chest depth (x).
    ``pose``: standing, walking (legs apart, arms swinging), carrying (a bag at the hand),
    walking_carrying. ``reflectance``: one value for the clothes, or (upper, lower) clothing;
    the head (skin/hair) gets its own value drawn from ``rng``. ``gait_phase`` in [-1, 1] sets
    the stride (+1: right leg forward); drawn from ``rng`` for walking poses when None.
    ``garment``: "skirt" (a flared frustum from the waist to between knee and calf) or "coat" (from
    the shoulders, flaring to its hem), over the legs, so the outline widens downwards instead of
    parting into two legs; ``backpack`` puts a box on the back. Their sizes come from ``rng``
    after the head and bag, so a plain person's mesh is the same with or without these options.
    ``pushing`` holds the arms forward to the handle of a pram or trolley (``pram_in_front``, a
    separate object) at PUSH_HANDLE_HEIGHT of the height.
    """
    if pose not in PERSON_POSES:
        raise PedcalInputError(f"person pose must be one of {PERSON_POSES}, got {pose!r}", column="pose")
    if garment not in GARMENTS:
        raise PedcalInputError(f"garment must be one of {GARMENTS}, got {garment!r}", column="garment")
    if not (0.5 <= height_m <= 2.5 and 0.1 <= width_m <= 1.0 and 0.05 <= depth_m <= 1.0):
        raise PedcalInputError(
            f"person size out of range: height {height_m} m (0.5-2.5), width {width_m} m (0.1-1.0), "
            f"depth {depth_m} m (0.05-1.0)")
    rng = np.random.default_rng(0) if rng is None else rng
    upper, lower = (reflectance, reflectance) if np.isscalar(reflectance) else reflectance
    head_refl = float(rng.uniform(0.15, 0.6))
    walking = pose in ("walking", "walking_carrying")
    if gait_phase is None:
        gait_phase = float(rng.uniform(-1.0, 1.0)) if walking else 0.0
    h = height_m
    parts: list[Mesh] = []

    # Head: the sphere's pole is the top of the head, exactly at height_m.
    head_r = 0.058 * h
    parts.append(ellipsoid((0.0, 0.0, h - head_r), (0.9 * head_r, 0.8 * head_r, head_r), head_refl))
    neck_top, neck_bottom = h - 1.8 * head_r, 0.815 * h
    parts.append(cylinder((0, 0, neck_bottom - 0.02), (0, 0, neck_top), 0.045, head_refl, 6))

    # Torso: an ellipsoid from hip (0.48 h) to shoulder (0.82 h), narrower than the shoulders.
    arm_r = 0.035 + 0.02 * (width_m - 0.35) / 0.2
    shoulder_z, hip_z = 0.82 * h, 0.48 * h
    torso_half_w = width_m / 2.0 - 2.0 * arm_r
    parts.append(ellipsoid((0.0, 0.0, (shoulder_z + hip_z) / 2.0),
                           (depth_m / 2.0, torso_half_w, (shoulder_z - hip_z) / 2.0 + 0.03), upper))
    # Shoulders: a flattened ellipsoid spanning the full shoulder width.
    parts.append(ellipsoid((0.0, 0.0, shoulder_z - 0.04), (0.42 * depth_m, width_m / 2.0 - arm_r, 0.06), upper))

    # Arms hang from the shoulders and swing opposite to the legs when walking; pushing, they reach
    # forward to a handle (``push_reach_m``).
    arm_len = 0.36 * h
    arm_swing = 0.35 * gait_phase if walking else 0.0
    reach = push_reach_m(h)
    for side, sign in ((1.0, 1.0), (-1.0, -1.0)):
        top = np.array([0.0, side * (width_m / 2.0 - arm_r), shoulder_z - 0.05])
        angle = -sign * arm_swing  # right arm (y < 0) forward when the left leg is forward
        if pushing:
            angle = -np.arcsin(reach / arm_len)
        direction = _rot_y(angle) @ np.array([0.0, 0.0, -1.0])
        parts.append(cylinder(top, top + arm_len * direction, arm_r, upper, 6))

    # Legs: from the hip to the floor, apart by the stride when walking.
    leg_r = 0.055 + 0.02 * (width_m - 0.35) / 0.2
    stride = 0.4 * gait_phase if walking else 0.0  # leg angle from vertical, rad
    leg_len = (hip_z + 0.03) / np.cos(stride)  # both feet reach the floor
    for side, sign in ((1.0, 1.0), (-1.0, -1.0)):
        top = np.array([0.0, side * 0.09 * width_m / 0.45, hip_z + 0.03])
        foot = top + leg_len * (_rot_y(sign * stride) @ np.array([0.0, 0.0, -1.0]))
        parts.append(cylinder(top, foot, leg_r, lower, 6))
        parts.append(box((foot[0] + 0.05, foot[1], 0.04), (0.24, 0.09, 0.08), lower * 0.5))

    if pose in ("carrying", "walking_carrying"):
        # A bag held at the right hand or slung at the hip, its own reflectance.
        bag = np.array([rng.uniform(0.25, 0.45), rng.uniform(0.08, 0.18), rng.uniform(0.2, 0.4)])
        hand_z = shoulder_z - 0.05 - arm_len
        centre = (0.0, -(width_m / 2.0 + bag[1] / 2.0 + 0.01), max(hand_z - bag[2] / 2.0 + 0.05, bag[2] / 2.0))
        parts.append(box(centre, (bag[0], bag[1], bag[2]), float(rng.uniform(0.1, 0.9))))
    if garment == "skirt":
        top = np.array([0.5 * depth_m, torso_half_w + 0.01])
        flare = rng.uniform(1.2, 1.9)
        hem_z = rng.uniform(0.2, 0.4) * h
        parts.append(frustum(hem_z, 0.56 * h, np.minimum(top * flare, 0.35), top, lower, 12))
    elif garment == "coat":
        top = np.array([0.5 * depth_m + 0.02, torso_half_w + 0.02])
        flare = np.array([rng.uniform(1.1, 1.6), rng.uniform(0.95, 1.25)])
        hem_z = rng.uniform(0.25, 0.45) * h
        parts.append(frustum(hem_z, 0.8 * h, np.minimum(top * flare, 0.35), top, upper, 12))
    if backpack:
        d, w, bh = rng.uniform(0.12, 0.2), rng.uniform(0.25, 0.35), rng.uniform(0.3, 0.45)
        parts.append(box((-(0.5 * depth_m + 0.5 * d - 0.03), 0.0, 0.7 * h - 0.02), (d, w, bh),
                         float(rng.uniform(0.05, 0.9))))
    mesh = Mesh.concat(parts)
    mesh.vertices[:, 2] = np.maximum(mesh.vertices[:, 2], 0.0)  # tilted leg caps stop at the floor
    return mesh


# --------------------------------------------------------------------------------------------
# Clutter
# --------------------------------------------------------------------------------------------


def clutter_mesh(kind: str, rng: np.random.Generator, *, ceiling_height_m: float = 2.7
                 ) -> tuple[Mesh, dict]:
    """A random instance of a clutter kind in its local frame; returns (mesh, size parameters).

    The parameters hold ``width_m``, ``depth_m`` (footprint extents in local x and y... as
    width along y, depth along x) and ``radius_m`` (collision radius; for walls, their half
    thickness, walls being handled as segments of length ``length_m`` along local x).
    """
    u = rng.uniform
    refl = float(u(0.1, 0.9))
    parts: list[Mesh]
    if kind == "wall":
        length, thick = u(3.0, 10.0), 0.12
        parts = [box((0, 0, ceiling_height_m / 2), (length, thick, ceiling_height_m), refl)]
        return Mesh.concat(parts), dict(width_m=thick, depth_m=length, length_m=length, radius_m=thick / 2)
    if kind == "pillar":
        side = u(0.3, 0.6)
        if rng.random() < 0.5:
            parts = [box((0, 0, ceiling_height_m / 2), (side, side, ceiling_height_m), refl)]
            r = side / np.sqrt(2)
        else:
            parts = [cylinder((0, 0, 0), (0, 0, ceiling_height_m), side / 2, refl, 16)]
            r = side / 2
        return Mesh.concat(parts), dict(width_m=side, depth_m=side, radius_m=r)
    if kind == "pole":
        radius, height = u(0.02, 0.05), u(1.0, 2.5)
        parts = [cylinder((0, 0, 0), (0, 0, height), radius, refl, 8)]
        return Mesh.concat(parts), dict(width_m=2 * radius, depth_m=2 * radius, radius_m=radius)
    if kind == "chair":
        w, seat_h, back_h = u(0.4, 0.55), u(0.42, 0.48), u(0.8, 1.05)
        leg = 0.02
        parts = [box((0, 0, seat_h), (w, w, 0.05), refl),
                 box((-w / 2 + 0.02, 0, (seat_h + back_h) / 2), (0.04, w, back_h - seat_h), refl)]
        for dx in (-1, 1):
            for dy in (-1, 1):
                parts.append(cylinder((dx * (w / 2 - 0.03), dy * (w / 2 - 0.03), 0),
                                      (dx * (w / 2 - 0.03), dy * (w / 2 - 0.03), seat_h), leg, refl * 0.7, 6))
        return Mesh.concat(parts), dict(width_m=w, depth_m=w, radius_m=w / np.sqrt(2))
    if kind == "potted_plant":
        pot_r, pot_h = u(0.15, 0.25), u(0.3, 0.5)
        total = u(1.0, 1.9)
        blob_w = u(0.35, 0.7)
        foliage = float(u(0.2, 0.6))
        parts = [cylinder((0, 0, 0), (0, 0, pot_h), pot_r, refl, 12),
                 ellipsoid((0, 0, (pot_h + total) / 2), (blob_w / 2, blob_w / 2 * u(0.8, 1.0),
                                                         (total - pot_h) / 2), foliage, 10)]
        # A few leafy lumps make the outline irregular.
        for _ in range(int(rng.integers(2, 5))):
            a = u(0, 2 * np.pi)
            zc = u(pot_h + 0.2 * (total - pot_h), pot_h + 0.8 * (total - pot_h))
            rr = u(0.1, 0.2)
            parts.append(ellipsoid((0.3 * blob_w * np.cos(a), 0.3 * blob_w * np.sin(a), min(zc, total - rr)),
                                   (rr, rr, rr), foliage, 6))
        return Mesh.concat(parts), dict(width_m=blob_w, depth_m=blob_w, radius_m=max(blob_w / 2 + 0.1, pot_r))
    if kind == "sign":
        height, board_w, board_h = u(1.2, 1.9), u(0.4, 0.8), u(0.5, 0.9)
        parts = [cylinder((0, 0, 0), (0, 0, 0.03), 0.2, refl * 0.5, 12),
                 cylinder((0, 0, 0.03), (0, 0, height - board_h / 2), 0.02, refl * 0.5, 6),
                 box((0, 0, height - board_h / 2), (0.02, board_w, board_h), refl)]
        return Mesh.concat(parts), dict(width_m=board_w, depth_m=0.4, radius_m=max(board_w / 2, 0.2))
    if kind == "trolley":
        length, w, h = u(0.6, 1.0), u(0.4, 0.6), u(0.8, 1.1)
        parts = [box((0, 0, 0.15), (length, w, 0.03), refl),  # bottom deck
                 box((0, 0, 0.55 * h), (length, w, 0.03), refl),  # middle deck
                 box((-length / 2, 0, h / 2), (0.03, w, h), refl),  # end frame with handle
                 cylinder((-length / 2, -w / 2, h), (-length / 2, w / 2, h), 0.015, refl, 6)]
        for dx in (-1, 1):
            for dy in (-1, 1):
                corner = (dx * length / 2.1, dy * w / 2.1)
                parts.append(cylinder((*corner, 0.0), (*corner, 0.6 * h), 0.012, refl, 6))
        if rng.random() < 0.6:  # a load on the deck
            lh = u(0.2, 0.5)
            parts.append(box((0.05, 0, 0.15 + lh / 2), (0.7 * length, 0.8 * w, lh), float(u(0.1, 0.9))))
        return Mesh.concat(parts), dict(width_m=w, depth_m=length, radius_m=np.hypot(length, w) / 2)
    if kind == "box":
        n = int(rng.integers(1, 4))
        parts, z = [], 0.0
        size = u(0.3, 0.8)
        for _ in range(n):
            s = size * u(0.7, 1.0)
            parts.append(box((u(-0.05, 0.05), u(-0.05, 0.05), z + s / 2), (s, s * u(0.8, 1.2), s),
                             float(u(0.2, 0.8)), yaw_rad=u(-0.2, 0.2)))
            z += s
            if z > 1.5:
                break
        return Mesh.concat(parts), dict(width_m=size * 1.2, depth_m=size, radius_m=size * 0.85)
    if kind == "coat_stand":
        height = u(1.6, 1.9)
        parts = [cylinder((0, 0, 0), (0, 0, height), 0.025, refl, 8)]
        for a in np.linspace(0, 2 * np.pi, 4, endpoint=False):
            d = np.array([np.cos(a), np.sin(a)])
            parts.append(cylinder((0, 0, 0.02), (*(0.3 * d), 0.0), 0.02, refl, 6))  # feet
            parts.append(cylinder((0, 0, height - 0.1), (*(0.15 * d), height - 0.02), 0.012, refl, 6))
        for _ in range(int(rng.integers(0, 3))):  # hanging coats: person-like upper bodies
            a = u(0, 2 * np.pi)
            clen = u(0.6, 1.0)
            parts.append(ellipsoid((0.17 * np.cos(a), 0.17 * np.sin(a), height - 0.12 - clen / 2),
                                   (0.12, 0.22, clen / 2), float(u(0.1, 0.9))))
        return Mesh.concat(parts), dict(width_m=0.6, depth_m=0.6, radius_m=0.4)
    if kind == "tree":  # a trunk (upright or leaning), a few branches and a crown of a few blobs
        trunk_r, crown_base = u(0.06, 0.25), u(1.6, 3.0)
        lean_dir = u(0, 2 * np.pi)
        lean = u(0.0, 0.12) * np.array([np.cos(lean_dir), np.sin(lean_dir)])  # rad from vertical
        top = np.array([*(lean * (crown_base + 0.3)), crown_base + 0.3])
        parts = [cylinder((0, 0, 0), top, trunk_r, refl * 0.6, 10)]
        for _ in range(int(rng.integers(0, 4))):  # branches leaving the trunk below the crown
            z0 = u(0.9, crown_base)
            start = np.array([*(lean * z0), z0])
            b = u(0, 2 * np.pi)
            length, rise = u(0.4, 1.4), u(0.2, 1.2)
            end = start + length * np.array([np.cos(b), np.sin(b), rise]) / np.hypot(1.0, rise)
            parts.append(cylinder(start, end, u(0.015, 0.5 * trunk_r + 0.01), refl * 0.6, 6))
        crown_r = u(0.8, 2.2)
        for _ in range(int(rng.integers(1, 4))):
            a, off = u(0, 2 * np.pi), u(0.0, 0.4) * crown_r
            centre = (top[0] + off * np.cos(a), top[1] + off * np.sin(a), crown_base + crown_r * u(0.6, 1.0))
            parts.append(ellipsoid(centre, (crown_r * u(0.7, 1.0), crown_r * u(0.7, 1.0), crown_r * u(0.6, 1.0)),
                                   float(u(0.1, 0.5)), 10))
        mesh = Mesh.concat(parts)
        mesh.vertices[:, 2] = np.maximum(mesh.vertices[:, 2], 0.0)  # a leaning trunk's cap stops at the floor
        return mesh, dict(width_m=2 * trunk_r, depth_m=2 * trunk_r, radius_m=max(trunk_r, 0.3))
    if kind == "street_pole":  # lamp post, traffic-light or sign pole: thin, often above 2 m
        radius, height = u(0.04, 0.15), u(1.2, 8.0)
        parts = [cylinder((0, 0, 0), (0, 0, height), radius, refl, 10)]
        if height > 3.0 and rng.random() < 0.5:  # an arm with a lamp or signal head
            arm = u(0.5, 2.0)
            parts.append(cylinder((0, 0, height - 0.1), (arm, 0, height - 0.1), 0.05, refl, 6))
        if rng.random() < 0.4:  # a box or plate on the pole at person height
            bh = u(0.3, 0.8)
            parts.append(box((radius + 0.05, 0, u(1.0, 2.0)), (0.1, u(0.2, 0.5), bh), float(u(0.2, 0.9))))
        return Mesh.concat(parts), dict(width_m=2 * radius, depth_m=2 * radius, radius_m=max(radius, 0.2))
    if kind == "bollard":
        radius, height = u(0.06, 0.15), u(0.6, 1.2)
        parts = [cylinder((0, 0, 0), (0, 0, height), radius, refl, 10)]
        return Mesh.concat(parts), dict(width_m=2 * radius, depth_m=2 * radius, radius_m=radius)
    if kind == "bush":
        w, h = u(0.5, 1.6), u(0.6, 1.8)
        parts = [ellipsoid((0, 0, h / 2), (w / 2, w / 2 * u(0.7, 1.0), h / 2), float(u(0.1, 0.5)), 10)]
        for _ in range(int(rng.integers(1, 4))):
            a, rr = u(0, 2 * np.pi), u(0.15, 0.3)
            parts.append(ellipsoid((0.35 * w * np.cos(a), 0.35 * w * np.sin(a), u(0.4, 0.8) * h), (rr, rr, rr),
                                   float(u(0.1, 0.5)), 6))
        return Mesh.concat(parts), dict(width_m=w, depth_m=w, radius_m=w / 2 + 0.1)
    if kind == "car":  # parked car: body and cabin along local x
        length, w = u(3.8, 4.9), u(1.65, 1.95)
        body_h, roof_h = u(0.75, 1.0), u(1.35, 1.75)
        parts = [box((0, 0, 0.2 + (body_h - 0.2) / 2), (length, w, body_h - 0.2), refl),
                 box((-0.1 * length, 0, (body_h + roof_h) / 2), (0.5 * length, 0.9 * w, roof_h - body_h),
                     float(u(0.05, 0.3)))]
        for dx in (-1, 1):
            for dy in (-1, 1):
                parts.append(cylinder((dx * 0.33 * length, dy * w / 2 * 0.95, 0.32),
                                      (dx * 0.33 * length, dy * w / 2 * 1.02, 0.32), 0.32, 0.05, 12))
        return Mesh.concat(parts), dict(width_m=w, depth_m=length, radius_m=np.hypot(length, w) / 2)
    if kind == "cyclist":  # a bicycle along local x with its rider (not a pedestrian)
        wheel = u(0.3, 0.36)
        base = u(1.0, 1.15)
        parts = [cylinder((dx * base / 2, -0.02, wheel), (dx * base / 2, 0.02, wheel), wheel, 0.2, 14)
                 for dx in (-1, 1)]
        parts.append(cylinder((-base / 2, 0, wheel), (0.1, 0, wheel + 0.5), 0.025, refl, 6))
        parts.append(cylinder((0.1, 0, wheel + 0.5), (base / 2, 0, wheel), 0.025, refl, 6))
        saddle = wheel + u(0.55, 0.75)
        torso = u(0.55, 0.7)
        lean = u(0.3, 0.8)  # rad from vertical, forward
        top = np.array([-0.1 + torso * np.sin(lean), 0.0, saddle + torso * np.cos(lean)])
        parts.append(ellipsoid(((-0.1 + top[0]) / 2, 0.0, (saddle + top[2]) / 2),
                               (torso / 2, u(0.17, 0.25), torso / 2 * 0.8), float(u(0.05, 0.95)), 8))
        parts.append(ellipsoid(top + np.array([0.1, 0, 0.15]), (0.1, 0.09, 0.12), float(u(0.05, 0.6)), 8))
        for dy in (-1, 1):  # legs to the pedals
            parts.append(cylinder((-0.1, dy * 0.1, saddle), (0.05, dy * 0.12, wheel), 0.06, float(u(0.05, 0.9)), 6))
        return Mesh.concat(parts), dict(width_m=0.6, depth_m=base + 2 * wheel, radius_m=(base + 2 * wheel) / 2)
    if kind == "cabinet":  # utility or electrical box, sometimes on a plinth
        w, d, h = u(0.35, 1.0), u(0.2, 0.6), u(0.8, 1.7)
        plinth = u(0.05, 0.3) if rng.random() < 0.4 else 0.0
        parts = [box((0, 0, plinth + h / 2), (d, w, h), refl)]
        if plinth:
            parts.append(box((0, 0, plinth / 2), (0.9 * d, 0.9 * w, plinth), refl * 0.5))
        return Mesh.concat(parts), dict(width_m=w, depth_m=d, radius_m=np.hypot(w, d) / 2)
    if kind == "panel":  # a freestanding board on two legs, or an A-frame sign
        w, bottom, top = u(0.35, 1.0), u(0.05, 0.6), u(1.0, 1.9)
        if rng.random() < 0.5:
            parts = [box((0, 0, (bottom + top) / 2), (u(0.02, 0.06), w, top - bottom), refl)]
            for dy in (-1, 1):
                parts.append(cylinder((0, dy * 0.45 * w, 0), (0, dy * 0.45 * w, bottom + 0.05), 0.02, refl, 6))
            return Mesh.concat(parts), dict(width_m=w, depth_m=0.1, radius_m=w / 2)
        h, spread = u(0.8, 1.3), u(0.15, 0.35)  # A-frame: two boards leaning together at the top
        tilt = np.arctan2(spread, h)
        parts = [_mesh("box", (0.02, w, h / np.cos(tilt)), _rot_y(sx * tilt), (sx * spread / 2, 0, h / 2),
                       refl) for sx in (-1, 1)]
        mesh = Mesh.concat(parts)
        mesh.vertices[:, 2] = np.maximum(mesh.vertices[:, 2], 0.0)
        return mesh, dict(width_m=w, depth_m=2 * spread, radius_m=np.hypot(w, 2 * spread) / 2)
    if kind == "sign_post":  # a traffic sign: a thin pole with one or two plates at its top
        radius, top = u(0.025, 0.05), u(2.0, 3.2)
        parts = [cylinder((0, 0, 0), (0, 0, top), radius, refl * 0.6, 8)]
        plate_refl = float(u(0.5, 1.0))  # retroreflective sheeting
        z, widest = top, 0.0
        for k in range(1 + int(rng.random() < 0.3)):
            shape, size = int(rng.integers(3)), u(0.4, 0.9)
            w, h = size, size * u(0.6, 1.4)  # (the aspect drawn for every shape, used by rectangles)
            h = min(h, z - 1.1) if shape == 1 else size  # plates stay above 1.1 m
            if k and z - h < 1.1:  # (a second one only where there is room)
                break
            centre = (radius + 0.02, 0.0, z - h / 2)
            if shape == 0:  # round
                parts.append(cylinder((radius + 0.01, 0, centre[2]), (radius + 0.03, 0, centre[2]), size / 2,
                                      plate_refl, 16))
            elif shape == 1:  # rectangular, wider than tall or taller than wide
                parts.append(box(centre, (0.02, w, h), plate_refl))
            else:  # a diamond: a square turned 45 deg
                parts.append(_mesh("box", (0.02, size / np.sqrt(2), size / np.sqrt(2)), _rot_x(np.pi / 4), centre,
                                   plate_refl))
            widest = max(widest, w)
            z -= h + 0.05
        return Mesh.concat(parts), dict(width_m=widest, depth_m=0.1, radius_m=max(widest / 2, 0.15))
    if kind == "bicycle":  # one to three parked bicycles side by side (a rack), each leaning a little
        n = int(rng.integers(1, 4))
        spacing = u(0.45, 0.7)
        parts = []
        length = 0.0
        for i in range(n):
            bike = _bicycle_mesh(rng)
            lean = u(-0.2, 0.2)  # rad about the bike's long axis
            v = bike.vertices @ _rot_x(lean).T
            if rng.random() < 0.5:  # racks hold bikes both ways round
                v = v * np.array([-1.0, -1.0, 1.0])
            v[:, 1] += (i - (n - 1) / 2) * spacing
            parts.append(Mesh(v, bike.triangles, bike.reflectance))
            length = max(length, float(np.ptp(bike.vertices[:, 0])))
        mesh = Mesh.concat(parts)
        mesh.vertices[:, 2] = np.maximum(mesh.vertices[:, 2], 0.0)
        width = (n - 1) * spacing + 0.6
        return mesh, dict(width_m=width, depth_m=length, radius_m=np.hypot(length, width) / 2)
    if kind == "kerb":  # a low step along local x (as walls, a chain of collision circles)
        length, h = u(3.0, 12.0), u(0.1, 0.25)
        parts = [box((0, 0, h / 2), (length, 0.25, h), refl)]
        return Mesh.concat(parts), dict(width_m=0.25, depth_m=length, length_m=length, radius_m=0.125)
    raise PedcalInputError(f"clutter kind must be one of {CLUTTER_KINDS + STREET_CLUTTER_KINDS}, got {kind!r}",
                           column="kind")


def _bicycle_mesh(rng: np.random.Generator) -> Mesh:
    """A bicycle along local x, standing upright, its wheels touching the floor: two tyres, the frame's
    tubes, fork, handlebar and saddle."""
    u = rng.uniform
    wheel, base = u(0.3, 0.36), u(0.98, 1.12)
    refl, tube = float(u(0.1, 0.9)), u(0.013, 0.022)
    rear, front = np.array([-base / 2, 0.0, wheel]), np.array([base / 2, 0.0, wheel])
    bracket = np.array([-0.05, 0.0, wheel - 0.03])
    seat_top = np.array([-base / 2 + 0.35, 0.0, wheel + u(0.45, 0.6)])
    head = np.array([base / 2 - 0.12, 0.0, wheel + u(0.42, 0.55)])
    parts = [ring(rear, wheel - 0.02, 0.02, 0.08), ring(front, wheel - 0.02, 0.02, 0.08)]
    for a, b in ((bracket, seat_top), (seat_top, head), (bracket, head), (head, front), (bracket, rear),
                 (seat_top, rear)):
        parts.append(cylinder(a, b, tube, refl, 6))
    bar = head + np.array([-0.05, 0.0, 0.12])
    parts.append(cylinder(head, bar, tube, refl, 6))
    half_bar = u(0.2, 0.3)
    parts.append(cylinder(bar + [0.0, -half_bar, 0.0], bar + [0.0, half_bar, 0.0], 0.014, float(u(0.05, 0.5)), 6))
    parts.append(box(seat_top + [0.0, 0.0, 0.05], (0.25, 0.12, 0.05), float(u(0.05, 0.3))))
    return Mesh.concat(parts)


# --------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------


@dataclass
class SceneObject:
    """One object of a scene with its ground truth. ``mesh_local`` is in the object's frame."""

    kind: str
    is_person: bool
    mesh_local: Mesh
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    width_m: float = 0.0  # extent along local y (shoulder width for people)
    depth_m: float = 0.0  # extent along local x
    radius_m: float = 0.3  # collision radius of the footprint (half thickness for walls)
    reflectance: float = 0.5  # mean reflectance of the surface (area-weighted is not needed)
    velocity_mps: tuple[float, float] = (0.0, 0.0)
    pose: str = ""  # person pose, "" for clutter
    length_m: float = 0.0  # walls: segment length along local x
    id: int | None = None
    params: dict = field(default_factory=dict)  # what rebuilds the mesh (person size, gait phase)

    @property
    def height_m(self) -> float:
        return self.mesh_local.z_max_m

    def mesh_scene(self) -> Mesh:
        return self.mesh_local.placed(self.x_m, self.y_m, self.yaw_rad)

    def collision_circles(self) -> np.ndarray:
        """(K, 3) circles [x, y, r] covering the footprint in the scene frame (walls as chains)."""
        if self.kind not in ("wall", "kerb"):
            return np.array([[self.x_m, self.y_m, self.radius_m]])
        s = np.arange(-self.length_m / 2, self.length_m / 2 + 1e-9, 0.1)
        return np.column_stack([self.x_m + s * np.cos(self.yaw_rad), self.y_m + s * np.sin(self.yaw_rad),
                                np.full(len(s), self.radius_m)])

    def truth(self) -> dict:
        """Ground truth as plain values."""
        return dict(id=self.id, kind=self.kind, is_person=self.is_person, x_m=self.x_m, y_m=self.y_m,
                    yaw_rad=self.yaw_rad, height_m=self.height_m, width_m=self.width_m,
                    depth_m=self.depth_m, reflectance=self.reflectance,
                    vx_mps=self.velocity_mps[0], vy_mps=self.velocity_mps[1], pose=self.pose)


def make_person(height_m: float, width_m: float, depth_m: float, pose: str, reflectance,
                rng: np.random.Generator, *, x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0,
                velocity_mps=(0.0, 0.0), gait_phase: float | None = None, garment: str = "none",
                backpack: bool = False, pushing: bool = False, random_clothing: bool = False) -> SceneObject:
    """A person SceneObject (mesh from ``person_mesh``) standing at (x, y) facing yaw.

    ``random_clothing`` draws the garment (GARMENT_SHARES), backpack (BACKPACK_SHARE) and a pram or
    trolley to push (PUSHING_SHARE) from the person's own mesh seed instead of taking ``garment``,
    ``backpack`` and ``pushing``: ``rng`` gives exactly the draws it gives without them, so scenes
    keep their layout (``random_scene`` then puts a pusher's pram in front where there is room)."""
    walking = pose in ("walking", "walking_carrying")
    gait_angle_rad = float(rng.uniform(-np.pi, np.pi)) if walking else 0.0
    if gait_phase is None:
        gait_phase = float(np.sin(gait_angle_rad))
    else:
        gait_angle_rad = float(np.arcsin(np.clip(gait_phase, -1.0, 1.0)))
    # The head and bag are drawn from their own seed, so re-posing the person keeps them.
    mesh_seed = int(rng.integers(2**62))
    if random_clothing:
        own = np.random.default_rng([mesh_seed, 1])
        names, shares = zip(*GARMENT_SHARES, strict=True)
        garment = str(own.choice(names, p=shares))
        backpack = bool(own.random() < BACKPACK_SHARE)
        pushing = bool(own.random() < PUSHING_SHARE)
    mesh = person_mesh(height_m, width_m, depth_m, pose, reflectance, np.random.default_rng(mesh_seed),
                       gait_phase=gait_phase, garment=garment, backpack=backpack, pushing=pushing)
    radius = max(width_m, depth_m) / 2 + 0.1
    refl = float(reflectance) if np.isscalar(reflectance) else float(np.mean(reflectance))
    return SceneObject(kind="person", is_person=True, mesh_local=mesh, x_m=x_m, y_m=y_m, yaw_rad=yaw_rad,
                       width_m=width_m, depth_m=depth_m, radius_m=radius,
                       reflectance=refl, velocity_mps=tuple(velocity_mps), pose=pose,
                       params=dict(height_m=height_m, reflectance=reflectance, gait_phase=gait_phase,
                                   gait_angle_rad=gait_angle_rad, mesh_seed=mesh_seed, garment=garment,
                                   backpack=backpack, pushing=pushing))


def pram_in_front(person: SceneObject) -> SceneObject:
    """The pram or trolley a pushing person (``params["pushing"]``) holds: its handle at the
    person's hands (``push_reach_m`` in front, PUSH_HANDLE_HEIGHT of the height), its body ahead,
    heading and velocity the person's. Its size comes from the person's own seed."""
    rng = np.random.default_rng([person.params["mesh_seed"], 2])
    u = rng.uniform
    refl = float(u(0.05, 0.9))
    handle_z, grip_y = PUSH_HANDLE_HEIGHT * person.height_m, u(0.2, 0.28)
    length, w = u(0.55, 1.0), u(0.45, 0.6)
    bottom, top_z = u(0.2, 0.35), u(0.7, 0.95)
    x0 = 0.12  # the body starts a little beyond the handle
    parts = [cylinder((0.0, -grip_y - 0.05, handle_z), (0.0, grip_y + 0.05, handle_z), 0.015, refl, 6)]
    for dy in (-1, 1):  # struts from the handle down to the body
        parts.append(cylinder((0.0, dy * grip_y, handle_z), (x0, dy * grip_y, top_z - 0.05), 0.012, refl, 6))
    if rng.random() < 0.5:  # a pram: a rounded bassinet
        parts.append(ellipsoid((x0 + length / 2, 0.0, (bottom + top_z) / 2),
                               (length / 2, w / 2, (top_z - bottom) / 2), refl, 10))
    else:  # a trolley: a basket
        parts.append(box((x0 + length / 2, 0.0, (bottom + top_z) / 2), (length, w, top_z - bottom), refl))
    for dx in (0.1, length - 0.1):
        for dy in (-1, 1):
            parts.append(cylinder((x0 + dx, dy * w / 2, 0.0), (x0 + dx, dy * w / 2, bottom), 0.015, refl, 6))
    mesh = Mesh.concat(parts)
    centre = x0 + length / 2
    mesh.vertices[:, 0] -= centre  # the object's origin at the body's centre
    ahead = push_reach_m(person.height_m) + centre
    c, s = np.cos(person.yaw_rad), np.sin(person.yaw_rad)
    return SceneObject(kind="pram", is_person=False, mesh_local=mesh, x_m=person.x_m + ahead * c,
                       y_m=person.y_m + ahead * s, yaw_rad=person.yaw_rad, width_m=w, depth_m=length + x0,
                       radius_m=(length + x0) / 2 + 0.05, reflectance=refl, velocity_mps=person.velocity_mps)


def make_clutter(kind: str, rng: np.random.Generator, *, x_m: float = 0.0, y_m: float = 0.0,
                 yaw_rad: float = 0.0, ceiling_height_m: float = 2.7) -> SceneObject:
    """A random clutter SceneObject of the given kind at (x, y) turned by yaw."""
    mesh, size = clutter_mesh(kind, rng, ceiling_height_m=ceiling_height_m)
    return SceneObject(kind=kind, is_person=False, mesh_local=mesh, x_m=x_m, y_m=y_m, yaw_rad=yaw_rad,
                       reflectance=float(np.mean(mesh.reflectance)), **size)


class Scene:
    """Objects on a floor (and optionally under a ceiling), with a cached open3d raycasting scene.

    ``add``/``move``/``remove``/``step`` invalidate the cache; the next ``raycasting()`` rebuilds
    it (one ``add_triangles`` per object; measured in benchmarks/bench_lidar_sim.py).
    """

    def __init__(self, objects: list[SceneObject] | None = None, *, floor_reflectance: float = 0.3,
                 floor_half_extent_m: float = 60.0, ceiling_height_m: float | None = None,
                 ceiling_reflectance: float = 0.6):
        self.objects: list[SceneObject] = []
        self.floor_reflectance = float(floor_reflectance)
        self.floor_half_extent_m = float(floor_half_extent_m)
        self.ceiling_height_m = ceiling_height_m
        self.ceiling_reflectance = float(ceiling_reflectance)
        self._next_id = 0
        self._cache = None
        for obj in objects or []:
            self.add(obj)

    # -- editing ---------------------------------------------------------------------------
    def add(self, obj: SceneObject) -> int:
        """Add an object; gives it the next free id unless it has one. Returns the id."""
        if obj.id is None:
            obj.id = self._next_id
        elif any(o.id == obj.id for o in self.objects) or obj.id < 0:
            raise PedcalInputError(f"object id {obj.id} is taken or negative (ids < 0 are the floor/ceiling)",
                                   column="id")
        self._next_id = max(self._next_id, obj.id + 1)
        self.objects.append(obj)
        self._cache = None
        return obj.id

    def get(self, obj_id: int) -> SceneObject:
        for o in self.objects:
            if o.id == obj_id:
                return o
        raise PedcalInputError(f"no object with id {obj_id} in the scene", column="id")

    def remove(self, obj_id: int) -> None:
        self.objects.remove(self.get(obj_id))
        self._cache = None

    def move(self, obj_id: int, x_m: float, y_m: float, yaw_rad: float | None = None) -> None:
        """Put an object at a new footprint position (and heading); its mesh is only re-placed."""
        o = self.get(obj_id)
        o.x_m, o.y_m = float(x_m), float(y_m)
        if yaw_rad is not None:
            o.yaw_rad = float(yaw_rad)
        self._cache = None

    def step(self, dt_s: float, *, animate: bool = True, stride_hz: float = 0.9) -> None:
        """Move every object with a velocity by dt; walking people also advance their gait."""
        for o in self.objects:
            vx, vy = o.velocity_mps
            if vx == 0.0 and vy == 0.0:
                continue
            o.x_m += vx * dt_s
            o.y_m += vy * dt_s
            if animate and o.is_person and o.pose in ("walking", "walking_carrying"):
                p = o.params
                p["gait_angle_rad"] = float(p["gait_angle_rad"] + 2 * np.pi * stride_hz * dt_s)
                p["gait_phase"] = float(np.sin(p["gait_angle_rad"]))
                o.mesh_local = person_mesh(p["height_m"], o.width_m, o.depth_m, o.pose, p["reflectance"],
                                           np.random.default_rng(p["mesh_seed"]), gait_phase=p["gait_phase"],
                                           garment=p["garment"], backpack=p["backpack"], pushing=p["pushing"])
        self._cache = None

    @property
    def people(self) -> list[SceneObject]:
        return [o for o in self.objects if o.is_person]

    def truth(self) -> list[dict]:
        return [o.truth() for o in self.objects]

    # -- raycasting ------------------------------------------------------------------------
    def raycasting(self):
        """(RaycastingScene, object id per geometry id, reflectance per (geometry, triangle)).

        Returns ``(scene, geom_object_id, geom_offset, triangle_reflectance)``: the reflectance
        of triangle p of geometry g is ``triangle_reflectance[geom_offset[g] + p]``.
        """
        if self._cache is not None:
            return self._cache
        rc = o3d.t.geometry.RaycastingScene()
        meshes: list[tuple[int, Mesh]] = [(FLOOR_ID, floor_mesh(self.floor_half_extent_m, 0.0, self.floor_reflectance))]
        if self.ceiling_height_m is not None:
            meshes.append((CEILING_ID, floor_mesh(self.floor_half_extent_m, self.ceiling_height_m,
                                                  self.ceiling_reflectance)))
        meshes += [(o.id, o.mesh_scene()) for o in self.objects]
        geom_object_id, offsets, refl = [], [], []
        offset = 0
        for obj_id, m in meshes:
            gid = rc.add_triangles(o3d.core.Tensor(m.vertices.astype(np.float32)),
                                   o3d.core.Tensor(m.triangles.astype(np.uint32)))
            assert gid == len(geom_object_id)
            geom_object_id.append(obj_id)
            offsets.append(offset)
            refl.append(m.reflectance)
            offset += len(m.triangles)
        self._cache = (rc, np.array(geom_object_id, dtype=np.int32), np.array(offsets, dtype=np.int64),
                       np.concatenate(refl).astype(np.float32))
        return self._cache


# --------------------------------------------------------------------------------------------
# Random scenes
# --------------------------------------------------------------------------------------------


def _range_draw(rng: np.random.Generator, value, name: str) -> int:
    lo, hi = (value, value) if np.isscalar(value) else value
    if not (0 <= lo <= hi):
        raise PedcalInputError(f"{name} must be a count or (min, max) with 0 <= min <= max, got {value!r}",
                               column=name)
    return int(rng.integers(lo, hi + 1))


def _clear(candidate: np.ndarray, placed: list[np.ndarray], margin_m: float) -> bool:
    if not placed:
        return True
    others = np.concatenate(placed)
    d = np.hypot(candidate[:, None, 0] - others[None, :, 0], candidate[:, None, 1] - others[None, :, 1])
    return bool(np.all(d > candidate[:, None, 2] + others[None, :, 2] + margin_m))


def _angular_interval(obj: SceneObject) -> tuple[float, float, float]:
    """(bearing, half width, range) of an object's footprint seen from the origin."""
    c = obj.collision_circles()
    b0 = np.arctan2(obj.y_m, obj.x_m)
    bearings = b0 + np.angle(np.exp(1j * (np.arctan2(c[:, 1], c[:, 0]) - b0)))  # unwrapped around b0
    ranges = np.hypot(c[:, 0], c[:, 1])
    half = np.arcsin(np.clip(c[:, 2] / np.maximum(ranges, 1e-6), 0, 1))
    lo, hi = np.min(bearings - half), np.max(bearings + half)
    return (lo + hi) / 2, (hi - lo) / 2, float(ranges.min())


def _occludes(front: SceneObject, back: SceneObject) -> bool:
    """Whether ``front`` hides part of ``back`` from the origin: overlapping bearings, nearer."""
    bf, hf, rf = _angular_interval(front)
    bb, hb, rb = _angular_interval(back)
    return abs(np.angle(np.exp(1j * (bf - bb)))) < hf + hb and rf < rb


def random_person(rng: np.random.Generator, *, static: bool) -> SceneObject:
    """A person of random height (1.45-1.95 m), build, clothing (colours, a skirt or coat, a
    backpack) and pose (not yet placed)."""
    height = rng.uniform(1.45, 1.95)
    width = rng.uniform(0.35, 0.55)
    depth = rng.uniform(0.2, 0.35)
    carrying = rng.random() < 0.3
    if static:
        pose = "carrying" if carrying else "standing"
    else:
        pose = "walking_carrying" if carrying else "walking"
    reflectance = (float(rng.uniform(0.05, 0.95)), float(rng.uniform(0.05, 0.95)))
    return make_person(height, width, depth, pose, reflectance, rng, random_clothing=True)


def _group_layout(rng: np.random.Generator, members: list[SceneObject]) -> np.ndarray:
    """(n, 3) [ahead_m, left_m, yaw_offset_rad] of each member relative to the row's centre and
    heading: side by side with 0-0.12 m between shoulders, each up to 0.1 m ahead of or behind the
    row, turned by N(0, 0.15 rad)."""
    n = len(members)
    widths = np.array([m.width_m for m in members])
    gaps = rng.uniform(0.0, 0.12, max(n - 1, 0))
    left = np.concatenate([[0.0], np.cumsum((widths[:-1] + widths[1:]) / 2 + gaps)])
    left -= (left[0] + left[-1]) / 2
    return np.column_stack([rng.uniform(-0.1, 0.1, n), left, rng.normal(0.0, 0.15, n)])


def _arrange_group(members: list[SceneObject], layout: np.ndarray, x_m: float, y_m: float, yaw_rad: float) -> None:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    for m, (ahead, left, dyaw) in zip(members, layout, strict=True):
        m.x_m, m.y_m = float(x_m + c * ahead - s * left), float(y_m + s * ahead + c * left)
        m.yaw_rad = float(np.angle(np.exp(1j * (yaw_rad + dyaw))))


def person_group(rng: np.random.Generator, n: int, *, static: bool, x_m: float = 0.0, y_m: float = 0.0,
                 yaw_rad: float = 0.0, velocity_mps=(0.0, 0.0)) -> list[SceneObject]:
    """``n`` random people (``random_person``) standing or walking together shoulder to shoulder,
    the row centred on (x, y) and facing ``yaw_rad`` (``_group_layout``), all with one velocity.
    Their footprints' collision circles overlap each other: place them as one (``random_scene``'s
    ``n_groups``). A scanner sees them as one wide cluster to be cut at the heads."""
    if n < 1:
        raise PedcalInputError(f"a group needs at least one person, got {n}", column="n")
    members = [random_person(rng, static=static) for _ in range(n)]
    _arrange_group(members, _group_layout(rng, members), x_m, y_m, yaw_rad)
    for m in members:
        m.velocity_mps = tuple(float(v) for v in velocity_mps)
    return members


def _bearings(mesh: Mesh, origin_xy, about_rad: float) -> tuple[float, float]:
    """(min, max) bearing of a mesh's vertices seen from ``origin_xy``, relative to ``about_rad``."""
    v = mesh.vertices
    rel = np.angle(np.exp(1j * (np.arctan2(v[:, 1] - origin_xy[1], v[:, 0] - origin_xy[0]) - about_rad)))
    return float(rel.min()), float(rel.max())


def hide_partly(scene: Scene, person: SceneObject, rng: np.random.Generator, *, kinds=HIDING_KINDS_STREET,
                origin_xy=(0.0, 0.0), margin_m: float = 0.05, min_range_m: float = 0.8,
                covered=(0.25, 0.75)) -> SceneObject | None:
    """Put an object of one of ``kinds`` (clutter kinds, or "person": a standing stranger) between
    ``person`` and the sensor at ``origin_xy`` so that it hides part of them, and add it to the scene.

    The occluder stands 0.1-1.2 m nearer than the person (between their collision circles), turned
    at random, and moved sideways (about the origin) until its outline covers a fraction drawn from
    ``covered`` of the person's width in bearing, from the left or the right (its mesh's bearings
    against the person's): a low occluder (a car, a bush, a box) hides also less than their
    height. Returns the occluder, or None when no such place is clear of the scene's objects (and
    of a 0.5 m robot at the origin) after 30 tries.
    """
    kind = str(kinds[int(rng.integers(len(kinds)))])
    occ = random_person(rng, static=True) if kind == "person" else make_clutter(kind, rng)
    dist = float(np.hypot(person.x_m - origin_xy[0], person.y_m - origin_xy[1]))
    bearing = float(np.arctan2(person.y_m - origin_xy[1], person.x_m - origin_xy[0]))
    p_lo, p_hi = _bearings(person.mesh_scene(), origin_xy, bearing)
    placed = [o.collision_circles() for o in scene.objects] + [np.array([[*origin_xy, 0.5]])]
    for _ in range(30):
        d_occ = dist - person.radius_m - occ.radius_m - rng.uniform(0.1, 1.2)
        yaw, share, left = rng.uniform(-np.pi, np.pi), rng.uniform(*covered), rng.random() < 0.5
        if d_occ < max(min_range_m, occ.radius_m + 0.5):
            continue
        occ.x_m, occ.y_m = origin_xy[0] + d_occ * np.cos(bearing), origin_xy[1] + d_occ * np.sin(bearing)
        occ.yaw_rad = float(yaw)
        o_lo, o_hi = _bearings(occ.mesh_scene(), origin_xy, bearing)
        # left (larger bearing): the occluder's right edge at the person's left edge minus the share
        shift = (p_hi - share * (p_hi - p_lo) - o_lo) if left else (p_lo + share * (p_hi - p_lo) - o_hi)
        b = bearing + shift
        occ.x_m = float(origin_xy[0] + d_occ * np.cos(b))
        occ.y_m = float(origin_xy[1] + d_occ * np.sin(b))
        occ.yaw_rad = float(yaw + shift)
        if _clear(occ.collision_circles(), placed, margin_m):
            scene.add(occ)
            return occ
    return None


def random_scene(rng: np.random.Generator | int, *, n_people=(1, 6), n_clutter=(3, 10),
                 area=(0.8, 5.0, -4.0, 4.0), fov_half_angle_deg: float = 60.0,
                 static_fraction: float = 0.4, allow_occlusion: bool = True,
                 walking_speed_mps=(0.4, 1.5), ceiling_height_m: float | None = None,
                 max_person_range_m: float | None = None, margin_m: float = 0.05,
                 clutter_weights: dict[str, float] | None = None, n_groups=0, group_size=(2, 5),
                 hidden_share: float = 0.0) -> Scene:
    """A random scene in front of the robot (robot base at the origin facing +x).

    People are placed inside ``area`` = (x_min, x_max, y_min, y_max), within
    ``fov_half_angle_deg`` of the +x axis (what the two front FX8s see) and at most
    ``max_person_range_m`` (default x_max) from the origin; three quarters of the other clutter
    in that cone too, the rest and the walls anywhere in ``area`` (walls may extend beyond it).
    No footprints interpenetrate. A fraction ``static_fraction`` of the people stand still, the
    others walk along their heading at a speed from ``walking_speed_mps``; a person who pushes
    (``make_person``'s random clothing) gets a pram or trolley in front (``pram_in_front``) where it
    fits. With
    ``allow_occlusion=False`` nothing nearer overlaps a person in bearing from the origin.
    Objects that cannot be placed after many draws are left out with a warning.
    ``clutter_weights`` (kind -> relative frequency) replaces the indoor mix ``CLUTTER_WEIGHTS``,
    e.g. with ``OUTDOOR_CLUTTER_WEIGHTS`` or ``STREET_CLUTTER_WEIGHTS`` for a street.
    ``n_groups`` (a count or (min, max)) rows of ``group_size`` people standing or walking
    shoulder to shoulder (``person_group``) go in after the single people; a ``hidden_share`` of
    all people then get an occluder in front (``hide_partly``: ``HIDING_KINDS_INDOOR``, or
    ``HIDING_KINDS_STREET`` with ``clutter_weights``). Both draw nothing at their defaults (0), so
    a scene drawn without them is the same as before they existed.
    """
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    x_min, x_max, y_min, y_max = area
    if not (x_min < x_max and y_min < y_max):
        raise PedcalInputError(f"area must be (x_min, x_max, y_min, y_max) with min < max, got {area!r}",
                               column="area")
    if not 0.0 <= static_fraction <= 1.0:
        raise PedcalInputError(f"static_fraction must be in [0, 1], got {static_fraction}", column="static_fraction")
    if not 0.0 <= hidden_share <= 1.0:
        raise PedcalInputError(f"hidden_share must be in [0, 1], got {hidden_share}", column="hidden_share")
    if hidden_share > 0 and not allow_occlusion:
        raise PedcalInputError("hidden_share > 0 hides people on purpose: it needs allow_occlusion=True",
                               column="hidden_share")
    n_p = _range_draw(rng, n_people, "n_people")
    n_c = _range_draw(rng, n_clutter, "n_clutter")
    ceiling = 2.7 if ceiling_height_m is None else ceiling_height_m
    scene = Scene(floor_reflectance=float(rng.uniform(0.15, 0.5)), ceiling_height_m=ceiling_height_m)
    # The robot's own footprint.
    placed: list[np.ndarray] = [np.array([[0.0, 0.0, 0.5]])]
    mix = CLUTTER_WEIGHTS if clutter_weights is None else clutter_weights
    kinds = list(CLUTTER_KINDS) if clutter_weights is None else list(mix)
    weights = np.array([mix[k] for k in kinds])
    clutter_kinds = [str(k) for k in rng.choice(kinds, size=n_c, p=weights / weights.sum())]
    # Walls first (they are long), then people, then the rest of the clutter.
    order = sorted(clutter_kinds, key=lambda k: k not in ("wall", "kerb"))
    walls = [k for k in order if k in ("wall", "kerb")]
    rest = [k for k in order if k not in ("wall", "kerb")]
    half_fov = np.radians(fov_half_angle_deg)
    r_min = max(x_min, 0.8)
    r_max = x_max if max_person_range_m is None else float(max_person_range_m)
    if r_max <= r_min:
        raise PedcalInputError(f"people need room between {r_min} m and max_person_range_m = {r_max} m",
                               column="max_person_range_m")
    dropped: list[str] = []

    def place(obj: SceneObject, person: bool) -> bool:
        # People always, most clutter too, go in the sensors' cone; the rest of the clutter anywhere.
        in_cone = person or (obj.kind not in ("wall", "kerb") and rng.random() < CLUTTER_IN_VIEW)
        for _ in range(200):
            if in_cone:
                r = rng.uniform(r_min, r_max if person else max(r_max, x_max))
                b = rng.uniform(-half_fov, half_fov)
                x, y = r * np.cos(b), r * np.sin(b)
                if not (x_min <= x <= x_max and y_min <= y <= y_max):
                    continue
            else:
                x, y = rng.uniform(x_min, x_max), rng.uniform(y_min, y_max)
            obj.x_m, obj.y_m, obj.yaw_rad = float(x), float(y), float(rng.uniform(-np.pi, np.pi))
            circles = obj.collision_circles()
            if not _clear(circles, placed, margin_m):
                continue
            if not allow_occlusion:
                if person and any(_occludes(o, obj) or (o.is_person and _occludes(obj, o)) for o in scene.objects):
                    continue
                if not person and any(_occludes(obj, o) for o in scene.people):
                    continue
            placed.append(circles)
            scene.add(obj)
            return True
        return False

    def place_group(members: list[SceneObject]) -> bool:
        layout = _group_layout(rng, members)
        for _ in range(200):
            r, b = rng.uniform(r_min, r_max), rng.uniform(-half_fov, half_fov)
            _arrange_group(members, layout, r * np.cos(b), r * np.sin(b), rng.uniform(-np.pi, np.pi))
            xy = np.array([[m.x_m, m.y_m] for m in members])
            rr, bb = np.hypot(xy[:, 0], xy[:, 1]), np.abs(np.arctan2(xy[:, 1], xy[:, 0]))
            if not (np.all((xy[:, 0] >= x_min) & (xy[:, 0] <= x_max) & (xy[:, 1] >= y_min) & (xy[:, 1] <= y_max))
                    and np.all((rr >= r_min) & (rr <= r_max) & (bb <= half_fov))):
                continue
            circles = np.vstack([m.collision_circles() for m in members])
            if not _clear(circles, placed, margin_m):
                continue
            if not allow_occlusion and any(_occludes(o, m) or (o.is_person and _occludes(m, o))
                                           for o in scene.objects for m in members):
                continue
            placed.append(circles)
            for m in members:
                scene.add(m)
            return True
        return False

    for kind in walls:
        if not place(make_clutter(kind, rng, ceiling_height_m=ceiling), False):
            dropped.append(kind)
    for _ in range(n_p):
        static = bool(rng.random() < static_fraction)
        person = random_person(rng, static=static)
        if not place(person, True):
            dropped.append("person")
            continue
        if not static:
            speed = rng.uniform(*walking_speed_mps)
            person.velocity_mps = (float(speed * np.cos(person.yaw_rad)), float(speed * np.sin(person.yaw_rad)))
        if person.params.get("pushing"):
            pram = pram_in_front(person)
            if _clear(pram.collision_circles(), placed[:-1], margin_m):  # (not against its own pusher)
                placed.append(pram.collision_circles())
                scene.add(pram)
    n_g = 0 if np.isscalar(n_groups) and n_groups == 0 else _range_draw(rng, n_groups, "n_groups")
    for _ in range(n_g):
        static = bool(rng.random() < static_fraction)
        members = person_group(rng, _range_draw(rng, group_size, "group_size"), static=static)
        if not place_group(members):
            dropped.append(f"group of {len(members)}")
            continue
        if not static:
            speed, yaw = rng.uniform(*walking_speed_mps), members[0].yaw_rad
            for m in members:
                m.velocity_mps = (float(speed * np.cos(yaw)), float(speed * np.sin(yaw)))
    if hidden_share > 0:
        kinds_hiding = HIDING_KINDS_INDOOR if clutter_weights is None else HIDING_KINDS_STREET
        for p in list(scene.people):
            if rng.random() < hidden_share:
                occ = hide_partly(scene, p, rng, kinds=kinds_hiding, margin_m=margin_m)
                if occ is not None:
                    placed.append(occ.collision_circles())
    for kind in rest:
        if not place(make_clutter(kind, rng, ceiling_height_m=ceiling), False):
            dropped.append(kind)
    if dropped:
        warnings.warn(f"random_scene: could not place {len(dropped)} object(s) without overlap "
                      f"({', '.join(dropped)}); the scene holds {len(scene.objects)}", stacklevel=2)
    return scene
