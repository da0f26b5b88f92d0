import os
import stat

import pytest

from pedcal.io.atomic import atomic_path, write_text_atomic


def test_written_file_has_the_mode_of_a_plain_open(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "out.txt", "x")
        (tmp_path / "plain.txt").write_text("x")
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "out.txt").stat().st_mode)
    assert mode == stat.S_IMODE((tmp_path / "plain.txt").stat().st_mode) == 0o644


def test_failure_leaves_no_output_and_no_temporary(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("bad input")
    assert list(tmp_path.iterdir()) == []


def test_temporary_of_a_killed_writer_is_removed_by_the_next_write(tmp_path):
    """SIGKILL mid-write: the target keeps a complete content, the temporary left behind is removed by
    the next write; the temporary of a writer still running is left alone by a concurrent write."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    target = tmp_path / "out.csv"
    target.write_text("old\n")
    writer = ("import sys, time\nfrom pedcal.io.atomic import atomic_path\n"
              "with atomic_path(sys.argv[1]) as tmp:\n"
              "    f = open(tmp, 'w'); f.write('half'); f.flush(); print('writing', flush=True); time.sleep(60)\n")
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", writer, str(target)], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(root)})
    try:
        assert proc.stdout.readline().strip() == "writing"
        running = list(tmp_path.glob(".out.csv.*.tmp"))
        assert len(running) == 1
        write_text_atomic(target, "concurrent\n")     # a concurrent run's write leaves the live temporary
        assert running[0].exists()
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    time.sleep(0.05)
    assert target.read_text() == "concurrent\n" and running[0].exists()
    write_text_atomic(target, "new\n")
    assert target.read_text() == "new\n"
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".*.tmp"))
