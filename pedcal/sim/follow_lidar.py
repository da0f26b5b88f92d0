"""The LIDAR and the detector in the following loop (``pedcal follow --sensing lidar``).

:class:`LidarSensing` replaces the abstract detection model of :class:`~pedcal.sim.follow.Sensing`
(in view, a detection probability, 5 cm noise) by what a robot would run: every frame, the
simulated LIDAR (``pedcal.sim.lidar.render``; the paper's FX8 pair by default, any
``LIDAR_PRESETS`` entry otherwise) is cast from the robot's true pose into a 3-D scene holding

- every person present as a body (``pedcal.sim.scene.person_mesh``: legs, torso, arms, head, a
  skirt, a coat or a backpack for some) at the walker's position, facing its direction of motion,
  walking (legs and arms at one of ``GAIT_PHASES``) or standing still;
- the episode's walls: the occupied cells of its occupancy map as boxes ``WALL_HEIGHT_M`` high
  (``wall_boxes``: runs of cells merged into rectangles);
- clutter (``pedcal.sim.scene.CLUTTER_KINDS`` but free-standing walls: pillars, poles, chairs,
  plants, signs, trolleys, boxes, coat stands), ``clutter_per_10m2`` objects per 10 m^2 of the
  scene's floor, placed where no walker ever comes within ``CLUTTER_CLEARANCE_M`` (``place_clutter``);

the shipped detector (``pedcal.detect.detection.detect``, the model of the sensor's family) runs
on the points, and each cluster it scores a person becomes a :class:`PersonDetection` in the robot
frame: the cluster's box centre, height, score and the normalized histogram of its points'
intensities (``N_REFLECTANCE_BINS`` bins over [0, 1], the tracker's appearance). A person the
detector misses is missed; a cluster of clutter or wall it scores a person is passed on as a false
detection. The localization estimate and the ESPAR readings are ``Sensing``'s.

Near the robot the FX8 pair sees a person only between its field of view's edges, a slab of torso
the classifier scores low. So the sensing keeps its person detections of the last ``HOLD_S`` (in
the world frame of the localization estimate: detection-level tracks) and passes on a cluster scored
below the threshold that lies within the gate of one of them when it scores at least
``HELD_THRESHOLD`` or is a person-sized column cut by the field of view at both edges
(``pedcal.detect.near_range.fov_cut``): ``LidarSensing.held_columns``. A person first seen that near
is not found; a pillar, a tall plant or a stack of boxes of a person's width where a person was a
moment before is taken for one.

Which people are *in sight* for scoring (``frame``'s second value, the follow log's
``target_visible``, CLEAR MOT's truth) is ``visible_people``, as with the abstract model, so both
sensing modes are scored against the same truth.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from pedcal.detect.detection import detect, load_model, model_family
from pedcal.detect.near_range import edge_flags, fov_cut, sensor_views
from pedcal.detect.sensors import SENSORS, THIN_BELOW_DEG, normalize_density
from pedcal.errors import PedcalInputError
from pedcal.follow_types import FollowFrame, PersonDetection
from pedcal.io.maps import OccupancyMap
from pedcal.sim.follow import (
    FRAME_HZ,
    N_REFLECTANCE_BINS,
    Episode,
    Sensing,
    SensorModel,
    Walker,
    to_robot,
    to_world,
    visible_people,
)
from pedcal.sim.lidar import LIDAR_PRESETS, LidarModel, Mount, fx8_pair_mounts, render
from pedcal.sim.scene import (
    BACKPACK_SHARE,
    CLUTTER_WEIGHTS,
    GARMENT_SHARES,
    Mesh,
    Scene,
    SceneObject,
    box,
    make_clutter,
    person_mesh,
)

SENSING_MODES = ("ideal", "lidar")
DEFAULT_LIDAR = "fx8"
WALL_HEIGHT_M = 2.5
WALL_REFLECTANCE = 0.5
CLUTTER_PER_10M2 = 0.3  # static clutter objects per 10 m^2 of the scene's floor
CLUTTER_CLEARANCE_M = 0.6  # from every walker's path (sampled every CLEARANCE_STEP_S) and the robot's start
CLEARANCE_STEP_S = 0.25
WALKING_SPEED_MPS = 0.2  # a walker slower than this stands (standing pose, last heading)
STRIDE_HZ = 0.9  # gait cycles per second (pedcal.sim.scene.Scene.step's)
GAIT_PHASES = np.linspace(-1.0, 1.0, 5)  # the stride of a walking body is the nearest of these
TARGET_MATCH_M = 0.5  # frame_stats: a detection this close to the target found it (the follow scoring's match)
HIST_BOX_MARGIN_M = 0.02  # a detection's histogram takes the points inside its box grown by this
CARRYING_SHARE = 0.3  # people carrying a bag (pedcal.sim.scene.random_person's share)
# Detection-level tracks (``LidarSensing.held_columns``): a cluster the classifier scores below a
# person's threshold is passed on as a person when it lies within the gate of a person detected
# (either way) at most HOLD_S before, HOLD_GATE_M + HOLD_SPEED_MPS x its age and at most
# HOLD_MAX_GATE_M (in the world frame of the localization estimate), and either scores at least
# HELD_THRESHOLD (the lower threshold inside a track's gate of tracking-by-detection) or is a
# person-sized column cut by the field of view (pedcal.detect.near_range.fov_cut: too near for the
# classifier to judge at all).
HOLD_S = 2.0
HOLD_GATE_M = 0.5
HOLD_SPEED_MPS = 1.0
HOLD_MAX_GATE_M = 1.0
HELD_THRESHOLD = 0.1


def check_sensing(sensing: str, lidar: str | None = None) -> None:
    """A clear error for an unknown ``sensing`` mode or LIDAR (``lidar`` only with "lidar"; a
    ``LIDAR_PRESETS`` name or a ``pedcal.detect.sensors.SENSORS`` name, ``lidar_preset``)."""
    if sensing not in SENSING_MODES:
        raise PedcalInputError(f"--sensing {sensing!r}: expected one of {', '.join(SENSING_MODES)}",
                               column="sensing")
    if lidar is not None:
        lidar_preset(lidar)
    if lidar is not None and sensing != "lidar":
        raise PedcalInputError(f"--lidar {lidar!r} goes with --sensing lidar (the ideal model has no LIDAR)",
                               column="lidar")


def lidar_preset(name: str) -> str:
    """The ``LIDAR_PRESETS`` name of a preset or of a ``SENSORS`` name (``os1-32`` -> ``spin32``)."""
    if name in LIDAR_PRESETS:
        return name
    if name in SENSORS:
        return SENSORS[name][0]
    raise PedcalInputError(f"--lidar {name!r}: expected a LIDAR preset ({', '.join(sorted(LIDAR_PRESETS))}) or a "
                           f"sensor name ({', '.join(sorted(SENSORS))})", column="lidar")


def lidar_mounts(lidar: LidarModel) -> tuple[Mount, ...]:
    """The FX8 pair's mounts (``fx8_pair_mounts``) for the FX8 presets; one sensor at 1 m on the
    base's centre, looking ahead, for any other."""
    return fx8_pair_mounts() if lidar.name.startswith("fx8") else (Mount(0.0, 0.0, 1.0),)


# -------------------------------------------------------------------------------------- static world
def wall_boxes(occupancy: OccupancyMap) -> np.ndarray:
    """The occupied cells as rectangles (K, 4) ``col0, col1, row0, row1`` (inclusive cell
    indices): each row's runs of occupied cells, then runs of equal columns in consecutive rows
    merged into one rectangle."""
    occ = np.asarray(occupancy.occupied, bool)
    pad = np.zeros((occ.shape[0], 1), bool)
    edges = np.diff(np.hstack([pad, occ, pad]).astype(np.int8), axis=1)
    r0, c0 = np.nonzero(edges == 1)
    r1, c1 = np.nonzero(edges == -1)  # same rows, same order (row-major)
    runs = np.column_stack([c0, c1 - 1, r0]) if len(r0) else np.zeros((0, 3), np.int64)
    if not len(runs):
        return np.zeros((0, 4), np.int64)
    runs = runs[np.lexsort((runs[:, 2], runs[:, 1], runs[:, 0]))]
    new = np.r_[True, (runs[1:, 0] != runs[:-1, 0]) | (runs[1:, 1] != runs[:-1, 1])
                | (runs[1:, 2] != runs[:-1, 2] + 1)]
    start = np.flatnonzero(new)
    end = np.r_[start[1:], len(runs)] - 1
    return np.column_stack([runs[start, 0], runs[start, 1], runs[start, 2], runs[end, 2]])


def wall_meshes(occupancy: OccupancyMap, height_m: float = WALL_HEIGHT_M,
                reflectance: float = WALL_REFLECTANCE) -> list[tuple[np.ndarray, Mesh]]:
    """The map's occupied cells as boxes ``height_m`` high (``wall_boxes``), in the world frame:
    (centre_xy_m, mesh) per box."""
    rects = wall_boxes(occupancy)
    if not len(rects):
        return []
    res = occupancy.resolution_m
    # opposite corners of each rectangle: (row1, col0) is its lower-left cell, (row0, col1) its upper-right
    lo = occupancy.cell_to_world(np.column_stack([rects[:, 3], rects[:, 0]])) - res / 2 * _map_axes(occupancy).sum(0)
    hi = occupancy.cell_to_world(np.column_stack([rects[:, 2], rects[:, 1]])) + res / 2 * _map_axes(occupancy).sum(0)
    yaw = float(occupancy.origin_xy_yaw[2])
    size_local = (hi - lo) @ _map_axes(occupancy).T  # extents along the map's own axes
    centres = (lo + hi) / 2
    return [(c, box((c[0], c[1], height_m / 2), (s[0], s[1], height_m), reflectance, yaw))
            for c, s in zip(centres, size_local, strict=True)]


def _map_axes(occupancy: OccupancyMap) -> np.ndarray:
    """(2, 2): the map's x and y axes (rows) in the world frame."""
    c, s = np.cos(occupancy.origin_xy_yaw[2]), np.sin(occupancy.origin_xy_yaw[2])
    return np.array([[c, s], [-s, c]])


def walker_samples(walkers: list[Walker], duration_s: float, step_s: float = CLEARANCE_STEP_S) -> np.ndarray:
    """(N, 2) every walker's positions every ``step_s`` over the episode."""
    t = np.arange(0.0, duration_s + step_s / 2, step_s)
    pts = [np.zeros((0, 2))]
    for w in walkers:  # Walker.at at every time of its span at once (np.interp holds the last position)
        if len(w.t_s) == 0:
            continue
        ti = t[(t >= w.t_s[0]) & ((t <= w.t_s[-1]) | w.stays)]
        pts.append(np.column_stack([np.interp(ti, w.t_s, w.xy_world_m[:, 0]),
                                    np.interp(ti, w.t_s, w.xy_world_m[:, 1])]))
    return np.vstack(pts)


def place_clutter(episode: Episode, rng: np.random.Generator, per_10m2: float = CLUTTER_PER_10M2,
                  clearance_m: float = CLUTTER_CLEARANCE_M, tries: int = 100) -> list[SceneObject]:
    """Static clutter for an episode: ``per_10m2`` objects per 10 m^2 of the scene (the map's
    extent, or the walkers' bounding box grown by 2 m without a map), each of a kind drawn by
    ``CLUTTER_WEIGHTS`` (free-standing walls left out) where its footprint keeps ``clearance_m``
    from every walker's path, from the robot's start, from the map's walls and from the other
    clutter. An object that finds no such place in ``tries`` draws is left out."""
    if not np.isfinite(per_10m2) or per_10m2 < 0:
        raise PedcalInputError(f"clutter density {per_10m2!r}: expected objects per 10 m^2 >= 0", column="clutter")
    paths = walker_samples(episode.walkers, episode.duration_s)
    occ = episode.occupancy
    if occ is not None:
        rows, cols = occ.shape
        corners = occ.cell_to_world(np.array([[0, 0], [0, cols - 1], [rows - 1, 0], [rows - 1, cols - 1]]))
        x0, y0 = corners.min(axis=0)
        x1, y1 = corners.max(axis=0)
    else:
        both = np.vstack([paths, episode.robot_pose0[None, :2]])
        (x0, y0), (x1, y1) = both.min(axis=0) - 2.0, both.max(axis=0) + 2.0
    n = int(round(per_10m2 * (x1 - x0) * (y1 - y0) / 10.0))
    kinds = [k for k in CLUTTER_WEIGHTS if k != "wall"]
    weights = np.array([CLUTTER_WEIGHTS[k] for k in kinds], float)
    busy = cKDTree(np.vstack([paths, episode.robot_pose0[None, :2]]))
    placed: list[np.ndarray] = []
    out = []
    for kind in rng.choice(kinds, size=n, p=weights / weights.sum()):
        obj = make_clutter(str(kind), rng)
        for _ in range(tries):
            obj.x_m, obj.y_m = (float(v) for v in rng.uniform([x0, y0], [x1, y1]))
            obj.yaw_rad = float(rng.uniform(-np.pi, np.pi))
            c = obj.collision_circles()
            if np.any(busy.query(c[:, :2])[0] < c[:, 2] + clearance_m):
                continue
            if occ is not None and _near_wall(occ, c):
                continue
            if placed and np.any(np.linalg.norm(c[:, None, :2] - np.vstack(placed)[None, :, :2], axis=2)
                                 < c[:, None, 2] + np.vstack(placed)[None, :, 2]):
                continue
            placed.append(c)
            out.append(obj)
            break
    return out


def _near_wall(occ: OccupancyMap, circles: np.ndarray) -> bool:
    """Whether any occupied cell lies within a circle (its centre and 8 points on its rim tested)."""
    a = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    rim = circles[:, None, :2] + circles[:, None, 2:3] * np.stack([np.cos(a), np.sin(a)], axis=1)[None]
    return bool(occ.is_occupied(np.vstack([circles[:, :2], rim.reshape(-1, 2)])).any())


# ---------------------------------------------------------------------------------------------- bodies
class _Body:
    """One walker's body: its build and clothing drawn once, its meshes cached by pose."""

    def __init__(self, walker: Walker, rng: np.random.Generator):
        a, b = walker.reflectance_ab
        self.height_m = float(np.clip(walker.height_m, 1.2, 2.2))
        self.width_m = float(rng.uniform(0.35, 0.55))
        self.depth_m = float(rng.uniform(0.2, 0.35))
        # upper clothing at the walker's mean reflectance, lower clothing a draw of it
        self.reflectance = (float(a / (a + b)), float(rng.beta(a, b)))
        self.carrying = bool(rng.random() < CARRYING_SHARE)
        names, shares = zip(*GARMENT_SHARES, strict=True)
        self.garment = str(rng.choice(names, p=shares))
        self.backpack = bool(rng.random() < BACKPACK_SHARE)
        self.mesh_seed = int(rng.integers(2 ** 62))
        self.gait_offset_rad = float(rng.uniform(-np.pi, np.pi))
        self.yaw_rad = float(rng.uniform(-np.pi, np.pi))
        self._meshes: dict[int | None, Mesh] = {}

    def mesh(self, phase: int | None) -> Mesh:
        """The body standing (``phase`` None) or walking at stride ``GAIT_PHASES[phase]``."""
        if phase not in self._meshes:
            walking = phase is not None
            pose = ("walking" if walking else "standing") if not self.carrying else \
                ("walking_carrying" if walking else "carrying")
            self._meshes[phase] = person_mesh(
                self.height_m, self.width_m, self.depth_m, pose, self.reflectance,
                np.random.default_rng(self.mesh_seed), gait_phase=float(GAIT_PHASES[phase]) if walking else 0.0,
                garment=self.garment, backpack=self.backpack)
        return self._meshes[phase]


def reflectance_histogram_of(intensity: np.ndarray, n_bins: int = N_REFLECTANCE_BINS) -> np.ndarray:
    """Normalized histogram of intensities in [0, 1] (uniform when there are none)."""
    h, _ = np.histogram(np.clip(intensity, 0.0, 1.0), bins=n_bins, range=(0.0, 1.0))
    return h / h.sum() if h.sum() else np.full(n_bins, 1.0 / n_bins)


def points_in_box(points: np.ndarray, cx: float, cy: float, width: float, depth: float, yaw: float,
                  height: float, margin_m: float = HIST_BOX_MARGIN_M, floor_m: float = 0.05) -> np.ndarray:
    """Indices of the points inside a detection's box (``width`` along ``yaw``, ``depth`` across it),
    grown by ``margin_m``, above ``floor_m`` and up to its height."""
    d = points[:, :2] - np.array([cx, cy])
    c, s = np.cos(yaw), np.sin(yaw)
    along, across = d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c
    return np.flatnonzero((np.abs(along) <= width / 2 + margin_m) & (np.abs(across) <= depth / 2 + margin_m)
                          & (points[:, 2] > floor_m) & (points[:, 2] <= height + margin_m))


# --------------------------------------------------------------------------------------------- sensing
class LidarSensing:
    """Per-frame detections from the simulated LIDAR and the shipped detector (module docstring),
    with :class:`Sensing`'s localization estimate and ESPAR readings; ``frame`` as ``Sensing.frame``.

    ``frame_stats`` collects, per frame, the seconds spent casting the rays (``raycast_s``: scene
    build and ``render``) and detecting (``detect_s``), the people present and within the LIDAR's
    reach, the points and detections, and, from ``frame``, the target's range from the robot
    (``target_range_m``, NaN when absent) and whether a detection lies within ``TARGET_MATCH_M`` of
    it (``target_detected``), the people with a detection that near (``people_detected``), the
    detections near nobody (``false_detections``) and those passed on by the hold (``near_rule``,
    ``held_columns``).
    """

    def __init__(self, episode: Episode, rng: np.random.Generator, lidar: str | LidarModel = DEFAULT_LIDAR,
                 clutter_per_10m2: float = CLUTTER_PER_10M2, model=None):
        if isinstance(lidar, str):
            lidar = LIDAR_PRESETS[lidar_preset(lidar)]
        self.lidar = lidar
        self.mounts = lidar_mounts(lidar)
        self.episode = episode
        self.occupancy = episode.occupancy
        self.rng = rng
        # localization and ESPAR from the abstract model, which is given nobody to detect and no clutter
        self.base = Sensing(episode.occupancy, rng, SensorModel(clutter_per_frame=0.0))
        world_rng = np.random.default_rng(rng.integers(2 ** 63))
        self.body_rng = np.random.default_rng(rng.integers(2 ** 63))
        self.render_rng = np.random.default_rng(rng.integers(2 ** 63))
        self.clutter = place_clutter(episode, world_rng, clutter_per_10m2)
        static = [(np.array([o.x_m, o.y_m]), o.mesh_scene()) for o in self.clutter]
        static += wall_meshes(episode.occupancy) if episode.occupancy is not None else []
        # each static mesh's footprint as a disc (centre, radius): only those within reach are cast at
        self.static_meshes = [m for _, m in static]
        self.static_xy_m = np.array([c for c, _ in static]).reshape(-1, 2)
        self.static_radius_m = np.array([np.linalg.norm(m.vertices[:, :2] - c, axis=1).max() for c, m in static])
        paths = walker_samples(episode.walkers, episode.duration_s)
        reach = np.abs(np.vstack([paths, episode.robot_pose0[None, :2]])).max() + 2 * lidar.max_range_m + 10.0
        self.floor_half_extent_m = float(reach)
        # a sensor denser than the trained LIDARs (a depth camera) is thinned as ``pedcal detect`` does
        self.sensor_name = next((k for k, (preset, _) in SENSORS.items() if preset == lidar.name), None)
        step_deg = (lidar.fov_horizontal_deg / max(lidar.n_horizontal - 1, 1),
                    lidar.fov_vertical_deg / max(lidar.n_vertical - 1, 1))
        self.thin = max(step_deg) < THIN_BELOW_DEG
        self.family = model_family(lidar.name)
        self.model = model if model is not None else load_model(None, self.family)
        self.bodies: dict[str, _Body] = {}
        self.sensor_xy_m = tuple(np.mean([m.position_base[:2] for m in self.mounts], axis=0))
        self.sensor_height_m = float(np.mean([m.z_m for m in self.mounts]))
        self.frame_stats: list[dict] = []
        self.last_points: np.ndarray | None = None
        try:  # the near-range rule needs level sensors with regular rows (the FX8 pair, the grids)
            self.views = sensor_views(lidar, self.mounts)
        except ValueError:
            self.views = ()
        self.held_xy_world_m = np.zeros((0, 2))  # person detections of the last HOLD_S (world frame, estimate)
        self.held_t_s = np.zeros(0)

    def _body(self, walker: Walker) -> _Body:
        if walker.person_id not in self.bodies:
            self.bodies[walker.person_id] = _Body(walker, self.body_rng)
        return self.bodies[walker.person_id]

    def _scene(self, t_s: float, pose: np.ndarray, people: list[tuple[Walker, np.ndarray]]) -> tuple[Scene, int]:
        """The 3-D scene at ``t_s``: static walls and clutter, and the people within the LIDAR's
        reach of the robot (farther ones cannot return a point nor hide one)."""
        scene = Scene(floor_half_extent_m=self.floor_half_extent_m)
        reach_m = self.lidar.max_range_m + 1.0  # the sensors sit within 1 m of the base's centre
        near = np.flatnonzero(np.hypot(*(self.static_xy_m - pose[:2]).T) - self.static_radius_m <= reach_m)
        if len(near):
            scene.add(SceneObject("static", False, Mesh.concat([self.static_meshes[i] for i in near])))
        in_range = 0
        dt = 0.5 / FRAME_HZ
        for w, xy in people:
            body = self._body(w)  # every person gets its body when first present (reproducible draws)
            if np.hypot(*(xy - pose[:2])) > reach_m + 0.5:  # a body's reach from its centre
                continue
            in_range += 1
            a, b = w.at(max(t_s - dt, float(w.t_s[0]))), w.at(t_s + dt)
            a = xy if a is None else a
            b = xy if b is None else b
            v = (b - a) / (2 * dt)
            phase = None
            if np.hypot(*v) >= WALKING_SPEED_MPS:
                body.yaw_rad = float(np.arctan2(v[1], v[0]))
                s = np.sin(2 * np.pi * STRIDE_HZ * t_s + body.gait_offset_rad)
                phase = int(np.argmin(np.abs(GAIT_PHASES - s)))
            scene.add(SceneObject("person", True, body.mesh(phase), float(xy[0]), float(xy[1]), body.yaw_rad))
        return scene, in_range

    def detections(self, t_s: float, pose_world_robot: np.ndarray, people: list[tuple[Walker, np.ndarray]],
                   pose_estimate: np.ndarray | None = None) -> list[PersonDetection]:
        """The detector's person detections in the LIDAR frame cast from the true pose (robot frame),
        and the clusters too near for the classifier held by a recent person detection
        (``held_columns``; in the world frame of ``pose_estimate``, the true pose when None)."""
        pose = np.asarray(pose_world_robot, dtype=float)
        est = pose if pose_estimate is None else np.asarray(pose_estimate, dtype=float)
        t0 = time.perf_counter()
        scene, in_range = self._scene(t_s, pose, people)
        frame = render(scene, self.lidar, self.mounts, self.render_rng, base_pose=pose, stamp_s=t_s)
        t1 = time.perf_counter()
        pts = frame.points.astype(float)
        if self.thin:
            pts = normalize_density(pts, self.sensor_name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gated = detect(pts, self.model, sensor=self.lidar.name, sensor_height_m=self.sensor_height_m,
                           sensor_xy_m=self.sensor_xy_m)
        boxes = [points_in_box(pts, d.x, d.y, d.width, d.depth, d.yaw, d.height) for d in gated]
        held = self.held_columns(t_s, est, pts, gated, boxes)
        keep = [k for k, d in enumerate(gated) if d.is_person or k in held]
        out = [PersonDetection(np.array([gated[k].x, gated[k].y]), float(gated[k].height), float(gated[k].score),
                               reflectance_histogram_of(pts[boxes[k], 3])) for k in keep]
        self._hold(t_s, est, np.array([d.xy_robot_m for d in out]).reshape(-1, 2))
        t2 = time.perf_counter()
        self.frame_stats.append(dict(t_s=t_s, raycast_s=t1 - t0, detect_s=t2 - t1, people=len(people),
                                 people_in_range=in_range, points=len(pts), detections=len(out),
                                 near_rule=len(held)))
        self.last_points = frame.points
        return out

    def held_columns(self, t_s: float, pose_estimate: np.ndarray, pts: np.ndarray, gated: list,
                     boxes: list[np.ndarray]) -> set[int]:
        """Indices into ``gated`` (the detector's gated clusters, ``boxes`` their points) of those
        scored below the threshold within the gate of a held person detection (``HOLD_GATE_M`` +
        ``HOLD_SPEED_MPS`` x its age, at most ``HOLD_MAX_GATE_M``; at most ``HOLD_S`` old) that score
        at least ``HELD_THRESHOLD`` or are person-sized columns cut by the field of view (``fov_cut``;
        not with sensors ``sensor_views`` cannot describe)."""
        fresh = t_s - self.held_t_s <= HOLD_S
        weak = [k for k, d in enumerate(gated) if not d.is_person]
        if not weak or not fresh.any():
            return set()
        held_robot = to_robot(self.held_xy_world_m[fresh], pose_estimate)
        gate_m = np.minimum(HOLD_GATE_M + HOLD_SPEED_MPS * (t_s - self.held_t_s[fresh]), HOLD_MAX_GATE_M)
        at_top, at_bottom = edge_flags(pts, self.views) if self.views else (None, None)
        out = set()
        for k in weak:
            d = gated[k]
            if not np.any(np.hypot(*(held_robot - [d.x, d.y]).T) <= gate_m):
                continue
            if d.score >= HELD_THRESHOLD or (
                    self.views and fov_cut(pts, boxes[k], d.width, d.depth, d.yaw, self.views, at_top, at_bottom)):
                out.add(k)
        return out

    def _hold(self, t_s: float, pose_estimate: np.ndarray, xy_robot_m: np.ndarray) -> None:
        """Keep this frame's person detections (robot frame) in the world frame for ``HOLD_S``."""
        xy_world = to_world(xy_robot_m, pose_estimate).reshape(-1, 2)
        fresh = t_s - self.held_t_s <= HOLD_S
        self.held_xy_world_m = np.vstack([self.held_xy_world_m[fresh], xy_world])
        self.held_t_s = np.r_[self.held_t_s[fresh], np.full(len(xy_world), t_s)]

    def frame(self, t_s: float, pose_world_robot: np.ndarray, people: list[tuple[Walker, np.ndarray]],
              target_xy_world_m: np.ndarray | None, robot_stopped: bool) -> tuple[FollowFrame, np.ndarray]:
        """The frame at ``t_s`` seen from the true pose; also which of ``people`` were in sight
        (``visible_people``, the scoring's truth)."""
        pose = np.asarray(pose_world_robot, dtype=float)
        base, _ = self.base.frame(t_s, pose, [], target_xy_world_m, robot_stopped)
        dets = self.detections(t_s, pose, people, np.asarray(base.pose_world_robot, float))
        xy = np.array([p for _, p in people]).reshape(-1, 2)
        target = None if target_xy_world_m is None else to_robot(target_xy_world_m, pose)[0]
        det_xy = np.array([d.xy_robot_m for d in dets]).reshape(-1, 2)
        near = np.linalg.norm(det_xy[:, None, :] - to_robot(xy, pose)[None, :, :], axis=2) <= TARGET_MATCH_M
        self.frame_stats[-1].update(
            target_range_m=np.nan if target is None else float(np.hypot(*target)),
            target_detected=bool(target is not None and np.any(np.hypot(*(det_xy - target).T) <= TARGET_MATCH_M)),
            people_detected=int(near.any(axis=0).sum()), false_detections=int((~near.any(axis=1)).sum()))
        return replace(base, detections=tuple(dets)), visible_people(pose, xy, self.occupancy)


def make_sensing(sensing: str, episode: Episode, rng: np.random.Generator, lidar: str | None = None):
    """The per-frame sensing of an episode: ``"ideal"`` (:class:`Sensing`) or ``"lidar"``
    (:class:`LidarSensing` with the preset ``lidar``, the FX8 pair by default)."""
    check_sensing(sensing, lidar)
    if sensing == "ideal":
        return Sensing(episode.occupancy, rng)
    return LidarSensing(episode, rng, lidar or DEFAULT_LIDAR)


__all__ = ["SENSING_MODES", "DEFAULT_LIDAR", "LidarSensing", "make_sensing", "check_sensing", "lidar_preset",
           "wall_boxes", "wall_meshes", "place_clutter", "walker_samples", "points_in_box", "reflectance_histogram_of"]
