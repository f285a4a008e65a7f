"""Shared plumbing of the figure functions: matplotlib ``Figure`` objects built without pyplot (no global state,
Agg rendering), PNG encoding, and small numeric helpers used by several figures."""

from __future__ import annotations

import io

import numpy as np

__all__ = ["new_figure", "figure_to_png", "auto_arrow_scale", "image_extent", "show_image", "show", "point_size_pt2", "MIN_POINT_DIAMETER_PT"]


def new_figure(width_in: float = 7.0, height_in: float = 4.5, nrows: int = 1, ncols: int = 1, **subplot_kw):
    """A matplotlib Figure (Agg canvas, not registered with pyplot) and its axes (array when nrows*ncols > 1)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=True, subplot_kw=subplot_kw or None)
    return fig, axes


def figure_to_png(fig, dpi: int = 96) -> bytes:
    """PNG bytes of a Figure."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def auto_arrow_scale(vectors: np.ndarray, image_size: tuple[int, int], fraction: float = 0.04) -> float:
    """Scale factor that draws the 95th-percentile vector length as ``fraction`` of the image diagonal."""
    v = np.asarray(vectors, float).reshape(-1, 2)
    n = np.linalg.norm(v, axis=1)
    n = n[np.isfinite(n)]
    p95 = float(np.percentile(n, 95)) if n.size else 0.0
    diag = float(np.hypot(*image_size))
    return fraction * diag / p95 if p95 > 0 else 1.0


MIN_POINT_DIAMETER_PT = 2.0  # 2.7 px at the report's 96 dpi: the smallest dot that stays visible in the page


def point_size_pt2(image_width_px: int, panel_width_in: float, image_px: float = 1.5, min_diameter_pt: float = MIN_POINT_DIAMETER_PT) -> float:
    """Marker area (pt², matplotlib's scatter ``s``) of a dot ``image_px`` image pixels wide on an image drawn
    ``panel_width_in`` inches wide, never smaller than ``min_diameter_pt`` across (a 1920-px image in an 8-inch panel
    has 0.3 pt per image pixel: a 1-pixel dot would vanish)."""
    pt_per_px = 72.0 * float(panel_width_in) / max(float(image_width_px), 1.0)
    return max(min_diameter_pt, image_px * pt_per_px) ** 2


def image_extent(image_size: tuple[int, int]) -> tuple[float, float, float, float]:
    """imshow extent for pixel centres at integer coordinates: (left, right, bottom, top) with y down."""
    w, h = image_size
    return (-0.5, w - 0.5, h - 0.5, -0.5)


def show_image(ax, image_size: tuple[int, int], image: np.ndarray | None = None, alpha: float = 1.0) -> None:
    """Set up ``ax`` in pixel coordinates (y down), optionally drawing a grey/colour image underneath."""
    w, h = image_size
    if image is not None:
        img = np.asarray(image)
        if img.ndim == 3 and img.shape[2] == 3:
            img = img[..., ::-1]  # OpenCV BGR -> RGB
        ax.imshow(img, cmap="gray" if img.ndim == 2 else None, extent=image_extent(image_size), alpha=alpha, interpolation="nearest")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")


def show(fig, dpi: int = 96):
    """Display a figure in a Jupyter notebook as an ``image/png`` output (independent of the matplotlib backend,
    so it works headless with ``MPLBACKEND=Agg``). Returns the figure."""
    from IPython.display import Image, display

    display(Image(data=figure_to_png(fig, dpi=dpi), format="png"))
    return fig
