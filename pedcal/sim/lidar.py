"""Seeded raycast 3D LIDAR simulator (open3d ``RaycastingScene``) for person detection.

The tracking paper (Misu and Miura) uses two FX8 3D LIDARs on the robot's front: 97 x 61 rays,
60 x 50 deg field of view, 0.3-5 m, about +-50 mm range error, 4 Hz, with reflectance; yawed
apart they cover 120 deg. ``LIDAR_PRESETS`` also holds sparser/denser and longer-range sensors so
a detector can be trained across resolutions.

The common spinning LIDARs are presets with the beam layouts of their data sheets (``vlp16``,
``vlp32c``, ``hdl32``, ``hdl64e``, ``os1_64``, ``os1_128``) and so are depth cameras of the
Kinect / RealSense class (``realsense_d435``, ``depth_vga_wide``: pinhole pixel grids, depth
noise growing with the range squared, no intensity). Real frames hold what a clean raycast does
not: stray returns metres below the ground (multipath, ``stray_below_share``), intensities on
other scales or none (``intensity_model``); ``random_nuisances`` draws such a variant of a preset
per frame and ``random_mount`` a mount on a robot (0.4-1.2 m) or a car roof (1.7-2.0 m).

Frames: the robot base frame has z = 0 on the floor, x forward, y left (pedcal.frames). A
``Mount`` places a LIDAR on the base with the pedcal convention (sensor x = optical axis,
positive pitch looks down). ``render`` returns points in the base frame;
``LidarFrame.points_in_sensor`` gives one mount's points in its sensor frame or in the camera
optical frame (REP 103: x right, y down, z forward), ``LidarFrame.organized`` as an image.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
import open3d as o3d

from pedcal.errors import PedcalInputError
from pedcal.frames import rot_from_ypr_deg
from pedcal.sim.scene import Scene

STRAY_ID = -3  # object id of stray returns below the ground (floor -1, ceiling -2)
RANGE_NOISE_MODELS = ("uniform", "gaussian", "quadratic")
INTENSITY_MODELS = ("unit", "uint8", "none")
STRAY_MODES = ("along_ray", "vertical", "patch")
PROJECTIONS = ("spherical", "pinhole")
# Sensor frame (x forward, y left, z up) -> camera optical frame (REP 103: x right, y down, z forward).
R_OPTICAL_SENSOR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class LidarModel:
    """A scanning LIDAR: a regular azimuth x elevation grid of rays in the sensor frame, or, with
    ``elevations_deg``, one row of rays per listed beam elevation (spinning LIDARs whose beams are
    packed closer near the horizon; ``n_vertical`` is then their number, ``fov_vertical_deg`` and
    ``vertical_center_deg`` follow from them: ``LidarModel.from_beams``).

    ``projection="pinhole"`` (depth cameras): the rays go through a pixel grid evenly spaced in
    tan(angle) over the fields of view (a camera's image plane), not evenly in angle.

    Range noise is added along the ray: ``range_noise="uniform"`` draws from
    +-sqrt(3)·std (the FX8's "+-50 mm" is such a band), ``"gaussian"`` from N(0, std),
    ``"quadratic"`` from N(0, std · (r / 1 m)^2): a stereo or structured-light camera's depth error
    grows with the range squared (sigma_z = z^2 · sigma_d / (f · b), disparity noise sigma_d,
    focal length f, baseline b), ``range_noise_std_m`` is its value at 1 m.
    Intensity (0..1) = reflectance · |cos(incidence)|^k · min(1, (ref_range / r)^exponent) + noise
    (k = ``intensity_incidence_exponent``, exponent = ``intensity_range_exponent``); returns weaker
    than ``min_return_intensity`` are lost, and each ray drops out with ``dropout_prob``. A sensor
    whose driver reports calibrated reflectance (KITTI's HDL-64E: its road reads 0.2-0.3 from 4 to
    20 m, its pedestrians 0.23-0.48 in the median) has exponent 0 and a small k.
    ``intensity_model`` sets what the frame reports: ``"unit"`` that 0..1 reflectance (KITTI's
    scale), ``"uint8"`` it as integers 0..255 (Velodyne and Ouster drivers, Argoverse), ``"none"``
    zeros (a sensor without intensity).

    Stray returns (multipath: an echo off a wet road or a car's glass that comes back late, seen in
    real street frames as points metres below the road): each return becomes one with probability
    ``stray_below_share``, placed a depth drawn uniformly from ``stray_depth_m`` below the floor
    (z = 0): ``stray_mode="along_ray"`` on its own ray, further out (kept only when that is
    within ``max_range_m`` and the ray points down), ``"vertical"`` straight below its hit,
    ``"patch"`` as a ghost of part of the scene: as many returns, the nearest ones to 1-3 random
    returns, moved down together (by the depth of their patch's centre, clipped to
    ``stray_depth_m``). Real frames hold few: in the shared KITTI training frames 0-0.12 % of
    the points, in tight clusters 7-9 m away, most 1.2-1.8 m below the road. A stray's intensity
    is the return's times U(0.05, 0.5), its object id ``STRAY_ID``.
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
    intensity_incidence_exponent: float = 1.0
    intensity_ref_range_m: float = 1.0
    min_return_intensity: float = 0.005
    dropout_prob: float = 0.01
    rate_hz: float = 4.0
    vertical_center_deg: float = 0.0  # elevation of the centre row (up positive)
    elevations_deg: tuple[float, ...] | None = None  # beam elevations, ascending (up positive)
    projection: str = "spherical"
    intensity_model: str = "unit"
    stray_below_share: float = 0.0
    stray_depth_m: tuple[float, float] = (1.0, 6.0)
    stray_mode: str = "along_ray"

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
        if self.range_noise not in RANGE_NOISE_MODELS:
            bad.append(f"range_noise must be one of {RANGE_NOISE_MODELS}")
        if self.projection not in PROJECTIONS:
            bad.append(f"projection must be one of {PROJECTIONS}")
        elif self.projection == "pinhole" and (self.elevations_deg is not None or self.fov_horizontal_deg >= 180
                                               or self.vertical_center_deg != 0.0):
            bad.append("a pinhole camera needs fov_horizontal_deg < 180, vertical_center_deg 0 and no beam table")
        if self.intensity_model not in INTENSITY_MODELS:
            bad.append(f"intensity_model must be one of {INTENSITY_MODELS}")
        if self.stray_mode not in STRAY_MODES:
            bad.append(f"stray_mode must be one of {STRAY_MODES}")
        if not 0 <= self.stray_below_share < 1:
            bad.append("stray_below_share must be in [0, 1)")
        lo_hi = tuple(self.stray_depth_m)
        if len(lo_hi) != 2 or not 0 < lo_hi[0] <= lo_hi[1]:
            bad.append("stray_depth_m must be (min, max) with 0 < min <= max")
        if not 0 <= self.dropout_prob < 1:
            bad.append("dropout_prob must be in [0, 1)")
        if self.intensity_range_exponent < 0 or self.intensity_incidence_exponent < 0:
            bad.append("intensity exponents must be >= 0")
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


def _pinhole_grid(lidar: LidarModel) -> tuple[np.ndarray, np.ndarray]:
    """(y / x, z / x) of every pixel ray of a pinhole camera, row-major by ascending elevation
    (columns from azimuth -fov/2 to +fov/2, as a spherical grid's)."""
    half_h, half_v = np.radians(lidar.fov_horizontal_deg) / 2, np.radians(lidar.fov_vertical_deg) / 2
    ty = np.linspace(-np.tan(half_h), np.tan(half_h), lidar.n_horizontal)
    tz = np.linspace(-np.tan(half_v), np.tan(half_v), lidar.n_vertical)
    ty_grid, tz_grid = np.meshgrid(ty, tz)
    return ty_grid.ravel(), tz_grid.ravel()


@lru_cache(maxsize=64)
def _ray_angles(lidar: LidarModel) -> tuple[np.ndarray, np.ndarray]:
    if lidar.projection == "pinhole":
        ty, tz = _pinhole_grid(lidar)
        az, el = np.arctan(ty), np.arctan2(tz, np.hypot(1.0, ty))
        az.setflags(write=False)
        el.setflags(write=False)
        return az, el
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
    if lidar.projection == "pinhole":
        ty, tz = _pinhole_grid(lidar)
        d = np.column_stack([np.ones_like(ty), ty, tz])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    else:
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

# The common spinning LIDARs with the beam layouts of their data sheets, 0.2 deg azimuth (10 Hz)
# unless said, reporting intensity as their drivers do. ``hdl32`` above already is the HDL-32E's
# layout (32 beams 1.33 deg apart, +10.67..-30.67 deg); ``spin16``, ``spin32`` and ``hdl64`` are
# evenly spaced stand-ins the shipped detector models were trained on, kept as they are.
VLP32C_ELEVATIONS_DEG = (  # Velodyne VLP-32C user manual: dense about the horizon, 1/3 deg at best
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0, -2.667,
    -2.333, -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333, 1.667, 2.333, 3.333,
    4.667, 7.0, 10.333, 15.0)
# HDL-64E S2: two blocks of 32 lasers, +2..-8.33 deg about 1/3 deg apart and -8.83..-24.9 deg about
# 1/2 deg apart (26.9 deg in all); KITTI's sensor, whose frames report reflectance 0..1.
HDL64E_ELEVATIONS_DEG = tuple(np.round(np.concatenate([np.linspace(2.0, -8.33, 32),
                                                       np.linspace(-8.83, -24.9, 32)]), 4).tolist())
_SPINNING = dict(range_noise="gaussian", rate_hz=10.0, dropout_prob=0.005)
LIDAR_PRESETS.update({
    # Velodyne VLP-16: 16 beams 2 deg apart over +-15 deg, 100 m, +-3 cm.
    "vlp16": LidarModel.from_beams("vlp16", np.arange(-15.0, 16.0, 2.0), 1800, 360.0, 0.5, 100.0,
                                   range_noise_std_m=0.015, intensity_model="uint8", **_SPINNING),
    # Velodyne VLP-32C: 32 beams over -25..+15 deg, packed about the horizon (Argoverse has two).
    "vlp32c": LidarModel.from_beams("vlp32c", VLP32C_ELEVATIONS_DEG, 1800, 360.0, 0.5, 200.0,
                                    range_noise_std_m=0.015, intensity_model="uint8", **_SPINNING),
    "hdl64e": LidarModel.from_beams("hdl64e", HDL64E_ELEVATIONS_DEG, 2000, 360.0, 0.9, 120.0,
                                    range_noise_std_m=0.02, intensity_model="unit", intensity_range_exponent=0.0,
                                    intensity_incidence_exponent=0.5, **_SPINNING),
    # Ouster OS1 (rev. 6): evenly spaced beams over 45 deg (+-22.5), 2048 or 1024 columns, 0.3-120 m.
    "os1_64": LidarModel("os1_64", 2048, 64, 360.0, 45.0, 0.3, 120.0, range_noise_std_m=0.02,
                         intensity_model="uint8", **_SPINNING),
    "os1_128": LidarModel("os1_128", 1024, 128, 360.0, 45.0, 0.3, 120.0, range_noise_std_m=0.02,
                          intensity_model="uint8", **_SPINNING),
    # Depth cameras of the RealSense D435 / wide Kinect class: 87 x 58 deg pinhole grids, 0.3-8 m, no
    # intensity; depth noise sigma = c · r^2 with c = sigma_d / (f · b): the D435's 0.08 px subpixel
    # disparity and 50 mm baseline with a 447 px focal length at 848 px give c = 3.6 mm at 1 m, with
    # 337 px at 640 px c = 4.7 mm.
    "realsense_d435": LidarModel("realsense_d435", 848, 480, 87.0, 58.0, 0.3, 8.0, range_noise_std_m=0.0036,
                                 range_noise="quadratic", rate_hz=30.0, dropout_prob=0.02, projection="pinhole",
                                 intensity_model="none"),
    "depth_vga_wide": LidarModel("depth_vga_wide", 640, 480, 87.0, 58.0, 0.3, 8.0, range_noise_std_m=0.0047,
                                 range_noise="quadratic", rate_hz=30.0, dropout_prob=0.02, projection="pinhole",
                                 intensity_model="none"),
})


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


# Where a sensor sits above the floor: on a mobile robot, or on a car's roof.
MOUNT_HEIGHTS_M = {"robot": (0.4, 1.2), "car": (1.7, 2.0)}


def _preset(lidar: LidarModel | str) -> LidarModel:
    if isinstance(lidar, str):
        if lidar not in LIDAR_PRESETS:
            raise PedcalInputError(f"unknown LIDAR preset {lidar!r}; expected one of {sorted(LIDAR_PRESETS)}",
                                   column="lidar")
        return LIDAR_PRESETS[lidar]
    return lidar


def mount_kinds(lidar: LidarModel | str) -> tuple[str, ...]:
    """Where a sensor of this kind is mounted (``MOUNT_HEIGHTS_M`` keys): spinning LIDARs on a robot
    or a car, cameras and narrow solid-state LIDARs on a robot."""
    return ("robot", "car") if _preset(lidar).fov_horizontal_deg >= 360.0 else ("robot",)


def draw_mount_height_m(lidar: LidarModel | str, rng: np.random.Generator, kind: str | None = None
                        ) -> tuple[float, str]:
    """(height above the floor in m, mount kind): the kind drawn evenly from ``mount_kinds`` unless
    given, the height uniformly from its ``MOUNT_HEIGHTS_M`` range. Two draws whatever is given."""
    kinds = mount_kinds(lidar)
    pick = kinds[min(int(rng.random() * len(kinds)), len(kinds) - 1)]
    kind = pick if kind is None else kind
    if kind not in MOUNT_HEIGHTS_M:
        raise PedcalInputError(f"mount kind must be one of {sorted(MOUNT_HEIGHTS_M)}, got {kind!r}", column="kind")
    lo, hi = MOUNT_HEIGHTS_M[kind]
    return float(lo + (hi - lo) * rng.random()), kind


def random_mount(lidar: LidarModel | str, rng: np.random.Generator, kind: str | None = None) -> tuple[Mount, str]:
    """(Mount, kind) for one frame: height from ``draw_mount_height_m``; a spinning LIDAR levelled
    to within +-2 deg of pitch and roll, a camera or solid-state sensor pitched -3..12 deg (looking
    down a little, as on a robot) with +-2 deg of roll. The FX8 pair is mounted by
    ``fx8_pair_mounts(height_m=...)`` instead."""
    height, kind = draw_mount_height_m(lidar, rng, kind)
    spinning = _preset(lidar).fov_horizontal_deg >= 360.0
    pitch = rng.uniform(-2.0, 2.0) if spinning else rng.uniform(-3.0, 12.0)
    roll = rng.uniform(-2.0, 2.0)
    return Mount(0.0, 0.0, height, 0.0, float(pitch), float(roll)), kind


def random_nuisances(lidar: LidarModel | str, rng: np.random.Generator) -> LidarModel:
    """A variant of a LIDAR for one frame, so that seeds vary what real sensors vary: stray returns
    below the ground (none in half the frames, else a share log-uniform in 0.01-0.5 %, one of the
    ``STRAY_MODES``), the intensity scale (``INTENSITY_MODELS``: 0..1 45 %, 0..255 35 %, absent 20 %;
    cameras have none), range noise (the preset's std times 2^U(-1, 1), uniform or gaussian for a
    LIDAR, quadratic for a camera), ray dropout (the preset's plus U(0, 3 %)) and how intensity
    depends on the geometry (half the frames calibrated reflectance as KITTI's: no range falloff,
    |cos(incidence)|^U(0, 0.5); the others raw: (1 m / r)^0.5 and |cos(incidence)|). Always the same
    nine draws."""
    lidar = _preset(lidar)
    u = rng.random(9)
    share = 0.0 if u[0] < 0.5 else float(10 ** (-4.0 + u[1] * np.log10(50.0)))
    mode = STRAY_MODES[int(u[2] * len(STRAY_MODES))]
    intensity = "none" if lidar.intensity_model == "none" else INTENSITY_MODELS[int(np.searchsorted([0.45, 0.8], u[3]))]
    noise = lidar.range_noise if lidar.range_noise == "quadratic" else ("uniform" if u[4] < 0.5 else "gaussian")
    return lidar.with_(stray_below_share=share, stray_mode=mode, intensity_model=intensity, range_noise=noise,
                       range_noise_std_m=lidar.range_noise_std_m * float(2.0 ** (2 * u[5] - 1)),
                       dropout_prob=min(lidar.dropout_prob + 0.03 * float(u[6]), 0.5),
                       intensity_range_exponent=0.0 if u[7] < 0.5 else 0.5,
                       intensity_incidence_exponent=0.5 * float(u[8]) if u[7] < 0.5 else 1.0)


@dataclass
class LidarFrame:
    """One simulated scan in the robot base frame.

    ``points``: (N, 4) float32 [x, y, z, intensity 0..1]; ``object_id``: (N,) int32 (-1 floor,
    -2 ceiling); ``mount_index``: (N,) int16, which mount saw the point; ``ray_index``: (N,)
    int32 ray within that mount (row-major: elevation row · n_horizontal + azimuth column);
    ``objects``: ground truth per scene object (``Scene.truth()`` entries, positions in the base
    frame, plus ``visible_points``); ``sensor_positions_base``: (M, 3) where each mount's sensor sits
    in the base frame (its height above the floor is ``[:, 2]``), ``R_base_sensors`` (M, 3, 3) how it
    is turned. The intensity column is on the LIDAR's ``intensity_model`` scale (0..1, 0..255 or
    zeros); stray returns below the ground have object id ``STRAY_ID``.
    """

    points: np.ndarray
    object_id: np.ndarray
    mount_index: np.ndarray
    ray_index: np.ndarray
    objects: list[dict] = field(default_factory=list)
    stamp_s: float = 0.0
    sensor_positions_base: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    R_base_sensors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))

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

    def points_in_sensor(self, mount_index: int = 0, optical: bool = False) -> np.ndarray:
        """(N_k, 4) the points mount ``mount_index`` saw, in its sensor frame (x forward, y left,
        z up) or, ``optical``, in the camera optical frame (REP 103: x right, y down, z forward)."""
        if not 0 <= mount_index < len(self.R_base_sensors):
            raise PedcalInputError(f"mount_index {mount_index} out of range: the frame has "
                                   f"{len(self.R_base_sensors)} mount(s) with known poses", column="mount_index")
        sel = self.points[self.mount_index == mount_index]
        R = self.R_base_sensors[mount_index]
        xyz = (sel[:, :3].astype(float) - self.sensor_positions_base[mount_index]) @ R
        if optical:
            xyz = xyz @ R_OPTICAL_SENSOR.T
        return np.column_stack([xyz, sel[:, 3]]).astype(np.float32)

    def organized(self, lidar: LidarModel | str, mount_index: int = 0, optical: bool = True) -> np.ndarray:
        """(n_vertical, n_horizontal, 4) one mount's points as an image, NaN where a ray returned
        nothing, as a depth camera's organized cloud: row 0 the top (highest elevation), column 0
        the left edge (largest azimuth); points as ``points_in_sensor``."""
        lidar = _preset(lidar)
        img = np.full((lidar.n_vertical * lidar.n_horizontal, 4), np.nan, dtype=np.float32)
        rays = self.ray_index[self.mount_index == mount_index]
        if len(rays) and rays.max() >= len(img):
            raise PedcalInputError(f"the frame's rays do not fit {lidar.name!r} ({lidar.n_rays} rays)", column="lidar")
        img[rays] = self.points_in_sensor(mount_index, optical)
        return img.reshape(lidar.n_vertical, lidar.n_horizontal, 4)[::-1, ::-1]

    def visible_people(self, min_points: int = 10) -> list[dict]:
        """Ground truth of the people with at least ``min_points`` points in this frame."""
        return [o for o in self.objects if o["is_person"] and o["visible_points"] >= min_points]


def _rotate(v: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(N, 3) vectors rotated by R: ``v @ R.T`` without BLAS, whose threads (for N over ~10^5)
    made a 64-beam render 10x slower on a loaded machine than the raycast itself."""
    return np.einsum("ij,kj->ik", v, R)


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
    lidar = _preset(lidar)
    mounts = (mounts,) if isinstance(mounts, Mount) else tuple(mounts)
    if not mounts:
        raise PedcalInputError("render needs at least one Mount", column="mounts")
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng

    R_scene_base, t_scene_base = _base_pose_matrix(base_pose)
    d_sensor = lidar.ray_directions_sensor()
    n = lidar.n_rays
    # Ray origins/directions in the base frame, then in the scene frame for casting.
    d_base = np.concatenate([_rotate(d_sensor, m.R_base_sensor) for m in mounts])
    o_base = np.repeat(np.stack([m.position_base for m in mounts]), n, axis=0)
    rays_scene = np.hstack([_rotate(o_base, R_scene_base) + t_scene_base, _rotate(d_base, R_scene_base)]
                           ).astype(np.float32)

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
    if lidar.intensity_incidence_exponent != 1.0:
        cos_incidence = cos_incidence ** lidar.intensity_incidence_exponent
    intensity = reflectance * cos_incidence * falloff
    if lidar.intensity_noise_std > 0:
        intensity = intensity + rng.normal(0.0, lidar.intensity_noise_std, len(idx))
    strong = intensity >= lidar.min_return_intensity
    idx, range_m, intensity, geom = idx[strong], range_m[strong], intensity[strong], geom[strong]

    if lidar.range_noise_std_m > 0:
        if lidar.range_noise == "uniform":
            half = np.sqrt(3.0) * lidar.range_noise_std_m
            range_m = range_m + rng.uniform(-half, half, len(idx))
        elif lidar.range_noise == "gaussian":
            range_m = range_m + rng.normal(0.0, lidar.range_noise_std_m, len(idx))
        else:  # quadratic: sigma = std · (r / 1 m)^2
            range_m = range_m + rng.normal(0.0, 1.0, len(idx)) * lidar.range_noise_std_m * range_m**2
    xyz_base = o_base[idx] + d_base[idx] * range_m[:, None]
    intensity = np.clip(intensity, 0.0, 1.0)
    object_id = geom_object_id[geom].astype(np.int32)
    if lidar.stray_below_share > 0:
        _stray_returns(lidar, rng, o_base[idx], d_base[idx], range_m, xyz_base, intensity, object_id)
    points = np.empty((len(idx), 4), dtype=np.float32)
    points[:, :3] = xyz_base
    points[:, 3] = {"unit": intensity, "uint8": np.round(255.0 * intensity), "none": 0.0}[lidar.intensity_model]

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
                      sensor_positions_base=np.stack([m.position_base for m in mounts]),
                      R_base_sensors=np.stack([m.R_base_sensor for m in mounts]))


def _stray_returns(lidar: LidarModel, rng: np.random.Generator, origin_base: np.ndarray, d_base: np.ndarray,
                   range_m: np.ndarray, xyz_base: np.ndarray, intensity: np.ndarray, object_id: np.ndarray) -> None:
    """Turn a ``stray_below_share`` of the returns into stray returns below the floor, in place
    (``LidarModel``'s docstring). Three draws per return, whichever are picked (and for patches
    their number and centres)."""
    n = len(range_m)
    pick = rng.random(n) < lidar.stray_below_share
    lo, hi = lidar.stray_depth_m
    depth = rng.uniform(lo, hi, n)
    weaken = rng.uniform(0.05, 0.5, n)
    if lidar.stray_mode == "along_ray":  # the echo comes back late: the point further out on its ray
        down = d_base[:, 2] < -1e-6
        t = np.where(down, (origin_base[:, 2] + depth) / np.where(down, -d_base[:, 2], 1.0), np.inf)
        ok = pick & down & (t <= lidar.max_range_m) & (t > range_m)
        xyz_base[ok] = origin_base[ok] + d_base[ok] * t[ok, None]
    elif lidar.stray_mode == "vertical":  # a ghost straight below the hit
        ok = pick
        xyz_base[ok, 2] = -depth[ok]
    else:  # patch: the returns nearest 1-3 centres, moved down together
        ok = np.zeros(n, dtype=bool)
        n_patches = min(1 + int(rng.integers(3)), n)
        centres = rng.choice(n, n_patches, replace=False) if n else np.zeros(0, dtype=int)
        per = int(np.ceil(pick.sum() / max(n_patches, 1)))
        for c in centres[: n_patches if per else 0]:
            near = np.argpartition(np.linalg.norm(xyz_base - xyz_base[c], axis=1), min(per, n) - 1)[:per]
            z = xyz_base[near, 2] - xyz_base[c, 2] - depth[c]
            xyz_base[near, 2] = np.clip(z, -hi, -lo)
            ok[near] = True
    intensity[ok] *= weaken[ok]
    object_id[ok] = STRAY_ID
