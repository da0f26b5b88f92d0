"""``pedcal follow-bench`` on a small subset of the real recordings: eligible targets, the per-recording
distribution, and the worst episode's replay command giving the same figures."""

import json
import shlex

import pandas as pd
import pytest

from pedcal.cli import main


def test_eligible_targets_are_the_long_present_people():
    from pedcal.track.follow_bench import eligible_targets

    people = pd.DataFrame({"t": [0.0, 50.0, 10.0, 40.0, 0.0, 60.0], "person": ["a", "a", "b", "b", "c", "c"],
                           "x": 0.0, "y": 0.0})
    assert list(eligible_targets(people, 45.0)["person"]) == ["c", "a"]
    assert list(eligible_targets(people, 45.0, max_targets=1)["person"]) == ["c"]


def test_follow_bench_on_zara_and_hotel(shared_data, tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["follow-bench", "--data-dir", str(shared_data), "--files", "eth_ucy/crowds_zara01.txt",
                 "eth_ucy/biwi_hotel.txt", "--trackers", "paper", "lidar-only", "--seeds", "1", "-o", str(out),
                 "-q"]) == 0
    episodes = pd.read_parquet(out / "episodes.parquet")
    # ZARA01 has one person present >= 45 s; HOTEL none (listed with its longest presence)
    assert sorted(episodes["tracker"]) == ["lidar-only", "paper"] and episodes["target"].nunique() == 1
    summary = pd.read_csv(out / "summary.csv")
    assert len(summary) == 2 and (summary["median"] == summary["worst"]).all()
    md = (out / "bench.md").read_text()
    assert "| eth_ucy/biwi_hotel.txt | " in md and "| 0 |" in md
    for tracker in ("paper", "lidar-only"):
        assert (out / "figures" / f"worst_crowds_zara01_{tracker}.png").stat().st_size > 1000
    # the worst episode's command replays it exactly
    row = summary[summary["tracker"] == "paper"].iloc[0]
    argv = shlex.split(row["worst_command"])[1:]
    argv[argv.index("-o") + 1] = str(tmp_path / "replay")
    capsys.readouterr()
    assert main([*argv, "--json"]) == 0
    replay = json.loads(capsys.readouterr().out)
    assert replay["with_target_fraction"] == pytest.approx(row["worst"])


def test_follow_bench_missing_recording_exits_2(tmp_path, capsys):
    (tmp_path / "data").mkdir()
    assert main(["follow-bench", "--data-dir", str(tmp_path / "data"), "--files", "nope.csv", "-o",
                 str(tmp_path / "o")]) == 2
    assert "nope.csv" in capsys.readouterr().err


def test_summary_worst_episode_is_the_minimum_of_several():
    from pedcal.track.follow_bench import summarize

    w = [0.9, 0.4, 0.95, 0.7]  # the worst neither first nor last
    episodes = pd.DataFrame({"recording": "r.csv", "tracker": "paper", "target": ["a", "b", "c", "d"],
                             "seed": [0, 1, 2, 0], "with_target_fraction": w, "near_fraction": 1.0,
                             "followed_to_end": True, "id_switches": 0, "mean_reacquire_s": None,
                             "robot_contacts": [0, 2, 0, 1], "frames": [100, 100, 200, 100],
                             "contact_frame_fraction": [0.0, 0.03, 0.0, 0.01],
                             "contacts_per_min": [0.0, 4.8, 0.0, 2.4], "min_clearance_m": [0.3, -0.1, 0.2, 0.0],
                             "replay": [f"cmd {t}" for t in "abcd"]})
    (row,) = summarize(episodes).itertuples()
    assert row.worst == 0.4 and row.worst_target == "b" and row.worst_seed == 1 and row.worst_command == "cmd b"
    assert row.median == pytest.approx(0.8) and row.p10 == pytest.approx(0.49)
    # contacts pooled over all frames, not averaged over episodes
    assert row.robot_contacts == 3 and row.contact_frames == pytest.approx(4 / 500)
    assert row.contacts_per_min == pytest.approx(3 / (500 / 4.0 / 60.0))
    assert row.min_clearance_m == pytest.approx(-0.1)


def test_a_bench_with_no_eligible_target_says_so(tmp_path):
    """Nobody present long enough in any recording: the empty bench is written with a warning naming
    each recording's longest presence, not in silence."""
    from pedcal.errors import DegenerateDataWarning
    from pedcal.track.follow_bench import run_follow_bench

    data = tmp_path / "data"
    data.mkdir()
    (data / "people.csv").write_text("t,person,x,y\n0,a,0,0\n12.5,a,1,0\n0,b,2,0\n3,b,2,1\n")
    with pytest.warns(DegenerateDataWarning, match=r"no episode to run: no person is present for --min-duration "
                                                   r"45 s in any recording \(longest: people.csv 12.5 s\)"):
        path = run_follow_bench(data, tmp_path / "out", files=["people.csv"], trackers=["paper"], seeds=1,
                                progress=False)
    assert "| people.csv | 2 | 0 | 12.5 |" in path.read_text()


def test_a_bench_that_fails_while_writing_leaves_the_previous_folder(tmp_path, capsys, monkeypatch):
    """bench.md, the tables and the figures change together: a failure after the tables and figures
    were written (bench.md refused) leaves the folder of the previous run, nothing of the new one."""
    import numpy as np

    import pedcal.track.follow_bench as fb

    data = tmp_path / "data"
    data.mkdir()
    t = np.arange(0.0, 12.0, 0.4)
    rows = [f"{ti:.1f},{p},{x0 + 1.0 * ti:.3f},{y0}\n" for p, x0, y0 in (("a", 0.0, 0.0), ("b", 3.0, 2.0))
            for ti in t]
    (data / "people.csv").write_text("t,person,x,y\n" + "".join(rows))
    out = tmp_path / "bench"
    argv = ["follow-bench", "--data-dir", str(data), "--files", "people.csv", "--trackers", "paper", "--seeds", "1",
            "--min-duration", "5", "--max-targets", "1", "-o", str(out), "-q"]
    assert main(argv) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert (out / "bench.md").is_file() and (out / "episodes.parquet").is_file()

    def refuse(path, text):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(fb, "write_text_atomic", refuse)
    assert main([*argv, "--seeds", "2"]) == 2
    assert f"{out / 'bench.md'}: Permission denied" in capsys.readouterr().err
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench", "data"]
