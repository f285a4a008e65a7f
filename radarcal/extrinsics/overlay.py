"""Overlay of a LiDAR cloud on an image (points coloured by depth), for before/after views. Pure: returns arrays."""

from __future__ import annotations

import cv2
import numpy as np

from radarcal.camera import Camera

__all__ = ["overlay_cloud", "side_by_side"]


def overlay_cloud(image: np.ndarray, camera: Camera, T_cam_lidar: np.ndarray, points: np.ndarray, max_points: int = 150_000, max_depth: float | None = None,
                  radius: int = 1, label: str | None = None) -> np.ndarray:
    """BGR image with the projected points drawn, coloured by camera depth (near red -> far blue)."""
    img = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    pts = np.asarray(points, float)
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(0).choice(len(pts), max_points, replace=False)]
    uv, valid, z = camera.project_from(T_cam_lidar, pts)
    ok = valid & camera.in_image(uv) & (z > 0.3)
    uv, z = uv[ok], z[ok]
    if len(z):
        zmax = max_depth or float(np.percentile(z, 95))
        t = np.clip(z / max(zmax, 1e-6), 0, 1)
        colours = cv2.applyColorMap((t * 255).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_JET).reshape(-1, 3)
        ij = np.round(uv).astype(int)
        if radius <= 0:
            img[ij[:, 1], ij[:, 0]] = colours
        else:
            order = np.argsort(-z)  # far first so near points stay on top
            for dv in range(-radius + 1, radius):
                for du in range(-radius + 1, radius):
                    u = np.clip(ij[order, 0] + du, 0, img.shape[1] - 1)
                    v = np.clip(ij[order, 1] + dv, 0, img.shape[0] - 1)
                    img[v, u] = colours[order]
    if label:
        cv2.putText(img, label, (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (255, 255, 255), 3, cv2.LINE_AA)
        cv2.putText(img, label, (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def side_by_side(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.concatenate([a, b], axis=1)
