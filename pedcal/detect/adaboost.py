"""Real AdaBoost with domain-partitioning weak learners (Schapire and Singer, "Improved boosting
algorithms using confidence-rated predictions", 1999, Sec. 4.1), the classifier of Misu and Miura.

Each feature's range is partitioned once into ``n_bins`` bins at quantiles of the training data.
Round t picks the feature whose partition minimizes

    Z = 2 * sum_j sqrt(W+_j * W-_j)                         (S&S eq. 10)

where W+-_j is the weight of the positive/negative samples falling into bin j, and outputs, for a
sample in bin j,

    h_t(x) = 1/2 * ln((W+_j + eps) / (W-_j + eps))            (S&S eq. 11, smoothed)

With ``tree_depth`` = D > 0 the partition of a round is instead the leaves of a binary tree of
depth D (S&S Sec. 4.1 allow any partition of the domain; a tree's leaves are one): grown greedily,
each node split at one of its feature's quantile edges where its children's share of eq. 10,
2 (sqrt(W+_L W-_L) + sqrt(W+_R W-_R)), is least, and eq. 11 gives each of the 2^D leaves its output.
A one-feature partition adds its feature's effect to the others' (the strong classifier is a sum
of per-feature curves); a tree's leaves are conjunctions ("tall AND near"), which a cluster's
features need: a person's visible height means something else 1 m from a narrow-FOV sensor than
4 m from it.

The weights are updated w <- w * exp(-y h_t(x)) and renormalized. The strong classifier is
F(x) = sum_t h_t(x) + b, whose sign is the class; F estimates half the log-odds, so
P(y = +1 | x) = 1 / (1 + exp(-2 F(x))). The offset b (``bias_``, 0 after ``fit``) moves the
decision threshold: ``set_threshold`` puts P = 0.5 at a decision value chosen on validation data.

Bin statistics are computed for all features at once with one ``np.bincount`` per round.
"""

from __future__ import annotations

import io
import json
import logging
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

import numpy as np

from pedcal.errors import PedcalInputError
from pedcal.io.atomic import atomic_path

_Classifier = TypeVar("_Classifier", bound="ScoreClassifier")


class ScoreClassifier:
    """What the person classifiers share: a score F(x) (:meth:`decision_function`) whose sign is the
    class (:meth:`predict`), with the offset ``bias_`` that :meth:`set_threshold` moves, over the
    ``n_features_`` features the model was trained on."""

    n_features_: int
    bias_: float

    def decision_function(self, X: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _rows(self, X: np.ndarray, trained: bool) -> np.ndarray:
        """``X`` as float rows (n, n_features_) for a ``trained`` model; else RuntimeError, and
        ValueError for another number of features."""
        if not trained:
            raise RuntimeError("the classifier is not trained")
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != self.n_features_:
            raise ValueError(f"expected {self.n_features_} features, got {X.shape[1]}")
        return X

    def set_threshold(self: _Classifier, decision_value: float) -> _Classifier:
        """Make ``decision_value`` (of the current F) the class boundary: F = 0, P = 0.5 there."""
        self.bias_ = float(self.bias_ - decision_value)
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        return (self.decision_function(X) > 0).astype(int)


class RealAdaBoost(ScoreClassifier):
    """Binary Real AdaBoost; labels are {0, 1} or {-1, +1} (1 = person)."""

    def __init__(self, n_rounds: int = 200, n_bins: int = 32, seed: int = 0, max_edge_samples: int = 20000,
                 tree_depth: int = 0):
        self.n_rounds = int(n_rounds)
        self.n_bins = int(n_bins)
        self.seed = int(seed)
        self.max_edge_samples = int(max_edge_samples)
        self.tree_depth = int(tree_depth)  # 0: one feature's bins per round; D > 0: a depth-D tree
        # one feature's bins: (T,) feature of each round, (T, B-1) its bin edges, (T, B) output per bin;
        # trees: (T, 2^D - 1) feature and threshold of each node (heap order), (T, 2^D) output per leaf
        self.feature_: np.ndarray | None = None
        self.edges_: np.ndarray | None = None
        self.h_: np.ndarray | None = None
        self.n_features_: int = 0
        self.bias_: float = 0.0  # b of F(x), moves the decision threshold
        self.metadata_: dict = {}  # how the model was chosen (JSON-serializable), saved with it

    # ------------------------------------------------------------------------------------ training
    def _bin_edges(self, X: np.ndarray) -> np.ndarray:
        """(F, B-1) interior edges at quantiles of (a seeded subsample of) the training data."""
        rng = np.random.default_rng(self.seed)
        if len(X) > self.max_edge_samples:
            X = X[np.sort(rng.choice(len(X), self.max_edge_samples, replace=False))]
        q = np.linspace(0.0, 1.0, self.n_bins + 1)[1:-1]
        return np.quantile(X, q, axis=0).T

    def fit(self, X: np.ndarray, y: np.ndarray, progress: bool = False,
            sample_weight: np.ndarray | None = None) -> RealAdaBoost:
        """``sample_weight`` (n,) > 0: the initial weights D_1 (S&S Sec. 2), uniform by default."""
        X = np.asarray(X, dtype=float)
        y = np.asarray(y)
        if X.ndim != 2 or len(X) != len(y) or len(X) == 0:
            raise ValueError(f"X must be (n, F) and y (n,), got {X.shape} and {y.shape}")
        if not np.isfinite(X).all():
            raise ValueError("X holds NaN or infinite values")
        if sample_weight is None:
            w0 = np.full(len(y), 1.0 / len(y))
        else:
            w0 = np.asarray(sample_weight, dtype=float)
            if w0.shape != (len(y),) or not (np.isfinite(w0).all() and (w0 > 0).all()):
                raise ValueError(f"sample_weight must be (n,) = ({len(y)},) positive and finite")
            w0 = w0 / w0.sum()
        y_pm = np.where(y > 0, 1.0, -1.0)
        if np.all(y_pm > 0) or np.all(y_pm < 0):
            raise ValueError("training needs both classes")
        n, F = X.shape
        B = self.n_bins
        edges = self._bin_edges(X)
        if self.tree_depth > 0:
            return self._fit_trees(X, y_pm, edges, progress, w0)
        # Bin index of every sample in every feature, offset by feature so one bincount does all.
        bins = np.empty((n, F), dtype=np.int64)
        for f in range(F):
            bins[:, f] = np.searchsorted(edges[f], X[:, f], side="right")
        # Negatives are offset by F*B, so one bincount gives W+ and W- of every bin of every feature.
        codes = (bins + np.arange(F) * B + (y_pm < 0)[:, None] * (F * B)).ravel()
        eps = 1.0 / (n * B)
        w = w0
        feats, hs = [], []
        for t in range(self.n_rounds):
            wb = np.bincount(codes, weights=np.repeat(w, F), minlength=2 * F * B).reshape(2, F, B)
            w_pos, w_neg = wb[0], wb[1]
            Z = 2.0 * np.sqrt(w_pos * w_neg).sum(axis=1)  # S&S eq. 10
            f = int(np.argmin(Z))
            h = 0.5 * np.log((w_pos[f] + eps) / (w_neg[f] + eps))  # S&S eq. 11
            w = w * np.exp(-y_pm * h[bins[:, f]])
            w /= w.sum()
            feats.append(f)
            hs.append(h)
            if progress and (t + 1) % 25 == 0:
                logging.getLogger(__name__).info(f"  boosting round {t + 1}/{self.n_rounds}: feature {f}, "
                                                 f"Z={Z[f]:.4f}", extra={"progress": (t + 1, self.n_rounds)})
        self.feature_ = np.asarray(feats, dtype=np.int64)
        self.edges_ = edges[self.feature_]
        self.h_ = np.vstack(hs)
        self.n_features_ = F
        self.bias_ = 0.0
        return self

    def _fit_trees(self, X: np.ndarray, y_pm: np.ndarray, edges: np.ndarray, progress: bool,
                   w0: np.ndarray) -> RealAdaBoost:
        """Rounds whose partitions are depth-``tree_depth`` trees (see the module docstring)."""
        n, F = X.shape
        B, D = self.n_bins, self.tree_depth
        bins = np.empty((n, F), dtype=np.int64)
        for f in range(F):
            bins[:, f] = np.searchsorted(edges[f], X[:, f], side="right")
        # (sample, feature) -> feature * B + bin, negatives offset by F * B; a node's offset on top
        codes = bins + np.arange(F) * B + (y_pm < 0)[:, None] * (F * B)
        eps = 1.0 / (n * 2**D)
        w = w0
        node_feature = np.zeros((self.n_rounds, 2**D - 1), dtype=np.int64)
        node_threshold = np.full((self.n_rounds, 2**D - 1), np.inf)
        leaves = np.zeros((self.n_rounds, 2**D))
        rows = np.arange(n)
        for t in range(self.n_rounds):
            node = np.zeros(n, dtype=np.int64)  # within the current level
            for level in range(D):
                m = 2**level
                wb = np.bincount((codes + (node * (2 * F * B))[:, None]).ravel(), weights=np.repeat(w, F),
                                 minlength=m * 2 * F * B).reshape(m, 2, F, B)
                # left child: bins <= b (x < edges[f, b]) for each of the B - 1 inner edges
                left = np.cumsum(wb, axis=3)[..., :-1]
                right = left[..., -1:] + wb[..., -1:] - left
                z = np.sqrt(left[:, 0] * left[:, 1]) + np.sqrt(right[:, 0] * right[:, 1])  # (m, F, B-1)
                best = z.reshape(m, -1).argmin(axis=1)
                f_best, b_best = np.divmod(best, B - 1)
                heap = m - 1 + np.arange(m)
                node_feature[t, heap] = f_best
                node_threshold[t, heap] = edges[f_best, b_best]
                go_right = bins[rows, f_best[node]] > b_best[node]
                node = 2 * node + go_right
            w_leaf = np.bincount(node + (y_pm < 0) * 2**D, weights=w, minlength=2**(D + 1)).reshape(2, -1)
            leaves[t] = 0.5 * np.log((w_leaf[0] + eps) / (w_leaf[1] + eps))  # S&S eq. 11 per leaf
            w = w * np.exp(-y_pm * leaves[t][node])
            w /= w.sum()
            if progress and (t + 1) % 25 == 0:
                z_tree = 2.0 * np.sqrt(w_leaf[0] * w_leaf[1]).sum()
                logging.getLogger(__name__).info(f"  boosting round {t + 1}/{self.n_rounds}: tree Z={z_tree:.4f}",
                                                 extra={"progress": (t + 1, self.n_rounds)})
        self.feature_, self.edges_, self.h_ = node_feature, node_threshold, leaves
        self.n_features_ = F
        self.bias_ = 0.0
        return self

    # ---------------------------------------------------------------------------------- prediction
    def decision_function(self, X: np.ndarray) -> np.ndarray:
        """F(x) = sum_t h_t(x) + b for each row of X."""
        X = self._rows(X, trained=self.feature_ is not None)
        if self.tree_depth > 0:
            # every sample down every round's tree at once, one level at a time (heap order)
            rounds = np.arange(len(self.feature_))[None, :]
            node = np.zeros((len(X), len(self.feature_)), dtype=np.int64)
            for _ in range(self.tree_depth):
                go_right = X[np.arange(len(X))[:, None], self.feature_[rounds, node]] >= self.edges_[rounds, node]
                node = 2 * node + 1 + go_right
            return self.h_[rounds, node - (2**self.tree_depth - 1)].sum(axis=1) + self.bias_
        vals = X[:, self.feature_]  # (n, T)
        # bin = number of edges <= value (searchsorted side='right'), for every round at once
        bins = (vals[:, :, None] >= self.edges_[None, :, :]).sum(axis=2)
        return self.h_[np.arange(len(self.feature_))[None, :], bins].sum(axis=1) + self.bias_

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """P(person | x) = 1 / (1 + exp(-2 F(x)))."""
        return 1.0 / (1.0 + np.exp(-2.0 * self.decision_function(X)))

    # ---------------------------------------------------------------------------------------- I/O
    def save(self, path: str | Path) -> None:
        """Write the model to a small .npz, atomically and byte-reproducibly (fixed zip timestamps,
        unlike ``np.savez``, so the same training gives the same file)."""
        arrays = dict(feature=self.feature_, edges=self.edges_, h=self.h_,
                      n_features=np.int64(self.n_features_), n_bins=np.int64(self.n_bins),
                      n_rounds=np.int64(self.n_rounds), seed=np.int64(self.seed), bias=np.float64(self.bias_))
        if self.tree_depth:  # (absent: one feature's bins per round, as in files before the trees)
            arrays["tree_depth"] = np.int64(self.tree_depth)
        write_npz(path, arrays, self.metadata_)

    @classmethod
    def load(cls, path: str | Path) -> RealAdaBoost:
        with open_model_npz(path, "a RealAdaBoost model .npz (feature, edges, h, n_features, n_bins, "
                                  "n_rounds, seed)") as d:
            m = cls(n_rounds=int(d["n_rounds"]), n_bins=int(d["n_bins"]), seed=int(d["seed"]),
                    tree_depth=int(d["tree_depth"]) if "tree_depth" in d.files else 0)
            m.feature_ = d["feature"].astype(np.int64)
            m.edges_ = d["edges"].astype(float)
            m.h_ = d["h"].astype(float)
            m.n_features_ = int(d["n_features"])
            m.bias_ = float(d["bias"]) if "bias" in d.files else 0.0  # files before the offset
            m.metadata_ = read_metadata(d)
        return m


def require_npz(path: Path, what: str) -> None:
    """Refuse ``path`` unless it is a zip (an .npz), naming ``what`` it should be: np.load would
    read a .npy array, or suggest unpickling anything else."""
    if not zipfile.is_zipfile(path):
        raise PedcalInputError(f"not {what}: not an .npz archive (a zip of .npy arrays)", path=path)


@contextmanager
def open_model_npz(path: str | Path, what: str, errors: tuple = ()):
    """The model file ``path`` opened as an .npz (no pickles) for the ``with`` body to read; a
    missing file, or a read that fails in the body (OSError, ValueError, KeyError,
    UnicodeDecodeError or one of ``errors``), is a PedcalInputError naming the file and ``what``
    it should be; a PedcalInputError of the body's own is passed on."""
    path = Path(path)
    if not path.is_file():
        raise PedcalInputError("no such model file", path=path)
    require_npz(path, what)
    try:
        with np.load(path, allow_pickle=False) as d:
            yield d
    except PedcalInputError:
        raise
    except (OSError, ValueError, KeyError, UnicodeDecodeError, *errors) as e:
        raise PedcalInputError(f"not {what}: {e}", path=path) from None


def write_npz(path: str | Path, arrays: dict, metadata: dict | None = None) -> None:
    """Write ``arrays`` to an .npz atomically and byte-reproducibly (fixed zip timestamps, unlike
    ``np.savez``, so the same training gives the same file); ``metadata`` goes in as JSON text
    (``metadata_json``, read back by ``read_metadata``)."""
    arrays = dict(arrays)
    if metadata:
        arrays["metadata_json"] = np.frombuffer(json.dumps(metadata, sort_keys=True).encode(), dtype=np.uint8)
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(arr), allow_pickle=False)
            zf.writestr(info, buf.getvalue())


def read_metadata(npz) -> dict:
    """The metadata a model file was saved with (``write_npz``), {} when it has none."""
    if "metadata_json" not in npz.files:
        return {}
    try:
        return json.loads(npz["metadata_json"].tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"unreadable metadata_json: {e}") from None
