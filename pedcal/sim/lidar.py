"""Seeded raycast 3D LIDAR simulator (open3d ``RaycastingScene``) for person detection.

The tracking paper (Misu and Miura) uses two FX8 3D LIDARs on the robot's front: 97 x 61 rays,
60 x 50 deg field of view, 0.3-5 m, about +-50 mm range error, 4 Hz, with reflectance; yawed
apart they cover 120 deg. ``LIDAR_PRESETS`` also holds sparser/denser and longer-range sensors so
a detector can be trained across resolutions.

Frames: the robot base frame has z = 0 on the floor, x forward, y left (pedcal.frames). A
``Mount`` places a LIDAR on the base with the pedcal convention (sensor x = optical axis,
positive pitch looks down). ``render`` returns points in the base frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
import open3d as o3d

from pedcal.errors import PedcalInputError
from pedcal.frames import rot_from_ypr_deg
from pedcal.sim.scene import Scene


@dataclass(frozen=True)
class LidarModel:
    """A scanning LIDAR: a regular azimuth x elevation grid of rays in the sensor frame, or, with
    ``elevations_deg``, one row of rays per listed beam elevation (spinning LIDARs whose beams are
    packed closer near the horizon; ``n_vertical`` is then their number, ``fov_vertical_deg`` and
    ``vertical_center_deg`` follow from them: ``LidarModel.from_beams``).

    Range noise is added along the ray: ``range_noise="uniform"`` draws from
    +-sqrt(3)·std (the FX8's "+-50 mm" is such a band), ``"gaussian"`` from N(0, std).
    Intensity (0..1) = reflectance · |cos(incidence)| · min(1, (ref_range / r)^exponent) + noise;
    returns weaker than ``min_return_intensity`` are lost, and each ray drops out with
    ``dropout_prob``.
    """

    name: str
    n_horizontal: int
    n_vertical: int
    fov_horizontal_deg: float
    fov_vertical_deg: float
    min_range_m: float
    max_range_m: float
    range_noise_std_m: float = 0.03
    range_noise: str = "uniform"
    intensity_noise_std: float = 0.02
    intensity_range_exponent: float = 0.5
    intensity_ref_range_m: float = 1.0
    min_return_intensity: float = 0.005
    dropout_prob: float = 0.01
    rate_hz: float = 4.0
    vertical_center_deg: float = 0.0  # elevation of the centre row (up positive)
    elevations_deg: tuple[float, ...] | None = None  # beam elevations, ascending (up positive)

    def __post_init__(self):
        bad = []
        if self.elevations_deg is not None:
            el = np.asarray(self.elevations_deg, dtype=float)
            if len(el) != self.n_vertical or not np.all(np.diff(el) > 0):
                bad.append(f"elevations_deg must hold n_vertical = {self.n_vertical} ascending angles")
            elif not (np.isclose(el[-1] - el[0], self.fov_vertical_deg)
                      and np.isclose((el[-1] + el[0]) / 2, self.vertical_center_deg)):
                bad.append("fov_vertical_deg and vertical_center_deg must be the span and middle of "
                           "elevations_deg (LidarModel.from_beams sets them)")
        if self.n_horizontal < 1 or self.n_vertical < 1:
            bad.append("n_horizontal and n_vertical must be >= 1")
        if not (0 < self.fov_horizontal_deg <= 360 and 0 <= self.fov_vertical_deg < 180):
            bad.append("fov_horizontal_deg must be in (0, 360], fov_vertical_deg in [0, 180)")
        if not (0 <= self.min_range_m < self.max_range_m):
            bad.append("need 0 <= min_range_m < max_range_m")
        if self.range_noise not in ("uniform", "gaussian"):
            bad.append("range_noise must be 'uniform' or 'gaussian'")
        if not 0 <= self.dropout_prob < 1:
            bad.append("dropout_prob must be in [0, 1)")
        if self.range_noise_std_m < 0 or self.intensity_noise_std < 0:
            bad.append("noise standard deviations must be >= 0")
        if bad:
            raise PedcalInputError(f"LidarModel {self.name!r}: " + "; ".join(bad))

    @classmethod
    def from_beams(cls, name: str, elevations_deg, n_horizontal: int, fov_horizontal_deg: float,
                   min_range_m: float, max_range_m: float, **kwargs) -> LidarModel:
        """A LIDAR with one beam at each of ``elevations_deg`` (any order; deg, up positive)."""
        el = tuple(sorted(float(e) for e in elevations_deg))
        return cls(name, n_horizontal, len(el), fov_horizontal_deg, el[-1] - el[0], min_range_m, max_range_m,
                   vertical_center_deg=(el[-1] + el[0]) / 2, elevations_deg=el, **kwargs)

    @property
    def n_rays(self) -> int:
        return self.n_horizontal * self.n_vertical

    def with_(self, **changes) -> LidarModel:
        """A copy with some fields changed (e.g. ``range_noise_std_m=0``)."""
        return replace(self, **changes)

    def ray_angles_rad(self) -> tuple[np.ndarray, np.ndarray]:
        """(azimuth, elevation) of every ray, each (n_vertical * n_horizontal,), row-major by elevation."""
        return _ray_angles(self)

    def ray_directions_sensor(self) -> np.ndarray:
        """(n_rays, 3) unit ray directions in the sensor frame (x optical axis, y left, z up)."""
        return _ray_directions(self)


@lru_cache(maxsize=64)
def _ray_angles(lidar: LidarModel) -> tuple[np.ndarray, np.ndarray]:
    half_h = np.radians(lidar.fov_horizontal_deg) / 2
    if lidar.fov_horizontal_deg >= 360.0:  # spinning: no duplicate column at +-180
        az = np.linspace(-np.pi, np.pi, lidar.n_horizontal, endpoint=False)
    else:
        az = np.linspace(-half_h, half_h, lidar.n_horizontal)
    if lidar.elevations_deg is not None:
        el = np.radians(np.asarray(lidar.elevations_deg, dtype=float))
    else:
        half_v = np.radians(lidar.fov_vertical_deg) / 2
        el = np.radians(lidar.vertical_center_deg) + np.linspace(-half_v, half_v, lidar.n_vertical)
    az_grid, el_grid = np.meshgrid(az, el)
    az_grid.setflags(write=False)
    el_grid.setflags(write=False)
    return az_grid.ravel(), el_grid.ravel()


@lru_cache(maxsize=64)
def _ray_directions(lidar: LidarModel) -> np.ndarray:
    az, el = _ray_angles(lidar)
    d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    d.setflags(write=False)
    return d


LIDAR_PRESETS: dict[str, LidarModel] = {
    # Misu and Miura's sensor: 97 x 61, 60 x 50 deg, 0.3-5 m, +-50 mm, 4 Hz.
    "fx8": LidarModel("fx8", 97, 61, 60.0, 50.0, 0.3, 5.0, range_noise_std_m=0.03, rate_hz=4.0),
    "fx8_far": LidarModel("fx8_far", 97, 61, 60.0, 50.0, 0.3, 8.0, range_noise_std_m=0.03, rate_hz=4.0),
    # Sparse spinning 16-beam (VLP-16-like): 0.4 deg azimuth, 2 deg between beams, +-30 mm.
    "spin16": LidarModel("spin16", 900, 16, 360.0, 30.0, 0.5, 15.0, range_noise_std_m=0.015,
                         range_noise="gaussian", rate_hz=10.0, dropout_prob=0.005),
    # 32-beam spinning (OS1-32-like).
    "spin32": LidarModel("spin32", 1024, 32, 360.0, 40.0, 0.5, 20.0, range_noise_std_m=0.015,
                         range_noise="gaussian", rate_hz=10.0, dropout_prob=0.005),
    # Dense solid-state.
    "solid_dense": LidarModel("solid_dense", 160, 100, 70.0, 55.0, 0.2, 10.0, range_noise_std_m=0.02,
                              range_noise="gaussian", rate_hz=10.0),
    # Automotive spinning LIDARs at the resolution of their data sheets (0.2 deg azimuth at 10 Hz):
    # 32 beams over +10.67..-30.67 deg (HDL-32E-like) and 64 beams over +2..-24.9 deg (HDL-64E-like).
    "hdl32": LidarModel("hdl32", 1800, 32, 360.0, 41.33, 0.5, 70.0, range_noise_std_m=0.02,
                        range_noise="gaussian", rate_hz=10.0, dropout_prob=0.005, vertical_center_deg=-10.0),
    "hdl64": LidarModel("hdl64", 2000, 64, 360.0, 26.9, 0.9, 80.0, range_noise_std_m=0.02,
                        range_noise="gaussian", rate_hz=10.0, dropout_prob=0.005, vertical_center_deg=-11.45),
    # Hesai Pandar40-like automotive LIDAR (data sheet): 40 beams from +7 to -16 deg, 1 deg apart
    # except between -6 and +2 deg, where they are 1/3 deg apart (dense about the horizon, where a
    # roof-mounted sensor sees people's bodies at 5-40 m); 0.2 deg azimuth at 10 Hz, +-2 cm.
    "pandar40": LidarModel.from_beams(
        "pandar40", [7.0, 6.0, 5.0, 4.0, 3.0, 2.0] + [round(float(e), 4) + 0.0 for e in np.linspace(5 / 3, -6.0, 24)]
        + [-7.0 - k for k in range(10)], 1800, 360.0, 0.3, 200.0, range_noise_std_m=0.02,
        range_noise="gaussian", rate_hz=10.0, dropout_prob=0.005),
    # Structured-light / ToF depth camera (Kinect-class): 640 x 480 over 58 x 45 deg, 0.5-6 m. Far
    # denser than anything the detector is trained on; ``pedcal detect --sensor depth-camera``
    # thins it to the training density first.
    "depth_camera": LidarModel("depth_camera", 640, 480, 58.0, 45.0, 0.5, 6.0, range_noise_std_m=0.01,
                               range_noise="gaussian", rate_hz=30.0, dropout_prob=0.02),
    # Sparse time-of-flight camera, coarser than the FX8 (0.95 x 1.15 deg a ray); the detector's
    # training leaves it out, so ``pedcal detect-eval --preset sparse_tof`` tests generalization.
    "sparse_tof": LidarModel("sparse_tof", 64, 40, 60.0, 45.0, 0.3, 6.0, range_noise_std_m=0.04, rate_hz=10.0),
}


@dataclass(frozen=True)
class Mount:
    """Pose of a LIDAR on the robot base (metres, degrees; pitch +: looks down, as pedcal.frames)."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 1.0
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    @property
    def position_base(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.z_m])

    @property
    def R_base_sensor(self) -> np.ndarray:
        return rot_from_ypr_deg([self.yaw_deg, self.pitch_deg, self.roll_deg])


def fx8_pair_mounts(height_m: float = 1.0, yaw_deg: float = 30.0, pitch_deg: float = 0.0,
                    x_m: float = 0.2, y_m: float = 0.05) -> tuple[Mount, Mount]:
    """Two FX8s on the robot's front at ~1 m, yawed +-30 deg: together 120 deg of azimuth.

    The left one (y = +y_m) looks left, so the pair's inner edge rays run parallel to x at
    y = +-y_m: a 2·y_m wide blind strip straight ahead (0.1 m by default, narrower than a person).
    """
    return (Mount(x_m, y_m, height_m, yaw_deg, pitch_deg), Mount(x_m, -y_m, height_m, -yaw_deg, pitch_deg))


@dataclass
class LidarFrame:
    """One simulated scan in the robot base frame.

    ``points``: (N, 4) float32 [x, y, z, intensity 0..1]; ``object_id``: (N,) int32 (-1 floor,
    -2 ceiling); ``mount_index``: (N,) int16, which mount saw the point; ``ray_index``: (N,)
    int32 ray within that mount (row-major: elevation row · n_horizontal + azimuth column);
    ``objects``: ground truth per scene object (``Scene.truth()`` entries, positions in the base
    frame, plus ``visible_points``); ``sensor_positions_base``: (M, 3) where each mount's sensor sits
    in the base frame (its height above the floor is ``[:, 2]``).
    """

    points: np.ndarray
    object_id: np.ndarray
    mount_index: np.ndarray
    ray_index: np.ndarray
    objects: list[dict] = field(default_factory=list)
    stamp_s: float = 0.0
    sensor_positions_base: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def sensor_height_m(self) -> float:
        """Mean height of the sensors above the floor (m)."""
        return float(self.sensor_positions_base[:, 2].mean())

    @property
    def xyz(self) -> np.ndarray:
        return self.points[:, :3]

    @property
    def intensity(self) -> np.ndarray:
        return self.points[:, 3]

    def visible_people(self, min_points: int = 10) -> list[dict]:
        """Ground truth of the people with at least ``min_points`` points in this frame."""
        return [o for o in self.objects if o["is_person"] and o["visible_points"] >= min_points]


def _base_pose_matrix(base_pose) -> tuple[np.ndarray, np.ndarray]:
    x, y, yaw = (0.0, 0.0, 0.0) if base_pose is None else base_pose
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([x, y, 0.0])


def render(scene: Scene, lidar: LidarModel | str, mounts, rng: np.random.Generator | int, *,
           base_pose=None, stamp_s: float = 0.0) -> LidarFrame:
    """Cast every ray of every mount into the scene and return the noisy points in the base frame.

    ``lidar``: a LidarModel or a LIDAR_PRESETS name; ``mounts``: one Mount or a sequence;
    ``base_pose``: the robot's (x_m, y_m, yaw_rad) in the scene frame (default: at the origin).
    All rays go to open3d in one ``cast_rays`` call; the scene's raycasting structure is cached
    until the scene changes. Hits beyond [min_range, max_range] are dropped before noise; range
    noise moves a point along its ray.
    """
    if isinstance(lidar, str):
        if lidar not in LIDAR_PRESETS:
            raise PedcalInputError(f"unknown LIDAR preset {lidar!r}; expected one of {sorted(LIDAR_PRESETS)}",
                                   column="lidar")
        lidar = LIDAR_PRESETS[lidar]
    mounts = (mounts,) if isinstance(mounts, Mount) else tuple(mounts)
    if not mounts:
        raise PedcalInputError("render needs at least one Mount", column="mounts")
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng

    R_scene_base, t_scene_base = _base_pose_matrix(base_pose)
    d_sensor = lidar.ray_directions_sensor()
    n = lidar.n_rays
    # Ray origins/directions in the base frame, then in the scene frame for casting.
    d_base = np.concatenate([d_sensor @ m.R_base_sensor.T for m in mounts])
    o_base = np.repeat(np.stack([m.position_base for m in mounts]), n, axis=0)
    rays_scene = np.hstack([o_base @ R_scene_base.T + t_scene_base, d_base @ R_scene_base.T]).astype(np.float32)

    rc, geom_object_id, geom_offset, tri_refl = scene.raycasting()
    hits = rc.cast_rays(o3d.core.Tensor(rays_scene))
    t_hit = hits["t_hit"].numpy()
    keep = np.isfinite(t_hit) & (t_hit >= lidar.min_range_m) & (t_hit <= lidar.max_range_m)
    keep &= rng.random(len(t_hit)) >= lidar.dropout_prob
    idx = np.flatnonzero(keep)
    geom = hits["geometry_ids"].numpy()[idx].astype(np.int64)
    prim = hits["primitive_ids"].numpy()[idx].astype(np.int64)
    normal_scene = hits["primitive_normals"].numpy()[idx]
    range_m = t_hit[idx].astype(float)

    reflectance = tri_refl[geom_offset[geom] + prim]
    d_hit_scene = rays_scene[idx, 3:]
    cos_incidence = np.abs(np.einsum("ij,ij->i", normal_scene, d_hit_scene))
    falloff = np.minimum(1.0, (lidar.intensity_ref_range_m / np.maximum(range_m, 1e-6))
                         ** lidar.intensity_range_exponent)
    intensity = reflectance * cos_incidence * falloff
    if lidar.intensity_noise_std > 0:
        intensity = intensity + rng.normal(0.0, lidar.intensity_noise_std, len(idx))
    strong = intensity >= lidar.min_return_intensity
    idx, range_m, intensity, geom = idx[strong], range_m[strong], intensity[strong], geom[strong]

    if lidar.range_noise_std_m > 0:
        if lidar.range_noise == "uniform":
            half = np.sqrt(3.0) * lidar.range_noise_std_m
            range_m = range_m + rng.uniform(-half, half, len(idx))
        else:
            range_m = range_m + rng.normal(0.0, lidar.range_noise_std_m, len(idx))
    xyz_base = o_base[idx] + d_base[idx] * range_m[:, None]
    points = np.empty((len(idx), 4), dtype=np.float32)
    points[:, :3] = xyz_base
    points[:, 3] = np.clip(intensity, 0.0, 1.0)
    object_id = geom_object_id[geom].astype(np.int32)

    counts = dict(zip(*np.unique(object_id, return_counts=True), strict=True))
    objects = []
    for o in scene.objects:
        t = o.truth()
        p_base = R_scene_base.T @ (np.array([o.x_m, o.y_m, 0.0]) - t_scene_base)
        v_base = R_scene_base.T @ np.array([*o.velocity_mps, 0.0])
        yaw0 = 0.0 if base_pose is None else base_pose[2]
        t.update(x_m=float(p_base[0]), y_m=float(p_base[1]), yaw_rad=float(np.angle(np.exp(1j * (o.yaw_rad - yaw0)))),
                 vx_mps=float(v_base[0]), vy_mps=float(v_base[1]), visible_points=int(counts.get(o.id, 0)))
        objects.append(t)
    return LidarFrame(points=points, object_id=object_id, mount_index=(idx // n).astype(np.int16),
                      ray_index=(idx % n).astype(np.int32), objects=objects, stamp_s=stamp_s,
                      sensor_positions_base=np.stack([m.position_base for m in mounts]))
