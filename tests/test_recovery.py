"""Fixed-lag target smoother: bearing-only triangulation from a moving robot, robustness to multipath,
LIDAR tracking, and the custom motion factors' Jacobians."""

from functools import partial

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import T, V

from pedcal.errors import PedcalInputError
from pedcal.follow_types import EsparReading
from pedcal.sim.espar import EsparParams, EsparSimulator
from pedcal.track.recovery import SmootherConfig, TargetSmoother, constant_velocity_error, gauss_markov_velocity_error

COV_ROBOT = np.diag([0.05 ** 2, 0.05 ** 2, np.radians(1.0) ** 2])
STATIC = SmootherConfig(walk_speed_mps=0.2)      # a target standing still: velocity spread 0.2 m/s


def drive_past(seed: int, extra: dict | None = None, n: int = 24, target=(1.5, 3.0),
               config: SmootherConfig = STATIC) -> TargetSmoother:
    """Robot drives 3 m along x at 0.5 m/s past a static target 3 m to its side; ESPAR readings only."""
    target = np.asarray(target)
    sim = EsparSimulator(EsparParams(), np.random.default_rng(seed))
    smoother = TargetSmoother(config)
    t_prev = 0.0
    for k in range(1, n + 1):
        t = 0.25 * k
        pose = np.array([3.0 * k / n, 0.0, 0.0])
        readings = sim.readings(t_prev, t, target - pose[:2])
        readings += (extra or {}).get(k, ())
        seed_xy = None
        if not smoother.started and readings:      # a weak guess 2 m along the first reading
            b = readings[0].bearing_robot_rad
            seed_xy = pose[:2] + 2.0 * np.array([np.cos(b), np.sin(b)])
        smoother.add_frame(t, pose, COV_ROBOT, espar=readings, seed_xy_world_m=seed_xy, seed_sigma_m=3.0)
        t_prev = t
    return smoother


def test_bearings_from_motion_triangulate_a_static_target():
    errors = np.array([np.linalg.norm(drive_past(seed).latest()[0] - [1.5, 3.0]) for seed in range(12)])
    # 24 readings, 30 deg quantization over 20 deg noise, 10 % multipath: the bearings alone give
    # about 0.26 m per axis at 3.3 m (0.38 rad x 3.3 m / sqrt(24))
    assert np.median(errors) < 0.5
    assert errors.max() < 1.2


def test_a_multipath_reading_does_not_drag_the_estimate():
    mount = np.array([0.0, 0.15])
    true_bearing = np.arctan2(3.0 - mount[1], 1.5 - 1.5)
    wrong = EsparReading(0, 0, float(np.angle(np.exp(1j * (true_bearing + np.radians(150))))), mount)
    plain = SmootherConfig(walk_speed_mps=0.2, espar_robust=False)
    shifts, shifts_plain = [], []
    for seed in range(4):
        clean = drive_past(seed).latest()[0]
        dirty = drive_past(seed, extra={12: (wrong, wrong)}).latest()[0]
        shifts.append(np.linalg.norm(dirty - clean))
        clean = drive_past(seed, config=plain).latest()[0]
        dirty = drive_past(seed, extra={12: (wrong, wrong)}, config=plain).latest()[0]
        shifts_plain.append(np.linalg.norm(dirty - clean))
    assert max(shifts) < 0.15, shifts
    assert min(shifts_plain) > 0.5, shifts_plain          # without the Cauchy kernel the pair drags it


def test_lidar_detections_track_a_walking_target():
    smoother = TargetSmoother()
    rng = np.random.default_rng(3)
    errors = []
    for k in range(60):
        t = 0.25 * k
        xy_target = np.array([2.0 + 1.0 * t, 1.0])
        pose = np.array([0.9 * t, 0.2, 0.05])
        c, s = np.cos(pose[2]), np.sin(pose[2])
        det = np.array([[c, s], [-s, c]]) @ (xy_target - pose[:2]) + rng.normal(0, 0.05, 2)
        xy = smoother.add_frame(t, pose, COV_ROBOT, detection_xy_robot_m=det)
        errors.append(np.linalg.norm(xy - xy_target))
    assert np.mean(errors[10:]) < 0.1
    np.testing.assert_allclose(smoother.latest_velocity(), [1.0, 0.0], atol=0.2)
    _, cov = smoother.latest()
    assert np.sqrt(np.trace(cov)) < 0.2


def test_nothing_starts_without_a_detection_or_seed():
    smoother = TargetSmoother()
    assert smoother.add_frame(0.0, np.zeros(3), COV_ROBOT) is None and smoother.latest() is None


def test_antenna_sigma_no_tighter_than_quantization():
    assert np.degrees(SmootherConfig().espar_sigma_rad) >= 30 / np.sqrt(12)
    with pytest.raises(PedcalInputError, match="quantization"):
        SmootherConfig(espar_sigma_rad=np.radians(5.0))


def _numerical_jacobians(factor, values, keys):
    """Central differences of the unwhitened error w.r.t. each Point2 key."""
    out = []
    for key in keys:
        J = np.zeros((2, 2))
        for i in range(2):
            d = np.zeros(2)
            d[i] = 1e-6
            plus, minus = gtsam.Values(values), gtsam.Values(values)
            plus.update(key, values.atPoint2(key) + d)
            minus.update(key, values.atPoint2(key) - d)
            J[:, i] = (factor.unwhitenedError(plus) - factor.unwhitenedError(minus)) / 2e-6
        out.append(J)
    return out


@pytest.mark.parametrize("make", [
    lambda noise: gtsam.CustomFactor(noise, [T(0), T(1), V(0)], partial(constant_velocity_error, 0.3)),
    lambda noise: gtsam.CustomFactor(noise, [V(0), V(1)], partial(gauss_markov_velocity_error, 0.8)),
])
def test_custom_factor_jacobians_match_numerical_derivatives(make):
    rng = np.random.default_rng(0)
    values = gtsam.Values()
    for key in (T(0), T(1), V(0), V(1)):
        values.insert(key, rng.normal(size=2))
    factor = make(gtsam.noiseModel.Unit.Create(2))
    keys = list(factor.keys())
    linear = factor.linearize(values)
    A, _ = linear.jacobian()
    numeric = np.hstack(_numerical_jacobians(factor, values, keys))
    # the Gaussian factor holds -J for error e: A x - b with b = -e, so A equals J for a unit model
    np.testing.assert_allclose(A, numeric, atol=1e-6)
