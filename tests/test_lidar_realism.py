"""What real LIDARs and depth cameras do that a clean raycast does not: the data sheets' beam
layouts, pinhole depth cameras in their optical frame, depth noise growing with range squared,
intensity scales, stray returns below the ground, mounts on robots and cars."""

from __future__ import annotations

import numpy as np
import pytest

from pedcal.errors import PedcalInputError
from pedcal.sim.lidar import (
    HDL64E_ELEVATIONS_DEG,
    INTENSITY_MODELS,
    LIDAR_PRESETS,
    MOUNT_HEIGHTS_M,
    STRAY_ID,
    STRAY_MODES,
    VLP32C_ELEVATIONS_DEG,
    LidarModel,
    Mount,
    draw_mount_height_m,
    mount_kinds,
    random_mount,
    random_nuisances,
    render,
)
from pedcal.sim.scene import FLOOR_ID, Scene, SceneObject, box, make_person

NOISELESS = dict(range_noise_std_m=0.0, intensity_noise_std=0.0, dropout_prob=0.0)


def _wall(x_face_m: float, reflectance: float = 0.6) -> SceneObject:
    """A 40 m wide, 3 m tall wall across the view whose front face is the plane x = x_face_m."""
    mesh = box((0.0, 0.0, 1.5), (40.0, 0.12, 3.0), reflectance)
    return SceneObject(kind="wall", is_person=False, mesh_local=mesh, x_m=x_face_m + 0.06, y_m=0.0,
                       yaw_rad=np.pi / 2, length_m=40.0, radius_m=0.06, reflectance=reflectance)


def _elevations_deg(preset: str) -> np.ndarray:
    return np.degrees(np.unique(LIDAR_PRESETS[preset].ray_angles_rad()[1]))


def test_spinning_presets_have_their_data_sheet_beam_layouts():
    vlp16 = _elevations_deg("vlp16")
    np.testing.assert_allclose(vlp16, np.arange(-15.0, 15.5, 2.0), atol=1e-9)
    hdl32 = _elevations_deg("hdl32")
    assert len(hdl32) == 32
    np.testing.assert_allclose(hdl32[[0, -1]], [-30.67, 10.67], atol=0.01)
    np.testing.assert_allclose(np.diff(hdl32), 41.33 / 31, atol=1e-3)
    hdl64e = _elevations_deg("hdl64e")
    assert len(hdl64e) == 64 and hdl64e.max() == pytest.approx(2.0) and hdl64e.min() == pytest.approx(-24.9)
    gaps = np.diff(hdl64e)
    # the upper block (above -8.33 deg) 1/3 deg apart, the lower one 0.518 deg, 0.5 deg between them
    np.testing.assert_allclose(gaps[hdl64e[1:] <= -8.83 + 1e-6], 16.07 / 31, atol=1e-3)
    np.testing.assert_allclose(gaps[hdl64e[:-1] >= -8.33 - 1e-6], 10.33 / 31, atol=1e-3)
    assert HDL64E_ELEVATIONS_DEG[0] == 2.0 and len(HDL64E_ELEVATIONS_DEG) == 64
    vlp32c = _elevations_deg("vlp32c")
    np.testing.assert_allclose(vlp32c, sorted(VLP32C_ELEVATIONS_DEG), atol=1e-9)
    assert vlp32c.min() == pytest.approx(-25.0) and vlp32c.max() == pytest.approx(15.0)
    # denser near the horizon: 1/3 deg between -2 and +2 deg, 10 deg between the lowest two beams
    near = (vlp32c[:-1] >= -2.0) & (vlp32c[1:] <= 1.7)
    assert np.allclose(np.diff(vlp32c)[near], 1 / 3, atol=2e-3) and np.diff(vlp32c)[0] == pytest.approx(9.361)
    for name, beams, cols in (("os1_64", 64, 2048), ("os1_128", 128, 1024)):
        el = _elevations_deg(name)
        assert len(el) == beams and LIDAR_PRESETS[name].n_horizontal == cols
        np.testing.assert_allclose(el[[0, -1]], [-22.5, 22.5], atol=1e-9)
        np.testing.assert_allclose(np.diff(el), 45.0 / (beams - 1), atol=1e-9)


def test_vlp16_rows_on_a_wall_lie_where_its_beams_point():
    lidar = LIDAR_PRESETS["vlp16"].with_(**NOISELESS)
    frame = render(Scene([_wall(10.0)]), lidar, Mount(0.0, 0.0, 0.8), np.random.default_rng(0))
    on_wall = frame.xyz[frame.object_id == 0].astype(float)
    ahead = on_wall[np.abs(on_wall[:, 1]) < 0.017]  # the column straight ahead (0.2 deg = 3.5 cm)
    expected = 0.8 + 10.0 * np.tan(np.radians(np.arange(-15.0, 15.5, 2.0)))
    expected = np.sort(expected[(expected > 0.0) & (expected < 3.0)])
    np.testing.assert_allclose(np.sort(ahead[:, 2]), expected, atol=0.005)


def test_a_pinhole_camera_samples_its_image_plane_evenly():
    """realsense_d435: 848 x 480 rays through a pinhole's pixel grid; on a wall 3 m ahead the
    columns are 2 · 3 m · tan(43.5 deg) / 847 apart (even in y, not in angle)."""
    lidar = LIDAR_PRESETS["realsense_d435"].with_(**NOISELESS)
    assert (lidar.n_horizontal, lidar.n_vertical, lidar.projection) == (848, 480, "pinhole")
    d = lidar.ray_directions_sensor()
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    az, el = lidar.ray_angles_rad()
    np.testing.assert_allclose(d, np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]),
                               atol=1e-12)
    frame = render(Scene([_wall(3.0)]), lidar, Mount(0.0, 0.0, 1.5), np.random.default_rng(0))
    row = frame.xyz[(frame.object_id == 0) & (frame.ray_index // 848 == 240)].astype(float)
    y = np.sort(row[:, 1])
    assert len(y) == 848
    np.testing.assert_allclose(np.diff(y), 6.0 * np.tan(np.radians(43.5)) / 847, rtol=1e-3)
    with pytest.raises(PedcalInputError, match="pinhole"):
        LidarModel("bad", 10, 10, 360.0, 30.0, 0.3, 5.0, projection="pinhole")


def test_depth_camera_organized_cloud_in_the_optical_frame():
    """A person 2.5 m ahead and 0.6 m to the left of a camera at 1.2 m: in the optical frame
    (x right, y down, z forward) the person is at x < 0, z ~ 2.5, and in the image's left half;
    the floor is at y = +1.2 m (down); rays that hit nothing are NaN."""
    rng = np.random.default_rng(0)
    scene = Scene(floor_half_extent_m=4.0)
    pid = scene.add(make_person(1.7, 0.45, 0.25, "standing", 0.5, rng, x_m=2.5, y_m=0.6))
    lidar = LIDAR_PRESETS["depth_vga_wide"].with_(**NOISELESS)
    frame = render(scene, lidar, Mount(0.0, 0.0, 1.2), np.random.default_rng(0))
    img = frame.organized(lidar)
    assert img.shape == (480, 640, 4) and img.dtype == np.float32
    ids = np.full(lidar.n_rays, -99)
    ids[frame.ray_index] = frame.object_id
    ids = ids.reshape(480, 640)[::-1, ::-1]
    person = img[ids == pid]
    assert len(person) > 1000
    assert np.nanmax(person[:, 0]) < -0.3 and np.median(person[:, 2]) == pytest.approx(2.5, abs=0.15)
    assert np.all(np.nonzero(ids == pid)[1] < 320)  # left half of the image
    np.testing.assert_allclose(img[ids == FLOOR_ID][:, 1], 1.2, atol=1e-4)
    # the top rows look over the 4 m floor's edge and the person: nothing comes back
    assert np.isnan(img[0, :, :3]).all() and not np.isnan(img[-1, :, :3]).any()
    # the same points as the base frame's, rotated: optical z is base x (the camera looks along x)
    opt = frame.points_in_sensor(0, optical=True)
    np.testing.assert_allclose(opt[:, 2], frame.xyz[:, 0], atol=1e-5)
    np.testing.assert_allclose(opt[:, 1], 1.2 - frame.xyz[:, 2], atol=1e-5)
    np.testing.assert_allclose(opt[:, 0], -frame.xyz[:, 1], atol=1e-5)
    assert (frame.intensity == 0).all()  # a depth camera reports no intensity
    with pytest.raises(PedcalInputError, match="mount_index"):
        frame.points_in_sensor(1)


def test_quadratic_depth_noise_grows_with_range_squared():
    lidar = LIDAR_PRESETS["realsense_d435"].with_(dropout_prob=0.0, intensity_noise_std=0.0)
    spread, scaled = {}, {}
    for x in (1.5, 4.0):
        frame = render(Scene([_wall(x)]), lidar, Mount(0.0, 0.0, 1.5), np.random.default_rng(1))
        # the central 40 columns, chosen by ray rather than by the noisy points (no selection bias)
        sel = (frame.object_id == 0) & (np.abs(frame.ray_index % 848 - 423.5) < 20)
        r = np.linalg.norm(frame.xyz[sel].astype(float) - [0.0, 0.0, 1.5], axis=1)
        true_r = x / lidar.ray_directions_sensor()[frame.ray_index[sel], 0]  # the ray meets the wall at x / cos
        err = r - true_r
        assert abs(float(np.mean(err))) < 4 * np.std(err) / np.sqrt(len(err))
        spread[x], scaled[x] = float(np.std(err)), float(np.std(err / true_r**2))
    # sigma = 3.6 mm · r^2: about 9 mm at 1.5 m, 60 mm at 4 m
    assert scaled[1.5] == pytest.approx(0.0036, rel=0.05) and scaled[4.0] == pytest.approx(0.0036, rel=0.05)
    assert spread[4.0] / spread[1.5] > 5.0


def test_intensity_models_rescale_or_drop_the_same_returns():
    scene = Scene([_wall(6.0, 0.7)])
    frames = {m: render(scene, LIDAR_PRESETS["hdl64e"].with_(intensity_model=m), Mount(0.0, 0.0, 1.8),
                        np.random.default_rng(3)) for m in INTENSITY_MODELS}
    unit = frames["unit"].intensity
    assert 0.0 <= unit.min() and unit.max() <= 1.0 and unit.max() > 0.3
    np.testing.assert_array_equal(frames["uint8"].xyz, frames["unit"].xyz)  # no draw changes
    as_uint8 = frames["uint8"].intensity
    assert np.all(as_uint8 == np.round(as_uint8)) and as_uint8.max() <= 255.0
    np.testing.assert_allclose(as_uint8, 255.0 * unit, atol=0.5 + 1e-4)  # (unit is float32)
    assert (frames["none"].intensity == 0).all()
    with pytest.raises(PedcalInputError, match="intensity_model"):
        LIDAR_PRESETS["vlp16"].with_(intensity_model="dB")


def test_calibrated_intensity_does_not_fall_off_with_range():
    """hdl64e reports calibrated reflectance as KITTI does: a wall reads the same at 4 and 12 m
    (straight ahead, where the incidence is nil); with the raw model it reads (4 / 12)^0.5 as much,
    and a calibrated cos^0.5 incidence term makes a grazing floor brighter than cos does."""
    def wall_reading(lidar, x):
        frame = render(Scene([_wall(x, 0.5)]), lidar, Mount(0.0, 0.0, 1.8), np.random.default_rng(0))
        ahead = (frame.object_id == 0) & (np.abs(frame.xyz[:, 1]) < 0.05) & (np.abs(frame.xyz[:, 2] - 1.8) < 0.3)
        return float(frame.intensity[ahead].mean())

    calibrated = LIDAR_PRESETS["hdl64e"].with_(**NOISELESS)
    raw = calibrated.with_(intensity_range_exponent=0.5, intensity_incidence_exponent=1.0)
    assert wall_reading(calibrated, 4.0) == pytest.approx(0.5, abs=0.01)
    assert wall_reading(calibrated, 12.0) == pytest.approx(wall_reading(calibrated, 4.0), rel=0.01)
    assert wall_reading(raw, 12.0) / wall_reading(raw, 4.0) == pytest.approx((4.0 / 12.0) ** 0.5, rel=0.02)
    floor = {k: render(Scene(), m, Mount(0.0, 0.0, 1.8), np.random.default_rng(0)) for k, m in
             (("calibrated", calibrated), ("cos", calibrated.with_(intensity_incidence_exponent=1.0)))}
    ratio = floor["calibrated"].intensity / floor["cos"].intensity
    cos_inc = 1.8 / np.linalg.norm(floor["cos"].xyz - [0.0, 0.0, 1.8], axis=1)  # the floor's normal is z
    np.testing.assert_allclose(ratio, cos_inc ** -0.5, rtol=1e-3)
    with pytest.raises(PedcalInputError, match="exponents"):
        calibrated.with_(intensity_incidence_exponent=-1.0)


@pytest.mark.parametrize("mode", STRAY_MODES)
def test_stray_returns_lie_one_to_six_metres_below_the_floor(mode):
    """On a bare floor a 64-beam LIDAR at 1.8 m with 3 % stray returns: every stray is 1-6 m
    below the floor, on its own ray (along_ray) or below its true hit (vertical, patch); about 3 %
    of the returns that can stray do; without the option nothing lies below the floor."""
    base = LIDAR_PRESETS["hdl64e"].with_(**NOISELESS)
    mount = Mount(0.0, 0.0, 1.8)
    clean = render(Scene(), base, mount, np.random.default_rng(5))
    assert clean.xyz[:, 2].min() > -1e-4
    stray = render(Scene(), base.with_(stray_below_share=0.03, stray_mode=mode), mount, np.random.default_rng(5))
    np.testing.assert_array_equal(stray.ray_index, clean.ray_index)  # the same returns, some moved
    is_stray = stray.object_id == STRAY_ID
    below = stray.xyz[:, 2] < -1e-3
    np.testing.assert_array_equal(is_stray, below)
    z = stray.xyz[is_stray, 2]
    assert z.min() >= -6.0 - 1e-4 and z.max() <= -1.0 + 1e-4
    d = base.ray_directions_sensor()[stray.ray_index[is_stray]]
    if mode == "along_ray":
        v = stray.xyz[is_stray].astype(float) - mount.position_base
        np.testing.assert_allclose(v / np.linalg.norm(v, axis=1, keepdims=True), d, atol=1e-5)
        # a ray can stray where the 1-6 m deeper point is within the 120 m range
        can = (1.8 + 1.0) / -base.ray_directions_sensor()[clean.ray_index, 2] <= 120.0
        share = is_stray.sum() / can.sum()
        assert np.all(can[is_stray])
    else:
        np.testing.assert_allclose(stray.xyz[is_stray, :2], clean.xyz[is_stray, :2], atol=1e-5)
        share = is_stray.mean()
    if mode == "patch":  # 1-3 sheets of the bare floor, each moved down by one depth
        assert 1 <= len(np.unique(np.round(z, 4))) <= 3
    assert share == pytest.approx(0.03, abs=4 * np.sqrt(0.03 * 0.97 / len(clean.points)) + 0.002)
    assert np.all(stray.intensity[is_stray] <= 0.5 * clean.intensity[is_stray] + 1e-6)
    with pytest.raises(PedcalInputError, match="stray_below_share"):
        base.with_(stray_below_share=1.5)
    with pytest.raises(PedcalInputError, match="stray_depth_m"):
        base.with_(stray_depth_m=(3.0, 1.0))


def test_mount_heights_by_kind():
    rng = np.random.default_rng(0)
    assert mount_kinds("vlp16") == ("robot", "car") and mount_kinds("fx8") == ("robot",)
    assert mount_kinds("realsense_d435") == ("robot",)
    drawn = [draw_mount_height_m("os1_64", rng) for _ in range(400)]
    for h, kind in drawn:
        lo, hi = MOUNT_HEIGHTS_M[kind]
        assert lo <= h <= hi
    kinds = [k for _, k in drawn]
    assert 150 < kinds.count("car") < 250  # evenly on a robot (0.4-1.2 m) or a car (1.7-2.0 m)
    heights = np.array([h for h, k in drawn if k == "robot"])
    assert heights.min() < 0.45 and heights.max() > 1.15
    assert {draw_mount_height_m("depth_vga_wide", rng)[1] for _ in range(50)} == {"robot"}
    mount, kind = random_mount("depth_vga_wide", np.random.default_rng(4))
    again, _ = random_mount("depth_vga_wide", np.random.default_rng(4))
    assert mount == again and 0.4 <= mount.z_m <= 1.2 and -3.0 <= mount.pitch_deg <= 12.0
    assert random_mount("vlp32c", np.random.default_rng(4), kind="car")[0].z_m >= 1.7
    with pytest.raises(PedcalInputError, match="mount kind"):
        draw_mount_height_m("vlp16", rng, kind="drone")


def test_random_nuisances_vary_by_seed_and_keep_the_geometry():
    variants = [random_nuisances("vlp32c", np.random.default_rng(s)) for s in range(200)]
    assert random_nuisances("vlp32c", np.random.default_rng(7)) == variants[7]
    assert {v.intensity_model for v in variants} == set(INTENSITY_MODELS)
    assert {v.stray_mode for v in variants if v.stray_below_share > 0} == set(STRAY_MODES)
    shares = np.array([v.stray_below_share for v in variants])
    assert 0.35 < np.mean(shares == 0) < 0.65 and shares.max() <= 0.005 and shares[shares > 0].min() >= 1e-4
    assert {v.range_noise for v in variants} == {"uniform", "gaussian"}
    calibrated = [v for v in variants if v.intensity_range_exponent == 0.0]
    assert 60 < len(calibrated) < 140 and all(0 <= v.intensity_incidence_exponent <= 0.5 for v in calibrated)
    assert all(v.intensity_incidence_exponent == 1.0 for v in variants if v.intensity_range_exponent == 0.5)
    base = LIDAR_PRESETS["vlp32c"]
    assert all(v.elevations_deg == base.elevations_deg and v.n_horizontal == base.n_horizontal for v in variants)
    cams = [random_nuisances("realsense_d435", np.random.default_rng(s)) for s in range(30)]
    assert all(c.intensity_model == "none" and c.range_noise == "quadratic" for c in cams)


@pytest.mark.parametrize("name", ["vlp16", "vlp32c", "os1-64", "os1-128", "realsense-d435", "depth-vga-wide"])
def test_named_sensors_state_their_presets_ray_steps(name):
    """``pedcal detect --sensor NAME`` knows these sensors' ray steps (azimuth, elevation; the
    finest elevation step of a beam table): they are the presets'; depth cameras get thinned."""
    from pedcal.detect.sensors import SENSORS, needs_thinning

    preset, (az_step, el_step) = SENSORS[name]
    lidar = LIDAR_PRESETS[preset]
    az, el = (np.degrees(a).reshape(lidar.n_vertical, lidar.n_horizontal) for a in lidar.ray_angles_rad())
    az, el = az[lidar.n_vertical // 2], el[:, lidar.n_horizontal // 2]  # the middle row and column
    spinning = lidar.fov_horizontal_deg >= 360.0
    assert az_step == pytest.approx(360.0 / lidar.n_horizontal if spinning else np.ptp(az) / (len(az) - 1), rel=1e-3)
    fine = np.diff(el).min() if lidar.elevations_deg is not None else np.ptp(el) / (len(el) - 1)
    assert el_step == pytest.approx(fine, rel=2e-3)
    assert needs_thinning(np.zeros((0, 4)), name) == (lidar.projection == "pinhole")


@pytest.mark.parametrize("mode", STRAY_MODES)
def test_stray_returns_of_an_empty_frame(mode):
    """A camera looking at the open sky returns nothing, strays or not."""
    lidar = LIDAR_PRESETS["depth_vga_wide"].with_(stray_below_share=0.1, stray_mode=mode)
    frame = render(Scene(), lidar, Mount(0.0, 0.0, 1.0, 0.0, -80.0), np.random.default_rng(0))
    assert frame.points.shape == (0, 4) and frame.organized(lidar).shape == (480, 640, 4)
    assert np.isnan(frame.organized(lidar)).all()
