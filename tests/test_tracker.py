"""The paper tracker and the LIDAR-only follower on small constructed frame sequences: association,
target probability (eqs. 9-14) on a worked example, and every state transition of Sec. 5."""

import numpy as np
import pytest

from pedcal.follow_types import EsparReading, FollowFrame, PersonDetection
from pedcal.track.appearance import OnlineBoost
from pedcal.track.tracker import (
    LidarOnlyTracker,
    MultiPersonCore,
    PaperTracker,
    TargetProbability,
    TrackerConfig,
    association_likelihood,
    greedy_assign,
)
from pedcal.track.trackers import make_tracker

DT = 0.25
B = 8
ANTENNAS = (np.array([0.0, 0.15]), np.array([0.0, -0.15]))
POSE0 = np.zeros(3)
COV0 = np.diag([1e-4, 1e-4, 1e-5])


def hist(k: int) -> np.ndarray:
    """A distinctive reflectance histogram per person (mass in bins 2k, 2k+1)."""
    h = np.full(B, 0.02)
    h[2 * k:2 * k + 2] = 0.4
    return h / h.sum()


def readings_towards(xy_robot_m) -> tuple[EsparReading, ...]:
    """Noise-free readings of both antennas: the direction nearest the target's bearing."""
    out = []
    for a, ant in enumerate(ANTENNAS):
        d = np.asarray(xy_robot_m, float) - ant
        k = int(np.rint(np.arctan2(d[1], d[0]) / (np.pi / 6))) % 12
        out.append(EsparReading(a, k, float(np.mod(k * np.pi / 6 + np.pi, 2 * np.pi) - np.pi), ant))
    return tuple(out)


def frame(k: int, people: dict[int, np.ndarray], espar_xy=None, stopped=False) -> FollowFrame:
    """Frame k with the robot at the origin facing +x: a detection for each visible person (id ->
    xy), readings towards ``espar_xy`` when given."""
    dets = tuple(PersonDetection(np.asarray(xy, float), 1.7, 0.9, hist(pid)) for pid, xy in people.items())
    return FollowFrame(k * DT, POSE0, COV0, dets, () if espar_xy is None else readings_towards(espar_xy), stopped)


TARGET = np.array([3.0, 0.0])
OTHER = np.array([0.5, 3.0])


def run(tracker, frames):
    return [tracker.step(f) for f in frames]


# ------------------------------------------------------------------------------------ association
def test_greedy_assignment_by_decreasing_likelihood_with_gate():
    d = np.array([[0.5, 1.0, 5.0], [0.4, 2.0, 4.0]])
    e = np.full(d.shape, 0.5)
    l = association_likelihood(d, e)
    assert l[0, 0] == pytest.approx(np.exp(-0.125) / np.sqrt(2 * np.pi) * 0.5)
    # (1, 0) has the highest l; filter 0 then takes detection 1; detection 2 is beyond the gate.
    assert greedy_assign(l, d, gate=3.0) == [(1, 0), (0, 1)]
    assert greedy_assign(np.zeros((0, 2)), np.zeros((0, 2)), 3.0) == []


def test_appearance_picks_the_target_among_two_near_detections():
    core = MultiPersonCore(TrackerConfig())
    # The target (appearance 0) walks beside person 1 for a few frames; the classifier learns them.
    for k in range(1, 9):
        core.manage(core.step(frame(k, {0: TARGET, 1: TARGET + [0.0, 1.2]})))
        if k == 2:
            core.set_target(0)
    assert core.appearance is not None and core.appearance.ready
    x_before = core.tracks[0].xy.copy()
    # Now the impostor stands closer to the target's prediction than the target itself.
    impostor = PersonDetection(x_before + [0.0, 0.08], 1.7, 0.9, hist(1))
    true = PersonDetection(x_before + [0.0, -0.15], 1.7, 0.9, hist(0))
    f = FollowFrame(9 * DT, POSE0, COV0, (impostor, true), (), False)
    core.step(f)
    assert core.tracks[0].xy[1] < x_before[1]  # pulled towards the true (appearance) detection
    # Without the classifier (e = 0.5 for every filter) the nearer impostor wins.
    core2 = MultiPersonCore(TrackerConfig())
    core2.step(frame(1, {0: TARGET}))
    core2.step(FollowFrame(2 * DT, POSE0, COV0, (impostor, true), (), False))
    nearest = core2.tracks[0].xy
    assert nearest[1] > true.xy_robot_m[1] + 0.05


# ----------------------------------------------------------------------------- target probability
def test_target_probability_worked_example():
    tp = TargetProbability(p_min=0.0)
    tp.add(0, 0.5)  # P(T=0) = 0.5, P_lost = 0.5
    tp.add(1, 0.6)  # P(T=1) = 0.3, P_lost = 0.2
    assert tp.p == pytest.approx({0: 0.5, 1: 0.3}) and tp.p_lost == pytest.approx(0.2)
    # Eq. 9 with P(Z|A_0) = 0.6, P(Z|A_1) = 0.1, P(Z|lost) = 1/12:
    # 0.5 * 0.6 = 0.3, 0.3 * 0.1 = 0.03, 0.2 / 12 = 0.016667; their sum is 0.346667.
    tp.update({0: 0.6, 1: 0.1}, 1 / 12)
    assert tp.p[0] == pytest.approx(0.3 / 0.346667, abs=1e-5)
    assert tp.p[1] == pytest.approx(0.03 / 0.346667, abs=1e-5)
    assert tp.p_lost == pytest.approx(0.016667 / 0.346667, abs=1e-5)
    # A deleted filter's probability goes to P_lost.
    tp.remove(0)
    assert tp.p_lost == pytest.approx((0.3 + 0.016667) / 0.346667, abs=1e-5)
    assert sum(tp.p.values()) + tp.p_lost == pytest.approx(1.0)
    assert tp.best() == (1, pytest.approx(0.03 / 0.346667, abs=1e-5))


def test_target_probability_floor_keeps_hypotheses_alive():
    tp = TargetProbability(p_min=1e-3)
    tp.add(0, 0.5)
    tp.update({0: 1e-9}, 1 / 12)
    assert tp.p[0] >= 1e-3 * 0.99 and tp.p[0] + tp.p_lost == pytest.approx(1.0)


# -------------------------------------------------------------------------------- state machine
def initialized(tracker: PaperTracker, n=6):
    outs = run(tracker, [frame(k, {0: TARGET, 1: OTHER}, espar_xy=TARGET) for k in range(1, n + 1)])
    return outs


def test_initialize_to_tracking_picks_the_filter_the_antenna_points_at():
    tr = PaperTracker()
    outs = initialized(tr)
    assert outs[0].state == "Initialize" and outs[0].target_track_id is None
    assert outs[-1].state == "Tracking"
    tid = outs[-1].target_track_id
    np.testing.assert_allclose(outs[-1].target_xy_world_m, TARGET, atol=0.05)
    # Chosen no earlier than the readings allow, with P(T) above the threshold.
    first = next(i for i, o in enumerate(outs) if o.state == "Tracking")
    assert 2 * (first + 1) >= tr.config.init_min_readings
    p = {e.track_id: e.p_target for e in outs[first].tracks}
    assert p[tid] > 0.7 and max(v for i, v in p.items() if i != tid) < 0.3


def test_tracking_to_lost_when_the_target_filter_is_deleted_then_searching_with_stop():
    tr = PaperTracker(lost_to_search_s=1.0)
    outs = initialized(tr)
    last = outs[-1].target_xy_world_m.copy()
    # The target vanishes (no detection, no antenna reading): its filter's entropy rises -> Lost.
    k0 = 7
    outs = run(tr, [frame(k, {1: OTHER}) for k in range(k0, k0 + 4)])
    states = [o.state for o in outs]
    assert "Lost" in states
    lost = outs[states.index("Lost")]
    assert lost.target_track_id is None and lost.target_xy_world_m is not None
    assert np.linalg.norm(lost.target_xy_world_m - last) < 0.3  # the last estimate
    assert not lost.stop_robot
    # Lost for lost_to_search_s -> Searching: the robot is asked to stop.
    outs = run(tr, [frame(k, {1: OTHER}) for k in range(k0 + 4, k0 + 8)])
    assert outs[-1].state == "Searching" and outs[-1].stop_robot and outs[-1].goal_xy_world_m is None
    # Stopped, the grid accumulates 10 readings (5 frames of two antennas); then it sets a goal.
    hidden = np.array([2.0, -2.0])  # out of the LIDAR's sight, the antenna still hears it
    outs = run(tr, [frame(k, {1: OTHER}, espar_xy=hidden, stopped=True) for k in range(k0 + 8, k0 + 13)])
    assert all(o.stop_robot for o in outs[:-1])
    assert not outs[-1].stop_robot and outs[-1].state == "Searching"
    goal = outs[-1].goal_xy_world_m
    bearing_err = np.degrees(abs(np.arctan2(goal[1], goal[0]) - np.arctan2(hidden[1], hidden[0])))
    assert bearing_err < 15.0  # within half a direction of the transmitter
    np.testing.assert_allclose(outs[-1].target_xy_world_m, goal)


def test_tracking_to_lost_when_the_antenna_points_elsewhere():
    tr = PaperTracker()
    outs = initialized(tr)
    tid = outs[-1].target_track_id
    # The transmitter is now behind the robot while the filter stays in front: P(T = tid) falls.
    outs = run(tr, [frame(k, {0: TARGET, 1: OTHER}, espar_xy=[-3.0, 0.0]) for k in range(7, 15)])
    states = [o.state for o in outs]
    assert "Lost" in states
    i = states.index("Lost")
    assert {e.track_id: e.p_target for e in outs[i].tracks}[tid] < 0.1
    assert all(s == "Tracking" for s in states[:i])


def test_searching_to_tracking_when_a_new_filter_gets_the_antennas_probability():
    tr = PaperTracker(lost_to_search_s=0.5)
    initialized(tr)
    run(tr, [frame(k, {1: OTHER}) for k in range(7, 14)])
    assert tr.state == "Searching"
    back = np.array([2.0, -2.0])
    outs = run(tr, [frame(k, {1: OTHER, 2: back}, espar_xy=back, stopped=True) for k in range(14, 24)])
    states = [o.state for o in outs]
    assert "Tracking" in states
    o = outs[states.index("Tracking")]
    p = {e.track_id: e.p_target for e in o.tracks}
    assert p[o.target_track_id] > 0.7
    np.testing.assert_allclose(o.target_xy_world_m, back, atol=0.1)
    assert not o.stop_robot


def test_occlusion_by_a_passer_by_fools_lidar_only_but_not_the_paper_tracker():
    """Fig. 7: the target is hidden for a second while a passer-by stands near its last position."""
    frames = [frame(k, {0: TARGET, 1: OTHER}, espar_xy=TARGET) for k in range(1, 9)]
    passer = TARGET + np.array([-0.6, 0.5])
    frames += [frame(k, {1: OTHER, 2: passer}, espar_xy=TARGET) for k in range(9, 14)]
    frames += [frame(k, {0: TARGET, 1: OTHER, 2: passer + [0.0, 0.6]}, espar_xy=TARGET) for k in range(14, 30)]
    lidar = run(LidarOnlyTracker(), frames)
    paper = run(PaperTracker(), frames)
    # The LIDAR-only follower now follows the passer-by; the paper tracker is back on the target.
    assert np.linalg.norm(lidar[-1].target_xy_world_m - TARGET) > 0.5
    assert paper[-1].state == "Tracking"
    np.testing.assert_allclose(paper[-1].target_xy_world_m, TARGET, atol=0.1)


def test_lidar_only_picks_the_nearest_filter_at_the_start_and_never_stops():
    outs = run(LidarOnlyTracker(), [frame(k, {0: TARGET, 1: OTHER + [5, 0]}) for k in range(1, 5)])
    assert outs[0].state == "Initialize"
    assert outs[-1].state == "Tracking"
    np.testing.assert_allclose(outs[-1].target_xy_world_m, TARGET, atol=0.05)
    assert not any(o.stop_robot for o in outs)


def test_make_tracker_knows_both_and_passes_options():
    assert make_tracker("paper").name == "paper"
    t = make_tracker("lidar-only", reacquire_radius_m=1.0)
    assert t.name == "lidar-only" and t.config.reacquire_radius_m == 1.0
    with pytest.raises(ValueError, match="unknown tracker"):
        make_tracker("nope")


def test_online_boost_separates_two_histograms():
    ob = OnlineBoost(B)
    assert ob.error(hist(0)[None])[0] == 0.5  # untrained
    rng = np.random.default_rng(0)
    for _ in range(20):
        ob.update(np.clip(hist(0) + rng.normal(0, 0.03, B), 0, None), True)
        ob.update(np.clip(hist(1) + rng.normal(0, 0.03, B), 0, None), False)
    e = ob.error(np.stack([hist(0), hist(1), hist(2)]))
    assert e[0] < 0.1 and e[1] > 0.9


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_paper_tracker_recovers_the_target_with_simulated_noisy_readings(seed):
    """The occlusion of Fig. 7 with the antenna simulator's noise and multipath: the passer-by is in
    the target's 30 deg direction, so it may be taken for a while; the target must be back once
    it is seen again."""
    from dataclasses import replace

    from pedcal.sim.espar import EsparParams, EsparSimulator

    sim = EsparSimulator(EsparParams(), np.random.default_rng(seed))
    passer = TARGET + np.array([-0.6, 0.5])
    frames = []
    for k in range(1, 40):
        people = {0: TARGET, 1: OTHER} if k < 9 else {1: OTHER, 2: passer} if k < 14 else \
            {0: TARGET, 1: OTHER, 2: passer + [0.0, 0.6]}
        frames.append(replace(frame(k, people), espar=sim.readings((k - 1) * DT, k * DT, TARGET)))
    outs = run(PaperTracker(), frames)
    assert all(o.state == "Tracking" for o in outs[-10:])
    np.testing.assert_allclose(outs[-1].target_xy_world_m, TARGET, atol=0.1)


def test_the_paper_tracker_does_not_import_the_factor_graph_tracker_and_sim_does_not_import_track():
    """Layering: the factor-graph tracker builds on the paper tracker; the simulator and the trackers
    share only pedcal.follow_types."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "pedcal"

    def imports(path: Path) -> set[str]:
        mods = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module:
                mods.add(node.module)
            elif isinstance(node, ast.Import):
                mods.update(a.name for a in node.names)
        return mods

    assert not any(m.startswith("pedcal.track.recovery") for m in imports(root / "track" / "tracker.py"))
    assert "pedcal.track.tracker" in imports(root / "track" / "recovery.py")
    for path in (root / "sim").glob("*.py"):
        assert not any(m.startswith("pedcal.track") for m in imports(path)), path.name


def test_a_filter_retaken_before_its_confirmation_keeps_its_probability():
    prob = TargetProbability()
    prob.p, prob.p_lost = {3: 0.7}, 0.3       # the factor-graph tracker re-took filter 3 while tentative
    prob.add(3, 0.05)                          # filter 3 is confirmed a frame later
    assert prob.p == {3: 0.7} and prob.p_lost == pytest.approx(0.3)
    prob.add(4, 0.05)
    assert prob.p[4] == pytest.approx(0.015) and prob.p_lost == pytest.approx(0.285)
