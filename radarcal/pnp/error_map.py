"""Expected localisation error over the field for a field-PnP pose (pure numeric core).

A robot seen at pixel ``uv`` is placed on the field in one of two ways (the runtime's two depth sources):

* **LiDAR depth**: the camera-frame point is ``z · [x_n, y_n, 1]`` with ``(x_n, y_n)`` the undistorted normalised
  pixel and ``z`` the depth from the LiDAR (σ ≈ the range noise, 2 cm for a Mid-70); the field point is
  ``T_field_cam · p_cam``. The pose error moves it by the rotation error × range plus the position error.
* **ground-ray fallback** (no LiDAR points on the robot): the pixel's ray from the estimated pose is intersected with
  the field surface (the height of the area the robot stands on). Grazing rays make this grow ≈ range² / height.

:func:`error_map` propagates, to first order, the pose covariance (from the clicked landmarks,
:func:`radarcal.pnp.field_pnp.solve_field_pnp`) plus the detection pixel noise plus the depth noise, and returns the
horizontal 1σ error ``sqrt(σx² + σy²)`` (m) on a grid of field points (the minimap is 2-D). :func:`monte_carlo`
measures the same quantity by simulation (noisy clicks → pose → noisy detections → localisation) to validate it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.field import FieldModel
from radarcal.pnp.field_pnp import FieldPnPError, PnPOptions, params_to_pose, pose_to_params, solve_field_pnp

__all__ = ["ErrorMap", "error_map", "ground_visible", "localise_lidar", "localise_ground", "localisation_sigma", "monte_carlo", "MonteCarloResult"]


@dataclass
class ErrorMap:
    """1σ horizontal localisation error (m) on a field grid; NaN where the camera does not see the point."""

    xs: np.ndarray              # (nx,) grid x (m)
    ys: np.ndarray              # (ny,) grid y (m)
    sigma_lidar: np.ndarray     # (ny, nx)
    sigma_ground: np.ndarray    # (ny, nx)
    pixel_sigma: float
    range_sigma: float
    target_height: float

    def stats(self, which: str = "lidar") -> dict:
        s = self.sigma_lidar if which == "lidar" else self.sigma_ground
        v = s[np.isfinite(s)]
        if v.size == 0:
            return {"visible_cells": 0, "median_m": None, "p90_m": None, "max_m": None}
        return {"visible_cells": int(v.size), "median_m": float(np.median(v)), "p90_m": float(np.percentile(v, 90)), "max_m": float(v.max())}


# --- localisation (shared by the map's Jacobians and the Monte-Carlo) ----------------------------------------------
def localise_lidar(camera: Camera, T_cam_field: np.ndarray, uv: np.ndarray, z_cam: np.ndarray) -> np.ndarray:
    """Field points (N,3) from pixels (N,2) and camera-frame depths z (N,) (the seed's ``inv[R,T]·(inv M · d · uv)``)."""
    rays = camera.unproject(uv)
    p_cam = rays / rays[:, 2:3] * np.asarray(z_cam, float).reshape(-1, 1)
    return geometry.transform_points(geometry.invert_T(T_cam_field), p_cam)


def localise_ground(camera: Camera, T_cam_field: np.ndarray, uv: np.ndarray, field_model: FieldModel | None = None, heights: np.ndarray | None = None) -> np.ndarray:
    """Field points (N,3) where the pixels' rays meet the surface: the field model's solid, or horizontal planes at
    ``heights`` (N,) when given (first-order model: the robot's own standing height). NaN where the ray misses."""
    T_field_cam = geometry.invert_T(T_cam_field)
    rays = camera.unproject(uv) @ T_field_cam[:3, :3].T
    C = T_field_cam[:3, 3]
    if heights is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (np.asarray(heights, float) - C[2]) / rays[:, 2]
        s = np.where(s > 0, s, np.nan)
        return C + s[:, None] * rays
    return field_model.intersect_rays(np.broadcast_to(C, rays.shape), rays)


# --- first-order propagation -------------------------------------------------------------------------------------
def localisation_sigma(camera: Camera, T_cam_field: np.ndarray, cov_pose: np.ndarray, targets: np.ndarray, pixel_sigma: float = 1.0, range_sigma: float = 0.02, mode: str = "lidar") -> np.ndarray:
    """Horizontal 1σ error (N,) of localising field points ``targets`` (N,3) with the pose covariance ``cov_pose``
    (6x6 over [rotvec, t] of ``T_cam_field``), pixel noise and depth noise. ``mode``: "lidar" or "ground"."""
    P = np.asarray(targets, float).reshape(-1, 3)
    x0 = pose_to_params(T_cam_field)
    uv, valid, z = camera.project_from(T_cam_field, P)
    heights = P[:, 2]
    eps_x, eps_u, eps_z = 1e-6, 1e-3, 1e-4

    def loc(x: np.ndarray, u: np.ndarray, zz: np.ndarray) -> np.ndarray:
        T = params_to_pose(x)
        return localise_lidar(camera, T, u, zz) if mode == "lidar" else localise_ground(camera, T, u, heights=heights)

    Jx = np.empty((len(P), 3, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps_x
        Jx[:, :, i] = (loc(x0 + d, uv, z) - loc(x0 - d, uv, z)) / (2 * eps_x)
    Ju = np.empty((len(P), 3, 2))
    for i in range(2):
        d = np.zeros(2)
        d[i] = eps_u
        Ju[:, :, i] = (loc(x0, uv + d, z) - loc(x0, uv - d, z)) / (2 * eps_u)
    cov = np.einsum("nij,jk,nlk->nil", Jx, cov_pose, Jx) + pixel_sigma**2 * np.einsum("nij,nkj->nik", Ju, Ju)
    if mode == "lidar":
        Jz = (loc(x0, uv, z + eps_z) - loc(x0, uv, z - eps_z)) / (2 * eps_z)
        cov += range_sigma**2 * np.einsum("ni,nj->nij", Jz, Jz)
    s = np.sqrt(cov[:, 0, 0] + cov[:, 1, 1])
    ok = valid & camera.in_image(uv) & np.isfinite(s)
    return np.where(ok, s, np.nan)


def ground_visible(field_model: FieldModel, camera_position: np.ndarray, targets: np.ndarray, tol: float = 0.05) -> np.ndarray:
    """(N,) True where the straight line from the camera to the target is not blocked by the field's surface solid
    (a ground point behind a highland cannot be reached by the ground-ray fallback)."""
    P = np.asarray(targets, float).reshape(-1, 3)
    C = np.asarray(camera_position, float).reshape(1, 3)
    d = P - C
    dist = np.linalg.norm(d, axis=1)
    t, _ = field_model.ray_hits(np.broadcast_to(C, d.shape), d / dist[:, None])
    return ~(np.isfinite(t) & (t < dist - tol))


def error_map(camera: Camera, T_cam_field: np.ndarray, cov_pose: np.ndarray, field_model: FieldModel, step: float = 1.0, pixel_sigma: float = 1.0, range_sigma: float = 0.02, target_height: float = 0.0) -> ErrorMap:
    """:func:`localisation_sigma` on a grid over the field (cell centres ``step`` apart), both depth sources.

    Targets are on the surface (+ ``target_height``); cells the camera does not see are NaN, and so are the
    ground-fallback cells whose surface point is hidden behind a raised area (the ray would land on the area)."""
    L, W = field_model.size
    xs = np.arange(step / 2, L, step)
    ys = np.arange(step / 2, W, step)
    X, Y = np.meshgrid(xs, ys)
    xy = np.stack([X.ravel(), Y.ravel()], 1)
    P = np.column_stack([xy, field_model.surface_z(xy) + target_height])
    sl = localisation_sigma(camera, T_cam_field, cov_pose, P, pixel_sigma, range_sigma, "lidar").reshape(X.shape)
    sg = localisation_sigma(camera, T_cam_field, cov_pose, P, pixel_sigma, range_sigma, "ground")
    C = geometry.invert_T(T_cam_field)[:3, 3]
    sg = np.where(ground_visible(field_model, C, P), sg, np.nan).reshape(X.shape)
    return ErrorMap(xs, ys, sl, sg, pixel_sigma, range_sigma, target_height)


# --- Monte-Carlo validation ---------------------------------------------------------------------------------------
@dataclass
class MonteCarloResult:
    errors_lidar: np.ndarray    # (trials, N) horizontal error (m), NaN where the solve failed
    errors_ground: np.ndarray   # (trials, N)
    failures: int               # trials whose picks were rejected (FieldPnPError)
    pose_errors: np.ndarray     # (trials, 2) rotation deg, translation m

    def rms(self, which: str = "lidar") -> np.ndarray:
        e = self.errors_lidar if which == "lidar" else self.errors_ground
        return np.sqrt(np.nanmean(e**2, axis=0))


def monte_carlo(camera: Camera, T_cam_field: np.ndarray, landmarks: np.ndarray, targets: np.ndarray, trials: int = 200, click_sigma: float = 1.0, pixel_sigma: float = 1.0, range_sigma: float = 0.02, rng: np.random.Generator | None = None, field_model: FieldModel | None = None, names: list[str] | None = None) -> MonteCarloResult:
    """Simulate ``trials`` pre-match calibrations: true landmark pixels + N(0, click_sigma) → :func:`solve_field_pnp`
    → localise ``targets`` (N,3) from their true pixels + N(0, pixel_sigma) with LiDAR depth (+ N(0, range_sigma)) and
    with the ground fallback (field surface). Returns the horizontal errors."""
    rng = rng or np.random.default_rng(0)
    Lm = np.asarray(landmarks, float).reshape(-1, 3)
    P = np.asarray(targets, float).reshape(-1, 3)
    uv_l, _, _ = camera.project_from(T_cam_field, Lm)
    uv_t, _, z_t = camera.project_from(T_cam_field, P)
    el = np.full((trials, len(P)), np.nan)
    eg = np.full((trials, len(P)), np.nan)
    pe = np.full((trials, 2), np.nan)
    fails = 0
    opt = PnPOptions(click_sigma_px=click_sigma, max_position_sigma_m=1e9)
    sz = field_model.surface_z if field_model is not None else None
    for k in range(trials):
        picks = uv_l + rng.normal(0, click_sigma, uv_l.shape)
        u = uv_t + rng.normal(0, pixel_sigma, uv_t.shape)
        zz = z_t + rng.normal(0, range_sigma, z_t.shape)
        try:
            res = solve_field_pnp(camera, Lm, picks, names, opt, surface_z=sz)
        except FieldPnPError:
            fails += 1
            continue
        pe[k] = geometry.pose_error(res.T_cam_field, T_cam_field)
        pl = localise_lidar(camera, res.T_cam_field, u, zz)
        el[k] = np.linalg.norm(pl[:, :2] - P[:, :2], axis=1)
        pg = localise_ground(camera, res.T_cam_field, u, field_model) if field_model is not None else localise_ground(camera, res.T_cam_field, u, heights=P[:, 2])
        eg[k] = np.linalg.norm(pg[:, :2] - P[:, :2], axis=1)
    return MonteCarloResult(el, eg, fails, pe)
