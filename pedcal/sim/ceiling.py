"""The ceiling sensor network: layout, hand-measured (installed) extrinsics, field of view, and
the tracking system that turns true head positions into observations.csv rows.

Sensors are ASUS Xtion Pro Live-like depth cameras (58 x 45 deg, 0.8-3.5 m reliable, noisy to
~5 m). Frames follow :mod:`pedcal.frames`: sensor x is the optical axis, y left, z up.
"""

from __future__ import annotations

import numpy as np

from pedcal import frames
from pedcal.errors import PedcalInputError
from pedcal.model import SensorExtrinsics, SensorNetwork
from pedcal.sim.nuisances import dome_point, head_point, sensor_clocks, sensor_head_models  # noqa: F401
from pedcal.sim.scenario import Scenario


def corridor_axes(sc: Scenario) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The corridors of a ``corridor``, ``cross`` or ``lhall`` layout: (start, end, width) of each
    centre line (m). ``lhall``: a wing along x at y < width and a wing along y at
    x > area_m[0] - width, sharing the corner square."""
    ax, ay = sc.area_m
    if sc.layout == "corridor":
        return [(np.array([0.0, ay / 2]), np.array([ax, ay / 2]), float(ay))]
    w = sc.corridor_width_m
    if sc.layout == "lhall":
        return [(np.array([0.0, w / 2]), np.array([ax, w / 2]), w),
                (np.array([ax - w / 2, 0.0]), np.array([ax - w / 2, ay]), w)]
    return [(np.array([0.0, ay / 2]), np.array([ax, ay / 2]), w), (np.array([ax / 2, 0.0]), np.array([ax / 2, ay]), w)]


WALL_MARGIN_M = 0.1     # a wall-mounted sensor's distance from the wall it hangs on (m)


def _corridor_layout(sc: Scenario, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """(position, yaw deg) of sensors on alternating walls of each corridor, WALL_MARGIN_M from the wall,
    looking across; in a ``cross`` none over the crossing of the two corridors."""
    out = []
    corridors = corridor_axes(sc)
    for n_c, (start, end, width) in enumerate(corridors):
        d = end - start
        length = float(np.linalg.norm(d))
        along = d / length
        left = np.array([-along[1], along[0]])
        n = sc.corridor_sensors
        if sc.layout == "lhall":    # none within lhall_gap_m of the corner square
            free = length - width - sc.lhall_gap_m
            s_k = (np.arange(n) + 0.5) * free / n
            s_k = s_k if n_c == 0 else length - s_k          # the x wing from its far end
        elif len(corridors) > 1:    # skip the crossing: n sensors over the two arms
            half = (length - width) / 2
            s_k = np.r_[(np.arange(n // 2) + 0.5) * half / (n // 2),
                        half + width + (np.arange(n - n // 2) + 0.5) * half / (n - n // 2)]
        else:
            s_k = (np.arange(n) + 0.5) * length / n
        for k, s_along in enumerate(s_k):
            side = 1.0 if k % 2 == 0 else -1.0      # left wall looks right and vice versa
            xy = start + s_along * along + side * (width / 2 - WALL_MARGIN_M) * left
            look = -side * left
            yaw = np.degrees(np.arctan2(look[1], look[0]))
            out.append((xy + rng.normal(0.0, sc.position_jitter_m, 2), yaw))
    return out


def layout_network(sc: Scenario, rng: np.random.Generator) -> SensorNetwork:
    """True extrinsics (``layout: grid``): ``grid_rows`` rows of ``grid_cols`` sensors over the area. Rows look
    alternately along +x and -x (each row starts at the end it looks away from), with
    ``pitch_deg`` cycled over the sensors, so neighbouring fields of view overlap partly.
    Ids run s01, s02, ... in x order. ``corridor`` and ``cross`` layouts: sensors on
    alternating walls (:func:`_corridor_layout`), ids in layout order."""
    if sc.layout != "grid":
        placed = _corridor_layout(sc, rng)
        n = len(placed)
        z = sc.sensor_height_m + rng.normal(0.0, sc.height_jitter_m, n)
        yaw = np.array([y for _, y in placed]) + rng.normal(0.0, sc.yaw_jitter_deg, n)
        pitch = np.resize(np.asarray(sc.pitch_deg, float), n)
        net = SensorNetwork([SensorExtrinsics(f"s{k + 1:02d}", [xy[0], xy[1], z[k]],
                                              [frames.wrap_angle_rad(np.radians(yaw[k])) * 180 / np.pi, pitch[k], 0.0])
                             for k, (xy, _) in enumerate(placed)])
        return _keep(net, sc)
    area_x, area_y = sc.area_m
    rows = np.arange(sc.grid_rows)
    row_y = (np.asarray(sc.row_y_m, float) if sc.row_y_m is not None
             else area_y * (rows + 0.5) / sc.grid_rows)
    if len(row_y) != sc.grid_rows:
        raise PedcalInputError(f"{len(row_y)} entries for {sc.grid_rows} rows (grid_rows)", column="row_y_m")
    row, col = np.divmod(np.arange(sc.grid_rows * sc.grid_cols), sc.grid_cols)
    forward = row % 2 == 0                                   # row looks along +x
    dx = area_x / sc.grid_cols
    x = np.where(forward, dx * (col + 0.2), area_x - dx * (col + 0.2))
    n = len(x)
    xy = np.column_stack([x, row_y[row]]) + rng.normal(0.0, sc.position_jitter_m, (n, 2))
    z = sc.sensor_height_m + rng.normal(0.0, sc.height_jitter_m, n)
    yaw = np.where(forward, 0.0, 180.0) + rng.normal(0.0, sc.yaw_jitter_deg, n)
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    pitch = np.resize(np.asarray(sc.pitch_deg, float), n)
    sensors = [SensorExtrinsics(f"s{k + 1:02d}", [xy[i, 0], xy[i, 1], z[i]],
                                [frames.wrap_angle_rad(np.radians(yaw[i])) * 180 / np.pi, pitch[k], 0.0])
               for k, i in enumerate(order)]
    return _keep(SensorNetwork(sensors), sc)


def mount_draw(sc: Scenario, n: int) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mixed mounting heights (sensor_height_range_m; None when off) and which of the ``n``
    sensors are wall-mounted (wall_mounted_fraction) at which pitch (wall_pitch_deg, deg), aimed
    how far (wall_aim_m, m) and, in a corridor, turned which way along it (+-1), drawn from a
    stream of their own so that the layout's other draws stay those of the seed."""
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x4D0]))
    z = rng.uniform(*sc.sensor_height_range_m, n) if sc.sensor_height_range_m is not None else None
    wall = np.zeros(n, dtype=bool)
    wall[rng.permutation(n)[:int(round(sc.wall_mounted_fraction * n))]] = True
    pitch = rng.uniform(*sc.wall_pitch_deg, n)
    return z, wall, pitch, rng.uniform(*sc.wall_aim_m, n), rng.choice([-1.0, 1.0], n)


def wall_mount(sc: Scenario, xy_m: np.ndarray, yaw_deg: float, pitch_deg: float, aim_m: float,
               turn_sign: float) -> tuple[np.ndarray, float, float]:
    """Where a wall-mounted sensor hangs, (xy (m), height (m), yaw (deg)), when its layout slot is
    ``xy_m`` looking along ``yaw_deg`` and it is pitched ``pitch_deg`` down: aimed so that its
    optical axis meets head height h (the middle of person_height_m) ``aim_m`` away horizontally,
    at height h + aim tan(pitch), and so that the aimed-at point lies on the covered floor.

    ``grid``: the sensor moves back along its view, never past the wall behind it, until that
    point is at least 0.5 m inside the area. Corridor layouts (their sensors are on the walls,
    looking across): the view turns along the corridor (toward ``turn_sign`` x its left) until
    that point is on the corridor's centre line, as wall sensors in corridors look along them."""
    h_aim = float(np.mean(sc.person_height_m))
    z = h_aim + aim_m * np.tan(np.radians(pitch_deg))
    xy = np.asarray(xy_m, float).copy()
    look = np.array([np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))])
    if sc.layout == "grid":
        hi = np.asarray(sc.area_m, float)
        target = np.clip(xy + aim_m * look, 0.5, hi - 0.5)
        # back along -look: the largest move s >= 0 needed on either axis, then no farther than the wall
        need = max([(xy[a] + aim_m * look[a] - target[a]) / look[a] for a in (0, 1) if abs(look[a]) > 1e-9] + [0.0])
        room = min([((hi[a] - WALL_MARGIN_M - xy[a]) if look[a] < 0 else (xy[a] - WALL_MARGIN_M)) / abs(look[a])
                    for a in (0, 1) if abs(look[a]) > 1e-9])
        return xy - min(max(need, 0.0), max(room, 0.0)) * look, float(z), float(yaw_deg)
    # the corridor whose wall the sensor is on: its centre line is half a width (less the margin) away
    def off_wall(c):
        start, end, width = c
        along = (end - start) / np.linalg.norm(end - start)
        rel = xy - start
        return abs(abs(along[0] * rel[1] - along[1] * rel[0]) - (width / 2 - WALL_MARGIN_M))
    start, end, width_m = min(corridor_axes(sc), key=off_wall)
    length = float(np.linalg.norm(end - start))
    along = (end - start) / length
    turn = np.degrees(np.arccos(np.clip((width_m / 2 - WALL_MARGIN_M) / aim_m, -1.0, 1.0)))
    for sign in (turn_sign, -turn_sign):      # the drawn way, unless it aims past the corridor's end
        yaw = yaw_deg + sign * turn
        aimed = xy + aim_m * np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))])
        if 0.5 <= float(along @ (aimed - start)) <= length - 0.5:
            break
    return xy, float(z), float(yaw)


def reaimed_pitch_deg(sc: Scenario, z_layout_m: float, pitch_deg: float, z_m: float) -> float:
    """The pitch (deg) of a ceiling sensor hung at ``z_m`` instead of its layout height
    ``z_layout_m`` (pitched ``pitch_deg`` there), re-aimed so that its optical axis still meets
    head height h (the middle of person_height_m) at the same floor point: atan((z - h) / d),
    d = (z_layout - h) / tan(pitch). Unchanged when either height is not above h + 0.1 m."""
    h_aim = float(np.mean(sc.person_height_m))
    if min(z_layout_m, z_m) <= h_aim + 0.1:
        return float(pitch_deg)
    reach_m = (z_layout_m - h_aim) / np.tan(np.radians(pitch_deg))
    return float(np.degrees(np.arctan2(z_m - h_aim, reach_m)))


def _mounts(net: SensorNetwork, sc: Scenario) -> SensorNetwork:
    """``net`` with the heights and wall mounts of :func:`mount_draw` (:func:`wall_mount`); a
    ceiling sensor hung at a mixed height is re-aimed at the floor point its layout slot watched
    (:func:`reaimed_pitch_deg`: raised without it, its view would land beyond the room's wall)."""
    if sc.sensor_height_range_m is None and sc.wall_mounted_fraction <= 0.0:
        return net
    z, wall, wall_pitch, aim, turn_sign = mount_draw(sc, len(net))
    out = []
    for k, s in enumerate(net):
        ypr = frames.ypr_deg_from_rot(s.R_world_sensor)
        p = np.array([s.position_m[0], s.position_m[1], s.position_m[2] if z is None else z[k]])
        if wall[k]:
            xy, p[2], yaw = wall_mount(sc, s.position_m[:2], ypr[0], wall_pitch[k], aim[k], turn_sign[k])
            p[:2] = xy
            ypr = np.array([frames.wrap_angle_rad(np.radians(yaw)) * 180 / np.pi, wall_pitch[k], ypr[2]])
        elif z is not None:
            ypr[1] = reaimed_pitch_deg(sc, s.position_m[2], ypr[1], z[k])
        out.append(SensorExtrinsics(s.id, p, ypr))
    return SensorNetwork(out)


def _keep(net: SensorNetwork, sc: Scenario) -> SensorNetwork:
    net = _mounts(net, sc)
    if sc.sensor_ids is not None:
        missing = [s for s in sc.sensor_ids if s not in net]
        if missing:
            raise PedcalInputError(f"{missing} are not in the layout ({', '.join(net.ids)})",
                                   column="sensor_ids")
        net = SensorNetwork([net[s] for s in sc.sensor_ids])
    return net


def _small_rotation(rng: np.random.Generator, sigma_ypr_deg, cap_deg: float) -> np.ndarray:
    """A random rotation with per-axis std ``sigma_ypr_deg``, its angle capped at ``cap_deg``."""
    ypr = rng.normal(0.0, sigma_ypr_deg)
    angle = frames.rotation_angle_deg(np.eye(3), frames.rot_from_ypr_deg(ypr))
    if angle > cap_deg:
        ypr = ypr * cap_deg / angle
    return frames.rot_from_ypr_deg(ypr)


def installed_network(truth: SensorNetwork, sc: Scenario, rng: np.random.Generator) -> SensorNetwork:
    """Extrinsics as a person measured them: the whole network shifted and turned coherently
    about its centroid (a survey whose origin and axes are off), then each sensor's own
    position and angle errors, capped at ``installed_cap_m`` and ``installed_cap_deg``."""
    P = np.array([s.position_m for s in truth])
    centroid = P.mean(axis=0)
    # Sizes between half and 1.5 times the nominal ones, random direction and sense: a survey
    # is off by about so much, never by several times it.
    size = rng.uniform(0.5, 1.5, 2)
    heading = rng.uniform(0.0, 2.0 * np.pi)
    turn = frames.rot_from_ypr_deg([rng.choice([-1.0, 1.0]) * size[0] * sc.installed_turn_deg, 0.0, 0.0])
    shift = size[1] * sc.installed_shift_m * np.array([np.cos(heading), np.sin(heading), 0.0])
    out = []
    for s, p in zip(truth, P, strict=True):
        d = rng.normal(0.0, sc.installed_sigma_position_m)
        norm = np.linalg.norm(d)
        if norm > sc.installed_cap_m:
            d *= sc.installed_cap_m / norm
        own = _small_rotation(rng, sc.installed_sigma_ypr_deg, sc.installed_cap_deg)
        p_inst = turn @ (p - centroid) + centroid + shift + d
        R_inst = turn @ s.R_world_sensor @ own
        # The coherent turn adds to the own error; cap the total error as well.
        total_err = p_inst - p
        if np.linalg.norm(total_err) > sc.installed_cap_m:
            p_inst = p + total_err * sc.installed_cap_m / np.linalg.norm(total_err)
        out.append(SensorExtrinsics(s.id, p_inst, frames.ypr_deg_from_rot(R_inst)))
    return SensorNetwork(out)


def in_frustum(p_sensor: np.ndarray, sc: Scenario) -> np.ndarray:
    """Mask of sensor-frame points (N, 3) inside the field of view and the range limits."""
    x, y, z = p_sensor[..., 0], p_sensor[..., 1], p_sensor[..., 2]
    r = np.linalg.norm(p_sensor, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return ((x > 0)
                & (np.abs(np.arctan2(y, x)) <= np.radians(sc.hfov_deg / 2))
                & (np.abs(np.arctan2(z, x)) <= np.radians(sc.vfov_deg / 2))
                & (r >= sc.min_range_m) & (r <= sc.max_range_m))


def coverage(net: SensorNetwork, sc: Scenario, p_world: np.ndarray) -> np.ndarray:
    """(n_sensors, N) mask: which sensor sees which world point."""
    return np.stack([in_frustum(s.to_sensor(p_world), sc) for s in net])


def ar1_coefficients(t_capture_s: np.ndarray, new_track: np.ndarray, sc: Scenario) -> np.ndarray:
    """Each row's AR(1) coefficient of the tracker's noise (Scenario.tracker_noise_rho) for rows
    sorted by (sensor, entity, capture time): rho^n with n the frames since the row before, 0 at
    the start of a track (the noise restarts)."""
    n_frames = np.rint(np.diff(t_capture_s, prepend=t_capture_s[:1]) * sc.frame_rate_hz)
    coef = sc.tracker_noise_rho ** np.maximum(n_frames, 1.0)
    return np.where(new_track, 0.0, coef)


def ar1(w: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Stationary AR(1) of white standard draws ``w`` (N, ...) along its rows:
    e_k = a_k e_{k-1} + sqrt(1 - a_k^2) w_k, each row's marginal law that of w_k (a_k = 0: e_k = w_k,
    a restart). Vectorized over the tracks: one step per position within a run of a_k > 0."""
    e = np.array(w, dtype=float, copy=True)
    going = coef > 0.0
    going[:1] = False               # (the first row has nothing to continue)
    if not going.any():
        return e
    # each row's position within its run of continued rows (0 at a restart), a step per position
    idx = np.arange(len(coef))
    pos = idx - np.maximum.accumulate(np.where(going, 0, idx))
    by_pos = np.argsort(pos, kind="stable")
    bounds = np.searchsorted(pos[by_pos], np.arange(1, pos.max() + 2))
    scale = np.sqrt(1.0 - coef ** 2)
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        rows = by_pos[lo:hi]
        shape = (len(rows),) + (1,) * (e.ndim - 1)
        e[rows] = coef[rows].reshape(shape) * e[rows - 1] + scale[rows].reshape(shape) * w[rows]
    return e


def measure(p_sensor: np.ndarray, sc: Scenario, rng: np.random.Generator,
            ar1_coef: np.ndarray | None = None) -> np.ndarray:
    """Add the depth sensor's noise to true sensor-frame points (N, 3): along the ray
    sigma = k r^2 (``linear``: 2.5 k r; times far_noise_factor beyond reliable_range_m), plus
    lateral noise. ``ar1_coef`` (per row, :func:`ar1_coefficients`) correlates both frame to
    frame within a track (a tracker that filters its output), each frame's std unchanged; None
    (the caller's switch, a tracker noise rho of 0) keeps the noise white."""
    r = np.linalg.norm(p_sensor, axis=1)
    ray = p_sensor / r[:, None]
    grow = 2.5 * r if sc.depth_noise_model == "linear" else r ** 2
    sigma_depth = sc.depth_noise_k_per_m * grow * np.where(r > sc.reliable_range_m, sc.far_noise_factor, 1.0)
    z_depth = rng.standard_normal(len(r))
    if ar1_coef is not None:
        z_depth = ar1(z_depth, ar1_coef)
    along = ray * (z_depth * sigma_depth)[:, None]
    lateral = 0.0
    if sc.lateral_noise_m > 0:
        lateral = rng.normal(0.0, sc.lateral_noise_m, p_sensor.shape)
        if ar1_coef is not None:        # the 3-D draw correlated, then taken across the ray
            lateral = ar1(lateral, ar1_coef)
        lateral = lateral - ray * np.sum(lateral * ray, axis=1, keepdims=True)
    return p_sensor + along + lateral


# ------------------------------------------------------------------------------------ tracker
def frame_times(sc: Scenario, n_sensors: int, t0: float, t1: float, rng: np.random.Generator) -> np.ndarray:
    """(n_sensors, n_frames) capture times: each sensor runs at frame_rate_hz with its own phase."""
    period = 1.0 / sc.frame_rate_hz
    k = np.arange(int(np.floor((t1 - t0) / period)))
    return t0 + rng.uniform(0.0, period, (n_sensors, 1)) + k * period


def _first_in_group(keys: list[np.ndarray]) -> np.ndarray:
    """For rows sorted by ``keys``, True where any key differs from the previous row's."""
    first = np.zeros(len(keys[0]), dtype=bool)
    first[:1] = True
    for k in keys:
        first[1:] |= k[1:] != k[:-1]
    return first


def _track_losses(t: np.ndarray, first: np.ndarray, sc: Scenario, rng: np.random.Generator) -> np.ndarray:
    """Mask of detections lost while a head is temporarily not tracked (occlusion, merging):
    a loss starts at rate track_loss_rate_hz and lasts a time drawn from track_loss_s. Rows are
    sorted by (sensor, entity, t); ``first`` marks the start of each (sensor, entity) group."""
    if sc.track_loss_rate_hz <= 0 or len(t) == 0:
        return np.zeros(len(t), dtype=bool)
    starts = rng.random(len(t)) < sc.track_loss_rate_hz / sc.frame_rate_hz
    ends = np.where(starts, t + rng.uniform(*sc.track_loss_s, len(t)), -np.inf)
    # Running maximum of loss ends within each group: offset each group far beyond the last.
    group = np.cumsum(first)
    offset = group * (10.0 * (t.max() - t.min() + 100.0))
    running = np.maximum.accumulate(ends + offset) - offset
    return t < running


def tracker_observations(true_net: SensorNetwork, installed: SensorNetwork, sc: Scenario,
                         frames_t: np.ndarray, entity: np.ndarray, sensor: np.ndarray, t_capture: np.ndarray,
                         p_top_world: np.ndarray, is_head: np.ndarray,
                         rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The ceiling tracking system: from candidate (entity, sensor, capture time, true head top)
    rows, keep what the sensor sees, drop lost frames, misses and temporary track losses, take
    the dome point facing the sensor, add depth noise in the sensor frame (true extrinsics),
    map to the world with the INSTALLED extrinsics (p_world = R_inst p_sensor + t_inst,
    LOG_FORMAT.md), stamp with the latency (and each sensor's clock offset and skew) and number
    the tracks per sensor.

    Returns arrays sorted by stamp: t, sensor (index), track, xyz, entity.
    """
    R_true = np.stack([s.R_world_sensor for s in true_net])
    t_true = np.stack([s.position_m for s in true_net])
    R_inst = np.stack([s.R_world_sensor for s in installed])
    t_inst = np.stack([s.position_m for s in installed])

    p_s = np.einsum("nji,nj->ni", R_true[sensor], p_top_world - t_true[sensor])
    keep = in_frustum(p_s, sc)
    # Lost frames: the whole frame of that sensor is gone.
    frame_k = np.rint((t_capture - frames_t[sensor, 0]) * sc.frame_rate_hz).astype(int)
    lost = rng.random(frames_t.shape) < sc.frame_loss_prob
    keep &= ~lost[sensor, np.clip(frame_k, 0, frames_t.shape[1] - 1)]
    keep &= rng.random(len(keep)) >= sc.miss_prob
    idx = np.flatnonzero(keep)
    order = idx[np.lexsort((t_capture[idx], entity[idx], sensor[idx]))]
    s_o, e_o, t_o = sensor[order], entity[order], t_capture[order]
    order = order[~_track_losses(t_o, _first_in_group([s_o, e_o]), sc, rng)]
    s_o, e_o, t_o = sensor[order], entity[order], t_capture[order]

    # Track ids: a new id at a new (sensor, entity) or after a gap longer than track_gap_s.
    new_track = _first_in_group([s_o, e_o])
    new_track[1:] |= np.diff(t_o) > sc.track_gap_s
    # Number each sensor's tracks 1, 2, ... in the order they start, as a tracker does.
    segment = np.cumsum(new_track) - 1
    seg_sensor, seg_start = s_o[new_track], t_o[new_track]
    seg_order = np.lexsort((seg_start, seg_sensor))
    first_of_sensor = _first_in_group([seg_sensor[seg_order]])
    rank = np.arange(len(seg_order)) - np.maximum.accumulate(
        np.where(first_of_sensor, np.arange(len(seg_order)), 0))
    seg_id = np.empty(len(seg_order), dtype=int)
    seg_id[seg_order] = rank + 1
    track = seg_id[segment]

    p_top = p_top_world[order]
    head = is_head[order]
    p_seen = p_top.copy()
    if sc.per_sensor_head:          # each sensor's own tracker
        for i, model in enumerate(sensor_head_models(sc, len(true_net))):
            mine = head & (s_o == i)
            p_seen[mine] = head_point(p_top[mine], t_true[s_o[mine]], model)
    else:
        p_seen[head] = head_point(p_top[head], t_true[s_o[head]], sc)
    p_sensor = np.einsum("nji,nj->ni", R_true[s_o], p_seen - t_true[s_o])
    if len(p_sensor):
        coef = ar1_coefficients(t_o, new_track, sc) if sc.tracker_noise_rho > 0 else None
        p_sensor = measure(p_sensor, sc, rng, coef)
    p_world = np.einsum("nij,nj->ni", R_inst[s_o], p_sensor) + t_inst[s_o]
    jitter = np.clip(rng.normal(0.0, sc.latency_jitter_s, len(t_o)), -3 * sc.latency_jitter_s,
                     3 * sc.latency_jitter_s) if sc.latency_jitter_s > 0 else 0.0
    stamp = t_o + sc.latency_s + jitter
    if sc.clock_offset_s or sc.clock_skew_ppm:      # each sensor's own clock
        offset, skew_ppm = sensor_clocks(sc, len(true_net))
        stamp = stamp + offset[s_o] + 1e-6 * skew_ppm[s_o] * (t_o - sc.start_time_s)
    by_time = np.argsort(stamp, kind="stable")
    return {"t": stamp[by_time], "sensor": s_o[by_time], "track": track[by_time],
            "xyz": p_world[by_time], "entity": e_o[by_time]}
