"""PNG of the localisation error map (matplotlib imported lazily) and the solved-pose overlay on the image."""

from __future__ import annotations

import os

import numpy as np

from radarcal.field import FieldModel
from radarcal.pnp.error_map import ErrorMap

__all__ = ["save_error_map_png", "draw_overlay"]


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


def draw_overlay(image_bgr: np.ndarray, camera, T_cam_field: np.ndarray, field_model: FieldModel, names: list[str], uv: np.ndarray) -> np.ndarray:
    """The field as the solved pose sees it, drawn on the image: field outline and raised areas (top edges, yellow),
    every landmark's projection (red cross + name) and the picks (green circles). Returns a new BGR image."""
    import cv2

    img = image_bgr.copy() if image_bgr.ndim == 3 else cv2.cvtColor(image_bgr, cv2.COLOR_GRAY2BGR)

    def polyline(poly_xyz: np.ndarray, color) -> None:
        closed = np.vstack([poly_xyz, poly_xyz[:1]])
        s = np.linspace(0, 1, 40)[None, :, None]
        pts = (closed[:-1, None] * (1 - s) + closed[1:, None] * s).reshape(-1, 3)  # sampled: distortion bends lines
        q, valid, _ = camera.project_from(T_cam_field, pts)
        q = q.reshape(len(closed) - 1, -1, 2)
        valid = valid.reshape(len(closed) - 1, -1)
        for seg, ok in zip(q, valid):
            seg = seg[ok]
            if len(seg) > 1:
                cv2.polylines(img, [np.round(seg).astype(np.int32)], False, color, 1, cv2.LINE_AA)

    o = field_model.outline
    polyline(np.column_stack([o, np.zeros(len(o))]), (255, 255, 255))
    for a in field_model.areas:
        poly = a["polygon"]
        pa, pb, pc = a["plane"] if a.get("plane") is not None else (0.0, 0.0, a["z"])
        polyline(np.column_stack([poly, pa * poly[:, 0] + pb * poly[:, 1] + pc]), (0, 220, 255))
    lm_names = list(field_model.landmarks)
    q, valid, _ = camera.project_from(T_cam_field, field_model.landmark_array(lm_names))
    inside = valid & camera.in_image(q)
    for n, p, ok in zip(lm_names, q, inside):
        if ok:
            c = tuple(int(round(v)) for v in p)
            cv2.drawMarker(img, c, (0, 0, 255), cv2.MARKER_CROSS, 14, 1, cv2.LINE_AA)
            cv2.putText(img, n, (c[0] + 6, c[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 255), 1, cv2.LINE_AA)
    for p in np.asarray(uv, float):
        cv2.circle(img, tuple(int(round(v)) for v in p), 7, (0, 255, 0), 1, cv2.LINE_AA)
    return img
