"""Online boosting of the target's appearance on reflectance histograms (Misu and Miura, Sec. 4.2).

Oza and Russell's online boosting ("Online bagging and boosting", 2001) with the importance weight
lambda passed down the chain of weak learners instead of Poisson(lambda) repetitions, so the
classifier is deterministic. Each weak learner is a decision stump on one histogram bin whose
threshold and polarity come from running weighted means of that bin over the positive and the
negative samples (Grabner and Bischof's online stumps): h_m(x) = sign(p_m (x_b - (mu+ + mu-)/2)).

For a sample (x, y), lambda = 1 and for m = 1..M in order:
    update stump m with weight lambda;
    if h_m(x) == y:  lambda_sc_m += lambda, eps_m = lambda_sw / (lambda_sc + lambda_sw), lambda *= 1 / (2 (1 - eps_m))
    else:            lambda_sw_m += lambda, eps_m = ...,                              lambda *= 1 / (2 eps_m)
The strong score is F(x) = sum_m alpha_m h_m(x) with alpha_m = 1/2 ln((1 - eps_m) / eps_m) for the
learners better than chance (others count 0), and P(target | x) = 1 / (1 + exp(-2 F(x))).
Predictions are vectorized over samples and learners.
"""

from __future__ import annotations

import numpy as np

EPS_CLIP = 1e-3  # keeps one perfect learner from outvoting all others forever


class OnlineBoost:
    """Online boosting of ``n_bins`` stumps (one per histogram bin) separating the target's
    reflectance histograms (positives) from other people's (negatives)."""

    def __init__(self, n_bins: int):
        self.n_bins = int(n_bins)
        self.w_pos = np.zeros(self.n_bins)  # summed weight of positives seen by each stump
        self.w_neg = np.zeros(self.n_bins)
        self.sum_pos = np.zeros(self.n_bins)  # weighted sums of the stump's bin value
        self.sum_neg = np.zeros(self.n_bins)
        self.lam_correct = np.zeros(self.n_bins)
        self.lam_wrong = np.zeros(self.n_bins)
        self.n_pos = 0
        self.n_neg = 0

    @property
    def ready(self) -> bool:
        """It has seen both classes (before that it knows nothing: error 0.5)."""
        return self.n_pos > 0 and self.n_neg > 0

    def _stumps(self) -> tuple[np.ndarray, np.ndarray]:
        mu_pos = self.sum_pos / np.maximum(self.w_pos, 1e-12)
        mu_neg = self.sum_neg / np.maximum(self.w_neg, 1e-12)
        return 0.5 * (mu_pos + mu_neg), np.where(mu_pos >= mu_neg, 1.0, -1.0)

    def weak_outputs(self, X: np.ndarray) -> np.ndarray:
        """(N, M) outputs in {-1, +1} of every stump for histograms X (N, B)."""
        thr, pol = self._stumps()
        return np.where(pol * (np.atleast_2d(X) - thr) >= 0.0, 1.0, -1.0)

    def alphas(self) -> np.ndarray:
        total = self.lam_correct + self.lam_wrong
        eps = np.clip(np.where(total > 0, self.lam_wrong / np.maximum(total, 1e-12), 0.5), EPS_CLIP, 1 - EPS_CLIP)
        return np.where(eps < 0.5, 0.5 * np.log((1 - eps) / eps), 0.0)

    def predict_proba(self, X: np.ndarray) -> np.ndarray:
        """(N,) P(target | histogram); 0.5 everywhere until both classes were seen."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if not self.ready:
            return np.full(len(X), 0.5)
        F = self.weak_outputs(X) @ self.alphas()
        return 1.0 / (1.0 + np.exp(-2.0 * F))

    def error(self, X: np.ndarray) -> np.ndarray:
        """(N,) e of eq. 3: the classifier's error if the histogram were the target's, 1 - P(target)."""
        return 1.0 - self.predict_proba(X)

    def update(self, x: np.ndarray, positive: bool) -> None:
        """One Oza-Russell step with histogram ``x`` (B,) and its label."""
        x = np.asarray(x, dtype=float)
        y = 1.0 if positive else -1.0
        if positive:
            self.n_pos += 1
        else:
            self.n_neg += 1
        # Plain floats in the chain: it is sequential in m by construction.
        xs = x.tolist()
        w_pos, w_neg = self.w_pos.tolist(), self.w_neg.tolist()
        s_pos, s_neg = self.sum_pos.tolist(), self.sum_neg.tolist()
        lam_c, lam_w = self.lam_correct.tolist(), self.lam_wrong.tolist()
        lam = 1.0
        for m in range(self.n_bins):
            if positive:
                w_pos[m] += lam
                s_pos[m] += lam * xs[m]
            else:
                w_neg[m] += lam
                s_neg[m] += lam * xs[m]
            mu_pos = s_pos[m] / w_pos[m] if w_pos[m] > 0 else xs[m]
            mu_neg = s_neg[m] / w_neg[m] if w_neg[m] > 0 else xs[m]
            pol = 1.0 if mu_pos >= mu_neg else -1.0
            h = 1.0 if pol * (xs[m] - 0.5 * (mu_pos + mu_neg)) >= 0.0 else -1.0
            if h == y:
                lam_c[m] += lam
                eps = lam_w[m] / (lam_c[m] + lam_w[m])
                lam /= 2.0 * (1.0 - min(max(eps, EPS_CLIP), 1 - EPS_CLIP))
            else:
                lam_w[m] += lam
                eps = lam_w[m] / (lam_c[m] + lam_w[m])
                lam /= 2.0 * min(max(eps, EPS_CLIP), 1 - EPS_CLIP)
        self.w_pos, self.w_neg = np.array(w_pos), np.array(w_neg)
        self.sum_pos, self.sum_neg = np.array(s_pos), np.array(s_neg)
        self.lam_correct, self.lam_wrong = np.array(lam_c), np.array(lam_w)

    def update_many(self, X: np.ndarray, positive: np.ndarray) -> None:
        for x, p in zip(np.atleast_2d(X), np.asarray(positive, dtype=bool), strict=True):
            self.update(x, bool(p))


__all__ = ["OnlineBoost"]
