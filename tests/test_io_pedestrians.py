"""Recorded pedestrian datasets read into t, person, x, y: row and person counts, and walking
speeds that catch unit errors (a median outside 0.5-2 m/s means wrong time or length units)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pedcal.errors import PedcalInputError
from pedcal.io import write_people_csv
from pedcal.io.pedestrians import detect_kind, read_atc, read_eth_ucy, read_pedestrians, read_thor
from pedcal.model import PEOPLE_COLUMNS
from tests.conftest import assert_refused_for_what_it_is

# file -> (kind, rows, people)
REAL_FILES = {
    "atc/atc-1024-10_test.csv": ("atc", 4914, 132),
    "atc/atc-1024-9_test.csv": ("atc", 2504, 57),
    "eth_ucy/biwi_eth.txt": ("eth_ucy", 5492, 360),
    "eth_ucy/biwi_hotel.txt": ("eth_ucy", 6543, 389),
    "eth_ucy/crowds_zara01.txt": ("eth_ucy", 5153, 148),
    "thor/exp-1-run-2.csv": ("thor", 2180, 87),
}
READERS = {"atc": read_atc, "eth_ucy": read_eth_ucy, "thor": read_thor}


def median_speed_mps(people: pd.DataFrame) -> float:
    df = people.sort_values(["person", "t"], kind="stable")
    g = df.groupby("person", sort=False)
    v = np.hypot(g["x"].diff(), g["y"].diff()) / g["t"].diff()
    return float(np.nanmedian(v.to_numpy()))


@pytest.mark.parametrize("name", sorted(REAL_FILES))
def test_real_recordings(shared_data, name):
    kind, rows, people_n = REAL_FILES[name]
    path = shared_data / name
    assert detect_kind(path) == kind
    people = read_pedestrians(path)
    assert list(people.columns) == list(PEOPLE_COLUMNS)
    assert len(people) == rows and people["person"].nunique() == people_n
    assert people["person"].map(type).eq(str).all()
    assert np.isfinite(people[["t", "x", "y"]].to_numpy()).all()
    assert 0.5 <= median_speed_mps(people) <= 2.0
    pd.testing.assert_frame_equal(people, READERS[kind](path))


def test_eth_ucy_time_from_frames(shared_data):
    hotel = read_eth_ucy(shared_data / "eth_ucy" / "biwi_hotel.txt")
    assert hotel["t"].iloc[0] == 0.0 and hotel["person"].iloc[0] == "1"
    steps = hotel.sort_values(["person", "t"]).groupby("person")["t"].diff().dropna()
    assert steps.min() == pytest.approx(0.4)                 # 2.5 fps
    eth = read_eth_ucy(shared_data / "eth_ucy" / "biwi_eth.txt")
    assert eth["t"].iloc[0] == pytest.approx(780 / 15)       # interpolated frame numbers, see module
    assert median_speed_mps(read_eth_ucy(shared_data / "eth_ucy" / "biwi_eth.txt", frames_per_s=25)) > 2.0


def test_atc_millimetres_converted(tmp_path, shared_data):
    raw = pd.read_csv(shared_data / "atc" / "atc-1024-9_test.csv", header=None)
    raw[[2, 3]] *= 1000.0
    raw.to_csv(tmp_path / "atc_mm.csv", header=False, index=False)
    in_m = read_atc(shared_data / "atc" / "atc-1024-9_test.csv")
    from_mm = read_atc(tmp_path / "atc_mm.csv")
    np.testing.assert_allclose(from_mm[["x", "y"]], in_m[["x", "y"]], rtol=1e-12)


def test_people_csv_kind_and_cli_round_trip(tmp_path, shared_data):
    people = read_thor(shared_data / "thor" / "exp-1-run-2.csv")
    write_people_csv(people, tmp_path / "p.csv")
    assert detect_kind(tmp_path / "p.csv") == "people"
    pd.testing.assert_frame_equal(read_pedestrians(tmp_path / "p.csv"), people, check_dtype=False)
    header = tmp_path / "thor_header.csv"
    header.write_text("time,person_id,x,y,velocity,motion_angle\n"
                      + (shared_data / "thor" / "exp-1-run-2.csv").read_text())
    assert detect_kind(header) == "thor"
    pd.testing.assert_frame_equal(read_pedestrians(header), people)


@pytest.mark.parametrize("content,kind,match,row,column", [
    ("1351040437.965,10003800,-25.397,abc,2.007,0.45\n", "atc", "'abc'", 0, "y"),
    ("780\t1.0\t8.46\t3.59\n790\t1.0\t\t3.79\n", "eth_ucy", None, None, None),
    ("0.02,12001,-0.046,-3.443,0.141,2.356\n0.43,,-0.077,-3.491,0.1,-1.571\n", "thor", "empty", 1, "person_id"),
    ("", "auto", "empty file", None, None),
    ("hello,world\n", "auto", "unrecognised header", None, None),
    ("1,2,3\n", "auto", "cannot tell the layout", None, None),
])
def test_bad_pedestrian_files(tmp_path, content, kind, match, row, column):
    p = tmp_path / "bad.txt"
    p.write_text(content)
    with pytest.raises(PedcalInputError, match=match) as ei:
        read_pedestrians(p, kind=kind)
    assert ei.value.path == str(p)
    if row is not None:
        assert (ei.value.row, ei.value.column) == (row, column)


@pytest.mark.parametrize("kind", ["auto", "atc"])
@pytest.mark.parametrize("what,match", [("missing", "pedestrian file not found"),
                                        ("folder", "is a directory, expected a pedestrian file"),
                                        ("fifo", "is a FIFO .*expected a regular pedestrian file")])
def test_a_path_that_is_no_regular_file_is_named_for_what_it_is(tmp_path, what, match, kind):
    # (the layout's sniffing and the table's reading check the path alike: a FIFO is refused, not read)
    assert_refused_for_what_it_is(lambda p: read_pedestrians(p, kind=kind), tmp_path / "people.csv", what, match)


def test_import_people_fps_for_renamed_recordings(shared_data, tmp_path, capsys):
    """A renamed ETH/UCY file does not get a guessed rate: the command asks for --fps; with it,
    every real recording plays at walking speed."""
    from pedcal.cli import EXIT_BAD_INPUT, main

    for name in ("biwi_eth", "biwi_hotel", "crowds_zara01"):
        renamed = tmp_path / f"{name}_copy.txt"
        renamed.write_bytes((shared_data / "eth_ucy" / f"{name}.txt").read_bytes())
        code = main(["import-people", str(renamed), "-o", str(tmp_path / "p.csv")])
        err = capsys.readouterr().err
        assert code == EXIT_BAD_INPUT and renamed.name in err and "--fps" in err
        fps = 15.0 if name == "biwi_eth" else 25.0
        assert main(["import-people", str(renamed), "-o", str(tmp_path / f"{name}.csv"), "--fps", str(fps)]) == 0
        people = pd.read_csv(tmp_path / f"{name}.csv")
        original = read_eth_ucy(shared_data / "eth_ucy" / f"{name}.txt")
        np.testing.assert_allclose(people["t"], original["t"])
        assert 0.5 < median_speed_mps(people.astype({"person": str})) < 1.8       # people walk
    capsys.readouterr()
    code = main(["import-people", str(shared_data / "thor" / "exp-1-run-2.csv"),
                 "-o", str(tmp_path / "t.csv"), "--fps", "10"])
    assert code == EXIT_BAD_INPUT and "--fps applies to frame-numbered" in capsys.readouterr().err


THOR_HEADER = "time,person_id,x,y,velocity,motion_angle\n"


def thor_rows(n: int, seed: int = 0) -> str:
    rng = np.random.default_rng(seed)
    xy = np.cumsum(rng.normal(scale=0.3, size=(n, 2)), axis=0)
    return "".join(f"{0.4 * i:.2f},{12000 + i % 3},{x:.3f},{y:.3f},1.0,0.0\n" for i, (x, y) in enumerate(xy))


@pytest.mark.parametrize("header", ["time,person_id,x,x,y,motion_angle", 'time,person_id,x,y,"x",motion_angle'])
def test_a_column_named_twice_in_the_header_is_refused(tmp_path, header):
    """pandas renames a repeated name (x, x.1): the file would be read with whichever x came first.
    The header is read as pandas reads the table: a quoted "x" is the column x."""
    p = tmp_path / "thor.csv"
    p.write_text(header + "\n" + thor_rows(5))
    with pytest.raises(PedcalInputError, match="column 'x' appears 2 times in the header") as ei:
        read_pedestrians(p)
    assert (ei.value.path, ei.value.column) == (str(p), "x")


@pytest.mark.parametrize("kind,line", [("thor", 3), ("thor", 400), ("eth_ucy", 400)])
def test_a_byte_that_is_not_utf8_is_located_by_line_and_file_offset(tmp_path, kind, line):
    """Past the first 4 kB pandas' decoding error gave an offset within its buffer, not the file's."""
    if kind == "thor":
        lines = (THOR_HEADER + thor_rows(600)).encode().splitlines(keepends=True)
    else:
        lines = [f"{10 * i}\t{i % 4}.0\t{i * 0.1:.2f}\t1.5\n".encode() for i in range(600)]
    lines[line - 1] = lines[line - 1].replace(b",", b"\xe9,", 1).replace(b"\t", b"\xe9\t", 1)
    data = b"".join(lines)
    p = tmp_path / ("biwi_hotel.txt" if kind == "eth_ucy" else "thor.csv")
    p.write_bytes(data)
    offset = data.index(b"\xe9")
    with pytest.raises(PedcalInputError, match=rf"not UTF-8 text \(byte 0xe9 on line {line}, at offset {offset}\)"):
        read_pedestrians(p, kind=kind)


def test_a_person_placed_twice_at_one_time(tmp_path):
    """Two places at one time: refused naming both rows; a whole row repeated: dropped and counted."""
    rows = thor_rows(9).splitlines(keepends=True)
    p = tmp_path / "thor.csv"
    p.write_text(THOR_HEADER + "".join(rows) + rows[4] + rows[7])
    with pytest.warns(UserWarning, match=r"2 row\(s\) repeating an earlier row whole .* dropped \(the first: row 9\)"):
        people = read_pedestrians(p)
    assert len(people) == 9
    t, pid, x = rows[4].split(",")[:3]
    moved = rows[4].replace(f",{x},", f",{float(x) + 0.5:.3f},", 1)
    p.write_text(THOR_HEADER + "".join(rows) + moved)
    with pytest.raises(PedcalInputError, match=rf"person '{pid}' at t = {float(t)!r} s is placed twice, at "
                                               rf"\({float(x):g}, .*\) in row 4 and \({float(x) + 0.5:g}, ") as ei:
        read_pedestrians(p)
    assert (ei.value.row, ei.value.column) == (9, "t")
    with pytest.raises(PedcalInputError, match="placed twice"):
        write_people_csv(pd.concat([people, people.iloc[[2]].assign(y=7.0)]), tmp_path / "out.csv")


def test_a_people_table_written_as_parquet_reads_back(tmp_path, capsys):
    """import-people -o people.parquet wrote a file that import-people and follow --people then
    sniffed as text and refused as not UTF-8."""
    from pedcal.cli import main

    src = tmp_path / "thor.csv"
    src.write_text(THOR_HEADER + thor_rows(12, seed=4))
    pq = tmp_path / "people.parquet"
    assert main(["import-people", str(src), "-o", str(pq)]) == 0
    pd.testing.assert_frame_equal(read_pedestrians(pq), read_pedestrians(src))
    capsys.readouterr()
    assert main(["follow", "--people", str(pq)]) == 0
    assert f"{pq}: 3 people" in capsys.readouterr().out


def test_a_renamed_eth_file_given_to_follow_says_how_to_give_its_rate(tmp_path, capsys):
    """follow has no --fps: the message says how to give the rate (through import-people)."""
    from pedcal.cli import main

    p = tmp_path / "myrecording.txt"
    p.write_text("0\t1.0\t1.0\t2.0\n10\t1.0\t1.5\t2.0\n")
    assert main(["follow", "--people", str(p)]) == 2
    assert "give its frame rate with --fps (frames per second of the frame numbers): pedcal import-people FILE " \
           "--fps F -o people.csv, then follow --people people.csv" in capsys.readouterr().err


@pytest.mark.parametrize("bad,match", [
    ("4.0,b,1e7,0.0", r"row 3 \(line 6\), column 'x': .*"),                      # check_coordinates
    ("1e12,b,1.0,0.0", r"row 3 \(line 6\), column 't': .*"),                     # check_times
    ("1.0,a,9.0,0.0", r"row 3 \(line 6\), column 't': person 'a' at t = 1.0 s is placed twice")])
def test_every_people_csv_row_error_names_its_line(tmp_path, bad, match):
    """Cell errors named the row's line (row 3 (line 6), the blank line counted) while the checks
    of the typed table (times, coordinates, a person placed twice) named the row alone."""
    from pedcal.io import read_people_csv

    p = tmp_path / "people.csv"
    p.write_text(f"t,person,x,y\n0.0,a,0.0,0.0\n\n1.0,a,1.0,0.0\n2.0,a,2.0,0.0\n{bad}\n")
    with pytest.raises(PedcalInputError, match=rf"{p}, {match}") as ei:
        read_people_csv(p)
    assert (ei.value.row, ei.value.line) == (3, 6)
    q = tmp_path / "people.parquet"                     # a Parquet table has no lines
    pd.read_csv(p, dtype={"person": str}).to_parquet(q)
    with pytest.raises(PedcalInputError, match=rf"{q}, row 3, column") as ei:
        read_people_csv(q)
    assert ei.value.line is None


def test_a_parquet_people_table_named_in_capitals_is_read_and_written_as_parquet(tmp_path):
    """read_pedestrians sent people.PARQUET to the people reader, which compared the suffix case-
    sensitively and read the Parquet bytes as CSV (not UTF-8); the writer wrote CSV into it."""
    src = tmp_path / "thor.csv"
    src.write_text(THOR_HEADER + thor_rows(12, seed=4))
    people = read_pedestrians(src)
    q = tmp_path / "people.PARQUET"
    people.to_parquet(q)
    pd.testing.assert_frame_equal(read_pedestrians(q), people)
    w = tmp_path / "written.Parquet"
    write_people_csv(people, w)
    assert w.read_bytes()[:4] == b"PAR1"
    pd.testing.assert_frame_equal(pd.read_parquet(w), people)


BOM = "\ufeff"


@pytest.mark.parametrize("header,kind", [
    ("t,person,x,y\n", "people"), ('"t","person","x","y"\n', "people"),
    (THOR_HEADER, "thor"), ('"time","person_id","x","y","velocity","motion_angle"\n', "thor")])
@pytest.mark.parametrize("bom", ["", BOM])
def test_a_header_with_a_bom_or_quoted_names_is_recognised(tmp_path, header, kind, bom):
    """The layout was sniffed from the first line split at commas and read without the BOM removed:
    a BOM or quoted names (as spreadsheets write them) made the header unrecognised, though the
    people and THÖR readers read the same file."""
    rows = "0.0,a,1.0,2.0\n0.4,a,1.2,2.1\n" if kind == "people" else thor_rows(5, seed=2)
    p = tmp_path / "walk.csv"
    p.write_text(bom + header + rows, encoding="utf-8")
    assert detect_kind(p) == kind
    plain = tmp_path / "plain.csv"
    plain.write_text(header.replace('"', "") + rows)
    people = read_pedestrians(p)
    pd.testing.assert_frame_equal(people, read_pedestrians(plain, kind=kind))
    assert len(people) == rows.count("\n")


@pytest.mark.parametrize("name,content,kind", [
    ("biwi_hotel.txt", "780\t1.0\t8.46\t3.59\n790\t1.0\t8.50\t3.79\n", "eth_ucy"),
    ("thor.csv", "0.02,12001,-0.046,-3.443,0.141,2.356\n0.43,12001,-0.077,-3.491,0.1,-1.571\n", "thor"),
    ("atc.csv", "1351040437.965,10003800,-25.397,1.0,2.007,0.45\n1351040438.0,10003800,-25.3,1.1,2.0,0.4\n", "atc")])
def test_a_headerless_file_starting_with_a_bom_is_taken_as_headerless(tmp_path, name, content, kind):
    """The BOM is no character of the first line: it made a numeric first line look like a header."""
    p = tmp_path / name
    p.write_text(BOM + content, encoding="utf-8")
    assert detect_kind(p) == kind
    plain = tmp_path / ("plain_" + name)
    plain.write_text(content)
    people = read_pedestrians(p, fps=25.0 if kind == "eth_ucy" else None)
    pd.testing.assert_frame_equal(people, read_pedestrians(plain, kind=kind, fps=25.0 if kind == "eth_ucy" else None))
    assert len(people) == 2


def test_a_header_pandas_cannot_split_is_an_input_error(tmp_path):
    p = tmp_path / "walk.csv"
    p.write_text('"t,person,x,y\n0.0,a,1.0,2.0\n')
    with pytest.raises(PedcalInputError, match=r"cannot read the header '\"t,person,x,y': .*EOF inside string") as ei:
        read_pedestrians(p)
    assert ei.value.path == str(p)
