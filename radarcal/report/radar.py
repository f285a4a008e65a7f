"""Figures of a radar(-LiDAR) calibration (``radarcal radar-lidar``): numpy arrays in, matplotlib Figure out.

Frames: the main LiDAR frame (x forward, y left, z up, m) for the top view; radar detections in each radar's scanning
plane (x forward, y left, m, the slant range as measured). Residuals in cm on the axes, m in the arrays; σ of the yaw
in degrees, of x / y in cm.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from radarcal.report._common import new_figure

__all__ = ["detection_category", "radar_points_in_main", "reflector_residuals_figure", "radar_top_view_figure", "rcs_range_figure", "radar_sigma_figure"]

# what the calibration took each detection for (radarcal.extrinsics.radar.session labels) -> (marker, colour, legend)
_CATEGORY_STYLE = {
    "reflector": ("o", None, "matched reflector"),
    "rejected": ("s", "tab:red", "matched, rejected as outlier"),
    "multipath": ("+", "tab:purple", "multipath ghost"),
    "clutter": ("x", "tab:olive", "clutter (low RCS)"),
    "ghost": (".", "tab:gray", "unmatched (ghost)"),
    "detection": ("o", None, "detection (not labelled by the session)"),
}


def detection_category(label: str) -> str:
    """``reflector 2`` -> reflector, ``rejected (reflector 1)`` -> rejected, ``multipath ghost of …`` -> multipath,
    ``clutter (low RCS)`` -> clutter, ``detection`` (no label stored) -> detection, anything else -> ghost."""
    s = str(label)
    for key in ("rejected", "multipath", "clutter", "reflector", "detection"):
        if s.startswith(key):
            return key
    return "ghost"


def radar_points_in_main(xy_radar: np.ndarray, T_main_radar: np.ndarray) -> np.ndarray:
    """(M,2) detections of a radar (its scanning plane, z = 0) -> (M,3) in the main LiDAR frame."""
    xy = np.asarray(xy_radar, float).reshape(-1, 2)
    T = np.asarray(T_main_radar, float)
    return xy @ T[:3, :2].T + T[:3, 3]


def _radar_colours(names: Sequence[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return {n: cmap(i % 10) for i, n in enumerate(names)}


def reflector_residuals_figure(residual_m: Mapping[str, np.ndarray], used: Mapping[str, np.ndarray], holdout_m: Mapping[str, np.ndarray] | None = None, labels: Mapping[str, Sequence[str]] | None = None,
                               title: str = "Residual per matched reflector"):  # fmt: skip
    """One bar per matched reflector (grouped by radar, in cm): the fit residual; rejected reflectors red and hatched;
    the leave-one-out residual of each kept reflector as a black tick. ``labels[r]``: a tick label per reflector."""
    radars = list(residual_m)
    cols = _radar_colours(radars)
    n_all = sum(np.size(residual_m[r]) for r in radars)
    fig, ax = new_figure(max(6.0, min(16.0, 1.2 + 0.28 * n_all)), 4.2)
    x0 = 0
    ticks, tick_labels = [], []
    for r in radars:
        res = np.asarray(residual_m[r], float).ravel() * 100.0
        ok = np.asarray(used[r], bool).ravel() if r in used else np.ones(res.size, bool)
        x = x0 + np.arange(res.size)
        rms = float(np.sqrt(np.mean(res[ok] ** 2))) if ok.any() else float("nan")
        ax.bar(x[ok], res[ok], color=cols[r], label=f"{r}: RMS {rms:.2f} cm over {int(ok.sum())}")
        if (~ok).any():
            ax.bar(x[~ok], res[~ok], color="tab:red", hatch="//", edgecolor="black", label=f"{r}: rejected ({int((~ok).sum())})")
        if holdout_m is not None and r in holdout_m:
            h = np.asarray(holdout_m[r], float).ravel() * 100.0
            fin = np.isfinite(h)
            if fin.any():
                ax.plot(x[fin], h[fin], "_", color="black", ms=12, mew=2, label="leave-one-out" if r == radars[0] else None)
        lab = list(labels[r]) if labels is not None and r in labels else [f"{r} #{i}" for i in range(res.size)]
        ticks += list(x)
        tick_labels += lab
        x0 += res.size + 1
    ax.set_xticks(ticks)
    ax.set_xticklabels(tick_labels, rotation=90, fontsize=7)
    ax.set_ylabel("residual (cm)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title)
    return fig


def radar_top_view_figure(lidar_centres: Mapping[str, np.ndarray], detections_main: Mapping[str, np.ndarray], categories: Mapping[str, Sequence[str]] | None = None,
                          sensor_poses: Mapping[str, np.ndarray] | None = None, main_lidar: str = "main LiDAR", title: str = "Reflectors and radar detections, main LiDAR frame (top view)"):  # fmt: skip
    """Top view of the main LiDAR frame: reflector centres of every placement (black triangles), each radar's
    detections mapped with its calibrated pose (``detections_main[r]`` (M,3), categories per detection as from
    :func:`detection_category`), and every sensor's position and forward axis (``sensor_poses[name]`` = T_main_sensor)."""
    fig, ax = new_figure(8.0, 6.5)
    cols = _radar_colours(list(detections_main))
    allc = [np.asarray(c, float).reshape(-1, 3) for c in lidar_centres.values()]
    c = np.concatenate(allc) if allc else np.zeros((0, 3))
    ax.plot(c[:, 0], c[:, 1], "^", color="black", ms=9, mfc="none", mew=1.5, label=f"reflector ({main_lidar})", zorder=5)
    for r, p in detections_main.items():
        p = np.asarray(p, float).reshape(-1, 3)
        cat = np.asarray(list(categories[r]) if categories is not None and r in categories else ["reflector"] * len(p), str)
        for key, (marker, colour, name) in _CATEGORY_STYLE.items():
            m = cat == key
            if m.any():
                ax.plot(p[m, 0], p[m, 1], marker, ls="none", color=colour or cols[r], ms=6 if marker != "." else 8, label=f"{r}: {name}" if key == "reflector" else f"{r}: {name}", zorder=4)
    L = 0.4 + 0.05 * float(np.ptp(c[:, :2], axis=0).max()) if len(c) else 0.5
    for name, T in (sensor_poses or {}).items():
        T = np.asarray(T, float)
        o, f = T[:3, 3], T[:3, 0]
        col = cols.get(name, "dimgray")
        ax.annotate("", xy=(o[0] + L * f[0], o[1] + L * f[1]), xytext=(o[0], o[1]), arrowprops=dict(arrowstyle="->", color=col, lw=2))
        ax.plot(o[0], o[1], "D", color=col, ms=6, zorder=6)
        ax.annotate(name, (o[0], o[1]), xytext=(4, -10), textcoords="offset points", fontsize=7, color=col)
    ax.plot(0, 0, "D", color="black", ms=7, zorder=6)
    ax.annotate(main_lidar, (0, 0), xytext=(4, 4), textcoords="offset points", fontsize=7)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title + "\nradar detections at their measured (slant) range in the radar's plane", fontsize=10)
    return fig


def rcs_range_figure(range_m: Mapping[str, np.ndarray], rcs_dbsm: Mapping[str, np.ndarray], categories: Mapping[str, Sequence[str]] | None = None, title: str = "Radar cross-section against range"):
    """RCS (dBsm) of every (frame-averaged) detection against its measured range (m), per radar, marked by what the
    calibration took it for (matched reflector, clutter, multipath, ghost)."""
    fig, ax = new_figure(7.5, 4.2)
    cols = _radar_colours(list(range_m))
    for r in range_m:
        rr = np.asarray(range_m[r], float).ravel()
        cs = np.asarray(rcs_dbsm[r], float).ravel()
        cat = np.asarray(list(categories[r]) if categories is not None and r in categories else ["reflector"] * rr.size, str)
        for key, (marker, colour, name) in _CATEGORY_STYLE.items():
            m = cat == key
            if m.any():
                ax.plot(rr[m], cs[m], marker, ls="none", color=colour or cols[r], ms=6 if marker != "." else 8, label=f"{r}: {name}")
    ax.set_xlabel("range (m)")
    ax.set_ylabel("RCS (dBsm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title)
    return fig


def radar_sigma_figure(names: Sequence[str], yaw_deg: Sequence[float], x_m: Sequence[float], y_m: Sequence[float], jackknife_yaw_deg: Sequence[float] | None = None,
                       title: str = "1σ of each radar's fitted pose (yaw, x, y in the ground plane)"):  # fmt: skip
    """Two panels: the yaw σ (deg; the jackknife σ beside it when given, NaN = absent) and the x / y σ (cm)."""
    fig, (a, b) = new_figure(8.0, 3.6, 1, 2)
    n = len(names)
    x = np.arange(n)
    yaw = np.asarray(yaw_deg, float)
    jk = None if jackknife_yaw_deg is None else np.asarray(jackknife_yaw_deg, float)
    w = 0.38 if jk is not None and np.isfinite(jk).any() else 0.7
    a.bar(x - (w / 2 if w < 0.5 else 0), yaw, w, color="tab:blue", label="from the fit (Jacobian)")
    if w < 0.5:
        a.bar(x + w / 2, np.nan_to_num(jk, nan=0.0), w, color="tab:orange", label="jackknife (leave one out)")
    a.set_xticks(x)
    a.set_xticklabels(names, rotation=30, fontsize=8)
    a.set_ylabel("σ yaw (deg)")
    a.legend(fontsize=7)
    b.bar(x - 0.19, np.asarray(x_m, float) * 100, 0.38, color="tab:green", label="x")
    b.bar(x + 0.19, np.asarray(y_m, float) * 100, 0.38, color="tab:purple", label="y")
    b.set_xticks(x)
    b.set_xticklabels(names, rotation=30, fontsize=8)
    b.set_ylabel("σ (cm)")
    b.legend(fontsize=7)
    fig.suptitle(title, fontsize=11)
    return fig
