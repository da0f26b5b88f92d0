"""Structural checks of a loaded detector model, so that a damaged or hand-edited model file is a
clear error naming the file instead of an IndexError deep in scoring, or scores of NaN.

The checks go by the model's array names (those of its .npz file: ``feature``, ``edges``, ``h``,
``n_features``, ``bias``, ``tree_depth``, ``n_bins``); a rule whose arrays the model does not hold
is skipped, so a format with more arrays needs only more entries in ``ARRAYS`` and ``RULES``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from pedcal.errors import PedcalInputError

# array name in the file -> attribute of the loaded model
ARRAYS = {"feature": "feature_", "edges": "edges_", "h": "h_", "n_features": "n_features_", "bias": "bias_",
          "tree_depth": "tree_depth", "n_bins": "n_bins", "lightgbm_model": "booster_"}
MAX_TREE_DEPTH = 20


def _finite(name: str) -> Callable[[dict], str | None]:
    def rule(a: dict) -> str | None:
        v = np.asarray(a[name])
        if v.dtype.kind not in "fiu":
            return f"'{name}' holds {v.dtype} values, expected numbers"
        bad = ~np.isfinite(v.astype(float))
        if bad.any():
            first = np.argwhere(bad)[0].tolist()
            return f"'{name}' holds {int(bad.sum())} NaN or infinite value(s) (first at index {first})"
        return None
    rule.needs = (name,)
    return rule


def _scalars(a: dict) -> str | None:
    if int(a["n_features"]) < 1:
        return f"'n_features' = {int(a['n_features'])}, expected at least 1"
    if not 0 <= int(a["tree_depth"]) <= MAX_TREE_DEPTH:
        return f"'tree_depth' = {int(a['tree_depth'])}, expected 0 to {MAX_TREE_DEPTH}"
    if int(a["n_bins"]) < 2:
        return f"'n_bins' = {int(a['n_bins'])}, expected at least 2"
    return None


_scalars.needs = ("n_features", "tree_depth", "n_bins")


def _feature_indices(a: dict) -> str | None:
    f, n = np.asarray(a["feature"]), int(a["n_features"])
    if f.dtype.kind not in "iu" or f.size == 0:
        return f"'feature' must be a non-empty integer array, got {f.dtype} of shape {f.shape}"
    bad = (f < 0) | (f >= n)
    if bad.any():
        return (f"'feature' index {int(f[bad].flat[0])} out of range: the model has {n} features "
                f"(0 to {n - 1})")
    return None


_feature_indices.needs = ("feature", "n_features")


def _shapes(a: dict) -> str | None:
    f, e, h = np.asarray(a["feature"]), np.asarray(a["edges"]), np.asarray(a["h"])
    depth, bins = int(a["tree_depth"]), int(a["n_bins"])
    rounds = f.shape[0] if f.ndim else 0
    if depth > 0:     # heap-ordered trees: 2^D - 1 split nodes, 2^D leaves per round
        want = {"feature": (rounds, 2 ** depth - 1), "edges": (rounds, 2 ** depth - 1), "h": (rounds, 2 ** depth)}
    else:             # one feature per round, its range cut into n_bins bins
        want = {"feature": (rounds,), "edges": (rounds, bins - 1), "h": (rounds, bins)}
    for name, arr in (("feature", f), ("edges", e), ("h", h)):
        if arr.shape != want[name]:
            return f"'{name}' has shape {arr.shape}, expected {want[name]} (tree_depth {depth}, n_bins {bins})"
    return None


_shapes.needs = ("feature", "edges", "h", "tree_depth", "n_bins")


def _edges_monotone(a: dict) -> str | None:
    if int(a["tree_depth"]) > 0:
        return None
    e = np.asarray(a["edges"], dtype=float)
    bad = np.diff(e, axis=1) < 0
    if bad.any():
        r = int(np.argwhere(bad)[0][0])
        return f"'edges' of round {r} are not in increasing order"
    return None


_edges_monotone.needs = ("edges", "tree_depth")

def _booster_features(a: dict) -> str | None:
    """A gradient-boosted-trees model (pedcal.detect.gbt): its trees split the n_features it says."""
    got, n = int(a["lightgbm_model"].num_feature()), int(a["n_features"])
    if got != n:
        return f"'lightgbm_model' splits {got} features, 'n_features' says {n}"
    return None


_booster_features.needs = ("lightgbm_model", "n_features")

# order matters: the scalars and the finiteness first, then the shapes the later rules index by
RULES = [_finite("edges"), _finite("h"), _finite("bias"), _scalars, _feature_indices, _shapes, _edges_monotone,
         _booster_features]


def lightgbm_text_problem(text: str) -> str | None:
    """What is wrong with a LightGBM model text (pedcal.detect.gbt's ``lightgbm_model``), or None.
    LightGBM aborts the whole process on a text it cannot parse (a truncated file, a hand edit), so
    its layout is checked first: the ``tree`` header, ``tree_sizes`` (each tree block's length in
    characters) locating every ``Tree=k`` block exactly, then ``end of trees`` and the parameters."""
    if not text.startswith("tree\n"):
        return "'lightgbm_model' does not start with LightGBM's 'tree' header"
    i = text.find("\ntree_sizes=")
    if i < 0:
        return "'lightgbm_model' has no 'tree_sizes' line"
    line = text[i + len("\ntree_sizes="): text.find("\n", i + 1)]
    try:
        sizes = [int(v) for v in line.split()]
    except ValueError:
        return "'lightgbm_model' has a 'tree_sizes' line that is not a list of integers"
    pos = text.find("Tree=0\n")
    if pos < 0 or not sizes or min(sizes) <= 0:
        return "'lightgbm_model' holds no tree"
    for k, size in enumerate(sizes):
        if not text.startswith(f"Tree={k}\n", pos):
            return f"'lightgbm_model' tree {k} is not where 'tree_sizes' puts it (the text is damaged or cut)"
        pos += size
    if not text.startswith("end of trees", pos) or "end of parameters" not in text[pos:]:
        return "'lightgbm_model' ends before 'end of trees' / 'end of parameters' (the text is cut)"
    return None


def model_arrays(model) -> dict:
    return {name: getattr(model, attr) for name, attr in ARRAYS.items()
            if getattr(model, attr, None) is not None}


def check_model(model, path: str | Path | None = None):
    """``model`` when every rule holds; else PedcalInputError naming ``path`` and the first problem."""
    arrays = model_arrays(model)
    for rule in RULES:
        if all(n in arrays for n in rule.needs):
            problem = rule(arrays)
            if problem is not None:
                raise PedcalInputError(f"not a usable detector model: {problem} (retrain it with "
                                       "pedcal train-detector)", path=path)
    return model


def load_checked(load: Callable[[], object], path: str | Path):
    """``load()`` (a model file's reader) with any failure of reading a damaged file as
    PedcalInputError naming it, then ``check_model``."""
    try:
        model = load()
    except (PedcalInputError, MemoryError, KeyboardInterrupt):
        raise
    except Exception as e:       # zipfile, numpy's format parser, int() of a non-scalar, ...
        raise PedcalInputError(f"not a detector model file: {type(e).__name__}: {str(e)[:200]}", path=path) from None
    return check_model(model, path)
