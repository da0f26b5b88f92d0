"""The local ground (pedcal.detect.ground): stray returns below the road, slopes, kerbs and ramps,
the warnings on implausible ground, optical-frame clouds, people shoulder to shoulder in a depth cloud."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from pedcal.cli import main
from pedcal.detect import detection as det
from pedcal.detect.ground import (
    body_from_optical,
    detector_frame,
    estimate_ground,
    ground_referenced,
)
from pedcal.errors import PedcalInputError

SENSOR_HEIGHT_M = 1.73


def spinning_scan(ground_z, rng, *, n_rings=40, r_min_m=3.0, r_max_m=50.0, step_deg=0.25, noise_m=0.01):
    """(N, 4) ground returns of a spinning LIDAR at the origin: rings of points every ``step_deg``
    of azimuth at geometrically spaced ranges, at the height ``ground_z(x, y)`` (+ range noise)."""
    az = np.radians(np.arange(-180.0, 180.0, step_deg))
    r = np.geomspace(r_min_m, r_max_m, n_rings)
    rr, aa = np.meshgrid(r, az, indexing="ij")
    x, y = (rr * np.cos(aa)).ravel(), (rr * np.sin(aa)).ravel()
    z = ground_z(x, y) + rng.normal(0.0, noise_m, len(x))
    return np.column_stack([x, y, z, np.full(len(x), 0.3)])


def standing_person(x_m, y_m, floor_z_m, rng, height_m=1.75, n=600):
    """(n, 4) points on the sensor-facing half of a person standing at (x, y) on a floor at ``floor_z_m``."""
    a = np.arctan2(-y_m, -x_m) + rng.uniform(-np.pi / 2, np.pi / 2, n)
    h = rng.uniform(0.0, height_m, n)
    radius = np.where(h > height_m - 0.25, 0.1, 0.22)
    return np.column_stack([x_m + radius * np.cos(a), y_m + radius * np.sin(a), floor_z_m + h, np.full(n, 0.4)])


def gated_at(points, xy, tol_m=0.25):
    return [c for c in det.segment(points) if c.gated and np.hypot(c.box.cx - xy[0], c.box.cy - xy[1]) < tol_m]


def test_stray_returns_metres_below_the_road_do_not_pull_the_floor_down(caplog):
    rng = np.random.default_rng(0)
    flat = lambda x, y: np.full_like(x, -SENSOR_HEIGHT_M)  # noqa: E731
    road = spinning_scan(flat, rng)
    # multipath as real street scans hold it: short runs of 6-12 returns along a scan line,
    # 2-6 m below the road, 8-14 m from the sensor (reflected off car bodies and windows)
    strays = []
    for _ in range(16):
        r, a = rng.uniform(8.0, 14.0), rng.uniform(-np.pi, np.pi)
        n = int(rng.integers(6, 13))
        da = np.arange(n) * np.radians(0.2)
        strays.append(np.column_stack([r * np.cos(a + da), r * np.sin(a + da),
                                       np.full(n, -SENSOR_HEIGHT_M - rng.uniform(2.0, 6.0)), np.zeros(n)]))
    strays = np.vstack(strays)
    person_xy = (10.0, 2.0)
    cloud = np.vstack([road, strays, standing_person(*person_xy, -SENSOR_HEIGHT_M, rng)])
    with caplog.at_level(logging.WARNING, logger="pedcal"):
        est = estimate_ground(cloud)
    assert est.warnings == [] and not caplog.records  # a plain road: nothing to warn about
    assert est.sensor_height_m == pytest.approx(SENSOR_HEIGHT_M, abs=0.03)
    # the ground where the strays are, under the person, and everywhere the road was seen
    np.testing.assert_allclose(est.height_at(strays[:, :2]), -SENSOR_HEIGHT_M, atol=0.05)
    assert est.height_at(np.array([person_xy]))[0] == pytest.approx(-SENSOR_HEIGHT_M, abs=0.05)
    np.testing.assert_allclose(est.point_ground_z_m[: len(road)], -SENSOR_HEIGHT_M, atol=0.05)
    # so the person 10 m away is a candidate of its full height
    floor_pts, dz = ground_referenced(cloud)
    assert dz == pytest.approx(SENSOR_HEIGHT_M, abs=0.03)
    (cand,) = gated_at(floor_pts, person_xy)
    assert cand.height == pytest.approx(1.75, abs=0.06)
    # the lowest point of each 1 m cell, as a floor, drops by metres under the strays
    assert strays[:, 2].max() < -SENSOR_HEIGHT_M - 1.9


def test_a_ramp_a_slope_and_a_kerb_are_followed():
    rng = np.random.default_rng(1)

    def ground(x, y):
        # a street rising at 8 % beyond 5 m ahead, a 0.15 m kerb up to the pavement beyond y = 4 m,
        # and behind the sensor a 12 % ramp down
        z = -1.2 + 0.08 * np.clip(x - 5.0, 0.0, None) - 0.12 * np.clip(-x - 6.0, 0.0, None)
        return z + np.where(y > 4.0, 0.15, 0.0)

    scan = spinning_scan(ground, rng, r_max_m=35.0)
    people = [(15.0, -2.0), (-16.0, 1.5), (8.0, 6.0)]  # on the slope, on the ramp, on the pavement
    cloud = np.vstack([scan] + [standing_person(x, y, float(ground(np.array([x]), np.array([y]))[0]), rng)
                                for x, y in people])
    est = estimate_ground(cloud)
    assert est.warnings == []
    # every point of the ground itself (away from the kerb's edge, where a cell straddles the step)
    xy = scan[:, :2]
    away = np.abs(xy[:, 1] - 4.0) > 0.6
    err = est.point_ground_z_m[: len(scan)][away] - ground(xy[away, 0], xy[away, 1])
    assert np.abs(err).max() < 0.15 and np.percentile(np.abs(err), 99) < 0.06 and np.median(np.abs(err)) < 0.02
    floor_pts, _ = ground_referenced(cloud)
    for xy_p in people:
        (cand,) = gated_at(floor_pts, xy_p)
        assert cand.height == pytest.approx(1.75, abs=0.08), xy_p
    # the tilt of the ground near the sensor is measured, below the warning's 15 deg
    assert 0.0 < est.tilt_deg < 8.0


def test_ground_above_the_sensor_warns(caplog, tmp_path, capsys):
    rng = np.random.default_rng(2)
    # a crop holding no ground: objects whose lowest points lie 0.5 m above the sensor
    objects = np.column_stack([rng.uniform(5, 40, 800), rng.uniform(-15, 15, 800), rng.uniform(0.5, 2.5, 800),
                               np.full(800, 0.2)])
    with caplog.at_level(logging.WARNING, logger="pedcal"):
        est = estimate_ground(objects)
    assert est.sensor_height_m < 0
    assert len(est.warnings) >= 1 and "above the sensor" in est.warnings[0]
    assert any("above the sensor" in r.getMessage() for r in caplog.records)
    # the CLI says it too, in its JSON output
    path = tmp_path / "no_ground.bin"
    objects.astype("<f4").tofile(path)
    assert main(["detect", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert any("above the sensor" in w for w in out["warnings"])
    assert out["ground"]["sensor_height_m"] < 0 and out["floor_shift_m"] < 0


def test_a_tilt_no_floor_has_warns():
    rng = np.random.default_rng(3)
    # a floor seen in a frame whose z is not up (tilted by 30 deg about y)
    scan = spinning_scan(lambda x, y: -1.0 + np.tan(np.radians(30.0)) * x, rng, r_max_m=15.0)
    est = estimate_ground(scan, warn=False)
    assert est.tilt_deg == pytest.approx(30.0, abs=3.0)
    assert any("tilted by" in w for w in est.warnings)


def test_no_points_and_no_ground_warn():
    est = estimate_ground(np.zeros((0, 4)), warn=False)
    assert est.warnings and "no points" in est.warnings[0]
    assert np.isnan(est.height_at(np.zeros((1, 2))))[0]
    # one lone object: nothing the ground could be told from; its lowest point is taken
    pts = np.array([[5.0, 0.0, -1.0, 0.0], [5.0, 0.05, 0.5, 0.0]])
    est = estimate_ground(pts, warn=False)
    assert est.warnings == ["no ground found: 1 ground cells among 1 occupied, fewer than 3; the lowest points "
                            "are taken as the ground"]
    assert est.sensor_height_m == pytest.approx(1.0)
    np.testing.assert_allclose(est.point_ground_z_m, -1.0)


def test_body_from_optical_is_rep103():
    # optical: x right, y down, z forward -> body: x forward, y left, z up
    p = np.array([[1.0, 2.0, 3.0, 0.5]])
    np.testing.assert_array_equal(body_from_optical(p), [[3.0, -1.0, -2.0, 0.5]])
    with pytest.raises(PedcalInputError, match="frame"):
        detector_frame(p, frame="camera")
    with pytest.raises(PedcalInputError, match="floor"):
        detector_frame(p, floor="lowest")


def rows(detections) -> np.ndarray:
    """(n, 9) the detections' fields (Detection objects or their JSON dicts)."""
    keys = ("x", "y", "height", "width", "depth", "yaw", "score", "is_person", "n_points")
    return np.array([[float(d[k] if isinstance(d, dict) else getattr(d, k)) for k in keys] for d in detections])


def optical_from_body(points):
    out = points.copy()
    out[:, 0], out[:, 1], out[:, 2] = -points[:, 1], -points[:, 2], points[:, 0]
    return out


def test_an_optical_frame_cloud_gives_the_body_frame_detections(tmp_path, capsys):
    from tests.test_real_eval import rendered_person_frame

    body = rendered_person_frame(x_m=5.0, y_m=-1.2, sensor_height_m=1.1, preset="hdl32")
    optical = optical_from_body(body)
    d_body = det.detect(body, floor="auto")
    d_optical = det.detect(optical, frame="optical", floor="auto")
    assert len(d_body) == 1 and d_body[0].is_person
    assert (d_body[0].x, d_body[0].y) == pytest.approx((5.0, -1.2), abs=0.25)
    np.testing.assert_allclose(rows(d_optical), rows(d_body), atol=1e-9)
    # read as a body frame, the optical cloud has no floor below the sensor
    assert not [d for d in det.detect(optical, floor="auto") if d.is_person]
    # the CLI: the same detections from both files
    np.save(tmp_path / "body.npy", body)
    np.save(tmp_path / "optical.npy", optical)
    assert main(["detect", str(tmp_path / "body.npy"), "--json"]) == 0
    from_body = json.loads(capsys.readouterr().out)
    assert main(["detect", str(tmp_path / "optical.npy"), "--frame", "optical", "--json"]) == 0
    from_optical = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(rows(from_optical["detections"]), rows(from_body["detections"]), atol=1e-9)
    assert len(from_body["detections"]) == 1 and from_body["warnings"] == []


def five_people_depth_cloud(seed: int = 0, camera_height_m: float = 1.0):
    """An organized (480, 640, 3) depth-camera cloud in the camera's optical frame (NaN where a
    pixel has no return) of five people standing shoulder to shoulder 2.3-2.7 m ahead, rendered
    by pedcal's simulator, and their (5, 2) positions in the camera's body frame."""
    from pedcal.sim.lidar import LIDAR_PRESETS, Mount, render
    from pedcal.sim.scene import Scene, make_person

    rng = np.random.default_rng(seed)
    xy = np.array([[2.5, -0.88], [2.6, -0.44], [2.4, 0.0], [2.55, 0.44], [2.45, 0.88]])
    heights = [1.72, 1.65, 1.83, 1.78, 1.60]
    people = [make_person(h, 0.48, 0.26, "standing", (0.3, 0.6), rng, x_m=x, y_m=y,
                          yaw_rad=np.pi + rng.uniform(-0.2, 0.2)) for (x, y), h in zip(xy, heights, strict=True)]
    frame = render(Scene(people, floor_half_extent_m=10.0), "depth_camera", Mount(0.0, 0.0, camera_height_m), rng)
    cam = LIDAR_PRESETS["depth_camera"]
    body = frame.points[:, :3].astype(float) - [0.0, 0.0, camera_height_m]
    image = np.full((cam.n_vertical * cam.n_horizontal, 3), np.nan)
    image[frame.ray_index] = optical_from_body(body)
    return image.reshape(cam.n_vertical, cam.n_horizontal, 3), xy


def test_five_people_shoulder_to_shoulder_in_a_depth_cloud_are_five_candidates(tmp_path):
    from pedcal.detect.detect_cli import detect_file, match_detections

    image, truth_xy = five_people_depth_cloud()
    path = tmp_path / "five.npy"
    np.save(path, image.astype(np.float32))
    res = detect_file(path, frame="optical", sensor="depth-camera")
    assert res.read.organized == (480, 640) and res.read.n_invalid > 0
    assert res.warnings == [res.read.summary()]      # the pixels without a return, counted; the ground is plausible
    assert res.ground.warnings == [] and res.floor_shift_m == pytest.approx(1.0, abs=0.03)
    # they touch: one cluster 2.2 m wide, cut at its five heads
    wide = [c for c in det.segment(res.points) if not c.gated and c.box.width > 1.8]
    assert len(wide) == 1
    det_xy = np.array([[d.x, d.y] for d in res.detections])
    assert len(det_xy) == 5
    pairs = match_detections(det_xy, truth_xy, radius_m=0.15)
    assert len(pairs) == 5
    heights = sorted(d.height for d in res.detections)
    assert heights == pytest.approx([1.60, 1.65, 1.72, 1.78, 1.83], abs=0.05)
