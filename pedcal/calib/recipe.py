"""The factor graph's recipe (graphs/*.toml): which factor families it holds and their noise
models, and the depth sensors' noise model it implies (:func:`observation_sigmas`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from pedcal.errors import PedcalInputError
from pedcal.io.sensors_yaml import read_text_file
from pedcal.options import check_recipe_numbers

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

GRAPHS_DIR = Path(__file__).resolve().parents[2] / "graphs"


# ------------------------------------------------------------------------------------------ recipe
@dataclass
class GraphRecipe:
    """Which factor families and noise models the graph holds (graphs/*.toml)."""

    name: str = "default"
    description: str = ""
    # factor families
    robot: bool = True              # the robot's observations (sensor -> head)
    odometry: bool = True           # wheel odometry between-factors when odometry.csv exists
    smoothness: bool = True         # motion smoothness when there is no odometry
    people: bool = True             # people seen by two or more sensors at once
    amcl: bool = True               # AMCL poses as a correlated-error measurement
    # sensor prior from the installed extrinsics (how far a hand measurement can be off)
    sensor_prior_sigma_m: float = 0.5
    sensor_prior_sigma_deg: float = 10.0
    # depth sensor model: sigma_range = floor + k r^2 (x far_factor past reliable_range_m),
    # lateral sigma of the head-top extraction (plus the latency jitter times the robot's speed)
    range_sigma_floor_m: float = 0.005
    range_sigma_k_per_m: float = 1.5e-3
    reliable_range_m: float = 3.5
    far_factor: float = 2.0
    lateral_sigma_m: float = 0.012
    # the three above estimated from consecutive observations (estimate_observation_noise) unless false
    estimate_observation_noise: bool = True
    # head-point model (module docstring, "Head point"): the prior is a dome of radius
    # head_radius_m (vertical offset -r, ray shift r); both are estimated unless
    # estimate_head_model is false
    head_radius_m: float = 0.05
    estimate_head_model: bool = True
    head_vertical_sigma_m: float = 0.03     # prior sigma of the vertical offset about -ray shift
    head_ray_shift_sigma_m: float = 0.05    # prior sigma of the shift toward the sensor
    head_ray_shift_step_m: float = 0.02     # step of the shifts' profile likelihood
    estimate_head_horizontal_shift: bool = True   # a constant horizontal shift toward the sensor too
    head_horizontal_shift_sigma_m: float = 0.05   # its prior sigma (mean 0)
    # the horizontal shift as a function of the horizontal distance from the sensor
    # (pedcal.calib.headpoint): cv (the constant, a one-parameter shape -- a line, a shift rising
    # or fading to an interior knot and flat beyond, or flat to one and rising -- or
    # head_profile_knots free linear hats, the one whose fit elsewhere best predicts each held-out
    # sensor, the simplest within one standard error), bic (the one of least chi^2 - k ln(n)),
    # linear, knots, or off (the constant shift alone); each knot's departure from the constant
    # has prior sigma head_profile_sigma_m. Off by default: on the simulator's constant-shift logs
    # (paper, 20 seeds) either criterion keeps a line 16 times in 20, which the held-out sensors
    # and time blocks confirm (the noise scale is right: the score's overdispersion is ~1), and it
    # costs 5.3 +- 1.3 mm of horizontal sensor RMS (2.8 +- 0.9 mm over the zoo) for 3.2 +- 1.6 mm
    # gained on fading shifts: a shift against distance trades with AMCL's wandering error (the
    # line vanishes with AMCL's error off) and, rising to a plateau, with the ray shift
    head_profile: str = "off"
    head_profile_knots: int = 4
    head_profile_sigma_m: float = 0.03
    # with head_profile on, each sensor's own departure from the shared horizontal shift (a
    # tracker per sensor), prior sigma head_profile_sigma_m, kept for the sensors whose held-out
    # time blocks it predicts (cv; bic: chi^2 against ln(n)); the others keep the shared shift
    head_profile_per_sensor: bool = False
    # with head_profile off, the shift is not thereby known to be constant: a line rising
    # 0 +- head_profile_sigma_m across the robot's distances from the sensors is left at 0 but
    # what the data leave of its prior (its posterior's root mean square about 0) carried into the
    # sensors' covariance (its sensitivity from the first profile step, the other nuisances
    # re-optimized: a consider parameter). Under a wandering AMCL the
    # robot's path takes its scale from the sensors' views, whose radial scale such a line sets:
    # without it a corridor's sensors spread along it by 3.4 mm/m (sd over the zoo's 20 seeds)
    # where their sigma gave 0.9
    head_profile_consider: bool = True
    # each sensor's own constant departure of the horizontal shift from the shared one, a random
    # effect always in the model (pedcal.calib.headpoint.sensor_shift_nuisances), prior 0 +- this
    # (m; 0: off): the spread of the head point between trackers (the nearest point of a blob, a
    # centroid of the visible head, a skeleton's head joint differ by ~1-3 cm horizontally).
    # Estimated where a sensor sees people all around, at its prior where it sees them from one
    # side, its covariance carried into the sensor's (widening it along the view axis there). On
    # by default: on the zoo (20 seeds, five scenes) it takes the horizontal RMS down 1-5 mm and
    # the within-1-sigma shares up (README)
    head_shift_per_sensor_sigma_m: float = 0.02
    # that sigma estimated from the data (pedcal.calib.headpoint.estimate_departure_spread: the
    # departures' marginal likelihood over it, every nuisance integrated out, its posterior's
    # root mean square taken, so its own uncertainty is carried) where the data determine three
    # or more sensors' own shift (seen from around); else head_shift_per_sensor_sigma_m, with a
    # warning (so too above clock_offsets_joint_max sensors, where it is not estimated). The
    # estimate is always reported in the head model's note; off by default, it is not used: on
    # the zoo (paper, corridor, cross, seeds 0-5) it finds 0-1 mm on a plain head top and
    # 11-17 mm on per-sensor head models, yet on seeds 0-5 and 6-17 it moves the pooled
    # error/sigma RMS by at most 0.02, a pooled within-1-sigma share by up to 3 points (x 72 ->
    # 75 %, seeds 0-5) and the horizontal RMS by under 1 mm (README)
    head_shift_per_sensor_sigma_estimate: bool = False
    # the head point's height curving with the sensor's elevation e, curvature_m x cos^2(e) up
    # (a centroid of the head's top sits lowest seen from straight above or the side): off, on,
    # auto (estimated when its profile chi^2 reaches head_curvature_select_chi2) or widen (the
    # default: not estimated, but when its chi^2 reaches head_curvature_widen_chi2, about two
    # sigma, the misfit is named in model_mismatch and the sensors' covariance carries the move
    # estimating it would make). Over the nuisance zoo's 80 logs without it, the other shifts'
    # model inexactness gave it a chi^2 of 3-54 and estimating it cost 2-5 mm of sensor RMS; the
    # simulated centroid tracker gives 20-145, and with it not widened for below 60 the sensors'
    # errors relative to their mean were 1.5-1.9x their sigma on paper and sparse (40 seeds), 1.0
    # and 1.15x widened from 4.
    head_curvature: str = "widen"
    head_curvature_sigma_m: float = 0.02
    head_curvature_select_chi2: float = 60.0
    head_curvature_widen_chi2: float = 4.0
    # height reference: the installed sensor heights measured to this sigma (0: no reference),
    # or, with ceiling_height_m > 0, every sensor at that height to this sigma
    sensor_height_sigma_m: float = 0.0
    ceiling_height_m: float = 0.0
    robust_kernel: str = "huber"    # huber | cauchy | tukey | none
    robust_k: float = 1.345
    # AMCL error process (std from AMCL's reported covariance)
    amcl_correlation_s: float = 20.0
    amcl_node_spacing_s: float = 1.0   # nodes of the error process (a small fraction of tau)
    amcl_white_fraction: float = 0.2   # share of AMCL's reported std that is white, per stamp
    # the wandering error's change since its node counted once per span between two nodes
    # (pedcal.calib.amcl_model.node_drift_variance); off: once per estimate
    amcl_change_per_span: bool = False
    # AMCL's error model (white std, wandering std and correlation time, jumps) estimated from the
    # residuals of a first solve (pedcal.calib.amcl_model); the three above are its starting point
    estimate_amcl_model: bool = True
    # how AMCL's reported std bounds the wandering part fitted to the residuals, which cannot show
    # the error's run mean (each sensor's pose absorbs AMCL's average over its view): hold (the
    # graph takes the wander at least at the reported std, at the rate of wander the residuals
    # show), consider (the graph is solved with the data's wander and the sensors' covariance read
    # from it with its AMCL block under the held one: pedcal.calib.factorgraph._held_graph) or off
    # (the data's alone, sigma included). pedcal.calib.amcl_model.estimate_model
    amcl_reported_floor: str = "consider"
    amcl_jump_threshold: float = 5.0   # robust sigmas off the running median: a jump, left out
    amcl_min_jump_m: float = 0.1       # ... and at least this far off
    # the relocalization jumps found as steps in AMCL's own track moved back by their steps (kept,
    # not left out: without odometry a left-out stretch left the robot's path there to the
    # smoothness factor alone, which carried the jump's steps; pedcal.calib.amcl_model.jumps_moved_back)
    amcl_jumps_moved_back: bool = True
    # robot poses: one per AMCL stamp, gaps longer than this filled
    max_pose_gap_s: float = 0.25
    # odometry: systematic errors estimated and removed, then white noise per sqrt(second)
    # and a residual scale / heading drift
    odometry_calibrate: bool = True
    odometry_white_sigma_m: float = 0.005          # per sqrt(s)
    odometry_white_yaw_sigma_deg: float = 0.25     # per sqrt(s)
    odometry_sigma_per_m: float = 0.003            # residual scale error
    odometry_yaw_sigma_deg_per_m: float = 0.05     # residual heading drift
    # what the calibration left of odometry's systematic errors (scale, heading drift per metre
    # and per second), estimated in the graph against what the sensors saw (a calibration against
    # a wandering AMCL leaves errors the graph would otherwise take as the robot's true motion);
    # prior sigmas of these corrections
    estimate_odometry_errors: bool = True
    odometry_scale_sigma: float = 0.01
    odometry_drift_sigma_deg_per_m: float = 0.1
    odometry_drift_sigma_deg_per_s: float = 0.01
    smoothness_sigma_mps: float = 0.05
    # without odometry, AMCL jitter above this (m, amcl_white_sigma) makes the short-term motion
    # come from AMCL smoothed over amcl_smooth_s (s)
    amcl_smooth_above_m: float = 0.01
    amcl_smooth_s: float = 0.5
    # robot planarity
    planar_sigma_deg: float = 0.5
    head_height_sigma_m: float = 0.02
    # tracker latency
    estimate_latency: bool = True
    latency_max_s: float = 0.4
    # each sensor's clock offset from the shared latency, a nuisance of the profile
    # (pedcal.calib.clocks), prior 0 +- clock_offset_sigma_s (s)
    clock_offsets: bool = True
    clock_offset_sigma_s: float = 0.15
    # above this many offsets, they join the linear system as variables (the same estimates as
    # the exact profile's, one sparse factorization instead of a right-hand side through the whole
    # graph per sensor and a dense Hessian) and each one's sigma is its own profile's given the
    # robot's path (a 6 x 6 solve per sensor): their coupling through the path is left out, so
    # that sigma is a lower bound (0.4-0.6 of the exact one at 160 synthetic sensors, 0.15-0.3
    # on the paper and sparse scenes, where one sensor sees each pose)
    clock_offsets_joint_max: int = 200
    # people association for shared observations (at most one shared point per period)
    people_sample_s: float = 0.5
    people_misfit_sigma: float = 5.0   # a shared sighting whose views the first solve puts this far apart is dropped
    # initializer: closedform | gridsearch | installed
    init: str = "closedform"
    max_iterations: int = 50
    relative_error_tol: float = 1e-5

    @classmethod
    def load(cls, path: str | Path) -> GraphRecipe:
        path = Path(path)
        if not path.exists() and not path.suffix and (GRAPHS_DIR / f"{path}.toml").exists():
            path = GRAPHS_DIR / f"{path}.toml"
        try:
            data = tomllib.loads(read_text_file(path, "graph recipe"))   # a regular file, size capped
        except tomllib.TOMLDecodeError as e:
            raise PedcalInputError(f"not valid TOML: {e}", path=path) from None
        flat = {}
        for k, v in data.items():
            if isinstance(v, dict):       # [sections] are only for readability
                flat.update(v)
            else:
                flat[k] = v
        known = {f.name: f for f in fields(cls)}
        defaults = cls()
        for k, v in flat.items():
            if k not in known:
                raise PedcalInputError(f"unknown key '{k}', expected one of {', '.join(known)}", path=path)
            default = getattr(defaults, k)
            if isinstance(default, bool) != isinstance(v, bool) or (
                    isinstance(default, float) and not isinstance(v, (int, float))):
                raise PedcalInputError(f"key '{k}' must be {type(default).__name__}, got {v!r}", path=path)
        if "name" not in flat:
            flat["name"] = path.stem
        check_recipe_numbers(flat, defaults, path, zero_off=ZERO_OFF_SIGMAS)
        return cls(**flat)



# sigmas whose 0 switches their random effect off (a graph file may give 0): each sensor's own
# departure of the horizontal shift, which head_profile_per_sensor needs off to select them instead
ZERO_OFF_SIGMAS = frozenset({"head_shift_per_sensor_sigma_m"})


def observation_sigmas(recipe: GraphRecipe, range_m: np.ndarray) -> np.ndarray:
    """(N, 3) sigmas [bearing rad, bearing rad, range m] of a head seen at ``range_m``:
    structured-light depth noise grows with range squared (Khoshelham and Elberink 2012),
    doubled past the reliable range; the lateral error is a distance across the ray."""
    r = np.asarray(range_m, float)
    sig_r = recipe.range_sigma_floor_m + recipe.range_sigma_k_per_m * r ** 2
    sig_r = np.where(r > recipe.reliable_range_m, recipe.far_factor * sig_r, sig_r)
    sig_b = recipe.lateral_sigma_m / np.maximum(r, 0.3)
    return np.column_stack([sig_b, sig_b, sig_r])



# ---------------------------------------------------------------------------------------- helpers
def _log(progress: bool, msg: str) -> None:
    if progress:
        logging.getLogger(__name__).info(f"[factorgraph] {msg}")



__all__ = ["GraphRecipe", "GRAPHS_DIR", "observation_sigmas"]
