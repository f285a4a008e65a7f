"""Corner-level simulation with known truth (no renderer): board corners projected through a known
:class:`~radarcal.camera.Camera` from random well-spread poses, plus Gaussian pixel noise. For solver, σ and
coverage tests and for the benchmark's accuracy column."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from radarcal.camera import Camera
from radarcal.intrinsics.detect import BoardSpec, object_points

__all__ = ["SimulatedViews", "simulate_views", "radar_station_camera"]


@dataclass
class SimulatedViews:
    camera: Camera  # truth
    board: BoardSpec
    T_cam_board: list[np.ndarray]  # truth poses (4x4)
    object_points: list[np.ndarray]  # (N,3) per view
    image_points: list[np.ndarray]  # (N,2) noisy per view
    image_points_true: list[np.ndarray]


def radar_station_camera(lens_mm: float = 4.0) -> Camera:
    """A 1280x1024 industrial camera (4.8 µm pixels) with a ``lens_mm`` lens, as on RoboMaster radar stations
    (4 mm: fx ≈ 833 px, ~75° horizontal field of view; 8 mm: fx ≈ 1667 px)."""
    f = lens_mm / 0.0048
    K = np.array([[f, 0.0, 645.3], [0.0, f * 0.9991, 509.8], [0.0, 0.0, 1.0]])
    return Camera((1280, 1024), K, np.array([-0.118, 0.162, 0.0006, -0.0004, -0.071]))


def simulate_views(camera: Camera, board: BoardSpec, n_views: int, noise_px: float, rng: np.random.Generator, max_tilt_deg: float = 45.0, fill: tuple[float, float] = (0.35, 0.75), margin_px: float = 10.0) -> SimulatedViews:
    """``n_views`` poses whose corners all land inside the image (``margin_px``), the board spanning ``fill`` of
    the image width, tilted up to ``max_tilt_deg`` about a random in-plane axis, centred anywhere in the image."""
    obj = object_points(board)
    centre = obj.mean(axis=0)
    span = float(np.ptp(obj[:, 0]))
    w, h = camera.image_size
    Ts, imgs, imgs_true, objs = [], [], [], []
    tries = 0
    while len(Ts) < n_views:
        tries += 1
        if tries > 200 * n_views:
            raise RuntimeError("could not place the board inside the image; lower fill or tilt")
        f = rng.uniform(*fill)
        depth = camera.fx * span / (f * w)
        q = np.array([rng.uniform(0.15, 0.85) * w, rng.uniform(0.15, 0.85) * h])
        ray = camera.unproject(q[None])[0]
        p_c = ray / ray[2] * depth
        axis = rng.normal(size=2)
        axis = np.array([*axis / np.linalg.norm(axis), 0.0])
        tilt = np.deg2rad(rng.uniform(0.3, 1.0) * max_tilt_deg)
        R = (Rotation.from_rotvec(axis * tilt) * Rotation.from_euler("z", rng.uniform(-np.pi, np.pi) if rng.uniform() < 0.2 else rng.uniform(-0.4, 0.4))).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = p_c - R @ centre
        uv, valid, z = camera.project_from(T, obj)
        if not (np.all(valid) and np.all(z > 0) and np.all(camera.in_image(uv, margin_px))):
            continue
        Ts.append(T)
        objs.append(obj.copy())
        imgs_true.append(uv)
        imgs.append(uv + rng.normal(scale=noise_px, size=uv.shape))
    return SimulatedViews(camera, board, Ts, objs, imgs, imgs_true)
