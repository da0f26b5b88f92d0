"""A user's bad input reaches the command line as exit code 2 and one message naming the file,
row and column, never as a traceback."""

from __future__ import annotations

import importlib.util
import os
import signal

import numpy as np
import pandas as pd
import pytest

from pedcal.cli import EXIT_BAD_INPUT, main
from pedcal.io import write_log, write_sensors_yaml
from pedcal.model import Log, SensorExtrinsics, SensorNetwork


def small_log(seed=0) -> Log:
    rng = np.random.default_rng(seed)
    sensors = SensorNetwork([SensorExtrinsics("s01", [0, 0, 2.6], [0, 45, 0]),
                             SensorExtrinsics("s02", [3, 0, 2.6], [180, 45, 0])])
    n = 20
    robot = pd.DataFrame({"t": np.arange(n, dtype=float), "x": rng.normal(size=n), "y": rng.normal(size=n),
                          "yaw": rng.normal(size=n), "cov_xx": 1e-3, "cov_xy": 0.0, "cov_xyaw": 0.0,
                          "cov_yy": 1e-3, "cov_yyaw": 0.0, "cov_yawyaw": 1e-4})
    obs = pd.DataFrame({"t": np.arange(n, dtype=float), "sensor": ["s01", "s02"] * (n // 2), "track": "1",
                        "x": rng.normal(size=n), "y": rng.normal(size=n), "z": 1.35})
    return Log(sensors=sensors, robot=robot, observations=obs)


def corrupt(path, row, column, value):
    df = pd.read_csv(path, dtype=str, keep_default_na=False)
    df.loc[row, column] = value
    df.to_csv(path, index=False)


def run(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def bad_log(tmp_path, case):
    log_dir = tmp_path / "log"
    write_log(small_log(), log_dir)
    if case == "missing column":
        df = pd.read_csv(log_dir / "observations.csv")
        df.drop(columns=["z"]).to_csv(log_dir / "observations.csv", index=False)
        return log_dir, ("observations.csv", "column 'z'")
    if case == "nan":
        corrupt(log_dir / "robot.csv", 7, "yaw", "nan")
        return log_dir, ("robot.csv", "row 7", "column 'yaw'")
    if case == "unknown sensor":
        corrupt(log_dir / "observations.csv", 3, "sensor", "s03")
        return log_dir, ("observations.csv", "row 3", "column 'sensor'", "s03")
    if case == "text in x":
        corrupt(log_dir / "observations.csv", 11, "x", "1,5")
        return log_dir, ("observations.csv", "row 11", "column 'x'", "'1,5'")
    raise AssertionError(case)


CASES = ["missing column", "nan", "unknown sensor", "text in x"]


@pytest.mark.parametrize("case", CASES)
def test_calibrate_bad_log(tmp_path, capsys, case):
    log_dir, expected = bad_log(tmp_path, case)
    code, err = run(capsys, ["calibrate", str(log_dir), "-o", str(tmp_path / "out.yaml"), "-q"])
    assert code == EXIT_BAD_INPUT
    assert err.startswith("pedcal calibrate: error:")
    for text in expected:
        assert text in err
    assert not (tmp_path / "out.yaml").exists()


@pytest.mark.skipif(importlib.util.find_spec("pedcal.metrics") is None, reason="pedcal.metrics not present")
@pytest.mark.parametrize("case", CASES)
def test_evaluate_bad_log(tmp_path, capsys, case):
    log_dir, expected = bad_log(tmp_path, case)
    code, err = run(capsys, ["evaluate", str(log_dir), "--extrinsics", str(log_dir / "sensors.yaml")])
    assert code == EXIT_BAD_INPUT
    for text in expected:
        assert text in err


def test_missing_log_directory(tmp_path, capsys):
    code, err = run(capsys, ["calibrate", str(tmp_path / "nope"), "-o", str(tmp_path / "o.yaml")])
    assert code == EXIT_BAD_INPUT and "nope" in err and "not found" in err


def test_import_bag_bad_input(tmp_path, capsys):
    code, err = run(capsys, ["import-bag", str(tmp_path / "nope.bag"), "-o", str(tmp_path / "out")])
    assert code == EXIT_BAD_INPUT and "nope.bag" in err and "bag not found" in err
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\nnot really")
    code, err = run(capsys, ["import-bag", str(tmp_path / "junk.bag"), "-o", str(tmp_path / "out")])
    assert code == EXIT_BAD_INPUT and "junk.bag" in err and "cannot open" in err
    assert not (tmp_path / "out").exists()


def test_import_bag_wrong_topic(tmp_path, capsys, shared_data):
    bag = shared_data / "turtlebot4_ros2_bag"
    code, err = run(capsys, ["import-bag", str(bag), "-o", str(tmp_path / "out"), "--odom-topic", "/nope"])
    assert code == EXIT_BAD_INPUT and "/nope not in the bag" in err and "/odom (nav_msgs/msg/Odometry)" in err


def test_import_people_bad_input(tmp_path, capsys):
    bad = tmp_path / "atc.csv"
    bad.write_text("1351040437.965,10003800,-25.397,6.412,2.007,0.45\n1351040438.996,10003800,x7,6.991,0.9,0.2\n")
    out = tmp_path / "people.csv"
    code, err = run(capsys, ["import-people", str(bad), "-o", str(out)])
    assert code == EXIT_BAD_INPUT
    assert "atc.csv" in err and "row 1" in err and "column 'x'" in err and "'x7'" in err
    assert not out.exists()
    code, err = run(capsys, ["import-people", str(tmp_path / "none.csv"), "-o", str(out)])
    assert code == EXIT_BAD_INPUT and "none.csv" in err


def test_import_people_good_file(tmp_path, capsys, shared_data):
    out = tmp_path / "people.csv"
    code = main(["import-people", str(shared_data / "thor" / "exp-1-run-2.csv"), "-o", str(out)])
    assert code == 0 and "2180 rows, 87 people" in capsys.readouterr().out
    assert len(pd.read_csv(out)) == 2180


def test_output_piped_into_a_reader_that_stops_is_not_an_error(tmp_path):
    """`pedcal follow --people FILE | head -2`: the command ends quietly when head closes the pipe."""
    import subprocess
    import sys

    n = 4000                                   # ~200 kB of listing, beyond any pipe buffer
    people = pd.DataFrame({"t": np.tile([0.0, 1.0], n), "person": np.repeat(np.arange(n), 2),
                           "x": np.tile([0.0, 0.5], n), "y": np.repeat(np.arange(n, dtype=float), 2)})
    path = tmp_path / "people.csv"
    people.to_csv(path, index=False)
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from pedcal.cli import main; sys.exit(main())",
                             "follow", "--people", str(path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = proc.stdout.readline()
    proc.stdout.close()                        # the reader stops after one line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert b"people" in first and "Traceback" not in err


def test_a_warning_reaches_the_user_as_one_line(capsys):
    """The command line shows a Python warning as `warning: message`, without the library's
    source line under it."""
    import warnings

    from pedcal.cli import configure_logging

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        configure_logging()
        warnings.warn("sensor s01: cannot estimate roll", UserWarning, stacklevel=1)
    err = capsys.readouterr().err
    assert err.strip() == "warning: sensor s01: cannot estimate roll"


def test_an_import_failed_by_ctrl_c_is_an_interrupt_not_an_error():
    """A Ctrl-C while a compiled module initializes reaches the command as ImportError('initialization
    failed') whose cause is the handler's SystemExit(130): exit 130, not a traceback."""
    from pedcal.interrupts import EXIT_INTERRUPTED, caused_by_interrupt

    def chained(inner: BaseException) -> ImportError:
        try:
            try:
                raise inner
            except BaseException as e:
                raise ImportError("initialization failed") from e
        except ImportError as outer:
            return outer

    assert caused_by_interrupt(chained(SystemExit(EXIT_INTERRUPTED)))
    assert not caused_by_interrupt(chained(SystemExit(1)))
    assert not caused_by_interrupt(chained(ValueError("bad wheel")))
    assert not caused_by_interrupt(ImportError("no module named gtsam"))


def test_a_class_creation_failed_by_ctrl_c_is_an_interrupt_not_an_error(capsys):
    """A Ctrl-C while a dataclass is created at import reaches the command as RuntimeError('Error
    calling __set_name__') whose cause is the handler's SystemExit(130): exit 130, no traceback; any
    other RuntimeError still propagates."""
    import dataclasses
    from types import SimpleNamespace

    from pedcal.cli import _run
    from pedcal.interrupts import EXIT_INTERRUPTED

    class _Interrupting:
        def __set_name__(self, owner, name):
            raise SystemExit(EXIT_INTERRUPTED)

    def loads_a_module(args):
        @dataclasses.dataclass
        class Network:
            extra: object = _Interrupting()

    assert _run(SimpleNamespace(command="calibrate", func=loads_a_module)) == EXIT_INTERRUPTED
    assert "Traceback" not in capsys.readouterr().err

    def fails(args):
        raise RuntimeError("a bug")

    with pytest.raises(RuntimeError, match="a bug"):
        _run(SimpleNamespace(command="calibrate", func=fails))


_CTRL_C_IN_A_CALLBACK = """
import os, signal, sys, time, weakref
import pedcal.interrupts as interrupts
interrupts.install()
class Held: pass
held = Held()
def callback(_):
    os.kill(os.getpid(), signal.SIGINT)      # the handler runs here, inside the weakref's callback
ref = weakref.ref(held, callback)
del held
time.sleep(5)
print("not interrupted", file=sys.stderr)
"""


def _run_script(code: str):
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def test_ctrl_c_whose_handler_runs_in_a_weakref_callback_still_ends_the_command():
    """Python ignores an exception raised in a weakref's callback (it prints 'Exception ignored' and a
    traceback, and the work goes on): a Ctrl-C that lands there (CI saw one in importlib's module
    lock) still exits 130 with the one line 'interrupted', printed once."""
    proc = _run_script(_CTRL_C_IN_A_CALLBACK)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr == "interrupted\n"


def test_a_ctrl_c_after_the_command_line_ended_changes_nothing():
    """Once the command has ended (its outputs written, its code set) the interpreter shuts down,
    and its finalization gives SIGINT its default back: a Ctrl-C there ended the process by the
    signal without a word. The command line now ignores a Ctrl-C from its end on: its code stands."""
    code = ("import os, signal, sys, time\nimport pedcal.interrupts as interrupts\n"
            "interrupts.running_the_command_line = lambda: True\n"       # (as `python -m pedcal.cli` is)
            "from pedcal.cli import main\n"
            "code = main(['calibrate', '--help'])\n"
            "os.kill(os.getpid(), signal.SIGINT)\ntime.sleep(0.2)\n"
            "print('ended with', code, file=sys.stderr)\nsys.exit(code)\n")
    proc = _run_script(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "ended with 0\n"


def test_a_ctrl_c_rescued_by_the_alarm_just_before_the_end_still_ends_in_130():
    """A Ctrl-C whose handler ran in a finalizer as the command ended leaves the hook's alarm
    pending: the end cancels it and exits 130, as 'interrupted' announced, instead of leaving the
    alarm to kill the process during the shutdown (142, 'Alarm clock')."""
    code = _CTRL_C_IN_A_CALLBACK.replace("time.sleep(5)\n", "interrupts.command_ended()\nsys.exit(0)\n")
    assert code != _CTRL_C_IN_A_CALLBACK
    proc = _run_script(code)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr == "interrupted\n"


def test_another_unraisable_error_still_reaches_the_hook_before_pedcals():
    """The hook that rescues the lost Ctrl-C passes any other ignored exception on unchanged."""
    code = ("import sys, weakref\nimport pedcal.interrupts as interrupts\n"
            "seen = []\nsys.unraisablehook = lambda u: seen.append(type(u.exc_value).__name__)\n"
            "previous = interrupts.install()\n"
            "class Held: pass\nheld = Held()\n"
            "def callback(_): raise ValueError('from a library')\n"
            "ref = weakref.ref(held, callback)\ndel held\n"
            "interrupts.restore(previous)\n"
            "print(seen, sys.unraisablehook.__name__)\n")
    proc = _run_script(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["['ValueError']", "<lambda>"]


def test_a_caller_that_lives_on_after_a_ctrl_c_gets_its_logging_and_the_next_announcement_back(capsys):
    """``main`` called from Python: after its Ctrl-C (the handler's SystemExit, caught by the
    caller; the handler run twice, as when the alarm re-fires it) ``restore`` gives logging back at
    the level it had, announces the next Ctrl-C, and gives SIGALRM its handler back, the alarm off."""
    import logging
    from types import SimpleNamespace

    import pedcal.interrupts as interrupts

    def callers_alarm(signum, frame):
        pass

    old_alarm = signal.signal(signal.SIGALRM, callers_alarm)
    try:
        for level in (logging.DEBUG, logging.INFO):        # the caller's own level, kept through
            logging.disable(level)
            previous = interrupts.install()
            try:
                for _ in range(2):
                    with pytest.raises(SystemExit):
                        interrupts._on_sigint(signal.SIGINT, None)
                    assert logging.root.manager.disable == logging.CRITICAL
                # the hook answers the handler's SystemExit lost in a callback: an alarm (held back here,
                # a loaded machine could let it fire inside the test), twice as when it lands in another
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
                for _ in range(2):
                    interrupts._on_unraisable(SimpleNamespace(exc_value=SystemExit(interrupts.EXIT_INTERRUPTED)))
                assert signal.getsignal(signal.SIGALRM) is interrupts._on_sigint
            finally:
                interrupts.restore(previous)
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGALRM})   # (a pending one: the caller's)
            assert logging.root.manager.disable == level
            assert capsys.readouterr().err == "interrupted\n"
            assert signal.getsignal(signal.SIGALRM) is callers_alarm
            assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)
    finally:
        logging.disable(logging.NOTSET)
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old_alarm)


def test_json_output_is_strict_json_without_nan():
    """--json output is RFC 8259 JSON: a figure with no value (a recall over no person) is null, not
    a bare NaN that jq and JavaScript refuse; NumPy values and paths are plain."""
    import json
    from pathlib import Path

    import numpy as np

    from pedcal.jsontext import dumps

    text = dumps({"recall": float("nan"), "worst": np.float64(np.inf), "n": np.int64(3),
                  "bands": [np.nan, 0.5], "xy": np.array([1.0, np.nan]), "file": Path("a/b.pcd")})
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"recall": None, "worst": None, "n": 3, "bands": [None, 0.5], "xy": [1.0, None],
                                "file": "a/b.pcd"}


def test_detect_eval_json_with_no_person_in_view_is_valid_json(capsys):
    """A simulated evaluation whose frames hold no person in some band prints JSON that parses."""
    import json

    assert main(["detect-eval", "--frames", "1", "--seed", "2", "--json"]) == 0   # bands with nobody in them
    out = capsys.readouterr().out
    assert "NaN" not in out
    bands = json.loads(out)["bands"]
    assert any(b["people"] == 0 and b["recall"] is None for b in bands)      # no person: no recall, null


def test_simulate_refuses_a_scenario_file_it_would_overwrite(tmp_path, capsys):
    """simulate -o D writes D/scenario.yaml: a scenario file there is an input the output would
    replace, refused before anything is written; beside it, it is read."""
    import shutil

    from pedcal.sim.scenario import DATASETS_DIR

    out = tmp_path / "run"
    out.mkdir()
    shutil.copy(DATASETS_DIR / "paper.yaml", out / "scenario.yaml")
    before = (out / "scenario.yaml").read_bytes()
    assert main(["simulate", str(out / "scenario.yaml"), "-o", str(out), "-q"]) == 2
    assert "scenario file is among what simulate writes" in capsys.readouterr().err
    assert (out / "scenario.yaml").read_bytes() == before and sorted(p.name for p in out.iterdir()) == ["scenario.yaml"]


def test_only_the_command_line_process_spares_the_cycle_collector(tmp_path):
    """The command line's process loads a command's libraries without the cycle collector's
    passes and moves them out of its sight (gc.freeze), the collector on again for the work, and
    freezes what is left before it exits; a library caller's process (main called from Python) is
    left alone."""
    import gc
    import subprocess
    import sys

    write_log(small_log(), tmp_path / "log")
    assert main(["simulate", "--help"]) == 0
    assert main(["calibrate", str(tmp_path / "log"), "-o", str(tmp_path / "in.yaml"), "--method", "closedform",
                 "-q"]) == 0
    assert gc.get_freeze_count() == 0 and gc.isenabled()
    # the method's module imported by the command while it loads (collector off, nothing frozen
    # yet), then by calibrate() (collector on, the loading's freeze done); the exit's freeze after
    # main() returned 0 adds what the command made
    code = ("import gc, importlib, sys; sys.argv[0] = 'pedcal'; from pedcal.cli import main; seen = []; "
            "load = importlib.import_module; "
            "importlib.import_module = lambda name, *a: (seen.append((gc.isenabled(), gc.get_freeze_count())), "
            "load(name, *a))[1]; "
            f"rc = main(['calibrate', {str(tmp_path / 'log')!r}, '-o', {str(tmp_path / 'out.yaml')!r}, "
            "'--method', 'closedform', '-q']); "
            "print(rc, *seen[0], *seen[-1], gc.isenabled(), gc.get_freeze_count())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    rc, first_enabled, first_frozen, last_enabled, loading_frozen, enabled, exit_frozen = \
        out.strip().splitlines()[-1].split()
    assert (int(rc), first_enabled, int(first_frozen), last_enabled, enabled) == (0, "False", 0, "True", "True")
    assert int(loading_frozen) > 0                     # the loading's freeze
    assert int(exit_frozen) > int(loading_frozen)      # the exit's


def test_command_line_process_that_fails_leaves_the_exit_s_collection_alone(tmp_path):
    """A command that fails (exit 2) is not followed by the exit's freeze: the interpreter's last
    collection still finalizes the cyclic garbage it left (an unclosed writer in a cycle is flushed);
    the loading's freeze alone happened."""
    import subprocess
    import sys

    (tmp_path / "log").mkdir()
    code = ("import gc, sys; sys.argv[0] = 'pedcal'; from pedcal.cli import main; freeze = gc.freeze; calls = []; "
            "gc.freeze = lambda: (calls.append(1), freeze())[1]; "
            f"rc = main(['calibrate', {str(tmp_path / 'log')!r}, '-o', {str(tmp_path / 'out.yaml')!r}, "
            "'--method', 'closedform', '-q']); "
            "print(rc, len(calls))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == f"{EXIT_BAD_INPUT} 1"


def test_warnings_of_a_folder_written_all_at_once_name_the_folder(tmp_path, capsys, shared_data):
    """import-bag writes into a temporary sibling that takes the folder's place: its warning (no
    sensors.yaml) names the folder the user gave, not the temporary."""
    out = tmp_path / "amcl"
    code = main(["import-bag", str(shared_data / "amcl_uf_retail" / "amcldata.txt"), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0 and (out / "robot.csv").is_file()
    assert f"{out} has no sensors.yaml" in err
    assert ".tmpdir" not in err


def test_evaluate_on_a_log_without_truth_says_what_it_cannot_compute(tmp_path, capsys):
    log_dir = tmp_path / "log"
    write_log(small_log(), log_dir)
    assert not (log_dir / "truth.yaml").exists()
    code, err = run(capsys, ["evaluate", str(log_dir), "--extrinsics", str(log_dir / "sensors.yaml")])
    assert code == 0
    assert f"{log_dir} has no truth.yaml: sensor position and orientation errors cannot be computed (left empty)" in err


def test_a_simulation_that_fails_at_the_end_leaves_the_previous_run(tmp_path, capsys, monkeypatch):
    """calib/, eval/ and scenario.yaml are written in turn: a failure at scenario.yaml (or a Ctrl-C
    after calib/) left the new seed's calib/ beside the previous seed's eval/."""
    import pedcal.sim

    scenario = tmp_path / "short.yaml"
    scenario.write_text("base: paper\nduration_s: 20\n")
    out = tmp_path / "run"
    assert main(["simulate", str(scenario), "-o", str(out), "--seed", "0", "-q"]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def refuse(path, text):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(pedcal.sim, "write_text_atomic", refuse)
    capsys.readouterr()
    assert main(["simulate", str(scenario), "-o", str(out), "--seed", "1", "-q"]) == 2
    assert f"{out / 'scenario.yaml'}: Permission denied" in capsys.readouterr().err
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "short.yaml"]


def test_an_input_error_inside_a_folder_written_all_at_once_names_the_folder(tmp_path, capsys, monkeypatch):
    """A PedcalInputError raised while simulate writes into its temporary sibling names the
    folder the user gave, in its message, path and detail, never the temporary."""
    from pathlib import Path

    import pedcal.sim
    from pedcal.cli import _rename_in_error
    from pedcal.errors import PedcalInputError

    scenario = tmp_path / "short.yaml"
    scenario.write_text("base: paper\nduration_s: 20\n")
    out = tmp_path / "run"

    def refuse(path, text):
        assert ".tmpdir" in str(path)                   # the writer is given the temporary's path
        raise PedcalInputError(f"refused, beside {Path(path).parent}/calib", path=path, row=2)

    monkeypatch.setattr(pedcal.sim, "write_text_atomic", refuse)
    assert main(["simulate", str(scenario), "-o", str(out), "--seed", "1", "-q"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert f"{out / 'scenario.yaml'}, row 2: refused, beside {out}/calib" in err and ".tmpdir" not in err
    e = PedcalInputError(f"refused, beside {tmp_path}/x.tmpdir/calib", path=tmp_path / "x.tmpdir" / "s.yaml", row=2)
    _rename_in_error(e, str(tmp_path / "x.tmpdir"), str(tmp_path / "x"))
    assert (e.path, e.detail, str(e)) == (str(tmp_path / "x" / "s.yaml"), f"refused, beside {tmp_path}/x/calib",
                                          f"{tmp_path / 'x' / 's.yaml'}, row 2: refused, beside {tmp_path}/x/calib")


def test_evaluate_names_the_extrinsics_sensors_the_log_does_not_have(tmp_path, capsys):
    log_dir = tmp_path / "log"
    write_log(small_log(), log_dir)
    ext = tmp_path / "ext.yaml"
    ext.write_text((log_dir / "sensors.yaml").read_text().replace("id: s02", "id: s99"))
    code, err = run(capsys, ["evaluate", str(log_dir), "--extrinsics", str(ext)])
    assert code == 0
    assert f"{ext}: 1 sensor(s) not in the log's sensors.yaml, not scored: s99" in err


def test_evaluate_lists_at_most_ten_foreign_sensors_in_its_warning_and_its_table(tmp_path, capsys):
    """The warning named the first 10 of a file of another site's sensors, and the table under it
    all of them again on one line; both now show the first 10 and how many in all."""
    log_dir = tmp_path / "log"
    write_log(small_log(), log_dir)
    ext = tmp_path / "ext.yaml"
    foreign = [f"x{i:02d}" for i in range(14)]
    write_sensors_yaml(SensorNetwork([SensorExtrinsics(sid, [i, 0, 2.6], [0, 45, 0]) for i, sid in enumerate(foreign)]
                                     + [small_log().sensors["s01"]]), ext)
    assert main(["evaluate", str(log_dir), "--extrinsics", str(ext)]) == 0
    out, err = capsys.readouterr()
    shown = "x00, x01, x02, x03, x04, x05, x06, x07, x08, x09, ... (14 in all)"
    assert f"{ext}: 14 sensor(s) not in the log's sensors.yaml, not scored: {shown}\n" in err
    assert f"not in the log's sensors.yaml (not scored): {shown}" in out.splitlines()
    assert "x10" not in out + err
