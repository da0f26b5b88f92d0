"""pedcal in research code: typed options refused up front, the factor graph's layout as
CalibrationResult documents it, re-optimizing with extra factors, results as tables, the YAML's
names in Python with the former ones as warning aliases, warnings at the caller's line."""

from __future__ import annotations

import warnings

import gtsam
import numpy as np
import pandas as pd
import pytest

import pedcal
from pedcal.calib import (
    ClosedFormOptions,
    FactorGraphOptions,
    GridSearchOptions,
    PedcalOptionError,
)
from pedcal.calib.common import FactorGraphDiagnostics
from pedcal.calib.crlb import CRLBResult
from pedcal.model import SensorExtrinsics, SensorNetwork


@pytest.fixture(scope="module")
def sim():
    return pedcal.simulate_logs("sparse", seed=0, duration_s=150)


@pytest.fixture(scope="module")
def fg(sim):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pedcal.calibrate(sim.calib)


# ------------------------------------------------------------------------------------------ options
def test_a_misspelled_option_is_refused_before_any_work_with_the_valid_names():
    with pytest.raises(PedcalOptionError) as err:
        pedcal.calibrate(None, method="gridsearch", angle_stepdeg=0.05)   # no log needed: refused first
    text = str(err.value)
    assert "angle_stepdeg" in text and "angle_step_deg" in text and "offset_range_m" in text
    assert isinstance(err.value, TypeError) and isinstance(err.value, pedcal.PedcalInputError)
    for method in ("factorgraph", "alternative", "closedform"):
        with pytest.raises(PedcalOptionError, match="nope"):
            pedcal.calibrate(None, method=method, nope=1)
    with pytest.raises(PedcalOptionError, match="head_radius_mm"):       # a recipe field misspelled
        FactorGraphOptions(recipe={"head_radius_mm": 0.05})
    with pytest.raises(PedcalOptionError, match="gate_mm"):
        ClosedFormOptions(association={"gate_mm": 1.0})


def test_options_dataclass_of_another_method_or_with_keywords_is_refused():
    with pytest.raises(PedcalOptionError, match="GridSearchOptions"):
        pedcal.calibrate(None, method="gridsearch", options=ClosedFormOptions())
    with pytest.raises(PedcalOptionError, match="not both"):
        pedcal.calibrate(None, options=GridSearchOptions(), angle_step_deg=0.1)
    with pytest.raises(pedcal.PedcalInputError, match="unknown calibration method 'grid'"):
        pedcal.calibrate(None, method="grid")


def test_keywords_and_dataclass_give_the_same_method_arguments():
    kw = dict(is_robot=None, angle_range_deg=8.0, angle_step_deg=0.1, offset_range_m=0.5, offset_step_m=0.01)
    assert GridSearchOptions.from_kwargs(**kw).to_kwargs() == kw
    cf = ClosedFormOptions.from_kwargs(latency_s=0.1, gate_m=2.0)
    assert cf.association == {"gate_m": 2.0} and cf.to_kwargs()["gate_m"] == 2.0 and cf.to_kwargs()["latency_s"] == 0.1
    fgo = FactorGraphOptions.from_kwargs(graph="robot-only", head_radius_m=0.07, sensor_height_sigma_m=0.01)
    out = fgo.to_kwargs()
    assert fgo.recipe == {"head_radius_m": 0.07} and out["head_radius_m"] == 0.07
    assert out["sensor_height_sigma_m"] == 0.01 and "ceiling_height_m" not in out    # None: the recipe's own


def test_closed_form_options_mirror_its_constants():
    """ClosedFormOptions writes the closed form's defaults out (AlternativeOptions is the alternative's
    own source of them)."""
    from pedcal.calib.closedform import COLLINEAR_SPREAD_M, MIN_PAIRS

    assert (ClosedFormOptions().min_pairs, ClosedFormOptions().collinear_spread_m) == (MIN_PAIRS, COLLINEAR_SPREAD_M)


def test_options_dataclass_runs_the_method(sim):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = pedcal.calibrate(sim.calib, options=ClosedFormOptions(latency_s=0.0))
        b = pedcal.calibrate(sim.calib, method="closedform", latency_s=0.0)
    assert a.method == "closedform" and a.diagnostics.tracker_latency_s == 0.0
    pd.testing.assert_frame_equal(a.to_dataframe(), b.to_dataframe())


def test_calibration_warnings_point_at_the_callers_line(sim):
    import inspect

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = inspect.currentframe().f_lineno + 1
        pedcal.calibrate(sim.calib)
    ours = [w for w in caught if issubclass(w.category, pedcal.errors.DegenerateDataWarning)]
    assert ours, "the head point's vertical offset without a height reference warns"
    assert all(w.filename == __file__ and w.lineno == line for w in ours), [(w.filename, w.lineno) for w in ours]


# ----------------------------------------------------------------------------------- vocabulary
def test_former_names_are_aliases_that_warn_at_the_callers_line():
    d = FactorGraphDiagnostics(tracker_latency_s=0.1, odometry_model={"scale": 1.0},
                               position_covariance_m2={"s": np.eye(3)}, amcl_error_model=None)
    for old, new in (("latency_s", "tracker_latency_s"), ("odometry", "odometry_model"),
                     ("position_cov_world_m2", "position_covariance_m2"), ("amcl_model", "amcl_error_model")):
        with pytest.warns(DeprecationWarning, match=new) as rec:
            value = getattr(d, old)
        assert value is getattr(d, new) and rec[0].filename == __file__
    with pytest.warns(DeprecationWarning) as rec:
        old_style = FactorGraphDiagnostics(latency_s=0.2)
    assert old_style.tracker_latency_s == 0.2 and rec[0].filename == __file__
    with pytest.warns(DeprecationWarning):
        old_style.latency_s = 0.3
    assert old_style.tracker_latency_s == 0.3
    with pytest.raises(TypeError, match="both"):
        FactorGraphDiagnostics(latency_s=0.2, tracker_latency_s=0.2)
    with pytest.warns(DeprecationWarning):
        assert CRLBResult(position_covariance_m2={}, recipe="x").position_cov_world_m2 == {}
    assert "latency_s" not in FactorGraphDiagnostics().to_dict()
    assert {"tracker_latency_s", "odometry_model", "amcl_error_model", "position_covariance_m2"} <= set(
        FactorGraphDiagnostics().to_dict())


def test_calibrating_raises_no_deprecation_warning(fg, sim):
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        warnings.simplefilter("ignore", pedcal.errors.DegenerateDataWarning)
        pedcal.calibrate(sim.calib, method="closedform")
        pedcal.calibrate(sim.calib, method="factorgraph", online=True)   # pedcal's own code uses the new names
    assert fg.diagnostics.tracker_latency_s == pytest.approx(fg.network.extra["tracker_latency_s"], abs=1e-4)


# ------------------------------------------------------------------------------- graph's layout
def test_graph_layout_is_as_documented(fg, sim):
    """Robot poses sit at the head point; the head-model variable's z is the vertical offset's
    change from -head_radius_m; the marginals exclude what is held fixed, so the result's
    covariance is never smaller than theirs."""
    from pedcal.calib.common import interpolate_pose2

    head_radius_m = 0.05                                       # the default recipe's
    h_z = fg.values.atPose3(fg.keys.head_model).z()
    assert fg.diagnostics.head_model.vertical_offset_m == pytest.approx(-head_radius_m + h_z, abs=1e-9)
    offset = sim.calib.meta.head_offset_m
    for k in (5, len(fg.keys.robot_poses) // 2):
        X = fg.values.atPose3(fg.keys.robot_poses[k])
        assert X.z() == pytest.approx(offset[2] - head_radius_m + h_z, abs=2e-3)    # head point, not base
        base = interpolate_pose2(sim.calib.robot, np.array([fg.keys.robot_pose_times[k]]))[0]
        assert np.hypot(*(X.translation()[:2] - base[:2])) < 0.15   # near AMCL's base (head offset 0 here)
    C = fg.position_covariance_m2
    m = fg.marginals()
    for i, sid in enumerate(fg.network.ids):
        key = fg.keys.sensors[sid]
        R = fg.values.atPose3(key).rotation().matrix()
        graph_only = R @ m.marginalCovariance(key)[3:, 3:] @ R.T
        assert np.trace(C[3 * i:3 * i + 3, 3 * i:3 * i + 3]) >= np.trace(graph_only) - 1e-12
        np.testing.assert_allclose(fg.diagnostics.position_covariance_m2[sid], C[3 * i:3 * i + 3, 3 * i:3 * i + 3],
                                   rtol=1e-9, atol=1e-15)


def test_network_from_values_reads_the_solution_back(fg):
    back = fg.network_from_values(fg.values)
    for s, b in zip(fg.network, back, strict=True):
        if s.status == "ok":
            np.testing.assert_allclose(b.position_m, s.position_m, atol=1e-9)
            np.testing.assert_allclose(b.ypr_deg, s.ypr_deg, atol=1e-7)
        assert b.sigma_position_m is None and b.status == s.status
    with_sigma = fg.network_from_values(fg.values, fg.marginals())
    assert all(s.sigma_position_m is not None and np.all(s.sigma_position_m > 0) for s in with_sigma)
    with pytest.raises(KeyError, match=fg.network.ids[0]):
        fg.network_from_values(gtsam.Values())


def test_reoptimize_with_a_prior_moves_the_network_as_the_covariance_predicts(fg):
    """A prior pulling one sensor 3 sigma along world x: the linear-Gaussian update
    delta = C[:, 0] (C_00 + Sigma_prior)^-1 e (the graph's joint covariance C) predicts where
    every sensor goes."""
    ids = fg.network.ids
    keys = [fg.keys.sensors[sid] for sid in ids]
    C = fg.marginals().jointMarginalCovariance(gtsam.KeyVector(keys)).fullMatrix()
    T0 = fg.values.atPose3(keys[0])
    shift_m = 3 * np.sqrt(fg.position_covariance_m2[0, 0])
    target = gtsam.Pose3(T0.rotation(), T0.translation() + np.array([shift_m, 0.0, 0.0]))
    sigmas = np.array([1e2, 1e2, 1e2, 1e-3, 1e-3, 1e-3])                 # position only
    new = fg.reoptimize([gtsam.PriorFactorPose3(keys[0], target, gtsam.noiseModel.Diagonal.Sigmas(sigmas))])
    delta = C[:, :6] @ np.linalg.solve(C[:6, :6] + np.diag(sigmas ** 2), T0.localCoordinates(target))
    for j, (sid, key) in enumerate(zip(ids, keys, strict=True)):
        T = fg.values.atPose3(key)
        predicted = T.retract(delta[6 * j:6 * j + 6]).translation() - T.translation()
        moved = new.network[sid].position_m - fg.network[sid].position_m
        np.testing.assert_allclose(moved, predicted, atol=0.1 * shift_m)
    assert np.linalg.norm(new.network[ids[0]].position_m - target.translation()) < 2e-3
    assert max(abs(new.network[sid].position_m[0] - fg.network[sid].position_m[0]) for sid in ids[1:]) > 0.3 * shift_m
    assert new.graph.size() == fg.graph.size() + 1 and fg.graph.size() == new.graph.size() - 1   # self unchanged
    assert new.position_covariance_m2.shape == fg.position_covariance_m2.shape
    assert new.position_covariance_m2[0, 0] < 1e-5                        # held by the 1 mm prior


def test_reoptimize_needs_a_graph(sim):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = pedcal.calibrate(sim.calib, method="closedform")
    with pytest.raises(ValueError, match="no graph"):
        res.reoptimize([])


# ---------------------------------------------------------------------------------------- tables
def _no_list_cells(df: pd.DataFrame) -> None:
    for col in df.columns:
        assert not df[col].map(lambda v: isinstance(v, (list, tuple, np.ndarray, dict))).any(), col


def test_results_as_tables_one_row_per_sensor(fg, sim):
    df = fg.to_dataframe()
    assert list(df.index) == fg.network.ids
    assert {"x_m", "y_m", "z_m", "sigma_x_m", "sigma_y_m", "sigma_z_m", "status"} <= set(df.columns)
    _no_list_cells(df)
    s0 = fg.network[fg.network.ids[0]]
    assert df.loc[s0.id, "z_m"] == s0.position_m[2] and df.loc[s0.id, "sigma_y_m"] == s0.sigma_position_m[1]
    d = fg.to_dict()
    assert d["method"] == "factorgraph" and len(d["network"]["sensors"]) == len(fg.network)
    assert np.asarray(d["position_covariance_m2"]["matrix"]).shape == fg.position_covariance_m2.shape
    import json

    json.dumps(d)                                                  # plain Python values only
    ev = pedcal.evaluate(sim.eval, fg.network)
    edf = ev.to_dataframe()
    _no_list_cells(edf)
    assert list(edf.index) == [s.id for s in ev.sensors]
    err = ev.sensors[0].position_error_mm
    assert list(edf.iloc[0][["error_x_mm", "error_y_mm", "error_z_mm"]]) == err
    ldf = sim.eval.to_dataframe()
    assert list(ldf.index) == sim.eval.sensors.ids and "truth_x_m" in ldf and ldf["observation_rows"].sum() == len(
        sim.eval.observations)
    json.dumps(sim.eval.to_dict())
    assert sim.eval.to_dict()["tables"]["robot"]["rows"] == len(sim.eval.robot)


def test_installed_network_table_has_empty_sigma_and_a_lone_sensor():
    net = SensorNetwork([SensorExtrinsics("a", [1, 2, 3], [10, 20, 30])])
    df = net.to_dataframe()
    assert df.shape[0] == 1 and df.loc["a", "yaw_deg"] == 10 and df["sigma_x_m"].isna().all()
    assert net.to_dict()["sensors"][0]["x_m"] == 1.0
    assert SensorNetwork([]).to_dataframe().shape[0] == 0


def test_warnings_at_caller_reraises_every_warning_under_the_callers_filters():
    import inspect

    from pedcal.errors import DegenerateDataWarning, warnings_at_caller

    @warnings_at_caller
    def inner():
        warnings.warn("first", DegenerateDataWarning, stacklevel=2)
        warnings.warn("second", UserWarning, stacklevel=1)
        return 7

    @warnings_at_caller
    def outer():
        return inner()

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = inspect.currentframe().f_lineno + 1
        assert outer() == 7
    assert [(str(w.message), w.category, w.filename, w.lineno) for w in caught] == [
        ("first", DegenerateDataWarning, __file__, line), ("second", UserWarning, __file__, line)]
    with warnings.catch_warnings():
        warnings.simplefilter("error", DegenerateDataWarning)
        with pytest.raises(DegenerateDataWarning, match="first"):
            outer()
