"""Figures of an intrinsics calibration (numpy arrays in, matplotlib Figure out; no file I/O).

Conventions: pixels with centres at integer coordinates, ``image_size = (width, height)``, residual = observed −
projected (px). Every figure function has a pure numeric helper next to it (``coverage_grid``, ``distortion_displacement``,
``projection_difference``, ``valid_region``) so the plotted numbers can be checked against ground truth.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from radarcal.camera import Camera
from radarcal.report._common import auto_arrow_scale, image_extent, new_figure, show_image

__all__ = [
    "per_view_error_figure",
    "residual_vectors_figure",
    "residual_histogram_figure",
    "coverage_grid",
    "coverage_figure",
    "valid_region",
    "uncertainty_map_figure",
    "distortion_displacement",
    "distortion_figure",
    "projection_difference",
    "crossval_difference_figure",
    "parameter_table_figure",
    "format_value_sigma",
]


# --- per-view error ----------------------------------------------------------------------------------------------
def per_view_error_figure(view_names: Sequence[str], view_error_px: np.ndarray, outlier: np.ndarray | None = None, threshold_px: float | None = None, rms_px: float | None = None, title: str = "Reprojection error per view", ylabel: str = "mean |residual| (px)"):
    """Bar per view (mean |residual| in px); outlier views red and hatched; optional rejection threshold line."""
    err = np.asarray(view_error_px, float).ravel()
    names = [str(n) for n in view_names]
    if len(names) != err.size:
        raise ValueError(f"{len(names)} view names for {err.size} errors")
    out = np.zeros(err.size, bool) if outlier is None else np.asarray(outlier, bool).ravel()
    fig, ax = new_figure(max(5.0, 0.32 * err.size + 2.0), 3.6)
    x = np.arange(err.size)
    colors = np.where(out, "tab:red", "tab:blue")
    bars = ax.bar(x, np.nan_to_num(err), color=colors, edgecolor="black", linewidth=0.5)
    for b, o in zip(bars, out):
        if o:
            b.set_hatch("//")
    if threshold_px is not None:
        ax.axhline(threshold_px, color="tab:red", ls="--", lw=1, label=f"rejection threshold {threshold_px:.2f} px")
    if rms_px is not None:
        ax.axhline(rms_px, color="gray", ls=":", lw=1, label=f"overall RMS {rms_px:.3f} px")
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel(ylabel)
    n_out = int(out.sum())
    ax.set_title(f"{title}\n{err.size} views, {n_out} outlier{'s' if n_out != 1 else ''} in red", fontsize=10)
    if threshold_px is not None or rms_px is not None:
        ax.legend(fontsize=8)
    return fig


# --- residual vectors ----------------------------------------------------------------------------------------------
def residual_vectors_figure(uv: np.ndarray, residual_px: np.ndarray, image_size: tuple[int, int], scale: float | None = None, image: np.ndarray | None = None, outlier: np.ndarray | None = None, title: str = "Residual vectors"):
    """Arrows from each observed corner along its residual, magnified by ``scale`` (auto: 95th pct = 4 % of the
    image diagonal). Outlier corners (if given) in red."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    r = np.asarray(residual_px, float).reshape(-1, 2)
    if scale is None:
        scale = auto_arrow_scale(r, image_size)
    out = np.zeros(len(uv), bool) if outlier is None else np.asarray(outlier, bool).ravel()
    fig, ax = new_figure(7.0, 7.0 * image_size[1] / image_size[0] + 0.6)
    show_image(ax, image_size, image, alpha=0.5)
    mag = np.linalg.norm(r, axis=1)
    inl = ~out
    q = ax.quiver(uv[inl, 0], uv[inl, 1], r[inl, 0] * scale, r[inl, 1] * scale, mag[inl], angles="xy", scale_units="xy", scale=1.0, cmap="viridis", width=0.002)
    if inl.any():
        fig.colorbar(q, ax=ax, label="|residual| (px)", shrink=0.8)
    if out.any():
        ax.quiver(uv[out, 0], uv[out, 1], r[out, 0] * scale, r[out, 1] * scale, color="tab:red", angles="xy", scale_units="xy", scale=1.0, width=0.003, label="outliers")
        ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"{title}\n(arrows ×{scale:.0f})", fontsize=10)
    return fig


# --- residual histogram ------------------------------------------------------------------------------------------
def residual_histogram_figure(residual_px: np.ndarray, expected_sigma_px: float | None = None, bins: int = 60, title: str = "Residuals against the expected noise"):
    """Histogram of the x and y residual components with the N(0, σ²) density of the expected noise overlaid
    (σ defaults to the observed component std)."""
    r = np.asarray(residual_px, float).reshape(-1, 2)
    r = r[np.all(np.isfinite(r), axis=1)]
    observed = float(np.sqrt(np.mean(r**2))) if r.size else float("nan")
    sigma = observed if expected_sigma_px is None else float(expected_sigma_px)
    fig, ax = new_figure(6.0, 3.8)
    lim = max(4.0 * sigma, float(np.percentile(np.abs(r), 99.5)) if r.size else 1.0)
    edges = np.linspace(-lim, lim, bins + 1)
    ax.hist(r[:, 0], bins=edges, density=True, alpha=0.55, label="x residual", color="tab:blue")
    ax.hist(r[:, 1], bins=edges, density=True, alpha=0.55, label="y residual", color="tab:orange")
    xs = np.linspace(-lim, lim, 400)
    if sigma > 0:
        ax.plot(xs, np.exp(-0.5 * (xs / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi)), "k-", lw=1.5, label=f"expected N(0, {sigma:.3f}²)")
    ax.set_xlabel("residual (px)")
    ax.set_ylabel("density")
    ax.set_title(f"{title}\nobserved σ = {observed:.3f} px, expected {sigma:.3f} px", fontsize=10)
    ax.legend(fontsize=8)
    return fig


# --- coverage ------------------------------------------------------------------------------------------------------
def coverage_grid(uv: np.ndarray, image_size: tuple[int, int], cells: tuple[int, int] = (16, 12)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corner counts per image cell: (counts (ny, nx), u_edges (nx+1), v_edges (ny+1)). Points outside are ignored."""
    w, h = image_size
    nx, ny = cells
    u_edges = np.linspace(-0.5, w - 0.5, nx + 1)
    v_edges = np.linspace(-0.5, h - 0.5, ny + 1)
    uv = np.asarray(uv, float).reshape(-1, 2)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    counts, _, _ = np.histogram2d(uv[:, 1], uv[:, 0], bins=(v_edges, u_edges))
    return counts, u_edges, v_edges


def coverage_figure(uv: np.ndarray, image_size: tuple[int, int], cells: tuple[int, int] = (16, 12), title: str = "Corner coverage"):
    """Heat map of corner counts over the image; empty cells are called out in the title."""
    counts, _, _ = coverage_grid(uv, image_size, cells)
    fig, ax = new_figure(7.0, 7.0 * image_size[1] / image_size[0] + 0.6)
    im = ax.imshow(counts, extent=image_extent(image_size), cmap="magma", interpolation="nearest", origin="upper")
    show_image(ax, image_size)
    fig.colorbar(im, ax=ax, label="corners per cell", shrink=0.8)
    empty = float(np.mean(counts == 0))
    ax.set_title(f"{title}\n{int(counts.sum())} corners, {empty:.0%} of cells empty", fontsize=10)
    return fig


# --- projection uncertainty ------------------------------------------------------------------------------------------
def valid_region(sigma_px: np.ndarray, threshold_px: float) -> np.ndarray:
    """Mask of grid cells where the projection uncertainty is below the threshold (NaN = not valid)."""
    s = np.asarray(sigma_px, float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(s) & (s < threshold_px)


def uncertainty_map_figure(u_grid: np.ndarray, v_grid: np.ndarray, sigma_px: np.ndarray, image_size: tuple[int, int], threshold_px: float, uv_observed: np.ndarray | None = None, title: str = "Projection uncertainty"):
    """σ of the projection (px) over a grid of pixels (``u_grid`` (nx,), ``v_grid`` (ny,), ``sigma_px`` (ny, nx)),
    log colour scale, with the valid-region contour σ = ``threshold_px``; observed corners optionally dotted."""
    from matplotlib.colors import LogNorm

    s = np.asarray(sigma_px, float)
    u = np.asarray(u_grid, float).ravel()
    v = np.asarray(v_grid, float).ravel()
    if s.shape != (v.size, u.size):
        raise ValueError(f"sigma_px shape {s.shape} does not match grid ({v.size}, {u.size})")
    fig, ax = new_figure(7.0, 7.0 * image_size[1] / image_size[0] + 0.6)
    finite = s[np.isfinite(s) & (s > 0)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (1e-3, 1.0)
    hi = max(hi, lo * 1.01)
    im = ax.pcolormesh(u, v, np.ma.masked_invalid(s), norm=LogNorm(lo, hi), cmap="viridis", shading="nearest")
    fig.colorbar(im, ax=ax, label="projection σ (px)", shrink=0.8)
    mask = valid_region(s, threshold_px)
    if mask.any() and (~mask).any():
        ax.contour(u, v, np.where(np.isfinite(s), s, hi * 10), levels=[threshold_px], colors="white", linewidths=2)
    if uv_observed is not None:
        p = np.asarray(uv_observed, float).reshape(-1, 2)
        ax.plot(p[:, 0], p[:, 1], ".", ms=1, color="tab:red", alpha=0.4)
    show_image(ax, image_size)
    ax.set_title(f"{title}\nvalid (σ < {threshold_px:.2g} px, white line) over {mask.mean():.0%} of the image", fontsize=10)
    return fig


# --- distortion field ----------------------------------------------------------------------------------------------
def distortion_displacement(camera: Camera, cells: tuple[int, int] = (32, 26)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the lens moves an ideal pinhole pixel: returns (uv_ideal (ny, nx, 2), displacement (ny, nx, 2) px,
    magnitude (ny, nx) px). ``displacement = K·distort(K⁻¹·uv) − uv`` via :meth:`Camera.distort`."""
    w, h = camera.image_size
    nx, ny = cells
    u = np.linspace(0, w - 1, nx)
    v = np.linspace(0, h - 1, ny)
    uu, vv = np.meshgrid(u, v)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    Kinv = np.linalg.inv(camera.K)
    xy = uv @ Kinv[:2, :2].T + Kinv[:2, 2]
    uv_d = camera.distort(xy) @ camera.K[:2, :2].T + camera.K[:2, 2]
    d = (uv_d - uv).reshape(ny, nx, 2)
    return uv.reshape(ny, nx, 2), d, np.linalg.norm(d, axis=2)


def distortion_figure(camera: Camera, cells: tuple[int, int] = (32, 26), arrows: tuple[int, int] = (16, 13), title: str = "Distortion field"):
    """Magnitude of the lens distortion (px) as a colour map with displacement arrows (true length, in px)."""
    uv, d, mag = distortion_displacement(camera, cells)
    fig, ax = new_figure(7.0, 7.0 * camera.height / camera.width + 0.6)
    im = ax.pcolormesh(uv[0, :, 0], uv[:, 0, 1], mag, cmap="plasma", shading="nearest")
    fig.colorbar(im, ax=ax, label="|displacement| (px)", shrink=0.8)
    if float(mag.max()) > 0:
        cs = ax.contour(uv[0, :, 0], uv[:, 0, 1], mag, levels=_nice_levels(float(mag.max())), colors="white", linewidths=0.7)
        ax.clabel(cs, fontsize=7, fmt="%g px")
    ua, da, _ = distortion_displacement(camera, arrows)
    ax.quiver(ua[..., 0], ua[..., 1], da[..., 0], da[..., 1], angles="xy", scale_units="xy", scale=1.0, color="white", width=0.002)
    ax.plot([camera.cx], [camera.cy], "+", color="cyan", ms=12, mew=2)
    show_image(ax, camera.image_size)
    ax.set_title(f"{title} ({camera.model})\nmax {mag.max():.1f} px; arrows to scale", fontsize=10)
    return fig


def _nice_levels(vmax: float, n: int = 6) -> list[float]:
    raw = vmax / n
    mag = 10 ** np.floor(np.log10(raw))
    step = min((m * mag for m in (1, 2, 5, 10) if m * mag >= raw), default=raw)
    return [float(x) for x in np.arange(step, vmax, step)]


# --- cross-validation ------------------------------------------------------------------------------------------------
def projection_difference(camera_a: Camera, camera_b: Camera, cells: tuple[int, int] = (32, 26), distance_m: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far apart two calibrations of the same camera put the same ray: for each pixel ``uv`` of a grid,
    unproject with ``camera_a`` and project with ``camera_b``. Returns (u_grid (nx,), v_grid (ny,), diff (ny, nx) px).
    (No rotation compensation; with ``distance_m`` the ray point at that range is used, which is the same thing for
    two cameras sharing the optical centre.)"""
    w, h = camera_a.image_size
    nx, ny = cells
    u = np.linspace(0, w - 1, nx)
    v = np.linspace(0, h - 1, ny)
    uu, vv = np.meshgrid(u, v)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    rays = camera_a.unproject(uv)
    p = rays * (1.0 if distance_m is None else float(distance_m))
    uv_b, valid = camera_b.project(p)
    diff = np.where(valid, np.linalg.norm(uv_b - uv, axis=1), np.nan)
    return u, v, diff.reshape(ny, nx)


def crossval_difference_figure(u_grid: np.ndarray, v_grid: np.ndarray, diff_px: np.ndarray, image_size: tuple[int, int], sigma_px: np.ndarray | float | None = None, title: str = "Cross-validation: projection difference between halves"):
    """Difference (px) between two half-set calibrations over the image; with ``sigma_px`` (their combined
    uncertainty, scalar or grid) a contour where the difference exceeds 2σ (i.e. not explained by noise)."""
    diff = np.asarray(diff_px, float)
    u = np.asarray(u_grid, float).ravel()
    v = np.asarray(v_grid, float).ravel()
    fig, ax = new_figure(7.0, 7.0 * image_size[1] / image_size[0] + 0.6)
    from matplotlib.colors import LogNorm

    finite = diff[np.isfinite(diff) & (diff > 0)]
    lo, hi = (max(float(finite.min()), float(finite.max()) * 1e-4), float(finite.max())) if finite.size else (1e-3, 1.0)
    im = ax.pcolormesh(u, v, np.ma.masked_invalid(np.maximum(diff, lo)), cmap="inferno", shading="nearest", norm=LogNorm(lo, max(hi, lo * 1.01)))
    fig.colorbar(im, ax=ax, label="|Δ projection| (px)", shrink=0.8)
    note = ""
    if sigma_px is not None:
        ratio = diff / np.broadcast_to(np.asarray(sigma_px, float), diff.shape)
        frac = float(np.nanmean(ratio > 2.0))
        finite = np.isfinite(ratio)
        if (ratio[finite] > 2).any() and (ratio[finite] <= 2).any():
            ax.contour(u, v, np.where(finite, ratio, 0), levels=[2.0], colors="cyan", linewidths=1.5)
        note = f"; > 2σ over {frac:.0%} (cyan)"
    show_image(ax, image_size)
    ax.set_title(f"{title}\nmedian {np.nanmedian(diff):.2f} px, max {np.nanmax(diff):.2f} px{note}", fontsize=10)
    return fig


# --- parameter table ---------------------------------------------------------------------------------------------------
def format_value_sigma(value: float, sigma: float | None) -> tuple[str, str]:
    """Value and σ as strings with the value rounded to two significant digits of σ."""
    if sigma is None or not np.isfinite(sigma) or sigma <= 0:
        return f"{value:.6g}", "—"
    digits = max(0, int(-np.floor(np.log10(sigma))) + 1)
    if digits > 10:
        return f"{value:.6g}", f"{sigma:.2g}"
    return f"{value:.{digits}f}", f"{sigma:.{digits}f}" if digits else f"{sigma:.2g}"


def parameter_table_figure(names: Sequence[str], values: Sequence[float], sigmas: Sequence[float | None] | None = None, units: Sequence[str] | None = None, title: str = "Parameters (±1σ)"):
    """A table of parameter, value, σ, unit rendered as a figure (the HTML report also gets a real table)."""
    names = [str(n) for n in names]
    sig = list(sigmas) if sigmas is not None else [None] * len(names)
    un = list(units) if units is not None else [""] * len(names)
    rows = []
    for n, val, s, un_ in zip(names, values, sig, un):
        vs, ss = format_value_sigma(float(val), None if s is None else float(s))
        rows.append([n, vs, ss, un_])
    fig, ax = new_figure(6.0, 0.5 + 0.28 * (len(rows) + 1))
    ax.axis("off")
    tbl = ax.table(cellText=rows, colLabels=["parameter", "value", "σ", "unit"], loc="center", cellLoc="right", colLoc="center")
    tbl.auto_set_font_size(False)
    tbl.set_fontsize(9)
    tbl.scale(1.0, 1.2)
    ax.set_title(title)
    return fig
