"""Edge cases a plausible bug would slip past: a radians sensors.yaml with a zero roll, a robot
that passes under a sensor and also drives far away, an output hard-linked elsewhere (an atomic
replace leaves the link's old contents, a copy over the file would not), and /tf chains that
need an inverted edge with a yaw, or tilted rotations (composition order matters only then)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from pedcal.errors import PedcalInputError
from pedcal.io import read_sensors_yaml
from pedcal.io.atomic import write_text_atomic
from pedcal.io.preflight import check_robot_near_sensors
from pedcal.io.ros import _Edge, tf_poses
from pedcal.model import Log, SensorExtrinsics, SensorNetwork


# ------------------------------------------------------------------------------ sensors.yaml units
def test_radians_sensors_yaml_with_a_zero_roll_is_refused(tmp_path):
    path = tmp_path / "sensors.yaml"
    path.write_text("frame: map\nsensors:\n"
                    "  - {id: s1, position: [1.0, 2.0, 2.6], ypr_deg: [1.5708, 0.7854, 0.0]}\n"
                    "  - {id: s2, position: [4.0, 2.0, 2.6], ypr_deg: [-1.5708, 0.6981, 0.0]}\n")
    with pytest.raises(PedcalInputError, match="radians") as err:
        read_sensors_yaml(path)
    assert str(path) in str(err.value)
    # the same file in degrees (a whole-degree roll of 0 beside fractional angles) reads
    path.write_text("frame: map\nsensors:\n"
                    "  - {id: s1, position: [1.0, 2.0, 2.6], ypr_deg: [90.0, 45.5, 0.0]}\n")
    assert read_sensors_yaml(path)["s1"].ypr_deg[1] == 45.5


# ---------------------------------------------------------------------- robot near the sensors
def _log(robot_xy: np.ndarray) -> Log:
    n = len(robot_xy)
    robot = pd.DataFrame({"t": np.arange(n, dtype=float), "x": robot_xy[:, 0], "y": robot_xy[:, 1],
                          "yaw": 0.0, "cov_xx": 0.01, "cov_xy": 0.0, "cov_xyaw": 0.0, "cov_yy": 0.01,
                          "cov_yyaw": 0.0, "cov_yawyaw": 0.01})
    sensors = SensorNetwork([SensorExtrinsics("s1", [2.0, 0.0, 2.6], [0.0, 60.0, 0.0]),
                             SensorExtrinsics("s2", [6.0, 1.0, 2.6], [180.0, 60.0, 0.0])])
    obs = pd.DataFrame({"t": [0.0], "sensor": ["s1"], "track": ["1"], "x": [2.0], "y": [0.0], "z": [1.3]})
    return Log(sensors=sensors, robot=robot, observations=obs)


def test_a_robot_passing_under_a_sensor_that_also_drives_100_m_away_is_accepted():
    under = np.column_stack([np.linspace(0, 8, 40), np.zeros(40)])            # under both sensors
    away = np.column_stack([np.linspace(8, 150, 200), np.linspace(0, 60, 200)])   # then far off, > 100 m
    check_robot_near_sensors(_log(np.vstack([under, away])))
    check_robot_near_sensors(_log(np.vstack([away[::-1], under])))            # in either order
    with pytest.raises(PedcalInputError, match="never comes within 100 m"):
        check_robot_near_sensors(_log(away[away[:, 0] > 120]))                # only far away: refused


# -------------------------------------------------------------------------------- atomic output
def test_a_hard_link_to_an_output_keeps_its_old_contents(tmp_path):
    out = tmp_path / "out.yaml"
    out.write_text("old\n")
    link = tmp_path / "backup.yaml"
    link.hardlink_to(out)
    write_text_atomic(out, "new\n")
    assert out.read_text() == "new\n"
    assert link.read_text() == "old\n"            # a new inode renamed over the name, not written in place
    assert out.stat().st_ino != link.stat().st_ino


# ------------------------------------------------------------------------------------ /tf chains
def _static(xyz, rot: Rotation) -> _Edge:
    return _Edge(t=[0.0], xyz=[list(xyz)], q_xyzw=[list(rot.as_quat())], static=True)


def _T(xyz, rot: Rotation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot.as_matrix(), xyz
    return T


def _check_chain(edges, source, target, expected: np.ndarray):
    _, p, R = tf_poses(edges, source, target, "test")
    np.testing.assert_allclose(p[-1], expected[:3, 3], atol=1e-12)
    np.testing.assert_allclose(R[-1].as_matrix(), expected[:3, :3], atol=1e-12)


def test_tf_chain_through_an_inverted_edge_with_a_yaw():
    """map -> odom is stored as odom -> map (inverted), with a yaw: the inverse's translation is
    -R^T t, which differs from -t only when R is not the identity."""
    T_map_odom = _T([2.0, -1.0, 0.0], Rotation.from_euler("z", 0.7))
    T_odom_base = _T([0.5, 0.3, 0.0], Rotation.from_euler("z", -0.4))
    T_odom_map = np.linalg.inv(T_map_odom)
    edges = {("odom", "map"): _static(T_odom_map[:3, 3], Rotation.from_matrix(T_odom_map[:3, :3])),
             ("odom", "base_link"): _static(T_odom_base[:3, 3], Rotation.from_matrix(T_odom_base[:3, :3]))}
    _check_chain(edges, "map", "base_link", T_map_odom @ T_odom_base)
    _check_chain(edges, "base_link", "map", np.linalg.inv(T_map_odom @ T_odom_base))


def test_tf_chain_with_tilted_rotations():
    """Rotations about x and y (a tilted mount) do not commute: the chain must compose them in order."""
    T_a_b = _T([0.1, 0.2, 0.3], Rotation.from_euler("xyz", [0.3, -0.5, 0.2]))
    T_b_c = _T([0.0, -0.4, 1.1], Rotation.from_euler("yx", [0.8, -0.6]))
    T_d_c = _T([0.7, 0.1, -0.2], Rotation.from_euler("xzy", [1.0, 0.4, -0.3]))        # stored child -> parent
    edges = {("a", "b"): _static(T_a_b[:3, 3], Rotation.from_matrix(T_a_b[:3, :3])),
             ("b", "c"): _static(T_b_c[:3, 3], Rotation.from_matrix(T_b_c[:3, :3])),
             ("d", "c"): _static(T_d_c[:3, 3], Rotation.from_matrix(T_d_c[:3, :3]))}
    _check_chain(edges, "a", "c", T_a_b @ T_b_c)
    _check_chain(edges, "a", "d", T_a_b @ T_b_c @ np.linalg.inv(T_d_c))
    _check_chain(edges, "d", "a", np.linalg.inv(T_a_b @ T_b_c @ np.linalg.inv(T_d_c)))
