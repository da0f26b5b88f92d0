"""Following simulation: visibility and occlusion, the identity metrics on a hand-made log, the
``pedcal follow`` command and its input errors."""

import json

import numpy as np
import pandas as pd
import pytest

from pedcal.cli import main
from pedcal.sim.follow import box_map, reflectance_histogram, visible_people
from pedcal.track.follow import METRIC_KEYS, follow_metrics, match_people

POSE = np.array([0.0, 0.0, 0.0])


# ------------------------------------------------------------------------------------- visibility
def test_person_behind_a_wall_is_not_visible():
    occ = box_map((-2.0, -4.0, 8.0, 4.0), [(2.0, 0.5, 2.3, 3.0)])  # a wall segment at x = 2..2.3, y = 0.5..3
    people = np.array([[3.0, 0.0], [3.5, 1.5], [1.0, 1.0]])
    vis = visible_people(POSE, people, occ)
    assert vis.tolist() == [True, False, True]


def test_person_behind_another_person_is_not_visible():
    people = np.array([[3.0, 0.0], [1.5, 0.1], [1.5, 1.0]])
    vis = visible_people(POSE, people, None)
    assert vis.tolist() == [False, True, True]  # person 0 hidden by person 1 (0.1 m off its ray)


def test_field_of_view_limits():
    people = np.array([[-2.0, 0.0], [0.2, 0.0], [5.5, 0.0], [1.0, 1.9], [1.0, 1.5]])
    # behind, too near, too far, 62 deg off axis, 56 deg off axis
    assert [bool(visible_people(POSE, p[None], None)[0]) for p in people] == [False, False, False, False, True]


def test_reflectance_histogram_normalized_and_distinct():
    rng = np.random.default_rng(0)
    a = reflectance_histogram((8.0, 3.0), rng)
    b = reflectance_histogram((3.0, 8.0), rng)
    assert a.shape == (25,) and a.sum() == pytest.approx(1.0)
    assert np.argmax(a) > np.argmax(b)


def test_match_people_one_to_one_within_gate():
    people = np.array([[0.0, 0.0], [1.0, 0.0]])
    tracks = np.array([[0.9, 0.1], [0.1, 0.0], [5.0, 5.0]])
    assert sorted(match_people(people, tracks)) == [(0, 1), (1, 0)]


# ---------------------------------------------------------------------------------------- metrics
def hand_log():
    """12 frames at 4 Hz: init (2), holding (3), target occluded while the tracker coasts (1),
    the tracker claims the passer 'p' (2), then nobody (1), then the target again (3)."""
    t = np.arange(12) * 0.25
    vis = [True, True, True, True, True, False, True, True, True, True, True, True]
    tid = [None, None, 1, 1, 1, 1, 1, 1, None, 4, 4, 4]
    claimed = [None, None, "T", "T", "T", None, "p", "p", None, "T", "T", "T"]
    state = ["Initialize"] * 2 + ["Tracking"] * 6 + ["Lost"] + ["Tracking"] * 3
    return pd.DataFrame({"t": t, "target_visible": vis, "target_track_id": pd.array(tid, dtype="Int64"),
                         "claimed_person": pd.Series(claimed, dtype=object), "state": state,
                         "target_x": 1.0, "target_y": 0.0,
                         "est_target_x": [np.nan, np.nan] + [1.0] * 3 + [1.3] + [1.0] * 6, "est_target_y": 0.0})


def test_follow_metrics_on_a_hand_made_log():
    m = follow_metrics(hand_log(), "T")
    # counted from frame 2 on: 10 frames; wrong: frames 6, 7 (passer claimed), 8 (visible, nobody claimed)
    assert m["frames"] == 12
    assert m["target_correct_fraction"] == pytest.approx(7 / 10)
    assert m["id_switches"] == 2  # T -> p -> T
    assert m["lost_episodes"] == 1  # holding up to frame 5 (coasting on track 1), lost at frame 6
    assert m["mean_reacquire_s"] == pytest.approx(0.75) and m["max_reacquire_s"] == pytest.approx(0.75)
    assert m["followed_to_end"] is True
    assert m["searching_episodes"] == 0 and m["searching_frames"] == 0
    assert m["lost_position_error_m"] == pytest.approx(0.3)


def test_follow_metrics_never_recovered():
    log = hand_log().iloc[:9]
    m = follow_metrics(log, "T")
    assert m["mean_reacquire_s"] is None and m["followed_to_end"] is False


# -------------------------------------------------------------------------------------------- CLI
def test_cli_follow_json_keys(capsys, tmp_path):
    assert main(["follow", "passing", "--json", "--seed", "1", "-o", str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out) == list(METRIC_KEYS)
    assert out["frames"] > 50 and 0.0 <= out["target_correct_fraction"] <= 1.0
    saved = json.loads((tmp_path / "follow.json").read_text())
    assert saved["scenario"] == "passing" and saved["frames"] == out["frames"]
    log = pd.read_parquet(tmp_path / "follow_log.parquet")
    assert len(log) == out["frames"] and {"t", "robot_x", "est_x", "target_x", "state"} <= set(log.columns)


def people_csv(path, ids=("a", "b")):
    t = np.arange(0.0, 12.0, 0.4)
    rows = []
    for k, pid in enumerate(ids):
        rows += [{"t": ti, "person": pid, "x": 0.7 * ti, "y": 1.0 * k} for ti in t]
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def test_cli_follow_people_csv(capsys, tmp_path):
    p = people_csv(tmp_path / "people.csv")
    assert main(["follow", "--people", str(p), "--target", "a", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 47 and out["target_correct_fraction"] > 0.5


def test_cli_follow_absent_target_exits_2(capsys, tmp_path):
    p = people_csv(tmp_path / "people.csv")
    assert main(["follow", "--people", str(p), "--target", "zz"]) == 2
    err = capsys.readouterr().err
    assert "'zz'" in err and "people.csv" in err and "Traceback" not in err


def test_cli_follow_bad_csv_exits_2(capsys, tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("t,person,x\n0,a,1\n")
    assert main(["follow", "--people", str(p), "--target", "a"]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "y" in err


def test_cli_follow_unknown_scenario_exits_2(capsys):
    assert main(["follow", "nowhere"]) == 2
    assert "passing" in capsys.readouterr().err
