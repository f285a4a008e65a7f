"""PNG of the localisation error map (matplotlib imported lazily)."""

from __future__ import annotations

import os

import numpy as np

from radarcal.field import FieldModel
from radarcal.pnp.error_map import ErrorMap

__all__ = ["save_error_map_png"]


def save_error_map_png(path: str | os.PathLike, em: ErrorMap, field_model: FieldModel, camera_position: np.ndarray | None = None, landmarks: list[str] | None = None, title: str = "") -> None:
    """Two panels (LiDAR depth, ground-ray fallback): 1σ horizontal error (m) over the field, raised areas,
    the landmarks used and the camera position."""
    from matplotlib.figure import Figure  # no pyplot: works headless and leaves the GUI backend alone

    L, W = field_model.size
    step = em.xs[1] - em.xs[0] if len(em.xs) > 1 else 1.0
    extent = [em.xs[0] - step / 2, em.xs[-1] + step / 2, em.ys[0] - step / 2, em.ys[-1] + step / 2]
    fig = Figure(figsize=(15, 4.8), constrained_layout=True)
    axes = fig.subplots(1, 2)
    panels = [("LiDAR depth", em.sigma_lidar), ("ground-ray fallback", em.sigma_ground)]
    for ax, (name, s) in zip(axes, panels):
        finite = s[np.isfinite(s)]
        vmax = float(np.percentile(finite, 98)) if finite.size else 1.0
        im = ax.imshow(s, origin="lower", extent=extent, cmap="viridis", vmin=0, vmax=max(vmax, 1e-3), interpolation="nearest")
        fig.colorbar(im, ax=ax, label="1σ horizontal error (m)", shrink=0.85)
        o = np.vstack([field_model.outline, field_model.outline[:1]])
        ax.plot(o[:, 0], o[:, 1], "k-", lw=1.2)
        for a in field_model.areas:
            p = np.vstack([a["polygon"], a["polygon"][:1]])
            ax.plot(p[:, 0], p[:, 1], "w-", lw=0.8)
        for n in landmarks or []:
            p = field_model.landmarks[n]
            ax.plot(p[0], p[1], "r^", ms=7)
            ax.annotate(n, (p[0], p[1]), color="red", fontsize=7, xytext=(3, 3), textcoords="offset points")
        if camera_position is not None:
            ax.plot(camera_position[0], camera_position[1], "ms", ms=8)
            ax.annotate("camera", (camera_position[0], camera_position[1]), color="m", fontsize=8, xytext=(3, -10), textcoords="offset points")
        med = f"median {np.median(finite):.3f} m, max {finite.max():.3f} m" if finite.size else "not visible"
        ax.set_title(f"{name}: {med}")
        ax.set_xlim(min(-1.5, (camera_position[0] - 1) if camera_position is not None else 0), L + 0.5)
        ax.set_ylim(-0.5, W + 0.5)
        ax.set_aspect("equal")
        ax.set_xlabel("field x (m)")
        ax.set_ylabel("field y (m)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
