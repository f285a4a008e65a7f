"""Figures of the field pose (field-pnp) and of a match run (tracks): numpy arrays in, matplotlib Figure out.

Field frame: origin at a field corner, x along the long side (28 m), y across (15 m), z up, metres. A field is
passed as plain values (``size=(length, width)``, ``landmarks={name: (x, y, z)}``, optional ``outline`` polygons),
so these figures work with any field model object.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from radarcal.report._common import auto_arrow_scale, new_figure, show_image
from radarcal.teams import track_colours

__all__ = [
    "draw_field",
    "field_landmarks_figure",
    "picks_residual_figure",
    "localisation_error_figure",
    "minimap_tracks_figure",
    "error_over_time_figure",
    "camera_position_on_field",
]


def camera_position_on_field(T_cam_field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre in the field frame and its viewing direction (unit z axis of the camera) in the field frame."""
    T = np.asarray(T_cam_field, float)
    R, t = T[:3, :3], T[:3, 3]
    return -R.T @ t, R.T @ np.array([0.0, 0.0, 1.0])


def draw_field(ax, size: tuple[float, float], outline: Sequence[np.ndarray] | None = None, landmarks: Mapping[str, Sequence[float]] | None = None, label_landmarks: bool | Sequence[str] = True) -> None:
    """Field rectangle, optional outline polygons (areas, walls) and landmarks on ``ax`` (x right, y up, metres).
    ``label_landmarks``: True (all), False (none) or the names to label."""
    from matplotlib.patches import Polygon, Rectangle

    L, W = float(size[0]), float(size[1])
    ax.add_patch(Rectangle((0, 0), L, W, fill=True, facecolor="#eef3ea", edgecolor="black", lw=1.5, zorder=0))
    for poly in outline or []:
        p = np.asarray(poly, float).reshape(-1, 2 if np.asarray(poly).shape[-1] == 2 else 3)[:, :2]
        ax.add_patch(Polygon(p, closed=True, fill=False, edgecolor="gray", lw=0.8, zorder=1))
    if landmarks:
        names = list(landmarks)
        xyz = np.array([np.asarray(landmarks[n], float)[:3] for n in names]).reshape(-1, 3)
        ax.plot(xyz[:, 0], xyz[:, 1], "s", color="tab:green", ms=5, zorder=3, label="landmarks")
        if label_landmarks:
            wanted = set(names) if label_landmarks is True else set(label_landmarks)
            for n, (x, y, _) in zip(names, xyz):
                if n in wanted:
                    ax.annotate(n, (x, y), xytext=(3, 3), textcoords="offset points", fontsize=7, color="darkgreen")
    m = 0.05 * L
    ax.set_xlim(-m, L + m)
    ax.set_ylim(-m, W + m)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def field_landmarks_figure(size: tuple[float, float], landmarks: Mapping[str, Sequence[float]], T_cam_field: np.ndarray | None = None, picked: Sequence[str] | None = None, outline: Sequence[np.ndarray] | None = None, title: str = "Field, landmarks and camera"):
    """Top view of the field: landmarks (the picked ones circled) and, with ``T_cam_field``, the camera's
    position and viewing direction."""
    fig, ax = new_figure(8.0, 8.0 * size[1] / size[0] + 0.8)
    draw_field(ax, size, outline, landmarks, label_landmarks=list(picked) if picked else True)
    if picked:
        xyz = np.array([np.asarray(landmarks[n], float)[:3] for n in picked if n in landmarks]).reshape(-1, 3)
        ax.plot(xyz[:, 0], xyz[:, 1], "o", mfc="none", mec="tab:red", ms=11, mew=1.5, zorder=4, label="picked")
    if T_cam_field is not None:
        c, d = camera_position_on_field(T_cam_field)
        ax.plot(c[0], c[1], "^", color="tab:blue", ms=10, zorder=5, label=f"camera (z = {c[2]:.2f} m)")
        dn = d[:2] / max(np.linalg.norm(d[:2]), 1e-9)
        ax.annotate("", xy=(c[0] + 3 * dn[0], c[1] + 3 * dn[1]), xytext=(c[0], c[1]), arrowprops=dict(arrowstyle="->", color="tab:blue", lw=2))
        ax.set_xlim(min(ax.get_xlim()[0], c[0] - 1), max(ax.get_xlim()[1], c[0] + 1))
        ax.set_ylim(min(ax.get_ylim()[0], c[1] - 1), max(ax.get_ylim()[1], c[1] + 1))
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title)
    return fig


def picks_residual_figure(image_size: tuple[int, int], names: Sequence[str], uv_picked: np.ndarray, uv_reprojected: np.ndarray, image: np.ndarray | None = None, scale: float | None = None, outlier: np.ndarray | None = None, title: str = "Landmark picks and reprojection residuals"):
    """The picked pixels (crosses), the landmarks reprojected with the solved pose (circles), and the residual
    (picked − reprojected) as arrows magnified by ``scale`` (auto). Outlier picks in red."""
    a = np.asarray(uv_picked, float).reshape(-1, 2)
    b = np.asarray(uv_reprojected, float).reshape(-1, 2)
    r = a - b
    if scale is None:
        scale = max(1.0, round(auto_arrow_scale(r, image_size, 0.06)))
    out = np.zeros(len(a), bool) if outlier is None else np.asarray(outlier, bool).ravel()
    w, h = image_size
    fig, ax = new_figure(8.0, 8.0 * h / w + 0.6)
    show_image(ax, image_size, image, alpha=0.7)
    ax.plot(b[:, 0], b[:, 1], "o", mfc="none", mec="tab:green", ms=9, label="reprojected landmark")
    ax.plot(a[:, 0], a[:, 1], "x", color="tab:blue", ms=7, label="pick")
    col = np.where(out, "tab:red", "tab:orange")
    ax.quiver(b[:, 0], b[:, 1], r[:, 0] * scale, r[:, 1] * scale, color=col, angles="xy", scale_units="xy", scale=1.0, width=0.003)
    err = np.linalg.norm(r, axis=1)
    for n, p, e in zip(names, a, err):
        ax.annotate(f"{n} {e:.2f}px", p, xytext=(5, -8), textcoords="offset points", fontsize=7, color="white", bbox=dict(fc="black", alpha=0.5, lw=0, pad=1))
    ax.legend(fontsize=8, loc="lower right")
    rms = float(np.sqrt(np.mean(err**2))) if err.size else float("nan")
    ax.set_title(f"{title}\nRMS {rms:.2f} px; arrows ×{scale:.0f}", fontsize=10)
    return fig


def localisation_error_figure(x_grid: np.ndarray, y_grid: np.ndarray, sigma_m: np.ndarray, size: tuple[float, float], T_cam_field: np.ndarray | None = None, landmarks: Mapping[str, Sequence[float]] | None = None, outline: Sequence[np.ndarray] | None = None, levels_m: Sequence[float] = (0.1, 0.2, 0.3, 0.5, 1.0), title: str = "Expected 1σ localisation error"):
    """Colour map of the expected position error (m) over the field (``sigma_m`` shape (ny, nx) on ``x_grid`` (nx,),
    ``y_grid`` (ny,)); NaN = not visible. Contours at ``levels_m``."""
    s = np.asarray(sigma_m, float)
    x = np.asarray(x_grid, float).ravel()
    y = np.asarray(y_grid, float).ravel()
    if s.shape != (y.size, x.size):
        raise ValueError(f"sigma_m shape {s.shape} does not match grid ({y.size}, {x.size})")
    fig, ax = new_figure(8.0, 8.0 * size[1] / size[0] + 0.8)
    draw_field(ax, size, outline, landmarks, label_landmarks=False)
    finite = s[np.isfinite(s)]
    vmax = float(np.percentile(finite, 98)) if finite.size else 1.0
    im = ax.pcolormesh(x, y, np.ma.masked_invalid(s), cmap="RdYlGn_r", vmin=0.0, vmax=max(vmax, 1e-6), shading="nearest", zorder=2, alpha=0.85)
    fig.colorbar(im, ax=ax, label="1σ error (m)", shrink=0.8)
    lv = [lv for lv in levels_m if finite.size and finite.min() < lv < finite.max()]
    if lv:
        cs = ax.contour(x, y, np.ma.masked_invalid(s), levels=lv, colors="black", linewidths=0.7, zorder=3)
        ax.clabel(cs, fontsize=7, fmt="%g m")
    if T_cam_field is not None:
        c, _ = camera_position_on_field(T_cam_field)
        ax.plot(c[0], c[1], "^", color="tab:blue", ms=10, zorder=5, label="camera")
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    med = float(np.median(finite)) if finite.size else float("nan")
    ax.set_title(f"{title}\nmedian {med:.2f} m, visible over {np.isfinite(s).mean():.0%} of the grid", fontsize=10)
    return fig


def minimap_tracks_figure(size: tuple[float, float], tracks: Mapping[str, np.ndarray], truth: Mapping[str, np.ndarray] | None = None, outline: Sequence[np.ndarray] | None = None, landmarks: Mapping[str, Sequence[float]] | None = None, title: str = "Minimap: tracks"):
    """Each robot's track (``tracks[label]`` = (N, 2+) field x, y[, …]) as a line with its last position marked;
    ``truth`` tracks (same labels) dashed. Colours by team (:mod:`radarcal.teams`)."""
    fig, ax = new_figure(8.0, 8.0 * size[1] / size[0] + 0.8)
    draw_field(ax, size, outline, landmarks, label_landmarks=False)
    colours = track_colours(tracks)
    for label, xy in sorted(tracks.items()):
        p = np.asarray(xy, float).reshape(len(xy), -1)[:, :2]
        col = colours[label]
        ax.plot(p[:, 0], p[:, 1], "-", color=col, lw=1.2, label=str(label), zorder=4)
        ok = np.all(np.isfinite(p), axis=1)
        if ok.any():
            last = p[ok][-1]
            ax.plot(last[0], last[1], "o", color=col, ms=7, mec="black", zorder=5)
        if truth and label in truth:
            q = np.asarray(truth[label], float).reshape(len(truth[label]), -1)[:, :2]
            ax.plot(q[:, 0], q[:, 1], "--", color=col, lw=0.8, alpha=0.7, zorder=3)
    if tracks:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title + (" (truth dashed)" if truth else ""))
    return fig


def error_over_time_figure(t: Mapping[str, np.ndarray], error_m: Mapping[str, np.ndarray], title: str = "Localisation error over time"):
    """Per-robot error (m) against time (s), with the overall median and 95th percentile as horizontal lines; colours
    by team as on the minimap."""
    fig, ax = new_figure(8.0, 3.6)
    colours = track_colours(error_m)
    allerr = []
    for label in sorted(error_m):
        e = np.asarray(error_m[label], float).ravel()
        ax.plot(np.asarray(t[label], float).ravel(), e, "-", lw=0.9, color=colours[label], label=str(label))
        allerr.append(e[np.isfinite(e)])
    a = np.concatenate(allerr) if allerr else np.zeros(0)
    if a.size:
        med, p95 = float(np.median(a)), float(np.percentile(a, 95))
        ax.axhline(med, color="k", lw=1, label=f"median {med:.2f} m")
        ax.axhline(p95, color="k", lw=1, ls="--", label=f"95th pct {p95:.2f} m")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("error (m)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title(title)
    return fig
