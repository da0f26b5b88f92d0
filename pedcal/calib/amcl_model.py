"""AMCL's position error as the factor graph models it, assumed or estimated from the data.

AMCL's estimate is the robot's position plus an error that is partly white (the scan matcher's
jitter from one estimate to the next) and partly a slowly wandering, Gauss-Markov process (the
particle cloud drifting over tens of seconds), now and then a jump (a wrong relocalization that
lasts seconds). How much of each differs between robots, maps and AMCL's settings, and AMCL's
reported covariance (its particle spread) says little about it. The graph's link to the map is
the average of AMCL's error over the run, whose uncertainty depends on exactly this split: a
white error of 5 cm averages out to a millimetre over a few minutes, a wandering one of 5 cm
with a correlation time of 20 s to about 2 cm.

:func:`assumed_model` is the model before any solve: the white share from AMCL's own jitter
(:func:`amcl_white_sigma`) and a fraction of the reported covariance, the
wandering part at the reported std with the recipe's correlation time. :func:`estimate_model`
replaces it after a first solve: where the ceiling sensors see the robot, its solved position
is known to millimetres, so AMCL's residual there is AMCL's error (up to the constant the whole
solution shares, which a variogram ignores). Its robust semivariogram over lags of 0.2-100 s is
fitted by ``white^2 + correlated^2 (1 - exp(-lag / tau))`` (the variogram of white noise plus an
Ornstein-Uhlenbeck process), and estimates that depart from the running median of the residual
by more than ``jump_threshold`` robust sigmas (and ``min_jump_m``) are jumps, left out of the graph.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

    from pedcal.model import Log

# how AMCL's reported std bounds the wandering part fitted to the residuals (estimate_model)
FLOOR_MODES = ("hold", "consider", "off")
VARIOGRAM_LAGS_S = np.array([0.2, 0.4, 0.8, 1.6, 3.2, 6.4, 12.8, 25.6, 51.2, 102.4])


@dataclass
class AmclErrorModel:
    """AMCL's position error: white per estimate (``white_sigma_m``, isotropic, on top of
    ``reported_white_fraction`` of AMCL's reported covariance) plus a Gauss-Markov process of std
    ``correlated_sigma_m`` and correlation time ``correlation_s``; ``excluded`` (over robot.csv's
    rows in time order) marks estimates left out as jumps. ``source``: ``assumed`` (before any
    solve) or ``estimated`` (from a solve's residuals, with the variogram it was fitted to).
    ``track_jumps``: the part of ``excluded`` found as steps in AMCL's own track
    (:func:`detect_steps`), kept by every later estimate."""

    white_sigma_m: float
    correlated_sigma_m: float
    correlation_s: float
    reported_white_fraction: float = 0.0
    source: str = "assumed"
    excluded: np.ndarray | None = field(default=None, repr=False)
    track_jumps: np.ndarray | None = field(default=None, repr=False)   # those found in AMCL's own track
    jumps: int = 0
    excluded_s: float = 0.0
    variogram_lags_s: list = field(default_factory=list)
    variogram_sigma_m: list = field(default_factory=list)   # sqrt of the semivariance per lag
    # the wandering part as AMCL's reported std holds it (at least that std, at the rate of wander
    # the residuals show: :func:`hold_at_floor`) where the graph was solved with the data's alone
    # (recipe ``amcl_reported_floor = "consider"``): the sensors' covariance is read with it
    # (:meth:`held`; pedcal.calib.factorgraph)
    held_sigma_m: float = 0.0
    held_correlation_s: float = 0.0

    def node_spacing_s(self, amcl_period_s: float, max_spacing_s: float) -> float:
        """Spacing of the error process's nodes: a quarter of its correlation time, at least
        AMCL's period, at most ``max_spacing_s``; the most without a wandering part (the nodes
        then hold nothing to resolve, whatever the fit's correlation time)."""
        most = max(max_spacing_s, amcl_period_s)
        if self.correlated_sigma_m <= 0.0:
            return float(most)
        return float(np.clip(self.correlation_s / 4.0, amcl_period_s, most))

    def floor_sigma_m(self, duration_s: float) -> float:
        """Std per axis of this error's average over a run of ``duration_s``: the accuracy no
        calibration anchored to AMCL alone can pass (white part over the estimates ignored)."""
        tau = max(self.correlation_s, 1e-9)
        T = max(duration_s, 1e-9)
        x = T / tau
        # variance of the mean of an OU process over T: 2 sigma^2 tau / T (1 - tau / T (1 - e^-T/tau))
        return float(self.correlated_sigma_m * np.sqrt(2.0 / x * (1.0 - (1.0 - np.exp(-x)) / x)))

    def held(self) -> AmclErrorModel | None:
        """This model with its wandering part as AMCL's reported std holds it (``held_sigma_m``,
        ``held_correlation_s``), or None when it holds none."""
        if not self.held_sigma_m > 0.0:
            return None
        return replace(self, correlated_sigma_m=self.held_sigma_m, correlation_s=self.held_correlation_s,
                       held_sigma_m=0.0, held_correlation_s=0.0)

    def to_dict(self) -> dict:
        out = {"white_sigma_m": round(self.white_sigma_m, 5), "correlated_sigma_m": round(self.correlated_sigma_m, 5),
               "correlation_s": round(self.correlation_s, 3), "source": self.source, "jumps": self.jumps,
               "excluded_s": round(self.excluded_s, 2)}
        if self.held_sigma_m > 0.0:
            out.update(held_sigma_m=round(self.held_sigma_m, 5), held_correlation_s=round(self.held_correlation_s, 3))
        return out


def node_drift_variance(t_s: np.ndarray, node_t0_s: float, node_spacing_s: float, n_nodes: int,
                        correlated_sigma_m: float, correlation_s: float,
                        *, per_span: bool) -> tuple[np.ndarray, np.ndarray]:
    """(node of each estimate, variance per axis (m^2) of the wandering error's change since that
    node) for estimates at ``t_s``, each tied to its nearest node of the error process (nodes
    every ``node_spacing_s`` from ``node_t0_s``). The change over |dt| is the OU's exact
    sigma^2 (1 - exp(-2 |dt| / tau)), times the number of estimates between the same two
    nodes: those changes are one path, strongly correlated, not independent draws, so the
    estimates between two nodes tell no more about the process than about one estimate's worth
    of its change (the mean of n fully correlated changes keeps their variance: n copies of n
    times it, averaged, give it back). Without that factor the graph reads the process's
    short-term shape from n estimates as if they were n independent looks and grows overconfident
    of whatever hangs on short lags (the network's common turn from the robot's sweeps: 2-3 times
    too small a sigma); the run's mean (the long lags) is held by the nodes and keeps its variance.
    ``per_span`` False: the change alone, as if each estimate's were independent. It has no
    default: the graph takes the recipe's ``amcl_change_per_span`` (off by default, for the
    profile loop's convergence: README), while the model above is the one a Monte Carlo of the
    process bears out; a caller states which it means."""
    t = np.asarray(t_s, float)
    dn = max(float(node_spacing_s), 1e-9)
    u = (t - node_t0_s) / dn
    node = np.clip(np.round(u).astype(int), 0, max(n_nodes - 1, 0))
    tau = max(float(correlation_s), 1e-3)
    change = correlated_sigma_m ** 2 * (1.0 - np.exp(-2.0 * np.abs(t - (node_t0_s + dn * node)) / tau))
    if not per_span:
        return node, change
    segment = np.clip(np.floor(u).astype(int), 0, max(n_nodes - 2, 0))
    shared = np.bincount(segment)[segment] if len(t) else np.zeros(0, int)
    return node, change * shared


def ar1_long_run_factor(rho: float) -> float:
    """An AR(1) of coefficient ``rho``: its long-run variance (the variance of a long run's mean
    times the run's length) over one value's, (1 + rho) / (1 - rho)."""
    return (1.0 + rho) / (1.0 - rho)


def ar1_factor_sigmas(sigma: float, a: float, n_nodes: int) -> tuple[np.ndarray, float]:
    """The AR(1) x_(m+1) = a x_m + noise of stationary std ``sigma`` on ``n_nodes`` nodes as
    factors: (the zero priors' sigma per node, the increments' x_(m+1) - x_m sigma). The
    increments give the AR(1)'s exact off-diagonal precision, -a / (sigma^2 (1 - a^2)), so their
    variance is sigma^2 (1 - a^2) / a; every prior, the two ends' too, has the inner nodes'
    variance sigma^2 (1 + a) / (1 - a), which makes up the inner diagonal (1 + a^2) / (sigma^2
    (1 - a^2)) exactly. At the ends that leaves out a / (sigma^2 (1 + a)) of the stationary
    precision: the process is free at the run's two ends. The exact ends would give the first and
    the last estimates the weight of a correlation time of data each (the best linear estimate of
    an OU mean), so that a misfit there (a robot not yet moving, a start-up transient) bends the
    network's link to the map; free, the run's mean weighs the estimates alike and its variance
    is sigma^2 (1 + a) / (n (1 - a)) (about 2 sigma^2 tau / T), a few percent above the exact
    AR(1)'s. One node: sigma."""
    if n_nodes <= 1:
        return np.full(max(n_nodes, 0), float(sigma)), float("inf")
    a = float(np.clip(a, 0.0, 1.0 - 1e-12))
    priors = np.full(n_nodes, sigma * np.sqrt(ar1_long_run_factor(a)))
    return priors, float(sigma * np.sqrt((1.0 - a * a) / max(a, 1e-12)))


def amcl_period_s(t: np.ndarray, default_s: float) -> float:
    """AMCL's period, s: the median step between its stamps ``t`` (sorted), or ``default_s`` with
    fewer than two of them."""
    return float(np.median(np.diff(t))) if len(t) > 1 else float(default_s)


def reported_sigma_m(amcl) -> float:
    """Median of AMCL's reported position std (m), at least 1 mm."""
    cov = amcl[["cov_xx", "cov_yy"]].to_numpy(float)
    return max(float(np.sqrt(np.median(0.5 * (cov[:, 0] + cov[:, 1])))), 1e-3)


def assumed_model(amcl, recipe, steps: np.ndarray | None = None) -> AmclErrorModel:
    """The model before any solve: the recipe's share of the reported covariance plus what AMCL's
    own jitter shows beyond it as the white error, the reported std as the wandering one with the
    recipe's correlation time; the relocalization jumps that AMCL's track shows as steps out and
    back (:func:`detect_steps`, at the recipe's ``amcl_jump_threshold`` and ``amcl_min_jump_m``)
    left out, wherever the robot was. ``steps``: that mask (over ``amcl`` sorted by time, stable)
    when the caller has it (:func:`jumps_moved_back`'s ``steps``, on this track)."""
    sig = reported_sigma_m(amcl)
    excess = max(amcl_white_sigma(amcl) ** 2 - recipe.amcl_white_fraction ** 2 * sig ** 2, 0.0)
    ordered = amcl.sort_values("t", kind="stable")
    t = ordered["t"].to_numpy(float)
    if steps is None:
        steps = detect_steps(t, ordered[["x", "y"]].to_numpy(float), threshold=recipe.amcl_jump_threshold,
                             min_jump_m=recipe.amcl_min_jump_m)
    elif len(steps) != len(t):
        raise ValueError(f"{len(steps)} step flags for {len(t)} AMCL estimates")
    return AmclErrorModel(white_sigma_m=float(np.sqrt(excess)), correlated_sigma_m=sig,
                          correlation_s=recipe.amcl_correlation_s, reported_white_fraction=recipe.amcl_white_fraction,
                          **_exclusion(steps, steps, t))


def _exclusion(excluded: np.ndarray, track_jumps: np.ndarray, t: np.ndarray) -> dict:
    """The model's fields for the estimates ``excluded`` (those of them ``track_jumps`` found in
    AMCL's track), over AMCL's rows at times ``t`` (sorted): the masks (None when empty), the
    number of runs left out and their time at AMCL's median period."""
    period = amcl_period_s(t, 1.0)
    starts = np.flatnonzero(np.diff(np.r_[0, excluded.astype(int)]) == 1)
    return dict(excluded=excluded if excluded.any() else None,
                track_jumps=track_jumps if track_jumps.any() else None,
                jumps=len(starts), excluded_s=float(excluded.sum() * period))


def robust_variogram(t: np.ndarray, series: list[tuple[np.ndarray, np.ndarray]],
                     lags_s: np.ndarray = VARIOGRAM_LAGS_S, min_pairs: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Robust semivariance (m^2, per axis, averaged over the axes) at each lag of several series
    ``(rows, values (n, k))`` sampled at ``t[rows]`` (finite times, non-decreasing within each
    series; ties allowed), pairs taken within a series only (a quarter of the lag of it):
    (1.4826 MAD of the differences)^2 / 2, and the number of such pairs. NaN where fewer than
    ``min_pairs`` pairs exist."""
    out = np.full(len(lags_s), np.nan)
    pairs = np.zeros(len(lags_s), int)
    # every series at once, in order: its times as the imaginary part of a complex key whose real
    # part is the series' number, so that one sorted search (complex numbers order by real part,
    # then imaginary) finds each sample's partner within its own series; a search past the
    # series' end lands on the next one's first sample, past ``end``. (The times themselves are
    # compared as they are: the pairs and their differences those of a search per series, for
    # finite times non-decreasing within each series only: the keys must be sorted, and a NaN
    # time has no place in their order.)
    if series:
        lengths = np.array([len(rows) for rows, _ in series], np.int64)
        tg = np.concatenate([t[rows] for rows, _ in series]).astype(float)
        e_all = np.concatenate([np.asarray(e, float) for _, e in series])
        number = np.repeat(np.arange(len(series), dtype=float), lengths)
        end = np.repeat(np.cumsum(lengths), lengths)
        key = number + 1j * tg
    for n, lag in enumerate(lags_s):
        if series:
            j = np.searchsorted(key, number + 1j * (tg + lag))
            ok = j < end
            jj = j[ok]
            ok[ok] = np.abs(tg[jj] - tg[ok] - lag) <= 0.25 * lag + 1e-6
            d = e_all[j[ok]] - e_all[ok]
        else:
            d = np.zeros((0, 2))
        pairs[n] = len(d)
        if len(d) < min_pairs:
            continue
        mad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
        out[n] = 0.5 * float(np.mean(mad ** 2))
    return out, pairs


def fit_variogram(lags_s: np.ndarray, gamma: np.ndarray, n_eff: np.ndarray, max_correlation_s: float = 1e4,
                  floor_sigma_m: float | None = None, default_correlation_s: float = float("nan")):
    """(white std, correlated std, correlation time) fitted to a semivariogram by weighted least
    squares: each lag's relative error is about sqrt(2.7 / n_eff) (a MAD-based variance of
    ``n_eff`` independent differences, two axes). The wandering part is kept only when it lowers
    the weighted misfit by more than its two parameters would by chance (Akaike: 4); otherwise
    the error is white. A wandering error's short lags (its rate of wander, correlated^2 /
    correlation time) are what residuals show reliably; its full size is not (each sensor's pose
    absorbs AMCL's local average), so it is at least ``floor_sigma_m`` (AMCL's reported std) at the
    same rate of wander. The correlation time is at most ``max_correlation_s``; for a white error
    the data do not tell it (the fit's is any point of a flat cost, moved by rounding), and
    ``default_correlation_s`` (the assumed one; NaN if not given) is returned. None with fewer than three lags."""
    from scipy.optimize import least_squares

    ok = np.isfinite(gamma) & (gamma > 0) & (n_eff > 0)
    L, g, w = lags_s[ok], gamma[ok], np.sqrt(n_eff[ok] / 2.7)
    if len(g) < 3:
        return None

    def res(p):
        w2, c2, log_tau = p
        return w * (w2 + c2 * (1.0 - np.exp(-L / np.exp(log_tau))) - g) / g

    hi = np.log(max(max_correlation_s, 0.1))
    best = None
    for tau0 in (1.0, 10.0, 100.0):
        p0 = [g[0], max(g[-1] - g[0], 1e-8), min(np.log(tau0), hi - 1e-6)]
        fit = least_squares(res, p0, bounds=([0.0, 0.0, np.log(0.05)], [np.inf, np.inf, hi]))
        if best is None or fit.cost < best.cost:
            best = fit
    # white alone: the weighted mean level; the wandering part kept only if the data ask for it
    white2 = float(np.sum(w ** 2 / g) / np.sum(w ** 2 / g ** 2))
    cost_white = 0.5 * float(np.sum((w * (white2 - g) / g) ** 2))
    if cost_white - best.cost < 2.0:          # Akaike: 2 x (cost difference) < 2 x 2 parameters
        return float(np.sqrt(white2)), 0.0, float(default_correlation_s)
    w2, c2, log_tau = best.x
    tau = float(np.exp(log_tau))
    if floor_sigma_m is not None:
        c2, tau = hold_at_floor(c2, tau, floor_sigma_m, float(np.exp(hi)))
    return float(np.sqrt(w2)), float(np.sqrt(c2)), tau


def hold_at_floor(correlated_m2: float, correlation_s: float, floor_sigma_m: float,
                  max_correlation_s: float) -> tuple[float, float]:
    """A wandering error's (variance m^2, correlation time) held at least at ``floor_sigma_m``^2 at
    the same rate of wander (variance / correlation time, what the short lags show), the
    correlation time at most ``max_correlation_s``; unchanged when it is at least the floor."""
    if not floor_sigma_m ** 2 > correlated_m2:
        return correlated_m2, correlation_s
    rate = correlated_m2 / correlation_s
    c2 = floor_sigma_m ** 2
    return c2, float(min(c2 / max(rate, 1e-12), max_correlation_s))


def jump_scale(size: np.ndarray) -> float:
    """The scale the jump thresholds are counted in, from the sizes of 2-D departures (or steps)
    that are mostly noise: 1.4826 x their median / sqrt(ln 4). The median / sqrt(ln 4) is the
    Rayleigh sigma of a 2-D normal error (median = sigma sqrt(2 ln 2)); the 1.4826 on top (the
    normal MAD's factor) makes it 1.48 of that sigma, so a threshold of 5 is about 7.4 sigma:
    a margin kept on purpose (the detectors' figures, no false jump on white or wandering AMCL
    at 8 cm nor on the real amcl_uf_retail track, were measured with it)."""
    return float(1.4826 * np.median(size) / np.sqrt(np.log(4.0)))


def detect_jumps(t: np.ndarray, e: np.ndarray, window_s: float = 15.0, threshold: float = 5.0,
                 min_jump_m: float = 0.1) -> np.ndarray:
    """Mask of estimates whose residual departs from its running median (over +-``window_s``)
    by more than ``threshold`` robust sigmas of such departures and ``min_jump_m``."""
    from pedcal.calib.common import running_median_nearest

    n = len(t)
    if n < 10:
        return np.zeros(n, bool)
    # the window in samples at the median spacing (the estimates come at AMCL's rate)
    size = int(2 * round(window_s / max(amcl_period_s(t, 1.0), 1e-6)) + 1)
    med = running_median_nearest(e, min(size, 2 * (n // 2) - 1))
    dev = np.linalg.norm(e - med, axis=1)
    return dev > max(threshold * jump_scale(dev), min_jump_m)


def _edge_values(t: np.ndarray, p: np.ndarray, lo: np.ndarray, hi: np.ndarray, at: np.ndarray):
    """(n, k) the least-squares line through the samples ``lo[j]:hi[j]`` of (``t``, ``p``),
    evaluated at ``at[j]``; NaN where fewer than two samples (or one time) are in the window.
    Also (n,) that value's variance per unit variance of a sample's noise,
    sum(u^2) / (n sum(u^2) - (sum u)^2) with u the samples' times about ``at[j]`` (the line's
    variance where it is read: large where it extrapolates over a hole or from samples close in
    time). From cumulative sums, so a long log costs O(n)."""
    t0 = float(t[0]) if len(t) else 0.0
    tt = t - t0
    z = lambda a: np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])  # noqa: E731
    c1, ct, ctt, cp, ctp = z(np.ones_like(tt)), z(tt), z(tt * tt), z(p), z(tt[:, None] * p)
    n = c1[hi] - c1[lo]
    s_t, s_tt = ct[hi] - ct[lo], ctt[hi] - ctt[lo]
    s_p, s_tp = cp[hi] - cp[lo], ctp[hi] - ctp[lo]
    u0 = at - t0
    # about u0: sum u = s_t - n u0, sum u^2 = s_tt - 2 u0 s_t + n u0^2, sum u p = s_tp - u0 s_p
    su = s_t - n * u0
    suu = s_tt - 2.0 * u0 * s_t + n * u0 ** 2
    sup = s_tp - u0[:, None] * s_p
    det = n * suu - su ** 2
    ok = (n >= 2) & (det > 1e-12 * np.maximum(n * suu, 1e-300))
    out = np.full(p[lo].shape, np.nan)
    out[ok] = (suu[ok, None] * s_p[ok] - su[ok, None] * sup[ok]) / det[ok, None]
    var = np.full(len(out), np.inf)
    var[ok] = suu[ok] / det[ok]
    return out, var


def detect_steps(t: np.ndarray, p: np.ndarray, half_window_s: float = 1.0, threshold: float = 5.0,
                 min_jump_m: float = 0.1, max_jump_s: float = 60.0, *, offsets: bool = False):
    """Mask of AMCL's estimates ``p`` (n, 2) at times ``t`` (sorted) that sit inside a
    relocalization jump, found from AMCL's own track, wherever the sensors see the robot or not.
    A jump is a step: at each gap between estimates, the line through the estimates of the
    ``half_window_s`` after it minus the line through those of the ``half_window_s`` before,
    both taken at the gap, is the step there (the robot's motion, smooth over a second, cancels).
    Each step is counted in its own standard error, the two lines' variances where they are read
    (:func:`_edge_values`): at irregular times a window that extrapolates over a hole, or from
    estimates close in time, reads a line several times as noisy, and its step is not a jump.
    A step spreads over the gaps within the window: the largest step (in its standard errors) of
    more than ``min_jump_m`` is taken, then taken out of the track (the estimates after it moved
    back by it) and the steps across it taken again, and so on while one is beyond ``threshold``
    robust sigmas of that statistic (over the track as given); so two steps within one window are
    both found. In time order they
    move an offset that starts at 0; the estimates while it is more than ``min_jump_m`` off are the jump, when a later
    step brings it back within ``max_jump_s`` (an offset that never returns is not told from a
    relocalization that was right, and nothing is left out for it). With ``offsets``, also (n, 2)
    each estimate's offset in its jump (the steps taken since the jump began, less half of what
    the step back leaves; 0 outside one, and 0 in a jump whose steps pair in doubt, below): the
    estimate less it is where AMCL's track would have been without the jump."""
    t = np.asarray(t, float)
    p = np.asarray(p, float)
    n = len(t)
    out = np.zeros(n, bool)
    off = np.zeros((n, p.shape[1]))

    def result():
        return (out, off) if offsets else out
    # (a non-finite estimate is left out and left unflagged: the cumulative sums would carry one
    # NaN into every later window, and no step after it would be found)
    finite = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    if np.count_nonzero(finite) < 10:
        return result()
    tu, inv = np.unique(t[finite], return_inverse=True)
    pu = np.zeros((len(tu), p.shape[1]))
    np.add.at(pu, inv, p[finite])
    pu /= np.bincount(inv, minlength=len(tu))[:, None]
    m = len(tu)
    if m < 2:                                            # (one instant, however many estimates: no gap)
        return result()
    k = np.arange(1, m)                                  # gap between estimates k - 1 and k
    at = 0.5 * (tu[k - 1] + tu[k])
    first = np.searchsorted(tu, tu[k] - half_window_s)   # each gap's window: estimates first..last - 1
    last = np.searchsorted(tu, tu[k] + half_window_s)

    def steps_at(gaps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the steps at ``gaps``, their sizes in standard errors, their sizes in metres)"""
        a, b = int(first[gaps].min()), int(last[gaps].max())     # the estimates these windows read
        kk, ts, ps = k[gaps] - a, tu[a:b], pu[a:b]
        # the windows after the gaps, then those before, in one call (one set of cumulative sums)
        both, v_both = _edge_values(ts, ps, np.r_[kk, first[gaps] - a], np.r_[last[gaps] - a, kk],
                                    np.r_[at[gaps], at[gaps]])
        (after, before), (v_after, v_before) = np.split(both, 2), np.split(v_both, 2)
        d = after - before
        norm = np.linalg.norm(d, axis=1)
        z = norm / np.sqrt(v_after + v_before)
        z[~np.isfinite(z)] = 0.0
        return d, z, norm

    step, size, metres = steps_at(np.arange(m - 1))
    if not np.any(size > 0.0):
        return result()
    limit = threshold * jump_scale(size[size > 0.0])
    size[metres <= min_jump_m] = 0.0
    # the steps one at a time, the largest first, each taken out of the track before the next is
    # looked for: the gaps whose windows reach across a step see part of it (as much as a third of
    # it, on the far side of the window), which taking it out removes, where counting a window's
    # largest step alone lost a second step within the window (two relocalizations 0.3 s apart)
    found = []
    for _ in range(m - 1):
        j = int(np.argmax(size))
        if not size[j] > limit:
            break
        found.append((j, step[j].copy()))
        pu[k[j]:] -= step[j]
        near = np.arange(np.searchsorted(last, k[j], 'right'), np.searchsorted(first, k[j]))  # windows across gap j
        step[near], size[near], metres = steps_at(near)
        size[near[metres <= min_jump_m]] = 0.0
        size[j] = 0.0
    big = sorted(found, key=lambda f: f[0])
    gap = [k[j] for j, _ in big]                        # the estimate each step starts at
    jump_u = np.zeros(m, bool)
    off_u = np.zeros((m, p.shape[1]))
    spans, dropped = [], []       # (first, last) step of each jump that came back; the openings that did not
    offset, i_open = np.zeros(p.shape[1]), None
    for i, (_, step_i) in enumerate(big):
        offset = offset + step_i
        if i_open is None:                               # (every step found is above min_jump_m)
            i_open = i
        elif np.linalg.norm(offset) <= min_jump_m:
            if tu[gap[i] - 1] - tu[gap[i_open]] <= max_jump_s:
                jump_u[gap[i_open]:gap[i]] = True
                spans.append((i_open, i))
            else:
                dropped.append(i_open)
            offset, i_open = np.zeros(p.shape[1]), None
        elif tu[gap[i]] - tu[gap[i_open]] > max_jump_s:
            dropped.append(i_open)
            offset, i_open = step_i.copy(), i
    if i_open is not None:
        dropped.append(i_open)
    # Each jump's offset, where its steps pair without doubt: a stretch between two steps that
    # cancel is a jump, or its complement is (a start-up error that converges, then a jump out
    # and back, pairs the right stretch as the jump). Of the two the shorter is taken as wrong: a
    # jump whose opening step is the track's first and comes sooner after the track's start than
    # the jump lasts, or whose closing step is followed within max_jump_s by a step that opens
    # one that never closes, keeps offset 0: moved back by nothing, left for the caller to leave
    # out. Otherwise the step back measures the jump as the step out does: half of what they
    # leave between them off each piece (an out-and-back jump's offset (out - back) / 2).
    for i0, i1 in spans:
        t_open, t_close = tu[gap[i0]], tu[gap[i1]]
        if i0 == 0 and t_open - tu[0] <= t_close - t_open:
            continue
        if any(i > i1 and tu[gap[i]] - t_close <= max_jump_s for i in dropped):
            continue
        cum = np.cumsum([s_ for _, s_ in big[i0:i1 + 1]], axis=0)
        for i in range(i0, i1):
            off_u[gap[i]:gap[i + 1]] = cum[i - i0] - 0.5 * cum[-1]
    out[finite] = jump_u[inv]
    off[finite] = off_u[inv]
    return result()


class MovedJumps(NamedTuple):
    """:func:`jumps_moved_back`'s result: the log (``log`` itself when nothing was moved), the
    number of jumps moved back, and :func:`detect_steps`' mask of the track as given (sorted by
    time, stable), every jump's, moved or not (what :func:`assumed_model` takes of an unmoved track)."""

    log: Log
    jumps: int
    steps: np.ndarray


def jumps_moved_back(log, threshold: float = 5.0, min_jump_m: float = 0.1) -> MovedJumps:
    """``log`` with AMCL's estimates inside the relocalization jumps its own track shows moved
    back by the jumps' steps (:func:`detect_steps` with ``offsets``): the track as it would have
    been without them, within the steps' own error (AMCL's wander over the steps' +-1 s windows
    and its jitter: 1-3 cm on 0.3-0.4 m jumps in a 5 cm wander, tests/test_amcl_model.py). Jumps
    whose steps pair in doubt are not moved (the error model leaves them out as before); AMCL's
    heading is not moved (the steps are measured in position). Returns :class:`MovedJumps`: the
    log (``log`` itself when the track shows none), the number of jumps moved and the steps' mask."""
    robot = log.robot
    order = np.argsort(robot["t"].to_numpy(float), kind="stable")
    xy = robot[["x", "y"]].to_numpy(float)[order]
    jump, offset = detect_steps(robot["t"].to_numpy(float)[order], xy, threshold=threshold, min_jump_m=min_jump_m,
                                offsets=True)
    steps = jump.copy()
    jump &= np.any(offset != 0.0, axis=1)       # (a jump whose steps pair in doubt is not moved)
    if not jump.any():
        return MovedJumps(log, 0, steps)
    moved = xy - offset
    out = copy.copy(log)
    out.robot = robot.copy()
    rows = order[jump]
    out.robot.iloc[rows, out.robot.columns.get_loc("x")] = moved[jump, 0]
    out.robot.iloc[rows, out.robot.columns.get_loc("y")] = moved[jump, 1]
    n = _exclusion(jump, jump, robot["t"].to_numpy(float)[order])["jumps"]
    return MovedJumps(out, n, steps)


def estimate_model(t_amcl: np.ndarray, per_sensor: list[tuple[np.ndarray, np.ndarray]], assumed: AmclErrorModel,
                   *, jump_threshold: float = 5.0, min_jump_m: float = 0.1,
                   min_covered: int = 100, min_white_m: float = 0.002,
                   prior_sigma_m: float | None = None, noise_m2: float = 0.0,
                   floor: str = "hold") -> AmclErrorModel:
    """AMCL's error model from its residuals against what the ceiling sensors saw (module
    docstring): ``t_amcl`` (sorted), per sensor (rows into it, (n, 2) AMCL's head minus the head
    that sensor saw there, world xy). Each residual is AMCL's error minus that sensor's own
    position error, the same at every visit; pairs for the variogram are taken within one
    sensor's sightings only, where it cancels (across sensors, the sensors' offsets, which
    absorb AMCL's local average, would make a wandering error look smaller than it is). The
    white std is at least ``min_white_m``; the wandering std, when the data show one, at least
    ``prior_sigma_m`` (AMCL's reported std; :func:`fit_variogram`) with ``floor`` "hold"; with
    "consider" the model is the data's and the held one is kept beside it (``held_sigma_m``,
    ``held_correlation_s``: :meth:`AmclErrorModel.held`); with "off" the data's
    alone. A residual holds the sensor's
    noise too, which the graph's observation factors already carry: its variance per axis,
    averaged over the residuals (``noise_m2``), is taken off the variogram's white part (the
    nugget), so that it is not counted twice as AMCL's. Jumps are found
    in the residuals averaged over the sensors, besides those ``assumed`` found in AMCL's own
    track (``track_jumps``, kept). Returns ``assumed`` unchanged when fewer than
    ``min_covered`` estimates are covered."""
    if floor not in FLOOR_MODES:
        raise ValueError(f"floor must be one of {', '.join(FLOOR_MODES)}, got {floor!r}")
    n = len(t_amcl)
    total, count = np.zeros((n, 2)), np.zeros(n)
    for rows, e in per_sensor:
        np.add.at(total, rows, e)
        np.add.at(count, rows, 1.0)
    covered = count > 0
    if covered.sum() < min_covered:
        return assumed
    t = t_amcl[covered]
    jumps_c = detect_jumps(t, total[covered] / count[covered, None], threshold=jump_threshold, min_jump_m=min_jump_m)
    jump = np.zeros(n, bool) if assumed.track_jumps is None else assumed.track_jumps.copy()
    jump[np.flatnonzero(covered)[jumps_c]] = True
    series = [(rows[~jump[rows]], e[~jump[rows]]) for rows, e in per_sensor if len(rows)]
    gamma, pairs = robust_variogram(t_amcl, series)
    # independent differences at a lag: every pair for a white error, about one per lag of the
    # sighted time for a wandering one (its increments over disjoint spans are independent)
    period = amcl_period_s(t_amcl, 1.0)
    sighted_s = float(sum(len(rows) for rows, _ in series)) * period
    n_eff = 0.5 * np.minimum(pairs, np.maximum(sighted_s / VARIOGRAM_LAGS_S, 1.0) * 2.0)
    # a correlation time beyond half the run cannot be told from a longer one: the run's mean error
    # is then about the wandering std either way
    max_tau = 0.5 * float(t_amcl[-1] - t_amcl[0])
    fit = fit_variogram(VARIOGRAM_LAGS_S, gamma, n_eff, max_correlation_s=max_tau,
                        floor_sigma_m=prior_sigma_m if floor == "hold" else None,
                        default_correlation_s=assumed.correlation_s)
    if fit is None:
        return assumed
    white, corr, tau = fit
    held = {}
    if floor == "consider" and prior_sigma_m is not None and corr > 0.0 and prior_sigma_m > corr:
        # (a white error, no wandering part kept, is held at nothing: as with "hold")
        held_m2, held_tau = hold_at_floor(corr ** 2, tau, prior_sigma_m, max(max_tau, 0.1))
        held = dict(held_sigma_m=float(np.sqrt(held_m2)), held_correlation_s=held_tau)
    white = max(float(np.sqrt(max(white ** 2 - max(float(noise_m2), 0.0), 0.0))), min_white_m)
    track = np.zeros(n, bool) if assumed.track_jumps is None else assumed.track_jumps
    return AmclErrorModel(white_sigma_m=white, correlated_sigma_m=corr, correlation_s=tau, source="estimated",
                          **held, **_exclusion(jump, track, t_amcl),
                          variogram_lags_s=VARIOGRAM_LAGS_S.tolist(),
                          variogram_sigma_m=[float(np.sqrt(v)) if np.isfinite(v) else float("nan") for v in gamma])


def amcl_cov_body(cov_world: np.ndarray, yaw) -> np.ndarray:
    """AMCL's (x, y, yaw) world covariance as a Pose3 tangent covariance [rx, ry, rz, tx, ty, tz]
    in the body frame (GTSAM's convention), without the roll/pitch/z blocks. Vectorized: a
    (N, 3, 3) stack with N yaws gives (N, 6, 6)."""
    C = np.asarray(cov_world, float)
    yaw = np.asarray(yaw, float)
    c, s = np.cos(yaw), np.sin(yaw)
    Rt = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)        # world -> body for xy
    out = np.zeros(C.shape[:-2] + (6, 6))
    out[..., 2, 2] = C[..., 2, 2]
    out[..., 3:5, 3:5] = Rt @ C[..., :2, :2] @ np.swapaxes(Rt, -1, -2)
    cross = (Rt @ C[..., :2, 2:3])[..., 0]
    out[..., 3:5, 2] = cross
    out[..., 2, 3:5] = cross
    return out


def amcl_white_sigma(amcl: pd.DataFrame) -> float:
    """Std (m) of the white part of AMCL's position error, from its own jitter: on a smooth
    trajectory each estimate's departure from the straight line through its two neighbours (in
    time: AMCL publishes irregularly) is a white error times sqrt(1 + a^2 + b^2), a and b the
    neighbours' interpolation weights (the robot's acceleration adds millimetres at AMCL's
    rates; a slowly wandering error adds less). Median absolute deviation, so jumps and turns do
    not count."""
    tr = amcl.groupby("t", sort=True)[["x", "y"]].mean()
    t, p = tr.index.to_numpy(float), tr.to_numpy(float)
    if len(t) < 10:
        return 0.0
    b = ((t[1:-1] - t[:-2]) / (t[2:] - t[:-2]))[:, None]      # weight of the next estimate
    e = (p[1:-1] - ((1.0 - b) * p[:-2] + b * p[2:])) / np.sqrt(1.0 + (1.0 - b) ** 2 + b ** 2)
    mad = np.median(np.abs(e - np.median(e, axis=0)), axis=0)
    return float(1.4826 * np.sqrt(np.mean(mad ** 2)))


__all__ = ["AmclErrorModel", "amcl_white_sigma", "amcl_cov_body", "assumed_model", "estimate_model",
           "robust_variogram", "fit_variogram", "hold_at_floor", "FLOOR_MODES",
           "node_drift_variance", "ar1_factor_sigmas", "ar1_long_run_factor",
           "detect_jumps", "detect_steps", "reported_sigma_m", "amcl_period_s", "VARIOGRAM_LAGS_S"]
