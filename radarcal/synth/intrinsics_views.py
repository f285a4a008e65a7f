"""Corner-level simulation with known truth (no renderer): board corners projected through a known
:class:`~radarcal.camera.Camera` from random well-spread poses, plus Gaussian pixel noise. For solver, σ and
coverage tests and for the benchmark's accuracy column."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from radarcal.camera import Camera
from radarcal.board import BoardSpec, object_points

__all__ = ["SimulatedViews", "simulate_views", "simulate_good_practice_views", "radar_station_camera"]


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


def _pose(R: np.ndarray, p_c: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """T_cam_board with rotation R putting the board's ``centre`` at camera point ``p_c``."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p_c - R @ centre
    return T


def _in_image(camera: Camera, T: np.ndarray, obj: np.ndarray, margin_px: float) -> tuple[np.ndarray, bool]:
    uv, valid, z = camera.project_from(T, obj)
    return uv, bool(np.all(valid) and np.all(z > 0) and np.all(camera.in_image(uv, margin_px)))


def _collect_views(camera: Camera, board: BoardSpec, n_views: int, noise_px: float, rng: np.random.Generator, propose, fail: str) -> SimulatedViews:
    """Draw poses with ``propose(i, obj) -> (T, uv) | None`` (None: rejected) until ``n_views`` are accepted; each
    accepted view's corners get Gaussian pixel noise."""
    obj = object_points(board)
    Ts, imgs, imgs_true, objs = [], [], [], []
    tries = 0
    while len(Ts) < n_views:
        tries += 1
        if tries > 200 * n_views:
            raise RuntimeError(fail)
        got = propose(len(Ts), obj)
        if got is None:
            continue
        T, uv = got
        Ts.append(T)
        objs.append(obj.copy())
        imgs_true.append(uv)
        imgs.append(uv + rng.normal(scale=noise_px, size=uv.shape))
    return SimulatedViews(camera, board, Ts, objs, imgs, imgs_true)


def simulate_views(camera: Camera, board: BoardSpec, n_views: int, noise_px: float, rng: np.random.Generator, max_tilt_deg: float = 45.0, fill: tuple[float, float] = (0.35, 0.75), margin_px: float = 10.0) -> SimulatedViews:
    """``n_views`` poses whose corners all land inside the image (``margin_px``), the board spanning ``fill`` of
    the image width, tilted up to ``max_tilt_deg`` about a random in-plane axis, centred anywhere in the image."""
    w, h = camera.image_size

    def propose(i: int, obj: np.ndarray):
        centre, span = obj.mean(axis=0), float(np.ptp(obj[:, 0]))
        f = rng.uniform(*fill)
        depth = camera.fx * span / (f * w)
        q = np.array([rng.uniform(0.15, 0.85) * w, rng.uniform(0.15, 0.85) * h])
        ray = camera.unproject(q[None])[0]
        axis = rng.normal(size=2)
        axis = np.array([*axis / np.linalg.norm(axis), 0.0])
        tilt = np.deg2rad(rng.uniform(0.3, 1.0) * max_tilt_deg)
        R = (Rotation.from_rotvec(axis * tilt) * Rotation.from_euler("z", rng.uniform(-np.pi, np.pi) if rng.uniform() < 0.2 else rng.uniform(-0.4, 0.4))).as_matrix()
        T = _pose(R, ray / ray[2] * depth, centre)
        uv, ok = _in_image(camera, T, obj, margin_px)
        return (T, uv) if ok else None

    return _collect_views(camera, board, n_views, noise_px, rng, propose, "could not place the board inside the image; lower fill or tilt")


def simulate_good_practice_views(camera: Camera, board: BoardSpec, n_views: int, noise_px: float, rng: np.random.Generator, tilt_bands_deg: tuple[tuple[float, float], ...] = ((0.0, 10.0), (20.0, 30.0), (45.0, 55.0)), centre_span: float = 0.1, slack: tuple[float, float] = (1.0, 1.05), margin_px: float = 3.0) -> SimulatedViews:
    """A capture plan following good practice: every view as CLOSE as the image allows (the distance is the
    smallest at which all corners stay ``margin_px`` inside the image, times ``slack``), the board centred near the
    image centre (within ``centre_span`` of the width/height), tilts cycling through ``tilt_bands_deg`` (near
    fronto-parallel, moderate, strong) about a tilt direction that turns round the circle from view to view, small
    in-plane roll. A Fisher-information greedy selection from random close/far, centred/off-centre, 0-60° poses picks
    the same mix (see docs/intrinsics.md)."""
    w, h = camera.image_size

    def propose(i: int, obj: np.ndarray):
        centre = obj.mean(axis=0)
        lo_t, hi_t = tilt_bands_deg[i % len(tilt_bands_deg)]
        tilt = np.deg2rad(rng.uniform(lo_t, hi_t))
        phi = 2 * np.pi * i / n_views + rng.uniform(-0.2, 0.2)
        R = (Rotation.from_rotvec(np.array([np.cos(phi), np.sin(phi), 0.0]) * tilt) * Rotation.from_euler("z", rng.uniform(-0.3, 0.3))).as_matrix()
        q = np.array([w, h]) * (0.5 + rng.uniform(-centre_span, centre_span, 2))
        ray = camera.unproject(q[None])[0]
        ray = ray / ray[2]
        near, far = 1e-3, 100.0 * float(np.ptp(obj[:, 0])) * camera.fx / w
        if not _in_image(camera, _pose(R, ray * far, centre), obj, margin_px)[1]:
            return None
        for _ in range(40):  # bisection for the closest distance that keeps every corner in the image
            mid = 0.5 * (near + far)
            if _in_image(camera, _pose(R, ray * mid, centre), obj, margin_px)[1]:
                far = mid
            else:
                near = mid
        T = _pose(R, ray * (far * rng.uniform(*slack)), centre)
        uv, ok = _in_image(camera, T, obj, margin_px)
        return (T, uv) if ok else None

    return _collect_views(camera, board, n_views, noise_px, rng, propose, "could not place the board inside the image; lower the tilts")
