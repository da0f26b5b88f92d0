"""Simulation scenarios: every parameter of the ceiling-network simulator, typed and documented.

A scenario is a YAML file in ``datasets/`` (``paper``, ``sparse``, ``mall``) or any YAML file whose
keys are the fields of :class:`Scenario`. A file may start from another one with ``base: <name>``.
Unknown keys are rejected, naming the file and the key.

Nuisances (everything that makes the logs differ from the truth, apart from the installed
extrinsics, which are what a calibration estimates) carry ``metadata={"off": value}``:
``Scenario.resolve(noise_free=True)`` sets every one of them to its "off" value.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

from pedcal.errors import PedcalInputError, show
from pedcal.io.sensors_yaml import load_yaml_file

DATASETS_DIR = Path(__file__).resolve().parents[2] / "datasets"
WALKER_SOURCES = ("builtin", "atc", "eth_ucy", "thor", "none")
CHOICES = {"layout": ("grid", "corridor", "cross", "lhall"),
           "head_point": ("top", "dome", "shift", "centroid", "ramp", "saturate"),
           "head_ramp_shape": ("linear", "exp", "smooth"),
           "amcl_error": ("white", "correlated", "jumps"), "depth_noise_model": ("quadratic", "linear")}


def _nuisance(default, off=0.0):
    return field(default=default, metadata={"off": off})


@dataclass
class Scenario:
    """Parameters of one simulated installation and its two robot runs (calib, eval)."""

    name: str = "custom"
    """Scenario name, recorded in scenario.yaml."""

    # ---- geometry -------------------------------------------------------------------------
    area_m: list = field(default_factory=lambda: [8.2, 4.5])
    """Size [x, y] of the covered floor area (m); the area spans [0, x] x [0, y]. The paper's
    experiment covered 8.2 x 4.5 m with 10 sensors."""
    grid_rows: int = 2
    """Rows of ceiling sensors (along y)."""
    grid_cols: int = 5
    """Sensors per row (along x)."""
    sensor_height_m: float = 2.6
    """Mounting height of the sensors (m); 2.6 m in the paper."""
    height_jitter_m: float = 0.05
    """Std of each sensor's height around sensor_height_m (m): ceilings and mounts differ."""
    row_y_m: list | None = None
    """y of each sensor row (m); None spaces the rows evenly over the area."""
    pitch_deg: list = field(default_factory=lambda: [45.0])
    """Downward tilt of the sensors (deg), cycled over the sensors in id order; the paper's
    sensors look 30-60 deg down. Steep ones see a small patch under them, shallow ones far."""
    yaw_jitter_deg: float = 2.0
    """Std of each sensor's yaw around its row's look direction (deg): mounts are not aligned."""
    position_jitter_m: float = 0.05
    """Std of each sensor's horizontal offset from its grid slot (m): mounts sit where the
    ceiling allows."""
    sensor_ids: list | None = None
    """Keep only these sensors of the layout (None: all). ``sparse`` keeps the 5 middle ones."""
    layout: str = "grid"
    """Where the sensors hang and where the robot drives: ``grid`` (rows over a room, a
    lawnmower route), ``corridor`` (a corridor along x, area_m = [length, width], corridor_sensors
    on alternating walls looking across it, the robot driving up and down it) or ``cross`` (two
    such corridors crossing at the centre of a square area_m, corridor_sensors per corridor, none
    over the crossing; the robot drives up and down one, then the other)."""
    corridor_width_m: float = 2.4
    """Width of the corridors of the ``corridor`` and ``cross`` layouts (m); ``corridor`` takes
    area_m[1]."""
    corridor_sensors: int = 16
    """Sensors per corridor of the ``corridor`` and ``cross`` layouts (per wing of ``lhall``)."""
    lhall_gap_m: float = 3.0
    """``lhall`` layout (an L-shaped hall: a wing along x and a wing along y joined at the
    corner x > area_m[0] - width, y < width): length of each wing next to the corner square
    without sensors (m), so that the two wings' sensors share no view and only the robot's path
    joins them."""
    sensor_height_range_m: list | None = None
    """Mixed mounting heights: each sensor's height drawn uniformly in [min, max] (m) instead of
    sensor_height_m +- height_jitter_m (e.g. [2.6, 4.5]: ceilings of a hall, a foyer, a
    mezzanine). None: sensor_height_m."""
    wall_mounted_fraction: float = 0.0
    """Share of the sensors (chosen from the seed) mounted on a wall and pitched only
    wall_pitch_deg down, looking far across the floor instead of down at it. A wall mount is
    aimed the way an installer aims one: its optical axis meets head height (the middle of
    person_height_m) wall_aim_m away, horizontally, inside the covered floor; its height follows
    from that and its pitch (:func:`pedcal.sim.ceiling.wall_mount`)."""
    wall_pitch_deg: list = field(default_factory=lambda: [10.0, 25.0])
    """Range [min, max] of a wall-mounted sensor's downward pitch (deg), drawn uniformly."""
    wall_aim_m: list = field(default_factory=lambda: [2.0, 3.5])
    """Range [min, max] of the horizontal distance (m), drawn uniformly, at which a wall-mounted
    sensor's optical axis meets head height: within the reliable range, so that the sensor
    watches the floor in front of it (a shallow sensor hung as high as a ceiling one looks over
    every head)."""

    # ---- depth sensor (ASUS Xtion Pro Live) -----------------------------------------------------
    hfov_deg: float = 58.0
    """Horizontal field of view (deg), Xtion Pro Live datasheet."""
    vfov_deg: float = 45.0
    """Vertical field of view (deg), Xtion Pro Live datasheet."""
    min_range_m: float = 0.8
    """Closest range the sensor measures (m), Xtion datasheet (0.8 m)."""
    max_range_m: float = 5.0
    """Farthest range a head is still tracked (m); beyond the reliable range depth is noisy."""
    reliable_range_m: float = 3.5
    """Range up to which depth is reliable (m), Xtion datasheet (0.8-3.5 m)."""

    # ---- tracker --------------------------------------------------------------------------------
    frame_rate_hz: float = 15.0
    """Rate of the ceiling tracking system's reports per sensor (Hz)."""
    latency_s: float = _nuisance(0.1)
    """Time by which a report's stamp is later than the instant its position belongs to (s);
    depth capture, segmentation and the network delay add up to ~0.1 s."""
    latency_jitter_s: float = _nuisance(0.01)
    """Std of the per-report latency around latency_s (s)."""
    clock_offset_s: float = _nuisance(0.0)
    """Per-sensor clock offsets: each sensor's stamps are late by a further offset drawn
    uniformly in [-this, +this] (s) from the seed (each tracker PC keeps its own clock; NTP
    leaves ~0.1 s between machines)."""
    clock_skew_ppm: float = _nuisance(0.0)
    """Per-sensor clock rate error: each sensor's stamps drift by a rate drawn uniformly in
    [-this, +this] (parts per million) times the time since start_time_s."""
    depth_noise_k_per_m: float = _nuisance(1.5e-3)
    """Depth noise along the ray, sigma = k r^2 (1/m): structured-light sensors (Khoshelham and
    Elberink 2012 report ~1.5e-3 r^2 for the Kinect/Xtion)."""
    depth_noise_model: str = "quadratic"
    """How depth noise grows with range: ``quadratic`` (k r^2, structured light) or ``linear``
    (2.5 k r, equal at 2.5 m: a time-of-flight sensor)."""
    far_noise_factor: float = _nuisance(2.0, off=1.0)
    """Multiplier of the depth noise beyond reliable_range_m: depth degrades past 3.5 m."""
    lateral_noise_m: float = _nuisance(0.01)
    """Std of the head-top estimate across the ray, per axis (m): the blob's top is found on a
    sparse, noisy point cloud."""
    tracker_noise_rho: float = _nuisance(0.0)
    """Frame-to-frame correlation of the tracker's noise (depth and lateral), 0 <= rho < 1: a
    stationary AR(1) over each track's frames, e_k = rho^n e_{k-1} + sqrt(1 - rho^2n) w_k (n the
    frames since the track's previous report; a new track restarts it), each frame's std that of
    the fields above. 0 is white noise; a tracker that filters its output at 10-30 Hz makes
    consecutive reports alike (0.3-0.85)."""
    head_point: str = _nuisance("dome", off="top")
    """Which point of a head the tracker reports: ``top`` (the highest point), ``dome`` (the
    point of a dome of radius head_radius_m facing the sensor), ``shift`` (the top moved
    head_shift_m horizontally toward the sensor), ``centroid`` (the centroid of the part of the
    top 10 cm of a 0.1 m head the sensor sees), ``ramp`` (a shift toward the sensor of
    head_shift_m right under it that shrinks linearly to nothing at head_ramp_m of horizontal
    distance) or ``saturate`` (a shift that grows linearly from nothing under the sensor to
    head_shift_m at head_ramp_m and stays there). Every one is then moved head_vertical_bias_m
    up."""
    head_ramp_m: float = 2.0
    """Horizontal distance (m) over which the ``ramp`` and ``saturate`` head points change."""
    head_ramp_shape: str = "linear"
    """How the ``ramp`` and ``saturate`` head points change over head_ramp_m, as the share f(x)
    of the change at x = d / head_ramp_m: ``linear`` (f = x, clipped to 1), ``exp`` (f = 1 -
    exp(-3 x): 95 % at head_ramp_m, approaching all of it beyond) or ``smooth`` (f = 3 x^2 - 2
    x^3, clipped: flat at both ends)."""
    per_sensor_head: bool = False
    """Each sensor runs its own tracker: its head point model (any of head_point's kinds) and
    its horizontal parameters (radius, shift, ramp) are drawn per sensor from the seed; the
    vertical bias stays head_vertical_bias_m (a per-sensor vertical offset is indistinguishable
    from that sensor's height error)."""
    head_radius_m: float = _nuisance(0.1)
    """Radius of the head dome (m). The tracker reports the point of the dome facing the
    sensor, so the reported head moves toward the sensor horizontally and down with
    obliquity (by r cos(e) and r (1 - sin e), e the elevation of the sensor seen from the head)."""
    head_shift_m: float = _nuisance(0.04)
    """Horizontal shift of the reported head point toward the sensor (m), head_point ``shift``."""
    head_vertical_bias_m: float = _nuisance(0.0)
    """Vertical bias of the reported head point (m; negative: below), any head_point."""
    head_sink_m: float = _nuisance(0.0)
    """How far the reported head point sinks as the head is seen more from the side (m; negative:
    it rises), any head_point, beyond what a dome's or a centroid's point does: nothing right
    under the sensor, head_sink_m times the share head_ramp_shape gives at d / head_ramp_m (all
    of it at head_ramp_m and beyond, but 95 % for ``exp``), d the horizontal distance from the
    sensor (a tracker whose point slides down the head's side as the view turns oblique). With
    per_sensor_head each sensor's sink is drawn uniform in 0-2 x head_sink_m. Seen from one side
    of the sensor's nadir (a tilted sensor) a sink against distance is the sensor's tilt to first
    order: it moves that sensor's horizontal position back along its view by up to its height
    above the head times the sink's slope (tests/test_head_sink.py)."""
    frame_loss_prob: float = _nuisance(0.02)
    """Probability a whole frame of a sensor is lost (-): network and processing drops."""
    miss_prob: float = _nuisance(0.05)
    """Probability a visible head is missed in a frame (-): segmentation failures."""
    track_loss_rate_hz: float = _nuisance(0.03)
    """Rate at which a tracked head is lost for a while (1/s of tracking): occlusion, merge."""
    track_loss_s: list = field(default_factory=lambda: [0.3, 2.0])
    """Range [min, max] of the duration of such a loss (s), drawn uniformly."""
    track_gap_s: float = 0.5
    """A gap longer than this (s) makes the tracker start a new track id for the same head."""
    false_track_rate_hz: float = _nuisance(1.0 / 60.0)
    """Rate of false tracks per sensor (1/s): reflections, furniture, bags; one a minute."""
    false_track_duration_s: list = field(default_factory=lambda: [0.3, 3.0])
    """Range [min, max] of a false track's life (s)."""
    false_track_height_m: list = field(default_factory=lambda: [0.5, 2.0])
    """Range [min, max] of a false track's height above the floor (m)."""
    false_track_jitter_m: float = 0.03
    """Std of a false track's frame-to-frame jitter (m)."""

    # ---- pedestrians ----------------------------------------------------------------------------
    walkers: str = _nuisance("builtin", off="none")
    """Where pedestrians come from: builtin (random walkers), atc / eth_ucy / thor (recorded
    tracks from the shared data folder; falls back to builtin when absent) or none."""
    walker_rate_hz: float = _nuisance(1.0 / 30.0)
    """Builtin walkers: arrival rate of new pedestrians in the area (1/s)."""
    walker_speed_mps: list = field(default_factory=lambda: [1.2, 0.2])
    """Builtin walkers: mean (> 0) and std (>= 0; 0: all at the mean) of the walking speed (m/s),
    typical indoor walking."""
    person_height_m: list = field(default_factory=lambda: [1.5, 1.9])
    """Range [min, max] of pedestrians' head-top heights (m), drawn uniformly."""
    companion_fraction: float = _nuisance(0.0)
    """Fraction of the run during which a pedestrian walks beside the robot (-), default 0."""
    companion_offset_m: float = 0.7
    """Lateral offset of that companion from the robot's centre, to its left (m; negative: to its right)."""
    companion_replaces_robot: bool = False
    """While the companion walks beside the robot the ceiling trackers report the companion's
    head instead of the robot's (the robot occluded, the tracker locked on the person): that
    fraction of what would be the robot's observations is the companion (labelled so)."""
    companion_swap_fraction: float = _nuisance(0.0)
    """Fraction of the robot's observations (-) that the ceiling trackers report as a companion
    walking beside the robot instead (they lose the robot and pick up the person, on a track of
    its own): swaps of a few seconds each (companion_swap_s),
    spread through the run, their total set so that this share of the robot's sightings (frames
    times sensors that see it) falls in them. Around each swap the companion is tracked as
    itself. truth_observations.csv labels the replaced rows ``companion``, the companion's own
    track ``companion-beside``."""
    companion_swap_s: list = field(default_factory=lambda: [2.0, 6.0])
    """Range [min, max] of the duration of one identity swap (s), drawn uniformly."""
    companion_beside_s: float = 2.0
    """Time (s) the companion walks beside the robot, tracked as itself, before and after each
    swap."""

    # ---- robot ----------------------------------------------------------------------------------
    head_offset_m: list = field(default_factory=lambda: [0.0, 0.0, 1.35])
    """Top of the robot's head in its base frame (m), written to meta.yaml (1.35 m in the paper)."""
    robot_speed_mps: float = 0.3
    """Cruise speed of the robot (m/s)."""
    lane_spacing_m: float = 0.9
    """Spacing of the lawnmower lanes of the route (m)."""
    route_margin_m: float = 0.5
    """Distance the route keeps from the area's border (m)."""
    lookahead_m: float = 0.5
    """Pure-pursuit lookahead distance (m): sets how smoothly corners are cut."""
    max_turn_rate_dps: float = 40.0
    """Cap of the robot's turn rate (deg/s)."""
    robot_stop_s: float = _nuisance(0.0)
    """How long (s) the robot stands still, its pose held, at each stopping waypoint of its
    route (a robot at a goal, or waiting for people to pass); 0: it never stops."""
    robot_stop_share: float = _nuisance(0.0)
    """Share of the route's waypoints (the first and last excepted) at which the robot stops for
    robot_stop_s, chosen from the seed in a stream of their own; 0: it never stops."""
    truth_rate_hz: float = 20.0
    """Rate of the true robot poses (truth_robot.csv) and of wheel odometry (Hz)."""
    duration_s: float | None = None
    """Cut each run after this time (s); None drives the whole route."""
    start_time_s: float = 1000.0
    """Clock time at which the calibration run starts (s)."""
    eval_gap_s: float = 60.0
    """Time between the end of the calibration run and the start of the evaluation run (s)."""

    # ---- AMCL -----------------------------------------------------------------------------------
    amcl_rate_hz: float = 5.0
    """Rate at which AMCL publishes its estimate (Hz)."""
    amcl_sigma_m: float = _nuisance(0.05)
    """Stationary std of AMCL's position error per axis (m); ~5 cm in the paper."""
    amcl_sigma_yaw_deg: float = _nuisance(1.0)
    """Stationary std of AMCL's heading error (deg)."""
    amcl_error: str = "correlated"
    """AMCL's error process: ``white`` (independent per estimate), ``correlated`` (the
    Ornstein-Uhlenbeck process of amcl_tau_s) or ``jumps`` (correlated, plus jumps of
    amcl_jump_m lasting 2-10 s at amcl_jump_rate_hz: a wrong relocalization, then recovery)."""
    amcl_jump_m: float = 0.3
    """Size of AMCL's jumps (m), amcl_error ``jumps``."""
    amcl_jump_rate_hz: float = 1.0 / 90.0
    """Rate of AMCL's jumps (1/s), amcl_error ``jumps``."""
    amcl_jump_life_s: list = field(default_factory=lambda: [2.0, 10.0])
    """Range [min, max] of how long AMCL stays off after a jump (s), drawn uniformly; [10, 10]
    is a wrong relocalization held for 10 s."""
    amcl_tau_s: float = 20.0
    """Correlation time of AMCL's error, a Gauss-Markov (Ornstein-Uhlenbeck) process (s): the
    particle cloud drifts slowly between scan matches, 10-30 s."""
    amcl_reported_sigma_m: list = field(default_factory=lambda: [0.02, 0.08])
    """Range [min, max] of the std AMCL *reports* (m); it varies with time and is uncorrelated
    with the actual error, as amcl's covariance is."""
    amcl_reported_sigma_yaw_deg: list = field(default_factory=lambda: [0.5, 2.0])
    """Range [min, max] of the heading std AMCL reports (deg)."""

    # ---- wheel odometry -------------------------------------------------------------------------
    odometry: bool = True
    """Whether the log has wheel odometry (odometry.csv)."""
    odom_scale_error: float = _nuisance(0.01)
    """Relative error of the distance the wheels report (-): tyre radius, ~1 %."""
    odom_yaw_drift_deg_per_m: float = _nuisance(0.5)
    """Heading drift per metre driven (deg/m): wheel-base error and slip."""
    odom_gyro_bias_dps: float = _nuisance(0.02)
    """Heading drift per second (deg/s): gyro bias of a fused odometry."""
    odom_noise_m: float = _nuisance(0.001)
    """Std of white noise on each position increment (m)."""
    odom_noise_yaw_deg: float = _nuisance(0.05)
    """Std of white noise on each heading increment (deg)."""

    # ---- installed extrinsics (what a person measured) --------------------------------------------
    installed_shift_m: float = 0.2
    """Size of the whole network's horizontal shift (m), drawn in [0.5, 1.5] x this in a random
    direction: the survey's origin is off."""
    installed_turn_deg: float = 2.0
    """Size of the whole network's turn about its centroid (deg), drawn in [0.5, 1.5] x this
    with a random sense: the survey's axes are off."""
    installed_sigma_position_m: list = field(default_factory=lambda: [0.24, 0.24, 0.1])
    """Std per axis [x, y, z] of each sensor's own position error (m): tape-measure work on a
    ladder; heights are easier to measure. With the network's shift and turn this gives a mean
    sensor position error of 371 mm over seeds 0-59 of the paper layout (the paper: ~370 mm)."""
    installed_sigma_ypr_deg: list = field(default_factory=lambda: [4.0, 3.0, 1.5])
    """Std of each sensor's own [yaw, pitch, roll] error (deg): angles are guessed by eye."""
    installed_cap_m: float = 1.0
    """Cap of a sensor's total position error (m)."""
    installed_cap_deg: float = 15.0
    """Cap of a sensor's total rotation error (deg)."""

    # ---- bookkeeping ----------------------------------------------------------------------------
    seed: int = 0
    """Seed of every random generator; the same seed gives identical logs."""

    @classmethod
    def field_names(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def nuisances(cls) -> dict:
        """{name: off value} of every nuisance parameter."""
        return {f.name: f.metadata["off"] for f in dataclasses.fields(cls) if "off" in f.metadata}

    def resolve(self, *, noise_free: bool = False, source: str | Path | None = None,
                **overrides) -> Scenario:
        """A copy with ``overrides`` applied (unknown names rejected) and, with
        ``noise_free=True``, every nuisance set to its off value."""
        values = dataclasses.asdict(self)
        if noise_free:
            values.update(self.nuisances())
        for key, value in overrides.items():
            if key not in values:
                raise PedcalInputError(f"unknown scenario parameter '{key}'", path=source, column=key)
            values[key] = value
        return _typed(values, source)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


_OPTIONAL_TYPES = {"duration_s": float, "sensor_ids": list, "row_y_m": list, "sensor_height_range_m": list}
_VARIABLE_LISTS = ("pitch_deg",)
# Domains of the numeric parameters (each value, or each item of a list): a rate, size, speed or
# count is > 0, a probability or share within [0, 1], these may take either sign, every other
# number (sigmas, noises, durations, margins) is >= 0; a list of [mean, std] has its own per item
# (_ITEM_KINDS). Every value is finite.
_POSITIVE = ("area_m", "grid_rows", "grid_cols", "sensor_height_m", "max_range_m", "reliable_range_m",
             "frame_rate_hz", "corridor_width_m", "corridor_sensors", "robot_speed_mps", "lane_spacing_m",
             "lookahead_m", "max_turn_rate_dps", "truth_rate_hz", "duration_s", "amcl_rate_hz", "amcl_tau_s",
             "person_height_m", "head_ramp_m")
_ANGLES_DEG = ("hfov_deg", "vfov_deg")      # > 0 and at most 180
_SHARES = ("frame_loss_prob", "miss_prob", "wall_mounted_fraction", "companion_fraction", "companion_swap_fraction",
           "robot_stop_share")
_SIGNED = ("row_y_m", "pitch_deg", "clock_offset_s", "clock_skew_ppm", "head_shift_m", "head_vertical_bias_m",
           "head_offset_m", "start_time_s", "odom_scale_error", "odom_yaw_drift_deg_per_m", "odom_gyro_bias_dps",
           "latency_s", "companion_offset_m", "head_sink_m")
_CORRELATIONS = ("tracker_noise_rho",)     # within [0, 1): 1 would never change
_ITEM_KINDS = {"walker_speed_mps": ("positive", "nonnegative")}     # a list whose items differ: [mean, std]


# (lowest, lowest excluded, highest, what the message asks for) of each kind of parameter
_DOMAINS = {"angle": (0.0, True, 180.0, "an angle > 0 and <= 180 deg"),
            "positive": (0.0, True, math.inf, "a finite number > 0"),
            "share": (0.0, False, 1.0, "a share within [0, 1]"),
            "correlation": (0.0, False, math.nextafter(1.0, 0.0), "a correlation within [0, 1)"),
            "signed": (-math.inf, False, math.inf, "a finite number"),
            "nonnegative": (0.0, False, math.inf, "a finite number >= 0")}


def _check_domain(key: str, value, source) -> None:
    items = value if isinstance(value, list) else [value]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
        return
    kind = ("angle" if key in _ANGLES_DEG else "positive" if key in _POSITIVE else "share" if key in _SHARES
            else "correlation" if key in _CORRELATIONS else "signed" if key in _SIGNED else "nonnegative")
    for i, (v, kind_i) in enumerate(zip(items, _ITEM_KINDS.get(key, [kind] * len(items)), strict=True)):
        lo, lo_open, hi, want = _DOMAINS[kind_i]
        if not (math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi):
            item = f" (item {i} of the list)" if isinstance(value, list) else ""
            raise PedcalInputError(f"expected {want}, got {show(v)}{item}", path=source, column=key)


def _typed(values: dict, source) -> Scenario:
    """Build a Scenario, checking each value against its default's type."""
    defaults = dataclasses.asdict(Scenario())
    out = {}
    for key, value in values.items():
        default = defaults[key]
        try:
            if value is None:
                out[key] = None
            elif default is None:
                out[key] = _OPTIONAL_TYPES[key](value)
            elif isinstance(default, bool):
                if not isinstance(value, bool):     # bool("false") is True
                    raise ValueError
                out[key] = value
            elif isinstance(default, int) and not isinstance(default, bool):
                if float(value) != int(value):
                    raise ValueError
                out[key] = int(value)
            elif isinstance(default, float):
                out[key] = float(value)
            elif isinstance(default, str):
                if not isinstance(value, str):
                    raise ValueError
                out[key] = value
            elif isinstance(default, list):
                value = [float(v) for v in value]
                if len(value) != len(default) and not (key in _VARIABLE_LISTS and value):
                    raise ValueError
                out[key] = value
            else:
                out[key] = value
        except (TypeError, ValueError, OverflowError):
            like = {float: "a number", list: "a list"}.get(_OPTIONAL_TYPES.get(key)) if default is None else \
                f"a value like {default!r}"
            raise PedcalInputError(f"expected {like or 'a value'}, got {show(value)}", path=source,
                                   column=key) from None
        _check_domain(key, out[key], source)
    for key, allowed in CHOICES.items():
        if out[key] not in allowed:
            raise PedcalInputError(f"expected one of {', '.join(allowed)}, got {out[key]!r}",
                                   path=source, column=key)
    if out["walkers"] not in WALKER_SOURCES:
        raise PedcalInputError(f"expected one of {', '.join(WALKER_SOURCES)}, got {out['walkers']!r}",
                               path=source, column="walkers")
    if out["row_y_m"] is not None:
        try:
            out["row_y_m"] = [float(v) for v in out["row_y_m"]]
        except (TypeError, ValueError):
            raise PedcalInputError("expected a list of numbers", path=source, column="row_y_m") from None
        if out["layout"] == "grid" and len(out["row_y_m"]) != out["grid_rows"]:   # named here, with the file
            raise PedcalInputError(f"{len(out['row_y_m'])} entries for {out['grid_rows']} rows (grid_rows)",
                                   path=source, column="row_y_m")
    if out["sensor_height_range_m"] is not None:
        try:
            lo, hi = (float(v) for v in out["sensor_height_range_m"])
        except (TypeError, ValueError):
            raise PedcalInputError("expected [min, max] heights in metres", path=source,
                                   column="sensor_height_range_m") from None
        if not 0.0 < lo <= hi:
            raise PedcalInputError(f"expected 0 < min <= max, got [{lo}, {hi}]", path=source,
                                   column="sensor_height_range_m")
        out["sensor_height_range_m"] = [lo, hi]
    for key in ("wall_pitch_deg", "wall_aim_m"):
        lo, hi = out[key]
        if not 0.0 < lo <= hi:
            raise PedcalInputError(f"expected 0 < min <= max, got [{lo}, {hi}]", path=source, column=key)
    if out["sensor_ids"] is not None:
        out["sensor_ids"] = [str(s) for s in out["sensor_ids"]]
    return Scenario(**out)


def scenario_path(name_or_path: str | Path) -> Path:
    """A scenario name of ``datasets/`` (paper, sparse, mall) or a YAML file path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise PedcalInputError("scenario file not found", path=p)
        return p
    candidate = DATASETS_DIR / f"{name_or_path}.yaml"
    if not candidate.is_file():
        known = sorted(q.stem for q in DATASETS_DIR.glob("*.yaml"))
        raise PedcalInputError(f"unknown scenario '{name_or_path}', expected one of {', '.join(known)} "
                               "or a path to a YAML file", path=candidate)
    return candidate


def load_scenario(name_or_path: str | Path | Scenario, *, _seen: tuple = ()) -> Scenario:
    """Load a scenario by name or path; ``base:`` inherits another scenario's values."""
    if isinstance(name_or_path, Scenario):
        return name_or_path
    path = scenario_path(name_or_path)
    if path.resolve() in _seen:
        raise PedcalInputError("scenario files include each other in a loop", path=path)
    data = load_yaml_file(path)[0] or {}  # size capped, UTF-8; one-line syntax errors; a key given twice refused
    if not isinstance(data, dict):
        raise PedcalInputError("expected a mapping of scenario parameters", path=path)
    base = Scenario()
    if "base" in data:
        base_ref = data.pop("base")
        base_path = Path(base_ref) if Path(str(base_ref)).suffix else base_ref
        if isinstance(base_path, Path) and not base_path.is_absolute():
            base_path = path.parent / base_path
        base = load_scenario(base_path, _seen=_seen + (path.resolve(),))
    data.setdefault("name", path.stem)
    return base.resolve(source=path, **data)
