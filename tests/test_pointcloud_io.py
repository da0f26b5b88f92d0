"""Point-cloud readers: every PCD layout and encoding, PLY, KITTI .bin, .npy, organized clouds with
NaN pixels, and fuzzing: no byte string may crash the process or raise anything but an input error."""

import subprocess
import sys
import warnings

import lzf
import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from pedcal.cli import main
from pedcal.detect.pointcloud_io import read_point_cloud, read_point_cloud_report
from pedcal.errors import DegenerateDataWarning, PedcalInputError

# x y z, padding of 4 bytes, intensity, a COUNT 0 padding field, an f8 timestamp, 6 padding bytes,
# a u2 ring: the layout of the SUSTech automotive LIDAR frames
FIELDS = [("x", "F", 4, 1), ("y", "F", 4, 1), ("z", "F", 4, 1), ("_", "U", 1, 4), ("intensity", "F", 4, 1),
          ("_", "U", 1, 0), ("timestamp", "F", 8, 1), ("_", "U", 1, 6), ("ring", "U", 2, 1)]


def _dtype(fields):
    kinds = {"F": "f", "U": "u", "I": "i"}
    parts = []
    for k, (name, t, s, c) in enumerate(fields):
        if c:
            parts.append((f"f{k}_{name}", f"<{kinds[t]}{s}", (c,)))
    return np.dtype(parts)


def pcd_bytes(xyzi, fields=FIELDS, data="binary", width=None, height=1, points=None, trailing=b""):
    n = len(xyzi)
    rec = np.zeros(n, _dtype(fields))
    for k, (name, _, _, c) in enumerate(fields):
        if c and name in ("x", "y", "z", "intensity"):
            rec[f"f{k}_{name}"][:, 0] = xyzi[:, "xyz".index(name) if name in "xyz" else 3]
    width = n if width is None else width
    header = ["# .PCD v0.7", "VERSION 0.7", "FIELDS " + " ".join(f[0] for f in fields),
              "SIZE " + " ".join(str(f[2]) for f in fields), "TYPE " + " ".join(f[1] for f in fields),
              "COUNT " + " ".join(str(f[3]) for f in fields), f"WIDTH {width}", f"HEIGHT {height}",
              "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {width * height if points is None else points}", f"DATA {data}"]
    head = ("\n".join(header) + "\n").encode()
    if data == "binary":
        return head + rec.tobytes() + trailing
    if data == "ascii":
        rows = []
        for r in rec:
            rows.append(" ".join(" ".join(repr(float(v)) for v in np.ravel(r[name])) for name in rec.dtype.names))
        return head + ("\n".join(rows) + "\n").encode() + trailing
    columns = b"".join(np.ascontiguousarray(rec[name]).tobytes() for name in rec.dtype.names)
    comp = lzf.compress(columns)
    return head + np.array([len(comp), len(columns)], "<u4").tobytes() + comp + trailing


def cloud(n=50, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-5, 5, (n, 3)), rng.uniform(0, 1, n)]).astype(np.float32).astype(float)


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_every_encoding_with_padding_and_count_zero(tmp_path, data):
    pts = cloud()
    path = tmp_path / f"f_{data}.pcd"
    path.write_bytes(pcd_bytes(pts, data=data, trailing=b"\x00" * 37 if data == "binary" else b""))
    np.testing.assert_allclose(read_point_cloud(path), pts, atol=1e-6)


def test_pcd_plain_layout_and_packed_colour(tmp_path):
    pts = cloud(20)
    fields = [("x", "F", 8, 1), ("y", "F", 8, 1), ("z", "F", 8, 1), ("rgb", "U", 4, 1)]
    raw = pcd_bytes(pts, fields=fields)
    # every point grey 0x808080: intensity 128/255
    head, body = raw.split(b"DATA binary\n")
    rec = np.frombuffer(body, np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("rgb", "<u4")])).copy()
    rec["rgb"] = 0x808080
    (tmp_path / "c.pcd").write_bytes(head + b"DATA binary\n" + rec.tobytes())
    back = read_point_cloud(tmp_path / "c.pcd")
    np.testing.assert_allclose(back[:, :3], pts[:, :3])
    np.testing.assert_allclose(back[:, 3], 128 / 255)


def test_organized_cloud_drops_and_counts_nan_pixels(tmp_path, capsys):
    h, w = 6, 8
    pts = cloud(h * w, seed=1)
    pts[::3, :3] = np.nan  # invalid pixels
    path = tmp_path / "organized.pcd"
    path.write_bytes(pcd_bytes(pts, data="binary_compressed", width=w, height=h))
    res = read_point_cloud_report(path)
    n_nan = len(pts[::3])
    assert res.n_in_file == h * w and res.n_invalid == n_nan and res.organized == (h, w)
    assert len(res.points) == h * w - n_nan and np.isfinite(res.points).all()
    assert f"{n_nan} pixels" in res.summary()
    with pytest.warns(DegenerateDataWarning, match=f"{n_nan} pixels"):
        read_point_cloud(path)
    # the same as an (H, W, 3) .npy depth image
    np.save(tmp_path / "organized.npy", pts[:, :3].reshape(h, w, 3))
    res = read_point_cloud_report(tmp_path / "organized.npy")
    assert res.n_invalid == n_nan and res.organized == (h, w)
    assert main(["detect", str(path)]) == 0
    assert f"{n_nan} pixels" in capsys.readouterr().err


def test_ply_ascii_and_binary(tmp_path):
    pts = cloud(30)
    vert = np.zeros(len(pts), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("intensity", "f4")])
    for k, name in enumerate("xyz"):
        vert[name] = pts[:, k]
    vert["intensity"] = pts[:, 3]
    for text in (True, False):
        path = tmp_path / f"c_{text}.ply"
        PlyData([PlyElement.describe(vert, "vertex")], text=text).write(str(path))
        np.testing.assert_allclose(read_point_cloud(path), pts, atol=1e-5)


def test_npy_layouts(tmp_path):
    pts = cloud(10)
    np.save(tmp_path / "a.npy", pts)
    np.save(tmp_path / "b.npy", pts[:, :3])
    np.testing.assert_allclose(read_point_cloud(tmp_path / "a.npy"), pts)
    np.testing.assert_allclose(read_point_cloud(tmp_path / "b.npy")[:, :3], pts[:, :3])
    np.save(tmp_path / "c.npy", np.array(["a", "b"]))
    with pytest.raises(PedcalInputError, match="c.npy"):
        read_point_cloud(tmp_path / "c.npy")


def test_bin_with_huge_coordinates_is_read_and_detected(tmp_path, capsys):
    pts = cloud(40).astype("<f4")
    pts[5, :3] = 1e30
    pts[6, 0] = -3e38
    path = tmp_path / "huge.bin"
    pts.tofile(path)
    res = read_point_cloud_report(path)
    assert res.n_too_far == 2 and len(res.points) == 38
    assert main(["detect", str(path), "--json"]) == 0
    assert "2 points farther" in capsys.readouterr().err


def test_pcd_promising_more_points_than_it_holds(tmp_path, capsys):
    pts = cloud(10)
    for data in ("binary", "ascii", "binary_compressed"):
        path = tmp_path / f"short_{data}.pcd"
        path.write_bytes(pcd_bytes(pts, data=data, width=1000))
        with pytest.raises(PedcalInputError, match="1000"):
            read_point_cloud(path)
        assert main(["detect", str(path)]) == 2
        err = capsys.readouterr().err
        assert str(path) in err and "Traceback" not in err


@pytest.mark.parametrize("header_edit", [
    (b"POINTS 50", b"POINTS 49"), (b"COUNT 1 1 1 4 1 0", b"COUNT 1 1 1 4 1"), (b"TYPE F F F", b"TYPE Q F F"),
    (b"SIZE 4 4 4", b"SIZE 3 4 4"), (b"DATA binary", b"DATA zip"), (b"FIELDS x y z", b"FIELDS a y z"),
    (b"WIDTH 50", b"WIDTH -50"), (b"WIDTH 50", b"WIDTH fifty"), (b"DATA binary\n", b""),
])
def test_pcd_bad_headers_are_input_errors(tmp_path, header_edit):
    raw = pcd_bytes(cloud()).replace(*header_edit, 1)
    path = tmp_path / "bad.pcd"
    path.write_bytes(raw)
    with pytest.raises(PedcalInputError, match="bad.pcd"):
        read_point_cloud(path)


def _fuzz_cases(seed: int = 7):
    """Byte strings derived from valid files: truncations, flipped bytes, garbage and spliced tails."""
    rng = np.random.default_rng(seed)
    pts = cloud(40)
    vert = np.zeros(len(pts), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    for k, name in enumerate("xyz"):
        vert[name] = pts[:, k]
    import io

    ply_bin, ply_txt = io.BytesIO(), io.BytesIO()
    PlyData([PlyElement.describe(vert, "vertex")], text=False).write(ply_bin)
    PlyData([PlyElement.describe(vert, "vertex")], text=True).write(ply_txt)
    npy = io.BytesIO()
    np.save(npy, pts)
    seeds = [(".pcd", pcd_bytes(pts, data=d)) for d in ("ascii", "binary", "binary_compressed")]
    seeds += [(".ply", ply_bin.getvalue()), (".ply", ply_txt.getvalue()), (".npy", npy.getvalue()),
              (".bin", pts.astype("<f4").tobytes())]
    for suffix, raw in seeds:
        for cut in rng.integers(0, len(raw), 6):
            yield suffix, raw[:cut]
        for _ in range(8):
            b = bytearray(raw)
            pos = rng.integers(0, len(b), rng.integers(1, 6))
            for p in pos:
                b[p] = rng.integers(0, 256)
            yield suffix, bytes(b)
        yield suffix, rng.integers(0, 256, rng.integers(1, 400)).astype(np.uint8).tobytes()
        yield suffix, raw + rng.integers(0, 256, 33).astype(np.uint8).tobytes()


def test_fuzzed_files_read_or_fail_with_an_input_error(tmp_path):
    n_read = n_refused = 0
    for k, (suffix, raw) in enumerate(_fuzz_cases()):
        path = tmp_path / f"fuzz{k}{suffix}"
        path.write_bytes(raw)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DegenerateDataWarning)
            try:
                pts = read_point_cloud(path)
            except PedcalInputError as e:
                assert str(path) in str(e)
                n_refused += 1
            else:
                assert pts.ndim == 2 and pts.shape[1] == 4 and np.isfinite(pts).all()
                n_read += 1
    assert n_read > 20 and n_refused > 20  # both outcomes are exercised


def test_fuzzed_files_never_crash_the_detect_command(tmp_path):
    """The detect command in a child process over a sample of fuzzed files: exit 0 or 2, never a
    signal (an abort in a C++ reader) or a traceback."""
    cases = list(_fuzz_cases(seed=11))[::6]
    paths = []
    for k, (suffix, raw) in enumerate(cases):
        path = tmp_path / f"fz{k}{suffix}"
        path.write_bytes(raw)
        paths.append(str(path))
    script = ("import sys, warnings\nwarnings.simplefilter('ignore')\nfrom pedcal.cli import main\n"
              "codes = [main(['detect', p, '--json']) for p in sys.argv[1:]]\nprint(codes)\n")
    proc = subprocess.run([sys.executable, "-c", script, *paths], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    codes = eval(proc.stdout.strip().splitlines()[-1])  # a printed list of ints
    assert len(codes) == len(paths) and set(codes) <= {0, 2}
    assert "Traceback" not in proc.stderr


def test_sustech_frames_read(shared_data):
    """The real automotive frames (padding fields, COUNT 0, trailing bytes) read in full."""
    for path in sorted((shared_data / "sustech_points").glob("*.pcd")):
        res = read_point_cloud_report(path)
        assert 60000 < len(res.points) == res.n_in_file < 70000
        r = np.hypot(res.points[:, 0], res.points[:, 1])
        assert 100 < r.max() < 300 and 0.5 < res.points[:, 3].max() <= 1.0  # 8-bit intensities rescaled


@pytest.mark.parametrize("suffix,match", [(".pcd", "empty file, expected a PCD point cloud"),
                                          (".bin", "its 0 bytes are not a positive multiple of 16"),
                                          (".ply", "not a readable PLY point cloud"),
                                          (".npy", "not a readable .npy array")])
def test_an_empty_file_of_each_format_is_named_as_such(tmp_path, suffix, match):
    """An empty .pcd read 'no DATA line in the first 0 bytes'."""
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    with pytest.raises(PedcalInputError, match=match) as ei:
        read_point_cloud(path)
    assert ei.value.path == str(path)
