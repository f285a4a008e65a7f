"""Figures of a LiDAR-camera extrinsic calibration (numpy arrays in, matplotlib Figure out; no file I/O).

Projection is :meth:`radarcal.camera.Camera.project_from` (the one projection of the package).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from radarcal.camera import Camera
from radarcal.extrinsics.pose_params import PARAM_NAMES  # one definition of the pose parameters (re-exported)
from radarcal.extrinsics.pose_params import parameter_profiles as cost_profiles  # the one profile evaluator (re-exported)
from radarcal.report._common import new_figure, point_size_pt2, show_image

__all__ = [
    "PARAM_NAMES",
    "project_cloud",
    "cloud_overlay_figure",
    "edge_matches_figure",
    "edge_residual_histogram_figure",
    "cost_profiles",
    "cost_profile_figure",
]



def project_cloud(camera: Camera, T_cam_lidar: np.ndarray, points_lidar: np.ndarray, max_points: int | None = 60_000, seed: int = 0, return_count: bool = False):
    """Pixels and depths of the cloud points that land inside the image in front of the camera (subsampled to
    ``max_points`` with a fixed seed), sorted far-to-near so near points are drawn on top. With ``return_count``
    also the number of points in view before subsampling."""
    p = np.asarray(points_lidar, float).reshape(-1, 3)
    uv, valid, z = camera.project_from(T_cam_lidar, p)
    keep = valid & camera.in_image(uv)
    uv, z = uv[keep], z[keep]
    n_in_view = len(z)
    if max_points is not None and len(z) > max_points:
        idx = np.random.default_rng(seed).choice(len(z), max_points, replace=False)
        uv, z = uv[idx], z[idx]
    order = np.argsort(-z, kind="stable")
    if return_count:
        return uv[order], z[order], n_in_view
    return uv[order], z[order]


def cloud_overlay_figure(image: np.ndarray | None, camera: Camera, points_lidar: np.ndarray, transforms: dict[str, np.ndarray] | Sequence[tuple[str, np.ndarray]], max_points: int | None = 60_000, depth_range: tuple[float, float] | None = None, point_size: float | None = None, title: str = "LiDAR over the image (coloured by depth)"):
    """One panel per labelled ``T_cam_lidar`` (e.g. ``{"before": T0, "after": T1}``): the cloud projected onto the
    image, coloured by camera depth with a shared colour scale. ``point_size`` (pt², scatter ``s``): by default sized to
    the figure's scale (:func:`radarcal.report._common.point_size_pt2`), so points stay visible on large images."""
    items = list(transforms.items()) if isinstance(transforms, dict) else list(transforms)
    n = len(items)
    w, h = camera.image_size
    panel_in = 6.0 if n > 1 else 8.0
    fig, axes = new_figure(panel_in * n, panel_in * h / w + 0.8, 1, n)
    if point_size is None:
        point_size = point_size_pt2(w, panel_in)
    axes = np.atleast_1d(axes)
    projected = [project_cloud(camera, T, points_lidar, max_points, return_count=True) for _, T in items]
    if depth_range is None:
        zs = np.concatenate([z for _, z, _ in projected]) if projected else np.zeros(0)
        depth_range = (float(np.percentile(zs, 2)), float(np.percentile(zs, 98))) if zs.size else (0.0, 1.0)
    sc = None
    for ax, (label, _), (uv, z, n) in zip(axes, items, projected):
        show_image(ax, camera.image_size, image)
        sc = ax.scatter(uv[:, 0], uv[:, 1], c=z, s=point_size, cmap="turbo", vmin=depth_range[0], vmax=depth_range[1], linewidths=0)
        shown = "" if n == len(z) else f" ({len(z)} drawn)"
        ax.set_title(f"{label}: {n} points in view{shown}", fontsize=10)
    if sc is not None:
        fig.colorbar(sc, ax=list(axes), label="depth (m)", shrink=0.8)
    fig.suptitle(title)
    return fig


def edge_matches_figure(image: np.ndarray | None, image_size: tuple[int, int], uv_lidar: np.ndarray, uv_matched: np.ndarray, residual_px: np.ndarray | None = None, max_lines: int = 4000, title: str = "Edge matches"):
    """Projected LiDAR edge points joined to their matched image-edge points, coloured by residual (px)."""
    from matplotlib.collections import LineCollection

    a = np.asarray(uv_lidar, float).reshape(-1, 2)
    b = np.asarray(uv_matched, float).reshape(-1, 2)
    res = np.linalg.norm(b - a, axis=1) if residual_px is None else np.abs(np.asarray(residual_px, float).ravel())
    if len(a) > max_lines:
        idx = np.random.default_rng(0).choice(len(a), max_lines, replace=False)
        a, b, res = a[idx], b[idx], res[idx]
    w, h = image_size
    fig, ax = new_figure(8.0, 8.0 * h / w + 0.6)
    show_image(ax, image_size, image, alpha=0.6)
    vmax = float(np.percentile(res, 98)) if res.size else 1.0
    lc = LineCollection(np.stack([a, b], axis=1), array=res, cmap="autumn_r", linewidths=1.2)
    lc.set_clim(0.0, max(vmax, 1e-6))
    ax.add_collection(lc)
    ax.scatter(a[:, 0], a[:, 1], c=res, s=5, cmap="autumn_r", vmin=0.0, vmax=max(vmax, 1e-6), edgecolors="black", linewidths=0.2, label="LiDAR edge (projected)", zorder=3)
    fig.colorbar(lc, ax=ax, label="residual (px)", shrink=0.8)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"{title}\n{len(res)} shown, median residual {np.median(res) if res.size else float('nan'):.2f} px", fontsize=10)
    return fig


def edge_residual_histogram_figure(residual_px: np.ndarray, robust_scale_px: float | None = None, bins: int = 50, before_px: np.ndarray | None = None, title: str = "Edge-match residuals"):
    """Histogram of point-to-line residuals (px) with median, 90th percentile and the robust-loss scale marked;
    ``before_px`` (the residuals at the initial guess) drawn behind for comparison."""
    r = np.abs(np.asarray(residual_px, float).ravel())
    r = r[np.isfinite(r)]
    fig, ax = new_figure(6.0, 3.6)
    edges = np.histogram_bin_edges(r, bins=bins) if r.size else bins
    if before_px is not None:
        rb = np.abs(np.asarray(before_px, float).ravel())
        rb = rb[np.isfinite(rb)]
        hi = float(np.percentile(np.r_[r, rb], 99)) if (r.size + rb.size) else 1.0
        edges = np.linspace(0.0, max(hi, 1e-6), bins + 1)
        ax.hist(np.minimum(rb, hi), bins=edges, color="tab:gray", alpha=0.5, label=f"before (n = {rb.size}, median {np.median(rb) if rb.size else float('nan'):.2f} px)")
    ax.hist(r, bins=edges, color="tab:blue", alpha=0.8, label="after" if before_px is not None else None)
    med = float(np.median(r)) if r.size else float("nan")
    p90 = float(np.percentile(r, 90)) if r.size else float("nan")
    ax.axvline(med, color="k", ls="-", lw=1, label=f"median {med:.2f} px")
    ax.axvline(p90, color="k", ls="--", lw=1, label=f"90th pct {p90:.2f} px")
    if robust_scale_px is not None:
        ax.axvline(robust_scale_px, color="tab:red", ls=":", lw=1.5, label=f"robust-loss scale {robust_scale_px:.2f} px")
    ax.set_xlabel("point-to-edge distance (px)")
    ax.set_ylabel("matches")
    ax.set_title(f"{title} (n = {r.size})")
    ax.legend(fontsize=8)
    return fig


def cost_profile_figure(offsets: np.ndarray, costs: np.ndarray, names: Sequence[str] = PARAM_NAMES, display_scale: Sequence[float] | None = None, units: Sequence[str] | None = None, sigma: Sequence[float] | None = None, title: str = "Cost along each parameter around the optimum (observability)"):
    """One small panel per parameter: cost against the offset from the optimum. A sharp V/U means the parameter is
    observable; a flat line (rise < 2 % of the steepest parameter's, over the chosen half-widths) is flagged as
    unobservable. ``display_scale`` converts offsets for the axis (e.g. rad→deg);
    ``sigma`` (in the same units as ``offsets``) is shaded as ±1σ."""
    off = np.asarray(offsets, float)
    c = np.asarray(costs, float)
    P = off.shape[0]
    scale = np.ones(P) if display_scale is None else np.asarray(display_scale, float)
    if units is None:
        units = ["deg", "deg", "deg", "m", "m", "m"] if P == 6 and display_scale is not None else [""] * P
    ncols = 3 if P > 3 else P
    nrows = int(np.ceil(P / ncols))
    fig, axes = new_figure(3.2 * ncols, 2.5 * nrows + 0.5, nrows, ncols)
    axes = np.atleast_1d(axes).ravel()
    rises = np.nanmax(c, axis=1) - np.nanmin(c, axis=1)
    top = float(np.nanmax(rises)) if np.isfinite(rises).any() else 0.0
    for i in range(P):
        ax = axes[i]
        x = off[i] * scale[i]
        ax.plot(x, c[i], "-o", ms=2.5, lw=1.2)
        j = int(np.nanargmin(c[i]))
        ax.plot(x[j], c[i, j], "v", color="tab:red", ms=6)
        ax.axvline(0.0, color="gray", lw=0.8, ls=":")
        if sigma is not None and np.isfinite(sigma[i]):
            ax.axvspan(-sigma[i] * scale[i], sigma[i] * scale[i], color="tab:green", alpha=0.2)
        rel = float(rises[i]) / top if top > 0 else 0.0  # rise relative to the steepest parameter
        flat = rel < 0.02
        ax.set_title(f"{names[i]}: rise {rises[i]:.3g} ({rel:.0%} of max)" + (" flat!" if flat else ""), fontsize=9, color="tab:red" if flat else "black")
        ax.set_xlabel(f"offset ({units[i]})" if units[i] else "offset", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[P:]:
        ax.axis("off")
    fig.suptitle(title, fontsize=11)
    return fig
