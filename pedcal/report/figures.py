"""Report figures: matplotlib on the Agg canvas (no pyplot state, no display), saved atomically
as PNG without a date or software stamp, so the same results give the same bytes (the canvas and
the writer are pedcal.plotting's, shared with the detector's and the follower's pictures)."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
from matplotlib.ticker import MaxNLocator

from pedcal.plotting import DPI, PNG_METADATA, new_figure, save_png  # noqa: F401  (report code imports them here)
from pedcal.report.sweep import UNCALIBRATED

METHOD_COLORS = {"installed": "#7f7f7f", "alternative": "#d62728", "gridsearch": "#1f77b4",
                 "closedform": "#2ca02c", "factorgraph": "#9467bd"}


def color(method: str, k: int = 0) -> str:
    return METHOD_COLORS.get(method, f"C{k % 10}")


def per_sensor_bars(sensors: pd.DataFrame, methods: list[str], title: str, per_row: int = 10) -> Figure:
    """Mean position error per sensor over seeds, one bar per method, with the mean reported
    3-D 1-sigma as a black dash for methods that report one; ``per_row`` sensors per panel."""
    ids = sorted(sensors["sensor"].unique())
    rows = [ids[i:i + per_row] for i in range(0, len(ids), per_row)]
    fig = new_figure(max(7.0, 0.14 * min(len(ids), per_row) * len(methods) + 1.5), 2.6 * len(rows) + 1.2)
    axes = fig.subplots(len(rows), 1, squeeze=False, sharey=True)[:, 0]
    width = 0.8 / len(methods)
    sig3 = np.sqrt(sensors["sigma_x_mm"] ** 2 + sensors["sigma_y_mm"] ** 2 + sensors["sigma_z_mm"] ** 2)
    df = sensors.assign(sigma_3d_mm=sig3)
    sigma_labelled = False
    for ax, row_ids in zip(axes, rows, strict=True):
        x = np.arange(len(row_ids))
        for k, m in enumerate(methods):
            g = df[df["method"] == m].groupby("sensor")
            err = g["err_mm"].mean().reindex(row_ids).to_numpy()
            sig = g["sigma_3d_mm"].mean().reindex(row_ids).to_numpy()
            xk = x + (k - (len(methods) - 1) / 2) * width
            ax.bar(xk, err, width, color=color(m, k), label=m if ax is axes[0] else None)
            if np.isfinite(sig).any():
                ax.scatter(xk, sig, marker="_", s=120, linewidths=2.0, color="k", zorder=3,
                           label="reported 3-D 1σ (mean)" if ax is axes[0] and not sigma_labelled else None)
                sigma_labelled = sigma_labelled or ax is axes[0]
        ax.set_xticks(x, row_ids)
        ax.set_xlim(-0.5, per_row - 0.5 if len(rows) > 1 else len(row_ids) - 0.5)
        ax.set_yscale("log")
        ax.set_ylabel("error (mm)")
        ax.grid(axis="y", which="both", alpha=0.3)
    axes[-1].set_xlabel("sensor")
    axes[0].set_title(title + "\n(position error |estimated − true| per sensor, log scale)")
    fig.legend(fontsize=8, ncols=min(len(methods) + 1, 6), loc="outside lower center")
    return fig


def error_histograms(sensors: pd.DataFrame, methods: list[str], title: str) -> Figure:
    """Histogram of per-sensor position errors over all seeds, one outline per method."""
    fig = new_figure(7.0, 3.8)
    ax = fig.add_subplot()
    e = sensors["err_mm"].to_numpy()
    e = e[np.isfinite(e) & (e > 0)]
    bins = np.geomspace(max(1.0, np.floor(e.min())), np.ceil(e.max()) * 1.01, 40) if len(e) else 10
    for k, m in enumerate(methods):
        v = sensors.loc[sensors["method"] == m, "err_mm"].to_numpy()
        ax.hist(v[np.isfinite(v)], bins=bins, histtype="step", linewidth=1.6, color=color(m, k),
                label=f"{m} (n={np.isfinite(v).sum()})")
    ax.set_xscale("log")
    ax.set_xlabel("sensor position error (mm, log scale)")
    ax.set_ylabel("sensors × seeds")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _sensor_markers(ax, truth: pd.DataFrame, label: str | None = "sensor (true position, arrow: view)",
                    arrow_color: str = "k") -> None:
    yaw = np.radians(truth["true_yaw_deg"].to_numpy())
    span_m = max(np.ptp(truth["true_x_m"]), np.ptp(truth["true_y_m"]), 1.0)
    arrow_m = max(0.5, 0.05 * span_m)
    ax.scatter(truth["true_x_m"], truth["true_y_m"], marker="^", s=30, color="k", zorder=5, label=label)
    ax.quiver(truth["true_x_m"], truth["true_y_m"], arrow_m * np.cos(yaw), arrow_m * np.sin(yaw), angles="xy",
              scale_units="xy", scale=1.0, width=0.004, color=arrow_color, zorder=4)


def head_trajectories(heads: pd.DataFrame, robot: pd.DataFrame, sensors: pd.DataFrame, methods: list[str],
                      title: str, ref_label: str = "robot's true head path",
                      sensor_label: str = "sensor (true position, arrow: view)") -> Figure:
    """One panel per method: the robot's head positions computed with that method's extrinsics
    over the robot's path (Kimoto et al., Figs. 5 and 6)."""
    truth = sensors.drop_duplicates("sensor")
    xs = np.r_[robot["x_m"], truth["true_x_m"]]
    ys = np.r_[robot["y_m"], truth["true_y_m"]]
    span = max(np.ptp(xs), 1.0), max(np.ptp(ys), 1.0)
    ncols = min(len(methods), 3 if span[0] < 2 * span[1] else 2)
    nrows = -(-len(methods) // ncols)
    panel_w = 4.2
    panel_h = float(np.clip(panel_w * span[1] / span[0], 1.8, 5.0)) + 0.6
    fig = new_figure(panel_w * ncols, panel_h * nrows + 0.4)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=True, sharey=True)
    for k, m in enumerate(methods):
        ax = axes.flat[k]
        ax.plot(robot["x_m"], robot["y_m"], color="0.6", lw=0.8, label=ref_label if k == 0 else None)
        h = heads[heads["method"] == m]
        ax.scatter(h["x_m"], h["y_m"], s=1.5, color=color(m, k), alpha=0.6)
        _sensor_markers(ax, truth, label=sensor_label if k == 0 else None)
        ax.set_title(f"head from {m}", fontsize=10)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(methods):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("x (m)")
    for ax in axes[:, 0]:
        ax.set_ylabel("y (m)")
    fig.suptitle(title)
    fig.legend(fontsize=8, ncols=2, loc="outside lower center")
    return fig


def covariance_floorplan(sensors: pd.DataFrame, methods: list[str], title: str) -> Figure | None:
    """Floor plan, one panel per method that reports a sigma: true sensors, each calibrated
    sensor's position error as an arrow and its reported 1-sigma (x, y) ellipse around the
    estimate, both magnified by the panel's stated factor; sensors left without data are crossed.
    None when no method reports a sigma."""
    with_sigma = [m for m in methods if np.isfinite(sensors.loc[sensors["method"] == m, "sigma_x_mm"]).any()]
    if not with_sigma:
        return None
    truth = sensors.drop_duplicates("sensor")
    span_x, span_y = max(np.ptp(truth["true_x_m"]), 1.0), max(np.ptp(truth["true_y_m"]), 1.0)
    span_m = max(span_x, span_y)
    pad_m = 0.6 + 0.05 * span_m
    axes_w = 5.4        # of the 8.5 in width; the legends take the rest
    panel_h = axes_w * (span_y + 2 * pad_m) / (span_x + 2 * pad_m) + 0.7
    fig = new_figure(9.0, panel_h * len(with_sigma) + 0.4)
    axes = fig.subplots(len(with_sigma), 1, squeeze=False)[:, 0]
    for k, (ax, m) in enumerate(zip(axes, with_sigma, strict=True)):
        d = sensors[sensors["method"] == m]
        calibrated = d[~d["status"].isin(UNCALIBRATED)]
        sizes = np.r_[calibrated["err_mm"], calibrated["sigma_x_mm"], calibrated["sigma_y_mm"]] / 1000.0
        sizes = sizes[np.isfinite(sizes)]
        typical_m = float(np.median(sizes)) if len(sizes) else 0.1
        # One power of ten such that a typical error or sigma is drawn about 5 % of the area.
        gain = float(10.0 ** np.round(np.log10(0.05 * span_m / max(typical_m, 1e-6))))
        c = color(m, methods.index(m))
        _sensor_markers(ax, truth, label="true sensor (grey: view)" if k == 0 else None,
                        arrow_color="0.75")
        ex, ey = gain * calibrated["err_x_mm"] / 1000.0, gain * calibrated["err_y_mm"] / 1000.0
        ax.quiver(calibrated["true_x_m"], calibrated["true_y_m"], ex, ey, angles="xy", scale_units="xy", scale=1.0,
                  width=0.003, color=c, label="position error (magnified)")
        for x0, y0, dx, dy, sx, sy in zip(calibrated["true_x_m"], calibrated["true_y_m"], ex, ey,
                                          calibrated["sigma_x_mm"], calibrated["sigma_y_mm"], strict=True):
            if np.isfinite(sx) and np.isfinite(sy):
                ax.add_patch(Ellipse((x0 + dx, y0 + dy), 2 * gain * sx / 1000.0, 2 * gain * sy / 1000.0,
                                     fill=False, color=c, lw=1.0))
        ax.plot([], [], color=c, lw=1.0, label="reported 1σ in x, y (magnified)")
        none = d[d["status"].isin(UNCALIBRATED)]
        if len(none):
            ax.scatter(none["true_x_m"], none["true_y_m"], marker="x", s=80, color=c, zorder=6,
                       label="no data: not calibrated")
        ax.set_aspect("equal")
        ax.set_xlim(truth["true_x_m"].min() - pad_m, truth["true_x_m"].max() + pad_m)
        ax.set_ylim(truth["true_y_m"].min() - pad_m, truth["true_y_m"].max() + pad_m)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{m}: error and reported 1σ, both × {gain:g}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.suptitle(title)
    return fig


def head_rms_bars(rows: pd.DataFrame, title: str) -> Figure:
    """Per-sensor head tracking RMS, one bar per extrinsics file (``rows``: label, sensor, head_rms_mm)."""
    labels = list(dict.fromkeys(rows["label"]))
    ids = sorted(rows["sensor"].unique())
    fig = new_figure(max(6.0, 0.3 * len(ids) * len(labels) + 1.5), 3.8)
    ax = fig.add_subplot()
    width = 0.8 / len(labels)
    x = np.arange(len(ids))
    for k, lab in enumerate(labels):
        v = rows[rows["label"] == lab].set_index("sensor")["head_rms_mm"].reindex(ids).to_numpy(float)
        ax.bar(x + (k - (len(labels) - 1) / 2) * width, v, width, color=color(lab, k), label=lab)
    ax.set_xticks(x, ids, rotation=90 if len(ids) > 12 else 0)
    ax.set_xlabel("sensor")
    ax.set_ylabel("head tracking RMS (mm)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return fig
