"""The network's sigmas read back for every sensor at once against one sensor at a time."""

import warnings
from types import SimpleNamespace

import gtsam
import numpy as np

from pedcal import frames
from pedcal.calib.keys import S
from pedcal.calib.readback import _network_from_result, observability, sensor_sigma_world, sensor_sigmas_world
from pedcal.calib.recipe import GraphRecipe
from pedcal.model import SensorExtrinsics, SensorNetwork


def _one_at_a_time(T: gtsam.Pose3, cov: np.ndarray):
    """sensor_sigma_world as it read before the batch: each sensor's own 3 x 3 products."""
    R = T.rotation().matrix()
    cov_pos = R @ cov[3:, 3:] @ R.T
    ypr0 = frames.ypr_deg_from_rot(R)
    J = np.zeros((3, 3))
    for c in range(3):
        w = np.zeros(3)
        w[c] = 1e-6
        d = frames.ypr_deg_from_rot(R @ gtsam.Rot3.Expmap(w).matrix()) - ypr0
        J[:, c] = (d + 180.0) % 360.0 - 180.0
    J /= 1e-6
    cov_ypr = J @ cov[:3, :3] @ J.T
    return cov_pos, np.sqrt(np.diag(cov_pos)), np.sqrt(np.maximum(np.diag(cov_ypr), 0.0))


def test_sigmas_of_many_sensors_equal_each_ones_bit_for_bit():
    rng = np.random.default_rng(3)
    # yaws across the +-180 deg wrap, pitches to straight down (yaw and roll blur there)
    ypr = np.column_stack([rng.uniform(-180, 180, 40), rng.uniform(0, 90, 40), rng.uniform(-10, 10, 40)])
    ypr[0] = [179.9999, 45.0, 0.0]
    ypr[1] = [30.0, 90.0, 0.0]
    poses = [gtsam.Pose3(gtsam.Rot3(frames.rot_from_ypr_deg(a)), rng.normal(size=3)) for a in ypr]
    L = rng.normal(size=(40, 6, 6)) * 0.01
    covs = L @ L.transpose(0, 2, 1) + 1e-6 * np.eye(6)
    R = np.stack([T.rotation().matrix() for T in poses])
    cov_pos, sp, sy = sensor_sigmas_world(R, covs)
    for i, T in enumerate(poses):
        want = _one_at_a_time(T, covs[i])
        for got, w in zip((cov_pos[i], sp[i], sy[i]), want, strict=True):
            assert np.array_equal(got, w)
        assert all(np.array_equal(g, w) for g, w in zip(sensor_sigma_world(T, covs[i]), want, strict=True))
    assert np.all(sy[2:] > 0.0) and sp.shape == (40, 3)


def test_observability_names_a_direction_the_data_left_to_the_prior():
    rec = GraphRecipe.load("default")
    p = np.r_[[np.radians(rec.sensor_prior_sigma_deg)] * 3, [rec.sensor_prior_sigma_m] * 3]
    cov = np.diag((0.01 * p) ** 2)
    T = gtsam.Pose3()
    assert observability(T, cov, rec)[0] == []
    cov[5, 5] = (0.9 * p[5]) ** 2          # z left at 0.9 of its prior sigma
    names, bad = observability(T, cov, rec)
    assert names == ["z"] and bad.shape == (6, 1)


def test_no_sensor_gives_empty_sigmas():
    cov_pos, sp, sy = sensor_sigmas_world(np.zeros((0, 3, 3)), np.zeros((0, 6, 6)))
    assert cov_pos.shape == (0, 3, 3) and sp.shape == (0, 3) and sy.shape == (0, 3)


def test_each_sensor_is_read_with_its_own_decomposition():
    # three sensors, the middle one's height left at its prior sigma: it alone is degenerate in z,
    # its height put back to the installed one; the others (x the first one's least constrained
    # direction, y the third's, far below their priors) are ok and keep their solution
    rec = GraphRecipe.load("default")
    p = np.r_[[np.radians(rec.sensor_prior_sigma_deg)] * 3, [rec.sensor_prior_sigma_m] * 3]
    ids = ["s0", "s1", "s2"]
    installed = SensorNetwork([SensorExtrinsics(sid, [float(i), 0.0, 2.5], [0.0, 0.0, 0.0])
                               for i, sid in enumerate(ids)])
    result, cov = gtsam.Values(), {}
    for i, sid in enumerate(ids):
        result.insert(S(i), gtsam.Pose3(gtsam.Rot3(), np.array([i + 0.01, 0.02, 2.53])))
        sd = 0.01 * p
        axis = (3, 5, 4)[i]                 # (x, z, y: rotation first in a Pose3's tangent)
        sd[axis] = (0.05, 0.9, 0.07)[i] * p[axis]
        cov[sid] = np.diag(sd ** 2)
    prob = SimpleNamespace(recipe=rec, sensor_ids=ids, people=[], obs_sensor=np.repeat(ids, 10))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        net = _network_from_result(SimpleNamespace(sensors=installed), prob, None, result, False, cov_body=cov)
    assert [s.status for s in net] == ["ok", "degenerate", "ok"]
    assert net["s1"].unobservable == ["z"] and sum("unconstrained" in str(w.message) for w in caught) == 1
    np.testing.assert_allclose(net["s1"].position_m, [1.01, 0.02, 2.5], atol=1e-9)
    np.testing.assert_allclose(net["s0"].position_m, [0.01, 0.02, 2.53], atol=1e-12)
    np.testing.assert_allclose(net["s2"].position_m, [2.01, 0.02, 2.53], atol=1e-12)


def test_a_position_variance_below_zero_by_rounding_gives_a_zero_sigma_not_nan():
    # identity rotation: the world position covariance is the body's; its x variance -1e-20 (a
    # round-off below 0) is read as 0, the others' sigmas their square roots
    cov = np.diag([1e-4, 1e-4, 1e-4, -1e-20, 4e-6, 9e-6])[None]
    _, pos_sigma, ypr_sigma = sensor_sigmas_world(np.eye(3)[None], cov)
    assert np.isfinite(pos_sigma).all() and np.isfinite(ypr_sigma).all()
    np.testing.assert_array_equal(pos_sigma[0], [0.0, 2e-3, 3e-3])
