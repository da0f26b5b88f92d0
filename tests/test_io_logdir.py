"""Log directory (LOG_FORMAT.md) and sensors YAML: exact round trips and every bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pedcal.errors import PedcalInputError
from pedcal.io import (
    read_log,
    read_people_csv,
    read_sensors_yaml,
    validate,
    write_log,
    write_people_csv,
    write_sensors_yaml,
)
from pedcal.model import Log, Meta, SensorExtrinsics, SensorNetwork
from tests.conftest import assert_refused_for_what_it_is


def make_network(rng, ids=("s01", "s02", "1")) -> SensorNetwork:
    return SensorNetwork([SensorExtrinsics(i, rng.uniform(-5, 5, 3) + [0, 0, 2.6],
                                           rng.uniform([-180, 30, -5], [180, 60, 5])) for i in ids])


def make_log(seed=0) -> Log:
    rng = np.random.default_rng(seed)
    sensors = make_network(rng)
    n = 50
    t = np.sort(rng.uniform(0, 100, n))
    A = rng.normal(0, [0.05, 0.05, 0.02], (n, 3, 3))      # a positive definite covariance per row
    cov = A @ A.transpose(0, 2, 1) + np.diag([1e-4, 1e-4, 1e-5])
    robot = pd.DataFrame({"t": t, "x": rng.normal(size=n), "y": rng.normal(size=n),
                          "yaw": rng.uniform(-np.pi, np.pi, n), "cov_xx": cov[:, 0, 0],
                          "cov_xy": cov[:, 0, 1], "cov_xyaw": cov[:, 0, 2],
                          "cov_yy": cov[:, 1, 1], "cov_yyaw": cov[:, 1, 2],
                          "cov_yawyaw": cov[:, 2, 2]})
    m = 120
    sensor = rng.choice(sensors.ids, m)
    track = rng.choice(["7", "12", "walker-3"], m)
    obs = pd.DataFrame({"t": np.sort(rng.uniform(0, 100, m)), "sensor": sensor, "track": track,
                        "x": rng.normal(size=m), "y": rng.normal(size=m), "z": 1.35 + rng.normal(0, .01, m)})
    # File order is not time order across tracks: shuffle whole tracks, keeping order within each.
    order = np.concatenate([g.index.to_numpy() for _, g in obs.groupby(["sensor", "track"])])
    obs = obs.loc[order].reset_index(drop=True).astype({"sensor": str, "track": str})
    odometry = pd.DataFrame({"t": t + 0.01, "x": np.cumsum(rng.normal(size=n)),
                             "y": np.cumsum(rng.normal(size=n)), "yaw": rng.normal(size=n)})
    truth_robot = robot[["t", "x", "y", "yaw"]] + 1e-3
    truth_obs = pd.DataFrame({"row": np.arange(m, dtype=np.int64),
                              "who": rng.choice(["robot", "17", "false"], m)}).astype({"who": str})
    truth = make_network(rng)
    return Log(sensors=sensors, robot=robot, observations=obs, odometry=odometry,
               meta=Meta(np.array([0.01, -0.02, 1.351]), {"robot": "sim", "seed": seed, "area_m": [20.0, 10.0]}),
               truth=truth,
               truth_robot=truth_robot, truth_observations=truth_obs)


def assert_networks_equal(a: SensorNetwork, b: SensorNetwork):
    assert a.ids == b.ids and a.frame == b.frame and a.extra == b.extra
    for sa, sb in zip(a, b, strict=True):
        np.testing.assert_array_equal(sa.position_m, sb.position_m)
        np.testing.assert_array_equal(sa.ypr_deg, sb.ypr_deg)
        for f in ("sigma_position_m", "sigma_ypr_deg"):
            va, vb = getattr(sa, f), getattr(sb, f)
            assert (va is None) == (vb is None)
            if va is not None:
                np.testing.assert_array_equal(va, vb)
        assert (sa.observations, sa.status, sa.unobservable) == (sb.observations, sb.status, sb.unobservable)


def assert_tables_equal(a: pd.DataFrame, b: pd.DataFrame):
    assert list(a.columns) == list(b.columns) and len(a) == len(b)
    for c in a.columns:
        if a[c].dtype.kind == "f":
            np.testing.assert_array_equal(a[c].to_numpy(), b[c].to_numpy())   # exact, bit for bit
        else:
            assert a[c].astype(str).tolist() == b[c].astype(str).tolist()


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_log_round_trip_is_exact(tmp_path, fmt):
    log = make_log(1)
    written = write_log(log, tmp_path / "log", fmt=fmt)
    assert written["robot"].suffix == f".{fmt}"
    back = read_log(tmp_path / "log")
    assert_networks_equal(log.sensors, back.sensors)
    assert_networks_equal(log.truth, back.truth)
    for name in ("robot", "observations", "odometry", "truth_robot", "truth_observations"):
        assert_tables_equal(getattr(log, name), getattr(back, name))
    np.testing.assert_array_equal(back.meta.head_offset_m, log.meta.head_offset_m)
    assert back.meta.notes == log.meta.notes
    assert back.truth_observations["row"].dtype == np.int64
    assert back.observations["sensor"].map(type).eq(str).all()


def test_numpy_values_in_notes_are_written_as_plain_yaml(tmp_path):
    log = make_log(8)
    log.meta.notes = {"seed": np.int64(8), "area_m": np.array([20.0, 10.0]), "rate": np.float64(0.5)}
    write_log(log, tmp_path)
    assert "area_m: [20.0, 10.0]" in (tmp_path / "meta.yaml").read_text()
    assert read_log(tmp_path).meta.notes == {"seed": 8, "area_m": [20.0, 10.0], "rate": 0.5}


def test_rewrite_in_other_format_removes_stale_tables(tmp_path):
    log = make_log(2)
    write_log(log, tmp_path, fmt="csv")
    log.odometry = None
    write_log(log, tmp_path, fmt="parquet")
    assert not list(tmp_path.glob("*.csv"))
    back = read_log(tmp_path)
    assert back.odometry is None
    assert_tables_equal(log.robot, back.robot)


def test_numeric_sensor_ids_match_between_yaml_and_csv(tmp_path):
    (tmp_path / "sensors.yaml").write_text(
        "sensors:\n  - {id: 1, position: [0, 0, 2.6], ypr_deg: [0, 45, 0]}\n"
        "  - {id: 02, position: [1, 0, 2.6], ypr_deg: [0, 45, 0]}\n")
    (tmp_path / "robot.csv").write_text("t,x,y,yaw,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw\n"
                                        "1,0,0,0,1,0,0,1,0,1\n0.5,0,0,0,1,0,0,1,0,1\n")
    # Columns in another order, an extra column, rows not sorted across tracks.
    (tmp_path / "observations.csv").write_text("sensor,track,t,x,y,z,extra\n02,5,2.0,1,1,1,a\n"
                                               "1,5,1.0,1,1,1,b\n02,5,3.0,1,1,1,c\n")
    log = read_log(tmp_path)
    assert log.sensors.ids == ["1", "02"]
    assert log.observations["sensor"].tolist() == ["02", "1", "02"]
    assert list(log.observations.columns) == ["t", "sensor", "track", "x", "y", "z"]
    assert log.robot["t"].tolist() == [0.5, 1.0]          # pose tables come back sorted by time
    assert log.meta.head_offset_m.tolist() == [0.0, 0.0, 1.35]
    assert log.odometry is None and log.truth is None


def test_calibrated_yaml_schema_round_trip_and_usable_as_sensors_yaml(tmp_path):
    rng = np.random.default_rng(3)
    net = make_network(rng)
    net.sensors[0].sigma_position_m = np.array([0.004, 0.005, 0.003])
    net.sensors[0].sigma_ypr_deg = np.array([0.2, 0.1, 0.1])
    net.sensors[0].observations, net.sensors[0].status = 812, "ok"
    net.sensors[1].sigma_position_m = np.array([0.1, 2.0, 0.003])
    net.sensors[1].sigma_ypr_deg = np.array([5.0, 0.1, 0.1])
    net.sensors[1].observations, net.sensors[1].status = 40, "degenerate"
    net.sensors[1].unobservable = ["y", "yaw"]
    net.sensors[2].observations, net.sensors[2].status = 0, "no-data"
    net.extra["method"] = "factorgraph"
    p = write_sensors_yaml(net, tmp_path / "calibrated.yaml")
    text = p.read_text()
    assert "position: [" in text and "unobservable: [y, yaw]" in text     # flow-style vectors
    assert_networks_equal(net, read_sensors_yaml(p))
    # Usable as the sensors.yaml of a log.
    log = make_log(3)
    log.sensors = read_sensors_yaml(p)
    log.observations["sensor"] = log.observations["sensor"].map(dict(zip(make_network(
        np.random.default_rng(1)).ids, net.ids, strict=True)))
    write_log(log, tmp_path / "log")
    assert read_log(tmp_path / "log").sensors.ids == net.ids


def test_people_csv_round_trip(tmp_path):
    rng = np.random.default_rng(4)
    df = pd.DataFrame({"t": rng.uniform(0, 10, 30), "person": rng.choice(["1", "b"], 30),
                       "x": rng.normal(size=30), "y": rng.normal(size=30)})
    write_people_csv(df, tmp_path / "p.csv")
    assert_tables_equal(df, read_people_csv(tmp_path / "p.csv"))


def test_people_csv_bad_cell_names_row_and_line(tmp_path):
    df = pd.DataFrame({"t": np.arange(6.0), "person": ["1"] * 6, "x": np.zeros(6), "y": np.zeros(6)})
    write_people_csv(df, tmp_path / "p.csv")
    edit_csv(tmp_path / "p.csv", set_cell(3, "x", "abc"))
    with pytest.raises(PedcalInputError, match=r"p\.csv, row 3 \(line 5\), column 'x': expected a number, got 'abc'"):
        read_people_csv(tmp_path / "p.csv")


@pytest.mark.parametrize("what,match", [("missing", "people CSV file not found"),
                                        ("folder", "is a directory, expected a people CSV file")])
def test_people_csv_path_that_is_no_regular_file_is_named_for_what_it_is(tmp_path, what, match):
    assert_refused_for_what_it_is(read_people_csv, tmp_path / "p.csv", what, match)


# ------------------------------------------------------------------------------------ bad input
def write_good(tmp_path: Path) -> Path:
    log = make_log(5)
    write_log(log, tmp_path, fmt="csv")
    return tmp_path


def edit_csv(path: Path, fn):
    df = pd.read_csv(path, dtype=str, keep_default_na=False)
    df = fn(df)
    df.to_csv(path, index=False)


def expect_error(tmp_path, match, row=None, column=None, file=None):
    with pytest.raises(PedcalInputError, match=match) as ei:
        read_log(tmp_path)
    e = ei.value
    if file is not None:
        assert e.path is not None and Path(e.path).name == file
    if row is not None:         # a CSV written by write_log: one header line, no blank lines
        line = row + 2 if e.path.endswith(".csv") else None
        assert e.row == row and e.line == line
        assert f"row {row}, " in str(e) if line is None else f"row {row} (line {line}), " in str(e)
    if column is not None:
        assert e.column == column and f"'{column}'" in str(e)
    return e


def set_cell(row, column, value):
    def fn(df):
        df.loc[row, column] = value
        return df
    return fn


def test_missing_required_column(tmp_path):
    write_good(tmp_path)
    edit_csv(tmp_path / "robot.csv", lambda df: df.drop(columns=["cov_yy"]))
    expect_error(tmp_path, "missing required column", column="cov_yy", file="robot.csv")


@pytest.mark.parametrize("value,match", [("abc", "expected a number, got 'abc'"), ("", "empty cell"),
                                         ("nan", "finite"), ("inf", "finite")])
def test_bad_cell(tmp_path, value, match):
    write_good(tmp_path)
    edit_csv(tmp_path / "observations.csv", set_cell(17, "x", value))
    expect_error(tmp_path, match, row=17, column="x", file="observations.csv")


def test_row_line_counts_blank_lines_and_quoted_line_breaks(tmp_path):
    """A data row's line as pandas read it: blank (or blank-looking) lines skipped, a quoted cell
    spanning two lines; the row keeps its 0-based data-row number."""
    write_good(tmp_path)
    p = tmp_path / "observations.csv"
    lines = p.read_text().splitlines()
    t, sensor, _, *rest = lines[2].split(",")
    lines[2] = ",".join([t, sensor, '"walker\nnine"', *rest])            # data row 1 over lines 3-4
    bad = lines[6].split(",")
    bad[3] = "north"                                                     # data row 5, x
    lines[6] = ",".join(bad)
    p.write_text("\n".join(["", lines[0], "  ", *lines[1:3], "", *lines[3:]]) + "\n")
    #  line 1 blank, 2 header, 3 blank, 4 row 0, 5-6 row 1, 7 blank, 8.. rows 2.. : row 5 on line 11
    e = expect_error(tmp_path, "expected a number, got 'north'", column="x", file="observations.csv")
    assert e.row == 5 and e.line == 11 and "row 5 (line 11), column 'x'" in str(e)


def test_row_line_of_a_table_from_dataframes_or_parquet_is_not_given(tmp_path):
    log = make_log(5)
    log.observations.loc[4, "x"] = np.nan
    with pytest.raises(PedcalInputError, match=r"^Log\.observations, row 4, column 'x': ") as ei:
        validate(log)
    assert ei.value.line is None


def test_bad_cell_in_parquet(tmp_path):
    log = make_log(6)
    write_log(log, tmp_path, fmt="parquet")     # write_log refuses NaN: the damaged table is written by hand
    robot = pd.read_parquet(tmp_path / "robot.parquet")
    robot.loc[3, "y"] = np.nan
    robot.to_parquet(tmp_path / "robot.parquet", index=False)
    expect_error(tmp_path, "finite", row=3, column="y", file="robot.parquet")


def test_empty_track_id(tmp_path):
    write_good(tmp_path)
    edit_csv(tmp_path / "observations.csv", set_cell(4, "track", ""))
    expect_error(tmp_path, "empty cell", row=4, column="track")


def test_unknown_sensor(tmp_path):
    write_good(tmp_path)
    edit_csv(tmp_path / "observations.csv", set_cell(9, "sensor", "s99"))
    e = expect_error(tmp_path, "unknown sensor id 's99'", row=9, column="sensor", file="observations.csv")
    assert "sensors.yaml" in str(e)


def test_duplicate_sensor_id_in_yaml(tmp_path):
    write_good(tmp_path)
    text = (tmp_path / "sensors.yaml").read_text().replace("id: s02", "id: s01")
    (tmp_path / "sensors.yaml").write_text(text)
    expect_error(tmp_path, "duplicate sensor id", file="sensors.yaml")


@pytest.mark.parametrize("name", ["robot.csv", "observations.csv"])
def test_empty_required_table(tmp_path, name):
    write_good(tmp_path)
    edit_csv(tmp_path / name, lambda df: df.iloc[:0])
    expect_error(tmp_path, "no data rows", file=name)


@pytest.mark.parametrize("name", ["robot.csv", "observations.csv", "odometry.csv", "truth_observations.csv"])
@pytest.mark.parametrize("content", ["", "\n\n  \n"])
def test_completely_empty_file(tmp_path, name, content):
    write_good(tmp_path)
    (tmp_path / name).write_text(content)
    columns = pd.read_csv(write_good(tmp_path / "good") / name, nrows=0).columns
    e = expect_error(tmp_path, "empty file, expected a CSV with header ", file=name)
    assert str(e).endswith(f"header {','.join(columns)}") and e.row is None and e.column is None


def test_empty_parquet_file(tmp_path):
    write_log(make_log(5), tmp_path, fmt="parquet")
    (tmp_path / "robot.parquet").write_bytes(b"")
    expect_error(tmp_path, "empty file, expected a Parquet table with columns t, x, y, yaw, cov_xx",
                 file="robot.parquet")


@pytest.mark.parametrize("repeat", ["x", " x"])
def test_column_named_twice_in_csv_header(tmp_path, repeat):
    """pandas renames a CSV header's repeated x to x.1: the file was read with the first x."""
    write_good(tmp_path)
    p = tmp_path / "observations.csv"
    lines = p.read_text().splitlines()
    p.write_text("\n".join([lines[0] + "," + repeat] + [line + ",99" for line in lines[1:]]) + "\n")
    e = expect_error(tmp_path, "column 'x' appears 2 times in the header; keep one", column="x",
                     file="observations.csv")
    assert e.row is None


def test_extra_column_named_twice_is_ignored(tmp_path):
    write_good(tmp_path)
    p = tmp_path / "robot.csv"
    lines = p.read_text().splitlines()
    p.write_text("\n".join([lines[0] + ",note,note"] + [line + ",a,b" for line in lines[1:]]) + "\n")
    assert len(read_log(tmp_path).robot) == 50


@pytest.mark.parametrize("line", [2, 50, 121])
def test_not_utf8_names_the_line_and_file_offset(tmp_path, line):
    """A cp1252 'é' (0xe9) on a line of observations.csv: the line and the byte's offset in the file
    (pandas' own error gives the offset within its buffer)."""
    write_good(tmp_path)
    p = tmp_path / "observations.csv"
    data = p.read_bytes()
    starts = [0] + [i + 1 for i, b in enumerate(data) if b == ord("\n")]
    offset = starts[line - 1] + 3             # within the time stamp
    p.write_bytes(data[:offset] + b"\xe9" + data[offset + 1:])
    expect_error(tmp_path, rf"not UTF-8 text \(byte 0xe9 on line {line}, at offset {offset}\)",
                 file="observations.csv")


MULTIBYTE = "t,note\n1.0,café\n2.0,€ 5\n\n3.0,😀 ok\n".encode() * 3     # 2, 3 and 4 bytes a character


@pytest.mark.parametrize("chunk_bytes", [1, 2, 3, 4, 5, 7, 1 << 20])
def test_not_utf8_text_reads_a_character_cut_between_chunks(tmp_path, chunk_bytes):
    """A character cut at a chunk's end is carried into the next chunk: UTF-8 text is UTF-8 at any
    chunk size (3 bytes cut every one of é, € and 😀 somewhere)."""
    from pedcal.io.inputs import not_utf8_text

    p = tmp_path / "t.csv"
    p.write_bytes(MULTIBYTE)
    assert not_utf8_text(p, chunk_bytes=chunk_bytes) is None


@pytest.mark.parametrize("bad", [b"\xe9", b"\xf0\x9f", b"\xff"])
@pytest.mark.parametrize("at", ["inside", "end"])
def test_not_utf8_text_locates_a_bad_byte_at_any_chunk_size(tmp_path, bad, at):
    """A bad byte after multi-byte characters (or a character cut by the file's end) is named at
    the same line and offset whatever the chunk size: the offset in the file, lines counted."""
    from pedcal.io.inputs import not_utf8_text

    offset = MULTIBYTE.index("😀".encode(), 40) + 4 if at == "inside" else len(MULTIBYTE)
    data = MULTIBYTE[:offset] + bad + (MULTIBYTE[offset:] if at == "inside" else b"")
    line = data[:offset].count(b"\n") + 1
    p = tmp_path / "t.csv"
    p.write_bytes(data)
    expected = f"byte 0x{bad[0]:02x} on line {line}, at offset {offset}"
    assert not_utf8_text(p) == expected
    assert [not_utf8_text(p, chunk_bytes=n) for n in (1, 2, 3, 4, 5, 7)] == [expected] * 6


@pytest.mark.parametrize("reader", ["read_json", "read_text_file"])
@pytest.mark.parametrize("bom", [b"", b"\xef\xbb\xbf"])
def test_whole_file_readers_name_the_bad_byte_in_the_file_after_a_bom(tmp_path, reader, bom):
    """The JSON and YAML/TOML readers decode with utf-8-sig, whose error offset counts from after a
    BOM: the byte, its line and offset named are the file's (0xe9 on line 2, 8 bytes after the BOM), not the
    BOM's last byte 0xbf three bytes before."""
    from pedcal.io.inputs import read_json
    from pedcal.io.sensors_yaml import read_text_file

    p = tmp_path / "f.txt"
    body = b'{"a":\n "\xe9"}\n'
    p.write_bytes(bom + body)
    offset = len(bom) + body.index(b"\xe9")
    with pytest.raises(PedcalInputError, match=rf"^{p}: not UTF-8 text \(byte 0xe9 on line 2, at offset {offset}\): "):
        dict(read_json=read_json, read_text_file=read_text_file)[reader](p)


def test_not_utf8_error_falls_back_on_the_decoding_errors_byte(tmp_path):
    """A file that is UTF-8 again when located (rewritten meanwhile) is named by the decoding
    error's own byte, without a line; the reader's advice follows."""
    from pedcal.io.inputs import not_utf8_error

    p = tmp_path / "t.csv"
    p.write_bytes(MULTIBYTE)
    try:
        b"ab\xfecd".decode("utf-8")
    except UnicodeDecodeError as e:
        err = not_utf8_error(p, e, "a binary file")
    assert str(err) == f"{p}: not UTF-8 text (byte 0xfe): a binary file"


def test_repeated_time_within_a_track(tmp_path):
    write_good(tmp_path)
    obs = pd.read_csv(tmp_path / "observations.csv", dtype=str, keep_default_na=False)
    key = obs["sensor"] + "/" + obs["track"]
    rows = np.flatnonzero(key == key.iloc[0])
    bad = int(rows[2])
    edit_csv(tmp_path / "observations.csv", set_cell(bad, "t", obs.loc[rows[1], "t"]))   # repeats
    expect_error(tmp_path, f"repeats row {rows[1]}; a track has one position per instant", row=bad, column="t")


def test_rows_of_a_track_in_any_order(tmp_path):
    """LOG_FORMAT.md: rows need not be sorted by time, within a track too; file order is kept."""
    write_good(tmp_path)
    obs = pd.read_csv(tmp_path / "observations.csv", dtype=str, keep_default_na=False)
    shuffled = obs.iloc[np.random.default_rng(3).permutation(len(obs))].reset_index(drop=True)
    shuffled.to_csv(tmp_path / "observations.csv", index=False)
    (tmp_path / "truth_observations.csv").unlink()
    back = read_log(tmp_path).observations
    assert back["t"].tolist() == shuffled["t"].astype(float).tolist()


def test_clock_may_go_back_across_tracks(tmp_path):
    write_good(tmp_path)   # make_log interleaves tracks so t goes back between them
    obs = pd.read_csv(tmp_path / "observations.csv")
    assert (np.diff(obs["t"]) < 0).any()
    assert len(read_log(tmp_path).observations) == len(obs)


def test_duplicate_robot_time(tmp_path):
    write_good(tmp_path)
    robot = pd.read_csv(tmp_path / "robot.csv", dtype=str)
    edit_csv(tmp_path / "robot.csv", set_cell(8, "t", robot.loc[2, "t"]))
    e = expect_error(tmp_path, "repeats row 2", row=8, column="t", file="robot.csv")
    assert e.row == 8


def test_negative_variance(tmp_path):
    write_good(tmp_path)
    edit_csv(tmp_path / "robot.csv", set_cell(5, "cov_yawyaw", "-0.01"))
    expect_error(tmp_path, "negative variance", row=5, column="cov_yawyaw")


SENSOR_TEXT = "sensors:\n- id: a\n  position: [0, 0, 2.6]\n  ypr_deg: [0, 45, 0]\n"


@pytest.mark.parametrize("text,match", [
    ("frame: map\n", "'sensors' list"),
    ("sensors:\n  - {id: a, ypr_deg: [0, 45, 0]}\n", "missing 'position'"),
    ("sensors:\n  - {id: a, position: [0, 0, 2.6]}\n", "missing 'ypr_deg'"),
    ("sensors:\n  - {id: a, position: [0, 2.6], ypr_deg: [0, 45, 0]}\n", "position: expected a list of 3"),
    ("sensors:\n  - {id: a, position: [0, 0, 2.6], ypr_deg: [0, x, 0]}\n", "ypr_deg: expected a list of 3"),
    ("sensors:\n  - {id: a, position: [0, 0, 2.6], ypr_deg: [0, 45, 0], status: fine}\n", "status"),
    ("sensors: [\n", "not valid YAML"),
    # a key given twice: PyYAML kept the last one silently
    (SENSOR_TEXT + "  position: [1, 0, 2.6]\n", r"key 'position' appears twice in one mapping \(line 3 and line 5\)"),
    ("frame: map\n" + SENSOR_TEXT + "frame: odom\n", r"key 'frame' appears twice in one mapping \(line 1 and line 6\)"),
    (SENSOR_TEXT.replace("  ypr_deg", "  sigma: {position_m: [0, 0, 0], position_m: [1, 1, 1]}\n  ypr_deg"),
     r"key 'position_m' appears twice in one mapping \(line 4, columns 11 and 34\)"),
])
def test_bad_sensors_yaml(tmp_path, text, match):
    p = tmp_path / "sensors.yaml"
    p.write_text(text)
    with pytest.raises(PedcalInputError, match=match) as ei:
        read_sensors_yaml(p)
    assert ei.value.path == str(p)


def test_yaml_error_names_line(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("sensors:\n  - {id: a, position: [0, 0, 2.6], ypr_deg: [0, 45, 0]}\n"
                 "  - {id: b, position: [0, 0], ypr_deg: [0, 45, 0]}\n")
    with pytest.raises(PedcalInputError, match=r"sensor 'b' \(line 3\) position"):
        read_sensors_yaml(p)


def test_truth_observation_rows_out_of_range(tmp_path):
    write_good(tmp_path)
    n = len(pd.read_csv(tmp_path / "observations.csv"))
    edit_csv(tmp_path / "truth_observations.csv", set_cell(6, "row", str(n)))
    expect_error(tmp_path, "out of range", row=6, column="row", file="truth_observations.csv")


def test_missing_directory_and_files(tmp_path):
    with pytest.raises(PedcalInputError, match="not found"):
        read_log(tmp_path / "nope")
    write_good(tmp_path)
    (tmp_path / "observations.csv").unlink()
    expect_error(tmp_path, "required file missing", file="observations.csv")
    (tmp_path / "sensors.yaml").unlink()
    expect_error(tmp_path, "required file missing", file="sensors.yaml")


def test_csv_and_parquet_of_one_table(tmp_path):
    write_good(tmp_path)
    pd.read_csv(tmp_path / "robot.csv").to_parquet(tmp_path / "robot.parquet")
    expect_error(tmp_path, "both robot.csv and robot.parquet")


def test_bad_meta(tmp_path):
    write_good(tmp_path)
    (tmp_path / "meta.yaml").write_text(yaml.safe_dump({"head_offset": [0, 1.35]}))
    expect_error(tmp_path, "head_offset", file="meta.yaml")


@pytest.mark.parametrize("key", ["head_ofset", "headoffset", "Head_Offset", "head_offset_m"])
def test_misspelled_meta_key_warns(tmp_path, key):
    """A misspelled head_offset would silently leave the default offset: kept as a note (the format
    accepts any key), with a warning naming the file, the key and the key it resembles."""
    write_good(tmp_path)
    (tmp_path / "meta.yaml").write_text(f"{key}: [0, 0, 1.2]\nseed: 3\n")
    with pytest.warns(UserWarning, match=rf"meta\.yaml: key '{key}' is not one meta\.yaml defines and is kept as "
                      r"a note: did you mean 'head_offset'\? \(the head offset used is \[0, 0, 1\.35\] m\)") as rec:
        log = read_log(tmp_path)
    assert len(rec) == 1 and str(tmp_path / "meta.yaml") in str(rec[0].message)
    assert log.meta.notes == {key: [0, 0, 1.2], "seed": 3} and log.meta.head_offset_m.tolist() == [0, 0, 1.35]


@pytest.mark.parametrize("head_offset", ["head_offset: [0, 0, 1.2]\n", ""])
def test_meta_notes_unlike_a_key_do_not_warn(tmp_path, recwarn, head_offset):
    write_good(tmp_path)
    (tmp_path / "meta.yaml").write_text(f"{head_offset}robot: sim\nseed: 3\nheading: north\n"
                                        "simulated: {scenario: paper}\ncamera_offset: [0, 0, 0.1]\n")
    assert read_log(tmp_path).meta.head_offset_m.tolist() == [0, 0, 1.2 if head_offset else 1.35]
    assert not [w for w in recwarn if "meta.yaml" in str(w.message)]


def test_meta_note_like_head_offset_beside_head_offset_does_not_warn(tmp_path, recwarn):
    """With head_offset given, a note named like it (head_offset_source, head_offset_m) is no
    misspelling: the offset is read, nothing is left at its default."""
    write_good(tmp_path)
    (tmp_path / "meta.yaml").write_text("head_offset: [0, 0, 1.2]\nhead_offset_source: tape measure\n"
                                        "head_offset_m: [0, 0, 1.2]\n")
    log = read_log(tmp_path)
    assert log.meta.head_offset_m.tolist() == [0, 0, 1.2]
    assert log.meta.notes == {"head_offset_source": "tape measure", "head_offset_m": [0, 0, 1.2]}
    assert not [w for w in recwarn if "meta.yaml" in str(w.message)]


def test_failed_write_leaves_previous_file(tmp_path):
    log = make_log(7)
    write_log(log, tmp_path)
    before = (tmp_path / "robot.csv").read_bytes()
    log.robot = log.robot.drop(columns=["cov_xx"])
    with pytest.raises(ValueError, match="cov_xx"):
        write_log(log, tmp_path)
    assert (tmp_path / "robot.csv").read_bytes() == before
    assert not list(tmp_path.glob(".*.tmp"))
