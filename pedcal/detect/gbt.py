"""Gradient-boosted decision trees (LightGBM) as the person classifier, beside the paper's
RealAdaBoost (``pedcal.detect.adaboost``), with the same interface: ``decision_function``,
``predict_proba``, ``predict``, ``set_threshold``, ``save``/``load`` (an .npz).

LightGBM fits each round's tree to the gradient of the logistic loss (Friedman 2001; Ke et al.
2017), with leaf-wise trees, shrinkage, row and feature subsampling: regularization RealAdaBoost
lacks (each of its rounds fits the reweighted samples exactly, which on a training set that holds
a few hundred real clusters beside tens of thousands of simulated ones learns the simulator).
F(x) is LightGBM's raw score, the log-odds, plus the offset ``bias_``; P(person | x) =
1 / (1 + exp(-F(x))).

The model file holds LightGBM's own text model (``Booster.model_to_string``) as bytes, so it
loads without pickle; training is deterministic (``deterministic``, one thread, the seed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pedcal.detect.adaboost import ScoreClassifier, open_model_npz, read_metadata, write_npz
from pedcal.errors import PedcalInputError


class GradientBoostedTrees(ScoreClassifier):
    """Binary gradient-boosted trees (LightGBM); labels {0, 1} (1 = person)."""

    def __init__(self, n_estimators: int = 300, num_leaves: int = 15, learning_rate: float = 0.05,
                 min_child_samples: int = 20, subsample: float = 0.8, colsample: float = 0.5, seed: int = 0):
        self.n_estimators = int(n_estimators)
        self.num_leaves = int(num_leaves)
        self.learning_rate = float(learning_rate)
        self.min_child_samples = int(min_child_samples)
        self.subsample = float(subsample)
        self.colsample = float(colsample)
        self.seed = int(seed)
        self.booster_ = None
        self.n_features_: int = 0
        self.bias_: float = 0.0
        self.metadata_: dict = {}

    def params(self) -> dict:
        return dict(objective="binary", learning_rate=self.learning_rate, num_leaves=self.num_leaves,
                    min_child_samples=self.min_child_samples, bagging_fraction=self.subsample, bagging_freq=1,
                    feature_fraction=self.colsample, seed=self.seed, deterministic=True, force_row_wise=True,
                    num_threads=1, verbose=-1)

    def fit(self, X: np.ndarray, y: np.ndarray, sample_weight: np.ndarray | None = None) -> GradientBoostedTrees:
        import lightgbm

        X = np.asarray(X, dtype=float)
        y = np.asarray(y)
        if X.ndim != 2 or len(X) != len(y) or len(X) == 0:
            raise ValueError(f"X must be (n, F) and y (n,), got {X.shape} and {y.shape}")
        if not np.isfinite(X).all():
            raise ValueError("X holds NaN or infinite values")
        y01 = (y > 0).astype(float)
        if y01.min() == y01.max():
            raise ValueError("training needs both classes")
        data = lightgbm.Dataset(X, y01, weight=sample_weight, params=dict(verbose=-1))
        self.booster_ = lightgbm.train(self.params(), data, num_boost_round=self.n_estimators)
        self.n_features_ = X.shape[1]
        self.bias_ = 0.0
        return self

    def decision_function(self, X: np.ndarray) -> np.ndarray:
        """F(x): the trees' raw score (log-odds) plus the offset ``bias_``."""
        X = self._rows(X, trained=self.booster_ is not None)
        if len(X) == 0:
            return np.zeros(0)
        return self.booster_.predict(X, raw_score=True, num_threads=1) + self.bias_

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """P(person | x) = 1 / (1 + exp(-F(x)))."""
        return 1.0 / (1.0 + np.exp(-self.decision_function(X)))

    def save(self, path: str | Path) -> None:
        text = self.booster_.model_to_string(num_iteration=-1)
        arrays = dict(lightgbm_model=np.frombuffer(text.encode(), dtype=np.uint8),
                      n_features=np.int64(self.n_features_), bias=np.float64(self.bias_),
                      hyper=np.array([self.n_estimators, self.num_leaves, self.min_child_samples, self.seed],
                                     dtype=np.int64),
                      hyper_float=np.array([self.learning_rate, self.subsample, self.colsample]))
        write_npz(path, arrays, self.metadata_)

    @classmethod
    def load(cls, path: str | Path) -> GradientBoostedTrees:
        import lightgbm

        from pedcal.detect.model_check import lightgbm_text_problem

        with open_model_npz(path, "a gradient-boosted-trees model .npz (lightgbm_model, n_features, bias, hyper)",
                            (lightgbm.basic.LightGBMError,)) as d:
            n_est, leaves, min_child, seed = (int(v) for v in d["hyper"])
            lr, sub, col = (float(v) for v in d["hyper_float"])
            m = cls(n_est, leaves, lr, min_child, sub, col, seed)
            text = d["lightgbm_model"].tobytes().decode()
            problem = lightgbm_text_problem(text)    # LightGBM aborts the process on a damaged text
            if problem is not None:
                raise PedcalInputError(f"not a usable detector model: {problem}", path=path)
            m.booster_ = lightgbm.Booster(model_str=text)
            m.n_features_ = int(d["n_features"])
            m.bias_ = float(d["bias"])
            m.metadata_ = read_metadata(d)
        return m
