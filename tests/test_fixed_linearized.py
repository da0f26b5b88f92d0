"""The sensors' and AMCL's blocks linearized in numpy from the arrays the build keeps
(GraphParts.linearized, Pose3Factors), against GTSAM's linearization of the same blocks."""

import copy

import gtsam
import numpy as np
import pytest
from test_profile import solved_graph

from pedcal.calib.graph import GraphRecipe
from pedcal.calib.profile import Columns, sparse_system
from pedcal.sim import simulate_logs


@pytest.fixture(scope="module")
def paper():
    sim = simulate_logs("paper", seed=3, head_point="dome", head_radius_m=0.07)
    rec = GraphRecipe.load("default")
    rec.people = False
    rec.estimate_amcl_model = False
    return sim, rec


@pytest.mark.parametrize("height_sigma_m, amcl", [(0.0, True), (0.02, True), (0.0, False)])
def test_blocks_linearized_from_their_arrays_equal_gtsams(paper, height_sigma_m, amcl):
    sim, rec = paper
    rec = copy.copy(rec)
    rec.sensor_height_sigma_m, rec.amcl = height_sigma_m, amcl
    prob, parts, result = solved_graph(sim.calib, rec)
    rng = np.random.default_rng(2)
    delta = gtsam.VectorValues()
    for key, dim in result.dims().items():
        delta.insert(key, rng.normal(0.0, 0.02, int(dim)))
    values = result.retract(delta)            # (off the solution: large errors, rotations away from identity)
    cols = Columns.of(values)
    for name in ("sensors", "amcl"):
        A, b = sparse_system(parts.blocks[name].linearize(values), cols)
        A_ours, b_ours = parts.linearized([name], values, cols)
        assert A.shape == A_ours.shape and A.shape[0] >= 60
        assert np.array_equal(A.indptr, A_ours.indptr) and np.array_equal(A.indices, A_ours.indices)
        assert np.abs(A.data - A_ours.data).max() <= 1e-13 * np.abs(A.data).max()
        assert np.abs(b).max() > 0.1 and np.abs(b - b_ours).max() <= 1e-13 * np.abs(b).max()


def test_a_block_holding_other_factors_is_refused(paper):
    sim, rec = paper
    prob, parts, result = solved_graph(sim.calib, rec)
    cols = Columns.of(result)
    assert parts.linearized(["sensors", "amcl"], result, cols) is not None
    parts.blocks["sensors"].add(gtsam.PriorFactorPose3(gtsam.symbol("s", 0), gtsam.Pose3(),
                                                       gtsam.noiseModel.Unit.Create(6)))
    assert parts.linearized(["sensors", "amcl"], result, cols) is None
    assert parts.linearized(["motion"], result, cols) is None      # (no arrays kept for it)
