"""Sensor names, poses and density normalization for ``pedcal detect``."""

import json

import numpy as np
import pytest

from pedcal.cli import main
from pedcal.detect import sensors
from pedcal.errors import PedcalInputError
from tests.test_real_eval import rendered_person_frame


def grid_cloud(step_deg, n_az=120, n_el=90, range_m=3.0):
    """A wall of points at ``range_m`` seen on a regular grid of rays ``step_deg`` apart."""
    az = np.radians(np.arange(n_az) - n_az / 2) * step_deg
    el = np.radians(np.arange(n_el) - n_el / 2) * step_deg
    A, E = np.meshgrid(az, el)
    d = np.column_stack([np.cos(E.ravel()) * np.cos(A.ravel()), np.cos(E.ravel()) * np.sin(A.ravel()),
                         np.sin(E.ravel())])
    return np.column_stack([d * range_m, np.full(len(d), 0.5)])


def test_ray_spacing_is_estimated_and_dense_clouds_are_thinned_to_the_target():
    dense = grid_cloud(0.09)
    assert sensors.angular_step_deg(dense) == pytest.approx(0.09, rel=0.05)  # a grid: 4 neighbours one step away
    thin = sensors.normalize_density(dense)
    # about (0.09 / 0.5)^2 of the points remain (more where the surface crosses voxel layers)
    share = (0.09 / sensors.TARGET_STEP_DEG) ** 2
    assert 0.8 * share < len(thin) / len(dense) < 3 * share
    assert sensors.angular_step_deg(thin) > 0.3
    np.testing.assert_allclose(thin[:, 3], 0.5)
    # a cloud at the trained density, or a spinning LIDAR's scan lines, stays as it is
    for cloud in (grid_cloud(0.6), rendered_person_frame(preset="hdl64", sensor_height_m=1.8)):
        assert sensors.normalize_density(cloud) is cloud
    assert sensors.normalize_density(dense, "vlp16") is dense
    assert len(sensors.normalize_density(grid_cloud(0.6), "depth-camera")) < len(grid_cloud(0.6))
    with pytest.raises(PedcalInputError, match="depth-camera"):
        sensors.normalize_density(dense, "kinect-9000")


def test_sensor_pose_maps_into_the_floor_frame():
    pos, ypr = sensors.parse_sensor_pose("0.5,0,1.2,0,10,0")
    np.testing.assert_allclose(pos, [0.5, 0.0, 1.2])
    np.testing.assert_allclose(ypr, [0.0, 10.0, 0.0])
    # a point straight ahead along the optical axis of a sensor pitched 10 deg down
    p = sensors.to_base_frame(np.array([[2.0, 0.0, 0.0, 0.3]]), pos, ypr)
    np.testing.assert_allclose(p[0], [0.5 + 2 * np.cos(np.radians(10)), 0.0, 1.2 - 2 * np.sin(np.radians(10)), 0.3])
    for bad in ("1,2,3", "a,b,c,d,e,f", "1,2,3,4,5,nan"):
        with pytest.raises(PedcalInputError, match="x,y,z,roll,pitch,yaw"):
            sensors.parse_sensor_pose(bad)


def test_detect_cli_sensor_and_pose_flags(tmp_path, capsys):
    pts = rendered_person_frame(x_m=7.0, y_m=-1.0, sensor_height_m=1.8, preset="hdl32")
    path = tmp_path / "scan.bin"
    pts.astype("<f4").tofile(path)
    found = {}
    for flags in ([], ["--sensor", "hdl32"], ["--sensor-pose", "0,0,1.8,0,0,0"], ["--floor", "plane"]):
        assert main(["detect", str(path), "--json", *flags]) == 0
        dets = [d for d in json.loads(capsys.readouterr().out)["detections"] if d["is_person"]]
        assert len(dets) == 1, flags
        found[tuple(flags)] = dets[0]
    for d in found.values():
        assert (d["x"], d["y"]) == pytest.approx((7.0, -1.0), abs=0.25)
        assert d["height"] == pytest.approx(1.75, abs=0.17)  # beams 1.33 deg apart: 0.16 m at 7 m
    assert main(["detect", str(path), "--sensor", "nope"]) == 2
    assert main(["detect", str(path), "--sensor-pose", "1,2"]) == 2
    assert "x,y,z,roll,pitch,yaw" in capsys.readouterr().err
