"""Fuzz suite: corrupted inputs built from a small simulated log (its YAMLs, tables, a calibrated
YAML, a people file) go through every command that reads them, in this process through
``pedcal.cli.main`` (a fresh interpreter per case would spend a second importing GTSAM).

For every case: the exit code is 0 (with a correct result where the case says what that is) or 2
with a message naming the file; never a traceback, never over the time limit (an interval timer)
or the memory limit (RLIMIT_AS above what the process already maps); every input file has the
checksum it had before; no temporary file is left behind. The named cases are the ones a new user
hit (nanosecond stamps, 1e300 coordinates, radians, cp1252 bytes, ``-o`` onto an input, ...);
Hypothesis adds cell and YAML corruptions (derandomized, so CI runs the same examples).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import resource
import shutil
import signal
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pedcal.cli import EXIT_BAD_INPUT, main

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis (dev extra) drives the generated cases")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

TIME_LIMIT_S = 30.0
MEMORY_HEADROOM_BYTES = 3 * 1024 ** 3
TALLY: Counter = Counter()


class CaseTimeout(BaseException):
    """Raised by the interval timer; a BaseException so no handler under test swallows it."""


# --------------------------------------------------------------------------------------- harness
def checksums(root: Path) -> dict[str, str]:
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            try:
                out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
            except PermissionError:    # an unreadable input of a case: its name stands for it
                out[str(p.relative_to(root))] = "unreadable"
    return out


def _mapped_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


@contextlib.contextmanager
def limits():
    """Time limit (SIGALRM interval timer) and memory limit (RLIMIT_AS) for one case."""
    def on_alarm(signum, frame):
        raise CaseTimeout()

    old_handler = signal.signal(signal.SIGALRM, on_alarm)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = _mapped_bytes() + MEMORY_HEADROOM_BYTES
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    signal.setitimer(signal.ITIMER_REAL, TIME_LIMIT_S)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
        signal.signal(signal.SIGALRM, old_handler)


def run_cli(argv: list[str], inputs: Path, names=()) -> tuple[int, str, str]:
    """Run one case; assert the contract; return (exit code, stdout, stderr)."""
    before = checksums(inputs)
    out, err = io.StringIO(), io.StringIO()
    TALLY["cases"] += 1
    try:
        with limits(), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in argv])
    except CaseTimeout:
        TALLY["hangs"] += 1
        pytest.fail(f"over {TIME_LIMIT_S} s: pedcal {' '.join(map(str, argv))}")
    except MemoryError:
        TALLY["memory"] += 1
        pytest.fail(f"memory blow-up: pedcal {' '.join(map(str, argv))}")
    except BaseException as e:          # a traceback the user would have seen
        TALLY["tracebacks"] += 1
        raise AssertionError(f"traceback from pedcal {' '.join(map(str, argv))}") from e
    err_text = err.getvalue()
    after = checksums(inputs)
    if after != before:
        TALLY["damaged"] += 1
        changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
        pytest.fail(f"inputs changed: {changed}")
    stray = [p for p in inputs.parent.rglob("*.tmp")]
    assert not stray, f"temporary files left: {stray}"
    assert "Traceback" not in err_text, err_text
    assert code in (0, EXIT_BAD_INPUT), (code, err_text)
    if code == EXIT_BAD_INPUT:
        TALLY["clean errors"] += 1
        # one error line; warnings the work gave before the error may stand above it
        lines = [ln for ln in err_text.strip().splitlines() if not ln.startswith("warning: ")]
        assert len(lines) == 1, err_text
        message = lines[0]
        assert message.startswith(f"pedcal {argv[0]}: error: "), err_text
        assert "np.float64" not in message and not re.search(r"[\x00-\x08\x0e-\x1f]", message), message
        assert len(message) < 2000, f"message too long ({len(message)} chars)"
        if names:
            assert any(n in message for n in names), f"message names none of {names}: {message}"
    else:
        TALLY["accepted"] += 1
    return code, out.getvalue(), err_text


# ---------------------------------------------------------------------------------------- inputs
def read_cells(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, dtype=str, keep_default_na=False)


def write_cells(df: pd.DataFrame, path: Path) -> None:
    df.to_csv(path, index=False)


def scale_time(path: Path, factor: float) -> None:
    df = pd.read_csv(path)
    df["t"] = df["t"] * factor
    df.to_csv(path, index=False)


def set_cell(path: Path, row, column: str, value: str) -> None:
    df = read_cells(path)
    df.loc[row if row is not None else slice(None), column] = value
    write_cells(df, path)


def yaml_edit(path: Path, fn) -> None:
    data = yaml.safe_load(path.read_text())
    fn(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A simulated sparse log (seed 0), its factor-graph calibration and a people file."""
    from pedcal.sim import simulate

    root = tmp_path_factory.mktemp("fuzz-base")
    simulate("sparse", root / "sim", seed=0, progress=False)
    log = root / "sim" / "calib"
    assert main(["calibrate", str(log), "-o", str(root / "calibrated.yaml"), "-q"]) == 0
    t = np.round(np.arange(0.0, 12.0, 0.4), 6)
    people = pd.concat([pd.DataFrame({"t": t, "person": str(p), "x": x0 + vx * t, "y": y0})
                        for p, (x0, y0, vx) in enumerate([(0.0, 0.0, 1.0), (6.0, 1.0, -1.0), (2.0, -2.0, 0.5)])])
    people.to_csv(root / "people.csv", index=False)
    yield root
    print(f"\nfuzz tally: {dict(TALLY)}")
    if os.environ.get("PEDCAL_FUZZ_TALLY"):
        Path(os.environ["PEDCAL_FUZZ_TALLY"]).write_text(f"{dict(TALLY)}\n")


@pytest.fixture
def case(base, tmp_path):
    """A fresh copy of the inputs: case/log, case/calibrated.yaml, case/people.csv; outputs go to out/."""
    inputs = tmp_path / "in"
    shutil.copytree(base / "sim" / "calib", inputs / "log")
    shutil.copy(base / "calibrated.yaml", inputs / "calibrated.yaml")
    shutil.copy(base / "people.csv", inputs / "people.csv")
    (tmp_path / "out").mkdir()
    return inputs


def positions(path: Path) -> dict[str, np.ndarray]:
    net = yaml.safe_load(path.read_text())["sensors"]
    return {str(s["id"]): np.r_[s["position"], s["ypr_deg"]] for s in net}


def assert_same_calibration(a: Path, b: Path, tol_m=0.005, tol_deg=0.2):
    pa, pb = positions(a), positions(b)
    assert pa.keys() == pb.keys()
    for k in pa:
        assert np.abs(pa[k][:3] - pb[k][:3]).max() < tol_m, (k, pa[k], pb[k])
        d = (pa[k][3:] - pb[k][3:] + 180.0) % 360.0 - 180.0
        assert np.abs(d).max() < tol_deg, (k, pa[k], pb[k])


# --------------------------------------------------------------------------- named cases (log)
def _ns_all(log):
    for name in ("robot", "observations", "odometry", "truth_robot"):
        scale_time(log / f"{name}.csv", 1e9)


def _cov_zero(log):
    for c in ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"):
        set_cell(log / "robot.csv", None, c, "0")


def _cov_not_pd(log):
    df = pd.read_csv(log / "robot.csv")
    df["cov_xy"] = 2.0 * np.sqrt(df["cov_xx"] * df["cov_yy"])
    df.to_csv(log / "robot.csv", index=False)


def _stretch_time(log):
    for name in ("robot", "observations", "odometry", "truth_robot"):
        scale_time(log / f"{name}.csv", 1000.0)


def _other_recording(log):
    df = pd.read_csv(log / "robot.csv")
    df["t"] += 1e6
    df.to_csv(log / "robot.csv", index=False)


def _cp1252(path):
    def fn(log):
        p = log / path
        p.write_bytes(p.read_bytes().replace(b"map", b"m\x92ap", 1) if b"map" in p.read_bytes()
                      else p.read_bytes() + b"# caf\xe9\n")
    return fn


def _radians(log):
    yaml_edit(log / "sensors.yaml", lambda d: [s.update(ypr_deg=[float(np.radians(a)) for a in s["ypr_deg"]])
                                               for s in d["sensors"]])


def _binary(name):
    def fn(log):
        (log / name).write_bytes(bytes(np.random.default_rng(0).integers(128, 256, 600, dtype=np.uint8)) + b"\x00\xff")
    return fn


def _dir_for(name):
    def fn(log):
        (log / name).unlink()
        (log / name).mkdir()
    return fn


def _parquet(log, truncate=False):
    for name in ("robot", "observations"):
        df = pd.read_csv(log / f"{name}.csv", dtype={"sensor": str, "track": str})
        df.to_parquet(log / f"{name}.parquet", index=False)
        (log / f"{name}.csv").unlink()
    if truncate:
        p = log / "robot.parquet"
        p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _crlf(log):
    for p in log.glob("*.csv"):
        p.write_bytes(p.read_bytes().replace(b"\n", b"\r\n"))


def _bom(log):
    for p in (log / "robot.csv", log / "sensors.yaml", log / "observations.csv"):
        p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())


def _reorder_and_extra(log):
    for p in log.glob("*.csv"):
        df = read_cells(p)
        df = df[df.columns[::-1]]
        df.insert(1, "comment", "x,y")
        df["extra"] = "7"
        write_cells(df, p)


def _shuffle_observations(log):
    """Rows out of time order (LOG_FORMAT.md allows it); truth_observations follows the rows."""
    obs = read_cells(log / "observations.csv")
    order = np.random.default_rng(1).permutation(len(obs))
    write_cells(obs.iloc[order], log / "observations.csv")
    truth = read_cells(log / "truth_observations.csv")
    new_row = np.empty(len(order), int)
    new_row[order] = np.arange(len(order))
    truth["row"] = new_row[truth["row"].astype(int).to_numpy()].astype(str)
    write_cells(truth, log / "truth_observations.csv")


def _reverse_robot(log):
    df = read_cells(log / "robot.csv")
    write_cells(df.iloc[::-1], log / "robot.csv")


def _spaces(log):
    p = log / "robot.csv"
    p.write_text(p.read_text().replace(",", ", "))


BAD_LOGS = {   # name: (edit of the log, file the message must name, extra calibrate arguments)
    "robot stamped in ns, observations in s": (lambda log: scale_time(log / "robot.csv", 1e9), "robot.csv", []),
    "every file stamped in ns": (_ns_all, "robot.csv", []),
    "observations stamped in ms": (lambda log: scale_time(log / "observations.csv", 1e3), "observations.csv", []),
    "robot from another recording": (_other_recording, "observations.csv", []),
    "robot t = 1e300": (lambda log: set_cell(log / "robot.csv", 40, "t", "1e300"), "robot.csv", []),
    "span of 4 days needs more memory": (_stretch_time, "robot.csv", []),
    "memory limit below need": (lambda log: None, "robot.csv", ["--max-memory-gb", "0.001"]),
    "robot x = 1e300": (lambda log: set_cell(log / "robot.csv", 10, "x", "1e300"), "robot.csv", []),
    "robot x = 1e300, gridsearch": (lambda log: set_cell(log / "robot.csv", 10, "x", "1e300"), "robot.csv",
                                    ["--method", "gridsearch"]),
    "robot in another frame (x + 9e5 m)": (lambda log: (lambda df: df.assign(x=df["x"] + 9e5).to_csv(
        log / "robot.csv", index=False))(pd.read_csv(log / "robot.csv")), "robot.csv", []),
    "robot x = -1e300, closedform": (lambda log: set_cell(log / "robot.csv", 3, "x", "-1e300"), "robot.csv",
                                     ["--method", "closedform"]),
    "all-zero covariance": (_cov_zero, "robot.csv", []),
    "covariance 1e300": (lambda log: set_cell(log / "robot.csv", None, "cov_xx", "1e300"), "robot.csv", []),
    "covariance not positive definite": (_cov_not_pd, "robot.csv", []),
    "negative variance": (lambda log: set_cell(log / "robot.csv", 5, "cov_yy", "-1e-3"), "robot.csv", []),
    "observation x = 1e300": (lambda log: set_cell(log / "observations.csv", 7, "x", "1e300"), "observations.csv",
                              []),
    "observation z = nan": (lambda log: set_cell(log / "observations.csv", 8, "z", "nan"), "observations.csv", []),
    "observation sensor unknown": (lambda log: set_cell(log / "observations.csv", 9, "sensor", "s99"),
                                   "observations.csv", []),
    "observation track empty": (lambda log: set_cell(log / "observations.csv", 9, "track", ""),
                                "observations.csv", []),
    "observation repeats an instant": (lambda log: set_cell(log / "observations.csv", 1, "t",
                                                            read_cells(log / "observations.csv")["t"][0]),
                                       "observations.csv", []),
    "robot time repeats": (lambda log: set_cell(log / "robot.csv", 6, "t", read_cells(log / "robot.csv")["t"][5]),
                           "robot.csv", []),
    "odometry yaw text": (lambda log: set_cell(log / "odometry.csv", 2, "yaw", "north"), "odometry.csv", []),
    "truth row out of range": (lambda log: set_cell(log / "truth_observations.csv", 0, "row", "999999"),
                               "truth_observations.csv", []),
    "sensor position 1e300": (lambda log: yaml_edit(log / "sensors.yaml",
                                                    lambda d: d["sensors"][0].update(position=[1e300, 0, 2.6])),
                              "sensors.yaml", []),
    "sensor angle 1e300": (lambda log: yaml_edit(log / "sensors.yaml",
                                                 lambda d: d["sensors"][1].update(ypr_deg=[0, 1e300, 0])),
                           "sensors.yaml", []),
    "sensors.yaml in radians": (_radians, "sensors.yaml", []),
    "sensors.yaml cp1252 byte": (_cp1252("sensors.yaml"), "sensors.yaml", []),
    "meta.yaml cp1252 byte": (_cp1252("meta.yaml"), "meta.yaml", []),
    "meta head_offset 1e300": (lambda log: yaml_edit(log / "meta.yaml", lambda d: d.update(head_offset=[0, 0, 1e300])),
                               "meta.yaml", []),
    "sensors.yaml syntax error": (lambda log: (log / "sensors.yaml").write_text("sensors: [\n  - {id: a\n"),
                                  "sensors.yaml", []),
    "sensors.yaml empty": (lambda log: (log / "sensors.yaml").write_text(""), "sensors.yaml", []),
    "sensors.yaml binary": (_binary("sensors.yaml"), "sensors.yaml", []),
    "robot.csv binary": (_binary("robot.csv"), "robot.csv", []),
    "observations.csv binary": (_binary("observations.csv"), "observations.csv", []),
    "robot.csv a directory": (_dir_for("robot.csv"), "robot.csv", []),
    "sensors.yaml a directory": (_dir_for("sensors.yaml"), "sensors.yaml", []),
    "meta.yaml a directory": (_dir_for("meta.yaml"), "meta.yaml", []),
    "robot.csv empty": (lambda log: (log / "robot.csv").write_text(""), "robot.csv", []),
    "robot.csv header only": (lambda log: write_cells(read_cells(log / "robot.csv").iloc[:0], log / "robot.csv"),
                              "robot.csv", []),
    "robot.csv missing column": (lambda log: write_cells(read_cells(log / "robot.csv").drop(columns="yaw"),
                                                         log / "robot.csv"), "robot.csv", []),
    "robot.csv ragged row": (lambda log: (log / "robot.csv").write_text((log / "robot.csv").read_text()
                                                                         + "1,2,3,4,5,6,7,8,9,10,11,12\n"),
                             "robot.csv", []),
    "robot csv and parquet": (lambda log: pd.read_csv(log / "robot.csv").to_parquet(log / "robot.parquet"),
                              "robot", []),
    "robot.parquet truncated": (lambda log: _parquet(log, truncate=True), "robot.parquet", []),
    "log directory missing": (lambda log: shutil.rmtree(log), "log", []),
}

# refused by the calibration's pre-flight (memory, frames); evaluate may read these logs
CALIBRATION_PREFLIGHT_ONLY = {"span of 4 days needs more memory", "memory limit below need",
                              "robot in another frame (x + 9e5 m)"}

GOOD_LOGS = {
    "CRLF line endings": _crlf,
    "byte order marks": _bom,
    "reordered and extra columns": _reorder_and_extra,
    "observations out of time order": _shuffle_observations,
    "robot rows reversed": _reverse_robot,
    "spaces after commas": _spaces,
    "Parquet tables": _parquet,
}


@pytest.mark.parametrize("name", list(BAD_LOGS))
def test_bad_log_is_a_clean_error(case, name):
    edit, names, extra = BAD_LOGS[name]
    log, out = case / "log", case.parent / "out" / "calibrated.yaml"
    edit(log)
    code, _, err = run_cli(["calibrate", log, "-o", out, "-q", *extra], case, names=(names,))
    assert code == EXIT_BAD_INPUT, err
    assert not out.exists()
    if (case / "log").is_dir():
        code, _, err = run_cli(["evaluate", log, "--extrinsics", case / "calibrated.yaml"], case, names=(names,))
        assert code == EXIT_BAD_INPUT or name in CALIBRATION_PREFLIGHT_ONLY, err
        if name not in CALIBRATION_PREFLIGHT_ONLY:
            code, _, err = run_cli(["report", log, "--extrinsics", case / "calibrated.yaml", "--out",
                                    case.parent / "out" / "report", "-q"], case, names=(names,))
            assert code == EXIT_BAD_INPUT, err


@pytest.mark.parametrize("name", list(GOOD_LOGS))
def test_harmless_variants_give_the_same_calibration(base, case, name):
    GOOD_LOGS[name](case / "log")
    out = case.parent / "out" / "calibrated.yaml"
    code, _, err = run_cli(["calibrate", case / "log", "-o", out, "-q"], case)
    assert code == 0, err
    assert_same_calibration(out, base / "calibrated.yaml")
    code, stdout, err = run_cli(["evaluate", case / "log", "--extrinsics", out, "--json"], case)
    assert code == 0, err


def test_message_details(case):
    """Units and figures in the plausibility messages; PyYAML's text on one line."""
    log, out = case / "log", case.parent / "out" / "o.yaml"
    scale_time(log / "robot.csv", 1e9)
    _, _, err = run_cli(["calibrate", log, "-o", out], case)
    assert "column 't'" in err and "nanoseconds" in err and " s " in err


# ------------------------------------------------------------------------ named cases (outputs)
def _output_cases(case: Path) -> dict:
    log = case / "log"
    (case.parent / "a_file").write_text("x")
    return {
        "-o onto the log's sensors.yaml": (["calibrate", log, "-o", log / "sensors.yaml"], "sensors.yaml"),
        "-o onto the log's robot.csv": (["calibrate", log, "-o", log / "robot.csv"], "robot.csv"),
        "-o is the log directory": (["calibrate", log, "-o", log], "log"),
        "-o inside the log directory": (["calibrate", log, "-o", log / "sub" / "c.yaml"], "c.yaml"),
        "-o an existing folder": (["calibrate", log, "-o", case.parent / "out"], "out"),
        "-o under a file": (["calibrate", log, "-o", case.parent / "a_file" / "c.yaml"], "c.yaml"),
        "import-people -o onto its input": (["import-people", case / "people.csv", "-o", case / "people.csv"],
                                            "people.csv"),
        "import-people -o a folder": (["import-people", case / "people.csv", "-o", case.parent / "out"], "out"),
        "follow -o onto the people file": (["follow", "--people", case / "people.csv", "--target", "0", "-o",
                                            case / "people.csv", "--json"], "people.csv"),
        "import-bag -o inside the bag": (["import-bag", case / "log", "-o", case / "log" / "x"], "x"),
        "report --out inside the log": (["report", log, "--extrinsics", case / "calibrated.yaml", "--out",
                                         log / "report"], "report"),
        "report --out onto the extrinsics": (["report", log, "--extrinsics", case / "calibrated.yaml", "--out",
                                              case / "calibrated.yaml"], "calibrated.yaml"),
        "export -o onto its input": (["export", case / "calibrated.yaml", "--format", "json", "-o",
                                      case / "calibrated.yaml"], "calibrated.yaml"),
        "export tum -o inside the log": (["export", log, "--format", "tum", "-o", log / "tum"], "tum"),
    }


OUTPUT_CASES = ["-o onto the log's sensors.yaml", "-o onto the log's robot.csv", "-o is the log directory",
                "-o inside the log directory", "-o an existing folder", "-o under a file",
                "import-people -o onto its input", "import-people -o a folder", "follow -o onto the people file",
                "import-bag -o inside the bag", "report --out inside the log", "report --out onto the extrinsics",
                "export -o onto its input", "export tum -o inside the log"]


@pytest.mark.parametrize("name", OUTPUT_CASES)
def test_output_onto_an_input_or_unwritable_is_refused(case, name):
    argv, names = _output_cases(case)[name]
    code, _, err = run_cli(argv, case, names=(names,))
    assert code == EXIT_BAD_INPUT, err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders and reads unreadable files")
def test_read_only_output_folder_and_unreadable_input(case):
    ro = case.parent / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    code, _, err = run_cli(["calibrate", case / "log", "-o", ro / "c.yaml"], case, names=("c.yaml",))
    assert code == EXIT_BAD_INPUT and "permission" in err
    (case / "log" / "sensors.yaml").chmod(0o000)
    code, _, err = run_cli(["calibrate", case / "log", "-o", case.parent / "out" / "c.yaml"], case,
                           names=("sensors.yaml",))
    assert code == EXIT_BAD_INPUT and "permission" in err


def test_temporary_left_by_a_killed_writer_is_removed(case):
    out = case.parent / "out" / "c.yaml"
    dead = 2 ** 22 + 12345          # above the default pid_max: no such process
    stale = out.parent / f".c.yaml.{dead}.abcd1234.tmp"
    stale.write_text("half")
    code, _, err = run_cli(["calibrate", case / "log", "-o", out, "-q"], case)
    assert code == 0, err
    assert not stale.exists() and out.exists()


# ------------------------------------------------------------------ named cases (extrinsics YAML)
ALIAS_BOMB = "".join(f"{k}: &{k} [{', '.join([f'*{p}' if p else 'x'] * 9)}]\n"
                     for k, p in zip("abcdefghi", ["", *"abcdefgh"], strict=True))


def _alias_bomb(where: str):
    """Aliases that expand to 9^9 values, in a sensor id or a position (printing them would hang)."""
    def fn(d):
        return ALIAS_BOMB + "sensors:\n  - {id: %s, position: %s, ypr_deg: [0, 45, 0]}\n" % (
            ("*i", "[0, 0, 2.6]") if where == "id" else ("s04", "[*i, 0, 2.6]"))
    return fn


BAD_EXTRINSICS = {
    "tracker_latency_s: fast": lambda d: d.update(tracker_latency_s="fast"),
    "tracker_latency_s: 1e300": lambda d: d.update(tracker_latency_s=1e300),
    "head_radius_m: -5": lambda d: d.update(head_radius_m=-5),
    "head_model not a mapping": lambda d: d.update(head_model=0.05),
    "head_model offset 1e300": lambda d: d.update(head_model={"vertical_offset_m": 1e300, "ray_shift_m": 0.0}),
    "head_model shift as text": lambda d: d.update(head_model={"vertical_offset_m": 0.0, "ray_shift_m": "4 cm"}),
    "head_model sigma negative": lambda d: d.update(head_model={"vertical_offset_m": -0.04,
                                                                 "sigma_vertical_offset_m": -0.01}),
    "sigma negative": lambda d: d["sensors"][0].update(sigma={"position_m": [-1, 0, 0], "ypr_deg": [0, 0, 0]}),
    "status unknown": lambda d: d["sensors"][0].update(status="great"),
    "sensor without position": lambda d: d["sensors"][0].pop("position"),
}


@pytest.mark.parametrize("name", list(BAD_EXTRINSICS) + ["alias bomb in an id", "alias bomb in a position"])
def test_bad_extrinsics_for_evaluate(case, name):
    if name.startswith("alias bomb"):
        (case / "calibrated.yaml").write_text(_alias_bomb("id" if name.endswith("id") else "position")(None))
    else:
        yaml_edit(case / "calibrated.yaml", BAD_EXTRINSICS[name])
    code, _, err = run_cli(["evaluate", case / "log", "--extrinsics", case / "calibrated.yaml"], case,
                           names=("calibrated.yaml",))
    assert code == EXIT_BAD_INPUT, err
    code, _, err = run_cli(["export", case / "calibrated.yaml", "--format", "tf-launch", "-o",
                            case.parent / "out" / "tf.launch"], case, names=("calibrated.yaml",))
    assert code == EXIT_BAD_INPUT, err


@pytest.mark.parametrize("how", ["cp1252", "directory", "missing"])
def test_extrinsics_file_unreadable(case, how):
    ext = case / "calibrated.yaml"
    if how == "cp1252":
        _cp1252("calibrated.yaml")(case)
    elif how == "directory":
        ext.unlink()
        ext.mkdir()
    else:
        ext.unlink()
    code, _, err = run_cli(["evaluate", case / "log", "--extrinsics", ext], case, names=("calibrated.yaml",))
    assert code == EXIT_BAD_INPUT, err


def test_calibrated_yaml_evaluates_and_feeds_back(case):
    code, out, err = run_cli(["evaluate", case / "log", "--extrinsics", case / "calibrated.yaml", "--json"], case)
    assert code == 0, err
    import json

    assert json.loads(out)
    code, _, err = run_cli(["calibrate", case / "log", "-o", case.parent / "out" / "again.yaml", "-q"], case)
    assert code == 0, err
    code, _, err = run_cli(["report", case / "log", "--extrinsics", case / "calibrated.yaml", "--extrinsics",
                            case.parent / "out" / "again.yaml", "--out", case.parent / "out" / "report", "-q"], case)
    assert code == 0 and (case.parent / "out" / "report" / "report.md").exists(), err
    for fmt, name in (("json", "c.json"), ("urdf", "c.urdf"), ("tum", "tum")):
        src = case / "log" if fmt == "tum" else case / "calibrated.yaml"
        code, _, err = run_cli(["export", src, "--format", fmt, "-o", case.parent / "out" / name], case)
        assert code == 0 and (case.parent / "out" / name).exists(), err


# --------------------------------------------------------------------- named cases (people files)
def _people_edit(fn):
    def edit(p):
        df = read_cells(p)
        write_cells(fn(df), p)
    return edit


BAD_PEOPLE = {
    "target seen at t=0 and t=1e7": (_people_edit(lambda df: pd.concat(
        [df, pd.DataFrame({"t": ["1e7"], "person": ["0"], "x": ["1"], "y": ["1"]})])), ["--target", "0"]),
    "x = 1e300": (_people_edit(lambda df: df.assign(x=np.where(np.arange(len(df)) == 4, "1e300", df["x"]))),
                  ["--target", "0"]),
    "t in nanoseconds": (_people_edit(lambda df: df.assign(t=(df["t"].astype(float) * 1e9 + 1.7e18).map(repr))),
                         ["--target", "0"]),
    "unknown target": (lambda p: None, ["--target", "nobody"]),
    "binary people file": (lambda p: p.write_bytes(b"\xff\xfe\x00\x01" * 50), ["--target", "0"]),
    "missing column": (_people_edit(lambda df: df.drop(columns="y")), ["--target", "0"]),
    "text in x": (_people_edit(lambda df: df.assign(x=np.where(np.arange(len(df)) == 2, "1,5", df["x"]))),
                  ["--target", "0"]),
}


@pytest.mark.parametrize("name", list(BAD_PEOPLE))
def test_bad_people_file_for_follow_and_import(case, name):
    edit, extra = BAD_PEOPLE[name]
    people = case / "people.csv"
    edit(people)
    code, _, err = run_cli(["follow", "--people", people, *extra, "--json"], case, names=("people.csv",))
    assert code == EXIT_BAD_INPUT, err
    if name not in ("unknown target", "target seen at t=0 and t=1e7"):
        code, _, err = run_cli(["import-people", people, "-o", case.parent / "out" / "p.csv"], case,
                               names=("people.csv",))
        assert code == EXIT_BAD_INPUT, err


def test_people_file_follows_and_imports(case):
    code, out, err = run_cli(["follow", "--people", case / "people.csv", "--target", "0", "--json"], case)
    assert code == 0, err
    # without --target the people who could be followed are listed, the target among them
    code, out, err = run_cli(["follow", "--people", case / "people.csv", "--json"], case)
    assert code == 0, err
    assert "0" in {c["person"] for c in json.loads(out)["candidates"]}
    target = case.parent / "out" / "p.csv"
    code, _, err = run_cli(["import-people", case / "people.csv", "-o", target], case)
    assert code == 0, err
    pd.testing.assert_frame_equal(pd.read_csv(target), pd.read_csv(case / "people.csv"), check_dtype=False)


def test_people_duration_limit_is_an_option(case):
    people = case / "people.csv"
    code, _, err = run_cli(["follow", "--people", people, "--target", "0", "--max-duration-s", "5", "--json"], case,
                           names=("people.csv",))
    assert code == EXIT_BAD_INPUT and "--max-duration-s" in err and "frames" in err


# ------------------------------------------------------------------- generated cases (Hypothesis)
NASTY = ["", " ", "nan", "NaN", "inf", "-inf", "1e300", "-1e300", "1e-300", "0", "-0", "abc", "1,5", "0x10",
         "1_000", "\x00", "€", "9" * 400, "1.5.2", "True", "None", "1e10", "-1e9", "3e18", "  7  ", '"q"']
TABLE_COLUMNS = {
    "robot.csv": ["t", "x", "y", "yaw", "cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"],
    "observations.csv": ["t", "sensor", "track", "x", "y", "z"],
    "odometry.csv": ["t", "x", "y", "yaw"],
    "truth_observations.csv": ["row", "who"],
    "truth_robot.csv": ["t", "x", "y", "yaw"],
}
cell_values = st.one_of(st.sampled_from(NASTY),
                        st.floats(allow_nan=True, allow_infinity=True).map(repr),
                        st.integers(min_value=-10 ** 20, max_value=10 ** 20).map(str),
                        st.text(max_size=8))
FUZZ_SETTINGS = settings(max_examples=110, deadline=None, derandomize=True, database=None,
                         suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@FUZZ_SETTINGS
@given(data=st.data())
def test_generated_cell_corruptions(base, tmp_path_factory, data):
    case = tmp_path_factory.mktemp("cell") / "in"
    shutil.copytree(base / "sim" / "calib", case / "log")
    shutil.copy(base / "calibrated.yaml", case / "calibrated.yaml")
    (case.parent / "out").mkdir()
    file = data.draw(st.sampled_from(sorted(TABLE_COLUMNS)), label="file")
    n_cells = data.draw(st.integers(1, 3), label="cells")
    df = read_cells(case / "log" / file)
    for _ in range(n_cells):
        row = data.draw(st.integers(0, len(df) - 1), label="row")
        column = data.draw(st.sampled_from(TABLE_COLUMNS[file]), label="column")
        df.loc[row, column] = data.draw(cell_values, label="value")
    write_cells(df, case / "log" / file)
    code, _, err = run_cli(["evaluate", case / "log", "--extrinsics", case / "calibrated.yaml"], case,
                           names=(file,))
    if code == 0 and data.draw(st.integers(0, 3), label="calibrate too") == 0:
        run_cli(["calibrate", case / "log", "-o", case.parent / "out" / "c.yaml", "-q"], case)


YAML_INSERTS = ["", "x", "-", ":", "[", "]", "{", "\n", " ", "1e300", "#", "'", "0.1", "\t", "\x92", "&a", "*a",
                "!!python/object"]
yaml_mutations = st.lists(st.tuples(st.integers(0, 10 ** 6), st.sampled_from(YAML_INSERTS)), min_size=1, max_size=4)


@settings(max_examples=60, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(which=st.sampled_from(["sensors.yaml", "meta.yaml", "calibrated.yaml"]), edits=yaml_mutations)
def test_generated_yaml_corruptions(base, tmp_path_factory, which, edits):
    case = tmp_path_factory.mktemp("yaml") / "in"
    shutil.copytree(base / "sim" / "calib", case / "log")
    shutil.copy(base / "calibrated.yaml", case / "calibrated.yaml")
    path = case / which if which == "calibrated.yaml" else case / "log" / which
    text = path.read_bytes().decode("utf-8")
    for pos, insert in edits:
        i = pos % (len(text) + 1)
        text = text[:i] + insert + text[i + 1:]
    path.write_bytes(text.encode("utf-8", errors="surrogateescape").replace("\x92".encode(), b"\x92"))
    names = (which,) if which != "sensors.yaml" else ("sensors.yaml",)
    code, _, err = run_cli(["evaluate", case / "log", "--extrinsics", case / "calibrated.yaml"], case,
                           names=names + ("observations.csv",))


def test_in_memory_log_gets_the_file_messages():
    """pedcal.io.validate and calibrate on a Log built from DataFrames: the table, row and column."""
    from pedcal.calib import calibrate
    from pedcal.errors import PedcalInputError
    from pedcal.io import validate
    from pedcal.model import Log, SensorExtrinsics, SensorNetwork

    sensors = SensorNetwork([SensorExtrinsics("s1", [0, 0, 2.6], [0, 45, 0])])
    robot = pd.DataFrame({"t": [0.0, 1.0], "x": [0.0, 1.0], "y": 0.0, "yaw": 0.0, "cov_xx": 1e-3, "cov_xy": 0.0,
                          "cov_xyaw": 0.0, "cov_yy": 1e-3, "cov_yyaw": 0.0, "cov_yawyaw": 1e-4})
    obs = pd.DataFrame({"t": [0.5], "sensor": ["s1"], "track": [1], "x": [0.5], "y": [0.0], "z": [1.35]})
    typed = validate(Log(sensors=sensors, robot=robot, observations=obs))
    assert typed.observations["track"].tolist() == ["1"]
    with pytest.raises(PedcalInputError, match=r"Log\.observations, column 'z': missing required column"):
        calibrate(Log(sensors=sensors, robot=robot, observations=obs.rename(columns={"z": "height"})))
    with pytest.raises(PedcalInputError, match=r"Log\.robot, row 1, column 'x': coordinate 1e\+300 m"):
        validate(Log(sensors=sensors, robot=robot.assign(x=[0.0, 1e300]), observations=obs))
    with pytest.raises(PedcalInputError, match=r"Log\.robot, row 0, column 'cov_xx': .*not positive definite"):
        validate(Log(sensors=sensors, robot=robot.assign(cov_xy=1.0), observations=obs))


def test_no_numpy_repr_in_messages(case):
    log = case / "log"
    set_cell(log / "robot.csv", 6, "t", read_cells(log / "robot.csv")["t"][5])
    _, _, err = run_cli(["calibrate", log, "-o", case.parent / "out" / "c.yaml"], case, names=("robot.csv",))
    assert re.search(r"time \d", err) and "np." not in err


# -------------------------------------------------------------------------- real recordings
REAL_PEDESTRIANS = ["atc/atc-1024-9_test.csv", "atc/atc-1024-10_test.csv", "eth_ucy/biwi_eth.txt",
                    "eth_ucy/biwi_hotel.txt", "eth_ucy/crowds_zara01.txt", "thor/exp-1-run-2.csv"]


@pytest.mark.parametrize("damage", ["none", "cut mid-line", "cp1252 byte", "binary tail"])
@pytest.mark.parametrize("name", REAL_PEDESTRIANS)
def test_real_pedestrian_recordings(shared_data, tmp_path, name, damage):
    """Every recording in shared/data (a copy) through import-people, and its people file through
    follow; damaged copies exit 0 or 2 naming the file, never a traceback."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    src = inputs / Path(name).name
    data = (shared_data / name).read_bytes()
    if damage == "cut mid-line":
        data = data[: len(data) // 2 + 3]
    elif damage == "cp1252 byte":
        data = data[:200] + b"\x92" + data[200:]
    elif damage == "binary tail":
        data = data + bytes(range(256))
    src.write_bytes(data)
    people = tmp_path / "out" / "people.csv"
    code, _, err = run_cli(["import-people", src, "-o", people], inputs, names=(src.name,))
    if damage == "none":
        assert code == 0, err
        df = pd.read_csv(people, dtype={"person": str})
        counts = df.groupby("person").size()
        target = str(counts[counts >= 2].index[0])
        code, _, err = run_cli(["follow", "--people", people, "--target", target, "--json"], people.parent)
        assert code == 0, err


def test_real_bag_import_and_output_inside_it(shared_data, tmp_path):
    inputs = tmp_path / "in"
    shutil.copytree(shared_data / "turtlebot4_ros2_bag", inputs / "bag")
    code, out, err = run_cli(["import-bag", inputs / "bag", "-o", tmp_path / "out", "--localization", "odometry",
                              "--map-frame", "odom"], inputs)
    assert code == 0 and "robot.csv" in out, err
    code, out, err = run_cli(["import-bag", inputs / "bag", "-o", tmp_path / "out2"], inputs, names=("bag",))
    assert code == EXIT_BAD_INPUT and "localization" in err, err   # the bag has no map-frame localization
    code, _, err = run_cli(["import-bag", inputs / "bag", "-o", inputs / "bag"], inputs, names=("bag",))
    assert code == EXIT_BAD_INPUT, err


@pytest.mark.parametrize("which", ["log/sensors.yaml", "log/meta.yaml", "calibrated.yaml", "log/robot.csv"])
def test_unreadable_input_is_a_clean_error_even_as_root(case, monkeypatch, which):
    """No read permission (simulated, so the case also runs as root, which ignores file modes)."""
    import builtins
    import pathlib

    target = str(case / which)
    real_read_bytes, real_open = pathlib.Path.read_bytes, builtins.open

    def read_bytes(self):
        if str(self) == target:
            raise PermissionError(13, "Permission denied", str(self))
        return real_read_bytes(self)

    def guarded_open(file, *args, **kwargs):
        if str(file) == target:
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "read_bytes", read_bytes)
    monkeypatch.setattr(builtins, "open", guarded_open)
    code, _, err = run_cli(["evaluate", case / "log", "--extrinsics", case / "calibrated.yaml"], case,
                           names=(Path(which).name,))
    assert code == EXIT_BAD_INPUT and "ermission denied" in err, err


def test_unwritable_output_folder_is_refused_even_as_root(case, monkeypatch):
    """A read-only folder (simulated through os.access and mkstemp, which root would bypass)."""
    import tempfile

    ro = case.parent / "ro"
    ro.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == ro else real_access(p, mode, **kw))
    code, _, err = run_cli(["calibrate", case / "log", "-o", ro / "c.yaml"], case, names=("c.yaml",))
    assert code == EXIT_BAD_INPUT and "permission denied" in err, err

    def no_mkstemp(*args, **kwargs):          # the folder turns read-only after the pre-flight
        raise PermissionError(13, "Permission denied", str(kwargs.get("dir")))

    monkeypatch.setattr(os, "access", real_access)
    monkeypatch.setattr(tempfile, "mkstemp", no_mkstemp)
    code, _, err = run_cli(["calibrate", case / "log", "-o", ro / "c.yaml", "-q"], case, names=("c.yaml",))
    assert code == EXIT_BAD_INPUT and "permission denied" in err, err
    assert not (ro / "c.yaml").exists()


# ======================================================================= hostile classes
# Special files, a full disk, option domains walked from the parser, structural tricks in point
# clouds, models and labels, corrupted bag payloads, library calls with wrong types, Ctrl-C at
# start-up. Every case goes through run_cli's contract (or its parse-time twin below).
def run_cli_refused_at_parse(argv: list[str], names=()) -> str:
    """An option value outside its domain: argparse refuses it before any work (main returns 2), the last stderr
    line ``pedcal CMD: error: argument --OPT: ...``; returns that line."""
    err = io.StringIO()
    TALLY["cases"] += 1
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main([str(a) for a in argv])
    assert code == EXIT_BAD_INPUT, err.getvalue()
    line = err.getvalue().strip().splitlines()[-1]
    assert line.startswith(f"pedcal {argv[0]}: error: argument "), line
    assert "Traceback" not in err.getvalue()
    if names:
        assert any(n in line for n in names), line
    TALLY["clean errors"] += 1
    return line


def _special(path: Path, kind: str):
    """Make a FIFO, a UNIX socket or a character device (/dev/null's numbers) at ``path``; returns
    the socket to keep it open, or None."""
    import socket
    import stat as stat_mod

    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(path))
        return s
    else:
        os.mknod(path, 0o666 | stat_mod.S_IFCHR, os.makedev(1, 3))
    return None


SPECIAL_KINDS = ["fifo", "socket"] + (["device"] if os.geteuid() == 0 else [])


def _kind_of(path: Path) -> str:
    import stat as stat_mod

    mode = os.lstat(path).st_mode
    return ("fifo" if stat_mod.S_ISFIFO(mode) else "socket" if stat_mod.S_ISSOCK(mode)
            else "device" if stat_mod.S_ISCHR(mode) else "other")


@pytest.mark.parametrize("kind", SPECIAL_KINDS)
def test_special_file_as_output_is_never_replaced(case, kind):
    out = case.parent / "out"
    node = out / "node"
    keep = _special(node, kind)
    try:
        for argv in (["calibrate", case / "log", "-o", node, "-q"],
                     ["import-people", case / "people.csv", "-o", node],
                     ["export", case / "calibrated.yaml", "--format", "json", "-o", node],
                     ["follow", "--people", case / "people.csv", "--target", "0", "-o", node, "--json"],
                     ["report", case / "log", "--extrinsics", case / "calibrated.yaml", "--out", node, "-q"]):
            code, _, err = run_cli(argv, case, names=("node",))
            assert code == EXIT_BAD_INPUT and "never replaces" in err, err
            assert _kind_of(node) == kind
    finally:
        if keep is not None:
            keep.close()


@pytest.mark.parametrize("kind", SPECIAL_KINDS)
def test_special_file_as_input_is_refused_without_blocking(case, kind):
    """A FIFO would block a reader forever; a device such as /dev/zero would fill memory."""
    log = case / "log"
    cases = {"sensors.yaml": lambda p: ["evaluate", log, "--extrinsics", case / "calibrated.yaml"],
             "meta.yaml": lambda p: ["evaluate", log, "--extrinsics", case / "calibrated.yaml"],
             "calibrated.yaml": lambda p: ["evaluate", log, "--extrinsics", p],
             "graph.toml": lambda p: ["calibrate", log, "--graph", p, "-o", case.parent / "out" / "c.yaml"],
             "cloud.pcd": lambda p: ["detect", p]}
    for name, argv_of in cases.items():
        path = log / name if name in ("sensors.yaml", "meta.yaml") else case / name
        backup = path.with_suffix(".bak")
        if path.exists():
            path.rename(backup)
        keep = _special(path, kind)
        try:
            code, _, err = run_cli(argv_of(path), case, names=(name,))
            assert code == EXIT_BAD_INPUT and "regular" in err, err
        finally:
            if keep is not None:
                keep.close()
            path.unlink()
            if backup.exists():
                backup.rename(path)


def test_dev_zero_as_extrinsics_is_refused(case):
    code, _, err = run_cli(["evaluate", case / "log", "--extrinsics", "/dev/zero"], case, names=("/dev/zero",))
    assert code == EXIT_BAD_INPUT and "character device" in err


@pytest.fixture
def small_disk(tmp_path):
    """A 64 kB tmpfs where the machine lets us mount one (root), else None."""
    import subprocess

    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
                                           capture_output=True).returncode != 0:
        yield None
        return
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_full_disk_is_one_line_and_keeps_the_old_output(case, small_disk, monkeypatch):
    """Writing a calibrated YAML, a people CSV (Arrow's writer) and a follow folder onto a full
    disk: exit 2, one line naming the output, the previous output byte for byte."""
    import errno

    if small_disk is None:            # simulate ENOSPC in the writes instead
        small_disk = case.parent / "out"
        real_write = os.write

        def full(fd, data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(os, "write", full)
        monkeypatch.setattr(Path, "write_text", lambda self, *a, **k: full(0, b""))
        del real_write
    old = small_disk / "c.yaml"
    old.write_text("old: 1\n")
    filler = small_disk / "filler"
    with contextlib.suppress(OSError):
        filler.write_bytes(b"\0" * 64 * 1024)
    before = old.read_bytes()
    for argv, target in ((["calibrate", case / "log", "-o", old, "-q"], "c.yaml"),
                         (["import-people", case / "people.csv", "-o", small_disk / "p.csv"], "p.csv"),
                         (["follow", "--people", case / "people.csv", "--target", "0", "-o", small_disk / "f",
                           "--json"], "f")):
        code, _, err = run_cli(argv, case, names=(target,))
        assert code == EXIT_BAD_INPUT and "no space left" in err, err
    assert old.read_bytes() == before
    assert not list(small_disk.glob(".*tmp*"))


# ----------------------------------------------------------------------- option domains
def _numeric_actions():
    """(command, option string, nargs, domain) of every option whose type carries a domain."""
    import argparse

    from pedcal.cli import build_parser

    out, untyped = [], []
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for command, parser in sub.choices.items():
        for action in parser._actions:
            domain = getattr(action.type, "domain", None)
            if domain is not None:
                out.append((command, action.option_strings[-1] if action.option_strings else None, action.nargs,
                            domain))
            elif action.type in (int, float) and not action.choices:
                untyped.append(f"{command} {action.option_strings}")
    return out, untyped


def _outside(domain, rng) -> list[str]:
    """Values outside ``domain``: not numbers, not finite, beyond each bound, a fraction for an integer."""
    vals = ["nan", "inf", "-inf", "", "abc", "1e400", "0x10"]
    if domain.lo is not None:
        below = domain.lo - max(1.0, abs(domain.lo)) * rng.uniform(1e-3, 1)
        vals.append(repr(domain.lo) if domain.lo_open else repr(below))
        if domain.lo_open:
            vals.append(repr(domain.lo - rng.uniform(1e-9, 1)))
    if domain.hi is not None:
        vals.append(repr(domain.hi + max(1.0, abs(domain.hi)) * rng.uniform(1e-3, 10)))
        vals.append("1e300")
    if domain.kind is int:
        vals += ["1.5", "2e3"]
    if domain.kind is int and domain.lo is not None:
        vals.append(str(int(domain.lo) - 1))
    return vals


def test_every_numeric_option_has_a_domain():
    actions, untyped = _numeric_actions()
    assert not untyped, f"numeric options without a domain (pedcal.options): {untyped}"
    assert len(actions) >= 15


def test_option_values_outside_their_domain_are_refused_at_parse():
    rng = np.random.default_rng(2718)
    actions, _ = _numeric_actions()
    n = 0
    for command, option, nargs, domain in actions:
        if option is None:
            continue
        width = nargs if isinstance(nargs, int) else 1
        for bad in _outside(domain, rng):
            for slot in range(width):        # the bad value in each position of a multi-value option
                values = ["1"] * width
                values[slot] = bad
                argv = [command, f"{option}={bad}"] if width == 1 else [command, option, *values]
                line = run_cli_refused_at_parse(argv, names=(option,))
                assert option in line
                n += 1
    assert n > 150


def test_library_checks_the_same_domains(case):
    """The library keywords of those options refuse the same values, before any work."""
    from pedcal import read_log, simulate_logs
    from pedcal.calib import calibrate
    from pedcal.detect.detection import detect
    from pedcal.errors import PedcalInputError
    from pedcal.track.follow import run_follow as follow

    log = read_log(case / "log")
    pts = np.zeros((10, 4))
    calls = [lambda: calibrate(log, sensor_height_sigma_m=float("nan")),
             lambda: calibrate(log, sensor_height_sigma_m=1e-300),
             lambda: calibrate(log, ceiling_height_m=-3.0), lambda: calibrate(log, ceiling_height_m=1e300),
             lambda: calibrate(log, max_memory_gb=float("nan")),
             lambda: detect(pts, threshold=float("nan")), lambda: detect(pts, cell_size_m=0.0),
             lambda: follow("crowd", density_per_10m2=1e6), lambda: follow("crowd", density_per_10m2=-0.0),
             lambda: follow("passing", seed=-1), lambda: simulate_logs("sparse", seed=-1)]
    for call in calls:
        TALLY["cases"] += 1
        with pytest.raises(PedcalInputError, match="expected"):
            call()
        TALLY["clean errors"] += 1


@pytest.mark.parametrize("argv_of,names", [
    (lambda c: ["calibrate", c / "log", "-o", c.parent / "out" / "c.yaml", "--graph", c / "g.toml"], "g.toml"),
])
@pytest.mark.parametrize("value", ["-0.01", "nan", "0.0", "1e300"])
def test_graph_recipe_sigmas_have_a_domain(case, argv_of, names, value):
    (case / "g.toml").write_text(f"lateral_sigma_m = {value}\n")
    code, _, err = run_cli(argv_of(case), case, names=(names,))
    assert code == EXIT_BAD_INPUT and "lateral_sigma_m" in err, err


# ------------------------------------------------------- point clouds, models, labels (structure)
def _pcd(fields="x y z", size="4 4 4", typ="F F F", count="1 1 1", width=1, points=None, data="binary",
         body=b"\0" * 12) -> bytes:
    points = width if points is None else points
    return (f"VERSION .7\nFIELDS {fields}\nSIZE {size}\nTYPE {typ}\nCOUNT {count}\nWIDTH {width}\nHEIGHT 1\n"
            f"POINTS {points}\nDATA {data}\n").encode() + body


def _cloud_tricks(d: Path) -> dict[str, Path]:
    out = {}

    def put(name, data):
        (d / name).write_bytes(data)
        out[name] = d / name

    put("count0.pcd", _pcd(count="0 1 1", body=b"\0" * 8))
    put("width0.pcd", _pcd(width=0, body=b""))
    put("listx.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nproperty float y\n"
                     b"property float z\nend_header\n2 1 2 3 4\n")
    for name, dt in (("subarray.npy", [("x", "f8", (3,)), ("y", "f8"), ("z", "f8")]),
                     ("text.npy", [("x", "U4"), ("y", "f8"), ("z", "f8")]),
                     ("nested.npy", [("x", [("a", "f8")]), ("y", "f8"), ("z", "f8")])):
        np.save(d / name, np.zeros(4, dtype=dt))
        out[name] = d / name
    np.savez(d / "archive.npz", a=np.zeros((3, 3)))
    (d / "archive.npz").rename(d / "archive.npy")
    out["archive.npy"] = d / "archive.npy"
    sparse = d.parent / "sparse" / "sparse.bin"    # beside the inputs: the harness would checksum 6 GB
    sparse.parent.mkdir()
    with open(sparse, "wb") as f:                  # 6 GB, no block allocated
        f.truncate(6 * 10 ** 9)
    out["sparse.bin"] = sparse
    rng = np.random.default_rng(31)
    for k in range(12):                            # generated header damage: a key's value replaced
        key = rng.choice(["FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "POINTS", "DATA"])
        value = rng.choice(["0", "-1", "", "x", "4 4", "0 0 0", "99999999999", "F", "binary_compressed", "nan"])
        text = _pcd(body=rng.bytes(int(rng.integers(0, 40)))).decode("latin-1")
        text = re.sub(rf"^{key} .*$", f"{key} {value}", text, count=1, flags=re.M)
        put(f"gen{k}.pcd", text.encode("latin-1"))
    return out


def test_point_cloud_structure_tricks(tmp_path):
    inputs = tmp_path / "in"
    inputs.mkdir()
    for name, path in _cloud_tricks(inputs).items():
        code, _, err = run_cli(["detect", path, "--json"], inputs, names=(name,))
        assert code in (0, EXIT_BAD_INPUT), err
        if not name.startswith("gen"):
            assert code == EXIT_BAD_INPUT, (name, err)


def _model_tricks(d: Path) -> dict[str, Path]:
    from pedcal.detect.adaboost import RealAdaBoost
    from pedcal.detect.detection import model_path
    from pedcal.detect.features import N_FEATURES

    rng = np.random.default_rng(11)      # a small one-feature-per-round RealAdaBoost of the detector's features
    X = rng.normal(size=(300, N_FEATURES))
    RealAdaBoost(n_rounds=12, n_bins=8, seed=0).fit(X, (X[:, 0] + X[:, 5] > 0).astype(int)).save(d / "stumps.npz")
    src = dict(np.load(d / "stumps.npz"))
    fx8 = dict(np.load(model_path("fx8")))
    gbt = dict(np.load(model_path("general")))
    text = gbt["lightgbm_model"].tobytes()
    h_nan = src["h"].copy()
    h_nan[3, 2] = np.nan
    edges_desc = src["edges"].copy()
    edges_desc[5] = edges_desc[5][::-1]
    tricks = {"feature out of range": dict(src, feature=src["feature"] + 1000),
              "negative feature": dict(src, feature=-src["feature"] - 1),
              "NaN weights": dict(src, h=h_nan), "truncated edges": dict(src, edges=src["edges"][:, :3]),
              "edges decreasing": dict(src, edges=edges_desc), "h wrong shape": dict(src, h=src["h"][:10]),
              "tree edges truncated": dict(fx8, edges=fx8["edges"][:, :2]),
              "tree depth 40": dict(fx8, tree_depth=np.int64(40)), "bias inf": dict(src, bias=np.float64(np.inf)),
              "no h": {k: v for k, v in src.items() if k != "h"},
              "trees: feature count off": dict(gbt, n_features=np.int64(int(gbt["n_features"]) + 7)),
              "trees: bias NaN": dict(gbt, bias=np.float64(np.nan)),
              "trees: text cut": dict(gbt, lightgbm_model=np.frombuffer(text[: len(text) // 3], np.uint8)),
              "trees: no hyper": {k: v for k, v in gbt.items() if k != "hyper"}}
    out = {}
    for k, (name, arrays) in enumerate(tricks.items()):
        out[name] = d / f"model{k}.npz"
        np.savez(out[name], **arrays)
    (d / "garbage.npz").write_bytes(np.random.default_rng(5).bytes(300))
    out["garbage"] = d / "garbage.npz"
    cut = (d / "model0.npz").read_bytes()
    (d / "cut.npz").write_bytes(cut[: len(cut) // 2])
    out["truncated file"] = d / "cut.npz"
    return out


def test_detector_model_structure_tricks(tmp_path):
    inputs = tmp_path / "in"
    inputs.mkdir()
    rng = np.random.default_rng(8)
    cloud = np.column_stack([rng.uniform(-5, 5, (3000, 2)), rng.uniform(0, 1.8, 3000), rng.uniform(0, 1, 3000)])
    np.save(inputs / "frame.npy", cloud)
    for name, path in _model_tricks(inputs).items():
        code, _, err = run_cli(["detect", inputs / "frame.npy", "--model", path, "--floor", "none", "--json"],
                               inputs, names=(path.name,))
        assert code == EXIT_BAD_INPUT, (name, err)


def _label_tricks() -> dict[str, str]:
    box = {"obj_type": "Pedestrian", "obj_id": "1", "psr": {"position": {"x": 1, "y": 0, "z": 0.9},
                                                             "scale": {"x": 0.5, "y": 0.5, "z": 1.7},
                                                             "rotation": {"x": 0, "y": 0, "z": 0}}}

    def with_scale(v):
        b = json.loads(json.dumps(box))
        b["psr"]["scale"]["y"] = v
        return json.dumps([b]).replace('"@@"', v if isinstance(v, str) else "0")

    return {"nested 100000 deep": "[" * 100_000 + "]" * 100_000, "5000-digit integer": "[" + "9" * 5000 + "]",
            "400-digit size": with_scale("@@").replace("0.5, \"z\"", "1" + "0" * 400 + ", \"z\"", 1),
            "negative size": with_scale(-0.5), "NaN size": with_scale("@@").replace('"y": 0', '"y": NaN', 1),
            "infinite size": with_scale("@@").replace('"y": 0', '"y": Infinity', 1), "zero size": with_scale(0.0)}


@pytest.mark.parametrize("name", list(_label_tricks()))
def test_label_file_tricks(tmp_path, name):
    inputs = tmp_path / "in"
    real = inputs / "real"
    real.mkdir(parents=True)
    rng = np.random.default_rng(9)
    np.save(real / "f0.npy", np.column_stack([rng.uniform(-5, 5, (500, 2)), rng.uniform(0, 1.8, 500),
                                              np.zeros(500)]))
    (real / "f0.json").write_text(_label_tricks()[name])
    code, _, err = run_cli(["detect-eval", "--real", real, "--floor", "none", "--json"], inputs, names=("f0.json",))
    assert code == EXIT_BAD_INPUT, err


# ------------------------------------------------------------------------ corrupted bag payloads
def _odometry_bag(path: Path, version: int, payload=None) -> None:
    """A small bag of nav_msgs/Odometry on /odom (map frame) and an empty /tf; ``payload(k, data)``
    replaces message k's serialized bytes."""
    from tests.rosbag_fixture import BagWriter, header, make, pose

    msgtype = "nav_msgs/msg/Odometry"
    with BagWriter(path, version) as w:
        ts = w.ts
        conn = w.writer.add_connection("/odom", msgtype, typestore=ts)
        tf = w.writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        for k in range(30):
            t = 100.0 + 0.2 * k
            cov = make(ts, "geometry_msgs/msg/PoseWithCovariance", pose=pose(ts, (0.1 * k, 0.0, 0.0)),
                       covariance=np.diag([0.01, 0.01, 0, 0, 0, 0.003]).ravel())
            msg = make(ts, msgtype, header=header(ts, t, "map"), child_frame_id="base_link", pose=cov)
            data = ts.serialize_ros1(msg, msgtype) if version == 1 else ts.serialize_cdr(msg, msgtype)
            w.writer.write(conn, int(t * 1e9), bytes(payload(k, bytes(data))) if payload else data)
            w.writer.write(tf, int(t * 1e9), b"" if payload else (
                ts.serialize_ros1 if version == 1 else ts.serialize_cdr)(make(ts, "tf2_msgs/msg/TFMessage"),
                                                                         "tf2_msgs/msg/TFMessage"))


BAG_DAMAGE = {
    "truncated payloads": lambda rng: lambda k, d: d[: int(rng.integers(0, len(d)))],
    "random payloads": lambda rng: lambda k, d: rng.bytes(int(rng.integers(0, 2 * len(d)))),
    "one payload cut": lambda rng: lambda k, d: d[:7] if k == 17 else d,
}


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("damage", list(BAG_DAMAGE))
def test_corrupted_bag_payloads(tmp_path, version, damage):
    inputs = tmp_path / "in"
    inputs.mkdir()
    bag = inputs / ("b.bag" if version == 1 else "b")
    _odometry_bag(bag, version, BAG_DAMAGE[damage](np.random.default_rng(17)))
    code, _, err = run_cli(["import-bag", bag, "-o", tmp_path / "out", "--localization", "odometry",
                            "--pose-sigma", "0.1", "5"], inputs, names=("b",))
    assert code == EXIT_BAD_INPUT and re.search(r"topic /(odom|tf), message \d+", err), err


def test_ros1_bag_with_flipped_bytes(tmp_path):
    inputs = tmp_path / "in"
    inputs.mkdir()
    clean = tmp_path / "clean.bag"
    _odometry_bag(clean, 1)
    data = clean.read_bytes()
    rng = np.random.default_rng(23)
    for k in range(10):
        bad = bytearray(data)
        for i in rng.integers(0, len(bad), int(rng.integers(1, 20))):
            bad[i] ^= 0xFF
        bag = inputs / f"flip{k}.bag"
        bag.write_bytes(bytes(bad))
        code, _, err = run_cli(["import-bag", bag, "-o", tmp_path / f"out{k}", "--localization", "odometry",
                                "--pose-sigma", "0.1", "5"], inputs, names=(bag.name,))
        assert code in (0, EXIT_BAD_INPUT), err


def test_import_into_a_folder_holding_parquet_tables_is_refused(case, tmp_path):
    bag = case / "b.bag"
    _odometry_bag(bag, 1)
    out = tmp_path / "out" / "log"
    out.mkdir()
    pd.DataFrame({"t": [0.0]}).to_parquet(out / "robot.parquet")
    code, _, err = run_cli(["import-bag", bag, "-o", out, "--localization", "odometry", "--pose-sigma", "0.1", "5"],
                           case, names=("robot.parquet",))
    assert code == EXIT_BAD_INPUT and not (out / "robot.csv").exists(), err


# ------------------------------------------------------------------ library calls, wrong types
def test_library_calls_with_wrong_types_name_the_argument(case):
    import pedcal
    from pedcal.errors import PedcalInputError

    log = pedcal.read_log(case / "log")
    calls = {"calibrate(None)": (lambda: pedcal.calibrate(None), "log"),
             "calibrate('path')": (lambda: pedcal.calibrate(str(case / "log")), "log"),
             "evaluate(log, 'path')": (lambda: pedcal.evaluate(log, str(case / "calibrated.yaml")), "extrinsics"),
             "evaluate(None, net)": (lambda: pedcal.evaluate(None, log.sensors), "log"),
             "write_log(None)": (lambda: pedcal.write_log(None, case.parent / "out" / "w"), "log"),
             "write_log(log, None)": (lambda: pedcal.write_log(log, None), "path"),
             "read_log(None)": (lambda: pedcal.read_log(None), "path"),
             "read_log(3)": (lambda: pedcal.read_log(3), "path"),
             "write_sensors_yaml(net, None)": (lambda: pedcal.write_sensors_yaml(log.sensors, None), "path")}
    for name, (call, arg) in calls.items():
        TALLY["cases"] += 1
        with pytest.raises((TypeError, PedcalInputError)) as exc:
            call()
        assert arg in str(exc.value), (name, exc.value)
        assert not isinstance(exc.value, AttributeError)
        TALLY["clean errors"] += 1
    assert not (case.parent / "out" / "w").exists()


def test_library_refuses_what_would_not_read_back(case):
    import pedcal
    import pedcal.io
    from pedcal.errors import PedcalInputError
    from pedcal.model import SensorExtrinsics, SensorNetwork
    from pedcal.track.follow import run_follow

    log = pedcal.read_log(case / "log")
    people = pd.read_csv(case / "people.csv", dtype={"person": str})
    nan_net = SensorNetwork([SensorExtrinsics("a", [np.nan, 0, 2.6], [0, 45, 0])])
    calls = [lambda: pedcal.write_sensors_yaml(nan_net, case.parent / "out" / "n.yaml"),
             lambda: pedcal.write_people_csv(people.assign(x=np.nan), case.parent / "out" / "p.csv"),
             lambda: pedcal.write_log(log.__class__(sensors=log.sensors, robot=log.robot.assign(x=np.nan),
                                                    observations=log.observations), case.parent / "out" / "l"),
             lambda: pedcal.io.validate(log.__class__(sensors=log.sensors, observations=log.observations,
                                                   robot=pd.concat([log.robot, log.robot[["x"]]], axis=1))),
             lambda: run_follow(people_csv=people.drop(columns="y"), target_id="0"),
             lambda: run_follow(people_csv=people.assign(x=np.nan), target_id="0"),
             lambda: run_follow(people_csv=people.assign(x=1e300), target_id="0")]
    for call in calls:
        TALLY["cases"] += 1
        with pytest.raises(PedcalInputError):
            call()
        TALLY["clean errors"] += 1
    assert not list((case.parent / "out").iterdir())


# ------------------------------------------------------ outputs inside inputs, folders at once
def test_outputs_inside_inputs_for_every_writing_command(case, tmp_path):
    labelled = case / "L.npz"
    np.savez(labelled, X=np.zeros((4, 264)), y=np.array([0, 1, 0, 1]))
    real = case / "real"
    real.mkdir()
    for argv, name in ((["train-detector", "--labelled", labelled, "-o", labelled], "L.npz"),
                       (["detect-eval", "--real", real, "-o", real], "real"),
                       (["detect-eval", "--real", real, "-o", real / "pics"], "pics"),
                       (["follow-bench", "--data-dir", case, "-o", case], "in"),
                       (["follow-bench", "--data-dir", case, "-o", case / "bench"], "bench")):
        code, _, err = run_cli(argv, case, names=(name,))
        assert code == EXIT_BAD_INPUT and "input" in err, err


def test_folder_output_changes_all_at_once(case, monkeypatch):
    """A failure between follow.json and follow_log.parquet leaves the previous folder intact."""
    from pedcal.track.follow import FollowResult

    out = case.parent / "out" / "f"
    code, _, err = run_cli(["follow", "--people", case / "people.csv", "--target", "0", "-o", out, "--json"], case)
    assert code == 0, err
    before = checksums(out)
    (out / "mine.txt").write_text("kept")
    real_save = FollowResult.save

    def save_then_fail(self, out_dir):
        real_save(self, out_dir)
        raise PermissionError(13, "Permission denied", str(Path(out_dir) / "follow_log.parquet"))

    monkeypatch.setattr(FollowResult, "save", save_then_fail)
    code, _, err = run_cli(["follow", "--people", case / "people.csv", "--target", "1", "-o", out, "--json"], case)
    assert code == EXIT_BAD_INPUT, err
    assert f"{out / 'follow_log.parquet'}: Permission denied" in err      # the folder given, not its temporary
    assert checksums(out) == {**before, "mine.txt": checksums(out)["mine.txt"]}
    assert sorted(p.name for p in out.parent.iterdir()) == ["f"]
    monkeypatch.setattr(FollowResult, "save", real_save)
    code, _, err = run_cli(["follow", "--people", case / "people.csv", "--target", "1", "-o", out, "--json"], case)
    assert code == 0 and (out / "mine.txt").read_text() == "kept", err
    assert json.loads((out / "follow.json").read_text())["target"] == "1"


def test_tum_export_folder_changes_all_at_once(case, monkeypatch):
    """export --format tum writes several files: a failure after the first leaves the folder as it
    was (a first export: no folder at all), never a mix of new and old paths."""
    import pedcal.io.tum as tum

    out = case.parent / "out" / "tum"
    real_write = tum.write_text_atomic
    calls = {"n": 0}

    def write_then_fail(path, text, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise PermissionError(13, "Permission denied", str(path))
        return real_write(path, text, *args, **kwargs)

    monkeypatch.setattr(tum, "write_text_atomic", write_then_fail)
    code, _, err = run_cli(["export", case / "log", "--format", "tum", "-o", out], case)
    assert code == EXIT_BAD_INPUT, err
    assert not out.exists() and list(out.parent.iterdir()) == []       # nothing, not two of four files
    monkeypatch.setattr(tum, "write_text_atomic", real_write)
    code, _, err = run_cli(["export", case / "log", "--format", "tum", "-o", out], case)
    assert code == 0, err
    before = checksums(out)
    calls["n"] = 0
    monkeypatch.setattr(tum, "write_text_atomic", write_then_fail)
    code, _, err = run_cli(["export", case / "log", "--format", "tum", "-o", out, "--extrinsics",
                            case / "calibrated.yaml"], case)
    assert code == EXIT_BAD_INPUT, err
    assert checksums(out) == before and sorted(p.name for p in out.parent.iterdir()) == ["tum"]


# ---------------------------------------------------------------------------- Ctrl-C at start-up
@pytest.mark.parametrize("delay_s", [0.3, 0.6, "at work"])
def test_ctrl_c_at_start_up_is_one_line_and_130(case, delay_s):
    """SIGINT while the command imports its libraries and starts (0.3 and 0.6 s in), or once it
    reports its first step of work ("at work": a fixed delay there could come after the command's
    end on a fast machine, the whole command taking about 1.1 s): 'interrupted', exit 130, no
    traceback, no output. (Python's own start-up, before pedcal's first line runs, is outside.)"""
    import subprocess
    import sys
    import time

    out = case.parent / "out" / "c.yaml"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    # started with Ctrl-C's default disposition, as from a terminal, whatever this test run's is (a
    # run in the background inherits SIGINT ignored, which the command rightly keeps ignoring)
    proc = subprocess.Popen([sys.executable, "-m", "pedcal.cli", "calibrate", str(case / "log"), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    first = b""
    if delay_s == "at work":
        first = proc.stderr.readline()       # the first progress line: the calibration has begun
        assert first.startswith(b"["), first
    else:
        time.sleep(delay_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    TALLY["cases"] += 1
    text = (first + err).decode()
    assert "Traceback" not in text, text
    assert proc.returncode == 130, (proc.returncode, text)
    assert [ln for ln in text.splitlines() if not ln.startswith(("warning: ", "["))][-1] == "interrupted", text
    assert not out.exists()
    TALLY["clean errors"] += 1


def test_a_sigma_whose_zero_switches_its_random_effect_off_takes_zero(case):
    """head_shift_per_sensor_sigma_m = 0 is the documented way to switch the per-sensor departures
    off (head_profile_per_sensor needs it so): a graph file giving it loads and calibrates, while
    0 for a noise sigma is still refused."""
    out = case.parent / "out" / "c.yaml"
    (case / "g.toml").write_text('head_shift_per_sensor_sigma_m = 0.0\nhead_profile = "cv"\n'
                                 "head_profile_per_sensor = true\n")
    code, _, err = run_cli(["calibrate", case / "log", "-o", out, "--graph", case / "g.toml"], case, names=("g.toml",))
    assert code == 0, err
    assert out.exists()
    (case / "g.toml").write_text("range_sigma_floor_m = 0.0\n")
    code, _, err = run_cli(["calibrate", case / "log", "-o", out, "--graph", case / "g.toml"], case, names=("g.toml",))
    assert code == EXIT_BAD_INPUT and "range_sigma_floor_m" in err, err
