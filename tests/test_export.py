"""ROS out: calibrated extrinsics as tf launch files (ROS 1, ROS 2), URDF and JSON, read back and
compared with the YAML; a log's robot and head paths as TUM files."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pedcal
from pedcal.cli import EXIT_BAD_INPUT, main
from pedcal.io import write_sensors_yaml
from pedcal.io.tum import read_tum
from pedcal.model import SensorExtrinsics, SensorNetwork


@pytest.fixture
def network():
    rng = np.random.default_rng(5)
    sensors = [SensorExtrinsics(f"s{i:02d}", rng.uniform(0, 8, 3), [rng.uniform(-180, 180), rng.uniform(30, 60),
                                                                     rng.uniform(-5, 5)],
                                sigma_position_m=[0.004, 0.005, 0.003], sigma_ypr_deg=[0.2, 0.1, 0.1],
                                observations=100 + i, status="ok") for i in range(1, 4)]
    sensors.append(SensorExtrinsics("s04", [1.0, 2.0, 2.6], [90.0, 45.0, 0.0], observations=0, status="no-data"))
    return SensorNetwork(sensors, frame="map")


def _check(network, poses):
    """poses: {child: (translation, R_parent_child)}."""
    assert set(poses) == set(network.ids)
    for s in network:
        t, R = poses[s.id]
        np.testing.assert_allclose(t, s.position_m, atol=1e-12)
        np.testing.assert_allclose(R, s.R_world_sensor, atol=1e-12)


def test_tf_launch_urdf_json_read_back(network, tmp_path, capsys):
    cal = tmp_path / "cal.yaml"
    write_sensors_yaml(network, cal)
    names = {"tf-launch": "out-tf-launch-{}.launch", "urdf": "out-urdf-{}", "json": "out-json-{}"}
    for fmt, extra in (("tf-launch", []), ("tf-launch", ["--ros", "2"]), ("urdf", []), ("json", [])):
        out = tmp_path / names[fmt].format(len(extra))
        assert main(["export", str(cal), "--format", fmt, "-o", str(out), *extra]) == 0
    # ROS 1: args = x y z yaw pitch roll parent child, R = Rz(yaw) Ry(pitch) Rx(roll)
    root = ET.parse(tmp_path / "out-tf-launch-0.launch").getroot()
    poses = {}
    for node in root.iter("node"):
        a = node.get("args").split()
        assert node.get("pkg") == "tf2_ros" and node.get("type") == "static_transform_publisher" and a[6] == "map"
        poses[a[7]] = (np.array(a[:3], float), Rotation.from_euler("ZYX", np.array(a[3:6], float)).as_matrix())
    _check(network, poses)
    assert "s04: status no-data" in (tmp_path / "out-tf-launch-0.launch").read_text()
    # ROS 2: named arguments
    poses = {}
    for node in ET.parse(tmp_path / "out-tf-launch-2.launch").getroot().iter("node"):
        a = node.get("args").split()
        kv = dict(zip(a[::2], a[1::2], strict=True))
        assert node.get("exec") == "static_transform_publisher" and kv["--frame-id"] == "map"
        ypr = [float(kv[f"--{k}"]) for k in ("yaw", "pitch", "roll")]
        poses[kv["--child-frame-id"]] = (np.array([float(kv[f"--{k}"]) for k in "xyz"]),
                                         Rotation.from_euler("ZYX", ypr).as_matrix())
    _check(network, poses)
    # URDF: origin rpy are fixed-axis X, Y, Z rotations
    poses = {}
    for joint in ET.parse(tmp_path / "out-urdf-0").getroot().iter("joint"):
        assert joint.get("type") == "fixed" and joint.find("parent").get("link") == "map"
        o = joint.find("origin")
        poses[joint.find("child").get("link")] = (np.array(o.get("xyz").split(), float),
                                                  Rotation.from_euler("xyz", np.array(o.get("rpy").split(), float))
                                                  .as_matrix())
    _check(network, poses)
    data = json.loads((tmp_path / "out-json-0").read_text())
    _check(network, {d["child_frame"]: (np.array(d["translation_m"]), Rotation.from_quat(d["quaternion_xyzw"])
                                        .as_matrix()) for d in data["sensors"]})
    # both quaternion orders, each named: (x, y, z, w) as ROS and scipy, (w, x, y, z) as the YAML and GTSAM
    yaml_q = {s["id"]: s["quaternion_wxyz"] for s in __import__("yaml").safe_load(cal.read_text())["sensors"]}
    for d in data["sensors"]:
        assert d["quaternion_wxyz"] == d["quaternion_xyzw"][3:] + d["quaternion_xyzw"][:3]
        np.testing.assert_allclose(d["quaternion_wxyz"], yaml_q[d["id"]], atol=1e-12)
    assert data["sensors"][0]["sigma_position_m"] == [0.004, 0.005, 0.003] and data["sensors"][3]["status"] == "no-data"
    capsys.readouterr()
    code = main(["export", str(tmp_path / "nope.yaml"), "--format", "urdf", "-o", str(tmp_path / "x")])
    assert code == EXIT_BAD_INPUT
    assert "nope.yaml" in capsys.readouterr().err


def test_tum_paths_score_the_extrinsics(tmp_path):
    sim = pedcal.simulate_logs("sparse", seed=3, duration_s=120)
    log = sim.eval
    written = pedcal.write_tum(log, tmp_path, {"truth": log.truth})
    assert {"robot", "head", "truth_robot", "truth_head", "head_installed", "head_truth"} <= set(written)
    robot = read_tum(written["robot"])
    yaw = Rotation.from_quat(robot[["qx", "qy", "qz", "qw"]].to_numpy()).as_euler("ZYX")[:, 0]
    ref = log.robot.sort_values("t")
    np.testing.assert_allclose(robot["t"], ref["t"])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - ref["yaw"].to_numpy()))), 0, atol=1e-12)
    assert (np.diff(robot["t"]) > 0).all()
    truth_head = read_tum(written["truth_head"])

    def rms_to_truth(name):
        seen = read_tum(written[name])
        ref = np.column_stack([np.interp(seen["t"], truth_head["t"], truth_head[c]) for c in "xyz"])
        return float(np.sqrt(np.mean(np.sum((seen[["x", "y", "z"]].to_numpy() - ref) ** 2, axis=1))))

    # With the true extrinsics the observed head lies near the true head path (off by the tracker's
    # noise, its latency at the robot's 0.3 m/s and the head dome: under 0.15 m); with the installed
    # ones (errors of decimetres) it does not.
    assert rms_to_truth("head_truth") < 0.15
    assert rms_to_truth("head_installed") > 2 * rms_to_truth("head_truth")


def _launch_py_nodes(path):
    """Run a ROS 2 Python launch file with stand-ins for ``launch`` and ``launch_ros`` and return
    each Node's keywords (what ros2 launch would start)."""
    import sys
    import types

    nodes = []
    launch = types.ModuleType("launch")
    launch.LaunchDescription = lambda entities: list(entities)
    actions = types.ModuleType("launch_ros.actions")
    actions.Node = lambda **kw: nodes.append(kw) or kw
    launch_ros = types.ModuleType("launch_ros")
    launch_ros.actions = actions
    saved = {k: sys.modules.get(k) for k in ("launch", "launch_ros", "launch_ros.actions")}
    sys.modules.update({"launch": launch, "launch_ros": launch_ros, "launch_ros.actions": actions})
    try:
        namespace: dict = {}
        exec(compile(path.read_text(), str(path), "exec"), namespace)   # noqa: S102
        described = namespace["generate_launch_description"]()
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    assert described == nodes
    return nodes


def _ros2_pose(args):
    kv = dict(zip(args[::2], args[1::2], strict=True))
    ypr = [float(kv[f"--{k}"]) for k in ("yaw", "pitch", "roll")]
    return (kv["--frame-id"], kv["--child-frame-id"], np.array([float(kv[f"--{k}"]) for k in "xyz"]),
            Rotation.from_euler("ZYX", ypr).as_matrix())


def test_launch_py_is_a_ros2_python_launch_and_other_names_are_refused(network, tmp_path, capsys):
    cal = tmp_path / "cal.yaml"
    write_sensors_yaml(network, cal)
    out = tmp_path / "sensors.launch.py"
    with pytest.warns(pedcal.errors.DegenerateDataWarning, match="s04 exported with status no-data"):
        pedcal.export_extrinsics(network, out)
    nodes = _launch_py_nodes(out)
    assert all(n["package"] == "tf2_ros" and n["executable"] == "static_transform_publisher" for n in nodes)
    poses = {}
    for n in nodes:
        parent, child, t, R = _ros2_pose(n["arguments"])
        assert parent == "map"
        poses[child] = (t, R)
    _check(network, poses)
    assert main(["export", str(cal), "--format", "tf-launch", "-o", str(tmp_path / "cli.launch.py")]) == 0
    assert (tmp_path / "cli.launch.py").read_text() == out.read_text()      # .launch.py: ROS 2 without --ros
    err = capsys.readouterr().err
    assert "warning: " in err and "sensor s04 exported with status no-data" in err
    for bad in ("sensors.py", "sensors.xml", "sensors"):
        assert main(["export", str(cal), "--format", "tf-launch", "-o", str(tmp_path / bad)]) == EXIT_BAD_INPUT
        assert ".launch.py" in capsys.readouterr().err and not (tmp_path / bad).exists()
    with pytest.raises(pedcal.PedcalInputError, match="ROS 2 Python"):
        pedcal.export_extrinsics(network, tmp_path / "x.launch.py", ros_version=1)
    ok = SensorNetwork([s for s in network if s.status == "ok"])
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")                      # every sensor ok: no warning
        pedcal.export_extrinsics(ok, tmp_path / "ok.launch.xml", ros_version=2)


def test_every_sensor_not_ok_warns_once(network, tmp_path):
    sensors = list(network)
    sensors[0].status, sensors[0].unobservable = "degenerate", ["yaw"]
    with pytest.warns(pedcal.errors.DegenerateDataWarning) as caught:
        pedcal.export_extrinsics(SensorNetwork(sensors), tmp_path / "s.urdf", "urdf")
    texts = sorted(str(w.message) for w in caught)
    assert len(texts) == 2 and "s01 exported with status degenerate (yaw unobservable)" in texts[0]
    assert "s04" in texts[1] and all(w.filename == __file__ for w in caught)


def test_a_warning_from_inside_the_export_points_at_the_callers_line(network, tmp_path, monkeypatch):
    """export_extrinsics is a public entry point (warnings_at_caller): a warning raised by the code
    it calls is re-raised at the caller's line, not at the line in pedcal/io/export.py."""
    import inspect
    import warnings

    import pedcal.io.export as export

    def warning_json_text(net, *, prefix=""):
        warnings.warn("from inside the export", UserWarning, stacklevel=2)    # export.py's line
        return "{}\n"

    monkeypatch.setattr(export, "json_text", warning_json_text)
    ok = SensorNetwork([s for s in network if s.status == "ok"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = inspect.currentframe().f_lineno + 1
        pedcal.export_extrinsics(ok, tmp_path / "s.json", "json")
    assert [(str(w.message), w.filename, w.lineno) for w in caught] == [("from inside the export", __file__, line)]


def test_optical_frames_are_z_forward_x_right_y_down(network, tmp_path):
    from pedcal import frames
    from pedcal.io.ros import optical_to_sensor

    R_sensor_optical = frames.rot_from_ypr_deg(frames.OPTICAL_YPR_DEG)
    p_optical = np.array([[0.3, -0.2, 2.0]])
    np.testing.assert_allclose(R_sensor_optical @ p_optical[0], optical_to_sensor(p_optical)[0], atol=1e-15)
    np.testing.assert_allclose(R_sensor_optical[:, 2], [1, 0, 0], atol=1e-15)   # optical z = the optical axis
    for fmt, name in (("tf-launch", "o.launch.py"), ("urdf", "o.urdf")):
        with pytest.warns(pedcal.errors.DegenerateDataWarning):
            path = pedcal.export_extrinsics(network, tmp_path / name, fmt, optical=True, prefix="cam_")
        edges = {}
        if fmt == "urdf":
            for joint in ET.parse(path).getroot().iter("joint"):
                o = joint.find("origin")
                edges[joint.find("child").get("link")] = (
                    joint.find("parent").get("link"), np.array(o.get("xyz").split(), float),
                    Rotation.from_euler("xyz", np.array(o.get("rpy").split(), float)).as_matrix())
        else:
            for n in _launch_py_nodes(path):
                parent, child, t, R = _ros2_pose(n["arguments"])
                edges[child] = (parent, t, R)
        assert len(edges) == 2 * len(network)
        for s in network:
            parent, t, R = edges[f"cam_{s.id}_optical"]
            assert parent == f"cam_{s.id}" and np.all(t == 0)
            np.testing.assert_allclose(R, R_sensor_optical, atol=1e-15)
            # the optical frame's z in the world is the sensor's optical axis (its body x)
            R_world_optical = edges[f"cam_{s.id}"][2] @ R
            np.testing.assert_allclose(R_world_optical[:, 2], s.R_world_sensor[:, 0], atol=1e-12)


def test_tum_head_points_read_back_the_identity_quaternion_and_latency_is_applied(tmp_path):
    sim = pedcal.simulate_logs("sparse", seed=3, duration_s=60)
    log = sim.eval
    late = log.truth.copy()
    late.extra["tracker_latency_s"] = 0.25
    written = pedcal.write_tum(log, tmp_path, {"truth": log.truth, "late": late})
    raw_lines = [ln for ln in written["head_truth"].read_text().splitlines() if not ln.startswith("#")]
    assert all(ln.split()[4:] == ["0.0", "0.0", "0.0", "1.0"] for ln in raw_lines)   # qx qy qz qw, w last
    head = read_tum(written["head_truth"])
    assert (head[["qx", "qy", "qz", "qw"]].to_numpy() == [0.0, 0.0, 0.0, 1.0]).all()
    late_head = read_tum(written["head_late"])
    np.testing.assert_allclose(late_head["t"], head["t"] - 0.25, atol=1e-9)
    np.testing.assert_allclose(late_head[["x", "y", "z"]], head[["x", "y", "z"]], atol=0)
    assert "latency 0.25 s" in written["head_late"].read_text().splitlines()[0]


@pytest.mark.parametrize("fmt,out,argv", [("tf-launch", "t.launch", ["--prefix", "site 1/"]),
                                          ("tf-launch", "t.launch.py", ["--prefix", "a\tb"]),
                                          ("urdf", "t.urdf", ["--prefix", "x\n"])])
def test_frame_names_a_launch_file_would_split_are_refused(network, tmp_path, capsys, fmt, out, argv):
    """A launch file's args are split at spaces: 'site 1/s01' became two arguments, the rest shifted."""
    cal = tmp_path / "cal.yaml"
    write_sensors_yaml(network, cal)
    assert main(["export", str(cal), "--format", fmt, "-o", str(tmp_path / out), *argv]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert f"{cal}: a sensor's frame (--prefix + id) {(argv[1] + network.ids[0])!r} is empty or holds whitespace" in err
    assert not (tmp_path / out).exists()
    assert main(["export", str(cal), "--format", "json", "-o", str(tmp_path / "t.json"), *argv]) == 0   # JSON: any text


@pytest.mark.parametrize("fmt,out", [("tf-launch", "t.launch.py"), ("urdf", "t.urdf")])
def test_a_parent_frame_a_launch_file_would_split_is_refused_as_the_parent_frame(network, tmp_path, capsys,
                                                                                fmt, out):
    cal = tmp_path / "cal.yaml"
    network.frame = "site map"
    write_sensors_yaml(network, cal)
    assert main(["export", str(cal), "--format", fmt, "-o", str(tmp_path / out)]) == EXIT_BAD_INPUT
    assert f"{cal}: the parent frame 'site map' is empty or holds whitespace" in capsys.readouterr().err
    assert not (tmp_path / out).exists()
